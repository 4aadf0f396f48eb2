"""Live sources: device and stream specs, a camera read through a capture stub."""

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_detect import live_sources, source_spec
from vessel_fixtures import detect_synthetic as synthetic


def test_device_and_stream_specs(tmp_path):
    assert live_sources.parse_device("device:0") == 0
    assert live_sources.parse_device("/dev/video2") == "/dev/video2"
    assert live_sources.parse_device("rtsp://cam.local/stream") == "rtsp://cam.local/stream"
    assert live_sources.parse_device(str(tmp_path)) is None
    with pytest.raises(DataError, match="cannot open camera /dev/video-missing: check that it is connected"):
        source_spec.open_source("device:/dev/video-missing")


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

    monkeypatch.setattr(live_sources.cv2, "VideoCapture", StubCapture)
    clock = iter(range(1_000_000_000, 2_000_000_000, 33_000_000))
    problems = []
    source = source_spec.open_source("device:0", on_problem=lambda kind, message: problems.append(kind))
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
