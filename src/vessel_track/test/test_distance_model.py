"""Box-size distance model: depth convention, fit, inversion (ROS-free, synthetic camera)."""
from pathlib import Path

import numpy as np
import pytest

from vessel_calib.camera_model import CameraModel
from vessel_common.errors import DataError
from vessel_tools.track.distance_model_fit import fit_distance_model
from vessel_tools.track.simulation import CHALLENGE_H, CHALLENGE_K1, challenge_camera
from vessel_track.distance_model import (
    BoxSizeDistanceModel,
    box_cut_by_border,
    depth_of_world,
    depth_scale,
    ideal_y_of_depth,
)


def _world_points(n=80, seed=0):
    rng = np.random.default_rng(seed)
    r = rng.uniform(40, 600, n)
    b = np.radians(rng.uniform(50, 100, n))
    return np.column_stack([r * np.sin(b), r * np.cos(b)])


def _boxes(camera, world, model, noise_px=0.0, seed=0):
    rng = np.random.default_rng(seed)
    xs, ys, _ = camera.world_to_screen(world[:, 0], world[:, 1])
    w, h = model.size_of_depth(depth_of_world(camera, world[:, 0], world[:, 1]))
    w = w + rng.normal(0, noise_px, w.size)
    h = h + rng.normal(0, noise_px, h.size)
    return np.column_stack([xs - w / 2, ys - h / 2, xs + w / 2, ys + h / 2])


def test_depth_is_metric_and_independent_of_the_scale_of_h():
    cam = challenge_camera()
    scaled = CameraModel(np.array(CHALLENGE_H) * -7.3, CHALLENGE_K1, camera_lat=cam.camera_lat,
                         camera_lon=cam.camera_lon)
    world = _world_points()
    np.testing.assert_allclose(depth_of_world(cam, *world.T), depth_of_world(scaled, *world.T), rtol=1e-9)
    # Depth is (nearly) the distance along the viewing direction for a near-horizontal camera.
    heading = np.radians(cam.heading_deg)
    along = world @ np.array([np.sin(heading), np.cos(heading)])
    np.testing.assert_allclose(depth_of_world(cam, *world.T), along, rtol=0.08)
    assert depth_scale(cam) == pytest.approx(np.hypot(0.512, 0.144), rel=1e-3)


def test_inversion_gives_the_ideal_y_of_the_true_point():
    cam = challenge_camera()
    world = _world_points()
    xp, yp, _ = cam.world_to_ideal(*world.T)
    y = ideal_y_of_depth(cam, xp, depth_of_world(cam, *world.T))
    np.testing.assert_allclose(y, yp, atol=1e-6)
    assert np.isnan(ideal_y_of_depth(cam, 640.0, -5.0))
    model = BoxSizeDistanceModel(a=3000.0, b=5.0, c=1500.0, d=2.0)
    boxes = _boxes(cam, world, model)
    y_w, y_h = model.ideal_y_from_sizes(cam, xp, boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1])
    np.testing.assert_allclose(y_w, yp, atol=1e-6)
    np.testing.assert_allclose(y_h, yp, atol=1e-6)
    assert np.isnan(model.depth_from_width(4.0))  # not above b: no finite depth


def test_fit_recovers_constants_and_noise():
    cam = challenge_camera()
    truth = BoxSizeDistanceModel(a=3000.0, b=6.0, c=1400.0, d=1.5)
    world = _world_points(300, seed=2)
    boxes = _boxes(cam, world, truth, noise_px=1.5, seed=3)
    fit = fit_distance_model(cam, boxes, world, source="synthetic")
    assert fit.a == pytest.approx(3000.0, rel=0.05)
    assert fit.c == pytest.approx(1400.0, rel=0.05)
    assert fit.b == pytest.approx(6.0, abs=1.0)
    assert fit.sigma_width_px == pytest.approx(1.5, rel=0.25)
    sigma_y_w, sigma_y_h = fit.ideal_y_sigma(cam)
    assert 0 < sigma_y_w < sigma_y_h  # the same pixel noise on a smaller slope (c < a) is worse
    # Robust: a few wrong boxes do not move the fit.
    boxes[:10, 2] += 200.0
    robust = fit_distance_model(cam, boxes, world)
    assert robust.a == pytest.approx(3000.0, rel=0.08)


def test_boxes_cut_by_the_border_are_left_out():
    cut = box_cut_by_border([[0, 400, 50, 420], [600, 400, 700, 720], [600, 400, 700, 430]], (1280, 720))
    assert cut.tolist() == [[True, False], [False, True], [False, False]]


def test_params_round_trip_and_validation():
    model = BoxSizeDistanceModel(a=3000.0, b=6.0, c=1400.0, d=1.5, n_points=10, source="x")
    assert BoxSizeDistanceModel.from_params(model.to_params()) == model
    with pytest.raises(DataError):
        BoxSizeDistanceModel(a=-1.0)
    with pytest.raises(DataError):
        BoxSizeDistanceModel.from_params({"a": "many"})
    with pytest.raises(DataError):
        fit_distance_model(challenge_camera(), np.zeros((2, 4)), np.ones((2, 2)))


def test_fit_tool_keeps_the_files_other_fusion_settings(data_dir, tmp_path):
    """Refitting into a parameter file replaces the distance model and cue statistics only.

    The detector's ``anchor_offset`` and the weights mode stay; the cues are measured on hand boxes (offset 0),
    each at the water level of its instant from the file's water-level table, as the shipped ones were.
    """
    import yaml

    from vessel_tools.track.distance_model_fit import main
    from vessel_track.fuser_settings import load_fuser_settings

    repo = Path(__file__).resolve().parents[3]
    out = tmp_path / "params.yaml"
    tide = repo / "config" / "water_level_aitas.csv"
    out.write_text("fuser:\n  ros__parameters:\n    fusion: {anchor_offset: 0.05, weights_mode: paper}\n"
                   f"    water_level: {{file: {tide}}}\ntracker:\n  ros__parameters: {{min_hits: 2}}\n"
                   "detector:\n  ros__parameters:\n    size_prior:\n      dimension: width  # compared\n"
                   "      model: [1.0, 2.0, 3.0, 4.0]\n")
    calib = repo / "config" / "aitas_camera.yaml"
    assert main(["--data", str(data_dir), "--videos", "7-12", "--calib", str(calib), "--out", str(out)]) == 0
    settings = load_fuser_settings(out)
    assert settings.fusion.anchor_offset == 0.05 and settings.fusion.weights_mode == "paper"
    assert settings.distance_model.n_points == 66
    shipped = load_fuser_settings(repo / "config" / "aitas.yaml")
    # The refit runs iterative robust fits (calibration per left-out video, then the cues): it reproduces the
    # shipped values to that iteration's precision, not to the last bits, which differ between CPUs.
    np.testing.assert_allclose(settings.cue_stats.covariance, shipped.cue_stats.covariance, rtol=1e-4)
    assert yaml.safe_load(out.read_text())["tracker"]["ros__parameters"] == {"min_hits": 2}
    model = settings.distance_model  # the detector's size prior reads the same model, its other settings kept
    assert yaml.safe_load(out.read_text())["detector"]["ros__parameters"]["size_prior"] == {
        "dimension": "width", "model": [model.a, model.b, model.c, model.d]}
    assert "# compared" in out.read_text()


def test_the_detectors_size_prior_defaults_to_the_same_distance_model():
    """The detector cannot import the fuser's model (it sits below it); its default copy must not drift."""
    from vessel_detect.size_prior import DEFAULT_SIZE_MODEL

    model = BoxSizeDistanceModel()
    assert DEFAULT_SIZE_MODEL == (model.a, model.b, model.c, model.d)
