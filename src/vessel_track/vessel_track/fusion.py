"""Screen -> sea plane for one box: position cue and box-size cues fused, with an honest covariance.

The paper's post-processing step 2: the vessel's ideal y comes from three cues,

* the box position (its reference point, the centre by default, undistorted),
* the depth implied by the box width and by the box height (``vessel_track.distance_model``),

fused as ``y = 0.5 y_position + 0.25 y_width + 0.25 y_height`` (the paper) or, by default, with the weights
that minimise the variance of the fused y given the covariance of the three cues measured on training
boxes (generalised least squares: ``w = S^-1 1 / (1' S^-1 1)``; the cues' errors are correlated because the
same box edges feed them). A cue whose box edge is cut by the image border is dropped and the weights
renormalised. The fused ideal point goes through ``H^-1`` to metres; points on or above the horizon or beyond
``max_range_m`` are rejected, positions clipped to ±``clip_m`` as in the paper. The 2x2 position covariance is
the pixel covariance pushed through the Jacobian of the back-projection, so it is long along the line of sight.

``vessel_track.track_fuser.TrackFuser`` applies this per track and frame, with a world Kalman filter per track and
the online vessel-of-interest selection.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vessel_common.errors import DataError
from vessel_track.distance_model import MAD_TO_SIGMA, BoxSizeDistanceModel, box_cut_by_border, depth_scale

WEIGHT_MODES = ("fitted", "paper", "position_only")
#: Which box of a track the fuser measures: the detection associated in this image, or the tracker's filtered box.
SCREEN_SOURCES = ("measured", "filtered")

#: Covariance of the cues' ideal-y errors (position, width, height), px^2, measured leave-one-video-out on the
#: hand boxes of training videos 7-12 (``./vessel fit distance-model``).
DEFAULT_CUE_COVARIANCE = (5.7147051439, -4.8621659687, -4.9854487734, -4.8621659687, 68.5918439092, 48.7700666298,
                          -4.9854487734, 48.7700666298, 54.709869639)
PAPER_WEIGHTS = (0.5, 0.25, 0.25)
#: measured boxes of a track whose median aspect a new box is compared with (``FusionConfig.shape_jump_ratio``)
SHAPE_HISTORY = 5
#: measured boxes of a track whose median height a new box is compared with (``FusionConfig.height_drop_ratio``;
#: 3 chosen on training videos 7-12 against 5)
HEIGHT_HISTORY = 3

# Why a box gave no position.
REASON_OK = 0
REASON_INVALID_INPUT = 1
REASON_ABOVE_HORIZON = 2
REASON_BEYOND_RANGE = 3
REASON_NAMES = {REASON_OK: "ok", REASON_INVALID_INPUT: "invalid_box", REASON_ABOVE_HORIZON: "above_horizon",
                REASON_BEYOND_RANGE: "beyond_max_range"}


@dataclass(frozen=True)
class CueStatistics:
    """Measured noise of the three y cues (position, width, height) and of x, in ideal pixels.

    ``covariance`` (3, 3) of the cues' y errors; ``x_std_px`` the position cue's x error; ``weights`` the
    variance-minimising weights of all three; ``fused_std_px`` the std of the fused y with those weights.
    """

    covariance: np.ndarray = field(default_factory=lambda: np.array(DEFAULT_CUE_COVARIANCE).reshape(3, 3))
    x_std_px: float = 11.9438446049
    n_points: int = 65

    def __post_init__(self) -> None:
        """Check the covariance is a usable 3x3 positive-definite matrix."""
        cov = np.asarray(self.covariance, dtype=float).reshape(3, 3)
        cov = 0.5 * (cov + cov.T)
        if not np.all(np.isfinite(cov)) or np.any(np.linalg.eigvalsh(cov) <= 0):
            raise DataError("fusion: cue_covariance must be a finite positive-definite 3x3 matrix (9 numbers)")
        object.__setattr__(self, "covariance", cov)
        if not (math.isfinite(self.x_std_px) and self.x_std_px > 0):
            raise DataError(f"fusion: cue_x_std_px must be > 0, got {self.x_std_px!r}")

    @property
    def std_px(self) -> np.ndarray:
        """Standard deviation of each cue's y, ideal px."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def weights(self) -> np.ndarray:
        """Variance-minimising weights of (position, width, height)."""
        return gls_weights(self.covariance, np.ones(3, dtype=bool))[0]

    def to_params(self) -> dict:
        """The ``fusion.cue_*`` parameters."""
        return {"cue_covariance": [float(v) for v in self.covariance.ravel()], "cue_x_std_px": float(self.x_std_px),
                "cue_n_points": int(self.n_points)}


def gls_weights(covariance: np.ndarray, available: np.ndarray) -> tuple[np.ndarray, float]:
    """Weights over the ``available`` cues minimising the fused variance; returns (weights (3,), variance)."""
    idx = np.flatnonzero(available)
    weights = np.zeros(3)
    if idx.size == 0:
        return weights, math.nan
    sub = covariance[np.ix_(idx, idx)]
    inv_one = np.linalg.solve(sub, np.ones(idx.size))
    total = float(inv_one.sum())
    weights[idx] = inv_one / total
    return weights, 1.0 / total


def fixed_weights(base, covariance: np.ndarray, available: np.ndarray) -> tuple[np.ndarray, float]:
    """``base`` weights renormalised over the available cues; returns (weights, variance of the fused y)."""
    weights = np.where(available, np.asarray(base, dtype=float), 0.0)
    total = weights.sum()
    if total <= 0:
        return np.zeros(3), math.nan
    weights = weights / total
    return weights, float(weights @ covariance @ weights)


@dataclass(frozen=True)
class FusionConfig:
    """How boxes become positions.

    weights_mode: ``fitted`` (variance-minimising, from the measured cue covariance), ``paper`` (0.5, 0.25,
        0.25 for position, width, height) or ``position_only`` (the box position alone).
    anchor_offset: where down its box a tracked vessel's position is read, relative to the calibration's
        ``camera.box_anchor`` (the point of the hand-drawn boxes H was fitted on): 0 reads boxes as the
        calibration did; a detector whose boxes sit differently on a vessel than hand-drawn ones (taller, with
        the wake, without the mast) reads them ``anchor_offset`` box heights lower (negative: higher).
    max_range_m: positions further than this from the camera are rejected (1 px near the horizon is
        hundreds of metres out there).
    clip_m: positions are clipped to ±clip_m east and north (the paper: 2000).
    min_depth_m: points closer than this in depth (behind or at the camera) are rejected.
    screen_source: ``measured`` (the detection associated with the track in this image: independent
        measurements for the world filter, which does the smoothing) or ``filtered`` (the tracker's filtered
        box, which a second filter then smooths again). Measured on the training videos 7-12: the raw box is
        better online and offline, with hand boxes and with the detector.
    shape_jump_ratio: a box whose aspect (height / width) is more than this many times the median aspect of its
        track's last ``SHAPE_HISTORY`` measured boxes is suspect: a detector box that took in the spray or wake
        below a fast hull is taller for its width, and its bottom, so its position, sits too near. Its position
        covariance is multiplied by ``shape_jump_variance_factor``, so the world filter and the offline
        smoother lean on the track's motion instead. 0: off (hand-drawn boxes, tight around the hull).
    shape_jump_variance_factor: that multiplier (>= 1).
    height_drop_ratio: a box less than this share as tall as the median of its track's last ``HEIGHT_HISTORY``
        measured boxes is suspect too: the detector boxed part of the vessel (its console or cabin, seen from the
        side), whose bottom is not the waterline, so its position sits too far, or too near when the part is a
        low one. Its covariance gets the same ``shape_jump_variance_factor``. 0: off (hand-drawn boxes).
    """

    weights_mode: str = "fitted"
    anchor_offset: float = 0.0
    max_range_m: float = 2000.0
    clip_m: float = 2000.0
    min_depth_m: float = 1.0
    screen_source: str = "measured"
    shape_jump_ratio: float = 0.0
    shape_jump_variance_factor: float = 9.0
    height_drop_ratio: float = 0.0

    def __post_init__(self) -> None:
        """Validate the fields."""
        if self.weights_mode not in WEIGHT_MODES:
            raise DataError(f"fusion: weights_mode must be one of {', '.join(WEIGHT_MODES)}, got "
                            f"{self.weights_mode!r}")
        if self.screen_source not in SCREEN_SOURCES:
            raise DataError(f"fusion: screen_source must be one of {', '.join(SCREEN_SOURCES)}, got "
                            f"{self.screen_source!r}")
        if not (math.isfinite(self.anchor_offset) and -1.0 <= self.anchor_offset <= 1.0):
            raise DataError(f"fusion: anchor_offset must be in [-1, 1] box heights, got {self.anchor_offset!r}")
        for name in ("max_range_m", "clip_m", "min_depth_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise DataError(f"fusion: {name} must be a positive number of metres, got {value!r}")
        if not (math.isfinite(self.shape_jump_ratio) and (self.shape_jump_ratio == 0 or self.shape_jump_ratio > 1)):
            raise DataError(f"fusion: shape_jump_ratio must be 0 (off) or a ratio > 1, got {self.shape_jump_ratio!r}")
        if not (math.isfinite(self.height_drop_ratio) and 0 <= self.height_drop_ratio < 1):
            raise DataError(f"fusion: height_drop_ratio must be 0 (off) or a share in (0, 1), got "
                            f"{self.height_drop_ratio!r}")
        if not (math.isfinite(self.shape_jump_variance_factor) and self.shape_jump_variance_factor >= 1):
            raise DataError("fusion: shape_jump_variance_factor must be a finite number >= 1, got "
                            f"{self.shape_jump_variance_factor!r}")

    def to_params(self) -> dict:
        """The ``fusion`` parameters (without the cue statistics)."""
        return {"weights_mode": self.weights_mode, "anchor_offset": float(self.anchor_offset),
                "max_range_m": float(self.max_range_m), "clip_m": float(self.clip_m),
                "min_depth_m": float(self.min_depth_m), "screen_source": self.screen_source,
                "shape_jump_ratio": float(self.shape_jump_ratio),
                "shape_jump_variance_factor": float(self.shape_jump_variance_factor),
                "height_drop_ratio": float(self.height_drop_ratio)}


@dataclass
class FusedBoxes:
    """Result of ``fuse_boxes`` for N boxes (arrays; NaN where invalid)."""

    world: np.ndarray          # (N, 2) metres east, north
    covariance: np.ndarray     # (N, 2, 2) m^2
    valid: np.ndarray          # (N,) bool
    reason: np.ndarray         # (N,) int, REASON_*
    ideal_x: np.ndarray        # (N,) ideal x of the reference point
    cue_y: np.ndarray          # (N, 3) ideal y from position, width, height (NaN: cue unavailable)
    fused_y: np.ndarray        # (N,) fused ideal y
    fused_y_std: np.ndarray    # (N,) its standard deviation, ideal px
    weights: np.ndarray        # (N, 3) weights used
    screen: np.ndarray         # (N, 2) the fused point on screen (px)

    @property
    def distance_m(self) -> np.ndarray:
        """Range from the camera, m."""
        return np.hypot(self.world[:, 0], self.world[:, 1])


def ideal_to_world_jacobian(camera, xp, yp) -> np.ndarray:
    """d(x_w, y_w)/d(x_p, y_p), shape (N, 2, 2), from H^-1."""
    G = np.asarray(camera.H_inv, dtype=float)
    xp = np.asarray(xp, dtype=float).reshape(-1)
    yp = np.asarray(yp, dtype=float).reshape(-1)
    W = G[2, 0] * xp + G[2, 1] * yp + G[2, 2]
    xw = (G[0, 0] * xp + G[0, 1] * yp + G[0, 2]) / W
    yw = (G[1, 0] * xp + G[1, 1] * yp + G[1, 2]) / W
    J = np.empty((xp.size, 2, 2))
    J[:, 0, 0] = (G[0, 0] - xw * G[2, 0]) / W
    J[:, 0, 1] = (G[0, 1] - xw * G[2, 1]) / W
    J[:, 1, 0] = (G[1, 0] - yw * G[2, 0]) / W
    J[:, 1, 1] = (G[1, 1] - yw * G[2, 1]) / W
    return J


def fuse_boxes(camera, model: BoxSizeDistanceModel, boxes_xyxy, config: FusionConfig | None = None,
               stats: CueStatistics | None = None, pose_sigma_px=None) -> FusedBoxes:
    """Fuse position and size cues of each box (N, 4 full-resolution px) into sea-plane positions.

    The box position is read where the calibration was fitted (``camera.box_reference_points``), shifted by
    ``config.anchor_offset``. ``pose_sigma_px`` (N, 2): the standard deviation the camera pose's uncertainty adds
    to each box's ideal x and y (a camera that moves); it weighs on the position cue only, since a rotation of
    the camera does not change a box's size, so the size cues gain weight when the pose is poorly known.
    """
    config = config or FusionConfig()
    stats = stats or CueStatistics()
    boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    ok_input, xp, cue_y = _cues(camera, model, boxes, config)
    pose_var = np.zeros((boxes.shape[0], 2)) if pose_sigma_px is None else np.square(
        np.nan_to_num(np.asarray(pose_sigma_px, dtype=float).reshape(-1, 2)))
    weights, var_y = _cue_weights(cue_y, config, stats, pose_var[:, 1])
    fused_y = np.where(ok_input, np.nansum(np.nan_to_num(cue_y) * weights, axis=1), np.nan)
    world, reason = _sea_plane(camera, xp, fused_y, ok_input, config)
    valid = reason == REASON_OK
    world[~valid] = np.nan
    covariance = _world_covariance(camera, xp, fused_y, var_y, valid, stats, pose_var[:, 0])
    xs, ys = camera.distort(xp, fused_y)
    screen = np.column_stack([np.asarray(xs, dtype=float).reshape(-1), np.asarray(ys, dtype=float).reshape(-1)])
    screen[~valid] = np.nan
    return FusedBoxes(world, covariance, valid, reason, xp, cue_y, np.where(valid, fused_y, np.nan),
                      np.sqrt(var_y), weights, screen)


def _cues(camera, model: BoxSizeDistanceModel, boxes: np.ndarray,
          config: FusionConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N,) usable boxes, (N,) ideal x of their reference points, (N, 3) ideal y of each cue (NaN: unavailable).

    A size cue whose box edge is cut by the image border is unavailable.
    """
    n = boxes.shape[0]
    sizes = boxes[:, 2:] - boxes[:, :2]
    ok_input = np.all(np.isfinite(boxes), axis=1) & np.all(sizes > 0, axis=1)
    safe = np.where(ok_input[:, None], boxes, np.array([0.0, 0.0, 1.0, 1.0]))
    ref = camera.box_reference_points(safe, config.anchor_offset)
    xp, yp_pos = camera.undistort(ref[:, 0], ref[:, 1])
    xp = np.asarray(xp, dtype=float).reshape(-1)
    yp_pos = np.asarray(yp_pos, dtype=float).reshape(-1)
    ok_input &= np.isfinite(xp) & np.isfinite(yp_pos)
    cue_y = np.full((n, 3), np.nan)
    cue_y[:, 0] = yp_pos
    if config.weights_mode != "position_only":
        y_w, y_h = model.ideal_y_from_sizes(camera, xp, sizes[:, 0], sizes[:, 1])
        cut = box_cut_by_border(safe, camera.image_size)
        cue_y[:, 1] = np.where(cut[:, 0], np.nan, y_w)
        cue_y[:, 2] = np.where(cut[:, 1], np.nan, y_h)
    cue_y[~ok_input] = np.nan
    return ok_input, xp, cue_y


def _cue_weights(cue_y: np.ndarray, config: FusionConfig, stats: CueStatistics,
                 pose_var_y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) weights of each box's available cues by ``config.weights_mode``, and (N,) the fused y's variance.

    ``pose_var_y`` (N,): variance the camera's pose adds to the position cue (0 for a fixed camera).
    """
    n = cue_y.shape[0]
    weights = np.zeros((n, 3))
    var_y = np.full(n, np.nan)
    for i in range(n):
        available = np.isfinite(cue_y[i])
        if not available[0]:
            continue  # without the box position there is no x either
        covariance = stats.covariance
        if pose_var_y[i] > 0:
            covariance = covariance.copy()
            covariance[0, 0] += pose_var_y[i]
        if config.weights_mode == "fitted":
            weights[i], var_y[i] = gls_weights(covariance, available)
        elif config.weights_mode == "paper":
            weights[i], var_y[i] = fixed_weights(PAPER_WEIGHTS, covariance, available)
        else:
            weights[i], var_y[i] = fixed_weights((1.0, 0.0, 0.0), covariance, available)
    return weights, var_y


def _sea_plane(camera, xp: np.ndarray, fused_y: np.ndarray, ok_input: np.ndarray,
               config: FusionConfig) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) sea-plane positions of the fused ideal points, clipped to ``clip_m``, and (N,) each one's REASON_*."""
    xw, yw, in_front = camera.ideal_to_world(xp, fused_y)
    xw = np.asarray(xw, dtype=float).reshape(-1)
    yw = np.asarray(yw, dtype=float).reshape(-1)
    in_front = np.asarray(in_front, dtype=bool).reshape(-1)
    reason = np.full(xp.shape[0], REASON_OK)
    reason[~ok_input] = REASON_INVALID_INPUT
    depth = -np.asarray(camera.zp_of_world(np.nan_to_num(xw), np.nan_to_num(yw)), dtype=float)

    depth = depth / depth_scale(camera)
    above = ok_input & (~in_front | ~(depth >= config.min_depth_m))
    reason[above] = REASON_ABOVE_HORIZON
    rng = np.hypot(xw, yw)
    beyond = ok_input & ~above & ~(rng <= config.max_range_m)
    reason[beyond] = REASON_BEYOND_RANGE
    world = np.column_stack([np.clip(xw, -config.clip_m, config.clip_m), np.clip(yw, -config.clip_m, config.clip_m)])
    return world, reason


def _world_covariance(camera, xp: np.ndarray, fused_y: np.ndarray, var_y: np.ndarray, valid: np.ndarray,
                      stats: CueStatistics, pose_var_x: np.ndarray) -> np.ndarray:
    """(N, 2, 2) covariance of the positions: the ideal pixels' pushed through the back-projection's Jacobian."""
    n = xp.shape[0]
    J = ideal_to_world_jacobian(camera, np.where(valid, xp, 0.0), np.where(valid, fused_y, 0.0))
    cov_px = np.zeros((n, 2, 2))
    cov_px[:, 0, 0] = stats.x_std_px**2 + pose_var_x
    cov_px[:, 1, 1] = np.where(valid, var_y, 1.0)
    covariance = J @ cov_px @ np.swapaxes(J, 1, 2)
    covariance = 0.5 * (covariance + np.swapaxes(covariance, 1, 2))
    covariance[~valid] = np.nan
    return covariance


def boxes_from_centers(centers, sizes) -> np.ndarray:
    """(N, 4) x1, y1, x2, y2 from centres (N, 2) and sizes (N, 2)."""
    c = np.asarray(centers, dtype=float).reshape(-1, 2)
    s = np.asarray(sizes, dtype=float).reshape(-1, 2)
    return np.column_stack([c - s / 2.0, c + s / 2.0])


def cue_residuals(camera, model: BoxSizeDistanceModel, boxes_xyxy, world_xy, config: FusionConfig | None = None):
    """Per box: the three cues' ideal-y errors (N, 3) and the ideal-x error (N,) against the true positions."""
    config = config or FusionConfig()
    boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    world = np.asarray(world_xy, dtype=float).reshape(-1, 2)
    fused = fuse_boxes(camera, model, boxes, FusionConfig(weights_mode="paper", anchor_offset=config.anchor_offset,
                                                          max_range_m=1e9, clip_m=1e9), CueStatistics())
    xp_true, yp_true, zp = camera.world_to_ideal(world[:, 0], world[:, 1])
    behind = ~(np.asarray(zp, dtype=float).reshape(-1) < 0)
    resid = fused.cue_y - np.asarray(yp_true, dtype=float).reshape(-1)[:, None]
    x_resid = fused.ideal_x - np.asarray(xp_true, dtype=float).reshape(-1)
    resid[behind] = np.nan
    return resid, x_resid


def fit_cue_statistics(camera, model: BoxSizeDistanceModel, boxes_xyxy, world_xy,
                       config: FusionConfig | None = None) -> CueStatistics:
    """Measure the cues' y errors (and the x error) against the true positions of training boxes.

    Robust: residuals beyond 4 robust sigmas are left out of the covariance. Boxes cut by the border are
    left out (their size cues do not exist).
    """
    resid, x_resid = cue_residuals(camera, model, boxes_xyxy, world_xy, config)
    return cue_statistics_of_residuals(resid, x_resid)


def cue_statistics_of_residuals(resid, x_resid) -> CueStatistics:
    """Robust covariance of cue residuals (N, 3) and robust std of x residuals (N,), see fit_cue_statistics."""
    resid = np.asarray(resid, dtype=float).reshape(-1, 3)
    x_resid = np.asarray(x_resid, dtype=float).reshape(-1)
    ok = np.all(np.isfinite(resid), axis=1) & np.isfinite(x_resid)
    if ok.sum() < 5:
        raise DataError(f"fusion: only {int(ok.sum())} training boxes have all three cues (need 5)")
    r = resid[ok]
    med = np.median(r, axis=0)
    sig = np.maximum(MAD_TO_SIGMA * np.median(np.abs(r - med), axis=0), 0.3)
    inliers = np.all(np.abs(r - med) <= 4.0 * sig, axis=1)
    r_in = r[inliers]
    cov = np.cov(r_in, rowvar=False, bias=False) if r_in.shape[0] > 3 else np.diag(sig**2)
    cov = cov + np.eye(3) * 1e-6
    xr = x_resid[ok]
    x_std = max(MAD_TO_SIGMA * float(np.median(np.abs(xr - np.median(xr)))), 0.5)
    return CueStatistics(cov, x_std, int(r_in.shape[0]))
