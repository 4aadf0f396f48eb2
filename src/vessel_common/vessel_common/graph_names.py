"""Names of a graph that may run under a namespace: several cameras, each its own graph, in one ROS domain.

A camera's topics are relative names (``vessel/fix``), so they resolve under the graph's namespace (``/a/vessel/fix``)
and are the old absolute names without one; what the whole domain shares stays absolute (``/diagnostics``, the own
ship's ``/own_ship/imu``). Plain strings, no ROS: the runners, the nodes and the tools all use it.
"""

from __future__ import annotations

import re

from vessel_common.errors import DataError

_SEGMENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
STANDBY_SEGMENT = re.compile(r"standby_[0-9]+\Z")
"""The last namespace segment of a hot standby (``/a/standby_1/tracker`` is graph ``/a``'s spare tracker)."""


def graph_namespace(name: str | None) -> str:
    """A graph namespace as ROS writes it: ``a`` and ``/a/`` are ``/a``; empty or ``/`` is the root, ``""``.

    A name ROS would refuse (a segment starting with a digit, a dash, a space) raises DataError with one line.
    """
    text = (name or "").strip().strip("/")
    if not text:
        return ""
    for segment in text.split("/"):
        if not _SEGMENT.match(segment):
            raise DataError(f"namespace {name!r}: each part must be letters, digits and underscores, not starting "
                            "with a digit (e.g. cam0, harbour/east)")
    return "/" + text


def node_graph(node_namespace: str) -> str:
    """The graph a node belongs to, from its own namespace: a hot standby's ``/a/standby_1`` is graph ``/a``."""
    parts = [part for part in node_namespace.strip("/").split("/") if part]
    if parts and STANDBY_SEGMENT.match(parts[-1]):
        parts.pop()
    return "/" + "/".join(parts) if parts else ""


def resolve_topic(topic: str, namespace: str) -> str:
    """The absolute name of ``topic`` in graph ``namespace`` (an absolute one is left as it is)."""
    if not topic or topic.startswith("/"):
        return topic
    return f"{graph_namespace(namespace)}/{topic}"


def status_name(namespace: str, node: str) -> str:
    """The name a node reports on ``/diagnostics`` (its fully qualified name without the leading slash)."""
    return f"{graph_namespace(namespace)}/{node}".lstrip("/")


def file_label(namespace: str) -> str:
    """A graph namespace as one path component (``/harbour/east`` -> ``harbour.east``; the root: ``""``)."""
    return graph_namespace(namespace).strip("/").replace("/", ".")
