"""Decoders of the three YOLO output layouts on synthetic output tensors with known boxes."""

import numpy as np
import pytest

from vessel_common.errors import ModelError
from vessel_detect.decoders import (
    OutputLayout,
    decode,
    decode_yolov5,
    decode_yolov8,
    decode_yolox,
    detect_layout,
    grid_point_count,
)

INPUT_HW = (416, 416)
NUM_CLASSES = 80
BOAT = 8
POINTS = grid_point_count(INPUT_HW)  # 52^2 + 26^2 + 13^2


def yolox_row_index(cx: float, cy: float, stride: int, input_hw=INPUT_HW) -> tuple[int, float, float]:
    """Row of the anchor point of the cell holding (cx, cy) at ``stride``, and the cell-relative offsets."""
    offset = 0
    for s in (8, 16, 32):
        if s == stride:
            break
        offset += (input_hw[0] // s) * (input_hw[1] // s)
    gx, gy = int(cx // stride), int(cy // stride)
    return offset + gy * (input_hw[1] // stride) + gx, cx / stride - gx, cy / stride - gy


def yolox_output(boxes, num_classes=NUM_CLASSES):
    """Raw YOLOX output with each (cx, cy, w, h, stride, objectness, class, class score) placed on its cell."""
    out = np.zeros((1, POINTS, 5 + num_classes), np.float32)
    out[0, :, 2:4] = -3.0  # tiny boxes with zero score elsewhere
    for cx, cy, w, h, stride, obj, cls, score in boxes:
        row, x, y = yolox_row_index(cx, cy, stride)
        out[0, row, :4] = [x, y, np.log(w / stride), np.log(h / stride)]
        out[0, row, 4] = obj
        out[0, row, 5 + cls] = score
    return out


def test_grid_point_count_matches_yolox_nano():
    assert POINTS == 3549
    assert grid_point_count((640, 640)) == 8400


@pytest.mark.parametrize(
    ("shape", "layout"),
    [
        ((1, 3549, 85), OutputLayout.YOLOX),
        ((3549, 85), OutputLayout.YOLOX),
        ((1, 3 * 3549, 85), OutputLayout.YOLOV5),
        ((1, 84, 3549), OutputLayout.YOLOV8),
        ((1, 5, 3549), OutputLayout.YOLOV8),  # one-class YOLOv8
        ((1, 3549, 6), OutputLayout.YOLOX),  # one-class YOLOX
    ],
)
def test_detect_layout_from_shape(shape, layout):
    assert detect_layout(shape, INPUT_HW) is layout


def test_detect_layout_for_640_inputs():
    assert detect_layout((1, 25200, 85), (640, 640), 80) is OutputLayout.YOLOV5
    assert detect_layout((1, 84, 8400), (640, 640), 80) is OutputLayout.YOLOV8


def test_detect_layout_uses_the_class_count_when_the_anchor_count_is_unusual():
    assert detect_layout((1, 1000, 85), INPUT_HW, 80) is OutputLayout.YOLOV5
    assert detect_layout((1, 84, 1000), INPUT_HW, 80) is OutputLayout.YOLOV8


@pytest.mark.parametrize("shape", [(1, 2, 3549, 85), (1, 1000, 85), (1, 3549), (2, 3549, 85)])
def test_detect_layout_rejects_unknown_shapes_with_a_clear_message(shape):
    with pytest.raises(ModelError, match="layout|shape|batch"):
        detect_layout(shape, INPUT_HW)


def test_yolox_decodes_known_boxes_on_each_stride():
    truth = [
        (100.0, 60.0, 30.0, 12.0, 8, 0.9, BOAT, 0.8),
        (250.0, 200.0, 90.0, 40.0, 16, 0.8, BOAT, 0.5),
        (300.0, 330.0, 200.0, 150.0, 32, 0.7, 2, 0.9),  # a car
    ]
    result = decode_yolox(yolox_output(truth), INPUT_HW, score_threshold=0.1)
    assert len(result) == 3
    order = np.argsort(result.boxes_xyxy[:, 0])
    for (cx, cy, w, h, _s, obj, cls, score), i in zip(sorted(truth, key=lambda t: t[0] - t[2] / 2), order, strict=True):
        np.testing.assert_allclose(result.boxes_xyxy[i], [cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], atol=1e-3)
        assert result.scores[i] == pytest.approx(obj * score, rel=1e-6)
        assert result.class_ids[i] == cls


def test_yolox_class_filter_takes_the_best_allowed_class_even_if_another_class_scores_higher():
    out = yolox_output([(100.0, 60.0, 30.0, 12.0, 8, 1.0, 2, 0.9)])
    row, _, _ = yolox_row_index(100.0, 60.0, 8)
    out[0, row, 5 + BOAT] = 0.4
    boats = decode_yolox(out, INPUT_HW, class_indices=np.array([BOAT]), score_threshold=0.1)
    assert len(boats) == 1 and boats.class_ids[0] == BOAT and boats.scores[0] == pytest.approx(0.4)
    assert len(decode_yolox(out, INPUT_HW, class_indices=np.array([BOAT]), score_threshold=0.5)) == 0


def test_yolox_score_threshold_and_non_finite_rows():
    out = yolox_output([(100.0, 60.0, 30.0, 12.0, 8, 0.5, BOAT, 0.5), (200.0, 60.0, 30.0, 12.0, 8, 0.9, BOAT, 0.9)])
    out[0, 0, :] = np.nan
    result = decode_yolox(out, INPUT_HW, score_threshold=0.3)
    assert len(result) == 1 and result.scores[0] == pytest.approx(0.81)


def test_yolox_rejects_a_row_count_that_does_not_fit_the_input():
    with pytest.raises(ModelError, match="grid points"):
        decode_yolox(np.zeros((1, 100, 85), np.float32), INPUT_HW)


def test_class_index_beyond_the_model_classes_is_an_error():
    with pytest.raises(ModelError, match="classes"):
        decode_yolox(yolox_output([]), INPUT_HW, class_indices=np.array([80]))


def test_yolov5_decodes_known_boxes():
    out = np.zeros((1, 3 * POINTS, 85), np.float32)
    out[0, 10, :5] = [120.0, 80.0, 40.0, 20.0, 0.9]
    out[0, 10, 5 + BOAT] = 0.7
    out[0, 500, :5] = [300.0, 300.0, 100.0, 50.0, 0.05]  # below threshold
    out[0, 500, 5 + BOAT] = 0.9
    result = decode_yolov5(out, class_indices=np.array([BOAT]), score_threshold=0.1)
    assert len(result) == 1
    np.testing.assert_allclose(result.boxes_xyxy[0], [100, 70, 140, 90], atol=1e-4)
    assert result.scores[0] == pytest.approx(0.63, rel=1e-6)
    assert result.class_ids[0] == BOAT


def test_yolov8_decodes_the_transposed_layout_without_objectness():
    out = np.zeros((1, 84, POINTS), np.float32)
    out[0, :4, 7] = [200.0, 150.0, 60.0, 30.0]
    out[0, 4 + BOAT, 7] = 0.6
    out[0, :4, 9] = [50.0, 50.0, 10.0, 10.0]
    out[0, 4 + 0, 9] = 0.95  # a person
    result = decode_yolov8(out, class_indices=np.array([BOAT]), score_threshold=0.25)
    assert len(result) == 1
    np.testing.assert_allclose(result.boxes_xyxy[0], [170, 135, 230, 165], atol=1e-4)
    assert result.scores[0] == pytest.approx(0.6)
    everything = decode_yolov8(out, score_threshold=0.25)
    assert sorted(everything.class_ids.tolist()) == [0, BOAT]


@pytest.mark.parametrize("layout", list(OutputLayout))
def test_decode_dispatches_and_returns_empty_for_no_candidates(layout):
    shape = {"yolox": (1, POINTS, 85), "yolov5": (1, 3 * POINTS, 85), "yolov8": (1, 84, POINTS)}[layout.value]
    result = decode(np.zeros(shape, np.float32), layout, INPUT_HW, np.array([BOAT]), 0.1)
    assert len(result) == 0 and result.boxes_xyxy.shape == (0, 4)


def test_the_target_class_score_comes_with_every_candidate_whatever_its_best_class():
    out = yolox_output([(100.0, 60.0, 30.0, 12.0, 8, 0.8, 1, 0.9), (250.0, 200.0, 90.0, 40.0, 16, 0.5, 0, 0.6)],
                       num_classes=2)
    row, _, _ = yolox_row_index(100.0, 60.0, 8)
    out[0, row, 5 + 0] = 0.25  # another vessel, a little like the target
    result = decode_yolox(out, INPUT_HW, score_threshold=0.1, target_class=0)
    by_x = np.argsort(result.boxes_xyxy[:, 0])
    assert result.class_ids[by_x].tolist() == [1, 0]
    np.testing.assert_allclose(result.target_scores[by_x], [0.8 * 0.25, 0.5 * 0.6], rtol=1e-6)
    assert np.all(np.isnan(decode_yolox(out, INPUT_HW, score_threshold=0.1).target_scores))
    v8 = np.zeros((1, 6, POINTS), np.float32)
    v8[0, :4, 0] = [50, 50, 10, 10]
    v8[0, 4:, 0] = [0.3, 0.7]
    assert decode_yolov8(v8, score_threshold=0.1, target_class=0).target_scores.tolist() == pytest.approx([0.3])
