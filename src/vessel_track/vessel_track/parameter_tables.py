"""The parameter tables of the tracker, fuser and GPS publisher nodes (ROS-free).

Each node declares its parameters from its table (``vessel_common.node_parameters.declare_table``), the part files
``config/parts/*.yaml`` and the table of ``docs/parameters.md`` are written from them (``./vessel params render``),
and the ROS-free tools read a parameter file against them. A row whose value lives in a settings dataclass
(``TrackerConfig``, ``FuserSettings``) takes its default from the dataclass: one value in one place.
"""

from __future__ import annotations

from dataclasses import fields

from vessel_common.parameter_names import flatten
from vessel_common.parameter_table import Param, ParameterTable, standby_row, state_rows
from vessel_track.collision import AlertRule
from vessel_track.error_model import KINDS as ERROR_MODEL_KINDS
from vessel_track.fuser_settings import OFFLINE_TARGETS, FuserSettings
from vessel_track.fusion import SCREEN_SOURCES, WEIGHT_MODES
from vessel_track.selection_config import CONFIDENCE_SCORES
from vessel_track.tracker_config import ASSOCIATION_METHODS, DISTANCE_METRICS, PROCESS_NOISE_MODELS, TrackerConfig

_TRACKER_DESCRIPTIONS: dict[str, tuple[str, tuple[float, float] | None]] = {
    "measurement_std_px": ("Std of a detection's box centre, px (paper: 10 px at half resolution).", (1e-3, 1e4)),
    "measurement_std_size_frac": ("Extra centre std as a fraction of the box size (w for x, h for y).", (0.0, 10.0)),
    "process_noise_model": (f"Kalman process noise: {', '.join(PROCESS_NOISE_MODELS)} (paper = diag(0, q dt^2, "
                            "0, q dt^2); continuous_wna is the same for any frame rate).", None),
    "process_noise": ("q for x: px^2/s^3 (continuous_wna) or px^2/s^4 (discrete_wna, paper).", (0.0, 1e6)),
    "process_noise_y": ("q for y, same units as process_noise (vessels near the horizon move little in y).",
                        (0.0, 1e6)),
    "init_velocity_std_x_px_s": ("Prior std of a new track's horizontal velocity, px/s.", (0.0, 1e4)),
    "init_velocity_std_y_px_s": ("Prior std of a new track's vertical velocity, px/s.", (0.0, 1e4)),
    "association": (f"{' or '.join(ASSOCIATION_METHODS)}: optimal (Hungarian) or nearest-first (paper).", None),
    "distance_metric": (f"Association cost: {' or '.join(DISTANCE_METRICS)}.", None),
    "gate_px": ("Detections this close to a prediction are always admissible, px (paper: 80 at half res).",
                (1e-3, 1e5)),
    "gate_sigmas": ("Beyond gate_px, admissible up to this Mahalanobis distance of the prediction.", (1e-3, 100.0)),
    "max_gate_px": ("No detection farther than this from a prediction is admissible, px.", (1e-3, 1e5)),
    "clutter_density_per_mpx": ("Expected false detections per frame per megapixel: a detection must be likelier "
                                "from the track than from clutter (0 disables).", (0.0, 1e6)),
    "size_weight": ("Weight of the box-size similarity in the association cost (0 disables).", (0.0, 1e3)),
    "confidence_weight": ("Weight of the confidence-agreement term in the association cost: a track that followed "
                          "a likely vessel of interest does not take an unlikely box, nor the other way round "
                          "(0 disables).", (0.0, 1e3)),
    "confidence_memory": ("Updates whose confidences make a track's side of the confidence-agreement term.",
                          None),
    "size_log_std": ("Expected change of ln(width), ln(height) between associated boxes.", (1e-3, 10.0)),
    "height_log_std": ("Expected change of ln(height) alone between boxes close in time (0: size_log_std; else at "
                       "least 0.001): the height follows the range, the width also the heading.", (0.0, 10.0)),
    "height_log_std_rate": ("Growth of the height's expected change per px of box height per s since the track's "
                            "last box, in quadrature (0: constant): near boats change size fast, far ones "
                            "slowly.", (0.0, 1.0)),
    "max_size_ratio": ("Boxes differing from the track's size by more than this factor are not associated "
                       "(0 disables).", (0.0, 1e3)),
    "min_hits": ("Detections before a track is CONFIRMED.", None),
    "max_coast_s": ("A track not updated for longer than this is LOST (paper: 10 frames), s.", (1e-3, 1e6)),
    "tentative_max_coast_s": ("A TENTATIVE track not updated for longer than this is dropped, s.", (1e-3, 1e6)),
    "tentative_max_misses": ("A TENTATIVE track missing more consecutive frames than this is dropped.", None),
    "max_tracks": ("At most this many live tracks; more detections are dropped and counted.", None),
    "duplicate_iou": ("An unassociated box overlapping an associated one or a track by more IoU than this is a "
                      "duplicate and starts no track (0 disables).", (0.0, 1.0)),
    "min_score": ("Detections scoring below this are ignored.", (0.0, 1.0)),
    "min_box_size_px": ("Boxes narrower or lower than this are invalid, px.", (1e-6, 1e4)),
    "backwards_reset_s": ("Stamps going back this much or more reset the tracker (replay restarted); smaller "
                          "steps back drop the frame, s.", (0.0, 1e9)),
    "history_length": ("Updates kept per track (stamps, boxes, confidences).", None),
    "id_prefix": ("Track ids are <id_prefix><n>.", None),
}

_TRACKER_INT_RANGES = {"min_hits": (1, 1000), "tentative_max_misses": (0, 1000), "max_tracks": (1, 100000),
               "history_length": (1, 10_000_000), "confidence_memory": (1, 1000)}

_TRACKER_CHOICES = {"process_noise_model": PROCESS_NOISE_MODELS, "association": ASSOCIATION_METHODS,
                    "distance_metric": DISTANCE_METRICS}
_TRACKER_LIVE = frozenset(f.name for f in fields(TrackerConfig)) - {"history_length", "id_prefix"}
"""Tracker settings a running tracker takes from its next frame on (the others shape the tracks it holds)."""

EVERY_CLASS = "*"
"""The ``classes`` entry that tracks every class (a parameter needs a value: ``ros2 param dump`` answers nothing
for a node with an unset one)."""


def settings_rows(defaults: dict, descriptions: dict, choices: dict, live) -> tuple[Param, ...]:
    """Rows whose defaults are a settings dataclass's (flat names): one value in one place.

    ``descriptions``: name -> (description, range); ``live(name)``: whether a running node applies a change.
    """
    rows = []
    for name, default in defaults.items():
        description, value_range = descriptions[name]
        if isinstance(default, (list, tuple)):
            default = [float(v) for v in default]
        numeric = isinstance(default, (int, float, list)) and not isinstance(default, bool)
        rows.append(Param(name, default, description, value_range=value_range if numeric else None,
                          choices=choices.get(name, ()), live=live(name)))
    return tuple(rows)


def _tracker_config_rows() -> tuple[Param, ...]:
    descriptions = {name: (text, _TRACKER_INT_RANGES.get(name, bounds))
                    for name, (text, bounds) in _TRACKER_DESCRIPTIONS.items()}
    return settings_rows(TrackerConfig().to_dict(), descriptions, _TRACKER_CHOICES, _TRACKER_LIVE.__contains__)


TRACKER_PARAMETERS = ParameterTable("tracker", "Tracker node (vessel_track tracker): detections -> screen-space "
                                    "tracks, one per vessel.", (
    Param("input_topic", "vessel/detections", "Detections of each image (vessel_msgs/Detection2DArray)."),
    Param("output_topic", "vessel/tracks/screen", "Screen-space tracks of each image (vessel_msgs/VesselTrackArray)."),
    Param("qos_depth", 10, "Queue depth of the reliable input and output.", value_range=(1, 1000)),
    *state_rows(),
    standby_row(),
    Param("classes", [EVERY_CLASS], "Class ids (hypothesis.class_id) to track, e.g. ['boat']; ['*']: every class the "
          "detector publishes.", live=True),
    Param("confidence_class", "", "Hypothesis class_id whose score is a track's confidence when a detection has it "
          "(the detector's target_class, e.g. vessel_of_interest); '' : the best accepted hypothesis.", live=True),
    *_tracker_config_rows(),
))

COVARIANCE_MODES = ("sum", "filter", "error_model", "max")
"""How the GPS publisher's horizontal covariance is made of the filter's and the error model's."""

GPS_PUBLISHER_PARAMETERS = ParameterTable("gps_publisher", "GPS publisher node (vessel_track gps_publisher): the "
                                          "vessel of interest as sensor_msgs/NavSatFix.", (
    Param("input_topic", "vessel/tracks", "World tracks from the fuser (VesselTrackArray)."),
    Param("fix_topic", "vessel/fix", "NavSatFix of the vessel of interest."),
    Param("fixes_topic", "vessel/fixes", "Every vessel with a position (VesselTrackArray); empty string: off."),
    Param("frame_id", "vessel_of_interest", "frame_id of the NavSatFix (the tracked vessel).", live=True),
    Param("max_coast_s", 2.0, "A target not seen by the detector for longer than this is published as NO_FIX, s. "
          "The challenge frames are 4 s apart, so no coasting fix there; live, a coasting target is reported for up "
          "to 2 s.", value_range=(0.0, 1.0e6), live=True),
    Param("covariance_mode", "sum", "Horizontal covariance: sum (filter + error model), filter, error_model or max.",
          choices=COVARIANCE_MODES, live=True),
    Param("covariance_type", "known", "position_covariance_type: known or approximated.",
          choices=("known", "approximated"), live=True),
    Param("altitude_m", float("nan"), "Altitude above the WGS-84 ellipsoid to report (.nan: unknown).", live=True),
    Param("altitude_variance_m2", 1.0e4, "Variance of the altitude in the covariance, m^2.",
          value_range=(0.0, 1e12), live=True),
    Param("publish_no_fix", True, "Publish STATUS_NO_FIX messages for frames without a target.", live=True),
    Param("qos_depth", 10, "Queue depth of the reliable topics.", value_range=(1, 1000)),
    standby_row(),
))

_INF = 1.0e12

_FUSER_DESCRIPTIONS: dict[str, tuple[str, tuple[float, float] | None]] = {
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


_FUSER_CHOICES = {"fusion.weights_mode": WEIGHT_MODES, "fusion.screen_source": SCREEN_SOURCES,
                  "selection.confidence_score": CONFIDENCE_SCORES, "offline.target": OFFLINE_TARGETS,
                  "error_model.kind": ERROR_MODEL_KINDS}
_FUSER_LIVE_BLOCKS = ("distance_model.", "fusion.", "error_model.")
"""Fuser settings a running fuser takes from its next frame on; the others shape the filters and selection it
holds, or the offline pass, and need a restart."""


def _fuser_settings_rows() -> tuple[Param, ...]:
    return settings_rows(flatten(FuserSettings().to_params()), _FUSER_DESCRIPTIONS, _FUSER_CHOICES,
                         lambda name: name.startswith(_FUSER_LIVE_BLOCKS))


def _collision_rows() -> tuple[Param, ...]:
    """The own ship and the collision alert (``vessel_track.collision``); the alert's defaults are ``AlertRule``'s."""
    rule = AlertRule()
    return (
        Param("collision_alerts_topic", "vessel/collision_alerts", "Tracks in collision alert (VesselTrackArray), "
              "published only for frames with at least one."),
        Param("own_ship_fix_topic", "", "sensor_msgs/NavSatFix of the camera's platform (e.g. /own_ship/fix), taken "
              "as the camera's position (an antenna offset from camera_link is not corrected). '': the camera is "
              "fixed at the calibration's camera_lat/lon, the own ship at rest there."),
        Param("own_ship_qos", "reliable", "QoS of the own-ship fix subscription: reliable (loses nothing) or "
              "sensor_data (best effort: for a GPS driver that publishes best effort).",
              choices=("reliable", "sensor_data")),
        Param("own_ship_max_age_s", 0.5, "A frame whose nearest own-ship fix is further than this from its stamp gets "
              "no CPA (has_cpa false, counted as own_ship_stale), s.", value_range=(0.0, 1.0e6)),
        Param("own_ship_velocity_window_s", 5.0, "The own ship's velocity is the least-squares slope of its fixes "
              "over this long, s.", value_range=(0.01, 3600.0)),
        Param("collision.cpa_alert_m", rule.cpa_alert_m, "A track is in alert when its CPA is under this (less "
              "cpa_sigma_k of its deviations) with 0 <= TCPA <= tcpa_alert_s, m.", value_range=(0.0, 1.0e6),
              live=True),
        Param("collision.tcpa_alert_s", rule.tcpa_alert_s, "How far ahead a CPA may lie and still alert, s.",
              value_range=(0.0, 1.0e6), live=True),
        Param("collision.cpa_sigma_k", rule.cpa_sigma_k, "Conservative alert: the CPA less this many of its standard "
              "deviations is compared with cpa_alert_m (0: the CPA itself).", value_range=(0.0, 10.0), live=True),
    )


FUSER_PARAMETERS = ParameterTable("fuser", "Fuser node (vessel_track fuser): screen tracks -> sea-plane tracks, "
                                  "the vessel of interest picked.", (
    Param("input_topic", "vessel/tracks/screen", "Screen-space tracks from the tracker (VesselTrackArray)."),
    Param("output_topic", "vessel/tracks", "Tracks with world position, covariance, lat/lon (VesselTrackArray)."),
    Param("qos_depth", 10, "Queue depth of the reliable input and output.", value_range=(1, 1000)),
    *state_rows(),
    standby_row(),
    *_collision_rows(),
    *_fuser_settings_rows(),
), notes=("distance_model and fusion.cue_* are written by `./vessel fit distance-model`, error_model by "
          "`./vessel fit error-model`.",))
