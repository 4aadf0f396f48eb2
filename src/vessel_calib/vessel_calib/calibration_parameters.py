"""The ``camera.*`` calibration parameters as parameter-table rows (ROS-free).

Every node that maps pixels to the sea (detector, fuser, GPS publisher) declares these rows, all read-only
(``vessel_calib.camera_parameters.declare_camera_model``): a calibration is given at start, with the file
``calibrate`` writes, and a running node never switches to another camera.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

from vessel_common.parameter_table import Param

PREFIX = "camera"
"""The parameters' group: ``camera.H``, ``camera.K1``, ..."""

BUILTIN_CALIBRATION = "builtin_calibration"

CALIBRATION_ROWS: tuple[Param, ...] = (
    Param(f"{PREFIX}.{BUILTIN_CALIBRATION}", False,
          "Use the paper's calibration of the challenge camera (corrected) when no calibration file is given; for "
          "tests and a first look at the challenge data only."),
    Param(f"{PREFIX}.camera_lat", 32.70297, "Camera latitude, WGS-84 degrees."),
    Param(f"{PREFIX}.camera_lon", -117.234631, "Camera longitude, WGS-84 degrees."),
    Param(f"{PREFIX}.image_width", 1280, "Image width in pixels the calibration was made for."),
    Param(f"{PREFIX}.image_height", 720, "Image height in pixels the calibration was made for."),
    Param(f"{PREFIX}.H", [-441.0, 379.0, -1000.0, -217.0, -56.5, -548.0, -0.512, -0.144, 1.0],
          "Homography, 9 numbers row-major: z_p (x_p, y_p, 1) = H (x_w, y_w, 1), world in metres east/north."),
    Param(f"{PREFIX}.K1", -4.053e-07,
          "Radial distortion term about the centre: x_s = x_c + (x_p - x_c)(1 + K1 r_p^2)."),
    Param(f"{PREFIX}.center_x", 640.0, "Distortion centre x, pixels."),
    Param(f"{PREFIX}.center_y", 360.0, "Distortion centre y, pixels."),
    Param(f"{PREFIX}.heading_deg", 76.475,
          "Camera heading implied by H, degrees from north (informational; checked against H)."),
    Param(f"{PREFIX}.box_anchor", 0.5,
          "Point of a vessel's box that H maps to its position: horizontal centre, this share of the way down (0 "
          "top, 0.5 centre as in the paper, 1 bottom); written by calibrate."),
    Param(f"{PREFIX}.water_level_m", math.nan,
          "Water level (in the datum of the fuser's water_level.file) that H belongs to; NaN: calibrated without "
          "the tide (calibrate --water-level writes it)."),
    Param(f"{PREFIX}.height_m", math.nan,
          "Camera height above the water at water_level_m, m; NaN: derived from H (calibrate writes it)."),
    Param(f"{PREFIX}.reference_attitude_deg", [math.nan, math.nan, math.nan],
          "The ship's [heading, pitch, roll] (degrees; heading from true north, pitch bow up, roll starboard down) "
          "at which H holds: with the ship's attitude per image it gives every image's pose. NaN: the ship points "
          "where the camera looks, level (a fixed camera)."),
    Param(f"{PREFIX}.far_edge_ideal_abc", [math.nan, math.nan, math.nan],
          "The sea's far edge (sea-sky or sea-shore line) at the reference attitude: a x + b y + c = 0 in ideal "
          "pixels, the line the horizon measured in each image is compared with (./vessel horizon measures it). "
          "NaN: the sea's horizon for the camera's height."),
)
"""``camera.builtin_calibration`` and the calibration's values; the defaults are the challenge camera, the paper's
calibration with its sign typo corrected (see aitas/camera.json). Every row is read-only."""


def calibration_rows(prefix: str = PREFIX) -> tuple[Param, ...]:
    """``CALIBRATION_ROWS`` with their names under ``prefix.`` instead of ``camera.``."""
    if prefix == PREFIX:
        return CALIBRATION_ROWS
    return tuple(replace(row, name=f"{prefix}.{_key(row)}") for row in CALIBRATION_ROWS)


def _key(row: Param) -> str:
    return row.name[len(PREFIX) + 1:]


def _copy(value: Any) -> Any:
    return list(value) if isinstance(value, list) else value


DEFAULT_CAMERA_PARAMETERS: dict[str, Any] = {
    _key(row): _copy(row.default) for row in CALIBRATION_ROWS if _key(row) != BUILTIN_CALIBRATION}
"""The calibration's values without the ``camera.`` prefix (``CameraModel.from_params`` takes them)."""

CAMERA_PARAMETER_DESCRIPTIONS: dict[str, str] = {
    _key(row): row.description for row in CALIBRATION_ROWS if _key(row) != BUILTIN_CALIBRATION}
