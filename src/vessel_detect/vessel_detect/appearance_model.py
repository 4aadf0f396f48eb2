"""Appearance cue for the vessel of interest: colour features of a box's crop and a logistic regression on them.

A COCO detector finds every boat with similar scores; what tells the vessel of interest from sailboats and jet
skis here is how it looks. The model is fitted offline (``python -m vessel_track.appearance fit``) with the
paper's trick, no hand labelling: boxes of the vessel generated from its GPS through the calibration on the
training videos are the positives, the other detections the negatives. The detector node applies it
(parameter ``appearance_model``): score x probability, boxes below ``appearance_min_probability`` dropped.
"""

from __future__ import annotations

import io
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_calib.errors import DataError, ModelError

FEATURE_SIZE = 46
#: Chosen on training videos 7-12 (leave-one-video-out, detector output): the detector score times the
#: probability, detections with a probability below 0.3 dropped (they are not the vessel of interest and only
#: give the tracker boxes to swap identities with).
DEFAULT_COMBINE = "product"
DEFAULT_MIN_PROBABILITY = 0.3


def crop_features(bgr: np.ndarray, boxes_xyxy) -> np.ndarray:
    """(N, 46) colour features of each box's crop of a BGR uint8 image (boxes clipped to the image)."""
    import cv2

    image = np.asarray(bgr)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise DataError(f"appearance: expected a BGR uint8 image (H, W, 3), got {image.dtype} {image.shape}")
    boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    height, width = image.shape[:2]
    out = np.zeros((boxes.shape[0], FEATURE_SIZE))
    for i, box in enumerate(boxes):
        if not np.all(np.isfinite(box)):
            out[i] = np.nan
            continue
        x1, y1, x2, y2 = (int(round(v)) for v in box)
        x1, y1 = min(max(x1, 0), width - 1), min(max(y1, 0), height - 1)
        x2, y2 = max(min(x2, width), x1 + 1), max(min(y2, height), y1 + 1)
        crop = image[y1:y2, x1:x2]
        hsv = cv2.cvtColor(crop, cv2.COLOR_BGR2HSV)
        hs = cv2.calcHist([hsv], [0, 1], None, [8, 4], [0, 180, 0, 256]).ravel()
        value = cv2.calcHist([hsv], [2], None, [8], [0, 256]).ravel()
        lab = cv2.cvtColor(crop, cv2.COLOR_BGR2LAB).reshape(-1, 3).astype(float) / 255.0
        out[i] = np.concatenate([hs / max(hs.sum(), 1.0), value / max(value.sum(), 1.0), lab.mean(0), lab.std(0)])
    return out


@dataclass(frozen=True)
class AppearanceModel:
    """Logistic regression on standardised crop features: ``p = 1 / (1 + exp(-(w . (f - mean) / scale + bias)))``."""

    mean: np.ndarray
    scale: np.ndarray
    weights: np.ndarray
    bias: float
    source: str = ""

    def __post_init__(self) -> None:
        """Check shapes and values."""
        for name in ("mean", "scale", "weights"):
            value = np.asarray(getattr(self, name), dtype=float).reshape(-1)
            if value.size != FEATURE_SIZE or not np.all(np.isfinite(value)):
                raise ModelError(f"appearance model: {name} must be {FEATURE_SIZE} finite numbers")
            object.__setattr__(self, name, value)
        if not np.all(self.scale > 0) or not math.isfinite(self.bias):
            raise ModelError("appearance model: scale must be > 0 and bias finite")

    def probability_of_features(self, features: np.ndarray) -> np.ndarray:
        """(N,) probability that each feature row is the vessel of interest (NaN rows: NaN)."""
        f = np.asarray(features, dtype=float).reshape(-1, FEATURE_SIZE)
        z = ((f - self.mean) / self.scale) @ self.weights + self.bias
        return 1.0 / (1.0 + np.exp(-np.clip(z, -50, 50)))

    def probability(self, bgr: np.ndarray, boxes_xyxy) -> np.ndarray:
        """(N,) probability that each box of the image is the vessel of interest."""
        return self.probability_of_features(crop_features(bgr, boxes_xyxy))

    def save(self, path: Path) -> None:
        """Write an .npz atomically."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        buffer = io.BytesIO()
        np.savez(buffer, mean=self.mean, scale=self.scale, weights=self.weights, bias=np.array(self.bias),
                 source=np.array(self.source))
        handle, temp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        try:
            with os.fdopen(handle, "wb") as out:
                out.write(buffer.getvalue())
            os.chmod(temp, 0o644)
            os.replace(temp, path)
        except BaseException:
            Path(temp).unlink(missing_ok=True)
            raise

    @classmethod
    def load(cls, path: Path) -> AppearanceModel:
        """Read an .npz written by ``save``; ModelError naming the file if it is missing or malformed."""
        path = Path(path)
        if not path.is_file():
            raise ModelError(f"{path}: no such appearance model; write one with `python -m vessel_track.appearance "
                             f"fit ...`")
        try:
            with np.load(path, allow_pickle=False) as data:
                return cls(data["mean"], data["scale"], data["weights"], float(data["bias"]), str(data["source"]))
        except (OSError, KeyError, ValueError) as error:
            raise ModelError(f"{path}: not an appearance model ({error}); re-run `python -m vessel_track.appearance "
                             f"fit`") from None


def rescore_detections(detections, bgr: np.ndarray, model: AppearanceModel,
                        min_probability: float = DEFAULT_MIN_PROBABILITY):
    """``Detections`` with scores multiplied by the appearance probability, boxes below ``min_probability`` dropped."""
    if len(detections) == 0:
        return detections
    probability = model.probability(bgr, detections.boxes_xyxy)
    keep = probability >= min_probability
    kept = detections.take(keep)
    kept.scores = kept.scores * probability[keep]
    return kept
