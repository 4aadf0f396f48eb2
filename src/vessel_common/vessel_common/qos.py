"""The QoS profiles the project's topics use, and ``builtin_interfaces/Time`` <-> seconds."""

from __future__ import annotations

from builtin_interfaces.msg import Time
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from vessel_common.errors import VesselError

SENSOR_DATA_QOS = qos_profile_sensor_data
"""Best effort, keep last 5: images and other high-rate data where the newest sample matters most."""

LATCHED_QOS = QoSProfile(
    depth=1,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""Reliable and transient local: a late subscriber still gets the last sample (e.g. the camera's fix)."""


def image_qos_profile(name: str, reliable_depth: int = 5) -> QoSProfile:
    """The QoS of image topics named by an ``image_qos`` parameter: ``sensor_data`` or ``reliable``.

    ``reliable_depth``: the history kept when reliable (a publisher keeps more, so a slow reader can catch up).
    """
    if name == "sensor_data":
        return SENSOR_DATA_QOS
    if name == "reliable":
        return reliable_qos(reliable_depth)
    raise VesselError(f"image_qos '{name}' unknown: use sensor_data or reliable")


SENSOR_STREAM_QOS_CHOICES = ("reliable", "sensor_data")


def sensor_stream_qos(name: str, depth: int = 200) -> QoSProfile:
    """The QoS of a sensor's stream (an IMU, a GPS) read in full, named by a parameter: ``reliable`` or ``sensor_data``.

    A reliable reader loses nothing of the bursts a replay sends between two images, but does not match a driver
    that publishes best effort; ``sensor_data`` (best effort) matches every driver and may lose samples in bursts.
    """
    reliability = ReliabilityPolicy.RELIABLE if name == "reliable" else ReliabilityPolicy.BEST_EFFORT
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST, reliability=reliability,
                      durability=DurabilityPolicy.VOLATILE)


def reliable_qos(depth: int = 10) -> QoSProfile:
    """Reliable, volatile, keep last ``depth``: detections, tracks and fixes, where no message may be lost."""
    return QoSProfile(
        depth=depth,
        history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


def stamp_to_sec(stamp: Time) -> float:
    """Seconds since the epoch of a ``builtin_interfaces/Time``."""
    return stamp.sec + stamp.nanosec * 1e-9


def sec_to_stamp(seconds: float) -> Time:
    """A ``builtin_interfaces/Time`` for seconds since the epoch (rounded to the nanosecond)."""
    total_ns = round(seconds * 1e9)
    return Time(sec=total_ns // 1_000_000_000, nanosec=total_ns % 1_000_000_000)
