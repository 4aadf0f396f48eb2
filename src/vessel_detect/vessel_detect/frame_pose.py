"""Each image's pose, as the detector node finds it: the own ship's attitude at its stamp and the horizon in it.

The node's executor thread hands the ship's attitude samples in (``add_attitude``) while its worker thread asks for
an image's pose (``pose_of``); the buffer is shared under a condition, and an image waits (up to ``wait_s``) for a
sample stamped after it, so its attitude is interpolated rather than held from the sample before. What goes wrong
comes back as a problem kind the node counts on ``/diagnostics``: ``stale_pose`` (no sample near the stamp),
``horizon_not_found``, ``horizon_rejected``. ROS-free; the message side is ``vessel_detect.pose_messages``.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from vessel_calib.attitude import (
    SOURCE_FIXED,
    SOURCE_OWN_SHIP,
    AttitudeEstimator,
    AttitudeSettings,
    MeasuredLine,
    PoseEstimate,
)
from vessel_calib.camera_pose import CameraMounting
from vessel_calib.own_ship import OwnShipBuffer, ShipAttitude
from vessel_common.errors import VesselError
from vessel_detect.horizon import FarEdge, FarEdgeFinder
from vessel_detect.image_view import ImageView

WIDE_SEARCH_PX = 110.0
"""Half-height searched for the horizon when nothing predicts it well (a compass alone, the horizon source)."""
SENSOR_SEARCH_PX = 30.0
STREAM_SILENT_S = 2.0
"""Wall-clock seconds without an attitude sample after which images stop waiting for one (the sensor is gone)."""
"""Half-height searched around the line the bias-corrected attitude sensor predicts."""


@dataclass(frozen=True)
class ImagePose:
    """One image's pose, its view for the detector, the horizon measured in it and what went wrong ('' : nothing)."""

    estimate: PoseEstimate
    view: ImageView | None
    edge: FarEdge | None
    problem_kind: str = ""


class FramePoser:
    """Poses of a camera's images; see the module docstring.

    ``camera``: the calibration's ``CameraModel`` (its reference attitude and far edge); ``settings``: the
    attitude's (``pose.*`` parameters); ``max_age_s``: how far an attitude sample may be from the image's stamp;
    ``wait_s``: how long an image waits for a sample after it.
    """

    def __init__(self, camera, settings: AttitudeSettings, max_age_s: float, wait_s: float,
                 measure_horizon: bool = True):
        self.camera = camera
        self.settings = settings
        self.wait_s = float(wait_s)
        self.max_age_s = float(max_age_s)
        self.finder = FarEdgeFinder() if measure_horizon else None
        self.mounting = self.estimator = None
        if settings.source != "fixed":  # a fixed camera needs no pinhole decomposition of its H
            self.mounting = CameraMounting.from_camera(camera, camera.reference_attitude_deg)
            self.estimator = AttitudeEstimator(self.mounting, camera.far_edge_line(), settings)
        self._buffer = OwnShipBuffer(max_age_s=self.max_age_s, horizon_s=max(30.0, 2.0 * self.max_age_s))
        self._changed = threading.Condition()
        self._newest = -np.inf
        self._arrived = -np.inf
        self._last_image = -np.inf

    def add_attitude(self, stamp: float, attitude: ShipAttitude, sigma_deg: float = float("nan")) -> None:
        """A sample of the ship's attitude (from the executor thread)."""
        with self._changed:
            resets = self._buffer.resets
            self._buffer.add_attitude(stamp, attitude, sigma_deg)
            self._newest = stamp if self._buffer.resets != resets else max(self._newest, stamp)
            self._arrived = time.monotonic()
            self._changed.notify_all()

    def pose_of(self, stamp: float, bgr: np.ndarray) -> ImagePose:
        """The pose of the image stamped ``stamp`` whose pixels are ``bgr`` (from the worker thread)."""
        if self.settings.source == "fixed":
            return self._fixed_pose(bgr)
        if stamp < self._last_image - 1.0:  # a replay restarted: the sensor's bias is learnt again
            self.estimator = AttitudeEstimator(self.mounting, self.camera.far_edge_line(), self.settings)
        self._last_image = stamp
        sensor, problem = self._sensor_at(stamp)
        if self.settings.source == "own_ship" and sensor is None:
            estimate = PoseEstimate(False, SOURCE_OWN_SHIP, problem=problem)
            return ImagePose(estimate, None, None, "stale_pose")
        predicted, search = self._search_for(sensor)
        edge = self._measure(bgr, predicted, search)
        line = None
        if edge is not None and edge.found:
            line = MeasuredLine(edge.abc, edge.sigma_px, edge.slope_sigma)
        rejected_before = self.estimator.horizons_rejected
        estimate = self.estimator.estimate(stamp, sensor, line)
        kind = ""
        if self.estimator.horizons_rejected > rejected_before:
            kind = "horizon_rejected"
        elif self.settings.source != "fixed" and self.settings.use_horizon and line is None:
            kind = "horizon_not_found"
        if not estimate.valid:
            return ImagePose(estimate, None, edge, kind or "no_pose")
        expected = self.estimator.expected_line(*estimate.attitude)
        view = ImageView.of_pose(self.camera, estimate.image_to_reference,
                                 edge.abc if edge is not None and edge.found else None, tuple(expected))
        return ImagePose(estimate, view, edge, kind)

    def _fixed_pose(self, bgr: np.ndarray) -> ImagePose:
        """A fixed camera: the calibration's pose, and the horizon measured where it is asked for (published)."""
        heading = float(self.camera.heading_deg) if self.camera is not None else float("nan")
        estimate = PoseEstimate(True, SOURCE_FIXED, heading, 0.0, 0.0, np.zeros((3, 3)), np.eye(3))
        if self.camera is None:  # no calibration (a camera not calibrated yet): no horizon to draw either
            return ImagePose(estimate, None, None)
        edge = None
        if self.finder is not None:
            try:
                edge = self._measure(bgr, np.asarray(self.camera.far_edge_line()), WIDE_SEARCH_PX)
            except VesselError:  # a calibration with no horizon to search about: nothing to measure
                edge = None
        view = ImageView.of_pose(self.camera, np.eye(3), edge.abc if edge is not None and edge.found else None)
        return ImagePose(estimate, view, edge)

    def _sensor_at(self, stamp: float) -> tuple[tuple | None, str]:
        if self.settings.source != "own_ship":
            return None, ""
        deadline = time.monotonic() + self.wait_s
        with self._changed:
            silent = time.monotonic() - self._arrived  # inf before the first sample: the first images wait
            alive = silent < STREAM_SILENT_S or self._arrived == -np.inf  # a stream gone silent is not waited for
            while alive and self._newest < stamp and time.monotonic() < deadline:
                self._changed.wait(timeout=max(0.0, deadline - time.monotonic()))
            lookup = self._buffer.attitude_at(stamp)
        if not lookup.ok:
            return None, f"own-ship attitude {lookup.reason} at this image's stamp"
        attitude = lookup.attitude
        return (attitude.heading_deg, attitude.pitch_deg, attitude.roll_deg), ""

    def _search_for(self, sensor) -> tuple[np.ndarray, float]:
        """Where to look for the horizon and how far either side of that line."""
        if sensor is None:
            heading, pitch, roll = self.mounting.reference
            return self.estimator.expected_line(heading, pitch, roll), WIDE_SEARCH_PX
        attitude = self.estimator.sensor_prediction(*sensor)
        wide = sensor[1] is None or sensor[2] is None
        return self.estimator.expected_line(*attitude), WIDE_SEARCH_PX if wide else SENSOR_SEARCH_PX

    def _measure(self, bgr: np.ndarray, predicted: np.ndarray, search_px: float) -> FarEdge | None:
        if self.finder is None:
            return None
        height, width = bgr.shape[:2]
        if (width, height) != tuple(self.camera.image_size):
            return None
        return self.finder.find(bgr, self.camera, predicted_abc=tuple(predicted), search_px=search_px)
