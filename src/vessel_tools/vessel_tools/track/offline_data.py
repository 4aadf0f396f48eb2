"""What the offline tools read and write: the data folder, its calibration, detections as frames, predictions.

Offline tool layer, shared by the pipeline, the evaluation, the cue and distance-model fits and the demo; the
runtime core (tracker, fusion, selection) never reads files through it.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_calib import geodesy
from vessel_calib.params import atomic_write_text, load_camera_yaml
from vessel_common.errors import DataError
from vessel_common.paths import default_data_dir, repo_root
from vessel_detect.detections_csv import read_detections_csv, require_rows_for
from vessel_tools.calib.dataset import Dataset


def open_dataset(data_dir: Path | None):
    """The dataset at ``data_dir`` (default: $VESSEL_DATA or ../shared/aitas); DataError if none."""
    if data_dir is None:
        data_dir = default_data_dir()
        if data_dir is None:
            raise DataError("no dataset: pass --data DIR or set VESSEL_DATA (default ../shared/aitas is absent)")
    return Dataset(data_dir)


def default_calibration_path() -> Path | None:
    """``config/aitas_camera.yaml`` of the project, if it exists (the project's fitted calibration)."""
    path = repo_root() / "config" / "aitas_camera.yaml"
    return path if path.is_file() else None


def default_params_path() -> Path | None:
    """The project's parameter file with a fuser block: config/aitas.yaml, else config/parts/fuser.yaml."""
    import yaml


    for candidate in (repo_root() / "config" / "aitas.yaml", repo_root() / "config" / "parts" / "fuser.yaml"):
        try:
            document = yaml.safe_load(candidate.read_text(encoding="utf-8")) if candidate.is_file() else None
        except (OSError, yaml.YAMLError):
            document = None
        if isinstance(document, dict) and isinstance(document.get("fuser"), dict):
            return candidate
    return None


def load_camera(calib: Path | None, dataset=None):
    """(camera model, description) for a run.

    ``calib`` if given; else the project's calibration if it belongs to this dataset's camera (same position
    within 10 m); else the dataset's paper-corrected calibration.
    """
    if calib is not None:
        return load_camera_yaml(calib), str(calib)
    default = default_calibration_path()
    if default is not None:
        camera = load_camera_yaml(default)
        if dataset is None or geodesy.haversine_m(camera.camera_lat, camera.camera_lon, dataset.camera_lat,
                                                  dataset.camera_lon) < 10.0:
            return camera, str(default)
    if dataset is None:
        raise DataError("no calibration: pass --calib FILE.yaml")
    return dataset.camera_model(), f"{dataset.path / 'camera.json'} (paper, corrected)"


@dataclass
class DetectionFrame:
    """The detections of one frame."""

    video: int
    frame: int
    stamp: float
    boxes: np.ndarray    # (N, 4) x1, y1, x2, y2 px
    scores: np.ndarray   # (N,)


def label_detections(dataset, videos) -> list[DetectionFrame]:
    """The hand-labelled primary boxes as detections (score 1), one frame per labelled frame."""
    grouped: dict[tuple[int, int], list] = defaultdict(list)
    for record in dataset.labels(videos, primary_only=True):
        grouped[(record.video, record.frame)].append(record)
    frames = []
    for (video, frame), records in sorted(grouped.items()):
        boxes = np.array([[r.x1, r.y1, r.x2, r.y2] for r in records], dtype=float)
        frames.append(DetectionFrame(video, frame, records[0].stamp, boxes, np.ones(len(records))))
    if not frames:
        raise DataError(f"{dataset.path}: no labelled boxes in videos {videos}; use --detections FILE.csv")
    return frames


def csv_detections(path: Path, dataset, videos) -> list[DetectionFrame]:
    """Detector output CSV -> frames; every frames.csv frame of ``videos`` is a frame (empty if no rows).

    A row for a frame not in frames.csv is timed by linear interpolation of frame numbers within its video.
    Rows with non-numeric or non-finite values, and a file with no box in ``videos``, raise DataError.
    """
    path = Path(path)
    grouped = read_detections_csv(path, "write one with `./vessel detect run ... --out FILE.csv` or use "
                                        "--detections labels")
    require_rows_for(grouped, videos, path)
    wanted = None if videos is None else set(videos)
    rows = {key: np.column_stack([boxes, scores]) for key, (boxes, scores) in grouped.items()
            if wanted is None or key[0] in wanted}
    frame_records = dataset.frames(videos)
    stamps = {(f.video, f.frame): f.stamp for f in frame_records}
    keys = set(stamps) | set(rows)
    by_video: dict[int, list] = defaultdict(list)
    for f in frame_records:
        by_video[f.video].append((f.frame, f.stamp))
    frames = []
    for video, frame in sorted(keys):
        stamp = stamps.get((video, frame))
        if stamp is None:
            known = sorted(by_video.get(video, []))
            if len(known) < 2:
                raise DataError(f"{path}: video {video} frame {frame} is not in frames.csv and the video has too "
                                f"few frames to time it")
            stamp = float(np.interp(frame, [k[0] for k in known], [k[1] for k in known],
                                    left=math.nan, right=math.nan))
            if not math.isfinite(stamp):
                f0, t0 = known[0] if frame < known[0][0] else known[-2]
                f1, t1 = known[1] if frame < known[0][0] else known[-1]
                stamp = t0 + (frame - f0) * (t1 - t0) / (f1 - f0)
        values = np.asarray(rows.get((video, frame), np.zeros((0, 5))), dtype=float).reshape(-1, 5)
        frames.append(DetectionFrame(video, frame, stamp, values[:, :4], values[:, 4]))
    return frames


def seconds_of_day(stamp: float) -> float:
    """UTC seconds of the day of a Unix time (the column ``t_utc_s`` of the predictions)."""
    return stamp % 86400.0


def atomic_lines(path: Path, lines: list[str]) -> None:
    """Write ``lines`` to ``path`` atomically (never a half file)."""
    atomic_write_text(path, "\n".join(lines) + "\n")


PREDICTION_HEADER = "video,t_utc_s,lat,lon"


def prediction_line(video: int, stamp: float, lat: float, lon: float) -> str:
    """One row of ``predictions.csv``: the time as UTC seconds of the day, as ``./vessel eval`` reads it."""
    return f"{int(video)},{seconds_of_day(stamp):.3f},{float(lat):.8f},{float(lon):.8f}"
