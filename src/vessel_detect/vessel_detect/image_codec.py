"""Image message payloads <-> BGR arrays, without ROS.

``sensor_msgs/Image`` fields (encoding, height, width, step, data) and ``sensor_msgs/CompressedImage`` bytes
become a ``(H, W, 3)`` uint8 BGR array, the detector's input. Anything that cannot be one raises
:class:`ImageError` (a ``DataError``) whose ``kind`` names the problem for counting.
"""

from __future__ import annotations

import cv2
import numpy as np

from vessel_common.errors import DataError

# encoding -> (channels, OpenCV conversion to BGR or None)
_ENCODINGS: dict[str, tuple[int, int | None]] = {
    "bgr8": (3, None),
    "rgb8": (3, cv2.COLOR_RGB2BGR),
    "mono8": (1, cv2.COLOR_GRAY2BGR),
    "8uc1": (1, cv2.COLOR_GRAY2BGR),
    "8uc3": (3, None),
    "bgra8": (4, cv2.COLOR_BGRA2BGR),
    "rgba8": (4, cv2.COLOR_RGBA2BGR),
    "8uc4": (4, cv2.COLOR_BGRA2BGR),
}
SUPPORTED_ENCODINGS = ("bgr8", "rgb8", "mono8", "bgra8", "rgba8")


class ImageError(DataError):
    """An image message that cannot be turned into a BGR frame; ``kind`` is a short counter name."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


def image_to_bgr(encoding: str, height: int, width: int, step: int, data) -> np.ndarray:
    """Turn the fields of a ``sensor_msgs/Image`` into a BGR uint8 array (a copy, safe to keep).

    Rows may be padded (``step`` larger than ``width * channels``); the padding is dropped.

    Raises:
        ImageError: unsupported encoding (kind ``bad_encoding``), zero size (``empty_image``), or a step or
            data length that does not match the size (``bad_image_size``).

    """
    key = str(encoding).strip().lower()
    if key not in _ENCODINGS:
        raise ImageError(
            "bad_encoding",
            f"image encoding '{encoding}' is not supported; publish one of {', '.join(SUPPORTED_ENCODINGS)} "
            "or CompressedImage (jpeg/png)",
        )
    channels, conversion = _ENCODINGS[key]
    height, width, step = int(height), int(width), int(step)
    if height <= 0 or width <= 0:
        raise ImageError("empty_image", f"image of size {width}x{height}: nothing to detect in")
    row_bytes = width * channels
    if step < row_bytes:
        raise ImageError(
            "bad_image_size",
            f"image step {step} is less than width {width} x {channels} bytes for '{encoding}'",
        )
    buffer = np.frombuffer(memoryview(data), dtype=np.uint8) if not isinstance(data, np.ndarray) else data
    buffer = buffer.reshape(-1).view(np.uint8)
    if buffer.size != step * height:
        raise ImageError(
            "bad_image_size",
            f"image data has {buffer.size} bytes; {width}x{height} '{encoding}' with step {step} needs "
            f"{step * height}",
        )
    rows = buffer.reshape(height, step)[:, :row_bytes]
    pixels = rows.reshape(height, width, channels) if channels > 1 else rows.reshape(height, width)
    if conversion is None:
        return np.ascontiguousarray(pixels).copy()
    return cv2.cvtColor(np.ascontiguousarray(pixels), conversion)


def compressed_to_bgr(data, format_hint: str = "") -> np.ndarray:
    """Decode ``sensor_msgs/CompressedImage`` bytes (JPEG, PNG, anything OpenCV reads) into BGR uint8.

    Raises:
        ImageError: no bytes (kind ``empty_image``) or bytes that do not decode (``undecodable_image``).

    """
    buffer = np.frombuffer(memoryview(data), dtype=np.uint8) if not isinstance(data, np.ndarray) else data
    buffer = buffer.reshape(-1).view(np.uint8)
    if buffer.size == 0:
        raise ImageError("empty_image", "compressed image with no data")
    image = cv2.imdecode(buffer, cv2.IMREAD_COLOR)
    if image is None or image.size == 0:
        hint = f" (format '{format_hint}')" if format_hint else ""
        raise ImageError(
            "undecodable_image",
            f"compressed image of {buffer.size} bytes{hint} does not decode as JPEG/PNG",
        )
    return image


def bgr_to_image_fields(bgr: np.ndarray) -> dict:
    """Fields of a ``bgr8`` ``sensor_msgs/Image`` for a BGR uint8 array (``data`` as bytes via ``tobytes``)."""
    array = np.asarray(bgr)
    if array.dtype != np.uint8 or array.ndim != 3 or array.shape[2] != 3:
        raise ImageError("bad_encoding", f"expected a (H, W, 3) uint8 BGR array, got {array.dtype} {array.shape}")
    height, width = array.shape[:2]
    return {
        "encoding": "bgr8",
        "height": int(height),
        "width": int(width),
        "step": int(width * 3),
        "is_bigendian": 0,
        "data": np.ascontiguousarray(array).tobytes(),
    }


def bgr_to_jpeg(bgr: np.ndarray, quality: int = 90) -> bytes:
    """JPEG bytes of a BGR image (for CompressedImage)."""
    ok, encoded = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ImageError("undecodable_image", "OpenCV could not encode the image as JPEG")
    return encoded.tobytes()
