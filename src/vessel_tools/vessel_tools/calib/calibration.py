"""GPS-only camera calibration: fit H and K1 from labelled (screen, GPS) pairs.

The paper's method, then better:

1. K1 by brute force (the paper): for each K1 on a grid, undistort the labelled screen points, solve H by the
   normalised DLT (Hartley: both point sets translated to their centroid and scaled to mean distance sqrt(2)),
   and score the screen reprojection error. The best grid K1 and its H start the refinement.
2. Joint non-linear refinement of H (8 dof, a minimal parametrisation about the DLT estimate in normalised
   coordinates) and K1 on screen reprojection error with ``scipy.optimize.least_squares``. A robust loss
   (``soft_l1`` by default, scale 3 px, about the label noise) keeps one bad label from dragging the fit.
   Optionally pairs are weighted by ``(distance / 100 m) ** far_weight`` to favour the far field, where a
   pixel is many metres (off by default: in leave-one-video-out cross-validation on the training videos it
   did not help).

Bad input raises CalibrationError before anything is written: fewer than 4 pairs, NaN/inf, duplicates,
collinear pairs, an invalid camera position (``vessel_tools.calib.pair_checks``), pairs that land on or above the
fitted horizon. The DLT, the lens model and the K1 scan of step 1 are ``vessel_tools.calib.homography``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from vessel_calib import geodesy
from vessel_calib.camera_model import PAPER_BOX_ANCHOR, CameraModel
from vessel_common.errors import CalibrationError
from vessel_tools.calib.homography import front_sign, msac_cost, normaliser, project, robust_initial_fit, scan_k1
from vessel_tools.calib.pair_checks import as_pairs, validate_pairs

LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")
#: With fewer pairs K1 is not fitted (12 residuals for 9 unknowns at least): it stays at k1_fixed or 0.
MIN_PAIRS_FOR_K1 = 6
#: |(H[2,0], H[2,1])| of the paper's H: the scale of z_p (about 0.53 x depth in metres) for every fitted H.
PAPER_ZP_ROW_NORM = math.hypot(0.512, 0.144)
#: Reprojection (px) assigned to a pair that falls behind the camera or off the lens model during the fit.
_BEHIND_PENALTY_PX = 1e4


@dataclass(frozen=True)
class FitOptions:
    """How to fit; the defaults are the project's shipped calibration method.

    Attributes:
        k1_min, k1_max, k1_steps: the brute-force K1 grid (1/px^2).
        refine: run the joint non-linear refinement (False: the paper's DLT + K1 scan only).
        fit_k1: refine K1 jointly (False keeps the scanned, or ``k1_fixed``, value).
        k1_fixed: if not None, no scan: K1 is this value (and stays fixed unless ``fit_k1``).
        loss: least_squares loss, one of LOSSES ("linear" = plain least squares).
        loss_scale_px: robust loss scale in pixels (residuals beyond it are down-weighted).
        far_weight: exponent of the per-pair weight (distance / 100 m) ** far_weight; 0 weights all equally.
        max_nfev: evaluation budget of the refinement.

    """

    k1_min: float = -1.2e-6
    k1_max: float = 6.0e-7
    k1_steps: int = 181
    refine: bool = True
    fit_k1: bool = True
    k1_fixed: float | None = None
    loss: str = "soft_l1"
    loss_scale_px: float = 3.0
    far_weight: float = 0.0
    max_nfev: int = 4000

    def checked(self) -> FitOptions:
        """Validate; CalibrationError naming the bad option."""
        if self.loss not in LOSSES:
            raise CalibrationError(f"loss must be one of {', '.join(LOSSES)}, got {self.loss!r}")
        if not (self.loss_scale_px > 0 and math.isfinite(self.loss_scale_px)):
            raise CalibrationError(f"robust loss scale must be a positive number of pixels, got {self.loss_scale_px}")
        if not (math.isfinite(self.far_weight) and 0 <= self.far_weight <= 2):
            raise CalibrationError(f"far_weight must be in [0, 2], got {self.far_weight}")
        if self.k1_fixed is None and not (self.k1_min < self.k1_max and self.k1_steps >= 2):
            raise CalibrationError("the K1 scan needs k1_min < k1_max and at least 2 steps")
        if self.k1_fixed is not None and not math.isfinite(self.k1_fixed):
            raise CalibrationError(f"fixed K1 must be finite, got {self.k1_fixed}")
        return self


#: The point of a labelled box taken as the vessel's GPS position: 0.65 of the way down (the paper: 0.5, the
#: centre). Chosen on training videos 7-12 alone, each video back-projected through a calibration fitted on the
#: other five (both labelling passes): 9.37 m per 100 m at 0.5, 7.38 at 0.6, 7.29 at 0.65, 7.55 at 0.7,
#: 8.11 at 0.75, 10.5 at 1.0 (primary labels only: 10.46 / 8.34 / 8.14 / 8.25 at 0.5 / 0.6 / 0.65 / 0.7). The
#: top of a small boat's box is its console, T-top and crew, which vary with the view; the hull below varies less.
DEFAULT_BOX_ANCHOR = 0.65

PAPER_OPTIONS = FitOptions(refine=False, loss="linear", far_weight=0.0)
"""The paper's protocol: K1 brute force and a least-squares (DLT) H, no refinement."""


@dataclass(frozen=True)
class Figures:
    """Accuracy of a camera model on labelled pairs (screen box centres vs GPS)."""

    pairs: int
    reproj_rmse_px: float
    reproj_median_px: float
    reproj_max_px: float
    backproj_median_m: float
    backproj_p80_m: float
    backproj_max_m: float
    backproj_per_100m: float
    backproj_invalid: int
    heading_deg: float

    def lines(self, title: str) -> list[str]:
        """Human-readable report lines."""
        return [
            f"{title}: {self.pairs} pairs",
            f"  reprojection  px: RMSE {self.reproj_rmse_px:.2f}, median {self.reproj_median_px:.2f}, "
            f"max {self.reproj_max_px:.2f}",
            f"  back-projected m: median {self.backproj_median_m:.2f}, p80 {self.backproj_p80_m:.2f}, "
            f"max {self.backproj_max_m:.2f}, {self.backproj_per_100m:.2f} m per 100 m"
            + (f", {self.backproj_invalid} on/above the horizon" if self.backproj_invalid else ""),
        ]


@dataclass
class CalibrationResult:
    """A fitted model with what it was fitted on and how well."""

    model: CameraModel
    options: FitOptions
    screen: np.ndarray  # (N, 2) px
    gps: np.ndarray  # (N, 2) lat, lon
    world: np.ndarray  # (N, 2) m
    reproj_px: np.ndarray  # (N, 2) projected - labelled
    backproj_m: np.ndarray  # (N,)
    figures: Figures
    k1_scan: tuple[np.ndarray, np.ndarray] = field(default_factory=lambda: (np.empty(0), np.empty(0)))
    scan_k1: float = math.nan
    nfev: int = 0

    def report_lines(self) -> list[str]:
        """The calibration report printed by the tool."""
        m = self.model
        o = self.options
        how = "K1 scan + normalised DLT"
        if o.refine:
            how += f", joint refinement of H and K1 ({o.loss}"
            how += f", scale {o.loss_scale_px:g} px" if o.loss != "linear" else ""
            how += f", far weight {o.far_weight:g})" if o.far_weight else ")"
        lines = [f"method: {how}"]
        lines += self.figures.lines("fit")
        lines += [
            f"  heading {m.heading_deg:.2f} deg, K1 {m.K1:.4g} (scan best {self.scan_k1:.4g}), "
            f"horizon at y = {float(m.horizon_y(m.center[0])):.1f} px (x = {m.center[0]:g}), "
            f"lens valid to r = {m.max_screen_radius:.0f} px",
        ]
        worst = np.argsort(-np.hypot(*self.reproj_px.T))[:3]
        lines.append("  worst pairs: " + ", ".join(
            f"#{i} ({self.screen[i, 0]:.0f}, {self.screen[i, 1]:.0f}) {np.hypot(*self.reproj_px[i]):.1f} px"
            for i in worst))
        return lines


# --------------------------------------------------------------------------- refinement
def _refine(screen, world, center, H0, K1_0, options: FitOptions, weights):
    """Joint least-squares refinement of H (8 dof about H0) and K1; returns (H, K1, nfev)."""
    r_ref2 = float(np.max(np.sum((screen - center) ** 2, axis=1))) or 1.0
    Tw = normaliser(world)
    Tp = normaliser(screen)
    Tp_inv = np.linalg.inv(Tp)
    Tw_inv = np.linalg.inv(Tw)
    Hn0 = Tp @ H0 @ Tw_inv
    Hn0 = Hn0 / np.linalg.norm(Hn0)
    # Orthonormal basis of the 8-dim complement of vec(Hn0): a minimal, well-conditioned parametrisation.
    _, _, Vt = np.linalg.svd(Hn0.reshape(1, 9))
    basis = Vt[1:].T  # (9, 8)
    fit_k1 = options.fit_k1
    sqrt_w = np.sqrt(weights)

    def unpack(x):
        Hn = Hn0 + (basis @ x[:8]).reshape(3, 3)
        H = Tp_inv @ Hn @ Tw
        K1 = x[8] / r_ref2 if fit_k1 else K1_0
        return H, K1

    def residuals(x):
        H, K1 = unpack(x)
        proj, zp, ok = project(H, K1, center, world)
        r = proj - screen
        bad = ~ok | ~(zp < 0) | ~np.isfinite(r).all(axis=1)
        r[bad] = _BEHIND_PENALTY_PX
        return (r * sqrt_w[:, None]).ravel()

    x0 = np.zeros(9 if fit_k1 else 8)
    if fit_k1:
        x0[8] = K1_0 * r_ref2
    result = least_squares(residuals, x0, loss=options.loss, f_scale=options.loss_scale_px, method="trf",
                           x_scale="jac", max_nfev=options.max_nfev)
    H, K1 = unpack(result.x)
    return H / np.linalg.norm(H), float(K1), int(result.nfev)


def _normalise_scale(H: np.ndarray) -> np.ndarray:
    """Scale H to the paper's z_p units: |(H[2,0], H[2,1])| = PAPER_ZP_ROW_NORM (sign kept).

    A homography is defined up to scale, but z_p is used as a distance cue (the paper's box-size formulas
    ``s = 1500 / |z_p| + 25``); giving every fitted H the third-row scale of the paper's H keeps |z_p| about
    0.53 x the depth in metres whatever the fit, so such constants carry over between calibrations.
    """
    return H * (PAPER_ZP_ROW_NORM / np.linalg.norm(H[2, :2]))


def pair_weights(world: np.ndarray, far_weight: float) -> np.ndarray:
    """(distance / 100 m) ** far_weight, normalised to mean 1 so the loss scale stays in pixels."""
    if far_weight == 0:
        return np.ones(len(world))
    d = np.maximum(np.hypot(world[:, 0], world[:, 1]), 1.0)
    w = (d / 100.0) ** (2.0 * far_weight)  # squared: these weight squared residuals
    return w / w.mean()


def calibrate(screen, gps, camera_lat: float, camera_lon: float, image_size=(1280, 720), center=None,
              options: FitOptions | None = None, box_anchor: float = PAPER_BOX_ANCHOR,
              water_levels=None, drop_beyond_horizon: bool = False) -> CalibrationResult:
    """Fit a CameraModel from labelled pairs: ``screen`` (N,2) pixels, ``gps`` (N,2) lat/lon degrees.

    ``box_anchor`` says where down its box each screen point was taken (0.5: box centres); the model carries
    it, so boxes are read the same way when it is used.

    ``water_levels`` (N,) metres: the water level at each pair's instant (``vessel_calib.water_level``). The
    model is then fitted for their mean level, each pair moved to where it would have been seen at that level
    (``CameraModel.from_water_level``, with the camera height H implies; three rounds), and carries that level.

    Raises CalibrationError for unusable input (see ``validate_pairs``) and when a pair lands on or above the
    fitted horizon (a label in the sky, or a wrong GPS match): nothing is returned then. With
    ``drop_beyond_horizon`` such pairs are left out and the fit repeated instead (for pairs that were matched
    automatically, where a few wrong matches are expected); the result holds the pairs kept.
    """
    if drop_beyond_horizon:
        return _calibrate_dropping(screen, gps, camera_lat, camera_lon, image_size, center, options, box_anchor,
                                   water_levels)
    if water_levels is not None:
        return _calibrate_at_water_levels(screen, gps, camera_lat, camera_lon, image_size, center, options,
                                          box_anchor, water_levels)
    options = (options or FitOptions()).checked()
    width, height = (int(v) for v in image_size)
    center_arr = np.array(center if center is not None else (width / 2.0, height / 2.0), dtype=float)
    screen, gps, world = validate_pairs(screen, gps, camera_lat, camera_lon, (width, height))
    weights = pair_weights(world, options.far_weight)
    options, k1_values = _k1_grid(options, len(screen))
    k1_scan_best, H, losses = scan_k1(screen, world, center_arr, k1_values, weights)
    H, K1 = _robust_start(screen, world, center_arr, H, k1_scan_best, k1_values, weights, options)
    nfev = 0
    if options.refine:
        H_ref, K1_ref, nfev = _refine(screen, world, center_arr, H, K1, options, weights)
        H_ref = front_sign(H_ref, world)
        proj, zp, ok = project(H_ref, K1_ref, center_arr, world)
        if ok.all() and np.all(zp < 0) and np.isfinite(proj).all():
            H, K1 = H_ref, K1_ref
    H = _normalise_scale(front_sign(H, world))
    try:
        model = CameraModel(H, K1, center=tuple(center_arr), image_size=(width, height),
                            camera_lat=camera_lat, camera_lon=camera_lon, box_anchor=box_anchor)
    except CalibrationError as exc:
        raise CalibrationError(f"the fit produced an unusable camera: {exc}") from None
    xs, ys = _screen_of_visible_pairs(model, screen, world)
    figures = evaluate(model, screen, gps)
    return CalibrationResult(
        model=model, options=options, screen=screen, gps=gps, world=world,
        reproj_px=np.column_stack([xs, ys]) - screen, backproj_m=_backproj_errors(model, screen, gps),
        figures=figures, k1_scan=(k1_values, losses), scan_k1=k1_scan_best, nfev=nfev)


def _k1_grid(options: FitOptions, n_pairs: int) -> tuple[FitOptions, np.ndarray]:
    """The K1 values to scan, and the options with K1 fixed at 0 for pairs too few to learn it from."""
    if n_pairs < MIN_PAIRS_FOR_K1 and options.k1_fixed is None:
        # 4-5 pairs fix H exactly for any K1: K1 cannot be learned from them.
        options = replace(options, k1_fixed=0.0, fit_k1=False)
    if options.k1_fixed is not None:
        return options, np.array([options.k1_fixed])
    return options, np.linspace(options.k1_min, options.k1_max, options.k1_steps)


def _robust_start(screen, world, center, H, K1, k1_values, weights, options: FitOptions):
    """The (H, K1) the refinement starts from: the scan's, or with a robust loss a consensus that explains more.

    The consensus of 4-pair samples (``robust_initial_fit``), K1 rescanned on its inliers, replaces the scan's
    start when its MSAC cost over all pairs is lower.
    """
    if options.loss != "linear" and len(screen) > 5:
        threshold = 5.0 * options.loss_scale_px
        H_cons, inliers = robust_initial_fit(screen, world, center, K1, threshold)
        if H_cons is not None and inliers.sum() >= max(4, len(screen) // 2) and not inliers.all():
            try:
                k1_in, H_in, _ = scan_k1(screen[inliers], world[inliers], center, k1_values, weights[inliers])
            except CalibrationError:
                k1_in, H_in = K1, H_cons
            if (msac_cost(H_in, k1_in, center, screen, world, threshold)
                    < msac_cost(H, K1, center, screen, world, threshold)):
                H, K1 = H_in, k1_in
    return H, K1


def _screen_of_visible_pairs(model: CameraModel, screen, world):
    """The pairs' GPS projected through ``model``; _BeyondHorizonError when a pair is on/above its horizon or behind."""
    _, _, valid = model.screen_to_world(screen[:, 0], screen[:, 1])
    if not valid.all():
        bad = np.flatnonzero(~valid)
        listed = ", ".join(f"#{i} ({screen[i, 0]:.0f}, {screen[i, 1]:.0f})" for i in bad[:5])
        raise _BeyondHorizonError(
            f"{bad.size} pair(s) land on or above the fitted horizon ({listed}): labels in the sky, on land, or "
            "matched to the wrong GPS time; remove them (or use --robust) and re-run", bad)
    xs, ys, in_front = model.world_to_screen(world[:, 0], world[:, 1])
    if not in_front.all():
        i = int(np.flatnonzero(~in_front)[0])
        raise _BeyondHorizonError(f"pair {i}: its GPS position falls behind the fitted camera; check that pair",
                                  np.flatnonzero(~in_front))
    return xs, ys


def _calibrate_dropping(screen, gps, camera_lat, camera_lon, image_size, center, options, box_anchor, water_levels,
                        rounds: int = 4) -> CalibrationResult:
    screen = as_pairs(screen, "screen points")
    gps = as_pairs(gps, "GPS positions", len(screen))
    levels = None if water_levels is None else _pair_levels(water_levels, len(screen))
    keep = np.ones(len(screen), dtype=bool)
    for _ in range(rounds):
        try:
            return calibrate(screen[keep], gps[keep], camera_lat, camera_lon, image_size, center, options,
                             box_anchor, None if levels is None else levels[keep])
        except _BeyondHorizonError as exc:
            kept = np.flatnonzero(keep)
            keep[kept[exc.indices]] = False
            if keep.sum() < MIN_PAIRS_FOR_K1:
                raise CalibrationError(f"only {int(keep.sum())} pairs stay below the fitted horizon") from None
    raise CalibrationError(f"pairs still land on or above the fitted horizon after {rounds} rounds of leaving "
                           "them out: the matches are inconsistent")


class _BeyondHorizonError(CalibrationError):
    """Pairs the fitted camera cannot see (on or above its horizon, or behind it); ``indices`` names them."""

    def __init__(self, message: str, indices: np.ndarray):
        super().__init__(message)
        self.indices = indices


#: Fewer pairs than this get a leave-one-pair-out figure in the calibration tool's report.
FEW_PAIRS = 8
#: The calibration tool writes no file from fewer pairs: 4 fix a homography exactly (no error can be measured).
MIN_PAIRS_TO_WRITE = 5


def degrees_of_freedom(n_pairs: int, fits_k1: bool) -> int:
    """Equations left over by a fit of H (8 unknowns) and, when fitted, K1 to ``n_pairs`` pairs."""
    return 2 * n_pairs - 8 - int(fits_k1)


def leave_one_pair_out_errors(screen, gps, camera_lat: float, camera_lon: float, image_size=(1280, 720),
                              center=None, options: FitOptions | None = None,
                              box_anchor: float = PAPER_BOX_ANCHOR) -> np.ndarray:
    """Back-projection error (m) of each pair under a fit of the others: what a few pairs' fit is worth.

    With few pairs the in-sample error says little (4 pairs fit H exactly: 0 m whatever the labels); this is
    the figure that does. NaN where the fit without that pair fails or the pair lands on its horizon.
    """
    screen = np.asarray(screen, dtype=float).reshape(-1, 2)
    gps = np.asarray(gps, dtype=float).reshape(-1, 2)
    errors = np.full(len(screen), np.nan)
    for i in range(len(screen)):
        keep = np.arange(len(screen)) != i
        try:
            model = calibrate(screen[keep], gps[keep], camera_lat, camera_lon, image_size, center, options,
                              box_anchor).model
        except CalibrationError:
            continue
        errors[i] = _backproj_errors(model, screen[i:i + 1], gps[i:i + 1])[0]
    return errors


#: Rounds of (camera height from H, pairs moved to the reference water level, refit).
WATER_LEVEL_ROUNDS = 3


def _pair_levels(levels, n: int) -> np.ndarray:
    arr = np.asarray(levels, dtype=float).ravel()
    if arr.size != n:
        raise CalibrationError(f"{arr.size} water levels for {n} pairs: give one level per pair")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.isfinite(arr))
        raise CalibrationError(f"no water level for {bad.size} pair(s) (first #{int(bad[0])}): their times are "
                               "outside the water-level file; extend the file or drop those videos")
    return arr


def _calibrate_at_water_levels(screen, gps, camera_lat, camera_lon, image_size, center, options, box_anchor,
                               water_levels) -> CalibrationResult:
    screen = as_pairs(screen, "screen points")
    gps = as_pairs(gps, "GPS positions", len(screen))
    levels = _pair_levels(water_levels, len(screen))
    reference = float(np.mean(levels))
    result = calibrate(screen, gps, camera_lat, camera_lon, image_size, center, options, box_anchor)
    xw, yw = geodesy.gps_to_local(gps[:, 0], gps[:, 1], camera_lat, camera_lon)
    for _ in range(WATER_LEVEL_ROUNDS):
        model = _with_water_level(result.model, reference)
        xr, yr = model.from_water_level(xw, yw, levels)
        lat, lon = geodesy.local_to_gps(xr, yr, camera_lat, camera_lon)
        result = calibrate(screen, np.column_stack([lat, lon]), camera_lat, camera_lon, image_size, center,
                           options, box_anchor)
    model = _with_water_level(result.model, reference)
    xs, ys, _ = _reprojected(model, gps, levels)
    return replace(result, model=model, gps=gps, world=np.column_stack([xw, yw]),
                   reproj_px=np.column_stack([xs, ys]) - screen,
                   backproj_m=_backproj_errors(model, screen, gps, levels),
                   figures=evaluate(model, screen, gps, levels))


def _with_water_level(model: CameraModel, level: float) -> CameraModel:
    return CameraModel(model.H, model.K1, model.center, model.image_size, model.camera_lat, model.camera_lon,
                       model.box_anchor, water_level_m=level)


def calibrate_from_labels(dataset, videos, box_anchor: float, label_passes: str = "primary",
                          water_level=None) -> CameraModel:
    """The camera fitted on a data folder's labelled boxes of ``videos``, each read ``box_anchor`` of the way down.

    One place that reads the pairs and fits with the same anchor (the leave-one-video-out fits of the pipeline and
    of the fusion's cue noise); ``dataset`` is a ``vessel_tools.calib.dataset.Dataset``, ``water_level`` a
    ``WaterLevelTable`` (None: the tide is ignored).
    """
    screen, gps, stamps = dataset.calibration_pairs(videos, anchor=box_anchor, label_passes=label_passes,
                                                    with_stamps=True)
    levels = None if water_level is None else water_level.level_at(stamps)
    return calibrate(screen, gps, dataset.camera_lat, dataset.camera_lon, dataset.image_size, dataset.center,
                     box_anchor=box_anchor, water_levels=levels).model


# --------------------------------------------------------------------------- evaluation
def _backproj_errors(model: CameraModel, screen, gps, levels=None) -> np.ndarray:
    xw, yw, valid = model.screen_to_world(screen[:, 0], screen[:, 1])
    if levels is not None:
        xw, yw = model.to_water_level(xw, yw, levels)
    lat, lon = model.world_to_gps(xw, yw)
    err = geodesy.haversine_m(lat, lon, gps[:, 0], gps[:, 1])
    return np.where(valid, err, np.inf)


def _reprojected(model: CameraModel, gps, levels=None):
    xw, yw = model.gps_to_world(gps[:, 0], gps[:, 1])
    if levels is not None:
        xw, yw = model.from_water_level(xw, yw, levels)
    return model.world_to_screen(xw, yw)


def evaluate(model: CameraModel, screen, gps, levels=None) -> Figures:
    """Reprojection (GPS -> screen vs labels) and back-projection (labels -> GPS vs GPS) figures.

    ``levels`` (m, per pair): the water level at each pair's instant, for a model with a water level.

    Back-projected errors of pairs on/above the horizon count as infinite (they produce no position) and are
    counted in ``backproj_invalid``; ``backproj_per_100m`` is the paper's least-squares slope through the origin,
    100 * sum(e * d) / sum(d^2), over valid pairs.
    """
    screen = as_pairs(screen, "screen points")
    gps = as_pairs(gps, "GPS positions", len(screen))
    if len(screen) == 0:
        raise CalibrationError("no pairs to evaluate on")
    if levels is not None:
        levels = _pair_levels(levels, len(screen))
    xs, ys, in_front = _reprojected(model, gps, levels)
    reproj = np.hypot(xs - screen[:, 0], ys - screen[:, 1])
    reproj = np.where(in_front, reproj, np.inf)
    back = _backproj_errors(model, screen, gps, levels)
    valid = np.isfinite(back)
    dist = geodesy.haversine_m(model.camera_lat, model.camera_lon, gps[:, 0], gps[:, 1])
    per100 = 100.0 * np.sum(back[valid] * dist[valid]) / np.sum(dist[valid] ** 2) if valid.any() else math.inf
    finite_reproj = reproj[np.isfinite(reproj)]
    return Figures(
        pairs=len(screen),
        reproj_rmse_px=float(np.sqrt(np.mean(reproj ** 2))) if np.isfinite(reproj).all() else math.inf,
        reproj_median_px=float(np.median(reproj)),
        reproj_max_px=float(np.max(finite_reproj)) if finite_reproj.size else math.inf,
        backproj_median_m=float(np.median(back)),
        backproj_p80_m=float(np.percentile(back, 80)) if valid.all() else float(np.quantile(back, 0.8,
                                                                                            method="higher")),
        backproj_max_m=float(np.max(back[valid])) if valid.any() else math.inf,
        backproj_per_100m=float(per100),
        backproj_invalid=int((~valid).sum()),
        heading_deg=float(model.heading_deg),
    )


# --------------------------------------------------------------------------- study (the paper's protocol)
@dataclass(frozen=True)
class DrawStudy:
    """Spread of validation figures over random draws of ``n_pairs`` training pairs."""

    n_pairs: int
    draws: int
    failed: int
    val_median_m: np.ndarray
    val_reproj_median_px: np.ndarray
    heading_deg: np.ndarray

    def lines(self) -> list[str]:
        """Human-readable summary."""
        def spread(a, unit):
            return (f"median {np.median(a):.2f}{unit}, min {np.min(a):.2f}{unit}, max {np.max(a):.2f}{unit}"
                    if a.size else "n/a")
        return [
            f"{self.draws} draws of {self.n_pairs} training pairs ({self.failed} refused as unusable):",
            f"  validation back-projected median error: {spread(self.val_median_m, ' m')}",
            f"  validation reprojection median:        {spread(self.val_reproj_median_px, ' px')}",
            f"  heading:                               {spread(self.heading_deg, ' deg')}",
        ]


def study_draws(train_screen, train_gps, val_screen, val_gps, camera_lat, camera_lon, n_pairs: int, draws: int,
                seed: int, image_size=(1280, 720), center=None, options: FitOptions | None = None) -> DrawStudy:
    """Fit on ``draws`` random subsets of ``n_pairs`` training pairs; evaluate each on the validation pairs."""
    rng = np.random.default_rng(seed)
    train_screen = np.asarray(train_screen, dtype=float)
    train_gps = np.asarray(train_gps, dtype=float)
    if n_pairs > len(train_screen):
        raise CalibrationError(f"asked for {n_pairs} pairs per draw but only {len(train_screen)} training pairs")
    meds, pxs, heads = [], [], []
    failed = 0
    for _ in range(draws):
        idx = rng.choice(len(train_screen), size=n_pairs, replace=False)
        try:
            result = calibrate(train_screen[idx], train_gps[idx], camera_lat, camera_lon, image_size, center,
                               options)
        except CalibrationError:
            failed += 1
            continue
        fig = evaluate(result.model, val_screen, val_gps)
        meds.append(fig.backproj_median_m)
        pxs.append(fig.reproj_median_px)
        heads.append(result.model.heading_deg)
    return DrawStudy(n_pairs, draws, failed, np.array(meds), np.array(pxs), np.array(heads))


def with_options(base: FitOptions | None, **changes) -> FitOptions:
    """``base`` (or the defaults) with some fields changed, validated."""
    return replace(base or FitOptions(), **changes).checked()
