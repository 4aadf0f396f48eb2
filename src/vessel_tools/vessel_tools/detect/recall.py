"""Recall of the vessel of interest, and how often its box is the most likely one: against hand boxes or its GPS.

What ``./vessel detect recall`` prints and what the training command validates with: one definition of a hit
(IoU >= ``HIT_IOU`` with a primary hand box) for both. ``./vessel detect rank`` asks the same on every frame with
the vessel's GPS in view (``gps_ranking``), about three times as many frames as are hand-labelled, by range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vessel_detect.box_ops import box_iou, boxes_containing

HIT_IOU = 0.3
GPS_MARGIN_PX = 10.0  # the dataset's screen point of the GPS is good to about 10 px
RANGE_EDGES_M = (0.0, 100.0, 150.0, 200.0, 300.0, math.inf)


@dataclass
class RecallResult:
    """Recall figures at one score threshold."""

    threshold: float
    boxes: int
    box_hits: int
    frames: int
    frame_hits: int
    other_per_frame: float
    per_video: dict[int, tuple[int, int]]
    top_hits: int = 0

    @property
    def top_rate(self) -> float:
        """Share of labelled frames whose most likely box (highest confidence) is the vessel."""
        return self.top_hits / self.frames if self.frames else math.nan

    @property
    def box_recall(self) -> float:
        """Share of primary hand boxes matched by a detection."""
        return self.box_hits / self.boxes if self.boxes else math.nan

    @property
    def frame_recall(self) -> float:
        """Share of labelled frames where some primary box was matched."""
        return self.frame_hits / self.frames if self.frames else math.nan

    def as_dict(self) -> dict:
        """JSON-friendly form."""
        return {
            "score_threshold": self.threshold,
            "boxes": self.boxes,
            "box_hits": self.box_hits,
            "box_recall": self.box_recall,
            "frames": self.frames,
            "frame_hits": self.frame_hits,
            "frame_recall": self.frame_recall,
            "top_hits": self.top_hits,
            "top_rate": self.top_rate,
            "other_detections_per_frame": self.other_per_frame,
            "per_video": {str(v): {"boxes": n, "hits": h} for v, (n, h) in sorted(self.per_video.items())},
        }


def recall_at(
    labels_by_frame: dict[tuple[int, int], np.ndarray],
    detections: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]],
    threshold: float,
    horizon_y=None,
    hit_iou: float = HIT_IOU,
) -> RecallResult:
    """Recall of the hand boxes and other detections below the horizon per labelled frame.

    ``horizon_y(xs) -> ys`` (a CameraModel's) decides "below the horizon" for the other detections: their
    bottom edge lies below the horizon at their centre x (all count when it is None).
    """
    boxes = hits = frame_hits = top_hits = 0
    others = []
    per_video: dict[int, tuple[int, int]] = {}
    for key, hand in sorted(labels_by_frame.items()):
        det_boxes, det_scores = detections.get(key, (np.zeros((0, 4)), np.zeros(0)))
        above = det_scores >= threshold
        det_boxes, det_scores = det_boxes[above], det_scores[above]
        iou = box_iou(hand, det_boxes) if len(det_boxes) else np.zeros((len(hand), 0))
        matched_hand = (iou >= hit_iou).any(axis=1)
        matched_det = (iou >= hit_iou).any(axis=0)
        boxes += len(hand)
        hits += int(matched_hand.sum())
        frame_hits += int(matched_hand.any())
        if len(det_boxes):
            best = int(np.argmax(det_scores))
            top_hits += int((iou[:, best] >= hit_iou).any())
        n, h = per_video.get(key[0], (0, 0))
        per_video[key[0]] = (n + len(hand), h + int(matched_hand.sum()))
        unmatched = det_boxes[~matched_det]
        if horizon_y is not None and len(unmatched):
            with np.errstate(invalid="ignore"):
                line = np.asarray(horizon_y((unmatched[:, 0] + unmatched[:, 2]) / 2.0), dtype=float)
            line = np.where(np.isfinite(line), line, np.nanmin(line) if np.isfinite(line).any() else -np.inf)
            unmatched = unmatched[unmatched[:, 3] > line]
        others.append(len(unmatched))
    return RecallResult(
        threshold, boxes, hits, len(labels_by_frame), frame_hits,
        float(np.mean(others)) if others else math.nan, per_video, top_hits,
    )


@dataclass
class GpsRanking:
    """Per range band: frames with the vessel's GPS point in view, those with a box at it, those whose top box is."""

    edges_m: tuple[float, ...]
    frames: list[int]
    found: list[int]
    top: list[int]
    margin_px: float = GPS_MARGIN_PX

    def as_dict(self) -> dict:
        """JSON-friendly form (``math.inf`` as null)."""
        bands = [{"from_m": lo, "to_m": hi if math.isfinite(hi) else None, "frames": n, "found": f, "top": t}
                 for lo, hi, n, f, t in zip(self.edges_m[:-1], self.edges_m[1:], self.frames, self.found, self.top,
                                            strict=True)]
        total = sum(self.frames)
        return {"margin_px": self.margin_px, "frames": total, "found": sum(self.found), "top": sum(self.top),
                "top_rate": sum(self.top) / total if total else None, "bands": bands}


def gps_ranking(
    points: dict[tuple[int, int], tuple[float, float, float]],
    detections: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]],
    margin_px: float = GPS_MARGIN_PX,
    edges_m=RANGE_EDGES_M,
) -> GpsRanking:
    """Whether a box, and the box of highest confidence, lies at the vessel's GPS point in each frame.

    ``points``: (video, frame) -> (x, y, range_m), the screen point of the vessel's GPS and its range; a box is at
    the point when the point lies inside the box grown by ``margin_px`` on every side. Needs no hand label, so it
    covers every frame with GPS, far ones included; the point is coarser than a hand box.
    """
    edges = tuple(float(e) for e in edges_m)
    if len(edges) < 2 or any(not b > a for a, b in zip(edges[:-1], edges[1:], strict=True)):
        raise ValueError(f"range edges must increase, got {edges_m!r}")
    frames, found, top = [0] * (len(edges) - 1), [0] * (len(edges) - 1), [0] * (len(edges) - 1)
    for key, (x, y, range_m) in sorted(points.items()):
        band = int(np.searchsorted(edges, range_m, side="right")) - 1
        if not 0 <= band < len(frames):
            continue
        frames[band] += 1
        boxes, scores = detections.get(key, (np.zeros((0, 4)), np.zeros(0)))
        if not len(boxes):
            continue
        at_point = boxes_containing(boxes, (x, y), margin_px)
        found[band] += int(at_point.any())
        top[band] += int(at_point[int(np.argmax(scores))])
    return GpsRanking(edges, frames, found, top, float(margin_px))
