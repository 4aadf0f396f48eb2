"""A node's health on ``/diagnostics``: problems logged once per kind and counted, figures, matched subscribers.

Nodes never die on bad input: they report it here, and a supervisor (``./vessel demo``, the graph runner) reads the
reports, e.g. the subscribers each publisher has matched before it starts the source.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from vessel_common.input_gaps import InputGaps


def steady_timer(node: Node, period_s: float, callback: Callable[[], None]):
    """A timer on the steady clock, whatever ``use_sim_time`` says.

    Housekeeping (reports, discovery, pacing) must run in real time: under ``use_sim_time`` the node clock
    stands still until a replay's first ``/clock`` (and the graph waits for these reports before it starts the
    camera), then jumps with it.
    """
    return node.create_timer(period_s, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))


#: Diagnostics key prefix of ``NodeHealth.watch_subscribers``: ``matched_subscribers./vessel/tracks`` = "3".
MATCHED_SUBSCRIBERS = "matched_subscribers."


def matched_subscribers(array, graph: str | None = None) -> dict[str, int]:
    """Subscriptions matched by each topic's publisher, from a ``DiagnosticArray`` of ``NodeHealth`` nodes.

    ``graph``: only the nodes right in that graph namespace ("" the root, "/a" camera a's), leaving out the other
    cameras' graphs and every hot standby (``a/standby_N/tracker``), whose publishers carry nothing until promoted.
    """
    found: dict[str, int] = {}
    parent = None if graph is None else graph.strip("/")
    for status in array.status:
        if parent is not None and status.name.rpartition("/")[0] != parent:
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
        self._input_gaps = InputGaps()
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

    def observe_input(self, stamp_s: float) -> None:
        """Count the frames missing before this input stamp as ``frames_missing_upstream``.

        A node before this one died and was restarted, or dropped them. An event, not a fault: the status stays.
        """
        missing = self._input_gaps.observe(stamp_s)
        if missing:
            self.count("frames_missing_upstream", missing)
            self.set_value("last_input_gap_s", self._input_gaps.last_gap_s)

    def restore_counts(self, counts: dict[str, int]) -> None:
        """Carry on counting from ``counts`` (a restarted node's, from its state file)."""
        with self._lock:
            for kind, value in counts.items():
                self._counts[kind] = self._counts.get(kind, 0) + int(value)

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
        # "tracker"; camera a's "a/tracker"; a spare's "standby_1/tracker" (graph_names.status_name)
        status.name = self._node.get_fully_qualified_name().lstrip("/")
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
