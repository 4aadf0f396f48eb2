"""``gps_publisher`` node: the vessel of interest as ``sensor_msgs/NavSatFix``, every vessel as a track array.

Subscribes ``/vessel/tracks`` (the fuser's ``VesselTrackArray``); publishes

* ``/vessel/fix`` (``NavSatFix``): the track flagged ``is_target``. Header stamp = the image's stamp,
  ``frame_id`` configurable. ``position_covariance`` is ENU (east, north, up) row-major: the fuser's filter
  covariance plus the error model (``expected_error_m`` of the track, read as the mean radial error of an
  isotropic Gaussian, i.e. sigma per axis = expected_error / sqrt(pi/2)), type COVARIANCE_TYPE_KNOWN.
  ``status`` is STATUS_FIX while the target has a position and was seen within ``max_coast_s``, else
  STATUS_NO_FIX (with NaN latitude/longitude) when ``publish_no_fix`` is true. The vessel is on the sea
  surface but its height above the WGS-84 ellipsoid is not measured: ``altitude`` is the parameter
  ``altitude_m`` (NaN by default, i.e. unknown) with variance ``altitude_variance_m2``.
* ``/vessel/fixes`` (``VesselTrackArray``): every vessel with a position (and those just LOST, so consumers can
  drop them), for collision avoidance.

The conversion is ``fix_fields_of_track`` (ROS-free, unit-tested); the node reports problems on
``/diagnostics``. Refused at the boundary (``vessel_track.message_checks``): a message with an invalid stamp, the
previous message's stamp or one slightly before it (no second fix with one stamp; a step back of
``BACKWARDS_RESET_S`` or more goes on, counted as ``stamp_backwards``: a replay restarted), and each track with a
repeated id, an unknown status, a confidence outside [0, 1], times after the stamp, or a covariance or expected
error that is not finite and non-negative (NaN only without ``has_world``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import NavSatFix, NavSatStatus

from vessel_calib import geodesy
from vessel_calib.camera_parameters import declare_camera_model
from vessel_common.health import NodeHealth
from vessel_common.node_parameters import declare_table
from vessel_common.node_state import Standby
from vessel_common.qos import reliable_qos, stamp_to_sec
from vessel_common.wire import WireType, decoding_callback, encoded_or_none
from vessel_msgs.msg import VesselTrackArray
from vessel_track.error_model import MEAN_RADIAL_ERROR_PER_SIGMA
from vessel_track.message_checks import (
    TIME_TOLERANCE_S,
    TRACK_ARRAY_TYPE,
    checked_tracks,
    covariance_problem,
    header_refusal,
    order_refusal,
    report,
)
from vessel_track.node_params import main_with_checks
from vessel_track.parameter_tables import GPS_PUBLISHER_PARAMETERS

STATUS_LOST = 3
MAX_TARGET_DISTANCE_M = 1.0e5
"""A target farther than this from the camera is a calibration or fuser fault, never a fix."""


@dataclass
class FixFields:
    """What goes into a NavSatFix for one target (or for none)."""

    status: int
    latitude: float
    longitude: float
    covariance_enu: list[float]   # 9 values, row-major
    problem: str = ""             # why a target was refused as impossible (a diagnostics counter), "" if it was not
    detail: str = ""


def enu_covariance(position_covariance_en, expected_error_m: float, mode: str = "sum",
                   altitude_variance_m2: float = 1.0e4) -> list[float]:
    """3x3 ENU covariance (row-major) from the filter's 2x2 east-north covariance and the expected error.

    ``mode``: ``sum`` (filter + error model), ``filter``, ``error_model`` or ``max`` (the larger of the two,
    per matrix trace). Non-finite inputs are treated as absent; if neither is usable the horizontal variance is
    NaN (callers then report no fix).
    """
    P = np.asarray(position_covariance_en, dtype=float).reshape(2, 2)
    P = P if np.all(np.isfinite(P)) else None
    model = None
    if math.isfinite(expected_error_m) and expected_error_m >= 0:
        sigma = expected_error_m / MEAN_RADIAL_ERROR_PER_SIGMA
        model = np.eye(2) * sigma**2
    if mode == "filter":
        horizontal = P
    elif mode == "error_model":
        horizontal = model
    elif mode == "max":
        candidates = [m for m in (P, model) if m is not None]
        horizontal = max(candidates, key=np.trace) if candidates else None
    else:
        horizontal = P + model if P is not None and model is not None else (P if P is not None else model)
    out = np.full((3, 3), 0.0)
    out[:2, :2] = np.nan if horizontal is None else 0.5 * (horizontal + horizontal.T)
    out[2, 2] = altitude_variance_m2
    return [float(v) for v in out.ravel()]


def fix_fields_of_track(track, stamp: float, max_coast_s: float, mode: str = "sum",
                        altitude_variance_m2: float = 1.0e4, origin: tuple[float, float] | None = None,
                        max_distance_m: float = MAX_TARGET_DISTANCE_M) -> FixFields:
    """NavSatFix content for a target ``track`` (a VesselTrack-like object) at ``stamp``; NO_FIX if unusable.

    An impossible target (latitude or longitude out of range, farther than ``max_distance_m`` from ``origin``,
    the camera, or a covariance that is not finite, symmetric and positive semi-definite) is never published as a
    fix: NO_FIX, with ``problem`` naming the kind.
    """
    no_fix = FixFields(NavSatStatus.STATUS_NO_FIX, math.nan, math.nan, [0.0] * 9)
    if track is None or not track.has_world or track.status == STATUS_LOST:
        return no_fix
    lat, lon = float(track.latitude), float(track.longitude)
    if not (math.isfinite(lat) and math.isfinite(lon)):
        return FixFields(**{**no_fix.__dict__, "problem": "nonfinite_target",
                            "detail": "the target has has_world set but NaN latitude/longitude"})
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        return FixFields(**{**no_fix.__dict__, "problem": "impossible_position",
                            "detail": f"target at latitude {lat:g}, longitude {lon:g}: outside the globe"})
    if origin is not None and geodesy.haversine_m(lat, lon, origin[0], origin[1]) > max_distance_m:
        return FixFields(**{**no_fix.__dict__, "problem": "implausible_target",
                            "detail": f"the target is more than {max_distance_m / 1000:g} km from the camera: is "
                                      "the fuser using the same calibration?"})
    age = stamp - stamp_to_sec(track.last_seen)
    if age > max_coast_s or age < -TIME_TOLERANCE_S:  # not seen for too long, or "seen" after this image
        return no_fix
    problem = "" if all(not math.isfinite(v) for v in track.position_covariance) else covariance_problem(
        track.position_covariance)
    if problem:
        return FixFields(**{**no_fix.__dict__, "problem": "bad_covariance", "detail": problem})
    covariance = enu_covariance(track.position_covariance, track.expected_error_m, mode, altitude_variance_m2)
    if not all(math.isfinite(v) for v in covariance):
        return no_fix
    return FixFields(NavSatStatus.STATUS_FIX, lat, lon, covariance)


class GpsPublisherNode(Node):
    """Publishes the vessel of interest as NavSatFix and every vessel as a track array."""

    def __init__(self):
        super().__init__("gps_publisher")
        # The calibration is read (and so validated) like in every node; its camera position is the origin
        # against which implausible target positions are caught.
        self.camera = declare_camera_model(self)
        values = declare_table(self, GPS_PUBLISHER_PARAMETERS, apply=self._apply_parameters)
        self._apply_parameters(values)
        input_topic, fix_topic, fixes_topic = values["input_topic"], values["fix_topic"], values["fixes_topic"]
        depth = values["qos_depth"]
        self.health = NodeHealth(self)
        self.standby = Standby(self)
        self._origin = ((self.camera.camera_lat, self.camera.camera_lon)
                        if self.camera.camera_lat is not None and self.camera.camera_lon is not None else None)
        self._last_stamp: float | None = None
        self.fix_publisher = self.create_publisher(NavSatFix, fix_topic, reliable_qos(depth))
        self.fixes_publisher = (self.create_publisher(VesselTrackArray, fixes_topic, reliable_qos(depth))
                                if fixes_topic else None)
        self.health.watch_subscribers(self.fix_publisher, self.fixes_publisher)
        self.wire = WireType(TRACK_ARRAY_TYPE)
        self.subscription = self.create_subscription(
            VesselTrackArray, input_topic, decoding_callback(self.wire, self.on_tracks, self.health),
            reliable_qos(depth), raw=True)
        self.get_logger().info(f"gps_publisher: {input_topic} -> {fix_topic} (frame_id {self.frame_id!r}), "
                               f"{fixes_topic or 'no all-vessel output'}")

    def _apply_parameters(self, values) -> None:
        """The output settings, at start and on a live change (the table has checked ranges and choices)."""
        self.frame_id = values["frame_id"]
        self.max_coast_s = values["max_coast_s"]
        self.covariance_mode = values["covariance_mode"]
        self.covariance_type = (NavSatFix.COVARIANCE_TYPE_KNOWN if values["covariance_type"] == "known"
                                else NavSatFix.COVARIANCE_TYPE_APPROXIMATED)
        self.altitude_m = values["altitude_m"]
        self.altitude_variance_m2 = values["altitude_variance_m2"]
        self.publish_no_fix = values["publish_no_fix"]

    def on_tracks(self, msg) -> None:
        """Publish the target's fix and the array of every vessel for one image (``msg``: a ``VesselTrackArray``).

        What ``message_checks`` refuses is left out: nothing is published for a refused message, and a refused
        track is neither the target nor in the array.
        """
        refusal = header_refusal(msg.header.stamp)
        if refusal is not None:
            report(self.health, [refusal])
            return
        stamp = stamp_to_sec(msg.header.stamp)
        previous = self._last_stamp
        refusal = order_refusal(stamp, previous)
        if refusal is not None:
            report(self.health, [refusal])
            return
        if previous is not None and stamp < previous:
            self.health.problem("stamp_backwards", "track stamps went backwards (replay restarted?)")
        self._last_stamp = stamp
        self.health.observe_input(stamp)
        tracks, refusals = checked_tracks(msg.tracks, msg.header.stamp, previous, world=True)
        report(self.health, refusals)
        self.health.count("frames")
        targets = [t for t in tracks if t.is_target]
        target = targets[0] if len(targets) == 1 else None
        if len(targets) > 1:
            # Which one is the vessel is unknown: publishing either could send a collision-avoidance stack
            # after the wrong boat.
            self.health.problem("several_targets", f"{len(targets)} tracks flagged is_target "
                                f"({', '.join(t.id for t in targets)}): NO_FIX for this frame")
        fields = fix_fields_of_track(target, stamp, self.max_coast_s, self.covariance_mode,
                                     self.altitude_variance_m2, self._origin)
        if fields.problem:
            self.health.problem(fields.problem, f"{fields.detail}: NO_FIX published instead")
        publishing = self.standby.publishing()
        if publishing and (fields.status == NavSatStatus.STATUS_FIX or self.publish_no_fix):
            self._publish_fix(msg.header.stamp, fields)
        if publishing and self.fixes_publisher is not None:
            out = self.wire.new(header=msg.header, tracks=[t for t in tracks if t.has_world or t.status == STATUS_LOST])
            cdr = encoded_or_none(self.wire, out, self.health)
            if cdr is not None:
                self.fixes_publisher.publish(cdr)
        if target is not None and fields.status == NavSatStatus.STATUS_FIX:
            self.health.set_value("target", target.id)
            self.health.set_value("target_distance_m", float(target.distance_m))

    def _publish_fix(self, stamp, fields: FixFields) -> None:
        """One NavSatFix on ``fix_topic``: the target's position, or NO_FIX."""
        fix = NavSatFix()
        fix.header.stamp = stamp
        fix.header.frame_id = self.frame_id
        fix.status.status = fields.status
        fix.status.service = 0
        fix.latitude = fields.latitude
        fix.longitude = fields.longitude
        fix.altitude = float(self.altitude_m)
        fix.position_covariance = fields.covariance_enu
        fix.position_covariance_type = (self.covariance_type if fields.status == NavSatStatus.STATUS_FIX
                                        else NavSatFix.COVARIANCE_TYPE_UNKNOWN)
        self.fix_publisher.publish(fix)
        self.health.count("fixes" if fields.status == NavSatStatus.STATUS_FIX else "no_fixes")


def main(args=None) -> None:
    """Console entry point: ``ros2 run vessel_track gps_publisher --ros-args --params-file config/aitas.yaml``."""
    import sys

    sys.exit(main_with_checks(GpsPublisherNode, args))


if __name__ == "__main__":
    main()
