"""Read and write rosbag2 folders (MCAP storage) without ROS.

The bags are what `ros2 bag record` makes: a folder with `metadata.yaml` and one MCAP file whose chunks are
zstd-compressed and carry the CRC32 of their content, messages CDR-serialised with the type definitions embedded, so
`ros2 bag info/play`, `rosbags` and the `mcap` library all read them. Serialisation uses the `rosbags` Jazzy type
store extended with this project's `vessel_msgs` types (read from their `.msg` files), so the evaluation can read
recorded detections and tracks without a ROS install. Damaged or unsuitable bags raise `DataError` naming the file
and the fix; a chunk whose content does not match its CRC (bytes changed on a disk or in a copy) is named, its
messages are counted as lost, and the other chunks are read.
"""

from __future__ import annotations

import functools
import heapq
import logging
import math
import os
import shutil
import struct
import tempfile
import time
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer
from rosbags.rosbag2.errors import ReaderError, WriterError
from rosbags.rosbag2.storage_mcap import McapReader, msgsrc
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from vessel_common.errors import DataError

DEFAULT_IMAGE_TOPIC = "/camera/image_raw/compressed"
DEFAULT_CAMERA_FIX_TOPIC = "/camera/fix"
DEFAULT_GPS_TRUTH_TOPIC = "/vessel/gps_truth"

COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMAGE = "sensor_msgs/msg/Image"
NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"
CLOCK = "rosgraph_msgs/msg/Clock"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
DETECTION_2D_ARRAY = "vessel_msgs/msg/Detection2DArray"
VESSEL_TRACK_ARRAY = "vessel_msgs/msg/VesselTrackArray"

# sensor_msgs/NavSatStatus and NavSatFix constants (kept here so callers need no message classes).
STATUS_NO_FIX = -1
STATUS_FIX = 0
SERVICE_GPS = 1
COVARIANCE_TYPE_UNKNOWN = 0
COVARIANCE_TYPE_APPROXIMATED = 1
COVARIANCE_TYPE_DIAGONAL_KNOWN = 2

BUILD_HINT = "rebuild it with `./vessel bag build` (or `bag_build`)"

_NS_PER_S = 1_000_000_000
_CHUNK_CRC_OFFSET = 1 + 8 + 8 + 8 + 8
"""Bytes from the start of an MCAP chunk record to its uncompressed_crc: opcode, record length, message start and
end time, uncompressed size."""
_LOG = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------------------------------------
# Time
# ---------------------------------------------------------------------------------------------------------------
def sec_to_ns(stamp_s: float) -> int:
    """Epoch seconds (float) to integer nanoseconds, rounded to the microsecond.

    A float64 epoch of today resolves about 0.2 us, so finer digits are noise; rounding to the microsecond makes
    `1601494438.835` come out as `...835000000` ns, not `...835000038`.
    """
    if not math.isfinite(stamp_s):
        raise DataError(f"time stamp {stamp_s!r} is not a finite number of seconds")
    whole = math.floor(stamp_s)
    micros = round((stamp_s - whole) * 1e6)
    return int(whole) * _NS_PER_S + micros * 1000


def ns_to_sec(stamp_ns: int) -> float:
    """Integer nanoseconds to epoch seconds (float)."""
    return stamp_ns / 1e9


def ns_of_stamp(stamp: object) -> int:
    """Nanoseconds of a `builtin_interfaces/Time` (rosbags or rclpy message: fields `sec`, `nanosec`)."""
    return int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)


# ---------------------------------------------------------------------------------------------------------------
# Types
# ---------------------------------------------------------------------------------------------------------------
def vessel_msgs_dirs() -> list[Path]:
    """Folders that may hold the `vessel_msgs` `.msg` files, most specific first.

    `VESSEL_MSGS_DIR` (if set), the source tree next to this package, then `share/vessel_msgs/msg` under every
    prefix of `AMENT_PREFIX_PATH` (an installed workspace).
    """
    candidates: list[Path] = []
    if env := os.environ.get("VESSEL_MSGS_DIR"):
        candidates.append(Path(env))
    here = Path(__file__).resolve()
    candidates.append(here.parents[2] / "vessel_msgs" / "msg")
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / "vessel_msgs" / "msg")
    return [c for c in candidates if c.is_dir() and any(c.glob("*.msg"))]


def msg_types_from_dir(msg_dir: Path, package: str = "vessel_msgs") -> dict:
    """Parse every `.msg` of one package folder into a rosbags types dict (`pkg/msg/Name` keys)."""
    types: dict = {}
    for msg_file in sorted(Path(msg_dir).glob("*.msg")):
        name = f"{package}/msg/{msg_file.stem}"
        try:
            types.update(get_types_from_msg(msg_file.read_text(encoding="utf-8"), name))
        except Exception as exc:  # the rosbags parser raises several kinds for a malformed definition
            raise DataError(f"cannot parse message definition {msg_file}: {exc}") from exc
    return types


@functools.cache
def typestore() -> Typestore:
    """The ROS 2 Jazzy type store of `rosbags` plus the `vessel_msgs` types (cached; do not mutate it).

    Without the `.msg` files (neither source tree nor install found) only the standard types are known, and
    serialising a `vessel_msgs` message raises `DataError` saying where the files are looked for.
    """
    store = get_typestore(Stores.ROS2_JAZZY)
    dirs = vessel_msgs_dirs()
    if dirs:
        store.register(msg_types_from_dir(dirs[0]))
    return store


def _require_type(store: Typestore, msgtype: str) -> None:
    if msgtype not in store.fielddefs:
        where = "VESSEL_MSGS_DIR, src/vessel_msgs/msg, $AMENT_PREFIX_PATH/share/vessel_msgs/msg"
        hint = f" (looked for the .msg files in {where})" if msgtype.startswith("vessel_msgs/") else ""
        raise DataError(f"unknown message type {msgtype!r}{hint}")


def validate_position(lat: float, lon: float, what: str) -> None:
    """`DataError` unless (lat, lon) is a finite WGS-84 position."""
    if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90 and abs(lon) <= 180):
        raise DataError(f"{what} ({lat!r}, {lon!r}) is not a WGS-84 latitude/longitude in degrees")


def normalise_msgtype(msgtype: str) -> str:
    """`sensor_msgs/NavSatFix` or `sensor_msgs/msg/NavSatFix` -> `sensor_msgs/msg/NavSatFix`."""
    parts = msgtype.strip().split("/")
    if len(parts) == 2 and all(parts):
        return f"{parts[0]}/msg/{parts[1]}"
    if len(parts) == 3 and all(parts):
        return msgtype.strip()
    raise DataError(f"message type {msgtype!r} is not of the form package/Name or package/msg/Name")


# ---------------------------------------------------------------------------------------------------------------
# Message constructors (rosbags message objects, no ROS needed)
# ---------------------------------------------------------------------------------------------------------------
def _time(stamp_ns: int, store: Typestore) -> object:
    Time = store.types["builtin_interfaces/msg/Time"]
    return Time(sec=stamp_ns // _NS_PER_S, nanosec=stamp_ns % _NS_PER_S)


def header(stamp_ns: int, frame_id: str, store: Typestore | None = None) -> object:
    """A `std_msgs/Header`."""
    store = store or typestore()
    return store.types["std_msgs/msg/Header"](stamp=_time(stamp_ns, store), frame_id=frame_id)


def compressed_image(stamp_ns: int, data: bytes, frame_id: str = "camera", fmt: str = "jpeg") -> object:
    """A `sensor_msgs/CompressedImage` holding `data` as it is."""
    store = typestore()
    return store.types[COMPRESSED_IMAGE](
        header=header(stamp_ns, frame_id, store),
        format=fmt,
        data=np.frombuffer(data, dtype=np.uint8),
    )


def nav_sat_fix(
    stamp_ns: int,
    lat: float,
    lon: float,
    alt: float = math.nan,
    frame_id: str = "gps",
    sigma_m: float | None = None,
    status: int = STATUS_FIX,
) -> object:
    """A `sensor_msgs/NavSatFix`; `sigma_m` (1-sigma horizontal, metres) fills an approximated covariance.

    Without `sigma_m` the covariance type is UNKNOWN and the matrix zero, as the message documents. Altitude NaN
    means unknown.
    """
    store = typestore()
    cov = np.zeros(9, dtype=np.float64)
    cov_type = COVARIANCE_TYPE_UNKNOWN
    if sigma_m is not None:
        if not (math.isfinite(sigma_m) and sigma_m > 0):
            raise DataError(f"position sigma {sigma_m!r} m must be a positive number")
        cov[0] = cov[4] = sigma_m**2
        cov[8] = (2.0 * sigma_m) ** 2  # vertical: GPS is about twice as poor, and unknown anyway
        cov_type = COVARIANCE_TYPE_APPROXIMATED
    Status = store.types["sensor_msgs/msg/NavSatStatus"]
    return store.types[NAV_SAT_FIX](
        header=header(stamp_ns, frame_id, store),
        status=Status(status=status, service=SERVICE_GPS),
        latitude=float(lat),
        longitude=float(lon),
        altitude=float(alt),
        position_covariance=cov,
        position_covariance_type=cov_type,
    )


# ---------------------------------------------------------------------------------------------------------------
# QoS recorded in metadata (what `ros2 bag play` offers when it republishes)
# ---------------------------------------------------------------------------------------------------------------
_ZERO = QosTime(0, 0)


def _qos(depth: int, reliability: QosReliability, durability: QosDurability) -> Qos:
    return Qos(
        QosHistory.KEEP_LAST,
        depth,
        reliability,
        durability,
        _ZERO,
        _ZERO,
        QosLiveliness.AUTOMATIC,
        _ZERO,
        False,
    )


QOS_PROFILES: dict[str, Qos] = {
    "sensor_data": _qos(5, QosReliability.BEST_EFFORT, QosDurability.VOLATILE),
    "reliable": _qos(10, QosReliability.RELIABLE, QosDurability.VOLATILE),
    "latched": _qos(1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL),
}


# ---------------------------------------------------------------------------------------------------------------
# Writer
# ---------------------------------------------------------------------------------------------------------------
class BagWriter:
    """Write one rosbag2 folder (MCAP, zstd chunks) message by message.

    With `atomic=True` the bag is written in a hidden folder beside `path` and renamed into place by `close()`,
    so a failed or interrupted build leaves no half bag (an existing bag at `path` is replaced only then, and
    only with `overwrite=True`). With `atomic=False` (a recorder) it is written in place, as `ros2 bag record`
    does. Use as a context manager: leaving on an exception aborts and removes the partial output.
    """

    def __init__(self, path: str | Path, *, overwrite: bool = False, atomic: bool = True,
                 flush_every_s: float = 0.0,
                 overwrite_hint: str = "pass --overwrite (overwrite=True) to replace it") -> None:
        """``overwrite_hint``: how the caller's user asks to replace an existing bag (a node's is a parameter)."""
        self.path = Path(path)
        self.overwrite = overwrite
        self.atomic = atomic
        self.flush_every_s = float(flush_every_s)
        self._last_flush = time.monotonic()
        if self.path.exists() and not overwrite:
            raise DataError(f"{self.path} exists already: {overwrite_hint}")
        self._store = typestore()
        self._staging: Path | None = None
        self._writer: Writer | None = None
        self._connections: dict[str, object] = {}
        self._msgtypes: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        self.closed = False

    # -- lifecycle
    def open(self) -> BagWriter:
        """Create the output folder (or the staging folder) and open the MCAP file."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.atomic:
            self._staging = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.partial-", dir=self.path.parent))
            target = self._staging / self.path.name
        else:
            if self.path.exists():
                _remove(self.path)
            target = self.path
        writer = Writer(target, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        try:
            writer.open()
        except (WriterError, OSError) as exc:
            self._cleanup()
            raise DataError(f"cannot create bag {self.path}: {exc}") from exc
        _write_chunk_crcs(writer.storage)
        self._writer = writer
        return self

    def close(self) -> Path:
        """Finish the MCAP (index, summary), write `metadata.yaml`, move the bag into place; return its path."""
        if self.closed:
            return self.path
        if self._writer is None:
            raise DataError(f"bag {self.path} was never opened")
        try:
            self._writer.close()
        except (WriterError, OSError) as exc:
            self.abort()
            raise DataError(f"cannot finish bag {self.path}: {exc}") from exc
        self._writer = None
        if self.atomic and self._staging is not None:
            built = self._staging / self.path.name
            old = None
            if self.path.exists():
                old = self._staging / f"{self.path.name}.old"
                self.path.rename(old)
            built.rename(self.path)
            self._cleanup()
        self.closed = True
        return self.path

    def abort(self) -> None:
        """Drop everything written so far (the staging folder; in place, the unfinished bag)."""
        if self._writer is not None:
            try:
                self._writer.abort()
            except Exception:  # best effort: already failing
                pass
            self._writer = None
        if not self.atomic and self.path.exists() and not self.closed:
            _remove(self.path)
        self._cleanup()
        self.closed = True

    def _cleanup(self) -> None:
        if self._staging is not None and self._staging.exists():
            shutil.rmtree(self._staging, ignore_errors=True)
        self._staging = None

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False

    # -- topics and messages
    def add_topic(self, topic: str, msgtype: str, qos: str | Qos = "reliable") -> None:
        """Declare a topic (once); `qos` is a profile name from `QOS_PROFILES` or a rosbags `Qos`."""
        if self._writer is None:
            raise DataError(f"bag {self.path} is not open")
        msgtype = normalise_msgtype(msgtype)
        if topic in self._connections:
            if self._msgtypes[topic] != msgtype:
                raise DataError(f"topic {topic} already has type {self._msgtypes[topic]}, not {msgtype}")
            return
        _require_type(self._store, msgtype)
        profile = QOS_PROFILES[qos] if isinstance(qos, str) else qos
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=self._store, offered_qos_profiles=[profile]
        )
        self._msgtypes[topic] = msgtype
        self.counts[topic] = 0

    def write(self, topic: str, message: object, log_time_ns: int | None = None) -> None:
        """Serialise a rosbags message and write it; the log time defaults to its header stamp."""
        if topic not in self._msgtypes:
            raise DataError(f"topic {topic} was not added to bag {self.path}")
        if log_time_ns is None:
            log_time_ns = ns_of_stamp(message.header.stamp)
        self.write_cdr(topic, self._store.serialize_cdr(message, self._msgtypes[topic]), log_time_ns)

    def write_cdr(self, topic: str, cdr: bytes | memoryview, log_time_ns: int) -> None:
        """Write an already serialised (CDR) message, e.g. from `rclpy.serialization.serialize_message`."""
        if self._writer is None:
            raise DataError(f"bag {self.path} is not open")
        connection = self._connections.get(topic)
        if connection is None:
            raise DataError(f"topic {topic} was not added to bag {self.path}")
        if log_time_ns < 0:
            raise DataError(f"log time {log_time_ns} ns on {topic} is negative")
        self._writer.write(connection, int(log_time_ns), cdr)
        self.counts[topic] += 1
        if self.flush_every_s > 0 and time.monotonic() - self._last_flush >= self.flush_every_s:
            self.flush()

    def flush(self) -> None:
        """Put what was written so far on disk as a complete MCAP chunk.

        A recorder killed with SIGKILL then loses at most ``flush_every_s`` of messages: the file lacks only its
        summary, which ``recover_bag`` rebuilds (``./vessel bag recover``).
        """
        self._last_flush = time.monotonic()
        storage = getattr(self._writer, "storage", None)
        if storage is None or not hasattr(storage, "close_chunk"):
            return
        if storage.chunk.bio.tell():
            storage.close_chunk()
        storage.bio.flush()
        os.fsync(storage.bio.fileno())

    def set_custom_data(self, key: str, value: str) -> None:
        """Store a key/value string in `metadata.yaml` (`custom_data`: provenance, e.g. the source video)."""
        if self._writer is None:
            raise DataError(f"bag {self.path} is not open")
        self._writer.set_custom_data(key, str(value))

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return sum(self.counts.values())


def _write_chunk_crcs(storage: object) -> None:
    """Make the rosbags MCAP writer fill in each chunk's CRC32, which it leaves 0 ("not computed").

    Without it a reader cannot tell a chunk whose bytes changed (a bad disk, a damaged copy) from a good one and
    plays whatever the changed bytes decode to. The CRC, of the chunk's uncompressed records as MCAP defines it, is
    written into the record ``close_chunk`` has just written.
    """
    close_chunk = storage.close_chunk

    def close_chunk_with_crc() -> None:
        start = storage.bio.tell()
        crc = zlib.crc32(storage.chunk.bio.getbuffer())
        close_chunk()
        end = storage.bio.tell()
        storage.bio.seek(start + _CHUNK_CRC_OFFSET)
        storage.bio.write(struct.pack("<I", crc))
        storage.bio.seek(end)

    storage.close_chunk = close_chunk_with_crc


def _remove(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink()


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
    `vessel_detect.bag_io` logger), `lost_messages` counts them by topic, and the other chunks are read.
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
        return _checked_type(self.path, topic, self.topics[topic], msgtypes)

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
        _require_type(self._store, message.msgtype)
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


def _checked_type(path: Path, topic: str, msgtype: str, msgtypes: Iterable[str] | None) -> str:
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


@dataclass
class Salvage:
    """What a streaming read recovered from an MCAP file that may have been cut short or hold damaged chunks."""

    messages: list[BagMessage]
    msgtypes: dict[str, str]          # topic -> message type
    file: Path
    size: int
    stopped_at: int | None = None     # byte offset where the readable part ends (None: the whole file read)
    reason: str = ""
    lost_chunks: list[str] = field(default_factory=list)  # each damaged chunk skipped: where, why, what it held
    lost: dict[str, int] = field(default_factory=dict)    # topic -> messages in the damaged chunks

    @property
    def complete(self) -> bool:
        """Whether every message of the file was recovered (read to its end, no damaged chunk)."""
        return self.stopped_at is None and not self.lost_chunks

    def describe(self) -> str:
        """One line: how much was read, the damaged chunks skipped, and where and why it stopped."""
        counts = ", ".join(f"{t} {sum(m.topic == t for m in self.messages)}" for t in sorted(self.msgtypes))
        skipped = ""
        if self.lost_chunks:
            lost = ", ".join(f"{topic} {count}" for topic, count in sorted(self.lost.items())) or "none indexed"
            skipped = (f"; {len(self.lost_chunks)} damaged chunk(s) skipped, their messages lost ({lost}): "
                       + "; ".join(self.lost_chunks))
        if self.stopped_at is None:
            return f"{self.file}: read whole, {len(self.messages)} messages ({counts}){skipped}"
        return (f"{self.file}: readable to byte {self.stopped_at} of {self.size} ({self.reason}); "
                f"{len(self.messages)} messages recovered ({counts or 'none'}), the rest is lost{skipped}")


def salvage_mcap(path: str | Path) -> Salvage:
    """Every message of an MCAP file up to where it stops being readable (a writer killed, a copy cut short).

    Reads record by record (chunks decompressed as they come) without the summary a killed writer never wrote. A
    chunk whose CRC does not match its content, or that does not decompress, is skipped and named, with the count
    of its messages from the index records that follow it; the records after it are read on.
    """
    from mcap.records import Channel, Chunk, Message, MessageIndex, Schema
    from mcap.stream_reader import StreamReader, breakup_chunk

    file = mcap_file_of(path)
    size = file.stat().st_size
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    found: list[tuple[int, int, bytes]] = []  # channel id, log time, data (a channel may be defined only later)
    damaged: list[tuple[int, str, dict[int, int]]] = []  # chunk offset, why, messages by channel id
    stopped_at, reason, position, counting = None, "", 0, None
    with file.open("rb") as stream:
        reader = StreamReader(stream, skip_magic=False, emit_chunks=True)
        try:
            for record in reader.records:
                start, position = position, stream.tell()
                records = [record]
                if isinstance(record, Chunk):
                    try:
                        records, counting = breakup_chunk(record, validate_crc=True), None
                    except Exception as exc:  # a CRC mismatch, or bytes zstd cannot decompress
                        counting = {}
                        damaged.append((start, f"{type(exc).__name__}: {exc}", counting))
                        continue
                elif isinstance(record, MessageIndex):  # the index of the chunk before: counts what a damaged one held
                    if counting is not None:
                        counting[record.channel_id] = len(record.records)
                    continue
                else:
                    counting = None
                for item in records:
                    if isinstance(item, Schema):
                        schemas[item.id] = item.name
                    elif isinstance(item, Channel):
                        channels[item.id] = (item.topic, schemas.get(item.schema_id, ""))
                    elif isinstance(item, Message):
                        found.append((item.channel_id, int(item.log_time), bytes(item.data)))
        except Exception as exc:
            stopped_at = stream.tell()
            reason = f"{type(exc).__name__}: {exc}".rstrip(": ") or "cut short"
    messages = sorted((BagMessage(*channels[cid], log_time, data) for cid, log_time, data in found
                       if cid in channels), key=lambda m: m.log_time_ns)
    if not schemas and not messages:
        raise DataError(f"{file}: nothing readable ({reason or 'empty'}); the writer died before its first flush")
    salvage = Salvage(messages, {t: m for t, m in channels.values()}, file, size, stopped_at, reason)
    for offset, why, counts in damaged:
        for cid, count in counts.items():
            topic = channels.get(cid, (f"channel {cid}", ""))[0]
            salvage.lost[topic] = salvage.lost.get(topic, 0) + count
        salvage.lost_chunks.append(f"chunk at byte {offset} ({why}): {sum(counts.values())} messages")
    return salvage


class SalvagedBagReader:
    """The readable part of a damaged MCAP bag, read the way ``BagReader`` reads a whole one.

    A bag cut short (a copy interrupted, a recorder killed) or with damaged chunks still plays what it holds;
    ``damage`` says what was lost and where.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.salvage = salvage_mcap(self.path)
        self.damage = "" if self.salvage.complete else self.salvage.describe()
        self._store = typestore()

    def close(self) -> None:
        """Nothing is held open."""

    def __enter__(self) -> SalvagedBagReader:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        return False

    @property
    def topics(self) -> dict[str, str]:
        """Topic name -> message type of what was recovered."""
        return dict(self.salvage.msgtypes)

    def message_count(self, topic: str | None = None) -> int:
        """Recovered messages, or those of one topic."""
        return sum(1 for m in self.salvage.messages if topic is None or m.topic == topic)

    @property
    def start_ns(self) -> int:
        """Log time of the first recovered message (ns)."""
        return self.salvage.messages[0].log_time_ns if self.salvage.messages else 0

    @property
    def end_ns(self) -> int:
        """Log time of the last recovered message (ns)."""
        return self.salvage.messages[-1].log_time_ns if self.salvage.messages else 0

    def require_topic(self, topic: str, msgtypes: Iterable[str] | None = None) -> str:
        """The type of ``topic``; ``DataError`` if the readable part has none of it, or another type."""
        if topic not in self.salvage.msgtypes:
            raise DataError(f"the readable part of bag {self.path} has no topic {topic} ({self.damage or 'whole'})")
        return _checked_type(self.path, topic, normalise_msgtype(self.salvage.msgtypes[topic]), msgtypes)

    def messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 stop_ns: int | None = None) -> Iterator[BagMessage]:
        """Recovered messages in log-time order, optionally only some topics and a time window [start, stop)."""
        wanted = set(topics) if topics is not None else None
        for message in self.salvage.messages:
            if wanted is not None and message.topic not in wanted:
                continue
            if (start_ns is not None and message.log_time_ns < start_ns) or (
                    stop_ns is not None and message.log_time_ns >= stop_ns):
                continue
            yield message

    def decode(self, message: BagMessage) -> object:
        """Deserialise a recovered message; ``DataError`` for bytes that do not parse."""
        msgtype = normalise_msgtype(message.msgtype)
        _require_type(self._store, msgtype)
        try:
            return self._store.deserialize_cdr(message.cdr, msgtype)
        except Exception as exc:
            raise DataError(f"message on {message.topic} in {self.path} does not parse as {msgtype}: {exc}") from exc


def recover_bag(path: str | Path, out: str | Path | None = None, *, overwrite: bool = False) -> Salvage:
    """Rebuild a readable bag (MCAP with its summary, and metadata.yaml) from what ``salvage_mcap`` recovers.

    ``out`` None replaces a bag folder in place; the damaged file is kept beside the folder as
    ``<folder>.damaged.mcap``, or ``<folder>.damaged.1.mcap``, ``.2``, ... when that name is taken (an earlier
    recovery's is never replaced), and a folder holding other files than its bag is not recovered in place. An
    ``out`` that exists is replaced only with ``overwrite``, and never when the damaged bag is inside it (that
    would delete what is being recovered).
    """
    path = Path(path)
    if out is not None:
        target = Path(out)
        source, resolved = path.resolve(), target.resolve()
        if resolved == source or resolved in source.parents:
            raise DataError(
                f"--out {target} holds the damaged bag {path}: replacing it would delete what is being recovered; "
                "give a new folder, or leave --out out to recover a bag folder in place"
            )
        if target.is_file():  # e.g. an earlier recovery's BAG.damaged.mcap: a bag is a folder, never put over a file
            raise DataError(f"--out {target} is a file, not a bag folder: give a new folder")
    salvage = salvage_mcap(path)
    if out is None:
        if not path.is_dir():
            raise DataError(f"{path}: give --out for a single .mcap file (in place works on a bag folder)")
        others = sorted(p.name for p in path.iterdir() if p != salvage.file and p.name != "metadata.yaml")
        if others:
            raise DataError(f"{path} holds other files than its bag ({', '.join(others)}): recovering it in place "
                            "would delete them; give --out NEW")
        salvage.file = _keep_aside(salvage.file, path.parent / f"{path.name}.damaged")
        target = path
    with BagWriter(target, overwrite=out is None or overwrite,
                   overwrite_hint="give a new folder, or pass --overwrite to replace it") as writer:
        for topic, msgtype in salvage.msgtypes.items():
            writer.add_topic(topic, msgtype)
        for message in salvage.messages:
            writer.write_cdr(message.topic, message.cdr, message.log_time_ns)
        writer.set_custom_data("recovered_from", f"{salvage.file.name}: {salvage.describe()}")
    return salvage


def _keep_aside(file: Path, stem: Path) -> Path:
    """Move ``file`` to ``<stem>.mcap``, else ``<stem>.1.mcap``, ``<stem>.2.mcap``, ...: the first name not taken.

    A hard link claims the name atomically (it fails on an existing file), so no earlier file is ever replaced;
    where links are not possible, the name is checked and the file renamed.
    """
    for number in range(1000):
        kept = stem.with_name(f"{stem.name}.mcap" if number == 0 else f"{stem.name}.{number}.mcap")
        try:
            os.link(file, kept)
        except FileExistsError:
            continue
        except OSError:  # no hard links on this file system
            if kept.exists():
                continue
            file.rename(kept)
            return kept
        file.unlink()
        return kept
    raise DataError(f"{stem}.mcap and 999 numbered names beside it exist already: move old damaged files away")


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
