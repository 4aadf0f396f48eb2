"""``./vessel bench``: the whole node graph's frames/s and latency against the detector core alone, in one run.

One challenge video is replayed from its bag (looped, with shifted stamps, when more frames are asked for than
it holds) and measured two ways, in alternating rounds so that a change of the shared machine's load weighs on
both alike (every round: the core, then the graph, over the same frames; per-round figures are reported):

1. **Detector core**, in this process: ``cv2.imdecode`` of each JPEG of the bag and ``VesselDetector.detect``,
   frame after frame, the detector built from the detector node's parameters exactly as the node builds it.
2. **The graph**: camera, detector, tracker, fuser and gps_publisher as separate processes (``GraphRunner``),
   started once; per round the camera replays the bag at rate 0 (the next frame goes when the detections of the
   previous one arrive). An in-process rclpy node notes when each image, detections, screen tracks, world tracks
   and fix of the same header stamp was published (DDS source timestamp) and arrived. Frames/s end to end are
   the world-track arrays out of the fuser over the wall time from the first image to the last array; latency
   is image arrival to ``/vessel/fix`` arrival for the same frame (matched by stamp and occurrence: each round
   repeats the stamps); the publication times give the time spent per stage.

CPU seconds, CPU % (over the measured frames) and peak memory (VmHWM) of every node process come from
``/proc/<pid>/stat`` and ``/proc/<pid>/status``, sampled until just before the graph is stopped.

    ./vessel bench --frames 72 --out out/bench/bench.json
"""

from __future__ import annotations

import argparse
import math
import os
import random
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from vessel_bringup.graph import default_calibration_file, default_params_file, repo_root
from vessel_calib.camera_model import CameraModel
from vessel_calib.camera_parameters import DEFAULT_CAMERA_PARAMETERS
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError, VesselError
from vessel_common.parameter_names import flatten
from vessel_common.paths import default_data_dir, parse_videos
from vessel_detect.bag_reader import BagReader
from vessel_detect.detector_params import DETECTOR_PARAMETERS, build_detector, merge_values
from vessel_tools.bench_graph import CAMERA_ACK_TIMEOUT_S, GraphError, GraphSession, graph_figures
from vessel_tools.bench_report import RATIO_TARGET, format_table, log, machine_info, print_and_save, summary_ms
from vessel_tools.detect.bag_build import BuildOptions, build_from_dataset

DEFAULT_VIDEO = 13
DEFAULT_FRAMES = 72
DEFAULT_WARMUP = 3
DEFAULT_ROUNDS = 3
DEFAULT_FRAMES_IN_FLIGHT = 2


# --------------------------------------------------------------------------------------------------------------
# Parameters: what a node reads from the parameter files, and the detector core built from it
# --------------------------------------------------------------------------------------------------------------
def node_parameters(params_files: Sequence[Path], node_name: str) -> dict[str, object]:
    """The parameters a node named ``node_name`` gets from ``--params-file`` files, later files winning.

    Follows the ROS rules the nodes see: blocks under ``/**``, ``/*``, the node's name or ``/name`` apply;
    nested keys become dotted names (``camera: {H: ...}`` -> ``camera.H``).
    """
    matching = {"/**", "/*", node_name, f"/{node_name}"}
    merged: dict[str, object] = {}
    for path in params_files:
        try:
            document = yaml.safe_load(Path(path).read_text()) or {}
        except (OSError, yaml.YAMLError) as error:
            raise DataError(f"parameter file {path} cannot be read: {error}") from None
        if not isinstance(document, dict):
            raise DataError(f"parameter file {path} is not a mapping of node names to ros__parameters")
        for key, block in document.items():
            if str(key) in matching and isinstance(block, dict):
                merged.update(flatten(block.get("ros__parameters") or {}))
    return merged


@dataclass
class CoreDetector:
    """The detector core as the node builds it, and what the report says about it."""

    detect: Callable[[np.ndarray], object]
    mode: str
    threads: int
    windows_per_frame: Callable[[], int]
    model_path: str


def build_core_detector(parameters: dict[str, object]) -> CoreDetector:
    """Build the detector core from the detector node's parameters, the way the node does.

    The node declares the parameters of ``detector_params.DETECTOR_PARAMETERS`` (others in the file do not reach
    it) and the ``camera.*`` calibration (``declare_camera_model``: its keys, the challenge camera's values by
    default), then calls ``detector_params.build_detector(values, camera)``; so does this.
    """
    declared = {param.name for param in DETECTOR_PARAMETERS}
    values = merge_values({key: value for key, value in parameters.items() if key in declared})
    camera_values = {key: parameters.get(f"camera.{key}", default)
                     for key, default in DEFAULT_CAMERA_PARAMETERS.items()}
    camera = CameraModel.from_params(camera_values, where="camera (detector parameters)")
    detector = build_detector(values, camera)
    return CoreDetector(
        detect=detector.detect,
        mode=detector.config.mode,
        threads=int(values["intra_op_threads"]),
        windows_per_frame=lambda: len(detector.windows(detector.reference_wh)),
        model_path=str(detector.model.path),
    )


# --------------------------------------------------------------------------------------------------------------
# The frames: the bag of one video, looped to the number of frames wanted
# --------------------------------------------------------------------------------------------------------------
def prepare_bag(video: int, data: Path | None, bags: Path | None) -> Path:
    """The bag folder of ``video``; built from the dataset when missing."""
    shared = default_data_dir()
    is_shared = data is None or (shared is not None and Path(data).resolve() == shared.resolve())
    root = bags or repo_root() / "bags" / ("" if is_shared else Path(data).resolve().name)
    bag = root / f"video_{video}"
    if (bag / "metadata.yaml").is_file():
        return bag
    source = data or shared
    if source is None or not (Path(source) / "frames.csv").is_file():
        raise DataError(
            f"no bag at {bag} and no dataset to build it from: pass --data DIR (a folder laid out like "
            f"../shared/aitas), set VESSEL_DATA, or build it with ./vessel bag build --data DIR --videos {video} "
            f"--out {root}"
        )

    log(f"building the bag of video {video} from {source} into {root}")
    build_from_dataset(Path(source), root, [video], BuildOptions(overwrite=True), report=log)
    return bag


def read_bag_jpegs(bag: Path) -> list[tuple[float, bytes]]:
    """(stamp s, JPEG bytes) of every image of the bag, in order."""
    with BagReader(bag) as reader:
        frames = list(reader.images())
    if not frames:
        raise DataError(f"bag {bag} holds no image: rebuild it with ./vessel bag build")
    return frames


def looped(frames: Sequence[tuple[float, bytes]], count: int) -> list[bytes]:
    """The first ``count`` JPEGs the camera publishes when it loops over ``frames``."""
    return [frames[i % len(frames)][1] for i in range(count)]


# --------------------------------------------------------------------------------------------------------------
# 1. The detector core alone
# --------------------------------------------------------------------------------------------------------------
@dataclass
class CoreTimes:
    """Seconds per frame of the detector core: decode, detect and both."""

    decode_s: list[float] = field(default_factory=list)
    detect_s: list[float] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)
    """CPU seconds of this process (every thread, i.e. onnxruntime's too) per frame."""

    def __add__(self, other: CoreTimes) -> CoreTimes:
        return CoreTimes(self.decode_s + other.decode_s, self.detect_s + other.detect_s, self.cpu_s + other.cpu_s)

    def cpu_percent(self) -> float:
        """CPU time over wall time while the core ran (100 % = one core busy)."""
        wall = sum(self.total_s)
        return 100.0 * sum(self.cpu_s) / wall if wall > 0 else float("nan")

    @property
    def total_s(self) -> list[float]:
        """Decode + detect per frame."""
        return [a + b for a, b in zip(self.decode_s, self.detect_s, strict=True)]

    def fps(self) -> float:
        """Frames per second of decode + detect, back to back."""
        total = sum(self.total_s)
        return len(self.decode_s) / total if total > 0 else float("nan")


def run_core(core: CoreDetector, jpegs: Sequence[bytes], times: CoreTimes | None = None) -> CoreTimes:
    """Decode and detect each JPEG, timing both; appends to ``times`` when given."""
    import cv2

    times = times if times is not None else CoreTimes()
    for jpeg in jpegs:
        cpu_started = time.process_time()
        started = time.perf_counter()
        image = cv2.imdecode(np.frombuffer(jpeg, dtype=np.uint8), cv2.IMREAD_COLOR)
        decoded = time.perf_counter()
        if image is None:
            raise DataError("a JPEG of the bag does not decode: rebuild the bag with ./vessel bag build")
        core.detect(image)
        done = time.perf_counter()
        times.cpu_s.append(time.process_time() - cpu_started)
        times.decode_s.append(decoded - started)
        times.detect_s.append(done - decoded)
    return times



# --------------------------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------------------------
def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command line of ``./vessel bench``."""
    parser = argparse.ArgumentParser(prog="./vessel bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=None, help="dataset folder to build the bag from if it is "
                        "missing (default: $VESSEL_DATA or ../shared/aitas)")
    parser.add_argument("--videos", default=str(DEFAULT_VIDEO), help=f"the video to replay (one; default "
                        f"{DEFAULT_VIDEO}); it is looped for more frames than it holds")
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES, help="frames measured, after the warm-up "
                        f"(default {DEFAULT_FRAMES})")
    parser.add_argument("--warmup", type=int, default=DEFAULT_WARMUP, help="frames run first and not measured, in "
                        f"the core and in the graph (default {DEFAULT_WARMUP})")
    parser.add_argument("--rounds", type=int, default=DEFAULT_ROUNDS, help="alternate the core and the graph "
                        f"this many times, the frames shared out between the rounds, so that a change of the "
                        f"machine's load weighs on both alike (default {DEFAULT_ROUNDS})")
    parser.add_argument("--out", type=Path, default=None, help="also write the figures to this JSON file")
    parser.add_argument("--params", type=Path, default=None, help="graph parameter file (default config/aitas.yaml)")
    parser.add_argument("--calib", type=Path, default=None,
                        help="calibration parameter file (default config/aitas_camera.yaml)")
    parser.add_argument("--bags", type=Path, default=None, help="folder of the video bags (default bags/; built "
                        "there if missing)")
    parser.add_argument("--log-dir", type=Path, default=None, help="node logs go to DIR/<node>.log (default: a "
                        "temporary folder, named in error messages)")
    parser.add_argument("--frames-in-flight", type=int, default=DEFAULT_FRAMES_IN_FLIGHT, choices=(1, 2),
                        metavar="N", help="images the camera publishes ahead of the detections that release them "
                        f"(its frames_in_flight; default {DEFAULT_FRAMES_IN_FLIGHT}: the next image waits at the "
                        "detector, which never idles on the transport; 1: lock step, each image after the "
                        "previous one's detections)")
    parser.add_argument("--frame-timeout", type=float, default=60.0, help="give up when no frame comes out of the "
                        "graph for this many seconds (default 60)")
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error("--frames must be at least 1")
    if args.rounds < 1:
        parser.error("--rounds must be at least 1")
    if args.warmup < 0:
        parser.error("--warmup must be >= 0")
    return args


def split_frames(frames: int, rounds: int) -> list[int]:
    """``frames`` shared out over ``rounds`` (at most one per frame) as evenly as possible."""
    rounds = max(1, min(rounds, frames))
    return [frames // rounds + (1 if index < frames % rounds else 0) for index in range(rounds)]


def _domain_id() -> int:
    """``ROS_DOMAIN_ID`` if set, else a random private one (other graphs on this machine stay apart)."""
    value = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if value:
        try:
            return int(value)
        except ValueError:
            raise DataError(f"ROS_DOMAIN_ID={value!r} is not a number: unset it or give 0-101") from None
    domain = random.randint(1, 100)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    return domain


def run(args: argparse.Namespace) -> dict:
    """The whole benchmark; the result dictionary (also what ``--out`` writes)."""
    videos = parse_videos(args.videos)
    if len(videos) != 1:
        raise DataError(f"--videos {args.videos}: the benchmark replays one video (looped for more frames); "
                        "give one, e.g. --videos 13")
    video = videos[0]
    params_files = [args.params or default_params_file(), args.calib or default_calibration_file()]
    for path in params_files:
        if not path.is_file():
            raise DataError(f"parameter file {path} not found: pass an existing file with --params/--calib")
    machine = machine_info()
    bag = prepare_bag(video, args.data, args.bags)
    try:
        import rclpy  # noqa: F401

        import vessel_msgs.msg  # noqa: F401
    except ImportError as error:
        raise VesselError(f"the ROS 2 workspace is not sourced ({error}): run ./vessel bench") from None
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    domain_id = _domain_id()
    bag_frames = read_bag_jpegs(bag)
    rounds = split_frames(args.frames, args.rounds)
    # Every round replays the bag from its start: the same frames for the core and the graph, in every round.
    one_round = looped(bag_frames, args.warmup + max(rounds))
    log(f"video {video}: {len(bag_frames)} frames in {bag}; {len(rounds)} round(s) of {args.warmup} warm-up + "
        f"{'/'.join(map(str, rounds))} measured frames" + (" (looped)" if len(one_round) > len(bag_frames) else ""))

    parameters = node_parameters(params_files, "detector")
    core = build_core_detector(parameters)
    log(f"detector core: {core.model_path}, mode {core.mode}, {core.threads} onnxruntime threads")
    run_core(core, one_round[: args.warmup])
    windows = core.windows_per_frame()

    log_dir = args.log_dir or Path(tempfile.mkdtemp(prefix="vessel_bench_"))
    session = GraphSession(bag, params_files, len(bag_frames), args.warmup, domain_id, log_dir, args.frame_timeout,
                           frames_in_flight=args.frames_in_flight)
    core_rounds: list[CoreTimes] = []
    try:
        session.start()
        for index, frames in enumerate(rounds, start=1):
            core_rounds.append(run_core(core, one_round[args.warmup : args.warmup + frames]))
            log(f"round {index}/{len(rounds)}: detector core {core_rounds[-1].fps():.2f} frames/s over {frames} "
                "frames; now the graph")
            session.run_round(frames)
        graph_run = session.result()
    finally:
        session.stop()
    times = CoreTimes()
    for part in core_rounds:
        times = times + part

    return _result(args, video, bag, params_files, rounds, core, times, core_rounds, graph_run, machine, windows,
                   domain_id, log_dir)


def _result(args, video, bag, params_files, rounds, core, times, core_rounds, graph_run, machine, windows,
            domain_id, log_dir) -> dict:
    """The figures of a finished run, with warnings for frames lost and nodes that did not exit cleanly."""
    graph = graph_figures(graph_run)
    machine.update({
        "load_average_after": list(os.getloadavg()),
        "onnxruntime_threads": core.threads,
        "detector_mode": core.mode,
        "windows_per_frame": windows,
        "ros_domain_id": domain_id,
    })
    core_fps = times.fps()
    graph_fps = float(graph["graph_fps"])
    usages = graph_run.usage + ([graph_run.watcher_usage] if graph_run.watcher_usage is not None else [])
    nodes = {u.name: u.as_dict() for u in usages}
    for figures in nodes.values():
        frames_out = graph["frames_measured"]
        figures["cpu_ms_per_frame"] = 1000.0 * figures["cpu_s_measured"] / frames_out if frames_out else math.nan
    warnings = _warnings(args, graph, graph_run, log_dir)
    latency = graph.get("latency_fix_ms", summary_ms([]))
    return {
        "graph_fps": graph_fps,
        "detector_core_fps": core_fps,
        "latency_ms_p50": latency["p50"],
        "latency_ms_p95": latency["p95"],
        "ratio_graph_to_core": graph_fps / core_fps if core_fps > 0 else float("nan"),
        "ratio_target": RATIO_TARGET,
        "video": video,
        "frames": args.frames,
        "warmup": args.warmup,
        "rounds": len(rounds),
        "frames_in_flight": args.frames_in_flight,
        "bag": str(bag),
        "params_files": [str(p) for p in params_files],
        "detector_core": {
            "total_ms": summary_ms(times.total_s),
            "decode_ms": summary_ms(times.decode_s),
            "detect_ms": summary_ms(times.detect_s),
            "fps_per_round": [part.fps() for part in core_rounds],
            "frames": len(times.decode_s),
            "cpu_ms_per_frame": 1000.0 * sum(times.cpu_s) / max(1, len(times.cpu_s)),
            "cpu_percent": times.cpu_percent(),
        },
        "graph": graph,
        "nodes": nodes,
        "node_exit_statuses": graph_run.statuses,
        "node_diagnostics": graph_run.diagnostics,
        "machine": machine,
        "log_dir": str(log_dir),
        "warnings": warnings,
    }


def _warnings(args, graph: dict, graph_run, log_dir: Path) -> list[str]:
    """What makes a run's figures doubtful: lost frames, ack time-outs, unclean exits (counters go into ``graph``)."""
    warnings = []
    if graph["frames_measured"] < args.frames:
        warnings.append(f"{args.frames - graph['frames_measured']} of {args.frames} measured frames did not come "
                        "out of the fuser (see the camera's ack timeouts in diagnostics)")
    counters = {
        "camera_ack_timeouts": graph_run.diagnostics.get("camera", {}).get("count.ack_timeouts"),
        "detector_dropped_frames": graph_run.diagnostics.get("detector", {}).get("count.dropped_frames"),
    }
    graph.update({k: int(v) for k, v in counters.items() if v is not None and str(v).isdigit()})
    if graph.get("camera_ack_timeouts"):
        warnings.append(f"the camera waited {CAMERA_ACK_TIMEOUT_S:g} s in vain for detections "
                        f"{graph['camera_ack_timeouts']} time(s): frames were lost on the way to the detector")
    bad_exits = {name: status for name, status in graph_run.statuses.items() if status != 0}
    if bad_exits:
        warnings.append(f"node(s) exited with a non-zero status on SIGINT: {bad_exits}; logs in {log_dir}")
    return warnings


@command_line_tool(interrupted="interrupted; every node was stopped")
def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; 0 when it ran, 2 on bad input (missing bag, model, data), 1 when the graph failed."""
    args = parse_args(argv)
    try:
        result = run(args)
    except GraphError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    return print_and_save(format_table(result), result, args.out)


if __name__ == "__main__":
    sys.exit(main())
