"""``fuser`` node: screen-space tracks in, tracks on the sea plane (metres, lat/lon, covariance, target) out.

Subscribes ``/vessel/tracks/screen`` (``vessel_msgs/VesselTrackArray`` from the tracker), publishes
``/vessel/tracks`` with every track's world position, velocity, 2x2 covariances, lat/lon, distance,
bearing, expected error and the vessel-of-interest flag; the header (image stamp) is kept. The work is done by
``vessel_track.track_fuser.TrackFuser`` (fusion of box position and size, a Kalman filter per track in world
coordinates, online target selection); this node converts messages and reports problems on ``/diagnostics``.

Collision figures (``vessel_track.collision``): every track with a position gets ``distance_sigma_m`` and
``bearing_sigma_deg``; one whose filter has measured a velocity (and not LOST) gets CPA and TCPA against the own
ship with their deviations (``has_cpa``) and ``cpa_alert``; the tracks in alert go out on
``collision_alerts_topic`` too, only in frames that have one. The own ship is the camera's platform: with
``own_ship_fix_topic`` '' the camera is fixed at the calibration's position and at rest. With a topic
(``sensor_msgs/NavSatFix``), the node keeps the recent fixes (``collision.OwnShipTrack``) and takes the own ship
at each frame's stamp; every measurement is shifted by the camera's position then, so the world filters stay in the
calibration's fixed frame. Published ``position``, ``distance_m`` and ``bearing_deg`` are from the camera at the
frame's stamp, ``velocity`` over ground, lat/lon absolute. A frame without a fresh own-ship fix
(``own_ship_max_age_s``) gets no CPA and is counted (``own_ship_stale``, ``own_ship_missing``); its positions
rest on the own ship dead-reckoned from its last fixes (the calibration's position before the first).

A track counts as measured in a frame when its ``last_seen`` equals the array's stamp (the tracker sets it to
the stamp of the detection it associated).

Refused at the boundary (``vessel_track.message_checks``): a message with an invalid stamp, the previous message's
stamp or one slightly before it (a step back of ``BACKWARDS_RESET_S`` or more goes on: a replay restarted, the
world filters reset), and each track with a repeated id, an unknown status, a confidence outside [0, 1], times
after the stamp, or a screen covariance or velocity that is not finite (a box without a position is not refused:
it goes on without a world position, ``invalid_track``).
"""
from __future__ import annotations

import math

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import NavSatFix, NavSatStatus

from vessel_calib import geodesy
from vessel_calib.camera_parameters import declare_camera_model
from vessel_common.errors import VesselError
from vessel_common.health import NodeHealth
from vessel_common.node_parameters import declare_table
from vessel_common.node_state import NodeState, Standby
from vessel_common.qos import reliable_qos, sensor_stream_qos, stamp_to_sec
from vessel_common.state_file import settings_fingerprint
from vessel_common.wire import WireType, decoding_callback, encoded_or_none
from vessel_msgs.msg import VesselTrack, VesselTrackArray
from vessel_track import deferred_imports
from vessel_track.collision import (
    AT_REST_AT_ORIGIN,
    AlertRule,
    Kinematics,
    OwnShipEstimate,
    OwnShipTrack,
    collision_figures,
    range_bearing,
)
from vessel_track.message_checks import TRACK_ARRAY_TYPE, checked_tracks, header_refusal, order_refusal, report
from vessel_track.node_params import fuser_settings_of, main_with_checks, refuse_moved_parameters
from vessel_track.parameter_tables import FUSER_PARAMETERS
from vessel_track.track_fuser import STATUS_LOST, ScreenTrack, TrackFuser, WorldTrack

#: last_seen within this of the frame stamp means the track was updated in this frame.
UPDATED_TOLERANCE_S = 1e-6

PROBLEM_MESSAGES = {
    "invalid_track": "a track with NaN/inf or non-positive box size was received; it is passed on without a "
                     "world position",
    "stamp_backwards": "track stamps went backwards (replay restarted?): every world filter was reset",
    "gap": "a long gap between track messages: the world filters restart",
    "above_horizon": "a box on or above the horizon gave no position",
    "beyond_max_range": "a box beyond fusion.max_range_m gave no position",
    "invalid_box": "a box could not be undistorted (outside the lens model)",
    "outlier_rejected": "a fused position far from its track's prediction was rejected by the world filter",
    "identity_changed": "a track's positions stopped fitting its world filter (motion.max_rejections outliers in a "
                        "row): the tracker may have moved it onto another vessel, so its history was ended",
    "shape_jump": "a box much taller for its width than its track's recent boxes (spray or wake below the hull) was "
                  "trusted less",
    "height_drop": "a box much shorter than its track's recent boxes (only the cabin or console boxed) was trusted "
                   "less",
    "water_level_unknown": "a frame's stamp is outside water_level.file (plus water_level.max_hold_s): it was fused "
                           "at the calibration's water level; extend the file to cover the recording",
    "water_level_unusable": "water_level.file gives a level that would put the camera under the water (metres? "
                            "the datum of the calibration?): the frame was fused at the calibration's level",
    "own_ship_missing": "no own-ship fix on own_ship_fix_topic yet: the frame gets no CPA (has_cpa false), its "
                        "positions as if the camera stood at the calibration's position",
    "own_ship_stale": "no own-ship fix within own_ship_max_age_s of a frame's stamp: its CPA is not given (has_cpa "
                      "false), its positions rest on the own ship dead-reckoned from its last fixes",
    "own_ship_no_fix": "an own-ship NavSatFix said STATUS_NO_FIX: ignored",
    "own_ship_bad_fix": "an own-ship NavSatFix with a NaN or impossible position, or an invalid stamp: ignored",
    "own_ship_fix_out_of_order": "an own-ship fix stamped at or before the previous one (by less than 1 s): ignored",
}


OPERATING_EVENTS = frozenset({"above_horizon", "beyond_max_range", "shape_jump", "height_drop", "outlier_rejected",
                              "identity_changed"})
"""Kinds of ``PROBLEM_MESSAGES`` that a healthy graph meets every minute (a boat at the horizon, a box of spray):
counted on ``/diagnostics`` but no warning, so that the node's status says WARN only for bad input or set-up."""


def screen_track_from_msg(msg: VesselTrack, stamp: float, source: str = "measured") -> ScreenTrack:
    """The fuser core's view of a ``VesselTrack`` from the tracker (as ``pipeline.screen_track_of``).

    ``source`` (``fusion.screen_source``): ``measured`` takes the box of the detection associated in this image
    (``detection_bbox``) when the track was updated and that box is filled in, else the filtered ``bbox``;
    ``filtered`` always takes ``bbox``.
    """
    last_seen = stamp_to_sec(msg.last_seen)
    updated = abs(last_seen - stamp) <= UPDATED_TOLERANCE_S
    box = msg.bbox
    detection = msg.detection_bbox
    if source == "measured" and updated and detection.size_x > 0 and detection.size_y > 0:
        box = detection
    return ScreenTrack(
        track_id=msg.id,
        status=int(msg.status),
        center=np.array([box.center.position.x, box.center.position.y], dtype=float),
        size=np.array([box.size_x, box.size_y], dtype=float),
        confidence=float(msg.confidence),
        updated=updated,
        detection_count=int(msg.detection_count),
        first_seen=stamp_to_sec(msg.first_seen),
        last_seen=last_seen,
        center_cov=np.array(msg.screen_covariance, dtype=float).reshape(2, 2),
        velocity_px=np.array([msg.screen_velocity.x, msg.screen_velocity.y], dtype=float),
        pose_sigma_px=np.nan_to_num(np.abs(np.asarray(msg.pose_sigma_px, dtype=float))),
    )


def _finite_or_nan(values) -> np.ndarray:
    array = np.array(values, dtype=np.float64).ravel()
    array[~np.isfinite(array)] = math.nan
    return array


def _symmetric(matrix) -> np.ndarray:
    """``matrix`` made exactly symmetric: a filter's covariance is only to rounding, and consumers may check it."""
    matrix = np.asarray(matrix, dtype=float)
    return (matrix + matrix.T) / 2.0


def fill_world_fields(msg: VesselTrack, world: WorldTrack) -> VesselTrack:
    """Write the fuser's results into ``msg`` (a copy of the input track); NaN and has_world=False if none.

    ``position`` is from the camera at this stamp (``WorldTrack.relative_position``), ``velocity`` over ground.
    """
    msg.is_target = bool(world.is_target)
    msg.score = float(world.score)
    msg.has_world = bool(world.has_world)
    position = world.relative_position
    msg.position.x, msg.position.y, msg.position.z = (float(position[0]), float(position[1]),
                                                      0.0 if world.has_world else math.nan)
    msg.velocity.x, msg.velocity.y, msg.velocity.z = (float(world.velocity[0]), float(world.velocity[1]),
                                                      0.0 if world.has_world else math.nan)
    msg.position_covariance = _finite_or_nan(_symmetric(world.position_covariance))
    msg.velocity_covariance = _finite_or_nan(_symmetric(world.velocity_covariance))
    msg.latitude = float(world.latitude)
    msg.longitude = float(world.longitude)
    msg.distance_m = float(world.distance_m)
    msg.bearing_deg = float(world.bearing_deg)
    msg.expected_error_m = float(world.expected_error_m)
    return msg


def fill_collision_fields(msg: VesselTrack, world: WorldTrack, own: OwnShipEstimate | None,
                          rule: AlertRule) -> VesselTrack:
    """Write the deviations of distance and bearing, and the CPA figures and alert, into ``msg``.

    ``own``: the own ship at this stamp (None: the fixed camera, at rest at the origin). NaN (and ``has_cpa``
    false) for what is not given: no position, no measured velocity yet, a LOST track, an own ship not known at
    this stamp, or a state the figures cannot be computed from. The own ship's position error is left out: the
    camera measures the vessel from where the own ship is, so a GPS error moves both alike; its velocity error is
    kept (the vessel's velocity over ground and the own ship's come from different measurements).
    """
    msg.has_cpa = msg.cpa_alert = False
    msg.distance_sigma_m = msg.bearing_sigma_deg = math.nan
    msg.cpa_m = msg.cpa_sigma_m = msg.tcpa_s = msg.tcpa_sigma_s = math.nan
    if not world.has_world:
        return msg
    try:
        _, msg.distance_sigma_m, _, msg.bearing_sigma_deg = range_bearing(world.relative_position,
                                                                          world.position_covariance)
        if not world.velocity_known or world.screen.status == STATUS_LOST or (own is not None and not own.usable):
            return msg
        ship = AT_REST_AT_ORIGIN if own is None else Kinematics(own.kinematics.position, own.kinematics.velocity,
                                                        velocity_covariance=own.kinematics.velocity_covariance)
        figures = collision_figures(ship, Kinematics(world.position, world.velocity, world.position_covariance,
                                                     world.velocity_covariance, world.position_velocity_covariance))
    except VesselError:  # a non-finite state: nothing to give
        return msg
    msg.has_cpa = True
    msg.cpa_m, msg.cpa_sigma_m = figures.cpa_m, figures.cpa_sigma_m
    msg.tcpa_s, msg.tcpa_sigma_s = figures.tcpa_s, figures.tcpa_sigma_s
    msg.cpa_alert = rule.in_alert(figures)
    return msg


def alert_rule_of(values: dict) -> AlertRule:
    """The ``AlertRule`` of the node's ``collision.*`` parameter values; a bad one is a DataError."""
    return AlertRule(cpa_alert_m=float(values["collision.cpa_alert_m"]),
                     tcpa_alert_s=float(values["collision.tcpa_alert_s"]),
                     cpa_sigma_k=float(values["collision.cpa_sigma_k"]))


def own_ship_fix_of(msg: NavSatFix, camera) -> tuple[float, np.ndarray, np.ndarray] | str:
    """(stamp, metres east/north of the calibration's camera position, 2x2 covariance) of a fix, or why not.

    The covariance is the fix's east/north block, zero when the fix says it is unknown or it is not a covariance.
    """
    if msg.status.status < NavSatStatus.STATUS_FIX:
        return "own_ship_no_fix"
    stamp = stamp_to_sec(msg.header.stamp)
    try:
        geodesy.validate_lat_lon(msg.latitude, msg.longitude, "own ship fix")
    except VesselError:
        return "own_ship_bad_fix"
    if not (math.isfinite(stamp) and stamp > 0):
        return "own_ship_bad_fix"
    east, north = geodesy.gps_to_local(msg.latitude, msg.longitude, camera.camera_lat, camera.camera_lon)
    covariance = np.asarray(msg.position_covariance, dtype=float).reshape(3, 3)[:2, :2]
    if (msg.position_covariance_type == NavSatFix.COVARIANCE_TYPE_UNKNOWN or not np.all(np.isfinite(covariance))
            or covariance[0, 0] < 0 or covariance[1, 1] < 0):
        covariance = np.zeros((2, 2))
    return stamp, np.array([east, north]), covariance


class FuserNode(Node):
    """Thin ROS wrapper around ``TrackFuser``; see the module docstring."""

    def __init__(self):
        super().__init__("fuser")
        self.camera = declare_camera_model(self)
        refuse_moved_parameters(self)
        values = declare_table(self, FUSER_PARAMETERS, apply=self._apply_parameters)
        self.settings = s = fuser_settings_of(values)
        input_topic, output_topic, depth = values["input_topic"], values["output_topic"], values["qos_depth"]
        water_level = s.water_level.load()
        self.core = TrackFuser(self.camera, s.distance_model, s.fusion, s.cue_stats, s.motion, s.selection,
                               s.error_model, water_level=water_level, water_level_max_hold_s=s.water_level.max_hold_s)
        self.health = NodeHealth(self)
        self.standby = Standby(self)
        self.state = NodeState(self, self.health, "fuser", settings_fingerprint(self.camera, s),
                               read_only=not self.standby.active)
        self._reported_counts: dict[str, int] = {}
        self.alert_rule = alert_rule_of(values)
        self.wire = WireType(TRACK_ARRAY_TYPE)
        self.publisher = self.create_publisher(VesselTrackArray, output_topic, reliable_qos(depth))
        self.alert_publisher = self.create_publisher(VesselTrackArray, values["collision_alerts_topic"],
                                                     reliable_qos(depth))
        self.health.watch_subscribers(self.publisher, self.alert_publisher)
        self.own_ship = self._subscribe_own_ship(values)
        self.subscription = self.create_subscription(
            VesselTrackArray, input_topic, decoding_callback(self.wire, self.on_tracks, self.health),
            reliable_qos(depth), raw=True)
        self.get_logger().info(
            f"fuser: {input_topic} -> {output_topic}; camera heading {self.camera.heading_deg:.1f} deg, weights "
            f"{s.fusion.weights_mode}, {s.fusion.screen_source} boxes, error model "
            f"{100 * s.error_model.slope:.2f} m/100 m" + (
                f"; tide from {water_level.source} (camera {self.camera.height_m:.2f} m above the sea at "
                f"{self.camera.water_level_m:.2f} m)" if water_level is not None else "") + (
                f"; own ship from {values['own_ship_fix_topic']}" if self.own_ship is not None else
                "; fixed camera (own ship at rest)"))

    def _subscribe_own_ship(self, values: dict) -> OwnShipTrack | None:
        """The own ship's fixes from ``own_ship_fix_topic`` (None without one: a fixed camera), QoS ``own_ship_qos``."""
        topic = values["own_ship_fix_topic"]
        if not topic:
            return None
        track = OwnShipTrack(values["own_ship_max_age_s"], values["own_ship_velocity_window_s"])
        self.own_ship_subscription = self.create_subscription(NavSatFix, topic, self.on_own_ship_fix,
                                                              sensor_stream_qos(values["own_ship_qos"]))
        return track

    def on_own_ship_fix(self, msg: NavSatFix) -> None:
        """Keep one own-ship fix; a refused one is counted and logged once per kind."""
        fix = own_ship_fix_of(msg, self.camera)
        refusal = fix if isinstance(fix, str) else self.own_ship.add(*fix)
        if refusal:
            self.health.problem(refusal, PROBLEM_MESSAGES[refusal])
        else:
            self.health.count("own_ship_fixes")

    def _apply_parameters(self, values) -> None:
        """A live change of the distance model, the fusion, the error model or the alert, from the next frame on."""
        settings, rule = fuser_settings_of(values), alert_rule_of(values)
        self.settings, self.alert_rule = settings, rule
        self.core.distance_model = settings.distance_model
        self.core.fusion_config = settings.fusion
        self.core.cue_stats = settings.cue_stats
        self.core.error_model = settings.error_model

    def on_tracks(self, msg) -> None:
        """Fuse one image's tracks and publish them with their world state (what ``message_checks`` refuses aside).

        ``msg``: a ``VesselTrackArray`` as ``WireType`` decodes it (or an rclpy one): its tracks are edited and sent
        on.
        """
        refusal = header_refusal(msg.header.stamp)
        if refusal is not None:
            report(self.health, [refusal])
            return
        stamp = stamp_to_sec(msg.header.stamp)
        if self.state.resume(stamp, self.core):
            return  # the snapshot resumed already holds this frame
        previous = self.core.last_stamp
        refusal = order_refusal(stamp, previous)
        if refusal is not None:
            report(self.health, [refusal])
            return
        tracks, refusals = checked_tracks(msg.tracks, msg.header.stamp, previous)
        report(self.health, refusals)
        source = self.settings.fusion.screen_source
        screen = [screen_track_from_msg(track, stamp, source) for track in tracks]
        own = self._own_ship_at(stamp)
        world = self.core.update(stamp, screen, None if own is None else own.kinematics.position)
        by_id = {id(w.screen): w for w in world}
        filled = []
        for track_msg, screen_track in zip(tracks, screen, strict=True):
            world_track = by_id[id(screen_track)]
            track_msg = fill_world_fields(track_msg, world_track)
            filled.append(fill_collision_fields(track_msg, world_track, own, self.alert_rule))
        out = self.wire.new(header=msg.header, tracks=filled)
        alerts = self.wire.new(header=msg.header, tracks=[t for t in filled if t.cpa_alert])
        publishing = self.standby.publishing()
        if publishing:
            self._publish(self.publisher, out)
            if alerts.tracks:
                self._publish(self.alert_publisher, alerts)
        self._report(out)
        self._report_alerts(alerts)
        self.health.observe_input(stamp)
        if publishing:
            self.state.save(stamp, self.core)

    def _publish(self, publisher, msg) -> None:
        cdr = encoded_or_none(self.wire, msg, self.health)
        if cdr is not None:
            publisher.publish(cdr)

    def _own_ship_at(self, stamp: float) -> OwnShipEstimate | None:
        """The own ship at ``stamp`` (None: a fixed camera); a problem with it is counted, logged once."""
        if self.own_ship is None:
            return None
        own = self.own_ship.at(stamp)
        if own.problem:
            self.health.problem(own.problem, PROBLEM_MESSAGES[own.problem])
        return own

    def _report_alerts(self, alerts) -> None:
        """Tracks in collision alert: counted per frame and track (an event, not a fault), and named now."""
        if alerts.tracks:
            self.health.count("cpa_alerts", len(alerts.tracks))
        self.health.set_value("tracks_in_alert", ",".join(t.id for t in alerts.tracks))

    def _report(self, out) -> None:
        self.health.count("frames")
        for kind, count in self.core.counts.items():
            new = count - self._reported_counts.get(kind, 0)
            if new > 0:
                if kind in OPERATING_EVENTS:
                    self.health.count(kind, new)
                else:
                    for _ in range(new):
                        self.health.problem(kind, PROBLEM_MESSAGES.get(kind, kind))
                self._reported_counts[kind] = count
        target = next((t for t in out.tracks if t.is_target), None)
        self.health.set_value("tracks", len(out.tracks))
        self.health.set_value("target", target.id if target is not None else "")
        if target is not None and target.has_world:
            self.health.set_value("target_distance_m", float(target.distance_m))


def main(args=None) -> None:
    """Console entry point: ``ros2 run vessel_track fuser --ros-args --params-file config/aitas.yaml``."""
    import sys

    sys.exit(main_with_checks(FuserNode, args, preload=deferred_imports.MODULES))


if __name__ == "__main__":
    main()
