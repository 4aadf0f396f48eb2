"""Distance from box size: the paper's ``s_x = a / |z_p| + b``, ``s_y = c / |z_p| + d``, fitted to hand boxes.

A vessel's box shrinks with its depth in front of the camera, so the box width and height each give a second
and third estimate of where the vessel is, independent of the box position (paper eq. BBToZ_P and BBToY_P).
The paper's constants (1500, 25, 850, 25 at half resolution) describe its deliberately loose training boxes,
2-3x the tight boxes of the data; here a, b, c, d are fitted by robust least squares to hand-drawn boxes
whose vessel GPS is known (``screen_labels.csv``, training videos only), in full-resolution pixels.

Depth convention: ``z_p`` from ``H`` is defined only up to the arbitrary scale of H, so this module uses
``depth = |z_p| / hypot(H[2,0], H[2,1])``, which for a physical camera is the point's depth along the optical
axis in metres divided by the cosine of the camera's tilt (≈ 1): the same model then works with any
normalisation of H, and a is "pixels times metres" (focal length times vessel width).

Inverting: a width gives a depth, the depth and the box's ideal x give the ideal y on the sea plane
(the third row of ``z_p H^-1 (x_p, y_p, 1) = (x_w, y_w, 1)``):

    y_p = (1 / z_p - G[2,0] x_p - G[2,2]) / G[2,1],   G = H^-1,  z_p = -depth * hypot(H[2,0], H[2,1])

Because ``1 / z_p`` is linear in the box size, a constant pixel noise of the size becomes a constant noise
of this y: the variances used for the fusion weights do not depend on distance.

The fit is ``distance_model_fit.py`` (``./vessel fit distance-model``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vessel_common.errors import CalibrationError, DataError

#: Boxes whose edge is within this many pixels of the image border are cut by it: their size says nothing.
BORDER_MARGIN_PX = 1.0

#: Robust scale from the median absolute deviation of a Gaussian.
MAD_TO_SIGMA = 1.4826


def depth_scale(camera) -> float:
    """hypot(H[2,0], H[2,1]) of the camera's homography: divides |z_p| into metres of depth."""
    H = np.asarray(camera.H, dtype=float)
    scale = float(math.hypot(H[2, 0], H[2, 1]))
    if not (math.isfinite(scale) and scale > 0):
        raise CalibrationError("the homography's third row has no horizontal part (H[2,0] = H[2,1] = 0): the "
                               "camera looks straight down, box sizes cannot give depth; re-run the calibration")
    return scale


def depth_of_world(camera, xw, yw):
    """Depth (m, positive in front) of world points: -z_p / hypot(H[2,0], H[2,1])."""
    return -np.asarray(camera.zp_of_world(xw, yw), dtype=float) / depth_scale(camera)


def ideal_y_of_depth(camera, xp, depth):
    """The ideal y of the sea point at ideal x ``xp`` and depth ``depth`` (m): the paper's BBToY_P.

    NaN where the depth is not positive and finite.
    """
    G = np.asarray(camera.H_inv, dtype=float)
    depth = np.asarray(depth, dtype=float)
    xp = np.asarray(xp, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_zp = -1.0 / (depth * depth_scale(camera))
        y = (inv_zp - G[2, 0] * xp - G[2, 2]) / G[2, 1]
    ok = np.isfinite(depth) & (depth > 0) & np.isfinite(y)
    out = np.where(ok, y, np.nan)
    return float(out) if out.ndim == 0 else out


def box_cut_by_border(boxes_xyxy, image_size, margin: float = BORDER_MARGIN_PX):
    """(N, 2) bool: (width cut, height cut) for boxes touching the left/right or top/bottom image border."""
    b = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    width, height = image_size
    cut_w = (b[:, 0] <= margin) | (b[:, 2] >= width - margin)
    cut_h = (b[:, 1] <= margin) | (b[:, 3] >= height - margin)
    return np.column_stack([cut_w, cut_h])


@dataclass(frozen=True)
class BoxSizeDistanceModel:
    """``width = a / depth + b``, ``height = c / depth + d`` (full-resolution px, depth in m, see module doc).

    ``sigma_width_px`` and ``sigma_height_px`` are the robust standard deviations of the fit residuals.
    The defaults are the fit on the 66 hand boxes of training videos 7-12 with the calibration fitted on the
    same videos (``./vessel fit distance-model``).
    """

    a: float = 4838.3043242984
    b: float = 6.0449776177
    c: float = 2844.3419953655
    d: float = -0.2718582771
    sigma_width_px: float = 14.0365271393
    sigma_height_px: float = 11.913855257
    n_points: int = 66
    source: str = "screen_labels videos 7-12, camera aitas_camera.yaml"

    def __post_init__(self) -> None:
        """Reject constants that would make the inversion meaningless."""
        for name in ("a", "c"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise DataError(f"distance model: {name} must be a positive number (px x m), got {value!r}")
        for name in ("b", "d"):
            if not math.isfinite(getattr(self, name)):
                raise DataError(f"distance model: {name} must be a finite number of px, got {getattr(self, name)!r}")
        for name in ("sigma_width_px", "sigma_height_px"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise DataError(f"distance model: {name} must be > 0, got {value!r}")

    # ------------------------------------------------------------------ forward and inverse
    def size_of_depth(self, depth):
        """Expected (width, height) in px at ``depth`` metres."""
        depth = np.asarray(depth, dtype=float)
        return self.a / depth + self.b, self.c / depth + self.d

    def depth_from_width(self, width_px):
        """Depth (m) from a box width; NaN where the width is not above ``b`` (no finite depth)."""
        return _invert(width_px, self.a, self.b)

    def depth_from_height(self, height_px):
        """Depth (m) from a box height; NaN where the height is not above ``d``."""
        return _invert(height_px, self.c, self.d)

    def ideal_y_from_sizes(self, camera, xp, width_px, height_px):
        """(y from width, y from height): ideal y of the vessel given its ideal x and box size; NaN if unusable."""
        return (ideal_y_of_depth(camera, xp, self.depth_from_width(width_px)),
                ideal_y_of_depth(camera, xp, self.depth_from_height(height_px)))

    def ideal_y_sigma(self, camera) -> tuple[float, float]:
        """Standard deviation (ideal px) of the y from width and from height implied by the size residuals."""
        G = np.asarray(camera.H_inv, dtype=float)
        n = depth_scale(camera)
        return (self.sigma_width_px / (self.a * n * abs(G[2, 1])),
                self.sigma_height_px / (self.c * n * abs(G[2, 1])))

    # ------------------------------------------------------------------ parameters
    def to_params(self) -> dict:
        """The ``distance_model`` block of the fuser's parameters."""
        return {"a": float(self.a), "b": float(self.b), "c": float(self.c), "d": float(self.d),
                "sigma_width_px": float(self.sigma_width_px), "sigma_height_px": float(self.sigma_height_px),
                "n_points": int(self.n_points), "source": str(self.source)}

    @classmethod
    def from_params(cls, params: dict) -> BoxSizeDistanceModel:
        """Build from a ``distance_model`` block; missing keys take the defaults."""
        defaults = cls()
        try:
            return cls(**{k: type(getattr(defaults, k))(params[k]) for k in
                          ("a", "b", "c", "d", "sigma_width_px", "sigma_height_px", "n_points", "source")
                          if k in params})
        except (TypeError, ValueError) as error:
            raise DataError(f"distance model: a value of the distance_model block is not a number: {error}") from None


def _invert(size, k, offset):
    size = np.asarray(size, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = k / (size - offset)
    ok = np.isfinite(depth) & (size - offset > 0)
    out = np.where(ok, depth, np.nan)
    return float(out) if out.ndim == 0 else out
