"""The one description of the node graph: which executables, with which per-run values, restarted how.

The launch file ``vessel_graph.launch.py`` builds its ``launch_ros`` nodes from ``GRAPH_NODES``, and ``./vessel
graph`` (``vessel_tools.graph``) starts the same executables with the same parameter files, as ``ros2 run`` would.
Plain data and string helpers: nothing here imports ROS.
"""

from __future__ import annotations

from dataclasses import dataclass


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


STATEFUL_NODES = ("tracker", "fuser")
"""Nodes that keep a ``state_file`` under ``--respawn``, so that a restarted one carries on from its tracks."""

STANDBY_NODES = ("tracker", "fuser", "gps_publisher")
"""Nodes with a ``standby`` parameter, which ``./vessel graph --hot-standby`` runs a spare of."""

MAX_RESTARTS = 5
"""A node restarted this many times is left down and the graph stops: it fails for a reason a restart cannot fix."""


def restart_delay_s(restarts: int) -> float:
    """Back-off before restart number ``restarts + 1``: at once the first time, then 0.5 s doubling to 8 s."""
    return 0.0 if restarts == 0 else min(0.5 * 2.0 ** (restarts - 1), 8.0)
