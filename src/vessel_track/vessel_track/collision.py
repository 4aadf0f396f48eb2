"""Collision-avoidance figures of a vessel against the own ship, with their uncertainty, and the alert rule.

Where a vessel is matters less to a watch-keeper than how close it will pass and when. ``collision_figures`` gives,
for one vessel and the own ship (the camera's platform; a fixed camera is an own ship that never moves):

- range and bearing (true, clockwise from north) of the vessel from the own ship;
- CPA, the least distance between the two from now on if both keep their present velocities, and TCPA, the time
  from now to the closest point of their straight lines (negative: that point is past, the two are drawing apart,
  and the CPA is the present range: the distance only grows from here);
- a standard deviation of each, propagated to first order from the covariances of both bodies.

Straight-line motion is the world filter's own model (``vessel_track.smoothing``), so the figures say what that
model predicts, no more. Everything is in metres east/north of one fixed origin and metres per second over ground;
the origin cancels out, only the relative position and velocity count.

``OwnShipTrack`` holds the own ship's recent GPS fixes (already in metres about the origin) and gives its position
and velocity at a frame's stamp. ``AlertRule`` says when a vessel's figures call for an alert. ROS-free (numpy).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from vessel_common.errors import DataError

RELATIVE_SPEED_EPS_MPS = 1e-6
"""Below this relative speed the two bodies are taken as not moving apart or together: TCPA is 0 and CPA the present
range (the closest point is now, and stays so). Above it the formulas hold; TCPA grows as 1/speed, but so far out
that no alert window reaches it."""


def _vector(value, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=float).reshape(-1)
    if array.shape != (2,) or not (math.isfinite(array[0]) and math.isfinite(array[1])):
        raise DataError(f"collision: {name} must be 2 finite numbers (east, north), got {value!r}")
    return array


def _matrix(value, name: str, symmetric: bool = True) -> np.ndarray:
    """A 2x2 matrix, finite; a covariance is made exactly symmetric and must have non-negative variances."""
    array = np.asarray(value, dtype=float)
    if array.size != 4:
        raise DataError(f"collision: {name} must be a finite 2x2 matrix, got {value!r}")
    array = array.reshape(2, 2)
    a, b, c, d = float(array[0, 0]), float(array[0, 1]), float(array[1, 0]), float(array[1, 1])
    if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(c) and math.isfinite(d)):
        raise DataError(f"collision: {name} must be a finite 2x2 matrix, got {value!r}")
    if symmetric:
        if a < 0 or d < 0:
            raise DataError(f"collision: {name} has a negative variance: {array.tolist()}")
        off_diagonal = (b + c) / 2.0
        array = np.array([[a, off_diagonal], [off_diagonal, d]])
    return array


@dataclass(frozen=True)
class Kinematics:
    """One body's position (m), velocity (m/s) and their covariances, east/north.

    ``position_velocity_covariance`` is cov(position, velocity) of this body (row: position component, column:
    velocity component); a Kalman filter knows it, and leaving it out would misstate how sure a TCPA is. Zero by
    default: a fixed camera has zero everything. NaN anywhere is refused (DataError): a figure computed from NaN
    would look like an answer.
    """

    position: np.ndarray
    velocity: np.ndarray
    position_covariance: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    velocity_covariance: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    position_velocity_covariance: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))

    def __post_init__(self) -> None:
        """Validate and store as float arrays."""
        object.__setattr__(self, "position", _vector(self.position, "position"))
        object.__setattr__(self, "velocity", _vector(self.velocity, "velocity"))
        object.__setattr__(self, "position_covariance", _matrix(self.position_covariance, "position_covariance"))
        object.__setattr__(self, "velocity_covariance", _matrix(self.velocity_covariance, "velocity_covariance"))
        object.__setattr__(self, "position_velocity_covariance",
                           _matrix(self.position_velocity_covariance, "position_velocity_covariance", False))

    @property
    def covariance(self) -> np.ndarray:
        """The 4x4 covariance of (east, north, v_east, v_north)."""
        covariance = np.empty((4, 4))
        covariance[:2, :2] = self.position_covariance
        covariance[:2, 2:] = self.position_velocity_covariance
        covariance[2:, :2] = self.position_velocity_covariance.T
        covariance[2:, 2:] = self.velocity_covariance
        return covariance


def at_rest(position=(0.0, 0.0)) -> Kinematics:
    """A body that does not move and whose position is exact: a fixed camera, the own ship of a harbour camera."""
    return Kinematics(np.asarray(position, dtype=float), np.zeros(2))


AT_REST_AT_ORIGIN = at_rest()
"""The fixed camera as an own ship (``Kinematics`` is immutable, so one instance serves every vessel)."""


@dataclass(frozen=True)
class CollisionFigures:
    """Range, bearing, CPA and TCPA of a vessel from the own ship, each with its standard deviation.

    ``bearing_deg`` is true, clockwise from north, in [0, 360). NaN bearing at zero range (no direction). An
    infinite ``tcpa_sigma_s`` means the relative speed is ~0: the time of the closest point is undetermined.
    """

    range_m: float
    range_sigma_m: float
    bearing_deg: float
    bearing_sigma_deg: float
    cpa_m: float
    cpa_sigma_m: float
    tcpa_s: float
    tcpa_sigma_s: float


def _sigma(gradient: np.ndarray, covariance: np.ndarray) -> float:
    return math.sqrt(max(float(gradient @ covariance @ gradient), 0.0))


def range_bearing(relative_position, relative_covariance) -> tuple[float, float, float, float]:
    """(range_m, range_sigma_m, bearing_deg, bearing_sigma_deg) of a position relative to the observer.

    First order: d range = (r / |r|) . d r, d bearing = (r_north, -r_east) / |r|^2 . d r. At zero range there is
    neither a direction nor a derivative: the range's standard deviation is then that of the error along its worst
    axis (the square root of the covariance's largest eigenvalue), and the bearing and its deviation are NaN.
    """
    r = _vector(relative_position, "relative position")
    cov = _matrix(relative_covariance, "relative covariance")
    rng = float(math.hypot(r[0], r[1]))
    if rng == 0.0:
        return 0.0, float(math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0))), math.nan, math.nan
    bearing = math.degrees(math.atan2(r[0], r[1])) % 360.0
    range_sigma = _sigma(r / rng, cov)
    bearing_sigma = math.degrees(_sigma(np.array([r[1], -r[0]]) / rng**2, cov))
    return rng, range_sigma, bearing, bearing_sigma


def relative_covariance(own: Kinematics, vessel: Kinematics, cross_covariance=None) -> np.ndarray:
    """The 4x4 covariance of the relative state (r, w) = vessel's (position, velocity) - own ship's.

    ``cross_covariance``: cov(own state, vessel state), 4x4 (rows: own east, north, v_east, v_north; columns: the
    vessel's). None: the two are estimated independently (a camera's filter and a GPS), so it is zero.
    cov(x_v - x_o) = C_v + C_o - X - X^T.
    """
    total = own.covariance + vessel.covariance
    if cross_covariance is not None:
        cross = np.asarray(cross_covariance, dtype=float)
        if cross.shape != (4, 4) or not np.all(np.isfinite(cross)):
            raise DataError(f"collision: cross_covariance must be a finite 4x4 matrix, got {cross_covariance!r}")
        total = total - cross - cross.T
    return (total + total.T) / 2.0


def cpa_tcpa(r: np.ndarray, w: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray]:
    """CPA, TCPA and their gradients with respect to (r_east, r_north, w_east, w_north).

    r: relative position, w: relative velocity (vessel - own ship). The distance at time t is |r + w t|, least at
    t* = -(r . w) / |w|^2 (TCPA), where it is |m|, m = r + w t* (CPA). When t* < 0 that point is past: the CPA is
    the least distance from now on, the present range |r| (with the range's gradient), and TCPA stays t*, negative,
    so that a consumer sees how long ago the two were closest and that they now draw apart.

    Gradients: dt*/dr = -w / |w|^2, dt*/dw = -(r + 2 t* w) / |w|^2. Since t* minimises the distance, its own change
    does not move the CPA to first order (m . w = 0), so dCPA/dr = m / |m| and dCPA/dw = t* m / |m|. On an exact
    collision course (m = 0) the direction m / |m| is replaced by the unit normal to w: the CPA is then the absolute
    value of a signed miss distance, and its deviation is that distance's.

    When |w| is below ``RELATIVE_SPEED_EPS_MPS`` the bodies keep their distance: TCPA = 0 with gradient 0 (its
    deviation is reported infinite by ``collision_figures``), CPA = the present range with the range's gradient.
    """
    speed2 = float(w @ w)
    rng = float(math.hypot(r[0], r[1]))
    if speed2 < RELATIVE_SPEED_EPS_MPS**2:
        grad_cpa = np.concatenate([r / rng if rng > 0 else np.zeros(2), np.zeros(2)])
        return rng, 0.0, grad_cpa, np.zeros(4)
    tcpa = -float(r @ w) / speed2
    grad_tcpa = np.concatenate([-w / speed2, -(r + 2.0 * tcpa * w) / speed2])
    if tcpa < 0.0:
        return rng, tcpa, np.concatenate([r / rng if rng > 0 else np.zeros(2), np.zeros(2)]), grad_tcpa
    m = r + w * tcpa
    cpa = float(math.hypot(m[0], m[1]))
    direction = m / cpa if cpa > 1e-12 * max(rng, 1.0) else np.array([-w[1], w[0]]) / math.sqrt(speed2)
    return cpa, tcpa, np.concatenate([direction, tcpa * direction]), grad_tcpa


def collision_figures(own: Kinematics, vessel: Kinematics, cross_covariance=None) -> CollisionFigures:
    """Range, bearing, CPA and TCPA of ``vessel`` from ``own`` with first-order standard deviations.

    Both bodies move in straight lines at their present velocities. The deviations come from the covariance of
    the relative state (``relative_covariance``: the eight inputs' covariances, the two bodies independent unless
    ``cross_covariance`` says otherwise) through the analytic gradients of ``cpa_tcpa`` and ``range_bearing``.
    First order is good while the deviations are small against the figures: a CPA near zero, or a relative speed
    near its own uncertainty, makes the true distribution skewed, and the deviation then only says "uncertain".
    """
    r = vessel.position - own.position
    w = vessel.velocity - own.velocity
    cov = relative_covariance(own, vessel, cross_covariance)
    rng, range_sigma, bearing, bearing_sigma = range_bearing(r, cov[:2, :2])
    cpa, tcpa, grad_cpa, grad_tcpa = cpa_tcpa(r, w)
    moving = float(w @ w) >= RELATIVE_SPEED_EPS_MPS**2
    return CollisionFigures(
        range_m=rng, range_sigma_m=range_sigma, bearing_deg=bearing, bearing_sigma_deg=bearing_sigma,
        cpa_m=cpa, cpa_sigma_m=_sigma(grad_cpa, cov) if moving else range_sigma,
        tcpa_s=tcpa, tcpa_sigma_s=_sigma(grad_tcpa, cov) if moving else math.inf)


@dataclass(frozen=True)
class AlertRule:
    """When a vessel's figures call for an alert: it will pass closer than ``cpa_alert_m`` within ``tcpa_alert_s``.

    ``in_alert``: ``cpa_m - cpa_sigma_k * cpa_sigma_m < cpa_alert_m and 0 <= tcpa_s <= tcpa_alert_s``.

    A CPA already past (TCPA < 0) raises no alert: the vessel is drawing away, and its present range is its
    closest. ``cpa_sigma_k`` makes the rule conservative: with k > 0 a vessel whose CPA is uncertain alerts
    earlier (k = 1: when the CPA could be under the limit by one standard deviation). It is 0 by default because
    the CPA's deviation of a vessel seen once or twice is large, and k > 0 would then alert on every new track; a
    user who wants the margin sets it. The TCPA window is not widened by its deviation: it bounds how far ahead
    straight-line motion is believed at all.
    """

    cpa_alert_m: float = 50.0
    tcpa_alert_s: float = 120.0
    cpa_sigma_k: float = 0.0

    def __post_init__(self) -> None:
        """Validate."""
        for name in ("cpa_alert_m", "tcpa_alert_s", "cpa_sigma_k"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value < 0:
                raise DataError(f"collision: {name} must be a finite number >= 0, got {value!r}")

    def in_alert(self, figures: CollisionFigures) -> bool:
        """Whether ``figures`` call for an alert (see the class docstring); False if any figure is NaN."""
        margin = self.cpa_sigma_k * figures.cpa_sigma_m if self.cpa_sigma_k > 0 else 0.0
        return bool(figures.cpa_m - margin < self.cpa_alert_m and 0.0 <= figures.tcpa_s <= self.tcpa_alert_s)


# ------------------------------------------------------------------------------------------------ the own ship

OWN_SHIP_MISSING = "own_ship_missing"
OWN_SHIP_STALE = "own_ship_stale"
OWN_SHIP_FIX_OUT_OF_ORDER = "own_ship_fix_out_of_order"
OWN_SHIP_RESET_S = 1.0
"""A fix this much or more older than the newest one is a replay restarting: the fixes held are dropped."""


@dataclass(frozen=True)
class OwnShipEstimate:
    """The own ship at one stamp: where it is and how it moves, and whether that is known well enough.

    ``kinematics``: east/north of the origin; ``age_s``: how far the nearest fix used is from the stamp;
    ``problem``: '' when usable, ``OWN_SHIP_MISSING`` or ``OWN_SHIP_STALE`` otherwise.

    An estimate with a problem still carries the best position there is (dead reckoning from the last fixes, or the
    origin before any fix): the fuser must place the frame's measurements somewhere, but its CPA figures are not
    given.
    """

    kinematics: Kinematics
    age_s: float
    problem: str = ""

    @property
    def usable(self) -> bool:
        """The own ship is known well enough at this stamp for collision figures."""
        return not self.problem


class OwnShipTrack:
    """The own ship's recent GPS fixes, and its position and velocity at any stamp near them.

    ``add`` keeps at most ``max_fixes`` fixes in stamp order. ``at(stamp)``:

    - position: linear interpolation between the fixes either side of the stamp; past the newest (or before the
      oldest) fix, extrapolation with the velocity. Frames are processed as they come, usually before the next fix,
      so extrapolating a fraction of a second is the normal case, not a fault.
    - velocity: least-squares slope of the fixes over ``velocity_window_s`` ending at the first fix at or after the
      stamp (the newest, past it); zero with its covariance zero when fewer than two fixes (or all at one time).
      NavSatFix carries no velocity, and differencing two noisy fixes would be far noisier than a fit over several.
    - usable only when the nearest fix used is at most ``max_age_s`` from the stamp; else ``OWN_SHIP_STALE``
      (``OWN_SHIP_MISSING`` before any fix).
    """

    def __init__(self, max_age_s: float = 0.5, velocity_window_s: float = 5.0, max_fixes: int = 512):
        if not (math.isfinite(max_age_s) and max_age_s >= 0):
            raise DataError(f"own ship: max_age_s must be a finite number >= 0, got {max_age_s!r}")
        if not (math.isfinite(velocity_window_s) and velocity_window_s > 0):
            raise DataError(f"own ship: velocity_window_s must be a finite number > 0, got {velocity_window_s!r}")
        self.max_age_s = float(max_age_s)
        self.velocity_window_s = float(velocity_window_s)
        self._fixes: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=int(max_fixes))

    def __len__(self) -> int:
        return len(self._fixes)

    def reset(self) -> None:
        """Forget every fix."""
        self._fixes.clear()

    def add(self, stamp: float, position, covariance=None) -> str:
        """Keep one fix (metres east/north of the origin, its 2x2 covariance, None: zero); '' or why it was refused.

        Fixes come in stamp order; one at or before the newest is refused (``OWN_SHIP_FIX_OUT_OF_ORDER``), unless
        it is ``OWN_SHIP_RESET_S`` or more older: a replay restarted, the fixes held are dropped and it is kept.
        A NaN is refused as a DataError: the caller checks its messages before.
        """
        stamp = float(stamp)
        if not math.isfinite(stamp):
            raise DataError(f"own ship: a fix's stamp must be finite seconds, got {stamp}")
        position = _vector(position, "own ship position")
        covariance = np.zeros((2, 2)) if covariance is None else _matrix(covariance, "own ship covariance")
        if self._fixes and stamp <= self._fixes[-1][0]:
            if self._fixes[-1][0] - stamp < OWN_SHIP_RESET_S:
                return OWN_SHIP_FIX_OUT_OF_ORDER
            self._fixes.clear()
        self._fixes.append((stamp, position, covariance))
        return ""

    def at(self, stamp: float) -> OwnShipEstimate:
        """The own ship at ``stamp`` (see the class docstring)."""
        if not self._fixes:
            return OwnShipEstimate(at_rest(), math.inf, OWN_SHIP_MISSING)
        times = np.array([t for t, _, _ in self._fixes])
        after = int(np.searchsorted(times, stamp, side="left"))  # first fix at or after the stamp
        velocity, velocity_cov = self._velocity(times, min(after, len(times) - 1))
        if 0 < after < len(times) or (after < len(times) and times[after] == stamp):
            position, position_cov, age = self._interpolated(stamp, after)
        else:
            t, p, c = self._fixes[-1] if after == len(times) else self._fixes[0]
            dt = stamp - t
            position, position_cov, age = p + velocity * dt, c + velocity_cov * dt * dt, abs(dt)
        kinematics = Kinematics(position, velocity, position_cov, velocity_cov)
        return OwnShipEstimate(kinematics, float(age), "" if age <= self.max_age_s else OWN_SHIP_STALE)

    def _interpolated(self, stamp: float, after: int) -> tuple[np.ndarray, np.ndarray, float]:
        """Position and covariance between fix ``after - 1`` and fix ``after`` (or fix ``after`` itself)."""
        t1, p1, c1 = self._fixes[after]
        if t1 == stamp or after == 0:
            return p1.copy(), c1.copy(), abs(t1 - stamp)
        t0, p0, c0 = self._fixes[after - 1]
        share = (stamp - t0) / (t1 - t0)
        # The covariance blended like the position: as if the two fixes' errors were one error (the GPS error
        # drifts slowly), which does not shrink it between fixes as independent errors would.
        return p0 + share * (p1 - p0), c0 + share * (c1 - c0), min(stamp - t0, t1 - stamp)

    def _velocity(self, times: np.ndarray, last: int) -> tuple[np.ndarray, np.ndarray]:
        """Least-squares velocity over the window ending at fix ``last``, with its covariance.

        With fixes at t_i and the mean t, v = sum (t_i - t)(p_i - p) / sum (t_i - t)^2, cov v = C / sum (t_i - t)^2
        for fixes each of covariance C (their mean here: NavSatFix states it per fix, or not at all).
        """
        chosen = [i for i in range(last + 1) if times[i] >= times[last] - self.velocity_window_s]
        if len(chosen) < 2:
            return np.zeros(2), np.zeros((2, 2))
        t = times[chosen]
        p = np.array([self._fixes[i][1] for i in chosen])
        dt = t - t.mean()
        spread = float(dt @ dt)
        if spread <= 0.0:
            return np.zeros(2), np.zeros((2, 2))
        velocity = dt @ (p - p.mean(axis=0)) / spread
        covariance = np.mean([self._fixes[i][2] for i in chosen], axis=0) / spread
        return velocity, covariance
