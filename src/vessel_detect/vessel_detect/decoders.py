"""Decoders of YOLO-family ONNX outputs into candidate boxes in network-input pixels.

Three output layouts are understood, told apart by the output shape (see :func:`detect_layout`):

- ``yolox``: ``(A, 5 + C)`` with one row per anchor point of the stride-8/16/32 grids, raw ``x, y, log w,
  log h`` relative to the grid cell, objectness and class scores already passed through a sigmoid (Megvii's
  YOLOX exported with ``decode_in_inference=False``, e.g. the default YOLOX-Nano model).
- ``yolov5``: ``(3 A, 5 + C)`` (three anchors per grid point), already decoded ``cx, cy, w, h`` in input
  pixels, objectness, class scores (Ultralytics YOLOv5 export; also any exporter that decodes in the graph,
  such as YOLOX with ``decode_in_inference=True``: configure that one as ``yolov5`` explicitly).
- ``yolov8``: ``(4 + C, A)``, the transposed layout of Ultralytics YOLOv8/YOLO11: decoded ``cx, cy, w, h``
  then class scores, no objectness.

A leading batch dimension of 1 is accepted everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from vessel_common.errors import ModelError

DEFAULT_STRIDES: tuple[int, ...] = (8, 16, 32)

# exp(log w) beyond this many strides is garbage (a 2^20-stride box); clipping keeps it finite.
_MAX_LOG_SIZE = 20.0


class OutputLayout(StrEnum):
    """Layout of a YOLO-family output tensor."""

    YOLOX = "yolox"
    YOLOV5 = "yolov5"
    YOLOV8 = "yolov8"


@dataclass(frozen=True)
class Candidates:
    """Detections of one network input before NMS, in network-input pixels.

    Attributes:
        boxes_xyxy: ``(N, 4)`` float64 corners ``x1, y1, x2, y2``.
        scores: ``(N,)`` float64 confidence (objectness x class score where the layout has objectness).
        class_ids: ``(N,)`` int64 index into the model's class list.
        target_scores: ``(N,)`` float64 score of the target class (objectness x its class score) whatever the
            best class is; NaN when no target class was asked for.

    """

    boxes_xyxy: np.ndarray
    scores: np.ndarray
    class_ids: np.ndarray
    target_scores: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.target_scores is None:
            object.__setattr__(self, "target_scores", np.full(self.scores.shape, np.nan))

    @staticmethod
    def empty() -> Candidates:
        """Return a record with no candidates."""
        return Candidates(np.zeros((0, 4)), np.zeros(0), np.zeros(0, dtype=np.int64))

    def __len__(self) -> int:
        return int(self.scores.shape[0])


def grid_point_count(input_hw: tuple[int, int], strides: tuple[int, ...] = DEFAULT_STRIDES) -> int:
    """Number of anchor points of the stride grids for an input of ``(height, width)`` pixels."""
    height, width = input_hw
    return int(sum((height // s) * (width // s) for s in strides))


def _as_2d(output: np.ndarray) -> np.ndarray:
    """Drop a leading batch dimension of 1; reject anything that is not one 2-D output."""
    array = np.asarray(output)
    if array.ndim == 3:
        if array.shape[0] != 1:
            raise ModelError(
                f"model output has batch size {array.shape[0]}; the detector runs one image at a time "
                "(export the model with batch size 1)"
            )
        array = array[0]
    if array.ndim != 2:
        raise ModelError(
            f"model output has shape {tuple(np.shape(output))}; expected a YOLO-family output "
            "(1, anchors, 5 + classes) or (1, 4 + classes, anchors)"
        )
    return array


def detect_layout(
    output_shape: tuple[int, ...],
    input_hw: tuple[int, int],
    num_classes: int | None = None,
    strides: tuple[int, ...] = DEFAULT_STRIDES,
) -> OutputLayout:
    """Tell the output layout from the output shape and the network input size.

    The anchor count decides: as many rows as grid points is YOLOX (raw, grid-relative), three times as
    many is YOLOv5 (decoded, three anchors per point), as many columns as grid points is the transposed
    YOLOv8 layout. When the count matches nothing (unusual strides), the class count decides between a
    ``5 + C`` row layout (taken as decoded, YOLOv5) and the ``4 + C`` transposed one.

    Raises:
        ModelError: the shape fits none of the layouts; the message shows the shape and the options.

    """
    shape = tuple(int(d) if d is not None and not isinstance(d, str) else -1 for d in output_shape)
    if len(shape) == 3 and shape[0] in (1, -1):
        shape = shape[1:]
    if len(shape) != 2 or min(shape) <= 0:
        raise ModelError(
            f"cannot use model output shape {tuple(output_shape)}: expected (1, anchors, 5 + classes) for "
            "YOLOX/YOLOv5 or (1, 4 + classes, anchors) for YOLOv8; set the layout parameter if the model "
            "has a dynamic output shape"
        )
    rows, cols = shape
    points = grid_point_count(input_hw, strides)
    if num_classes is not None:
        row_layout_fits = cols == 5 + num_classes
        transposed_fits = rows == 4 + num_classes
    else:
        row_layout_fits = cols >= 6
        transposed_fits = rows >= 5
    if row_layout_fits and rows == points:
        return OutputLayout.YOLOX
    if row_layout_fits and rows == 3 * points:
        return OutputLayout.YOLOV5
    if transposed_fits and cols == points:
        return OutputLayout.YOLOV8
    if num_classes is not None and row_layout_fits and not transposed_fits:
        return OutputLayout.YOLOV5
    if num_classes is not None and transposed_fits and not row_layout_fits:
        return OutputLayout.YOLOV8
    hint = "" if num_classes is not None else " (give the class names file so the class count can decide)"
    raise ModelError(
        f"cannot tell the layout of model output shape {tuple(output_shape)} for input {input_hw[0]}x"
        f"{input_hw[1]} with strides {strides}: {points} grid points{hint}; set the layout parameter to "
        "yolox, yolov5 or yolov8"
    )


def _select(
    array: np.ndarray,
    first_class_column: int,
    objectness_column: int | None,
    class_indices: np.ndarray | None,
    score_threshold: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Best allowed class per row and its score; return (row indices kept, scores, class ids)."""
    num_classes = array.shape[1] - first_class_column
    if class_indices is None:
        ids_of_column = np.arange(num_classes)
    else:
        ids_of_column = np.asarray(class_indices, dtype=np.int64).reshape(-1)
        if ids_of_column.size == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0, dtype=np.int64)
    allowed = array[:, first_class_column + ids_of_column]
    if objectness_column is not None:
        allowed = allowed * array[:, objectness_column : objectness_column + 1]
    best_column = np.argmax(allowed, axis=1)
    best_score = allowed[np.arange(allowed.shape[0]), best_column]
    keep = np.flatnonzero(np.isfinite(best_score) & (best_score >= score_threshold))
    return keep, best_score[keep].astype(np.float64), ids_of_column[best_column[keep]].astype(np.int64)


def _target_scores(rows: np.ndarray, first_class_column: int, objectness_column: int | None,
                   target_class: int | None) -> np.ndarray:
    """Objectness x the target class's score of each row; NaN without a target class."""
    if target_class is None or target_class < 0:
        return np.full(rows.shape[0], np.nan)
    scores = rows[:, first_class_column + int(target_class)].astype(np.float64)
    if objectness_column is not None:
        scores = scores * rows[:, objectness_column]
    return scores


def _centre_size_to_xyxy(cx: np.ndarray, cy: np.ndarray, w: np.ndarray, h: np.ndarray) -> np.ndarray:
    boxes = np.stack([cx - w / 2.0, cy - h / 2.0, cx + w / 2.0, cy + h / 2.0], axis=1).astype(np.float64)
    return boxes.reshape(-1, 4)


def _finite_rows(boxes: np.ndarray) -> np.ndarray:
    return np.all(np.isfinite(boxes), axis=1)


def _check_classes(array: np.ndarray, columns_before_classes: int, class_indices: np.ndarray | None) -> int:
    num_classes = array.shape[1] - columns_before_classes
    if num_classes < 1:
        raise ModelError(f"model output rows have {array.shape[1]} values: too few for boxes and classes")
    if class_indices is not None and np.size(class_indices) and (
        int(np.max(class_indices)) >= num_classes or int(np.min(class_indices)) < 0
    ):
        raise ModelError(
            f"class index {int(np.max(class_indices))} asked for, but the model has {num_classes} classes: "
            "check the class names file against the model"
        )
    return num_classes


def decode_yolox(
    output: np.ndarray,
    input_hw: tuple[int, int],
    class_indices: np.ndarray | None = None,
    score_threshold: float = 0.0,
    strides: tuple[int, ...] = DEFAULT_STRIDES,
    target_class: int | None = None,
) -> Candidates:
    """Decode a raw YOLOX output: ``cx = (x + grid_x) * stride``, ``w = exp(log w) * stride``.

    Scores are objectness x class score; only the best class among ``class_indices`` is kept per anchor.
    """
    array = _as_2d(output)
    _check_classes(array, 5, class_indices)
    points = grid_point_count(input_hw, strides)
    if array.shape[0] != points:
        raise ModelError(
            f"YOLOX output has {array.shape[0]} rows but an input of {input_hw[0]}x{input_hw[1]} with strides "
            f"{strides} has {points} grid points: wrong layout or input size"
        )
    keep, scores, class_ids = _select(array, 5, 4, class_indices, score_threshold)
    if keep.size == 0:
        return Candidates.empty()
    grid_x, grid_y, stride_of_row = _grids(input_hw, strides)
    rows = array[keep].astype(np.float64)
    stride = stride_of_row[keep]
    cx = (rows[:, 0] + grid_x[keep]) * stride
    cy = (rows[:, 1] + grid_y[keep]) * stride
    w = np.exp(np.clip(rows[:, 2], -_MAX_LOG_SIZE, _MAX_LOG_SIZE)) * stride
    h = np.exp(np.clip(rows[:, 3], -_MAX_LOG_SIZE, _MAX_LOG_SIZE)) * stride
    boxes = _centre_size_to_xyxy(cx, cy, w, h)
    ok = _finite_rows(boxes)
    target = _target_scores(rows, 5, 4, target_class)
    return Candidates(boxes[ok], scores[ok], class_ids[ok], target[ok])


_GRID_CACHE: dict[tuple[tuple[int, int], tuple[int, ...]], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}


def _grids(input_hw: tuple[int, int], strides: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid x, grid y and stride of every anchor row, in YOLOX's order (stride, then row-major y, x)."""
    key = (tuple(input_hw), tuple(strides))
    cached = _GRID_CACHE.get(key)
    if cached is not None:
        return cached
    xs, ys, ss = [], [], []
    for stride in strides:
        rows, cols = input_hw[0] // stride, input_hw[1] // stride
        gy, gx = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
        xs.append(gx.ravel())
        ys.append(gy.ravel())
        ss.append(np.full(rows * cols, stride))
    result = (
        np.concatenate(xs).astype(np.float64),
        np.concatenate(ys).astype(np.float64),
        np.concatenate(ss).astype(np.float64),
    )
    _GRID_CACHE[key] = result
    return result


def decode_yolov5(
    output: np.ndarray,
    class_indices: np.ndarray | None = None,
    score_threshold: float = 0.0,
    target_class: int | None = None,
) -> Candidates:
    """Decode a YOLOv5-style output: rows of decoded ``cx, cy, w, h`` (input pixels), objectness, classes."""
    array = _as_2d(output)
    _check_classes(array, 5, class_indices)
    keep, scores, class_ids = _select(array, 5, 4, class_indices, score_threshold)
    if keep.size == 0:
        return Candidates.empty()
    rows = array[keep].astype(np.float64)
    boxes = _centre_size_to_xyxy(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3])
    ok = _finite_rows(boxes)
    return Candidates(boxes[ok], scores[ok], class_ids[ok], _target_scores(rows, 5, 4, target_class)[ok])


def decode_yolov8(
    output: np.ndarray,
    class_indices: np.ndarray | None = None,
    score_threshold: float = 0.0,
    target_class: int | None = None,
) -> Candidates:
    """Decode a YOLOv8-style output: columns of decoded ``cx, cy, w, h`` then class scores, no objectness."""
    array = _as_2d(output).T
    _check_classes(array, 4, class_indices)
    keep, scores, class_ids = _select(array, 4, None, class_indices, score_threshold)
    if keep.size == 0:
        return Candidates.empty()
    rows = array[keep].astype(np.float64)
    boxes = _centre_size_to_xyxy(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3])
    ok = _finite_rows(boxes)
    return Candidates(boxes[ok], scores[ok], class_ids[ok], _target_scores(rows, 4, None, target_class)[ok])


def decode(
    output: np.ndarray,
    layout: OutputLayout | str,
    input_hw: tuple[int, int],
    class_indices: np.ndarray | None = None,
    score_threshold: float = 0.0,
    strides: tuple[int, ...] = DEFAULT_STRIDES,
    target_class: int | None = None,
) -> Candidates:
    """Decode one output tensor of the given layout into candidates in network-input pixels.

    ``target_class`` (a column index) also returns each candidate's score for that class (``target_scores``).
    """
    layout = OutputLayout(layout)
    if layout is OutputLayout.YOLOX:
        return decode_yolox(output, input_hw, class_indices, score_threshold, strides, target_class)
    if layout is OutputLayout.YOLOV5:
        return decode_yolov5(output, class_indices, score_threshold, target_class)
    return decode_yolov8(output, class_indices, score_threshold, target_class)
