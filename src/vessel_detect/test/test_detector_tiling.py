"""Box geometry, NMS, the layout of tiles over the band and the merge of detections across tiles."""

import numpy as np
import pytest

from vessel_detect.box_ops import box_iou, intersection_over_first, nms, suppress_nested
from vessel_detect.tiling import (
    BOTTOM,
    LEFT,
    RIGHT,
    Window,
    WindowDetections,
    axis_positions,
    cut_flags,
    merge_windows,
    tile_windows,
)


def test_box_iou_known_values():
    a = np.array([[0, 0, 10, 10]])
    b = np.array([[0, 0, 10, 10], [5, 0, 15, 10], [20, 20, 30, 30], [0, 0, 0, 0]])
    np.testing.assert_allclose(box_iou(a, b)[0], [1.0, 50 / 150, 0.0, 0.0])
    np.testing.assert_allclose(intersection_over_first(np.array([[5, 0, 10, 10]]), a)[0], [1.0])


def test_nms_keeps_the_best_of_overlapping_boxes_per_class():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [50, 50, 60, 60], [0, 0, 10, 10]], float)
    scores = np.array([0.6, 0.9, 0.5, 0.4])
    classes = np.array([8, 8, 8, 2])
    keep = nms(boxes, scores, 0.45, classes)
    assert keep.tolist() == [1, 2, 3]  # box 0 suppressed by 1; box 3 is another class
    assert nms(boxes, scores, 0.45).tolist() == [1, 2]  # class-agnostic
    assert nms(np.zeros((0, 4)), np.zeros(0), 0.5).size == 0


def test_nested_boxes_keep_only_the_likelier_one():
    """A hull box and its cabin box (IoU 0.2, so plain NMS keeps both) become one; a neighbour stays."""
    hull = [100, 100, 150, 120]
    cabin = [110, 100, 120, 110]       # inside the hull: IoU 0.1, all of the smaller box
    wake = [140, 105, 200, 125]        # overlaps the hull by 10x15 = 150 of its 1200: kept
    far = [400, 100, 420, 110]
    boxes = np.array([hull, cabin, wake, far], float)
    assert nms(boxes, np.array([0.6, 0.9, 0.5, 0.4]), 0.5).tolist() == [1, 0, 2, 3]
    assert suppress_nested(boxes, np.array([0.6, 0.9, 0.5, 0.4]), 0.5).tolist() == [1, 2, 3]
    assert suppress_nested(boxes, np.array([0.9, 0.6, 0.5, 0.4]), 0.5).tolist() == [0, 2, 3]
    assert suppress_nested(np.zeros((0, 4)), np.zeros(0), 0.5).size == 0


def test_nms_threshold_is_strict_above():
    boxes = np.array([[0, 0, 10, 10], [5, 0, 15, 10]], float)  # IoU 1/3
    assert nms(boxes, np.array([0.9, 0.8]), 0.34).tolist() == [0, 1]
    assert nms(boxes, np.array([0.9, 0.8]), 0.33).tolist() == [0]


def test_axis_positions_cover_the_span_with_the_overlap():
    for span_end, window, overlap in [(1280, 333, 96), (1280, 416, 96), (1000, 300, 0), (720, 416, 50)]:
        starts = axis_positions(0, span_end, window, overlap, span_end)
        assert starts[0] == 0 and starts[-1] + window == span_end
        steps = np.diff(starts)
        assert np.all(window - steps >= overlap)
    assert axis_positions(100, 200, 416, 96, 720) == [0]  # short span: one window, centred then shifted in
    assert axis_positions(500, 700, 416, 96, 720) == [304]
    assert axis_positions(0, 100, 2000, 0, 720) == [0]  # window larger than the image


def test_tile_windows_cover_the_band_and_mark_interior_edges():
    windows = tile_windows((0, 378, 1280, 720), (1280, 720), (416, 416), 1.25, 96)
    assert all(w.x1 - w.x0 == 333 and w.y1 - w.y0 == 333 for w in windows)
    covered = np.zeros((720, 1280), bool)
    for w in windows:
        covered[w.y0 : w.y1, w.x0 : w.x1] = True
    assert covered[378:720].all()
    leftmost = min(windows, key=lambda w: (w.x0, w.y0))
    assert leftmost.interior[LEFT] is False and leftmost.interior[RIGHT] is True


def test_cut_flags_only_on_interior_edges():
    window = Window(100, 300, 433, 633, 1.25, (True, True, True, False))
    boxes = np.array([[100.5, 400, 150, 420], [200, 400, 250, 420], [300, 600, 432, 633]])
    flags = cut_flags(boxes, window, 2.0)
    assert flags[0].tolist() == [True, False, False, False]
    assert not flags[1].any()
    assert flags[2].tolist() == [False, False, True, False]  # bottom is the image border: not a cut


def _dets(rows):
    """Detections from rows of (box, score, window index, cut flags)."""
    return WindowDetections(
        np.array([r[0] for r in rows], float),
        np.array([r[1] for r in rows], float),
        np.full(len(rows), 8, np.int64),
        np.array([r[2] for r in rows], np.int64),
        np.array([r[3] for r in rows], bool),
    )


TWO_TILES = [Window(0, 300, 416, 716, 1.0, (False, True, True, True)),
             Window(300, 300, 716, 716, 1.0, (True, True, True, True))]


def test_a_box_split_over_two_tiles_comes_out_once_as_the_union():
    # A 200 px boat from x=250 to 450: tile 0 sees 250-416 (cut right), tile 1 sees 300-450 (cut left).
    dets = _dets([
        ([250, 400, 416, 440], 0.6, 0, [0, 0, 1, 0]),
        ([300, 401, 450, 441], 0.7, 1, [1, 0, 0, 0]),
    ])
    merged = merge_windows(dets, TWO_TILES, 0.45)
    assert len(merged) == 1
    np.testing.assert_allclose(merged.boxes_xyxy[0], [250, 400, 450, 441])
    assert merged.scores[0] == pytest.approx(0.7)
    assert not merged.cut[0].any()


def test_the_uncut_box_wins_over_the_cut_piece_of_the_same_boat():
    # Boat 320-400 is whole in tile 0 (0-416) and cut by tile 1's... a third tile starting at 350.
    tiles = [TWO_TILES[0], Window(350, 300, 766, 716, 1.0, (True, True, True, True))]
    dets = _dets([
        ([320, 400, 400, 430], 0.5, 0, [0, 0, 0, 0]),
        ([350, 401, 400, 430], 0.8, 1, [1, 0, 0, 0]),  # cut piece with a higher score
    ])
    merged = merge_windows(dets, tiles, 0.45)
    assert len(merged) == 1
    np.testing.assert_allclose(merged.boxes_xyxy[0], [320, 400, 400, 430])


def test_distinct_boats_near_a_tile_edge_are_both_kept():
    dets = _dets([
        ([380, 400, 416, 420], 0.6, 0, [0, 0, 1, 0]),  # a small boat cut at tile 0's right edge ...
        ([380, 400, 440, 420], 0.6, 1, [0, 0, 0, 0]),  # ... whole in tile 1
        ([300, 500, 340, 520], 0.5, 1, [1, 0, 0, 0]),  # another boat, cut at tile 1's left edge
        ([280, 500, 340, 520], 0.55, 0, [0, 0, 0, 0]),  # ... whole in tile 0
        ([100, 450, 140, 470], 0.9, 0, [0, 0, 0, 0]),
    ])
    merged = merge_windows(dets, TWO_TILES, 0.45)
    boxes = sorted(map(tuple, merged.boxes_xyxy.tolist()))
    assert boxes == [(100, 450, 140, 470), (280, 500, 340, 520), (380, 400, 440, 420)]


def test_pieces_that_do_not_match_in_the_shared_area_are_not_joined():
    dets = _dets([
        ([250, 400, 416, 440], 0.6, 0, [0, 0, 1, 0]),
        ([300, 480, 450, 520], 0.7, 1, [1, 0, 0, 0]),  # another object lower down
    ])
    assert len(merge_windows(dets, TWO_TILES, 0.45)) == 2


def test_a_boat_across_three_tiles_is_joined_transitively():
    tiles = [Window(0, 0, 400, 400, 1.0, (False, False, True, False)),
             Window(300, 0, 700, 400, 1.0, (True, False, True, False)),
             Window(600, 0, 1000, 400, 1.0, (True, False, False, False))]
    dets = _dets([
        ([200, 100, 400, 150], 0.5, 0, [0, 0, 1, 0]),
        ([300, 100, 700, 152], 0.6, 1, [1, 0, 1, 0]),
        ([600, 102, 800, 150], 0.4, 2, [1, 0, 0, 0]),
    ])
    merged = merge_windows(dets, tiles, 0.45)
    assert len(merged) == 1
    np.testing.assert_allclose(merged.boxes_xyxy[0], [200, 100, 800, 152])
    assert not merged.cut[0, [LEFT, RIGHT, BOTTOM]].any()
