"""``./vessel demo``: the whole node graph on challenge videos, recorded, scored like the paper, plotted.

For each video: build its bag if needed, start recorder, detector (or, through ``replay_detector``, the hand
labels or a saved ``./vessel detect run`` CSV), tracker, fuser and GPS publisher as separate processes, wait until
they are all connected, replay the bag through the camera node as fast as the graph consumes it, wait until every
frame has come out of the fuser, and stop the graph with SIGINT. Then read the recorded bags back and write
``predictions.csv`` (the vessel of interest as published on ``/vessel/fix``), ``predictions_offline.csv`` (the same
after the paper's offline smoothing pass), ``tracks.csv``, ``summary.json`` and plots, and print a short table.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import yaml

from vessel_bringup.graph import (
    GRAPH_NODES,
    RECORDER,
    GraphNode,
    GraphRunner,
    default_params_file,
    repo_root,
    wait_until_connected,
)
from vessel_bringup.graph_watcher import GraphWatcher
from vessel_calib.params import atomic_write_text, load_camera_yaml
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError, VesselError
from vessel_common.paths import default_data_dir, parse_videos
from vessel_detect.bag_messages import ns_of_stamp
from vessel_detect.bag_reader import BagReader
from vessel_detect.bag_salvage import recover_bag
from vessel_detect.replay_detector_node import CSV_COLUMNS
from vessel_tools import calibrate as calibrate_tool
from vessel_tools.calib.dataset import TRAIN_VIDEOS, Dataset
from vessel_tools.demo_report import write_report
from vessel_tools.detect.bag_build import BuildOptions, build_from_dataset
from vessel_tools.track.evaluation import FIX_COLUMNS
from vessel_tools.track.offline_data import DetectionFrame
from vessel_track.fuser_settings import HAND_BOX_FUSION, load_fuser_settings
from vessel_track.pose_input import pose_refusal
from vessel_track.tracker_config import load_tracker_config
from vessel_track.tracker_node import detections_to_arrays, load_detection_inputs

REPLAY_DETECTOR = GraphNode("detector", "vessel_detect", "replay_detector", "hand-labelled boxes as detections")
OUTPUT_TOPICS = {
    "/vessel/detections": "vessel_msgs/msg/Detection2DArray",
    "/vessel/tracks/screen": "vessel_msgs/msg/VesselTrackArray",
    "/vessel/tracks": "vessel_msgs/msg/VesselTrackArray",
    "/vessel/fix": "sensor_msgs/msg/NavSatFix",
    "/vessel/fixes": "vessel_msgs/msg/VesselTrackArray",
    "/vessel/gps_truth": "sensor_msgs/msg/NavSatFix",
    "/camera/fix": "sensor_msgs/msg/NavSatFix",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}


def log(message: str) -> None:
    """Progress on stderr, so stdout keeps only the table."""
    print(f"[demo] {message}", file=sys.stderr, flush=True)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command line of ``./vessel demo``."""
    parser = argparse.ArgumentParser(prog="./vessel demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=None, help="dataset folder laid out like ../shared/aitas "
                        "(default: $VESSEL_DATA or ../shared/aitas)")
    parser.add_argument("--videos", default=None, help="videos to run, e.g. 13-17 or 13,14 (default: the "
                        "validation videos 13-17 where present, else every video of the folder)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default out/demo)")
    parser.add_argument("--calib", type=Path, default=None, help="calibration parameter file; default: fitted "
                        "from the dataset's training labels (videos 7-12), else from the shared set's, else "
                        "config/aitas_camera.yaml")
    parser.add_argument("--params", type=Path, default=None, help="graph parameter file (default config/aitas.yaml)")
    parser.add_argument("--detector-params", type=Path, default=None, help="a parameter file laid over --params, "
                        "e.g. config/detector_coco.yaml: the generic COCO detector set-up, for comparison")
    parser.add_argument("--detections", default="detector", metavar="detector|labels|FILE.csv",
                        help="detector: run the ONNX detector node; labels: feed the hand-labelled boxes; "
                             "FILE.csv: replay a saved detector run (`./vessel detect run --out FILE.csv`, columns "
                             "video,frame,x1,y1,x2,y2,score,class_id) in step with the camera")
    parser.add_argument("--bags", type=Path, default=None, help="where the video bags are (built if missing; "
                        "default bags/ for the shared set, bags/<dataset folder name> for others)")
    parser.add_argument("--max-frames", type=int, default=0, help="replay at most this many frames per video "
                        "(0: all), for a quick check")
    parser.add_argument("--frame-timeout", type=float, default=60.0, help="seconds to wait for one frame to come "
                        "out of the graph before giving up on the video")
    return parser.parse_args(argv)


# --------------------------------------------------------------------------------------------------------------
# Inputs: calibration, bags, label detections
# --------------------------------------------------------------------------------------------------------------
def merged_params_file(base: Path, overlay: Path, out: Path) -> Path:
    """``overlay``'s parameters over ``base``'s, node by node, written to ``out``.

    One file for the nodes and the offline pass alike, as ``--params-file base --params-file overlay`` would give.
    """
    if not Path(overlay).is_file():
        raise VesselError(f"--detector-params {overlay} not found (e.g. config/detector_coco.yaml)")

    def merge(into: dict, extra: dict) -> dict:
        for key, value in extra.items():
            into[key] = merge(dict(into.get(key) or {}), value) if isinstance(value, dict) else value
        return into

    try:
        merged = merge(yaml.safe_load(Path(base).read_text()) or {}, yaml.safe_load(Path(overlay).read_text()) or {})
    except yaml.YAMLError as error:
        raise VesselError(f"cannot read {base} or {overlay} as YAML: {error}") from None
    atomic_write_text(out, f"# {overlay} over {base}, written by ./vessel demo --detector-params\n"
                      + yaml.safe_dump(merged, sort_keys=False))
    return out


def prepare_calibration(dataset: Dataset, calib: Path | None, out: Path, water_level_file: str = "") -> Path:
    """The calibration file the graph loads: given, fitted from training labels, or the shipped one.

    With ``water_level_file`` (the parameter file's fuser ``water_level.file``) the fit allows for the tide; if
    the labels' times are outside that file, it is fitted without (and the fuser then runs without the tide).
    """
    if calib is not None:
        if not calib.is_file():
            raise VesselError(f"calibration file {calib} not found: run ./vessel calibrate or drop --calib")
        return calib

    sources = [dataset]
    shared = default_data_dir()
    if shared is not None and shared.resolve() != dataset.path.resolve():
        sources.append(Dataset(shared))
    for source in sources:
        train = [v for v in TRAIN_VIDEOS if any(label.gps_ok for label in source.labels([v]))]
        if train:
            target = out / "calibration.yaml"
            videos = ",".join(str(v) for v in train)
            log(f"calibrating from {source.path} training videos {videos} -> {target}")
            command = ["--data", str(source.path), "--videos", videos, "--label-passes", "all", "--out", str(target)]
            status = 1
            if water_level_file:
                status = calibrate_tool.main(command + ["--water-level", water_level_file])
                if status != 0:
                    log(f"calibrating with the water level of {water_level_file} failed (see above): calibrating "
                        "without it")
            if status != 0:
                status = calibrate_tool.main(command)
            if status != 0:
                raise VesselError(f"calibration from {source.path} failed (status {status}); pass --calib FILE")
            return target
    fallback = repo_root() / "config" / "aitas_camera.yaml"
    log(f"no training labels found: using the shipped calibration {fallback}")
    return fallback


def own_ship_params(dataset: Dataset, out: Path) -> Path | None:
    """The parameters of a camera on a ship, for a dataset with ``own_ship.csv``; None for a fixed camera.

    The detector poses each image from the ship's attitude and the fuser places the camera at the ship's position.

    The dataset's ``reference_attitude`` (the ship's attitude at which its calibration holds) goes in as the
    calibration's ``camera.reference_attitude_deg``, listed before the calibration file so that a calibration
    which records its own mounting wins.
    """
    if dataset.own_ship() is None:
        return None
    block: dict = {"detector": {"ros__parameters": {"pose": {"source": "own_ship"}}},
                   "fuser": {"ros__parameters": {"own_ship_fix_topic": "/own_ship/fix"}}}
    reference = dataset.reference_attitude()
    if reference is not None:
        attitude = [float(reference.heading_deg), float(reference.pitch_deg or 0.0), float(reference.roll_deg or 0.0)]
        block["/**"] = {"ros__parameters": {"camera": {"reference_attitude_deg": attitude}}}
    path = out / "own_ship.yaml"
    atomic_write_text(path, f"# the own ship of {dataset.path}, written by ./vessel demo\n"
                      + yaml.safe_dump(block, sort_keys=False))
    log(f"{dataset.path} has own_ship.csv: the detector poses each image from the ship's attitude ({path})")
    return path


def prepare_bags(dataset: Dataset, videos: list[int], bag_root: Path) -> dict[int, Path]:
    """Bag folders ``bag_root/video_<N>``, built from the dataset where missing."""
    missing = [v for v in videos if not (bag_root / f"video_{v}" / "metadata.yaml").is_file()]
    if missing:
        log(f"building bags for videos {missing} into {bag_root}")
        build_from_dataset(dataset.path, bag_root, missing, BuildOptions(overwrite=True), report=log)
    return {v: bag_root / f"video_{v}" for v in videos}


def write_saved_detections(frames, video: int, path: Path) -> None:
    """One video's frames of a saved detector run (``pipeline.DetectionFrame``) as a ``replay_detector`` CSV.

    Frames without boxes have no row (the replay detector, following the camera, publishes an empty array for
    their images).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(CSV_COLUMNS)
        for frame in frames:
            if frame.video != video:
                continue
            for box, score in zip(frame.boxes, frame.scores, strict=True):
                writer.writerow([f"{frame.stamp:.6f}", *(f"{v:.2f}" for v in box), f"{score:.6f}", "boat"])


def write_label_detections(dataset: Dataset, video: int, path: Path) -> int:
    """One video's primary hand-labelled boxes as a detections CSV for ``replay_detector``; frames written.

    Hand labels are drawn on frames that need not be among the dataset's images, so ``replay_detector`` runs
    self-paced on their own stamps instead of following the camera.
    """
    labels = dataset.labels([video], primary_only=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(CSV_COLUMNS)
        for label in labels:
            writer.writerow([f"{label.stamp:.6f}", label.x1, label.y1, label.x2, label.y2, 1.0, "boat"])
    return len({round(label.stamp, 6) for label in labels})


# --------------------------------------------------------------------------------------------------------------
# Running the graph
# --------------------------------------------------------------------------------------------------------------
@dataclass
class VideoRun:
    """What happened while one video went through the graph."""

    video: int
    frames_expected: int
    frames_out: int
    seconds: float
    recording: Path
    node_statuses: dict[str, int]
    failed_nodes: tuple[str, ...] = ()


def run_video(video: int, bag: Path, recording: Path, params: list[Path], args, label_csv: Path | None,
              log_dir: Path, frames_expected: int, saved_csv: Path | None = None,
              fuser_overrides: dict | None = None) -> VideoRun:
    """One video through the whole graph as separate processes; the outputs recorded to ``recording``.

    The source is the camera replaying the video's bag into the detector (or into the replay detector
    publishing the boxes of ``saved_csv`` for each image), or, with hand labels, the replay detector publishing
    the labelled boxes on their own stamps. It ends when every frame has come out of the
    fuser, or when the source has finished and nothing more has come out for a few seconds (a frame lost on the
    way), or after ``--frame-timeout`` seconds without progress.
    """
    runner = GraphRunner(params, log_dir=log_dir)
    watcher = GraphWatcher()
    started = time.monotonic()
    labels = label_csv is not None
    try:
        _start_consumers(runner, labels, saved_csv, recording, fuser_overrides)
        wait_until_connected(runner, watcher, 60.0, f"see the logs in {log_dir}", with_camera=not labels,
                             with_detector=not labels)
        source = _start_source(runner, bag, args, label_csv, saved_csv)
        expected = min(frames_expected, args.max_frames) if args.max_frames else frames_expected
        failed_nodes = _wait_for_frames(runner, watcher, video, expected, source, args.frame_timeout, log_dir)
        watcher.spin(1.0)  # let the GPS publisher and the recorder take the last messages
        frames_out = watcher.tracks_received
    finally:
        statuses = runner.stop()
        watcher.close()
    return VideoRun(video, frames_expected, frames_out, time.monotonic() - started, recording, statuses,
                    failed_nodes)


def _start_consumers(runner: GraphRunner, labels: bool, saved_csv: Path | None, recording: Path,
                     fuser_overrides: dict | None) -> None:
    """Recorder, GPS publisher, fuser, tracker and the detector (none for hand labels), consumers first."""
    runner.start(RECORDER, {"output": str(recording),
                            "topics": [f"{topic}:{msgtype}" for topic, msgtype in OUTPUT_TOPICS.items()]})
    nodes = {node.name: node for node in GRAPH_NODES}
    runner.start(nodes["gps_publisher"])
    # Hand-drawn boxes are read as the calibration read them (FuserSettings.for_hand_boxes).
    fuser_values = {"fusion": dict(HAND_BOX_FUSION)} if labels else {}
    fuser_values.update(fuser_overrides or {})
    runner.start(nodes["fuser"], fuser_values or None)
    runner.start(nodes["tracker"])
    if saved_csv is not None:
        runner.start(REPLAY_DETECTOR, {"detections_csv": str(saved_csv), "pace": "images",
                                       "image_qos": "reliable"})
    elif not labels:
        runner.start(nodes["detector"])


def _start_source(runner: GraphRunner, bag: Path, args, label_csv: Path | None, saved_csv: Path | None) -> str:
    """Start what feeds the graph: the camera replaying the bag, or the replay detector of hand labels; its name."""
    if label_csv is not None:  # self-paced: it waits for the tracker and the recorder before sending anything
        runner.start(REPLAY_DETECTOR, {"detections_csv": str(label_csv), "pace": "self",
                                       "wait_for_subscribers": 2})
        return "detector"
    camera_parameters: dict[str, object] = {"source": str(bag), "rate": 0.0, "loop": False, "exit_at_end": True}
    if saved_csv is not None:  # the replay answers at once: pace on the fuser, send images reliably
        camera_parameters.update(image_qos="reliable", ack_topic="/vessel/tracks",
                                 ack_type="vessel_msgs/msg/VesselTrackArray")
    if args.max_frames:
        camera_parameters["max_frames"] = args.max_frames
    nodes = {node.name: node for node in GRAPH_NODES}
    runner.start(nodes["camera"], camera_parameters)
    return "camera"


def _wait_for_frames(runner: GraphRunner, watcher: GraphWatcher, video: int, expected: int, source: str,
                     frame_timeout: float, log_dir: Path) -> tuple[str, ...]:
    """Spin until ``expected`` frames came out of the fuser, a node failed or progress stopped; the failed nodes."""
    last_progress = time.monotonic()
    last_count = -1
    failed_nodes: tuple[str, ...] = ()
    while watcher.tracks_received < expected:
        watcher.spin(0.2)
        if watcher.tracks_received != last_count:
            last_count = watcher.tracks_received
            last_progress = time.monotonic()
            if sys.stderr.isatty():
                print(f"\r[demo] video {video}: {last_count}/{expected} frames through the graph",
                      end="", file=sys.stderr, flush=True)
            elif last_count % 10 == 0:  # a log file gets a line every ten frames
                log(f"video {video}: {last_count}/{expected} frames through the graph")
        failed = runner.failed()
        if failed:
            print(file=sys.stderr)
            log(f"video {video}: node(s) {failed} failed after {watcher.tracks_received}/{expected} frames; "
                f"what was recorded is kept and scored. Its last lines:\n{runner.log_tail(failed[0])}")
            failed_nodes = tuple(failed)
            break
        idle = time.monotonic() - last_progress
        source_done = runner.running[source].process.poll() is not None
        if (source_done and idle > 5.0) or idle > frame_timeout:
            print(file=sys.stderr)
            log(f"video {video}: stopping with {watcher.tracks_received}/{expected} frames through the graph "
                f"({'the source finished' if source_done else 'no progress'}; see {log_dir})")
            break
    if sys.stderr.isatty():
        print(file=sys.stderr)
    return failed_nodes


# --------------------------------------------------------------------------------------------------------------
# Outputs
# --------------------------------------------------------------------------------------------------------------
def readable_recording(run: VideoRun, log) -> bool:
    """Whether a video's recording can be read; a recorder that died is recovered (``recover_bag``) first."""
    try:
        BagReader(run.recording).close()
        return True
    except DataError as error:
        log(f"video {run.video}: the recording is not readable ({error}); recovering it")
    try:
        salvage = recover_bag(run.recording)
    except DataError as error:
        log(f"video {run.video}: nothing could be recovered ({error}); the video is left out of the scores")
        return False
    log(f"video {run.video}: {salvage.describe()}")
    return True


def export_recordings(runs: list[VideoRun], out: Path) -> tuple[Path, Path]:
    """``predictions.csv`` from /vessel/fix and ``tracks.csv`` from /vessel/tracks of the recorded bags.

    Also ``fixes.csv``: the same fixes with their east-north covariance (how honest it is goes into the report).
    """
    predictions_path = out / "predictions.csv"
    tracks_path = out / "tracks.csv"
    with predictions_path.open("w", newline="") as p_handle, tracks_path.open("w", newline="") as t_handle, \
            (out / "fixes.csv").open("w", newline="") as f_handle:
        predictions = csv.writer(p_handle)
        predictions.writerow(["video", "t_utc_s", "lat", "lon"])
        fixes = csv.writer(f_handle)
        fixes.writerow(FIX_COLUMNS)
        tracks = csv.writer(t_handle)
        tracks.writerow(["video", "t_utc_s", "track_id", "is_target", "status", "x_px", "y_px", "w_px", "h_px",
                         "east_m", "north_m", "lat", "lon", "distance_m", "expected_error_m", "confidence"])
        for run in runs:
            with BagReader(run.recording) as reader:
                topics = reader.topics
                if "/vessel/fix" in topics:
                    for _, fix in reader.read_topic("/vessel/fix"):
                        if fix.status.status < 0 or not (math.isfinite(fix.latitude) and math.isfinite(fix.longitude)):
                            continue
                        t = ns_of_stamp(fix.header.stamp) / 1e9
                        row = [run.video, f"{t % 86400:.3f}", f"{fix.latitude:.8f}", f"{fix.longitude:.8f}"]
                        predictions.writerow(row)
                        c = fix.position_covariance
                        fixes.writerow(row + [f"{c[0]:.4f}", f"{c[1]:.4f}", f"{c[4]:.4f}"])
                if "/vessel/tracks" in topics:
                    for _, array in reader.read_topic("/vessel/tracks"):
                        t = ns_of_stamp(array.header.stamp) / 1e9
                        for track in array.tracks:
                            tracks.writerow([
                                run.video, f"{t % 86400:.3f}", track.id, int(track.is_target), track.status,
                                f"{track.bbox.center.position.x:.2f}", f"{track.bbox.center.position.y:.2f}",
                                f"{track.bbox.size_x:.2f}", f"{track.bbox.size_y:.2f}",
                                f"{track.position.x:.3f}", f"{track.position.y:.3f}",
                                f"{track.latitude:.8f}", f"{track.longitude:.8f}",
                                f"{track.distance_m:.2f}", f"{track.expected_error_m:.2f}", f"{track.confidence:.3f}",
                            ])
    return predictions_path, tracks_path


def tide_overrides(calibration: Path, params_file: Path) -> dict:
    """Fuser parameter overrides that turn the tide correction off when ``calibration`` cannot be corrected.

    The parameter file may name a water-level file (``water_level.file``) while the calibration was fitted
    without one (``--calib`` an older file, or labels outside the file's times): the fuser node would refuse to
    start, so the demo says so and runs without the correction (``FuserSettings.for_camera``, which the offline
    pass applies too).
    """
    settings, note = load_fuser_settings(params_file).for_camera(load_camera_yaml(calibration), str(calibration))
    if note:
        log(note)
        return {"water_level": {"file": settings.water_level.file}}
    return {}


def recorded_detection_frames(recording: Path, video: int, classes: frozenset[str] | None,
                              confidence_class: str) -> list[DetectionFrame]:
    """The ``/vessel/detections`` of a recording as the tracker node took them: boxes and confidences.

    ``classes`` and ``confidence_class`` as the tracker node's parameters (``load_detection_inputs``); empty when
    the recording holds no detections.
    """
    frames = []
    with BagReader(recording) as reader:
        if "/vessel/detections" not in reader.topics:
            return []
        for index, (_, array) in enumerate(reader.read_topic("/vessel/detections")):
            if pose_refusal(array.camera_pose) is not None:
                continue  # the tracker node skipped this image too: no pose, no positions
            boxes, scores = detections_to_arrays(array, classes, confidence_class)
            frames.append(DetectionFrame(video, index, ns_of_stamp(array.header.stamp) / 1e9, boxes, scores))
    return frames


def export_offline_predictions(runs: list[VideoRun], out: Path, calibration: Path, params_file: Path,
                               hand_boxes: bool = False) -> Path:
    """``predictions_offline.csv``: the recorded detections through the paper's offline pass (recorded data).

    The same tracker and fuser cores the nodes run, with the parameter file's settings, then the trajectory
    joining, scoring and smoothing over the whole video that only recorded data allows (``vessel_tools.track.pipeline``,
    mode ``offline``). With ``hand_boxes`` the boxes are read as the fuser node read them
    (``FuserSettings.for_hand_boxes``). Each box's confidence is what the tracker node took from the same message
    (``detections_to_arrays`` with the file's ``classes`` and ``confidence_class``).
    """
    from vessel_tools.track.pipeline import PipelineConfig, run_video
    from vessel_tools.track.pipeline_results import write_predictions_csv

    camera = load_camera_yaml(calibration)
    classes, confidence_class = load_detection_inputs(params_file)
    settings, _ = load_fuser_settings(params_file).for_camera(camera)  # the note was logged by tide_overrides
    config = PipelineConfig(mode="offline", tracker=load_tracker_config(params_file),
                            settings=settings.for_hand_boxes() if hand_boxes else settings)
    results = []
    for run in runs:
        frames = recorded_detection_frames(run.recording, run.video, classes, confidence_class)
        if frames:
            results.append(run_video(frames, camera, config))
    path = out / "predictions_offline.csv"
    write_predictions_csv(path, results)
    return path


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo; 0 when it ran to the end, 2 on bad input, 1 when the graph failed."""
    args = parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    data = args.data or default_data_dir()
    if data is None:
        raise VesselError("no dataset: pass --data DIR (a folder laid out like ../shared/aitas) or set "
                          "VESSEL_DATA")
    dataset = Dataset(data)
    videos = dataset.check_videos(parse_videos(args.videos)) if args.videos else dataset.default_videos()
    saved = None
    if args.detections not in ("detector", "labels"):  # read first: a bad file fails before any work
        from vessel_tools.track.offline_data import csv_detections

        saved = csv_detections(Path(args.detections), dataset, videos)
    out = args.out or repo_root() / "out" / "demo"
    out.mkdir(parents=True, exist_ok=True)
    params_file = args.params or default_params_file()
    if args.detector_params is not None:
        params_file = merged_params_file(params_file, args.detector_params, out / "params.yaml")
        log(f"parameters: {args.detector_params} over {args.params or default_params_file()} -> {params_file}")

    water_level = load_fuser_settings(params_file).water_level
    if water_level.file:
        water_level.load()  # a missing or broken file fails here, before any work
    calibration = prepare_calibration(dataset, args.calib, out, water_level.file)
    fuser_overrides = tide_overrides(calibration, params_file)
    pose_file = own_ship_params(dataset, out)
    params = [params_file, *([pose_file] if pose_file else []), calibration]
    shared = default_data_dir()
    is_shared = shared is not None and Path(data).resolve() == shared.resolve()
    bag_root = args.bags or repo_root() / "bags" / ("" if is_shared else Path(data).resolve().name)
    bags = prepare_bags(dataset, videos, bag_root)
    frames_per_video = _frames_per_video(args, dataset, videos, out, data)
    saved_csvs = {v: out / "saved_detections" / f"video_{v}.csv" for v in videos} if saved is not None else {}
    for v, path in saved_csvs.items():
        write_saved_detections(saved, v, path)
    runs = _run_videos(args, videos, bags, params, out, frames_per_video, saved_csvs, fuser_overrides)
    runs = [run for run in runs if readable_recording(run, log)]
    if not runs:
        raise VesselError("no video left a readable recording: see the logs in " + str(out / "logs"))
    predictions, tracks = export_recordings(runs, out)

    offline = export_offline_predictions(runs, out, calibration, params[0], args.detections == "labels")
    summary = write_report(dataset, videos, out, predictions, tracks, runs, calibration, offline,
                           "labels" if args.detections == "labels" else "frames")
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    log(f"outputs in {out}: predictions.csv, predictions_offline.csv, fixes.csv, tracks.csv, summary.json, "
        "plots, recording/")
    return _status(runs, videos)


def _frames_per_video(args, dataset: Dataset, videos: list[int], out: Path, data) -> dict[int, int]:
    """Frames each video sends through the graph: its labelled frames (written for the replay), or its images."""
    if args.detections != "labels":
        return {v: len(dataset.frames([v])) for v in videos}
    frames_per_video = {v: write_label_detections(dataset, v, out / "labels" / f"video_{v}.csv") for v in videos}
    unlabelled = [v for v, count in frames_per_video.items() if count == 0]
    if unlabelled:
        raise VesselError(f"--detections labels: {data} has no hand labels for video(s) {unlabelled}")
    return frames_per_video


def _run_videos(args, videos: list[int], bags: dict[int, Path], params: list[Path], out: Path,
                frames_per_video: dict[int, int], saved_csvs: dict[int, Path], fuser_overrides: dict) -> list[VideoRun]:
    """Each video through the graph in turn, recorded to ``out/recording/video_N`` (replacing an older one)."""
    runs = []
    for video in videos:
        label_csv = out / "labels" / f"video_{video}.csv" if args.detections == "labels" else None
        recording = out / "recording" / f"video_{video}"
        if recording.exists():
            import shutil

            shutil.rmtree(recording)
        recording.parent.mkdir(parents=True, exist_ok=True)
        log(f"video {video}: {frames_per_video[video]} frames from {bags[video]}")
        run = run_video(video, bags[video], recording, params, args, label_csv, out / "logs" / f"video_{video}",
                        frames_per_video[video], saved_csvs.get(video), fuser_overrides)
        log(f"video {video}: {run.frames_out}/{run.frames_expected} frames in {run.seconds:.1f} s "
            f"({run.frames_out / max(run.seconds, 1e-9):.2f} frames/s incl. start-up)")
        runs.append(run)
    return runs


def _status(runs: list[VideoRun], videos: list[int]) -> int:
    """0 when every video went through, else 1 with a line naming what failed."""
    failures = [f"video {run.video}: {', '.join(run.failed_nodes)}" for run in runs if run.failed_nodes]
    failures += [f"video {video}: no readable recording" for video in videos
                 if video not in {run.video for run in runs}]
    if failures:
        log("these failed, and the figures above lack what they would have given: " + "; ".join(failures))
        return 1
    return 0

if __name__ == "__main__":
    sys.exit(main())
