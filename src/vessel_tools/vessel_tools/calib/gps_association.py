"""Calibration without hand labels: which detection is the GPS-tracked vessel, and the camera that says so.

Neither the camera nor which box of a frame is the vessel is known. A camera hypothesis (H, K1) fixes where the
vessel's GPS position falls in every frame; the right one puts it on a detected box in many frames, a wrong one
in few. So:

1. **Consensus search** (RANSAC over frame-box pairs): four frames, one box of each, a K1 drawn from its range,
   the DLT through those four points; each hypothesis is scored by MSAC over all frames (the nearest box's
   distance to the predicted point, truncated at a gate). Batched: many thousand hypotheses a second.
2. **Refinement**: the best hypotheses' associations (the nearest box within the gate, one per frame) go to the
   labelled-pair fit (``calibration.calibrate``, robust loss); every frame is associated again under the new
   camera with a tighter gate, and refitted, a few rounds.
3. **Checks**: the camera must be one that can exist (a positive focal length, above the water, below it the
   given camera position) and the associations must be enough and spread in range; otherwise CalibrationError
   and nothing is written.

An offline tool (the tools layer): NumPy/SciPy only; the detector that makes the boxes is the caller's business.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NoReturn

import numpy as np

from vessel_calib import geodesy
from vessel_calib.camera_model import CameraModel, box_points
from vessel_calib.pinhole import pinhole_decomposition
from vessel_common.errors import CalibrationError
from vessel_tools.calib.calibration import DEFAULT_BOX_ANCHOR, CalibrationResult, FitOptions, calibrate
from vessel_tools.calib.homography import front_sign

#: The consensus search scores cameras up to this many times ``max_nadir_m`` from the given position (a 4-point
#: hypothesis is noisy); the final camera must be within ``max_nadir_m``.
OFFSET_SLACK = 5.0


@dataclass(frozen=True)
class FrameBoxes:
    """One frame: the boxes a detector found in it and the tracked vessel's GPS at its instant."""

    video: int
    frame: int
    stamp: float
    lat: float
    lon: float
    boxes: np.ndarray = field(repr=False)  # (k, 4) x1, y1, x2, y2 pixels
    scores: np.ndarray = field(repr=False)  # (k,)


@dataclass(frozen=True)
class SearchOptions:
    """Settings of the search; the defaults work on the challenge camera's COCO detections.

    box_anchor: the point of a box that stands for the GPS (0 top, 1 bottom), written to the calibration.
    min_score, max_boxes_per_frame: which detections are candidates (the best few of each frame).
    hypotheses, k1_range: the consensus search's size and the lens terms it draws from.
    gates_px: association gate of the consensus search, then of each refinement round (the last is the final one).
    min_associations, min_range_ratio: what a fit must rest on (frames, and their 90th/10th percentile range).
    max_nadir_m: how far from the given camera position the fitted camera may stand.
    height_range_m, focal_range_px: cameras that can exist.
    """

    box_anchor: float = DEFAULT_BOX_ANCHOR
    min_score: float = 0.1
    max_boxes_per_frame: int = 12
    hypotheses: int = 200000
    k1_range: tuple[float, float] = (-5e-7, 1e-7)
    gates_px: tuple[float, ...] = (30.0, 20.0, 12.0, 12.0)
    min_associations: int = 12
    min_range_ratio: float = 1.5
    max_nadir_m: float = 50.0
    height_range_m: tuple[float, float] = (0.3, 300.0)
    focal_range_px: tuple[float, float] = (100.0, 20000.0)
    candidates_refined: int = 8
    seed: int = 0

    def checked(self) -> SearchOptions:
        """Self, or CalibrationError naming the setting that cannot work."""
        if not 0.0 <= self.box_anchor <= 1.0:
            raise CalibrationError(f"box_anchor must be in [0, 1] (0 box top, 1 bottom), got {self.box_anchor}")
        if self.hypotheses < 100:
            raise CalibrationError(f"hypotheses must be at least 100, got {self.hypotheses}")
        if not self.gates_px or any(not (g > 0 and math.isfinite(g)) for g in self.gates_px):
            raise CalibrationError(f"gates_px must be positive pixel distances, got {self.gates_px}")
        if self.min_associations < 6:
            raise CalibrationError(f"min_associations must be at least 6 (a homography and K1 need more than 4 "
                                   f"pairs), got {self.min_associations}")
        if self.max_boxes_per_frame < 1:
            raise CalibrationError(f"max_boxes_per_frame must be at least 1, got {self.max_boxes_per_frame}")
        return self


@dataclass
class Association:
    """What the search found: the fit, and which box of which frame it rests on."""

    result: CalibrationResult
    frames: list[FrameBoxes]
    chosen: np.ndarray  # (n_frames,) index of the associated box of each frame, -1 for none
    residual_px: np.ndarray  # (n_frames,) distance of the predicted point to that box's anchor, NaN for none
    consensus: int  # frames the best consensus hypothesis explained
    hypotheses: int  # hypotheses scored
    frames_with_boxes: int

    @property
    def associated(self) -> int:
        """Number of frames whose vessel box was found."""
        return int(np.sum(self.chosen >= 0))

    def pairs(self, anchor: float, with_keys: bool = False):
        """(screen (N,2), gps (N,2), stamps (N,)) of the associated frames, boxes read ``anchor`` of the way down.

        ``with_keys`` adds their (video, frame) keys.
        """
        idx = np.flatnonzero(self.chosen >= 0)
        boxes = self.boxes()
        screen = box_points(boxes, anchor) if len(boxes) else np.zeros((0, 2))
        gps = np.array([(self.frames[i].lat, self.frames[i].lon) for i in idx]).reshape(-1, 2)
        stamps = np.array([self.frames[i].stamp for i in idx], dtype=float)
        if with_keys:
            return screen, gps, stamps, [(self.frames[i].video, self.frames[i].frame) for i in idx]
        return screen, gps, stamps

    def boxes(self) -> np.ndarray:
        """(N, 4) the associated boxes, in frame order."""
        idx = np.flatnonzero(self.chosen >= 0)
        return np.array([self.frames[i].boxes[self.chosen[i]] for i in idx], dtype=float).reshape(-1, 4)

    def track_gps(self) -> np.ndarray:
        """(F, 2) the vessel's GPS at every frame searched."""
        return np.array([(f.lat, f.lon) for f in self.frames], dtype=float).reshape(-1, 2)

    def report_lines(self) -> list[str]:
        """The association part of the calibration report."""
        model = self.result.model
        geometry = model.pinhole()
        used = self.residual_px[np.isfinite(self.residual_px)]
        ranges = self._ranges()
        lines = [
            f"association: {self.associated} of {len(self.frames)} frames with a GPS fix ({self.frames_with_boxes} "
            f"with a candidate box); consensus search: {self.hypotheses} hypotheses, best explained "
            f"{self.consensus} frames",
        ]
        if used.size:
            lines.append(f"  association residuals px: median {np.median(used):.1f}, "
                         f"p80 {np.percentile(used, 80):.1f}, max {used.max():.1f}; range {ranges.min():.0f} to "
                         f"{ranges.max():.0f} m")
        lines.append(f"  camera found: height {geometry.height_m:.2f} m above the water, heading "
                     f"{model.heading_deg:.2f} deg, focal length {geometry.focal_px:.0f} px, "
                     f"{math.hypot(*geometry.nadir_xy):.1f} m from the given camera position")
        per_video: dict[int, list[int]] = {}
        for frame, box in zip(self.frames, self.chosen, strict=True):
            per_video.setdefault(frame.video, [0, 0])
            per_video[frame.video][1] += 1
            per_video[frame.video][0] += int(box >= 0)
        lines.append("  per video (associated/with GPS): "
                     + ", ".join(f"{v}: {a}/{n}" for v, (a, n) in sorted(per_video.items())))
        return lines

    def _ranges(self) -> np.ndarray:
        model = self.result.model
        idx = np.flatnonzero(self.chosen >= 0)
        lat = np.array([self.frames[i].lat for i in idx])
        lon = np.array([self.frames[i].lon for i in idx])
        return geodesy.haversine_m(model.camera_lat, model.camera_lon, lat, lon)


# --------------------------------------------------------------------------- candidates
def _candidate_anchors(frames: list[FrameBoxes], options: SearchOptions):
    """Each frame's best boxes: (F, K, 2) anchor points (NaN padded), (F, K) box indices (-1), (F, K) scores (NaN)."""
    k_max = options.max_boxes_per_frame
    anchors = np.full((len(frames), k_max, 2), np.nan)
    index = np.full((len(frames), k_max), -1, dtype=int)
    chosen_scores = np.full((len(frames), k_max), np.nan)
    for f, frame in enumerate(frames):
        boxes = np.asarray(frame.boxes, dtype=float).reshape(-1, 4)
        scores = np.asarray(frame.scores, dtype=float).reshape(-1)
        ok = np.flatnonzero(np.isfinite(boxes).all(axis=1) & (scores >= options.min_score))
        ok = ok[np.argsort(-scores[ok], kind="stable")][:k_max]
        if ok.size:
            anchors[f, :ok.size] = box_points(boxes[ok], options.box_anchor)
            index[f, :ok.size] = ok
            chosen_scores[f, :ok.size] = scores[ok]
    _drop_static(anchors, index, chosen_scores)
    return anchors, index, chosen_scores


def _drop_static(anchors: np.ndarray, index: np.ndarray, scores: np.ndarray, tol_px: float = 1.0) -> None:
    """Remove boxes found at the same pixel in another frame.

    Such a box is something fixed (a post, a moored boat), not a vessel under way, and a pair the fit would refuse as
    a duplicate.
    """
    flat = anchors.reshape(-1, 2)
    frame_of = np.repeat(np.arange(anchors.shape[0]), anchors.shape[1])
    live = np.flatnonzero(np.isfinite(flat[:, 0]))
    if live.size < 2:
        return
    keys = np.round(flat[live] / tol_px).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    for group in np.flatnonzero(counts > 1):
        members = live[inverse.reshape(-1) == group]
        if np.unique(frame_of[members]).size > 1:
            anchors.reshape(-1, 2)[members] = np.nan
            index.reshape(-1)[members] = -1
            scores.reshape(-1)[members] = np.nan
    for f in range(anchors.shape[0]):  # keep each frame's live slots first
        order = np.argsort(index[f] < 0, kind="stable")
        anchors[f] = anchors[f, order]
        index[f] = index[f, order]
        scores[f] = scores[f, order]


# --------------------------------------------------------------------------- batched geometry
def _undistort_batch(points: np.ndarray, k1: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Ideal points of (B, n, 2) screen points under per-hypothesis K1 (B,) (Newton on the radius)."""
    d = points - center
    rs = np.hypot(d[..., 0], d[..., 1])
    k = k1[:, None]
    u = rs.copy()
    for _ in range(12):
        u = u - (u + k * u ** 3 - rs) / (1.0 + 3.0 * k * u * u)
    scale = np.where(rs > 0, u / np.where(rs > 0, rs, 1.0), 1.0)
    return center + d * scale[..., None]


def _hartley(points: np.ndarray) -> np.ndarray:
    """(B, 3, 3) Hartley normalisations of (B, n, 2) point sets."""
    c = points.mean(axis=1)
    mean_dist = np.mean(np.linalg.norm(points - c[:, None, :], axis=2), axis=1)
    s = math.sqrt(2.0) / np.maximum(mean_dist, 1e-12)
    T = np.zeros((len(points), 3, 3))
    T[:, 0, 0] = s
    T[:, 1, 1] = s
    T[:, 0, 2] = -s * c[:, 0]
    T[:, 1, 2] = -s * c[:, 1]
    T[:, 2, 2] = 1.0
    return T


def _dlt_batch(ideal: np.ndarray, world: np.ndarray) -> np.ndarray:
    """(B, 3, 3) homographies world -> ideal from (B, 4, 2) point sets (normalised DLT)."""
    Tw, Tp = _hartley(world), _hartley(ideal)
    wn = np.einsum("bij,bnj->bni", Tw[:, :2, :2], world) + Tw[:, None, :2, 2]
    pn = np.einsum("bij,bnj->bni", Tp[:, :2, :2], ideal) + Tp[:, None, :2, 2]
    B, n = world.shape[:2]
    X = np.concatenate([wn, np.ones((B, n, 1))], axis=2)
    A = np.zeros((B, 2 * n, 9))
    A[:, 0::2, 0:3] = X
    A[:, 0::2, 6:9] = -pn[..., 0:1] * X
    A[:, 1::2, 3:6] = X
    A[:, 1::2, 6:9] = -pn[..., 1:2] * X
    _, _, vt = np.linalg.svd(A, full_matrices=True)
    Hn = vt[:, -1].reshape(B, 3, 3)
    return np.linalg.inv(Tp) @ Hn @ Tw


def _project_batch(H: np.ndarray, k1: np.ndarray, center: np.ndarray, world: np.ndarray):
    """Screen points (B, F, 2) of world points (F, 2) under (B, 3, 3) H and K1, and a (B, F) mask of usable ones."""
    q = np.einsum("bij,fj->bfi", H[:, :, :2], world) + H[:, None, :, 2]
    zp = q[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        p = q[..., :2] / zp[..., None]
        d = p - center
        r2 = np.sum(d * d, axis=2)
        ok = (zp < 0) & np.isfinite(r2)
        k = k1[:, None]
        ok &= np.where(k < 0, r2 * (-3.0 * k) < 1.0, True)
        s = center + d * (1.0 + k * r2)[..., None]
    return s, ok


def _nearest(predicted: np.ndarray, ok: np.ndarray, anchors: np.ndarray):
    """Squared distance (B, F) to each frame's nearest anchor and its slot (B, F); inf where not usable."""
    d2 = np.sum((predicted[:, :, None, :] - anchors[None]) ** 2, axis=3)
    d2 = np.where(np.isfinite(d2), d2, np.inf)
    slot = np.argmin(d2, axis=2)
    best = np.take_along_axis(d2, slot[..., None], axis=2)[..., 0]
    return np.where(ok, best, np.inf), slot


# --------------------------------------------------------------------------- search
def _consensus_search(world, anchors, scores, center, options: SearchOptions, batch: int = 2000):
    """The MSAC consensus search: its best hypotheses ``(H, K1, cost)``, best first, and how many it scored.

    Also the best camera the offset check rejected: the frames it explains and its offset in metres.
    """
    rng = np.random.default_rng(options.seed)
    counts = np.sum(np.isfinite(anchors[..., 0]), axis=1)
    usable = np.flatnonzero(counts > 0)
    weights = np.where(np.isfinite(anchors[..., 0]), np.nan_to_num(scores, nan=0.0), 0.0)
    gate2 = options.gates_px[0] ** 2
    kept: list[tuple[np.ndarray, float, float]] = []
    scored = 0
    misplaced = [0, math.nan]  # the best camera the offset check rejected: frames it explains, its offset (m)
    for start in range(0, options.hypotheses, batch):
        b = min(batch, options.hypotheses - start)
        frames = _distinct_draws(rng, usable, b)
        slots = _weighted_slots(rng, weights[frames])
        screen = anchors[frames, slots]
        wpts = world[frames]
        k1 = rng.uniform(*options.k1_range, size=b)
        spread_ok = (_min_pairwise(wpts) > 3.0) & (_min_pairwise(screen) > 3.0)
        ideal = _undistort_batch(screen, k1, center)
        H = _dlt_batch(ideal, wpts)
        zp = np.einsum("bj,bnj->bn", H[:, 2, :2], wpts) + H[:, 2, 2][:, None]
        H = np.where((np.median(zp, axis=1) > 0)[:, None, None], -H, H)
        zp = np.where((np.median(zp, axis=1) > 0)[:, None], -zp, zp)
        good = spread_ok & np.all(zp < 0, axis=1) & np.isfinite(H).all(axis=(1, 2))
        physical, offset = _physical(H[good], center, options)
        near = offset <= OFFSET_SLACK * options.max_nadir_m
        far = np.flatnonzero(good)[physical & ~near]
        good[good] = physical & near
        if far.size:
            far_predicted, far_ok = _project_batch(H[far], k1[far], center, world)
            far_d2, _ = _nearest(far_predicted, far_ok, anchors)
            far_inliers = np.sum(far_d2 < gate2, axis=1)
            i = int(np.argmax(far_inliers))
            if far_inliers[i] > misplaced[0]:
                misplaced[:] = [int(far_inliers[i]), float(offset[physical & ~near][i])]
        if not good.any():
            continue
        H, k1 = H[good], k1[good]
        predicted, ok = _project_batch(H, k1, center, world)
        d2, _ = _nearest(predicted, ok, anchors)
        cost = np.sum(np.minimum(d2, gate2), axis=1)
        scored += int(good.sum())
        kept += [(H[i], float(k1[i]), float(cost[i])) for i in np.argsort(cost)[: options.candidates_refined]]
        kept = sorted(kept, key=lambda item: item[2])[: options.candidates_refined]  # stable: ties keep the earlier
    return kept, scored, misplaced


def _physical(H: np.ndarray, center: np.ndarray, options: SearchOptions) -> tuple[np.ndarray, np.ndarray]:
    """Which homographies an upright pinhole camera above the sea could give, and how far from the origin it stands.

    ``pinhole_decomposition`` with loose shape limits (a 4-point hypothesis is noisy): a (B,) mask and the (B,)
    camera offsets in metres.

    A free homography explains one boat's track through many impossible cameras; scoring only possible ones keeps
    the search on cameras that exist.
    """
    focal, centre, skew, aspect, ok = pinhole_decomposition(H, center)
    with np.errstate(invalid="ignore"):
        ok &= (focal >= options.focal_range_px[0]) & (focal <= options.focal_range_px[1])
        ok &= np.isfinite(aspect) & (aspect > 0.5) & (aspect < 2.0) & (skew < 0.3)
        ok &= (centre[:, 2] >= options.height_range_m[0]) & (centre[:, 2] <= options.height_range_m[1])
    return ok, np.where(ok, np.hypot(centre[:, 0], centre[:, 1]), np.inf)


def _distinct_draws(rng, population: np.ndarray, rows: int) -> np.ndarray:
    """(rows, 4) draws of four distinct members of ``population``."""
    keys = rng.random((rows, population.size))
    return population[np.argpartition(keys, 4, axis=1)[:, :4]]


def _weighted_slots(rng, weights: np.ndarray) -> np.ndarray:
    """A slot per (row, frame) drawn with probability proportional to ``weights`` (rows, 4, K): likelier boxes first."""
    cumulative = np.cumsum(weights, axis=2)
    u = rng.random(weights.shape[:2])[..., None] * cumulative[..., -1:]
    return np.minimum(np.sum(cumulative < u, axis=2), weights.shape[2] - 1)


def _min_pairwise(points: np.ndarray) -> np.ndarray:
    d = np.linalg.norm(points[:, :, None, :] - points[:, None, :, :], axis=3)
    d[:, np.arange(4), np.arange(4)] = np.inf
    return d.min(axis=(1, 2))


def _associate(model: CameraModel, world, levels, anchors, gate_px: float):
    """Per frame: the slot of the box nearest to the model's prediction within the gate (-1 none), and distance."""
    xw, yw = world[:, 0], world[:, 1]
    if levels is not None and math.isfinite(model.water_level_m):
        xw, yw = model.from_water_level(xw, yw, levels)
    xs, ys, in_front = model.world_to_screen(xw, yw)
    predicted = np.column_stack([xs, ys])[None]
    d2, slot = _nearest(predicted, np.asarray(in_front, dtype=bool)[None] & np.isfinite(predicted[0]).all(axis=1)[None],
                        anchors)
    d = np.sqrt(d2[0])
    within = d <= gate_px
    return np.where(within, slot[0], -1), np.where(within, d, np.nan)


def _implausible(model: CameraModel, options: SearchOptions) -> str | None:
    """Why no real camera can be this model (None: it can)."""
    try:
        geometry = model.pinhole()
    except CalibrationError:
        return "no pinhole camera above a plane gives this homography"
    if not geometry.above_water:
        return f"the camera would be {geometry.height_m:.1f} m under the water"
    low, high = options.height_range_m
    if not low <= geometry.height_m <= high:
        return f"the camera would be {geometry.height_m:.2f} m above the water (allowed {low:g} to {high:g} m)"
    low, high = options.focal_range_px
    if not low <= geometry.focal_px <= high:
        return f"the focal length would be {geometry.focal_px:.0f} px (allowed {low:g} to {high:g} px)"
    offset = math.hypot(*geometry.nadir_xy)
    if offset > options.max_nadir_m:
        return (f"the camera would stand {offset:.0f} m from the given camera position (allowed "
                f"{options.max_nadir_m:g} m): check --camera-lat/--camera-lon")
    return None


def _fit(frames, chosen, anchors_index, camera_lat, camera_lon, image_size, center, fit_options, anchor, levels):
    """The labelled-pair fit of the chosen boxes; (result, chosen with the pairs it left out set to -1)."""
    idx = np.flatnonzero(chosen >= 0)
    boxes = np.array([frames[i].boxes[anchors_index[i, chosen[i]]] for i in idx])
    screen = box_points(boxes, anchor)
    gps = np.array([(frames[i].lat, frames[i].lon) for i in idx])
    result = calibrate(screen, gps, camera_lat, camera_lon, image_size, center, fit_options, box_anchor=anchor,
                       water_levels=None if levels is None else levels[idx], drop_beyond_horizon=True)
    kept = (screen[:, None, :] == result.screen[None, :, :]).all(axis=2).any(axis=1)
    chosen = chosen.copy()
    chosen[idx[~kept]] = -1
    return result, chosen


def associate_and_calibrate(frames: list[FrameBoxes], camera_lat: float, camera_lon: float,
                            image_size=(1280, 720), center=None, options: SearchOptions | None = None,
                            fit_options: FitOptions | None = None, water_levels=None) -> Association:
    """Find the vessel's box in each frame and the camera; CalibrationError if no trustworthy fit exists.

    ``water_levels`` (per frame, m): the tide at each frame's instant, for a fit that allows for it.
    """
    options = (options or SearchOptions()).checked()
    fit_options = fit_options or FitOptions()
    geodesy.validate_lat_lon(camera_lat, camera_lon, "camera position")
    width, height = (int(v) for v in image_size)
    center_arr = np.array(center if center is not None else (width / 2.0, height / 2.0), dtype=float)
    frames = [f for f in frames if math.isfinite(f.lat) and math.isfinite(f.lon)]
    levels = None if water_levels is None else np.asarray(water_levels, dtype=float)
    if len(frames) < options.min_associations:
        raise CalibrationError(
            f"only {len(frames)} frames with a GPS fix of the vessel: at least {options.min_associations} are needed; "
            "give more videos (or frames) during which the GPS-tracked boat passes in view")
    xw, yw = geodesy.gps_to_local(np.array([f.lat for f in frames]), np.array([f.lon for f in frames]),
                                  camera_lat, camera_lon)
    world = np.column_stack([xw, yw])
    anchors, anchors_index, scores = _candidate_anchors(frames, options)
    with_boxes = int(np.sum(anchors_index[:, 0] >= 0))
    if with_boxes == 0:
        raise CalibrationError(
            f"the detector found no boat (score >= {options.min_score:g}) in any of the {len(frames)} frames: check "
            "that the frames show the sea, or lower the detector's score threshold")
    if with_boxes < options.min_associations:
        raise CalibrationError(
            f"only {with_boxes} of {len(frames)} frames have a detected boat: at least {options.min_associations} "
            "are needed")
    hypotheses, scored, misplaced = _consensus_search(world, anchors, scores, center_arr, options)
    association, reasons = _best_association(hypotheses, frames, world, levels, anchors, anchors_index, camera_lat,
                                             camera_lon, (width, height), center_arr, options, fit_options,
                                             scored, with_boxes)
    if association is None:
        _refuse_without_camera(reasons, misplaced, options)
    _check_trustworthy(association, options)
    return association


def _best_association(hypotheses, frames, world, levels, anchors, anchors_index, camera_lat, camera_lon, image_size,
                      center, options, fit_options, scored, with_boxes) -> tuple[Association | None, list[str]]:
    """Each consensus hypothesis refined: the association of the most frames (then the least residual).

    Also why hypotheses were dropped (an unusable or impossible camera), for the error when none is left.
    """
    best: tuple[int, float, Association] | None = None
    reasons: list[str] = []
    for H, k1, _cost in hypotheses:
        try:
            model = CameraModel(front_sign(H, world), k1, center=tuple(center), image_size=image_size,
                                camera_lat=camera_lat, camera_lon=camera_lon, box_anchor=options.box_anchor)
        except CalibrationError as exc:
            reasons.append(str(exc))
            continue
        first_chosen, _ = _associate(model, world, None, anchors, options.gates_px[0])
        consensus = int(np.sum(first_chosen >= 0))
        try:
            found = _refine_association(frames, world, levels, anchors, anchors_index, model, camera_lat, camera_lon,
                                        image_size, center, options, fit_options)
        except CalibrationError as exc:
            reasons.append(str(exc))
            continue
        if found is None:
            continue
        result, chosen_slots, residual = found
        why = _implausible(result.model, options)
        if why is not None:
            reasons.append(why)
            continue
        chosen = np.where(chosen_slots >= 0, anchors_index[np.arange(len(frames)), np.maximum(chosen_slots, 0)], -1)
        association = Association(result=result, frames=frames, chosen=chosen, residual_px=residual,
                                  consensus=consensus, hypotheses=scored, frames_with_boxes=with_boxes)
        count = association.associated
        if best is None or count > best[0] or (count == best[0] and np.nanmedian(residual) < best[1]):
            best = (count, float(np.nanmedian(residual)), association)
    return (None if best is None else best[2]), reasons


def _refuse_without_camera(reasons: list[str], misplaced, options: SearchOptions) -> NoReturn:
    """CalibrationError saying why no hypothesis gave a camera: the likeliest of the reasons met."""
    far = [why for why in reasons if "given camera position" in why]
    if far:
        raise CalibrationError(f"the best camera explaining the track is impossible here: {far[0]}")
    if misplaced[0] >= options.min_associations:
        raise CalibrationError(
            f"the best camera explaining the track is impossible here: it would stand {misplaced[1]:.0f} m from "
            f"the given camera position (allowed {options.max_nadir_m:g} m; it puts {misplaced[0]} frames' GPS "
            "on a detected boat): check --camera-lat/--camera-lon")
    implausible = [why for why in reasons if why.startswith("the camera would") or why.startswith("the focal")]
    detail = f" (the best candidate: {implausible[0]})" if implausible else ""
    raise CalibrationError(
        "no camera puts the vessel's GPS track on detected boats: the track may never come into view, the "
        f"camera position may be wrong, or the detector misses the boat{detail}")


def _refine_association(frames, world, levels, anchors, anchors_index, model, camera_lat, camera_lon, image_size,
                        center, options, fit_options):
    """Rounds of associate-then-fit with a tightening gate; (result, slots, residuals) or None if it falls apart.

    The rounds ignore the tide (cheap fits); the last association and fit allow for it when levels are given.
    """
    def fit(slots, pair_levels):
        return _fit(frames, slots, anchors_index, camera_lat, camera_lon, image_size, center, fit_options,
                    options.box_anchor, pair_levels)

    for gate in options.gates_px:
        slots, _ = _associate(model, world, None, anchors, gate)
        if np.sum(slots >= 0) < 6:
            return None
        model = fit(slots, None)[0].model
    if levels is not None:
        slots, _ = _associate(model, world, None, anchors, options.gates_px[-1])
        model = fit(slots, levels)[0].model
    slots, residual = _associate(model, world, levels, anchors, options.gates_px[-1])
    if np.sum(slots >= 0) < 6:
        return None
    result, slots = fit(slots, levels)
    return result, slots, np.where(slots >= 0, residual, np.nan)


def _check_trustworthy(association: Association, options: SearchOptions) -> None:
    count = association.associated
    if count < options.min_associations:
        raise CalibrationError(
            f"only {count} frames could be associated with a detected boat (at least {options.min_associations} "
            "needed): the track may barely come into view, or the detector misses the boat; add videos")
    ranges = association._ranges()
    ratio = float(np.percentile(ranges, 90) / max(np.percentile(ranges, 10), 1e-9))
    if ratio < options.min_range_ratio:
        raise CalibrationError(
            f"the {count} associated frames are all at about one range ({np.percentile(ranges, 10):.0f} to "
            f"{np.percentile(ranges, 90):.0f} m, 10th to 90th percentile): the fit cannot tell height from tilt; "
            "add videos where the boat runs towards or away from the camera")
