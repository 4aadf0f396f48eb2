"""``./vessel bench cameras``: how many cameras one computer carries, every frame of each, at a camera's rate.

N cameras (namespaces ``cam0`` .. ``camN-1``) replay different challenge videos (bags ``video_13`` .. ``video_17``,
built when missing), each looped at ``--fps`` frames per second with its stamps moving on (``loop``,
``loop_restamp``), started together once every camera's graph is connected. The nodes run as ``./vessel graph
--cameras ... --processes MODE`` runs them (``vessel_bringup.fleet``), on the wall clock (no ``/clock``, as a live
camera). Every camera sends exactly its warm-up frames plus the measured ones (``max_frames``); one in-process
watcher (``FleetWatcher``) notes when each image and each ``/NAME/vessel/fix`` arrived, by header stamp.

Per camera and for the whole machine: frames offered (measured frames the camera sent), processed (those whose
fix came out), the fraction, latency from an image's arrival to its fix's, p50 and p95, resident memory of the
processes (a process serving several cameras shared out evenly) and CPU time per processed frame (a shared
process's shared out by frames processed), all from ``/proc``. The watcher reads every image too, which costs the
cameras a second reader. ``--kill cam1`` kills that camera's own processes (SIGKILL) mid-run: the other cameras
must carry on; the machine's figures leave a killed camera out, its own say when it was killed.

    ./vessel bench cameras --cameras 4 --fps 2 --minutes 1 --out out/bench/cameras_4.json
    ./vessel bench cameras --cameras 1,2,4,8 --fps 2 --minutes 1 --out out/bench/cameras.json --plot cameras.png
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from vessel_bringup.fleet import PROCESS_MODES, CameraSpec, Fleet, FleetProcess
from vessel_bringup.graph import default_calibration_file, default_params_file
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError, VesselError
from vessel_tools.bench import _domain_id, prepare_bag
from vessel_tools.bench_cameras_report import camera_figures, format_table, machine_figures, plot_curve
from vessel_tools.bench_report import log, machine_info, write_json
from vessel_tools.proc_monitor import ProcMonitor, node_pid

VIDEOS = (13, 14, 15, 16, 17)
DEFAULT_FPS = 2.0
DEFAULT_MINUTES = 1.0
DEFAULT_WARMUP_S = 15.0
DRAIN_S = 3.0
"""After the last frame: how long without a new fix before the run ends."""


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command line."""
    parser = argparse.ArgumentParser(prog="./vessel bench cameras", description=__doc__.split("\n\n")[0])
    parser.add_argument("--cameras", default="4", help="how many cameras, or a list run one after another "
                        "(e.g. 1,2,4,8; default 4)")
    parser.add_argument("--fps", type=float, default=DEFAULT_FPS, help=f"frames per second of each camera "
                        f"(default {DEFAULT_FPS:g})")
    parser.add_argument("--minutes", type=float, default=DEFAULT_MINUTES, help="measured time per run, after the "
                        f"warm-up (default {DEFAULT_MINUTES:g})")
    parser.add_argument("--warmup-s", type=float, default=DEFAULT_WARMUP_S, help="frames of this many seconds "
                        f"first, not measured (default {DEFAULT_WARMUP_S:g})")
    parser.add_argument("--processes", choices=PROCESS_MODES, default="per-node", help="how the nodes go into "
                        "processes, as ./vessel graph --processes (default per-node)")
    parser.add_argument("--kill", default="", metavar="CAMERA", help="kill this camera's own processes (e.g. cam1) "
                        "with SIGKILL mid-run, to show the others carry on")
    parser.add_argument("--kill-at-s", type=float, default=None, help="seconds into the measured time to kill "
                        "(default: half-way)")
    parser.add_argument("--data", type=Path, default=None, help="dataset folder to build missing bags from "
                        "(default $VESSEL_DATA or ../shared/aitas)")
    parser.add_argument("--bags", type=Path, default=None, help="folder of the video bags (default bags/)")
    parser.add_argument("--params", type=Path, default=None, help="graph parameter file (default config/aitas.yaml)")
    parser.add_argument("--calib", type=Path, default=None, help="calibration file (default "
                        "config/aitas_camera.yaml)")
    parser.add_argument("--out", type=Path, default=None, help="also write the figures to this JSON file (a list "
                        "for several runs)")
    parser.add_argument("--plot", type=Path, default=None, help="draw frames processed and memory against the "
                        "number of cameras into this PNG (with --out FILE.json of earlier runs: --from)")
    parser.add_argument("--from", dest="from_json", type=Path, nargs="*", default=[], help="only plot: the "
                        "JSON files of earlier runs")
    parser.add_argument("--log-dir", type=Path, default=None, help="node logs (default: a temporary folder)")
    args = parser.parse_args(argv)
    try:
        args.counts = [int(part) for part in args.cameras.split(",") if part.strip()]
    except ValueError:
        parser.error(f"--cameras must be a number or a list of numbers like 1,2,4,8, got {args.cameras!r}")
    if not args.counts or min(args.counts) < 1:
        parser.error(f"--cameras must be at least 1, got {args.cameras!r}")
    for name in ("fps", "minutes", "warmup_s"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0 or name == "warmup_s" and value == 0):
            parser.error(f"--{name.replace('_', '-')} must be a positive number, got {value}")
    if args.kill and args.kill.strip("/") not in {f"cam{i}" for i in range(max(args.counts))}:
        parser.error(f"--kill {args.kill}: no such camera (cam0 .. cam{max(args.counts) - 1})")
    return args


def frame_stamps(bag: Path, count: int) -> list[int]:
    """The stamps (ns) of the first ``count`` frames a camera sends looping over ``bag`` with restamped loops."""
    from vessel_detect.image_source import AuxMessage
    from vessel_detect.source_spec import open_source

    stamps = []
    with open_source(bag, aux_topics=[], loop=True, restamp_loops=True) as source:
        for item in source:
            if not isinstance(item, AuxMessage):
                stamps.append(item.stamp_ns)
                if len(stamps) == count:
                    break
    return stamps


def replay_rate(bag: Path, fps: float) -> float:
    """The camera's ``rate`` that plays ``bag`` at ``fps`` frames per second (the bag's mean frame interval)."""
    from vessel_detect.bag_reader import BagReader

    with BagReader(bag) as reader:
        stamps = [stamp for stamp, _ in reader.images()]
    if len(stamps) < 2:
        raise DataError(f"bag {bag} holds fewer than two images: rebuild it with ./vessel bag build")
    return fps * (stamps[-1] - stamps[0]) / (len(stamps) - 1)


@dataclass
class CameraRun:
    """One camera of a run: its bag, the frames it sends, and what became of them."""

    spec: CameraSpec
    video: int
    stamps: list[int]
    warmup: int
    rate: float
    killed_at_s: float | None = None
    ended: bool = False
    failed: list[str] = field(default_factory=list)


@dataclass
class Run:
    """One run's set-up: the cameras, the fleet of processes, the watcher and the /proc monitor."""

    cameras: list[CameraRun]
    fleet: Fleet
    watcher: object
    monitor: ProcMonitor
    labels: dict[str, FleetProcess] = field(default_factory=dict)


def _cameras(args, count: int) -> list[CameraRun]:
    """The cameras of a run of ``count``: camK replays video 13 + K mod 5."""
    frames = round(args.fps * 60.0 * args.minutes)
    warmup = round(args.fps * args.warmup_s)
    out = []
    for index in range(count):
        video = VIDEOS[index % len(VIDEOS)]
        bag = prepare_bag(video, args.data, args.bags)
        out.append(CameraRun(CameraSpec(f"/cam{index}", str(bag)), video, frame_stamps(bag, warmup + frames), warmup,
                             replay_rate(bag, args.fps)))
    return out


def _watch(run: Run, process: FleetProcess) -> None:
    """Add a started process to the /proc monitor under its label."""
    pid = node_pid(process.running.process.pid, process.running.node.executable)
    run.monitor.add(process.label, pid)
    run.labels[process.label] = process


def _start(args, cameras: list[CameraRun], domain_id: int, log_dir: Path) -> Run:
    """Start every camera's consumers, wait until all graphs are connected, then start the cameras together."""
    from vessel_bringup.fleet import connect_all
    from vessel_bringup.fleet_watcher import FleetWatcher
    from vessel_bringup.graph_runner import StopRequest

    params = [args.params or default_params_file(), args.calib or default_calibration_file()]
    fleet = Fleet([camera.spec for camera in cameras], params, log_dir=log_dir, mode=args.processes)
    watcher = FleetWatcher([camera.spec.name for camera in cameras], domain_id, log_images=True)
    run = Run(cameras, fleet, watcher, ProcMonitor())
    fleet.start_consumers(lambda camera: {"use_sim_time": False})
    for process in list(fleet.processes):
        _watch(run, process)
    log(f"{len(cameras)} camera(s), {len(fleet.processes)} processes before the cameras ({args.processes}); "
        f"waiting for every graph to connect (ROS_DOMAIN_ID {domain_id}, logs in {log_dir})")
    connect_all(fleet, watcher, 60.0 + 20.0 * len(cameras), StopRequest(), with_recorder=False)
    for camera in cameras:
        _watch(run, fleet.start_camera(camera.spec, {
            "rate": camera.rate, "loop": True, "loop_restamp": True, "max_frames": len(camera.stamps),
            "exit_at_end": True, "publish_clock": False, "use_sim_time": False,
            "wait_for_subscribers": 2,  # its detector and the watcher
        }))
    return run


def _kill(run: Run, name: str, at_s: float) -> None:
    """SIGKILL every process that holds only camera ``name``'s nodes."""
    camera = next(c for c in run.cameras if c.spec.label == name.strip("/"))
    for process in run.fleet.of_camera(camera.spec.name):
        if len(process.cameras) == 1 and process.running.process.poll() is None:
            os.killpg(process.running.process.pid, signal.SIGKILL)
    camera.killed_at_s = at_s
    log(f"killed the processes of {camera.spec.label} {at_s:.0f} s into the measured time")


def _measure(args, run: Run) -> float:
    """Run the cameras to their last frame (killing one on the way); the measured seconds."""
    started = time.monotonic()
    measured_from = started + args.warmup_s
    kill_at = measured_from + (args.kill_at_s if args.kill_at_s is not None else 30.0 * args.minutes)
    deadline = started + 1.5 * (args.warmup_s + 60.0 * args.minutes) + 60.0
    last_fixes, quiet_since = -1, time.monotonic()
    while time.monotonic() < deadline:
        run.watcher.spin(0.25)
        now = time.monotonic()
        run.monitor.sample(min_interval_s=2.0)
        if not run.monitor.window_open and now >= measured_from:
            run.monitor.open_window()
        if args.kill and now >= kill_at and not any(c.killed_at_s is not None for c in run.cameras):
            _kill(run, args.kill, now - measured_from)
        _note_exits(run)
        fixes = sum(len(log.fixes) for log in run.watcher.logs.values())
        if fixes != last_fixes:
            last_fixes, quiet_since = fixes, now
        if all(c.ended or c.killed_at_s is not None for c in run.cameras) and now - quiet_since > DRAIN_S:
            break
    else:
        log("the run ran past its deadline: cameras still sending are counted as far as they got")
    run.monitor.close_window()
    return time.monotonic() - measured_from


def _note_exits(run: Run) -> None:
    """Mark cameras whose camera process has ended; note every process that failed (the others carry on)."""
    for camera in run.cameras:
        for process in run.fleet.of_camera(camera.spec.name):
            status = process.running.process.poll()
            if status is None:
                continue
            if process.name == "camera":
                camera.ended = True
            if status != 0 and process.label not in camera.failed and camera.killed_at_s is None:
                camera.failed.append(process.label)
                log(f"{process.label} exited with status {status}; the other cameras carry on")


def run_once(args, count: int, domain_id: int) -> dict:
    """One run of ``count`` cameras; its figures."""
    machine = machine_info()
    cameras = _cameras(args, count)
    log_dir = (args.log_dir or Path(tempfile.mkdtemp(prefix="vessel_bench_cameras_"))) / f"n{count}"
    run = _start(args, cameras, domain_id, log_dir)
    try:
        log(f"{count} camera(s) at {args.fps:g} frames/s: {args.warmup_s:g} s warm-up, then "
            f"{args.minutes:g} min" + (f"; {args.kill} is killed half-way" if args.kill else ""))
        seconds = _measure(args, run)
        usage = {u.name: u for u in run.monitor.usage()}
    finally:
        statuses = run.fleet.stop()
        run.watcher.close()
    per_camera = {camera.spec.label: camera_figures(camera, run.watcher.logs[camera.spec.name], run, usage)
                  for camera in cameras}
    machine["load_average_after"] = list(os.getloadavg())
    return {
        "cameras": count, "fps": args.fps, "minutes": args.minutes, "warmup_s": args.warmup_s,
        "processes_mode": args.processes, "measured_s": seconds,
        **machine_figures(per_camera, run, usage),
        "per_camera": per_camera,
        "process_usage": {name: u.as_dict() for name, u in usage.items()},
        "exit_statuses": statuses, "machine": machine, "log_dir": str(log_dir),
    }


def run(args) -> list[dict]:
    """Every run asked for, one after another."""
    try:
        import rclpy  # noqa: F401

        import vessel_msgs.msg  # noqa: F401
    except ImportError as error:
        raise VesselError(f"the ROS 2 workspace is not sourced ({error}): run ./vessel bench cameras") from None
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    domain_id = _domain_id()
    results = []
    for count in args.counts:
        results.append(run_once(args, count, domain_id))
        print(format_table(results[-1]), flush=True)
    return results


@command_line_tool(interrupted="interrupted; every node was stopped")
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: 0 done, 2 bad input, 130 interrupted."""
    args = parse_args(argv)
    if args.from_json:
        if args.plot is None:
            raise DataError("--from plots earlier runs: give --plot FILE.png too")
        results = plot_inputs(args.from_json)
    else:
        results = run(args)
        if args.out is not None:
            write_json(args.out, results[0] if len(results) == 1 else results)
            log(f"figures written to {args.out}")
    if args.plot is not None:
        plot_curve(results, args.plot)
        log(f"curve drawn into {args.plot}")
    return 0


def plot_inputs(paths: Sequence[Path]) -> list[dict]:
    """The runs in JSON files this tool wrote (one run or a list each)."""
    import json

    results = []
    for path in paths:
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, ValueError) as error:
            raise DataError(f"{path}: not a JSON file of ./vessel bench cameras ({error})") from None
        for item in data if isinstance(data, list) else [data]:
            if not isinstance(item, dict) or "per_camera" not in item:
                raise DataError(f"{path}: not a result of ./vessel bench cameras (no per_camera)")
            results.append(item)
    return results


if __name__ == "__main__":
    sys.exit(main())
