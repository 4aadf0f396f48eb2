"""Image sources: bags (with the other topics), video files, image folders, devices; offset, loop, bad frames."""

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_detect import bag_io, sources
from vessel_detect.sources import AuxMessage, Frame
from vessel_fixtures import detect_synthetic as synthetic


def frames_of(items):
    return [i for i in items if isinstance(i, Frame)]


def test_bag_source_yields_frames_and_other_topics_in_time_order(tmp_path):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=5, frame_step_s=0.2)
    with sources.open_source(tmp_path / "bag") as source:
        assert isinstance(source, sources.BagSource)
        assert source.frame_count() == 5 and source.first_stamp_ns() == stamps[0]
        items = list(source)
    frames = frames_of(items)
    assert [f.stamp_ns for f in frames] == stamps
    assert [f.jpeg for f in frames] == [synthetic.frame_jpeg(k) for k in range(5)]
    assert all(not f.decoded for f in frames)  # nothing decoded until asked
    assert frames[2].bgr().shape == (120, 160, 3) and frames[2].decoded
    aux = [i for i in items if isinstance(i, AuxMessage)]
    assert [a.topic for a in aux].count(bag_io.DEFAULT_CAMERA_FIX_TOPIC) == 1
    assert [a.topic for a in aux].count(bag_io.DEFAULT_GPS_TRUTH_TOPIC) == 5
    assert isinstance(items[0], AuxMessage) and items[0].topic == bag_io.DEFAULT_CAMERA_FIX_TOPIC
    times = [i.stamp_ns for i in items]
    assert times == sorted(times)
    assert source.stats.frames == 5 and source.stats.aux == 6


def test_bag_source_offset_keeps_latched_fix(tmp_path):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=10, frame_step_s=0.2)
    items = list(sources.open_source(tmp_path / "bag", start_offset_s=1.0))
    frames = frames_of(items)
    assert [f.stamp_ns for f in frames] == stamps[5:]
    assert items[0].topic == bag_io.DEFAULT_CAMERA_FIX_TOPIC  # the fix logged before the offset comes first
    truth = [i for i in items if isinstance(i, AuxMessage) and i.topic == bag_io.DEFAULT_GPS_TRUTH_TOPIC]
    assert len(truth) == 1 + 5  # latest one before the offset, then those from the offset on


def test_bag_source_loop_restamps_or_repeats(tmp_path):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=3, frame_step_s=0.5)
    source = sources.open_source(tmp_path / "bag", loop=True)
    frames = []
    for item in source:
        if isinstance(item, Frame):
            frames.append(item)
        if len(frames) == 7:
            break
    period = stamps[-1] - stamps[0] + 500_000_000  # the span plus one frame interval
    assert [f.stamp_ns for f in frames] == [s + k * period for k in range(3) for s in stamps][:7]
    assert [f.loop for f in frames] == [0, 0, 0, 1, 1, 1, 2]
    assert frames[3].jpeg == frames[0].jpeg
    repeat = sources.open_source(tmp_path / "bag", loop=True, restamp_loops=False)
    first_six = []
    for item in repeat:
        if isinstance(item, Frame):
            first_six.append(item.stamp_ns)
        if len(first_six) == 6:
            break
    assert first_six == stamps + stamps


def test_unreadable_jpeg_mid_bag_is_skipped_counted_and_reported(tmp_path):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=6, bad_frames=(3,))
    problems = []
    source = sources.open_source(tmp_path / "bag", on_problem=lambda kind, msg: problems.append((kind, msg)))
    frames = frames_of(source)
    assert [f.stamp_ns for f in frames] == stamps[:3] + stamps[4:]
    assert source.stats.unreadable == 1
    [(kind, message)] = problems
    assert kind == "unreadable" and "unreadable" in message and f"{stamps[3] / 1e9:.6f}" in message


def test_out_of_order_frames_skipped_or_refused(tmp_path):
    stamps = [bag_io.sec_to_ns(synthetic.START_UTC + t) for t in (0.0, 0.2, 0.1, 0.4)]
    with bag_io.BagWriter(tmp_path / "bag") as writer:
        writer.add_topic(bag_io.DEFAULT_IMAGE_TOPIC, bag_io.COMPRESSED_IMAGE)
        for k, stamp in enumerate(stamps):
            writer.write(bag_io.DEFAULT_IMAGE_TOPIC, bag_io.compressed_image(stamp, synthetic.frame_jpeg(k)),
                         log_time_ns=stamps[0] + k)
    problems = []
    source = sources.open_source(tmp_path / "bag", on_problem=lambda kind, msg: problems.append(kind))
    assert [f.stamp_ns for f in frames_of(source)] == [stamps[0], stamps[1], stamps[3]]
    assert problems == ["out_of_order"] and source.stats.out_of_order == 1
    with pytest.raises(DataError, match="out of time order"):
        list(sources.open_source(tmp_path / "bag", strict_order=True))


def test_bag_source_errors(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        sources.open_source(tmp_path / "missing")
    synthetic.write_bag(tmp_path / "bag", frames=2, image_topic="/other/image")
    with pytest.raises(DataError, match="no topic /camera/image_raw/compressed"):
        sources.open_source(tmp_path / "bag")
    source = sources.open_source(tmp_path / "bag", image_topic="/other/image")
    assert len(frames_of(source)) == 2


def test_video_source_stamps_and_offset(tmp_path):
    video = synthetic.write_video(tmp_path / "v.avi", frames=10, fps=10.0)
    start = synthetic.START_UTC
    source = sources.open_source(video, start_utc=start)
    frames = frames_of(source)
    base = bag_io.sec_to_ns(start)
    assert [f.stamp_ns for f in frames] == [base + k * 100_000_000 for k in range(10)]
    assert all(f.jpeg is None and f.decoded for f in frames)
    assert np.abs(frames[4].bgr().astype(int) - synthetic.frame_image(4).astype(int)).mean() < 12
    assert frames[4].jpeg_bytes()[:3] == b"\xff\xd8\xff"
    late = frames_of(sources.open_source(video, start_utc=start, start_offset_s=0.55))
    assert [f.stamp_ns for f in late] == [base + k * 100_000_000 for k in range(6, 10)]
    with pytest.raises(DataError, match="does not exist"):
        sources.VideoSource(tmp_path / "none.mp4")


def test_folder_source_stamps_from_names(tmp_path):
    folder = tmp_path / "images"
    folder.mkdir()
    names = ["cam_2020-09-30T19-55-53.500Z.jpg", "cam_2020-09-30T19-55-52.884Z.jpg", "cam_2020-09-30T19-55-54.1Z.jpg"]
    for k, name in enumerate(names):
        (folder / name).write_bytes(synthetic.frame_jpeg(k))
    source = sources.open_source(folder)
    assert isinstance(source, sources.FolderSource) and source.stamp_origin == "file names"
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
    source = sources.open_source(folder, fps=2.0, start_utc=100.0, on_problem=lambda k, m: problems.append(m))
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
    assert sources.stamp_from_name(name) == expected


def test_parse_utc():
    assert sources.parse_utc("2020-09-30T19:55:52.884Z") == pytest.approx(1601495752.884)
    assert sources.parse_utc("2020-09-30T21:55:52.884+02:00") == pytest.approx(1601495752.884)
    assert sources.parse_utc("1601495752.884") == 1601495752.884
    with pytest.raises(DataError, match="neither ISO-8601"):
        sources.parse_utc("noon")


def test_device_and_stream_specs(tmp_path):
    assert sources.parse_device("device:0") == 0
    assert sources.parse_device("/dev/video2") == "/dev/video2"
    assert sources.parse_device("rtsp://cam.local/stream") == "rtsp://cam.local/stream"
    assert sources.parse_device(str(tmp_path)) is None
    with pytest.raises(DataError, match="cannot open camera /dev/video-missing: check that it is connected"):
        sources.open_source("device:/dev/video-missing")


def test_device_source_reads_a_capture_stub(monkeypatch):
    class StubCapture:
        def __init__(self, device):
            self.reads = 0

        def isOpened(self):  # noqa: N802 - the OpenCV name
            return True

        def set(self, *args):
            return True

        def read(self):
            self.reads += 1
            if self.reads == 2:
                return False, None  # one failed read: counted, not fatal
            return True, synthetic.frame_image(self.reads)

        def release(self):
            pass

    monkeypatch.setattr(sources.cv2, "VideoCapture", StubCapture)
    clock = iter(range(1_000_000_000, 2_000_000_000, 33_000_000))
    problems = []
    source = sources.open_source("device:0", on_problem=lambda kind, message: problems.append(kind))
    source.clock = lambda: next(clock)
    frames = []
    for frame in source:
        frames.append(frame)
        if len(frames) == 4:
            source.stop()
    assert len(frames) == 4 and source.is_live
    assert [f.stamp_ns for f in frames] == sorted(f.stamp_ns for f in frames)
    assert problems == ["unreadable"] and source.stats.unreadable == 1
    np.testing.assert_array_equal(frames[0].bgr(), synthetic.frame_image(1))


def test_source_argument_errors(tmp_path):
    with pytest.raises(DataError, match="no source given"):
        sources.open_source("")
    with pytest.raises(DataError, match="start offset"):
        synthetic.write_bag(tmp_path / "bag", frames=2)
        sources.open_source(tmp_path / "bag", start_offset_s=-1.0)
    (tmp_path / "one.jpg").write_bytes(synthetic.frame_jpeg(0))
    with pytest.raises(DataError, match="single image"):
        sources.open_source(tmp_path / "one.jpg")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="has no images"):
        sources.open_source(tmp_path / "empty")


def test_jpeg_problem():
    good = synthetic.frame_jpeg(1)
    assert sources.jpeg_problem(good) is None
    assert "end marker" in sources.jpeg_problem(good[: len(good) // 2])
    assert "start marker" in sources.jpeg_problem(b"\x89PNG" + good[4:])
    assert "bytes" in sources.jpeg_problem(b"\xff\xd8")
    # Garbage inside, both markers intact: libjpeg patches it over (and says so), so only strict refuses it.
    textured = sources.encode_jpeg(np.random.default_rng(1).integers(0, 255, (240, 320, 3), dtype=np.uint8))
    corrupt = bytearray(textured)
    start, size = 2 * len(textured) // 3, 400
    corrupt[start:start + size] = np.random.default_rng(0).integers(0, 255, size, dtype=np.uint8).tobytes()
    assert sources.jpeg_problem(bytes(corrupt)) is None
    assert "corrupt JPEG data inside" in sources.jpeg_problem(bytes(corrupt), strict=True)
    assert sources.jpeg_problem(textured, strict=True) is None
