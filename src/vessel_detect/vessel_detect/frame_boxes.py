"""Detected boats of each frame with the tracked vessel's GPS at its instant: the label-free calibration's input.

The detector is the generic COCO set-up (``config/detector_coco.yaml``) without anything that needs a
calibration: no appearance cue, no band below a horizon (the whole frame is tiled), no exclusion masks drawn for
one camera. Frames come from a data folder (``frames.csv`` + ``target_gps_fixes.csv``) or from a video file with a
start time and a GPS track (CSV or GPX), so a new camera needs no data folder.
"""

from __future__ import annotations

import csv
import sys
import time
from collections import defaultdict
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from vessel_calib.errors import DataError
from vessel_calib.gps_association import FrameBoxes
from vessel_calib.gps_track import GpsTrack
from vessel_calib.params import atomic_write_text
from vessel_calib.paths import repo_file
from vessel_detect.detector import VesselDetector
from vessel_detect.detector_params import detector_config, load_params_file, open_model
from vessel_detect.sources import VideoSource

#: The generic detector's parameters (its cue and masks are left out).
DEFAULT_DETECTOR_PARAMS = "config/detector_coco.yaml"


def calibration_free_detector(params_path: str | None, image_wh: tuple[int, int]):
    """The detector of ``params_path`` (default: the COCO preset) made independent of any calibration."""
    path = params_path or repo_file(DEFAULT_DETECTOR_PARAMS)
    if path is None:
        raise DataError(f"{DEFAULT_DETECTOR_PARAMS} not found: give --detector-params FILE")
    values, _ = load_params_file(path)
    values["appearance_model"] = ""
    values["exclusion_polygons"] = [""]
    return VesselDetector(open_model(values), detector_config(values), None, tuple(int(v) for v in image_wh))


def read_detections_csv(path) -> dict[tuple[int, int], np.ndarray]:
    """``detect run`` CSV -> {(video, frame): (k, 5) x1, y1, x2, y2, score}."""
    out: dict[tuple[int, int], list[list[float]]] = defaultdict(list)
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            missing = {"video", "frame", "x1", "y1", "x2", "y2", "score"} - set(reader.fieldnames or [])
            if missing:
                raise DataError(f"{path}: missing column(s) {', '.join(sorted(missing))}: give a `detect run` CSV")
            for line, row in enumerate(reader, start=2):
                try:
                    key = (int(row["video"]), int(row["frame"]))
                    out[key].append([float(row[k]) for k in ("x1", "y1", "x2", "y2", "score")])
                except (TypeError, ValueError):
                    raise DataError(f"{path}, line {line}: expected numbers in video,frame,x1,y1,x2,y2,score") from None
    except OSError as exc:
        raise DataError(f"cannot read detections {path}: {exc.strerror or exc}") from None
    return {k: np.array(v, dtype=float) for k, v in out.items()}


def _frame_boxes(video: int, frame: int, stamp: float, track: GpsTrack, max_gap_s: float,
                 boxes: np.ndarray) -> FrameBoxes | None:
    lat, lon, ok = track.interpolate(stamp, max_gap_s=max_gap_s)
    if not ok:
        return None
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 5)
    return FrameBoxes(video, frame, float(stamp), float(lat), float(lon), boxes[:, :4], boxes[:, 4])


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
    with_gps = [r for r in records if track.interpolate(r.stamp, max_gap_s=max_gap_s)[2]]
    if detections:
        table = read_detections_csv(detections)
        boxes = {(r.video, r.frame): table.get((r.video, r.frame), np.zeros((0, 5))) for r in with_gps}
    else:
        boxes = _detect_records(with_gps, detector_params, dataset.image_size, save_csv)
    frames = [_frame_boxes(r.video, r.frame, r.stamp, track, max_gap_s, boxes[(r.video, r.frame)]) for r in with_gps]
    return [f for f in frames if f is not None], len(records) - len(with_gps)


def _detect_records(records, detector_params, image_wh, save_csv) -> dict[tuple[int, int], np.ndarray]:
    import cv2

    detector = calibration_free_detector(detector_params, image_wh)
    out: dict[tuple[int, int], np.ndarray] = {}
    started = time.monotonic()
    for index, record in enumerate(records, start=1):
        image = cv2.imread(str(record.path), cv2.IMREAD_COLOR)
        if image is None or not image.size:
            print(f"\nwarning: cannot read frame {record.path}; skipped", file=sys.stderr)
            out[(record.video, record.frame)] = np.zeros((0, 5))
            continue
        dets = detector.detect(image)
        out[(record.video, record.frame)] = np.column_stack([dets.boxes_xyxy, dets.scores]).reshape(-1, 5)
        if index % 10 == 0 or index == len(records):
            _progress(index, len(records), started)
    print(file=sys.stderr)
    if save_csv:
        _save_detections(save_csv, ((v, f, b) for (v, f), b in out.items()))
    return out


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
        stamp = item.stamp
        if not track.interpolate(stamp, max_gap_s=max_gap_s)[2]:
            without_gps += 1
            continue
        image = item.bgr()
        if first_image is None:
            first_image = image
        if detector is None:
            detector = calibration_free_detector(detector_params, (image.shape[1], image.shape[0]))
        dets = detector.detect(image)
        boxes = np.column_stack([dets.boxes_xyxy, dets.scores]).reshape(-1, 5)
        rows.append((video_id, item.index, boxes))
        found = _frame_boxes(video_id, item.index, stamp, track, max_gap_s, boxes)
        if found is not None:
            frames.append(found)
        if index % 10 == 0:
            _progress(index, total, started)
    print(file=sys.stderr)
    if save_csv:
        _save_detections(save_csv, rows)
    if first_image is None:
        raise DataError(f"no frame of {video_path} falls inside the GPS track {track.time_span()} (Unix s): check "
                        "--start-utc and that the track covers the video")
    return frames, without_gps, first_image


def _save_detections(path, rows: Iterable[tuple[int, int, np.ndarray]]) -> None:

    lines = ["video,frame,x1,y1,x2,y2,score,class_id,p_target"]
    for video, frame, boxes in rows:
        for x1, y1, x2, y2, score in boxes:
            lines.append(f"{video},{frame},{x1:.1f},{y1:.1f},{x2:.1f},{y2:.1f},{score:.4f},,")
    atomic_write_text(Path(path), "\n".join(lines) + "\n")
    print(f"wrote {path} ({len(lines) - 1} boxes)", file=sys.stderr)

