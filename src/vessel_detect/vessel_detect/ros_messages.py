"""Small rclpy-side helpers shared by the camera and recorder nodes (message classes by name, stamps)."""

from __future__ import annotations

import importlib

from builtin_interfaces.msg import Time

from vessel_common.errors import DataError
from vessel_detect.bag_messages import normalise_msgtype

NS_PER_S = 1_000_000_000


def message_class(msgtype: str) -> type:
    """The rclpy message class of `pkg/msg/Name` (or `pkg/Name`); `DataError` if it is not installed."""
    package, _, name = normalise_msgtype(msgtype).split("/")
    try:
        return getattr(importlib.import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError) as exc:
        raise DataError(f"message type {msgtype} is not available in this ROS environment") from exc


def time_msg(stamp_ns: int) -> Time:
    """A builtin_interfaces/Time from integer nanoseconds (exact, unlike a float round trip)."""
    return Time(sec=stamp_ns // NS_PER_S, nanosec=stamp_ns % NS_PER_S)


def stamp_ns(stamp: Time) -> int:
    """Integer nanoseconds of a builtin_interfaces/Time."""
    return stamp.sec * NS_PER_S + stamp.nanosec
