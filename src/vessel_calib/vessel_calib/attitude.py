"""The camera's attitude at each image: the own ship's sensors, corrected by the horizon measured in the image.

A low camera cannot live with an attitude sensor alone: a tenth of a degree of pitch moves a position by about a
tenth of its range when the sea at that range is a degree below the horizon, and an IMU's bias is a few tenths.
The horizon (the sea's far edge) is the absolute reference: a line has two degrees of freedom, so with the heading
from a compass (or the calibration) it fixes pitch and roll. The sensor covers what the horizon cannot (an image
where it is hidden); the horizon calibrates the sensor's bias, tracked per axis by a scalar Kalman filter on the
difference sensor - horizon. Each estimate carries a covariance from the line's fit and the sensor's noise, which
the tracker turns into pixels of the positions it makes.

Sources (``AttitudeSettings.source``): ``fixed`` (the calibration's attitude; the horizon is only reported),
``horizon`` (a camera on a pole or a pier that sways: pitch and roll from the horizon, the calibration's heading,
the calibration's attitude when the horizon is not found), ``own_ship`` (the ship's attitude sensor or compass,
corrected by the horizon when ``use_horizon``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vessel_calib.camera_pose import LINE_PROBE_PX, CameraMounting
from vessel_common.errors import VesselError

SOURCES = ("fixed", "horizon", "own_ship")
REJECTIONS_BEFORE_RELEARNING = 5
"""Horizons rejected in a row after which the sensor's bias is taken as unknown again (it may have jumped)."""

SOURCE_NOT_GIVEN, SOURCE_FIXED, SOURCE_OWN_SHIP, SOURCE_HORIZON, SOURCE_FUSED = range(5)
"""The ``vessel_msgs/CameraPose`` source codes (an estimate that is not valid keeps the source it was tried with)."""


@dataclass(frozen=True)
class AttitudeSettings:
    """How the attitude is made; see the module docstring for ``source``.

    ``sensor_sigma_deg``: the attitude sensor's noise on pitch and roll. ``heading_sigma_deg``: the compass's.
    ``bias_drift_deg_per_s``: how fast the sensor's bias may wander (the bias filter's process noise).
    ``gate_sigmas``: a horizon further from the bias-corrected sensor than this many standard deviations of
    their difference is taken for a wrong edge (a shore, a wake) and not used. ``horizon_floor_px``: the least
    standard error granted to a measured line, px (what the edge's own texture allows).
    """

    source: str = "fixed"
    use_horizon: bool = True
    sensor_sigma_deg: float = 0.1
    heading_sigma_deg: float = 0.5
    bias_drift_deg_per_s: float = 0.01
    gate_sigmas: float = 5.0
    horizon_floor_px: float = 0.3

    def validate(self) -> None:
        """VesselError naming the setting that cannot work."""
        if self.source not in SOURCES:
            raise VesselError(f"pose.source must be one of {', '.join(SOURCES)}, got {self.source!r}")
        for name in ("sensor_sigma_deg", "heading_sigma_deg", "bias_drift_deg_per_s", "gate_sigmas",
                     "horizon_floor_px"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise VesselError(f"pose.{name} must be a positive number, got {value!r}")


@dataclass(frozen=True)
class MeasuredLine:
    """The horizon measured in one image: a x + b y + c = 0 in ideal pixels, and its standard errors.

    ``sigma_px``: of its height at the lens centre's column; ``slope_sigma``: of its slope (px per px).
    """

    abc: tuple[float, float, float]
    sigma_px: float
    slope_sigma: float


@dataclass(frozen=True)
class PoseEstimate:
    """The attitude an image was taken at, how it was found, and the homography into the reference image."""

    valid: bool
    source: int
    heading_deg: float = math.nan
    pitch_deg: float = math.nan
    roll_deg: float = math.nan
    covariance_deg2: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    image_to_reference: np.ndarray = field(default_factory=lambda: np.eye(3))
    problem: str = ""
    horizon_used: bool = False

    @property
    def attitude(self) -> tuple[float, float, float]:
        """(heading, pitch, roll) in degrees."""
        return (self.heading_deg, self.pitch_deg, self.roll_deg)


class _BiasFilter:
    """The sensor's pitch and roll bias: a random walk seen through sensor - horizon."""

    def __init__(self, drift_deg_per_s: float):
        self.drift = drift_deg_per_s
        self.bias = np.zeros(2)
        self.variance = np.full(2, 1.0)  # deg^2: a bias of a degree is plausible before any horizon
        self.stamp: float | None = None

    def predict(self, stamp: float) -> None:
        if self.stamp is not None and stamp > self.stamp:
            self.variance = self.variance + self.drift ** 2 * (stamp - self.stamp)
        self.stamp = stamp if self.stamp is None else max(stamp, self.stamp)

    def update(self, difference: np.ndarray, noise_variance: np.ndarray) -> None:
        gain = self.variance / (self.variance + noise_variance)
        self.bias = self.bias + gain * (difference - self.bias)
        self.variance = (1.0 - gain) * self.variance


class AttitudeEstimator:
    """One image's attitude from the own ship's sensors and the horizon measured in it (module docstring).

    ``mounting``: the camera on the ship (``CameraMounting``); ``far_edge_abc``: the sea's far edge in the
    reference image (ideal pixels), the line the measured horizon is compared with.
    """

    def __init__(self, mounting: CameraMounting, far_edge_abc, settings: AttitudeSettings):
        settings.validate()
        self.mounting = mounting
        self.far_edge = np.asarray(far_edge_abc, dtype=float)
        self.settings = settings
        self._bias = _BiasFilter(settings.bias_drift_deg_per_s)
        self.horizons_rejected = 0
        self._rejected_in_a_row = 0

    def expected_line(self, heading_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
        """Where the far edge should be in an image at this attitude (where to search for it)."""
        return self.mounting.line_in_image(self.far_edge, heading_deg, pitch_deg, roll_deg)

    def sensor_prediction(self, heading_deg: float | None, pitch_deg: float | None,
                          roll_deg: float | None) -> tuple[float, float, float]:
        """The attitude the sensors give, bias-corrected, with the reference filling what they do not measure."""
        ref = self.mounting.reference
        heading = ref[0] if heading_deg is None else heading_deg
        if pitch_deg is None or roll_deg is None:
            return (heading, ref[1], ref[2])
        bias = self._bias.bias
        return (heading, pitch_deg - bias[0], roll_deg - bias[1])

    def estimate(self, stamp: float, sensor: tuple[float | None, float | None, float | None] | None,
                 line: MeasuredLine | None) -> PoseEstimate:
        """The attitude of the image stamped ``stamp`` (seconds).

        ``sensor``: (heading, pitch, roll) in degrees interpolated at the stamp, pitch and roll None for a compass
        alone; None when the own ship's sensors give nothing for this image (the caller names why). ``line``: the
        horizon measured in the image, None when not found.
        """
        s = self.settings
        if s.source == "fixed":
            return self._pose(SOURCE_FIXED, self.mounting.reference, np.zeros(2), 0.0)
        if s.source == "horizon":
            heading = self.mounting.reference[0]
            if line is None or not s.use_horizon:
                return self._pose(SOURCE_FIXED, self.mounting.reference, np.zeros(2), 0.0,
                                  problem="horizon not found: the calibration's attitude")
            tilt = self._tilt_of_line(line, heading)
            if tilt is None:
                return self._pose(SOURCE_FIXED, self.mounting.reference, np.zeros(2), 0.0,
                                  problem="no attitude fits the measured horizon: the calibration's attitude")
            return self._pose(SOURCE_HORIZON, (heading, *tilt[:2]), tilt[2], 0.0, horizon_used=True)
        if sensor is None:
            return PoseEstimate(False, SOURCE_OWN_SHIP, problem="no own-ship attitude for this image")
        heading, pitch, roll = sensor
        heading_var = s.heading_sigma_deg ** 2
        if pitch is None or roll is None:
            if line is None or not s.use_horizon:
                return PoseEstimate(False, SOURCE_OWN_SHIP, problem="compass only and the horizon is not found")
            tilt = self._tilt_of_line(line, heading)
            if tilt is None:
                return PoseEstimate(False, SOURCE_OWN_SHIP, problem="compass only and no attitude fits the horizon")
            return self._pose(SOURCE_HORIZON, (heading, *tilt[:2]), tilt[2], heading_var, horizon_used=True)
        return self._fused(stamp, heading, np.array([pitch, roll]), line, heading_var)

    def _fused(self, stamp: float, heading: float, measured: np.ndarray, line: MeasuredLine | None,
               heading_var: float) -> PoseEstimate:
        s = self.settings
        self._bias.predict(stamp)
        sensor_var = s.sensor_sigma_deg ** 2
        corrected = measured - self._bias.bias
        corrected_cov = np.diag(sensor_var + self._bias.variance)
        if line is None or not s.use_horizon:
            return self._pose(SOURCE_OWN_SHIP, (heading, *corrected), corrected_cov, heading_var)
        tilt = self._tilt_of_line(line, heading, start=tuple(corrected))
        if tilt is None:
            return self._pose(SOURCE_OWN_SHIP, (heading, *corrected), corrected_cov, heading_var,
                              problem="no attitude fits the measured horizon")
        p, r, horizon_cov = tilt
        horizon = np.array([p, r])
        difference = measured - horizon
        spread = np.sqrt(np.diag(corrected_cov) + np.diag(horizon_cov))
        if not np.all(np.abs(difference - self._bias.bias) <= s.gate_sigmas * spread):
            self.horizons_rejected += 1
            self._rejected_in_a_row += 1
            if self._rejected_in_a_row >= REJECTIONS_BEFORE_RELEARNING:
                self._bias.variance = np.full(2, 1.0)  # the bias may have jumped: let the horizon teach it again
            return self._pose(SOURCE_OWN_SHIP, (heading, *corrected), corrected_cov, heading_var,
                              problem="horizon rejected: too far from the attitude sensor")
        self._rejected_in_a_row = 0
        self._bias.update(difference, sensor_var + np.diag(horizon_cov))
        # Fused with the sensor as corrected before this horizon taught the bias: the horizon counts once.
        info = np.linalg.inv(corrected_cov) + np.linalg.inv(horizon_cov)
        cov = np.linalg.inv(info)
        fused = cov @ (np.linalg.solve(corrected_cov, corrected) + np.linalg.solve(horizon_cov, horizon))
        return self._pose(SOURCE_FUSED, (heading, *fused), cov, heading_var, horizon_used=True)

    def _tilt_of_line(self, line: MeasuredLine, heading: float,
                      start: tuple[float, float] | None = None) -> tuple[float, float, np.ndarray] | None:
        """Pitch, roll and their 2x2 covariance (deg^2) from a measured line; None when no attitude fits it."""
        if start is None:
            start = tuple(self.mounting.reference[1:])
        solved = self.mounting.tilt_from_line(line.abc, self.far_edge, heading, start)
        if solved is None:
            return None
        pitch, roll, J = solved
        sigma0 = max(line.sigma_px, self.settings.horizon_floor_px)
        lever = LINE_PROBE_PX * line.slope_sigma
        heights_cov = np.array([[sigma0 ** 2 + lever ** 2, sigma0 ** 2 - lever ** 2],
                                [sigma0 ** 2 - lever ** 2, sigma0 ** 2 + lever ** 2]])
        J_inv = np.linalg.inv(J)
        return pitch, roll, J_inv @ heights_cov @ J_inv.T

    def _pose(self, source: int, attitude, tilt_cov, heading_var: float, problem: str = "",
              horizon_used: bool = False) -> PoseEstimate:
        heading, pitch, roll = (float(v) for v in attitude)
        cov = np.zeros((3, 3))
        tilt = np.asarray(tilt_cov, dtype=float)
        if tilt.ndim == 2:
            cov[0, 0], cov[0, 1], cov[1, 0], cov[1, 1] = tilt[1, 1], tilt[1, 0], tilt[0, 1], tilt[0, 0]
        cov[2, 2] = heading_var
        if source == SOURCE_FIXED:
            M = np.eye(3)  # exactly: a fixed camera's boxes go through untouched
        else:
            M = self.mounting.image_to_reference(heading, pitch, roll)
        return PoseEstimate(True, source, heading, pitch, roll, cov, M / M[2, 2], problem, horizon_used)
