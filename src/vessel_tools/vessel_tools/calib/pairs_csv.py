"""The labelled pairs CSV of ``calibrate --pairs-csv``: screen points and the vessel's GPS position at each.

Columns ``x,y,lat,lon`` (or box corners ``x1,y1,x2,y2`` instead of ``x,y``), or ``x,y,t`` with a GPS track (CSV
or GPX fixes) the positions are interpolated from at ``t``. Column names are matched without regard to case, and
a few common spellings are accepted (``screen_x``, ``latitude``, ``timestamp``...).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from vessel_calib.camera_model import PAPER_BOX_ANCHOR, box_points
from vessel_calib.gps_track import GpsTrack, parse_time
from vessel_common.errors import DataError

_X_NAMES = ("x", "xs", "x_s", "screen_x", "u")
_Y_NAMES = ("y", "ys", "y_s", "screen_y", "v")
_LAT_NAMES = ("lat", "latitude")
_LON_NAMES = ("lon", "lng", "long", "longitude")
_T_NAMES = ("t", "time", "stamp", "utc", "t_utc_s", "timestamp")


def read_pairs_csv(path, gps_path=None, max_gap_s: float = 3.0, anchor: float = PAPER_BOX_ANCHOR):
    """Labelled pairs from a CSV -> (screen (N,2), gps (N,2), notes, stamps (N,)).

    Box corners become the box's horizontal centre, ``anchor`` of the way down it; x,y columns are used as given.
    ``stamps`` are the time column's Unix seconds (NaN without one: needed only for ``--water-level``).
    """
    path = Path(path)
    fields, rows = _read_rows(path)
    lower = {f.lower(): f for f in fields}
    xcol, ycol = _column(lower, _X_NAMES), _column(lower, _Y_NAMES)
    box = all(c in lower for c in ("x1", "y1", "x2", "y2"))
    if (xcol is None or ycol is None) and not box:
        raise DataError(f"{path}: missing screen columns x,y (or box x1,y1,x2,y2); found: {', '.join(fields)}")
    latcol, loncol = _column(lower, _LAT_NAMES), _column(lower, _LON_NAMES)
    tcol = _column(lower, _T_NAMES)
    use_time = latcol is None or loncol is None
    if use_time and (tcol is None or gps_path is None):
        raise DataError(
            f"{path}: missing columns lat,lon (or a time column t plus --gps FIXES); found: {', '.join(fields)}")
    track = GpsTrack.from_file(gps_path) if use_time else None
    if track is not None and len(track) < 2:
        raise DataError(f"{gps_path}: fewer than 2 usable GPS fixes ({track.skipped_rows} rows skipped)")

    screen, gps, stamps = [], [], []
    dropped = 0
    for i, row in enumerate(rows):
        if xcol is not None and ycol is not None:
            x, y = _number(path, i, row, xcol), _number(path, i, row, ycol)
        else:
            x, y = box_points([_number(path, i, row, lower[c]) for c in ("x1", "y1", "x2", "y2")], anchor)[0]
        t = math.nan if tcol is None else _time(path, i, row, tcol)
        if use_time:
            lat, lon, ok = track.interpolate(t, max_gap_s=max_gap_s)
            if not ok:
                dropped += 1
                continue
        else:
            lat, lon = _number(path, i, row, latcol), _number(path, i, row, loncol)
        screen.append((x, y))
        gps.append((lat, lon))
        stamps.append(t)
    notes = []
    if dropped:
        notes.append(f"{dropped} pair(s) dropped: no GPS fix within {max_gap_s:g} s of their time")
    if track is not None and track.skipped_rows:
        notes.append(f"{track.skipped_rows} unusable GPS row(s) skipped in {gps_path}")
    return (np.array(screen, dtype=float).reshape(-1, 2), np.array(gps, dtype=float).reshape(-1, 2), notes,
            np.array(stamps, dtype=float))


def _read_rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    """The file's column names and rows, names and values stripped; DataError when it cannot be read."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            fields = [f.strip() for f in (reader.fieldnames or [])]
            rows = [{(k or "").strip(): (v or "").strip() for k, v in r.items()} for r in reader]
    except OSError as exc:
        raise DataError(f"cannot read pairs CSV {path}: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise DataError(f"{path}: not a readable CSV file ({exc})") from None
    return fields, rows


def _column(fields_lower: dict[str, str], names) -> str | None:
    return next((fields_lower[n] for n in names if n in fields_lower), None)


def _number(path: Path, i: int, row: dict[str, str], col: str) -> float:
    """Row ``i``'s finite number in column ``col``; DataError naming the file's row (header is row 1)."""
    text = row.get(col, "")
    try:
        value = float(text)
    except ValueError:
        raise DataError(f"{path}, row {i + 2}, column '{col}': expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise DataError(f"{path}, row {i + 2}, column '{col}': expected a finite number, got {text!r}; fix or "
                        "drop that row")
    return value


def _time(path: Path, i: int, row: dict[str, str], col: str) -> float:
    """Row ``i``'s time in column ``col`` as Unix seconds; DataError naming the file's row."""
    try:
        return parse_time(row.get(col, ""))
    except ValueError:
        raise DataError(f"{path}, row {i + 2}, column '{col}': expected epoch seconds or ISO-8601 time, "
                        f"got {row.get(col)!r}") from None
