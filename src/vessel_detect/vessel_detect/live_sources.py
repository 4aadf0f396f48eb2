"""Live image sources: a camera or stream through OpenCV, stamped by the clock, reconnecting when it drops out."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import cv2

from vessel_common.errors import DataError
from vessel_detect.image_source import AuxMessage, Frame, ImageSource

STREAM_PREFIXES = ("rtsp://", "rtsps://", "http://", "https://", "udp://", "tcp://", "rtmp://")


# ---------------------------------------------------------------------------------------------------------------
# Live cameras
# ---------------------------------------------------------------------------------------------------------------
class DeviceSource(ImageSource):
    """A live camera or stream through OpenCV (`device:0`, `/dev/video2`, `rtsp://...`), stamped by the clock.

    The stamp is the wall-clock time when the frame was grabbed. Failed reads are counted; after
    `reconnect_after` failures in a row the device is reopened (once a second until it answers), so a camera
    that drops out comes back without restarting the node. It ends only when `stop()` is called.
    """

    kind = "device"
    is_live = True

    def __init__(
        self,
        device: int | str,
        *,
        width: int = 0,
        height: int = 0,
        fps: float = 0.0,
        reconnect_after: int = 30,
        clock: Callable[[], int] = time.time_ns,
        **options,
    ) -> None:
        options.pop("loop", None)
        super().__init__(**options)
        self.device = device
        self.description = f"camera {device}"
        self.width, self.height, self.fps = int(width), int(height), float(fps)
        self.reconnect_after = int(reconnect_after)
        self.clock = clock
        self._stopped = False
        self._capture = self._open()
        if self._capture is None:
            raise DataError(
                f"cannot open {self.description}: check that it is connected and not used by another program "
                "(device:N is the OpenCV index, /dev/videoN a V4L2 path, or a stream URL)"
            )

    def _open(self) -> cv2.VideoCapture | None:
        capture = cv2.VideoCapture(self.device)
        if not capture.isOpened():
            capture.release()
            return None
        if self.width > 0:
            capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        if self.height > 0:
            capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        if self.fps > 0:
            capture.set(cv2.CAP_PROP_FPS, self.fps)
        return capture

    def stop(self) -> None:
        """End the iteration after the current frame."""
        self._stopped = True

    def _pass(self, start_ns: int | None) -> Iterator[Frame | AuxMessage]:
        index = 0
        failures = 0
        skip_until = None if self.start_offset_s <= 0 else time.monotonic() + self.start_offset_s
        while not self._stopped:
            if self._capture is None:
                time.sleep(1.0)
                self._capture = self._open()
                continue
            ok, image = self._capture.read()
            stamp_ns = self.clock()
            if not ok or image is None:
                failures += 1
                self.problem("unreadable", f"{self.description}: reading a frame failed")
                if failures >= self.reconnect_after:
                    self._capture.release()
                    self._capture = None
                    failures = 0
                else:
                    time.sleep(0.01)
                continue
            failures = 0
            if skip_until is not None and time.monotonic() < skip_until:
                continue
            yield Frame(stamp_ns, index, _bgr=image)
            index += 1

    def close(self) -> None:
        """Release the device."""
        self._stopped = True
        if self._capture is not None:
            self._capture.release()
            self._capture = None


def parse_device(spec: str) -> int | str | None:
    """The OpenCV device of `device:0`, `/dev/video0`, a stream URL; None when `spec` names no device."""
    spec = spec.strip()
    if spec.startswith("device:"):
        value = spec[len("device:") :]
        return int(value) if value.isdigit() else value
    if spec.startswith("/dev/video"):
        return spec
    if spec.lower().startswith(STREAM_PREFIXES):
        return spec
    return None
