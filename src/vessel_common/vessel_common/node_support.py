"""What every node of the project shares: start-up and shutdown, parameters, QoS, health reporting.

The cores stay ROS-free; nodes and the ROS plumbing of the other packages build on this. Nodes use it so that
they all behave the same way: parameters declared with descriptors, a clean exit (status 0, no traceback) on
SIGINT, problems logged once per kind, counted and published on ``/diagnostics``, and configuration errors
that stop the node at start with one clear line.
"""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from vessel_common.errors import DataError, VesselError, file_system_problem
from vessel_common.imports import import_serialized
from vessel_common.parameter_names import flatten, is_rcl_parameter, with_closest
from vessel_common.state_file import STANDBY_DESCRIPTION, STATE_PARAMETERS, StateFile

SENSOR_DATA_QOS = qos_profile_sensor_data
"""Best effort, keep last 5: images and other high-rate data where the newest sample matters most."""

LATCHED_QOS = QoSProfile(
    depth=1,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""Reliable and transient local: a late subscriber still gets the last sample (e.g. the camera's fix)."""


def image_qos_profile(name: str, reliable_depth: int = 5) -> QoSProfile:
    """The QoS of image topics named by an ``image_qos`` parameter: ``sensor_data`` or ``reliable``.

    ``reliable_depth``: the history kept when reliable (a publisher keeps more, so a slow reader can catch up).
    """
    if name == "sensor_data":
        return SENSOR_DATA_QOS
    if name == "reliable":
        return reliable_qos(reliable_depth)
    raise VesselError(f"image_qos '{name}' unknown: use sensor_data or reliable")


def reliable_qos(depth: int = 10) -> QoSProfile:
    """Reliable, volatile, keep last ``depth``: detections, tracks and fixes, where no message may be lost."""
    return QoSProfile(
        depth=depth,
        history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


def stamp_to_sec(stamp: Time) -> float:
    """Seconds since the epoch of a ``builtin_interfaces/Time``."""
    return stamp.sec + stamp.nanosec * 1e-9


def sec_to_stamp(seconds: float) -> Time:
    """A ``builtin_interfaces/Time`` for seconds since the epoch (rounded to the nanosecond)."""
    total_ns = round(seconds * 1e9)
    return Time(sec=total_ns // 1_000_000_000, nanosec=total_ns % 1_000_000_000)


_command_line: list[str] = []
"""The arguments ``run_node`` started the node with (their ``-p`` assignments win over parameter files)."""


def command_line_parameters(args: Sequence[str], node_name: str) -> dict[str, str]:
    """``name -> value text`` of the ``-p name:=value`` / ``--param name:=value`` assignments for ``node_name``.

    Only the ``--ros-args`` parts count (up to ``--`` or the next ``--ros-args``); ``-p other_node:name:=value``
    is for another node. rcl files these under ``/**``, which a node's own block in a parameter file beats;
    a ROS user who types ``-p`` expects it to win, so ``declare_parameter`` applies them last.
    """
    found: dict[str, str] = {}
    for assignment in _ros_arguments(args, ("-p", "--param")):
        if ":=" not in assignment:
            continue
        name, value = assignment.split(":=", 1)
        target, _, bare = name.rpartition(":")
        if target and target.lstrip("/") != node_name:
            continue
        found[bare] = value
    return found


def _ros_arguments(args: Sequence[str], options: tuple[str, ...]):
    """The argument after each of ``options`` inside the ``--ros-args`` parts of ``args`` (up to ``--``)."""
    inside = False
    args = list(args)
    for i, arg in enumerate(args):
        if arg == "--ros-args":
            inside = True
        elif arg == "--":
            inside = False
        elif inside and arg in options and i + 1 < len(args):
            yield args[i + 1]


def _command_line_value(name: str, text: str) -> Any:
    """The value of ``-p name:=text`` as rcl reads it (YAML), as a type ROS parameters hold."""
    import yaml

    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        value = text
    if value is None:
        raise VesselError(f"-p {name}:={text}: no value; give one, e.g. -p {name}:=1.0")
    return value


def declare_parameter(
    node: Node,
    name: str,
    default: Any,
    description: str,
    *,
    read_only: bool = False,
    float_range: tuple[float, float] | None = None,
    int_range: tuple[int, int] | None = None,
    additional_constraints: str = "",
) -> Any:
    """Declare one parameter with a descriptor and return its value.

    Ranges are enforced by ROS when the parameter is set at start (``--params-file``, ``-p``) or later; a value
    out of range or of the wrong type stops the node with one line naming the parameter. A ``-p`` on the command
    line wins over the parameter files, even over the node's own block in them.
    """
    from rclpy.exceptions import ParameterException
    from rclpy.parameter import Parameter


    given = command_line_parameters(_command_line, node.get_name()).get(name)
    overrides = getattr(node, "_parameter_overrides", None)
    if given is not None and overrides is not None:
        try:
            overrides[name] = Parameter(name, value=_command_line_value(name, given))
        except (TypeError, ValueError) as error:
            raise DataError(f"-p {name}:={given}: {error}") from None
    descriptor = ParameterDescriptor(
        description=description,
        read_only=read_only,
        additional_constraints=additional_constraints,
    )
    if float_range is not None:
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(float_range[0]), to_value=float(float_range[1]), step=0.0)
        ]
    if int_range is not None:
        descriptor.integer_range = [
            IntegerRange(from_value=int(int_range[0]), to_value=int(int_range[1]), step=0)
        ]
    try:
        return node.declare_parameter(name, default, descriptor).value
    except (ParameterException, TypeError, ValueError) as error:
        constraint = ""
        if float_range is not None or int_range is not None:
            low, high = float_range if float_range is not None else int_range
            constraint = f" (allowed: {low:g} to {high:g})"
        raise DataError(f"parameter {name} of {node.get_name()}: {error}{constraint}; fix the value in the "
                        f"parameter file or on the command line (default {default!r})") from None


def _apply_command_line_sim_time(node: Node, args: Sequence[str]) -> None:
    """``-p use_sim_time:=...`` wins over the parameter files too (rclpy declares it before any of ours)."""
    from rclpy.parameter import Parameter


    given = command_line_parameters(args, node.get_name()).get("use_sim_time")
    if given is None:
        return
    value = _command_line_value("use_sim_time", given)
    if not isinstance(value, bool):
        raise DataError(f"-p use_sim_time:={given}: use true or false")
    if node.get_parameter("use_sim_time").value != value:
        node.set_parameters([Parameter("use_sim_time", value=value)])


def unknown_command_line_parameters(node: Node, args: Sequence[str]) -> list[str]:
    """``-p`` names given for ``node`` that it does not declare (a misspelling would otherwise pass silently)."""
    return _undeclared(node, command_line_parameters(args, node.get_name()))


def _undeclared(node: Node, names) -> list[str]:
    """The ``names`` the node does not declare (``qos_overrides.*`` are rcl's, read when a publisher is made)."""
    return [name for name in names if not node.has_parameter(name) and not is_rcl_parameter(name)]


def params_file_parameters(args: Sequence[str], node_fqn: str) -> dict[str, str]:
    """Parameter names that the ``--params-file`` files in ``args`` give the node ``node_fqn`` -> the file.

    Only a block that names this node (``tracker``, ``/tracker``, ``/ns/tracker``, ``/**/tracker``, or the node
    nested under its namespace), not ``/**``, which every node reads and no node owns. A file that cannot be read
    is left to rcl, which has already refused it.
    """
    import yaml

    base = node_fqn.rsplit("/", 1)[-1]
    found: dict[str, str] = {}

    def blocks(mapping: Any, parts: tuple[str, ...]):
        for key, body in mapping.items():
            if not isinstance(body, dict):
                continue
            if key == "ros__parameters":
                yield "/" + "/".join(parts), body
            else:
                yield from blocks(body, parts + tuple(p for p in str(key).split("/") if p))

    for path in _ros_arguments(args, ("--params-file",)):
        try:
            with open(path, encoding="utf-8") as stream:
                document = yaml.safe_load(stream)
        except (OSError, UnicodeDecodeError, yaml.YAMLError):
            continue
        if not isinstance(document, dict):
            continue
        for name, body in blocks(document, ()):
            if name in (node_fqn, f"/**/{base}"):
                found.update(dict.fromkeys(flatten(body), path))
    return found


def unknown_params_file_parameters(node: Node, args: Sequence[str]) -> dict[str, str]:
    """Names a parameter file gives ``node`` in its own block that it does not declare -> the file.

    A stand-in for another node (the replay detector) reads that node's block and names what it ignores there in
    ``foreign_parameters``.
    """
    given = params_file_parameters(args, node.get_fully_qualified_name())
    foreign = getattr(node, "foreign_parameters", frozenset()) if given else frozenset()
    return {name: given[name] for name in _undeclared(node, given) if name not in foreign}


def _misspelt(node: Node, names: Sequence[str]) -> str:
    """``name (did you mean close?)`` for each name, against the node's declared parameters."""
    return ", ".join(with_closest(name, node._parameters) for name in names)


def steady_timer(node: Node, period_s: float, callback: Callable[[], None]):
    """A timer on the steady clock, whatever ``use_sim_time`` says.

    Housekeeping (reports, discovery, pacing) must run in real time: under ``use_sim_time`` the node clock
    stands still until a replay's first ``/clock`` (and the graph waits for these reports before it starts the
    camera), then jumps with it.
    """
    from rclpy.clock import Clock, ClockType

    return node.create_timer(period_s, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))


#: Diagnostics key prefix of ``NodeHealth.watch_subscribers``: ``matched_subscribers./vessel/tracks`` = "3".
MATCHED_SUBSCRIBERS = "matched_subscribers."


def matched_subscribers(array, root_namespace_only: bool = False) -> dict[str, int]:
    """Subscriptions matched by each topic's publisher, from a ``DiagnosticArray`` of ``NodeHealth`` nodes.

    ``root_namespace_only``: leave out nodes in a namespace (a hot standby, ``standby_N/tracker``), whose
    publishers carry nothing until promoted.
    """
    found: dict[str, int] = {}
    for status in array.status:
        if root_namespace_only and "/" in status.name:
            continue
        for item in status.values:
            if item.key.startswith(MATCHED_SUBSCRIBERS) and item.value.isdigit():
                found[item.key[len(MATCHED_SUBSCRIBERS):]] = int(item.value)
    return found


class NodeHealth:
    """Counts a node's problems, logs each kind once, and publishes them on ``/diagnostics``.

    A running node never dies on bad input: it calls ``problem(kind, message)``, which logs the first
    occurrence of that kind as a warning (later ones at debug level), counts every occurrence, and reports the
    counts with the node's own figures (``set_value``) once a second.
    """

    def __init__(self, node: Node, hardware_id: str = "camera", period_s: float = 1.0):
        self._node = node
        self._hardware_id = hardware_id
        self._counts: dict[str, int] = {}
        self._values: dict[str, str] = {}
        self._messages: dict[str, str] = {}
        self._status_level = DiagnosticStatus.OK
        self._status_message = "running"
        self._lock = threading.Lock()
        self._watched: list = []
        self._publisher = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._timer = steady_timer(node, period_s, self.publish)  # the reports carry the node's time

    def watch_subscribers(self, *publishers) -> None:
        """Report how many subscriptions each publisher has matched (``matched_subscribers.<topic>``).

        Seen from the publisher's own side: a subscriber that other nodes already see may not be matched to this
        publisher yet, and what is published before the match is lost (reliable QoS covers matched readers only).
        A supervisor (``./vessel demo``) waits on these before it starts the source.
        """
        self._watched.extend(p for p in publishers if p is not None)

    def unwatch(self, *publishers) -> None:
        """Stop reporting these publishers (before they are destroyed: a managed node's cleanup)."""
        self._watched = [p for p in self._watched if all(p is not q for q in publishers)]

    def _matched_counts(self) -> list[tuple[str, str]]:
        counts = []
        for publisher in list(self._watched):
            try:
                counts.append((f"{MATCHED_SUBSCRIBERS}{publisher.topic_name}", str(publisher.get_subscription_count())))
            except RuntimeError:  # destroyed without unwatch (rclpy's InvalidHandle): never let it stop the node
                self.unwatch(publisher)
        return counts

    @property
    def counts(self) -> dict[str, int]:
        """A copy of the problem counters by kind."""
        with self._lock:
            return dict(self._counts)

    def problem(self, kind: str, message: str) -> None:
        """Record one problem of a kind: logged the first time, counted always."""
        with self._lock:
            count = self._counts.get(kind, 0) + 1
            self._counts[kind] = count
            self._messages[kind] = message
        if count == 1:
            self._node.get_logger().warning(f"{message} (counted as '{kind}' on /diagnostics; logged once)")
        else:
            self._node.get_logger().debug(f"{message} ({kind} #{count})")

    def count(self, kind: str, amount: int = 1) -> None:
        """Count an event that needs no log line (e.g. frames processed)."""
        with self._lock:
            self._counts[kind] = self._counts.get(kind, 0) + amount

    def set_value(self, key: str, value: Any) -> None:
        """Report a figure (latency, frames sent, progress) in the next diagnostics message."""
        if isinstance(value, float):
            value = f"{value:.6g}" if math.isfinite(value) else str(value)
        with self._lock:
            self._values[key] = str(value)

    def set_status(self, level: bytes, message: str) -> None:
        """Set the overall level (``DiagnosticStatus.OK/WARN/ERROR/STALE``) and its message."""
        with self._lock:
            self._status_level = level
            self._status_message = message

    def publish(self) -> None:
        """Publish the current status, figures and problem counts."""
        status = DiagnosticStatus()
        status.name = self._node.get_fully_qualified_name().lstrip("/")  # "tracker"; a spare's "standby_1/tracker"
        status.hardware_id = self._hardware_id
        with self._lock:
            level = self._status_level
            message = self._status_message
            counts = sorted(self._counts.items())
            values = sorted(self._values.items())
            problem_kinds = set(self._messages)
        if problem_kinds and level == DiagnosticStatus.OK:
            level = DiagnosticStatus.WARN
            message = f"{message}; problems: " + ", ".join(f"{k}={v}" for k, v in counts if k in problem_kinds)
        status.level = level
        status.message = message
        values += self._matched_counts()
        status.values = [KeyValue(key=k, value=v) for k, v in values]
        status.values += [KeyValue(key=f"count.{k}", value=str(v)) for k, v in counts]
        array = DiagnosticArray()
        array.header.stamp = self._node.get_clock().now().to_msg()
        array.status = [status]
        self._publisher.publish(array)


def _declared(node: Node, name: str, default: Any, description: str, bounds=None) -> Any:
    """The value of a parameter the node's table has declared, else declared here (a node without a table)."""
    if node.has_parameter(name):
        return node.get_parameter(name).value
    return declare_parameter(node, name, default, description, **({"float_range": bounds} if bounds else {}))


class NodeState:
    """A node's ``state_file``: resume the core at the first message, snapshot it every ``state_period_s``.

    ``core`` has ``snapshot()`` (its state as plain data) and ``restore(state)``. Failures to write are counted
    (``state_not_saved``) and never stop the node; a file refused as not a snapshot of this node, schema and version
    is one warning (``state_file_refused``) and a cold start.
    """

    def __init__(self, node: Node, health: NodeHealth, kind: str, fingerprint: str, read_only: bool = False):
        values = {name: _declared(node, name, default, description, bounds)
                  for name, (default, description, bounds) in STATE_PARAMETERS.items()}
        self._node = node
        self._health = health
        self.read_only = read_only
        self.file = StateFile(values["state_file"], kind, fingerprint, values["state_period_s"],
                              values["state_max_age_s"]) if values["state_file"] else None

    def resume(self, stamp: float, core) -> bool:
        """At the first message after a start: restore ``core`` from the state file if it fits ``stamp``.

        True when the snapshot already holds the message stamped ``stamp`` (a hot standby reading the file its
        active node has just written): the caller skips it rather than apply it twice. ``read_only`` (a standby)
        reads the snapshot without marking it resumed, since it is the active node's.
        """
        if self.file is None or not self.file.pending or stamp <= 0.0:  # a zero stamp says nothing of the time
            return False
        state, what = self.file.resume(stamp, consume=not self.read_only)
        holds_this_message = False
        if state is not None:
            try:
                core.restore(state)
            except (KeyError, TypeError, ValueError, AttributeError, VesselError) as error:
                what = self.file.refuse(f"it does not fit this node ({error})")
            else:
                self._health.count("resumed_from_state_file")
                holds_this_message = self.file.resumed_stamp == stamp
        if self.file.refused:
            self._health.problem("state_file_refused", what)
        else:
            self._node.get_logger().info(what)
        return holds_this_message

    def save(self, stamp: float, core) -> None:
        """Snapshot ``core`` if ``state_period_s`` of message time has passed since the last one."""
        if self.file is None or not self.file.due(stamp):
            return
        try:
            self.file.save(stamp, core.snapshot())
        except (OSError, VesselError) as error:
            self._health.problem("state_not_saved", f"the state file could not be written ({error}); a restart "
                                 "would start cold: check state_file's folder")


class Standby:
    """The ``standby`` parameter of a node that can wait as a hot spare of another process.

    A spare subscribes, runs its core on every message and is discovered by the rest of the graph like the
    active node, so promoting it costs no start-up and no discovery. Promotion is ``standby:=false`` (``ros2
    param set``) or SIGUSR1; the signal only raises a flag, acted on at the node's next message.
    """

    def __init__(self, node: Node):
        self._node = node
        self.active = not bool(_declared(node, "standby", False, STANDBY_DESCRIPTION))
        self._promotion_requested = False
        node.add_on_set_parameters_callback(self._on_set_parameters)
        if not self.active and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGUSR1, self._on_signal)

    def _on_signal(self, signum, frame) -> None:
        self._promotion_requested = True

    def _on_set_parameters(self, parameters):
        from rcl_interfaces.msg import SetParametersResult

        for parameter in parameters:
            if parameter.name != "standby":
                continue
            if parameter.value and self.active:
                return SetParametersResult(successful=False, reason="a promoted node stays active: stop it instead")
            if not parameter.value and not self.active:
                self.active = True
                self._node.get_logger().info("promoted from standby: publishing from now on")
        return SetParametersResult(successful=True)

    def publishing(self) -> bool:
        """Whether to publish (and save state) now; carries out a promotion SIGUSR1 asked for."""
        if self._promotion_requested and not self.active:
            from rclpy.parameter import Parameter

            self._promotion_requested = False
            self._node.set_parameters([Parameter("standby", value=False)])
        return self.active


def _ignore_late_sigint() -> None:
    """Ignore SIGINT once the exit status is decided.

    A supervisor stopping the graph while this node already leaves (e.g. the camera at the end of a bag) must not
    turn a clean exit into death by signal.
    """
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


class _Preloader:
    """Imports modules in a background thread while the node starts and connects.

    ``check()`` turns a failed import into a ``VesselError`` in the thread that runs the node, so a missing
    library still stops the node at start-up with one clear line.
    """

    def __init__(self, modules: Sequence[str]):
        self.failure: str | None = None
        self.thread = threading.Thread(target=self._import, args=(tuple(modules),), name="preload", daemon=True)
        self.thread.start()

    def _import(self, modules: tuple[str, ...]) -> None:
        for name in modules:
            try:
                import_serialized(name)
            except VesselError as error:  # reported by check() in the node's thread
                self.failure = str(error)
                return

    def check(self) -> None:
        if self.failure is not None:
            raise VesselError(self.failure)


def run_node(
    node_factory: Callable[[], Node],
    args: Sequence[str] | None = None,
    *,
    threads: int = 1,
    preload: Sequence[str] = (),
) -> int:
    """Run a node until SIGINT or shutdown, the same way for every executable of the project.

    ``preload`` names modules the node needs only once messages arrive; they are imported in the background
    once the node exists, while it is being discovered (see ``vessel_track.deferred_imports``).

    Returns the process exit status: 0 after SIGINT or a node that finished its work, 2 when a ``VesselError``
    or a file-system error on a path stopped it, at start as a rule (printed as one ``error:`` line naming the
    problem and the fix).
    """
    if wants_help(args if args is not None else sys.argv):
        try:
            print(node_help(node_factory, args if args is not None else sys.argv))
        except BrokenPipeError:  # `EXE --help | head`
            pass
        return 0
    try:
        rclpy.init(args=args)
    except RuntimeError as error:  # rclpy's RCLError: malformed --ros-args
        print(f"error: cannot start: {error}. Check the --ros-args part of the command line "
              "(e.g. -p name:=value, --params-file FILE).", file=sys.stderr)
        return 2
    node = None
    preloader = None
    status = 0
    _command_line[:] = list(args if args is not None else sys.argv)
    try:
        node = node_factory()
        preloader = _Preloader(preload) if preload else None  # after the node: its entities are announced first
        _apply_command_line_sim_time(node, _command_line)
        unknown = unknown_command_line_parameters(node, _command_line)
        if unknown:
            raise VesselError(f"{node.get_name()} has no parameter {_misspelt(node, unknown)}: `ros2 param list` "
                              "names them all; fix the -p on the command line")
        unknown_in_files = unknown_params_file_parameters(node, _command_line)
        if unknown_in_files:
            files = ", ".join(sorted(set(unknown_in_files.values())))
            raise VesselError(f"{node.get_name()} has no parameter {_misspelt(node, sorted(unknown_in_files))}, "
                              f"given in its block of {files}: `ros2 param list` names them all; fix the "
                              "parameter file")
        executor = MultiThreadedExecutor(num_threads=threads) if threads > 1 else SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok() and not getattr(node, "finished", False):
            if preloader is not None:
                preloader.check()
            executor.spin_once(timeout_sec=0.1)
        status = int(getattr(node, "exit_status", 0))
    except VesselError as error:
        print(f"error: {error}", file=sys.stderr)
        status = 2
    except OSError as error:
        problem = file_system_problem(error)
        if problem is None:
            raise
        print(f"error: {problem}", file=sys.stderr)
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        status = 0
    finally:
        _ignore_late_sigint()
        if node is not None:
            try:
                close = getattr(node, "close", None)
                if close is not None:
                    close()
                node.destroy_node()
            except Exception as error:
                print(f"warning: while shutting down: {error}", file=sys.stderr)
        if rclpy.ok():
            rclpy.try_shutdown()
        _ignore_late_sigint()  # again: shutting rclpy down puts back the handler it replaced at init
    return status


def release_publisher(node, publisher) -> None:
    """Destroy a publisher the node made, as a lifecycle publisher when it is one (so no transition touches it)."""
    from rclpy.lifecycle import LifecycleNode, LifecyclePublisher

    if isinstance(node, LifecycleNode) and isinstance(publisher, LifecyclePublisher):
        node.destroy_lifecycle_publisher(publisher)
    else:
        node.destroy_publisher(publisher)


class PhasedLifecycle:
    """Lifecycle callbacks for a node whose work is split into phases, as ros2/demos lifecycle_py lays them out.

    The node defines ``_configure``, ``_activate``, ``_deactivate`` and ``_cleanup``; mix this in before
    ``rclpy.lifecycle.LifecycleNode``. A configure that fails with a ``VesselError`` (a missing model, a bad
    source) is logged and leaves the node unconfigured; shutdown works from any state.
    """

    def on_configure(self, state):
        """Make what the node needs (``_configure``); FAILURE, logged, when it cannot."""
        from rclpy.lifecycle import TransitionCallbackReturn

        try:
            self._configure()
        except VesselError as error:
            self.get_logger().error(f"configure failed: {error}")
            self._cleanup()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state):
        """Start the work (``_activate``); the lifecycle publishers start publishing."""
        self._activate()
        return super().on_activate(state)

    def on_deactivate(self, state):
        """Stop the work (``_deactivate``); what was configured stays."""
        self._deactivate()
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        """Release what configure made (``_cleanup``)."""
        from rclpy.lifecycle import TransitionCallbackReturn

        self._cleanup()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        """Stop and release everything, from any state."""
        from rclpy.lifecycle import TransitionCallbackReturn

        self._deactivate()
        self._cleanup()
        return TransitionCallbackReturn.SUCCESS


def wants_help(args: Sequence[str]) -> bool:
    """``-h`` / ``--help`` among the arguments that are not ROS arguments (a node must not start then)."""
    inside = False
    for arg in list(args)[1:]:
        if arg == "--ros-args":
            inside = True
        elif arg == "--":
            inside = False
        elif not inside and arg in ("-h", "--help"):
            return True
    return False


def node_help(node_factory: Callable[[], Node], args: Sequence[str]) -> str:
    """What ``EXE --help`` prints: the node's module description and how to set its parameters."""
    import importlib
    import os

    module = importlib.import_module(getattr(node_factory, "__module__", "")) if hasattr(
        node_factory, "__module__") else None
    text = (module.__doc__ if module is not None and module.__doc__ else node_factory.__doc__ or "").strip()
    exe = os.path.basename(list(args)[0]) if args else "node"
    return (f"usage: {exe} [-h] [--ros-args [--params-file FILE] [-p NAME:=VALUE] [-r FROM:=TO] ...]\n\n{text}\n\n"
            "Parameters: every one is declared with a description and range; with the node running, `ros2 param "
            "list` / `ros2 param describe` show them, and config/parts/*.yaml of the repository lists each node's "
            "defaults. A -p on the command line wins over --params-file; an unknown name or a value out of range "
            "stops the node with one line.")


def main_for(node_class: type[Node], threads: int = 1) -> Callable[[], None]:
    """Make the console-script entry point of a node class; a node module ends with one such line."""

    def main(args: Sequence[str] | None = None) -> None:
        sys.exit(run_node(node_class, args if args is not None else sys.argv, threads=threads))

    return main


def wait_for(predicate: Callable[[], bool], timeout_s: float, node: Node | None = None) -> bool:
    """Poll ``predicate`` (spinning ``node`` if given) until it is true or ``timeout_s`` passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        if node is not None:
            rclpy.spin_once(node, timeout_sec=0.05)
        else:
            time.sleep(0.05)
    return predicate()
