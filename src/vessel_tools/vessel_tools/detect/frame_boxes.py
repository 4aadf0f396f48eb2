"""Detected boats of each frame with the tracked vessel's GPS at its instant: the label-free calibration's input.

The detector is the generic COCO set-up (``config/detector_coco.yaml``) without anything that needs a
calibration: no appearance cue, no band below a horizon (the whole frame is tiled), no exclusion masks drawn for
one camera. Frames come from a data folder (``frames.csv`` + ``target_gps_fixes.csv``) or from a video file with a
start time and a GPS track (CSV or GPX), so a new camera needs no data folder.
"""

from __future__ import annotations

import csv
import io
import sys
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from vessel_calib.gps_track import GpsTrack
from vessel_calib.params import atomic_write_text
from vessel_common.errors import DataError
from vessel_common.paths import repo_file
from vessel_detect.detections_csv import CSV_COLUMNS, csv_row, read_detections_csv
from vessel_detect.detector import VesselDetector
from vessel_detect.detector_params import build_detector, detector_config, load_params_file, open_model
from vessel_detect.file_sources import VideoSource
from vessel_tools.calib.gps_association import FrameBoxes

#: The generic detector's parameters (its cue and masks are left out).
DEFAULT_DETECTOR_PARAMS = "config/detector_coco.yaml"
#: The graph's parameter file: its detector makes the boxes the fuser reads.
GRAPH_PARAMS = "config/aitas.yaml"


def calibration_free_detector(params_path: str | None, image_wh: tuple[int, int]):
    """The detector of ``params_path`` (default: the COCO preset) made independent of any calibration."""
    path = params_path or repo_file(DEFAULT_DETECTOR_PARAMS)
    if path is None:
        raise DataError(f"{DEFAULT_DETECTOR_PARAMS} not found: give --detector-params FILE")
    values, _ = load_params_file(path)
    values["appearance_model"] = ""
    values["exclusion_polygons"] = [""]
    return VesselDetector(open_model(values), detector_config(values), None, tuple(int(v) for v in image_wh))


def _frame_boxes(video: int, frame: int, stamp: float, gps: tuple[float, float], boxes, scores) -> FrameBoxes:
    return FrameBoxes(video, frame, float(stamp), float(gps[0]), float(gps[1]),
                      np.asarray(boxes, dtype=float).reshape(-1, 4), np.asarray(scores, dtype=float).reshape(-1))


def _gps_at(track: GpsTrack, stamp: float, max_gap_s: float) -> tuple[float, float] | None:
    lat, lon, ok = track.interpolate(stamp, max_gap_s=max_gap_s)
    return (float(lat), float(lon)) if ok else None


def _progress(index: int, total: int | None, started: float) -> None:
    rate = index / max(time.monotonic() - started, 1e-9)
    of = f"/{total}" if total else ""
    print(f"\r  detecting: {index}{of} frames, {rate:.1f} frames/s", end="", file=sys.stderr, flush=True)


def dataset_frame_boxes(dataset, videos, detections: str | None = None, detector_params: str | None = None,
                        max_gap_s: float = 3.0, save_csv: str | None = None) -> tuple[list[FrameBoxes], int]:
    """FrameBoxes of a data folder's frames with a GPS fix; also the number of frames without one.

    ``detections``: a ``detect run`` CSV of the frames; else the calibration-free detector runs on them (its boxes
    saved to ``save_csv`` if given, to re-use with ``--detections``).
    """
    track = dataset.gps_track()
    if len(track) < 2:
        raise DataError(f"{dataset.path}: no GPS track of the vessel (target_gps_fixes.csv with 2 or more fixes)")
    records = dataset.frames(videos)
    if not records:
        raise DataError(f"no frames for videos {videos or 'all'} in {dataset.path / 'frames.csv'}")
    gps = {(r.video, r.frame): _gps_at(track, r.stamp, max_gap_s) for r in records}
    with_gps = [r for r in records if gps[(r.video, r.frame)] is not None]
    if detections:
        table = read_detections_csv(detections, "write one with `--save-detections` or `./vessel detect run`",
                                    confidence="score")
        empty = (np.zeros((0, 4)), np.zeros(0))
        boxes = {(r.video, r.frame): table.get((r.video, r.frame), empty) for r in with_gps}
    else:
        boxes = _detect_records(with_gps, detector_params, dataset.image_size, save_csv)
    frames = [_frame_boxes(r.video, r.frame, r.stamp, gps[(r.video, r.frame)], *boxes[(r.video, r.frame)])
              for r in with_gps]
    return frames, len(records) - len(with_gps)


def _detect_records(records, detector_params, image_wh, save_csv) -> dict[tuple[int, int], tuple]:
    """(video, frame) -> (boxes (k, 4), scores (k,)) of the calibration-free detector."""
    detector = calibration_free_detector(detector_params, image_wh)
    out, unreadable = _detect_each(detector, records, lambda found: found.scores)
    for path in unreadable:
        print(f"warning: cannot read frame {path}; skipped", file=sys.stderr)
    if save_csv:
        _save_detections(save_csv, ((v, f, *found) for (v, f), found in out.items()))
    return out


def _detect_each(detector, records, confidence) -> tuple[dict[tuple[int, int], tuple], list]:
    """(video, frame) -> (boxes (k, 4), ``confidence(detections)`` (k,)) of ``detector`` on each record's image.

    Also the paths of the frames that could not be read: they get no box. Progress goes to stderr.
    """
    import cv2

    out: dict[tuple[int, int], tuple] = {}
    unreadable: list = []
    started = time.monotonic()
    for index, record in enumerate(records, start=1):
        path = Path(record.path) if record.path else None
        image = cv2.imread(str(path), cv2.IMREAD_COLOR) if path is not None and path.is_file() else None
        if image is None or not image.size:
            unreadable.append(path)
            out[(record.video, record.frame)] = (np.zeros((0, 4)), np.zeros(0))
            continue
        found = detector.detect(image)
        out[(record.video, record.frame)] = (found.boxes_xyxy, confidence(found))
        if index % 10 == 0 or index == len(records):
            _progress(index, len(records), started)
    print(file=sys.stderr)
    return out, unreadable


def video_frame_boxes(video_path, start_utc: float, track: GpsTrack, every: int = 25, max_gap_s: float = 3.0,
                      detector_params: str | None = None, save_csv: str | None = None,
                      video_id: int = 0) -> tuple[list[FrameBoxes], int, np.ndarray]:
    """FrameBoxes of every ``every``-th frame of a video whose GPS fix exists.

    Also returns the number of frames without one and the first such frame (BGR; for the calibration picture).
    """
    source = VideoSource(video_path, start_utc=start_utc, every=every)
    frames: list[FrameBoxes] = []
    rows = []
    without_gps = 0
    detector = None
    first_image = None
    started = time.monotonic()
    total = source.frame_count()
    for index, item in enumerate(source, start=1):
        gps = _gps_at(track, item.stamp, max_gap_s)
        if gps is None:
            without_gps += 1
            continue
        image = item.bgr()
        if first_image is None:
            first_image = image
        if detector is None:
            detector = calibration_free_detector(detector_params, (image.shape[1], image.shape[0]))
        dets = detector.detect(image)
        rows.append((video_id, item.index, dets.boxes_xyxy, dets.scores))
        frames.append(_frame_boxes(video_id, item.index, item.stamp, gps, dets.boxes_xyxy, dets.scores))
        if index % 10 == 0:
            _progress(index, total, started)
    print(file=sys.stderr)
    if save_csv:
        _save_detections(save_csv, rows)
    if first_image is None:
        raise DataError(f"no frame of {video_path} falls inside the GPS track {track.time_span()} (Unix s): check "
                        "--start-utc and that the track covers the video")
    return frames, without_gps, first_image


def _save_detections(path, rows: Iterable[tuple[int, int, np.ndarray, np.ndarray]]) -> None:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    count = 0
    for video, frame, boxes, scores in rows:
        for box, score in zip(boxes, scores, strict=True):
            writer.writerow(csv_row(video, frame, box, score))
            count += 1
    atomic_write_text(Path(path), out.getvalue())
    print(f"wrote {path} ({count} boxes)", file=sys.stderr)


def graph_detector_boxes(records, camera, params_path: str | None = None, detections: str | None = None
                         ) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """(video, frame) -> (boxes (k, 4), probability of being the vessel of interest (k,)) of the graph's detector.

    ``records``: the frames (``dataset.frames``); ``camera``: the calibration it runs with (its band below the
    horizon, its cue). ``params_path``: the graph's parameter file (default ``config/aitas.yaml``);
    ``detections``: a ``detect run`` CSV of that detector instead of running it (its ``p_target`` column).
    """
    if detections:
        table = read_detections_csv(detections, "write one with `./vessel detect run --params P --calib C`")
        empty = (np.zeros((0, 4)), np.zeros(0))
        return {(r.video, r.frame): table.get((r.video, r.frame), empty) for r in records}
    path = params_path or repo_file(GRAPH_PARAMS)
    if path is None:
        raise DataError(f"{GRAPH_PARAMS} not found: give the graph's parameter file")
    values, _ = load_params_file(path)
    out, unreadable = _detect_each(build_detector(values, camera), records,
                                   lambda found: np.where(np.isfinite(found.p_target), found.p_target, found.scores))
    if unreadable:
        print(f"warning: {len(unreadable)} of {len(records)} frames could not be read (first: {unreadable[0]}); "
              "they count as frames without a box", file=sys.stderr)
    return out
