"""The issue's "Done when" figures on the shared AI Tracks at Sea data (skipped when it is absent).

Bounds sit slightly above the measured figures (in the comments) so a regression fails.
"""

from pathlib import Path

import numpy as np
import pytest

from vessel_calib.geodesy import haversine_m
from vessel_calib.params import load_camera_yaml
from vessel_calib.water_level import load_water_level
from vessel_tools.calib.calibration import DEFAULT_BOX_ANCHOR, calibrate, calibrate_from_labels, evaluate

SHIPPED = Path(__file__).resolve().parents[3] / "config" / "aitas_camera.yaml"
TIDE = Path(__file__).resolve().parents[3] / "config" / "water_level_aitas.csv"


@pytest.fixture(scope="module")
def validation(dataset):
    return dataset.calibration_pairs("13-17")


def test_paper_corrected_calibration(dataset, validation):
    model = dataset.camera_model()
    assert model.heading_deg == pytest.approx(76.5, abs=0.5)  # 76.48
    fig = evaluate(model, *validation)
    assert fig.pairs == 77
    assert fig.reproj_median_px < 10.0  # 6.34


def test_fit_on_all_training_pairs_at_box_centres(dataset, validation):
    screen, gps = dataset.calibration_pairs("7-12")
    result = calibrate(screen, gps, dataset.camera_lat, dataset.camera_lon)
    assert result.figures.pairs == 64
    assert result.model.heading_deg == pytest.approx(76.5, abs=1.0)  # 75.83
    fig = evaluate(result.model, *validation)
    assert fig.backproj_invalid == 0
    assert fig.backproj_median_m < 8.5  # 8.20
    assert fig.reproj_median_px < 5.0  # 4.39


@pytest.mark.parametrize("label_passes, median_m, p80_m", [("primary", 6.4, 12.8), ("all", 6.4, 12.9)])
def test_fit_at_the_default_box_anchor(dataset, label_passes, median_m, p80_m):
    """Boxes read 0.65 of the way down: 6.14 m median on 13-17 (8.20 / 7.35 at the centre), either label set."""
    anchor = DEFAULT_BOX_ANCHOR
    screen, gps = dataset.calibration_pairs("7-12", anchor=anchor, label_passes=label_passes)
    result = calibrate(screen, gps, dataset.camera_lat, dataset.camera_lon, box_anchor=anchor)
    assert result.model.box_anchor == anchor
    assert result.model.heading_deg == pytest.approx(76.5, abs=1.0)  # 75.83-75.84
    fig = evaluate(result.model, *dataset.calibration_pairs("13-17", anchor=anchor))
    assert fig.backproj_invalid == 0
    assert fig.backproj_median_m < median_m  # 6.14 both
    assert fig.backproj_p80_m < p80_m  # 12.39 primary, 12.54 all


def _leave_one_video_out_m_per_100m(dataset, anchor: float, water_level=None) -> float:
    """Training videos 7-12, each back-projected through a calibration fitted on the other five."""
    errors, distances = [], []
    for video in range(7, 13):
        others = [v for v in range(7, 13) if v != video]
        model = calibrate_from_labels(dataset, others, anchor, label_passes="all", water_level=water_level)
        screen, gps, stamps = dataset.calibration_pairs([video], anchor=anchor, label_passes="all", with_stamps=True)
        xw, yw, valid = model.screen_to_world(screen[:, 0], screen[:, 1])
        if water_level is not None:
            xw, yw = model.to_water_level(xw, yw, water_level.level_at(stamps))
        lat, lon = model.world_to_gps(xw, yw)
        errors += list(haversine_m(lat, lon, gps[:, 0], gps[:, 1])[valid])
        distances += list(haversine_m(gps[:, 0], gps[:, 1], dataset.camera_lat, dataset.camera_lon)[valid])
    e, d = np.array(errors), np.array(distances)
    return float(100 * np.sum(e * d) / np.sum(d * d))


def test_default_box_anchor_is_the_training_choice(dataset):
    """How DEFAULT_BOX_ANCHOR was chosen, on training videos only: 9.37 m/100 m at 0.5, 7.29 at 0.65, 7.55 at 0.7."""
    centre = _leave_one_video_out_m_per_100m(dataset, 0.5)
    chosen = _leave_one_video_out_m_per_100m(dataset, DEFAULT_BOX_ANCHOR)
    lower = _leave_one_video_out_m_per_100m(dataset, 0.75)
    assert chosen < 7.6 < 9.0 < centre
    assert chosen < lower


def test_the_tide_explains_why_later_videos_read_too_near(dataset):
    """The videos were recorded on a falling tide (0.34 m an hour at NOAA 9410166) under a camera 2.6 m up.

    With the water level of each pair's instant (config/water_level_aitas.csv, a prediction from NOAA's harmonic
    constants, not fitted to anything here), hand boxes back-projected per frame improve on the training videos
    left out one at a time (7.29 -> 6.60 m/100 m) and on the validation videos 13-16 (6.37 -> 5.84; median
    5.78 -> 4.26 m), and the validation range bias (-2.5 %) goes.
    """
    tide = load_water_level(TIDE)
    assert _leave_one_video_out_m_per_100m(dataset, DEFAULT_BOX_ANCHOR, tide) < 6.7  # 6.60 (7.29 without)
    results = {}
    for name, water_level in (("fixed", None), ("tide", tide)):
        model = calibrate_from_labels(dataset, range(7, 13), DEFAULT_BOX_ANCHOR, "all", water_level)
        screen, gps, stamps = dataset.calibration_pairs("13-16", anchor=DEFAULT_BOX_ANCHOR, with_stamps=True)
        results[name] = evaluate(model, screen, gps, None if water_level is None else water_level.level_at(stamps))
    assert results["tide"].backproj_per_100m < 5.95 < 6.3 < results["fixed"].backproj_per_100m  # 5.84, 6.37
    assert results["tide"].backproj_median_m < 4.5 < results["fixed"].backproj_median_m  # 4.26, 5.78


def test_shipped_calibration(dataset):
    if not SHIPPED.is_file():
        pytest.skip(f"{SHIPPED} not written yet")
    model = load_camera_yaml(SHIPPED)
    assert model.box_anchor == DEFAULT_BOX_ANCHOR
    assert model.heading_deg == pytest.approx(76.5, abs=1.0)
    assert model.height_m == pytest.approx(2.6, abs=0.1) and model.water_level_m == pytest.approx(0.895, abs=0.01)
    screen, gps, stamps = dataset.calibration_pairs("13-17", anchor=model.box_anchor, with_stamps=True)
    fig = evaluate(model, screen, gps, load_water_level(TIDE).level_at(stamps))
    assert fig.backproj_median_m < 4.5  # 4.23 (6.14 before the tide)
    assert fig.reproj_median_px < 4.2  # 3.81
