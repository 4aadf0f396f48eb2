"""``./vessel graph``: the whole node graph as separate processes, what the launch file does with ``ros2 launch``.

The nodes are ``vessel_bringup.graph_nodes.GRAPH_NODES``, the launch file's list; each is started with the same
parameter files, as ``ros2 run`` would. The demo and the benchmarks drive the graph through ``GraphRunner``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from vessel_bringup.graph_nodes import (
    GRAPH_NODES,
    MAX_RESTARTS,
    RECORDER,
    STANDBY_NODES,
    GraphNode,
    camera_waits_for_detector,
    file_parameters,
    respawn_files,
    restart_delay_s,
    restart_wanted,
    sim_time_for_source,
)
from vessel_bringup.graph_watcher import GraphWatcher
from vessel_common.command_line import command_line_tool
from vessel_common.errors import VesselError
from vessel_common.parameter_names import flatten
from vessel_common.paths import repo_root
from vessel_common.state_file import remove_state_file


def install_dir() -> Path:
    """The colcon install folder of the workspace."""
    return repo_root() / "ros2_ws" / "install"


def default_params_file() -> Path:
    """The graph's parameter file for the challenge camera."""
    return repo_root() / "config" / "aitas.yaml"


def default_calibration_file() -> Path:
    """The shipped calibration of the challenge camera (fitted on training videos 7-12)."""
    return repo_root() / "config" / "aitas_camera.yaml"


def executable_path(node: GraphNode) -> Path:
    """Where colcon installed a node (``lib/<pkg>/<exe>``, what ``ros2 run`` starts)."""
    path = install_dir() / node.package / "lib" / node.package / node.executable
    if not path.is_file():
        raise VesselError(f"{path} is not installed: run ./vessel setup (or colcon build) first")
    return path


@dataclass
class RunningNode:
    """A started node process and the file its output goes to."""

    node: GraphNode
    process: subprocess.Popen
    log_path: Path | None
    log_file: object = field(default=None, repr=False)
    parameters: dict[str, object] | None = None
    restarts: int = 0
    namespace: str = ""
    promote_until: float = 0.0


PROMOTION_SIGNALS_S = 30.0
"""How long a promoted spare is signalled again, in case it was still starting when promoted."""


def _ignore_sigusr1() -> None:
    signal.signal(signal.SIGUSR1, signal.SIG_IGN)


class GraphRunner:
    """Start nodes as processes with shared parameter files, stop them all with SIGINT like Ctrl-C."""

    def __init__(
        self,
        params_files: Sequence[Path],
        log_dir: Path | None = None,
        env: dict[str, str] | None = None,
        echo: bool = False,
    ):
        self.params_files = [Path(p) for p in params_files]
        for path in self.params_files:
            if not path.is_file():
                raise VesselError(f"parameter file {path} not found: pass an existing file with --params/--calib")
        self.log_dir = log_dir
        self.env = dict(env if env is not None else os.environ)
        self.echo = echo
        self.running: dict[str, RunningNode] = {}
        self.spares: dict[str, RunningNode] = {}
        self.spares_wanted: set[str] = set()
        self._spares_started = 0
        self._temp_dir: Path | None = None

    def start(self, node: GraphNode, parameters: dict[str, object] | None = None,
              append_log: bool = False) -> RunningNode:
        """Start one node with the parameter files plus per-run overrides.

        Overrides go into one more parameter file under the node's own name: a ``-p name:=value`` on the
        command line is a ``/**`` override, which a file's node-specific value would beat.
        """
        overrides = None
        if parameters:
            overrides = self._overrides_dir() / f"{node.name}.overrides.yaml"
            overrides.write_text(yaml.safe_dump({node.name: {"ros__parameters": dict(parameters)}}))
        running = self._spawn(node, self._command(node, overrides), node.name, append_log, parameters)
        previous = self.running.get(node.name)
        if previous is not None:
            running.restarts = previous.restarts
        self.running[node.name] = running
        return running

    def file_parameters(self, name: str, with_shared: bool = True) -> dict[str, object]:
        """The node's values in the parameter files, the later file winning (``/**`` blocks too, unless told not).

        What the node ``name`` reads from them, without the per-run overrides.
        """
        return file_parameters(self.params_files, name, with_shared)

    def start_spare(self, name: str) -> RunningNode:
        """Start a hot standby of the running node ``name`` (``vessel_common.node_state.Standby``).

        Same executable, parameters and topics, in its own namespace (``/standby_N``) with ``standby:=true``: it
        is discovered and runs its core on every message now, so promoting it costs neither start-up nor
        discovery. The node's blocks of the parameter files are copied under its namespaced name, which they
        would not match otherwise.
        """
        active = self.running[name]
        self._spares_started += 1
        namespace = f"/standby_{self._spares_started}"
        parameters = self.file_parameters(name, with_shared=False)  # the /** blocks apply as they are
        parameters.update(flatten(active.parameters or {}))
        parameters["standby"] = True
        label = f"{name}.standby_{self._spares_started}"
        spare_params = self._overrides_dir() / f"{label}.overrides.yaml"
        spare_params.write_text(yaml.safe_dump({f"{namespace}/{name}": {"ros__parameters": parameters}}))
        spare = self._spawn(active.node, self._command(active.node, spare_params, namespace), label, False,
                            active.parameters, ignore_sigusr1=True)
        spare.namespace = namespace
        self.spares[name] = spare
        return spare

    def promote_spare(self, name: str) -> RunningNode | None:
        """Make the hot standby of ``name`` the active node (SIGUSR1); None when it has none alive."""
        spare = self.spares.pop(name, None)
        if spare is None or spare.process.poll() is not None:
            return None
        old = self.running[name]
        if old.log_file is not None:
            old.log_file.close()
            old.log_file = None
        spare.restarts = old.restarts + 1
        spare.promote_until = time.monotonic() + PROMOTION_SIGNALS_S
        spare.process.send_signal(signal.SIGUSR1)
        self.running[name] = spare
        return spare

    def repeat_promotions(self) -> None:
        """Signal each recently promoted spare again (once a tick for ``PROMOTION_SIGNALS_S``).

        A spare still starting ignores SIGUSR1 until its node installs the handler (it is started with the
        signal ignored, so an early one cannot kill it); a promoted node ignores the repeats.
        """
        now = time.monotonic()
        for running in self.running.values():
            if running.promote_until > now and running.process.poll() is None:
                running.process.send_signal(signal.SIGUSR1)

    def _command(self, node: GraphNode, overrides: Path | None, namespace: str = "") -> list[str]:
        """The node's executable with the parameter files, then ``overrides``, optionally in ``namespace``."""
        args = [str(executable_path(node)), "--ros-args", "-r", f"__node:={node.name}"]
        if namespace:
            args += ["-r", f"__ns:={namespace}"]
        for path in [*self.params_files, *([overrides] if overrides is not None else [])]:
            args += ["--params-file", str(path)]
        return args

    def _spawn(self, node: GraphNode, args: list[str], label: str, append_log: bool,
               parameters: dict[str, object] | None, ignore_sigusr1: bool = False) -> RunningNode:
        log_file = None
        log_path = None
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            log_path = self.log_dir / f"{label}.log"
            log_file = open(log_path, "a" if append_log else "w")
        stdout = None if self.echo and log_file is None else (log_file or subprocess.DEVNULL)
        process = subprocess.Popen(args, env=self.env, stdout=stdout, stderr=subprocess.STDOUT,
                                   start_new_session=True,
                                   preexec_fn=_ignore_sigusr1 if ignore_sigusr1 else None)
        return RunningNode(node, process, log_path, log_file, dict(parameters) if parameters else None)

    def restart(self, name: str) -> RunningNode:
        """Start a node that exited again, with the same parameters (its log is appended to)."""
        old = self.running[name]
        if old.log_file is not None:
            old.log_file.close()
            old.log_file = None
        old.restarts += 1
        return self.start(old.node, old.parameters, append_log=True)

    def respawn_files(self, name: str, state_files: bool = True) -> dict[str, str]:
        """The state and resume files node ``name`` keeps under respawn (``graph_nodes.respawn_files``) as parameters.

        They are in the folder of the overrides, and removed first: a new run starts from the beginning.
        """
        files = respawn_files(name, self._overrides_dir(), state_files)
        for path in files.values():
            remove_state_file(Path(path))
        return files

    def _overrides_dir(self) -> Path:
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            return self.log_dir
        if self._temp_dir is None:
            self._temp_dir = Path(tempfile.mkdtemp(prefix="vessel_graph_"))
        return self._temp_dir

    def failed(self) -> list[str]:
        """Names of nodes that exited with a non-zero status (``graph_nodes.restart_wanted``)."""
        return [name for name, r in self.running.items()
                if r.process.poll() is not None and restart_wanted(r.process.returncode)]

    def wait(self, name: str, timeout_s: float | None = None) -> int | None:
        """Wait for one node to exit; its status, or None on time-out."""
        try:
            return self.running[name].process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, names: Sequence[str] | None = None, timeout_s: float = 15.0) -> dict[str, int]:
        """SIGINT the nodes (all by default, in reverse start order), wait, kill stragglers; exit statuses."""
        chosen = list(names) if names is not None else list(reversed(list(self.running)))
        processes = {name: self.running[name] for name in chosen}
        processes.update({f"{name} (standby)": self.spares.pop(name) for name in chosen if name in self.spares})
        for running in processes.values():
            if running.process.poll() is None:
                running.process.send_signal(signal.SIGINT)
        statuses = {}
        deadline = time.monotonic() + timeout_s
        for name, running in processes.items():
            try:
                statuses[name] = running.process.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                running.process.kill()
                statuses[name] = running.process.wait()
            if running.log_file is not None:
                running.log_file.close()
                running.log_file = None
        if names is None and self._temp_dir is not None:  # every node stopped: its overrides and state go too
            shutil.rmtree(self._temp_dir, ignore_errors=True)
            self._temp_dir = None
        return statuses

    def log_tail(self, name: str, lines: int = 20) -> str:
        """The last lines a node printed (for error messages)."""
        running = self.running.get(name)
        if running is None or running.log_path is None or not running.log_path.is_file():
            return ""
        if running.log_file is not None:
            running.log_file.flush()
        return "\n".join(running.log_path.read_text(errors="replace").splitlines()[-lines:])


class StopRequest:
    """What SIGINT and SIGTERM ask of the graph runner: to stop. Its loops poll ``is_set()``.

    The handler only assigns a plain attribute. It used to call ``threading.Event.set()``, which takes the event's
    lock: a second signal arriving while the first handler held it (Ctrl-C twice, or SIGTERM after Ctrl-C) ran the
    handler again in the same thread, which then waited for its own lock, and the runner hung for good with its
    nodes running. ``install``/``restore`` put the handler in place and the previous ones back.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signal: int | None = None  # the first signal received
        self._previous: dict[int, object] = {}

    def handler(self, signum: int, frame: object) -> None:
        """The signal handler: note the signal and return (no lock, no I/O: safe however often it interrupts)."""
        if self.signal is None:
            self.signal = signum

    def is_set(self) -> bool:
        """Whether a stop was asked for."""
        return self.signal is not None

    def install(self) -> None:
        """Handle SIGINT and SIGTERM with ``handler`` (in the main thread, where Python runs signal handlers)."""
        for signum in self.SIGNALS:
            self._previous.setdefault(signum, signal.signal(signum, self.handler))

    def restore(self) -> None:
        """Put back the handlers ``install`` replaced."""
        while self._previous:
            signum, previous = self._previous.popitem()
            signal.signal(signum, previous if previous is not None else signal.SIG_DFL)  # None: set outside Python


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


def _respawn(runner: GraphRunner, failed: list[str], backoff: dict[str, float]) -> bool:
    """Replace each failed node: by its hot standby at once, else by a restart after its back-off.

    False once a node has failed MAX_RESTARTS times.
    """
    now = time.monotonic()
    for name in failed:
        running = runner.running[name]
        if running.restarts >= MAX_RESTARTS:
            print(f"[graph] {name} failed {running.restarts + 1} times (exit {running.process.returncode}): not "
                  f"restarted again; see its log", file=sys.stderr)
            return False
        status = running.process.returncode
        spare = runner.promote_spare(name)
        if spare is not None:
            print(f"[graph] {name} exited with status {status}: promoted its hot standby {spare.namespace}/{name} "
                  f"(restart {spare.restarts} of at most {MAX_RESTARTS}); starting a new standby", file=sys.stderr)
            runner.start_spare(name)
            continue
        due = backoff.setdefault(name, now + restart_delay_s(running.restarts))
        if now < due:
            continue
        del backoff[name]
        print(f"[graph] {name} exited with status {status}: restarting it "
              f"(restart {running.restarts + 1} of at most {MAX_RESTARTS})", file=sys.stderr)
        runner.restart(name)
        if name in runner.spares_wanted:
            runner.start_spare(name)
    return True


def _replace_dead_spares(runner: GraphRunner, spare_failures: dict[str, int]) -> None:
    """Start a new hot standby for one that died (at most MAX_RESTARTS per node, then the node goes without)."""
    for name, spare in list(runner.spares.items()):
        if spare.process.poll() is None:
            continue
        del runner.spares[name]
        if spare.log_file is not None:
            spare.log_file.close()
        spare_failures[name] = spare_failures.get(name, 0) + 1
        if spare_failures[name] > MAX_RESTARTS:
            print(f"[graph] the hot standby of {name} failed {spare_failures[name]} times (exit "
                  f"{spare.process.returncode}): {name} runs without one; see {spare.log_path}", file=sys.stderr)
            runner.spares_wanted.discard(name)
            continue
        print(f"[graph] the hot standby of {name} exited with status {spare.process.returncode}: starting another",
              file=sys.stderr)
        runner.start_spare(name)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command line of ``./vessel graph``."""
    parser = argparse.ArgumentParser(
        prog="./vessel graph",
        description="Start the whole node graph as separate processes (what vessel_graph.launch.py does for "
        "ros2 launch). Ctrl-C stops every node.",
    )
    parser.add_argument("--source", help="camera source: a rosbag2 folder, .mcap, video file, image folder or "
                        "device:N (default: the camera node's parameter)")
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
        watcher = GraphWatcher()
        try:
            wait_until_connected(runner, watcher, args.connect_timeout, "see the nodes' output above",
                                 stop_requested, with_recorder=args.record is not None, spares=set(runner.spares))
        finally:
            watcher.close()
        print("[graph] every link from the detector to the GPS publisher is matched", file=sys.stderr)
    elif "detector" in wanted:  # the tracking runs elsewhere (another host or namespace)
        watcher = GraphWatcher()
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
        params = [args.params or default_params_file(), args.calib or default_calibration_file()]
        wanted = [name.strip() for name in args.nodes.split(",") if name.strip()]
        known = {node.name for node in GRAPH_NODES}
        unknown = [name for name in wanted if name not in known]
        if unknown:
            raise VesselError(f"unknown node(s) {unknown}: choose from {sorted(known)}")
        runner = GraphRunner(params, log_dir=args.log_dir, echo=True)
        if "camera" in wanted:  # before any node starts: the camera would fail only after the graph connected
            from vessel_detect.source_spec import check_source

            check_source(args.source or str(runner.file_parameters("camera").get("source") or ""))
        stop_requested.install()
        if args.hot_standby and not args.respawn:
            raise VesselError("--hot-standby needs --respawn: the spares replace nodes that die")
        sim_time = sim_time_for_source(args.source or "") if args.sim_time == "auto" else args.sim_time == "true"
        if sim_time:
            print("[graph] use_sim_time: the nodes follow the replay's /clock", file=sys.stderr)
        _start_consumers(args, runner, wanted, sim_time)
        if "camera" in wanted:
            _start_camera(args, runner, wanted, sim_time, stop_requested)
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
