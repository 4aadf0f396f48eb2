"""The detector-run CSV (``video,frame,x1,y1,x2,y2,score,class_id,p_target``): one writer and one reader for every tool.

``p_target`` is the probability that the box is the vessel of interest (the network's target class, or the
appearance cue); empty where neither gives one. Readers hand it on as the box's confidence where it is given,
as the tracker node does with the detector's target hypothesis (``confidence_class``), else the score.

``./vessel detect run`` writes it, ``vessel_tools.track.appearance score`` rewrites it with the cue's probabilities,
and ``vessel_tools.track.pipeline``, ``./vessel demo --detections`` and ``detect eval`` read it. Kept free of OpenCV
and onnxruntime so the ROS-free tracking tools can read it cheaply.
"""
from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

import numpy as np

from vessel_common.errors import DataError

CSV_COLUMNS = ("video", "frame", "x1", "y1", "x2", "y2", "score", "class_id", "p_target")
#: COCO's "boat", the class written when a tool does not know it.
COCO_BOAT = 8


def csv_row(video: int, frame: int, box, score: float, class_id: int = COCO_BOAT,
            p_target: float = float("nan")) -> list[str]:
    """One row: pixel coordinates to 0.1 px, the score and ``p_target`` to 4 decimals (empty when unknown)."""
    target = f"{float(p_target):.4f}" if math.isfinite(float(p_target)) else ""
    return [str(int(video)), str(int(frame)), *(f"{float(v):.1f}" for v in box), f"{float(score):.4f}",
            str(int(class_id)), target]


def read_detections_csv(path: Path, missing_hint: str = "write one with './vessel detect run'",
                        confidence: str = "p_target") -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """(video, frame) -> (boxes (N, 4), confidences (N,)); DataError naming the file, and the row, for bad input.

    A row's confidence is its ``p_target`` where the column is filled, else its ``score``; with
    ``confidence="score"`` always the detector's score (a tool that wants every boat, not the vessel of interest).
    """
    if confidence not in ("p_target", "score"):
        raise ValueError(f"confidence must be 'p_target' or 'score', got {confidence!r}")
    path = Path(path)
    if not path.is_file():
        raise DataError(f"detections file {path} not found: {missing_hint}")
    grouped: dict[tuple[int, int], list[list[float]]] = {}
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        missing = [c for c in CSV_COLUMNS[:7] if c not in (reader.fieldnames or [])]
        if missing:
            raise DataError(f"{path} lacks column(s) {', '.join(missing)}; expected {','.join(CSV_COLUMNS)}")
        for line, row in enumerate(reader, start=2):
            try:
                key = (int(row["video"]), int(row["frame"]))
                values = [float(row[c]) for c in ("x1", "y1", "x2", "y2", "score")]
                target_text = (row.get("p_target") or "").strip()
                target = float(target_text) if target_text else 0.0
            except (TypeError, ValueError):
                raise DataError(f"{path}, row {line}: video, frame, x1..y2, score and p_target must be numbers, got "
                                f"{row}") from None
            if not all(math.isfinite(v) for v in (*values, target)):
                raise DataError(f"{path}, row {line}: x1..y2, score and p_target must be finite numbers (or "
                                f"p_target empty), got {row}; fix or delete the row")
            if target_text and confidence == "p_target":
                values[4] = target
            grouped.setdefault(key, []).append(values)
    return {k: (np.asarray(v)[:, :4], np.asarray(v)[:, 4]) for k, v in grouped.items()}


def require_rows_for(detections: dict, videos, path: Path) -> None:
    """DataError when ``detections`` (``read_detections_csv``) has boxes, none of them in ``videos`` (None: any).

    A file written for other videos would otherwise be scored as a detector that found nothing. A file with no
    box at all is what a detector that found nothing writes: said on standard error, not refused.
    """
    wanted = None if videos is None else set(videos)
    if any(wanted is None or video in wanted for video, _ in detections):
        return
    which = "any video" if wanted is None else f"videos {', '.join(map(str, sorted(wanted)))}"
    if not detections:
        print(f"warning: {path} holds no box: every frame of {which} counts as one where the detector found "
              "nothing", file=sys.stderr)
        return
    found = sorted({video for video, _ in detections})
    raise DataError(f"{path} has no box in {which} (its boxes are in videos {', '.join(map(str, found))}): give "
                    "the detections of these videos (`./vessel detect run --videos ... --out FILE.csv`) or fix "
                    "--videos")
