"""Read rosbag2 folders (MCAP or sqlite3 storage) and single MCAP files without ROS.

Damaged or unsuitable bags raise `DataError` naming the file and the fix; a chunk whose content does not match its
CRC (bytes changed on a disk or in a copy) is named, its messages are counted as lost, and the other chunks are read.
`iter_mcap` reads a bag with the `mcap` library, an independent second reader.
"""

from __future__ import annotations

import heapq
import logging
import struct
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.errors import ReaderError
from rosbags.rosbag2.storage_mcap import McapReader, msgsrc
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from vessel_common.errors import DataError
from vessel_common.message_types import msg_types_from_dir, require_type, typestore, vessel_msgs_dirs
from vessel_detect.bag_messages import normalise_msgtype, ns_of_stamp, ns_to_sec
from vessel_detect.bag_topics import BUILD_HINT, COMPRESSED_IMAGE, DEFAULT_IMAGE_TOPIC, NAV_SAT_FIX

_LOG = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------------------------------------
# Reader
# ---------------------------------------------------------------------------------------------------------------
# What the storage layers raise on damaged input: their own errors, short reads, bad lengths, codec errors.
_DAMAGE_ERRORS: tuple[type[BaseException], ...] = (
    ReaderError,
    struct.error,
    EOFError,
    ValueError,
    IndexError,
    KeyError,
    zlib.error,
    MemoryError,
    OverflowError,
)
try:  # the zstd codec rosbags uses
    from backports import zstd as _zstd

    _DAMAGE_ERRORS = (*_DAMAGE_ERRORS, _zstd.ZstdError)
except ImportError:  # pragma: no cover - Python 3.14 has compression.zstd
    from compression import zstd as _zstd  # type: ignore[no-redef]

    _DAMAGE_ERRORS = (*_DAMAGE_ERRORS, _zstd.ZstdError)


@dataclass(frozen=True)
class BagMessage:
    """One serialised message as stored: topic, type, log time and CDR bytes."""

    topic: str
    msgtype: str
    log_time_ns: int
    cdr: bytes

    @property
    def log_time_s(self) -> float:
        """Log time in epoch seconds."""
        return ns_to_sec(self.log_time_ns)


@dataclass
class FixSeries:
    """The NavSatFix messages of one topic as arrays (header stamps in epoch seconds)."""

    stamps: np.ndarray
    lats: np.ndarray
    lons: np.ndarray
    alts: np.ndarray
    status: np.ndarray
    covariance_type: np.ndarray
    covariances: np.ndarray = field(repr=False)  # (N, 9)

    def __len__(self) -> int:
        return len(self.stamps)


class BagReader:
    """Read a rosbag2 folder (MCAP or sqlite3 storage) or a single `.mcap` file.

    Opening checks the bag and raises `DataError` for a missing path, a folder that is not a bag, and damaged
    storage (naming the file and what is wrong). Types the bag embeds but the type store lacks (someone else's
    messages) are registered from the bag's own definitions, so every topic decodes.

    A chunk of an indexed MCAP file that cannot be read (its CRC does not match, it does not decompress) is skipped
    by `messages`: one line names it and the messages lost (`on_damage(line)`, by default a warning on the
    `vessel_detect.bag_reader` logger), `lost_messages` counts them by topic, and the other chunks are read.
    """

    def __init__(self, path: str | Path, on_damage: Callable[[str], None] | None = None) -> None:
        self.on_damage = on_damage if on_damage is not None else _LOG.warning
        self.lost_messages: dict[str, int] = {}  # topic -> messages in chunks that could not be read
        self._lost_chunks: dict[tuple[str, int], str] = {}  # (file, chunk offset) -> the line that named it
        self.path = Path(path)
        if not self.path.exists():
            raise DataError(f"bag {self.path} does not exist: {BUILD_HINT}, or check the path")
        self._reader = Reader(self._storage_path())
        try:
            self._reader.open()
        except _DAMAGE_ERRORS as exc:
            raise self._damaged(exc) from exc
        except OSError as exc:
            raise DataError(f"cannot read bag {self.path}: {exc}") from exc
        self._store = typestore()
        self._extended = False
        self._connections = {}
        for conn in self._reader.connections:
            self._connections.setdefault(conn.topic, []).append(conn)
            if conn.msgtype not in self._store.fielddefs:
                self._register_from_bag(conn)

    def _storage_path(self) -> Path:
        if self.path.is_dir():
            if (self.path / "metadata.yaml").is_file():
                return self.path
            files = sorted(self.path.glob("*.mcap"))
            if len(files) == 1:
                return files[0]  # a recording that did not finish its metadata.yaml
            raise DataError(
                f"{self.path} is not a rosbag2 folder (no metadata.yaml"
                f"{', and several .mcap files' if files else ' and no .mcap file'}): {BUILD_HINT}"
            )
        if self.path.suffix != ".mcap":
            raise DataError(f"{self.path} is neither a rosbag2 folder nor an .mcap file")
        return self.path

    def _storage_files(self) -> str:
        if self.path.is_dir():
            files = [str(p) for p in sorted(self.path.iterdir()) if p.suffix in (".mcap", ".db3", ".zstd")]
        else:
            files = [str(self.path)]
        return ", ".join(files) or str(self.path)

    def _damaged(self, exc: BaseException) -> DataError:
        detail = str(exc) or type(exc).__name__
        return DataError(
            f"bag {self.path} is damaged ({self._storage_files()}: {detail}); the file is truncated or corrupt: "
            f"`./vessel bag recover {self.path} --out NEW` keeps every message that can be read; else "
            f"{BUILD_HINT}, or re-record it"
        )

    def _register_from_bag(self, conn: object) -> None:
        msgdef = conn.msgdef
        if msgdef is None or not msgdef.data or msgdef.format.name != "MSG":
            return  # decoding this topic will say so
        if not self._extended:  # a private store: the shared one stays as it is
            self._store = get_typestore(Stores.ROS2_JAZZY)
            if dirs := vessel_msgs_dirs():
                self._store.register(msg_types_from_dir(dirs[0]))
            self._extended = True
        try:
            self._store.register(get_types_from_msg(msgdef.data, conn.msgtype))
        except Exception:  # only matters if that topic is decoded
            pass

    # -- context manager
    def close(self) -> None:
        """Close the storage."""
        self._reader.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        self.close()
        return False

    # -- what is in it
    @property
    def topics(self) -> dict[str, str]:
        """Topic name -> message type (`pkg/msg/Name`)."""
        return {topic: conns[0].msgtype for topic, conns in self._connections.items()}

    def message_count(self, topic: str | None = None) -> int:
        """Messages in the bag, or on one topic."""
        if topic is None:
            return int(self._reader.message_count)
        return sum(c.msgcount for c in self._connections.get(topic, []))

    @property
    def start_ns(self) -> int:
        """Log time of the first message (ns)."""
        return int(self._reader.start_time)

    @property
    def end_ns(self) -> int:
        """Log time of the last message (ns)."""
        return max(int(self._reader.end_time) - 1, self.start_ns)  # rosbags reports end + 1 ns

    def describe(self) -> str:
        """Topics, types and counts on one line each (for messages and `--info`)."""
        lines = [f"  {t} [{m}] {self.message_count(t)} messages" for t, m in sorted(self.topics.items())]
        return "\n".join(lines) or "  (no topics)"

    def require_topic(self, topic: str, msgtypes: Iterable[str] | None = None) -> str:
        """The type of `topic`; `DataError` if it is absent or of another type, listing what the bag has."""
        if topic not in self._connections:
            have = ", ".join(f"{t} [{m}]" for t, m in sorted(self.topics.items())) or "no topics"
            raise DataError(
                f"bag {self.path} has no topic {topic} (it has: {have}); name the right topic in the parameters "
                f"or {BUILD_HINT}"
            )
        return checked_type(self.path, topic, self.topics[topic], msgtypes)

    # -- messages
    def messages(
        self,
        topics: Iterable[str] | None = None,
        start_ns: int | None = None,
        stop_ns: int | None = None,
    ) -> Iterator[BagMessage]:
        """Messages in log-time order, optionally only some topics and a time window [start, stop)."""
        if topics is None:
            conns = list(self._reader.connections)
        else:
            conns = [c for t in topics for c in self._connections.get(t, [])]
        if not conns:
            return
        storages = self._indexed_mcap_storages()
        lost: list[str] = []  # the damaged chunks met by this read
        read = 0
        try:
            if storages is None:
                source = self._reader.messages(connections=conns, start=start_ns, stop=stop_ns)
            else:
                source = self._chunked_messages(storages, conns, start_ns, stop_ns, lost)
            for conn, log_time, data in source:
                read += 1
                yield BagMessage(conn.topic, conn.msgtype, int(log_time), bytes(data))
        except _DAMAGE_ERRORS as exc:
            raise self._damaged(exc) from exc
        if lost and not read:  # nothing left to play: as unreadable as a bag that does not open
            raise self._damaged(ReaderError(f"every chunk with these messages is damaged: {'; '.join(lost)}"))

    @property
    def damage(self) -> str:
        """The chunks `messages` has found unreadable so far, one line each ('' : none)."""
        return "\n".join(self._lost_chunks.values())

    def _indexed_mcap_storages(self) -> list[McapReader] | None:
        """The bag's MCAP files when every one has a chunk index (read chunk by chunk); else None (rosbags reads)."""
        storage = self._reader.storage
        storages = list(getattr(storage, "storages", [storage]))
        if self._reader.compression_mode == "message" or not all(
                isinstance(s, McapReader) and s.chunks for s in storages):
            return None
        return storages

    def _chunked_messages(self, storages: list[McapReader], connections: list, start: int | None,
                          stop: int | None, lost: list[str]) -> Iterator[tuple[object, int, bytes]]:
        """What rosbags' ``messages`` yields, with each chunk read and checked on its own (``_chunk``).

        A damaged chunk's line is added to ``lost``.
        """
        for storage in storages:
            wanted = {(c.topic, c.msgtype): c for c in reversed(connections)}
            own = {c.id: wanted[c.topic, c.msgtype] for c in storage.connections if (c.topic, c.msgtype) in wanted}
            channels = {c.id: c for c in storage.connections if c.id in own}
            chunks = [self._chunk(storage, chunk, channels, start, stop, lost) for chunk in storage.chunks
                      if (start is None or start <= chunk.message_end_time)
                      and (stop is None or chunk.message_start_time < stop)
                      and any(chunk.channel_count.get(cid, 0) for cid in channels)]
            for timestamp, offset, connection, data in heapq.merge(*chunks):
                if offset:  # 0: a chunk's start time, before it is read
                    yield own[connection.id], timestamp, data

    def _chunk(self, storage: McapReader, chunk: object, channels: dict, start: int | None,
               stop: int | None, lost: list[str]) -> Iterator[tuple]:
        """One chunk's messages in time order, read when the merge reaches its start time; none if it is damaged."""
        source = msgsrc(chunk, channels, chunk.message_start_time if start is None else start,
                        chunk.message_end_time + 1 if stop is None else stop, storage.bio)
        yield next(source)  # the chunk's start time: nothing is read yet
        try:
            messages = list(source)  # the whole chunk is checked before any of it is played
        except _DAMAGE_ERRORS as exc:
            lost.append(self._chunk_lost(storage, chunk, exc))
            return
        yield from messages

    def _chunk_lost(self, storage: McapReader, chunk: object, exc: BaseException) -> str:
        """Name a chunk that cannot be read (once) and count its messages as lost; the line that names it."""
        key = (str(storage.path), chunk.chunk_start_offset)
        if key in self._lost_chunks:
            return self._lost_chunks[key]
        lost: dict[str, int] = {}
        for cid, count in chunk.channel_count.items():
            topic = storage.channels[cid].topic if cid in storage.channels else f"channel {cid}"
            lost[topic] = lost.get(topic, 0) + count
            self.lost_messages[topic] = self.lost_messages.get(topic, 0) + count
        number = storage.chunks.index(chunk) + 1
        detail = str(exc) or type(exc).__name__
        line = (f"bag {self.path}: chunk {number} of {len(storage.chunks)} in {Path(storage.path).name} (bytes "
                f"{chunk.chunk_start_offset}-{chunk.chunk_start_offset + chunk.chunk_length}, log times "
                f"{ns_to_sec(chunk.message_start_time):.3f}-{ns_to_sec(chunk.message_end_time):.3f} s) is damaged "
                f"({detail}): its {sum(lost.values())} messages are lost ("
                + ", ".join(f"{topic} {count}" for topic, count in sorted(lost.items()))
                + "); the other chunks are read")
        self._lost_chunks[key] = line
        self.on_damage(line)
        return line

    def decode(self, message: BagMessage) -> object:
        """Deserialise a message into a rosbags object; `DataError` for bytes that do not parse."""
        require_type(self._store, message.msgtype)
        try:
            return self._store.deserialize_cdr(message.cdr, message.msgtype)
        except Exception as exc:  # struct/index/value errors from a damaged payload
            raise DataError(
                f"message on {message.topic} at {message.log_time_s:.6f} s in {self.path} does not parse as "
                f"{message.msgtype}: {exc}"
            ) from exc

    def read_topic(self, topic: str) -> list[tuple[float, object]]:
        """Every message of one topic decoded, with its log time in seconds, in log-time order."""
        self.require_topic(topic)
        return [(m.log_time_s, self.decode(m)) for m in self.messages([topic])]

    def images(self, topic: str = DEFAULT_IMAGE_TOPIC, *, strict: bool = True) -> Iterator[tuple[float, bytes]]:
        """(header stamp in s, encoded bytes) of every CompressedImage on `topic`, in log-time order.

        With `strict`, a header stamp at or before the previous one raises `DataError` (the frames are out of
        time order: tracking and /clock need them increasing); otherwise such frames are skipped.
        """
        self.require_topic(topic, [COMPRESSED_IMAGE])
        previous_ns = -1
        for index, message in enumerate(self.messages([topic])):
            image = self.decode(message)
            stamp_ns = ns_of_stamp(image.header.stamp)
            if stamp_ns <= previous_ns:
                if strict:
                    raise out_of_order_error(self.path, topic, index, previous_ns, stamp_ns)
                continue
            previous_ns = stamp_ns
            yield ns_to_sec(stamp_ns), bytes(image.data)

    def fixes(self, topic: str) -> FixSeries:
        """Every NavSatFix of `topic` as arrays (empty arrays when the topic has no messages)."""
        self.require_topic(topic, [NAV_SAT_FIX])
        rows = [self.decode(m) for m in self.messages([topic])]
        return FixSeries(
            stamps=np.array([ns_to_sec(ns_of_stamp(r.header.stamp)) for r in rows], dtype=np.float64),
            lats=np.array([r.latitude for r in rows], dtype=np.float64),
            lons=np.array([r.longitude for r in rows], dtype=np.float64),
            alts=np.array([r.altitude for r in rows], dtype=np.float64),
            status=np.array([r.status.status for r in rows], dtype=np.int16),
            covariance_type=np.array([r.position_covariance_type for r in rows], dtype=np.uint8),
            covariances=np.array([np.asarray(r.position_covariance) for r in rows], dtype=np.float64).reshape(
                -1, 9
            ),
        )


def checked_type(path: Path, topic: str, msgtype: str, msgtypes: Iterable[str] | None) -> str:
    """``msgtype`` of ``topic``, or ``DataError`` when it is not one of ``msgtypes`` (None: any)."""
    allowed = [normalise_msgtype(m) for m in msgtypes] if msgtypes else []
    if allowed and msgtype not in allowed:
        raise DataError(f"topic {topic} in bag {path} is {msgtype}, expected {' or '.join(allowed)}")
    return msgtype


def out_of_order_error(path: Path | str, topic: str, index: int, previous_ns: int, stamp_ns: int) -> DataError:
    """The error for a frame whose stamp is not after the previous frame's."""
    return DataError(
        f"frames out of time order in {path}: message {index} on {topic} is stamped {ns_to_sec(stamp_ns):.6f} s, "
        f"not after the previous frame ({ns_to_sec(previous_ns):.6f} s); fix the frame times and {BUILD_HINT}"
    )


def mcap_file_of(path: str | Path) -> Path:
    """The MCAP file of a rosbag2 folder (or the file itself)."""
    path = Path(path)
    if path.is_file():
        return path
    files = sorted(path.glob("*.mcap"))
    if len(files) != 1:
        raise DataError(f"{path} holds {len(files)} .mcap files, expected one")
    return files[0]


def iter_mcap(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Messages of a bag read with the `mcap` library (an independent second reader), in log-time order."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    file = mcap_file_of(path)
    try:
        with file.open("rb") as stream:
            reader = make_reader(stream, validate_crcs=True)
            wanted = list(topics) if topics is not None else None
            for schema, channel, message in reader.iter_messages(topics=wanted, log_time_order=True):
                name = schema.name if schema is not None else ""
                yield BagMessage(channel.topic, name, int(message.log_time), bytes(message.data))
    except (McapError, *_DAMAGE_ERRORS) as exc:
        raise DataError(f"bag file {file} is damaged ({exc}): {BUILD_HINT}") from exc


def bag_info(path: str | Path) -> str:
    """A `ros2 bag info`-like summary of a bag: files, size, duration, time span, topics with types and counts."""
    from datetime import UTC, datetime

    path = Path(path)
    with BagReader(path) as reader:
        files = [path] if path.is_file() else sorted(p for p in path.iterdir() if p.is_file())
        size = sum(p.stat().st_size for p in files)
        start, end = reader.start_ns, reader.end_ns

        def utc(ns: int) -> str:
            return datetime.fromtimestamp(ns / 1e9, tz=UTC).isoformat(timespec="milliseconds")

        lines = [
            f"bag:       {path}",
            f"files:     {', '.join(p.name for p in files)}",
            f"size:      {size / 1e6:.1f} MB",
            f"duration:  {(end - start) / 1e9:.3f} s",
            f"start:     {utc(start)} ({start / 1e9:.3f})",
            f"end:       {utc(end)} ({end / 1e9:.3f})",
            f"messages:  {reader.message_count()}",
            "topics:",
            reader.describe(),
        ]
    return "\n".join(lines)
