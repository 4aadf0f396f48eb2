"""Training crops of the water band: scale, horizontal position, flip and colour, with a fixed seed.

A crop is a window of the band below the horizon (where vessels are), resized to the network's training
input. Its top follows the horizon with a random shift, its scale is drawn log-uniformly, and with probability
``focus_target`` it is placed to contain the vessel of interest, so that the rare positive is seen often. With
probability ``zoom_target`` the crop is instead a close-up of the vessel of interest at a scale drawn from
``zoom_range``, centred on it wherever it is in the band: the training passes keep the vessel far enough to be at
most about 100 px wide, while the band reaches the image bottom, where a vessel passing close to the camera is
several times larger. With probability ``zoom_other`` a close-up is centred on another boat of the frame instead,
so that a large, upscaled boat is not by itself a sign of the vessel of interest. Boxes that the crop cuts to less
than ``min_visible`` of their area become ignore regions, not negatives.

With probability ``paste_target`` a frame first gets a copy of the vessel of interest of another training frame
(its GPS-generated box with a ``paste_margin`` border, edges feathered, flipped at random): on the same image rows,
so at the same range and size, at most ``paste_shift_px`` left or right of where it was and clear of every labelled
box and ignore region. The copy is labelled as the vessel of interest; no hand label is used. A small shift keeps
where the vessel is as informative as in the frames themselves; a shift the width of the frame puts it anywhere on
its rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from vessel_detect.box_ops import intersection_areas
from vessel_detect.detector import LETTERBOX_PAD_VALUE, horizon_band_top, letterbox


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
    zoom_other: float = 0.0
    paste_target: float = 0.0
    paste_margin: float = 0.2
    paste_shift_px: float = 1280.0


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


PASTE_TRIES = 10
"""Random places tried for a pasted vessel before the frame is left as it is."""


def _feather(length: int, margin: float) -> np.ndarray:
    """(length,) blend weights rising from the edges to 1 over ``margin`` pixels (at least one)."""
    inside = np.minimum(np.arange(length) + 0.5, length - np.arange(length) - 0.5)
    return np.clip(inside / max(margin, 1.0), 0, 1)


def paste_target(bgr: np.ndarray, labels, donor_bgr: np.ndarray, donor_labels, rng: np.random.Generator,
                 settings: AugmentSettings):
    """``(image, labels)``: ``bgr`` with the donor frame's vessel of interest pasted in, or the inputs unchanged.

    The donor's first class-0 box, grown by ``paste_margin`` on each side, is blended in with feathered edges on the
    same rows, shifted by at most ``paste_shift_px``, and randomly flipped; the pasted box (without the margin) is
    added to the labels as class 0. Nothing is pasted when the donor has no vessel of interest or no place clear of
    the frame's boxes and ignore regions was found in ``PASTE_TRIES`` draws.
    """
    targets = donor_labels.boxes[donor_labels.classes == 0]
    if not len(targets):
        return bgr, labels
    height, width = bgr.shape[:2]
    x1, y1, x2, y2 = targets[0]
    margin_x, margin_y = settings.paste_margin * (x2 - x1), settings.paste_margin * (y2 - y1)
    px1, py1 = int(math.floor(max(x1 - margin_x, 0))), int(math.floor(max(y1 - margin_y, 0)))
    px2 = int(math.ceil(min(x2 + margin_x, donor_bgr.shape[1])))
    py2 = int(math.ceil(min(y2 + margin_y, donor_bgr.shape[0], height)))
    patch_w, patch_h = px2 - px1, py2 - py1
    if patch_w < 2 or patch_h < 2 or patch_w >= width:
        return bgr, labels
    occupied = np.concatenate([labels.boxes.reshape(-1, 4), labels.ignore.reshape(-1, 4)], 0)
    for _ in range(PASTE_TRIES):
        left = px1 + rng.uniform(-settings.paste_shift_px, settings.paste_shift_px)
        left = int(round(min(max(left, 0.0), width - patch_w)))
        spot = np.array([left, py1, left + patch_w, py2], float)
        if not np.any(intersection_areas(spot, occupied) > 0):
            break
    else:
        return bgr, labels
    patch = donor_bgr[py1:py2, px1:px2].astype(np.float32)
    box = np.array([x1 - px1, y1 - py1, x2 - px1, y2 - py1], float)
    if rng.random() < 0.5:
        patch = patch[:, ::-1]
        box = np.array([patch_w - box[2], box[1], patch_w - box[0], box[3]])
    alpha = (_feather(patch_h, margin_y)[:, None] * _feather(patch_w, margin_x)[None, :])[..., None]
    image = bgr.copy()
    region = image[py1:py2, left:left + patch_w].astype(np.float32)
    image[py1:py2, left:left + patch_w] = np.clip(alpha * patch + (1 - alpha) * region + 0.5, 0, 255).astype(
        image.dtype)
    pasted = box + np.array([left, py1, left, py1], float)
    return image, replace(labels, boxes=np.concatenate([labels.boxes.reshape(-1, 4), pasted[None]], 0),
                          classes=np.concatenate([labels.classes, np.array([0], dtype=labels.classes.dtype)]))


def random_sample(bgr: np.ndarray, labels, band_top: float, rng: np.random.Generator,
                  settings: AugmentSettings, donors=None) -> Sample:
    """One augmented crop of a frame and its ``FrameLabels``.

    ``donors``: ``(image, FrameLabels)`` of the training frames whose vessel of interest may be pasted in
    (``paste_target``); None or empty, none.
    """
    if donors and settings.paste_target > 0 and rng.random() < settings.paste_target:
        donor_bgr, donor_labels = donors[int(rng.integers(len(donors)))]
        if donor_labels is not labels:
            bgr, labels = paste_target(bgr, labels, donor_bgr, donor_labels, rng, settings)
    height, width = bgr.shape[:2]
    out_w, out_h = settings.crop_wh
    targets = labels.boxes[labels.classes == 0]
    if len(targets) and settings.zoom_target > 0 and rng.random() < settings.zoom_target:
        lo, hi = settings.zoom_range
        scale = math.exp(rng.uniform(math.log(lo), math.log(hi)))
        src_w, src_h = out_w / scale, out_h / scale
        centre = targets[0]
        others = labels.boxes[labels.classes != 0]
        if len(others) and settings.zoom_other > 0 and rng.random() < settings.zoom_other:
            centre = others[rng.integers(len(others))]
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
