"""Hand-labelled images of other fixed cameras as extra ``vessel`` training data (``detect train --webcams``).

A model trained on one camera learns that camera's sea, light and boat sizes and misses boats elsewhere. Folders
laid out like Shore Livecams (``images/{train,test}/``, YOLO ``labels/{train,test}/``, the file name starting with
the webcam's id) add boats of other cameras: their watercraft boxes become ``vessel`` boxes, never the vessel of
interest, which stays the GPS-labelled camera's. These cameras have no horizon known, so their crops come from
the whole image, and at several scales up to a few times enlarged, because many of their boats are a few pixels
wide and the network's finest stride would otherwise never see them at a learnable size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from vessel_common.errors import DataError
from vessel_tools.detect.image_folder import parse_yolo_file
from vessel_tools.detect.training.augment import AugmentSettings, Sample, _finish
from vessel_tools.detect.training.labels import OTHER_CLASS, FrameLabels

WEBCAM_SOURCE = "webcam"
"""``FrameLabels.target_source`` of a webcam image: the trainer crops it with :func:`webcam_sample`."""
WEBCAM_VIDEO_BASE = -1000
"""Webcam images are keyed ``(WEBCAM_VIDEO_BASE - camera index, image index)``: never a dataset video number."""
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


@dataclass(frozen=True)
class WebcamSettings:
    """How webcam crops are drawn."""

    scale_range: tuple[float, float] = (0.6, 3.0)
    focus_box: float = 0.7
    watercraft_class: int = 2


def webcam_id(path: Path) -> str:
    """The webcam a Shore Livecams file belongs to: its name up to the first underscore."""
    return path.stem.split("_", 1)[0]


def image_files(root: Path, splits: tuple[str, ...] = ("train", "test")) -> list[Path]:
    """Every image under ``root/images/<split>/``, sorted (the draw order of a seed depends on it)."""
    files = []
    for split in splits:
        folder = root / "images" / split
        files += [p for p in sorted(folder.glob("*")) if p.suffix.lower() in IMAGE_SUFFIXES]
    return files


def load_webcams(root: str | Path, held_out: set[str], settings: WebcamSettings = WebcamSettings(),
                 log=print) -> tuple[list[FrameLabels], dict, dict[str, int]]:
    """Labels and images of every webcam not in ``held_out``; returns (labels, images, images per webcam)."""
    root = Path(root)
    files = image_files(root)
    if not files:
        raise DataError(f"--webcams {root}: no images under images/train or images/test")
    cameras = sorted({webcam_id(p) for p in files})
    unknown = sorted(held_out - set(cameras))
    if unknown:
        raise DataError(f"--webcam-holdout {','.join(unknown)}: no such webcam in {root} ({', '.join(cameras)})")
    labels, images, counts = [], {}, {}
    for index, path in enumerate(files):
        camera = webcam_id(path)
        if camera in held_out:
            continue
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None or not image.size:
            log(f"warning: cannot read webcam image {path}; left out")
            continue
        label_path = root / "labels" / path.parent.name / f"{path.stem}.txt"
        boxes = (parse_yolo_file(label_path, (image.shape[1], image.shape[0]), settings.watercraft_class)
                 if label_path.is_file() else np.zeros((0, 4)))
        key = (WEBCAM_VIDEO_BASE - cameras.index(camera), index)
        labels.append(FrameLabels(key[0], key[1], "labelled", boxes, np.full(len(boxes), OTHER_CLASS, np.int64),
                                  target_source=WEBCAM_SOURCE))
        images[key] = image
        counts[camera] = counts.get(camera, 0) + 1
    return labels, images, counts


def webcam_sample(bgr: np.ndarray, labels: FrameLabels, rng: np.random.Generator, augment: AugmentSettings,
                  settings: WebcamSettings = WebcamSettings()) -> Sample:
    """One crop of the whole image at a log-uniform scale, most often around one of its boats."""
    height, width = bgr.shape[:2]
    out_w, out_h = augment.crop_wh
    lo, hi = settings.scale_range
    scale = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    src_w, src_h = out_w / scale, out_h / scale
    if len(labels.boxes) and rng.random() < settings.focus_box:
        box = labels.boxes[rng.integers(len(labels.boxes))]
        x0 = 0.5 * (box[0] + box[2]) - rng.uniform(0.1, 0.9) * src_w
        y0 = 0.5 * (box[1] + box[3]) - rng.uniform(0.2, 0.8) * src_h
    else:
        x0 = rng.uniform(-0.05 * src_w, max(width - 0.95 * src_w, 0.0))
        y0 = rng.uniform(-0.05 * src_h, max(height - 0.95 * src_h, 0.0))
    return _finish(bgr, labels, x0, y0, scale, rng, augment)
