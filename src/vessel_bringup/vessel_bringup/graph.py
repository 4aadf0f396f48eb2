"""``./vessel graph``: the whole node graph as separate processes, what the launch file does with ``ros2 launch``.

The nodes are ``vessel_bringup.graph_nodes.GRAPH_NODES``, the launch file's list; each is started with the same
parameter files, as ``ros2 run`` would. The demo and the benchmarks drive the graph through ``GraphRunner``
(``vessel_bringup.graph_runner``).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

from vessel_bringup.fleet import PROCESS_MODES, run_fleet
from vessel_bringup.graph_nodes import (
    GRAPH_NODES,
    RECORDER,
    STANDBY_NODES,
    GraphNode,  # noqa: F401  (as the tools import it from here)
    camera_waits_for_detector,
    clock_topic,
    restart_wanted,
    sim_time_for_source,
)
from vessel_bringup.graph_runner import (  # noqa: F401  (the runner's names, as the tools import them from here)
    GraphRunner,
    RunningNode,
    StopRequest,
    default_calibration_file,
    default_params_file,
    executable_path,
    install_dir,
    repo_root,
)
from vessel_bringup.graph_runner import replace_dead_spares as _replace_dead_spares
from vessel_bringup.graph_runner import respawn_failed as _respawn
from vessel_bringup.graph_watcher import GraphWatcher
from vessel_common.command_line import command_line_tool
from vessel_common.errors import VesselError


def wait_until_connected(runner: GraphRunner, watcher: GraphWatcher, timeout_s: float, where: str,
                         stop: StopRequest | threading.Event | None = None, **links) -> None:
    """Spin ``watcher`` until the graph is connected (``GraphWatcher.connected(**links)``), before the camera.

    A frame published before every link is matched is lost without a count; this is what keeps the first frames.
    Raises VesselError naming the node that stopped meanwhile, or the time-out (``where``: where to look), and
    KeyboardInterrupt once ``stop`` is set (Ctrl-C while waiting).
    """
    deadline = time.monotonic() + timeout_s
    detector_only = links.pop("detector_only", False)
    # Across hosts the readers are discovered one by one: the state must hold for a while, not for one look.
    settle_s = 2.0 if detector_only else 0.0
    connected_since = None
    while True:
        if watcher.detector_connected() if detector_only else watcher.connected(**links):
            connected_since = connected_since if connected_since is not None else time.monotonic()
            if time.monotonic() - connected_since >= settle_s:
                return
        else:
            connected_since = None
        watcher.spin(0.1)
        if stop is not None and stop.is_set():
            raise KeyboardInterrupt
        failed = runner.failed()
        if failed:
            raise VesselError(f"node(s) {failed} stopped at start:\n{runner.log_tail(failed[0])}")
        if time.monotonic() > deadline:
            raise VesselError(f"the graph did not connect within {timeout_s:g} s; {where}")


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command line of ``./vessel graph``."""
    parser = argparse.ArgumentParser(
        prog="./vessel graph",
        description="Start the whole node graph as separate processes (what vessel_graph.launch.py does for "
        "ros2 launch). Ctrl-C stops every node.",
    )
    parser.add_argument("--source", help="camera source: a rosbag2 folder, .mcap, video file, image folder or "
                        "device:N (default: the camera node's parameter)")
    parser.add_argument("--namespace", default="", help="run the graph under this namespace, one camera of several "
                        "in one ROS domain: its topics become /NAME/vessel/fix, ..., its clock /NAME/clock, its "
                        "logs and state files go to LOG_DIR/NAME (default: none, /vessel/fix)")
    parser.add_argument("--cameras", default="", help="several cameras from this one runner: NAME=SOURCE,... "
                        "(e.g. cam0=bags/video_13,cam1=bags/video_14), each a graph under its namespace NAME, "
                        "sharing --params and --calib")
    parser.add_argument("--processes", choices=PROCESS_MODES, default="per-node",
                        help="with --cameras: per-node (default), every node a process of its own; per-role, a "
                        "process per camera for its camera node, one for every camera's detector (one network, one "
                        "worker taking each camera's newest image in turn), one for every camera's tracker, fuser "
                        "and GPS publisher")
    parser.add_argument("--params", type=Path, default=None, help="graph parameter file (default config/aitas.yaml)")
    parser.add_argument("--calib", type=Path, default=None,
                        help="calibration parameter file (default config/aitas_camera.yaml)")
    parser.add_argument("--rate", type=float, default=None, help="replay rate: 1 real time, 10, 0 = as fast as "
                        "the graph consumes")
    parser.add_argument("--nodes", default=",".join(n.name for n in GRAPH_NODES),
                        help="comma-separated subset of nodes to start (default: all)")
    parser.add_argument("--record", type=Path, default=None, help="also record the outputs into this bag folder")
    parser.add_argument("--log-dir", type=Path, default=None, help="write each node's output to DIR/<node>.log "
                        "instead of the terminal")
    parser.add_argument("--exit-at-end", action="store_true", help="stop the graph when the camera source ends")
    parser.add_argument("--sim-time", choices=("auto", "true", "false"), default="auto",
                        help="use_sim_time of every node: auto (default) follows the replay's /clock for a recorded "
                        "source (bag, video, folder), so messages, /diagnostics and a --record are all in its time")
    parser.add_argument("--respawn", action="store_true",
                        help="restart a node that fails (at once, then after 0.5 s doubling to 8 s, at most 5 "
                        "times), as respawn:=true does for ros2 launch; the tracker and the fuser keep a state "
                        "file, so a restarted one carries on from its tracks, the camera carries on after the last "
                        "frame it sent, the recorder into the next part of --record (RECORD.1, ...)")
    parser.add_argument("--hot-standby", action="store_true",
                        help="with --respawn: run a spare tracker, fuser and GPS publisher that process every message "
                        "without publishing, and promote one at once when its node dies (no start-up, no "
                        "rediscovery), then start a new spare")
    parser.add_argument("--no-state-files", action="store_true",
                        help="with --respawn: restart the tracker and the fuser cold, without a state file")
    parser.add_argument("--connect-timeout", type=float, default=60.0,
                        help="seconds to wait for every link of the graph to be matched before the camera starts "
                        "(frames sent earlier would be lost)")
    parser.add_argument("--no-wait", action="store_true",
                        help="start the camera at once, without waiting for the links (frames sent before a reader "
                        "matched are lost): e.g. --nodes camera,detector with no tracker anywhere yet")
    return parser.parse_args(argv)


def _start_consumers(args: argparse.Namespace, runner: GraphRunner, wanted: list[str], sim_time: bool) -> None:
    """Start the recorder and every wanted node but the camera, consumers first, with their hot standbys."""
    known = {node.name: node for node in GRAPH_NODES}
    if args.record is not None:
        overrides = {"output": str(args.record), "use_sim_time": sim_time}
        if args.respawn:  # a restarted recorder continues into the next part, RECORD.1, ...
            overrides.update(runner.respawn_files(RECORDER.name))
        runner.start(RECORDER, overrides)
    for name in reversed(wanted):  # consumers first, so nothing the camera sends is missed
        if name == "camera":
            continue
        overrides = {"use_sim_time": sim_time}
        if args.respawn:
            overrides.update(runner.respawn_files(name, state_files=not args.no_state_files))
        runner.start(known[name], overrides)
        print(f"[graph] started {name}: {known[name].role}", file=sys.stderr)
        if args.hot_standby and name in STANDBY_NODES:
            runner.spares_wanted.add(name)
            spare = runner.start_spare(name)
            print(f"[graph] started {spare.namespace}/{name}: its hot standby", file=sys.stderr)


def _start_camera(args: argparse.Namespace, runner: GraphRunner, wanted: list[str], sim_time: bool,
                  stop_requested: StopRequest) -> None:
    """Start the camera once its readers have matched (unless ``--no-wait``); KeyboardInterrupt on a stop."""
    camera = next(node for node in GRAPH_NODES if node.name == "camera")
    if args.no_wait:
        print("[graph] --no-wait: the camera starts before its readers have matched", file=sys.stderr)
    elif set(wanted) >= {"detector", "tracker", "fuser", "gps_publisher"}:
        watcher = GraphWatcher(namespace=runner.namespace)
        try:
            wait_until_connected(runner, watcher, args.connect_timeout, "see the nodes' output above",
                                 stop_requested, with_recorder=args.record is not None, spares=set(runner.spares))
        finally:
            watcher.close()
        print("[graph] every link from the detector to the GPS publisher is matched", file=sys.stderr)
    elif "detector" in wanted:  # the tracking runs elsewhere (another host or namespace)
        watcher = GraphWatcher(namespace=runner.namespace)
        try:
            wait_until_connected(runner, watcher, args.connect_timeout, "is the tracker running and "
                                 "reachable (same ROS_DOMAIN_ID and network)?", stop_requested, detector_only=True)
        finally:
            watcher.close()
        print("[graph] the detector's output is matched by a tracker", file=sys.stderr)
    overrides = {"use_sim_time": sim_time}
    if args.source:
        overrides["source"] = args.source
    if args.rate is not None:
        overrides["rate"] = args.rate
    overrides.update(camera_waits_for_detector(runner.file_parameters("camera"), overrides,
                                               "detector" in wanted and not args.no_wait))
    if args.respawn:  # a restarted camera carries on after the last frame it sent
        overrides.update(runner.respawn_files(camera.name))
    runner.start(camera, overrides)
    print(f"[graph] started camera: {camera.role}", file=sys.stderr)


def start_graph_nodes(args: argparse.Namespace, runner: GraphRunner, wanted: list[str], sim_time: bool,
                      stop_requested: StopRequest) -> None:
    """Start the ``wanted`` nodes as ``./vessel graph`` does: the recorder and the consumers, then the camera.

    The camera comes last and waits until its readers have matched (unless ``--no-wait``): a frame sent earlier
    would be lost without a count. A tool that starts the graph for itself (``./vessel view --source``) passes
    ``./vessel graph``'s command line (``parse_args``) so that its graph is this very one. Raises VesselError naming
    a node that stopped at start, or the time-out, and KeyboardInterrupt once ``stop_requested`` is set while the
    camera waits.
    """
    _start_consumers(args, runner, wanted, sim_time)
    if "camera" in wanted:
        _start_camera(args, runner, wanted, sim_time, stop_requested)


def _source_ended(runner: GraphRunner, respawn: bool) -> bool:
    """Whether the camera exited at the end of its source: under respawn only with status 0 (else it is restarted)."""
    camera = runner.running.get("camera")
    status = camera.process.poll() if camera is not None else None
    return status is not None and not (respawn and restart_wanted(status))


def _run_until_stopped(args: argparse.Namespace, runner: GraphRunner, stop_requested: StopRequest) -> None:
    """Watch the nodes (respawn, replace spares) until a stop is asked for, the source ends or a node fails."""
    backoff: dict[str, float] = {}  # node -> monotonic time before which it is not restarted
    spare_failures: dict[str, int] = {}
    while not stop_requested.is_set():
        time.sleep(0.2)
        if args.exit_at_end and _source_ended(runner, args.respawn):
            print("[graph] camera source ended", file=sys.stderr)
            time.sleep(2.0)
            break
        _replace_dead_spares(runner, spare_failures)
        runner.repeat_promotions()
        failed = runner.failed()
        if failed and args.respawn:
            if not _respawn(runner, failed, backoff):
                break
        elif failed:
            print(f"[graph] node(s) exited with an error: {failed}", file=sys.stderr)
            break
    if stop_requested.is_set():
        print(f"[graph] {signal.Signals(stop_requested.signal).name}: stopping every node", file=sys.stderr)


def _say_recording_parts(record: Path | None) -> None:
    """Name the parts of a recording that a restarted recorder continued (``resume_files.recording_parts``)."""
    if record is None:
        return
    from vessel_detect.resume_files import recording_parts

    parts = recording_parts(record)
    if len(parts) > 1:
        print(f"[graph] the recording is in {len(parts)} bags, a restarted recorder continuing into the later ones: "
              + ", ".join(map(str, parts)), file=sys.stderr)


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """Run the graph until Ctrl-C (or the end of the source with --exit-at-end)."""
    args = parse_args(argv)
    runner: GraphRunner | None = None
    stop_requested = StopRequest()
    try:
        if args.cameras:  # several cameras' graphs from this runner
            stop_requested.install()
            return run_fleet(args, stop_requested)
        params = [args.params or default_params_file(), args.calib or default_calibration_file()]
        wanted = [name.strip() for name in args.nodes.split(",") if name.strip()]
        known = {node.name for node in GRAPH_NODES}
        unknown = [name for name in wanted if name not in known]
        if unknown:
            raise VesselError(f"unknown node(s) {unknown}: choose from {sorted(known)}")
        runner = GraphRunner(params, log_dir=args.log_dir, echo=True, namespace=args.namespace)
        if runner.namespace:
            print(f"[graph] namespace {runner.namespace}: the fix on {runner.namespace}/vessel/fix, the clock on "
                  f"{clock_topic(runner.namespace)}", file=sys.stderr)
        if "camera" in wanted:  # before any node starts: the camera would fail only after the graph connected
            from vessel_detect.source_spec import check_source

            check_source(args.source or str(runner.file_parameters("camera").get("source") or ""))
        stop_requested.install()
        if args.hot_standby and not args.respawn:
            raise VesselError("--hot-standby needs --respawn: the spares replace nodes that die")
        sim_time = sim_time_for_source(args.source or "") if args.sim_time == "auto" else args.sim_time == "true"
        if sim_time:
            print("[graph] use_sim_time: the nodes follow the replay's /clock", file=sys.stderr)
        start_graph_nodes(args, runner, wanted, sim_time, stop_requested)
        _run_until_stopped(args, runner, stop_requested)
        statuses = runner.stop()
        print("[graph] stopped: " + ", ".join(f"{k}={v}" for k, v in statuses.items()), file=sys.stderr)
        _say_recording_parts(args.record)
        return 0 if all(code == 0 for name, code in statuses.items() if not name.endswith("(standby)")) else 1
    except (VesselError, KeyboardInterrupt, OSError):
        if runner is not None:  # never leave started nodes behind
            runner.stop()
        raise
    finally:
        stop_requested.restore()

if __name__ == "__main__":
    sys.exit(main())
