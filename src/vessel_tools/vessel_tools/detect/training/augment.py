"""Training crops of the water band: scale, horizontal position, flip and colour, with a fixed seed.

A crop is a window of the band below the horizon (where vessels are), resized to the network's training
input. Its top follows the horizon with a random shift, its scale is drawn log-uniformly, and with probability
``focus_target`` it is placed to contain the vessel of interest, so that the rare positive is seen often. With
probability ``zoom_target`` the crop is instead a close-up of the vessel of interest at a scale drawn from
``zoom_range``, centred on it wherever it is in the band: the training passes keep the vessel far enough to be at
most about 100 px wide, while the band reaches the image bottom, where a vessel passing close to the camera is
several times larger. Boxes that the crop cuts to less than ``min_visible`` of their area become ignore regions,
not negatives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from vessel_detect.detector import horizon_band_top
from vessel_detect.network_input import LETTERBOX_PAD_VALUE, letterbox


@dataclass(frozen=True)
class AugmentSettings:
    """Ranges of the random transforms."""

    crop_wh: tuple[int, int] = (640, 352)
    scale_range: tuple[float, float] = (0.7, 1.6)
    top_jitter_px: float = 24.0
    flip: float = 0.5
    hue_deg: float = 6.0
    saturation: float = 0.35
    value: float = 0.35
    focus_target: float = 0.7
    min_visible: float = 0.45
    zoom_target: float = 0.2
    zoom_range: tuple[float, float] = (1.6, 4.0)


def band_top_px(camera, margin_px: float) -> float:
    """Top row of the band the detector's ``band`` mode shows the network (0 without a calibration)."""
    horizon = horizon_band_top(camera) if camera is not None else None
    return max(0.0, horizon - margin_px) if horizon is not None else 0.0


def band_input(image: np.ndarray, camera, input_hw: tuple[int, int], margin_px: float) -> np.ndarray:
    """The ``(1, 3, H, W)`` network input of ``image`` in the detector's ``band`` mode."""
    tensor, _ = letterbox(image[int(math.floor(band_top_px(camera, margin_px))):], input_hw)
    return tensor


@dataclass
class Sample:
    """One network input and its targets in network pixels."""

    image: np.ndarray  # (3, H, W) float32 BGR 0-255
    boxes: np.ndarray  # (N, 4) xyxy
    classes: np.ndarray  # (N,)
    ignore: np.ndarray  # (M, 4) xyxy


def warp_boxes(boxes: np.ndarray, x0: float, y0: float, scale: float) -> np.ndarray:
    """Source pixels -> crop pixels for a crop at ``(x0, y0)`` resized by ``scale``."""
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    return (boxes - np.array([x0, y0, x0, y0])) * scale


def _clip(boxes: np.ndarray, wh: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    area = np.maximum(boxes[:, 2] - boxes[:, 0], 0) * np.maximum(boxes[:, 3] - boxes[:, 1], 0)
    clipped = np.clip(boxes, 0, [wh[0], wh[1], wh[0], wh[1]])
    kept = np.maximum(clipped[:, 2] - clipped[:, 0], 0) * np.maximum(clipped[:, 3] - clipped[:, 1], 0)
    return clipped, np.where(area > 0, kept / np.maximum(area, 1e-9), 0.0)


def crop_window(source, x0: float, y0: float, scale: float, out_wh: tuple[int, int]) -> np.ndarray:
    """The ``out_wh`` crop of ``source`` whose top-left is ``(x0, y0)`` at ``scale``; outside pixels are padding."""
    matrix = np.array([[scale, 0.0, -x0 * scale], [0.0, scale, -y0 * scale]], dtype=np.float64)
    return cv2.warpAffine(source, matrix, out_wh, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=(LETTERBOX_PAD_VALUE,) * 3)


def jitter_colour(bgr: np.ndarray, rng: np.random.Generator, settings: AugmentSettings) -> np.ndarray:
    """Random hue shift and saturation/value gains (HSV)."""
    hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV).astype(np.float32)
    hsv[..., 0] = (hsv[..., 0] + rng.uniform(-settings.hue_deg, settings.hue_deg) / 2.0) % 180.0
    hsv[..., 1] *= rng.uniform(1 - settings.saturation, 1 + settings.saturation)
    hsv[..., 2] *= rng.uniform(1 - settings.value, 1 + settings.value)
    return cv2.cvtColor(np.clip(hsv, 0, 255).astype(np.uint8), cv2.COLOR_HSV2BGR)


def random_sample(bgr: np.ndarray, labels, band_top: float, rng: np.random.Generator,
                  settings: AugmentSettings) -> Sample:
    """One augmented crop of a frame and its ``FrameLabels``."""
    height, width = bgr.shape[:2]
    out_w, out_h = settings.crop_wh
    targets = labels.boxes[labels.classes == 0]
    if len(targets) and settings.zoom_target > 0 and rng.random() < settings.zoom_target:
        lo, hi = settings.zoom_range
        scale = math.exp(rng.uniform(math.log(lo), math.log(hi)))
        src_w, src_h = out_w / scale, out_h / scale
        centre = targets[0]
        cx, cy = 0.5 * (centre[0] + centre[2]), 0.5 * (centre[1] + centre[3])
        x0 = cx - rng.uniform(0.25, 0.75) * src_w
        y0 = cy - rng.uniform(0.3, 0.7) * src_h
        return _finish(bgr, labels, x0, y0, scale, rng, settings)
    lo, hi = settings.scale_range
    scale = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    src_w, src_h = out_w / scale, out_h / scale
    y0 = band_top + rng.uniform(-settings.top_jitter_px, settings.top_jitter_px)
    y0 = min(max(y0, 0.0), max(height - src_h * 0.6, 0.0))
    if len(targets) and rng.random() < settings.focus_target:
        cx = 0.5 * (targets[0, 0] + targets[0, 2])
        x0 = cx - rng.uniform(0.1, 0.9) * src_w
    else:
        x0 = rng.uniform(-0.05 * src_w, max(width - 0.95 * src_w, 0.0))
    return _finish(bgr, labels, x0, y0, scale, rng, settings)


def _finish(bgr: np.ndarray, labels, x0: float, y0: float, scale: float, rng: np.random.Generator,
            settings: AugmentSettings) -> Sample:
    """The crop at ``(x0, y0)`` and ``scale``, its boxes, flip and colour jitter."""
    out_w, out_h = settings.crop_wh
    image = crop_window(bgr, x0, y0, scale, (out_w, out_h))
    boxes, visible = _clip(warp_boxes(labels.boxes, x0, y0, scale), (out_w, out_h))
    ignore, _ = _clip(warp_boxes(labels.ignore, x0, y0, scale), (out_w, out_h))
    big_enough = ((boxes[:, 2] - boxes[:, 0]) >= 2.0) & ((boxes[:, 3] - boxes[:, 1]) >= 2.0)
    keep = big_enough & (visible >= settings.min_visible)
    cut = big_enough & ~keep & (visible > 0)
    ignore = np.concatenate([ignore, boxes[cut]], 0)
    boxes, classes = boxes[keep], labels.classes[keep]
    if rng.random() < settings.flip:
        image = image[:, ::-1]
        boxes = np.stack([out_w - boxes[:, 2], boxes[:, 1], out_w - boxes[:, 0], boxes[:, 3]], 1).reshape(-1, 4)
        ignore = np.stack([out_w - ignore[:, 2], ignore[:, 1], out_w - ignore[:, 0], ignore[:, 3]], 1).reshape(-1, 4)
    image = jitter_colour(np.ascontiguousarray(image), rng, settings)
    ignore = ignore[((ignore[:, 2] - ignore[:, 0]) > 0) & ((ignore[:, 3] - ignore[:, 1]) > 0)]
    return Sample(np.ascontiguousarray(image.transpose(2, 0, 1), dtype=np.float32), boxes, classes, ignore)
