"""Collision figures (range, bearing, CPA, TCPA and their deviations), the alert rule, the own ship's fixes.

Every expected figure is worked out by hand in the comments: r = vessel - own ship position, w = vessel - own ship
velocity, TCPA = -(r . w) / |w|^2, CPA = |r + w TCPA| (the present range when TCPA < 0).
"""
import math

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_track.collision import (
    OWN_SHIP_FIX_OUT_OF_ORDER,
    OWN_SHIP_MISSING,
    OWN_SHIP_STALE,
    AlertRule,
    Kinematics,
    OwnShipTrack,
    at_rest,
    collision_figures,
    range_bearing,
)


def test_a_vessel_crossing_ahead():
    # Own ship at rest at the origin; vessel at (-100, 50) going east at 5 m/s.
    # r = (-100, 50), w = (5, 0): r . w = -500, |w|^2 = 25 -> TCPA = 500 / 25 = 20 s.
    # r + 20 w = (-100 + 100, 50) = (0, 50) -> CPA = 50 m.
    # range = sqrt(100^2 + 50^2) = sqrt(12500) = 111.803 m; bearing = atan2(east -100, north 50) = -63.435 deg
    # -> 296.565 deg (west-north-west).
    f = collision_figures(at_rest(), Kinematics([-100.0, 50.0], [5.0, 0.0]))
    assert f.tcpa_s == pytest.approx(20.0)
    assert f.cpa_m == pytest.approx(50.0)
    assert f.range_m == pytest.approx(math.sqrt(12500.0))
    assert f.bearing_deg == pytest.approx(360.0 - math.degrees(math.atan2(100.0, 50.0)))
    assert f.bearing_deg == pytest.approx(296.565, abs=1e-3)
    # No covariance anywhere: every deviation is 0.
    assert (f.range_sigma_m, f.bearing_sigma_deg, f.cpa_sigma_m, f.tcpa_sigma_s) == (0.0, 0.0, 0.0, 0.0)
    # The alert: CPA 50 is not under 50; under 60 it is, with TCPA 20 s inside 120 s but not inside 15 s.
    assert not AlertRule(cpa_alert_m=50.0, tcpa_alert_s=120.0).in_alert(f)
    assert AlertRule(cpa_alert_m=60.0, tcpa_alert_s=120.0).in_alert(f)
    assert not AlertRule(cpa_alert_m=60.0, tcpa_alert_s=15.0).in_alert(f)


def test_a_vessel_moving_away_has_a_negative_tcpa_its_present_range_as_cpa_and_no_alert():
    # Vessel at (30, 40) going away from the own ship along its line of sight, w = (3, 4) m/s.
    # r . w = 90 + 160 = 250, |w|^2 = 25 -> TCPA = -10 s (the lines were closest 10 s ago, at the origin).
    # From now on the distance only grows: CPA = the present range = sqrt(30^2 + 40^2) = 50 m.
    f = collision_figures(at_rest(), Kinematics([30.0, 40.0], [3.0, 4.0]))
    assert f.tcpa_s == pytest.approx(-10.0)
    assert f.cpa_m == pytest.approx(50.0) and f.cpa_m == pytest.approx(f.range_m)
    assert not AlertRule(cpa_alert_m=1000.0, tcpa_alert_s=1000.0).in_alert(f)  # TCPA < 0: never an alert


def test_head_on_with_deviations_worked_by_hand():
    # Own ship at the origin going north at 5 m/s; vessel 1000 m north coming south at 5 m/s.
    # r = (0, 1000), w = (0, -10): r . w = -10000, |w|^2 = 100 -> TCPA = 100 s; r + 100 w = (0, 0) -> CPA = 0.
    own = Kinematics([0.0, 0.0], [0.0, 5.0])
    vessel = Kinematics([0.0, 1000.0], [0.0, -5.0], position_covariance=np.diag([4.0, 4.0]),
                        velocity_covariance=np.diag([0.01, 0.01]))
    f = collision_figures(own, vessel)
    assert f.tcpa_s == pytest.approx(100.0)
    assert f.cpa_m == pytest.approx(0.0, abs=1e-9)
    # CPA on an exact collision course: the signed miss distance across the track, along n = (1, 0) (normal to w).
    # Its gradient is n for r and TCPA n for w: var = 4 (east position) + 100^2 * 0.01 (east velocity) = 104.
    assert f.cpa_sigma_m == pytest.approx(math.sqrt(104.0))
    # TCPA = -r_n / w_n: d/dr_n = -1 / w_n = 0.1, d/dw_n = r_n / w_n^2 = 1000 / 100 = 10.
    # var = 0.1^2 * 4 + 10^2 * 0.01 = 0.04 + 1 = 1.04.
    assert f.tcpa_sigma_s == pytest.approx(math.sqrt(1.04))
    # Range 1000 m with 2 m deviation along the line of sight; bearing deviation = 2 m / 1000 m = 0.002 rad.
    assert f.range_sigma_m == pytest.approx(2.0)
    assert f.bearing_sigma_deg == pytest.approx(math.degrees(0.002))
    assert f.bearing_deg == pytest.approx(0.0)
    assert AlertRule().in_alert(f)  # CPA 0 < 50 m, TCPA 100 s inside 120 s
    assert not AlertRule(tcpa_alert_s=90.0).in_alert(f)


def test_parallel_at_the_same_speed_keeps_the_present_range():
    # Both going east at 3 m/s, the vessel 200 m north: w = (0, 0), so TCPA = 0 and CPA = range = 200 m (documented:
    # the closest point is now and stays so); the time has no deviation worth the name (infinite).
    own = Kinematics([0.0, 0.0], [3.0, 0.0])
    vessel = Kinematics([0.0, 200.0], [3.0, 0.0], position_covariance=np.diag([9.0, 16.0]))
    f = collision_figures(own, vessel)
    assert (f.tcpa_s, f.cpa_m, f.range_m) == (0.0, 200.0, 200.0)
    assert f.cpa_sigma_m == pytest.approx(4.0) and f.range_sigma_m == pytest.approx(4.0)  # north std sqrt(16)
    assert math.isinf(f.tcpa_sigma_s)
    assert not AlertRule().in_alert(f)
    # Keeping station 30 m off: CPA 30 < 50 with TCPA 0 in [0, 120]: an alert (it is that close now).
    assert AlertRule().in_alert(collision_figures(own, Kinematics([0.0, 30.0], [3.0, 0.0])))


def test_own_ship_moving_towards_a_vessel_at_rest():
    # Own ship at the origin going north at 5 m/s; a vessel at rest at (200, 200).
    # r = (200, 200), w = (0, -5): r . w = -1000, |w|^2 = 25 -> TCPA = 40 s; r + 40 w = (200, 0) -> CPA = 200 m.
    f = collision_figures(Kinematics([0.0, 0.0], [0.0, 5.0]), Kinematics([200.0, 200.0], [0.0, 0.0]))
    assert f.tcpa_s == pytest.approx(40.0) and f.cpa_m == pytest.approx(200.0)
    assert f.bearing_deg == pytest.approx(45.0)
    # Only relative motion counts: both displaced by (1000, -500) and both given +(2, 1) m/s, the same figures.
    g = collision_figures(Kinematics([1000.0, -500.0], [2.0, 6.0]), Kinematics([1200.0, -300.0], [2.0, 1.0]))
    assert (g.tcpa_s, g.cpa_m, g.range_m) == pytest.approx((40.0, 200.0, f.range_m))
    # Own ship at (10, 20) going (2, 1); vessel at (110, 20) going (-3, 1): r = (100, 0), w = (-5, 0)
    # -> TCPA = 500 / 25 = 20 s, CPA = |(100 - 100, 0)| = 0: a collision in 20 s.
    h = collision_figures(Kinematics([10.0, 20.0], [2.0, 1.0]), Kinematics([110.0, 20.0], [-3.0, 1.0]))
    assert h.tcpa_s == pytest.approx(20.0) and h.cpa_m == pytest.approx(0.0, abs=1e-9)
    assert h.bearing_deg == pytest.approx(90.0)


def _monte_carlo(own, vessel, n=200_000, seed=1):
    """CPA, TCPA, range, bearing of n draws of the eight inputs (both bodies independent, Gaussian)."""
    rng = np.random.default_rng(seed)
    own_draws = rng.multivariate_normal(np.r_[own.position, own.velocity], own.covariance, n)
    vessel_draws = rng.multivariate_normal(np.r_[vessel.position, vessel.velocity], vessel.covariance, n)
    r = vessel_draws[:, :2] - own_draws[:, :2]
    w = vessel_draws[:, 2:] - own_draws[:, 2:]
    tcpa = -np.sum(r * w, axis=1) / np.sum(w * w, axis=1)
    cpa = np.hypot(*(r + w * tcpa[:, None]).T)
    bearing = np.degrees(np.arctan2(r[:, 0], r[:, 1]))
    return cpa, tcpa, np.hypot(r[:, 0], r[:, 1]), bearing


def test_the_deviations_match_a_monte_carlo_estimate_within_a_few_percent():
    # The crossing case (CPA 50 m at TCPA 20 s), with a filter-like vessel covariance (position-velocity
    # correlated) and an own ship whose velocity is known to 0.1 m/s. Deviations small against the figures, so
    # first order should hold: within 3 % of 200 000 draws (their own sampling error is ~0.2 %).
    own = Kinematics([0.0, 0.0], [0.0, 0.0], velocity_covariance=np.diag([0.01, 0.01]))
    vessel = Kinematics([-100.0, 50.0], [5.0, 0.0], position_covariance=[[9.0, 2.0], [2.0, 4.0]],
                        velocity_covariance=[[0.04, 0.01], [0.01, 0.02]],
                        position_velocity_covariance=[[0.2, 0.05], [0.03, 0.1]])
    f = collision_figures(own, vessel)
    cpa, tcpa, rng, bearing = _monte_carlo(own, vessel)
    assert np.all(tcpa > 0)  # the whole cloud is ahead: the plain line formulas apply to every draw
    for figure, sigma, draws in ((f.cpa_m, f.cpa_sigma_m, cpa), (f.tcpa_s, f.tcpa_sigma_s, tcpa),
                                 (f.range_m, f.range_sigma_m, rng), (f.bearing_deg - 360.0, f.bearing_sigma_deg,
                                                                     bearing)):
        assert sigma == pytest.approx(np.std(draws), rel=0.03)
        assert figure == pytest.approx(np.mean(draws), abs=0.05 * sigma)
    assert f.cpa_sigma_m > 1.0 and f.tcpa_sigma_s > 0.1  # not a trivially small check


def test_a_cross_covariance_between_the_bodies_is_used():
    # Own ship and vessel position errors fully shared (one error moving both): the relative position is exact.
    # cov(r) = C_v + C_o - X - X^T with X = C (positions only): 4 + 4 - 4 - 4 = 0.
    both = np.diag([4.0, 4.0, 0.0, 0.0])
    own = Kinematics([0.0, 0.0], [0.0, 0.0], position_covariance=np.diag([4.0, 4.0]))
    vessel = Kinematics([0.0, 100.0], [1.0, 0.0], position_covariance=np.diag([4.0, 4.0]))
    assert collision_figures(own, vessel, cross_covariance=both).range_sigma_m == pytest.approx(0.0, abs=1e-9)
    assert collision_figures(own, vessel).range_sigma_m == pytest.approx(math.sqrt(8.0))  # independent: 4 + 4


def test_range_and_bearing_deviations_and_zero_range():
    # (300, 400): range 500; along the line of sight u = (0.6, 0.8), var = 0.36 * 25 + 0.64 * 100 = 73.
    # Across: (0.8, -0.6) / 500, var = (0.64 * 25 + 0.36 * 100) / 500^2 = 52 / 250000 rad^2.
    rng, rng_sigma, bearing, bearing_sigma = range_bearing([300.0, 400.0], np.diag([25.0, 100.0]))
    assert (rng, bearing) == pytest.approx((500.0, math.degrees(math.atan2(300.0, 400.0))))
    assert rng_sigma == pytest.approx(math.sqrt(73.0))
    assert bearing_sigma == pytest.approx(math.degrees(math.sqrt(52.0 / 250000.0)))
    # At zero range: no direction; the range's deviation is that of the worst axis (sqrt 9 = 3).
    rng, rng_sigma, bearing, bearing_sigma = range_bearing([0.0, 0.0], np.diag([4.0, 9.0]))
    assert (rng, rng_sigma) == (0.0, 3.0) and math.isnan(bearing) and math.isnan(bearing_sigma)


@pytest.mark.parametrize("bad", [
    dict(position=[math.nan, 0.0], velocity=[0.0, 0.0]),
    dict(position=[0.0, 0.0], velocity=[0.0, math.inf]),
    dict(position=[0.0, 0.0], velocity=[0.0, 0.0], position_covariance=[[math.nan, 0.0], [0.0, 1.0]]),
    dict(position=[0.0, 0.0], velocity=[0.0, 0.0], velocity_covariance=[[-1.0, 0.0], [0.0, 1.0]]),
    dict(position=[0.0, 0.0, 0.0], velocity=[0.0, 0.0]),
    dict(position=[0.0, 0.0], velocity=[0.0, 0.0], position_velocity_covariance=np.full((2, 2), math.nan)),
])
def test_nan_and_malformed_inputs_are_refused(bad):
    with pytest.raises(DataError, match="collision"):
        Kinematics(**bad)


def test_nan_is_refused_by_every_entry_point():
    with pytest.raises(DataError):
        range_bearing([math.nan, 1.0], np.eye(2))
    with pytest.raises(DataError):
        collision_figures(at_rest(), Kinematics([1.0, 1.0], [0.0, 0.0]), cross_covariance=np.full((4, 4), np.nan))
    with pytest.raises(DataError):
        OwnShipTrack().add(1.0, [math.nan, 0.0])
    with pytest.raises(DataError):
        AlertRule(cpa_alert_m=math.nan)


def test_the_conservative_alert_subtracts_k_deviations_of_the_cpa():
    # Crossing with CPA 60 m (vessel at (-100, 60) going east at 5 m/s: TCPA 20 s) and the east velocity known to
    # 0.25 m/s: dCPA/dw = TCPA * m / |m| = 20 * (0, 1), which the east velocity does not move; the north position
    # moves it one for one: north deviation 8 m -> CPA deviation 8 m.
    vessel = Kinematics([-100.0, 60.0], [5.0, 0.0], position_covariance=np.diag([1.0, 64.0]),
                        velocity_covariance=np.diag([0.0625, 0.0]))
    f = collision_figures(at_rest(), vessel)
    assert (f.cpa_m, f.cpa_sigma_m) == pytest.approx((60.0, 8.0))
    assert not AlertRule(cpa_alert_m=50.0).in_alert(f)                    # 60 >= 50
    assert not AlertRule(cpa_alert_m=50.0, cpa_sigma_k=1.0).in_alert(f)   # 60 - 8 = 52 >= 50
    assert AlertRule(cpa_alert_m=50.0, cpa_sigma_k=1.5).in_alert(f)       # 60 - 12 = 48 < 50
    with pytest.raises(DataError):
        AlertRule(cpa_sigma_k=-1.0)


def test_own_ship_interpolated_between_fixes_and_extrapolated_a_little():
    track = OwnShipTrack(max_age_s=0.5, velocity_window_s=5.0)
    assert track.at(100.0).problem == OWN_SHIP_MISSING
    # Fixes along x = 10 + 2 t (east at 2 m/s), y = -3 t (south at 3 m/s), one a second from t = 100.
    for t in range(100, 106):
        assert track.add(float(t), [10.0 + 2.0 * (t - 100), -3.0 * (t - 100)], np.eye(2)) == ""
    # Between the fixes at 102 and 103: 102.25 -> (10 + 4.5, -6.75), the nearest fix 0.25 s away.
    own = track.at(102.25)
    assert own.usable and own.age_s == pytest.approx(0.25)
    np.testing.assert_allclose(own.kinematics.position, [14.5, -6.75])
    np.testing.assert_allclose(own.kinematics.velocity, [2.0, -3.0])  # least squares on exact points: exact
    # 0.4 s past the newest (105): extrapolated with the velocity, (20 + 0.8, -15 - 1.2), still usable.
    own = track.at(105.4)
    assert own.usable
    np.testing.assert_allclose(own.kinematics.position, [20.8, -16.2])
    # 0.6 s past it: stale, but still dead-reckoned for the fuser's frame.
    own = track.at(105.6)
    assert own.problem == OWN_SHIP_STALE and not own.usable
    np.testing.assert_allclose(own.kinematics.position, [21.2, -16.8])


def test_own_ship_velocity_and_its_covariance_by_least_squares():
    # Fixes at t = 0..4 s (window 5 s holds them all), each with covariance 4 I.
    # mean t = 2, sum (t - 2)^2 = 4 + 1 + 0 + 1 + 4 = 10 -> velocity variance 4 / 10 = 0.4 per axis.
    track = OwnShipTrack(max_age_s=1.0, velocity_window_s=5.0)
    noise = [0.5, -0.5, 0.0, 0.5, -0.5]
    for t, e in zip(range(5), noise, strict=True):
        track.add(1000.0 + t, [3.0 * t + e, 0.0], 4.0 * np.eye(2))
    own = track.at(1004.0)
    # slope of 3 t + e: 3 + sum (t - 2) e / 10 = 3 + (-2 * 0.5 + -1 * -0.5 + 0 + 1 * 0.5 + 2 * -0.5) / 10 = 2.9
    np.testing.assert_allclose(own.kinematics.velocity, [2.9, 0.0])
    np.testing.assert_allclose(own.kinematics.velocity_covariance, 0.4 * np.eye(2))
    # One fix only: velocity zero, with zero covariance (as a fixed camera).
    single = OwnShipTrack()
    single.add(5.0, [1.0, 2.0])
    assert np.all(single.at(5.0).kinematics.velocity == 0.0) and single.at(5.0).usable


def test_own_ship_fixes_out_of_order_are_refused_and_a_replay_restart_starts_over():
    track = OwnShipTrack()
    assert track.add(10.0, [0.0, 0.0]) == ""
    assert track.add(10.0, [1.0, 0.0]) == OWN_SHIP_FIX_OUT_OF_ORDER
    assert track.add(9.5, [1.0, 0.0]) == OWN_SHIP_FIX_OUT_OF_ORDER
    assert len(track) == 1
    assert track.add(2.0, [5.0, 5.0]) == ""  # 8 s back: a replay restarted; the old fixes are dropped
    assert len(track) == 1
    np.testing.assert_allclose(track.at(2.0).kinematics.position, [5.0, 5.0])


def test_the_own_ship_buffer_is_bounded():
    track = OwnShipTrack(max_fixes=16)
    for k in range(100):
        track.add(float(k), [float(k), 0.0])
    assert len(track) == 16


def test_the_fuser_core_places_a_displaced_camera_s_measurements_in_the_fixed_frame():
    """A camera displaced from the calibration's position: the same boxes give the same figures, lat/lon shifted.

    100 m east and 50 m south: positions from the camera, distances and velocities as before, and lat/lon shifted by
    exactly that much (the filters' frame is fixed).
    """
    from vessel_calib import geodesy
    from vessel_tools.track.pipeline import screen_track_of
    from vessel_tools.track.simulation import challenge_camera, harbour_scenario
    from vessel_track.track_fuser import TrackFuser
    from vessel_track.tracker import MultiTargetTracker
    from vessel_track.tracker_config import TrackerConfig

    camera, offset = challenge_camera(), np.array([100.0, -50.0])
    fixed, moved, tracker = TrackFuser(camera), TrackFuser(camera), MultiTargetTracker(TrackerConfig())
    compared = 0
    for frame in harbour_scenario(seed=2).run().frames[:30]:
        screen = [screen_track_of(state) for state in tracker.update(frame.stamp, frame.boxes_xyxy, frame.scores)]
        for a, b in zip(fixed.update(frame.stamp, screen), moved.update(frame.stamp, screen, offset), strict=True):
            assert a.has_world == b.has_world and a.velocity_known == b.velocity_known
            if not a.has_world:
                continue
            np.testing.assert_allclose(b.relative_position, a.position, atol=1e-6)
            np.testing.assert_allclose(b.position, a.position + offset, atol=1e-6)
            np.testing.assert_allclose(b.velocity, a.velocity, atol=1e-9)
            assert b.distance_m == pytest.approx(a.distance_m, abs=1e-6)
            east, north = geodesy.gps_to_local(b.latitude, b.longitude, a.latitude, a.longitude)
            assert (east, north) == pytest.approx(tuple(offset), abs=0.01)
            compared += 1
    assert compared > 50
    with pytest.raises(DataError, match="camera_offset"):
        moved.update(frame.stamp + 1.0, screen, [math.nan, 0.0])
    assert moved.last_stamp == frame.stamp  # refused before the stamp was taken
