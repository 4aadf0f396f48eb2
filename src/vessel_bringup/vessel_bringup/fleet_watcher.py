"""Several cameras' graphs watched from one process: is each connected, what each reports, when each frame passed.

``GraphWatcher`` watches one graph; a computer running many cameras would need as many DDS participants for that.
``FleetWatcher`` is one rclpy node in a context of its own that reads ``/diagnostics`` once for every graph and,
per camera namespace, ``/NAME/vessel/fix`` and (with ``log_images``) ``/NAME/camera/image_raw/compressed``,
reading only the header stamps of the serialised messages.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

from vessel_bringup.graph_watcher import (
    DETECTIONS_TOPIC,
    FIX_TOPIC,
    IMAGE_TOPIC,
    SCREEN_TOPIC,
    TRACKS_TOPIC,
    header_stamp_ns,
)
from vessel_common.graph_names import graph_namespace, node_graph, resolve_topic


@dataclass
class CameraLog:
    """One camera's frames as the watcher saw them: header stamp -> reception time (ns, CLOCK_REALTIME)."""

    images: dict[int, int] = field(default_factory=dict)
    fixes: dict[int, int] = field(default_factory=dict)
    matched: dict[str, int] = field(default_factory=dict)  # its nodes' matched_subscribers.<topic>


class FleetWatcher:
    """Watches the graphs of ``namespaces`` (one per camera) from one in-process node; see the module docstring.

    No rclpy signal handler is installed: Ctrl-C reaches the program as KeyboardInterrupt.
    """

    def __init__(self, namespaces: Sequence[str], domain_id: int | None = None, log_images: bool = False):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions
        from sensor_msgs.msg import CompressedImage, NavSatFix

        from vessel_common.qos import SENSOR_DATA_QOS, reliable_qos

        self._rclpy = rclpy
        self.namespaces = [graph_namespace(name) for name in namespaces]
        self.logs = {name: CameraLog() for name in self.namespaces}
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.log_images = log_images
        self.context = Context()
        init = {"context": self.context, "signal_handler_options": SignalHandlerOptions.NO}
        rclpy.init(**init, **({"domain_id": domain_id} if domain_id is not None else {}))
        self.node = rclpy.create_node("fleet_watcher", context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        for name in self.namespaces:
            log = self.logs[name]
            self.node.create_subscription(NavSatFix, resolve_topic(FIX_TOPIC.lstrip("/"), name),
                                          self._stamp_into(log.fixes), reliable_qos(100), raw=True)
            if log_images:
                self.node.create_subscription(CompressedImage, resolve_topic(IMAGE_TOPIC.lstrip("/"), name),
                                              self._stamp_into(log.images), SENSOR_DATA_QOS, raw=True)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, reliable_qos(200))

    @staticmethod
    def _stamp_into(arrivals: dict[int, int]):
        def on_message(cdr) -> None:
            arrivals.setdefault(header_stamp_ns(cdr), time.time_ns())  # the first copy of a frame counts

        return on_message

    def _on_diagnostics(self, array) -> None:
        from vessel_common.health import MATCHED_SUBSCRIBERS

        for status in array.status:
            parent, _, _ = status.name.rpartition("/")
            graph = node_graph(parent)
            values = {kv.key: kv.value for kv in status.values}
            values["_message"] = status.message
            self.diagnostics[status.name] = values
            if graph not in self.logs or f"/{parent}" != graph:  # another graph's, or a hot standby's
                continue
            for key, value in values.items():
                if key.startswith(MATCHED_SUBSCRIBERS) and value.isdigit():
                    self.logs[graph].matched[key[len(MATCHED_SUBSCRIBERS):]] = int(value)

    def spin(self, seconds: float) -> None:
        """Process callbacks for a while."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))

    def connected(self, namespace: str, with_recorder: bool = False) -> bool:
        """Every link of one camera's graph from the detector to the GPS publisher (and to this watcher) is matched.

        Seen from each publisher's side (its ``matched_subscribers`` on ``/diagnostics``), as in ``GraphWatcher``.
        """
        namespace = graph_namespace(namespace)
        matched = self.logs[namespace].matched
        wanted = {DETECTIONS_TOPIC: 1, SCREEN_TOPIC: 1, TRACKS_TOPIC: 1, FIX_TOPIC: 1}
        links = [matched.get(resolve_topic(topic.lstrip("/"), namespace), 0) >= n + with_recorder
                 for topic, n in wanted.items()]
        image_readers = 1 + self.log_images
        links.append(self.node.count_subscribers(resolve_topic(IMAGE_TOPIC.lstrip("/"), namespace)) >= image_readers)
        return all(links)

    def counter(self, namespace: str, node: str, key: str) -> int | None:
        """A ``count.<key>`` node ``node`` of camera ``namespace`` last reported (None: not reported)."""
        values = self.diagnostics.get(f"{graph_namespace(namespace)}/{node}".lstrip("/"), {})
        value = values.get(f"count.{key}")
        return int(value) if value is not None and value.isdigit() else None

    def close(self) -> None:
        """Shut the watcher's context down."""
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)
