"""The water level (tide) against time, for a camera fixed above the sea.

A camera on a pier sits at a height h above the water, and the sea-plane homography is fitted at the water levels
of its calibration pairs. When the tide falls by 10 cm, a camera 2.5 m up is 4 % higher: every range read through
the fixed homography comes out 4 % too near. The AI Tracks at Sea videos were recorded on a falling tide (about
0.34 m per hour at NOAA station 9410166, 50 m from the camera), which is why their later, validation videos read
too near. ``CameraModel.at_water_level`` corrects for it; this module supplies the level at a stamp.

A water-level table is a CSV file of times and levels in metres above any fixed datum (chart datum, MLLW, ...;
the datum cancels: only the change from the calibration's level matters). Lines starting with ``#`` are comments.
The header names a time column, ``utc_s`` (Unix seconds) or ``utc`` / ``Date Time`` (ISO 8601 UTC, as in NOAA
CO-OPS CSV downloads with ``time_zone=gmt``), and a level column, ``level_m`` or NOAA's ``Prediction`` / ``Water
Level`` (download them with ``units=metric``). Rows must go forward in time.
"""
from __future__ import annotations

import csv
import datetime as _dt
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_common.errors import DataError
from vessel_common.paths import in_repo

TIME_COLUMNS_UNIX = ("utc_s", "unix_s")
TIME_COLUMNS_ISO = ("utc", "date time", "time")
LEVEL_COLUMNS = ("level_m", "prediction", "water level", "verified")
#: Levels beyond this many metres from the table's median are refused (a feet/metres mix-up, a sentinel value).
MAX_LEVEL_SPREAD_M = 30.0


def _parse_iso_utc(text: str) -> float:
    value = text.strip().replace(" ", "T", 1)
    if value.endswith("Z"):
        value = value[:-1] + "+00:00"
    stamp = _dt.datetime.fromisoformat(value)
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=_dt.UTC)
    return stamp.timestamp()


@dataclass(frozen=True)
class WaterLevelTable:
    """Water level (m) at times (Unix seconds), linearly interpolated; ``source`` says where it came from."""

    times_s: np.ndarray
    levels_m: np.ndarray
    source: str = ""

    def __post_init__(self) -> None:
        """Validate: at least two rows, finite values, times strictly increasing."""
        times = np.asarray(self.times_s, dtype=float).ravel()
        levels = np.asarray(self.levels_m, dtype=float).ravel()
        where = f" ({self.source})" if self.source else ""
        if times.size != levels.size:
            raise DataError(f"water level table{where}: {times.size} times but {levels.size} levels")
        if times.size < 2:
            raise DataError(f"water level table{where}: needs at least two rows to interpolate, got {times.size}")
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(levels))):
            raise DataError(f"water level table{where}: times and levels must be finite numbers (a NaN or an empty "
                            "cell); remove those rows")
        steps = np.diff(times)
        if np.any(steps <= 0):
            i = int(np.flatnonzero(steps <= 0)[0])
            raise DataError(f"water level table{where}: times must increase; row {i + 2} is not after row {i + 1}; "
                            "sort the file by time and remove duplicate rows")
        spread = np.abs(levels - np.median(levels))
        if np.any(spread > MAX_LEVEL_SPREAD_M):
            raise DataError(f"water level table{where}: a level {float(levels[int(np.argmax(spread))])} m is more "
                            f"than {MAX_LEVEL_SPREAD_M:.0f} m from the others; levels must be metres (units=metric)")
        object.__setattr__(self, "times_s", times)
        object.__setattr__(self, "levels_m", levels)

    @property
    def start_s(self) -> float:
        """First time of the table, Unix seconds."""
        return float(self.times_s[0])

    @property
    def end_s(self) -> float:
        """Last time of the table, Unix seconds."""
        return float(self.times_s[-1])

    def level_at(self, stamp_s, max_hold_s: float = 0.0):
        """Water level (m) at ``stamp_s`` (Unix seconds, scalar or array).

        Outside the table the end value is held for up to ``max_hold_s`` seconds; beyond that the level is NaN
        (unknown), and the caller decides what to do.
        """
        t = np.asarray(stamp_s, dtype=float)
        level = np.interp(t, self.times_s, self.levels_m)
        known = np.isfinite(t) & (t >= self.start_s - max_hold_s) & (t <= self.end_s + max_hold_s)
        out = np.where(known, level, np.nan)
        return float(out) if out.ndim == 0 else out

    @classmethod
    def from_csv(cls, path) -> WaterLevelTable:
        """Read a water-level CSV (module docstring); DataError naming the file, line and column on bad input."""
        path = Path(path).expanduser()
        if not path.is_file():
            raise DataError(f"water level file {path} does not exist; give a CSV of utc_s (or utc) and level_m, e.g. "
                            "a NOAA CO-OPS tide prediction download (units=metric, time_zone=gmt)")
        try:
            text = path.read_text(encoding="utf-8-sig")
        except (OSError, UnicodeDecodeError) as error:
            raise DataError(f"water level file {path} cannot be read as text: {error}") from None
        lines = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
        rows = list(csv.reader(lines))
        if not rows:
            raise DataError(f"water level file {path} has no header row (utc_s or utc, and level_m)")
        header = [name.strip().lower() for name in rows[0]]
        unix_col = next((header.index(n) for n in TIME_COLUMNS_UNIX if n in header), None)
        iso_col = next((header.index(n) for n in TIME_COLUMNS_ISO if n in header), None)
        level_col = next((header.index(n) for n in LEVEL_COLUMNS if n in header), None)
        if (unix_col is None and iso_col is None) or level_col is None:
            times = ", ".join(TIME_COLUMNS_UNIX + TIME_COLUMNS_ISO)
            raise DataError(f"water level file {path}: the header {rows[0]} needs a time column ({times}) and a "
                            f"level column ({', '.join(LEVEL_COLUMNS)})")
        times, levels = [], []
        for number, row in enumerate(rows[1:], start=2):
            try:
                if unix_col is not None:
                    times.append(float(row[unix_col]))
                else:
                    times.append(_parse_iso_utc(row[iso_col]))
            except (IndexError, ValueError):
                column = rows[0][unix_col if unix_col is not None else iso_col]
                raise DataError(f"water level file {path}, data row {number}: {column!r} is not a time "
                                f"({row!r})") from None
            try:
                levels.append(float(row[level_col]))
            except (IndexError, ValueError):
                raise DataError(f"water level file {path}, data row {number}: {rows[0][level_col]!r} is not a "
                                f"number of metres ({row!r})") from None
        try:
            return cls(np.array(times), np.array(levels), source=str(path))
        except DataError as error:
            raise DataError(str(error)) from None


def load_water_level(path) -> WaterLevelTable | None:
    """The table of a ``water_level.file`` parameter; None for an empty path (no correction)."""
    if path is None or not str(path).strip():
        return None

    return WaterLevelTable.from_csv(in_repo(path))

