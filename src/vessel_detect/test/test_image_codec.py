"""Image message payloads to BGR: every supported encoding, padded rows, and each kind of bad input."""

import cv2
import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_detect.image_codec import (
    ImageError,
    bgr_to_image_fields,
    bgr_to_jpeg,
    compressed_to_bgr,
    image_to_bgr,
)

RNG = np.random.default_rng(5)
BGR = RNG.integers(0, 256, (6, 7, 3), dtype=np.uint8)


def _payload(encoding: str) -> tuple[np.ndarray, np.ndarray]:
    """(message pixels, expected BGR)."""
    if encoding == "bgr8":
        return BGR, BGR
    if encoding == "rgb8":
        return BGR[:, :, ::-1], BGR
    if encoding == "mono8":
        gray = BGR[:, :, 0]
        return gray, np.repeat(gray[:, :, None], 3, axis=2)
    alpha = np.full(BGR.shape[:2] + (1,), 200, np.uint8)
    if encoding == "bgra8":
        return np.concatenate([BGR, alpha], axis=2), BGR
    return np.concatenate([BGR[:, :, ::-1], alpha], axis=2), BGR  # rgba8


@pytest.mark.parametrize("encoding", ["bgr8", "rgb8", "mono8", "bgra8", "rgba8"])
def test_every_supported_encoding(encoding):
    pixels, expected = _payload(encoding)
    pixels = np.ascontiguousarray(pixels)
    height, width = pixels.shape[:2]
    step = pixels.strides[0]
    out = image_to_bgr(encoding, height, width, step, pixels.tobytes())
    assert out.dtype == np.uint8 and out.shape == (height, width, 3)
    np.testing.assert_array_equal(out, expected)


def test_padded_rows_are_dropped():
    padded = np.zeros((6, 7 * 3 + 5), np.uint8)
    padded[:, : 7 * 3] = BGR.reshape(6, -1)
    out = image_to_bgr("bgr8", 6, 7, 7 * 3 + 5, padded.tobytes())
    np.testing.assert_array_equal(out, BGR)


def test_accepts_array_and_memoryview_payloads_like_rclpy_gives():
    import array

    data = array.array("B", BGR.tobytes())
    np.testing.assert_array_equal(image_to_bgr("bgr8", 6, 7, 21, data), BGR)
    np.testing.assert_array_equal(image_to_bgr("BGR8", 6, 7, 21, memoryview(BGR.tobytes())), BGR)


@pytest.mark.parametrize(
    ("args", "kind"),
    [
        (("16UC1", 6, 7, 14, bytes(84)), "bad_encoding"),
        (("yuv422", 6, 7, 14, bytes(84)), "bad_encoding"),
        (("bgr8", 0, 7, 21, b""), "empty_image"),
        (("bgr8", 6, 0, 0, b""), "empty_image"),
        (("bgr8", 6, 7, 21, bytes(100)), "bad_image_size"),
        (("bgr8", 6, 7, 20, bytes(120)), "bad_image_size"),
    ],
)
def test_bad_images_raise_a_counted_kind(args, kind):
    with pytest.raises(ImageError) as info:
        image_to_bgr(*args)
    assert info.value.kind == kind
    assert isinstance(info.value, DataError)
    assert str(info.value)


def test_compressed_jpeg_and_png_decode():
    image = cv2.resize(BGR, (64, 48), interpolation=cv2.INTER_NEAREST)
    ok, png = cv2.imencode(".png", image)
    assert ok
    np.testing.assert_array_equal(compressed_to_bgr(png.tobytes(), "png"), image)
    decoded = compressed_to_bgr(bgr_to_jpeg(image, 95), "jpeg")
    assert decoded.shape == image.shape
    assert np.abs(decoded.astype(int) - image).mean() < 30


@pytest.mark.parametrize(("data", "kind"), [(b"", "empty_image"), (b"\xff\xd8 not really a jpeg", "undecodable_image")])
def test_compressed_that_does_not_decode(data, kind):
    with pytest.raises(ImageError) as info:
        compressed_to_bgr(data, "jpeg")
    assert info.value.kind == kind


def test_bgr_to_image_fields_round_trip():
    fields = bgr_to_image_fields(BGR)
    assert fields["encoding"] == "bgr8" and fields["step"] == 21 and isinstance(fields["data"], bytes)
    back = image_to_bgr(fields["encoding"], fields["height"], fields["width"], fields["step"], fields["data"])
    np.testing.assert_array_equal(back, BGR)
    with pytest.raises(ImageError):
        bgr_to_image_fields(BGR[:, :, 0])
