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

``TrackFuser`` applies this per track and frame, runs a ``WorldKalmanFilter`` per track and the online
vessel-of-interest selection: it is the core of the ``fuser`` node and of the pipeline's online mode.
"""
from __future__ import annotations

import copy
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from vessel_calib import geodesy
from vessel_common.errors import CalibrationError, DataError
from vessel_common.state_file import fields_of, object_state, restore_object, set_fields
from vessel_track.distance_model import MAD_TO_SIGMA, BoxSizeDistanceModel, box_cut_by_border, depth_scale
from vessel_track.error_model import ErrorModel
from vessel_track.selection import OnlineTargetSelector, SelectionConfig, _Running
from vessel_track.smoothing import FilterOutput, MotionConfig, WorldKalmanFilter

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
               stats: CueStatistics | None = None) -> FusedBoxes:
    """Fuse position and size cues of each box (N, 4 full-resolution px) into sea-plane positions.

    The box position is read where the calibration was fitted (``camera.box_reference_points``), shifted by
    ``config.anchor_offset``.
    """
    config = config or FusionConfig()
    stats = stats or CueStatistics()
    boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
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
    weights = np.zeros((n, 3))
    var_y = np.full(n, np.nan)
    for i in range(n):
        available = np.isfinite(cue_y[i])
        if not available[0]:
            continue  # without the box position there is no x either
        if config.weights_mode == "fitted":
            weights[i], var_y[i] = gls_weights(stats.covariance, available)
        elif config.weights_mode == "paper":
            weights[i], var_y[i] = fixed_weights(PAPER_WEIGHTS, stats.covariance, available)
        else:
            weights[i], var_y[i] = fixed_weights((1.0, 0.0, 0.0), stats.covariance, available)
    fused_y = np.where(ok_input, np.nansum(np.nan_to_num(cue_y) * weights, axis=1), np.nan)
    xw, yw, in_front = camera.ideal_to_world(xp, fused_y)
    xw = np.asarray(xw, dtype=float).reshape(-1)
    yw = np.asarray(yw, dtype=float).reshape(-1)
    in_front = np.asarray(in_front, dtype=bool).reshape(-1)
    reason = np.full(n, REASON_OK)
    reason[~ok_input] = REASON_INVALID_INPUT
    depth = -np.asarray(camera.zp_of_world(np.nan_to_num(xw), np.nan_to_num(yw)), dtype=float)

    depth = depth / depth_scale(camera)
    above = ok_input & (~in_front | ~(depth >= config.min_depth_m))
    reason[above] = REASON_ABOVE_HORIZON
    rng = np.hypot(xw, yw)
    beyond = ok_input & ~above & ~(rng <= config.max_range_m)
    reason[beyond] = REASON_BEYOND_RANGE
    valid = reason == REASON_OK
    world = np.column_stack([np.clip(xw, -config.clip_m, config.clip_m), np.clip(yw, -config.clip_m, config.clip_m)])
    world[~valid] = np.nan
    J = ideal_to_world_jacobian(camera, np.where(valid, xp, 0.0), np.where(valid, fused_y, 0.0))
    cov_px = np.zeros((n, 2, 2))
    cov_px[:, 0, 0] = stats.x_std_px**2
    cov_px[:, 1, 1] = np.where(valid, var_y, 1.0)
    covariance = J @ cov_px @ np.swapaxes(J, 1, 2)
    covariance = 0.5 * (covariance + np.swapaxes(covariance, 1, 2))
    covariance[~valid] = np.nan
    xs, ys = camera.distort(xp, fused_y)
    screen = np.column_stack([np.asarray(xs, dtype=float).reshape(-1), np.asarray(ys, dtype=float).reshape(-1)])
    screen[~valid] = np.nan
    return FusedBoxes(world, covariance, valid, reason, xp, cue_y, np.where(valid, fused_y, np.nan),
                      np.sqrt(var_y), weights, screen)


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


# ---------------------------------------------------------------------------------------------------------
# Per-track online fusion


@dataclass
class ScreenTrack:
    """One tracked vessel as the fuser receives it (from a ``TrackState`` or a ``VesselTrack`` message)."""

    track_id: str
    status: int                 # TrackStatus / VesselTrack.STATUS_*
    center: np.ndarray          # (2,) px
    size: np.ndarray            # (2,) px
    confidence: float
    updated: bool               # a detection was associated in this frame
    detection_count: int = 0
    first_seen: float = math.nan
    last_seen: float = math.nan
    center_cov: np.ndarray | None = None
    velocity_px: np.ndarray | None = None

    @property
    def box_xyxy(self) -> np.ndarray:
        """(4,) box around the centre."""
        return boxes_from_centers(self.center, self.size)[0]


STATUS_LOST = 3
STATUS_TENTATIVE = 0


@dataclass
class WorldTrack:
    """A track after fusion: the screen track plus its filtered sea-plane state (NaN when unknown)."""

    screen: ScreenTrack
    stamp: float
    has_world: bool = False
    position: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    velocity: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    position_covariance: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    velocity_covariance: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    latitude: float = math.nan
    longitude: float = math.nan
    distance_m: float = math.nan
    bearing_deg: float = math.nan
    expected_error_m: float = math.nan
    is_target: bool = False
    score: float = 0.0
    measured_position: np.ndarray | None = None   # this frame's fused (unfiltered) position, if any
    measured_covariance: np.ndarray | None = None
    measured_screen: np.ndarray | None = None     # the fused point on screen, px
    rejected_reason: str = ""                     # why this frame's box gave no position ("" if it did)


class TrackFuser:
    """Per-frame fusion, per-track world Kalman filter and online target selection.

    The filters follow the selection's view of identity: a track the selection joins to an earlier one continues
    that one's filter, and a track whose filter restarts after ``motion.max_rejections`` outliers in a row has its
    selection history ended (``OnlineTargetSelector.identity_changed``).

    ``update(stamp, tracks)`` takes every track of one image (``ScreenTrack``) and returns a ``WorldTrack``
    for each. ``counts`` records bad input and rejections by kind (for the node's diagnostics).
    """

    def __init__(self, camera, distance_model: BoxSizeDistanceModel | None = None,
                 fusion_config: FusionConfig | None = None, cue_stats: CueStatistics | None = None,
                 motion_config: MotionConfig | None = None, selection_config: SelectionConfig | None = None,
                 error_model: ErrorModel | None = None, water_level=None, water_level_max_hold_s: float = 900.0):
        if camera.camera_lat is None:
            raise DataError("fuser: the camera model has no position (camera_lat/camera_lon); set them in the "
                            "calibration file")
        if water_level is not None and not math.isfinite(camera.water_level_m):
            raise DataError(f"fuser: a water-level file is set ({water_level.source or 'water_level.file'}) but the "
                            "calibration has no camera.water_level_m to correct from; re-run calibrate with "
                            "--water-level FILE.csv, or set water_level.file to ''")
        self.camera = camera
        self.water_level = water_level
        self.water_level_max_hold_s = float(water_level_max_hold_s)
        self.distance_model = distance_model or BoxSizeDistanceModel()
        self.fusion_config = fusion_config or FusionConfig()
        self.cue_stats = cue_stats or CueStatistics()
        self.motion_config = motion_config or MotionConfig()
        self.selector = OnlineTargetSelector(selection_config or SelectionConfig())
        self.error_model = error_model or ErrorModel()
        self.filters: dict[str, WorldKalmanFilter] = {}
        self._ended_filters: dict[str, WorldKalmanFilter] = {}   # of ended tracks, while a join may continue them
        self._shapes: dict[str, deque] = {}   # recent (aspect, height) of each track's boxes (shape_jump, height_drop)
        self.last_stamp: float | None = None
        self.counts: dict[str, int] = {}

    def _count(self, kind: str) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + 1

    def reset(self) -> None:
        """Forget every track (a replay restarted)."""
        self.filters.clear()
        self._ended_filters.clear()
        self._shapes.clear()
        self.selector.reset()
        self.last_stamp = None

    def snapshot(self) -> dict:
        """The world filters and selection history ``restore`` needs to carry on in another process, as plain data.

        Numbers, strings, containers and numpy arrays only: what a state file holds (``vessel_common.state_file``).
        Each world filter and the selector by its attributes, except the settings (the restored fuser's own).
        """
        def filters(by_id: dict) -> dict:
            return {track_id: fields_of(kf, skip=("config",)) for track_id, kf in by_id.items()}

        return {"filters": filters(self.filters), "ended_filters": filters(self._ended_filters),
                "shapes": {track_id: list(shapes) for track_id, shapes in self._shapes.items()},
                "selector": object_state(self.selector, _Running, skip=("config",)), "last_stamp": self.last_stamp}

    def restore(self, snapshot: dict) -> None:
        """Carry on from ``snapshot()`` of a fuser with the same settings (a node restarted after a crash).

        ValueError (KeyError, TypeError) for a snapshot with other fields than this version's: the fuser is then
        left as it was.
        """
        def filters(by_id: dict) -> dict:
            return {str(track_id): set_fields(WorldKalmanFilter(self.motion_config), fields, "a world filter",
                                              skip=("config",)) for track_id, fields in dict(by_id).items()}

        shapes = {str(track_id): deque(((float(aspect), float(height)) for aspect, height in history),
                                       maxlen=SHAPE_HISTORY) for track_id, history in dict(snapshot["shapes"]).items()}
        selector = restore_object(OnlineTargetSelector(self.selector.config), snapshot["selector"], _Running,
                                  "the target selection", skip=("config",))
        restored = (filters(snapshot["filters"]), filters(snapshot["ended_filters"]), shapes, selector,
                    None if snapshot["last_stamp"] is None else float(snapshot["last_stamp"]))
        self.filters, self._ended_filters, self._shapes, self.selector, self.last_stamp = restored

    def update(self, stamp: float, tracks: list[ScreenTrack]) -> list[WorldTrack]:
        """Fuse one frame's tracks; raises DataError only for a non-finite stamp."""
        stamp = float(stamp)
        if not math.isfinite(stamp):
            raise DataError(f"fuser: stamp must be finite seconds, got {stamp}")
        if self.last_stamp is not None and stamp < self.last_stamp:
            self._count("stamp_backwards")
            self.reset()
        elif self.last_stamp is not None and stamp - self.last_stamp > self.motion_config.max_gap_s:
            self._count("gap")
        self.last_stamp = stamp
        good: list[ScreenTrack] = []
        out: list[WorldTrack] = []
        for track in tracks:
            if not (np.all(np.isfinite(track.center)) and np.all(np.isfinite(track.size)) and
                    np.all(np.asarray(track.size) > 0)):
                self._count("invalid_track")
                out.append(WorldTrack(track, stamp, rejected_reason=REASON_NAMES[REASON_INVALID_INPUT]))
                if track.status == STATUS_LOST:
                    self.filters.pop(track.track_id, None)
                continue
            good.append(track)
        measured = [t for t in good if t.updated and t.status != STATUS_LOST]
        fused = None
        if measured:
            boxes = np.array([t.box_xyxy for t in measured]).reshape(-1, 4)
            fused = fuse_boxes(self.camera_at(stamp), self.distance_model, boxes, self.fusion_config, self.cue_stats)
        fused_by_id = {t.track_id: i for i, t in enumerate(measured)}
        world_tracks: list[WorldTrack] = []
        changed_identity: list[str] = []
        for track in good:
            wt = WorldTrack(track, stamp)
            kf = self.filters.get(track.track_id)
            result: FilterOutput | None = None
            if track.status == STATUS_LOST:
                if kf is not None and kf.initialised:
                    result = kf.predict(stamp)
                    self._ended_filters[track.track_id] = kf
                self.filters.pop(track.track_id, None)
            elif track.track_id in fused_by_id:
                i = fused_by_id[track.track_id]
                if kf is None:
                    kf = self.filters[track.track_id] = WorldKalmanFilter(self.motion_config)
                if fused.valid[i]:
                    wt.measured_position = fused.world[i].copy()
                    wt.measured_covariance = fused.covariance[i] * self._shape_factor(track)
                    wt.measured_screen = fused.screen[i].copy()
                    result = kf.update(stamp, fused.world[i], wt.measured_covariance)
                    if result is not None and not result.accepted and not result.restarted:
                        self._count("outlier_rejected")
                    if result is not None and result.restart_reason == "rejections":
                        self._count("identity_changed")
                        changed_identity.append(track.track_id)
                else:
                    wt.rejected_reason = REASON_NAMES[int(fused.reason[i])]
                    self._count(wt.rejected_reason)
                    result = kf.predict(stamp) if kf.initialised else None
            elif kf is not None and kf.initialised:
                result = kf.predict(stamp)
            if result is not None:
                self._fill_world(wt, result)
            world_tracks.append(wt)
        present = {t.track_id for t in tracks}
        for tid in [t for t in self.filters if t not in present]:
            self._ended_filters[tid] = self.filters.pop(tid)  # vanished without a LOST report
        live = {t.track_id for t in good if t.status != STATUS_LOST}
        self._shapes = {tid: history for tid, history in self._shapes.items() if tid in live}
        for tid in changed_identity:
            self.selector.identity_changed(tid, stamp)
        target = self.selector.update(stamp, world_tracks)
        self._continue_filters(stamp, world_tracks)
        max_gap = self.selector.config.join_max_gap_s
        self._ended_filters = {tid: kf for tid, kf in self._ended_filters.items()
                               if kf.stamp is not None and 0 <= stamp - kf.stamp <= max_gap}
        for wt in world_tracks:
            wt.score = self.selector.score(wt.screen.track_id)
            wt.is_target = target is not None and wt.screen.track_id == target and wt.screen.status != STATUS_LOST
        return out + world_tracks

    def camera_at(self, stamp: float):
        """The camera for the water level at ``stamp`` (the calibration's own without a water-level file)."""
        if self.water_level is None:
            return self.camera
        level = self.water_level.level_at(stamp, self.water_level_max_hold_s)
        if not math.isfinite(level):
            self._count("water_level_unknown")
            return self.camera
        try:
            return self.camera.at_water_level(level)
        except CalibrationError:
            self._count("water_level_unusable")
            return self.camera

    def _shape_factor(self, track: ScreenTrack) -> float:
        """Covariance multiplier of this frame's box: ``shape_jump_variance_factor`` if it is suspect, else 1.

        Suspect: its aspect jumped up, or its height dropped, against the track's recent boxes.
        """
        config = self.fusion_config
        history = self._shapes.setdefault(track.track_id, deque(maxlen=SHAPE_HISTORY))
        aspect = float(track.size[1] / track.size[0])
        height = float(track.size[1])
        aspects = [a for a, _ in history]
        heights = [h for _, h in history][-HEIGHT_HISTORY:]
        jumped = config.shape_jump_ratio > 0 and len(aspects) >= 2 and aspect > config.shape_jump_ratio * float(
            np.median(aspects))
        dropped = config.height_drop_ratio > 0 and len(heights) >= 2 and height < config.height_drop_ratio * float(
            np.median(heights))
        history.append((aspect, height))
        if jumped:
            self._count("shape_jump")
        if dropped:
            self._count("height_drop")
        return config.shape_jump_variance_factor if jumped or dropped else 1.0

    def _continue_filters(self, stamp: float, world_tracks: list[WorldTrack]) -> None:
        """A track the selection joined to an earlier one (``selector.continued``) continues that one's filter too.

        Its own filter started from this frame's measurement with no velocity; the earlier track's filter knows
        how the vessel was moving, so the next frames are gated against that motion (a track that then jumps onto
        another vessel is seen by the world gate: ``identity_changed``).
        """
        by_id = {wt.screen.track_id: wt for wt in world_tracks}
        for new_id, old_id in self.selector.continued.items():
            wt = by_id.get(new_id)
            old = self._ended_filters.pop(old_id, None)
            if old is None and old_id in self.filters:
                old = copy.deepcopy(self.filters[old_id])  # a handover: the old track still coasts on its own
            if wt is None or old is None or not old.initialised or wt.measured_position is None:
                continue
            result = old.update(stamp, wt.measured_position, wt.measured_covariance)
            if result is None:
                continue
            if not result.accepted and not result.restarted:
                self._count("outlier_rejected")
            self.filters[new_id] = old
            self._fill_world(wt, result)

    def _fill_world(self, wt: WorldTrack, result: FilterOutput) -> None:
        clip = self.fusion_config.clip_m
        position = np.clip(result.position, -clip, clip)
        wt.has_world = True
        wt.position = position
        wt.velocity = result.velocity
        wt.position_covariance = result.position_covariance
        wt.velocity_covariance = result.velocity_covariance
        lat, lon = geodesy.local_to_gps(position[0], position[1], self.camera.camera_lat, self.camera.camera_lon)
        wt.latitude, wt.longitude = float(lat), float(lon)
        wt.distance_m = float(np.hypot(position[0], position[1]))
        wt.bearing_deg = float(geodesy.bearing_deg(self.camera.camera_lat, self.camera.camera_lon, lat, lon))
        wt.expected_error_m = float(self.error_model.expected_error_m(wt.distance_m))
