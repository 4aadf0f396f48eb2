"""The (screen, GPS) pairs ``calibrate`` fits: from a data folder's labels, a pairs CSV, or found without labels.

Without labels (``--from detections``, ``--video``) the vessel is found among the boats a detector finds in each
frame, as the one its GPS track explains (``vessel_tools.calib.gps_association``); the detector runs through
``vessel_tools.detect.frame_boxes``, imported only then (it needs the vessel_detect package).
"""

from __future__ import annotations

import datetime
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vessel_calib.gps_track import GpsTrack, parse_time
from vessel_common.errors import CalibrationError, DataError
from vessel_common.paths import parse_videos
from vessel_tools.calib.calibration import MIN_PAIRS_TO_WRITE
from vessel_tools.calib.gps_association import associate_and_calibrate
from vessel_tools.calib.pairs_csv import read_pairs_csv
from vessel_tools.calibrate_options import (
    DEFAULT_TRAIN_VIDEOS,
    fit_options,
    parse_center,
    parse_size,
    search_options,
)


@dataclass
class FitPairs:
    """The (screen, GPS) pairs a calibration is fitted to, and where they came from."""

    screen: Any
    gps: Any
    stamps: Any
    source: str
    name: str
    image_size: tuple[int, int]
    center: tuple[float, float]
    notes: list[str] = field(default_factory=list)
    videos: list[int] | None = None
    association: Any = None
    picture_frame: Any = None
    anchor_note: str = ""  # how box_anchor was measured, when it is not the boxes' the fit read


def collect_pairs(args, ds, camera_lat: float, camera_lon: float, water_level) -> FitPairs:
    """The pairs from a video file, a pairs CSV or a data folder (its labels, detections or both)."""
    image_size = parse_size(args.image_size, ds.image_size if ds is not None else (1280, 720))
    center = parse_center(args.center, image_size) if args.center or ds is None else ds.center
    if args.video:
        if args.data or args.pairs_csv:
            raise CalibrationError("--video replaces --data and --pairs-csv: give one of them")
        association, picture_frame, image_size = _search_video(args, camera_lat, camera_lon, args.center,
                                                               water_level)
        screen, gps, stamps = association.pairs(args.box_anchor)
        return FitPairs(screen, gps, stamps, f"video {args.video} without labels ({association.associated} frames "
                        "associated)", Path(args.video).stem, image_size, parse_center(args.center, image_size),
                        association=association, picture_frame=picture_frame)
    if args.pairs_csv:
        screen, gps, notes, stamps = read_pairs_csv(args.pairs_csv, args.gps, args.max_gap_s, args.box_anchor)
        return FitPairs(screen, gps, stamps, f"pairs {args.pairs_csv}", Path(args.pairs_csv).stem, image_size,
                        center, notes)
    return _dataset_pairs(args, ds, camera_lat, camera_lon, image_size, center, water_level)


def _dataset_pairs(args, ds, camera_lat, camera_lon, image_size, center, water_level) -> FitPairs:
    """A data folder's pairs: its labels, the associations of the label-free search, or both."""
    spec = args.videos or DEFAULT_TRAIN_VIDEOS
    videos = parse_videos(spec)
    pairs_from = pairs_source(args.pairs_from, ds)
    pairs = FitPairs(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2)), "", ds.path.name, image_size, center,
                     videos=videos)
    if pairs_from in ("labels", "both"):
        pairs.screen, pairs.gps, pairs.stamps = ds.calibration_pairs(videos, anchor=args.box_anchor,
                                                                     label_passes=args.label_passes, with_stamps=True)
        pairs.source = f"{ds.path} videos {spec} ({args.label_passes} labels)"
        if len(pairs.screen) == 0:
            raise DataError(f"{ds.path}: no labelled pairs with gps_ok=1 in videos {spec}"
                            + ("" if pairs_from == "labels" else "; use --from detections"))
    if pairs_from in ("detections", "both"):
        association = _search_dataset(args, ds, videos, camera_lat, camera_lon, image_size, center, water_level)
        pairs.association = association
        found_screen, found_gps, found_stamps, keys = association.pairs(args.box_anchor, with_keys=True)
        if pairs_from == "both":
            labelled = {(lab.video, lab.frame) for lab in ds.labels(videos, args.label_passes == "primary")
                        if lab.gps_ok}
            extra = np.array([key not in labelled for key in keys], dtype=bool)
            pairs.screen = np.vstack([pairs.screen, found_screen[extra]])
            pairs.gps = np.vstack([pairs.gps, found_gps[extra]])
            pairs.stamps = np.concatenate([pairs.stamps, found_stamps[extra]])
            pairs.source += f" and {int(extra.sum())} frames without a label associated from detections"
        else:
            pairs.screen, pairs.gps, pairs.stamps = found_screen, found_gps, found_stamps
            pairs.source = (f"{ds.path} videos {spec} without labels ({association.associated} frames associated "
                            "from detections)")
    return pairs


def pairs_source(requested: str, ds) -> str:
    """Where a data folder's pairs come from: ``--from``, or for ``auto`` its labels if it has any."""
    if requested != "auto":
        return requested
    return "labels" if (ds.path / "screen_labels.csv").is_file() else "detections"


def draw_pairs(args, pairs: FitPairs) -> None:
    """``--pairs N --seed S``: keep a random draw of N pairs (the paper's protocol)."""
    if args.pairs is None:
        return
    if args.pairs < MIN_PAIRS_TO_WRITE:
        raise CalibrationError(f"--pairs must be at least {MIN_PAIRS_TO_WRITE}, got {args.pairs}: 4 pairs fit the "
                               "homography exactly, so no error of the calibration could be measured")
    if args.pairs > len(pairs.screen):
        raise CalibrationError(f"--pairs {args.pairs} but only {len(pairs.screen)} pairs are available")
    idx = np.sort(np.random.default_rng(args.seed).choice(len(pairs.screen), size=args.pairs, replace=False))
    pairs.screen, pairs.gps, pairs.stamps = pairs.screen[idx], pairs.gps[idx], pairs.stamps[idx]
    pairs.source += f", random draw of {args.pairs} (seed {args.seed})"


def pair_levels(args, pairs: FitPairs, water_level):
    """The water level at each pair (None without ``--water-level``); refuses too few pairs to measure a fit."""
    levels = None
    if water_level is not None:
        if not np.all(np.isfinite(pairs.stamps)):
            raise CalibrationError("--water-level needs the time of every pair: give the pairs CSV a time column t "
                                   "(epoch seconds or ISO-8601 UTC)")
        levels = levels_at(water_level, pairs.stamps, "pair(s)")
        pairs.source += f", water level from {args.water_level}"
    if len(pairs.screen) < MIN_PAIRS_TO_WRITE:
        raise CalibrationError(
            f"{len(pairs.screen)} pairs: a homography fitted to 4 pairs passes through them exactly (0 px, 0 m "
            f"whatever the labels), so nothing says how wrong it is; give at least {MIN_PAIRS_TO_WRITE} pairs (more "
            "than 8 for a calibration to rely on)")
    return levels


def _utc(stamp: float) -> str:
    return datetime.datetime.fromtimestamp(stamp, datetime.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def levels_at(water_level, stamps, what: str):
    """The water level at each of ``stamps`` (None without a water-level file).

    CalibrationError naming how many ``what`` fall outside the file.
    """
    if water_level is None:
        return None
    levels = water_level.level_at(np.asarray(stamps, dtype=float))
    if not np.all(np.isfinite(levels)):
        raise CalibrationError(f"{int(np.sum(~np.isfinite(levels)))} {what} fall outside the water-level file "
                               f"{water_level.source} ({_utc(water_level.start_s)} to {_utc(water_level.end_s)}); "
                               "extend the file to cover them")
    return levels


def _search_dataset(args, ds, videos, camera_lat, camera_lon, image_size, center, water_level):
    """The label-free association over a data folder's frames (detector boxes + the vessel's GPS)."""
    frame_boxes = frame_boxes_module()
    frames, without_gps = frame_boxes.dataset_frame_boxes(ds, videos, args.detections, args.detector_params,
                                                          args.max_gap_s, args.save_detections)
    print(f"calibrate: {len(frames)} frames of videos {args.videos or DEFAULT_TRAIN_VIDEOS} with a GPS fix of the "
          f"vessel ({without_gps} without one, left out); searching for the camera", flush=True)
    return associate_and_calibrate(frames, camera_lat, camera_lon, image_size, center, search_options(args),
                                   fit_options(args), levels_at(water_level, [f.stamp for f in frames], "frame(s)"))


def _search_video(args, camera_lat, camera_lon, center_text, water_level):
    """The label-free association over a video file's frames; (association, a saved frame, image size)."""
    if not args.gps or not args.start_utc:
        raise CalibrationError("--video needs --gps TRACK (CSV or GPX of the boat in view) and --start-utc TIME (the "
                               "video's first frame, ISO-8601 UTC or epoch seconds)")
    try:
        start = parse_time(args.start_utc)
    except ValueError:
        raise CalibrationError(f"--start-utc {args.start_utc!r} is not a time: give ISO-8601 UTC "
                               "(2024-05-01T10:00:00Z) or epoch seconds") from None
    if args.every < 1:
        raise CalibrationError(f"--every must be at least 1, got {args.every}")
    if args.detections:
        raise CalibrationError("--detections applies to --data folders; with --video the detector runs on the video's "
                               "frames (--save-detections keeps its boxes)")
    track = GpsTrack.from_file(args.gps)
    if len(track) < 2:
        raise DataError(f"{args.gps}: fewer than 2 usable GPS fixes")
    frame_boxes = frame_boxes_module()
    frames, without_gps, first_image = frame_boxes.video_frame_boxes(
        args.video, start, track, args.every, args.max_gap_s, args.detector_params, args.save_detections)
    image_size = parse_size(args.image_size, (first_image.shape[1], first_image.shape[0]))
    frame_file = _temporary_frame(first_image)
    print(f"calibrate: {len(frames)} frames of {args.video} with a GPS fix ({without_gps} without one, left out); "
          "searching for the camera", flush=True)
    center = parse_center(center_text, image_size)
    association = associate_and_calibrate(frames, camera_lat, camera_lon, image_size, center, search_options(args),
                                          fit_options(args),
                                          levels_at(water_level, [f.stamp for f in frames], "frame(s)"))
    return association, frame_file, image_size


def _temporary_frame(image) -> Path:
    """``image`` saved as a JPEG for the picture, removed when the process ends."""
    import atexit

    import cv2

    fd, name = tempfile.mkstemp(prefix="calibrate_frame_", suffix=".jpg")
    os.close(fd)
    cv2.imwrite(name, image)
    atexit.register(lambda: Path(name).unlink(missing_ok=True))
    return Path(name)


def frame_boxes_module():
    """``vessel_tools.detect.frame_boxes`` (the detector over frames); CalibrationError without vessel_detect."""
    try:
        from vessel_tools.detect import frame_boxes
    except ImportError as exc:
        raise CalibrationError(f"calibrating without labels needs the vessel_detect package (its detector): {exc}; "
                               "build the workspace (./vessel setup)") from None
    return frame_boxes
