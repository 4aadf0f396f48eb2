"""own_ship_messages: own-ship samples as rclpy Imu / NavSatFix and back, and the bag (rosbags) Imu read by rclpy."""

import math

import numpy as np
import pytest

from vessel_calib.own_ship import OwnShipSample, ShipAttitude, quaternion_of_attitude
from vessel_detect import bag_messages, bag_topics

pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")

from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus

from vessel_detect.own_ship_messages import (
    imu_of_sample,
    navsatfix_of_sample,
    position_of_navsatfix,
    sample_attitude_of_imu,
    stamp_s,
)

STAMP = 1601494583.25
ROLLING = ShipAttitude(72.9, -1.5, 4.8)


def sample(attitude=ROLLING, lat=32.70297, lon=-117.234631):
    return OwnShipSample(STAMP, lat, lon, attitude)


def test_imu_of_a_full_attitude_round_trips_through_cdr():
    message = imu_of_sample(sample(), sigma_deg=0.3, heading_sigma_deg=1.5)
    assert message.header.frame_id == "base_link" and stamp_s(message) == pytest.approx(STAMP, abs=1e-6)
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (1601494583, 250_000_000)
    q = message.orientation
    assert (q.x, q.y, q.z, q.w) == pytest.approx(quaternion_of_attitude(ShipAttitude(72.9, -1.5, 4.8)))
    assert message.angular_velocity_covariance[0] == -1.0 and message.linear_acceleration_covariance[0] == -1.0
    back = deserialize_message(serialize_message(message), Imu)
    reading = sample_attitude_of_imu(back)
    assert reading.ok and reading.sigma_deg == pytest.approx(1.5)
    a = reading.attitude
    assert (a.heading_deg, a.pitch_deg, a.roll_deg) == pytest.approx((72.9, -1.5, 4.8))


def test_compass_only_imu():
    message = imu_of_sample(sample(ShipAttitude(359.5)), heading_sigma_deg=2.0)
    cov = message.orientation_covariance
    assert cov[0] == -1.0 and cov[4] == -1.0 and cov[8] == pytest.approx(math.radians(2.0) ** 2)
    reading = sample_attitude_of_imu(message)
    assert reading.ok and reading.attitude.heading_deg == pytest.approx(359.5) and not reading.attitude.has_tilt
    assert reading.attitude.pitch_deg is None and reading.sigma_deg == pytest.approx(2.0)


def test_an_imu_without_orientation_and_broken_ones_are_refused():
    assert list(imu_of_sample(sample(None)).orientation_covariance) == [-1.0] * 9
    assert sample_attitude_of_imu(imu_of_sample(sample(None))).reason == "no_orientation"
    nan = imu_of_sample(sample())
    nan.orientation.x = math.nan
    assert sample_attitude_of_imu(nan).reason == "nan_quaternion"
    long = imu_of_sample(sample())
    long.orientation.w *= 1.01
    assert sample_attitude_of_imu(long).reason == "quaternion_not_unit"
    zero_stamp = imu_of_sample(sample())
    zero_stamp.header.stamp.sec = 0
    zero_stamp.header.stamp.nanosec = 0
    reading = sample_attitude_of_imu(zero_stamp)
    assert (reading.ok, reading.reason, reading.attitude) == (False, "bad_stamp", None)


def test_navsatfix_of_a_sample_and_back():
    message = navsatfix_of_sample(sample())
    assert message.status.status == NavSatStatus.STATUS_FIX and message.header.frame_id == "base_link"
    assert math.isnan(message.altitude) and message.position_covariance_type == NavSatFix.COVARIANCE_TYPE_UNKNOWN
    reading = position_of_navsatfix(deserialize_message(serialize_message(message), NavSatFix))
    assert reading.ok and (reading.lat, reading.lon) == (32.70297, -117.234631)
    none = navsatfix_of_sample(sample(lat=math.nan, lon=math.nan))
    assert none.status.status == NavSatStatus.STATUS_NO_FIX and math.isnan(none.latitude)
    assert position_of_navsatfix(none).reason == "no_fix"


@pytest.mark.parametrize(("lat", "lon", "reason"), [(math.nan, 0.0, "nan_position"), (0.0, math.inf, "nan_position"),
                                                    (90.5, 0.0, "position_out_of_range"),
                                                    (0.0, -180.5, "position_out_of_range")])
def test_bad_positions_are_refused(lat, lon, reason):
    message = navsatfix_of_sample(sample())
    message.latitude, message.longitude = lat, lon
    reading = position_of_navsatfix(message)
    assert not reading.ok and reading.reason == reason


def test_the_bag_imu_is_the_same_message():
    """bag_messages.imu (rosbags, what bag_build writes) reads back in rclpy exactly like imu_of_sample's."""
    store = bag_messages.typestore()
    for attitude in (ShipAttitude(12.0, 3.0, -4.0), ShipAttitude(200.0), None):
        stamp_ns = bag_messages.sec_to_ns(STAMP)
        cdr = store.serialize_cdr(bag_messages.imu(stamp_ns, attitude, sigma_deg=0.5), bag_topics.IMU)
        from_bag = deserialize_message(bytes(cdr), Imu)
        direct = imu_of_sample(sample(attitude), sigma_deg=0.5)
        assert from_bag.header == direct.header
        assert from_bag.orientation == direct.orientation
        np.testing.assert_array_equal(from_bag.orientation_covariance, direct.orientation_covariance)
        np.testing.assert_array_equal(from_bag.angular_velocity_covariance, direct.angular_velocity_covariance)
