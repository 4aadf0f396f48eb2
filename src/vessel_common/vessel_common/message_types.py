"""The ROS 2 message types without ROS: the rosbags Jazzy type store plus this project's ``vessel_msgs``.

The bag tools read and write recorded messages with it, and the tracking chain's nodes put their track arrays on
the wire with it (``vessel_common.wire``); the ``vessel_msgs`` types come from their ``.msg`` files, so neither
needs the generated Python message classes.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from vessel_common.errors import DataError


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


def require_type(store: Typestore, msgtype: str) -> None:
    """`DataError` unless `store` knows `msgtype` (for `vessel_msgs` types, saying where the `.msg` files are)."""
    if msgtype not in store.fielddefs:
        where = "VESSEL_MSGS_DIR, src/vessel_msgs/msg, $AMENT_PREFIX_PATH/share/vessel_msgs/msg"
        hint = f" (looked for the .msg files in {where})" if msgtype.startswith("vessel_msgs/") else ""
        raise DataError(f"unknown message type {msgtype!r}{hint}")
