"""Salvage damaged MCAP bags: read what a cut-short or corrupt file holds, play it, or rebuild a readable bag.

A chunk whose content does not match its CRC, or that does not decompress, is skipped and named with the count of its
messages; a file cut short (a writer killed, a copy interrupted) is read up to where it stops being readable.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from vessel_common.errors import DataError
from vessel_common.message_types import require_type, typestore
from vessel_detect.bag_messages import normalise_msgtype
from vessel_detect.bag_reader import BagMessage, checked_type, mcap_file_of
from vessel_detect.bag_writer import BagWriter


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
        return checked_type(self.path, topic, normalise_msgtype(self.salvage.msgtypes[topic]), msgtypes)

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
        require_type(self._store, msgtype)
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
