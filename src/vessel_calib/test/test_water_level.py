"""The tide: water-level tables, the pinhole geometry behind H, the camera at another water level, and the fit."""
import math

import numpy as np
import pytest

from vessel_calib.camera_model import CameraModel
from vessel_calib.water_level import WaterLevelTable, load_water_level
from vessel_common.errors import CalibrationError, DataError
from vessel_fixtures.calib_synthetic import CAMERA_LAT, CAMERA_LON, T0, offset_pinhole, tidal_pairs
from vessel_tools.calib.calibration import calibrate, evaluate


# --------------------------------------------------------------------------------------------------- the table
def test_iso_and_unix_tables_with_comments_interpolate_and_hold(tmp_path):
    iso = tmp_path / "tide.csv"
    iso.write_text("# predicted tide\nutc,level_m\n2020-09-30T19:30:00Z,0.97\n2020-09-30T20:00:00Z,0.80\n")
    table = WaterLevelTable.from_csv(iso)
    assert table.start_s == T0 and table.end_s == T0 + 1800
    assert table.level_at(T0 + 900) == pytest.approx(0.885)
    levels = table.level_at(np.array([T0 - 60, T0 + 1800 + 60]), max_hold_s=120)
    np.testing.assert_allclose(levels, [0.97, 0.80])
    assert math.isnan(table.level_at(T0 - 60))  # no hold asked for: unknown
    assert math.isnan(table.level_at(T0 + 1800 + 121, max_hold_s=120))
    unix = tmp_path / "tide_unix.csv"
    unix.write_text(f"utc_s,level_m\n{T0},0.97\n{T0 + 1800},0.80\n")
    assert WaterLevelTable.from_csv(unix).level_at(T0 + 900) == pytest.approx(0.885)


def test_a_noaa_download_reads_as_it_comes(tmp_path):
    """NOAA CO-OPS CSV (datagetter, units=metric, time_zone=gmt): 'Date Time, Prediction'."""
    noaa = tmp_path / "CO-OPS_9410166.csv"
    noaa.write_text("Date Time, Prediction\n2020-09-30 19:30,0.973\n2020-09-30 19:36,0.939\n")
    table = WaterLevelTable.from_csv(noaa)
    assert table.start_s == T0 and table.level_at(T0 + 360) == pytest.approx(0.939)


@pytest.mark.parametrize(("text", "needle"), [
    ("utc,height\n2020-09-30T19:30:00Z,1\n2020-09-30T19:36:00Z,1\n", "needs a time column"),
    ("utc,level_m\n2020-09-30T19:30:00Z,1\n", "at least two rows"),
    ("utc,level_m\n2020-09-30T19:36:00Z,1\n2020-09-30T19:30:00Z,1\n", "times must increase"),
    ("utc,level_m\n2020-09-30T19:30:00Z,1\nyesterday,1\n", "is not a time"),
    ("utc,level_m\n2020-09-30T19:30:00Z,1\n2020-09-30T19:36:00Z,high\n", "is not a number of metres"),
    ("utc,level_m\n2020-09-30T19:30:00Z,1\n2020-09-30T19:36:00Z,nan\n", "finite"),
    ("utc,level_m\n2020-09-30T19:30:00Z,1\n2020-09-30T19:36:00Z,3\n2020-09-30T19:42:00Z,99\n", "metres"),
    ("", "no header"),
])
def test_a_bad_table_is_refused_naming_the_problem(tmp_path, text, needle):
    path = tmp_path / "tide.csv"
    path.write_text(text)
    with pytest.raises(DataError, match=needle):
        WaterLevelTable.from_csv(path)


def test_a_missing_file_says_what_to_give_and_no_file_means_no_correction(tmp_path):
    with pytest.raises(DataError, match="does not exist.*NOAA"):
        load_water_level(tmp_path / "nowhere.csv")
    assert load_water_level("") is None and load_water_level(None) is None


# --------------------------------------------------------------------------------------------------- the camera
def test_the_pinhole_behind_h_is_recovered():
    geometry = offset_pinhole(2.6).pinhole()
    assert geometry.focal_px == pytest.approx(950.0, rel=1e-6)
    assert geometry.height_m == pytest.approx(2.6, rel=1e-6)
    assert geometry.nadir_xy == pytest.approx((1.5, -2.0), abs=1e-6)
    assert geometry.skew == pytest.approx(0.0, abs=1e-9) and geometry.aspect == pytest.approx(1.0)


def test_the_camera_at_another_water_level_is_the_pinhole_at_that_height():
    """Water 20 cm lower: the same camera 2.8 m up instead of 2.6; every method of the result agrees with it."""
    calibrated = offset_pinhole(2.6, water_level_m=0.9)
    truth = offset_pinhole(2.8)
    lower = calibrated.at_water_level(0.7)
    assert lower.height_m == pytest.approx(2.8) and lower.water_level_m == 0.7
    xs, ys = np.meshgrid(np.linspace(100, 1180, 12), np.linspace(440, 710, 12))
    got = lower.screen_to_world(xs.ravel(), ys.ravel())
    want = truth.screen_to_world(xs.ravel(), ys.ravel())
    assert got[2].all() and want[2].all()
    np.testing.assert_allclose(got[0], want[0], atol=1e-6)
    np.testing.assert_allclose(got[1], want[1], atol=1e-6)
    np.testing.assert_allclose(lower.depth_m(got[0], got[1]), truth.depth_m(want[0], want[1]), rtol=1e-9)
    np.testing.assert_allclose(lower.screen_to_world_jacobian(xs, ys), truth.screen_to_world_jacobian(xs, ys),
                               rtol=1e-6)
    assert lower.horizon_y(640.0) == pytest.approx(float(calibrated.horizon_y(640.0)))
    # the vectorised forms agree with the model at that level, and undo each other
    xw, yw, _ = calibrated.screen_to_world(xs.ravel(), ys.ravel())
    moved = calibrated.to_water_level(xw, yw, 0.7)
    np.testing.assert_allclose(moved, (got[0], got[1]), atol=1e-6)
    np.testing.assert_allclose(calibrated.from_water_level(*moved, 0.7), (xw, yw), atol=1e-9)
    # a lower sea puts everything farther away: ranges grow by 2.8 / 2.6
    assert np.median(np.hypot(got[0], got[1]) / np.hypot(xw, yw)) == pytest.approx(2.8 / 2.6, rel=0.02)
    assert calibrated.at_water_level(0.9) is calibrated


def test_a_camera_without_a_water_level_or_under_the_water_is_refused():
    with pytest.raises(CalibrationError, match="--water-level"):
        offset_pinhole(2.6).at_water_level(0.5)
    with pytest.raises(CalibrationError, match="under the water"):
        offset_pinhole(2.6, water_level_m=0.9).at_water_level(3.2)
    with pytest.raises(CalibrationError, match="height_m"):
        CameraModel(offset_pinhole(2.6).H, height_m=-1.0)
    with pytest.raises(CalibrationError, match="water_level_m"):
        CameraModel(offset_pinhole(2.6).H, water_level_m=math.inf)


def test_water_level_and_height_round_trip_through_the_parameters():
    camera = offset_pinhole(2.6, water_level_m=0.9)
    params = camera.to_params()
    assert params["water_level_m"] == 0.9 and params["height_m"] == pytest.approx(2.6)
    assert CameraModel.from_params(params) == CameraModel(camera.H, camera.K1, camera.center, camera.image_size,
                                                          camera.camera_lat, camera.camera_lon, camera.box_anchor,
                                                          water_level_m=0.9, height_m=params["height_m"])
    untided = offset_pinhole(2.6).to_params()
    assert "water_level_m" not in untided
    assert math.isnan(CameraModel.from_params({**untided, "water_level_m": math.nan}).water_level_m)
    with pytest.raises(CalibrationError, match="camera.water_level_m must be a number"):
        CameraModel.from_params({**untided, "water_level_m": "low"})


# --------------------------------------------------------------------------------------------------- the fit
def test_the_fit_with_the_tide_explains_pairs_a_fixed_h_cannot():
    screen, gps, levels = tidal_pairs()
    fixed = calibrate(screen, gps, CAMERA_LAT, CAMERA_LON, box_anchor=0.65)
    tided = calibrate(screen, gps, CAMERA_LAT, CAMERA_LON, box_anchor=0.65, water_levels=levels)
    print(f"back-projection m/100 m: fixed H {fixed.figures.backproj_per_100m:.3f}, with the tide "
          f"{tided.figures.backproj_per_100m:.4f}")
    assert tided.model.water_level_m == pytest.approx(levels.mean())
    assert tided.model.height_m == pytest.approx(2.6 + 0.9 - levels.mean(), abs=0.02)
    assert tided.figures.backproj_per_100m < 0.05 < fixed.figures.backproj_per_100m
    assert tided.figures.reproj_median_px < 0.05
    # evaluated without the levels, the tided model is as wrong as a fixed H
    assert evaluate(tided.model, screen, gps).backproj_per_100m > 10 * tided.figures.backproj_per_100m


def test_the_fit_refuses_pairs_without_a_water_level():
    screen, gps, levels = tidal_pairs(20)
    levels[3] = math.nan
    with pytest.raises(CalibrationError, match="no water level for 1 pair"):
        calibrate(screen, gps, CAMERA_LAT, CAMERA_LON, water_levels=levels)
    with pytest.raises(CalibrationError, match="19 water levels for 20 pairs"):
        calibrate(screen, gps, CAMERA_LAT, CAMERA_LON, water_levels=levels[:-1])
