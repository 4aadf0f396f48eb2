"""The size prior: a box far larger than the vessel would be at its depth is less likely the vessel of interest."""

import math
from pathlib import Path

import numpy as np
import pytest

from vessel_calib.params import load_camera_yaml
from vessel_common.errors import ModelError, VesselError
from vessel_detect.detector import Detections, apply_size_prior
from vessel_detect.detector_params import build_detector, load_params_files, merge_values, size_prior
from vessel_detect.size_prior import SizePrior

REPO = Path(__file__).resolve().parents[3]
CAMERA = load_camera_yaml(REPO / "config/aitas_camera.yaml")
PRIOR = SizePrior(dimension="width", tolerance=0.3, strength=10.0)


def box_at(depth_m: float, width_factor: float, bearing_deg: float | None = None) -> list[float]:
    """A box whose reference point is the sea point ``depth_m`` ahead, ``width_factor`` times the vessel's width."""
    heading = math.radians(CAMERA.heading_deg if bearing_deg is None else bearing_deg)
    xw, yw = depth_m * math.sin(heading), depth_m * math.cos(heading)
    depth = float(CAMERA.depth_m(xw, yw))
    x, y = (float(v) for v in CAMERA.world_to_screen(xw, yw)[:2])
    a, b, c, d = PRIOR.size_model
    width, height = width_factor * (a / depth + b), c / depth + d
    top = y - CAMERA.box_anchor * height
    return [x - width / 2, top, x + width / 2, top + height]


def test_a_box_three_times_the_vessels_width_at_its_depth_loses_its_p_target_and_a_vessel_sized_one_keeps_it():
    boxes = np.array([box_at(100.0, 1.0), box_at(100.0, 3.0), box_at(300.0, 1.3), box_at(60.0, 0.4)])
    ratios = PRIOR.log_size_ratios(CAMERA, boxes)
    assert ratios == pytest.approx(np.log([1.0, 3.0, 1.3, 0.4]), abs=0.02)
    lowered = PRIOR.apply(np.array([0.8, 0.8, 0.8, 0.8]), ratios)
    assert lowered[[0, 2, 3]] == pytest.approx([0.8, 0.8, 0.8])  # within the tolerance, or smaller: unchanged
    expected = 1.0 / (1.0 + np.exp(-(np.log(4.0) - 10.0 * (np.log(3.0) - 0.3))))
    assert lowered[1] == pytest.approx(expected, rel=1e-3) and lowered[1] < 0.01


def test_a_box_whose_position_gives_no_depth_and_an_unknown_p_target_are_left_as_they_are():
    above_horizon = [600.0, 300.0, 900.0, 340.0]
    boxes = np.array([above_horizon, box_at(100.0, 3.0)])
    ratios = PRIOR.log_size_ratios(CAMERA, boxes)
    assert np.isnan(ratios[0]) and ratios[1] > 1.0
    out = PRIOR.apply(np.array([0.7, np.nan]), ratios)
    assert out[0] == 0.7 and np.isnan(out[1])
    assert PRIOR.log_size_ratios(CAMERA, np.zeros((0, 4))).shape == (0,)
    certain = PRIOR.apply(np.array([0.0, 1.0]), np.array([2.0, 2.0]))  # kept off 0 and 1: finite log-odds
    assert np.all(np.isfinite(certain)) and certain[0] <= 1e-9 and 0.5 < certain[1] < 1.0


def test_the_detector_applies_the_prior_in_the_calibrations_pixels():
    boxes = np.array([box_at(100.0, 1.0), box_at(100.0, 3.0)])
    detections = Detections(boxes / 2.0, np.full(2, 0.5), np.zeros(2, np.int64), ["vessel_of_interest"],
                            np.array([0.7, 0.8]))
    half_size_frame = apply_size_prior(detections, PRIOR, CAMERA, calibration_scale=(2.0, 2.0))
    assert half_size_frame.p_target[0] == pytest.approx(0.7) and half_size_frame.p_target[1] < 0.01
    assert half_size_frame.boxes_xyxy == pytest.approx(boxes / 2.0)  # the boxes stay in the frame's pixels
    assert detections.p_target.tolist() == [0.7, 0.8]  # the input is left as it was


@pytest.mark.parametrize(("key", "value", "message"), [
    ("size_prior.dimension", "area", "size_prior.dimension 'area' unknown: use one of none, width, height"),
    ("size_prior.strength", -1.0, "size_prior.strength must be >= 0"),
    ("size_prior.tolerance", float("nan"), "size_prior.tolerance must be >= 0"),
    ("size_prior.model", [0.0, 6.0, 2800.0, 0.0], "size_prior.model a and c must be > 0"),
    ("size_prior.model", [4800.0, 6.0], "size_prior.model must be four finite numbers"),
])
def test_a_wrong_size_prior_parameter_is_refused_naming_it(key, value, message):
    with pytest.raises(VesselError, match=message):
        size_prior(merge_values({key: value}))


def test_an_unquoted_off_is_refused_with_the_fix():
    with pytest.raises(VesselError, match="quote it"):
        merge_values({"size_prior": {"dimension": False}})
    with pytest.raises(VesselError, match="use one of none, width, height"):
        size_prior(merge_values({"size_prior.dimension": "off"}))


def test_the_prior_needs_the_calibration():
    values = merge_values({"size_prior.dimension": "width"})
    with pytest.raises(ModelError, match="needs the calibration"):
        build_detector(values, camera_model=None, model=object())


def test_nested_size_prior_blocks_of_two_files_merge_parameter_by_parameter(tmp_path):
    first, second = tmp_path / "a.yaml", tmp_path / "b.yaml"
    first.write_text("detector:\n  ros__parameters:\n    size_prior:\n      dimension: width\n      strength: 4.0\n")
    second.write_text("detector:\n  ros__parameters:\n    size_prior:\n      tolerance: 0.5\n")
    values, _ = load_params_files([first, second])
    prior = size_prior(values)
    assert (prior.dimension, prior.strength, prior.tolerance) == ("width", 4.0, 0.5)


def test_the_shipped_configuration_reads_the_fusers_distance_model():
    import yaml

    document = yaml.safe_load((REPO / "config/aitas.yaml").read_text())
    fuser = document["fuser"]["ros__parameters"]["distance_model"]
    values, _ = load_params_files([REPO / "config/aitas.yaml"])
    assert list(size_prior(values).size_model) == [fuser[k] for k in "abcd"]
