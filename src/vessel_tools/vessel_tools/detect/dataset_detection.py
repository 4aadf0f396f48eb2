"""The detector core over a data folder's frames: what ``detect run`` and ``detect train`` share.

Offline tool layer: a data folder (``vessel_tools.calib.dataset``), its calibration, the frames read from disk and the
detections written as the ``detect run`` CSV.
"""

from __future__ import annotations

import csv
import dataclasses
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


class DatasetPoser:
    """Each frame's pose for a dataset with ``own_ship.csv`` (a camera on a ship), as the detector node finds it.

    The ship's samples go into a ``FramePoser`` in time order up to just past each frame, as they would arrive
    live; ``detect`` then detects in the frame and returns the boxes in the calibration's reference image, where
    the tracker and the fuser read them. A frame that gets no pose comes back as None (no positions from it).
    """

    LOOK_AHEAD_S = 1.0

    def __init__(self, samples, camera, values):
        from vessel_detect.detector_params import frame_poser

        values = dict(values, **{"pose.source": "own_ship", "pose.wait_s": 0.0})
        self.poser = frame_poser(values, camera)
        self.camera = camera
        self.samples = [s for s in samples if s.attitude is not None]
        self.next_index = 0
        self.skipped = 0

    def detect(self, detector: VesselDetector, stamp: float, image: np.ndarray) -> Detections | None:
        """The frame's detections in the reference image, or None when it has no pose."""
        if self.next_index and self.samples[self.next_index - 1].stamp > stamp + self.LOOK_AHEAD_S:
            self.next_index = 0  # frames went back in time (another video): feed the ship's samples again
        while self.next_index < len(self.samples) and self.samples[self.next_index].stamp <= stamp + self.LOOK_AHEAD_S:
            sample = self.samples[self.next_index]
            self.poser.add_attitude(sample.stamp, sample.attitude)
            self.next_index += 1
        pose = self.poser.pose_of(stamp, image)
        if not pose.estimate.valid:
            self.skipped += 1
            return None
        detections = detector.detect(image, pose.view)
        height, width = image.shape[:2]
        detections = detections.in_calibrated_pixels((width, height), detector.reference_wh)
        boxes = pose.view.boxes_in_reference(detections.boxes_xyxy, detector.reference_wh, detector.reference_wh)
        mapped = dataclasses.replace(detections, boxes_xyxy=boxes)
        return mapped.take(np.all(np.isfinite(boxes), axis=1))  # a box beyond the lens's reach has no place there


def dataset_poser(dataset, camera, values) -> DatasetPoser | None:
    """The poser of a dataset with ``own_ship.csv`` (its ``reference_attitude`` unless the calibration has one)."""
    samples = dataset.own_ship()
    if samples is None:
        return None
    if camera is None:
        raise DataError(f"{dataset.path} has own_ship.csv: pass the calibration (--calib FILE) to pose its frames")
    if camera.reference_attitude_deg is None and dataset.reference_attitude() is not None:
        reference = dataset.reference_attitude()
        params = dict(camera.to_params(), reference_attitude_deg=[
            reference.heading_deg, reference.pitch_deg or 0.0, reference.roll_deg or 0.0])
        camera = type(camera).from_params(params)
    return DatasetPoser(samples, camera, values)


def detect_frames(detector: VesselDetector, frames: list, progress: bool = True,
                  poser: DatasetPoser | None = None) -> Iterator[tuple[object, Detections]]:
    """Run the detector over dataset frames; unreadable frames are reported once each and skipped.

    With ``poser`` (a camera on a ship) boxes come back in the calibration's reference image and frames without
    a pose are skipped.
    """
    started = time.monotonic()
    for index, record in enumerate(frames, start=1):
        image = read_frame(record.path)
        if image is None:
            print(f"warning: cannot read frame {record.path}; skipped", file=sys.stderr)
            continue
        if poser is None:
            yield record, detector.detect(image)
        else:
            detections = poser.detect(detector, record.stamp, image)
            if detections is not None:
                yield record, detections
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
