"""vessel_calib.own_ship: own_ship.csv, the buffer's lookups and refusals, and the REP-103 orientation conventions."""

import math

import numpy as np
import pytest

from vessel_calib.own_ship import (
    ENU_FROM_NED,
    NO_ORIENTATION_COVARIANCE,
    REASONS,
    OwnShipBuffer,
    OwnShipSample,
    ShipAttitude,
    attitude_of_quaternion,
    attitude_reading,
    gaps,
    ned_from_body,
    orientation_covariance,
    position_reading,
    quaternion_of_attitude,
    read_own_ship_csv,
    wrap_deg,
)
from vessel_common.errors import DataError

DAY = 1601424000.0  # 2020-09-30T00:00:00Z
HEADER = "utc_s,lat,lon,heading_deg,pitch_deg,roll_deg\n"


def to_epoch(utc_s: float) -> float:
    return DAY + utc_s


def write(tmp_path, body: str, header: str = HEADER):
    path = tmp_path / "own_ship.csv"
    path.write_text(header + body)
    return path


# ---------------------------------------------------------------------------------------------------------------
# own_ship.csv
# ---------------------------------------------------------------------------------------------------------------
def test_reads_positions_attitudes_and_compass_only_rows(tmp_path):
    path = write(tmp_path, "70578.00,32.70297,-117.234631,72.9,-1.5,4.8\n"
                           "70578.05,32.70297,-117.234631,360.0,,\n"
                           "70578.10,,,10.0,1.0,-2.0\n"
                           "70578.15,32.7,-117.2,,,\n")
    samples = read_own_ship_csv(path, to_epoch)
    assert [s.stamp for s in samples] == [to_epoch(t) for t in (70578.0, 70578.05, 70578.1, 70578.15)]
    assert samples[0] == OwnShipSample(to_epoch(70578.0), 32.70297, -117.234631, ShipAttitude(72.9, -1.5, 4.8))
    assert samples[1].attitude == ShipAttitude(0.0) and not samples[1].attitude.has_tilt
    assert samples[0].attitude.has_tilt
    assert math.isnan(samples[2].lat) and math.isnan(samples[2].lon) and not samples[2].has_position
    assert samples[3].attitude is None and samples[3].has_position


@pytest.mark.parametrize(("row", "column", "what"), [
    ("70578.05,32.7,-117.2,abc,1,1", "heading_deg", "expected a number"),
    ("70578.05,32.7,-117.2,nan,1,1", "heading_deg", "expected a finite number"),
    ("70578.05,32.7,-117.2,inf,1,1", "heading_deg", "expected a finite number"),
    ("70578.05,NaN,-117.2,10,1,1", "lat", "expected a finite number"),
    ("70578.05,95.0,-117.2,10,1,1", "lat", "not a WGS-84 position"),
    ("70578.05,32.7,-190.0,10,1,1", "lon", "not a WGS-84 position"),
    ("70578.05,32.7,,10,1,1", "lon", "must both be given or both empty"),
    ("70578.05,32.7,-117.2,10,1,", "roll_deg", "must both be given or both empty"),
    ("70578.05,32.7,-117.2,10,,2", "pitch_deg", "must both be given or both empty"),
    ("70578.05,32.7,-117.2,,1,2", "heading_deg", "pitch and roll need a heading"),
    ("70578.05,32.7,-117.2,10,91,2", "pitch_deg", "within -90..90"),
    ("70578.05,,,,,", "lat", "neither a position nor a heading"),
    (",32.7,-117.2,10,1,1", "utc_s", "expected the time"),
])
def test_a_bad_row_is_named_with_its_column_and_the_fix(tmp_path, row, column, what):
    path = write(tmp_path, f"70578.00,32.7,-117.2,10,1,1\n{row}\n")
    with pytest.raises(DataError) as error:
        read_own_ship_csv(path, to_epoch)
    message = str(error.value)
    assert f"{path}, row 3, column '{column}'" in message and what in message
    assert "correct or delete that row" in message and "\n" not in message


def test_a_repeated_row_is_refused(tmp_path):
    path = write(tmp_path, "70578.00,32.7,-117.2,10,1,1\n70578.05,32.7,-117.2,10,1,1\n70578.05,32.7,-117.2,11,1,1\n")
    with pytest.raises(DataError, match=r"row 4, column 'utc_s': the time 70578.05 repeats the previous row's; keep"):
        read_own_ship_csv(path, to_epoch)


def test_overlapping_runs_are_merged_in_time_order_keeping_the_first_of_a_time(tmp_path):
    """make_motion_set.py writes one window per video, +-10 s: the windows of adjacent videos overlap."""
    first = "".join(f"{70578 + 0.05 * k:.2f},32.7,-117.2,{k},1,1\n" for k in range(5))
    second = "".join(f"{70578.1 + 0.05 * k:.2f},32.7,-117.2,{100 + k},1,1\n" for k in range(5))
    samples = read_own_ship_csv(write(tmp_path, first + second), to_epoch)
    assert [round(s.stamp - DAY, 2) for s in samples] == [70578.0, 70578.05, 70578.1, 70578.15, 70578.2, 70578.25,
                                                          70578.3]
    assert [s.attitude.heading_deg for s in samples] == [0, 1, 2, 3, 4, 103, 104]


def test_missing_columns_empty_and_unreadable_files(tmp_path):
    with pytest.raises(DataError, match=r"missing column\(s\) pitch_deg, roll_deg"):
        read_own_ship_csv(write(tmp_path, "1,2,3,4\n", header="utc_s,lat,lon,heading_deg\n"), to_epoch)
    with pytest.raises(DataError, match="no data row under the header"):
        read_own_ship_csv(write(tmp_path, ""), to_epoch)
    with pytest.raises(DataError, match="cannot read"):
        read_own_ship_csv(tmp_path / "absent.csv", to_epoch)
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00\x81garbage")
    with pytest.raises(DataError, match="not a readable CSV"):
        read_own_ship_csv(tmp_path / "bin.csv", to_epoch)


def test_gaps_are_reported():
    samples = [OwnShipSample(t, 1.0, 2.0, ShipAttitude(0.0)) for t in (0.0, 0.05, 0.1, 2.1, 2.15, 5.0)]
    assert gaps(samples, 1.0) == [(0.1, 2.1), (2.15, 5.0)]
    assert gaps(samples, 5.0) == [] and gaps([], 1.0) == []


# ---------------------------------------------------------------------------------------------------------------
# Buffer
# ---------------------------------------------------------------------------------------------------------------
T0 = 1.6e9
TIME = 1e-5  # epoch seconds near 1.6e9 carry about 0.2 us: fractions of a step are that precise
ANGLE = 1e-4  # degrees: that time error times 100 degrees a second


def test_attitude_is_interpolated_and_the_heading_wraps_through_north():
    buffer = OwnShipBuffer(max_age_s=0.5)
    buffer.add_attitude(T0, ShipAttitude(350.0, 1.0, -2.0), 0.2)
    buffer.add_attitude(T0 + 0.2, ShipAttitude(10.0, 3.0, 2.0), 0.4)
    lookup = buffer.attitude_at(T0 + 0.05)
    assert lookup.ok and lookup.reason == ""
    assert lookup.attitude.heading_deg == pytest.approx(355.0, abs=ANGLE)
    assert lookup.attitude.pitch_deg == pytest.approx(1.5, abs=ANGLE)
    assert lookup.attitude.roll_deg == pytest.approx(-1.0, abs=ANGLE)
    assert lookup.sigma_deg == 0.4 and lookup.age_s == pytest.approx(0.05, abs=TIME)
    middle = buffer.attitude_at(T0 + 0.15)
    assert middle.attitude.heading_deg == pytest.approx(5.0, abs=ANGLE)
    assert middle.age_s == pytest.approx(0.05, abs=TIME)
    assert abs(wrap_deg(buffer.attitude_at(T0 + 0.1).attitude.heading_deg)) < ANGLE
    assert buffer.attitude_at(T0).attitude == ShipAttitude(350.0, 1.0, -2.0) and buffer.attitude_at(T0).age_s == 0


def test_heading_wraps_the_other_way_and_compass_only_stays_compass_only():
    buffer = OwnShipBuffer()
    buffer.add_attitude(T0, ShipAttitude(5.0))
    buffer.add_attitude(T0 + 0.1, ShipAttitude(345.0, 1.0, 1.0))
    lookup = buffer.attitude_at(T0 + 0.025)
    assert abs(wrap_deg(lookup.attitude.heading_deg)) < ANGLE and not lookup.attitude.has_tilt
    assert lookup.attitude.pitch_deg is None and lookup.attitude.roll_deg is None
    assert math.isnan(lookup.sigma_deg)


def test_lookups_are_refused_by_name():
    buffer = OwnShipBuffer(max_age_s=0.5)
    assert buffer.attitude_at(T0).reason == "missing" and not buffer.attitude_at(T0).ok
    assert buffer.position_at(T0).reason == "missing"
    buffer.add_attitude(T0, ShipAttitude(10.0, 0.0, 0.0))
    buffer.add_attitude(T0 + 0.1, ShipAttitude(20.0, 0.0, 0.0))
    buffer.add_attitude(T0 + 2.0, ShipAttitude(30.0, 0.0, 0.0))
    held = buffer.attitude_at(T0 + 2.4)  # beyond the newest, within max_age_s: held
    assert held.ok and held.attitude.heading_deg == 30.0 and held.age_s == pytest.approx(0.4, abs=TIME)
    stale = buffer.attitude_at(T0 + 2.6)
    assert (stale.ok, stale.reason, stale.attitude) == (False, "stale", None)
    assert stale.age_s == pytest.approx(0.6, abs=TIME)
    assert buffer.attitude_at(T0 - 0.4).ok and buffer.attitude_at(T0 - 0.6).reason == "early"
    gap = buffer.attitude_at(T0 + 0.2)  # between T0+0.1 and T0+2.0: 1.9 s apart, more than 2 max_age_s
    assert gap.reason == "gap" and gap.age_s == pytest.approx(0.1, abs=TIME)
    assert buffer.attitude_at(math.nan).reason == "bad_stamp"
    assert set(REASONS) >= {"missing", "stale", "early", "gap", "bad_stamp"}


def test_positions_interpolate_and_out_of_order_samples_go_in_order():
    buffer = OwnShipBuffer()
    buffer.add_fix(T0 + 0.2, 32.0002, -117.0002)
    buffer.add_fix(T0, 32.0, -117.0)
    buffer.add_fix(T0 + 0.1, 32.0001, -117.0001)  # late, inserted between
    lookup = buffer.position_at(T0 + 0.15)
    assert lookup.ok and lookup.lat == pytest.approx(32.00015, abs=TIME)
    assert lookup.lon == pytest.approx(-117.00015, abs=TIME)
    across = OwnShipBuffer()
    across.add_fix(T0, 0.0, 179.9)
    across.add_fix(T0 + 0.2, 0.0, -179.9)  # across the antimeridian: the short way
    lon = across.position_at(T0 + 0.1).lon
    assert abs(lon) <= 180.0 and abs(wrap_deg(lon - 180.0)) < TIME
    with pytest.raises(DataError, match="not a WGS-84 position"):
        buffer.add_fix(T0, math.nan, 0.0)
    with pytest.raises(DataError, match="not a finite, positive time"):
        buffer.add_attitude(math.inf, ShipAttitude(0.0))


def test_memory_is_bounded_by_the_horizon_and_a_step_back_starts_over():
    buffer = OwnShipBuffer(max_age_s=0.5, horizon_s=30.0)
    for k in range(20 * 120):  # two minutes at 20 Hz
        buffer.add_attitude(T0 + k * 0.05, ShipAttitude(k % 360))
        buffer.add_fix(T0 + k * 0.05, 32.0, -117.0)
    assert len(buffer) <= 2 * (30 * 20 + 1)
    assert buffer.attitude_at(T0 + 60.0).reason == "early" and buffer.attitude_at(T0 + 110.0).ok
    buffer.add_attitude(T0 + 100.0, ShipAttitude(1.0))  # out of order but within the horizon: kept
    assert buffer.resets == 0 and buffer.attitude_at(T0 + 100.0).attitude.heading_deg == 1.0
    buffer.add_attitude(T0, ShipAttitude(2.0))  # a replay restarted
    assert buffer.resets == 1 and buffer.attitude_at(T0).attitude.heading_deg == 2.0
    assert buffer.attitude_at(T0 + 110.0).reason == "stale"


def test_bad_buffer_settings_and_attitudes():
    with pytest.raises(DataError, match="max_age_s"):
        OwnShipBuffer(max_age_s=0.0)
    with pytest.raises(DataError, match="horizon_s"):
        OwnShipBuffer(max_age_s=1.0, horizon_s=1.0)
    with pytest.raises(DataError, match="only one of pitch and roll"):
        ShipAttitude(10.0, 1.0, None)
    with pytest.raises(DataError, match="heading"):
        ShipAttitude(math.nan)


# ---------------------------------------------------------------------------------------------------------------
# REP-103 orientation
# ---------------------------------------------------------------------------------------------------------------
def rotation_of_quaternion(x, y, z, w):
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def r_nb(heading, pitch, roll):
    """Rz(heading) Ry(pitch) Rx(roll), built here independently of the module."""
    h, p, r = np.radians([heading, pitch, roll])
    rz = np.array([[np.cos(h), -np.sin(h), 0], [np.sin(h), np.cos(h), 0], [0, 0, 1]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    return rz @ ry @ rx


def random_attitudes(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    return [ShipAttitude(float(h), float(p), float(r)) for h, p, r in
            zip(rng.uniform(0, 360, n), rng.uniform(-89, 89, n), rng.uniform(-180, 180, n), strict=True)]


def test_the_imu_orientation_is_rep103_of_the_ned_frd_attitude():
    """R_nb = ENU_FROM_NED . R_enu_flu . diag(1, -1, -1), with R_enu_flu from the quaternion."""
    for attitude in random_attitudes():
        q = quaternion_of_attitude(attitude)
        r_enu_flu = rotation_of_quaternion(*q)
        expected = r_nb(attitude.heading_deg, attitude.pitch_deg, attitude.roll_deg)
        np.testing.assert_allclose(ENU_FROM_NED @ r_enu_flu @ np.diag([1.0, -1.0, -1.0]), expected, atol=1e-12)
        np.testing.assert_allclose(ned_from_body(attitude), expected, atol=1e-12)


def test_simple_cases_read_as_rep103_says():
    """Heading 90 (east) is yaw 0 in ENU; bow up is negative pitch about the left axis; starboard down is +roll."""
    x, y, z, w = quaternion_of_attitude(ShipAttitude(90.0, 0.0, 0.0))
    assert (x, y, z, w) == pytest.approx((0.0, 0.0, 0.0, 1.0))
    forward = rotation_of_quaternion(*quaternion_of_attitude(ShipAttitude(0.0, 0.0, 0.0))) @ [1, 0, 0]
    assert forward == pytest.approx([0.0, 1.0, 0.0])  # north in ENU
    bow_up = rotation_of_quaternion(*quaternion_of_attitude(ShipAttitude(90.0, 10.0, 0.0))) @ [1, 0, 0]
    assert bow_up[2] == pytest.approx(math.sin(math.radians(10.0)))
    starboard_down = rotation_of_quaternion(*quaternion_of_attitude(ShipAttitude(90.0, 0.0, 10.0))) @ [0, -1, 0]
    assert starboard_down[2] == pytest.approx(-math.sin(math.radians(10.0)))  # the right side goes down


def test_quaternion_round_trip_at_many_attitudes():
    for attitude in random_attitudes(seed=1):
        q = quaternion_of_attitude(attitude)
        assert math.isclose(sum(v * v for v in q), 1.0, rel_tol=0, abs_tol=1e-12)
        back = attitude_of_quaternion(*q)
        assert 0.0 <= back.heading_deg < 360.0
        assert wrap_deg(back.heading_deg - attitude.heading_deg) == pytest.approx(0.0, abs=1e-8)
        assert back.pitch_deg == pytest.approx(attitude.pitch_deg, abs=1e-8)
        assert wrap_deg(back.roll_deg - attitude.roll_deg) == pytest.approx(0.0, abs=1e-8)
        again = quaternion_of_attitude(back)
        sign = 1.0 if np.dot(again, q) > 0 else -1.0
        np.testing.assert_allclose(np.multiply(sign, again), q, atol=1e-12)


def test_compass_only_is_the_heading_alone_with_roll_and_pitch_not_measured():
    compass = ShipAttitude(123.0)
    q = quaternion_of_attitude(compass)
    assert q == pytest.approx(quaternion_of_attitude(ShipAttitude(123.0, 0.0, 0.0)))
    covariance = orientation_covariance(compass, heading_sigma_deg=2.0)
    assert covariance[0] == covariance[4] == -1.0 and covariance[8] == pytest.approx(math.radians(2.0) ** 2)
    reading = attitude_reading(q, covariance)
    assert reading.ok and reading.attitude.heading_deg == pytest.approx(123.0) and not reading.attitude.has_tilt
    assert reading.sigma_deg == pytest.approx(2.0)
    unknown = attitude_reading(q, orientation_covariance(compass))
    assert unknown.ok and math.isnan(unknown.sigma_deg) and unknown.attitude.pitch_deg is None


def test_full_attitude_covariance_and_reading():
    attitude = ShipAttitude(200.0, -3.0, 7.0)
    covariance = orientation_covariance(attitude, 0.5, 2.0)
    assert covariance[0] == covariance[4] == pytest.approx(math.radians(0.5) ** 2)
    assert covariance[8] == pytest.approx(math.radians(2.0) ** 2)
    reading = attitude_reading(quaternion_of_attitude(attitude), covariance)
    assert reading.ok and reading.sigma_deg == pytest.approx(2.0)
    assert (reading.attitude.heading_deg, reading.attitude.pitch_deg, reading.attitude.roll_deg) == pytest.approx(
        (200.0, -3.0, 7.0))
    assert orientation_covariance(attitude) == [0.0] * 9  # unknown: all zero, as sensor_msgs/Imu documents


@pytest.mark.parametrize(("quaternion", "covariance", "reason"), [
    ((math.nan, 0.0, 0.0, 1.0), [0.0] * 9, "nan_quaternion"),
    ((0.0, 0.0, math.inf, 1.0), [0.0] * 9, "nan_quaternion"),
    ((0.0, 0.0, 0.0, 1.002), [0.0] * 9, "quaternion_not_unit"),
    ((0.0, 0.0, 0.0, 0.0), [0.0] * 9, "quaternion_not_unit"),
    ((0.0, 0.0, 0.0, 1.0), NO_ORIENTATION_COVARIANCE, "no_orientation"),
    ((0.0, 0.0, 0.0, 1.0), [-1.0] + [0.0] * 8, "no_orientation"),
    ((0.0, 0.0, 0.0, 1.0), [0.1, 0, 0, 0, 0.1, 0, 0, 0, -1.0], "no_heading"),
    ((0.0, 0.0, 0.0, 1.0), [0.1, 0, 0, 0, -1.0, 0, 0, 0, 0.1], "bad_covariance"),
    ((0.0, 0.0, 0.0, 1.0), [0.0] * 8 + [math.nan], "bad_covariance"),
    ((0.0, 0.0, 0.0, 1.0), [-0.5] + [0.0] * 8, "bad_covariance"),
])
def test_orientation_refusals(quaternion, covariance, reason):
    reading = attitude_reading(quaternion, covariance)
    assert not reading.ok and reading.reason == reason and reading.attitude is None
    assert reason in REASONS


def test_a_quaternion_nearly_unit_is_read():
    x, y, z, w = quaternion_of_attitude(ShipAttitude(45.0, 1.0, 2.0))
    assert attitude_reading((x * 1.0009, y * 1.0009, z * 1.0009, w * 1.0009), [0.0] * 9).ok


def test_position_readings():
    assert position_reading(0, 32.7, -117.2) == position_reading(2, 32.7, -117.2)
    assert position_reading(0, 32.7, -117.2).ok and position_reading(0, 32.7, -117.2).lat == 32.7
    assert position_reading(-1, 32.7, -117.2).reason == "no_fix"
    assert position_reading(0, math.nan, -117.2).reason == "nan_position"
    assert position_reading(0, 91.0, -117.2).reason == "position_out_of_range"
    assert position_reading(0, 32.0, 181.0).reason == "position_out_of_range"
