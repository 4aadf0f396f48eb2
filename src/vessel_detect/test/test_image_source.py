"""image_source: loop and time order (every source's), JPEG checks."""

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_detect import bag_messages, bag_topics, bag_writer, image_source, source_spec
from vessel_detect.image_source import Frame
from vessel_fixtures import detect_synthetic as synthetic


def frames_of(items):
    return [i for i in items if isinstance(i, Frame)]


def test_bag_source_loop_restamps_or_repeats(tmp_path):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=3, frame_step_s=0.5)
    source = source_spec.open_source(tmp_path / "bag", loop=True)
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
    repeat = source_spec.open_source(tmp_path / "bag", loop=True, restamp_loops=False)
    first_six = []
    for item in repeat:
        if isinstance(item, Frame):
            first_six.append(item.stamp_ns)
        if len(first_six) == 6:
            break
    assert first_six == stamps + stamps


def test_out_of_order_frames_skipped_or_refused(tmp_path):
    stamps = [bag_messages.sec_to_ns(synthetic.START_UTC + t) for t in (0.0, 0.2, 0.1, 0.4)]
    with bag_writer.BagWriter(tmp_path / "bag") as writer:
        writer.add_topic(bag_topics.DEFAULT_IMAGE_TOPIC, bag_topics.COMPRESSED_IMAGE)
        for k, stamp in enumerate(stamps):
            writer.write(bag_topics.DEFAULT_IMAGE_TOPIC, bag_messages.compressed_image(stamp, synthetic.frame_jpeg(k)),
                         log_time_ns=stamps[0] + k)
    problems = []
    source = source_spec.open_source(tmp_path / "bag", on_problem=lambda kind, msg: problems.append(kind))
    assert [f.stamp_ns for f in frames_of(source)] == [stamps[0], stamps[1], stamps[3]]
    assert problems == ["out_of_order"] and source.stats.out_of_order == 1
    with pytest.raises(DataError, match="out of time order"):
        list(source_spec.open_source(tmp_path / "bag", strict_order=True))


def test_jpeg_problem():
    good = synthetic.frame_jpeg(1)
    assert image_source.jpeg_problem(good) is None
    assert "end marker" in image_source.jpeg_problem(good[: len(good) // 2])
    assert "start marker" in image_source.jpeg_problem(b"\x89PNG" + good[4:])
    assert "bytes" in image_source.jpeg_problem(b"\xff\xd8")
    # Garbage inside, both markers intact: libjpeg patches it over (and says so), so only strict refuses it.
    textured = image_source.encode_jpeg(np.random.default_rng(1).integers(0, 255, (240, 320, 3), dtype=np.uint8))
    corrupt = bytearray(textured)
    start, size = 2 * len(textured) // 3, 400
    corrupt[start:start + size] = np.random.default_rng(0).integers(0, 255, size, dtype=np.uint8).tobytes()
    assert image_source.jpeg_problem(bytes(corrupt)) is None
    assert "corrupt JPEG data inside" in image_source.jpeg_problem(bytes(corrupt), strict=True)
    assert image_source.jpeg_problem(textured, strict=True) is None
