"""The graph's nodes as processes: ``GraphRunner`` starts, restarts, promotes and stops them.

What ``./vessel graph`` (``vessel_bringup.graph``), the demo and the benchmarks start the nodes with; each is
started with the same parameter files, as ``ros2 run`` would.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from vessel_bringup.graph_nodes import (
    MAX_RESTARTS,
    GraphNode,
    clock_topic,
    file_parameters,
    namespaced_blocks,
    respawn_files,
    restart_delay_s,
    restart_wanted,
    standby_topics,
)
from vessel_common.errors import VesselError
from vessel_common.graph_names import file_label, graph_namespace
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
    """Start nodes as processes with shared parameter files, stop them all with SIGINT like Ctrl-C.

    ``namespace``: the graph's (one camera of several): every node in it, with its own ``/NAME/clock``
    (``graph_nodes.clock_topic``), its node blocks of the parameter files under its namespaced name, its logs,
    overrides and state files in ``log_dir/NAME``.
    """

    def __init__(
        self,
        params_files: Sequence[Path],
        log_dir: Path | None = None,
        env: dict[str, str] | None = None,
        echo: bool = False,
        namespace: str = "",
    ):
        self.params_files = [Path(p) for p in params_files]
        for path in self.params_files:
            if not path.is_file():
                raise VesselError(f"parameter file {path} not found: pass an existing file with --params/--calib")
        self.namespace = graph_namespace(namespace)
        label = file_label(self.namespace)
        self.log_dir = log_dir / label if log_dir is not None and label else log_dir
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
        running = self._spawn(node, self._command(node, self._overrides(node, parameters)), node.name, append_log,
                              parameters)
        previous = self.running.get(node.name)
        if previous is not None:
            running.restarts = previous.restarts
        self.running[node.name] = running
        return running

    def _overrides(self, node: GraphNode, parameters: dict[str, object] | None) -> Path | None:
        """The node's overrides file (its node blocks too under a namespace), written; None when it needs none."""
        if not (parameters or self.namespace):
            return None
        overrides = self._overrides_dir() / f"{node.name}.overrides.yaml"
        blocks = (namespaced_blocks(self.params_files, node.name, self.namespace, parameters) if self.namespace
                  else {node.name: {"ros__parameters": dict(parameters)}})
        overrides.write_text(yaml.safe_dump(blocks))
        return overrides

    def spec_path(self, name: str) -> Path:
        """Where the spec of host process ``name`` goes (beside the overrides, removed with them)."""
        return self._overrides_dir() / f"{name}.spec.json"

    def node_arguments(self, node: GraphNode, parameters: dict[str, object] | None = None) -> list[str]:
        """The ``--ros-args`` ``start`` would give the node, for a host process that runs it among others."""
        return self._command(node, self._overrides(node, parameters))[1:]

    def file_parameters(self, name: str, with_shared: bool = True) -> dict[str, object]:
        """The node's values in the parameter files, the later file winning (``/**`` blocks too, unless told not).

        What the node ``name`` reads from them, without the per-run overrides.
        """
        return file_parameters(self.params_files, name, with_shared)

    def start_spare(self, name: str) -> RunningNode:
        """Start a hot standby of the running node ``name`` (``vessel_common.node_state.Standby``).

        Same executable, parameters and topics, in its own namespace (``/standby_N`` in the graph's) with
        ``standby:=true``: it is discovered and runs its core on every message now, so promoting it costs neither
        start-up nor discovery. The node's blocks of the parameter files are copied under its namespaced name, which
        they would not match otherwise, and its topics are given as the active node's resolved names.
        """
        active = self.running[name]
        self._spares_started += 1
        namespace = f"{self.namespace}/standby_{self._spares_started}"
        parameters = self.file_parameters(name, with_shared=False)  # the /** blocks apply as they are
        parameters.update(flatten(active.parameters or {}))
        parameters.update(standby_topics(name, parameters, self.namespace))
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
        """The node's executable with the parameter files, then ``overrides``, in ``namespace`` (else the graph's)."""
        args = [str(executable_path(node)), "--ros-args", "-r", f"__node:={node.name}"]
        namespace = namespace or self.namespace
        if namespace:
            args += ["-r", f"__ns:={namespace}"]
        if self.namespace:
            args += ["-r", f"/clock:={clock_topic(self.namespace)}"]
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


def respawn_failed(runner: GraphRunner, failed: list[str], backoff: dict[str, float]) -> bool:
    """Replace each failed node: by its hot standby at once, else by a restart after its back-off.

    False once a node has failed MAX_RESTARTS times.
    """
    now = time.monotonic()
    for name in failed:
        running = runner.running[name]
        label = f"{runner.namespace}/{name}".lstrip("/")  # cam0/tracker: which camera's, when several run
        if running.restarts >= MAX_RESTARTS:
            print(f"[graph] {label} failed {running.restarts + 1} times (exit {running.process.returncode}): not "
                  f"restarted again; see its log", file=sys.stderr)
            return False
        status = running.process.returncode
        spare = runner.promote_spare(name)
        if spare is not None:
            print(f"[graph] {label} exited with status {status}: promoted its hot standby {spare.namespace}/{name} "
                  f"(restart {spare.restarts} of at most {MAX_RESTARTS}); starting a new standby", file=sys.stderr)
            runner.start_spare(name)
            continue
        due = backoff.setdefault(name, now + restart_delay_s(running.restarts))
        if now < due:
            continue
        del backoff[name]
        print(f"[graph] {label} exited with status {status}: restarting it "
              f"(restart {running.restarts + 1} of at most {MAX_RESTARTS})", file=sys.stderr)
        runner.restart(name)
        if name in runner.spares_wanted:
            runner.start_spare(name)
    return True


def replace_dead_spares(runner: GraphRunner, spare_failures: dict[str, int]) -> None:
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
