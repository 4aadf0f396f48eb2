"""The ``camera.*`` parameters of a node: the calibration ``calibrate`` writes, declared and turned into a camera.

Every node that maps pixels to the sea (detector, fuser, GPS publisher) declares them the same way; a node never
runs on another camera's values for a key the calibration file lacks.
"""

from __future__ import annotations

from rclpy.node import Node

from vessel_calib.calibration_parameters import (
    BUILTIN_CALIBRATION,
    CAMERA_PARAMETER_DESCRIPTIONS,
    DEFAULT_CAMERA_PARAMETERS,
    calibration_rows,
)
from vessel_calib.camera_model import CameraModel
from vessel_common.errors import CalibrationError
from vessel_common.node_parameters import declare_table
from vessel_common.parameter_table import ParameterTable

__all__ = ["BUILTIN_CALIBRATION", "CAMERA_PARAMETER_DESCRIPTIONS", "DEFAULT_CAMERA_PARAMETERS", "REQUIRED_CAMERA_KEYS",
           "declare_camera_model", "missing_calibration_keys"]
"""The rows and their defaults live in ``vessel_calib.calibration_parameters`` (ROS-free); importable here too."""

REQUIRED_CAMERA_KEYS = ("camera_lat", "camera_lon", "image_width", "image_height", "H", "K1", "center_x",
                        "center_y", "box_anchor")
"""The keys a calibration file must give: without any of them the node would run on another camera's values."""


def missing_calibration_keys(given: set[str], prefix: str = "camera") -> list[str]:
    """``REQUIRED_CAMERA_KEYS`` (as ``prefix.key``) that are not among the ``given`` parameter names."""
    return [f"{prefix}.{key}" for key in REQUIRED_CAMERA_KEYS if f"{prefix}.{key}" not in given]


def declare_camera_model(node: Node, prefix: str = "camera", required: bool = True):
    """Declare the ``camera.*`` calibration parameters and build the camera model from them.

    A calibration must be given (``--params-file`` of the file ``calibrate`` writes), with every key of
    ``REQUIRED_CAMERA_KEYS``: a file missing ``H`` must not run on another camera's homography. The paper's
    corrected calibration of the challenge camera is used only when asked for (``camera.builtin_calibration:
    true``, for tests and a first look at the challenge data). A calibration that cannot be used raises
    ``CalibrationError`` naming the key; nodes let it stop them at start (``run_node`` prints it as one line).
    ``required`` False: a node that can work without one (a detector on a camera not calibrated yet) gets None when
    no ``camera.*`` key at all is given; a partial calibration is refused all the same.
    """
    rows = calibration_rows(prefix)
    values = declare_table(node, ParameterTable(node.get_name(), "The camera's calibration (read-only)", rows))
    builtin = values[f"{prefix}.{BUILTIN_CALIBRATION}"]
    given = {name for name in getattr(node, "_parameter_overrides", {}) if name.startswith(f"{prefix}.")}
    missing = missing_calibration_keys(given, prefix)
    if missing and not builtin:
        if len(missing) == len(REQUIRED_CAMERA_KEYS):
            if not required:
                return None
            raise CalibrationError(
                f"{node.get_name()}: no calibration given: pass the calibration file `calibrate` writes, e.g. "
                f"--params-file config/aitas_camera.yaml (or -p {prefix}.{BUILTIN_CALIBRATION}:=true for the "
                "paper's calibration of the challenge camera)")
        raise CalibrationError(
            f"{node.get_name()}: the calibration lacks {', '.join(missing)}: write it again with `calibrate` (a "
            f"node never runs on another camera's values for missing keys)")
    return CameraModel.from_params({name[len(prefix) + 1:]: value for name, value in values.items()
                                    if name != f"{prefix}.{BUILTIN_CALIBRATION}"})
