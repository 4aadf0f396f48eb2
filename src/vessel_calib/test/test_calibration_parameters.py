"""The ``camera.*`` calibration rows (ROS-free)."""

import math

from vessel_calib.calibration_parameters import (
    CALIBRATION_ROWS,
    CAMERA_PARAMETER_DESCRIPTIONS,
    DEFAULT_CAMERA_PARAMETERS,
    calibration_rows,
)
from vessel_calib.camera_model import CameraModel


def test_the_rows_are_the_calibration_and_builtin_calibration_all_read_only():
    names = [row.name for row in CALIBRATION_ROWS]
    assert names[0] == "camera.builtin_calibration" and all(name.startswith("camera.") for name in names)
    assert [name[len("camera."):] for name in names[1:]] == list(DEFAULT_CAMERA_PARAMETERS)
    assert list(CAMERA_PARAMETER_DESCRIPTIONS) == list(DEFAULT_CAMERA_PARAMETERS)
    assert not any(row.live for row in CALIBRATION_ROWS)
    assert {row.type_name for row in CALIBRATION_ROWS} == {"bool", "float", "int", "float[]"}
    assert math.isnan(DEFAULT_CAMERA_PARAMETERS["height_m"]) and len(DEFAULT_CAMERA_PARAMETERS["H"]) == 9


def test_the_defaults_are_a_copy_and_make_the_challenge_camera():
    row = next(row for row in CALIBRATION_ROWS if row.name == "camera.H")
    assert DEFAULT_CAMERA_PARAMETERS["H"] == row.default and DEFAULT_CAMERA_PARAMETERS["H"] is not row.default
    camera = CameraModel.from_params(DEFAULT_CAMERA_PARAMETERS)
    assert camera is not None


def test_rows_under_another_prefix():
    rows = calibration_rows("left")
    assert [row.name for row in rows][:2] == ["left.builtin_calibration", "left.camera_lat"]
    assert calibration_rows() is CALIBRATION_ROWS
