"""``host``: the nodes of several cameras in one process, each an rclpy node of its own, on one executor.

``./vessel graph --cameras ... --processes per-role`` starts one host for every camera's detector and one for every
camera's tracker, fuser and GPS publisher, so a camera costs a node, not a Python process with its libraries and
its DDS participant. Each hosted node gets the command line it would get as a process of its own (name, namespace,
``/NAME/clock``, parameter files, state files), so it behaves, reports and restarts from its state file as one.
The detectors of a host share one onnxruntime session per model and one worker that takes each camera's newest
image in turn (``vessel_detect.detector_sharing``).

The host reads what to run from a JSON file named by its ``spec`` parameter (in its own block of the parameter
files): a list of ``{"node": "tracker", "args": ["--ros-args", ...]}``. A node that cannot start stops the host
with one ``error:`` line naming it (exit 2); a failure while running ends the host with a non-zero status, which
``--respawn`` restarts with every node of it.
"""

from __future__ import annotations

import importlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from vessel_bringup.graph_nodes import file_parameters
from vessel_common.errors import DataError, VesselError, file_system_problem
from vessel_common.ros_arguments import remapped_node_name, ros_arguments

NODE_CLASSES = {
    "camera": "vessel_detect.camera_node:CameraNode",
    "detector": "vessel_detect.detector_node:DetectorNode",
    "tracker": "vessel_track.tracker_node:TrackerNode",
    "fuser": "vessel_track.fuser_node:FuserNode",
    "gps_publisher": "vessel_track.gps_publisher_node:GpsPublisherNode",
}
"""The nodes a host can run, by their executable's name."""


def read_spec(args: Sequence[str]) -> list[dict]:
    """The nodes to host: the JSON file of the host's ``spec`` parameter; DataError (one line) when unusable."""
    name = remapped_node_name(args, "host")
    files = list(ros_arguments(args, ("--params-file",)))
    spec = file_parameters(files, name).get("spec")
    if not spec:
        raise DataError(f"host {name}: no spec parameter in its block of the parameter files ({', '.join(files)})")
    try:
        entries = json.loads(Path(str(spec)).read_text())
    except (OSError, ValueError) as error:
        raise DataError(f"host {name}: spec {spec} cannot be read ({error})") from None
    if not isinstance(entries, list) or not entries or not all(
            isinstance(e, dict) and e.get("node") in NODE_CLASSES and isinstance(e.get("args"), list) for e in entries):
        raise DataError(f"host {name}: spec {spec} is not a list of {{node: one of {sorted(NODE_CLASSES)}, args: "
                        "[...]}")
    return entries


def node_class(kind: str, shared=None):
    """The node class of ``kind``; a detector shares ``shared`` (a ``SharedDetection``) with the host's others."""
    module, _, name = NODE_CLASSES[kind].partition(":")
    cls = getattr(importlib.import_module(module), name)
    if kind == "detector":
        cls = type(cls.__name__, (cls,), {"shared": shared, "__module__": cls.__module__, "__doc__": cls.__doc__})
    return cls


def _label(args: Sequence[str], kind: str) -> str:
    """``cam0/tracker``: a hosted node by its namespace and name (for messages)."""
    namespace = next((rule.split(":=", 1)[1] for rule in ros_arguments(args, ("-r",)) if rule.startswith("__ns:=")),
                     "")
    return f"{namespace}/{remapped_node_name(args, kind)}".strip("/")


def _preload(entries: Sequence[dict]) -> None:
    """Import what the tracking nodes load at their first message, before the executor spins.

    One executor serves every hosted node: a first callback that spent seconds importing SciPy would hold up every
    other camera's messages meanwhile, and a reader keeps only its last ``qos_depth`` of them. The graph runner
    starts the cameras only once the nodes report, which they do once spinning, so nothing is sent meanwhile.
    """
    if any(entry["node"] in ("tracker", "fuser") for entry in entries):
        from vessel_common.imports import import_serialized
        from vessel_track import deferred_imports

        for module in deferred_imports.MODULES:
            import_serialized(module)


def run_host(args: Sequence[str]) -> int:
    """Start every node of the spec, spin them on one executor until SIGINT; the exit status."""
    import rclpy
    from rclpy.exceptions import ParameterException
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    from vessel_common.run import check_parameter_names, hosted, shut_down, stopped_by_signal
    from vessel_detect.detector_sharing import SharedDetection

    entries = read_spec(args)
    rclpy.init(args=[args[0]] if args else None)
    shared = SharedDetection()
    nodes = []
    executor = None
    try:
        for entry in entries:
            label = _label(entry["args"], entry["node"])
            try:
                node = hosted(node_class(entry["node"], shared), entry["args"])()
                nodes.append(node)
                check_parameter_names(node, entry["args"])
            except (VesselError, ParameterException) as error:
                raise VesselError(f"{label}: {error}") from None
            except OSError as error:
                problem = file_system_problem(error)
                if problem is None:
                    raise
                raise VesselError(f"{label}: {problem}") from None
        _preload(entries)
        print(f"[host] running {', '.join(_label(e['args'], e['node']) for e in entries)}", file=sys.stderr,
              flush=True)
        executor = SingleThreadedExecutor()
        for node in nodes:
            executor.add_node(node)
        while executor.context.ok():
            executor.spin_once(timeout_sec=0.1)
        return 0
    except (KeyboardInterrupt, ExternalShutdownException, RuntimeError) as error:
        if not stopped_by_signal(error):
            raise
        return 0
    finally:
        shut_down(nodes, executor)


def main(argv: Sequence[str] | None = None) -> None:
    """Console entry point of ``host`` (started by ``./vessel graph --processes per-role``)."""
    args = list(sys.argv if argv is None else argv)
    if any(arg in ("-h", "--help") for arg in args[1:args.index("--ros-args") if "--ros-args" in args else None]):
        print(f"usage: {Path(args[0]).name} --ros-args --params-file FILE (its block's spec: a JSON list of nodes)"
              f"\n\n{__doc__.strip()}")
        sys.exit(0)
    try:
        status = run_host(args)
    except VesselError as error:
        print(f"error: {error}", file=sys.stderr)
        status = 2
    sys.exit(status)


if __name__ == "__main__":
    main()
