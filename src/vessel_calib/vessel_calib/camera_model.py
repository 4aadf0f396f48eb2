"""The paper's camera model: a sea-plane homography H plus one radial distortion term K1 about the image centre.

Conventions (checked against the AI Tracks at Sea data, see ``../shared/aitas/README.md``):

* World: metres east (x_w) and north (y_w) of the camera on the sea plane (``vessel_calib.geodesy``).
* Ideal pixel: ``z_p (x_p, y_p, 1)^T = H (x_w, y_w, 1)^T``; ``z_p < 0`` for points in front of the camera. The
  constructor normalises the overall sign of H (H and -H are the same homography) so this holds for the
  ground seen at the bottom centre of the image; the camera must be mounted upright (roll well under 90 deg).
* Screen pixel: ``x_s = x_c + (x_p - x_c)(1 + K1 r_p^2)`` (y likewise), ``r_p`` the ideal point's distance from
  the distortion centre ``(x_c, y_c)``. With K1 < 0 the map folds at ``r_p = sqrt(-1 / (3 K1))``: ideal points
  beyond the fold and screen points beyond ``max_screen_radius`` have no meaningful counterpart and are
  reported invalid (NaN coordinates), never as garbage.
* Horizon: the vanishing line of the sea plane, where ``z_p = 0``, i.e. the third row of ``H^-1`` dotted with
  ``(x_p, y_p, 1)`` is zero (the paper's horizon equation), mapped through the distortion.
* Heading: the paper's method: the ideal horizon point at ``x_p = x_c`` back-projected through ``H^-1`` gives
  the direction (x_w, y_w) the camera looks in; heading = atan2(x_w, y_w), degrees clockwise from north.

Everything is vectorised: arrays of any (broadcastable) shape in, arrays of that shape out. The lens is
``vessel_calib.radial_lens``, the pinhole camera behind H ``vessel_calib.pinhole`` and the ``camera:`` parameter block
``vessel_calib.camera_model_params``; this module joins them and checks what makes a camera.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from vessel_calib import geodesy
from vessel_calib.camera_model_params import (
    camera_arguments_of_params,
    homography_of_params,
    is_number,
    params_of_camera,
)
from vessel_calib.pinhole import PinholeGeometry, pinhole_geometry
from vessel_calib.radial_lens import RadialLens
from vessel_common.errors import CalibrationError

#: Condition number above which H is treated as singular.
MAX_H_CONDITION = 1e12
#: |K1| * r_corner^2 above this changes the corner radius by more than 100 %: no real lens, a unit mistake.
MAX_K1_CORNER_EFFECT = 1.0
#: Relative margin on z_p below which a point counts as on the horizon.
_HORIZON_EPS = 1e-9

#: The paper's box reference point: the box centre (and that of every calibration file without ``box_anchor``).
PAPER_BOX_ANCHOR = 0.5


def box_points(boxes_xyxy, anchor: float) -> np.ndarray:
    """(N, 2) points of boxes (x1, y1, x2, y2): the horizontal centre, ``anchor`` of the way down (0 top, 1 bottom)."""
    b = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    return np.column_stack([(b[:, 0] + b[:, 2]) / 2.0, b[:, 1] + anchor * (b[:, 3] - b[:, 1])])


def _same_number(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


def _arr(value) -> np.ndarray:
    return np.asarray(value, dtype=float)


def _checked_levels(water_level_m, height_m) -> tuple[float, float]:
    """The water level and the camera height: finite metres or NaN (unknown), a known height above the water."""
    for name, value in (("water_level_m", water_level_m), ("height_m", height_m)):
        if not is_number(value) or math.isinf(float(value)):
            raise CalibrationError(f"{name} must be a finite number of metres (or NaN: unknown), got {value!r}")
    if math.isfinite(float(height_m)) and float(height_m) <= 0:
        raise CalibrationError(f"height_m is the camera's height above the water and must be > 0, got {height_m!r}")
    return float(water_level_m), float(height_m)


def _checked_triple(values, name: str) -> tuple[float, float, float] | None:
    """Three finite numbers, or None for absent or all NaN (unknown)."""
    if values is None:
        return None
    triple = tuple(float(v) for v in values)
    if len(triple) == 3 and all(math.isnan(v) for v in triple):
        return None
    if len(triple) != 3 or not all(math.isfinite(v) for v in triple):
        raise CalibrationError(f"camera.{name} must be 3 finite numbers (or all .nan: unknown), got {list(triple)!r}")
    return triple


def _checked_box_anchor(box_anchor) -> float:
    if not is_number(box_anchor) or not 0.0 <= float(box_anchor) <= 1.0:
        raise CalibrationError(
            f"box_anchor must be a number in [0, 1] (0 box top, 0.5 centre, 1 bottom), got {box_anchor!r}")
    return float(box_anchor)


def _checked_homography(H) -> np.ndarray:
    """H as a 3x3 float array that can map screen points back to the sea (finite, not near singular)."""
    try:
        H_arr = np.array(H, dtype=float).reshape(3, 3)
    except (TypeError, ValueError):
        raise CalibrationError(
            f"H must be a 3x3 matrix or 9 numbers row-major, got {H!r}; re-run the calibration") from None
    if not np.all(np.isfinite(H_arr)):
        raise CalibrationError("H contains NaN or infinite values; re-run the calibration to get a finite H")
    if not np.any(H_arr):
        raise CalibrationError("H is all zeros (singular); re-run the calibration")
    cond = np.linalg.cond(H_arr)
    if not np.isfinite(cond) or cond > MAX_H_CONDITION:
        raise CalibrationError(
            f"H is singular or nearly so (condition number {cond:.3g} > {MAX_H_CONDITION:.0e}): it cannot "
            "map screen points back to the sea; re-run the calibration with well spread, non-collinear pairs")
    return H_arr


def _checked_image(image_size, center) -> tuple[int, int, float, float]:
    """Width and height (positive integers) and the distortion centre inside the image."""
    try:
        width, height = (int(v) for v in image_size)
        if (width, height) != tuple(float(v) for v in image_size):
            raise ValueError
    except (TypeError, ValueError):
        raise CalibrationError(f"image_size must be two integers (width, height), got {image_size!r}") from None
    if width <= 0 or height <= 0:
        raise CalibrationError(f"image_size must be positive, got {width}x{height}")
    try:
        cx, cy = (float(v) for v in center)
    except (TypeError, ValueError):
        raise CalibrationError(f"center must be two numbers (x_c, y_c), got {center!r}") from None
    if not (math.isfinite(cx) and math.isfinite(cy)) or not (0 <= cx <= width and 0 <= cy <= height):
        raise CalibrationError(
            f"distortion centre ({cx}, {cy}) is not inside the {width}x{height} image; use the image centre")
    return width, height, cx, cy


def _checked_k1(K1, width: int, height: int, cx: float, cy: float) -> float:
    """K1 as a float that a real lens could have on this image (a wrong unit or convention is far off)."""
    if not is_number(K1) or not math.isfinite(float(K1)):
        raise CalibrationError(f"K1 must be a finite number, got {K1!r}")
    K1 = float(K1)
    if abs(K1) < 1e-30:
        K1 = 0.0  # physically no distortion; avoids overflow in the fold radius
    r_corner2 = max((px - cx) ** 2 + (py - cy) ** 2 for px in (0, width) for py in (0, height))
    if abs(K1) * r_corner2 > MAX_K1_CORNER_EFFECT:
        raise CalibrationError(
            f"K1 = {K1:.4g} is absurd for a {width}x{height} image: it changes the corner radius by "
            f"{100 * abs(K1) * r_corner2:.0f} %; expect |K1| < {MAX_K1_CORNER_EFFECT / r_corner2:.2g} (paper: "
            "-4.05e-7). Check the convention x_s = x_c + (x_p - x_c)(1 + K1 r_p^2) and full-resolution pixels")
    return K1


def _checked_position(camera_lat, camera_lon) -> tuple[float | None, float | None]:
    if (camera_lat is None) != (camera_lon is None):
        raise CalibrationError("give both camera_lat and camera_lon, or neither")
    if camera_lat is not None:
        geodesy.validate_lat_lon(camera_lat, camera_lon, "camera position (camera_lat, camera_lon)")
        camera_lat, camera_lon = float(camera_lat), float(camera_lon)
    return camera_lat, camera_lon


class CameraModel:
    """Immutable camera model: sea-plane homography H, radial K1, image geometry and camera position.

    Args:
        H: 3x3 (or 9 values row-major) homography in the paper's convention, world metres -> ideal pixels.
        K1: radial distortion coefficient (1/px^2), the paper's convention above.
        center: distortion centre (x_c, y_c) in screen pixels.
        image_size: (width, height) in pixels.
        camera_lat, camera_lon: camera position (WGS-84 degrees), the origin of the world frame; needed only
            for the GPS conversions.
        box_anchor: the point of a vessel's box that H maps to the vessel's position: its horizontal centre,
            ``box_anchor`` of the way down the box (0 top, 0.5 centre as in the paper, 1 bottom). A property of
            the calibration: H was fitted on that point of the labelled boxes, so every box must be read the
            same way (``box_reference_points``).
        water_level_m: the water level H belongs to, in the datum of a water-level table
            (``vessel_calib.water_level``); NaN: the calibration ignored the tide, ``at_water_level`` refuses.
        height_m: the camera's height above the water at ``water_level_m``; NaN: derived from H (``pinhole``).
        reference_attitude_deg: the ship's (heading, pitch, roll) at which H holds, for a camera on a ship
            (``vessel_calib.camera_pose``); None: the ship points where the camera looks, level.
        far_edge_abc: the sea's far edge in ideal pixels at that attitude (a x + b y + c = 0); None: the sea's
            horizon for the camera's height (``far_edge_line``).

    Raises:
        CalibrationError: non-finite or singular H, absurd K1, bad image size or centre, invalid position.

    """

    __slots__ = (
        "_H", "_Hinv", "_lens", "_image_size", "_camera_lat", "_camera_lon",
        "_horizon", "_heading", "_box_anchor", "_water_level_m", "_height_m", "_pinhole",
        "_reference_attitude", "_far_edge",
    )

    def __init__(self, H, K1: float = 0.0, center=(640.0, 360.0), image_size=(1280, 720),
                 camera_lat: float | None = None, camera_lon: float | None = None,
                 box_anchor: float = PAPER_BOX_ANCHOR, water_level_m: float = math.nan, height_m: float = math.nan,
                 reference_attitude_deg=None, far_edge_abc=None):
        self._reference_attitude = _checked_triple(reference_attitude_deg, "reference_attitude_deg")
        self._far_edge = _checked_triple(far_edge_abc, "far_edge_ideal_abc")
        self._water_level_m, self._height_m = _checked_levels(water_level_m, height_m)
        self._pinhole: PinholeGeometry | None = None
        self._box_anchor = _checked_box_anchor(box_anchor)
        H_arr = _checked_homography(H)
        width, height, cx, cy = _checked_image(image_size, center)
        K1 = _checked_k1(K1, width, height, cx, cy)
        self._camera_lat, self._camera_lon = _checked_position(camera_lat, camera_lon)
        self._lens = RadialLens(K1, (cx, cy))
        self._image_size = (width, height)
        self._H, self._Hinv = self._facing_the_sea(H_arr)
        a, b, c = self._Hinv[2]
        norm = math.hypot(a, b)
        self._horizon = (a / norm, b / norm, c / norm) if norm > 0 else (0.0, 0.0, 1.0)
        self._heading = self._compute_heading()

    def _facing_the_sea(self, H_arr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """H and its inverse (read-only), signed so z_p < 0 in front: the bottom centre of the image is sea in front.

        H and -H are the same homography; only this sign makes ``ideal_to_world``'s test of z_p mean "in front".
        """
        width, height = self._image_size
        cx = self.center[0]
        Hinv = np.linalg.inv(H_arr)
        bx, by = self._lens.undistort(np.array(cx), np.array(height - 1.0))[:2]
        if not np.isfinite(bx):
            bx, by = cx, height - 1.0
        w_bottom = Hinv[2] @ np.array([float(bx), float(by), 1.0])
        if abs(w_bottom) <= _HORIZON_EPS * np.abs(Hinv[2]).sum() * max(width, height):
            raise CalibrationError(
                "the horizon of this H passes through the bottom centre of the image: it cannot be the sea "
                "seen by an upright camera; re-run the calibration")
        if w_bottom > 0:
            H_arr = -H_arr
            Hinv = -Hinv
        H_arr.setflags(write=False)
        Hinv.setflags(write=False)
        return H_arr, Hinv

    # ----------------------------------------------------------------- properties
    @property
    def H(self) -> np.ndarray:  # noqa: N802 - the paper's symbol
        """The 3x3 homography (read-only), sign-normalised so z_p < 0 in front."""
        return self._H

    @property
    def H_inv(self) -> np.ndarray:  # noqa: N802
        """Inverse of H (read-only): ideal pixels -> homogeneous world."""
        return self._Hinv

    @property
    def K1(self) -> float:  # noqa: N802
        """Radial distortion coefficient, 1/px^2."""
        return self._lens.K1

    @property
    def center(self) -> tuple[float, float]:
        """Distortion centre (x_c, y_c), screen pixels."""
        return self._lens.center

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self._image_size

    @property
    def camera_lat(self) -> float | None:
        """Camera latitude (degrees), origin of the world frame."""
        return self._camera_lat

    @property
    def camera_lon(self) -> float | None:
        """Camera longitude (degrees), origin of the world frame."""
        return self._camera_lon

    @property
    def water_level_m(self) -> float:
        """The water level H belongs to (NaN: calibrated without one)."""
        return self._water_level_m

    @property
    def height_m(self) -> float:
        """The camera's height above the water at ``water_level_m``: the given value, else derived from H."""
        return self._height_m if math.isfinite(self._height_m) else self.pinhole().height_m

    @property
    def reference_attitude_deg(self) -> tuple[float, float, float] | None:
        """The ship's (heading, pitch, roll) at which H holds; None: unknown (a fixed camera)."""
        return self._reference_attitude

    @property
    def far_edge_calibrated(self) -> tuple[float, float, float] | None:
        """The far edge the calibration file gives (``camera.far_edge_ideal_abc``); None: not measured."""
        return self._far_edge

    def far_edge_line(self) -> tuple[float, float, float]:
        """The sea's far edge at the reference attitude, ideal pixels: the calibrated line, else the sea's horizon.

        The sea's horizon lies below the vanishing line of the sea plane by the dip of a sphere's horizon seen
        from the camera's height, sqrt(2 h / R).
        """
        if self._far_edge is not None:
            return self._far_edge
        a, b, c = self._horizon
        dip_px = self.pinhole().focal_px * math.sqrt(2.0 * self.height_m / geodesy.EARTH_RADIUS_M)
        return (a, b, c - dip_px * b)

    @property
    def box_anchor(self) -> float:
        """Where down a box (0 top, 0.5 centre, 1 bottom) the point lies that H maps to the vessel."""
        return self._box_anchor

    def box_reference_points(self, boxes_xyxy, anchor_offset: float = 0.0) -> np.ndarray:
        """(N, 2) screen point of each box (x1, y1, x2, y2) that stands for the vessel: see ``box_anchor``.

        ``anchor_offset`` reads the boxes that many box heights lower (boxes drawn differently from the labels
        the calibration was fitted on); the point stays inside the box.
        """
        return box_points(boxes_xyxy, min(max(self._box_anchor + float(anchor_offset), 0.0), 1.0))

    def box_depths_m(self, boxes_xyxy) -> np.ndarray:
        """Depth (``depth_m``) of each box's reference point on the sea; NaN where it has none.

        None: the point is on or above the horizon, or off the lens model. The box size a vessel would have at the
        box's place follows from this depth.
        """
        ref = self.box_reference_points(boxes_xyxy)
        with np.errstate(invalid="ignore"):
            xw, yw, valid = self.screen_to_world(ref[:, 0], ref[:, 1])
            return np.where(valid, self.depth_m(np.nan_to_num(xw), np.nan_to_num(yw)), np.nan)

    @property
    def max_screen_radius(self) -> float:
        """Largest screen distance from the centre that the lens model can undistort (inf when K1 >= 0)."""
        return self._lens.rs_max

    @property
    def horizon_line_ideal(self) -> tuple[float, float, float]:
        """(a, b, c) with a x_p + b y_p + c = 0 on the horizon, a^2 + b^2 = 1, negative in front (sea side)."""
        return self._horizon

    @property
    def heading_deg(self) -> float:
        """Camera heading by the paper's method, degrees clockwise from north in [0, 360); NaN if undefined."""
        return self._heading

    # ----------------------------------------------------------------- lens
    def distort(self, xp, yp):
        """Ideal pixel -> screen pixel: x_s = x_c + (x_p - x_c)(1 + K1 r_p^2); the inverse is ``undistort``."""
        return self._lens.distort(xp, yp)

    def undistort(self, xs, ys):
        """Screen pixel -> ideal pixel (Newton on the radius, < 1e-6 px); NaN where the lens model has no inverse."""
        xp, yp, _ = self._lens.undistort(xs, ys)
        return xp, yp

    # ----------------------------------------------------------------- plane <-> ideal
    def zp_of_world(self, xw, yw):
        """z_p of world points (negative in front of the camera; |z_p| grows with distance)."""
        h = self._H[2]
        return h[0] * _arr(xw) + h[1] * _arr(yw) + h[2]

    def depth_m(self, xw, yw):
        """Distance in metres of world points in front of the camera's principal line (scale-free z_p).

        ``-z_p / |(H[2,0], H[2,1])|``: positive in front, about the depth along the viewing direction for a
        near-level camera. Unlike z_p it does not depend on the arbitrary scale of H.
        """
        return -self.zp_of_world(xw, yw) / math.hypot(self._H[2, 0], self._H[2, 1])

    def world_to_ideal(self, xw, yw):
        """World metres -> (x_p, y_p, z_p), the paper's homography equation (NaN x_p, y_p where z_p = 0)."""
        xw = _arr(xw)
        yw = _arr(yw)
        H = self._H
        zp = H[2, 0] * xw + H[2, 1] * yw + H[2, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xp = (H[0, 0] * xw + H[0, 1] * yw + H[0, 2]) / zp
            yp = (H[1, 0] * xw + H[1, 1] * yw + H[1, 2]) / zp
        bad = ~np.isfinite(xp) | ~np.isfinite(yp)
        return np.where(bad, np.nan, xp), np.where(bad, np.nan, yp), zp

    def ideal_to_world(self, xp, yp):
        """Ideal pixel -> (x_w, y_w, valid): valid only below the horizon (z_p < 0); NaN elsewhere."""
        xp = _arr(xp)
        yp = _arr(yp)
        G = self._Hinv
        W = G[2, 0] * xp + G[2, 1] * yp + G[2, 2]
        scale = np.abs(G[2, 0] * xp) + np.abs(G[2, 1] * yp) + abs(G[2, 2])
        valid = np.isfinite(W) & (W < -_HORIZON_EPS * scale)
        Wsafe = np.where(valid, W, -1.0)
        xw = (G[0, 0] * xp + G[0, 1] * yp + G[0, 2]) / Wsafe
        yw = (G[1, 0] * xp + G[1, 1] * yp + G[1, 2]) / Wsafe
        valid &= np.isfinite(xw) & np.isfinite(yw)
        return np.where(valid, xw, np.nan), np.where(valid, yw, np.nan), valid

    # ----------------------------------------------------------------- plane <-> screen
    def world_to_screen(self, xw, yw):
        """World metres -> (x_s, y_s, in_front).

        ``in_front`` is True where the point is in front of the camera (z_p < 0) and inside the lens model's
        domain, i.e. where (x_s, y_s) is meaningful; elsewhere x_s, y_s are NaN. Points in front may still be
        outside the image: use ``in_image``.
        """
        xp, yp, zp = self.world_to_ideal(xw, yw)
        in_front = (zp < 0) & self._lens.in_domain(xp, yp)
        xs, ys = self.distort(xp, yp)
        return np.where(in_front, xs, np.nan), np.where(in_front, ys, np.nan), in_front

    def screen_to_world(self, xs, ys):
        """Screen pixel -> (x_w, y_w, valid) on the sea plane; invalid (NaN) on/above the horizon or off-lens."""
        xp, yp, ok = self._lens.undistort(xs, ys)
        xw, yw, valid = self.ideal_to_world(xp, yp)
        valid &= ok
        return np.where(valid, xw, np.nan), np.where(valid, yw, np.nan), valid

    def in_image(self, xs, ys, margin: float = 0.0):
        """True where the screen point lies inside the image (optionally shrunk by ``margin`` pixels)."""
        width, height = self._image_size
        xs = _arr(xs)
        ys = _arr(ys)
        return (xs >= margin) & (xs <= width - margin) & (ys >= margin) & (ys <= height - margin)

    # ----------------------------------------------------------------- GPS
    def _require_position(self):
        if self._camera_lat is None:
            raise CalibrationError(
                "this camera model has no camera position: set camera_lat/camera_lon in the calibration file")
        return self._camera_lat, self._camera_lon

    def gps_to_world(self, lat, lon):
        """WGS-84 degrees -> world metres about the camera."""
        lat0, lon0 = self._require_position()
        return geodesy.gps_to_local(lat, lon, lat0, lon0)

    def world_to_gps(self, xw, yw):
        """World metres about the camera -> WGS-84 degrees."""
        lat0, lon0 = self._require_position()
        return geodesy.local_to_gps(xw, yw, lat0, lon0)

    def gps_to_screen(self, lat, lon):
        """WGS-84 degrees -> (x_s, y_s, in_front), see ``world_to_screen``."""
        xw, yw = self.gps_to_world(lat, lon)
        return self.world_to_screen(xw, yw)

    def screen_to_gps(self, xs, ys):
        """Screen pixel -> (lat, lon, valid); NaN where invalid (on/above the horizon, off-lens)."""
        lat0, lon0 = self._require_position()
        xw, yw, valid = self.screen_to_world(xs, ys)
        lat, lon = geodesy.local_to_gps(xw, yw, lat0, lon0)
        return lat, lon, valid

    # ----------------------------------------------------------------- horizon and heading
    def horizon_y(self, xs):
        """Screen y of the horizon at screen x (NaN where the horizon is vertical or off the lens domain)."""
        return self._lens.line_y(self._horizon, xs)

    def _compute_heading(self) -> float:
        a, b, c = self._horizon
        G = self._Hinv
        cx, cy = self.center
        if abs(b) < 1e-12:
            # No usable horizon (camera looking down): bearing of the ground under the image centre instead.
            xw, yw, valid = self.ideal_to_world(cx, cy)
            return float(math.degrees(math.atan2(xw, yw)) % 360.0) if bool(valid) else math.nan
        y_hor = -(a * cx + c) / b
        direction = G[:2] @ np.array([cx, y_hor, 1.0])
        # The vanishing direction is defined up to sign: take the one pointing at the sea in front.
        p_front = np.array([cx, y_hor - 1e-3 * math.copysign(1.0, b), 1.0])
        w_front = G @ p_front
        front_point = w_front[:2] / w_front[2]
        if direction @ front_point < 0:
            direction = -direction
        return float(math.degrees(math.atan2(direction[0], direction[1])) % 360.0)

    # ----------------------------------------------------------------- uncertainty
    def screen_to_world_jacobian(self, xs, ys):
        """d(x_w, y_w)/d(x_s, y_s), shape (..., 2, 2); NaN where the point is invalid.

        Propagate pixel noise with ``J @ cov_px @ J.T`` to get a world covariance in m^2.
        """
        xp, yp, ok = self._lens.undistort(xs, ys)
        xw, yw, valid = self.ideal_to_world(xp, yp)
        valid &= ok
        G = self._Hinv
        W = G[2, 0] * xp + G[2, 1] * yp + G[2, 2]
        # world wrt ideal: (G[:2,:2] - w g3^T) / W
        Jh = np.empty(np.shape(xw) + (2, 2))
        Jh[..., 0, 0] = (G[0, 0] - xw * G[2, 0]) / W
        Jh[..., 0, 1] = (G[0, 1] - xw * G[2, 1]) / W
        Jh[..., 1, 0] = (G[1, 0] - yw * G[2, 0]) / W
        Jh[..., 1, 1] = (G[1, 1] - yw * G[2, 1]) / W
        J = Jh @ self._lens.undistort_jacobian(xp, yp)
        return np.where(valid[..., None, None], J, np.nan)

    # ----------------------------------------------------------------- pinhole geometry and the tide
    def pinhole(self) -> PinholeGeometry:
        """The pinhole camera behind H: focal length, height above the water and the point below the camera.

        H = K [r1 r2 t] for a camera with square pixels and its principal point at the distortion centre:
        the focal length is the one that makes r1 and r2 orthogonal and of equal length (least squares of the
        two conditions), the rest follows. CalibrationError if no positive focal length fits (a homography no
        upright pinhole camera above a plane can produce).
        """
        if self._pinhole is None:
            self._pinhole = self._decompose()
        return self._pinhole

    def _decompose(self) -> PinholeGeometry:
        geometry = pinhole_geometry(self._H, self.center)
        if geometry is None:
            raise CalibrationError("H is not the view of a pinhole camera over the sea plane (no positive focal "
                                   "length makes its columns orthogonal): give the camera height (height_m) "
                                   "or re-run the calibration")
        return geometry

    def water_level_scale(self, level_m):
        """The scale k = h / (h - rise) for water ``rise`` = ``level_m`` - ``water_level_m`` higher than at calibration.

        A sea point at distance r from below the camera looks, at that level, like the point at k r did at the
        calibration's level (similar triangles): ranges read through H must be divided by k.
        """
        if not math.isfinite(self._water_level_m):
            raise CalibrationError("this calibration has no water level (camera.water_level_m): it cannot be "
                                   "corrected for the tide; re-run calibrate with --water-level FILE.csv")
        height = self.height_m
        rise = np.asarray(level_m, dtype=float) - self._water_level_m
        above = height - rise
        if not np.all(np.isfinite(above) & (above > 0.2 * height)):
            worst = float(np.nanmax(np.abs(rise))) if np.any(np.isfinite(rise)) else math.nan
            raise CalibrationError(f"water level {worst:+.2f} m from the calibration's would put the camera "
                                   f"(h = {height:.2f} m) at or under the water: check the water-level file's "
                                   "units (metres) and datum")
        k = height / above
        return float(k) if k.ndim == 0 else k

    def to_water_level(self, xw, yw, level_m):
        """Sea points back-projected through H (at the calibration's water level) -> where they are at ``level_m``."""
        k = self.water_level_scale(level_m)
        nx, ny = self.pinhole().nadir_xy
        return nx + (_arr(xw) - nx) / k, ny + (_arr(yw) - ny) / k

    def from_water_level(self, xw, yw, level_m):
        """Sea points at ``level_m`` -> the points H maps to the same pixels (the inverse of ``to_water_level``)."""
        k = self.water_level_scale(level_m)
        nx, ny = self.pinhole().nadir_xy
        return nx + (_arr(xw) - nx) * k, ny + (_arr(yw) - ny) * k

    def at_water_level(self, level_m: float) -> CameraModel:
        """The same camera when the water is at ``level_m``: H composed with the scaling about the camera's nadir.

        Every method of the result (screen to world, depth, Jacobians, horizon) is right for that level; the
        horizon and the lens do not change. ``level_m`` equal to ``water_level_m`` returns this model.
        """
        level = float(level_m)
        if level == self._water_level_m:
            return self
        k = self.water_level_scale(level)
        geometry = self.pinhole()
        nx, ny = geometry.nadir_xy
        S = np.array([[k, 0.0, (1.0 - k) * nx], [0.0, k, (1.0 - k) * ny], [0.0, 0.0, 1.0]])
        return CameraModel(self._H @ S, self.K1, self.center, self._image_size, self._camera_lat,
                           self._camera_lon, self._box_anchor, water_level_m=level,
                           height_m=self.height_m / k, reference_attitude_deg=self._reference_attitude,
                           far_edge_abc=self._far_edge)

    # ----------------------------------------------------------------- parameters
    def to_params(self) -> dict:
        """The ``camera:`` parameter block: plain Python numbers, ROS-parameter friendly (doubles stay doubles).

        ``heading_deg``, ``horizon_ideal_abc`` and ``horizon_y_center`` are derived from H for people and plots
        (``vessel_calib.camera_model_params.params_of_camera``); ``from_params`` reads the block back.
        """
        return params_of_camera(self)

    @classmethod
    def from_params(cls, params: Mapping[str, Any], where: str = "camera") -> CameraModel:
        """Build from a ``camera:`` parameter block; CalibrationError naming the key for missing/mistyped values.

        Derived keys (``heading_deg``, ``horizon_*``) are informational and recomputed from H. ``box_anchor`` is
        optional: files without it were fitted on box centres (the paper's 0.5). The inverse of ``to_params``.
        """
        H = homography_of_params(params, where)
        try:
            return cls(H, **camera_arguments_of_params(params, where))
        except CalibrationError as exc:
            raise CalibrationError(f"{where}: {exc}") from None

    def __repr__(self) -> str:
        return (f"CameraModel(H={self._H.tolist()!r}, K1={self.K1!r}, center={self.center!r}, "
                f"image_size={self._image_size!r}, camera_lat={self._camera_lat!r}, camera_lon={self._camera_lon!r}, "
                f"box_anchor={self._box_anchor!r}, water_level_m={self._water_level_m!r}, height_m={self._height_m!r})")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CameraModel):
            return NotImplemented
        return (np.array_equal(self._H, other._H) and self.K1 == other.K1 and self.center == other.center
                and self._image_size == other._image_size and self._camera_lat == other._camera_lat
                and self._camera_lon == other._camera_lon and self._box_anchor == other._box_anchor
                and _same_number(self._water_level_m, other._water_level_m)
                and _same_number(self._height_m, other._height_m))

    __hash__ = None  # type: ignore[assignment]
