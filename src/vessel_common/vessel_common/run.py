"""How every node executable of the project starts, runs and stops: ``main = main_for(NodeClass)``.

What rclpy does, rclpy does here (``rclpy.init``, an executor, its SIGINT handling and shutdown). The runner adds
what a user of the project relies on: ``--help`` that starts nothing; a ``-p`` that wins over the node's own block of
a parameter file (handed to rclpy as ``parameter_overrides``); a misspelt parameter name, on the command line or in
the node's block of a parameter file, stops the node naming the closest declared name; a configuration error is
one ``error:`` line and exit status 2, never a traceback; SIGINT and a node that has finished its work exit with 0.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter, get_parameter_value
from rclpy.signals import uninstall_signal_handlers

from vessel_common.command_line import EXIT_BAD_INPUT
from vessel_common.errors import VesselError, file_system_problem
from vessel_common.imports import import_serialized
from vessel_common.parameter_names import is_rcl_parameter, with_closest
from vessel_common.ros_arguments import (
    command_line_parameters,
    params_file_parameters,
    remapped_node_name,
    wants_help,
)

NodeFactory = Callable[[], Node]


def main_for(node_class: type[Node]) -> Callable[[Sequence[str] | None], None]:
    """Make the console-script entry point of a node class; a node module ends with one such line."""

    def main(args: Sequence[str] | None = None) -> None:
        sys.exit(run_node(node_class, args))

    return main


def run_node(node_factory: NodeFactory, args: Sequence[str] | None = None, *, preload: Sequence[str] = ()) -> int:
    """Run a node until SIGINT, rclpy's shutdown or the node's ``finished``; the process exit status.

    ``node_factory``: the node class (a plain callable is called as it is: its ``-p`` keep rcl's precedence).
    ``preload`` names modules the node needs only once messages arrive; they are imported in the background once
    the node exists, while it is being discovered (see ``vessel_track.deferred_imports``).

    0 after SIGINT or a node that finished its work (else its ``exit_status``), 2 when a ``VesselError``, a bad
    parameter value or a file-system error on a path stopped it, at start as a rule (one ``error:`` line).
    """
    args = list(sys.argv if args is None else args)
    if wants_help(args):
        return _print_help(node_factory, args)
    try:
        rclpy.init(args=args)
    except RuntimeError as error:  # rclpy's RCLError: malformed --ros-args
        return _error(f"cannot start: {error}. Check the --ros-args part of the command line (e.g. -p name:=value, "
                      "--params-file FILE).")
    node = executor = None
    try:
        node = with_command_line(node_factory, args)()
        preloader = _Preloader(preload) if preload else None  # after the node: its entities are announced first
        check_parameter_names(node, args)
        executor = SingleThreadedExecutor()  # held here: shut_down releases it only after rclpy's signal thread
        return _spin(node, executor, preloader)
    except (KeyboardInterrupt, ExternalShutdownException, RuntimeError) as error:
        if not stopped_by_signal(error):
            raise
        return 0
    except VesselError as error:
        return _error(str(error))
    except ParameterException as error:  # a value rclpy refused before any node code ran (use_sim_time)
        return _error(f"{error}; fix the value in the parameter file or on the command line")
    except OSError as error:
        problem = file_system_problem(error)
        if problem is None:
            raise
        return _error(problem)
    finally:
        shut_down([] if node is None else [node], executor)


def stopped_by_signal(error: BaseException) -> bool:
    """``error`` only says the process was told to stop (SIGINT, SIGTERM, an external shutdown).

    rclpy's RCLError (a RuntimeError) counts when the context is already down: a call made just as rclpy's signal
    thread shut it down, e.g. while the executor built its wait set.
    """
    if isinstance(error, (KeyboardInterrupt, ExternalShutdownException)):
        return True
    return isinstance(error, RuntimeError) and not rclpy.ok()


def _error(message: str) -> int:
    print(f"error: {message}", file=sys.stderr)
    return EXIT_BAD_INPUT


def with_command_line(node_factory: NodeFactory, args: Sequence[str]) -> NodeFactory:
    """``node_factory`` whose rclpy ``Node.__init__`` gets the ``-p`` assignments of ``args`` as parameter_overrides.

    rcl files ``-p`` under ``/**``, which the node's own block of a parameter file beats; rclpy applies the
    constructor's ``parameter_overrides`` after both (``use_sim_time`` included). The project's node classes take
    no constructor arguments, so the overrides reach rclpy's ``__init__`` through a subclass of the node class with
    one class placed just above rclpy's own (``Node`` or ``LifecycleNode``). Nothing existing is changed.
    """
    if not (isinstance(node_factory, type) and issubclass(node_factory, Node)):
        return node_factory
    rclpy_class = next(cls for cls in node_factory.__mro__ if cls.__module__.startswith("rclpy."))

    class CommandLineOverrides(rclpy_class):
        def __init__(self, node_name: str, **kwargs: Any) -> None:
            given = [*(kwargs.pop("parameter_overrides", None) or ()), *command_line_overrides(args, node_name)]
            super().__init__(node_name, parameter_overrides=given, **kwargs)

    return type(node_factory.__name__, (node_factory, CommandLineOverrides),
                {"__module__": node_factory.__module__, "__doc__": node_factory.__doc__})


def hosted(node_class: type[Node], args: Sequence[str]) -> NodeFactory:
    """``node_class`` made with ``args`` as its own ``--ros-args`` (name, namespace, parameter files, ``-p``).

    For several nodes in one process (``vessel_bringup.node_host``): each gets its own command line, as if it
    were a process of its own; the process's global arguments are not used.
    """
    rclpy_class = next(cls for cls in node_class.__mro__ if cls.__module__.startswith("rclpy."))

    class OwnCommandLine(rclpy_class):
        def __init__(self, node_name: str, **kwargs: Any) -> None:
            given = [*(kwargs.pop("parameter_overrides", None) or ()), *command_line_overrides(args, node_name)]
            super().__init__(node_name, parameter_overrides=given, cli_args=list(args), use_global_arguments=False,
                             **kwargs)

    return type(node_class.__name__, (node_class, OwnCommandLine),
                {"__module__": node_class.__module__, "__doc__": node_class.__doc__})


def command_line_overrides(args: Sequence[str], name: str) -> list[Parameter]:
    """The ``-p`` assignments of ``args`` for the node created as ``name``, typed as ``ros2 param set`` types them."""
    given = command_line_parameters(args, remapped_node_name(args, name))
    return [_typed(parameter, text) for parameter, text in given.items()]


def _typed(name: str, text: str) -> Parameter:
    import yaml

    try:
        value = get_parameter_value(text)
    except yaml.YAMLError:  # rcl has read it already; what PyYAML cannot is a string
        value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=text)
    return Parameter.from_parameter_msg(ParameterMsg(name=name, value=value))


def check_parameter_names(node: Node, args: Sequence[str]) -> None:
    """Stop the node (``VesselError``) when a ``-p`` or its own block of a parameter file names an undeclared name.

    rclpy keeps such a value unused, so a misspelling would pass silently. ``qos_overrides.*`` are rcl's; a stand-in
    for another node (the replay detector) names what it ignores of that node's block in ``foreign_parameters``.
    """
    unknown = _undeclared(node, command_line_parameters(args, node.get_name()))
    if unknown:
        raise VesselError(f"{node.get_name()} has no parameter {_misspelt(node, unknown)}: `ros2 param list` "
                          "names them all; fix the -p on the command line")
    given = params_file_parameters(args, node.get_fully_qualified_name())
    foreign = getattr(node, "foreign_parameters", frozenset())
    in_files = {name: given[name] for name in _undeclared(node, given) if name not in foreign}
    if in_files:
        files = ", ".join(sorted(set(in_files.values())))
        raise VesselError(f"{node.get_name()} has no parameter {_misspelt(node, sorted(in_files))}, given in its "
                          f"block of {files}: `ros2 param list` names them all; fix the parameter file")


def _undeclared(node: Node, names) -> list[str]:
    return [name for name in names if not node.has_parameter(name) and not is_rcl_parameter(name)]


def _misspelt(node: Node, names: Sequence[str]) -> str:
    """``name (did you mean close?)`` for each name, against the node's declared parameters."""
    declared = node.list_parameters([], 0).names  # depth 0: every name
    return ", ".join(with_closest(name, declared) for name in names)


def _spin(node: Node, executor: SingleThreadedExecutor, preloader: _Preloader | None) -> int:
    """Spin the node on ``executor`` until rclpy shuts down (SIGINT) or the node has ``finished`` its work.

    ``rclpy.spin`` stops at shutdown only: a camera at the end of its bag says ``finished`` (and its ``exit_status``),
    and a failed preload stops the node too.
    """
    executor.add_node(node)
    while executor.context.ok() and not getattr(node, "finished", False):
        executor.spin_once(timeout_sec=0.1)
        if preloader is not None:
            preloader.check()
    return int(getattr(node, "exit_status", 0))


def shut_down(nodes: Sequence[Node], executor: SingleThreadedExecutor | None = None) -> None:
    """Release the nodes (each one's ``close()`` first), the executor and rclpy; a late signal changes nothing.

    rclpy handles SIGINT/SIGTERM in a thread of its own, beside this one: it triggers the SIGINT guard condition of
    every executor and shuts the context down. That thread has to be over before the executor goes, else it
    triggers a guard condition already freed and the process dies with SIGSEGV instead of closing. The executor is
    then shut down, not left to the garbage collector: a callback cut short by SIGINT leaves the nodes' timers and
    subscriptions in its wait set, where ``destroy_node`` could not destroy them before the process's exit. Nodes
    are closed in reverse order of creation, each on its own: one that fails to close is named and the others are
    still closed (whatever they have written is finished).
    """
    _ignore_late_signals()
    uninstall_signal_handlers()  # ends (joins) rclpy's signal thread
    for node in reversed(nodes):
        try:
            close = getattr(node, "close", None)
            if close is not None:
                close()
        except Exception as error:
            print(f"warning: while shutting down {node.get_name()}: {error}", file=sys.stderr)
    try:
        if executor is not None:
            executor.shutdown()
        for node in reversed(nodes):
            node.destroy_node()
    except Exception as error:
        print(f"warning: while shutting down: {error}", file=sys.stderr)
    rclpy.try_shutdown()


def _ignore_late_signals() -> None:
    """Ignore SIGINT and SIGTERM once the exit status is decided.

    A supervisor stopping the graph while this node already leaves (e.g. the camera at the end of a bag) must not
    turn a clean exit into death by signal. Set before rclpy's handlers are uninstalled, which then leave them as
    they are rather than put back the defaults they replaced at init (SIGTERM's would end the process mid-close).
    """
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)


class _Preloader:
    """Imports modules in a background thread while the node starts and connects.

    SciPy and filterpy take about 1.6 s to import on the project's 2-core machine, as long as a restarted node's
    discovery; loading them beside it, not after it, is the point. ``check()`` turns a failed import into a
    ``VesselError`` in the thread that runs the node, so a missing library still stops the node with one line.
    """

    def __init__(self, modules: Sequence[str]):
        self.failure: str | None = None
        self.thread = threading.Thread(target=self._import, args=(tuple(modules),), name="preload", daemon=True)
        self.thread.start()

    def _import(self, modules: tuple[str, ...]) -> None:
        for name in modules:
            try:
                import_serialized(name)  # never beside a callback's first import of the same modules
            except VesselError as error:  # reported by check() in the node's thread
                self.failure = str(error)
                return

    def check(self) -> None:
        if self.failure is not None:
            raise VesselError(self.failure)


def _print_help(node_factory: NodeFactory, args: Sequence[str]) -> int:
    try:
        print(node_help(node_factory, args))
    except BrokenPipeError:  # `EXE --help | head`
        pass
    return 0


def node_help(node_factory: NodeFactory, args: Sequence[str]) -> str:
    """What ``EXE --help`` prints: the node's module description and how to set its parameters."""
    import importlib
    import os

    module = importlib.import_module(node_factory.__module__) if hasattr(node_factory, "__module__") else None
    text = (module.__doc__ if module is not None and module.__doc__ else node_factory.__doc__ or "").strip()
    exe = os.path.basename(list(args)[0]) if args else "node"
    return (f"usage: {exe} [-h] [--ros-args [--params-file FILE] [-p NAME:=VALUE] [-r FROM:=TO] ...]\n\n{text}\n\n"
            "Parameters: every one is declared with a description and range; with the node running, `ros2 param "
            "list` / `ros2 param describe` show them, and config/parts/*.yaml of the repository lists each node's "
            "defaults. A -p on the command line wins over --params-file; an unknown name or a value out of range "
            "stops the node with one line.")


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
