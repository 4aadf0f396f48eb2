"""Recall, precision and average precision of boxes against hand boxes, overall and by the hand box's width.

What ``./vessel detect score-images`` prints (the definitions are in :mod:`vessel_tools.detect.image_folder`):
one matching of boxes to hand boxes per image, greedy by score, then the figures of each width class, where boxes
that belong to another class (matched to its hand box, or unmatched and of its width) are left out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vessel_detect.box_ops import box_iou
from vessel_tools.detect.image_folder import WIDTH_CLASSES
from vessel_tools.detect.recall import HIT_IOU


@dataclass
class Matched:
    """Every box of every image after matching: its score, width, hit flag and the width of its hand box."""

    scores: np.ndarray
    widths: np.ndarray
    hits: np.ndarray  # bool
    matched_widths: np.ndarray  # width of the hand box it matched, NaN when none
    truth_widths: np.ndarray  # every hand box's width


def match_image(boxes: np.ndarray, scores: np.ndarray, truth: np.ndarray, iou: float = HIT_IOU) -> np.ndarray:
    """For each box (any order) the index of the hand box it matches, or -1; highest score first, one each."""
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    truth = np.asarray(truth, float).reshape(-1, 4)
    matched = np.full(len(boxes), -1, dtype=np.int64)
    if not len(boxes) or not len(truth):
        return matched
    overlaps = box_iou(boxes, truth)
    taken = np.zeros(len(truth), bool)
    for i in np.argsort(-np.asarray(scores, float), kind="stable"):
        candidates = np.where(~taken, overlaps[i], -1.0)
        best = int(np.argmax(candidates))
        if candidates[best] >= iou:
            matched[i], taken[best] = best, True
    return matched


def match_all(detections: dict, truths: dict, threshold: float) -> Matched:
    """Match every image's boxes at or above ``threshold``; images without hand labels are not in ``truths``."""
    scores, widths, hits, matched_widths, truth_widths = [], [], [], [], []
    for name, truth in truths.items():
        boxes, image_scores = detections.get(name, (np.zeros((0, 4)), np.zeros(0)))
        keep = np.asarray(image_scores, float) >= threshold
        boxes, image_scores = np.asarray(boxes, float).reshape(-1, 4)[keep], np.asarray(image_scores, float)[keep]
        index = match_image(boxes, image_scores, truth)
        truth_w = truth[:, 2] - truth[:, 0]
        scores.append(image_scores)
        widths.append(boxes[:, 2] - boxes[:, 0])
        hits.append(index >= 0)
        matched_widths.append(np.where(index >= 0, truth_w[np.maximum(index, 0)] if len(truth) else np.nan, np.nan))
        truth_widths.append(truth_w)
    def joined(parts, dtype=float):
        return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)
    return Matched(joined(scores), joined(widths), joined(hits, bool), joined(matched_widths), joined(truth_widths))


def average_precision(scores: np.ndarray, hits: np.ndarray, positives: int) -> float:
    """Area under the all-point interpolated precision-recall curve (VOC 2010 on)."""
    if positives == 0:
        return math.nan
    order = np.argsort(-scores, kind="stable")
    true_pos = np.cumsum(hits[order])
    precision = true_pos / np.arange(1, len(order) + 1)
    recall = true_pos / positives
    precision = np.concatenate([[0.0], precision, [0.0]])
    recall = np.concatenate([[0.0], recall, [recall[-1] if len(recall) else 0.0]])
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    steps = np.where(recall[1:] != recall[:-1])[0]
    return float(np.sum((recall[steps + 1] - recall[steps]) * precision[steps + 1]))


def width_class_figures(matched: Matched, low: float, high: float) -> dict:
    """Recall, precision and AP of one width class of hand boxes ``[low, high)``."""
    truth_in = (matched.truth_widths >= low) & (matched.truth_widths < high)
    matched_in = (matched.matched_widths >= low) & (matched.matched_widths < high)
    own_width = (matched.widths >= low) & (matched.widths < high)
    counted = np.where(matched.hits, matched_in, own_width)
    scores, hits = matched.scores[counted], matched.hits[counted]
    positives, found = int(truth_in.sum()), int(hits.sum())
    return {"boxes": positives, "found": found, "detections": int(len(hits)),
            "recall": found / positives if positives else math.nan,
            "precision": found / len(hits) if len(hits) else math.nan,
            "ap": average_precision(scores, hits, positives)}


def score_images(detections: dict, truths: dict, threshold: float) -> dict:
    """The figures of every width class (``WIDTH_CLASSES``), keyed by its name."""
    matched = match_all(detections, truths, threshold)
    return {name: width_class_figures(matched, low, high) for name, low, high in WIDTH_CLASSES}


def figures_table(figures: dict, images: int, threshold: float) -> str:
    """The table ``score-images`` prints."""
    lines = [f"{images} images, IoU >= {HIT_IOU}, score >= {threshold:g}, every box a vessel",
             f"{'width':>9} {'boxes':>6} {'found':>6} {'recall':>7} {'dets':>6} {'precision':>9} {'AP':>6}"]
    for name, f in figures.items():
        lines.append(f"{name:>9} {f['boxes']:6d} {f['found']:6d} {_pct(f['recall']):>7} {f['detections']:6d} "
                     f"{_pct(f['precision']):>9} {_pct(f['ap']):>6}")
    return "\n".join(lines)


def _pct(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{value:.3f}"
