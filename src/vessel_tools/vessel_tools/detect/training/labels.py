"""Training boxes generated from the vessel's GPS through the calibration, with no hand labels.

For each frame the vessel's GPS, interpolated at the frame's stamp, is projected through the calibration (at
the frame's water level when a tide table is given) to the screen point that stands for it: the point at the
calibration's ``box_anchor`` of the way down the vessel's box. The box around that point:

- its height comes from a size model, ``h = c / |z_p|``, with ``c`` the ``height_quantile`` of ``h |z_p|`` over
  the generic COCO detector's boxes that contain the projected point. The generic detector often boxes only
  the cabin or the console, so its typical box is too short; the tall end of its boxes is the whole boat;
- its vertical placement puts the anchor at the projected point;
- its horizontal extent is the COCO box's that overlaps the size model's box best along x (at least
  ``match_x_iou``) and agrees with it in width, else the size model's width, ``a / |z_p| + b``, fitted robustly
  to the same COCO boxes.

Every other COCO box at or above ``other_score`` is labelled ``vessel`` (the second class), so other boats never
become negatives; weaker COCO boxes and the ones overlapping the vessel's box become ignore regions, where no
objectness loss is taken. Frames whose GPS is stale (the vessel may be visible but unlabelled) are left out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vessel_common.errors import DataError
from vessel_detect.box_ops import box_iou, boxes_containing

CLASS_NAMES = ("vessel_of_interest", "vessel")
TARGET_CLASS, OTHER_CLASS = 0, 1
PAPER_SIZE_MODEL = ((3000.0, 50.0), (1700.0, 50.0))
"""The paper's loose box formula (half resolution, doubled here): width, height = a / |z_p| + b."""


@dataclass(frozen=True)
class LabelSettings:
    """How boxes are generated; the defaults were chosen on the training videos."""

    max_gps_gap_s: float = 6.0
    match_x_iou: float = 0.4
    max_size_ratio: float = 1.8
    height_quantile: float = 0.9
    other_score: float = 0.3
    ignore_score: float = 0.05
    min_box_px: float = 3.0


@dataclass
class FrameLabels:
    """The training targets of one frame, in full-resolution pixels."""

    video: int
    frame: int
    status: str  # labelled | out_of_view | gps_invalid
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    classes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    ignore: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    target_source: str = ""  # coco | size_model | "" (no vessel of interest in view)
    abs_zp: float = math.nan


@dataclass(frozen=True)
class SizeModel:
    """Box width and height of a vessel at projective depth ``|z_p|``: ``a / |z_p| + b`` each."""

    width: tuple[float, float]
    height: tuple[float, float]
    n_points: int = 0

    def size(self, abs_zp) -> tuple[np.ndarray, np.ndarray]:
        """(width, height) in pixels."""
        zp = np.asarray(abs_zp, dtype=float)
        return self.width[0] / zp + self.width[1], self.height[0] / zp + self.height[1]

    def box_at(self, point_xy, abs_zp: float, anchor: float) -> np.ndarray:
        """The model's box whose ``anchor`` point (0 top, 1 bottom) is ``point_xy``."""
        w, h = (float(v) for v in self.size(abs_zp))
        x, y = point_xy
        return np.array([x - w / 2.0, y - anchor * h, x + w / 2.0, y + (1.0 - anchor) * h])


def robust_line_fit(inverse_depth: np.ndarray, sizes: np.ndarray, rounds: int = 5) -> tuple[float, float]:
    """``size = a x + b`` by iteratively reweighted least squares (Huber weights on the MAD scale)."""
    x = np.asarray(inverse_depth, float)
    y = np.asarray(sizes, float)
    A = np.c_[x, np.ones_like(x)]
    weights = np.ones_like(x)
    coef = np.zeros(2)
    for _ in range(rounds):
        sw = np.sqrt(weights)
        coef, *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
        residual = y - A @ coef
        scale = 1.4826 * np.median(np.abs(residual)) + 1e-9
        u = np.abs(residual) / (1.345 * scale)
        weights = np.where(u <= 1.0, 1.0, 1.0 / np.maximum(u, 1e-12))
    return float(coef[0]), float(coef[1])


@dataclass
class Projection:
    """The vessel's GPS at one frame, through the calibration."""

    video: int
    frame: int
    valid: bool
    in_view: bool
    point: tuple[float, float] = (math.nan, math.nan)
    abs_zp: float = math.nan


def project_gps(dataset, camera, frames, max_gap_s: float, water_levels=None) -> list[Projection]:
    """Project the vessel's GPS at each frame's stamp to the screen (the box's anchor point)."""
    track = dataset.gps_track()
    if len(track.stamps) == 0:
        raise DataError(f"{dataset.path} has no GPS of the vessel (target_gps_fixes.csv): no labels can be made")
    if camera.camera_lat is None or camera.camera_lon is None:
        raise DataError("the calibration has no camera position (camera_lat/camera_lon): needed to project GPS")
    stamps = np.array([f.stamp for f in frames], dtype=float)
    lat, lon, valid = track.interpolate(stamps, max_gap_s=max_gap_s)
    width, height = camera.image_size
    out = []
    for i, record in enumerate(frames):
        if not valid[i]:
            out.append(Projection(record.video, record.frame, False, False))
            continue
        cam = camera
        if water_levels is not None:
            level = water_levels.level_at(float(stamps[i]), max_hold_s=900.0)
            if np.isfinite(level):
                cam = camera.at_water_level(float(level))
        xw, yw = cam.gps_to_world(lat[i], lon[i])
        xs, ys, in_front = cam.world_to_screen(xw, yw)
        zp = abs(float(cam.zp_of_world(xw, yw)))
        inside = bool(in_front) and np.isfinite(xs) and np.isfinite(ys) and 0 <= xs < width and 0 <= ys < height
        out.append(Projection(record.video, record.frame, True, bool(inside and zp > 0), (float(xs), float(ys)), zp))
    return out


def _boxes_at_gps(projections, detections, prior: SizeModel, anchor: float) -> tuple[np.ndarray, np.ndarray]:
    """(1/|z_p|, (w, h)) of each frame's COCO box that contains the projected GPS, the one nearest ``prior``."""
    inv, sizes = [], []
    for p in projections:
        if not p.in_view:
            continue
        boxes, _ = detections.get((p.video, p.frame), (np.zeros((0, 4)), np.zeros(0)))
        if len(boxes) == 0:
            continue
        hit = boxes_containing(boxes, p.point, margin=3.0)
        if not hit.any():
            continue
        candidates = boxes[hit]
        best = candidates[int(np.argmax(box_iou(prior.box_at(p.point, p.abs_zp, anchor)[None], candidates)[0]))]
        inv.append(1.0 / p.abs_zp)
        sizes.append((best[2] - best[0], best[3] - best[1]))
    return np.asarray(inv), np.asarray(sizes).reshape(-1, 2)


def fit_size_model(projections, detections, anchor: float, height_quantile: float = 0.9) -> SizeModel:
    """The box-size model of the COCO boxes that contain the vessel's projected GPS (one per frame).

    A first pass picks each frame's box nearest the paper's loose box and fits both sizes robustly; a second
    picks the box nearest that fit. Width: robust least squares of ``a / |z_p| + b``. Height: ``c / |z_p|``
    with ``c`` the ``height_quantile`` of ``h |z_p|`` (the boxes that caught the whole boat, not its cabin).
    """
    prior = SizeModel(*PAPER_SIZE_MODEL)
    for _ in range(2):
        inv, sizes = _boxes_at_gps(projections, detections, prior, anchor)
        if len(inv) < 6:
            raise DataError(
                f"only {len(inv)} frames where the generic detector boxed the vessel at its GPS position: too few "
                "to fit a box-size model (check the calibration, the frames' times and the GPS)")
        fitted = SizeModel(robust_line_fit(inv, sizes[:, 0]), robust_line_fit(inv, sizes[:, 1]), len(inv))
        prior = fitted
    c = float(np.quantile(sizes[:, 1] / inv, height_quantile))
    return SizeModel(fitted.width, (c, 0.0), len(inv))


def _widths_agree(boxes: np.ndarray, width: float, settings: LabelSettings) -> np.ndarray:
    """Which boxes are at most ``max_size_ratio`` times wider or narrower than ``width``."""
    widths = np.maximum(boxes[:, 2] - boxes[:, 0], 1e-6)
    return np.maximum(widths / width, width / widths) <= settings.max_size_ratio


def frame_labels(projection: Projection, boxes: np.ndarray, scores: np.ndarray, size_model: SizeModel, anchor: float,
                 image_wh: tuple[int, int], settings: LabelSettings) -> FrameLabels:
    """The targets of one frame from its projection and the generic detector's boxes."""
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    scores = np.asarray(scores, float).reshape(-1)
    if not projection.valid:
        return FrameLabels(projection.video, projection.frame, "gps_invalid")
    width, height = image_wh
    targets, classes, ignore = [], [], []
    used = np.zeros(len(boxes), dtype=bool)
    status, source = "out_of_view", ""
    if projection.in_view:
        expected = size_model.box_at(projection.point, projection.abs_zp, anchor)
        target = expected
        source = "size_model"
        if len(boxes):
            ew, eh = expected[2] - expected[0], expected[3] - expected[1]
            overlap = np.minimum(boxes[:, 2], expected[2]) - np.maximum(boxes[:, 0], expected[0])
            span = np.maximum(boxes[:, 2], expected[2]) - np.minimum(boxes[:, 0], expected[0])
            x_iou = np.clip(overlap, 0, None) / np.maximum(span, 1e-6)
            ok = (x_iou >= settings.match_x_iou) & _widths_agree(boxes, ew, settings)
            ok &= boxes_containing(boxes, projection.point, margin=max(3.0, 0.25 * eh))
            if ok.any():
                best = int(np.argmax(np.where(ok, x_iou, -1.0)))
                target = np.array([boxes[best, 0], expected[1], boxes[best, 2], expected[3]])
                used[best] = True
                source = "coco"
        target = np.clip(target, [0, 0, 0, 0], [width, height, width, height])
        if target[2] - target[0] >= settings.min_box_px and target[3] - target[1] >= settings.min_box_px:
            targets.append(target)
            classes.append(0)
            status = "labelled"
            if len(boxes):
                near = box_iou(target[None], boxes)[0] > 0.05
                ignore += [b for b in boxes[near & ~used]]
                used |= near
        else:
            source = ""
    for box, score, taken in zip(boxes, scores, used, strict=True):
        if taken:
            continue
        if score >= settings.other_score:
            targets.append(box)
            classes.append(OTHER_CLASS)
        elif score >= settings.ignore_score:
            ignore.append(box)
    return FrameLabels(
        projection.video, projection.frame, status,
        np.asarray(targets, float).reshape(-1, 4), np.asarray(classes, dtype=np.int64),
        np.asarray(ignore, float).reshape(-1, 4), source, projection.abs_zp,
    )


def generate_labels(dataset, camera, frames, detections, settings: LabelSettings | None = None,
                    water_levels=None) -> tuple[list[FrameLabels], SizeModel]:
    """Labels of every frame and the size model they used. ``detections``: (video, frame) -> (boxes, scores)."""
    settings = settings or LabelSettings()
    projections = project_gps(dataset, camera, frames, settings.max_gps_gap_s, water_levels)
    anchor = float(camera.box_anchor)
    size_model = fit_size_model(projections, detections, anchor, settings.height_quantile)
    empty = (np.zeros((0, 4)), np.zeros(0))
    labels = [
        frame_labels(p, *detections.get((p.video, p.frame), empty), size_model, anchor, camera.image_size, settings)
        for p in projections
    ]
    return labels, size_model
