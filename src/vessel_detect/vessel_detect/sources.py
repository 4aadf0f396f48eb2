"""Image sources without ROS: a rosbag2 bag or MCAP file, a video file, an image folder, a live camera.

Every source yields `Frame`s in time order (stamps in integer nanoseconds since the epoch, as ROS headers carry
them), with the encoded bytes as they were stored (JPEG from bags and folders) and the BGR image decoded only when
asked for. Bag sources also yield the other recorded topics (`AuxMessage`: the camera's fix, the vessel's GPS
truth) so a replay republishes them. Sources can start at an offset and loop. Problems with single frames are
reported to a handler and counted, never raised, so a node keeps going; problems with the source as a whole
(missing file, damaged bag, no image topic) raise `DataError` when the source is opened.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np

from vessel_common.errors import DataError
from vessel_detect import bag_io

ProblemHandler = Callable[[str, str], None]
"""Called as handler(kind, message) for every frame-level problem (kinds: see `SourceStats`)."""

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov", ".m4v", ".webm", ".mpg", ".mpeg", ".ts", ".mjpeg", ".h264")
STREAM_PREFIXES = ("rtsp://", "rtsps://", "http://", "https://", "udp://", "tcp://", "rtmp://")

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
                        raise bag_io.out_of_order_error(
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


# ---------------------------------------------------------------------------------------------------------------
# Bags
# ---------------------------------------------------------------------------------------------------------------
class BagSource(ImageSource):
    """Frames of a CompressedImage topic of a rosbag2 folder or `.mcap` file, with the other topics' messages.

    Frames carry their header stamps; other messages their log times (header stamps in bags this project
    writes). Before the start offset, the last message of each other topic is still yielded (first), so latched
    data such as the camera's fix is known from the start.
    """

    kind = "bag"

    def __init__(
        self,
        path: str | Path,
        image_topic: str = bag_io.DEFAULT_IMAGE_TOPIC,
        aux_topics: Iterable[str] | None = (bag_io.DEFAULT_CAMERA_FIX_TOPIC, bag_io.DEFAULT_GPS_TRUTH_TOPIC),
        **options,
    ) -> None:
        super().__init__(**options)
        self.path = Path(path)
        self.description = f"bag {self.path}"
        self.damage = ""
        try:
            self.reader = bag_io.BagReader(self.path, on_damage=self._damaged_chunk)
        except DataError as error:
            if "damaged" not in str(error) and "truncated" not in str(error):
                raise
            try:  # a bag cut short plays what it holds; the node says what was lost and exits non-zero
                self.reader = bag_io.SalvagedBagReader(self.path)
            except DataError:
                raise error from None
            self.damage = self.reader.damage or f"{error}"
        self.image_topic = image_topic
        self.reader.require_topic(image_topic, [bag_io.COMPRESSED_IMAGE])
        if self.reader.message_count(image_topic) == 0:
            raise DataError(f"bag {self.path} has no messages on {image_topic}: {bag_io.BUILD_HINT}")
        wanted = list(aux_topics) if aux_topics is not None else [t for t in self.reader.topics if t != image_topic]
        self.aux_topics = [t for t in wanted if t in self.reader.topics and t != image_topic]
        self.missing_aux_topics = [t for t in wanted if t not in self.reader.topics]
        self._first_ns: int | None = None

    def _damaged_chunk(self, line: str) -> None:
        """A chunk whose checksum fails: its frames are lost, the rest plays, and the replay ends non-zero."""
        self.damage = f"{self.damage}; {line}" if self.damage else line
        self.problem("damaged_chunk", line)

    def _stamp_of(self, message: bag_io.BagMessage) -> int | None:
        try:
            return bag_io.ns_of_stamp(self.reader.decode(message).header.stamp)
        except DataError:
            return None

    def first_stamp_ns(self) -> int | None:
        """Header stamp of the first image (its log time if the message does not parse)."""
        if self._first_ns is None:
            first = next(self.reader.messages([self.image_topic]))
            self._first_ns = self._stamp_of(first) or first.log_time_ns
        return self._first_ns

    def frame_count(self) -> int | None:
        """Images on the image topic."""
        return self.reader.message_count(self.image_topic)

    def _pass(self, start_ns: int | None) -> Iterator[Frame | AuxMessage]:
        first_ns = self.first_stamp_ns()
        # Log times may precede header stamps by a little (a recorder logs at receipt): read from a margin back.
        read_from = None
        if start_ns is not None and start_ns > first_ns:
            read_from = start_ns - _NS_PER_S
            latest: dict[str, bag_io.BagMessage] = {}
            for message in self.reader.messages(self.aux_topics, stop_ns=start_ns):
                latest[message.topic] = message
            for message in sorted(latest.values(), key=lambda m: m.log_time_ns):
                yield AuxMessage(start_ns, message.topic, message.msgtype, message.cdr)
        topics = [self.image_topic, *self.aux_topics]
        for index, message in enumerate(self.reader.messages(topics, start_ns=read_from)):
            if message.topic != self.image_topic:
                if read_from is not None and message.log_time_ns < start_ns:
                    continue
                yield AuxMessage(message.log_time_ns, message.topic, message.msgtype, message.cdr)
                continue
            frame = self._frame(index, message)
            if frame is None or (start_ns is not None and frame.stamp_ns < start_ns):
                continue
            yield frame

    def _frame(self, index: int, message: bag_io.BagMessage) -> Frame | None:
        try:
            image = self.reader.decode(message)
        except DataError as error:
            self.problem("unreadable", f"{self.description}: {error}; skipped")
            return None
        stamp_ns = bag_io.ns_of_stamp(image.header.stamp)
        data = bytes(image.data)
        fmt = image.format.lower()
        if "jpeg" in fmt or "jpg" in fmt or fmt == "":
            reason = jpeg_problem(data)
            if reason is not None:
                self.problem(
                    "unreadable",
                    f"{self.description}: image at {stamp_ns / 1e9:.6f} s on {self.image_topic} is unreadable "
                    f"({reason}); skipped",
                )
                return None
            return Frame(stamp_ns, index, jpeg=data, frame_id=image.header.frame_id or None)
        return Frame(stamp_ns, index, encoded=data, frame_id=image.header.frame_id or None)

    def close(self) -> None:
        """Close the bag."""
        self.reader.close()


# ---------------------------------------------------------------------------------------------------------------
# Video files
# ---------------------------------------------------------------------------------------------------------------
def parse_utc(text: str) -> float:
    """ISO-8601 UTC time (`2020-09-30T19:55:52.884Z`, a `+00:00` offset, or naive = UTC) or epoch seconds."""
    text = str(text).strip()
    try:
        value = float(text)
    except ValueError:
        pass
    else:
        if math.isfinite(value):
            return value
        raise DataError(f"time {text!r} is not finite")
    try:
        parsed = datetime.fromisoformat(text.replace("Z", "+00:00").replace("z", "+00:00"))
    except ValueError as exc:
        raise DataError(
            f"time {text!r} is neither ISO-8601 (e.g. 2020-09-30T19:55:52.884Z) nor epoch seconds"
        ) from exc
    if parsed.tzinfo is None:
        parsed = parsed.replace(tzinfo=UTC)
    return parsed.timestamp()


class VideoSource(ImageSource):
    """Frames of a video file (any container OpenCV reads), decoded, stamped from a start time.

    Stamps are `start_utc` plus the video's own frame times (`CAP_PROP_POS_MSEC`, which follows a variable frame
    rate) or, with `fps` given or when the container has no usable times, `index / fps`. Without `start_utc`
    the wall-clock time at opening is used. `every` keeps one frame in N.
    """

    kind = "video"

    def __init__(
        self,
        path: str | Path,
        *,
        start_utc: float | None = None,
        fps: float | None = None,
        every: int = 1,
        **options,
    ) -> None:
        super().__init__(**options)
        self.path = Path(path)
        self.description = f"video {self.path}"
        if not self.path.is_file():
            raise DataError(f"video file {self.path} does not exist: check the path")
        if fps is not None and not (math.isfinite(fps) and fps > 0):
            raise DataError(f"fps {fps!r} must be a positive number")
        if every < 1:
            raise DataError(f"every={every} must be at least 1")
        self.every = int(every)
        self.fixed_fps = fps
        self.start_utc = time.time() if start_utc is None else float(start_utc)
        capture = self._open()
        self.container_fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        capture.release()
        self._count = count if count > 0 else None
        if self.fixed_fps is None and not (math.isfinite(self.container_fps) and self.container_fps > 0):
            self.container_fps = 0.0

    def _open(self) -> cv2.VideoCapture:
        capture = cv2.VideoCapture(str(self.path))
        if not capture.isOpened():
            capture.release()
            raise DataError(
                f"cannot open video {self.path}: OpenCV has no reader for it (unsupported container/codec "
                "or damaged file); convert it, e.g. ffmpeg -i IN -c:v mjpeg OUT.avi"
            )
        return capture

    def first_stamp_ns(self) -> int | None:
        """The start time (the first frame's stamp)."""
        return bag_io.sec_to_ns(self.start_utc)

    def frame_count(self) -> int | None:
        """Frames kept per pass (from the container's frame count, which can be approximate)."""
        return None if self._count is None else (self._count + self.every - 1) // self.every

    def _pass(self, start_ns: int | None) -> Iterator[Frame | AuxMessage]:
        capture = self._open()
        try:
            start_ns = start_ns or self.first_stamp_ns()
            base_ns = self.first_stamp_ns()
            offset_ms = (start_ns - base_ns) / 1e6
            if offset_ms > 0:
                capture.set(cv2.CAP_PROP_POS_MSEC, offset_ms)
            index = int(capture.get(cv2.CAP_PROP_POS_FRAMES) or 0)
            fps = self.fixed_fps or self.container_fps or 25.0
            previous_t_ms: float | None = None
            failures = 0
            while True:
                ok, image = capture.read()
                if not ok or image is None:
                    # A damaged packet mid-file fails one read; the end fails every read.
                    failures += 1
                    if self._count is None or index >= self._count - 1 or failures > 25:
                        return
                    self.problem("unreadable", f"{self.description}: frame {index} cannot be decoded; skipped")
                    index += 1
                    continue
                failures = 0
                if self.fixed_fps is not None:
                    t_ms = index * 1000.0 / fps
                else:
                    position_ms = float(capture.get(cv2.CAP_PROP_POS_MSEC) or 0.0)
                    if previous_t_ms is None:
                        t_ms = position_ms if position_ms > 0 or index == 0 else index * 1000.0 / fps
                    elif position_ms > previous_t_ms:
                        t_ms = position_ms
                    else:  # the container gave no usable time for this frame
                        t_ms = previous_t_ms + 1000.0 / fps
                previous_t_ms = t_ms
                if index % self.every == 0:
                    stamp_ns = base_ns + round(t_ms * 1e6)
                    if stamp_ns >= start_ns:
                        yield Frame(stamp_ns, index, _bgr=image)
                index += 1
        finally:
            capture.release()


# ---------------------------------------------------------------------------------------------------------------
# Image folders
# ---------------------------------------------------------------------------------------------------------------
_EPOCH_IN_NAME = re.compile(r"(?<!\d)(\d{10}(?:[._]\d{1,9})?|\d{19})(?!\d)")
_ISO_IN_NAME = re.compile(
    r"(\d{4})-?(\d{2})-?(\d{2})[T_ ](\d{2})[:\-_]?(\d{2})[:\-_]?(\d{2})(?:[.,](\d{1,9}))?"
)


def stamp_from_name(name: str) -> int | None:
    """Stamp (ns) encoded in a file name, or None.

    Understands epoch seconds with a fraction (`1601495752.884.jpg`, `cam_1601495752_884.jpg`), epoch
    nanoseconds (19 digits, as ROS tools write them) and ISO-like UTC times (`2020-09-30T19-55-52.884Z.jpg`,
    `20200930_195552.jpg`).
    """
    stem = Path(name).stem
    iso = _ISO_IN_NAME.search(stem)
    if iso:
        year, month, day, hour, minute, second, frac = iso.groups()
        try:
            moment = datetime(int(year), int(month), int(day), int(hour), int(minute), int(second), tzinfo=UTC)
        except ValueError:
            moment = None
        if moment is not None:
            nanos = int((frac or "0").ljust(9, "0")[:9])
            return int(moment.timestamp()) * _NS_PER_S + nanos
    epoch = _EPOCH_IN_NAME.search(stem)
    if epoch:
        digits = epoch.group(1)
        if len(digits) == 19:
            return int(digits)
        whole, _, frac = digits.replace("_", ".").partition(".")
        return int(whole) * _NS_PER_S + int((frac or "0").ljust(9, "0")[:9])
    return None


def _natural_key(path: Path) -> list:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


class FolderSource(ImageSource):
    """Images of a folder (JPEG passed through as they are; other formats decoded), one per frame.

    Stamps come from the file names when every name holds one (see `stamp_from_name`), the frames then in stamp
    order; otherwise files go in natural name order at a fixed `fps` from `start_utc` (default: now).
    """

    kind = "folder"

    def __init__(
        self,
        path: str | Path,
        *,
        fps: float = 1.0,
        start_utc: float | None = None,
        stamps_from_names: bool = True,
        **options,
    ) -> None:
        super().__init__(**options)
        self.path = Path(path)
        self.description = f"image folder {self.path}"
        if not self.path.is_dir():
            raise DataError(f"image folder {self.path} does not exist")
        if not (math.isfinite(fps) and fps > 0):
            raise DataError(f"fps {fps!r} must be a positive number")
        files = sorted(
            (p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()), key=_natural_key
        )
        if not files:
            raise DataError(f"image folder {self.path} has no images ({', '.join(IMAGE_SUFFIXES)})")
        named = [stamp_from_name(p.name) for p in files] if stamps_from_names else [None] * len(files)
        if all(s is not None for s in named):
            order = sorted(range(len(files)), key=lambda i: named[i])
            self.entries = [(named[i], files[i]) for i in order]
            self.stamp_origin = "file names"
        else:
            start = time.time() if start_utc is None else float(start_utc)
            start_ns = bag_io.sec_to_ns(start)
            self.entries = [(start_ns + round(i * _NS_PER_S / fps), p) for i, p in enumerate(files)]
            self.stamp_origin = f"{fps:g} frames/s"

    def first_stamp_ns(self) -> int | None:
        """Stamp of the first image."""
        return self.entries[0][0]

    def last_stamp_ns(self) -> int | None:
        """Stamp of the last image."""
        return self.entries[-1][0]

    def frame_count(self) -> int | None:
        """Images in the folder."""
        return len(self.entries)

    def _pass(self, start_ns: int | None) -> Iterator[Frame | AuxMessage]:
        for index, (stamp_ns, file) in enumerate(self.entries):
            if start_ns is not None and stamp_ns < start_ns:
                continue
            try:
                data = file.read_bytes()
            except OSError as error:
                self.problem("unreadable", f"{self.description}: cannot read {file.name} ({error}); skipped")
                continue
            if file.suffix.lower() in (".jpg", ".jpeg"):
                reason = jpeg_problem(data)
                if reason is not None:
                    self.problem("unreadable", f"{self.description}: {file.name} is unreadable ({reason}); skipped")
                    continue
                yield Frame(stamp_ns, index, jpeg=data)
            else:
                yield Frame(stamp_ns, index, encoded=data)


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


# ---------------------------------------------------------------------------------------------------------------
# Choosing a source from a string
# ---------------------------------------------------------------------------------------------------------------
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


def check_source(spec: str | Path) -> int | str | None:
    """The device ``spec`` names (``parse_device``), else None once its path is known to exist; else DataError.

    What ``open_source`` checks first; a launcher checks it before it starts a graph that would wait for a camera
    that cannot start.
    """
    text = str(spec).strip()
    if not text:
        raise DataError("no source given: name a bag folder, .mcap, video file, image folder or device:N")
    device = parse_device(text)
    if device is not None:
        return device
    path = Path(text).expanduser()
    if not path.exists():
        raise DataError(
            f"source {path} does not exist (expected a bag folder, .mcap file, video file, image folder, or "
            "device:N)"
        )
    return None


def open_source(
    spec: str | Path,
    *,
    image_topic: str = bag_io.DEFAULT_IMAGE_TOPIC,
    aux_topics: Iterable[str] | None = (bag_io.DEFAULT_CAMERA_FIX_TOPIC, bag_io.DEFAULT_GPS_TRUTH_TOPIC),
    start_utc: float | None = None,
    fps: float | None = None,
    every: int = 1,
    device_width: int = 0,
    device_height: int = 0,
    **options,
) -> ImageSource:
    """Open what `spec` names: a rosbag2 folder or `.mcap`, a video file, an image folder, or a device/stream.

    `options` go to every source (`start_offset_s`, `loop`, `restamp_loops`, `on_problem`, `strict_order`).
    `fps` is the folder's frame rate, a video's forced rate, or a device's requested rate.
    """
    device = check_source(spec)
    if device is not None:
        return DeviceSource(device, width=device_width, height=device_height, fps=fps or 0.0, **options)
    path = Path(str(spec).strip()).expanduser()
    if path.is_dir():
        if (path / "metadata.yaml").is_file() or any(path.glob("*.mcap")):
            return BagSource(path, image_topic=image_topic, aux_topics=aux_topics, **options)
        return FolderSource(path, fps=fps or 1.0, start_utc=start_utc, **options)
    if path.suffix.lower() in (".mcap", ".db3"):
        return BagSource(path, image_topic=image_topic, aux_topics=aux_topics, **options)
    if path.suffix.lower() in IMAGE_SUFFIXES:
        raise DataError(f"{path} is a single image: give its folder as the source")
    return VideoSource(path, start_utc=start_utc, fps=fps, every=every, **options)
