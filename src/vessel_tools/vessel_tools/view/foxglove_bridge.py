"""The view's data in Foxglove's own schemas, served on Foxglove's WebSocket protocol (``--foxglove-port``).

Foxglove reads ROS 2 topics only through a bridge; this process already holds every vessel as plain values, so it
logs them with the ``foxglove-sdk`` (an optional extra, ``requirements-view.txt``) in the schemas Foxglove's panels
draw without configuration:

- ``/view/vessel/<id>``: ``foxglove.LocationFix`` of each vessel with its covariance (the Map panel);
  ``/view/target``: the vessel of interest alone;
- ``/view/image`` and ``/view/image/annotations``: the camera's own JPEG and each track's box as
  ``foxglove.ImageAnnotations`` (the Image panel draws the boxes itself, in full-resolution pixels);
- ``/view/plan``: ``foxglove.SceneUpdate`` in metres east/north of the camera (frame ``camera``): the field of
  view, each vessel with its track, ellipse, velocity and label (the 3-D panel, seen from above);
- ``/view/status``: the page's status line as JSON.

``config/foxglove_layout.json`` (written by ``foxglove_layout``) arranges the map, image and plan side by side.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence

from vessel_common.errors import DataError
from vessel_tools.view.geometry import CameraGeometry
from vessel_tools.view.state import KNOTS_PER_MPS, STILL_MPS, TrackRecord, covariance_ellipse, speed_course

PLAN_TOPIC = "/view/plan"
IMAGE_TOPIC = "/view/image"
ANNOTATIONS_TOPIC = "/view/image/annotations"
TARGET_TOPIC = "/view/target"
STATUS_TOPIC = "/view/status"
VESSEL_TOPIC_PREFIX = "/view/vessel/"
FRAME_ID = "camera"
ORANGE, BLUE, RED, WHITE = (1.0, 0.69, 0.0, 1.0), (0.37, 0.78, 1.0, 1.0), (1.0, 0.3, 0.3, 1.0), (1.0, 1.0, 1.0, 1.0)


def foxglove_module():
    """The ``foxglove`` package; DataError saying how to install it when it is missing."""
    try:
        import foxglove
        import foxglove.channels
        import foxglove.messages
    except ImportError:
        raise DataError("--foxglove-port needs the foxglove-sdk package: run ./vessel setup --view "
                        "(pip install -r requirements-view.txt -c constraints.txt)") from None
    return foxglove


def vessel_topic(track_id: str) -> str:
    """The LocationFix topic of one vessel (its id, with characters a topic name cannot hold replaced)."""
    return VESSEL_TOPIC_PREFIX + (re.sub(r"[^A-Za-z0-9_]", "_", track_id) or "_")


class FoxgloveBridge:
    """A Foxglove WebSocket server fed with the view's vessels, image and status.

    Built from the node's thread only. A vessel's channel is closed when the vessel is gone, so a long run does
    not advertise every id it ever saw.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, name: str = "vessel view"):
        fox = foxglove_module()
        self._m = fox.messages
        try:
            self.server = fox.start_server(name=name, host=host, port=port)
        except Exception as error:  # the SDK raises its own error types; none may end in a traceback
            raise DataError(f"cannot serve Foxglove on {host}:{port} ({error}): choose another --foxglove-port") \
                from None
        channels = fox.channels
        self.plan = channels.SceneUpdateChannel(PLAN_TOPIC)
        self.image = channels.CompressedImageChannel(IMAGE_TOPIC)
        self.annotations = channels.ImageAnnotationsChannel(ANNOTATIONS_TOPIC)
        self.target = channels.LocationFixChannel(TARGET_TOPIC)
        status_schema = json.dumps({"type": "object", "title": "the page's status line and its figures"})
        self.status = fox.Channel(STATUS_TOPIC, message_encoding="json", schema=fox.Schema(
            name="vessel_view.Status", encoding="jsonschema", data=status_schema.encode()))
        self._location_channel = channels.LocationFixChannel
        self.vessels: dict[str, object] = {}
        self._drawn: set[str] = set()
        self.port = self.server.port

    def close(self) -> None:
        """Stop the server."""
        self.server.stop()

    # ------------------------------------------------------------------------------------------ messages
    def _timestamp(self, stamp: float):
        return self._m.Timestamp.from_epoch_secs(max(stamp, 0.0)) if math.isfinite(stamp) else None

    def _color(self, rgba: tuple[float, float, float, float], alpha: float | None = None):
        r, g, b, a = rgba
        return self._m.Color(r=r, g=g, b=b, a=a if alpha is None else alpha)

    def location_fix(self, record: TrackRecord):
        """A vessel as ``foxglove.LocationFix``: its position with the ENU covariance (3x3, m²) and its colour."""
        m = self._m
        e, n = record.covariance[0], record.covariance[3]
        en = record.covariance[1]
        known = all(math.isfinite(v) for v in record.covariance)
        covariance = [e, en, 0.0, en, n, 0.0, 0.0, 0.0, 0.0] if known else None
        kind = m.LocationFixPositionCovarianceType.Known if known else m.LocationFixPositionCovarianceType.Unknown
        return m.LocationFix(timestamp=self._timestamp(record.stamp), frame_id=record.id, latitude=record.lat,
                             longitude=record.lon, altitude=0.0, position_covariance=covariance,
                             position_covariance_type=kind, color=self._color(ORANGE if record.is_target else BLUE))

    def annotations_message(self, stamp: float, records: Sequence[TrackRecord]):
        """Each track's box (outline) and label as ``foxglove.ImageAnnotations`` in the image's pixels."""
        m = self._m
        points, texts = [], []
        for record in records:
            cx, cy, w, h = record.bbox
            if not all(math.isfinite(v) for v in record.bbox) or w <= 0 or h <= 0:
                continue
            color = self._color(ORANGE if record.is_target else BLUE)
            corners = [(cx - w / 2, cy - h / 2), (cx + w / 2, cy - h / 2), (cx + w / 2, cy + h / 2),
                       (cx - w / 2, cy + h / 2)]
            points.append(m.PointsAnnotation(timestamp=self._timestamp(stamp), type=m.PointsAnnotationType.LineLoop,
                                             points=[m.Point2(x=x, y=y) for x, y in corners], outline_color=color,
                                             thickness=2.0))
            texts.append(m.TextAnnotation(timestamp=self._timestamp(stamp),
                                          position=m.Point2(x=cx - w / 2, y=cy - h / 2 - 4), text=_label(record),
                                          font_size=14.0, text_color=color,
                                          background_color=self._color((0.0, 0.0, 0.0, 0.6))))
        return m.ImageAnnotations(points=points, texts=texts)

    def _point(self, e: float, n: float):
        return self._m.Point3(x=e, y=n, z=0.0)

    def _pose(self, e: float = 0.0, n: float = 0.0, yaw: float = 0.0):
        m = self._m
        return m.Pose(position=m.Vector3(x=e, y=n, z=0.0),
                      orientation=m.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0)))

    def camera_entity(self, geometry: CameraGeometry, stamp: float):
        """The camera and its field of view on the plan."""
        m = self._m
        outline = m.LinePrimitive(type=m.LinePrimitiveLineType.LineLoop, thickness=2.0, scale_invariant=True,
                                  points=[self._point(e, n) for e, n in geometry.fov], color=self._color(BLUE, 0.6))
        label = m.TextPrimitive(pose=self._pose(), billboard=True, font_size=14.0, scale_invariant=True,
                                color=self._color(WHITE), text="camera")
        return m.SceneEntity(timestamp=self._timestamp(stamp), frame_id=FRAME_ID, id="camera", lines=[outline],
                             texts=[label], cubes=[m.CubePrimitive(pose=self._pose(), size=m.Vector3(x=6, y=6, z=2),
                                                                   color=self._color(WHITE))])

    def vessel_entity(self, record: TrackRecord, track: Sequence[tuple[float, float]]):
        """A vessel on the plan: marker, recent track, 95 % ellipse, one minute of velocity, label."""
        m = self._m
        color = ORANGE if record.is_target else (RED if record.cpa_alert else BLUE)
        e, n = record.east, record.north
        lines = []
        if len(track) > 1:
            lines.append(m.LinePrimitive(type=m.LinePrimitiveLineType.LineStrip, thickness=2.0, scale_invariant=True,
                                         points=[self._point(a, b) for a, b in track], color=self._color(color, 0.6)))
        ellipse = covariance_ellipse(record.covariance)
        if ellipse is not None:
            angle = math.radians(ellipse["angle_deg"])
            ring = [(ellipse["a_m"] * math.cos(t), ellipse["b_m"] * math.sin(t))
                    for t in (2 * math.pi * k / 36 for k in range(36))]
            lines.append(m.LinePrimitive(type=m.LinePrimitiveLineType.LineLoop, thickness=1.5, scale_invariant=True,
                                         points=[self._point(e + x * math.cos(angle) - y * math.sin(angle),
                                                             n + x * math.sin(angle) + y * math.cos(angle))
                                                 for x, y in ring], color=self._color(color, 0.8)))
        arrows = []
        speed, _ = speed_course(record.vx, record.vy)
        if math.isfinite(speed) and speed >= STILL_MPS:
            arrows.append(m.ArrowPrimitive(pose=self._pose(e, n, math.atan2(record.vy, record.vx)),
                                           shaft_length=speed * 60.0, shaft_diameter=2.0, head_length=8.0,
                                           head_diameter=6.0, color=self._color(color)))
        marker = m.SpherePrimitive(pose=self._pose(e, n), size=m.Vector3(x=12.0, y=12.0, z=2.0),
                                   color=self._color(color))
        label = m.TextPrimitive(pose=self._pose(e + 10.0, n + 10.0), billboard=True, font_size=13.0,
                                scale_invariant=True, color=self._color(WHITE), text=_label(record))
        return m.SceneEntity(timestamp=self._timestamp(record.stamp), frame_id=FRAME_ID, id=f"vessel/{record.id}",
                             spheres=[marker], lines=lines, arrows=arrows, texts=[label])

    # ------------------------------------------------------------------------------------------ logging
    def publish_tracks(self, stamp: float, records: Sequence[TrackRecord],
                       tracks: dict[str, Sequence[tuple[float, float]]], geometry: CameraGeometry | None) -> None:
        """Log the plan, the boxes and every vessel's fix for one track array."""
        m = self._m
        placed = [r for r in records if r.placed]
        entities = [self.vessel_entity(r, tracks.get(r.id, ())) for r in placed]
        if geometry is not None:
            entities.append(self.camera_entity(geometry, stamp))
        drawn = {f"vessel/{r.id}" for r in placed}
        deletions = [m.SceneEntityDeletion(timestamp=self._timestamp(stamp), id=gone) for gone in self._drawn - drawn]
        self._drawn = drawn
        self.plan.log(m.SceneUpdate(deletions=deletions, entities=entities))
        self.annotations.log(self.annotations_message(stamp, records))
        self._publish_fixes(placed)

    def _publish_fixes(self, placed: Sequence[TrackRecord]) -> None:
        current = set()
        for record in placed:
            if not (math.isfinite(record.lat) and math.isfinite(record.lon)):
                continue
            current.add(record.id)
            channel = self.vessels.get(record.id)
            if channel is None:
                channel = self.vessels[record.id] = self._location_channel(vessel_topic(record.id))
            fix = self.location_fix(record)
            channel.log(fix)
            if record.is_target:
                self.target.log(fix)
        for gone in set(self.vessels) - current:
            self.vessels.pop(gone).close()

    def publish_image(self, stamp: float, data: bytes, image_format: str = "jpeg") -> None:
        """Log the camera's compressed image as it came (no re-encoding)."""
        self.image.log(self._m.CompressedImage(timestamp=self._timestamp(stamp), frame_id=FRAME_ID, data=bytes(data),
                                               format=image_format or "jpeg"))

    def publish_status(self, status: dict) -> None:
        """Log the status line and its figures as JSON."""
        self.status.log(json.loads(json.dumps(status)))

    def has_sinks(self) -> bool:
        """Whether any Foxglove client listens to the image (the node then subscribes to the camera's JPEGs)."""
        return self.image.has_sinks() or self.plan.has_sinks()


def _label(record: TrackRecord) -> str:
    """``id class, 4.2 kn 123°`` and the CPA when known."""
    speed, course = speed_course(record.vx, record.vy)
    text = f"{record.id} {record.class_id}".strip() + (" (target)" if record.is_target else "")
    if math.isfinite(speed):
        text += f", {speed * KNOTS_PER_MPS:.1f} kn" + (f" {course:.0f}°" if math.isfinite(course) else "")
    if record.has_cpa and math.isfinite(record.cpa_m):
        text += f", CPA {record.cpa_m:.0f} m in {record.tcpa_s:.0f} s"
    return text


def foxglove_layout() -> str:
    """The layout ``config/foxglove_layout.json`` holds: map, image with boxes, plan from above, status."""
    foxglove_module()
    import foxglove.layouts as fl

    map_panel = fl.MapPanel(title="vessels", config=fl.MapConfig(follow_topic=TARGET_TOPIC, zoom_level=15.0))
    image_panel = fl.ImagePanel(title="camera", config=fl.ImageConfig(image_mode=fl.ImageModeConfig(
        image_topic=IMAGE_TOPIC, annotations={ANNOTATIONS_TOPIC: fl.ImageAnnotationSettings(visible=True)})))
    plan_panel = fl.ThreeDeePanel(title="plan (metres east/north of the camera)", config=fl.ThreeDeeConfig(
        follow_tf=FRAME_ID, fixed_frame=FRAME_ID,
        camera_state=fl.ThreeDeeCameraState(perspective=False, distance=3000.0, phi=0.0, theta_offset=0.0),
        topics={PLAN_TOPIC: fl.BaseRendererSceneUpdateTopicSettings(visible=True)}))
    status_panel = fl.RawMessagesPanel(title="status", config=fl.RawMessagesConfig(topic_path=STATUS_TOPIC))
    layout = fl.Layout(content=fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=4, content=fl.SplitContainer(direction="row", items=[
            fl.SplitItem(content=map_panel), fl.SplitItem(content=image_panel), fl.SplitItem(content=plan_panel)])),
        fl.SplitItem(proportion=1, content=status_panel)]))
    return json.dumps(json.loads(layout.to_json()), indent=2, sort_keys=True) + "\n"
