"""Vectorised box geometry: IoU, intersection over own area, points in boxes, class-aware NMS, nested boxes."""

from __future__ import annotations

import numpy as np


def box_areas(boxes_xyxy: np.ndarray) -> np.ndarray:
    """Areas of ``(N, 4)`` boxes; boxes with negative extent have area 0."""
    boxes = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4)
    return np.clip(boxes[:, 2] - boxes[:, 0], 0, None) * np.clip(boxes[:, 3] - boxes[:, 1], 0, None)


def intersection_areas(a_xyxy: np.ndarray, b_xyxy: np.ndarray) -> np.ndarray:
    """``(N, M)`` areas of the intersections of every box of ``a`` with every box of ``b``."""
    a = np.asarray(a_xyxy, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(b_xyxy, dtype=np.float64).reshape(-1, 4)
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    return np.clip(w, 0, None) * np.clip(h, 0, None)


def box_iou(a_xyxy: np.ndarray, b_xyxy: np.ndarray) -> np.ndarray:
    """``(N, M)`` intersection over union; 0 where both boxes are empty."""
    inter = intersection_areas(a_xyxy, b_xyxy)
    union = box_areas(a_xyxy)[:, None] + box_areas(b_xyxy)[None, :] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def boxes_containing(boxes_xyxy: np.ndarray, point, margin: float = 0.0) -> np.ndarray:
    """``(N,)`` which boxes, each grown by ``margin`` on every side, contain the point ``(x, y)``."""
    boxes = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4)
    x, y = point
    return (boxes[:, 0] - margin <= x) & (x <= boxes[:, 2] + margin) & (boxes[:, 1] - margin <= y) & (
        y <= boxes[:, 3] + margin)


def intersection_over_first(a_xyxy: np.ndarray, b_xyxy: np.ndarray) -> np.ndarray:
    """``(N, M)`` share of each box of ``a`` covered by each box of ``b`` (0 for empty boxes of ``a``)."""
    inter = intersection_areas(a_xyxy, b_xyxy)
    area = box_areas(a_xyxy)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(area > 0, inter / np.where(area > 0, area, 1.0), 0.0)


def _greedy_keep(overlap: np.ndarray, order: np.ndarray, threshold: float) -> np.ndarray:
    """Walk ``order``; keep a box unless a kept one overlaps it by more than ``threshold`` (``overlap`` N x N)."""
    suppressed = np.zeros(overlap.shape[0], dtype=bool)
    keep = []
    for index in order:
        if suppressed[index]:
            continue
        keep.append(index)
        suppressed |= overlap[index] > threshold
    return np.asarray(keep, dtype=np.int64)


def nms(
    boxes_xyxy: np.ndarray,
    scores: np.ndarray,
    iou_threshold: float,
    class_ids: np.ndarray | None = None,
    order: np.ndarray | None = None,
) -> np.ndarray:
    """Greedy non-maximum suppression; return the indices kept, best first.

    Boxes of different classes never suppress each other when ``class_ids`` is given. ``order`` replaces the
    default processing order (descending score), e.g. to prefer boxes not cut by a tile edge.
    """
    boxes = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4)
    if boxes.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    if order is None:
        order = np.argsort(-scores, kind="stable")
    iou = box_iou(boxes, boxes)
    if class_ids is not None:
        ids = np.asarray(class_ids).reshape(-1)
        iou = np.where(ids[:, None] == ids[None, :], iou, 0.0)
    return _greedy_keep(iou, np.asarray(order, dtype=np.int64), iou_threshold)


def suppress_nested(boxes_xyxy: np.ndarray, scores: np.ndarray, overlap: float) -> np.ndarray:
    """Indices kept, best first, dropping boxes nested in a better-scored kept box.

    Nested: sharing more than ``overlap`` of the smaller box's area. Plain NMS (IoU) keeps a hull box and a box
    of its cabin or wake as two boats; after the appearance cue has scored them, keeping only the likelier of
    nested boxes leaves the tracker one box per vessel.
    """
    boxes = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4)
    if boxes.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.argsort(-np.asarray(scores, dtype=np.float64).reshape(-1), kind="stable")
    inter = intersection_areas(boxes, boxes)
    areas = box_areas(boxes)
    smaller = np.minimum(areas[:, None], areas[None, :])
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.where(smaller > 0, inter / np.where(smaller > 0, smaller, 1.0), 0.0)
    return _greedy_keep(share, order, overlap)
