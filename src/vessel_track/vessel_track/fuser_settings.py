"""Every setting of the fusion stage in one place, read from / written to the ``fuser`` parameter block.

The fuser node, the pipeline and the fit tools share this, so the parameter file is the single source: the
``fuser`` block of ``config/aitas.yaml`` (``config/parts/fuser.yaml``) holds the sub-blocks

    distance_model: {a, b, c, d, sigma_width_px, sigma_height_px, ...}     (distance_model.py)
    fusion: {weights_mode, anchor_offset, ..., shape_jump_ratio, cue_covariance, cue_x_std_px}  (fusion.py)
    motion: {accel_psd, initial_speed_std, max_speed, gate_chi2, max_rejections, max_gap_s}          (smoothing.py)
    selection: {confidence_percentile, join_*, switch_*, ...}                                 (selection_config.py)
    offline: {outlier_threshold_px, iterations}                                                       (pipeline)
    error_model: {kind, slope, intercept_m, ...}                                                     (error_model.py)
    water_level: {file, max_hold_s}                                        (vessel_calib.water_level, the tide)

Keys may be nested (YAML) or flattened with dots (ROS parameter names); unknown keys are rejected by name.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vessel_calib.params import node_blocks, read_params_yaml
from vessel_calib.water_level import load_water_level
from vessel_common.errors import DataError
from vessel_common.parameter_names import flatten
from vessel_track.distance_model import BoxSizeDistanceModel
from vessel_track.error_model import ErrorModel
from vessel_track.fusion import CueStatistics, FusionConfig
from vessel_track.selection_config import SelectionConfig
from vessel_track.smoothing import MotionConfig

OFFLINE_TARGETS = ("joined", "online")


@dataclass(frozen=True)
class OfflineConfig:
    """The paper's offline smoothing pass: outlier threshold in screen-y pixels and number of passes.

    adaptive_noise: choose the process noise (0.1-10 m^2/s^3) and a scale of the measurement covariances
    (0.25-2) per trajectory by maximum likelihood of its own measurements (empirical Bayes) instead of
    ``motion.accel_psd`` and the fitted cue noise.

    target: which measurements are smoothed. ``joined`` (the paper's): trajectories joined and scored over the
    whole recording, the best one. ``online``: the target the online selection chose at each frame, so the pass
    smooths what was published live instead of choosing again.

    max_gap_s: a frame without a measurement of the target is published only if the gap it lies in (between the
    target's measurements either side) is at most this long (0: no limit, every gap is bridged). Interpolating
    across a short gap is what smoothing is for; across a long one the vessel may have turned.
    """

    outlier_threshold_px: float = 5.0
    iterations: int = 5
    adaptive_noise: bool = True
    target: str = "online"
    max_gap_s: float = 34.0

    def __post_init__(self) -> None:
        """Validate."""
        if self.target not in OFFLINE_TARGETS:
            raise DataError(f"offline: target must be one of {', '.join(OFFLINE_TARGETS)}, got {self.target!r}")
        if not (np.isfinite(self.outlier_threshold_px) and self.outlier_threshold_px > 0):
            raise DataError(f"offline: outlier_threshold_px must be > 0, got {self.outlier_threshold_px!r}")
        if self.iterations < 1:
            raise DataError(f"offline: iterations must be >= 1, got {self.iterations!r}")
        if not (isinstance(self.max_gap_s, int | float) and math.isfinite(self.max_gap_s) and self.max_gap_s >= 0):
            raise DataError(f"offline: max_gap_s must be a finite number of seconds >= 0 (0: no limit), "
                            f"got {self.max_gap_s!r}")


@dataclass(frozen=True)
class WaterLevelConfig:
    """The tide: a water-level CSV (``vessel_calib.water_level``) read at each frame's stamp.

    file: '' for none (the camera's height above the water is taken as constant). With a file, the calibration
    must carry the water level it was fitted at (``camera.water_level_m``, written by ``calibrate --water-level``).
    max_hold_s: outside the file's times its first or last level is used for this long; beyond, the frame is
    fused at the calibration's level and counted as ``water_level_unknown``.
    """

    file: str = ""
    max_hold_s: float = 900.0

    def __post_init__(self) -> None:
        """Validate."""
        if not (np.isfinite(self.max_hold_s) and self.max_hold_s >= 0):
            raise DataError(f"water_level: max_hold_s must be >= 0 seconds, got {self.max_hold_s!r}")

    def load(self):
        """The ``WaterLevelTable`` of ``file`` (None without one); DataError naming the file if it is unusable."""
        return load_water_level(self.file)


#: The shipped error model: the online pipeline on the hand boxes of training videos 7-12, each video scored
#: with the calibration and fusion fitted on the others (``pipeline --leave-one-out 7-12``), line through the
#: origin, with the shipped calibration (boxes read 0.65 of the way down; 0.1016 with box centres). The paper's
#: 0.0555 is ``ErrorModel()``.
FITTED_ERROR_MODEL = ErrorModel(slope=0.0721617495, kind="origin", n_points=61,
                                source="online pipeline on hand boxes of 7-12, leave-one-video-out "
                                       "(pipeline --leave-one-out 7-12)")


#: the ``fusion`` settings that describe a detector's boxes, as they are for hand-drawn ones
#: (``FuserSettings.for_hand_boxes``; the demo passes them to the fuser node in its labels mode)
HAND_BOX_FUSION = {"anchor_offset": 0.0, "shape_jump_ratio": 0.0, "height_drop_ratio": 0.0}

FUSION_ANCHOR_MOVED = ("fuser parameters: fusion.anchor is no longer a fuser parameter: where a box stands for the "
                       "vessel belongs to the calibration it was fitted with (camera.box_anchor, written by calibrate "
                       "--box-anchor); remove fusion.anchor from the parameter file")


@dataclass(frozen=True)
class FuserSettings:
    """Everything the fusion stage needs besides the camera."""

    distance_model: BoxSizeDistanceModel = field(default_factory=BoxSizeDistanceModel)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    cue_stats: CueStatistics = field(default_factory=CueStatistics)
    motion: MotionConfig = field(default_factory=MotionConfig)
    selection: SelectionConfig = field(default_factory=SelectionConfig)
    offline: OfflineConfig = field(default_factory=OfflineConfig)
    error_model: ErrorModel = field(default_factory=lambda: FITTED_ERROR_MODEL)
    water_level: WaterLevelConfig = field(default_factory=WaterLevelConfig)

    def for_hand_boxes(self) -> FuserSettings:
        """These settings for hand-drawn boxes: read at the calibration's ``box_anchor``, no shape suspicion.

        ``fusion.anchor_offset`` describes how a detector's boxes sit on a vessel against the hand-drawn boxes the
        calibration was fitted on, ``fusion.shape_jump_ratio`` a detector box that took in spray or wake; hand-drawn
        boxes fed as detections (``--detections labels``) need neither: their shape changes when the vessel turns.
        """
        return dataclasses.replace(self, fusion=dataclasses.replace(self.fusion, **HAND_BOX_FUSION))

    def for_camera(self, camera, where: str = "the calibration") -> tuple[FuserSettings, str]:
        """These settings for ``camera``, and a note when they had to change ('' otherwise).

        A water-level file (``water_level.file``) needs a calibration fitted with it (``camera.water_level_m``);
        for one without (an older file, labels outside the file's times) the correction is dropped, and the note,
        naming ``where``, says so. The fuser node refuses such a pair instead (``TrackFuser``).
        """
        if not self.water_level.file or math.isfinite(camera.water_level_m):
            return self, ""
        note = (f"{where} has no camera.water_level_m (calibrated without --water-level): running without the tide "
                f"correction of {self.water_level.file}")
        return dataclasses.replace(self, water_level=dataclasses.replace(self.water_level, file="")), note

    def to_params(self) -> dict:
        """Nested parameter dict (the ``fuser`` block's ``ros__parameters`` minus topics)."""
        fusion = self.fusion.to_params()
        fusion.update(self.cue_stats.to_params())
        return {
            "distance_model": self.distance_model.to_params(),
            "fusion": fusion,
            "motion": dataclasses.asdict(self.motion),
            "selection": dataclasses.asdict(self.selection),
            "offline": dataclasses.asdict(self.offline),
            "error_model": self.error_model.to_params(),
            "water_level": dataclasses.asdict(self.water_level),
        }

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> FuserSettings:
        """Build from a (nested or dot-flattened) parameter mapping; other top-level keys are ignored."""
        nested = nest(params)
        defaults = cls()

        def block(name: str) -> dict:
            value = nested.get(name, {})
            if not isinstance(value, Mapping):
                raise DataError(f"fuser parameters: '{name}' must be a block of parameters, got {value!r}")
            return dict(value)

        fusion_block = block("fusion")
        if "anchor" in fusion_block:
            raise DataError(FUSION_ANCHOR_MOVED)
        cue = {k: fusion_block.pop(k) for k in ("cue_covariance", "cue_x_std_px", "cue_n_points") if k in fusion_block}
        try:
            cue_stats = CueStatistics(
                covariance=np.asarray(cue.get("cue_covariance", defaults.cue_stats.covariance.ravel()),
                                      dtype=float).reshape(3, 3),
                x_std_px=float(cue.get("cue_x_std_px", defaults.cue_stats.x_std_px)),
                n_points=int(cue.get("cue_n_points", defaults.cue_stats.n_points)))
        except (TypeError, ValueError) as error:
            raise DataError(f"fuser parameters: fusion.cue_covariance must be 9 numbers ({error})") from None
        return cls(
            distance_model=BoxSizeDistanceModel.from_params({**defaults.distance_model.to_params(),
                                                             **block("distance_model")}),
            fusion=_build(FusionConfig, fusion_block, "fusion"),
            cue_stats=cue_stats,
            motion=_build(MotionConfig, block("motion"), "motion"),
            selection=_build(SelectionConfig, block("selection"), "selection"),
            offline=_build(OfflineConfig, block("offline"), "offline"),
            error_model=ErrorModel.from_params({**defaults.error_model.to_params(), **block("error_model")}),
            water_level=_build(WaterLevelConfig, block("water_level"), "water_level"),
        )


def _build(kind, values: dict, name: str):
    known = {f.name: f for f in dataclasses.fields(kind)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise DataError(f"fuser parameters: unknown {name} parameter(s) {', '.join(unknown)}; known: "
                        f"{', '.join(sorted(known))}")
    converted = {}
    for key, value in values.items():
        default = getattr(kind(), key)
        try:
            converted[key] = type(default)(value)
        except (TypeError, ValueError):
            raise DataError(f"fuser parameters: {name}.{key} must be a {type(default).__name__}, got {value!r}") \
                from None
    return kind(**converted)


def nest(params: Mapping[str, Any]) -> dict:
    """``{"a.b": 1, "c": {"d": 2}}`` -> ``{"a": {"b": 1}, "c": {"d": 2}}``."""
    out: dict = {}
    for key, value in params.items():
        parts = str(key).split(".")
        node = out
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise DataError(f"parameters: '{key}' clashes with a value at '{part}'")
        if isinstance(value, Mapping):
            existing = node.setdefault(parts[-1], {})
            existing.update(nest(value))
        else:
            node[parts[-1]] = value
    return out


def load_fuser_settings(path: Path | None, node: str = "fuser") -> FuserSettings:
    """Settings from the ``/**`` and ``node`` blocks of a parameter YAML; defaults when ``path`` is None.

    The blocks merge parameter by parameter, as ROS merges them: a ``/**`` ``selection.switch_hold_s`` stays when
    the node's block sets another ``selection`` parameter.
    """
    if path is None:
        return FuserSettings()

    merged: dict = {}
    for block in node_blocks(read_params_yaml(path), node):
        merged.update(flatten(block))
    return FuserSettings.from_params(nest(merged))
