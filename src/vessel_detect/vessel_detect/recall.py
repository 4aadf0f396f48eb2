"""Recall of the vessel of interest against its hand boxes, and how often its box is the most likely one.

What ``./vessel detect recall`` prints and what the training command validates with: one definition of a hit
(IoU >= ``HIT_IOU`` with a primary hand box) for both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vessel_detect.box_ops import box_iou

HIT_IOU = 0.3


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
