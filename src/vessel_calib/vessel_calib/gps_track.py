"""A GPS fix list (time, lat, lon) with linear interpolation that refuses to bridge long gaps.

Used for labelling (GPS of the vessel at a frame's instant), for ground truth and for the calibration pairs.
Loaders read CSV (lat/lon plus a time column) and GPX; rows that are not usable fixes are skipped and counted in
``skipped_rows`` rather than aborting the whole file, because real logger files contain such rows.
"""

from __future__ import annotations

import csv
import math
import xml.etree.ElementTree as ET
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from vessel_common.errors import DataError

_LAT_NAMES = ("lat", "latitude")
_LON_NAMES = ("lon", "lng", "long", "longitude")
#: Seconds since 00:00 UTC of the recording day (need a date to become epoch seconds).
_DAY_SECONDS_NAMES = ("t_spread_s", "t_utc_s", "utc_s")
#: Absolute times: epoch seconds or ISO-8601 strings.
_ABSOLUTE_NAMES = ("stamp", "t", "time", "timestamp", "epoch", "epoch_s", "utc", "datetime")
SECONDS_PER_DAY = 86400.0


def parse_time(value: str) -> float:
    """Epoch seconds from an ISO-8601 UTC string (``2020-09-30T19:33:58.835Z``) or a number of epoch seconds.

    Raises ValueError when it is neither.
    """
    text = value.strip()
    if not text:
        raise ValueError("empty time")
    try:
        number = float(text)
    except ValueError:
        pass
    else:
        if not math.isfinite(number):
            raise ValueError(f"non-finite time {text!r}")
        return number
    iso = text[:-1] + "+00:00" if text.endswith(("Z", "z")) else text
    stamp = datetime.fromisoformat(iso.replace(" ", "T", 1) if "T" not in iso else iso)
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=UTC)
    return stamp.timestamp()


def day_start_epoch(epoch_s: float) -> float:
    """Epoch seconds of 00:00 UTC of the day containing ``epoch_s``."""
    return math.floor(epoch_s / SECONDS_PER_DAY) * SECONDS_PER_DAY


def seconds_of_day_to_epoch(seconds_of_day, reference_epoch):
    """Seconds since 00:00 UTC -> epoch seconds, on the day of ``reference_epoch`` (nearest across midnight)."""
    sod = np.asarray(seconds_of_day, dtype=float)
    ref = np.asarray(reference_epoch, dtype=float)
    day0 = np.floor(ref / SECONDS_PER_DAY) * SECONDS_PER_DAY
    t = day0 + sod
    t = np.where(t - ref > SECONDS_PER_DAY / 2, t - SECONDS_PER_DAY, t)
    t = np.where(ref - t > SECONDS_PER_DAY / 2, t + SECONDS_PER_DAY, t)
    return float(t) if t.ndim == 0 else t


class GpsTrack:
    """Time-sorted GPS fixes with gap-aware linear interpolation.

    Args:
        stamps: fix times, epoch seconds (any order; sorted here).
        lats, lons: WGS-84 degrees.
        skipped_rows: how many input rows the loader dropped (kept for reporting).

    Fixes sharing a timestamp are averaged into one. Non-finite or out-of-range fixes raise DataError here
    (loaders drop them before construction and count them).

    """

    def __init__(self, stamps, lats, lons, skipped_rows: int = 0):
        t = np.asarray(stamps, dtype=float).ravel()
        la = np.asarray(lats, dtype=float).ravel()
        lo = np.asarray(lons, dtype=float).ravel()
        if not (t.shape == la.shape == lo.shape):
            raise DataError(f"GPS track: stamps, lats and lons differ in length ({t.size}, {la.size}, {lo.size})")
        bad = ~(np.isfinite(t) & np.isfinite(la) & np.isfinite(lo)) | (np.abs(la) > 90) | (np.abs(lo) > 180)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise DataError(f"GPS track: fix {i} is not a valid (time, lat, lon): ({t[i]}, {la[i]}, {lo[i]})")
        order = np.argsort(t, kind="stable")
        t, la, lo = t[order], la[order], lo[order]
        if t.size > 1 and np.any(np.diff(t) == 0):
            uniq, inverse, counts = np.unique(t, return_inverse=True, return_counts=True)
            la = np.bincount(inverse, weights=la) / counts
            # Average longitudes as offsets from the first so the antimeridian cannot split a pair.
            lo_off = (lo - lo[0] + 180.0) % 360.0 - 180.0
            lo = (lo[0] + np.bincount(inverse, weights=lo_off) / counts + 180.0) % 360.0 - 180.0
            self.duplicate_stamps = int(t.size - uniq.size)
            t = uniq
        else:
            self.duplicate_stamps = 0
        for arr in (t, la, lo):
            arr.setflags(write=False)
        self._t = t
        self._lat = la
        self._lon = lo
        self.skipped_rows = int(skipped_rows)

    # ----------------------------------------------------------------- access
    @property
    def stamps(self) -> np.ndarray:
        """Fix times, epoch seconds, strictly increasing."""
        return self._t

    @property
    def lats(self) -> np.ndarray:
        """Latitudes, degrees."""
        return self._lat

    @property
    def lons(self) -> np.ndarray:
        """Longitudes, degrees."""
        return self._lon

    def __len__(self) -> int:
        return int(self._t.size)

    def time_span(self) -> tuple[float, float]:
        """(first, last) fix time; (nan, nan) when empty."""
        if not self._t.size:
            return (math.nan, math.nan)
        return float(self._t[0]), float(self._t[-1])

    # ----------------------------------------------------------------- interpolation
    def interpolate(self, t, max_gap_s: float = 3.0):
        """Position at time(s) ``t`` -> (lat, lon, valid).

        Linear between the bracketing fixes; ``valid`` is False (and lat/lon NaN) outside the track or where
        the bracketing fixes are more than ``max_gap_s`` apart. A time equal to a fix is always valid.
        """
        tq = np.asarray(t, dtype=float)
        shape = tq.shape
        tq = tq.ravel()
        lat = np.full(tq.shape, np.nan)
        lon = np.full(tq.shape, np.nan)
        valid = np.zeros(tq.shape, dtype=bool)
        n = self._t.size
        if n:
            idx = np.searchsorted(self._t, tq, side="right")  # first fix strictly after t
            exact = (idx >= 1) & (self._t[np.clip(idx - 1, 0, n - 1)] == tq)
            i0 = np.clip(idx - 1, 0, n - 1)
            i1 = np.clip(idx, 0, n - 1)
            inside = np.isfinite(tq) & (idx >= 1) & (idx <= n - 1)
            gap = self._t[i1] - self._t[i0]
            bridged = inside & (gap <= max_gap_s) & (gap > 0)
            w = np.where(bridged, (tq - self._t[i0]) / np.where(gap > 0, gap, 1.0), 0.0)
            dlon = (self._lon[i1] - self._lon[i0] + 180.0) % 360.0 - 180.0
            lat_i = self._lat[i0] + w * (self._lat[i1] - self._lat[i0])
            lon_i = (self._lon[i0] + w * dlon + 180.0) % 360.0 - 180.0
            valid = bridged | exact
            lat = np.where(exact, self._lat[i0], np.where(bridged, lat_i, np.nan))
            lon = np.where(exact, self._lon[i0], np.where(bridged, lon_i, np.nan))
        if not shape:
            return float(lat[0]), float(lon[0]), bool(valid[0])
        return lat.reshape(shape), lon.reshape(shape), valid.reshape(shape)

    def bracket_gap(self, t):
        """Seconds between the fixes bracketing ``t`` (0 on a fix, inf outside the track)."""
        tq = np.asarray(t, dtype=float)
        n = self._t.size
        if not n:
            return np.full(tq.shape, np.inf)
        idx = np.searchsorted(self._t, tq, side="right")
        i0 = np.clip(idx - 1, 0, n - 1)
        i1 = np.clip(idx, 0, n - 1)
        exact = (idx >= 1) & (self._t[i0] == tq)
        inside = (idx >= 1) & (idx <= n - 1)
        out = np.where(exact, 0.0, np.where(inside, self._t[i1] - self._t[i0], np.inf))
        return float(out) if out.ndim == 0 else out

    # ----------------------------------------------------------------- loaders
    @classmethod
    def from_csv(cls, path, day_start: float | None = None) -> GpsTrack:
        """Load a CSV with latitude/longitude columns and a time column.

        Time columns, first found wins: ``t_spread_s``, ``t_utc_s``, ``utc_s`` (seconds since 00:00 UTC; the
        day comes from ``day_start`` (epoch of that midnight) or, per row, from an ISO ``utc``/``time`` column;
        without either they are kept as seconds of day), else ``stamp``/``t``/``time``/``timestamp``/``epoch``/
        ``utc``/``datetime`` holding epoch seconds or ISO-8601 UTC. Rows with missing or garbage values are
        skipped and counted. Raises DataError if the file or its columns are unusable.
        """
        path = Path(path)
        try:
            with path.open(newline="", encoding="utf-8-sig") as fh:
                reader = csv.DictReader(fh)
                fields = [f.strip() for f in (reader.fieldnames or [])]
                rows = list(reader)
        except OSError as exc:
            raise DataError(f"cannot read GPS file {path}: {exc.strerror or exc}") from None
        except (UnicodeDecodeError, csv.Error) as exc:
            raise DataError(f"{path}: not a readable CSV file ({exc})") from None
        lower = {f.lower(): f for f in fields}
        lat_col = next((lower[n] for n in _LAT_NAMES if n in lower), None)
        lon_col = next((lower[n] for n in _LON_NAMES if n in lower), None)
        sod_col = next((lower[n] for n in _DAY_SECONDS_NAMES if n in lower), None)
        abs_col = next((lower[n] for n in _ABSOLUTE_NAMES if n in lower), None)
        if lat_col is None or lon_col is None:
            raise DataError(f"{path}: needs 'lat' and 'lon' columns (found: {', '.join(fields) or 'none'})")
        if sod_col is None and abs_col is None:
            raise DataError(
                f"{path}: needs a time column: t_spread_s/utc_s (seconds of day) or time/utc/stamp (ISO-8601 or "
                f"epoch seconds); found: {', '.join(fields)}")
        stamps, lats, lons = [], [], []
        skipped = 0
        for row in rows:
            row = {(k or "").strip(): (v or "") for k, v in row.items()}
            try:
                lat = float(row[lat_col])
                lon = float(row[lon_col])
                if not (math.isfinite(lat) and math.isfinite(lon)) or abs(lat) > 90 or abs(lon) > 180:
                    raise ValueError
                if lat == 0.0 and lon == 0.0:
                    raise ValueError  # logger "no fix"
                if sod_col is not None:
                    sod = float(row[sod_col])
                    if not math.isfinite(sod):
                        raise ValueError
                    if day_start is not None:
                        t = float(seconds_of_day_to_epoch(sod, day_start + sod))
                    elif abs_col is not None and row.get(abs_col, "").strip():
                        t = float(seconds_of_day_to_epoch(sod, parse_time(row[abs_col])))
                    else:
                        t = sod
                else:
                    t = parse_time(row[abs_col])
            except (ValueError, KeyError, TypeError, OverflowError):
                skipped += 1
                continue
            stamps.append(t)
            lats.append(lat)
            lons.append(lon)
        return cls(stamps, lats, lons, skipped_rows=skipped)

    @classmethod
    def from_gpx(cls, path) -> GpsTrack:
        """Load track, route and way points of a GPX file (any GPX version); points without time are skipped."""
        path = Path(path)
        try:
            root = ET.parse(path).getroot()
        except OSError as exc:
            raise DataError(f"cannot read GPX file {path}: {exc.strerror or exc}") from None
        except ET.ParseError as exc:
            raise DataError(f"{path}: not valid GPX/XML ({exc})") from None
        stamps, lats, lons = [], [], []
        skipped = 0
        for elem in root.iter():
            if _local(elem.tag) not in ("trkpt", "rtept", "wpt"):
                continue
            try:
                lat = float(elem.attrib["lat"])
                lon = float(elem.attrib["lon"])
                if not (math.isfinite(lat) and math.isfinite(lon)) or abs(lat) > 90 or abs(lon) > 180:
                    raise ValueError
                time_text = next((c.text for c in elem if _local(c.tag) == "time"), None)
                if not time_text:
                    raise ValueError
                t = parse_time(time_text)
            except (ValueError, KeyError, TypeError, OverflowError):
                skipped += 1
                continue
            stamps.append(t)
            lats.append(lat)
            lons.append(lon)
        if not stamps and not skipped:
            raise DataError(f"{path}: no <trkpt>, <rtept> or <wpt> points found; is it a GPX file?")
        return cls(stamps, lats, lons, skipped_rows=skipped)

    @classmethod
    def from_file(cls, path, day_start: float | None = None) -> GpsTrack:
        """Load by extension: ``.gpx`` as GPX, anything else as CSV."""
        if Path(path).suffix.lower() == ".gpx":
            return cls.from_gpx(path)
        return cls.from_csv(path, day_start=day_start)


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]
