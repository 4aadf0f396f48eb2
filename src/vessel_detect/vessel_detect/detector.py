"""The ROS-free vessel detector: an ONNX YOLO model run on the water band of a frame, whole or in tiles.

Modes (``DetectorConfig.mode``):

- ``full``: the whole frame, letterboxed into the network input (the plain way; small boats vanish: a 60 px
  boat is 20 px at 416/1280).
- ``band``: the band below the horizon (from the calibration, with a margin above it for masts and waves),
  letterboxed whole.
- ``tiled`` (default): overlapping windows of the band shown to the network at ``tile_scales`` network pixels
  per image pixel (one tiling per scale), plus optionally the whole band in one pass (``global_pass``) for boats
  too large for a tile. Detections of all windows are merged (see :mod:`vessel_detect.tiling`).

``size_prior`` (a ``SizePrior``, off by default) lowers the ``p_target`` of a box much larger than the vessel of
interest would be at the depth its position gives (``vessel_detect.size_prior``).

Then boxes whose bottom lies above the band top (the sky, the far shore) and boxes mostly inside a static
exclusion mask are dropped. Boxes come back in full-image pixels. How a window becomes the network's input is
``vessel_detect.network_input``, where the model's class names come from ``vessel_detect.class_names``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vessel_common.errors import ModelError, VesselError
from vessel_detect.appearance_model import rescore_detections
from vessel_detect.class_names import COCO_CLASSES, find_class_names, read_class_names
from vessel_detect.decoders import DEFAULT_STRIDES, OutputLayout, decode, detect_layout
from vessel_detect.image_codec import ImageError
from vessel_detect.image_view import ImageView, ReferenceGrid
from vessel_detect.masks import DEFAULT_EXCLUSION_POLYGONS, ExclusionMask
from vessel_detect.model_store import ModelSpec, how_to_get, resolve_model, sha256_of
from vessel_detect.network_input import LETTERBOX_PAD_VALUE, Letterbox, letterbox
from vessel_detect.size_prior import SizePrior
from vessel_detect.tiling import (
    Window,
    WindowDetections,
    cut_flags,
    merge_windows,
    nms_per_window,
    tile_windows,
)

MODES = ("full", "band", "tiled")
CHALLENGE_HORIZON_Y = 418.0
"""Screen y of the horizon of the challenge camera (1280x720), for when no calibration is at hand."""

@dataclass
class Detections:
    """Detections of one frame, in full-image pixels.

    Attributes:
        boxes_xyxy: ``(N, 4)`` float corners ``x1, y1, x2, y2``.
        scores: ``(N,)`` confidence in [0, 1].
        class_ids: ``(N,)`` int index into ``class_names``.
        class_names: the model's class names (all of them, not only the detected ones).
        p_target: ``(N,)`` probability that the box is the vessel of interest (the model's target class, or
            the appearance cue), NaN where neither gives one.

    """

    boxes_xyxy: np.ndarray
    scores: np.ndarray
    class_ids: np.ndarray
    class_names: list[str] = field(default_factory=list)
    p_target: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.p_target is None:
            self.p_target = np.full(np.shape(self.scores), np.nan)

    def __len__(self) -> int:
        return int(self.scores.shape[0])

    def in_calibrated_pixels(self, image_wh: tuple[int, int], calibrated_wh: tuple[int, int],
                             aspect_tolerance: float = 0.01) -> Detections:
        """These detections of an ``image_wh`` frame in the pixels of the calibration's ``calibrated_wh``.

        Everything downstream (tracker, fuser, the calibration's H) reads calibrated pixels. A frame of another
        size with the same aspect ratio (a scaled stream) has its boxes scaled; one of another aspect ratio is
        another camera or a crop, which no scale makes right: ``ImageError`` (kind ``wrong_image_size``).
        """
        (width, height), (ref_w, ref_h) = image_wh, calibrated_wh
        if (width, height) == (ref_w, ref_h):
            return self
        sx, sy = ref_w / width, ref_h / height
        if abs(sx / sy - 1.0) > aspect_tolerance:
            raise ImageError(
                "wrong_image_size",
                f"image is {width}x{height} but the calibration is for {ref_w}x{ref_h} (another aspect ratio): "
                f"publish the calibrated camera's frames, or calibrate this stream (camera.image_width/height)")
        boxes = self.boxes_xyxy * np.array([sx, sy, sx, sy])
        return Detections(boxes, self.scores, self.class_ids, self.class_names, self.p_target)

    @staticmethod
    def empty(class_names: Sequence[str] = ()) -> Detections:
        """No detections."""
        return Detections(np.zeros((0, 4)), np.zeros(0), np.zeros(0, dtype=np.int64), list(class_names))

    def target_confidences(self) -> np.ndarray:
        """Each box's probability of being the vessel of interest where known, else its score.

        The ranking the tracker's confidence follows (``confidence_class``).
        """
        return np.where(np.isfinite(self.p_target), self.p_target, self.scores)

    def labels(self) -> list[str]:
        """Class name of each detection."""
        return [self.class_names[i] if 0 <= i < len(self.class_names) else str(i) for i in self.class_ids]

    def take(self, indices) -> Detections:
        """The detections at ``indices`` (boolean mask or index array)."""
        return Detections(self.boxes_xyxy[indices], self.scores[indices], self.class_ids[indices], self.class_names,
                          self.p_target[indices])


@dataclass
class DetectorConfig:
    """Everything the detector core needs besides the model; the node's parameters map onto it 1:1."""

    score_threshold: float = 0.15
    nms_iou: float = 0.55
    classes: tuple[str, ...] = ("boat",)
    mode: str = "tiled"
    band_margin_px: float = 40.0
    band_bottom_px: float = 0.0
    tile_scales: tuple[float, ...] = (1.25,)
    tile_overlap_px: int = 96
    global_pass: bool = True
    exclusion_polygons: tuple[str, ...] = DEFAULT_EXCLUSION_POLYGONS
    mask_max_inside: float = 0.5
    cut_edge_tolerance_px: float = 3.0
    covered_threshold: float = 0.6
    target_class: str = ""
    class_agnostic_nms: bool = False
    masks_fixed_to: str = "reference"

    def validate(self) -> None:
        """Reject values the detector cannot work with; the message names the parameter."""
        checks = [
            (0.0 <= self.score_threshold <= 1.0, "score_threshold must be in [0, 1]"),
            (0.0 < self.nms_iou <= 1.0, "nms_iou must be in (0, 1]"),
            (self.mode in MODES, f"mode '{self.mode}' unknown: use one of {', '.join(MODES)}"),
            (self.band_margin_px >= 0, "band_margin_px must be >= 0"),
            (self.band_bottom_px >= 0, "band_bottom_px must be >= 0 (0: the image bottom)"),
            (len(self.tile_scales) > 0, "tile_scales must hold at least one scale"),
            (all(0.05 <= s <= 8.0 for s in self.tile_scales), "tile_scales must each be in [0.05, 8]"),
            (self.tile_overlap_px >= 0, "tile_overlap_px must be >= 0"),
            (0.0 <= self.mask_max_inside <= 1.0, "mask_max_inside must be in [0, 1]"),
            (len(self.classes) > 0, "classes must name at least one class (e.g. ['boat'])"),
            (self.masks_fixed_to in ("reference", "image"), "exclusion_polygons_frame must be reference or image"),
        ]
        for ok, message in checks:
            if not ok:
                raise VesselError(f"detector configuration: {message}")


class OnnxModel:
    """An onnxruntime session of a YOLO-family model, with its input size and output layout.

    Args:
        path: ONNX file.
        intra_op_threads: onnxruntime intra-op threads (the detector's share of the CPU).
        layout: ``auto`` (from the output shape), ``yolox``, ``yolov5`` or ``yolov8``.
        class_names: class names in output order; None to find them next to the model, or COCO's when the
            model has 80 classes.
        input_size: (width, height) for models with a dynamic input size.
        expected_sha256: only used in error messages.
        how_to_get: how to obtain a good copy, appended to the error for an unreadable file.

    Raises:
        ModelError: not a readable ONNX model, input not a 3-channel image tensor, unknown output layout, or
            class names that do not match the model.

    """

    def __init__(
        self,
        path: str | Path,
        intra_op_threads: int = 2,
        layout: str = "auto",
        class_names: Sequence[str] | None = None,
        input_size: tuple[int, int] = (416, 416),
        expected_sha256: str = "",
        strides: tuple[int, ...] = DEFAULT_STRIDES,
        how_to_get: str = "",
    ):
        import onnxruntime as ort

        self.path = Path(path)
        self.strides = tuple(strides)
        options = ort.SessionOptions()
        options.intra_op_num_threads = max(1, int(intra_op_threads))
        options.inter_op_num_threads = 1
        # Spinning worker threads burn the cores the rest of the graph needs between frames; on the 2-core
        # development machine turning it off made inference 1.5-2x faster under load (bench report).
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        options.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        except Exception as error:  # onnxruntime raises its own untyped errors for unreadable files
            first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            expected = f", expected {expected_sha256}" if expected_sha256 else ""
            fix = f"; {how_to_get}" if how_to_get else ""
            raise ModelError(
                f"model file {self.path} is not a usable ONNX model ({first_line[:200]}); its sha256 is "
                f"{_safe_sha(self.path)}{expected}{fix}"
            ) from None
        model_input = _image_input(self.session, self.path)
        self.input_name = model_input.name
        shape = list(model_input.shape)
        fixed = [isinstance(side, int) and side > 0 for side in shape[2:]]
        self.free_input_size = not any(fixed)
        nominal_wh = _nominal_input_size(self.session, self.path) or (int(input_size[0]), int(input_size[1]))
        height = shape[2] if fixed[0] else nominal_wh[1]
        width = shape[3] if fixed[1] else nominal_wh[0]
        self.input_hw = (int(height), int(width))
        self.output_name = self.session.get_outputs()[0].name
        self.output_shape = self._probe_output_shape()
        names = list(class_names) if class_names else find_class_names(self.path)
        self.layout = self._output_layout(layout, names, strides)
        self.num_classes = self._class_count()
        self.class_names = self._checked_class_names(names)

    def _probe_output_shape(self) -> tuple[int, ...]:
        """One dry run: checks the model runs at all and gives the real output shape for dynamic models."""
        try:
            probe = self.session.run(
                [self.output_name],
                {self.input_name: np.full((1, 3, *self.input_hw), LETTERBOX_PAD_VALUE, np.float32)},
            )[0]
        except Exception as error:
            height, width = self.input_hw
            raise ModelError(f"model {self.path} fails on a {width}x{height} image: {str(error)[:300]}") from None
        return tuple(probe.shape)

    def _output_layout(self, layout: str, names: list[str] | None, strides) -> OutputLayout:
        """The given layout, or for ``auto`` the one the output shape implies (with the class count, if known)."""
        if layout == "auto":
            try:
                return detect_layout(self.output_shape, self.input_hw, None, strides)
            except ModelError:
                if not names:
                    raise
                return detect_layout(self.output_shape, self.input_hw, len(names), strides)
        try:
            return OutputLayout(layout)
        except ValueError:
            raise ModelError(f"layout '{layout}' unknown: use auto, yolox, yolov5 or yolov8") from None

    def _checked_class_names(self, names: list[str] | None) -> list[str]:
        """One name per output class: the ones found, else COCO's for an 80-class model."""
        if names is None:
            if self.num_classes == len(COCO_CLASSES):
                names = list(COCO_CLASSES)
            else:
                raise ModelError(
                    f"model {self.path} has {self.num_classes} classes and no class names were found: put one "
                    "name per line in classes.txt next to the model or set class_names_file"
                )
        if len(names) != self.num_classes:
            raise ModelError(
                f"model {self.path} outputs {self.num_classes} classes but {len(names)} class names were given"
            )
        return names

    def _class_count(self) -> int:
        dims = self.output_shape[1:] if len(self.output_shape) == 3 else self.output_shape
        if self.layout is OutputLayout.YOLOV8:
            return int(dims[0]) - 4
        return int(dims[1]) - 5

    def run(self, tensor: np.ndarray) -> np.ndarray:
        """Run the network on one ``(1, 3, H, W)`` float32 tensor; return its first output."""
        return self.session.run([self.output_name], {self.input_name: tensor})[0]


def _image_input(session, path: Path):
    """The model's one input, checked to be a float image tensor (1, 3, H, W)."""
    inputs = session.get_inputs()
    if len(inputs) != 1:
        raise ModelError(
            f"model {path} has {len(inputs)} inputs; the detector needs one image input (1, 3, H, W)"
        )
    model_input = inputs[0]
    shape = list(model_input.shape)
    if len(shape) != 4 or (isinstance(shape[1], int) and shape[1] != 3):
        raise ModelError(
            f"model {path} input '{model_input.name}' has shape {shape}: the detector needs a 3-channel "
            "image tensor (1, 3, height, width), BGR"
        )
    if "float" not in model_input.type:
        raise ModelError(
            f"model {path} input '{model_input.name}' is {model_input.type}: the detector feeds float32 "
            "pixels 0-255"
        )
    return model_input


INPUT_SIZE_METADATA_KEY = "input_size"
"""ONNX metadata key of a free-size model's usual input, ``WIDTHxHEIGHT`` (what ``detect train`` writes)."""


def _nominal_input_size(session, path: Path) -> tuple[int, int] | None:
    """The ``(width, height)`` a free-size model was trained for, from its metadata; None when not recorded."""
    text = session.get_modelmeta().custom_metadata_map.get(INPUT_SIZE_METADATA_KEY, "")
    if not text:
        return None
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise ModelError(
            f"model {path} metadata {INPUT_SIZE_METADATA_KEY}='{text}' is not WIDTHxHEIGHT (e.g. 1280x352): "
            "re-export the model with ./vessel detect train"
        ) from None
    if width <= 0 or height <= 0 or width % 32 or height % 32:
        raise ModelError(
            f"model {path} metadata {INPUT_SIZE_METADATA_KEY}='{text}' must be positive multiples of 32"
        )
    return width, height


def _safe_sha(path: Path) -> str:
    try:
        return sha256_of(path)
    except OSError:
        return "(unreadable)"


def load_model(
    spec: ModelSpec,
    intra_op_threads: int = 2,
    layout: str = "auto",
    class_names_file: str = "",
    cache_dir: Path | None = None,
    allow_download: bool = True,
) -> OnnxModel:
    """Resolve (and if needed download and verify) the model, then open it."""
    path = resolve_model(spec, cache_dir=cache_dir, allow_download=allow_download)
    names = read_class_names(Path(class_names_file)) if class_names_file else None
    return OnnxModel(
        path, intra_op_threads, layout, names, expected_sha256=spec.expected_sha256,
        how_to_get=how_to_get(spec, cache_dir),
    )


@dataclass(frozen=True)
class NetworkRun:
    """One network run on a frame.

    ``window`` is the source rectangle; ``fixed_scale`` shows it at ``window.scale`` (the tiles) instead of fitting
    it whole.
    """

    window: Window
    fixed_scale: bool


def horizon_band_top(camera_model, image_wh: tuple[int, int] | None = None, samples: int = 65) -> float | None:
    """Highest screen y of the horizon across the image width (the band starts there), None if undefined.

    ``camera_model`` is a ``vessel_calib.camera_model.CameraModel``; the horizon curves with the lens, so the
    line is sampled across the width and its top taken.
    """
    width = image_wh[0] if image_wh else camera_model.image_size[0]
    xs = np.linspace(0.0, float(width), samples)
    ys = np.asarray(camera_model.horizon_y(xs), dtype=np.float64)
    ys = ys[np.isfinite(ys)]
    if ys.size == 0:
        return None
    return float(ys.min())


class VesselDetector:
    """Detect vessels in BGR frames with an ONNX YOLO model (see the module docstring for the modes).

    Args:
        model: an :class:`OnnxModel`.
        config: thresholds, classes, mode, band, tiles, masks.
        horizon_y: screen y of the horizon (its top across the width) in pixels of ``reference_wh``; None
            when unknown (the band then starts at the top of the image).
        reference_wh: image size the horizon and the mask polygons refer to (the calibration's); frames of
            another size get them scaled.

    """

    def __init__(
        self,
        model: OnnxModel,
        config: DetectorConfig | None = None,
        horizon_y: float | None = CHALLENGE_HORIZON_Y,
        reference_wh: tuple[int, int] = (1280, 720),
    ):
        self.model = model
        self.config = config or DetectorConfig()
        self.config.validate()
        self.horizon_y = None if horizon_y is None or not np.isfinite(horizon_y) else float(horizon_y)
        self.reference_wh = (int(reference_wh[0]), int(reference_wh[1]))
        unknown = [name for name in self.config.classes if name not in model.class_names]
        if unknown:
            raise ModelError(
                f"class(es) {', '.join(unknown)} not among the model's classes "
                f"({', '.join(model.class_names[:12])}{', ...' if len(model.class_names) > 12 else ''})"
            )
        self.class_indices = np.array([model.class_names.index(n) for n in self.config.classes], dtype=np.int64)
        if self.config.target_class and self.config.target_class not in model.class_names:
            raise ModelError(
                f"target_class '{self.config.target_class}' is not among the model's classes "
                f"({', '.join(model.class_names[:12])}); set it to the model's vessel-of-interest class or ''"
            )
        self.target_index = model.class_names.index(self.config.target_class) if self.config.target_class else None
        self.mask = ExclusionMask(list(self.config.exclusion_polygons), self.reference_wh)
        self._plans: dict[tuple[int, int], list[NetworkRun]] = {}
        self.appearance = None  # an appearance_model.AppearanceModel rescoring the boxes (set by build_detector)
        self.appearance_min_probability = 0.0
        self.appearance_camera = None  # the CameraModel its geometry features need (set by build_detector)
        self.appearance_combine = "replace"
        self.appearance_nested_overlap = 0.0  # > 0: after the cue, nested boxes keep only the likelier one
        self.size_prior = SizePrior()  # off; build_detector sets it from the parameters, with its camera
        self.size_prior_camera = None
        self.last_window_count = 0
        self._grid: ReferenceGrid | None = None
        self._warped = False  # detecting in a warped image: masks fixed to the camera wait for the boxes to go back

    @property
    def class_names(self) -> list[str]:
        """The model's class names."""
        return self.model.class_names

    def band(self, image_wh: tuple[int, int]) -> tuple[float, float]:
        """The processed band ``(top, bottom)`` in pixels of an image of ``image_wh``."""
        width, height = image_wh
        sy = height / self.reference_wh[1]
        if self.horizon_y is None:
            top = 0.0
        else:
            top = max(0.0, (self.horizon_y - self.config.band_margin_px) * sy)
        bottom = float(height) if self.config.band_bottom_px <= 0 else min(height, self.config.band_bottom_px * sy)
        if bottom <= top + 1:
            top, bottom = 0.0, float(height)
        return top, bottom

    def windows(self, image_wh: tuple[int, int]) -> list[NetworkRun]:
        """The network runs on an image of ``image_wh`` (cached per size)."""
        key = (int(image_wh[0]), int(image_wh[1]))
        if key not in self._plans:
            self._plans[key] = self._plan(key)
        return self._plans[key]

    def _plan(self, image_wh: tuple[int, int]) -> list[NetworkRun]:
        width, height = image_wh
        config = self.config
        net_wh = (self.model.input_hw[1], self.model.input_hw[0])
        if config.mode == "full":
            return [NetworkRun(_whole_window(0, 0, width, height, net_wh, image_wh), False)]
        top, bottom = self.band(image_wh)
        itop, ibottom = int(np.floor(top)), int(np.ceil(bottom))
        band_run = NetworkRun(_whole_window(0, itop, width, ibottom, net_wh, image_wh), False)
        if config.mode == "band":
            return [band_run]
        plan: list[NetworkRun] = []
        if config.global_pass:
            plan.append(band_run)
        for scale in config.tile_scales:
            plan += [
                NetworkRun(window, True)
                for window in tile_windows((0, top, width, bottom), image_wh, net_wh, scale, config.tile_overlap_px)
            ]
        return plan

    def detect(self, bgr: np.ndarray, view: ImageView | None = None) -> Detections:
        """Detect vessels in one BGR uint8 frame; boxes in the frame's pixels.

        ``view``: where this image sits relative to the calibration (a camera that moves): the band is warped into
        the reference image's geometry and detected there (``vessel_detect.image_view``); boxes come back in this
        image's pixels.
        """
        image = np.asarray(bgr)
        if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] == 0 or image.shape[1] == 0:
            raise VesselError(f"detector input must be a (H, W, 3) BGR image, got shape {image.shape}")
        height, width = image.shape[:2]
        if view is not None and (width, height) == self.reference_wh:
            return self._detect_in_reference(image, view)
        plan = self.windows((width, height))
        self.last_window_count = len(plan)
        parts = []
        windows = []
        for index, run in enumerate(plan):
            window = run.window
            windows.append(window)
            crop = image[window.y0 : window.y1, window.x0 : window.x1]
            tensor, scale = letterbox(crop, self.model.input_hw, window.scale if run.fixed_scale else None)
            output = self.model.run(tensor)
            candidates = decode(
                output, self.model.layout, self.model.input_hw, self.class_indices,
                self.config.score_threshold, self.model.strides, self.target_index,
            )
            if len(candidates) == 0:
                continue
            boxes = Letterbox(scale, window.x0, window.y0).to_source(candidates.boxes_xyxy)
            boxes = np.clip(boxes, [window.x0, window.y0, window.x0, window.y0],
                            [window.x1, window.y1, window.x1, window.y1])
            tolerance = self.config.cut_edge_tolerance_px / scale
            part = WindowDetections(
                boxes, candidates.scores, candidates.class_ids,
                np.full(len(candidates), index, dtype=np.int64), cut_flags(boxes, window, tolerance),
                candidates.target_scores,
            )
            parts.append(nms_per_window(part, self.config.nms_iou, self.config.class_agnostic_nms))
        merged = WindowDetections.concatenate(parts)
        if len(plan) > 1:
            merged = merge_windows(merged, windows, self.config.nms_iou, self.config.covered_threshold,
                                   class_agnostic=self.config.class_agnostic_nms)
        detections = Detections(merged.boxes_xyxy, merged.scores, merged.class_ids, self.class_names,
                                merged.target_scores)
        detections = self._filter(detections, (width, height))
        calibration_scale = (self.reference_wh[0] / width, self.reference_wh[1] / height)
        if self.appearance is not None:
            detections = rescore_detections(detections, image, self.appearance, self.appearance_min_probability,
                                            self.appearance_camera, calibration_scale, self.appearance_combine,
                                            self.appearance_nested_overlap)
        if self.size_prior.enabled and self.size_prior_camera is not None:
            detections = apply_size_prior(detections, self.size_prior, self.size_prior_camera, calibration_scale)
        order = np.argsort(-detections.scores, kind="stable")
        return detections.take(order)

    def _detect_in_reference(self, image: np.ndarray, view: ImageView) -> Detections:
        """Detect in the band warped into the reference image's geometry, boxes back in the image's pixels."""
        if self._grid is None:
            self._grid = ReferenceGrid(view.lens, self.reference_wh)
        band = self.band(self.reference_wh) if self.config.mode != "full" else (0.0, float(self.reference_wh[1]))
        self._warped = True
        try:
            found = self.detect(view.warp_to_reference(image, band, self._grid))
        finally:
            self._warped = False
        found.boxes_xyxy = view.boxes_to_image(found.boxes_xyxy)
        keep = np.all(np.isfinite(found.boxes_xyxy), axis=1)
        if self.mask and self.config.masks_fixed_to == "image":
            keep &= self.mask.keep(np.nan_to_num(found.boxes_xyxy), self.reference_wh, self.config.mask_max_inside)
        return found.take(keep)

    def _filter(self, detections: Detections, image_wh: tuple[int, int]) -> Detections:
        """Drop empty boxes, boxes standing above the band, and boxes mostly inside an exclusion mask."""
        if len(detections) == 0:
            return detections
        boxes = detections.boxes_xyxy
        keep = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])
        if self.config.mode != "full":
            top, _ = self.band(image_wh)
            keep &= boxes[:, 3] > top
        if self.mask and not (self._warped and self.config.masks_fixed_to == "image"):
            keep &= self.mask.keep(boxes, image_wh, self.config.mask_max_inside)
        return detections.take(keep)


def apply_size_prior(detections: Detections, prior: SizePrior, camera,
                     calibration_scale: tuple[float, float] = (1.0, 1.0)) -> Detections:
    """``detections`` with the ``p_target`` of boxes too large for the vessel at their depth lowered (``prior``).

    ``camera`` is the calibration's ``CameraModel``; ``calibration_scale`` turns frame pixels into its pixels.
    """
    if len(detections) == 0 or not np.isfinite(detections.p_target).any():
        return detections
    sx, sy = calibration_scale
    ratios = prior.log_size_ratios(camera, detections.boxes_xyxy * np.array([sx, sy, sx, sy]))
    lowered = detections.take(np.arange(len(detections)))
    lowered.p_target = prior.apply(lowered.p_target, ratios)
    return lowered


def _whole_window(x0: int, y0: int, x1: int, y1: int, net_wh: tuple[int, int], image_wh: tuple[int, int]) -> Window:
    """A window showing a whole region letterboxed; its edges inside the image count as cut edges."""
    scale = min(net_wh[0] / max(1, x1 - x0), net_wh[1] / max(1, y1 - y0))
    interior = (x0 > 0, y0 > 0, x1 < image_wh[0], y1 < image_wh[1])
    return Window(int(x0), int(y0), int(x1), int(y1), float(scale), interior)

