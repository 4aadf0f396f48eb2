"""Windows of the frame fed to the network, and the merge of their detections into one set.

A window is a source rectangle resized by a scale to fit the network input. Overlapping windows see a boat
near their shared edge twice: whole in one, cut by the edge in the other. The merge (1) joins pieces of one
boat cut by facing edges of two windows (when no window holds it whole), (2) prefers boxes not cut by a
window edge, dropping cut boxes mostly covered by a kept box, and (3) suppresses the remaining duplicates
with IoU NMS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vessel_detect.box_ops import box_iou, intersection_over_first, nms

# Box sides: index into the (N, 4) cut flags.
LEFT, TOP, RIGHT, BOTTOM = 0, 1, 2, 3


@dataclass(frozen=True)
class Window:
    """A source rectangle ``[x0, x1) x [y0, y1)`` (pixels) shown to the network at ``scale``.

    ``interior`` flags (left, top, right, bottom) mark the edges inside the image: a box touching one of
    them may be cut off there, while the image border cuts nothing that can be seen anyway.
    """

    x0: int
    y0: int
    x1: int
    y1: int
    scale: float
    interior: tuple[bool, bool, bool, bool] = (False, False, False, False)

    @property
    def xyxy(self) -> np.ndarray:
        """The rectangle as a float array ``[x0, y0, x1, y1]``."""
        return np.array([self.x0, self.y0, self.x1, self.y1], dtype=np.float64)


def axis_positions(start: float, end: float, window: int, min_overlap: int, limit: int) -> list[int]:
    """Starts of windows of length ``window`` covering ``[start, end)`` inside ``[0, limit)``.

    Adjacent windows overlap by at least ``min_overlap`` pixels. A span shorter than one window gets a single
    window centred on it and shifted inside the image, so it shows the network some context around the span.
    """
    window = int(window)
    if window >= limit:
        return [0]
    span = end - start
    if span <= window:
        first = int(round((start + end) / 2.0 - window / 2.0))
        return [min(max(first, 0), limit - window)]
    step = max(window - int(min_overlap), 1)
    count = int(math.ceil((span - window) / step)) + 1
    starts = np.linspace(start, end - window, count)
    return sorted({min(max(int(round(s)), 0), limit - window) for s in starts})


def tile_windows(
    region_xyxy: tuple[float, float, float, float],
    image_wh: tuple[int, int],
    network_wh: tuple[int, int],
    scale: float,
    min_overlap: int,
) -> list[Window]:
    """Overlapping windows covering ``region_xyxy`` that the network sees at ``scale`` (px per source px).

    Each window's source size is the network input divided by the scale (clipped to the image).
    """
    width, height = image_wh
    win_w = max(1, int(round(network_wh[0] / scale)))
    win_h = max(1, int(round(network_wh[1] / scale)))
    x0, y0, x1, y1 = region_xyxy
    windows = []
    for top in axis_positions(y0, y1, win_h, min_overlap, height):
        for left in axis_positions(x0, x1, win_w, min_overlap, width):
            right, bottom = min(left + win_w, width), min(top + win_h, height)
            interior = (left > 0, top > 0, right < width, bottom < height)
            windows.append(Window(left, top, right, bottom, float(scale), interior))
    return windows


def cut_flags(boxes_xyxy: np.ndarray, window: Window, tolerance_px: float) -> np.ndarray:
    """``(N, 4)`` flags: the box touches an interior edge of ``window`` (left, top, right, bottom)."""
    boxes = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4)
    flags = np.zeros((boxes.shape[0], 4), dtype=bool)
    interior = window.interior
    flags[:, LEFT] = interior[LEFT] & (boxes[:, 0] <= window.x0 + tolerance_px)
    flags[:, TOP] = interior[TOP] & (boxes[:, 1] <= window.y0 + tolerance_px)
    flags[:, RIGHT] = interior[RIGHT] & (boxes[:, 2] >= window.x1 - tolerance_px)
    flags[:, BOTTOM] = interior[BOTTOM] & (boxes[:, 3] >= window.y1 - tolerance_px)
    return flags


@dataclass
class WindowDetections:
    """Detections of every window in source pixels, with where they came from and which sides are cut."""

    boxes_xyxy: np.ndarray
    scores: np.ndarray
    class_ids: np.ndarray
    window_index: np.ndarray
    cut: np.ndarray  # (N, 4) bool, see LEFT/TOP/RIGHT/BOTTOM
    target_scores: np.ndarray | None = None  # (N,) score of the target class, NaN when the model has none

    def __post_init__(self) -> None:
        if self.target_scores is None:
            self.target_scores = np.full(np.shape(self.scores), np.nan)

    @staticmethod
    def concatenate(parts: list[WindowDetections]) -> WindowDetections:
        """Stack the detections of several windows."""
        if not parts:
            return WindowDetections(
                np.zeros((0, 4)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 4), bool)
            )
        return WindowDetections(
            np.concatenate([p.boxes_xyxy for p in parts]).reshape(-1, 4),
            np.concatenate([p.scores for p in parts]),
            np.concatenate([p.class_ids for p in parts]).astype(np.int64),
            np.concatenate([p.window_index for p in parts]).astype(np.int64),
            np.concatenate([p.cut for p in parts]).reshape(-1, 4).astype(bool),
            np.concatenate([p.target_scores for p in parts]).astype(np.float64),
        )

    def take(self, indices: np.ndarray) -> WindowDetections:
        """The detections at ``indices``."""
        return WindowDetections(
            self.boxes_xyxy[indices],
            self.scores[indices],
            self.class_ids[indices],
            self.window_index[indices],
            self.cut[indices],
            self.target_scores[indices],
        )

    def __len__(self) -> int:
        return int(self.scores.shape[0])


def _shared_area_iou(a: np.ndarray, b: np.ndarray, shared: np.ndarray) -> float:
    """IoU of boxes ``a`` and ``b`` clipped to the rectangle ``shared`` (0 when either clip is empty)."""
    lo, hi = shared[:2], shared[2:]
    a_clip = np.concatenate([np.maximum(a[:2], lo), np.minimum(a[2:], hi)])
    b_clip = np.concatenate([np.maximum(b[:2], lo), np.minimum(b[2:], hi)])
    if np.any(a_clip[2:] <= a_clip[:2]) or np.any(b_clip[2:] <= b_clip[:2]):
        return 0.0
    return float(box_iou(a_clip, b_clip)[0, 0])


def join_cut_pieces(
    dets: WindowDetections, windows: list[Window], join_iou: float = 0.5
) -> WindowDetections:
    """Join boxes of one object cut by the edges of two overlapping windows into their union.

    Two cut boxes of the same class from different windows are one object when, clipped to the area both
    windows share, they overlap with IoU >= ``join_iou``. Groups are joined transitively (a boat across
    three windows), the score is the group's best, and a side of the union stays cut only if the piece that
    reaches furthest on that side is cut there.
    """
    cut_rows = np.flatnonzero(dets.cut.any(axis=1))
    if cut_rows.size < 2:
        return dets
    groups = _cut_piece_groups(dets, windows, cut_rows, join_iou)
    if all(len(members) == 1 for members in groups.values()):
        return dets
    pieces = {int(i) for i in cut_rows}
    rows = [(dets.boxes_xyxy[i], dets.scores[i], dets.class_ids[i], dets.window_index[i], dets.cut[i],
             dets.target_scores[i]) for i in range(len(dets)) if i not in pieces]
    rows += [_joined_pieces(dets, members) for members in groups.values()]
    boxes, scores, class_ids, window_index, cut, targets = zip(*rows, strict=True)
    return WindowDetections(
        np.asarray(boxes, dtype=np.float64).reshape(-1, 4),
        np.asarray(scores, dtype=np.float64),
        np.asarray(class_ids, dtype=np.int64),
        np.asarray(window_index, dtype=np.int64),
        np.asarray(cut, dtype=bool).reshape(-1, 4),
        np.asarray(targets, dtype=np.float64),
    )


def _cut_piece_groups(dets: WindowDetections, windows: list[Window], cut_rows: np.ndarray,
                      join_iou: float) -> dict[int, list[int]]:
    """The cut boxes ``cut_rows`` grouped by object (union-find over the pairs that are pieces of one object)."""
    parent = {int(i): int(i) for i in cut_rows}

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a_pos, i in enumerate(cut_rows):
        for j in cut_rows[a_pos + 1 :]:
            if _pieces_of_one_object(dets, windows, i, j, join_iou):
                parent[root(int(i))] = root(int(j))
    groups: dict[int, list[int]] = {}
    for i in cut_rows:
        groups.setdefault(root(int(i)), []).append(int(i))
    return groups


def _pieces_of_one_object(dets: WindowDetections, windows: list[Window], i: int, j: int, join_iou: float) -> bool:
    """Whether cut boxes ``i`` and ``j`` (same class, other windows) overlap enough where their windows meet."""
    if dets.window_index[i] == dets.window_index[j] or dets.class_ids[i] != dets.class_ids[j]:
        return False
    wi, wj = windows[dets.window_index[i]].xyxy, windows[dets.window_index[j]].xyxy
    shared = np.concatenate([np.maximum(wi[:2], wj[:2]), np.minimum(wi[2:], wj[2:])])
    if np.any(shared[2:] <= shared[:2]):
        return False
    return _shared_area_iou(dets.boxes_xyxy[i], dets.boxes_xyxy[j], shared) >= join_iou


def _joined_pieces(dets: WindowDetections, members: list[int]) -> tuple:
    """One detection for the pieces ``members``: (box, score, class id, window index, cut flags, target score)."""
    member_boxes = dets.boxes_xyxy[members]
    union = np.concatenate([member_boxes[:, :2].min(axis=0), member_boxes[:, 2:].max(axis=0)])
    reach = [
        int(np.argmin(member_boxes[:, 0])),
        int(np.argmin(member_boxes[:, 1])),
        int(np.argmax(member_boxes[:, 2])),
        int(np.argmax(member_boxes[:, 3])),
    ]
    best = members[int(np.argmax(dets.scores[members]))]
    member_targets = dets.target_scores[members]
    target = np.nanmax(member_targets) if np.isfinite(member_targets).any() else np.nan
    cut = np.array([dets.cut[members[reach[side]], side] for side in range(4)])
    return union, dets.scores[best], dets.class_ids[best], dets.window_index[best], cut, target


def merge_windows(
    dets: WindowDetections,
    windows: list[Window],
    iou_threshold: float,
    covered_threshold: float = 0.6,
    join_iou: float = 0.5,
    class_agnostic: bool = False,
) -> WindowDetections:
    """Merge the detections of overlapping windows into one set (see the module docstring).

    Boxes not cut by a window edge are taken first (best score first), then cut ones. A box is dropped when
    its IoU with a kept box of its class exceeds ``iou_threshold``, or when it is cut and a kept box of its
    class covers at least ``covered_threshold`` of its area.
    """
    if len(dets) == 0:
        return dets
    dets = join_cut_pieces(dets, windows, join_iou)
    is_cut = dets.cut.any(axis=1)
    order = np.lexsort((-dets.scores, is_cut))
    same_class = dets.class_ids[:, None] == dets.class_ids[None, :]
    if class_agnostic:
        same_class = np.ones_like(same_class)
    iou = np.where(same_class, box_iou(dets.boxes_xyxy, dets.boxes_xyxy), 0.0)
    covered = np.where(same_class, intersection_over_first(dets.boxes_xyxy, dets.boxes_xyxy), 0.0)
    kept: list[int] = []
    for index in order:
        if kept:
            if np.any(iou[index, kept] > iou_threshold):
                continue
            if is_cut[index] and np.any(covered[index, kept] >= covered_threshold):
                continue
        kept.append(int(index))
    return dets.take(np.asarray(kept, dtype=np.int64))


def nms_per_window(dets: WindowDetections, iou_threshold: float, class_agnostic: bool = False) -> WindowDetections:
    """NMS inside one window's detections (the usual single-image NMS), per class unless ``class_agnostic``."""
    return dets.take(nms(dets.boxes_xyxy, dets.scores, iou_threshold, None if class_agnostic else dets.class_ids))
