"""The graph watched from this process: is every link matched, what the nodes report, what each frame did.

One watcher for the graph runner, the demo and the benchmarks. It is an rclpy node in a context of its own (so
it never shares a context or signal handler with a node under test) that reads ``/diagnostics`` (each publisher's
own count of matched readers, and every node's counters) and ``/vessel/tracks``; with ``log_frames`` it also notes
when each frame's messages pass along the chain, reading only the header stamp of the serialised message. A
watcher of a graph under a namespace (one camera of several) reads that graph's topics (``/a/vessel/tracks``) and
its nodes' reports only; its log keeps the topics' names without the namespace (``CHAIN``).
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Collection, Sequence
from dataclasses import dataclass

from vessel_common.graph_names import graph_namespace, node_graph, resolve_topic

IMAGE_TOPIC = "/camera/image_raw/compressed"
DETECTIONS_TOPIC = "/vessel/detections"
SCREEN_TOPIC = "/vessel/tracks/screen"
TRACKS_TOPIC = "/vessel/tracks"
FIX_TOPIC = "/vessel/fix"
DIAGNOSTICS_TOPIC = "/diagnostics"
CHAIN = (IMAGE_TOPIC, DETECTIONS_TOPIC, SCREEN_TOPIC, TRACKS_TOPIC, FIX_TOPIC)
"""The topics one frame passes, in order; every message carries the image's header stamp."""



def header_stamp_ns(cdr: bytes) -> int:
    """The header stamp of a serialised message whose first field is a ``std_msgs/Header`` (CDR)."""
    little = len(cdr) > 1 and cdr[1] & 1
    sec, nanosec = struct.unpack_from("<iI" if little else ">iI", cdr, 4)
    return sec * 1_000_000_000 + nanosec


@dataclass(frozen=True)
class Arrival:
    """One message of one frame on one topic: header stamp, its occurrence, and when it went and came (ns).

    ``published_ns`` is the DDS source timestamp (the publisher's clock, CLOCK_REALTIME), ``received_ns`` the
    watcher's reception by the middleware (before any Python queueing); both fall back to the callback time
    when the middleware gives none. ``occurrence`` counts earlier messages with the same stamp on the topic, so
    frames whose stamps repeat (a loop without restamping) are matched in order.
    """

    stamp_ns: int
    occurrence: int
    published_ns: int
    received_ns: int

    @property
    def key(self) -> tuple[int, int]:
        """Which frame: (occurrence, stamp), in the order the camera sent them."""
        return (self.occurrence, self.stamp_ns)


class ArrivalLog:
    """Arrivals per topic, keyed by frame."""

    def __init__(self, topics: Sequence[str]):
        self.by_topic: dict[str, dict[tuple[int, int], Arrival]] = {topic: {} for topic in topics}
        self._occurrences: dict[str, dict[int, int]] = {topic: {} for topic in topics}

    def add(self, topic: str, stamp_ns: int, published_ns: int, received_ns: int) -> Arrival:
        """Record one message."""
        seen = self._occurrences[topic]
        occurrence = seen.get(stamp_ns, 0)
        seen[stamp_ns] = occurrence + 1
        arrival = Arrival(stamp_ns, occurrence, published_ns, received_ns)
        self.by_topic[topic][arrival.key] = arrival
        return arrival

    def count(self, topic: str) -> int:
        """Messages seen on a topic."""
        return len(self.by_topic[topic])

    def frames(self) -> list[tuple[int, int]]:
        """Every frame seen on any topic, in the order the camera sent them."""
        keys: set[tuple[int, int]] = set()
        for arrivals in self.by_topic.values():
            keys.update(arrivals)
        return sorted(keys)


def _message_info_times(info) -> tuple[int, int]:
    now = time.time_ns()
    if not isinstance(info, dict):
        return now, now
    return int(info.get("source_timestamp") or now), int(info.get("received_timestamp") or now)


class GraphWatcher:
    """Watches the graph from an in-process node: links, diagnostics, tracks, fixes; each frame with ``log_frames``.

    ``domain_id``: the graph's ROS domain (None: ``ROS_DOMAIN_ID``). No rclpy signal handler is installed: Ctrl-C
    reaches the program as KeyboardInterrupt, so that it stops every node on the way out.
    """

    def __init__(self, domain_id: int | None = None, log_frames: bool = False, namespace: str = ""):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions
        from sensor_msgs.msg import CompressedImage, NavSatFix

        from vessel_common.qos import SENSOR_DATA_QOS, reliable_qos
        from vessel_msgs.msg import Detection2DArray, VesselTrackArray

        self._rclpy = rclpy
        self.namespace = graph_namespace(namespace)
        self.context = Context()
        init = {"context": self.context, "signal_handler_options": SignalHandlerOptions.NO}
        rclpy.init(**init, **({"domain_id": domain_id} if domain_id is not None else {}))
        self.node = rclpy.create_node("graph_watcher", context=self.context, namespace=self.namespace or None)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.log = ArrivalLog(CHAIN)
        self.log_frames = log_frames
        self.tracks_received = 0
        self.fixes_with_position = 0
        self.fixes: list[tuple[float, int, float, float]] = []  # (monotonic s received, stamp ns, lat, lon)
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.matched: dict[str, int] = {}   # topic -> subscriptions its publisher has matched (its /diagnostics)
        # Serialised messages (raw=True): only the header stamp is read, so a 200 kB image costs no
        # deserialisation while the graph runs.
        self.subscriptions = {
            TRACKS_TOPIC: self.node.create_subscription(VesselTrackArray, self.resolved(TRACKS_TOPIC),
                                                        self._raw_callback(TRACKS_TOPIC), reliable_qos(100), raw=True),
            FIX_TOPIC: self.node.create_subscription(NavSatFix, self.resolved(FIX_TOPIC), self._on_fix,
                                                     reliable_qos(100)),
        }
        if log_frames:
            for topic, kind, qos in ((IMAGE_TOPIC, CompressedImage, SENSOR_DATA_QOS),
                                     (DETECTIONS_TOPIC, Detection2DArray, reliable_qos(100)),
                                     (SCREEN_TOPIC, VesselTrackArray, reliable_qos(100))):
                self.subscriptions[topic] = self.node.create_subscription(kind, self.resolved(topic),
                                                                          self._raw_callback(topic), qos, raw=True)
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics, reliable_qos(50))

    def resolved(self, topic: str) -> str:
        """The name of one of the graph's topics (``CHAIN``) in this watcher's graph: ``/a/vessel/fix`` under ``a``."""
        return resolve_topic(topic.lstrip("/"), self.namespace)

    def _raw_callback(self, topic: str):
        def on_message(cdr, info) -> None:
            if topic == TRACKS_TOPIC:
                self.tracks_received += 1
            if self.log_frames:
                published, received = _message_info_times(info)
                self.log.add(topic, header_stamp_ns(cdr), published, received)

        return on_message

    def _on_fix(self, fix, info) -> None:
        stamp = fix.header.stamp
        if fix.status.status >= 0 and math.isfinite(fix.latitude) and math.isfinite(fix.longitude):
            self.fixes_with_position += 1
            self.fixes.append((time.monotonic(), stamp.sec * 1_000_000_000 + stamp.nanosec, fix.latitude,
                               fix.longitude))
        if self.log_frames:
            published, received = _message_info_times(info)
            self.log.add(FIX_TOPIC, stamp.sec * 1_000_000_000 + stamp.nanosec, published, received)

    def _on_diagnostics(self, array) -> None:
        from vessel_common.health import matched_subscribers

        self.matched.update(matched_subscribers(array, graph=self.namespace))
        for status in array.status:
            if node_graph(status.name.rpartition("/")[0]) != self.namespace:
                continue  # another camera's graph
            values = {kv.key: kv.value for kv in status.values}
            values["_message"] = status.message
            self.diagnostics[status.name] = values

    def spin(self, seconds: float) -> None:
        """Process callbacks for a while."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))

    def connected(self, with_camera: bool = True, with_recorder: bool = True, with_detector: bool = True,
                  spares: Collection[str] = ()) -> bool:
        """Every link from the detector to the GPS publisher (and the recorder, and this watcher) is matched.

        Seen from each publisher's own side (the ``matched_subscribers`` its node reports on ``/diagnostics``):
        that this watcher sees a subscriber does not mean the publisher has matched it yet, and a frame published
        before then is lost. ``with_detector=False``: the links after the detector only (a self-paced source that
        waits for its own readers is started once these are up). ``with_camera=False``: no image reader needed.
        ``spares``: the nodes with a hot standby, whose spare must have matched too (it needs every frame).
        """
        readers = {DETECTIONS_TOPIC: 1 + ("tracker" in spares), SCREEN_TOPIC: 1 + ("fuser" in spares),
                   TRACKS_TOPIC: 1 + ("gps_publisher" in spares), FIX_TOPIC: 0}
        wanted = {topic: n + (topic in self.subscriptions) + with_recorder for topic, n in readers.items()}
        if not with_detector:
            del wanted[DETECTIONS_TOPIC]
        image_readers = 1 + (IMAGE_TOPIC in self.subscriptions)
        links = [self.node.count_subscribers(self.resolved(IMAGE_TOPIC)) >= image_readers or not with_camera]
        links += [self.matched.get(self.resolved(topic), 0) >= n for topic, n in wanted.items()]
        if self.log_frames:  # and this watcher's own readers see a publisher on every topic after the camera
            links += [self.subscriptions[topic].get_publisher_count() >= 1 for topic in CHAIN[1:]
                      if topic != DETECTIONS_TOPIC or with_detector]
        return all(links)

    def detector_connected(self) -> bool:
        """The detector takes images and has matched every reader of its detections the graph knows of.

        For a graph split across hosts: the camera and detector here, the tracking (and perhaps a recorder) on
        another machine; a first reader matched is not enough, the tracker may not be that one.
        """
        readers = self.node.count_subscribers(self.resolved(DETECTIONS_TOPIC))  # every one known, here or there
        return (self.node.count_subscribers(self.resolved(IMAGE_TOPIC)) >= 1 and readers >= 1
                and self.matched.get(self.resolved(DETECTIONS_TOPIC), 0) >= readers)

    def close(self) -> None:
        """Shut the watcher's context down."""
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)
