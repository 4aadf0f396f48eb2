"""Write rosbag2 folders (MCAP storage) without ROS, as `ros2 bag record` makes them.

A folder with `metadata.yaml` and one MCAP file whose chunks are zstd-compressed and carry the CRC32 of their
content, messages CDR-serialised with the type definitions embedded, so `ros2 bag info/play`, `rosbags` and the
`mcap` library all read them.
"""

from __future__ import annotations

import os
import shutil
import struct
import tempfile
import time
import zlib
from pathlib import Path

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.rosbag2.errors import WriterError

from vessel_common.errors import DataError
from vessel_common.message_types import require_type, typestore
from vessel_detect.bag_messages import normalise_msgtype, ns_of_stamp

_CHUNK_CRC_OFFSET = 1 + 8 + 8 + 8 + 8
"""Bytes from the start of an MCAP chunk record to its uncompressed_crc: opcode, record length, message start and
end time, uncompressed size."""


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
        require_type(self._store, msgtype)
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
