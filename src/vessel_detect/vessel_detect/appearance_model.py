"""Cue for the vessel of interest: colour, box geometry and surroundings of a detection, logistic regression.

A COCO detector finds every boat with similar scores (the vessel of interest is the top-scoring box in 3 % of the
validation frames); what tells it from ferries, moored sailboats and jet skis here is how it looks (colour), how
large its box is for where it sits in the image (a small motor boat's box at the depth its position gives, through
the calibration and the box-size distance model), and what is around it (a wake). The model is fitted offline
(``./vessel appearance fit``) with the paper's trick, no hand labelling: boxes of the vessel
generated from its GPS through the calibration on the training videos are the positives, the other detections
the negatives. The detector node applies it (parameter ``appearance_model``): the probability replaces the score
(``appearance_combine``), boxes below ``appearance_min_probability`` dropped.

Feature sets (stored in the model file): ``colour`` (46 numbers of the crop, the first model) and
``colour_geometry_context`` (those, 12 box-geometry numbers that need the calibration, 6 of the surroundings).
"""

from __future__ import annotations

import io
import math
import os
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_common.errors import DataError, ModelError
from vessel_detect.box_ops import suppress_nested

#: Colour features of a crop (``crop_features``); FEATURE_SIZE is kept for the first, colour-only models.
FEATURE_SIZE = COLOUR_SIZE = 46
GEOMETRY_SIZE = 12
CONTEXT_SIZE = 6
FEATURE_SETS = {"colour": COLOUR_SIZE, "colour_geometry_context": COLOUR_SIZE + GEOMETRY_SIZE + CONTEXT_SIZE}
DEFAULT_FEATURE_SET = "colour_geometry_context"
#: Depths used for boxes whose position gives none (on or above the horizon) or an absurd one, m.
FAR_DEPTH_M = 3000.0
NEAR_DEPTH_M = 5.0
#: Chosen on training videos 7-12 (leave-one-video-out models and calibrations, detector output at score 0.05,
#: the whole online and offline pipeline; `vessel_tools.track.appearance` doc): the probability replaces the detector
#: score (which is one of the features), detections below 0.5 dropped (they are not the vessel of interest and
#: only give the tracker boxes to swap identities with). Offline 10.2 m/100 m against 36.0 at 0.3, 28.1 at 0.7
#: and 48.3 for score x probability at 0.5; online 26.1, 33.3, 31.6 and 25.0.
COMBINE_MODES = ("replace", "product")
DEFAULT_COMBINE = "replace"
DEFAULT_MIN_PROBABILITY = 0.5
#: Of nested boxes (sharing more than this of the smaller one's area) only the likelier is kept: chosen on 7-12 the
#: same way, offline 10.2 -> 4.9 m/100 m, online 26.1 -> 23.5.
DEFAULT_NESTED_OVERLAP = 0.5


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


def context_features(bgr: np.ndarray, boxes_xyxy) -> np.ndarray:
    """(N, 6) of the box and of a strip 1.5 box widths to each side and half a height below (a wake, open water).

    Per region: share of bright unsaturated pixels (foam, white hulls), std of the value channel and mean
    saturation, both scaled to [0, 1].
    """
    import cv2

    image = np.asarray(bgr)
    boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    out = np.full((boxes.shape[0], CONTEXT_SIZE), np.nan)
    if boxes.shape[0] == 0:
        return out
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    height, width = image.shape[:2]
    for i, (x1, y1, x2, y2) in enumerate(boxes):
        if not np.all(np.isfinite((x1, y1, x2, y2))):
            continue
        w, h = max(x2 - x1, 1.0), max(y2 - y1, 1.0)
        for k, (grow_x, grow_down) in enumerate(((0.0, 0.0), (1.5, 0.5))):
            c1, c2 = int(max(0, x1 - grow_x * w)), int(min(width, x2 + grow_x * w))
            r1, r2 = int(max(0, y1)), int(min(height, y2 + grow_down * h))
            region = hsv[r1:max(r2, r1 + 1), c1:max(c2, c1 + 1)].reshape(-1, 3).astype(float)
            if region.size == 0:
                out[i, 3 * k:3 * k + 3] = 0.0
                continue
            bright = np.mean((region[:, 2] > 170) & (region[:, 1] < 50))
            out[i, 3 * k:3 * k + 3] = (bright, region[:, 2].std() / 255.0, region[:, 1].mean() / 255.0)
    return out


def geometry_features(camera, size_model, boxes_xyxy, scores) -> np.ndarray:
    """(N, 12) box geometry in the calibration's pixels: has the box the vessel's size where it sits.

    ``size_model`` = (a, b, c, d) of the box-size distance model (width = a/depth + b, height = c/depth + d).
    The depth comes from the box's reference point (``camera.box_reference_points``) through the calibration
    (on or above the horizon: ``FAR_DEPTH_M``).
    Numbers: log of width and height over the expected ones, log aspect, log of the pixels from the horizon down
    to the centre, log detector score, log depth, position valid, and the squares of the first four and the
    product of the first two (a logistic regression can then prefer sizes near the expected ones).
    """
    a, b, c, d = (float(v) for v in size_model)
    boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    scores = np.asarray(scores, dtype=float).reshape(-1)
    cx, cy = (boxes[:, 0] + boxes[:, 2]) / 2.0, (boxes[:, 1] + boxes[:, 3]) / 2.0
    w = np.maximum(boxes[:, 2] - boxes[:, 0], 1.0)
    h = np.maximum(boxes[:, 3] - boxes[:, 1], 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        depth = camera.box_depths_m(boxes)
        valid = np.isfinite(depth)
        depth = np.clip(np.nan_to_num(depth, nan=FAR_DEPTH_M), NEAR_DEPTH_M, FAR_DEPTH_M)
        width_ratio = np.log(w / np.maximum(a / depth + b, 2.0))
        height_ratio = np.log(h / np.maximum(c / depth + d, 2.0))
        aspect = np.log(h / w)
        horizon = np.asarray(camera.horizon_y(cx), dtype=float)
        below = np.log(np.clip(np.nan_to_num(cy - horizon, nan=1.0), 1.0, None))
        log_score = np.log(np.clip(np.nan_to_num(scores, nan=1e-3), 1e-3, 1.0))
    return np.column_stack([width_ratio, height_ratio, aspect, below, log_score, np.log(depth),
                            valid.astype(float), width_ratio ** 2, height_ratio ** 2, aspect ** 2, below ** 2,
                            width_ratio * height_ratio])


def detection_features(feature_set: str, bgr: np.ndarray, boxes_xyxy, scores=None, camera=None, size_model=None,
                       calibration_scale=(1.0, 1.0)) -> np.ndarray:
    """The features of ``feature_set`` for each box of one image.

    ``calibration_scale`` maps image pixels to the calibration's (sx, sy) when the image is not the size the
    camera was calibrated at.
    """
    colour = crop_features(bgr, boxes_xyxy)
    if feature_set == "colour":
        return colour
    if feature_set != "colour_geometry_context":
        raise ModelError(f"appearance: unknown feature set {feature_set!r} (known: {', '.join(FEATURE_SETS)})")
    if camera is None or size_model is None:
        raise ModelError("appearance: this model uses box geometry and needs the calibration (the camera.* "
                         "parameters, e.g. --params-file config/aitas_camera.yaml) and a size model")
    boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    scale = np.array([calibration_scale[0], calibration_scale[1]] * 2, dtype=float)
    scores = np.ones(len(boxes)) if scores is None else scores
    return np.hstack([colour, geometry_features(camera, size_model, boxes * scale, scores),
                      context_features(bgr, boxes)])


@dataclass(frozen=True)
class AppearanceModel:
    """Logistic regression on standardised features: ``p = 1 / (1 + exp(-(w . (f - mean) / scale + bias)))``.

    ``feature_set`` names the features (``FEATURE_SETS``); ``size_model`` (a, b, c, d) is the box-size distance
    model the geometry features were computed with (None for the colour-only set).
    """

    mean: np.ndarray
    scale: np.ndarray
    weights: np.ndarray
    bias: float
    source: str = ""
    feature_set: str = "colour"
    size_model: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        """Check shapes and values."""
        if self.feature_set not in FEATURE_SETS:
            raise ModelError(f"appearance model: unknown feature set {self.feature_set!r} "
                             f"(known: {', '.join(FEATURE_SETS)})")
        size = FEATURE_SETS[self.feature_set]
        for name in ("mean", "scale", "weights"):
            value = np.asarray(getattr(self, name), dtype=float).reshape(-1)
            if value.size != size or not np.all(np.isfinite(value)):
                raise ModelError(f"appearance model: {name} must be {size} finite numbers for feature set "
                                 f"{self.feature_set}")
            object.__setattr__(self, name, value)
        if not np.all(self.scale > 0) or not math.isfinite(self.bias):
            raise ModelError("appearance model: scale must be > 0 and bias finite")
        if self.feature_set != "colour":
            values = () if self.size_model is None else tuple(float(v) for v in np.asarray(self.size_model).ravel())
            if len(values) != 4 or not all(math.isfinite(v) for v in values) or values[0] <= 0 or values[2] <= 0:
                raise ModelError("appearance model: size_model must be (a, b, c, d) with a, c > 0 for feature set "
                                 f"{self.feature_set}")
            object.__setattr__(self, "size_model", values)

    @property
    def needs_camera(self) -> bool:
        """True when the features include box geometry (the calibration is needed)."""
        return self.feature_set != "colour"

    def probability_of_features(self, features: np.ndarray) -> np.ndarray:
        """(N,) probability that each feature row is the vessel of interest (NaN features count as the mean)."""
        f = np.asarray(features, dtype=float).reshape(-1, self.mean.size)
        z = (np.nan_to_num((f - self.mean) / self.scale)) @ self.weights + self.bias
        return 1.0 / (1.0 + np.exp(-np.clip(z, -50, 50)))

    def features(self, bgr: np.ndarray, boxes_xyxy, scores=None, camera=None, calibration_scale=(1.0, 1.0)):
        """The model's features of each box of one image (see ``detection_features``)."""
        return detection_features(self.feature_set, bgr, boxes_xyxy, scores, camera, self.size_model,
                                  calibration_scale)

    def probability(self, bgr: np.ndarray, boxes_xyxy, scores=None, camera=None,
                    calibration_scale=(1.0, 1.0)) -> np.ndarray:
        """(N,) probability that each box of the image is the vessel of interest."""
        return self.probability_of_features(self.features(bgr, boxes_xyxy, scores, camera, calibration_scale))

    def save(self, path: Path) -> None:
        """Write an .npz atomically."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        buffer = io.BytesIO()
        extra = {} if self.size_model is None else {"size_model": np.asarray(self.size_model, dtype=float)}
        np.savez(buffer, mean=self.mean, scale=self.scale, weights=self.weights, bias=np.array(self.bias),
                 source=np.array(self.source), feature_set=np.array(self.feature_set), **extra)
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
            raise ModelError(f"{path}: no such appearance model; write one with `./vessel appearance "
                             f"fit ...`")
        try:
            with np.load(path, allow_pickle=False) as data:
                feature_set = str(data["feature_set"]) if "feature_set" in data else "colour"
                size_model = tuple(data["size_model"].tolist()) if "size_model" in data else None
                return cls(data["mean"], data["scale"], data["weights"], float(data["bias"]), str(data["source"]),
                           feature_set, size_model)
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as error:
            # an empty file raises EOFError, a cut one BadZipFile
            raise ModelError(f"{path}: not an appearance model ({error or type(error).__name__}); re-run "
                             "`./vessel appearance fit`") from None
        except ModelError as error:
            raise ModelError(f"{path}: {error}; re-run `./vessel appearance fit`") from None


def score_with_cue(model: AppearanceModel, bgr: np.ndarray, boxes_xyxy, scores,
                   min_probability: float = DEFAULT_MIN_PROBABILITY, camera=None, calibration_scale=(1.0, 1.0),
                   combine: str = DEFAULT_COMBINE, nested_overlap: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the boxes kept, their new scores): what the detector node and ``pipeline --appearance`` do.

    ``combine``: ``replace`` the score by the probability, or the ``product`` of both; boxes whose probability is
    below ``min_probability`` are dropped, and with ``nested_overlap`` > 0 boxes nested in a likelier one
    (``box_ops.suppress_nested``; the kept ones then come best first).
    """
    if combine not in COMBINE_MODES:
        raise ModelError(f"appearance: combine must be one of {', '.join(COMBINE_MODES)}, got {combine!r}")
    boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    scores = np.asarray(scores, dtype=float).reshape(-1)
    if len(boxes) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    probability = model.probability(bgr, boxes, scores, camera, calibration_scale)
    keep = np.flatnonzero(probability >= min_probability)
    new_scores = probability[keep] if combine == "replace" else scores[keep] * probability[keep]
    if nested_overlap > 0 and len(keep) > 1:
        order = suppress_nested(boxes[keep], new_scores, nested_overlap)
        keep, new_scores = keep[order], new_scores[order]
    return keep, new_scores


def rescore_detections(detections, bgr: np.ndarray, model: AppearanceModel,
                       min_probability: float = DEFAULT_MIN_PROBABILITY, camera=None,
                       calibration_scale=(1.0, 1.0), combine: str = DEFAULT_COMBINE, nested_overlap: float = 0.0):
    """``Detections`` scored by the appearance cue (``score_with_cue``)."""
    if len(detections) == 0:
        return detections
    keep, new_scores = score_with_cue(model, bgr, detections.boxes_xyxy, detections.scores, min_probability, camera,
                                      calibration_scale, combine, nested_overlap)
    kept = detections.take(keep)
    kept.scores = new_scores
    kept.p_target = np.asarray(new_scores, dtype=float).copy()
    return kept
