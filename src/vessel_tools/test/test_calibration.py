import numpy as np
import pytest

from vessel_calib import geodesy
from vessel_calib.camera_model import CameraModel
from vessel_common.errors import CalibrationError
from vessel_fixtures.calib_synthetic import CAMERA_LAT, CAMERA_LON, pinhole_camera, synthetic_pairs
from vessel_tools.calib.calibration import PAPER_OPTIONS, FitOptions, calibrate, evaluate, study_draws
from vessel_tools.calib.homography import normalized_dlt, scan_k1


def grid_error_m(fitted: CameraModel, truth: CameraModel) -> np.ndarray:
    """Back-projection disagreement (m) of two cameras over the visible sea out to 300 m."""
    xs, ys = np.meshgrid(np.linspace(60, 1220, 25), np.linspace(0, 715, 60))
    xw, yw, ok = truth.screen_to_world(xs.ravel(), ys.ravel())
    keep = ok & (np.hypot(xw, yw) < 300) & (np.hypot(xw, yw) > 10)
    fx, fy, fok = fitted.screen_to_world(xs.ravel()[keep], ys.ravel()[keep])
    assert fok.all()
    return np.hypot(fx - xw[keep], fy - yw[keep])


def test_dlt_recovers_exact_homography():
    truth = pinhole_camera(K1=0.0)
    screen, gps = synthetic_pairs(truth, 12, seed=1)
    world = np.column_stack(truth.gps_to_world(gps[:, 0], gps[:, 1]))
    H = normalized_dlt(screen, world)
    H_true = truth.H / np.linalg.norm(truth.H)
    assert min(np.abs(H - H_true).max(), np.abs(H + H_true).max()) < 1e-9


def test_k1_scan_finds_the_grid_value():
    truth = pinhole_camera(K1=-3.0e-7)
    screen, gps = synthetic_pairs(truth, 20, seed=2)
    world = np.column_stack(truth.gps_to_world(gps[:, 0], gps[:, 1]))
    k1_values = np.linspace(-6e-7, 2e-7, 81)  # contains -3e-7
    best, H, losses = scan_k1(screen, world, (640.0, 360.0), k1_values)
    assert best == pytest.approx(-3.0e-7, abs=1e-12)
    assert losses[np.argmin(losses)] < 1e-12


def test_fit_recovers_synthetic_camera_from_noiseless_pairs():
    truth = pinhole_camera(K1=-3.7e-7)  # off the scan grid: the refinement has to find it
    screen, gps = synthetic_pairs(truth, 15, seed=3)
    result = calibrate(screen, gps, CAMERA_LAT, CAMERA_LON)
    assert result.model.K1 == pytest.approx(-3.7e-7, rel=1e-6)
    assert result.figures.reproj_max_px < 1e-4
    assert result.figures.backproj_max_m < 1e-3
    assert np.max(grid_error_m(result.model, truth)) < 1e-2
    assert result.model.heading_deg == pytest.approx(truth.heading_deg, abs=1e-4)


def test_fit_with_label_noise_is_close():
    truth = pinhole_camera()
    screen, gps = synthetic_pairs(truth, 60, seed=4)
    noisy = screen + np.random.default_rng(5).normal(0, 1.0, screen.shape)
    result = calibrate(noisy, gps, CAMERA_LAT, CAMERA_LON)
    err = grid_error_m(result.model, truth)
    xs, ys = np.meshgrid(np.linspace(60, 1220, 25), np.linspace(0, 715, 60))
    assert np.median(err) < 2.0
    assert result.model.heading_deg == pytest.approx(truth.heading_deg, abs=0.5)
    assert 0.7 < result.figures.reproj_median_px < 2.0


def test_robust_loss_survives_an_outlier():
    truth = pinhole_camera()
    screen, gps = synthetic_pairs(truth, 40, seed=6)
    screen = screen + np.random.default_rng(7).normal(0, 0.7, screen.shape)
    bad = screen.copy()
    k = int(np.argmax(screen[:, 1]))  # a near pair, so it stays below the horizon when moved
    bad[k, 0] += 150.0
    plain = calibrate(bad, gps, CAMERA_LAT, CAMERA_LON, options=FitOptions(loss="linear"))
    robust = calibrate(bad, gps, CAMERA_LAT, CAMERA_LON, options=FitOptions(loss="soft_l1", loss_scale_px=2.0))
    clean = calibrate(screen, gps, CAMERA_LAT, CAMERA_LON)
    e_plain = np.median(grid_error_m(plain.model, truth))
    e_robust = np.median(grid_error_m(robust.model, truth))
    e_clean = np.median(grid_error_m(clean.model, truth))
    assert e_robust < 0.5 * e_plain
    assert e_robust < 3 * e_clean + 0.5
    # the outlier stands out in the robust fit's residuals
    assert np.argmax(np.hypot(*robust.reproj_px.T)) == k


def test_paper_protocol_runs_without_refinement():
    truth = pinhole_camera(K1=-3.0e-7)
    screen, gps = synthetic_pairs(truth, 11, seed=8)
    result = calibrate(screen, gps, CAMERA_LAT, CAMERA_LON, options=PAPER_OPTIONS)
    assert result.nfev == 0
    assert result.model.K1 == result.scan_k1


def test_fixed_k1_option():
    truth = pinhole_camera(K1=-2.0e-7)
    screen, gps = synthetic_pairs(truth, 15, seed=9)
    result = calibrate(screen, gps, CAMERA_LAT, CAMERA_LON, options=FitOptions(k1_fixed=-2.0e-7, fit_k1=False))
    assert result.model.K1 == -2.0e-7
    assert result.figures.reproj_max_px < 1e-4


def test_fitted_H_has_paper_sign_and_scale():  # noqa: N802
    truth = pinhole_camera()
    screen, gps = synthetic_pairs(truth, 15, seed=10)
    model = calibrate(screen, gps, CAMERA_LAT, CAMERA_LON).model
    assert np.hypot(model.H[2, 0], model.H[2, 1]) == pytest.approx(np.hypot(0.512, 0.144))
    xw, yw = model.gps_to_world(gps[:, 0], gps[:, 1])
    assert np.all(model.zp_of_world(xw, yw) < 0)
    assert np.all(model.depth_m(xw, yw) > 0)


# ----------------------------------------------------------------------------- bad input
@pytest.fixture
def good_pairs():
    return synthetic_pairs(pinhole_camera(), 12, seed=11)


def test_too_few_pairs(good_pairs):
    screen, gps = good_pairs
    with pytest.raises(CalibrationError, match="at least 4"):
        calibrate(screen[:3], gps[:3], CAMERA_LAT, CAMERA_LON)


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_non_finite_values(good_pairs, value):
    screen, gps = (a.copy() for a in good_pairs)
    screen[4, 1] = value
    with pytest.raises(CalibrationError, match="pair 4"):
        calibrate(screen, gps, CAMERA_LAT, CAMERA_LON)
    screen, gps = (a.copy() for a in good_pairs)
    gps[2, 0] = value
    with pytest.raises(CalibrationError, match="pair 2"):
        calibrate(screen, gps, CAMERA_LAT, CAMERA_LON)


def test_duplicates(good_pairs):
    screen, gps = (a.copy() for a in good_pairs)
    screen[5] = screen[2]
    with pytest.raises(CalibrationError, match="pairs 2 and 5 have the same screen point"):
        calibrate(screen, gps, CAMERA_LAT, CAMERA_LON)
    screen, gps = (a.copy() for a in good_pairs)
    gps[7] = gps[1]
    with pytest.raises(CalibrationError, match="pairs 1 and 7 have the same GPS point"):
        calibrate(screen, gps, CAMERA_LAT, CAMERA_LON)


def test_collinear_pairs():
    cam = pinhole_camera()
    t = np.linspace(0, 1, 8)
    xw, yw = 80 + 100 * t, 20 + 30 * t  # one straight line on the sea
    xs, ys, ok = cam.world_to_screen(xw, yw)
    assert ok.all()
    lat, lon = cam.world_to_gps(xw, yw)
    with pytest.raises(CalibrationError, match="collinear"):
        calibrate(np.column_stack([xs, ys]), np.column_stack([lat, lon]), CAMERA_LAT, CAMERA_LON)


def test_degenerate_layout_three_of_four_collinear():
    cam = pinhole_camera()
    xw = np.array([50.0, 100.0, 150.0, 90.0])
    yw = np.array([10.0, 20.0, 30.0, 60.0])
    xs, ys, ok = cam.world_to_screen(xw, yw)
    lat, lon = cam.world_to_gps(xw, yw)
    with pytest.raises(CalibrationError, match="but pair 3 lie on one line"):
        calibrate(np.column_stack([xs, ys]), np.column_stack([lat, lon]), CAMERA_LAT, CAMERA_LON)


def test_pair_above_the_fitted_horizon(good_pairs):
    screen, gps = (a.copy() for a in good_pairs)
    screen = np.vstack([screen, [640.0, 150.0]])  # a label in the sky ...
    gps = np.vstack([gps, geodesy.local_to_gps(300.0, 60.0, CAMERA_LAT, CAMERA_LON)])  # ... of a sea position
    with pytest.raises(CalibrationError, match="above the fitted horizon"):
        calibrate(screen, gps, CAMERA_LAT, CAMERA_LON)


@pytest.mark.parametrize("lat, lon", [(95.0, 0.0), (32.7, 200.0), (np.nan, -117.2), (0.0, 0.0)])
def test_invalid_camera_position(good_pairs, lat, lon):
    with pytest.raises(CalibrationError, match="camera position"):
        calibrate(*good_pairs, lat, lon)


def test_wrong_camera_position_or_swapped_lat_lon(good_pairs):
    screen, gps = good_pairs
    with pytest.raises(CalibrationError, match="km from the camera"):
        calibrate(screen, gps, 40.0, -100.0)
    with pytest.raises(CalibrationError, match=r"pair 0 GPS position: latitude -117.2\d* is outside .* swapped"):
        calibrate(screen, gps[:, ::-1], CAMERA_LAT, CAMERA_LON)


def test_screen_points_outside_image(good_pairs):
    screen, gps = (a.copy() for a in good_pairs)
    screen *= 2.0
    with pytest.raises(CalibrationError, match="outside the 1280x720 image"):
        calibrate(screen, gps, CAMERA_LAT, CAMERA_LON)


def test_bad_options(good_pairs):
    with pytest.raises(CalibrationError, match="loss"):
        calibrate(*good_pairs, CAMERA_LAT, CAMERA_LON, options=FitOptions(loss="l2"))
    with pytest.raises(CalibrationError, match="scale"):
        calibrate(*good_pairs, CAMERA_LAT, CAMERA_LON, options=FitOptions(loss_scale_px=0.0))


def test_evaluate_counts_points_above_horizon():
    cam = pinhole_camera()
    screen, gps = synthetic_pairs(cam, 10, seed=12)
    screen[0] = (640.0, 100.0)
    fig = evaluate(cam, screen, gps)
    assert fig.backproj_invalid == 1 and fig.pairs == 10
    assert fig.backproj_median_m < 1e-3


def test_study_draws_spread():
    truth = pinhole_camera()
    screen, gps = synthetic_pairs(truth, 40, seed=13)
    noisy = screen + np.random.default_rng(14).normal(0, 1.0, screen.shape)
    vs, vg = synthetic_pairs(truth, 30, seed=15)
    study = study_draws(noisy, gps, vs, vg, CAMERA_LAT, CAMERA_LON, n_pairs=11, draws=4, seed=1)
    assert study.draws == 4 and len(study.val_median_m) + study.failed == 4
    assert "4 draws of 11 training pairs" in "\n".join(study.lines())
