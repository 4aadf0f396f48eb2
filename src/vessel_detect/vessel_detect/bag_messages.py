"""Messages of rosbag2 bags without ROS: time stamps, the type store, and message constructors.

Serialisation uses the `rosbags` Jazzy type store extended with this project's `vessel_msgs` types (read from their
`.msg` files), so the tools can write and read recorded detections and tracks without a ROS install.
"""

from __future__ import annotations

import math

import numpy as np
from rosbags.typesys.store import Typestore

from vessel_calib.own_ship import (
    NO_ORIENTATION_COVARIANCE,
    NOT_MEASURED,
    ShipAttitude,
    orientation_covariance,
    quaternion_of_attitude,
)
from vessel_common.errors import DataError
from vessel_common.message_types import typestore
from vessel_detect.bag_topics import (
    COMPRESSED_IMAGE,
    COVARIANCE_TYPE_APPROXIMATED,
    COVARIANCE_TYPE_UNKNOWN,
    IMU,
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


def imu(stamp_ns: int, attitude: ShipAttitude | None, frame_id: str = "base_link", sigma_deg: float | None = None,
        heading_sigma_deg: float | None = None) -> object:
    """A `sensor_msgs/Imu` holding a ship attitude as its REP-103 orientation (`vessel_calib.own_ship`).

    Compass only: roll and pitch variances -1; no attitude: every orientation variance -1. Angular rate and
    acceleration are not measured (their covariance's first entry -1).
    """
    store = typestore()
    if attitude is None:
        quaternion, covariance = (0.0, 0.0, 0.0, 1.0), list(NO_ORIENTATION_COVARIANCE)
    else:
        quaternion = quaternion_of_attitude(attitude)
        covariance = orientation_covariance(attitude, sigma_deg, heading_sigma_deg)
    Quaternion = store.types["geometry_msgs/msg/Quaternion"]
    Vector3 = store.types["geometry_msgs/msg/Vector3"]
    not_measured = np.zeros(9, dtype=np.float64)
    not_measured[0] = NOT_MEASURED
    x, y, z, w = quaternion
    return store.types[IMU](
        header=header(stamp_ns, frame_id, store),
        orientation=Quaternion(x=x, y=y, z=z, w=w),
        orientation_covariance=np.array(covariance, dtype=np.float64),
        angular_velocity=Vector3(x=0.0, y=0.0, z=0.0),
        angular_velocity_covariance=not_measured.copy(),
        linear_acceleration=Vector3(x=0.0, y=0.0, z=0.0),
        linear_acceleration_covariance=not_measured.copy(),
    )


def camera_pose_not_given(stamp_ns: int, frame_id: str = "camera") -> object:
    """A ``vessel_msgs/CameraPose`` of a producer that knows no pose (its boxes are in the reference image)."""
    store = typestore()
    point = store.types["vessel_msgs/msg/Point2D"](x=0.0, y=0.0)
    return store.types["vessel_msgs/msg/CameraPose"](
        header=header(stamp_ns, frame_id, store), valid=False, source=0, problem="", heading_deg=0.0, pitch_deg=0.0,
        roll_deg=0.0, attitude_covariance=np.zeros(9), camera_rotation_covariance=np.zeros(9),
        image_to_reference=np.eye(3).ravel(), focal_px=0.0, lens_k1=0.0, lens_center=point, horizon_found=False,
        horizon_ideal_abc=np.zeros(3), horizon_sigma_px=0.0)

