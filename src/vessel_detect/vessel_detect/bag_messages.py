"""Messages of rosbag2 bags without ROS: time stamps, the type store, and message constructors.

Serialisation uses the `rosbags` Jazzy type store extended with this project's `vessel_msgs` types (read from their
`.msg` files), so the tools can write and read recorded detections and tracks without a ROS install.
"""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from vessel_common.errors import DataError
from vessel_detect.bag_topics import (
    COMPRESSED_IMAGE,
    COVARIANCE_TYPE_APPROXIMATED,
    COVARIANCE_TYPE_UNKNOWN,
    NAV_SAT_FIX,
    SERVICE_GPS,
    STATUS_FIX,
)

_NS_PER_S = 1_000_000_000


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


def require_type(store: Typestore, msgtype: str) -> None:
    """`DataError` unless `store` knows `msgtype` (for `vessel_msgs` types, saying where the `.msg` files are)."""
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
