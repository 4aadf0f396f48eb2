"""Reader for a data folder laid out like ``../shared/aitas`` (AI Tracks at Sea development set).

Layout: ``camera.json`` and ``frames.csv`` are required; ``screen_labels.csv``, ``target_gps_fixes.csv``,
``gt_1hz.csv`` and ``videos.csv`` are optional (missing ones give empty results), and so is ``own_ship.csv``, the
position and attitude of the ship a camera is on (missing: a camera on land, ``None``). Every time is returned as UNIX
epoch seconds: ``frames.csv`` holds ISO UTC, the other files seconds since 00:00 UTC of the recording day,
which is taken from ``frames.csv`` (per video).

A malformed file raises DataError naming the file, the row (1-based, header = row 1) and the column.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_calib.camera_model import PAPER_BOX_ANCHOR, CameraModel, box_points
from vessel_calib.gps_track import GpsTrack, parse_time, seconds_of_day_to_epoch
from vessel_calib.own_ship import OwnShipSample, ShipAttitude, read_own_ship_csv
from vessel_common.errors import CalibrationError, DataError
from vessel_common.paths import parse_videos

DEFAULT_CALIBRATION = "paper_corrected_H00_negative"
TRAIN_VIDEOS = (7, 8, 9, 10, 11, 12)
VALIDATION_VIDEOS = (13, 14, 15, 16, 17)
#: Which labelling passes make the calibration pairs: the primary labels, or also the second pass.
LABEL_PASSES = ("primary", "all")


@dataclass(frozen=True)
class FrameRecord:
    """One frame of ``frames.csv``."""

    video: int
    frame: int
    stamp: float
    path: Path
    has_label: bool = False


@dataclass(frozen=True)
class LabelRecord:
    """One hand-drawn box of the vessel of interest with its GPS position at that instant."""

    video: int
    frame: int
    stamp: float
    x1: float
    y1: float
    x2: float
    y2: float
    lat: float
    lon: float
    gps_ok: bool
    primary: bool = True
    split: str = ""

    @property
    def center(self) -> tuple[float, float]:
        """Box centre (x, y) in pixels."""
        return (0.5 * (self.x1 + self.x2), 0.5 * (self.y1 + self.y2))

    def reference_point(self, anchor: float) -> tuple[float, float]:
        """(x, y): the box's horizontal centre, ``anchor`` of the way down it (0 top, 0.5 centre, 1 bottom)."""
        x, y = box_points([self.x1, self.y1, self.x2, self.y2], anchor)[0]
        return (float(x), float(y))


@dataclass(frozen=True)
class GtRecord:
    """One row of ``gt_1hz.csv``: the vessel's GPS at a whole second inside a video."""

    video: int
    stamp: float
    lat: float
    lon: float
    valid: bool
    in_view: bool
    dist_m: float
    frame: float = math.nan
    x_ref: float = math.nan
    y_ref: float = math.nan


class _Csv:
    """A CSV file read into dict rows with typed accessors that raise DataError naming file, row and column."""

    def __init__(self, path: Path, required: Iterable[str]):
        self.path = path
        try:
            with path.open(newline="", encoding="utf-8-sig") as fh:
                reader = csv.DictReader(fh)
                self.fields = [f.strip() for f in (reader.fieldnames or [])]
                self.rows = [{(k or "").strip(): (v if isinstance(v, str) else "") for k, v in r.items()}
                             for r in reader]
        except OSError as exc:
            raise DataError(f"cannot read {path}: {exc.strerror or exc}") from None
        except (UnicodeDecodeError, csv.Error) as exc:
            raise DataError(f"{path}: not a readable CSV file ({exc})") from None
        missing = [c for c in required if c not in self.fields]
        if missing:
            raise DataError(f"{path}: missing column(s) {', '.join(missing)} (found: {', '.join(self.fields)})")

    def _fail(self, i: int, col: str, value: str, what: str):
        raise DataError(f"{self.path}, row {i + 2}, column '{col}': {what}, got {value!r}")

    def float(self, i: int, col: str, allow_empty: bool = False) -> float:
        value = self.rows[i].get(col, "").strip()
        if value == "" and allow_empty:
            return math.nan
        try:
            number = float(value)
        except ValueError:
            self._fail(i, col, value, "expected a number")
        if not math.isfinite(number) and not allow_empty:
            self._fail(i, col, value, "expected a finite number")
        return number

    def int(self, i: int, col: str) -> int:
        value = self.rows[i].get(col, "").strip()
        try:
            number = float(value)
            if number != int(number):
                raise ValueError
            return int(number)
        except (ValueError, OverflowError):
            self._fail(i, col, value, "expected an integer")

    def flag(self, i: int, col: str, default: bool = False) -> bool:
        value = self.rows[i].get(col, "").strip().lower()
        if value == "" and col not in self.fields:
            return default
        if value in ("1", "true", "yes"):
            return True
        if value in ("0", "false", "no", ""):
            return False
        self._fail(i, col, value, "expected 0 or 1")

    def time(self, i: int, col: str) -> float:
        value = self.rows[i].get(col, "")
        try:
            return parse_time(value)
        except ValueError:
            self._fail(i, col, value, "expected an ISO-8601 UTC time like 2020-09-30T19:33:58.835Z")


class Dataset:
    """A data folder laid out like ``../shared/aitas``; see the module docstring."""

    def __init__(self, path):
        self.path = Path(path).expanduser()
        if not self.path.is_dir():
            raise DataError(f"data folder {self.path} does not exist; pass --data DIR or set VESSEL_DATA")
        cam_path = self.path / "camera.json"
        if not cam_path.is_file():
            raise DataError(f"{cam_path} is missing: a data folder needs camera.json (camera position, image size)")
        try:
            self.camera = json.loads(cam_path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise DataError(f"{cam_path}: not valid JSON ({exc})") from None
        if not isinstance(self.camera, dict):
            raise DataError(f"{cam_path}: expected a JSON object")
        for key in ("camera_lat", "camera_lon"):
            value = self.camera.get(key)
            if not isinstance(value, int | float) or isinstance(value, bool):
                raise DataError(f"{cam_path}: '{key}' must be a number (degrees), got {value!r}")
        if not (self.path / "frames.csv").is_file():
            raise DataError(f"{self.path / 'frames.csv'} is missing: a data folder needs frames.csv")
        self._frames: list[FrameRecord] | None = None
        self._video_ref: dict[int, float] | None = None
        self._own_ship: list[OwnShipSample] | None = None

    def __repr__(self) -> str:
        return f"Dataset({str(self.path)!r})"

    # ----------------------------------------------------------------- camera
    @property
    def camera_lat(self) -> float:
        """Camera latitude from camera.json."""
        return float(self.camera["camera_lat"])

    @property
    def camera_lon(self) -> float:
        """Camera longitude from camera.json."""
        return float(self.camera["camera_lon"])

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) from camera.json (default 1280x720)."""
        return int(self.camera.get("image_width", 1280)), int(self.camera.get("image_height", 720))

    @property
    def center(self) -> tuple[float, float]:
        """Distortion centre from camera.json (default: image centre)."""
        width, height = self.image_size
        c = self.camera.get("distortion_centre") or (width / 2.0, height / 2.0)
        return float(c[0]), float(c[1])

    def camera_model(self, which: str = DEFAULT_CALIBRATION) -> CameraModel:
        """The calibration ``which`` of camera.json (default: the paper's, with the H[0][0] sign corrected)."""
        cals = self.camera.get("calibrations") or {}
        if which not in cals:
            raise DataError(
                f"{self.path / 'camera.json'} has no calibration '{which}' (has: {', '.join(cals) or 'none'})")
        cal = cals[which]
        try:
            return CameraModel(cal["H"], cal["K1"], center=self.center, image_size=self.image_size,
                               camera_lat=self.camera_lat, camera_lon=self.camera_lon)
        except (KeyError, CalibrationError) as exc:
            raise DataError(f"{self.path / 'camera.json'}: calibration '{which}' unusable: {exc}") from None

    def reference_attitude(self) -> ShipAttitude | None:
        """The ship attitude at which the calibration holds (camera.json ``reference_attitude``); None: not given.

        A camera on a ship sees the sea through its calibration only at this attitude; pitch and roll null or
        absent: only the heading is known.
        """
        value = self.camera.get("reference_attitude")
        if value is None:
            return None
        where = f"{self.path / 'camera.json'}: 'reference_attitude'"
        if not isinstance(value, dict):
            raise DataError(f"{where} must be an object {{heading_deg, pitch_deg, roll_deg}}, got {value!r}")
        angles = {}
        for key in ("heading_deg", "pitch_deg", "roll_deg"):
            angle = value.get(key)
            if angle is None and key != "heading_deg":
                angles[key] = None
            elif isinstance(angle, int | float) and not isinstance(angle, bool) and math.isfinite(angle):
                angles[key] = float(angle)
            else:
                raise DataError(f"{where}: '{key}' must be a number of degrees, got {angle!r}")
        try:
            return ShipAttitude(**angles)
        except DataError as error:
            raise DataError(f"{where}: {error}") from None

    # ----------------------------------------------------------------- frames
    def frames(self, videos=None) -> list[FrameRecord]:
        """Frames of the given videos (all by default), sorted by video and frame."""
        if self._frames is None:
            table = _Csv(self.path / "frames.csv", ("video", "frame", "utc"))
            has_file = "file" in table.fields
            out = []
            for i, row in enumerate(table.rows):
                video = table.int(i, "video")
                frame = table.int(i, "frame")
                rel = row["file"].strip() if has_file and row["file"].strip() else f"frames/{video}/{frame:05d}.jpg"
                out.append(FrameRecord(video, frame, table.time(i, "utc"), self.path / rel,
                                       table.flag(i, "has_label")))
            out.sort(key=lambda r: (r.video, r.frame))
            self._frames = out
        wanted = _video_set(videos)
        return [f for f in self._frames if wanted is None or f.video in wanted]

    def videos(self) -> list[int]:
        """Video numbers present in frames.csv."""
        return sorted({f.video for f in self.frames()})

    def default_videos(self) -> list[int]:
        """The validation videos 13-17 this dataset has; all of its videos when it has none of them."""
        available = self.videos()
        return [v for v in VALIDATION_VIDEOS if v in available] or available

    def check_videos(self, videos) -> list[int]:
        """``videos`` (None: all), when every one is in frames.csv; else DataError naming those that are not.

        A mistyped video number would otherwise select no frame and pass as an empty, successful run.
        """
        available = self.videos()
        wanted = available if videos is None else sorted(_video_set(videos))
        unknown = [v for v in wanted if v not in available]
        if unknown:
            raise DataError(
                f"video(s) {', '.join(map(str, unknown))} not in {self.path / 'frames.csv'} "
                f"(it has {', '.join(map(str, available)) or 'none'}); fix --videos"
            )
        return wanted

    def video_splits(self) -> dict[int, str]:
        """Video -> split (train/val/...) from videos.csv; empty if the file is absent."""
        path = self.path / "videos.csv"
        if not path.is_file():
            return {}
        table = _Csv(path, ("video",))
        if "paper_split" not in table.fields:
            return {}
        return {table.int(i, "video"): row["paper_split"].strip() for i, row in enumerate(table.rows)}

    def _reference_epoch(self, video: int) -> float:
        """A time inside ``video`` (its first frame), or of the whole recording; sets the day of seconds-of-day."""
        if self._video_ref is None:
            refs: dict[int, float] = {}
            for f in self.frames():
                refs.setdefault(f.video, f.stamp)
            self._video_ref = refs
        if not self._video_ref:
            raise DataError(f"{self.path / 'frames.csv'} has no rows: cannot tell the recording date")
        return self._video_ref.get(video, next(iter(self._video_ref.values())))

    def _sod_to_epoch(self, sod: float, video: int | None) -> float:
        ref = self._reference_epoch(video) if video is not None else self._reference_epoch(-1)
        return float(seconds_of_day_to_epoch(sod, ref))

    # ----------------------------------------------------------------- labels
    def labels(self, videos=None, primary_only: bool = True) -> list[LabelRecord]:
        """Hand-labelled boxes (``screen_labels.csv``) of the given videos; [] if the file is absent."""
        path = self.path / "screen_labels.csv"
        if not path.is_file():
            return []
        table = _Csv(path, ("video", "frame", "t_utc_s", "x1", "y1", "x2", "y2", "lat", "lon"))
        wanted = _video_set(videos)
        out = []
        for i, row in enumerate(table.rows):
            video = table.int(i, "video")
            if wanted is not None and video not in wanted:
                continue
            primary = table.flag(i, "primary", default=True)
            if primary_only and not primary:
                continue
            x1, y1, x2, y2 = (table.float(i, c) for c in ("x1", "y1", "x2", "y2"))
            if x2 < x1 or y2 < y1:
                raise DataError(f"{path}, row {i + 2}, columns 'x1..y2': box ({x1}, {y1}, {x2}, {y2}) has x2 < x1 "
                                "or y2 < y1")
            lat = table.float(i, "lat", allow_empty=True)
            lon = table.float(i, "lon", allow_empty=True)
            gps_ok = table.flag(i, "gps_ok", default=math.isfinite(lat) and math.isfinite(lon))
            if gps_ok and not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90 and abs(lon) <= 180):
                raise DataError(f"{path}, row {i + 2}, column 'lat'/'lon': gps_ok=1 but no valid position "
                                f"({row.get('lat')!r}, {row.get('lon')!r})")
            stamp = self._sod_to_epoch(table.float(i, "t_utc_s"), video)
            out.append(LabelRecord(video, table.int(i, "frame"), stamp, x1, y1, x2, y2, lat, lon, gps_ok,
                                   primary, row.get("paper_split", "").strip()))
        return out

    def calibration_pairs(self, videos=None, merge_same_frame: bool = True, anchor: float = PAPER_BOX_ANCHOR,
                          label_passes: str = "primary", with_stamps: bool = False):
        """(screen (N,2) box reference points, gps (N,2) lat/lon) of labels with gps_ok=1 in ``videos``.

        The reference point is the box's horizontal centre, ``anchor`` of the way down it (0.5: the centre).
        Some frames carry two primary labels (from two labelling sources), and ``label_passes="all"`` adds the
        second labelling pass of the same frames: with ``merge_same_frame`` the labels of a frame are averaged
        into one pair, so one instant counts once and the fit sees no duplicate GPS point. ``with_stamps`` adds
        a third array, each pair's stamp (Unix seconds).
        """
        if label_passes not in LABEL_PASSES:
            raise DataError(f"label passes must be one of {', '.join(LABEL_PASSES)}, got {label_passes!r}")
        labels = [lab for lab in self.labels(videos, primary_only=label_passes == "primary") if lab.gps_ok]
        groups: dict[tuple[int, int], list[LabelRecord]] = {}
        for lab in labels:
            key = (lab.video, lab.frame) if merge_same_frame else (lab.video, id(lab))
            groups.setdefault(key, []).append(lab)
        screen = np.array([np.mean([lab.reference_point(anchor) for lab in group], axis=0)
                           for group in groups.values()], dtype=float).reshape(-1, 2)
        gps = np.array([(group[0].lat, group[0].lon) for group in groups.values()], dtype=float).reshape(-1, 2)
        if with_stamps:
            return screen, gps, np.array([group[0].stamp for group in groups.values()], dtype=float)
        return screen, gps

    # ----------------------------------------------------------------- GPS
    def gps_track(self) -> GpsTrack:
        """The vessel's raw fixes (``target_gps_fixes.csv``, ``t_spread_s``) as epoch seconds; empty if absent."""
        path = self.path / "target_gps_fixes.csv"
        if not path.is_file():
            return GpsTrack([], [], [])
        table = _Csv(path, ("lat", "lon"))
        time_col = "t_spread_s" if "t_spread_s" in table.fields else "utc_s" if "utc_s" in table.fields else None
        if time_col is None:
            raise DataError(f"{path}: missing column t_spread_s (or utc_s) (found: {', '.join(table.fields)})")
        stamps, lats, lons = [], [], []
        skipped = 0
        for i in range(len(table.rows)):
            lat = table.float(i, "lat", allow_empty=True)
            lon = table.float(i, "lon", allow_empty=True)
            if not (math.isfinite(lat) and math.isfinite(lon)):
                skipped += 1
                continue
            if abs(lat) > 90 or abs(lon) > 180:
                raise DataError(f"{path}, row {i + 2}, column 'lat'/'lon': ({lat}, {lon}) is not a WGS-84 position")
            stamps.append(self._sod_to_epoch(table.float(i, time_col), None))
            lats.append(lat)
            lons.append(lon)
        return GpsTrack(stamps, lats, lons, skipped_rows=skipped)

    def own_ship(self) -> list[OwnShipSample] | None:
        """The own ship's samples (``own_ship.csv``, epoch stamps, cached); None when the folder has none."""
        path = self.path / "own_ship.csv"
        if not path.is_file():
            return None
        if self._own_ship is None:
            self._own_ship = read_own_ship_csv(path, lambda utc_s: self._sod_to_epoch(utc_s, None))
        return self._own_ship

    def gt_1hz(self, videos=None) -> list[GtRecord]:
        """Ground truth at every whole second inside each video (``gt_1hz.csv``); [] if absent."""
        path = self.path / "gt_1hz.csv"
        if not path.is_file():
            return []
        table = _Csv(path, ("video", "t_utc_s", "lat", "lon", "valid"))
        wanted = _video_set(videos)
        out = []
        for i in range(len(table.rows)):
            video = table.int(i, "video")
            if wanted is not None and video not in wanted:
                continue
            out.append(GtRecord(
                video=video,
                stamp=self._sod_to_epoch(table.float(i, "t_utc_s"), video),
                lat=table.float(i, "lat", allow_empty=True),
                lon=table.float(i, "lon", allow_empty=True),
                valid=table.flag(i, "valid"),
                in_view=table.flag(i, "in_view"),
                dist_m=table.float(i, "dist_m", allow_empty=True) if "dist_m" in table.fields else math.nan,
                frame=table.float(i, "frame", allow_empty=True) if "frame" in table.fields else math.nan,
                x_ref=table.float(i, "x_ref", allow_empty=True) if "x_ref" in table.fields else math.nan,
                y_ref=table.float(i, "y_ref", allow_empty=True) if "y_ref" in table.fields else math.nan,
            ))
        return out


def _video_set(videos) -> set[int] | None:
    if videos is None:
        return None
    if isinstance(videos, str):
        return set(parse_videos(videos) or [])
    if isinstance(videos, int):
        return {videos}
    return {int(v) for v in videos}
