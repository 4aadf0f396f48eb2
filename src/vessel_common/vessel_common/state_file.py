"""Crash-safe snapshots of a node's working state, so that a node restarted after a crash resumes where it stopped.

A restarted tracker or fuser that starts cold has no tracks, no world filters and no target history: the graph
publishes no fix until new tracks are confirmed and a target is chosen again, and then a worse one for a while.
With a state file the node writes its core's state every ``period_s`` of message time (to a temporary file, then
renamed over the old one, so a kill at any moment leaves the previous snapshot whole). At its first message after
a start it reads the snapshot back, but only if it was written with the same settings (``fingerprint``) and its
stamp is not after that message's and at most ``max_age_s`` before it. Anything else is a cold start, and
``resume`` says why.

The snapshot is a pickle: point ``state_file`` only at a file the node itself writes.
"""

from __future__ import annotations

import hashlib
import os
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vessel_common.errors import DataError

FORMAT = "vessel_state/1"

STATE_PARAMETERS: dict[str, tuple[Any, str, tuple[float, float] | None]] = {
    "state_file": ("", "Snapshot of the node's tracks, written every state_period_s of message time and read back "
                   "at the first message after a start, so that a node restarted after a crash (respawn) carries "
                   "on instead of starting cold; '': none. A snapshot written with other settings, or more than "
                   "state_max_age_s before the first message, is not used, and a snapshot is resumed only once.", None),
    "state_period_s": (0.5, "Message time between two snapshots of state_file (0: every message), s.",
                       (0.0, 3600.0)),
    "state_max_age_s": (60.0, "A snapshot older than this at the first message after a start is not used, s.",
                        (0.0, 1e9)),
}
"""The parameters of a node with a state file (tracker, fuser): name -> (default, description, float range)."""

STANDBY_DESCRIPTION = ("Hot standby: process every message but publish nothing and write no state file until "
                       "promoted (set to false, or SIGUSR1, which ./vessel graph --hot-standby sends when the active "
                       "node dies). A promoted node stays active.")
"""The ``standby`` parameter of the tracker, the fuser and the GPS publisher (``node_support.Standby``)."""


def settings_fingerprint(*settings: object) -> str:
    """A short hash of the settings a snapshot is only valid for (a changed setting means a cold start).

    The same settings give the same hash in every process: sets are hashed sorted (their pickled order follows
    the per-process string hash).
    """
    settings = tuple(sorted(value) if isinstance(value, (set, frozenset)) else value for value in settings)
    try:
        data = pickle.dumps(settings, protocol=4)
    except (pickle.PicklingError, TypeError, AttributeError):
        data = repr(settings).encode()
    return hashlib.sha256(data).hexdigest()[:16]


def remove_state_file(path: Path) -> None:
    """Remove a node's snapshot and its resumed marker (a new run starts cold)."""
    for stale in (Path(path), resumed_path(Path(path))):
        stale.unlink(missing_ok=True)


def resumed_path(path: Path) -> Path:
    """Where a snapshot goes once it has been resumed (it is never resumed twice)."""
    return path.with_name(path.name + ".resumed")


@dataclass
class StateFile:
    """One node's snapshot file: ``resume`` once at the first message, then ``save`` whenever ``due``."""

    path: Path
    node: str
    fingerprint: str
    period_s: float = 0.5
    max_age_s: float = 60.0

    def __post_init__(self) -> None:
        self.path = Path(self.path).expanduser()
        self.pending = True  # resume not tried yet
        self._saved_stamp: float | None = None
        self.resumed_stamp: float | None = None  # the stamp of the snapshot resume() returned

    @property
    def resumed_path(self) -> Path:
        """Where this snapshot goes once it has been resumed."""
        return resumed_path(self.path)

    def resume(self, stamp: float, consume: bool = True) -> tuple[object | None, str]:
        """The saved state if it is valid for a message stamped ``stamp``, else None; and what happened, in words.

        A snapshot is resumed once: a node that stops again before it writes a new one starts cold the next time,
        since the state it resumed may be what stopped it. ``consume=False`` reads it without marking it (a hot
        standby reading its active node's snapshot).
        """
        self.pending = False
        if not self.path.is_file():
            if self.resumed_path.is_file():
                return None, (f"state file {self.path} was resumed once already and the node stopped again before "
                              "writing a new one (the state may be what stopped it): cold start")
            return None, f"no state file {self.path}: cold start"
        try:
            with open(self.path, "rb") as stream:
                saved = pickle.load(stream)
        except Exception as error:  # any unreadable pickle (truncated, another version): a cold start
            return None, f"state file {self.path} unreadable ({type(error).__name__}: {error}): cold start"
        if not isinstance(saved, dict) or saved.get("format") != FORMAT or saved.get("node") != self.node:
            return None, f"state file {self.path} is not a {self.node} snapshot ({FORMAT}): cold start"
        if saved.get("fingerprint") != self.fingerprint:
            return None, f"state file {self.path} was written with other settings: cold start"
        age = stamp - float(saved["stamp"])
        if not 0.0 <= age <= self.max_age_s:
            return None, (f"state file {self.path} is {age:+.1f} s from the first message (resumed only within "
                          f"0..{self.max_age_s:g} s, state_max_age_s): cold start")
        self._saved_stamp = float(saved["stamp"])
        if consume:
            try:
                os.replace(self.path, self.resumed_path)
            except OSError as error:
                return None, f"state file {self.path} could not be marked as resumed ({error}): cold start"
        self.resumed_stamp = float(saved["stamp"])
        return saved["state"], f"resumed from state file {self.path}, saved {age:.2f} s before the first message"

    def due(self, stamp: float) -> bool:
        """Whether a snapshot at ``stamp`` is due (``period_s`` of message time since the last one, or none yet)."""
        return self._saved_stamp is None or not 0.0 <= stamp - self._saved_stamp < self.period_s

    def save(self, stamp: float, state: object) -> None:
        """Write the snapshot atomically; OSError when the disk refuses, DataError when the state cannot be pickled.

        Either way the previous snapshot stays whole.
        """
        self.path.parent.mkdir(parents=True, exist_ok=True)
        temporary = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        payload = {"format": FORMAT, "node": self.node, "fingerprint": self.fingerprint, "stamp": float(stamp),
                   "state": state}
        try:
            with open(temporary, "wb") as stream:
                try:
                    pickle.dump(payload, stream, protocol=pickle.HIGHEST_PROTOCOL)
                except (pickle.PicklingError, TypeError, AttributeError) as error:
                    raise DataError(f"{self.node} state cannot be saved to {self.path}: {error}") from None
            os.replace(temporary, self.path)
        finally:
            temporary.unlink(missing_ok=True)
        self.resumed_path.unlink(missing_ok=True)
        self._saved_stamp = float(stamp)
