"""ROS parameter declarations of the fusion stage, and a start-up check of ``--params-file`` arguments.

Imports rclpy only inside the functions that need a node, so the table of parameters (names, defaults,
descriptions, ranges) can be tested and turned into ``config/parts/fuser.yaml`` without ROS.
"""
from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from vessel_common.command_line import command_line_tool
from vessel_common.errors import CalibrationError, DataError
from vessel_common.parameter_names import flatten
from vessel_common.state_file import STANDBY_DESCRIPTION, STATE_PARAMETERS
from vessel_track.fuser_settings import FUSION_ANCHOR_MOVED, FuserSettings

_INF = 1.0e12

#: name -> (description, float range or None). Defaults come from ``FuserSettings()``.
FUSER_PARAMETERS: dict[str, tuple[str, tuple[float, float] | None]] = {
    "distance_model.a": ("Box width = a / depth + b: a in px x m (fitted to hand boxes).", (1e-6, _INF)),
    "distance_model.b": ("Box width = a / depth + b: b in px.", (-1e4, 1e4)),
    "distance_model.c": ("Box height = c / depth + d: c in px x m.", (1e-6, _INF)),
    "distance_model.d": ("Box height = c / depth + d: d in px.", (-1e4, 1e4)),
    "distance_model.sigma_width_px": ("Robust std of the box-width residuals of the fit, px.", (1e-6, 1e4)),
    "distance_model.sigma_height_px": ("Robust std of the box-height residuals of the fit, px.", (1e-6, 1e4)),
    "distance_model.n_points": ("Boxes the distance model was fitted to (informational).", None),
    "distance_model.source": ("Where the distance model comes from (informational).", None),
    "fusion.weights_mode": ("fitted (variance-minimising from cue_covariance), paper (0.5/0.25/0.25) or "
                            "position_only.", None),
    "fusion.anchor_offset": ("Box heights below the calibration's camera.box_anchor at which a box is read (0: as "
                             "the calibration; for detector boxes that sit differently than hand-drawn ones).",
                             (-1.0, 1.0)),
    "fusion.max_range_m": ("Positions further than this from the camera are rejected, m.", (1.0, 1e6)),
    "fusion.clip_m": ("Positions are clipped to +-clip_m east and north (paper: 2000), m.", (1.0, 1e6)),
    "fusion.min_depth_m": ("Points closer than this depth in front of the camera are rejected, m.", (1e-3, 1e4)),
    "fusion.screen_source": ("Box the fuser measures: measured (the detection associated in this image, "
                             "VesselTrack.detection_bbox) or filtered (the tracker's filtered bbox).", None),
    "fusion.shape_jump_ratio": ("A box taller for its width than this many times its track's median aspect (last "
                                "5 boxes) is suspect (spray or wake below the hull): its position covariance is "
                                "multiplied by shape_jump_variance_factor. 0: off.", (0.0, 100.0)),
    "fusion.shape_jump_variance_factor": ("Covariance multiplier of a box whose aspect jumped (or height "
                                          "dropped).", (1.0, 1e6)),
    "fusion.height_drop_ratio": ("A box less than this share as tall as its track's last 3 boxes (median) is "
                                 "suspect (the detector boxed only the vessel's cabin or console, whose bottom is "
                                 "not the waterline): its position covariance is multiplied by "
                                 "shape_jump_variance_factor. 0: off.", (0.0, 0.999)),
    "fusion.cue_covariance": ("3x3 covariance (row-major) of the ideal-y errors of the position, width and "
                              "height cues, px^2 (fitted).", None),
    "fusion.cue_x_std_px": ("Std of the box reference point's x, ideal px (fitted).", (1e-6, 1e4)),
    "fusion.cue_n_points": ("Boxes the cue statistics were measured on (informational).", None),
    "water_level.file": ("Water-level CSV (utc or utc_s, level_m; a NOAA tide prediction download works): the "
                         "camera's height above the sea changes with the tide, ranges are corrected at each "
                         "frame's stamp. Needs a calibration with camera.water_level_m (calibrate --water-level). "
                         "'': none.", None),
    "water_level.max_hold_s": ("Outside the file's times its end level is held this long, s; beyond, no "
                               "correction (counted as water_level_unknown).", (0.0, 1e9)),
    "motion.accel_psd": ("World Kalman filter: acceleration noise spectral density, m^2/s^3.", (1e-9, 1e6)),
    "motion.initial_speed_std": ("Prior std of each velocity component of a new track, m/s.", (1e-6, 1e3)),
    "motion.max_speed": ("Fitted speeds above this are clipped, m/s.", (1e-3, 1e3)),
    "motion.gate_chi2": ("Measurements with a larger squared Mahalanobis distance are rejected.", (1e-3, 1e6)),
    "motion.max_rejections": ("Consecutive rejections after which a track's filter restarts.", None),
    "motion.max_gap_s": ("A gap between frames longer than this restarts the filters, s.", (1e-3, 1e9)),
    "motion.manoeuvre_factor": ("A measurement outside the gate is retried with the process noise times this "
                                "(hard turn or acceleration) before it counts as an outlier; 1 disables.",
                                (1.0, 1e6)),
    "selection.confidence_percentile": ("Percentile of detector confidences in the trajectory score (paper 80; 50 "
                                        "chosen with the appearance cue).",
                                        (0.0, 100.0)),
    "selection.min_step_m": ("Path steps shorter than this are not counted, m.", (0.0, 1e6)),
    "selection.path_noise_sigmas": ("A path step counts once it exceeds this many standard deviations of its "
                                    "noise (0: the paper's plain path length).", (0.0, 100.0)),
    "selection.join_max_gap_s": ("Longest gap over which a new track continues an ended one, s.", (0.0, 1e6)),
    "selection.join_max_overlap_s": ("Pieces may overlap this long in time and still be joined, s.", (0.0, 1e6)),
    "selection.join_gate_m": ("Join gate: constant part, m.", (0.0, 1e6)),
    "selection.join_gate_range_frac": ("Join gate: share of the range from the camera.", (0.0, 100.0)),
    "selection.join_gate_speed_mps": ("Join gate: growth per second of gap, m/s.", (0.0, 1e3)),
    "selection.max_speed_mps": ("A join implying a faster motion is refused, m/s.", (1e-3, 1e3)),
    "selection.switch_ratio": ("A challenger must score above current x ratio + margin to take over.", (1.0, 1e3)),
    "selection.switch_margin": ("See switch_ratio.", (0.0, 1e6)),
    "selection.switch_hold_s": ("... for this long, s.", (0.0, 1e6)),
    "selection.reacquire_fraction": ("After the target's track ended, another track needs this share of its score "
                                     "to take over (for reacquire_window_s).", (0.0, 1.0)),
    "selection.size_consistency": ("Weight the trajectory score by the share of boxes whose size agrees with "
                                   "their position for a vessel of the fitted size.", None),
    "selection.history_length": ("Confidences kept per track for the percentile.", None),
    "selection.confidence_score": ("How confidences enter the trajectory score: percentile (the paper's) or "
                                   "evidence (sum of their log-odds; for appearance probabilities).", None),
    "selection.evidence_clip": ("Bound of one confidence's log-odds in the evidence score.", (1e-3, 100.0)),
    "selection.reacquire_window_s": ("For this long after the target's track ended, another track needs "
                                     "reacquire_fraction of its score to take over, s.", (0.0, 1e9)),
    "selection.positive_evidence_only": ("With the evidence score, only a track whose evidence is positive (more "
                                         "likely the vessel of interest than not) may be the target.", None),
    "selection.recent_evidence_s": ("With the evidence score, a track whose confidences of the last this many "
                                    "seconds sum to non-positive log-odds may not be the target (0: off), s.",
                                    (0.0, 1e9)),
    "selection.reacquire_recent_evidence": ("With recent_evidence_s, while there is no target a track whose "
                                            "confidences of that window sum to at least this many log-odds becomes "
                                            "the target, whatever its history (0: off).", (0.0, 1e9)),
    "selection.reacquire_waits_for_dropped_track": ("With recent_evidence_s, while the track dropped from the role "
                                                    "for its recent boxes still runs, only a track carrying the lost "
                                                    "target's history may take the role (NO_FIX meanwhile).", None),
    "selection.appearance_joins": ("With the evidence score, an ended track's history is continued only by a "
                                   "track whose first box looks the same way (vessel of interest or not).", None),
    "selection.evidence_half_life_s": ("With the evidence score, each confidence's log-odds counts "
                                       "0.5^(age / half-life) (0: no forgetting), s.", (0.0, 1e9)),
    "selection.path_log_floor": ("Lower bound of the path factor log(max(l, 1)) (paper 0: tracks that have not "
                                 "moved yet all score 0; 1 lets their confidences rank them).", (0.0, 100.0)),
    "offline.outlier_threshold_px": ("Offline smoothing: screen-y outlier threshold, px (paper 5).", (1e-3, 1e4)),
    "offline.iterations": ("Offline smoothing passes (paper 5).", None),
    "offline.adaptive_noise": ("Offline: process noise and measurement-noise scale per trajectory by maximum "
                               "likelihood of its own measurements.", None),
    "offline.target": ("Offline: smooth the best trajectory joined over the recording (joined, the paper's) or the "
                       "target the online selection chose at each frame (online).", None),
    "offline.max_gap_s": ("Offline: a frame without a measurement of the target is published only if its gap "
                          "between measurements is at most this long (0: no limit), s.", (0.0, 1e9)),
    "error_model.kind": ("origin, affine or quantile (how the error model was fitted).", None),
    "error_model.slope": ("Expected error per metre of distance (paper 0.0555).", (0.0, 100.0)),
    "error_model.intercept_m": ("Expected error at zero distance, m.", (0.0, 1e6)),
    "error_model.quantile": ("Quantile of a quantile fit (informational).", (0.0, 1.0)),
    "error_model.n_points": ("Scored predictions the error model was fitted to (informational).", None),
    "error_model.source": ("Where the error model comes from (informational).", None),
}


def fuser_parameter_defaults() -> dict:
    """Flattened default values of every fuser setting."""
    return flatten(FuserSettings().to_params())


def declare_fuser_settings(node) -> FuserSettings:
    """Declare every fusion parameter on ``node`` (with descriptors) and build the settings from them."""
    from vessel_common.node_support import declare_parameter

    if "fusion.anchor" in getattr(node, "_parameter_overrides", {}):  # rclpy keeps undeclared overrides there
        raise DataError(FUSION_ANCHOR_MOVED)  # a file from before camera.box_anchor: say so rather than ignore it
    values = {}
    for name, default in fuser_parameter_defaults().items():
        description, value_range = FUSER_PARAMETERS[name]
        if isinstance(default, list):
            default = [float(v) for v in default]
        float_range = value_range if isinstance(default, float) and value_range is not None else None
        try:
            values[name] = declare_parameter(node, name, default, description, float_range=float_range)
        except DataError:
            raise  # declare_parameter's own one-line report, complete as it is
        except Exception as error:  # rclpy's type/range exceptions: report them as a configuration problem
            raise DataError(f"parameter {name}: {error} (default {default!r}); fix the parameter file") from None
    return FuserSettings.from_params(values)


def params_file_problem(argv: Sequence[str] | None) -> str | None:
    """Why a ``--params-file`` argument cannot be used (missing, unreadable, not YAML), or None.

    rcl itself would fail on such a file with a traceback; the nodes check first and exit with one line.
    """
    import yaml

    args = list(sys.argv if argv is None else argv)
    for i, arg in enumerate(args):
        if arg != "--params-file":
            continue
        if i + 1 >= len(args):
            return "--params-file needs a file name"
        path = Path(args[i + 1])
        if not path.is_file():
            return f"parameter file {path} does not exist; give the calibration/parameter YAML written by " \
                   f"`calibrate` (e.g. config/aitas.yaml)"
        try:
            document = yaml.safe_load(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError) as error:
            return f"cannot read parameter file {path}: {error}"
        except yaml.YAMLError as error:
            return f"parameter file {path} is not valid YAML ({str(error).splitlines()[0]}); fix or regenerate it"
        if not isinstance(document, dict):
            return f"parameter file {path} is not a ROS parameter file (expected '/**: ros__parameters: ...')"
    return None


def main_with_checks(node_class, argv: Sequence[str] | None = None, preload: Sequence[str] = ()) -> int:
    """Check ``--params-file`` arguments, then run the node with ``vessel_common.node_support.run_node``."""
    from vessel_common.node_support import run_node

    args = list(sys.argv if argv is None else argv)
    problem = params_file_problem(args)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    try:
        return run_node(node_class, args, preload=preload)
    except CalibrationError as error:  # raised before the node exists (e.g. by rcl argument parsing)
        print(f"error: {error}", file=sys.stderr)
        return 2


FUSER_TOPICS = {
    "input_topic": ("/vessel/tracks/screen", "Screen-space tracks from the tracker (VesselTrackArray)."),
    "output_topic": ("/vessel/tracks", "Tracks with world position, covariance, lat/lon (VesselTrackArray)."),
    "qos_depth": (10, "Queue depth of the reliable input and output."),
}

MAX_COAST_RANGE_S = (0.0, 1.0e6)
"""The values the gps_publisher's ``max_coast_s`` may take, s."""

GPS_PUBLISHER_PARAMETERS = {
    "input_topic": ("/vessel/tracks", "World tracks from the fuser (VesselTrackArray)."),
    "fix_topic": ("/vessel/fix", "NavSatFix of the vessel of interest."),
    "fixes_topic": ("/vessel/fixes", "Every vessel with a position (VesselTrackArray); empty string: off."),
    "frame_id": ("vessel_of_interest", "frame_id of the NavSatFix (the tracked vessel)."),
    "max_coast_s": (12.0, "A target not seen by the detector for longer than this is published as NO_FIX, s."),
    "covariance_mode": ("sum", "Horizontal covariance: sum (filter + error model), filter, error_model or max."),
    "covariance_type": ("known", "position_covariance_type: known or approximated."),
    "altitude_m": (float("nan"), "Altitude above the WGS-84 ellipsoid to report (.nan: unknown)."),
    "altitude_variance_m2": (1.0e4, "Variance of the altitude in the covariance, m^2."),
    "publish_no_fix": (True, "Publish STATUS_NO_FIX messages for frames without a target."),
    "qos_depth": (10, "Queue depth of the reliable topics."),
}


def _yaml_value(value) -> str:
    """``vessel_calib.params.yaml_value_text`` with floats rounded to 10 decimals (readable part files)."""
    import math

    from vessel_calib.params import yaml_value_text

    def rounded(v):
        if isinstance(v, list):
            return [rounded(x) for x in v]
        return round(v, 10) if isinstance(v, float) and math.isfinite(v) else v

    return yaml_value_text(rounded(value))


def render_fuser_yaml(settings: FuserSettings) -> str:
    """``config/parts/fuser.yaml``: the fuser block with every parameter and its description as a comment."""
    lines = ["# Fuser node (vessel_track fuser): screen tracks -> sea-plane tracks. Written by",
             "# `./vessel params render`; distance_model/fusion.cue_* from",
             "# `./vessel fit distance-model`, error_model from",
             "# `./vessel fit error-model`.",
             "fuser:", "  ros__parameters:"]
    for name, (default, description) in FUSER_TOPICS.items():
        lines.append(f"    {name}: {_yaml_value(default)}  # {description}")
    for name, (default, description, _) in STATE_PARAMETERS.items():
        lines.append(f"    {name}: {_yaml_value(default)}  # {description}")
    lines.append(f"    standby: false  # {STANDBY_DESCRIPTION}")
    nested = settings.to_params()
    for block, values in nested.items():
        lines.append(f"    {block}:")
        for key, value in values.items():
            description = FUSER_PARAMETERS[f"{block}.{key}"][0]
            lines.append(f"      {key}: {_yaml_value(value)}  # {description}")
    return "\n".join(lines) + "\n"


def render_gps_publisher_yaml() -> str:
    """``config/parts/gps_publisher.yaml`` with every parameter and its description."""
    lines = ["# GPS publisher node (vessel_track gps_publisher): the vessel of interest as sensor_msgs/NavSatFix.",
             "gps_publisher:", "  ros__parameters:"]
    for name, (default, description) in GPS_PUBLISHER_PARAMETERS.items():
        lines.append(f"    {name}: {_yaml_value(default)}  # {description}")
    lines.append(f"    standby: false  # {STANDBY_DESCRIPTION}")
    return "\n".join(lines) + "\n"


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """``render --params FILE --out config/parts/``: write the commented fuser and gps_publisher part files."""
    import argparse

    from vessel_calib.params import atomic_write_text
    from vessel_track.fuser_settings import load_fuser_settings

    parser = argparse.ArgumentParser(prog="./vessel params")
    sub = parser.add_subparsers(dest="command", required=True)
    render = sub.add_parser("render", help="write config/parts/fuser.yaml and gps_publisher.yaml")
    render.add_argument("--params", type=Path, default=None, help="parameter YAML whose fuser block to use "
                                                                  "(default: the built-in defaults)")
    render.add_argument("--out", type=Path, required=True, help="folder for fuser.yaml and gps_publisher.yaml")
    args = parser.parse_args(argv)
    settings = load_fuser_settings(args.params)
    atomic_write_text(args.out / "fuser.yaml", render_fuser_yaml(settings))
    atomic_write_text(args.out / "gps_publisher.yaml", render_gps_publisher_yaml())
    print(f"written: {args.out / 'fuser.yaml'}, {args.out / 'gps_publisher.yaml'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
