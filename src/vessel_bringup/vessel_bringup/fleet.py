"""Many cameras on one computer, from one runner: ``./vessel graph --cameras cam0=SOURCE,cam1=SOURCE,...``.

Each camera is a graph under its own namespace (``/cam0/vessel/fix``, ...). How the nodes are put into processes is
the ``--processes`` choice: ``per-node`` (the default) runs every camera's graph as ``./vessel graph --namespace``
does, each node a process of its own; ``per-role`` keeps each camera's camera node a process of its own (a source
that fails stops only its camera) and runs every camera's detector in one host process (one network, one worker
taking each camera's newest image in turn) and every camera's tracker, fuser and GPS publisher in another
(``vessel_bringup.node_host``). Either way each node has its namespace, parameters, state and resume files and
counters, and ``--respawn`` restarts a failed process, a host with all its nodes, each from its state file. The
cameras share one set of parameter files (each node's block reaches it under its namespaced name); a camera with
files of its own runs as a graph of its own (``--namespace``).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from vessel_bringup.graph_nodes import GRAPH_NODES, GraphNode, camera_waits_for_detector
from vessel_bringup.graph_runner import GraphRunner, RunningNode
from vessel_common.errors import DataError
from vessel_common.graph_names import graph_namespace

PROCESS_MODES = ("per-node", "per-role")
"""How the nodes of many cameras go into processes (``--processes``)."""

HOST_DETECTORS = GraphNode("detectors", "vessel_bringup", "host", "every camera's detector: one network, one worker")
HOST_TRACKING = GraphNode("tracking", "vessel_bringup", "host", "every camera's tracker, fuser and GPS publisher")

CONSUMERS = tuple(node for node in reversed(GRAPH_NODES) if node.name != "camera")
"""The nodes after the camera, consumers first (so nothing the camera sends is missed)."""
CAMERA = next(node for node in GRAPH_NODES if node.name == "camera")


@dataclass(frozen=True)
class CameraSpec:
    """One camera of the fleet: its graph's namespace and its source."""

    name: str
    source: str

    @property
    def label(self) -> str:
        """The namespace without its slash (``cam0``), as in the logs and the figures."""
        return self.name.strip("/")


def parse_cameras(text: str) -> list[CameraSpec]:
    """``cam0=bags/video_13,cam1=bags/video_14`` -> the cameras; a malformed list raises DataError (one line)."""
    cameras = []
    for item in (part.strip() for part in text.split(",")):
        name, equals, source = item.partition("=")
        if not item or not equals or not name.strip() or not source.strip():
            raise DataError(f"--cameras: {item!r} is not NAME=SOURCE (e.g. cam0=bags/video_13,cam1=bags/video_14)")
        cameras.append(CameraSpec(graph_namespace(name), source.strip()))
    names = [camera.name for camera in cameras]
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise DataError(f"--cameras: {', '.join(twice)} named twice: each camera needs a namespace of its own")
    return cameras


@dataclass
class FleetProcess:
    """One process of the fleet: its runner, its name there, and the cameras whose nodes it holds."""

    runner: GraphRunner
    name: str
    cameras: tuple[str, ...]

    @property
    def running(self) -> RunningNode:
        """The process as it runs now (a restart replaces it)."""
        return self.runner.running[self.name]

    @property
    def label(self) -> str:
        """``cam0/tracker``; a process of several cameras' nodes is named by its role alone."""
        return f"{self.cameras[0].strip('/')}/{self.name}" if len(self.cameras) == 1 else self.name


class Fleet:
    """The processes of many cameras' graphs: started, watched, restarted and stopped together.

    ``respawn``: each node keeps the state and resume files ``./vessel graph --respawn`` gives it, in its camera's
    log folder, so that ``restart_failed`` brings a failed process back where it was.
    """

    def __init__(self, cameras: Sequence[CameraSpec], params_files: Sequence[Path], log_dir: Path | None = None,
                 mode: str = "per-node", env: dict[str, str] | None = None, echo: bool = False,
                 respawn: bool = False, state_files: bool = True):
        if mode not in PROCESS_MODES:
            raise DataError(f"--processes {mode}: choose {' or '.join(PROCESS_MODES)}")
        self.cameras = list(cameras)
        self.mode = mode
        self.respawn = respawn
        self.state_files = state_files
        self.runners = {camera.name: GraphRunner(params_files, log_dir=log_dir, env=env, echo=echo,
                                                 namespace=camera.name) for camera in self.cameras}
        self.hosts = GraphRunner(params_files, log_dir=log_dir, env=env, echo=echo) if mode == "per-role" else None
        self.processes: list[FleetProcess] = []

    def _all_runners(self) -> dict[str, GraphRunner]:
        return {**self.runners, **({"": self.hosts} if self.hosts is not None else {})}

    def _files(self, runner: GraphRunner, name: str) -> dict[str, str]:
        return runner.respawn_files(name, state_files=self.state_files) if self.respawn else {}

    def start_consumers(self, overrides: Callable[[CameraSpec], dict[str, object]] | None = None) -> None:
        """Start every camera's nodes but its camera, consumers first, each with ``overrides(camera)``."""
        hosted: dict[str, list[dict]] = {HOST_TRACKING.name: [], HOST_DETECTORS.name: []}
        for camera in self.cameras:
            runner = self.runners[camera.name]
            for node in CONSUMERS:
                values = {**(overrides(camera) if overrides else {}), **self._files(runner, node.name)}
                if self.hosts is None:
                    runner.start(node, values)
                    self.processes.append(FleetProcess(runner, node.name, (camera.name,)))
                    continue
                host = HOST_DETECTORS if node.name == "detector" else HOST_TRACKING
                hosted[host.name].append({"node": node.executable, "args": runner.node_arguments(node, values)})
        if self.hosts is not None:
            for host in (HOST_TRACKING, HOST_DETECTORS):  # consumers first
                spec = self.hosts.spec_path(host.name)
                spec.write_text(json.dumps(hosted[host.name], indent=1))
                self.hosts.start(host, {"spec": str(spec)})
                self.processes.append(FleetProcess(self.hosts, host.name, tuple(c.name for c in self.cameras)))

    def start_camera(self, camera: CameraSpec, overrides: dict[str, object]) -> FleetProcess:
        """Start one camera's camera node on its source, holding the first frame for its detector."""
        runner = self.runners[camera.name]
        values = {"source": camera.source, **overrides}
        values.update(camera_waits_for_detector(runner.file_parameters("camera"), values, local_detector=True))
        values.update(self._files(runner, CAMERA.name))
        runner.start(CAMERA, values)
        process = FleetProcess(runner, CAMERA.name, (camera.name,))
        self.processes.append(process)
        return process

    def of_camera(self, camera: str) -> list[FleetProcess]:
        """The processes that hold any node of ``camera`` (a shared one too)."""
        camera = graph_namespace(camera)
        return [process for process in self.processes if camera in process.cameras]

    def failed(self) -> list[FleetProcess]:
        """The processes that exited with a non-zero status."""
        return [process for process in self.processes
                if process.name in process.runner.failed()]

    def restart_failed(self, backoff: dict[str, dict[str, float]]) -> bool:
        """Restart every failed process as ``./vessel graph --respawn`` does; False once one failed too often."""
        from vessel_bringup.graph_runner import respawn_failed

        for camera, runner in self._all_runners().items():
            failed = runner.failed()
            if failed and not respawn_failed(runner, failed, backoff.setdefault(camera, {})):
                return False
        return True

    def stop(self) -> dict[str, int]:
        """Stop every process (SIGINT, then kill after a time-out): the cameras' first; exit statuses by label."""
        statuses = {}
        for camera, runner in self.runners.items():
            if CAMERA.name in runner.running:
                statuses.update({f"{camera.strip('/')}/{name}": status
                                 for name, status in runner.stop([CAMERA.name]).items()})
        for camera, runner in self._all_runners().items():
            statuses.update({f"{camera.strip('/')}/{name}".lstrip("/"): status
                             for name, status in runner.stop().items()})
        return statuses


def say(message: str) -> None:
    """The fleet's progress on stderr."""
    print(f"[graph] {message}", file=sys.stderr, flush=True)


def connect_all(fleet: Fleet, watcher, timeout_s: float, stop, with_recorder: bool) -> None:
    """Spin until every camera's graph is connected (``FleetWatcher.connected``); VesselError on a failure."""
    import time

    from vessel_common.errors import VesselError

    deadline = time.monotonic() + timeout_s
    waiting = [camera.name for camera in fleet.cameras]
    while waiting:
        waiting = [name for name in waiting if not watcher.connected(name, with_recorder=with_recorder)]
        watcher.spin(0.1)
        if stop.is_set():
            raise KeyboardInterrupt
        failed = fleet.failed()
        if failed:
            raise VesselError(f"{failed[0].label} stopped at start:\n{failed[0].runner.log_tail(failed[0].name)}")
        if time.monotonic() > deadline:
            raise VesselError(f"the graphs of {', '.join(waiting)} did not connect within {timeout_s:g} s; see the "
                              "nodes' logs")


def run_fleet(args, stop) -> int:
    """``./vessel graph --cameras ...``: start every camera's graph, then watch it until Ctrl-C or the sources end."""
    import time

    from vessel_bringup.fleet_watcher import FleetWatcher
    from vessel_bringup.graph_nodes import RECORDER
    from vessel_bringup.graph_runner import default_calibration_file, default_params_file
    from vessel_detect.source_spec import check_source

    if args.source or args.namespace or args.hot_standby:
        raise DataError("--cameras names every camera's source and namespace; --source, --namespace and "
                        "--hot-standby are for one camera's graph (run ./vessel graph --namespace NAME for it)")
    cameras = parse_cameras(args.cameras)
    for camera in cameras:  # before any node starts
        check_source(camera.source)
    params = [args.params or default_params_file(), args.calib or default_calibration_file()]
    fleet = Fleet(cameras, params, log_dir=args.log_dir, mode=args.processes, echo=True, respawn=args.respawn,
                  state_files=not args.no_state_files)
    watcher = None
    try:
        for camera in cameras:
            runner = fleet.runners[camera.name]
            if args.record is not None:
                output = {"output": str(args.record / camera.label), "use_sim_time": _sim_time(args, camera)}
                runner.start(RECORDER, {**output, **fleet._files(runner, RECORDER.name)})
                fleet.processes.append(FleetProcess(runner, RECORDER.name, (camera.name,)))
        fleet.start_consumers(lambda camera: {"use_sim_time": _sim_time(args, camera)})
        say(f"started the nodes after the camera of {len(cameras)} cameras in {len(fleet.processes)} processes "
            f"({args.processes}); the cameras follow, one process each")
        watcher = FleetWatcher([camera.name for camera in cameras])
        connect_all(fleet, watcher, args.connect_timeout, stop, with_recorder=args.record is not None)
        watcher.close()
        watcher = None
        say("every camera's graph is connected")
        for camera in cameras:
            rate = {"rate": args.rate} if args.rate is not None else {}
            fleet.start_camera(camera, {"use_sim_time": _sim_time(args, camera), **rate})
        backoff: dict[str, dict[str, float]] = {}
        while not stop.is_set():
            time.sleep(0.2)
            cameras_left = [p for p in fleet.processes if p.name == CAMERA.name and p.running.process.poll() is None]
            if args.exit_at_end and not cameras_left and not fleet.failed():
                say("every camera source ended")
                time.sleep(2.0)
                break
            if fleet.failed() and not (args.respawn and fleet.restart_failed(backoff)):
                say(f"{', '.join(p.label for p in fleet.failed())} failed: stopping")
                break
        statuses = fleet.stop()
        say("stopped: " + ", ".join(f"{k}={v}" for k, v in statuses.items()))
        return 0 if all(code == 0 for code in statuses.values()) else 1
    except BaseException:
        if watcher is not None:
            watcher.close()
        fleet.stop()
        raise


def _sim_time(args, camera: CameraSpec) -> bool:
    from vessel_bringup.graph_nodes import sim_time_for_source

    return sim_time_for_source(camera.source) if args.sim_time == "auto" else args.sim_time == "true"
