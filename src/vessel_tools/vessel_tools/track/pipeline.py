"""The whole post-processing chain without ROS: detections -> tracker -> fusion -> selection -> positions.

    ./vessel pipeline --data DIR --videos 13-17 --detections labels|FILE.csv --out DIR
        [--mode online|offline] [--calib FILE.yaml] [--params FILE.yaml] [--appearance MODEL.npz] [--no-eval]

writes ``predictions.csv`` (``video,t_utc_s,lat,lon``: the vessel of interest), ``tracks.csv`` (every track,
every frame; both ``vessel_tools.track.pipeline_results``), ``counts.json`` (per video: the tracker's, fuser's and
selection's counters: joins, switches, identity changes, outliers, rejected boxes) and then scores them
(``vessel_tools.track.evaluation``: ``summary.json``, ``scores.csv``, plots).

Detections: ``labels`` = the hand-labelled boxes of the vessel of interest (primary pass, score 1.0), one
frame per labelled frame; ``FILE.csv`` = the detector's output, columns ``video,frame,x1,y1,x2,y2,score,class_id``
(full-resolution pixels), where every frame of ``frames.csv`` of the chosen videos is a frame of the run
(frames without a row had no detection). ``--appearance config/appearance_aitas.npz`` rescores detector output
with the appearance cue (``vessel_tools.track.appearance``: the probability of being the vessel of interest replaces the
score, boxes below probability 0.5 dropped), as the detector node does.

Modes:

* ``online``: exactly what the nodes publish frame by frame: ``MultiTargetTracker`` -> ``TrackFuser`` (fusion,
  world Kalman filter per track, online target selection with hysteresis); a prediction for every frame where
  the target has a position (a coasting target for at most ``--max-coast`` seconds).
* ``offline``: the same tracks, then the paper's recorded-data pass: trajectories joined and scored over the
  whole video, the best one smoothed (Kalman + RTS with outlier masking, 5 px / 5 passes) and predicted at
  every frame of its time span.

Each video is a separate run (its own tracker), as each is a separate recording.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vessel_calib import geodesy
from vessel_calib.params import atomic_write_text
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_common.paths import parse_videos
from vessel_tools.calib.calibration import calibrate_from_labels
from vessel_tools.track import appearance
from vessel_tools.track.distance_model_fit import cross_validated_cue_statistics, fit_distance_model, training_pairs
from vessel_tools.track.evaluation import evaluate, format_table
from vessel_tools.track.offline_data import (
    DetectionFrame,
    csv_detections,
    default_params_path,
    label_detections,
    load_camera,
    open_dataset,
)
from vessel_tools.track.pipeline_results import (
    Prediction,
    TrackRow,
    VideoResult,
    write_predictions_csv,
    write_target_measurement_csvs,
    write_tracks_csv,
)
from vessel_track.fuser_settings import FuserSettings, load_fuser_settings
from vessel_track.fusion import SCREEN_SOURCES
from vessel_track.offline_selection import Trajectory, select_target
from vessel_track.parameter_tables import GPS_PUBLISHER_PARAMETERS
from vessel_track.smoothing import most_likely_noise, rts_smooth, smooth_with_outlier_masking
from vessel_track.track_fuser import ScreenTrack, TrackFuser
from vessel_track.tracker import MultiTargetTracker
from vessel_track.tracker_config import TrackerConfig, load_tracker_config, node_values

MODES = ("online", "offline")


def screen_track_of(state, source: str = "measured") -> ScreenTrack:
    """A tracker ``TrackState`` as the fuser sees it (``fuser_node.screen_track_from_msg`` does the same).

    ``measured``: the raw associated detection when there is one (``VesselTrack.detection_bbox``), else the
    filtered box; ``filtered``: the tracker's filtered box (``VesselTrack.bbox``).
    """
    updated = state.measured_center is not None
    if source == "measured" and updated:
        center, size = np.asarray(state.measured_center, float), np.asarray(state.measured_size, float)
    else:
        center, size = np.asarray(state.center, float), np.asarray(state.size, float)
    return ScreenTrack(track_id=state.track_id, status=int(state.status), center=center, size=size,
                       confidence=float(state.confidence), updated=updated,
                       detection_count=int(state.detection_count), first_seen=float(state.first_seen),
                       last_seen=float(state.last_seen), center_cov=np.asarray(state.center_cov, float),
                       velocity_px=np.asarray(state.velocity, float))


@dataclass
class PipelineConfig:
    """How to run: mode, which screen box the fuser sees, how long a coasting target is still reported."""

    mode: str = "online"
    screen_source: str | None = None
    """``measured`` (the associated detection) or ``filtered`` (the tracker's box); None: the fuser parameter
    ``fusion.screen_source`` of ``settings``, which is what the fuser node uses."""
    max_coast_s: float = 12.0
    tracker: object = None   # TrackerConfig (the command line: the parameter file's); None: the tracker's defaults
    settings: FuserSettings = field(default_factory=FuserSettings)
    water_level: object = None  # WaterLevelTable; None: that of settings.water_level.file (if any)

    def __post_init__(self) -> None:
        """Validate; load the water-level file the settings name."""
        if self.water_level is None and self.settings.water_level.file:
            self.water_level = self.settings.water_level.load()
        if self.mode not in MODES:
            raise DataError(f"pipeline: mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.screen_source is None:
            self.screen_source = self.settings.fusion.screen_source
        if self.screen_source not in SCREEN_SOURCES:
            raise DataError(f"pipeline: screen_source must be one of {', '.join(SCREEN_SOURCES)}")


def run_video(frames: list[DetectionFrame], camera, config: PipelineConfig) -> VideoResult:
    """Run one video's frames (sorted by stamp here) through tracker, fuser and selection."""
    if not frames:
        raise DataError("pipeline: no frames to run")
    frames = sorted(frames, key=lambda f: f.stamp)
    tracker = MultiTargetTracker(config.tracker if config.tracker is not None else TrackerConfig())

    def screen_frames():
        for frame in frames:
            states = tracker.update(frame.stamp, frame.boxes, frame.scores)
            yield frame.frame, frame.stamp, [screen_track_of(st, config.screen_source) for st in states]

    result = run_screen_tracks(frames[0].video, screen_frames(), camera, config)
    result.counts.update({f"tracker.{k}": v for k, v in tracker.counters.as_dict().items()})
    return result


def run_screen_tracks(video: int, screen_frames, camera, config: PipelineConfig) -> VideoResult:
    """Fuse, select (and in offline mode smooth) a sequence of ``(frame, stamp, [ScreenTrack])`` in stamp order.

    The part of the chain after the tracker: what the fuser node does online, plus the offline pass. Use it on
    screen tracks recorded from ``/vessel/tracks/screen`` (``fuser_node.screen_track_from_msg``) to get the
    offline smoothing of a recorded run.
    """
    s = config.settings
    fuser = TrackFuser(camera, s.distance_model, s.fusion, s.cue_stats, s.motion, s.selection, s.error_model,
                       water_level=config.water_level, water_level_max_hold_s=s.water_level.max_hold_s)
    result = VideoResult(video)
    stamps: list[float] = []
    for frame, stamp, screen_tracks in screen_frames:
        stamps.append(stamp)
        world = fuser.update(stamp, screen_tracks)
        for wt in world:
            result.track_rows.append(TrackRow(video, frame, stamp, wt))
        target = next((wt for wt in world if wt.is_target and wt.has_world), None)
        if target is not None and stamp - target.screen.last_seen <= config.max_coast_s:
            result.predictions.append(Prediction(video, stamp, target.latitude, target.longitude,
                                                 float(target.position[0]), float(target.position[1]),
                                                 target.screen.track_id, target.screen.updated))
    result.counts = {**{f"fuser.{k}": v for k, v in fuser.counts.items()},
                     "selection.switches": fuser.selector.switches, "selection.joins": fuser.selector.joins,
                     "selection.identity_changes": fuser.selector.identity_changes,
                     "selection.reacquisitions": fuser.selector.reacquisitions}
    if config.mode == "offline":
        _offline_pass(result, stamps, camera, config)
    return result


def trajectories_of(rows: list[TrackRow], motion=None) -> tuple[list[Trajectory], dict[str, dict]]:
    """Per track: its trajectory and its measurements.

    The trajectory holds the positions at measured frames for scoring and joining: RTS-smoothed with ``motion``
    when given (path lengths of raw or causally filtered positions are inflated by their noise), else the online
    filter's; the measurements hold the fused position, covariance and screen point (for the smoother).
    """
    per_track: dict[str, dict] = defaultdict(lambda: defaultdict(list))
    for row in rows:
        wt = row.world
        if wt.measured_position is None or not wt.has_world:
            continue
        data = per_track[wt.screen.track_id]
        data["stamps"].append(row.stamp)
        data["filtered"].append(wt.position)
        data["filtered_cov"].append(wt.position_covariance)
        data["confidences"].append(wt.screen.confidence)
        data["measured"].append(wt.measured_position)
        data["covariance"].append(wt.measured_covariance)
        data["screen"].append(wt.measured_screen)
    trajectories = []
    for tid, d in per_track.items():
        positions, covariances = np.array(d["filtered"]), np.array(d["filtered_cov"])
        if motion is not None and len(d["stamps"]) >= 3:
            smoothed = rts_smooth(np.array(d["stamps"]), np.array(d["measured"]), np.array(d["covariance"]), motion)
            positions, covariances = smoothed.positions, smoothed.covariances[:, :2, :2]
        trajectories.append(Trajectory(tid, d["stamps"], positions, d["confidences"], covariances=covariances))
    return trajectories, per_track


def _online_target_measurements(rows: list[TrackRow]) -> tuple[list[str], list, list, list, list]:
    """The online target's measurements, frame by frame.

    Its track ids (in order), stamps, positions, covariances and screen points.
    """
    members: list[str] = []
    stamps, z, R, screen = [], [], [], []
    for row in rows:
        wt = row.world
        if not wt.is_target or wt.measured_position is None or not wt.has_world:
            continue
        if stamps and row.stamp <= stamps[-1]:
            continue
        if wt.screen.track_id not in members:
            members.append(wt.screen.track_id)
        stamps.append(row.stamp)
        z.append(wt.measured_position)
        R.append(wt.measured_covariance)
        screen.append(wt.measured_screen)
    return members, stamps, z, R, screen


def _joined_target_measurements(rows: list[TrackRow], settings) -> tuple[list[str], list, list, list, list]:
    """The paper's choice: the best trajectory joined over the whole recording, and its measurements."""
    trajectories, measurements = trajectories_of(rows, settings.motion)
    if not trajectories:
        return [], [], [], [], []
    target, _ = select_target(trajectories, settings.selection)
    if target is None:  # no trajectory may be the vessel of interest (selection.positive_evidence_only)
        return [], [], [], [], []
    stamps, z, R, screen = [], [], [], []
    for member in target.members:
        m = measurements[member]
        keep = [i for i, t in enumerate(m["stamps"]) if not stamps or t > stamps[-1]]
        stamps += [m["stamps"][i] for i in keep]
        z += [m["measured"][i] for i in keep]
        R += [m["covariance"][i] for i in keep]
        screen += [m["screen"][i] for i in keep]
    return list(target.members), stamps, z, R, screen


def _gap_lengths(stamps: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """For each stamp, the time between the measured stamps either side of it (0 where it is measured itself)."""
    t = stamps[measured]
    after = np.searchsorted(t, stamps, side="left")
    before = np.clip(after - 1, 0, max(t.size - 1, 0))
    after = np.clip(after, 0, max(t.size - 1, 0))
    return np.where(measured, 0.0, t[after] - t[before]) if t.size else np.full(stamps.size, np.inf)


def _offline_pass(result: VideoResult, frame_stamps: list[float], camera, config: PipelineConfig) -> None:
    s = config.settings
    if s.offline.target == "online":
        members, stamps, z, R, screen = _online_target_measurements(result.track_rows)
    else:
        members, stamps, z, R, screen = _joined_target_measurements(result.track_rows, s)
    result.predictions = []
    result.target_members = members
    if not stamps:
        return
    measured_t = np.array(stamps)
    grid = np.array(sorted({t for t in frame_stamps if measured_t[0] <= t <= measured_t[-1]} | set(stamps)))
    index = {t: i for i, t in enumerate(grid)}
    Z = np.full((grid.size, 2), np.nan)
    RR = np.tile(np.eye(2), (grid.size, 1, 1))
    screen_y = np.full(grid.size, np.nan)
    for t, zi, Ri, si in zip(stamps, z, R, screen, strict=True):
        Z[index[t]] = zi
        RR[index[t]] = Ri
        screen_y[index[t]] = si[1]

    levels = None
    if config.water_level is not None:
        levels = config.water_level.level_at(grid, s.water_level.max_hold_s)
        levels = np.where(np.isfinite(levels), levels, camera.water_level_m)

    def residual_px(positions: np.ndarray) -> np.ndarray:
        xw, yw = positions[:, 0], positions[:, 1]
        if levels is not None:
            xw, yw = camera.from_water_level(xw, yw, levels)
        _, ys, ok = camera.world_to_screen(xw, yw)
        return np.where(np.asarray(ok) & np.isfinite(screen_y), np.asarray(ys) - screen_y, np.nan)

    motion = s.motion
    if s.offline.adaptive_noise:
        q, r_scale = most_likely_noise(grid, Z, RR, motion, r_scale_candidates=(0.25, 0.5, 1.0, 2.0))
        motion = dataclasses.replace(motion, accel_psd=q)
        RR = RR * r_scale
    smoothed = smooth_with_outlier_masking(grid, Z, RR, residual_px, s.offline.outlier_threshold_px,
                                           s.offline.iterations, motion)
    clip = s.fusion.clip_m
    gap = _gap_lengths(grid, np.isfinite(Z[:, 0]))
    for i, t in enumerate(grid):
        if s.offline.max_gap_s > 0 and gap[i] > s.offline.max_gap_s:
            continue
        x, y = np.clip(smoothed.positions[i], -clip, clip)
        if math.hypot(x, y) > s.fusion.max_range_m:
            continue
        lat, lon = geodesy.local_to_gps(x, y, camera.camera_lat, camera.camera_lon)
        result.predictions.append(Prediction(result.video, float(t), float(lat), float(lon), float(x), float(y),
                                             "+".join(members), bool(np.isfinite(Z[i, 0]))))
    if s.offline.target == "joined":  # online: the rows keep the online selection's flags, one target a frame
        chosen = set(members)
        for row in result.track_rows:
            row.world.is_target = row.world.screen.track_id in chosen


def run(frames: list[DetectionFrame], camera, config: PipelineConfig) -> list[VideoResult]:
    """Run every video of ``frames`` separately."""
    by_video: dict[int, list[DetectionFrame]] = defaultdict(list)
    for frame in frames:
        by_video[frame.video].append(frame)
    return [run_video(by_video[v], camera, config) for v in sorted(by_video)]


def leave_one_video_out(dataset, frames: list[DetectionFrame], train_videos: list[int],
                        config: PipelineConfig, box_anchor: float) -> list[VideoResult]:
    """Run each video with everything fitted on the other training videos: an honest score on training data.

    For each video of ``frames``: the camera is calibrated
    (``vessel_tools.calib.calibration.calibrate_from_labels``), the distance model fitted and the cue noise
    measured (itself leave-one-out) on the labelled training videos other than this one; the rest of
    ``config.settings`` is kept. Used to fit the error model on scores the calibration has not seen.
    """
    by_video: dict[int, list[DetectionFrame]] = defaultdict(list)
    for frame in frames:
        by_video[frame.video].append(frame)
    results = []
    for video in sorted(by_video):
        others = [v for v in train_videos if v != video]
        camera = calibrate_from_labels(dataset, others, box_anchor, water_level=config.water_level)
        boxes, world = training_pairs(dataset, camera, others)
        settings = dataclasses.replace(config.settings, distance_model=fit_distance_model(camera, boxes, world),
                                       cue_stats=cross_validated_cue_statistics(dataset, others, box_anchor,
                                                                                water_level=config.water_level))
        results.append(run_video(by_video[video], camera, dataclasses.replace(config, settings=settings)))
    return results


def _filter_against_its_boxes(out: Path, results: list[VideoResult], camera, dataset, videos) -> str:
    """Lines comparing the published target with its own boxes back-projected, on the same frames, per split."""
    measured_path, filtered_path = write_target_measurement_csvs(out, results, camera.camera_lat, camera.camera_lon)
    scored = {name: evaluate(path, dataset.path, videos, None, None, "frames", False)
              for name, path in (("measured", measured_path), ("filtered", filtered_path))}
    lines = ["the filter against its own boxes back-projected frame by frame (same frames; target_measured.csv, "
             "target_filtered.csv):"]
    for split, block in scored["filtered"]["splits"].items():
        own = scored["measured"]["splits"][split]
        if block["m_per_100m"] is None or own["m_per_100m"] is None:
            continue
        lines.append(f"  {split}: filter {block['m_per_100m']:.2f}, its boxes {own['m_per_100m']:.2f} m/100m "
                     f"({block['n']} frames; median {block['median_m']:.1f} against {own['median_m']:.1f} m)")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The pipeline's options."""
    from vessel_detect.appearance_model import (
        COMBINE_MODES,
        DEFAULT_COMBINE,
        DEFAULT_MIN_PROBABILITY,
        DEFAULT_NESTED_OVERLAP,
    )

    parser = argparse.ArgumentParser(prog="./vessel pipeline", description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=None, help="dataset folder (default $VESSEL_DATA or "
                                                                "../shared/aitas)")
    parser.add_argument("--videos", default=None, help="videos to run (default 13-17, those the data has; else all)")
    parser.add_argument("--detections", default="labels", help="'labels' or a detector CSV "
                                                               "(video,frame,x1,y1,x2,y2,score,class_id)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--mode", choices=MODES, default="online", help="online (as the nodes) or offline "
                                                                        "(plus the smoothing pass)")
    parser.add_argument("--screen-source", choices=SCREEN_SOURCES, default=None,
                        help="box the fuser sees: the raw detection or the tracker's filtered box (default: the "
                             "fuser parameter fusion.screen_source, as the nodes)")
    parser.add_argument("--calib", type=Path, default=None, help="calibration YAML (default: "
                                                                 "config/aitas_camera.yaml, else camera.json)")
    parser.add_argument("--params", type=Path, default=None, help="parameter YAML with the fuser block "
                                                                  "(default: config/aitas.yaml or "
                                                                  "config/parts/fuser.yaml)")
    parser.add_argument("--max-coast", type=float, default=None,
                        help="report a coasting target this long, s (default: the parameter file's gps_publisher "
                             "max_coast_s, as the nodes)")
    parser.add_argument("--leave-one-out", metavar="TRAIN_VIDEOS", default=None,
                        help="calibrate and fit the fusion for each video on these training videos minus that one "
                             "(e.g. 7-12 with --videos 7-12): out-of-sample scores for the error model fit")
    parser.add_argument("--appearance", type=Path, default=None, metavar="MODEL.npz",
                        help="rescore detector output with this appearance model (vessel_tools.track.appearance; e.g. "
                             "config/appearance_aitas.npz): the probability as score, boxes below "
                             "--appearance-min dropped")
    parser.add_argument("--appearance-min", type=float, default=DEFAULT_MIN_PROBABILITY,
                        help="with --appearance: drop detections whose probability is below this "
                             "(default %(default)s)")
    parser.add_argument("--appearance-combine", choices=COMBINE_MODES, default=DEFAULT_COMBINE,
                        help="with --appearance: the probability replaces the score, or multiplies it")
    parser.add_argument("--appearance-nested", type=float, default=DEFAULT_NESTED_OVERLAP,
                        help="with --appearance: drop boxes nested in a likelier one beyond this share of the "
                             "smaller box (0: off; the detector node's appearance_nested_overlap)")
    parser.add_argument("--no-eval", action="store_true", help="do not score the predictions")
    parser.add_argument("--no-plots", action="store_true", help="score without plots")
    return parser


CHECKED_NODES = ("tracker", "fuser", "gps_publisher")
"""The nodes whose blocks of ``--params`` the pipeline reads, and checks as the nodes would."""
SPECIALLY_REPORTED = frozenset({"fusion.anchor"})
"""Names the settings loaders refuse with their own message (``FUSION_ANCHOR_MOVED``: where the setting went)."""
NODES_WITH_CALIBRATION = ("fuser", "gps_publisher")
"""They also take the ``camera.*`` calibration (``declare_camera_model``), which their part files leave out and
the calibration tool checks."""


def unknown_node_parameters(params_path: Path, parts_dir: Path | None = None) -> list[str]:
    """``node: name (did you mean ...?)`` for each name a checked node's own block gives that the node lacks.

    The nodes refuse such a file; the pipeline ran with the default instead, so a misspelt setting went unnoticed.
    A node declares the names of its part file (``config/parts/NODE.yaml``, every parameter with its default);
    ``/**`` is shared by every node and not checked. Empty when the part files are not there.
    """
    from vessel_calib.params import read_params_yaml
    from vessel_common.parameter_names import flatten, is_rcl_parameter, with_closest
    from vessel_common.paths import repo_root

    parts_dir = parts_dir or repo_root() / "config" / "parts"
    blocks = read_params_yaml(params_path)
    problems = []
    for node in CHECKED_NODES:
        part = parts_dir / f"{node}.yaml"
        own = {**blocks.get(node, {}), **blocks.get(f"/{node}", {})}
        if not own or not part.is_file():
            continue
        declared = set(flatten(read_params_yaml(part).get(node, {})))
        given = {name for name in flatten(own) if not is_rcl_parameter(name) and name not in SPECIALLY_REPORTED}
        if node in NODES_WITH_CALIBRATION:
            given = {name for name in given if not name.startswith("camera.")}
        problems += [f"{node}: {with_closest(name, declared)}" for name in sorted(given - declared)]
    return problems


def max_coast_of_params(params_path: Path | None) -> float:
    """The GPS publisher's ``max_coast_s`` of a parameter YAML (the node's default where the file has none)."""
    default = GPS_PUBLISHER_PARAMETERS["max_coast_s"].default
    value = node_values(params_path, "gps_publisher").get("max_coast_s", default) if params_path else default
    low, high = GPS_PUBLISHER_PARAMETERS["max_coast_s"].value_range
    if not (isinstance(value, float) and low <= value <= high):
        raise DataError(f"{params_path}: gps_publisher max_coast_s must be a floating-point number of seconds from "
                        f"{low:g} to {high:g}, as the node declares it (write 2.0, not 2), got {value!r}; fix the file")
    return value


def _frames_and_settings(args, dataset, videos, camera, camera_source: str, params_path):
    """The detections to run (hand labels, or a CSV optionally rescored) and the fuser settings for them."""
    settings = load_fuser_settings(params_path)
    if not args.leave_one_out:
        settings, note = settings.for_camera(camera, camera_source)
        if note:
            print(f"note: {note}", file=sys.stderr)
    if args.detections == "labels":
        frames = label_detections(dataset, videos)
        settings = settings.for_hand_boxes()
    else:
        frames = csv_detections(Path(args.detections), dataset, videos)
        if args.appearance is not None:
            model = appearance.AppearanceModel.load(args.appearance)
            frames = appearance.rescore(frames, dataset, videos, lambda _video: model,
                                        args.appearance_combine, args.appearance_min, camera,
                                        args.appearance_nested)

    return frames, settings


@command_line_tool
def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    args = build_parser().parse_args(argv)
    dataset = open_dataset(args.data)
    videos = dataset.check_videos(parse_videos(args.videos)) if args.videos else dataset.default_videos()
    if args.leave_one_out:
        dataset.check_videos(parse_videos(args.leave_one_out))
    camera, camera_source = load_camera(args.calib, dataset)
    params_path = args.params if args.params is not None else default_params_path()
    unknown = unknown_node_parameters(params_path) if params_path is not None else []
    if unknown:
        raise DataError(f"{params_path} gives parameters no node declares: {'; '.join(unknown)}; fix the file "
                        "(config/parts/NODE.yaml lists each node's parameters)")
    frames, settings = _frames_and_settings(args, dataset, videos, camera, camera_source, params_path)
    if args.max_coast is None:
        max_coast_s = max_coast_of_params(params_path)
    elif math.isfinite(args.max_coast) and args.max_coast >= 0:
        max_coast_s = args.max_coast
    else:
        raise DataError(f"--max-coast must be a number of seconds >= 0, got {args.max_coast}")
    config = PipelineConfig(args.mode, args.screen_source, max_coast_s, load_tracker_config(params_path), settings)
    if args.leave_one_out:
        results = leave_one_video_out(dataset, frames, parse_videos(args.leave_one_out), config,
                                      camera.box_anchor)
        camera_source = f"calibrated per video on {args.leave_one_out} minus that video"
    else:
        results = run(frames, camera, config)
    args.out.mkdir(parents=True, exist_ok=True)
    write_predictions_csv(args.out / "predictions.csv", results)
    write_tracks_csv(args.out / "tracks.csv", results)
    atomic_write_text(args.out / "counts.json",
                      json.dumps({str(r.video): r.counts for r in results}, indent=1, sort_keys=True) + "\n")
    print(f"{sum(len(r.predictions) for r in results)} predictions from {len(frames)} frames "
          f"({args.mode}, camera: {camera_source}, parameters: {params_path or 'defaults'}) -> {args.out}")
    if not args.no_eval:
        coverage_frames = "labels" if args.detections == "labels" else "frames"
        summary = evaluate(args.out / "predictions.csv", dataset.path, videos, args.out, args.calib,
                           coverage_frames, not args.no_plots)
        print(format_table(summary))
        if args.mode == "online":
            print(_filter_against_its_boxes(args.out, results, camera, dataset, videos))
    return 0


if __name__ == "__main__":
    sys.exit(main())
