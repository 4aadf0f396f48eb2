"""Crash-safe snapshots of a node's working state, so that a node restarted after a crash resumes where it stopped.

A restarted tracker or fuser that starts cold has no tracks, no world filters and no target history: the graph
publishes no fix until new tracks are confirmed and a target is chosen again, and then a worse one for a while.
With a state file the node writes its core's state every ``period_s`` of message time (to a temporary file, then
renamed over the old one, so a kill at any moment leaves the previous snapshot whole). At its first message after
a start it reads the snapshot back, but only if it was written with the same settings (``fingerprint``) and its
stamp is not after that message's and at most ``max_age_s`` before it. Anything else is a cold start, and
``resume`` says why.

The snapshot is JSON (schema ``vessel_state``, ``VERSION``): data only, never code. Reading it builds nothing but
numbers, strings, lists, tuples, dicts, sets, deques and numeric numpy arrays (``encode_state``/``decode_state``);
the core turns its objects into such data (``snapshot()``) and back (``restore()``) itself. A file that is not
such a snapshot (another format, another version, a pickle of an earlier version, damaged) is refused before any
of it is used, with the reason, and the node starts cold.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import pickle
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vessel_common.errors import DataError

SCHEMA = "vessel_state"
VERSION = 2
"""Version 1 was a pickle (never read any more: loading a pickle runs whatever code the file names)."""
FORMAT = f"{SCHEMA}/{VERSION}"
_NUMERIC_KINDS = "biuf"  # the numpy dtypes a snapshot may hold: bool, int, unsigned, float (never object)

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
"""The ``standby`` parameter of the tracker, the fuser and the GPS publisher (``vessel_common.node_state.Standby``)."""


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


class StateFileError(DataError):
    """A file that is not a state file of this schema and version; the message says why (refused before use)."""


def encode_state(value: object, where: str = "state") -> object:
    """``value`` as JSON data that ``decode_state`` turns back into an equal value of the same types.

    Holds None, bool, int, float (NaN and infinities too), str, list, tuple, dict, set, frozenset, deque and numpy
    arrays and scalars of bool, int or float dtype; anything else (an object, a function) raises DataError naming
    where it is (``where``): the core must turn its objects into such data itself.
    """
    kind = type(value)
    if value is None or kind in (bool, int, str):
        return value
    if kind is float:
        return value if math.isfinite(value) else {"$float": repr(value)}
    if kind is list:
        return [encode_state(item, f"{where}[{index}]") for index, item in enumerate(value)]
    if kind is dict:
        if all(type(key) is str and not key.startswith("$") for key in value):
            return {key: encode_state(item, f"{where}[{key!r}]") for key, item in value.items()}
        return {"$dict": [[encode_state(key, f"{where} key"), encode_state(item, f"{where}[{key!r}]")]
                          for key, item in value.items()]}
    if kind in (tuple, set, frozenset):
        return {f"${kind.__name__}": [encode_state(item, f"{where}[{index}]") for index, item in enumerate(value)]}
    if kind is deque:
        return {"$deque": {"maxlen": value.maxlen,
                           "items": [encode_state(item, f"{where}[{index}]") for index, item in enumerate(value)]}}
    if kind is np.ndarray and value.dtype.kind in _NUMERIC_KINDS:
        flat = value.ravel().tolist()
        if value.dtype.kind == "f" and not np.isfinite(value).all():
            flat = [encode_state(item) for item in flat]
        return {"$ndarray": {"dtype": value.dtype.str, "shape": list(value.shape), "data": flat}}
    if isinstance(value, np.generic) and value.dtype.kind in _NUMERIC_KINDS:
        return {"$scalar": {"dtype": value.dtype.str, "value": encode_state(value.item(), where)}}
    raise DataError(f"{where} is a {kind.__module__}.{kind.__qualname__}, which a state file does not hold (only "
                    "numbers, strings, containers and numeric numpy arrays)")


def decode_state(data: object, where: str = "state") -> object:
    """The value ``encode_state`` made ``data`` from; StateFileError for anything it cannot have made."""
    kind = type(data)
    if data is None or kind in (bool, int, float, str):
        return data
    if kind is list:
        return [decode_state(item, f"{where}[{index}]") for index, item in enumerate(data)]
    if kind is not dict:
        raise StateFileError(f"{where} is a JSON {kind.__name__}")
    if not any(key.startswith("$") for key in data):
        return {key: decode_state(item, f"{where}[{key!r}]") for key, item in data.items()}
    decoder = _DECODERS.get(next(iter(data))) if len(data) == 1 else None
    if decoder is None:
        raise StateFileError(f"{where} is an unknown tagged value {sorted(data)}")
    (tag, body), = data.items()
    try:
        return decoder(body, where)
    except (TypeError, ValueError, KeyError, OverflowError) as error:
        raise StateFileError(f"{where} is not a valid {tag} ({type(error).__name__}: {error})") from None


def _decode_float(body: object, where: str) -> float:
    if body not in ("nan", "inf", "-inf"):
        raise ValueError(f"{body!r} is not nan, inf or -inf")
    return float(body)


def _decode_items(body: object, where: str) -> list:
    if type(body) is not list:
        raise TypeError("its items are not a list")
    return [decode_state(item, f"{where}[{index}]") for index, item in enumerate(body)]


def _decode_dict(body: object, where: str) -> dict:
    pairs = _decode_items(body, where)
    if not all(type(pair) is list and len(pair) == 2 for pair in pairs):
        raise ValueError("not a list of [key, value] pairs")
    return {key: value for key, value in pairs}


def _decode_deque(body: object, where: str) -> deque:
    maxlen = body["maxlen"]
    if maxlen is not None and not (type(maxlen) is int and maxlen >= 0):
        raise ValueError(f"maxlen {maxlen!r}")
    return deque(_decode_items(body["items"], where), maxlen=maxlen)


def _numeric_dtype(name: object) -> np.dtype:
    dtype = np.dtype(str(name))
    if dtype.kind not in _NUMERIC_KINDS:
        raise ValueError(f"dtype {name!r} is not a number type")
    return dtype


def _decode_array(body: object, where: str) -> np.ndarray:
    dtype, shape, data = _numeric_dtype(body["dtype"]), body["shape"], body["data"]
    if type(shape) is not list or not all(type(n) is int and n >= 0 for n in shape) or type(data) is not list:
        raise ValueError("shape or data is not a list")
    if len(data) != math.prod(shape):
        raise ValueError(f"{len(data)} values for shape {tuple(shape)}")
    values = [_decode_float(item.get("$float"), where) if type(item) is dict else item for item in data]
    if not all(type(item) in (bool, int, float) for item in values):
        raise ValueError("a value is not a number")
    return np.array(values, dtype=dtype).reshape(shape)


def _decode_scalar(body: object, where: str) -> np.generic:
    value = decode_state(body["value"], where)
    if type(value) not in (bool, int, float):
        raise ValueError("the value is not a number")
    return _numeric_dtype(body["dtype"]).type(value)


_DECODERS = {
    "$float": _decode_float,
    "$tuple": lambda body, where: tuple(_decode_items(body, where)),
    "$set": lambda body, where: set(_decode_items(body, where)),
    "$frozenset": lambda body, where: frozenset(_decode_items(body, where)),
    "$dict": _decode_dict,
    "$deque": _decode_deque,
    "$ndarray": _decode_array,
    "$scalar": _decode_scalar,
}


def _refuse_constant(name: str) -> None:
    raise StateFileError(f"it holds the non-JSON constant {name}")


def read_snapshot(path: Path, node: str) -> dict:
    """The checked header of a state file (schema, version, node, fingerprint, stamp) and its undecoded state.

    StateFileError says why the file is not a snapshot of ``node`` in this schema and version; nothing of such a
    file is used.
    """
    try:
        data = Path(path).read_bytes()
    except OSError as error:
        raise StateFileError(f"unreadable ({error.strerror or error})") from None
    if data[:1] == b"\x80":
        raise StateFileError("it is a pickle (the format before version 2; never loaded, since loading a pickle runs "
                             "code it names)")
    try:
        saved = json.loads(data.decode("utf-8"), parse_constant=_refuse_constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as error:
        raise StateFileError(f"not JSON ({type(error).__name__}: {str(error)[:200]})") from None
    if type(saved) is not dict:
        raise StateFileError(f"its top level is a JSON {type(saved).__name__}, not an object")
    header = {key: saved.get(key) for key in ("schema", "version", "node")}
    if header != {"schema": SCHEMA, "version": VERSION, "node": node}:
        raise StateFileError("it is " + ", ".join(f"{key} {value!r}" for key, value in header.items()))
    stamp = saved.get("stamp")
    if type(stamp) not in (int, float) or not math.isfinite(stamp) or "state" not in saved:
        raise StateFileError("it has no finite stamp or no state")
    if type(saved.get("fingerprint")) is not str:
        raise StateFileError("it has no settings fingerprint")
    return saved


def fields_of(obj: object, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    """A dataclass's fields, or another object's attributes, by name (except ``skip``): an object as plain data."""
    names = [f.name for f in dataclasses.fields(obj)] if dataclasses.is_dataclass(obj) else list(vars(obj))
    return {name: getattr(obj, name) for name in names if name not in skip}


def checked_fields(state: object, expected: set[str] | dict, what: str) -> dict:
    """``state`` if it is a dict of exactly the ``expected`` names, else ValueError (a snapshot of another version)."""
    if not isinstance(state, dict):
        raise ValueError(f"{what} is not a set of fields")
    if set(state) != set(expected):
        differ = ", ".join(sorted(map(str, set(state) ^ set(expected))))
        raise ValueError(f"{what} has other fields than this version's ({differ})")
    return state


def set_fields(obj: object, state: object, what: str, skip: tuple[str, ...] = ()) -> object:
    """Give ``obj`` (a new object) the fields ``fields_of`` took from another; ValueError if they are not its own."""
    for name, value in checked_fields(state, fields_of(obj, skip), what).items():
        setattr(obj, name, value)
    return obj


def object_state(obj: object, part: type, skip: tuple[str, ...] = ()) -> dict[str, dict]:
    """An object's attributes as plain data; its ``part`` objects (a dataclass), alone or in a dict, by field.

    A ``part`` held in a dict and also by an attribute of its own is saved once, with where it is held, so that
    ``restore_object`` makes one object of it again (code that compares them with ``is`` behaves the same).
    """
    held = {id(item): [name, key] for name, value in vars(obj).items() if isinstance(value, dict)
            for key, item in value.items() if isinstance(item, part)}
    state: dict[str, dict] = {"plain": {}, "parts": {}, "part": {}}
    for name, value in fields_of(obj, skip).items():
        if isinstance(value, part):
            where = held.get(id(value))
            state["part"][name] = {"held_in": where} if where else {"fields": fields_of(value)}
        elif isinstance(value, dict) and value and all(isinstance(item, part) for item in value.values()):
            state["parts"][name] = {key: fields_of(item) for key, item in value.items()}
        else:
            state["plain"][name] = value
    return state


def restore_object(obj: object, state: object, part: type, what: str, skip: tuple[str, ...] = ()) -> object:
    """Give ``obj`` (a new object) what ``object_state`` took from another; ValueError if it has other fields."""
    state = checked_fields(state, {"plain", "parts", "part"}, what)
    names = {f.name for f in dataclasses.fields(part)}

    def new_part(fields: object) -> object:
        return part(**checked_fields(fields, names, f"a {part.__name__} of {what}"))

    values = dict(state["plain"])
    for name, parts in state["parts"].items():
        values[name] = {key: new_part(fields) for key, fields in parts.items()}
    for name, single in state["part"].items():
        if single.get("held_in"):
            holder, key = single["held_in"]
            if holder not in state["parts"]:
                raise ValueError(f"{what}: {name} is said to be held in {holder!r}, which holds no {part.__name__}")
            values[name] = values[holder][key]
        else:
            values[name] = new_part(single["fields"])
    return set_fields(obj, values, what, skip)


@dataclass
class StateFile:
    """One node's snapshot file: ``resume`` once at the first message, then ``save`` whenever ``due``."""

    path: Path
    node: str
    fingerprint: str
    period_s: float = 0.5
    max_age_s: float = 60.0
    graph: str = ""  # the namespace of the node's graph (one camera's), so that another camera's file is refused

    def __post_init__(self) -> None:
        self.path = Path(self.path).expanduser()
        self.pending = True  # resume not tried yet
        self._saved_stamp: float | None = None
        self.resumed_stamp: float | None = None  # the stamp of the snapshot resume() returned
        self.refused = ""  # why resume() refused the file as not a snapshot of this node, schema and version

    @property
    def resumed_path(self) -> Path:
        """Where this snapshot goes once it has been resumed."""
        return resumed_path(self.path)

    def resume(self, stamp: float, consume: bool = True) -> tuple[object | None, str]:
        """The saved state if it is valid for a message stamped ``stamp``, else None; and what happened, in words.

        A snapshot is resumed once: a node that stops again before it writes a new one starts cold the next time,
        since the state it resumed may be what stopped it. ``consume=False`` reads it without marking it (a hot
        standby reading its active node's snapshot). A file that is not a snapshot of this node in this schema and
        version is refused before any of it is used (``refused`` says why).
        """
        self.pending = False
        self.refused = ""
        if not self.path.is_file():
            if self.resumed_path.is_file():
                return None, (f"state file {self.path} was resumed once already and the node stopped again before "
                              "writing a new one (the state may be what stopped it): cold start")
            return None, f"no state file {self.path}: cold start"
        try:
            saved = read_snapshot(self.path, self.node)
            if saved.get("graph", "") != self.graph:
                raise StateFileError(f"it was written by the {self.node} of graph {saved.get('graph') or '/'!r}, "
                                     f"this one is of graph {self.graph or '/'!r} (two graphs given one state_file?)")
            if saved["fingerprint"] != self.fingerprint:
                return None, f"state file {self.path} was written with other settings: cold start"
            age = stamp - float(saved["stamp"])
            if not 0.0 <= age <= self.max_age_s:
                return None, (f"state file {self.path} is {age:+.1f} s from the first message (resumed only within "
                              f"0..{self.max_age_s:g} s, state_max_age_s): cold start")
            state = decode_state(saved["state"])
        except (StateFileError, RecursionError) as error:  # RecursionError: nested deeper than any snapshot
            return None, self.refuse(error)
        self._saved_stamp = float(saved["stamp"])
        if consume:
            try:
                os.replace(self.path, self.resumed_path)
            except OSError as error:
                return None, f"state file {self.path} could not be marked as resumed ({error}): cold start"
        self.resumed_stamp = float(saved["stamp"])
        return state, f"resumed from state file {self.path}, saved {age:.2f} s before the first message"

    def refuse(self, reason: object) -> str:
        """Refuse the snapshot ``resume`` returned (the core found it does not fit): the log line, as ``resume``'s."""
        self.refused = str(reason)
        return f"state file {self.path} is not a {self.node} state file of version {VERSION}: {reason}; cold start"

    def due(self, stamp: float) -> bool:
        """Whether a snapshot at ``stamp`` is due (``period_s`` of message time since the last one, or none yet)."""
        return self._saved_stamp is None or not 0.0 <= stamp - self._saved_stamp < self.period_s

    def save(self, stamp: float, state: object) -> None:
        """Write the snapshot atomically; OSError when the disk refuses, DataError when the state is not plain data.

        Either way the previous snapshot stays whole.
        """
        try:
            payload = {"schema": SCHEMA, "version": VERSION, "node": self.node, "fingerprint": self.fingerprint,
                       "graph": self.graph, "stamp": float(stamp), "state": encode_state(state, f"{self.node} state")}
            text = json.dumps(payload, allow_nan=False, separators=(",", ":"))
        except (DataError, ValueError, TypeError) as error:
            raise DataError(f"{self.node} state cannot be saved to {self.path}: {error}") from None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        temporary = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        try:
            temporary.write_text(text, encoding="utf-8")
            os.replace(temporary, self.path)
        finally:
            temporary.unlink(missing_ok=True)
        self.resumed_path.unlink(missing_ok=True)
        self._saved_stamp = float(stamp)
