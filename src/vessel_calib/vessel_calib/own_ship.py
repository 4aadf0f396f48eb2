"""The own ship's position and attitude: a camera on a ship sees the sea tilt and turn as the ship rolls and yaws.

A homography fitted for a camera at rest holds only at the ship attitude it was fitted at; to read the sea through
it at another instant a consumer needs the ship's heading, pitch and roll at the image's stamp, and the ship's
position to place the camera. This module holds that data without ROS:

- ``ShipAttitude`` and ``OwnShipSample``: one measurement, in the conventions of ``own_ship.csv`` (NED world, body
  x forward, y starboard, z down; heading clockwise from true north, pitch positive bow up, roll positive starboard
  down; R_nb = Rz(heading) Ry(pitch) Rx(roll)). A ship with a compass and no attitude sensor has a heading and no
  pitch or roll (None: not measured, which is not the same as level).
- ``read_own_ship_csv``: the file, every row checked, so a bad row is one line naming the file, row and fix.
- ``OwnShipBuffer``: the recent samples of a running node, looked up at an image's stamp by interpolation, and
  refused with a named reason when the data is missing, old, or has a hole at that instant: a wrong attitude moves
  every position read from the image, so no answer is better than a guess.
- The conversions between these angles and the orientation of a REP-103 / REP-145 ``sensor_msgs/Imu`` (ENU world,
  body x forward, y left, z up): yaw_enu = 90 deg - heading, pitch_flu = -pitch, roll_flu = roll, which is
  R_nb = ENU_FROM_NED . R_enu_flu . diag(1, -1, -1). The checks of a received orientation and position.

Stamps are epoch seconds (floats) throughout, as in the rest of the runtime.
"""

from __future__ import annotations

import bisect
import csv
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_common.errors import DataError

OWN_SHIP_COLUMNS = ("utc_s", "lat", "lon", "heading_deg", "pitch_deg", "roll_deg")
ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""Swaps north/east and flips down to up: a vector's ENU coordinates from its NED ones (its own inverse)."""
FLU_FROM_FRD = np.diag([1.0, -1.0, -1.0])
"""A body vector's forward-left-up coordinates from its forward-right-down ones (its own inverse)."""

NOT_MEASURED = -1.0
"""An ``orientation_covariance`` diagonal entry meaning that angle is not measured (sensor_msgs/Imu)."""
QUATERNION_NORM_TOLERANCE = 1e-3
DEFAULT_MAX_AGE_S = 0.5
"""How far from its nearest sample the buffer answers by default; it interpolates across twice that at most."""

REASONS = {
    "missing": "no sample received yet",
    "stale": "the newest sample is older than max_age_s at this stamp",
    "early": "the stamp is before the oldest sample kept by more than max_age_s",
    "gap": "the samples around this stamp are more than 2 max_age_s apart",
    "bad_stamp": "the stamp is not a finite, positive time",
    "nan_quaternion": "the orientation quaternion is not finite",
    "quaternion_not_unit": "the orientation quaternion's norm is off 1 by more than 1e-3",
    "bad_covariance": "orientation_covariance is not 9 finite numbers with a non-negative (or -1) diagonal",
    "no_orientation": "orientation_covariance says no orientation is measured",
    "no_heading": "orientation_covariance says the heading is not measured (yaw variance -1)",
    "no_fix": "the fix's status is NO_FIX",
    "nan_position": "latitude or longitude is not finite",
    "position_out_of_range": "latitude or longitude is outside the globe",
}
"""Every refusal reason of this module and what it means (count names for a node's health)."""


# ---------------------------------------------------------------------------------------------------------------
# Samples
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ShipAttitude:
    """Heading, pitch and roll in degrees (see the module docstring); pitch and roll None: not measured."""

    heading_deg: float
    pitch_deg: float | None = None
    roll_deg: float | None = None

    def __post_init__(self) -> None:
        if not math.isfinite(self.heading_deg):
            raise DataError(f"ship heading {self.heading_deg!r} is not a finite number of degrees")
        if (self.pitch_deg is None) != (self.roll_deg is None):
            raise DataError("ship attitude with only one of pitch and roll: give both, or neither (compass only)")
        if self.pitch_deg is not None and not (math.isfinite(self.pitch_deg) and math.isfinite(self.roll_deg)):
            raise DataError(f"ship pitch/roll ({self.pitch_deg!r}, {self.roll_deg!r}) are not finite degrees")

    @property
    def has_tilt(self) -> bool:
        """Pitch and roll are measured (not a compass-only ship)."""
        return self.pitch_deg is not None and self.roll_deg is not None


@dataclass(frozen=True)
class OwnShipSample:
    """One row of ``own_ship.csv``: epoch stamp, position (NaN: none) and attitude (None: none)."""

    stamp: float
    lat: float
    lon: float
    attitude: ShipAttitude | None

    @property
    def has_position(self) -> bool:
        """The sample carries a position."""
        return math.isfinite(self.lat) and math.isfinite(self.lon)


def wrap_deg(angle: float) -> float:
    """An angle in degrees brought into [-180, 180)."""
    return (angle + 180.0) % 360.0 - 180.0


def position_problem(lat: float, lon: float) -> str | None:
    """``nan_position`` or ``position_out_of_range`` for an unusable WGS-84 position, else None."""
    if not (math.isfinite(lat) and math.isfinite(lon)):
        return "nan_position"
    if abs(lat) > 90.0 or abs(lon) > 180.0:
        return "position_out_of_range"
    return None


# ---------------------------------------------------------------------------------------------------------------
# own_ship.csv
# ---------------------------------------------------------------------------------------------------------------
class _Row:
    """One data row of own_ship.csv with accessors whose errors name the file, the row and the fix."""

    def __init__(self, path: Path, number: int, cells: dict) -> None:
        self.path, self.number = path, number
        self.cells = {key: (value or "").strip() for key, value in cells.items() if isinstance(key, str)}

    def fail(self, column: str, what: str) -> None:
        raise DataError(f"{self.path}, row {self.number}, column '{column}': {what}, got "
                        f"{self.cells.get(column, '')!r}; correct or delete that row")

    def number_or_none(self, column: str) -> float | None:
        """The cell as a finite number, None when empty."""
        text = self.cells.get(column, "")
        if text == "":
            return None
        try:
            value = float(text)
        except ValueError:
            self.fail(column, "expected a number")
        if not math.isfinite(value):
            self.fail(column, "expected a finite number (leave the cell empty when not measured)")
        return value

    def pair(self, first: str, second: str) -> tuple[float | None, float | None]:
        """Two cells that are both given or both empty."""
        a, b = self.number_or_none(first), self.number_or_none(second)
        if (a is None) != (b is None):
            self.fail(first if a is None else second, f"'{first}' and '{second}' must both be given or both empty")
        return a, b


def _sample_of_row(row: _Row, to_epoch: Callable[[float], float]) -> OwnShipSample:
    utc_s = row.number_or_none("utc_s")
    if utc_s is None:
        row.fail("utc_s", "expected the time, seconds since 00:00 UTC")
    lat, lon = row.pair("lat", "lon")
    if lat is not None and position_problem(lat, lon):
        row.fail("lat" if abs(lat) > 90 else "lon", "not a WGS-84 position in degrees")
    heading = row.number_or_none("heading_deg")
    pitch, roll = row.pair("pitch_deg", "roll_deg")
    if heading is None and pitch is not None:
        row.fail("heading_deg", "pitch and roll need a heading")
    if pitch is not None and abs(pitch) > 90.0:
        row.fail("pitch_deg", "pitch must be within -90..90 degrees")
    if roll is not None and abs(roll) > 180.0:
        row.fail("roll_deg", "roll must be within -180..180 degrees")
    if lat is None and heading is None:
        row.fail("lat", "the row holds neither a position nor a heading")
    attitude = None if heading is None else ShipAttitude(heading % 360.0, pitch, roll)
    return OwnShipSample(float(to_epoch(utc_s)), math.nan if lat is None else lat,
                         math.nan if lon is None else lon, attitude)


def _rows(path: Path) -> list[_Row]:
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            reader = csv.DictReader(handle)
            fields = [(name or "").strip() for name in (reader.fieldnames or [])]
            reader.fieldnames = fields
            rows = [_Row(path, number, cells) for number, cells in enumerate(reader, start=2)]
    except OSError as error:
        raise DataError(f"cannot read {path}: {error.strerror or error}") from None
    except (UnicodeDecodeError, csv.Error) as error:
        raise DataError(f"{path}: not a readable CSV file ({error})") from None
    missing = [column for column in OWN_SHIP_COLUMNS if column not in fields]
    if missing:
        raise DataError(f"{path}: missing column(s) {', '.join(missing)} (found: {', '.join(fields) or 'none'}); "
                        f"the header must be {','.join(OWN_SHIP_COLUMNS)}")
    if not rows:
        raise DataError(f"{path}: no data row under the header; write the samples or remove the file")
    return rows


def read_own_ship_csv(path: str | Path, to_epoch: Callable[[float], float]) -> list[OwnShipSample]:
    """Every sample of an ``own_ship.csv`` (``utc_s,lat,lon,heading_deg,pitch_deg,roll_deg``), in time order.

    ``to_epoch`` turns ``utc_s`` (seconds since 00:00 UTC of the recording day) into epoch seconds. Empty lat/lon:
    no position; empty heading, pitch and roll: no attitude; empty pitch and roll only: a compass-only ship. A row
    that cannot be read, or a time equal to the previous row's (a repeated row), raises ``DataError`` naming the file
    and the row: a silently skipped attitude row would be interpolated over without anyone knowing. The file may
    hold several runs of increasing times that overlap (one window per video, as ``make_motion_set.py`` writes
    them): a time before the previous row's starts a run, the samples are merged in time order, and of rows with
    the same time the first is kept.
    """
    path = Path(path)
    rows = _rows(path)
    samples = [_sample_of_row(row, to_epoch) for row in rows]
    for previous, sample, row in zip(samples, samples[1:], rows[1:], strict=False):
        if sample.stamp == previous.stamp:
            raise DataError(f"{path}, row {row.number}, column 'utc_s': the time {row.cells['utc_s']} repeats the "
                            "previous row's; keep one row per time")
    samples.sort(key=lambda sample: sample.stamp)  # stable: the first of a time leads
    merged = [samples[0]]
    for sample in samples[1:]:
        if sample.stamp > merged[-1].stamp:
            merged.append(sample)
    return merged


def gaps(samples: Sequence[OwnShipSample], max_gap_s: float) -> list[tuple[float, float]]:
    """(start, end) stamps of every step between consecutive samples longer than ``max_gap_s``.

    The buffer refuses lookups inside such a hole; tools count them to say how much of a recording has no attitude.
    """
    return [(a.stamp, b.stamp) for a, b in zip(samples, samples[1:], strict=False) if b.stamp - a.stamp > max_gap_s]


# ---------------------------------------------------------------------------------------------------------------
# Rotations and sensor_msgs/Imu orientation
# ---------------------------------------------------------------------------------------------------------------
def _rz(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _ry(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rx(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def ned_from_body(attitude: ShipAttitude) -> np.ndarray:
    """R_nb = Rz(heading) Ry(pitch) Rx(roll): body (FRD) vectors into NED; a compass-only ship is taken level."""
    pitch, roll = (attitude.pitch_deg, attitude.roll_deg) if attitude.has_tilt else (0.0, 0.0)
    return _rz(math.radians(attitude.heading_deg)) @ _ry(math.radians(pitch)) @ _rx(math.radians(roll))


def quaternion_of_attitude(attitude: ShipAttitude) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the REP-103 orientation (FLU body in ENU) of a ship attitude; compass only: the yaw alone.

    The ZYX (yaw, pitch, roll) angles of that rotation are (90 deg - heading, -pitch, roll).
    """
    pitch, roll = (attitude.pitch_deg, attitude.roll_deg) if attitude.has_tilt else (0.0, 0.0)
    yaw = math.radians(90.0 - attitude.heading_deg)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    cp, sp = math.cos(math.radians(-pitch) / 2), math.sin(math.radians(-pitch) / 2)
    cr, sr = math.cos(math.radians(roll) / 2), math.sin(math.radians(roll) / 2)
    return (sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy)


def attitude_of_quaternion(x: float, y: float, z: float, w: float) -> ShipAttitude:
    """The ship attitude (heading in [0, 360), pitch, roll) of a REP-103 orientation; ``DataError`` if not finite.

    The inverse of ``quaternion_of_attitude`` away from pitch +-90 deg, where heading and roll are not separable.
    """
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if not (math.isfinite(norm) and norm > 0.0):
        raise DataError(f"quaternion ({x}, {y}, {z}, {w}) is not a finite rotation")
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    heading = (90.0 - math.degrees(yaw)) % 360.0
    return ShipAttitude(0.0 if heading == 360.0 else heading, -math.degrees(pitch), math.degrees(roll))


def orientation_covariance(attitude: ShipAttitude, sigma_deg: float | None = None,
                           heading_sigma_deg: float | None = None) -> list[float]:
    """The 9 ``orientation_covariance`` entries (rad^2, row-major) of an attitude measured to ``sigma_deg``.

    Diagonal: roll, pitch, yaw variance. A compass-only ship has -1 for roll and pitch (not measured). An unknown
    sigma (None or NaN) gives zeros, which sensor_msgs/Imu documents as "covariance unknown"; the heading sigma
    defaults to ``sigma_deg``.
    """
    heading_sigma = sigma_deg if heading_sigma_deg is None else heading_sigma_deg
    tilt_known, heading_known = (s is not None and math.isfinite(s) and s > 0.0 for s in (sigma_deg, heading_sigma))
    covariance = [0.0] * 9
    if not attitude.has_tilt:
        covariance[0] = covariance[4] = NOT_MEASURED
        covariance[8] = math.radians(heading_sigma) ** 2 if heading_known else 0.0
    elif tilt_known and heading_known:  # else all zero: a partly zero matrix would claim perfect angles
        covariance[0] = covariance[4] = math.radians(sigma_deg) ** 2
        covariance[8] = math.radians(heading_sigma) ** 2
    return covariance


NO_ORIENTATION_COVARIANCE = [NOT_MEASURED] * 9
"""The ``orientation_covariance`` of an Imu that measures no orientation at all."""


@dataclass(frozen=True)
class AttitudeReading:
    """A received orientation as a ship attitude with its 1-sigma (degrees, NaN: unknown), or why it is refused."""

    attitude: ShipAttitude | None
    sigma_deg: float = math.nan
    reason: str = ""

    @property
    def ok(self) -> bool:
        """The orientation is usable."""
        return not self.reason


def _covariance_problem(covariance: Sequence[float]) -> str | None:
    values = [float(v) for v in covariance]
    if len(values) != 9 or not all(math.isfinite(v) for v in values):
        return "bad_covariance"
    diagonal = (values[0], values[4], values[8])
    if any(v < 0.0 and v != NOT_MEASURED for v in diagonal):
        return "bad_covariance"
    if values[0] == NOT_MEASURED and (values[4] != NOT_MEASURED or values[8] < 0.0):
        return "no_orientation"  # [0] alone is sensor_msgs' "no orientation"; all -1 the same
    if values[0] != NOT_MEASURED and values[4] == NOT_MEASURED:
        return "bad_covariance"  # pitch without roll: no ship attitude sensor reports that
    if values[8] == NOT_MEASURED:
        return "no_heading"
    return None


def attitude_reading(quaternion: Sequence[float], covariance: Sequence[float]) -> AttitudeReading:
    """The ship attitude of an Imu orientation (x, y, z, w) and its covariance, or the reason it is refused.

    Roll and pitch variances of -1 with a heading variance: a compass-only ship (pitch and roll None). The sigma is
    the largest measured angle's (a zero variance counts as unknown: no sensor is perfect).
    """
    if len(quaternion) != 4 or not all(math.isfinite(float(q)) for q in quaternion):
        return AttitudeReading(None, reason="nan_quaternion")
    if abs(math.sqrt(sum(float(q) ** 2 for q in quaternion)) - 1.0) > QUATERNION_NORM_TOLERANCE:
        return AttitudeReading(None, reason="quaternion_not_unit")
    problem = _covariance_problem(covariance)
    if problem:
        return AttitudeReading(None, reason=problem)
    full = attitude_of_quaternion(*(float(q) for q in quaternion))
    compass_only = float(covariance[0]) == NOT_MEASURED
    attitude = ShipAttitude(full.heading_deg) if compass_only else full
    measured = [float(covariance[8])] if compass_only else [float(covariance[i]) for i in (0, 4, 8)]
    variance = max(measured)
    sigma = math.degrees(math.sqrt(variance)) if variance > 0.0 else math.nan
    return AttitudeReading(attitude, sigma)


@dataclass(frozen=True)
class PositionReading:
    """A received position (WGS-84 degrees), or why it is refused."""

    lat: float = math.nan
    lon: float = math.nan
    reason: str = ""

    @property
    def ok(self) -> bool:
        """The position is usable."""
        return not self.reason


def position_reading(status: int, lat: float, lon: float) -> PositionReading:
    """A NavSatFix's position, refused when its status is NO_FIX (below 0) or it is not on the globe."""
    if status < 0:
        return PositionReading(reason="no_fix")
    problem = position_problem(lat, lon)
    return PositionReading(reason=problem) if problem else PositionReading(float(lat), float(lon))


# ---------------------------------------------------------------------------------------------------------------
# Buffer
# ---------------------------------------------------------------------------------------------------------------
def interpolate_attitude(a: ShipAttitude, b: ShipAttitude, fraction: float) -> ShipAttitude:
    """The attitude ``fraction`` of the way from ``a`` to ``b``, the heading the short way round north.

    Pitch and roll only when both ends measure them.
    """
    heading = (a.heading_deg + fraction * wrap_deg(b.heading_deg - a.heading_deg)) % 360.0
    if not (a.has_tilt and b.has_tilt):
        return ShipAttitude(heading)
    return ShipAttitude(heading, a.pitch_deg + fraction * (b.pitch_deg - a.pitch_deg),
                        a.roll_deg + fraction * (b.roll_deg - a.roll_deg))


def _interpolate_position(a: tuple[float, float], b: tuple[float, float], fraction: float) -> tuple[float, float]:
    lon = a[1] + fraction * wrap_deg(b[1] - a[1])
    return a[0] + fraction * (b[0] - a[0]), wrap_deg(lon) if abs(lon) > 180.0 else lon


def _interpolate_reading(a: tuple[ShipAttitude, float], b: tuple[ShipAttitude, float],
                         fraction: float) -> tuple[ShipAttitude, float]:
    sigma = max(a[1], b[1]) if math.isfinite(a[1]) and math.isfinite(b[1]) else math.nan
    return interpolate_attitude(a[0], b[0], fraction), sigma


@dataclass(frozen=True)
class AttitudeLookup:
    """The ship attitude at a stamp: ``ok``, or ``reason`` (see ``REASONS``); age: to the nearest sample used, s."""

    ok: bool
    reason: str
    attitude: ShipAttitude | None
    sigma_deg: float
    age_s: float


@dataclass(frozen=True)
class PositionLookup:
    """The ship position at a stamp: ``ok``, or ``reason`` (see ``REASONS``); age: to the nearest sample used, s."""

    ok: bool
    reason: str
    lat: float
    lon: float
    age_s: float


class _Series:
    """Time-sorted values within ``horizon_s`` of the newest; a step back beyond it starts the series over."""

    def __init__(self, horizon_s: float) -> None:
        self.horizon_s = horizon_s
        self.stamps: list[float] = []
        self.values: list = []
        self.resets = 0

    def add(self, stamp: float, value) -> None:
        if self.stamps and stamp < self.stamps[-1] - self.horizon_s:
            self.stamps, self.values = [], []  # a replay restarted: the kept samples are of another time
            self.resets += 1
        index = bisect.bisect_left(self.stamps, stamp)
        if index < len(self.stamps) and self.stamps[index] == stamp:
            self.values[index] = value  # the same instant again: the later message wins
            return
        self.stamps.insert(index, stamp)
        self.values.insert(index, value)
        old = bisect.bisect_left(self.stamps, self.stamps[-1] - self.horizon_s)
        if old:
            del self.stamps[:old], self.values[:old]

    def lookup(self, stamp: float, max_age_s: float, interpolate: Callable) -> tuple[str, object, float]:
        """(reason or "", value, age): the value at ``stamp`` interpolated or held near the ends."""
        if not (math.isfinite(stamp) and stamp > 0.0):
            return "bad_stamp", None, math.nan
        if not self.stamps:
            return "missing", None, math.inf
        after = bisect.bisect_right(self.stamps, stamp)
        if after == 0:
            age = self.stamps[0] - stamp
            return ("early", None, age) if age > max_age_s else ("", self.values[0], age)
        t0 = self.stamps[after - 1]
        if t0 == stamp:
            return "", self.values[after - 1], 0.0
        if after == len(self.stamps):
            age = stamp - t0
            return ("stale", None, age) if age > max_age_s else ("", self.values[-1], age)
        t1 = self.stamps[after]
        age = min(stamp - t0, t1 - stamp)
        if t1 - t0 > 2.0 * max_age_s:
            return "gap", None, age
        return "", interpolate(self.values[after - 1], self.values[after], (stamp - t0) / (t1 - t0)), age


class OwnShipBuffer:
    """The own ship's recent attitude and position, looked up at a stamp (see the module docstring).

    ``max_age_s``: how far a lookup may be from the nearest sample at either end, and half the largest step it
    interpolates across. ``horizon_s``: samples older than this before the newest are dropped, so the memory is
    bounded however long the node runs; a sample older than that before the newest means time went back (a replay
    restarted) and the buffer starts over (``resets``). Samples arriving out of order are inserted in order.
    """

    def __init__(self, max_age_s: float = DEFAULT_MAX_AGE_S, horizon_s: float = 30.0) -> None:
        if not (math.isfinite(max_age_s) and max_age_s > 0.0):
            raise DataError(f"own-ship max_age_s {max_age_s!r} must be a positive number of seconds")
        if not (math.isfinite(horizon_s) and horizon_s >= 2.0 * max_age_s):
            raise DataError(f"own-ship horizon_s {horizon_s!r} must be a number of seconds of at least 2 max_age_s")
        self.max_age_s, self.horizon_s = float(max_age_s), float(horizon_s)
        self._attitudes = _Series(self.horizon_s)
        self._fixes = _Series(self.horizon_s)

    @staticmethod
    def _check_stamp(stamp: float) -> None:
        if not (math.isfinite(stamp) and stamp > 0.0):
            raise DataError(f"own-ship sample stamp {stamp!r} is not a finite, positive time")

    def add_attitude(self, stamp: float, attitude: ShipAttitude, sigma_deg: float = math.nan) -> None:
        """One attitude measurement (from ``attitude_reading``: check a message before adding it)."""
        self._check_stamp(stamp)
        self._attitudes.add(float(stamp), (attitude, float(sigma_deg)))

    def add_fix(self, stamp: float, lat: float, lon: float) -> None:
        """One position (from ``position_reading``); ``DataError`` for a position not on the globe."""
        self._check_stamp(stamp)
        if position_problem(lat, lon):
            raise DataError(f"own-ship position ({lat!r}, {lon!r}) is not a WGS-84 position in degrees")
        self._fixes.add(float(stamp), (float(lat), float(lon)))

    def attitude_at(self, stamp: float) -> AttitudeLookup:
        """The attitude at ``stamp``, interpolated between the samples around it, or the reason there is none."""
        reason, value, age = self._attitudes.lookup(stamp, self.max_age_s, _interpolate_reading)
        if reason:
            return AttitudeLookup(False, reason, None, math.nan, age)
        return AttitudeLookup(True, "", value[0], value[1], age)

    def position_at(self, stamp: float) -> PositionLookup:
        """The position at ``stamp``, interpolated between the fixes around it, or the reason there is none."""
        reason, value, age = self._fixes.lookup(stamp, self.max_age_s, _interpolate_position)
        if reason:
            return PositionLookup(False, reason, math.nan, math.nan, age)
        return PositionLookup(True, "", value[0], value[1], age)

    @property
    def resets(self) -> int:
        """How often time went back beyond the horizon and the buffer started over."""
        return self._attitudes.resets + self._fixes.resets

    def __len__(self) -> int:
        return len(self._attitudes.stamps) + len(self._fixes.stamps)
