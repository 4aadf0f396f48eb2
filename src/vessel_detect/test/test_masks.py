"""Static exclusion masks: parsing, the share of a box inside, scaling, and the challenge camera's post."""

import numpy as np
import pytest

from vessel_detect.masks import (
    CHALLENGE_MOORING_POST,
    ExclusionMask,
    MaskError,
    format_polygon,
    parse_polygon,
)


def test_parse_and_format_round_trip():
    points = parse_polygon("10,20 30,20 30,40;10,40")
    np.testing.assert_allclose(points, [[10, 20], [30, 20], [30, 40], [10, 40]])
    np.testing.assert_allclose(parse_polygon(format_polygon(points)), points)


@pytest.mark.parametrize("text", ["", "1,2 3,4", "1,2 3 5,6", "1,2 a,4 5,6", "1,2 3,nan 5,6"])
def test_bad_polygons_are_rejected_with_the_text(text):
    with pytest.raises(MaskError, match="polygon"):
        parse_polygon(text)


def test_inside_fraction_of_boxes():
    mask = ExclusionMask(["100,100 200,100 200,200 100,200"], (400, 300))
    boxes = np.array([[100, 100, 200, 200], [150, 100, 250, 200], [300, 0, 350, 50], [0, 0, 0, 0]])
    np.testing.assert_allclose(mask.inside_fraction(boxes, (400, 300)), [1.0, 0.51, 0.0, 0.0], atol=0.02)
    assert mask.keep(boxes, (400, 300), 0.5).tolist() == [False, False, True, True]
    assert mask.keep(boxes, (400, 300), 0.6).tolist() == [False, True, True, True]


def test_masks_scale_to_the_frame_size():
    mask = ExclusionMask(["100,100 200,100 200,200 100,200"], (400, 300))
    half = np.array([[50, 50, 100, 100]])
    assert mask.inside_fraction(half, (200, 150))[0] == pytest.approx(1.0, abs=0.05)
    assert mask.raster((200, 150)).shape == (150, 200)


def test_boxes_outside_the_image_are_clipped():
    mask = ExclusionMask(["0,0 50,0 50,50 0,50"], (100, 100))
    assert mask.inside_fraction(np.array([[-50, -50, 50, 50]]), (100, 100))[0] == pytest.approx(1.0, abs=0.05)


def test_no_polygons_keeps_everything():
    mask = ExclusionMask([], (1280, 720))
    assert not mask
    assert mask.keep(np.array([[0, 0, 10, 10]]), (1280, 720)).tolist() == [True]


def test_the_challenge_post_polygon_drops_the_post_detections_but_not_a_near_boat():
    mask = ExclusionMask([CHALLENGE_MOORING_POST], (1280, 720))
    # Boxes the COCO detector reports on the post (from the challenge frames) ...
    post_boxes = np.array([[695, 648, 926, 718], [689, 641, 928, 719], [697, 650, 930, 718], [693, 645, 927, 717]])
    assert not mask.keep(post_boxes, (1280, 720), 0.5).any()
    # ... and the boat passing close to the camera in video 17, just above the post, is kept.
    near_boat = np.array([[557, 525, 831, 659], [714, 569, 828, 662]])
    assert mask.keep(near_boat, (1280, 720), 0.5).all()
