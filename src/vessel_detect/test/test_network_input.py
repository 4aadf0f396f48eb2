"""The letterbox: a crop placed top-left in the network input, and boxes mapped between the two."""

import numpy as np
import pytest

from vessel_detect.network_input import Letterbox, letterbox


@pytest.mark.parametrize(("height", "width"), [(720, 1280), (333, 333), (342, 1280), (100, 50), (416, 416)])
def test_letterbox_places_the_image_top_left_and_maps_boxes_back(height, width):
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    tensor, scale = letterbox(image, (416, 416))
    assert tensor.shape == (1, 3, 416, 416) and tensor.dtype == np.float32
    assert scale == pytest.approx(min(416 / height, 416 / width))
    new_w, new_h = round(width * scale), round(height * scale)
    canvas = tensor[0].transpose(1, 2, 0)
    assert np.all(canvas[new_h:, :] == 114) and np.all(canvas[:, new_w:] == 114)
    if scale == 1.0:
        np.testing.assert_array_equal(canvas[:height, :width], image)  # BGR kept, 0-255, no normalisation
    boxes = np.array([[10.0, 20.0, 40.0, 60.0], [0.0, 0.0, width, height]])
    transform = Letterbox(scale, 7.0, 300.0)
    np.testing.assert_allclose(transform.to_network(transform.to_source(boxes)), boxes)
    np.testing.assert_allclose(transform.to_source(boxes * scale), boxes + [7, 300, 7, 300])


def test_letterbox_with_a_given_scale_crops_to_the_canvas():
    image = np.zeros((400, 400, 3), np.uint8)
    tensor, scale = letterbox(image, (416, 416), scale=1.25)
    assert scale == 1.25 and tensor.shape == (1, 3, 416, 416)
    assert np.all(tensor[0, :, :416, :416] == 0)
