"""Constant-velocity Kalman filtering of vessel positions on the sea plane (metres east, north of the camera).

Two uses, one motion model:

- ``WorldKalmanFilter``: the online filter a live node runs per track, time steps from the stamps. Its
  measurement covariance is the fused position's covariance, which is long and thin (range is far less certain
  than bearing), so the filter averages mostly along the line of sight.
- ``rts_smooth`` / ``smooth_with_outlier_masking``: the paper's offline pass for recorded trajectories: a
  Kalman filter forward, Rauch-Tung-Striebel backward, points further than a threshold from the smoothed
  trajectory masked out and the whole pass repeated (the paper: 5 px in screen y, 5 passes; a masked point is
  taken back once the trajectory has moved close to it again).

State order is ``[x, y, vx, vy]``. Process noise is the continuous white-noise-acceleration model with spectral
density ``accel_psd`` (m^2/s^3), so the filter behaves the same at 30 ms and at 4 s between frames.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from vessel_common.errors import DataError

#: Squared Mahalanobis distance beyond which a 2-D measurement is an outlier (chi-square, 2 dof, p = 0.999).
CHI2_2DOF_999 = 13.8155


def cv_transition(dt: float) -> np.ndarray:
    """State transition of the constant-velocity model over ``dt`` seconds."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    return F


def cv_process_noise(dt: float, accel_psd: float) -> np.ndarray:
    """Process noise of the white-noise-acceleration model over ``dt`` seconds (m^2/s^3 spectral density)."""
    dt = abs(dt)
    q_pp = accel_psd * dt**3 / 3.0
    q_pv = accel_psd * dt**2 / 2.0
    q_vv = accel_psd * dt
    return np.array(
        [
            [q_pp, 0.0, q_pv, 0.0],
            [0.0, q_pp, 0.0, q_pv],
            [q_pv, 0.0, q_vv, 0.0],
            [0.0, q_pv, 0.0, q_vv],
        ]
    )


_H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class MotionConfig:
    """Parameters of the constant-velocity model shared by the online filter and the offline smoother.

    accel_psd: process noise spectral density, m^2/s^3 (how hard vessels manoeuvre).
    initial_speed_std: prior standard deviation of each velocity component at a track's start, m/s.
    max_speed: a fitted speed above this is clipped (m/s); a boat on this data reaches ~17 m/s.
    gate_chi2: squared Mahalanobis distance beyond which a measurement is rejected as an outlier.
    max_rejections: consecutive rejections after which the filter restarts from the measurement.
    max_gap_s: a gap between stamps longer than this restarts the filter (a replay restarted, minutes lost).
    manoeuvre_factor: a measurement outside the gate is tried again with the process noise of this step
        multiplied by this factor (a vessel turning or accelerating hard, Bar-Shalom's adjustable process noise);
        only if it is still outside is it an outlier. 1 disables it.
    """

    accel_psd: float = 0.3
    initial_speed_std: float = 6.0
    max_speed: float = 25.0
    gate_chi2: float = CHI2_2DOF_999
    max_rejections: int = 3
    max_gap_s: float = 30.0
    manoeuvre_factor: float = 25.0

    def __post_init__(self) -> None:
        """Reject values the filter cannot run with."""
        for name in ("accel_psd", "initial_speed_std", "max_speed", "gate_chi2", "max_gap_s", "manoeuvre_factor"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise DataError(f"motion model: {name} must be a positive number, got {value!r}")
        if self.manoeuvre_factor < 1:
            raise DataError(f"motion model: manoeuvre_factor must be >= 1, got {self.manoeuvre_factor!r}")
        if self.max_rejections < 1:
            raise DataError(f"motion model: max_rejections must be at least 1, got {self.max_rejections!r}")


def _validate_measurement(z: np.ndarray, R: np.ndarray) -> bool:
    return bool(
        z.shape == (2,) and R.shape == (2, 2) and np.all(np.isfinite(z)) and np.all(np.isfinite(R))
        and R[0, 0] > 0 and R[1, 1] > 0 and np.linalg.det(R) > 0
    )


@dataclass
class FilterOutput:
    """The filter's estimate after one step (copies; safe to keep)."""

    stamp: float
    state: np.ndarray        # (4,) x, y, vx, vy
    covariance: np.ndarray   # (4, 4)
    accepted: bool           # the measurement of this step was used (False: rejected or prediction only)
    restarted: bool          # the filter restarted at this step (first measurement, gap, stamps backwards)
    restart_reason: str = "" # why: "start", "gap", "backwards" or "rejections" (the track stopped fitting)

    @property
    def position(self) -> np.ndarray:
        """Position (2,) in metres."""
        return self.state[:2].copy()

    @property
    def velocity(self) -> np.ndarray:
        """Velocity (2,) in metres per second."""
        return self.state[2:].copy()

    @property
    def position_covariance(self) -> np.ndarray:
        """Position covariance (2, 2), m^2."""
        return self.covariance[:2, :2].copy()

    @property
    def velocity_covariance(self) -> np.ndarray:
        """Velocity covariance (2, 2), (m/s)^2."""
        return self.covariance[2:, 2:].copy()


class WorldKalmanFilter:
    """Online constant-velocity Kalman filter for one vessel on the sea plane.

    ``update(stamp, z, R)`` with ``z`` the fused position (m) and ``R`` its covariance; ``predict(stamp)`` for
    frames without a measurement. Stamps going backwards or a gap longer than ``max_gap_s`` restart the
    filter from the next measurement instead of extrapolating nonsense; ``events`` counts why.
    """

    def __init__(self, config: MotionConfig | None = None):
        self.config = config or MotionConfig()
        self.state: np.ndarray | None = None
        self.covariance: np.ndarray | None = None
        self.stamp: float | None = None
        self.rejections_in_row = 0
        self.events: dict[str, int] = {"restart_backwards": 0, "restart_gap": 0, "rejected": 0,
                                       "restart_rejections": 0, "invalid_measurement": 0, "manoeuvre": 0}

    @property
    def initialised(self) -> bool:
        """True once a measurement has been taken."""
        return self.state is not None

    def reset(self) -> None:
        """Forget the track's state; the next measurement starts it again."""
        self.state = None
        self.covariance = None
        self.stamp = None
        self.rejections_in_row = 0

    def _start(self, stamp: float, z: np.ndarray, R: np.ndarray, reason: str) -> FilterOutput:
        self.state = np.array([z[0], z[1], 0.0, 0.0])
        self.covariance = np.zeros((4, 4))
        self.covariance[:2, :2] = R
        self.covariance[2, 2] = self.covariance[3, 3] = self.config.initial_speed_std**2
        self.stamp = stamp
        self.rejections_in_row = 0
        return self._output(True, reason)

    def _output(self, accepted: bool, restart_reason: str = "") -> FilterOutput:
        return FilterOutput(float(self.stamp), self.state.copy(), self.covariance.copy(), accepted,
                            bool(restart_reason), restart_reason)

    def _time_problem(self, stamp: float) -> str:
        """Why ``stamp`` cannot continue the current track ("" if it can); the filter is reset then."""
        if self.stamp is None:
            return "start"
        dt = stamp - self.stamp
        if dt < 0:
            self.events["restart_backwards"] += 1
            self.reset()
            return "backwards"
        if dt > self.config.max_gap_s:
            self.events["restart_gap"] += 1
            self.reset()
            return "gap"
        return ""

    def _predict_in_place(self, stamp: float, noise_scale: float = 1.0) -> None:
        dt = stamp - self.stamp
        if dt > 0:
            F = cv_transition(dt)
            self.state = F @ self.state
            self.covariance = F @ self.covariance @ F.T + cv_process_noise(dt, self.config.accel_psd * noise_scale)
            self._clip_speed()
        self.stamp = stamp

    def _clip_speed(self) -> None:
        speed = float(np.hypot(self.state[2], self.state[3]))
        if speed > self.config.max_speed:
            self.state[2:] *= self.config.max_speed / speed

    def predict(self, stamp: float) -> FilterOutput | None:
        """Advance to ``stamp`` without a measurement; None when the filter has nothing to predict from."""
        if self._time_problem(stamp):
            return None
        self._predict_in_place(stamp)
        return self._output(False)

    def update(self, stamp: float, z, R) -> FilterOutput | None:
        """Take the measurement ``z`` (2,) with covariance ``R`` (2, 2) made at ``stamp`` (seconds).

        An invalid measurement (NaN, non-positive-definite covariance) is counted and treated as none.
        """
        z = np.asarray(z, dtype=float).reshape(-1)
        R = np.asarray(R, dtype=float)
        if not _validate_measurement(z, R):
            self.events["invalid_measurement"] += 1
            return self.predict(stamp) if self.initialised else None
        problem = self._time_problem(stamp)
        if problem:
            return self._start(stamp, z, R, problem)
        before = (self.state.copy(), self.covariance.copy(), self.stamp)
        self._predict_in_place(stamp)
        innovation = z - _H @ self.state
        S = _H @ self.covariance @ _H.T + R
        d2 = float(innovation @ np.linalg.solve(S, innovation))
        if d2 > self.config.gate_chi2 and self.config.manoeuvre_factor > 1:
            predicted = (self.state, self.covariance, self.stamp)
            self.state, self.covariance, self.stamp = before
            self._predict_in_place(stamp, self.config.manoeuvre_factor)
            innovation = z - _H @ self.state
            S = _H @ self.covariance @ _H.T + R
            d2 = float(innovation @ np.linalg.solve(S, innovation))
            if d2 <= self.config.gate_chi2:
                self.events["manoeuvre"] += 1
            else:
                self.state, self.covariance, self.stamp = predicted
        if d2 > self.config.gate_chi2:
            self.events["rejected"] += 1
            self.rejections_in_row += 1
            if self.rejections_in_row >= self.config.max_rejections:
                self.events["restart_rejections"] += 1
                return self._start(stamp, z, R, "rejections")
            return self._output(False)
        self.rejections_in_row = 0
        K = self.covariance @ _H.T @ np.linalg.inv(S)
        self.state = self.state + K @ innovation
        I_KH = np.eye(4) - K @ _H
        # Joseph form: stays symmetric positive definite over thousands of steps.
        self.covariance = I_KH @ self.covariance @ I_KH.T + K @ R @ K.T
        self._clip_speed()
        return self._output(True)


@dataclass
class SmoothedTrajectory:
    """Result of the offline pass at every input time."""

    stamps: np.ndarray        # (N,)
    states: np.ndarray        # (N, 4) x, y, vx, vy
    covariances: np.ndarray   # (N, 4, 4)
    used: np.ndarray          # (N,) bool: measurement used in the final pass (False: masked or none)
    iterations: int           # passes run
    log_likelihood: float = math.nan   # of the used measurements under the model (innovations), for model choice
    accel_psd: float = math.nan        # process noise the pass ran with

    @property
    def positions(self) -> np.ndarray:
        """Positions (N, 2) in metres."""
        return self.states[:, :2]


def _check_series(stamps: np.ndarray, z: np.ndarray, R: np.ndarray) -> None:
    n = stamps.shape[0]
    if stamps.ndim != 1 or z.shape != (n, 2) or R.shape != (n, 2, 2):
        raise DataError(f"smoother: expected stamps (N,), positions (N, 2), covariances (N, 2, 2); got "
                        f"{stamps.shape}, {z.shape}, {R.shape}")
    if not np.all(np.isfinite(stamps)):
        raise DataError("smoother: stamps must be finite seconds")
    if n > 1 and np.any(np.diff(stamps) < 0):
        raise DataError("smoother: stamps must not decrease; sort the trajectory by time first")


def rts_smooth(stamps, z, R, config: MotionConfig | None = None, mask=None) -> SmoothedTrajectory:
    """Kalman filter forward and Rauch-Tung-Striebel smoother backward over one trajectory.

    ``z`` rows that are NaN (or masked out by ``mask``) are times without a measurement: the smoother
    interpolates there. Raises DataError when no measurement is usable.
    """
    config = config or MotionConfig()
    stamps = np.asarray(stamps, dtype=float)
    z = np.asarray(z, dtype=float)
    R = np.asarray(R, dtype=float)
    _check_series(stamps, z, R)
    n = stamps.shape[0]
    usable = np.array([_validate_measurement(z[i], R[i]) for i in range(n)], dtype=bool)
    if mask is not None:
        usable &= np.asarray(mask, dtype=bool)
    if not usable.any():
        raise DataError("smoother: the trajectory has no usable measurement")
    first = int(np.argmax(usable))
    predicted, filtered, log_likelihood = _forward_pass(stamps, z, R, usable, first, config)
    xs, Ps = _backward_pass(stamps, predicted, filtered, first, config)
    return SmoothedTrajectory(stamps, xs, Ps, usable, 1, log_likelihood, config.accel_psd)


def _forward_pass(stamps: np.ndarray, z: np.ndarray, R: np.ndarray, usable: np.ndarray, first: int,
                  config: MotionConfig) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray], float]:
    """The Kalman filter from the first usable measurement on, and the likelihood of the measurements it used.

    Returns (predicted states, covariances) and (filtered states, covariances) at every time (zeros before
    ``first``), and the log-likelihood of the used measurements' innovations. A measurement outside the gate is
    predicted to with the process noise times ``manoeuvre_factor`` (a vessel turning or accelerating hard).
    """
    n = stamps.shape[0]
    x_pred = np.zeros((n, 4))
    P_pred = np.zeros((n, 4, 4))
    x_filt = np.zeros((n, 4))
    P_filt = np.zeros((n, 4, 4))
    x = np.array([z[first, 0], z[first, 1], 0.0, 0.0])
    P = np.zeros((4, 4))
    P[:2, :2] = R[first]
    P[2, 2] = P[3, 3] = config.initial_speed_std**2
    # Before the first measurement the prior is started at the first measurement's time and run backwards
    # by the smoother; filtering starts at `first`.
    t_prev = stamps[first]
    log_likelihood = 0.0
    for i in range(first, n):
        if i > first:
            dt = stamps[i] - t_prev
            F = cv_transition(dt)
            x_prior = F @ x
            P_prior = F @ P @ F.T + cv_process_noise(dt, config.accel_psd)
            if usable[i] and config.manoeuvre_factor > 1:
                innovation = z[i] - _H @ x_prior
                if innovation @ np.linalg.solve(_H @ P_prior @ _H.T + R[i], innovation) > config.gate_chi2:
                    P_prior = F @ P @ F.T + cv_process_noise(dt, config.accel_psd * config.manoeuvre_factor)
            x, P = x_prior, P_prior
            t_prev = stamps[i]
        x_pred[i], P_pred[i] = x, P
        if usable[i] and i > first:
            S = _H @ P @ _H.T + R[i]
            innovation = z[i] - _H @ x
            log_likelihood -= 0.5 * (float(innovation @ np.linalg.solve(S, innovation))
                                     + math.log(float(np.linalg.det(S))) + 2.0 * math.log(2.0 * math.pi))
            K = P @ _H.T @ np.linalg.inv(S)
            x = x + K @ innovation
            I_KH = np.eye(4) - K @ _H
            P = I_KH @ P @ I_KH.T + K @ R[i] @ K.T
        x_filt[i], P_filt[i] = x, P
    return (x_pred, P_pred), (x_filt, P_filt), log_likelihood


def _backward_pass(stamps: np.ndarray, predicted: tuple[np.ndarray, np.ndarray],
                   filtered: tuple[np.ndarray, np.ndarray], first: int,
                   config: MotionConfig) -> tuple[np.ndarray, np.ndarray]:
    """Rauch-Tung-Striebel from the last time back to ``first``, then extrapolated back to the times before it."""
    x_pred, P_pred = predicted
    x_filt, P_filt = filtered
    n = stamps.shape[0]
    xs = x_filt.copy()
    Ps = P_filt.copy()
    for i in range(n - 2, first - 1, -1):
        F = cv_transition(stamps[i + 1] - stamps[i])
        C = P_filt[i] @ F.T @ np.linalg.inv(P_pred[i + 1])
        xs[i] = x_filt[i] + C @ (xs[i + 1] - x_pred[i + 1])
        Ps[i] = P_filt[i] + C @ (Ps[i + 1] - P_pred[i + 1]) @ C.T
    for i in range(first - 1, -1, -1):  # leading times without measurement: extrapolate backwards
        dt = stamps[i] - stamps[i + 1]
        F = cv_transition(dt)
        xs[i] = F @ xs[i + 1]
        Ps[i] = F @ Ps[i + 1] @ F.T + cv_process_noise(dt, config.accel_psd)
    return xs, Ps


def most_likely_noise(stamps, z, R, config: MotionConfig | None = None,
                      accel_candidates=(0.1, 0.3, 1.0, 3.0, 10.0), r_scale_candidates=(1.0,),
                      mask=None) -> tuple[float, float]:
    """(process noise, measurement-covariance scale) under which a recorded trajectory is most likely.

    Empirical Bayes over a grid, on the trajectory's own measurements (innovation likelihood), no truth
    involved: vessels differ (a ferry on a straight line, a launch doing loops) and so does the measurement
    noise of a given camera and detector from the training average. Falls back to (``config.accel_psd``, 1)
    with fewer than 4 usable measurements.
    """
    config = config or MotionConfig()
    z = np.asarray(z, dtype=float)
    R = np.asarray(R, dtype=float)
    usable = np.all(np.isfinite(z), axis=1) if mask is None else np.asarray(mask, bool) & np.all(np.isfinite(z), 1)
    if usable.sum() < 4:
        return config.accel_psd, 1.0
    scores = {(q, k): rts_smooth(stamps, z, R * k, replace(config, accel_psd=q), mask).log_likelihood
              for q in accel_candidates for k in r_scale_candidates}
    return max(scores, key=lambda key: scores[key])


def smooth_with_outlier_masking(
    stamps,
    z,
    R,
    residual_fn: Callable[[np.ndarray], np.ndarray],
    threshold: float = 5.0,
    iterations: int = 5,
    config: MotionConfig | None = None,
    min_points: int = 2,
) -> SmoothedTrajectory:
    """The paper's offline pass: smooth, mask points further than ``threshold`` from the result, repeat.

    ``residual_fn(positions (N, 2)) -> (N,)`` gives each point's distance from the smoothed position in the
    unit of ``threshold`` (the paper: screen-y pixels between the measured point and the smoothed one). A
    masked point comes back when a later pass moves the trajectory close to it. At least ``min_points`` (the
    closest ones) are always kept. Stops early when the mask no longer changes.
    """
    stamps = np.asarray(stamps, dtype=float)
    z = np.asarray(z, dtype=float)
    R = np.asarray(R, dtype=float)
    _check_series(stamps, z, R)
    valid = np.array([_validate_measurement(z[i], R[i]) for i in range(len(stamps))], dtype=bool)
    mask = valid.copy()
    result = rts_smooth(stamps, z, R, config, mask)
    passes = 1
    while passes < iterations:
        residual = np.abs(np.asarray(residual_fn(result.positions), dtype=float))
        residual = np.where(np.isfinite(residual), residual, np.inf)
        new_mask = valid & (residual <= threshold)
        if new_mask.sum() < min(min_points, valid.sum()):
            keep = np.argsort(np.where(valid, residual, np.inf))[: min(min_points, int(valid.sum()))]
            new_mask = np.zeros_like(valid)
            new_mask[keep] = True
        if np.array_equal(new_mask, mask):
            break
        mask = new_mask
        result = rts_smooth(stamps, z, R, config, mask)
        passes += 1
    result.iterations = passes
    return result
