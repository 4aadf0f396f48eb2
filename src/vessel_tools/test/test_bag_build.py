"""bag_build: bags from a dataset folder (generated, and the shared one when present) and from a video file."""

import csv
import math

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_detect import bag_messages, bag_reader, bag_topics
from vessel_fixtures import detect_synthetic as synthetic
from vessel_tools.detect import bag_build


def run_cli(args, capsys):
    status = bag_build.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return status, out, err


def read_back(path):
    """Images (stamp ns, bytes) and fixes per topic, read with rosbags and again with the mcap library."""
    with bag_reader.BagReader(path) as reader:
        images = [(bag_messages.sec_to_ns(t), data) for t, data in reader.images()]
        fixes = {
            topic: reader.fixes(topic)
            for topic in (bag_topics.DEFAULT_CAMERA_FIX_TOPIC, bag_topics.DEFAULT_GPS_TRUTH_TOPIC)
            if topic in reader.topics
        }
        times = [m.log_time_ns for m in reader.messages()]
    store = bag_messages.typestore()
    via_mcap_images, via_mcap_fixes = [], {}
    for message in bag_reader.iter_mcap(path):
        decoded = store.deserialize_cdr(message.cdr, message.msgtype)
        assert message.log_time_ns == bag_messages.ns_of_stamp(decoded.header.stamp)
        if message.topic == bag_topics.DEFAULT_IMAGE_TOPIC:
            assert decoded.format == "jpeg" and decoded.header.frame_id == "camera"
            via_mcap_images.append((message.log_time_ns, bytes(decoded.data)))
        else:
            via_mcap_fixes.setdefault(message.topic, []).append(
                (bag_messages.ns_of_stamp(decoded.header.stamp), decoded.latitude, decoded.longitude)
            )
    assert via_mcap_images == images
    for topic, series in fixes.items():
        assert via_mcap_fixes[topic] == [
            (bag_messages.sec_to_ns(t), la, lo)
            for t, la, lo in zip(series.stamps, series.lats, series.lons, strict=True)
        ]
    assert times == sorted(times)
    return images, fixes


def test_dataset_round_trip_every_byte_and_fix(tmp_path, capsys):
    data = synthetic.write_dataset(tmp_path / "data", videos=(13, 14), frames_per_video=5, bad_gps_rows=3)
    status, out, err = run_cli(["--data", data.path, "--videos", "13,14", "--out", tmp_path / "bags"], capsys)
    assert status == 0, err
    assert "video_13: 5 frames" in out and "done: 2 bag(s), 10 frames" in out
    assert "3 rows of target_gps_fixes.csv have no position (NaN/empty); skipped" in out
    assert sorted(p.name for p in (tmp_path / "bags").iterdir()) == ["video_13", "video_14"]
    margin = bag_build.BuildOptions().gps_margin_s
    for video in (13, 14):
        images, fixes = read_back(tmp_path / "bags" / f"video_{video}")
        stamps = data.stamps[video]
        assert [t for t, _ in images] == [bag_messages.sec_to_ns(s) for s in stamps]
        frames = sorted((data.path / "frames" / str(video)).glob("*.jpg"))
        assert [b for _, b in images] == [f.read_bytes() for f in frames]
        camera = fixes[bag_topics.DEFAULT_CAMERA_FIX_TOPIC]
        assert np.all(camera.lats == synthetic.CAMERA_LAT) and np.all(camera.lons == synthetic.CAMERA_LON)
        assert camera.stamps[0] == pytest.approx(stamps[0]) and camera.stamps[-1] <= stamps[-1]
        assert len(camera) == math.floor(stamps[-1] - stamps[0]) + 1  # 1 Hz from the first frame
        assert np.all(camera.status == bag_topics.STATUS_FIX)
        truth = fixes[bag_topics.DEFAULT_GPS_TRUTH_TOPIC]
        expected = [g for g in data.gps if stamps[0] - margin <= g[0] <= stamps[-1] + margin]
        assert len(truth) == len(expected) > 0
        np.testing.assert_allclose(truth.stamps, [g[0] for g in expected], rtol=0, atol=1e-6)
        np.testing.assert_array_equal(truth.lats, [g[1] for g in expected])
        np.testing.assert_array_equal(truth.lons, [g[2] for g in expected])


def test_existing_output_needs_overwrite(tmp_path, capsys):
    data = synthetic.write_dataset(tmp_path / "data", videos=(13,), frames_per_video=2)
    args = ["--data", data.path, "--out", tmp_path / "bags"]
    assert run_cli(args, capsys)[0] == 0
    status, _, err = run_cli(args, capsys)
    assert status == 2 and "exist(s) already" in err and "--overwrite" in err and "Traceback" not in err
    assert run_cli([*args, "--overwrite"], capsys)[0] == 0
    assert sorted(p.name for p in (tmp_path / "bags").iterdir()) == ["video_13"]


def test_unreadable_and_missing_jpegs_are_skipped_and_counted(tmp_path, capsys):
    data = synthetic.write_dataset(tmp_path / "data", videos=(13,), frames_per_video=6)
    (data.path / "frames/13/00200.jpg").write_bytes(b"\xff\xd8\xff\xe0" + b"\x00" * 4000)  # no image data
    (data.path / "frames/13/00300.jpg").unlink()
    status, out, err = run_cli(["--data", data.path, "--out", tmp_path / "bags"], capsys)
    assert status == 0, err
    assert "00200.jpg is unreadable" in out and "00300.jpg is missing" in out
    assert "video_13: 4 frames, 2 frames skipped" in out
    images, _ = read_back(tmp_path / "bags" / "video_13")
    assert [t for t, _ in images] == [bag_messages.sec_to_ns(s) for i, s in enumerate(data.stamps[13])
                                      if i not in (2, 3)]


def test_frames_out_of_time_order_are_refused(tmp_path, capsys):
    data = synthetic.write_dataset(tmp_path / "data", videos=(13,), frames_per_video=4)
    rows = list(csv.reader((data.path / "frames.csv").open()))
    rows[3][2], rows[2][2] = rows[2][2], rows[3][2]  # frame 200 now before frame 100
    with (data.path / "frames.csv").open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    status, _, err = run_cli(["--data", data.path, "--out", tmp_path / "bags"], capsys)
    assert status == 2
    assert "out of time order: video 13 frame 200" in err and "not after video 13 frame 100" in err
    assert not (tmp_path / "bags" / "video_13").exists()
    assert [p.name for p in (tmp_path / "bags").iterdir()] == []  # no half bag, no staging folder


def test_unknown_video_and_missing_dataset(tmp_path, capsys):
    data = synthetic.write_dataset(tmp_path / "data", videos=(13,), frames_per_video=2)
    status, _, err = run_cli(["--data", data.path, "--videos", "7-9", "--out", tmp_path / "bags"], capsys)
    assert status == 2 and "video(s) 7, 8, 9 not in" in err and "it has 13" in err
    status, _, err = run_cli(["--data", tmp_path / "nothing", "--out", tmp_path / "bags"], capsys)
    assert status == 2 and "does not exist" in err


def test_video_mode_with_gps_garbage_rows(tmp_path, capsys):
    video = synthetic.write_video(tmp_path / "boat.avi", frames=12, fps=10.0)
    start = synthetic.START_UTC
    good = synthetic.write_gps_csv(tmp_path / "track.csv", start, seconds=1.2)
    status, out, err = run_cli(
        ["--video", video, "--start-utc", synthetic.iso_utc(start), "--gps", tmp_path / "track.csv",
         "--camera-lat", synthetic.CAMERA_LAT, "--camera-lon", synthetic.CAMERA_LON, "--out", tmp_path / "bags"],
        capsys,
    )
    assert status == 0, err
    assert "boat: 12 frames" in out and "3 GPS rows skipped" in out
    images, fixes = read_back(tmp_path / "bags" / "boat")
    assert [t for t, _ in images] == [bag_messages.sec_to_ns(start) + k * 100_000_000 for k in range(12)]
    for k, (_, jpeg) in enumerate(images):  # re-encoded frames still show the right picture
        decoded = np.frombuffer(jpeg, dtype=np.uint8)
        import cv2

        image = cv2.imdecode(decoded, cv2.IMREAD_COLOR)
        assert image.shape == (120, 160, 3)
        assert np.abs(image.astype(int) - synthetic.frame_image(k).astype(int)).mean() < 12
    assert len(fixes[bag_topics.DEFAULT_GPS_TRUTH_TOPIC]) == good  # every good row, none of the garbage


def test_video_mode_fixed_fps_every_and_mp4(tmp_path, capsys):
    video = synthetic.write_video(tmp_path / "clip.mp4", frames=10, fps=5.0)
    status, out, err = run_cli(
        ["--video", video, "--start-utc", "1601495752.5", "--fps", "20", "--every", "3", "--camera-lat", "32.7",
         "--camera-lon", "-117.2", "--out", tmp_path / "bags", "--name", "clip3"],
        capsys,
    )
    assert status == 0, err
    images, fixes = read_back(tmp_path / "bags" / "clip3")
    assert [t for t, _ in images] == [bag_messages.sec_to_ns(1601495752.5 + k / 20) for k in (0, 3, 6, 9)]
    assert bag_topics.DEFAULT_GPS_TRUTH_TOPIC not in fixes  # no --gps: no truth topic


def test_video_mode_errors(tmp_path, capsys):
    common = ["--camera-lat", "32.7", "--camera-lon", "-117.2", "--out", tmp_path / "bags"]
    status, _, err = run_cli(["--video", tmp_path / "missing.mp4", "--start-utc", "0", *common], capsys)
    assert status == 2 and "video file" in err and "missing.mp4 does not exist" in err
    (tmp_path / "junk.mp4").write_bytes(b"not a video at all" * 100)
    status, _, err = run_cli(["--video", tmp_path / "junk.mp4", "--start-utc", "0", *common], capsys)
    assert status == 2 and "cannot open video" in err
    video = synthetic.write_video(tmp_path / "v.avi", frames=3)
    status, _, err = run_cli(["--video", video, *common], capsys)
    assert status == 2 and "needs --start-utc" in err
    status, _, err = run_cli(["--video", video, "--start-utc", "yesterday", *common], capsys)
    assert status == 2 and "neither ISO-8601" in err
    (tmp_path / "nan.csv").write_text("time,lat,lon\n2020-09-30T19:55:52Z,nan,nan\n")
    status, _, err = run_cli(["--video", video, "--start-utc", "0", "--gps", tmp_path / "nan.csv", *common], capsys)
    assert status == 2 and "no usable fix (1 rows skipped" in err
    assert not (tmp_path / "bags" / "v").exists()


def test_write_bag_rejects_bad_camera_position(tmp_path):
    with pytest.raises(DataError, match="camera position"):
        bag_build.write_bag(tmp_path / "b", [], camera_lat=math.nan, camera_lon=0.0, gps=None,
                            options=bag_build.BuildOptions(), name="b")


@pytest.mark.data
def test_shared_dataset_video_round_trip(tmp_path, capsys):
    from vessel_common.paths import default_data_dir
    from vessel_tools.calib.dataset import Dataset

    data_dir = default_data_dir()
    if data_dir is None:
        pytest.skip("shared dataset ../shared/aitas (or $VESSEL_DATA) is absent")
    status, out, err = run_cli(["--data", data_dir, "--videos", "15", "--out", tmp_path], capsys)
    assert status == 0, err
    dataset = Dataset(data_dir)
    records = dataset.frames([15])
    images, fixes = read_back(tmp_path / "video_15")
    assert [b for _, b in images] == [r.path.read_bytes() for r in records]
    assert [t for t, _ in images] == [bag_messages.sec_to_ns(r.stamp) for r in records]
    track = dataset.gps_track()
    margin = bag_build.BuildOptions().gps_margin_s
    keep = (track.stamps >= records[0].stamp - margin) & (track.stamps <= records[-1].stamp + margin)
    truth = fixes[bag_topics.DEFAULT_GPS_TRUTH_TOPIC]
    assert len(truth) == int(keep.sum()) > 100
    np.testing.assert_array_equal(truth.lats, track.lats[keep])
    np.testing.assert_array_equal(truth.lons, track.lons[keep])
    np.testing.assert_allclose(truth.stamps, track.stamps[keep], rtol=0, atol=1e-6)
