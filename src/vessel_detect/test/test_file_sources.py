"""File sources: bags (with the other topics), video files, image folders; offset, bad frames, stamps."""

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_detect import bag_messages, bag_topics, file_sources, source_spec
from vessel_detect.image_source import AuxMessage, Frame
from vessel_fixtures import detect_synthetic as synthetic


def frames_of(items):
    return [i for i in items if isinstance(i, Frame)]


def test_bag_source_yields_frames_and_other_topics_in_time_order(tmp_path):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=5, frame_step_s=0.2)
    with source_spec.open_source(tmp_path / "bag") as source:
        assert isinstance(source, file_sources.BagSource)
        assert source.frame_count() == 5 and source.first_stamp_ns() == stamps[0]
        items = list(source)
    frames = frames_of(items)
    assert [f.stamp_ns for f in frames] == stamps
    assert [f.jpeg for f in frames] == [synthetic.frame_jpeg(k) for k in range(5)]
    assert all(not f.decoded for f in frames)  # nothing decoded until asked
    assert frames[2].bgr().shape == (120, 160, 3) and frames[2].decoded
    aux = [i for i in items if isinstance(i, AuxMessage)]
    assert [a.topic for a in aux].count(bag_topics.DEFAULT_CAMERA_FIX_TOPIC) == 1
    assert [a.topic for a in aux].count(bag_topics.DEFAULT_GPS_TRUTH_TOPIC) == 5
    assert isinstance(items[0], AuxMessage) and items[0].topic == bag_topics.DEFAULT_CAMERA_FIX_TOPIC
    times = [i.stamp_ns for i in items]
    assert times == sorted(times)
    assert source.stats.frames == 5 and source.stats.aux == 6


def test_bag_source_offset_keeps_latched_fix(tmp_path):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=10, frame_step_s=0.2)
    items = list(source_spec.open_source(tmp_path / "bag", start_offset_s=1.0))
    frames = frames_of(items)
    assert [f.stamp_ns for f in frames] == stamps[5:]
    assert items[0].topic == bag_topics.DEFAULT_CAMERA_FIX_TOPIC  # the fix logged before the offset comes first
    truth = [i for i in items if isinstance(i, AuxMessage) and i.topic == bag_topics.DEFAULT_GPS_TRUTH_TOPIC]
    assert len(truth) == 1 + 5  # latest one before the offset, then those from the offset on


def test_unreadable_jpeg_mid_bag_is_skipped_counted_and_reported(tmp_path):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=6, bad_frames=(3,))
    problems = []
    source = source_spec.open_source(tmp_path / "bag", on_problem=lambda kind, msg: problems.append((kind, msg)))
    frames = frames_of(source)
    assert [f.stamp_ns for f in frames] == stamps[:3] + stamps[4:]
    assert source.stats.unreadable == 1
    [(kind, message)] = problems
    assert kind == "unreadable" and "unreadable" in message and f"{stamps[3] / 1e9:.6f}" in message


def test_bag_source_errors(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        source_spec.open_source(tmp_path / "missing")
    synthetic.write_bag(tmp_path / "bag", frames=2, image_topic="/other/image")
    with pytest.raises(DataError, match="no topic /camera/image_raw/compressed"):
        source_spec.open_source(tmp_path / "bag")
    source = source_spec.open_source(tmp_path / "bag", image_topic="/other/image")
    assert len(frames_of(source)) == 2


def test_video_source_stamps_and_offset(tmp_path):
    video = synthetic.write_video(tmp_path / "v.avi", frames=10, fps=10.0)
    start = synthetic.START_UTC
    source = source_spec.open_source(video, start_utc=start)
    frames = frames_of(source)
    base = bag_messages.sec_to_ns(start)
    assert [f.stamp_ns for f in frames] == [base + k * 100_000_000 for k in range(10)]
    assert all(f.jpeg is None and f.decoded for f in frames)
    assert np.abs(frames[4].bgr().astype(int) - synthetic.frame_image(4).astype(int)).mean() < 12
    assert frames[4].jpeg_bytes()[:3] == b"\xff\xd8\xff"
    late = frames_of(source_spec.open_source(video, start_utc=start, start_offset_s=0.55))
    assert [f.stamp_ns for f in late] == [base + k * 100_000_000 for k in range(6, 10)]
    with pytest.raises(DataError, match="does not exist"):
        file_sources.VideoSource(tmp_path / "none.mp4")


def test_folder_source_stamps_from_names(tmp_path):
    folder = tmp_path / "images"
    folder.mkdir()
    names = ["cam_2020-09-30T19-55-53.500Z.jpg", "cam_2020-09-30T19-55-52.884Z.jpg", "cam_2020-09-30T19-55-54.1Z.jpg"]
    for k, name in enumerate(names):
        (folder / name).write_bytes(synthetic.frame_jpeg(k))
    source = source_spec.open_source(folder)
    assert isinstance(source, file_sources.FolderSource) and source.stamp_origin == "file names"
    frames = frames_of(source)
    assert [f.stamp_ns for f in frames] == [1601495752_884000000, 1601495753_500000000, 1601495754_100000000]
    assert frames[0].jpeg == synthetic.frame_jpeg(1)


def test_folder_source_fixed_rate_png_and_bad_file(tmp_path):
    import cv2

    folder = tmp_path / "images"
    folder.mkdir()
    for k in range(4):
        cv2.imwrite(str(folder / f"frame{k}.png"), synthetic.frame_image(k))
    (folder / "frame10.jpg").write_bytes(b"not a jpeg" * 50)
    problems = []
    source = source_spec.open_source(folder, fps=2.0, start_utc=100.0, on_problem=lambda k, m: problems.append(m))
    frames = frames_of(source)
    assert [f.stamp_ns for f in frames] == [100_000_000_000 + k * 500_000_000 for k in range(4)]
    np.testing.assert_array_equal(frames[3].bgr(), synthetic.frame_image(3))  # PNG is lossless
    assert frames[0].jpeg is None and frames[0].jpeg_bytes()[:2] == b"\xff\xd8"
    assert len(problems) == 1 and "frame10.jpg is unreadable" in problems[0]


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("1601495752.884.jpg", 1601495752_884000000),
        ("cam_1601495752_5.jpg", 1601495752_500000000),
        ("1601495752884000000.jpg", 1601495752_884000000),
        ("20200930_195552.jpg", 1601495752_000000000),
        ("00100.jpg", None),
        ("frame_7.png", None),
    ],
)
def test_stamp_from_name(name, expected):
    assert file_sources.stamp_from_name(name) == expected


def test_parse_utc():
    assert file_sources.parse_utc("2020-09-30T19:55:52.884Z") == pytest.approx(1601495752.884)
    assert file_sources.parse_utc("2020-09-30T21:55:52.884+02:00") == pytest.approx(1601495752.884)
    assert file_sources.parse_utc("1601495752.884") == 1601495752.884
    with pytest.raises(DataError, match="neither ISO-8601"):
        file_sources.parse_utc("noon")
