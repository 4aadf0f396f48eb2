"""Image sources of files, without ROS: a rosbag2 bag or MCAP file, a video file, an image folder.

Bags yield their frames with the other recorded topics' messages; videos are stamped from a start time, folders from
their file names or a fixed rate (see `vessel_detect.image_source` for what every source yields).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Iterable, Iterator
from datetime import UTC, datetime
from pathlib import Path

import cv2

from vessel_common.errors import DataError
from vessel_detect import bag_messages, bag_reader, bag_salvage, bag_topics
from vessel_detect.image_source import AuxMessage, Frame, ImageSource, jpeg_problem

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov", ".m4v", ".webm", ".mpg", ".mpeg", ".ts", ".mjpeg", ".h264")

_NS_PER_S = 1_000_000_000


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
        image_topic: str = bag_topics.DEFAULT_IMAGE_TOPIC,
        aux_topics: Iterable[str] | None = (bag_topics.DEFAULT_CAMERA_FIX_TOPIC, bag_topics.DEFAULT_GPS_TRUTH_TOPIC),
        **options,
    ) -> None:
        super().__init__(**options)
        self.path = Path(path)
        self.description = f"bag {self.path}"
        self.damage = ""
        try:
            self.reader = bag_reader.BagReader(self.path, on_damage=self._damaged_chunk)
        except DataError as error:
            if "damaged" not in str(error) and "truncated" not in str(error):
                raise
            try:  # a bag cut short plays what it holds; the node says what was lost and exits non-zero
                self.reader = bag_salvage.SalvagedBagReader(self.path)
            except DataError:
                raise error from None
            self.damage = self.reader.damage or f"{error}"
        self.image_topic = image_topic
        self.reader.require_topic(image_topic, [bag_topics.COMPRESSED_IMAGE])
        if self.reader.message_count(image_topic) == 0:
            raise DataError(f"bag {self.path} has no messages on {image_topic}: {bag_topics.BUILD_HINT}")
        wanted = list(aux_topics) if aux_topics is not None else [t for t in self.reader.topics if t != image_topic]
        self.aux_topics = [t for t in wanted if t in self.reader.topics and t != image_topic]
        self.missing_aux_topics = [t for t in wanted if t not in self.reader.topics]
        self._first_ns: int | None = None

    def _damaged_chunk(self, line: str) -> None:
        """A chunk whose checksum fails: its frames are lost, the rest plays, and the replay ends non-zero."""
        self.damage = f"{self.damage}; {line}" if self.damage else line
        self.problem("damaged_chunk", line)

    def _stamp_of(self, message: bag_reader.BagMessage) -> int | None:
        try:
            return bag_messages.ns_of_stamp(self.reader.decode(message).header.stamp)
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
            latest: dict[str, bag_reader.BagMessage] = {}
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

    def _frame(self, index: int, message: bag_reader.BagMessage) -> Frame | None:
        try:
            image = self.reader.decode(message)
        except DataError as error:
            self.problem("unreadable", f"{self.description}: {error}; skipped")
            return None
        stamp_ns = bag_messages.ns_of_stamp(image.header.stamp)
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
        return bag_messages.sec_to_ns(self.start_utc)

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
            start_ns = bag_messages.sec_to_ns(start)
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
