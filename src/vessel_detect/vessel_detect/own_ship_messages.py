"""The own ship's samples as ROS messages and back: ``sensor_msgs/Imu`` (REP-103/REP-145) and ``NavSatFix``.

The angle conventions and the checks are ``vessel_calib.own_ship``'s (ROS-free, tested without ROS); this module
only moves them in and out of rclpy messages, so a node that receives the own ship's data refuses exactly what the
tools refuse. A compass-only ship's Imu carries the heading alone with roll and pitch variances of -1 (not
measured); an Imu without any orientation has every orientation_covariance entry -1.
"""

from __future__ import annotations

import math

from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus

from vessel_calib.own_ship import (
    NO_ORIENTATION_COVARIANCE,
    NOT_MEASURED,
    AttitudeReading,
    OwnShipSample,
    PositionReading,
    attitude_reading,
    orientation_covariance,
    position_reading,
    quaternion_of_attitude,
)
from vessel_detect.bag_messages import sec_to_ns
from vessel_detect.ros_messages import stamp_ns, time_msg

OWN_SHIP_FRAME_ID = "base_link"
"""The ship's body frame (REP-105); the Imu orientation is of this frame in ENU."""


def _stamp_problem(stamp) -> str | None:
    if not 0 <= stamp.nanosec < 1_000_000_000 or stamp_ns(stamp) <= 0:
        return "bad_stamp"
    return None


def imu_of_sample(sample: OwnShipSample, frame_id: str = OWN_SHIP_FRAME_ID, sigma_deg: float | None = None,
                  heading_sigma_deg: float | None = None) -> Imu:
    """The Imu of a sample's attitude, stamped with the sample's time; angular rate and acceleration not measured.

    A sample without attitude gives an Imu whose orientation_covariance is all -1 (no orientation).
    """
    message = Imu()
    message.header.stamp = time_msg(sec_to_ns(sample.stamp))
    message.header.frame_id = frame_id
    if sample.attitude is None:
        message.orientation.w = 1.0
        message.orientation_covariance = list(NO_ORIENTATION_COVARIANCE)
    else:
        x, y, z, w = quaternion_of_attitude(sample.attitude)
        message.orientation.x, message.orientation.y, message.orientation.z, message.orientation.w = x, y, z, w
        message.orientation_covariance = orientation_covariance(sample.attitude, sigma_deg, heading_sigma_deg)
    message.angular_velocity_covariance[0] = NOT_MEASURED
    message.linear_acceleration_covariance[0] = NOT_MEASURED
    return message


def sample_attitude_of_imu(message: Imu) -> AttitudeReading:
    """The ship attitude and its sigma of a received Imu, or the reason it is refused (``own_ship.REASONS``)."""
    if _stamp_problem(message.header.stamp):
        return AttitudeReading(None, reason="bad_stamp")
    q = message.orientation
    return attitude_reading((q.x, q.y, q.z, q.w), list(message.orientation_covariance))


def stamp_s(message) -> float:
    """A message's header stamp in epoch seconds (the time to add its sample at)."""
    return stamp_ns(message.header.stamp) / 1e9


def navsatfix_of_sample(sample: OwnShipSample, frame_id: str = OWN_SHIP_FRAME_ID) -> NavSatFix:
    """The NavSatFix of a sample's position; NO_FIX with NaN latitude and longitude when it has none."""
    message = NavSatFix()
    message.header.stamp = time_msg(sec_to_ns(sample.stamp))
    message.header.frame_id = frame_id
    message.status.service = NavSatStatus.SERVICE_GPS
    if sample.has_position:
        message.status.status = NavSatStatus.STATUS_FIX
        message.latitude, message.longitude = float(sample.lat), float(sample.lon)
    else:
        message.status.status = NavSatStatus.STATUS_NO_FIX
        message.latitude = message.longitude = math.nan
    message.altitude = math.nan
    message.position_covariance_type = NavSatFix.COVARIANCE_TYPE_UNKNOWN
    return message


def position_of_navsatfix(message: NavSatFix) -> PositionReading:
    """The position of a received NavSatFix, or why it is refused: bad stamp, NO_FIX, NaN, off the globe."""
    if _stamp_problem(message.header.stamp):
        return PositionReading(reason="bad_stamp")
    return position_reading(int(message.status.status), float(message.latitude), float(message.longitude))
