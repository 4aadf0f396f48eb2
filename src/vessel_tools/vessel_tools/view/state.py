"""What the view shows, without ROS: the vessels of each camera, their recent tracks, the status line, the image.

The node turns each message into plain values (``TrackRecord``, ``NodeStatus``) and hands them here; the server
reads JSON built here. Keeping this free of ROS lets the page's data be tested without a graph, and lets the same
state feed both the page and the Foxglove bridge.

Cameras are keyed by namespace (``''`` for the graph as it runs today): a camera's topics, calibration, vessels
and image belong to it alone, so several cameras side by side are several entries, not a new data model.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from vessel_tools.view.geometry import CameraGeometry, Chart
from vessel_tools.view.status import NodeStatus, status_summary

HISTORY_POINTS = 120
"""Positions kept per vessel for its drawn track."""
TRACK_SPACING_S = 1.0
"""A track keeps one position per this many seconds (the newest replaces the last until then): at a live camera's
frame rate the track stays minutes long and the JSON small."""
BACKWARDS_RESET_S = 1.0
"""A stamp this far before the last one is a replay starting again: every vessel is dropped, as the nodes do."""
ELLIPSE_PROBABILITY = 0.95
"""The uncertainty ellipse drawn holds the vessel with this probability (2-D Gaussian)."""
STATUS_LOST = 3
KNOTS_PER_MPS = 3600.0 / 1852.0
STILL_MPS = 0.05


@dataclass(frozen=True)
class TrackRecord:
    """One vessel of a ``VesselTrackArray`` as plain values (the fields the view draws); NaN: unknown."""

    id: str
    stamp: float
    is_target: bool = False
    class_id: str = ""
    status: int = 1
    confidence: float = math.nan
    has_world: bool = False
    east: float = math.nan
    north: float = math.nan
    vx: float = math.nan
    vy: float = math.nan
    covariance: tuple[float, float, float, float] = (math.nan,) * 4
    lat: float = math.nan
    lon: float = math.nan
    distance_m: float = math.nan
    bearing_deg: float = math.nan
    has_cpa: bool = False
    cpa_m: float = math.nan
    tcpa_s: float = math.nan
    cpa_alert: bool = False
    bbox: tuple[float, float, float, float] = (math.nan,) * 4  # centre x, centre y, width, height (pixels)

    @property
    def placed(self) -> bool:
        """Whether the plan can draw it: a world position that is finite."""
        return self.has_world and math.isfinite(self.east) and math.isfinite(self.north)


def finite_or_none(value: float, digits: int | None = None) -> float | None:
    """A JSON-safe number: None for NaN or infinite (JSON has neither), rounded when ``digits`` is given."""
    value = float(value)
    if not math.isfinite(value):
        return None
    return round(value, digits) if digits is not None else value


def speed_course(vx: float, vy: float) -> tuple[float, float]:
    """Speed (m/s) and course over ground (degrees clockwise from north) of a velocity east/north; NaN unknown.

    A vessel at rest (under ``STILL_MPS``) has no course: its direction would be noise.
    """
    if not (math.isfinite(vx) and math.isfinite(vy)):
        return math.nan, math.nan
    speed = math.hypot(vx, vy)
    return speed, (math.degrees(math.atan2(vx, vy)) % 360.0 if speed >= STILL_MPS else math.nan)


def covariance_ellipse(covariance: Sequence[float], probability: float = ELLIPSE_PROBABILITY) -> dict | None:
    """Semi-axes (m) and angle (degrees counter-clockwise from east) of the ellipse holding ``probability``.

    None when the 2x2 row-major covariance is not finite, symmetric and positive semi-definite: no ellipse is
    better than a wrong one.
    """
    if len(covariance) != 4 or not all(math.isfinite(float(v)) for v in covariance):
        return None
    a, b, c, d = (float(v) for v in covariance)
    if abs(b - c) > 1e-6 * max(1.0, abs(a), abs(d)):
        return None
    half_trace, det = (a + d) / 2.0, a * d - b * b
    root = math.sqrt(max(half_trace * half_trace - det, 0.0))
    major, minor = half_trace + root, half_trace - root
    if minor < -1e-9 * max(1.0, major):
        return None
    scale = math.sqrt(-2.0 * math.log(1.0 - probability))
    angle = 0.5 * math.degrees(math.atan2(2.0 * b, a - d))
    return {"a_m": scale * math.sqrt(max(major, 0.0)), "b_m": scale * math.sqrt(max(minor, 0.0)),
            "angle_deg": angle}


def vessel_json(record: TrackRecord, track: Iterable[tuple[float, float]] = ()) -> dict:
    """One vessel as ``/vessels.json`` and the page carry it (None for what is not known)."""
    speed, course = speed_course(record.vx, record.vy)
    placed = record.placed
    ellipse = covariance_ellipse(record.covariance) if placed else None
    return {
        "id": record.id,
        "class": record.class_id,
        "is_target": bool(record.is_target),
        "status": int(record.status),
        "lat": finite_or_none(record.lat, 7) if placed else None,
        "lon": finite_or_none(record.lon, 7) if placed else None,
        "east_m": finite_or_none(record.east, 2) if placed else None,
        "north_m": finite_or_none(record.north, 2) if placed else None,
        "distance_m": finite_or_none(record.distance_m, 1) if placed else None,
        "bearing_deg": finite_or_none(record.bearing_deg, 1) if placed else None,
        "speed_mps": finite_or_none(speed, 2),
        "speed_kn": finite_or_none(speed * KNOTS_PER_MPS, 1),
        "course_deg": finite_or_none(course, 1),
        "covariance": [finite_or_none(v, 3) for v in record.covariance] if placed else None,
        "ellipse": {k: round(v, 2) for k, v in ellipse.items()} if ellipse else None,
        "confidence": finite_or_none(record.confidence, 3),
        "cpa_m": finite_or_none(record.cpa_m, 1) if record.has_cpa else None,
        "tcpa_s": finite_or_none(record.tcpa_s, 1) if record.has_cpa else None,
        "cpa_alert": bool(record.has_cpa and record.cpa_alert),
        "track": [[round(e, 1), round(n, 1)] for e, n in track],
    }


class Track(deque):
    """A vessel's recent positions (east, north), at most one per ``TRACK_SPACING_S`` of its stamps."""

    def __init__(self, maxlen: int):
        super().__init__(maxlen=maxlen)
        self.last_stamp = -math.inf

    def add(self, stamp: float, east: float, north: float) -> None:
        """Add a position; within ``TRACK_SPACING_S`` of the last kept one it replaces the newest point."""
        if self and stamp - self.last_stamp < TRACK_SPACING_S:
            self[-1] = (east, north)
            return
        self.append((east, north))
        self.last_stamp = stamp


class RateMeter:
    """Events per second over the last ``window`` events, from the wall clock (the page's "frames per second")."""

    def __init__(self, window: int = 20):
        self._times: deque[float] = deque(maxlen=window)

    def tick(self, now: float) -> None:
        """Count one event at monotonic time ``now``."""
        self._times.append(now)

    def rate(self, now: float, stale_s: float = 10.0) -> float:
        """Events per second; NaN with fewer than two, or when the last is older than ``stale_s``."""
        times = self._times
        if len(times) < 2 or now - times[-1] > stale_s or times[-1] <= times[0]:
            return math.nan
        return (len(times) - 1) / (times[-1] - times[0])


class Throttle:
    """At most one update per ``interval_s``, and never a last update left unsent.

    ``offer`` marks that something changed; ``due`` says whether to send now. A change that arrives within the
    interval is sent once the interval has passed (the next ``due``), so the page always ends on the newest state.
    """

    def __init__(self, interval_s: float):
        self.interval_s = float(interval_s)
        self._last = -math.inf
        self._pending = False

    def offer(self) -> None:
        """Something changed."""
        self._pending = True

    def due(self, now: float) -> bool:
        """Whether to send at monotonic time ``now`` (then the pending change counts as sent)."""
        if not self._pending or now - self._last < self.interval_s:
            return False
        self._pending = False
        self._last = now
        return True


@dataclass
class ImageSlot:
    """The newest camera image of one camera as JPEG bytes; ``seq`` grows with each, so the page asks only anew."""

    jpeg: bytes = b""
    seq: int = 0
    stamp: float = math.nan


class CameraState:
    """One camera (one namespace): its geometry, its vessels with their tracks, its status and its image."""

    def __init__(self, namespace: str, geometry: CameraGeometry | None = None, history: int = HISTORY_POINTS):
        self.namespace = namespace
        self.geometry = geometry
        self.history = history
        self.records: dict[str, TrackRecord] = {}
        self.tracks: dict[str, Track] = {}
        self.stamp = math.nan
        self.nodes: dict[str, NodeStatus] = {}
        self.fix: dict | None = None
        self.image = ImageSlot()
        self.arrays = RateMeter()

    def update_tracks(self, stamp: float, records: Sequence[TrackRecord], now: float) -> str:
        """Apply one array of every vessel tracked in one image; what was done: new, merged, old or reset.

        A newer stamp replaces the vessels (an array lists them all; those missing have ended). The same stamp
        again (``/vessel/tracks`` and ``/vessel/fixes`` carry the same frame) merges by id. An older stamp is
        dropped, unless it is ``BACKWARDS_RESET_S`` or more back: a replay starting over, which starts afresh.
        """
        outcome = "new"
        if math.isfinite(self.stamp) and stamp < self.stamp:
            if self.stamp - stamp < BACKWARDS_RESET_S:
                return "old"
            self.records.clear()
            self.tracks.clear()
            outcome = "reset"
        if math.isfinite(self.stamp) and stamp == self.stamp:
            outcome = "merged"
            current = dict(self.records)
        else:
            current = {}
            self.arrays.tick(now)
        for record in records:
            if record.status == STATUS_LOST:
                current.pop(record.id, None)
                continue
            current[record.id] = record
            if record.placed:
                self.tracks.setdefault(record.id, Track(self.history)).add(stamp, record.east, record.north)
        self.records = current
        for gone in set(self.tracks) - set(current):
            del self.tracks[gone]
        self.stamp = stamp
        return outcome

    def vessels(self) -> list[dict]:
        """Every current vessel as ``vessel_json``: the vessel of interest first, then those placed, then by id."""
        ordered = sorted(self.records.values(), key=lambda r: (not r.is_target, not r.placed, r.id))
        return [vessel_json(r, self.tracks.get(r.id, ())) for r in ordered]

    def status(self, now: float) -> dict:
        """The status line and its parts, from the nodes' reports and the arrival rate of track arrays."""
        return status_summary(self.nodes.values(), self.arrays.rate(now))

    def snapshot(self, now: float) -> dict:
        """Everything the page draws for this camera."""
        return {
            "namespace": self.namespace,
            "camera": self.geometry.to_json() if self.geometry is not None else None,
            "stamp": finite_or_none(self.stamp, 3),
            "vessels": self.vessels(),
            "fix": self.fix,
            "status": self.status(now),
            "image_seq": self.image.seq,
        }


class ViewState:
    """Every camera's state behind one lock: ROS callbacks write, the server thread reads.

    ``counts`` holds the problems met (a bad message, a dropped update), which the node also reports on
    ``/diagnostics``: the view keeps going on bad input and says how often it met it.
    """

    def __init__(self, chart: Chart | None = None, history: int = HISTORY_POINTS):
        self._lock = threading.Lock()
        self.cameras: dict[str, CameraState] = {}
        self.chart = chart
        self.history = history
        self.counts: dict[str, int] = {}
        self.version = 0

    def add_camera(self, namespace: str, geometry: CameraGeometry | None) -> CameraState:
        """Register a camera (its namespace and, if known, its calibration's geometry)."""
        with self._lock:
            camera = self.cameras.setdefault(namespace, CameraState(namespace, geometry, self.history))
            camera.geometry = geometry if geometry is not None else camera.geometry
            return camera

    def _camera(self, namespace: str) -> CameraState:
        camera = self.cameras.get(namespace)
        if camera is None:
            camera = self.cameras[namespace] = CameraState(namespace, None, self.history)
        return camera

    def count(self, kind: str, n: int = 1) -> None:
        """Count a problem or an event (``bad_track``, ``old_array``, ``dropped_updates``)."""
        with self._lock:
            self.counts[kind] = self.counts.get(kind, 0) + n

    def update_tracks(self, namespace: str, stamp: float, records: Sequence[TrackRecord],
                      now: float | None = None) -> str:
        """Apply a track array to a camera (``CameraState.update_tracks``); old ones are counted."""
        with self._lock:
            outcome = self._camera(namespace).update_tracks(stamp, records, time.monotonic() if now is None else now)
            if outcome in ("old", "reset"):
                self.counts[f"{outcome}_arrays"] = self.counts.get(f"{outcome}_arrays", 0) + 1
            self.version += 1
            return outcome

    def set_fix(self, namespace: str, fix: dict) -> None:
        """The vessel of interest as published on ``/vessel/fix`` (``{"status", "lat", "lon", "stamp"}``)."""
        with self._lock:
            self._camera(namespace).fix = fix
            self.version += 1

    def set_node_statuses(self, namespace: str, statuses: Iterable[NodeStatus]) -> None:
        """The newest report of each node (``/diagnostics`` carries one node's per message, as a rule)."""
        with self._lock:
            camera = self._camera(namespace)
            for status in statuses:
                camera.nodes[status.name] = status
            self.version += 1

    def set_image(self, namespace: str, jpeg: bytes, stamp: float) -> int:
        """Keep the newest JPEG of a camera; its sequence number."""
        with self._lock:
            slot = self._camera(namespace).image
            slot.jpeg, slot.stamp, slot.seq = bytes(jpeg), stamp, slot.seq + 1
            return slot.seq

    def image(self, namespace: str) -> tuple[bytes, int] | None:
        """The newest JPEG of a camera and its sequence number; None before the first."""
        with self._lock:
            camera = self.cameras.get(namespace)
            if camera is None or not camera.image.seq:
                return None
            return camera.image.jpeg, camera.image.seq

    def records(self, namespace: str) -> tuple[float, list[TrackRecord]]:
        """A camera's stamp and current records (a copy, for the Foxglove bridge)."""
        with self._lock:
            camera = self.cameras.get(namespace)
            return (camera.stamp, list(camera.records.values())) if camera else (math.nan, [])

    def status(self, namespace: str, now: float | None = None) -> dict:
        """A camera's status line and its parts (``status_summary``)."""
        with self._lock:
            camera = self._camera(namespace)
            return camera.status(time.monotonic() if now is None else now)

    def snapshot(self, now: float | None = None) -> dict:
        """The whole state as the page reads it: ``{"type": "state", "cameras": [...], "chart": ...}``."""
        now = time.monotonic() if now is None else now
        with self._lock:
            return {
                "type": "state",
                "version": self.version,
                "cameras": [camera.snapshot(now) for camera in self.cameras.values()],
                "chart": self.chart.to_json() if self.chart is not None else None,
                "counts": dict(sorted(self.counts.items())),
            }

    def snapshot_json(self, now: float | None = None) -> str:
        """``snapshot`` as compact JSON text (strict: no NaN)."""
        return json.dumps(self.snapshot(now), separators=(",", ":"), allow_nan=False)

    def vessels_json(self) -> str:
        """``GET /vessels.json``: every camera's current vessels, each with its camera's namespace."""
        with self._lock:
            vessels = [dict(v, namespace=camera.namespace) for camera in self.cameras.values()
                       for v in camera.vessels()]
        return json.dumps({"vessels": vessels}, separators=(",", ":"), allow_nan=False)
