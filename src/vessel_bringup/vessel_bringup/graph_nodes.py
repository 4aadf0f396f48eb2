"""The one description of the node graph: which executables, with which per-run values, restarted how.

The launch file ``vessel_graph.launch.py`` builds its ``launch_ros`` nodes from ``GRAPH_NODES``, and ``./vessel
graph`` (``vessel_bringup.graph``) starts the same executables with the same parameter files, as ``ros2 run`` would.
Plain data, string helpers and a parameter-file reader: nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from vessel_calib.params import read_params_yaml
from vessel_common.errors import DataError
from vessel_common.graph_names import graph_namespace, resolve_topic
from vessel_common.parameter_names import flatten


@dataclass(frozen=True)
class GraphNode:
    """One node of the graph: which executable, and what it is for."""

    name: str
    package: str
    executable: str
    role: str


GRAPH_NODES: tuple[GraphNode, ...] = (
    GraphNode("camera", "vessel_detect", "camera", "replays a bag, video, folder or device as images + /clock"),
    GraphNode("detector", "vessel_detect", "detector", "ONNX detector: images -> /vessel/detections"),
    GraphNode("tracker", "vessel_track", "tracker", "Kalman tracks in screen space -> /vessel/tracks/screen"),
    GraphNode("fuser", "vessel_track", "fuser", "screen -> world, target choice -> /vessel/tracks"),
    GraphNode("gps_publisher", "vessel_track", "gps_publisher", "-> /vessel/fix (target), /vessel/fixes"),
)
RECORDER = GraphNode("recorder", "vessel_detect", "recorder", "records the graph's outputs to an MCAP bag")


LIVE_SOURCE_PREFIXES = ("device:", "/dev/video", "rtsp://", "http://", "https://")


def sim_time_for_source(source: str) -> bool:
    """Whether a graph fed by camera ``source`` runs on ``/clock`` (``use_sim_time``): a recording, yes.

    A replayed bag, video file or image folder carries its own time, which the camera publishes on ``/clock``:
    with it every node's clock, its ``/diagnostics`` and a recording of the replay are in the replay's time, not
    today's. A live device is in today's time. No source (the parameter file's) counts as live.
    """
    source = str(source).strip()
    return bool(source) and not source.startswith(LIVE_SOURCE_PREFIXES)


def camera_command_line(source: str, rate: str | float | None) -> list[str]:
    """``-p`` assignments of the camera's per-run values (a ``-p`` wins over the parameter files)."""
    args: list[str] = []
    if str(source).strip():
        args += ["-p", f"source:={source}"]
    if rate is not None and str(rate).strip():
        args += ["-p", f"rate:={float(rate)!r}"]
    return args


def file_parameters(params_files: Sequence[Path | str], name: str, with_shared: bool = True) -> dict[str, object]:
    """Node ``name``'s values in the parameter files, the later file winning (``/**`` blocks too, unless told not).

    What the node reads from them, without the per-run ``-p`` values; an unreadable file raises CalibrationError.
    """
    parameters: dict[str, object] = {}
    keys = (("/**",) if with_shared else ()) + (name, f"/{name}")
    for path in params_files:
        blocks = read_params_yaml(path)
        for key in keys:
            parameters.update(flatten(blocks.get(key) or {}))
    return parameters


def camera_waits_for_detector(camera_file_values: dict[str, object], overrides: dict[str, object],
                              local_detector: bool) -> dict[str, object]:
    """The camera override that holds its first frame until the graph's own detector has matched its images.

    The camera's automatic ``wait_for_subscribers`` (-1) waits only at rate 0; at any other rate a replay started
    before the detector's subscription had matched sent its first frames to no one (best effort, uncounted).
    A value other than the automatic -1 in the parameter files is kept; so is the automatic one where there is no
    local detector. A rate that is not a number raises DataError naming where it came from.
    """
    if not local_detector or camera_file_values.get("wait_for_subscribers", -1) != -1:
        return {}
    given = "rate" in overrides
    rate = overrides["rate"] if given else camera_file_values.get("rate", 1.0)
    try:
        rate = float(rate)
    except (TypeError, ValueError):
        where = "the replay rate given" if given else "the camera's rate in the parameter files"
        raise DataError(f"{where} is {rate!r}, not a number: give e.g. 1.0 (real time) or 0 (as fast as the "
                        "graph consumes)") from None
    return {} if rate == 0.0 else {"wait_for_subscribers": 1}


STATEFUL_NODES = ("tracker", "fuser")
"""Nodes that keep a ``state_file`` under ``--respawn``, so that a restarted one carries on from its tracks."""

RESUMING_NODES = ("camera", "recorder")
"""Nodes that keep a ``resume_file`` under ``--respawn``: a restarted camera carries on after the last frame it sent
(not from the first), a restarted recorder into the next part of its recording (``OUT.1``, not failing on ``OUT``)."""


def respawn_files(name: str, state_dir: Path, state_files: bool = True) -> dict[str, str]:
    """The files node ``name`` keeps under respawn in the run's state folder, as parameters: ``{parameter: path}``.

    The tracker and the fuser a ``state_file`` (unless ``state_files`` is false: they restart cold), the camera and
    the recorder a ``resume_file``; the other nodes none. Both runners (the launch file, ``./vessel graph``) use it.
    """
    files = {}
    if state_files and name in STATEFUL_NODES:
        files["state_file"] = str(Path(state_dir) / f"{name}.state")
    if name in RESUMING_NODES:
        files["resume_file"] = str(Path(state_dir) / f"{name}.resume")
    return files


def standby_topics(name: str, parameters: dict[str, object], namespace: str) -> dict[str, str]:
    """The topic parameters of a hot standby of node ``name`` in graph ``namespace``, as absolute names.

    A spare lives one namespace deeper (``/a/standby_1``), where the node's relative topics (``vessel/tracks``)
    would resolve to topics nobody publishes; given as the active node's resolved names (``/a/vessel/tracks``) it
    reads and would publish exactly what the active node does. ``parameters``: the node's values from the
    parameter files and the run, over its table's defaults.
    """
    from vessel_track.parameter_tables import FUSER_PARAMETERS, GPS_PUBLISHER_PARAMETERS, TRACKER_PARAMETERS

    tables = {table.node: table for table in (TRACKER_PARAMETERS, FUSER_PARAMETERS, GPS_PUBLISHER_PARAMETERS)}
    topics = {}
    for row in tables[name]:
        if row.name.rsplit(".", 1)[-1].endswith("topic"):
            value = str(parameters.get(row.name, row.default))
            if value:  # '' is a topic switched off
                topics[row.name] = resolve_topic(value, namespace)
    return topics


def clock_topic(namespace: str) -> str:
    """The clock of graph ``namespace``: ``/clock`` for the root, ``/NAME/clock`` under a namespace.

    ``/clock`` is absolute in rclpy, so every node of a namespaced graph has it remapped (``-r /clock:=/a/clock``):
    two replaying cameras never drive one clock, and each graph runs on its own replay's time under
    ``use_sim_time``.
    """
    return f"{graph_namespace(namespace)}/clock"


def namespaced_blocks(params_files: Sequence[Path | str], name: str, namespace: str,
                      overrides: dict[str, object] | None = None) -> dict[str, dict]:
    """Node ``name``'s blocks of the parameter files (later winning), plus ``overrides``, under its namespaced name.

    A block named ``tracker`` does not reach ``/a/tracker`` (rcl matches the fully qualified name); written again
    as ``/a/tracker`` in one more file after them it does, and still beats the files' ``/**`` blocks as a node's
    own block does. One parameter file then serves every camera.
    """
    parameters = file_parameters(params_files, name, with_shared=False)
    parameters.update(flatten(overrides or {}))
    return {f"{graph_namespace(namespace)}/{name}": {"ros__parameters": parameters}}


STANDBY_NODES = ("tracker", "fuser", "gps_publisher")
"""Nodes with a ``standby`` parameter, which ``./vessel graph --hot-standby`` runs a spare of."""

MAX_RESTARTS = 5
"""A node restarted this many times is left down and the graph stops: it fails for a reason a restart cannot fix."""


def restart_wanted(status: int) -> bool:
    """Whether a node that exited with ``status`` is restarted under respawn: when it failed.

    The camera at the end of its source, and a node stopped by Ctrl-C, exit 0: they are not restarted.
    """
    return status != 0


def restart_delay_s(restarts: int) -> float:
    """Back-off before restart number ``restarts + 1``: at once the first time, then 0.5 s doubling to 8 s."""
    return 0.0 if restarts == 0 else min(0.5 * 2.0 ** (restarts - 1), 8.0)
