"""What image sources yield and their base class: frames, other topics' messages, counts, offset, loop, order.

Every source yields `Frame`s in time order (stamps in integer nanoseconds since the epoch, as ROS headers carry
them), with the encoded bytes as they were stored (JPEG from bags and folders) and the BGR image decoded only when
asked for. Bag sources also yield the other recorded topics (`AuxMessage`: the camera's fix, the vessel's GPS
truth) so a replay republishes them. Sources can start at an offset and loop. Problems with single frames are
reported to a handler and counted, never raised, so a node keeps going; problems with the source as a whole
(missing file, damaged bag, no image topic) raise `DataError` when the source is opened.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

from vessel_common.errors import DataError
from vessel_detect import bag_reader

ProblemHandler = Callable[[str, str], None]
"""Called as handler(kind, message) for every frame-level problem (kinds: see `SourceStats`)."""

_NS_PER_S = 1_000_000_000


# ---------------------------------------------------------------------------------------------------------------
# Frames and encoded images
# ---------------------------------------------------------------------------------------------------------------
def jpeg_problem(data: bytes, strict: bool = False) -> str | None:
    """Why `data` is not a usable JPEG (a short reason), or None when it decodes.

    Checks the start and end markers (a truncated file has no end marker, although libjpeg would still decode
    its top part with a grey bottom) and then decodes at 1/8 scale, which parses the whole file quickly.
    ``strict`` also refuses a JPEG that libjpeg decodes only by patching over corrupt data inside it (it says so
    on the process's standard error and returns an image with garbage blocks): for offline tools such as the bag
    builder, single-threaded, since it captures file descriptor 2 while decoding.
    """
    if len(data) < 128:
        return f"only {len(data)} bytes"
    if data[:3] != b"\xff\xd8\xff":
        return "no JPEG start marker"
    if b"\xff\xd9" not in data[-64:]:
        return "no JPEG end marker (truncated?)"
    buffer = np.frombuffer(data, dtype=np.uint8)
    if strict:
        image, warnings = _decode_capturing_libjpeg_warnings(buffer)
        if warnings:
            return f"corrupt JPEG data inside ({warnings.splitlines()[0].strip()})"
    else:
        image = cv2.imdecode(buffer, cv2.IMREAD_REDUCED_GRAYSCALE_8)
    if image is None or image.size == 0:
        return "the JPEG does not decode"
    return None


def _decode_capturing_libjpeg_warnings(buffer: np.ndarray) -> tuple[np.ndarray | None, str]:
    """Decode at 1/8 scale; what libjpeg wrote to standard error meanwhile ("Corrupt JPEG data: ...")."""
    import os
    import sys
    import tempfile

    with tempfile.TemporaryFile() as captured:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(captured.fileno(), 2)
        try:
            image = cv2.imdecode(buffer, cv2.IMREAD_REDUCED_GRAYSCALE_8)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        text = captured.read().decode(errors="replace")
    warnings = "\n".join(line for line in text.splitlines() if "JPEG" in line or "jpeg" in line)
    return image, warnings


def encode_jpeg(bgr: np.ndarray, quality: int = 95) -> bytes:
    """JPEG bytes of a BGR image."""
    ok, buffer = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise DataError(f"cannot encode a {bgr.shape} image as JPEG")
    return buffer.tobytes()


def decode_image(data: bytes, what: str = "image") -> np.ndarray:
    """Decode encoded bytes (JPEG, PNG, ...) to a BGR uint8 image; `DataError` when they do not decode."""
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise DataError(f"{what} does not decode ({len(data)} bytes)")
    return image


@dataclass
class Frame:
    """One image with its stamp.

    `jpeg` holds JPEG bytes exactly as stored, when the source stores JPEG (bags, folders of .jpg); `bgr()`
    decodes them once, on first use (a video or camera frame is already decoded and has `jpeg=None`).
    """

    stamp_ns: int
    index: int
    jpeg: bytes | None = None
    loop: int = 0
    frame_id: str | None = None  # from the source (a bag's header), else the node's parameter
    encoded: bytes | None = field(default=None, repr=False)  # non-JPEG encoded bytes (PNG from a bag/folder)
    _bgr: np.ndarray | None = field(default=None, repr=False)
    _loader: Callable[[], np.ndarray] | None = field(default=None, repr=False)

    @property
    def stamp(self) -> float:
        """Stamp in epoch seconds."""
        return self.stamp_ns / 1e9

    def bgr(self) -> np.ndarray:
        """The image as a BGR uint8 array (decoded once); `DataError` when the stored bytes do not decode."""
        if self._bgr is None:
            if self.jpeg is not None:
                self._bgr = decode_image(self.jpeg, f"JPEG of frame {self.index} at {self.stamp:.3f} s")
            elif self.encoded is not None:
                self._bgr = decode_image(self.encoded, f"image of frame {self.index} at {self.stamp:.3f} s")
            elif self._loader is not None:
                self._bgr = self._loader()
            else:
                raise DataError(f"frame {self.index} at {self.stamp:.3f} s holds no image")
        return self._bgr

    @property
    def decoded(self) -> bool:
        """Whether the BGR image is at hand without decoding."""
        return self._bgr is not None

    def jpeg_bytes(self, quality: int = 95) -> bytes:
        """JPEG bytes: the stored ones when there are, else the image encoded now (and kept)."""
        if self.jpeg is None:
            self.jpeg = encode_jpeg(self.bgr(), quality)
        return self.jpeg


@dataclass
class AuxMessage:
    """A message of another topic recorded in a bag (CDR bytes, log time), for republishing."""

    stamp_ns: int
    topic: str
    msgtype: str
    cdr: bytes
    loop: int = 0


@dataclass
class SourceStats:
    """What a source has yielded and skipped so far."""

    frames: int = 0  # frames yielded
    aux: int = 0  # other-topic messages yielded
    out_of_order: int = 0  # frames skipped: stamp not after the previous frame's
    unreadable: int = 0  # frames skipped: no image could be read (bad file, device read failure)
    damaged_chunk: int = 0  # chunks of a bag whose checksum failed (their frames are lost)
    loops: int = 0  # completed passes


# ---------------------------------------------------------------------------------------------------------------
# Base class: offset, loop, ordering
# ---------------------------------------------------------------------------------------------------------------
class ImageSource:
    """Iterate frames (and, for bags, other messages) in time order, with a start offset and optional loop.

    Subclasses implement `_pass(start_ns)`, one pass over their content from a stamp on. On a loop every pass
    yields the same window again; with `restamp_loops` later passes are shifted by the window's length plus one
    frame interval so time keeps increasing (trackers and /clock need that), otherwise stamps repeat.
    """

    kind = "source"
    is_live = False

    def __init__(
        self,
        *,
        start_offset_s: float = 0.0,
        loop: bool = False,
        restamp_loops: bool = True,
        on_problem: ProblemHandler | None = None,
        strict_order: bool = False,
    ) -> None:
        if not math.isfinite(start_offset_s) or start_offset_s < 0:
            raise DataError(f"start offset {start_offset_s!r} s must be a non-negative number")
        self.start_offset_s = float(start_offset_s)
        self.loop = loop
        self.restamp_loops = restamp_loops
        self.on_problem = on_problem
        self.strict_order = strict_order
        self.stats = SourceStats()
        self.description = self.kind

    # -- subclass interface
    def first_stamp_ns(self) -> int | None:
        """Stamp of the source's first frame, when known before reading (files), else None."""
        return None

    def last_stamp_ns(self) -> int | None:
        """Stamp of the source's last frame, when known before reading."""
        return None

    def frame_count(self) -> int | None:
        """Frames in one pass, when known before reading (for progress)."""
        return None

    def _pass(self, start_ns: int | None) -> Iterator[Frame | AuxMessage]:
        raise NotImplementedError

    def close(self) -> None:
        """Release files and devices."""

    # -- shared behaviour
    def problem(self, kind: str, message: str) -> None:
        """Count a frame-level problem and hand it to the handler."""
        setattr(self.stats, kind, getattr(self.stats, kind) + 1)
        if self.on_problem is not None:
            self.on_problem(kind, message)

    def _start_ns(self) -> int | None:
        first = self.first_stamp_ns()
        if first is None:
            return None
        return first + round(self.start_offset_s * _NS_PER_S)

    def __iter__(self) -> Iterator[Frame | AuxMessage]:
        start_ns = self._start_ns()
        loop_index = 0
        shift_ns = 0
        while True:
            previous_ns: int | None = None
            first_ns: int | None = None
            yielded = 0
            for item in self._pass(start_ns):
                if isinstance(item, AuxMessage):
                    item.loop = loop_index
                    item.stamp_ns += shift_ns
                    self.stats.aux += 1
                    yield item
                    continue
                if previous_ns is not None and item.stamp_ns <= previous_ns:
                    if self.strict_order:
                        raise bag_reader.out_of_order_error(
                            self.description, "frames", item.index, previous_ns, item.stamp_ns
                        )
                    self.problem(
                        "out_of_order",
                        f"{self.description}: frame {item.index} stamped {item.stamp_ns / 1e9:.6f} s is not after "
                        f"the previous frame ({previous_ns / 1e9:.6f} s); skipped",
                    )
                    continue
                if first_ns is None:
                    first_ns = item.stamp_ns
                previous_ns = item.stamp_ns
                item.loop = loop_index
                item.stamp_ns += shift_ns
                self.stats.frames += 1
                yielded += 1
                yield item
            self.stats.loops += 1
            if not self.loop or yielded == 0 or self.is_live:
                return
            if self.restamp_loops and first_ns is not None and previous_ns is not None:
                interval = (previous_ns - first_ns) // max(yielded - 1, 1) if yielded > 1 else _NS_PER_S
                shift_ns += previous_ns - first_ns + interval
            loop_index += 1

    def __enter__(self) -> ImageSource:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        self.close()
        return False
