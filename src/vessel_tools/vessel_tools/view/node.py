"""The view's rclpy node: the graph's topics in, plain values into ``ViewState``, snapshots out to the server.

Thin on purpose: every message is turned into ``TrackRecord`` / ``NodeStatus`` values at once and all the rest
(what to draw, JSON, throttling) is ROS-free. It never blocks: a snapshot is built at most ``update_hz`` times a
second and only while someone watches, the server's ``broadcast`` returns at once, and the annotated image is
JPEG-encoded only while a page is open, at most ``image_hz`` times a second. A bad message is counted on
``/diagnostics`` (``vessel_common.health``) and the node goes on.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

from rclpy.node import Node

from vessel_common.health import NodeHealth, steady_timer
from vessel_common.qos import SENSOR_DATA_QOS, reliable_qos, stamp_to_sec
from vessel_tools.view.geometry import CameraGeometry
from vessel_tools.view.state import Throttle, TrackRecord, ViewState
from vessel_tools.view.status import NodeStatus

TRACK_TOPICS = ("/vessel/fixes", "/vessel/tracks")
FIX_TOPIC = "/vessel/fix"
ANNOTATED_TOPIC = "/vessel/detections/image"
RAW_JPEG_TOPIC = "/camera/image_raw/compressed"
NO_FIX = -1  # sensor_msgs/NavSatStatus.STATUS_NO_FIX
STATUS_PERIOD_S = 1.0


@dataclass(frozen=True)
class ViewOptions:
    """How often the view sends what (per second), and how large the page's image is."""

    update_hz: float = 10.0
    image_hz: float = 4.0
    image_max_width: int = 960
    jpeg_quality: int = 80


def topic(namespace: str, name: str) -> str:
    """``name`` under a camera's namespace (``''``: the graph as it runs today)."""
    namespace = namespace.strip("/")
    return f"/{namespace}{name}" if namespace else name


def _finite(value) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return math.nan
    return value


def track_record(track, stamp: float) -> TrackRecord:
    """One ``vessel_msgs/VesselTrack`` as plain values (fields a newer message adds default to unknown)."""
    box = track.bbox
    return TrackRecord(
        id=str(track.id), stamp=stamp, is_target=bool(track.is_target), class_id=str(track.class_id),
        status=int(track.status), confidence=_finite(track.confidence), has_world=bool(track.has_world),
        east=_finite(track.position.x), north=_finite(track.position.y),
        vx=_finite(track.velocity.x), vy=_finite(track.velocity.y),
        covariance=tuple(_finite(v) for v in track.position_covariance),
        lat=_finite(track.latitude), lon=_finite(track.longitude),
        distance_m=_finite(track.distance_m), bearing_deg=_finite(track.bearing_deg),
        has_cpa=bool(getattr(track, "has_cpa", False)), cpa_m=_finite(getattr(track, "cpa_m", math.nan)),
        tcpa_s=_finite(getattr(track, "tcpa_s", math.nan)), cpa_alert=bool(getattr(track, "cpa_alert", False)),
        bbox=(_finite(box.center.position.x), _finite(box.center.position.y), _finite(box.size_x),
              _finite(box.size_y)),
    )


def check_record(record: TrackRecord) -> str | None:
    """The problem kind of a record the plan cannot draw as sent (None when fine): the view still lists it."""
    if record.has_world and not record.placed:
        return "bad_position"
    if record.placed and not all(math.isfinite(v) for v in record.covariance):
        return "bad_covariance"
    return None


def node_statuses(array) -> list[NodeStatus]:
    """Each status of a ``diagnostic_msgs/DiagnosticArray`` as plain values."""
    level = {b"\x00": 0, b"\x01": 1, b"\x02": 2, b"\x03": 3}
    return [NodeStatus(str(s.name), level.get(bytes(s.level), 2) if isinstance(s.level, bytes) else int(s.level),
                       str(s.message), {str(kv.key): str(kv.value) for kv in s.values}) for s in array.status]


class ViewNode(Node):
    """Subscribes to every camera's topics and keeps ``state`` current; ``tick`` sends what changed.

    ``server`` (``ViewServer``) says how many pages are connected (nothing is built for no one) and takes the
    snapshots and images; ``bridge`` (optional) is the Foxglove bridge, fed from this thread too.
    """

    def __init__(self, state: ViewState, cameras: dict[str, CameraGeometry | None], server,
                 options: ViewOptions = ViewOptions(), bridge=None, context=None, name: str = "view"):
        super().__init__(name, context=context)
        self.state, self.server, self.options, self.bridge = state, server, options, bridge
        self.health = NodeHealth(self, hardware_id="view")
        for kind in ("bad_stamp", "bad_position", "bad_covariance", "bad_image", "dropped_updates"):
            self.health.count(kind, 0)
        self._throttle = Throttle(1.0 / max(options.update_hz, 0.1))
        self._image_due = 0.0
        self._topics_in = []
        for namespace, geometry in cameras.items():
            state.add_camera(namespace, geometry)
            self._subscribe(namespace)
        from diagnostic_msgs.msg import DiagnosticArray

        self._topics_in.append(self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics,
                                                            reliable_qos(50)))
        self._status_changed = False
        steady_timer(self, 1.0 / max(options.update_hz, 0.1), self.tick)
        steady_timer(self, STATUS_PERIOD_S, self._status_tick)

    def _subscribe(self, namespace: str) -> None:
        from sensor_msgs.msg import CompressedImage, Image, NavSatFix

        from vessel_msgs.msg import VesselTrackArray

        add = self._topics_in.append
        for name in TRACK_TOPICS:
            add(self.create_subscription(VesselTrackArray, topic(namespace, name),
                                         lambda msg, ns=namespace: self._on_tracks(ns, msg), reliable_qos(10)))
        add(self.create_subscription(NavSatFix, topic(namespace, FIX_TOPIC),
                                     lambda msg, ns=namespace: self._on_fix(ns, msg), reliable_qos(10)))
        add(self.create_subscription(Image, topic(namespace, ANNOTATED_TOPIC),
                                     lambda msg, ns=namespace: self._on_image(ns, msg), SENSOR_DATA_QOS))
        if self.bridge is not None:
            add(self.create_subscription(CompressedImage, topic(namespace, RAW_JPEG_TOPIC),
                                         lambda msg: self._on_raw_jpeg(msg), SENSOR_DATA_QOS))

    def problem(self, kind: str, message: str) -> None:
        """Count a bad input on ``/diagnostics`` (logged once per kind) and on the page; the node goes on."""
        self.health.problem(kind, message)
        self.state.count(kind)

    def dropped(self, count: int) -> None:
        """Updates a slow client lost (its queue was full): an event, counted, not a fault."""
        self.health.count("dropped_updates", count)
        self.state.count("dropped_updates", count)

    # ------------------------------------------------------------------------------------------ callbacks
    def _on_tracks(self, namespace: str, msg) -> None:
        stamp = stamp_to_sec(msg.header.stamp)
        if not (math.isfinite(stamp) and stamp > 0 and msg.header.stamp.nanosec < 1_000_000_000):
            self.problem("bad_stamp", f"track array stamped {msg.header.stamp.sec}.{msg.header.stamp.nanosec}:"
                                " dropped")
            return
        records = [track_record(track, stamp) for track in msg.tracks]
        for record in records:
            kind = check_record(record)
            if kind is not None:
                self.problem(kind, f"track {record.id}: {kind.replace('_', ' ')} (drawn without it)")
        self.state.update_tracks(namespace, stamp, records)
        self.changed()
        if self.bridge is not None:
            self._bridge_tracks(namespace)

    def _bridge_tracks(self, namespace: str) -> None:
        camera = self.state.cameras.get(namespace)
        stamp, records = self.state.records(namespace)
        tracks = {k: list(v) for k, v in camera.tracks.items()} if camera is not None else {}
        self.bridge.publish_tracks(stamp, records, tracks, camera.geometry if camera is not None else None)

    def _on_fix(self, namespace: str, msg) -> None:
        placed = msg.status.status != NO_FIX and math.isfinite(msg.latitude) and math.isfinite(msg.longitude)
        self.state.set_fix(namespace, {"stamp": round(stamp_to_sec(msg.header.stamp), 3),
                                       "lat": round(msg.latitude, 7) if placed else None,
                                       "lon": round(msg.longitude, 7) if placed else None})
        self.changed()

    def _on_diagnostics(self, msg) -> None:
        by_camera: dict[str, list[NodeStatus]] = {}
        for status in node_statuses(msg):
            first, _, rest = status.name.partition("/")
            if rest and first in self.state.cameras and first:
                status = NodeStatus(rest, status.level, status.message, status.values)
                by_camera.setdefault(first, []).append(status)
            else:
                by_camera.setdefault("", []).append(status)
        for namespace, statuses in by_camera.items():
            if namespace in self.state.cameras:
                self.state.set_node_statuses(namespace, statuses)
        self._status_changed = True  # sent with the next tracks, or by the status timer when none come

    def _on_image(self, namespace: str, msg) -> None:
        now = time.monotonic()
        if self.server.clients == 0 or now < self._image_due:
            return
        self._image_due = now + 1.0 / max(self.options.image_hz, 0.1)
        try:
            jpeg = encode_jpeg(msg, self.options.image_max_width, self.options.jpeg_quality)
        except ValueError as error:
            self.problem("bad_image", f"annotated image not shown: {error}")
            return
        self.state.set_image(namespace, jpeg, stamp_to_sec(msg.header.stamp))
        self.server.broadcast_image(namespace, jpeg)

    def _on_raw_jpeg(self, msg) -> None:
        if self.bridge is not None and self.bridge.has_sinks():
            self.bridge.publish_image(stamp_to_sec(msg.header.stamp), bytes(msg.data), str(msg.format).split(";")[0])

    # ------------------------------------------------------------------------------------------ output
    def _status_tick(self) -> None:
        """Send a changed status line once a second even when no track array comes (every node reports at 1 Hz)."""
        if self._status_changed:
            self.changed()

    def changed(self) -> None:
        """The state changed: send it now if the throttle allows, else ``tick`` sends it once it does."""
        self._throttle.offer()
        self.tick()

    def tick(self) -> None:
        """Send the newest snapshot when one is due (at most ``update_hz`` a second); report the view's figures."""
        watchers = self.server.clients
        self.health.set_value("clients", watchers)
        if not self._throttle.due(time.monotonic()):
            return
        self._status_changed = False
        if watchers:
            self.server.broadcast(self.state.snapshot_json())
        if self.bridge is not None:
            for namespace in list(self.state.cameras):
                self.bridge.publish_status(self.state.status(namespace))


def encode_jpeg(msg, max_width: int, quality: int) -> bytes:
    """A ``sensor_msgs/Image`` as JPEG for the browser, at most ``max_width`` wide; ValueError naming a problem."""
    import cv2

    from vessel_detect.image_codec import ImageError, bgr_to_jpeg, image_to_bgr

    try:
        bgr = image_to_bgr(msg.encoding, msg.height, msg.width, msg.step, msg.data)
    except ImageError as error:
        raise ValueError(str(error)) from None
    if bgr.shape[1] > max_width:
        scale = max_width / bgr.shape[1]
        bgr = cv2.resize(bgr, (max_width, max(1, round(bgr.shape[0] * scale))), interpolation=cv2.INTER_AREA)
    return bgr_to_jpeg(bgr, quality)


def camera_namespaces(values: Sequence[str]) -> list[str]:
    """The cameras' namespaces from the command line (``''``: the graph as it runs today), unique, in order."""
    seen: list[str] = []
    for value in values or [""]:
        namespace = value.strip().strip("/")
        if namespace not in seen:
            seen.append(namespace)
    return seen
