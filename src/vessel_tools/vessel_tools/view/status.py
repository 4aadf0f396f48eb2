"""The page's status line from ``/diagnostics``: frames per second, latency, the camera's progress, warnings.

Every node of the graph reports itself once a second (``vessel_common.health``); a person watching the water needs
three figures and anything that is not OK, not every counter. ROS-free: the node hands in plain ``NodeStatus``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

LEVELS = ("ok", "warn", "error", "stale")


@dataclass(frozen=True)
class NodeStatus:
    """One node's report on ``/diagnostics``: level (0 OK, 1 WARN, 2 ERROR, 3 STALE), message and figures."""

    name: str
    level: int
    message: str
    values: dict[str, str] = field(default_factory=dict)


def _number(text: str | None) -> float:
    try:
        return float(text) if text is not None else math.nan
    except ValueError:
        return math.nan


def _figure(nodes: dict[str, NodeStatus], node: str, key: str) -> float:
    status = nodes.get(node)
    return _number(status.values.get(key)) if status is not None else math.nan


def status_summary(nodes: Iterable[NodeStatus], arrays_per_s: float = math.nan) -> dict:
    """The status line and its parts.

    Frames per second are the detector's own figure when it reports one, else the rate the view receives track
    arrays at; latency is the detector's time from an image's arrival to its detections (p50). Warnings are the
    messages of nodes whose level is not OK (hot standbys, ``standby_N/...``, are left out).
    """
    by_name = {status.name: status for status in nodes}
    fps = _figure(by_name, "detector", "frames_per_s")
    if not math.isfinite(fps):
        fps = arrays_per_s
    latency = _figure(by_name, "detector", "input_to_output_ms_p50")
    progress = by_name["camera"].values.get("progress", "") if "camera" in by_name else ""
    warnings = [f"{s.name}: {s.message}" for s in sorted(by_name.values(), key=lambda s: s.name)
                if s.level != 0 and "/" not in s.name]
    level = max((min(s.level, 3) for s in by_name.values() if "/" not in s.name), default=0)
    parts = [f"{fps:.1f} frames/s" if math.isfinite(fps) else "no frames yet"]
    if math.isfinite(latency):
        parts.append(f"detector latency {latency:.0f} ms")
    if progress:
        parts.append(f"camera {progress}")
    parts.append(f"{len(by_name)} node(s) reporting" if by_name else "no /diagnostics yet")
    line = " · ".join(parts) + ("" if not warnings else " · " + "; ".join(warnings))
    return {
        "line": line,
        "level": LEVELS[max(0, level)],
        "frames_per_s": round(fps, 2) if math.isfinite(fps) else None,
        "latency_ms": round(latency, 1) if math.isfinite(latency) else None,
        "warnings": warnings,
        "nodes": sorted(by_name),
    }
