"""A camera model as a ``camera:`` parameter block, and back (``CameraModel.to_params`` and ``from_params``).

A block comes from a file a person may have edited, so reading it checks every value and names the key that is
wrong; writing gives plain Python numbers so the block is also a valid set of ROS parameters. This module knows
the block's keys and types; what values make a camera is ``CameraModel``'s to check.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from vessel_common.errors import CalibrationError

PARAM_KEYS_REQUIRED = ("camera_lat", "camera_lon", "image_width", "image_height", "H", "K1", "center_x", "center_y")


def is_number(value: Any) -> bool:
    """True for an int or float of Python or numpy; False for a bool, which YAML and ROS keep apart from numbers."""
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool | np.bool_)


def params_of_camera(camera) -> dict:
    """The ``camera:`` block of a ``CameraModel`` (doubles stay doubles); ``CameraModel.from_params`` reads it back.

    ``heading_deg``, ``horizon_ideal_abc`` (a x_p + b y_p + c = 0, ideal pixels) and ``horizon_y_center``
    (screen y of the horizon at x_c) are derived from H for people and plots; loaders recompute them.
    """
    width, height = camera.image_size
    cx, cy = camera.center
    params: dict[str, Any] = {}
    if camera.camera_lat is not None:
        params["camera_lat"] = float(camera.camera_lat)
        params["camera_lon"] = float(camera.camera_lon)
    params.update({
        "image_width": int(width),
        "image_height": int(height),
        "H": [float(v) for v in camera.H.ravel()],
        "K1": float(camera.K1),
        "center_x": float(cx),
        "center_y": float(cy),
        "box_anchor": float(camera.box_anchor),
    })
    if math.isfinite(camera.water_level_m):
        params["water_level_m"] = float(camera.water_level_m)
        params["height_m"] = float(camera.height_m)
    if camera.reference_attitude_deg is not None:
        params["reference_attitude_deg"] = [float(v) for v in camera.reference_attitude_deg]
    if camera.far_edge_calibrated is not None:
        params["far_edge_ideal_abc"] = [float(v) for v in camera.far_edge_calibrated]
    # Derived, informational (recomputed from H on load); NaN is left out because ROS YAML cannot hold it.
    if math.isfinite(camera.heading_deg):
        params["heading_deg"] = float(camera.heading_deg)
    a, b, c = camera.horizon_line_ideal
    params["horizon_ideal_abc"] = [float(a), float(b), float(c)]
    y_center = float(camera.horizon_y(np.array(cx)))
    if math.isfinite(y_center):
        params["horizon_y_center"] = y_center
    return params


def homography_of_params(params: Mapping[str, Any], where: str) -> np.ndarray:
    """The block's H as a 3x3 array, once the block is a mapping with every required key and H nine numbers."""
    if not isinstance(params, Mapping):
        raise CalibrationError(
            f"{where}: expected a mapping of calibration parameters, got {type(params).__name__}")
    missing = [k for k in PARAM_KEYS_REQUIRED if k not in params]
    if missing:
        raise CalibrationError(
            f"{where}: missing key(s) {', '.join(missing)}; write the file with the calibrate tool")
    H = params["H"]
    if isinstance(H, str | bytes) or not hasattr(H, "__len__"):
        raise CalibrationError(f"{where}.H must be a list of 9 numbers (row-major), got {H!r}")
    H_flat = list(np.asarray(H, dtype=object).ravel())
    if len(H_flat) != 9:
        raise CalibrationError(f"{where}.H must have 9 numbers (3x3 row-major), got {len(H_flat)}")
    for i, v in enumerate(H_flat):
        if not is_number(v):
            raise CalibrationError(f"{where}.H[{i}] must be a number, got {v!r} ({type(v).__name__})")
    return np.array(H_flat, dtype=float).reshape(3, 3)


def camera_arguments_of_params(params: Mapping[str, Any], where: str) -> dict[str, Any]:
    """The ``CameraModel`` arguments but H of a block that ``homography_of_params`` accepted.

    ``box_anchor`` is left out when the block has none: files without it were fitted on box centres, the
    constructor's default.
    """
    arguments: dict[str, Any] = {
        "K1": _number(params, "K1", where),
        "center": (_number(params, "center_x", where), _number(params, "center_y", where)),
        "image_size": (_integer(params, "image_width", where), _integer(params, "image_height", where)),
        "camera_lat": _number(params, "camera_lat", where),
        "camera_lon": _number(params, "camera_lon", where),
    }
    if "box_anchor" in params:
        arguments["box_anchor"] = _number(params, "box_anchor", where)
    arguments["water_level_m"] = _optional_number(params, "water_level_m", where)
    arguments["height_m"] = _optional_number(params, "height_m", where)
    for key, argument in (("reference_attitude_deg", "reference_attitude_deg"), ("far_edge_ideal_abc", "far_edge_abc")):
        if key in params:
            values = params[key]
            if isinstance(values, str | bytes) or not hasattr(values, "__len__") or not all(
                    is_number(v) for v in values):
                raise CalibrationError(f"{where}.{key} must be a list of 3 numbers, got {values!r}")
            arguments[argument] = [float(v) for v in values]
    return arguments


def _number(params: Mapping[str, Any], key: str, where: str) -> float:
    value = params[key]
    if not is_number(value):
        raise CalibrationError(f"{where}.{key} must be a number, got {value!r} ({type(value).__name__})")
    if not math.isfinite(float(value)):
        raise CalibrationError(f"{where}.{key} must be finite, got {value!r}")
    return float(value)


def _optional_number(params: Mapping[str, Any], key: str, where: str) -> float:
    """A number that may be NaN (unknown) or absent."""
    if key not in params:
        return math.nan
    value = params[key]
    if not is_number(value) or math.isinf(float(value)):
        raise CalibrationError(f"{where}.{key} must be a number (or .nan: unknown), got {value!r}")
    return float(value)


def _integer(params: Mapping[str, Any], key: str, where: str) -> int:
    value = _number(params, key, where)
    if value != int(value) or value <= 0:
        raise CalibrationError(f"{where}.{key} must be a positive integer, got {params[key]!r}")
    return int(value)
