"""The ``camera.*`` parameters of a node: the calibration ``calibrate`` writes, declared and turned into a camera.

Every node that maps pixels to the sea (detector, fuser, GPS publisher) declares them the same way; a node never
runs on another camera's values for a key the calibration file lacks.
"""

from __future__ import annotations

import math
from typing import Any

from rclpy.node import Node

from vessel_calib.camera_model import CameraModel
from vessel_common.errors import CalibrationError
from vessel_common.node_support import declare_parameter

CAMERA_PARAMETER_DESCRIPTIONS: dict[str, str] = {
    "camera_lat": "Camera latitude, WGS-84 degrees.",
    "camera_lon": "Camera longitude, WGS-84 degrees.",
    "image_width": "Image width in pixels the calibration was made for.",
    "image_height": "Image height in pixels the calibration was made for.",
    "H": "Homography, 9 numbers row-major: z_p (x_p, y_p, 1) = H (x_w, y_w, 1), world in metres east/north.",
    "K1": "Radial distortion term about the centre: x_s = x_c + (x_p - x_c)(1 + K1 r_p^2).",
    "center_x": "Distortion centre x, pixels.",
    "center_y": "Distortion centre y, pixels.",
    "heading_deg": "Camera heading implied by H, degrees from north (informational; checked against H).",
    "box_anchor": "Point of a vessel's box that H maps to its position: horizontal centre, this share of the way "
                  "down (0 top, 0.5 centre as in the paper, 1 bottom); written by calibrate.",
    "water_level_m": "Water level (in the datum of the fuser's water_level.file) that H belongs to; NaN: calibrated "
                     "without the tide (calibrate --water-level writes it).",
    "height_m": "Camera height above the water at water_level_m, m; NaN: derived from H (calibrate writes it).",
}


DEFAULT_CAMERA_PARAMETERS: dict[str, Any] = {
    "camera_lat": 32.70297,
    "camera_lon": -117.234631,
    "image_width": 1280,
    "image_height": 720,
    "H": [-441.0, 379.0, -1000.0, -217.0, -56.5, -548.0, -0.512, -0.144, 1.0],
    "K1": -4.053e-07,
    "center_x": 640.0,
    "center_y": 360.0,
    "heading_deg": 76.475,
    "box_anchor": 0.5,
    "water_level_m": math.nan,
    "height_m": math.nan,
}
"""The challenge camera, the paper's calibration with its sign typo corrected (see aitas/camera.json)."""


REQUIRED_CAMERA_KEYS = ("camera_lat", "camera_lon", "image_width", "image_height", "H", "K1", "center_x",
                        "center_y", "box_anchor")
"""The keys a calibration file must give: without any of them the node would run on another camera's values."""

BUILTIN_CALIBRATION = "builtin_calibration"


def missing_calibration_keys(given: set[str], prefix: str = "camera") -> list[str]:
    """``REQUIRED_CAMERA_KEYS`` (as ``prefix.key``) that are not among the ``given`` parameter names."""
    return [f"{prefix}.{key}" for key in REQUIRED_CAMERA_KEYS if f"{prefix}.{key}" not in given]


def declare_camera_model(node: Node, prefix: str = "camera"):
    """Declare the ``camera.*`` calibration parameters and build the camera model from them.

    A calibration must be given (``--params-file`` of the file ``calibrate`` writes), with every key of
    ``REQUIRED_CAMERA_KEYS``: a file missing ``H`` must not run on another camera's homography. The paper's
    corrected calibration of the challenge camera is used only when asked for (``camera.builtin_calibration:
    true``, for tests and a first look at the challenge data). A calibration that cannot be used raises
    ``CalibrationError`` naming the key; nodes let it stop them at start (``run_node`` prints it as one line).
    """
    builtin = declare_parameter(
        node, f"{prefix}.{BUILTIN_CALIBRATION}", False,
        "Use the paper's calibration of the challenge camera (corrected) when no calibration file is given; for "
        "tests and a first look at the challenge data only.", read_only=True)
    given = {name for name in getattr(node, "_parameter_overrides", {}) if name.startswith(f"{prefix}.")}
    missing = missing_calibration_keys(given, prefix)
    if missing and not builtin:
        if len(missing) == len(REQUIRED_CAMERA_KEYS):
            raise CalibrationError(
                f"{node.get_name()}: no calibration given: pass the calibration file `calibrate` writes, e.g. "
                f"--params-file config/aitas_camera.yaml (or -p {prefix}.{BUILTIN_CALIBRATION}:=true for the "
                "paper's calibration of the challenge camera)")
        raise CalibrationError(
            f"{node.get_name()}: the calibration lacks {', '.join(missing)}: write it again with `calibrate` (a "
            f"node never runs on another camera's values for missing keys)")
    values = {}
    for key, default in DEFAULT_CAMERA_PARAMETERS.items():
        description = CAMERA_PARAMETER_DESCRIPTIONS.get(key, f"Camera calibration value '{key}'.")
        values[key] = declare_parameter(node, f"{prefix}.{key}", default, description, read_only=True)
    return CameraModel.from_params(values)
