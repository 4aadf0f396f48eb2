"""The detector core over a data folder's frames: what ``detect run`` and ``detect train`` share.

Offline tool layer: a data folder (``vessel_tools.calib.dataset``), its calibration, the frames read from disk and the
detections written as the ``detect run`` CSV.
"""

from __future__ import annotations

import csv
import io
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

import cv2
import numpy as np

from vessel_calib.params import load_camera_yaml
from vessel_common.errors import DataError, VesselError
from vessel_common.paths import default_data_dir, parse_videos
from vessel_detect.detections_csv import CSV_COLUMNS, csv_row
from vessel_detect.detector import Detections, VesselDetector
from vessel_tools.calib.dataset import Dataset


def open_dataset(data: str | None):
    """The data folder ``data`` (default ``$VESSEL_DATA`` or ``../shared/aitas``); DataError when there is none."""
    path = Path(data) if data else default_data_dir()
    if path is None:
        raise DataError("no dataset folder: pass --data DIR or set VESSEL_DATA (default ../shared/aitas)")
    return Dataset(path)


def parse_video_spec(spec: str | None):
    """``--videos`` text to a list of video numbers (None: all)."""
    return parse_videos(spec)


def camera_for(dataset, params_camera, calib=None):
    """The calibration: ``--calib``, else the params file's camera block, else the dataset's camera.json one."""
    if calib:

        return load_camera_yaml(calib)
    if params_camera is not None:
        return params_camera
    try:
        return dataset.camera_model()
    except VesselError as error:
        print(f"warning: {error}; using the challenge camera's horizon (y = 418)", file=sys.stderr)
        return None


def read_frame(path: Path) -> np.ndarray | None:
    """A frame as BGR, None when it cannot be read."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    return image if image is not None and image.size else None


def detect_frames(detector: VesselDetector, frames: list, progress: bool = True) -> Iterator[tuple[object, Detections]]:
    """Run the detector over dataset frames; unreadable frames are reported once each and skipped."""
    started = time.monotonic()
    for index, record in enumerate(frames, start=1):
        image = read_frame(record.path)
        if image is None:
            print(f"warning: cannot read frame {record.path}; skipped", file=sys.stderr)
            continue
        yield record, detector.detect(image)
        if progress and (index % 20 == 0 or index == len(frames)):
            rate = index / max(time.monotonic() - started, 1e-9)
            print(f"\r  {index}/{len(frames)} frames, {rate:.1f} frames/s", end="", file=sys.stderr, flush=True)
    if progress and frames:
        print(file=sys.stderr)


def detections_csv_text(rows: Iterable[tuple[int, int, Detections]]) -> str:
    """The CSV of ``run`` for (video, frame, detections) rows."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for video, frame, dets in rows:
        for box, score, class_id, p_target in zip(dets.boxes_xyxy, dets.scores, dets.class_ids, dets.p_target,
                                                  strict=True):
            writer.writerow(csv_row(video, frame, box, score, class_id, p_target))
    return out.getvalue()
