import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from vessel_calib import geodesy
from vessel_calib.camera_model import CameraModel
from vessel_common.errors import CalibrationError
from vessel_fixtures.calib_synthetic import CAMERA_LAT, CAMERA_LON, pinhole_h

PAPER_H = [[-441.0, 379.0, -1000.0], [-217.0, -56.5, -548.0], [-0.512, -0.144, 1.0]]
PAPER_K1 = -4.053e-7


def paper_camera():
    return CameraModel(PAPER_H, PAPER_K1, camera_lat=CAMERA_LAT, camera_lon=CAMERA_LON)


def test_paper_camera_heading_and_horizon():
    cam = paper_camera()
    assert cam.heading_deg == pytest.approx(76.5, abs=0.1)
    # the paper: the horizon is about y = 418 px; it bends slightly with the lens
    assert 410 < float(cam.horizon_y(640.0)) < 430
    xp, yp, zp = cam.world_to_ideal(100.0, 20.0)
    assert zp < 0  # the sign of z_p: negative in front


def test_distortion_convention_matches_readme():
    cam = paper_camera()
    xs, ys = cam.distort(1000.0, 500.0)
    r2 = 360.0 ** 2 + 140.0 ** 2
    assert xs == pytest.approx(640 + 360 * (1 + PAPER_K1 * r2))
    assert ys == pytest.approx(360 + 140 * (1 + PAPER_K1 * r2))


def test_undistort_inverts_distort_to_micro_pixels():
    cam = paper_camera()
    rng = np.random.default_rng(1)
    xs = rng.uniform(0, 1280, 5000)
    ys = rng.uniform(0, 720, 5000)
    xp, yp = cam.undistort(xs, ys)
    ok = np.isfinite(xp)
    r = np.hypot(xs - 640, ys - 360)
    assert np.all(ok == (r <= cam.max_screen_radius))
    xs2, ys2 = cam.distort(xp[ok], yp[ok])
    assert np.max(np.hypot(xs2 - xs[ok], ys2 - ys[ok])) < 1e-6


def test_screen_points_beyond_the_lens_fold_are_invalid_not_garbage():
    cam = paper_camera()
    assert 600 < cam.max_screen_radius < 610  # sqrt(-1/(3 K1)) * 2/3
    xw, yw, valid = cam.screen_to_world(np.array([2.0, 1278.0]), np.array([500.0, 500.0]))
    assert not valid.any() and np.isnan(xw).all() and np.isnan(yw).all()
    # ideal points beyond the fold would fold back into the image: reported as not in front
    xs, ys, in_front = cam.world_to_screen(np.array([30.0]), np.array([-60.0]))
    xp, yp, zp = cam.world_to_ideal(30.0, -60.0)
    if zp < 0 and math.hypot(xp - 640, yp - 360) > math.sqrt(-1 / (3 * PAPER_K1)):
        assert not in_front[0] and np.isnan(xs[0])


def test_horizon_points_and_above_are_invalid():
    cam = paper_camera()
    xs = np.linspace(100, 1180, 50)
    yh = cam.horizon_y(xs)
    assert np.isfinite(yh).all()
    for dy, expect in ((0.0, False), (-0.5, False), (-100.0, False), (1.0, True)):
        xw, yw, valid = cam.screen_to_world(xs, yh + dy)
        assert (valid == expect).all(), dy
        if not expect:
            assert np.isnan(xw).all()
    # just below the horizon is far away, and distance falls off going down
    xw, yw, _ = cam.screen_to_world(np.full(3, 640.0), float(yh[25]) + np.array([1.0, 10.0, 100.0]))
    d = np.hypot(xw, yw)
    assert d[0] > d[1] > d[2] > 0


def test_world_behind_camera_is_not_in_front():
    cam = paper_camera()
    # heading 76.5: a point 200 m west-south-west is behind
    xs, ys, in_front = cam.world_to_screen(np.array([-200.0, 200.0]), np.array([-50.0, 50.0]))
    assert list(in_front) == [False, True]
    assert np.isnan(xs[0]) and np.isfinite(xs[1])


def test_gps_round_trip_paper_camera():
    cam = paper_camera()
    lat, lon = geodesy.local_to_gps(np.array([150.0, 60.0, 900.0]), np.array([40.0, 5.0, 200.0]),
                                    CAMERA_LAT, CAMERA_LON)
    xs, ys, ok = cam.gps_to_screen(lat, lon)
    assert ok.all()
    lat2, lon2, valid = cam.screen_to_gps(xs, ys)
    assert valid.all()
    assert np.max(geodesy.haversine_m(lat, lon, lat2, lon2)) < 1e-3


def test_jacobian_matches_finite_differences():
    cam = paper_camera()
    xs = np.array([300.0, 640.0, 900.0])
    ys = np.array([450.0, 600.0, 430.0])
    J = cam.screen_to_world_jacobian(xs, ys)
    assert J.shape == (3, 2, 2)
    eps = 1e-4
    for k, (dx, dy) in enumerate(((eps, 0.0), (0.0, eps))):
        xw1, yw1, _ = cam.screen_to_world(xs + dx, ys + dy)
        xw0, yw0, _ = cam.screen_to_world(xs - dx, ys - dy)
        num = np.stack([(xw1 - xw0) / (2 * eps), (yw1 - yw0) / (2 * eps)], axis=-1)
        np.testing.assert_allclose(J[:, :, k], num, rtol=1e-5, atol=1e-6)
    Jbad = cam.screen_to_world_jacobian(640.0, 200.0)
    assert np.isnan(Jbad).all()


def test_scalar_and_shaped_inputs():
    cam = paper_camera()
    xw, yw, valid = cam.screen_to_world(640.0, 500.0)
    assert np.shape(xw) == () and bool(valid)
    xs = np.full((2, 3), 640.0)
    ys = np.full((2, 3), 500.0)
    assert cam.screen_to_world(xs, ys)[0].shape == (2, 3)
    assert cam.world_to_screen(xs * 0 + 100, ys * 0 + 30)[0].shape == (2, 3)


def test_negated_h_is_normalised_to_the_same_model():
    a = paper_camera()
    b = CameraModel(-np.array(PAPER_H), PAPER_K1, camera_lat=CAMERA_LAT, camera_lon=CAMERA_LON)
    np.testing.assert_array_equal(a.H, b.H)
    assert b.world_to_ideal(100.0, 20.0)[2] < 0


def test_model_is_immutable():
    cam = paper_camera()
    with pytest.raises(ValueError):
        cam.H[0, 0] = 1.0
    with pytest.raises(AttributeError):
        cam.K1 = 0.0


@pytest.mark.parametrize("H, match", [
    (np.full((3, 3), np.nan), "NaN"),
    (np.zeros((3, 3)), "zeros"),
    ([[1, 2, 3], [2, 4, 6], [0, 0, 1]], "singular"),
    ([1, 2, 3], "3x3"),
])
def test_constructor_rejects_bad_h(H, match):
    with pytest.raises(CalibrationError, match=match):
        CameraModel(H, 0.0)


@pytest.mark.parametrize("K1", [1e-3, -5e-6, float("nan"), "big"])
def test_constructor_rejects_absurd_k1(K1):
    with pytest.raises(CalibrationError, match="K1"):
        CameraModel(PAPER_H, K1)


def test_constructor_rejects_bad_geometry_and_position():
    with pytest.raises(CalibrationError, match="image_size"):
        CameraModel(PAPER_H, PAPER_K1, image_size=(1280.5, 720))
    with pytest.raises(CalibrationError, match="centre"):
        CameraModel(PAPER_H, PAPER_K1, center=(5000, 360))
    with pytest.raises(CalibrationError, match="latitude"):
        CameraModel(PAPER_H, PAPER_K1, camera_lat=132.0, camera_lon=10.0)
    with pytest.raises(CalibrationError, match="both"):
        CameraModel(PAPER_H, PAPER_K1, camera_lat=32.0)
    with pytest.raises(CalibrationError, match="camera position"):
        CameraModel(PAPER_H, PAPER_K1).gps_to_screen(32.7, -117.2)


def test_params_round_trip_and_type_checks():
    cam = paper_camera()
    params = cam.to_params()
    assert set(params) >= {"camera_lat", "camera_lon", "image_width", "image_height", "H", "K1", "center_x",
                           "center_y", "heading_deg"}
    assert CameraModel.from_params(params) == cam
    bad = dict(params, H=params["H"][:8])
    with pytest.raises(CalibrationError, match="H"):
        CameraModel.from_params(bad)
    bad = dict(params, K1="-4e-7")
    with pytest.raises(CalibrationError, match="K1"):
        CameraModel.from_params(bad)
    bad = dict(params, image_width=True)
    with pytest.raises(CalibrationError, match="image_width"):
        CameraModel.from_params(bad)
    bad = {k: v for k, v in params.items() if k != "center_y"}
    with pytest.raises(CalibrationError, match="center_y"):
        CameraModel.from_params(bad)


def test_box_anchor_is_part_of_the_calibration():
    cam = paper_camera()
    assert cam.box_anchor == 0.5
    params = cam.to_params()
    legacy = {k: v for k, v in params.items() if k != "box_anchor"}
    assert CameraModel.from_params(legacy).box_anchor == 0.5  # files fitted before box_anchor: box centres
    lower = CameraModel.from_params(dict(params, box_anchor=0.65))
    assert lower.box_anchor == 0.65 and lower != cam
    assert CameraModel.from_params(lower.to_params()) == lower
    for bad in (1.5, -0.1, "0.6", float("nan"), True):
        with pytest.raises(CalibrationError, match="box_anchor"):
            CameraModel.from_params(dict(params, box_anchor=bad))


def test_box_reference_points_read_the_box_at_the_anchor():
    cam = CameraModel.from_params(dict(paper_camera().to_params(), box_anchor=0.65))
    boxes = np.array([[100.0, 400.0, 140.0, 420.0], [0.0, 0.0, 10.0, 100.0]])
    np.testing.assert_allclose(cam.box_reference_points(boxes), [[120.0, 413.0], [5.0, 65.0]])
    np.testing.assert_allclose(cam.box_reference_points(boxes, 0.05), [[120.0, 414.0], [5.0, 70.0]])
    # an offset never leaves the box
    np.testing.assert_allclose(cam.box_reference_points(boxes, 0.9)[:, 1], [420.0, 100.0])
    np.testing.assert_allclose(cam.box_reference_points(boxes, -0.9)[:, 1], [400.0, 0.0])


def test_pinhole_heading_is_exact():
    for heading in (0.0, 45.0, 76.5, 200.0, 359.0):
        cam = CameraModel(pinhole_h(8.0, heading, 2.0, 1000.0, 0.0), 0.0)
        assert cam.heading_deg == pytest.approx(heading % 360.0, abs=1e-6)


cameras = st.builds(
    lambda h, psi, tilt, f, roll, k1: CameraModel(pinhole_h(h, psi, tilt, f, roll), k1, camera_lat=CAMERA_LAT,
                                                  camera_lon=CAMERA_LON),
    st.floats(2.0, 40.0), st.floats(0.0, 359.9), st.floats(-5.0, 25.0), st.floats(500.0, 2500.0),
    st.floats(-4.0, 4.0), st.floats(-6e-7, 3e-7))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cameras, st.integers(0, 2 ** 31 - 1))
def test_property_gps_screen_gps_round_trip(cam, seed):
    rng = np.random.default_rng(seed)
    xs = rng.uniform(0, 1280, 400)
    ys = rng.uniform(0, 720, 400)
    xw, yw, valid = cam.screen_to_world(xs, ys)
    near = valid & (np.hypot(xw, yw) < 3000.0)
    assume(near.sum() >= 5)
    lat, lon = cam.world_to_gps(xw[near], yw[near])
    xs2, ys2, in_front = cam.gps_to_screen(lat, lon)
    assert in_front.all()
    assert np.max(np.hypot(xs2 - xs[near], ys2 - ys[near])) < 1e-4
    lat2, lon2, valid2 = cam.screen_to_gps(xs2, ys2)
    assert valid2.all()
    assert np.max(geodesy.haversine_m(lat, lon, lat2, lon2)) < 1e-3
    # the invalid ones are invalid for a reason: above the horizon or beyond the lens fold
    bad = ~valid
    if bad.any():
        yh = cam.horizon_y(xs[bad])
        off_lens = np.hypot(xs[bad] - 640, ys[bad] - 360) > cam.max_screen_radius
        above = np.isfinite(yh) & (ys[bad] <= yh + 1e-6)
        assert np.all(off_lens | above | ~np.isfinite(yh))


@settings(max_examples=40, deadline=None)
@given(cameras)
def test_property_horizon_flagged_and_zp_sign(cam):
    xs = np.linspace(0, 1280, 41)
    yh = cam.horizon_y(xs)
    on = np.isfinite(yh)
    assume(on.any())
    assert not cam.screen_to_world(xs[on], yh[on])[2].any()
    assert not cam.screen_to_world(xs[on], yh[on] - 2.0)[2].any()
    xw, yw, valid = cam.screen_to_world(xs[on], yh[on] + 2.0)
    assert np.all(cam.zp_of_world(xw[valid], yw[valid]) < 0)
