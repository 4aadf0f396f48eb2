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
``/diagnostics``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import NavSatFix, NavSatStatus

from vessel_calib import geodesy
from vessel_calib.node_support import (
    NodeHealth,
    declare_camera_model,
    declare_parameter,
    reliable_qos,
    stamp_to_sec,
)
from vessel_msgs.msg import VesselTrackArray
from vessel_track.error_model import MEAN_RADIAL_ERROR_PER_SIGMA
from vessel_track.node_params import GPS_PUBLISHER_PARAMETERS, main_with_checks

COVARIANCE_MODES = ("sum", "filter", "error_model", "max")
STATUS_LOST = 3


@dataclass
class FixFields:
    """What goes into a NavSatFix for one target (or for none)."""

    status: int
    latitude: float
    longitude: float
    covariance_enu: list[float]   # 9 values, row-major


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
                        altitude_variance_m2: float = 1.0e4) -> FixFields:
    """NavSatFix content for a target ``track`` (a VesselTrack-like object) at ``stamp``; NO_FIX if unusable."""
    no_fix = FixFields(NavSatStatus.STATUS_NO_FIX, math.nan, math.nan, [0.0] * 9)
    if track is None or not track.has_world or track.status == STATUS_LOST:
        return no_fix
    if not (math.isfinite(track.latitude) and math.isfinite(track.longitude)):
        return no_fix
    if stamp - stamp_to_sec(track.last_seen) > max_coast_s:
        return no_fix
    covariance = enu_covariance(track.position_covariance, track.expected_error_m, mode, altitude_variance_m2)
    if not all(math.isfinite(v) for v in covariance):
        return no_fix
    return FixFields(NavSatStatus.STATUS_FIX, float(track.latitude), float(track.longitude), covariance)


class GpsPublisherNode(Node):
    """Publishes the vessel of interest as NavSatFix and every vessel as a track array."""

    def __init__(self):
        super().__init__("gps_publisher")
        # The calibration is read (and so validated) like in every node; its camera position is the origin
        # against which implausible target positions are caught.
        self.camera = declare_camera_model(self)
        spec = GPS_PUBLISHER_PARAMETERS

        def param(name, **kw):
            default, description = spec[name]
            return declare_parameter(self, name, default, description, **kw)

        input_topic = param("input_topic")
        fix_topic = param("fix_topic")
        fixes_topic = param("fixes_topic")
        self.frame_id = param("frame_id")
        self.max_coast_s = param("max_coast_s", float_range=(0.0, 1e6))
        self.covariance_mode = param("covariance_mode", additional_constraints="one of sum, filter, error_model, max")
        covariance_type = param("covariance_type", additional_constraints="known or approximated")
        self.altitude_m = param("altitude_m")
        self.altitude_variance_m2 = param("altitude_variance_m2", float_range=(0.0, 1e12))
        self.publish_no_fix = param("publish_no_fix")
        depth = param("qos_depth", int_range=(1, 1000))
        from vessel_calib.errors import DataError

        if self.covariance_mode not in COVARIANCE_MODES:
            raise DataError(f"gps_publisher: covariance_mode must be one of {', '.join(COVARIANCE_MODES)}, got "
                            f"{self.covariance_mode!r}")
        if covariance_type not in ("known", "approximated"):
            raise DataError(f"gps_publisher: covariance_type must be known or approximated, got {covariance_type!r}")
        self.covariance_type = (NavSatFix.COVARIANCE_TYPE_KNOWN if covariance_type == "known"
                                else NavSatFix.COVARIANCE_TYPE_APPROXIMATED)
        self.health = NodeHealth(self)
        self._last_stamp: float | None = None
        self.fix_publisher = self.create_publisher(NavSatFix, fix_topic, reliable_qos(depth))
        self.fixes_publisher = (self.create_publisher(VesselTrackArray, fixes_topic, reliable_qos(depth))
                                if fixes_topic else None)
        self.health.watch_subscribers(self.fix_publisher, self.fixes_publisher)
        self.subscription = self.create_subscription(VesselTrackArray, input_topic, self.on_tracks,
                                                     reliable_qos(depth))
        self.get_logger().info(f"gps_publisher: {input_topic} -> {fix_topic} (frame_id {self.frame_id!r}), "
                               f"{fixes_topic or 'no all-vessel output'}")

    def on_tracks(self, msg: VesselTrackArray) -> None:
        """Publish the target's fix and the array of every vessel for one image."""
        stamp = stamp_to_sec(msg.header.stamp)
        if self._last_stamp is not None and stamp < self._last_stamp:
            self.health.problem("stamp_backwards", "track stamps went backwards (replay restarted?)")
        self._last_stamp = stamp
        self.health.count("frames")
        targets = [t for t in msg.tracks if t.is_target]
        if len(targets) > 1:
            self.health.problem("several_targets", "more than one track flagged is_target: the first is used")
        target = targets[0] if targets else None
        if target is not None and target.has_world and not (math.isfinite(target.latitude)
                                                             and math.isfinite(target.longitude)):
            self.health.problem("nonfinite_target", "the target has has_world set but NaN latitude/longitude")
        if target is not None and target.has_world and math.isfinite(target.latitude) and \
                math.isfinite(target.longitude) and geodesy.haversine_m(
                    target.latitude, target.longitude, self.camera.camera_lat, self.camera.camera_lon) > 1.0e5:
            self.health.problem("implausible_target", "the target is more than 100 km from the camera: is the "
                                "fuser using the same calibration?")
        fields = fix_fields_of_track(target, stamp, self.max_coast_s, self.covariance_mode,
                                     self.altitude_variance_m2)
        if fields.status == NavSatStatus.STATUS_FIX or self.publish_no_fix:
            fix = NavSatFix()
            fix.header.stamp = msg.header.stamp
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
        if self.fixes_publisher is not None:
            out = VesselTrackArray()
            out.header = msg.header
            out.tracks = [t for t in msg.tracks if t.has_world or t.status == STATUS_LOST]
            self.fixes_publisher.publish(out)
        if target is not None and fields.status == NavSatStatus.STATUS_FIX:
            self.health.set_value("target", target.id)
            self.health.set_value("target_distance_m", float(target.distance_m))


def main(args=None) -> None:
    """Console entry point: ``ros2 run vessel_track gps_publisher --ros-args --params-file config/aitas.yaml``."""
    import sys

    sys.exit(main_with_checks(GpsPublisherNode, args))


if __name__ == "__main__":
    main()
