"""How a crop of a frame becomes the network's input tensor, and how the network's boxes come back to the frame.

The crop is resized keeping its aspect ratio and placed at the top-left of the input canvas, the rest padded
grey (as YOLOX was trained): ``Letterbox`` records that placement so boxes can go either way.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

LETTERBOX_PAD_VALUE = 114


def letterbox(
    bgr: np.ndarray, input_hw: tuple[int, int], scale: float | None = None, pad_value: int = LETTERBOX_PAD_VALUE
) -> tuple[np.ndarray, float]:
    """Resize keeping the aspect ratio, place at the top-left of an ``input_hw`` canvas of ``pad_value``.

    Returns the ``(1, 3, H, W)`` float32 tensor (BGR, 0-255, no normalisation, as YOLOX expects) and the
    scale used. ``scale`` (network px per source px) defaults to the largest that fits; the resized image is
    cropped to the canvas if a given scale makes it larger.
    """
    in_h, in_w = input_hw
    src_h, src_w = bgr.shape[:2]
    if scale is None:
        scale = min(in_h / src_h, in_w / src_w)
    new_w = max(1, min(in_w, int(round(src_w * scale))))
    new_h = max(1, min(in_h, int(round(src_h * scale))))
    if (new_w, new_h) == (src_w, src_h):
        resized = bgr
    else:
        full_w, full_h = max(1, int(round(src_w * scale))), max(1, int(round(src_h * scale)))
        resized = cv2.resize(bgr, (full_w, full_h), interpolation=cv2.INTER_LINEAR)[:new_h, :new_w]
    canvas = np.full((in_h, in_w, 3), pad_value, dtype=np.uint8)
    canvas[:new_h, :new_w] = resized
    tensor = np.ascontiguousarray(canvas.transpose(2, 0, 1)[None], dtype=np.float32)
    return tensor, float(scale)


@dataclass(frozen=True)
class Letterbox:
    """How a source crop was placed into the network input: resized by ``scale``, top-left, padded."""

    scale: float
    offset_x: float = 0.0
    offset_y: float = 0.0

    def to_source(self, boxes_xyxy: np.ndarray) -> np.ndarray:
        """Network-input pixels -> source image pixels; the inverse of ``to_network``."""
        boxes = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4) / self.scale
        return boxes + np.array([self.offset_x, self.offset_y, self.offset_x, self.offset_y])

    def to_network(self, boxes_xyxy: np.ndarray) -> np.ndarray:
        """Source image pixels -> network-input pixels; the inverse of ``to_source``."""
        boxes = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4)
        return (boxes - np.array([self.offset_x, self.offset_y, self.offset_x, self.offset_y])) * self.scale
