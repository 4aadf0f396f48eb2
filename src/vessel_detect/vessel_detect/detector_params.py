"""The detector node's parameters in one table, shared by the node (which declares them) and the CLI tools.

``./vessel detect run`` and the benchmark use exactly the node's defaults, or the ``detector:`` block of a
parameter file, so a figure measured offline is the figure of the running node. No ROS import here.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from vessel_calib.attitude import AttitudeSettings
from vessel_calib.camera_model import CameraModel
from vessel_calib.params import camera_block, node_blocks, read_params_yaml
from vessel_common.errors import ModelError, VesselError
from vessel_common.parameter_names import flatten, is_rcl_parameter
from vessel_common.parameter_table import Param, ParameterTable
from vessel_common.paths import in_repo
from vessel_detect.appearance_model import (
    COMBINE_MODES,
    DEFAULT_COMBINE,
    DEFAULT_MIN_PROBABILITY,
    DEFAULT_NESTED_OVERLAP,
    AppearanceModel,
)
from vessel_detect.detector import (
    CHALLENGE_HORIZON_Y,
    MODES,
    DetectorConfig,
    OnnxModel,
    VesselDetector,
    horizon_band_top,
    load_model,
)
from vessel_detect.frame_pose import FramePoser
from vessel_detect.masks import DEFAULT_EXCLUSION_POLYGONS
from vessel_detect.model_store import ModelSpec
from vessel_detect.size_prior import DEFAULT_SIZE_MODEL, DIMENSIONS, SizePrior

NODE_NAME = "detector"


MODEL_PARAMS: tuple[Param, ...] = (
    Param("model_path", "", "ONNX model file; '' searches $VESSEL_MODEL, ../shared/models, the cache, "
              "then downloads model_url."),
    Param("model_url", "", "URL to download the model from into the cache ('' with no model_path: the "
              "default YOLOX-Nano's URL)."),
    Param("model_sha256", "", "sha256 of the model file: required with model_url (a download is checked "
              "before it is used); '' with neither model_path nor model_url: the default model's."),
    Param("model_cache_dir", "", "Download cache ('' : $VESSEL_MODEL_CACHE or "
              "~/.cache/vessel_tracking/models)."),
    Param("allow_download", True, "Download model_url when the model is not found locally."),
    Param("class_names_file", "", "Class names, one per line in output order ('' : coco_classes.txt or "
              "classes.txt next to the model, else COCO's for 80-class models)."),
    Param("layout", "auto", "Output layout: auto (from the output shape), yolox, yolov5 or yolov8.",
          choices=("auto", "yolox", "yolov5", "yolov8")),
    Param("intra_op_threads", 1, "onnxruntime intra-op threads (the detector's share of the CPU). In a graph on "
          "two cores 1 leaves the other core to the camera, tracker and fuser, and more frames get through; the "
          "detector alone (offline, or a host serving several cameras) is faster with 2.",
              value_range=(1, 64)),
)

DETECTION_PARAMS: tuple[Param, ...] = (
    Param("classes", ["boat"], "Class names to detect (others are ignored)."),
    Param("score_threshold", 0.1, "Minimum confidence (objectness x class score) of a detection; the "
              "tracker downstream handles the clutter of low values.", value_range=(0.0, 1.0), live=True),
    Param("target_class", "", "The model's class of the vessel of interest (e.g. vessel_of_interest): each "
              "detection also carries its probability as a hypothesis of this class ('' : none)."),
    Param("class_agnostic_nms", False, "Suppress overlapping boxes whatever their class (a model whose "
              "classes split one kind of object, such as vessel_of_interest and vessel)."),
    Param("nms_iou", 0.5, "IoU above which the weaker of two boxes of a class is suppressed.",
              value_range=(0.01, 1.0), live=True),
    Param("mode", "tiled", "full (whole frame), band (the band below the horizon, letterboxed whole) or "
              "tiled (overlapping windows of the band at tile_scales).", choices=MODES),
    Param("band_margin_px", 40.0, "Band starts this far above the horizon (masts, waves, calibration "
              "error), pixels of the calibrated image size.", value_range=(0.0, 2000.0)),
    Param("band_bottom_px", 0.0, "Band ends at this image row (0: the image bottom).",
              value_range=(0.0, 20000.0)),
    Param("tile_scales", [1.25], "Network pixels per image pixel of the tiles (several values: one tiling "
              "per scale). 1.25 shows a 333x333 window to a 416x416 network."),
    Param("tile_overlap_px", 96, "Minimum overlap of neighbouring tiles, image pixels (a boat narrower "
              "than this is whole in some tile).", value_range=(0, 4096)),
    Param("global_pass", True, "Tiled mode: also run the whole band letterboxed once, for boats too "
              "large for a tile."),
    Param("size_prior.dimension", "none", "A box much larger than the vessel of interest would be at the depth "
              "its position gives (through the calibration and size_prior.model) is less likely the vessel: "
              f"{', '.join(DIMENSIONS)} (which box size is compared). Needs the calibration (camera.* parameters).",
          choices=DIMENSIONS),
    Param("size_prior.tolerance", 0.3, "With size_prior.dimension: sizes up to exp(this) times the vessel's "
              "expected size change nothing (natural log of the ratio).", value_range=(0.0, 5.0)),
    Param("size_prior.strength", 10.0, "With size_prior.dimension: log-odds of p_target lowered per unit of "
              "log size ratio beyond the tolerance (0: off).", value_range=(0.0, 100.0)),
    Param("size_prior.model", list(DEFAULT_SIZE_MODEL), "a, b, c, d of the vessel's box size at a depth: width "
              "= a / depth + b, height = c / depth + d (px, m); the fuser's distance_model, which ./vessel fit "
              "distance-model writes to both."),
    Param("exclusion_polygons", list(DEFAULT_EXCLUSION_POLYGONS), "Static exclusion masks, one polygon "
              "per string 'x,y x,y x,y ...' in pixels of the calibrated image size (default: the challenge "
              "camera's mooring post); [''] for none."),
    Param("mask_max_inside", 0.5, "A detection whose box lies more than this share inside a mask is "
              "dropped.", value_range=(0.0, 1.0), live=True),
    Param("appearance_model", "", "Appearance model of the vessel of interest (.npz from `python -m "
              "vessel_tools.track.appearance fit`; relative paths from the working directory, then the repository): "
              "scores become its probability of the vessel of interest. '' : off."),
    Param("appearance_min_probability", DEFAULT_MIN_PROBABILITY, "With appearance_model: boxes whose "
              "probability of being the vessel of interest is below this are dropped.", value_range=(0.0, 1.0)),
    Param("appearance_combine", DEFAULT_COMBINE, "With appearance_model: replace (the published score is the "
              "probability) or product (detector score x probability).", choices=COMBINE_MODES),
    Param("appearance_nested_overlap", DEFAULT_NESTED_OVERLAP, "With appearance_model: a box sharing more "
              "than this share of the smaller box's area with a likelier box is dropped (one box per vessel; 0: off).",
              value_range=(0.0, 1.0)),
)

POSE_PARAMS: tuple[Param, ...] = (
    Param("pose.source", "fixed", "The camera's attitude per image: fixed (the calibration's; the horizon is "
              "measured only for the annotated image), horizon (a camera on a pole or pier that sways: pitch and "
              "roll from the horizon measured in each image) or own_ship (a camera on a ship: the ship's attitude on "
              "imu_topic, corrected by the horizon with use_horizon).", choices=("fixed", "horizon", "own_ship")),
    Param("pose.imu_topic", "/own_ship/imu", "The ship's attitude (sensor_msgs/Imu orientation, REP-103/145: ENU, "
              "body x forward, z up). A compass alone: the heading in the orientation and -1 in "
              "orientation_covariance[0] and [4] (roll, pitch not measured)."),
    Param("pose.imu_qos", "reliable", "QoS of the attitude subscription: reliable (loses nothing; a replay's "
              "camera node publishes reliably) or sensor_data (best effort: for a driver that publishes best "
              "effort, which a reliable reader does not hear).", choices=("reliable", "sensor_data")),
    Param("pose.max_age_s", 0.5, "An image whose stamp is further than this from the ship's attitude samples "
              "around it gets no pose (counted as stale_pose): no positions are made from it.",
              value_range=(0.001, 15.0)),
    Param("pose.wait_s", 0.2, "How long an image waits for an attitude sample stamped after it (so the "
              "attitude is interpolated, not held).", value_range=(0.0, 5.0)),
    Param("pose.use_horizon", True, "Measure the sea's far edge in each image and, with source horizon or "
              "own_ship, correct the attitude with it."),
    Param("pose.sensor_sigma_deg", 0.1, "Noise of the ship's pitch and roll sensor, degrees.",
              value_range=(1e-4, 10.0), live=True),
    Param("pose.heading_sigma_deg", 0.5, "Noise of the ship's heading (compass), degrees.",
              value_range=(1e-4, 30.0), live=True),
    Param("pose.bias_drift_deg_per_s", 0.01, "How fast the attitude sensor's bias may wander, degrees per "
              "second (the horizon tracks it).", value_range=(1e-6, 1.0)),
    Param("pose.gate_sigmas", 5.0, "A horizon further than this many standard deviations from the "
              "bias-corrected sensor is taken for a wrong edge and not used (counted).", value_range=(1.0, 100.0),
          live=True),
    Param("pose.topic", "vessel/camera_pose", "vessel_msgs/CameraPose output: the attitude used for each image "
              "and the horizon measured in it."),
    Param("exclusion_polygons_frame", "reference", "What the exclusion masks are fixed to: reference (the world "
              "seen at the calibration's attitude, e.g. a mooring post: they move with the camera's pose) or "
              "image (the camera, e.g. the own ship's bow).", choices=("reference", "image")),
)

NODE_PARAMS: tuple[Param, ...] = (
    Param("compressed_topic", "camera/image_raw/compressed", "CompressedImage input topic."),
    Param("raw_topic", "camera/image_raw", "Image input topic."),
    Param("subscribe_compressed", True, "Subscribe to compressed_topic."),
    Param("subscribe_raw", False, "Subscribe to raw_topic."),
    Param("image_qos", "sensor_data", "QoS of the image subscriptions: sensor_data (best effort) or "
              "reliable.", choices=("sensor_data", "reliable")),
    Param("images_waiting", 1, "Images kept waiting while the network works; beyond this the oldest is "
              "dropped (counted). 1 = only the newest (live cameras); 2 for a replay whose camera has "
              "frames_in_flight 2, so that two images arriving back to back are both detected.",
              value_range=(1, 2)),
    Param("decode_ahead", True, "Decode the next waiting image in a second thread while the network runs on "
              "the current one (at most one ahead per processed image); false: the worker decodes each image "
              "itself, one thread."),
    Param("detections_topic", "vessel/detections", "Detection2DArray output topic (reliable)."),
    Param("detections_qos_depth", 10, "History depth of the detections publisher.", value_range=(1, 1000)),
    Param("publish_annotated", False, "Publish the annotated image (boxes, scores, band, masks)."),
    Param("annotated_topic", "vessel/detections/image", "Annotated image topic (Image, bgr8)."),
    Param("annotated_scale", 0.5, "Scale of the annotated image (0.5: half resolution, lighter to send).",
              value_range=(0.05, 1.0)),
    Param("frame_id", "", "frame_id for the output header when the image's is empty ('' : keep it)."),
)

DETECTOR_PARAMETERS = ParameterTable(NODE_NAME, "Detector node (vessel_detect detector): images -> vessel boxes "
                                     "(vision_msgs-style Detection2DArray).",
                                     MODEL_PARAMS + DETECTION_PARAMS + POSE_PARAMS + NODE_PARAMS)


def default_values() -> dict[str, Any]:
    """Every parameter at its default."""
    return DETECTOR_PARAMETERS.defaults()


def merge_values(overrides: Mapping[str, Any] | None) -> dict[str, Any]:
    """Defaults overlaid with a parameter block (e.g. the ``detector:`` block of a YAML); unknown keys rejected."""
    values = default_values()
    for key, value in flatten(overrides or {}).items():
        if key in ("camera", "qos_overrides") or str(key).startswith("camera.") or is_rcl_parameter(str(key)):
            continue
        if key not in DETECTOR_PARAMETERS:
            raise VesselError(
                f"unknown detector parameter '{key}'; known: {', '.join(sorted(DETECTOR_PARAMETERS.names))}"
            )
        default = DETECTOR_PARAMETERS[key].default
        values[key] = _coerce(key, value, default)
    return values


def _coerce(key: str, value: Any, default: Any) -> Any:
    """Give a YAML value the parameter's type (ints for floats are fine, as ROS allows in YAML files)."""
    try:
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise TypeError
            return value
        if isinstance(default, int):
            if isinstance(value, bool) or not isinstance(value, int):
                raise TypeError
            return value
        if isinstance(default, float):
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise TypeError
            return float(value)
        if isinstance(default, str):
            if not isinstance(value, str):
                raise TypeError
            return value
        if isinstance(default, list):
            if not isinstance(value, list | tuple):
                raise TypeError
            if default and isinstance(default[0], float):
                return [float(v) for v in value]
            return [str(v) for v in value]
    except (TypeError, ValueError):
        pass
    hint = (" (YAML reads an unquoted on/off/yes/no as true/false: quote it)"
            if isinstance(default, str) and isinstance(value, bool) else "")
    raise VesselError(f"detector parameter '{key}' = {value!r} has the wrong type; expected like {default!r}{hint}")


def model_spec(values: Mapping[str, Any]) -> ModelSpec:
    """The model named by the parameters."""
    return ModelSpec(str(values["model_path"]), str(values["model_url"]), str(values["model_sha256"]))


def detector_config(values: Mapping[str, Any]) -> DetectorConfig:
    """The core's configuration from parameter values (validated)."""
    polygons = tuple(p for p in values["exclusion_polygons"] if str(p).strip())
    config = DetectorConfig(
        score_threshold=float(values["score_threshold"]),
        nms_iou=float(values["nms_iou"]),
        classes=tuple(str(c) for c in values["classes"] if str(c).strip()),
        mode=str(values["mode"]),
        band_margin_px=float(values["band_margin_px"]),
        band_bottom_px=float(values["band_bottom_px"]),
        tile_scales=tuple(float(s) for s in values["tile_scales"]),
        tile_overlap_px=int(values["tile_overlap_px"]),
        global_pass=bool(values["global_pass"]),
        exclusion_polygons=polygons,
        mask_max_inside=float(values["mask_max_inside"]),
        target_class=str(values["target_class"]).strip(),
        class_agnostic_nms=bool(values["class_agnostic_nms"]),
        masks_fixed_to=str(values["exclusion_polygons_frame"]),
    )
    config.validate()
    return config


def size_prior(values: Mapping[str, Any]) -> SizePrior:
    """The size prior of the parameters (validated)."""
    return SizePrior(dimension=str(values["size_prior.dimension"]), tolerance=float(values["size_prior.tolerance"]),
                     strength=float(values["size_prior.strength"]),
                     size_model=tuple(float(v) for v in values["size_prior.model"]))


def open_model(values: Mapping[str, Any]) -> OnnxModel:
    """Resolve, verify and open the model the parameters name."""
    cache = str(values["model_cache_dir"]).strip()
    return load_model(
        model_spec(values),
        intra_op_threads=int(values["intra_op_threads"]),
        layout=str(values["layout"]),
        class_names_file=str(values["class_names_file"]),
        cache_dir=Path(cache).expanduser() if cache else None,
        allow_download=bool(values["allow_download"]),
    )


def build_detector(values: Mapping[str, Any], camera_model=None, model: OnnxModel | None = None) -> VesselDetector:
    """A detector core from parameter values and a ``CameraModel`` (None: the challenge camera's horizon)."""
    config = detector_config(values)
    if camera_model is None:
        horizon, reference = CHALLENGE_HORIZON_Y, (1280, 720)
    else:
        reference = tuple(int(v) for v in camera_model.image_size)
        horizon = horizon_band_top(camera_model)
    prior = size_prior(values)
    if prior.enabled and camera_model is None:
        raise ModelError(f"size_prior.dimension '{prior.dimension}' needs the calibration to give each box a depth: "
                         "load it with --params-file config/aitas_camera.yaml (the camera.* parameters), or set "
                         "size_prior.dimension none")
    detector = VesselDetector(model or open_model(values), config, horizon, reference)
    detector.size_prior, detector.size_prior_camera = prior, camera_model
    if values.get("appearance_model"):

        path = in_repo(values["appearance_model"])
        detector.appearance = AppearanceModel.load(path)
        if detector.appearance.needs_camera and camera_model is None:
            raise ModelError(f"appearance model {path} uses box geometry ({detector.appearance.feature_set}) and "
                             "needs the calibration: load it with --params-file config/aitas_camera.yaml (the "
                             "camera.* parameters), or set appearance_model to ''")
        detector.appearance_camera = camera_model
        detector.appearance_min_probability = float(values.get("appearance_min_probability", DEFAULT_MIN_PROBABILITY))
        combine = str(values.get("appearance_combine", DEFAULT_COMBINE))
        if combine not in COMBINE_MODES:
            raise VesselError(f"detector parameter 'appearance_combine' must be one of {' or '.join(COMBINE_MODES)}, "
                              f"got {combine!r}")
        detector.appearance_combine = combine
        detector.appearance_nested_overlap = float(values.get("appearance_nested_overlap", DEFAULT_NESTED_OVERLAP))
    return detector


def attitude_settings(values: Mapping[str, Any]) -> AttitudeSettings:
    """The ``pose.*`` parameters as the attitude estimator's settings (validated)."""
    settings = AttitudeSettings(
        source=str(values["pose.source"]), use_horizon=bool(values["pose.use_horizon"]),
        sensor_sigma_deg=float(values["pose.sensor_sigma_deg"]),
        heading_sigma_deg=float(values["pose.heading_sigma_deg"]),
        bias_drift_deg_per_s=float(values["pose.bias_drift_deg_per_s"]),
        gate_sigmas=float(values["pose.gate_sigmas"]))
    settings.validate()
    return settings


def frame_poser(values: Mapping[str, Any], camera_model) -> FramePoser:
    """The poser of each image from the parameters and the calibration (which a moving camera needs)."""
    if camera_model is None and str(values["pose.source"]) != "fixed":
        raise ModelError(f"pose.source {values['pose.source']} needs the calibration: load it with --params-file "
                         "config/aitas_camera.yaml")
    settings = attitude_settings(values)
    measure = bool(values["pose.use_horizon"]) and (settings.source != "fixed" or bool(values["publish_annotated"]))
    return FramePoser(camera_model, settings, float(values["pose.max_age_s"]), float(values["pose.wait_s"]), measure)


def load_params_file(path: str | Path | None, node_name: str = NODE_NAME) -> tuple[dict[str, Any], Any]:
    """Detector values and the ``CameraModel`` of a parameter YAML (None path: defaults and no camera).

    The detector block is the node's (``detector:``) overlaid on ``/**``'s non-camera keys; the camera is the
    ``camera:`` block (``/**`` preferred).
    """
    return load_params_files([path] if path else [], node_name)


def load_params_files(paths, node_name: str = NODE_NAME) -> tuple[dict[str, Any], Any]:
    """As :func:`load_params_file` for several files loaded in order.

    As ``--params-file A --params-file B`` would: a later file's values win, the last camera block is the calibration.
    """
    overrides: dict[str, Any] = {}
    camera = None
    for path in paths:
        if not path:
            continue
        blocks = read_params_yaml(path)
        overrides.update({k: v for k, v in flatten(blocks.get("/**") or {}).items() if k in DETECTOR_PARAMETERS})
        for name in (node_name, f"/{node_name}"):
            overrides.update(flatten(blocks.get(name) or {}))
        for params in node_blocks(blocks, node_name):
            block = camera_block(params)
            if block is not None:

                camera = CameraModel.from_params(block, where=f"{path}: camera")
                break
    return merge_values(overrides), camera
