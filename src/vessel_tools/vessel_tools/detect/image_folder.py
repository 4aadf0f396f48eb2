"""The detector over folders of still images of any camera, and its figures against YOLO labels.

``./vessel detect images`` runs a parameter file's detector over every image of one or more folders and writes
``file,x1,y1,x2,y2,score,class_id,p_target``; ``./vessel detect score-images`` scores such boxes (or runs the
detector itself) against hand boxes in YOLO text labels. These images come from cameras without a calibration,
so no horizon is known: the whole image height is searched, whatever the parameter file says about the band.

Every box counts as a vessel, whatever its class: the question is whether the boats are found, not which one
is the vessel of interest. A hit is IoU >= 0.3 with a hand box of the watercraft class, matched greedily by
score (each hand box at most once); average precision is the area under the all-point interpolated
precision-recall curve of the boxes at or above the threshold. Width classes follow the hand box's width at the
image's own resolution; a box matched to a hand box of another width class, or unmatched and of another width,
is left out of that class's figures rather than counted against it.
"""

from __future__ import annotations

import csv
import io
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from vessel_common.errors import DataError

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
WIDTH_CLASSES = (("all", 0.0, math.inf), ("<20 px", 0.0, 20.0), ("20-50 px", 20.0, 50.0), (">50 px", 50.0, math.inf))
MIN_SIDE_PX = 32
MAX_SIDE_PX = 16384
MAX_ASPECT = 10.0
CSV_HEADER = ("file", "x1", "y1", "x2", "y2", "score", "class_id", "p_target")


def image_paths(folders: list[str], only: list[str]) -> list[Path]:
    """The image files of ``folders`` (not recursive), sorted by name; ``only``: file-name prefixes to keep."""
    paths = []
    for folder in folders:
        root = Path(folder)
        if not root.is_dir():
            raise DataError(f"--images {folder}: no such folder")
        paths += [p for p in sorted(root.iterdir()) if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
    if only:
        paths = [p for p in paths if any(p.name.startswith(prefix) for prefix in only)]
    names = [p.name for p in paths]
    duplicate = next((n for n in names if names.count(n) > 1), None)
    if duplicate:
        raise DataError(f"--images: two folders hold {duplicate}; boxes are keyed by file name, give one of them")
    if not paths:
        raise DataError(f"no image files ({', '.join(IMAGE_SUFFIXES)}) in {', '.join(folders)}"
                        f"{' starting with ' + ','.join(only) if only else ''}")
    return paths


def read_image(path: Path) -> tuple[np.ndarray | None, str]:
    """The BGR image of ``path``, or None and why it cannot be used (one line)."""
    if path.stat().st_size == 0:
        return None, "empty file"
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or not image.size:
        return None, "unreadable (not an image the decoder knows)"
    if image.ndim == 2 or image.shape[2] == 1:
        return None, "grayscale (the detector takes colour images)"
    if image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    if image.dtype != np.uint8:
        return None, f"{image.dtype} pixels (the detector takes 8-bit images)"
    height, width = image.shape[:2]
    if min(width, height) < MIN_SIDE_PX or max(width, height) > MAX_SIDE_PX or \
            max(width, height) > MAX_ASPECT * min(width, height):
        return None, f"odd size {width}x{height} (sides {MIN_SIDE_PX}-{MAX_SIDE_PX} px, aspect at most {MAX_ASPECT:g})"
    return image, ""


@dataclass
class FolderRun:
    """The detector's boxes per usable image, the image sizes, and the files skipped with their reason."""

    boxes: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)
    sizes: dict[str, tuple[int, int]] = field(default_factory=dict)
    skipped: list[tuple[str, str]] = field(default_factory=list)


def whole_image_detector(params: str):
    """The parameter file's detector with no horizon: the band is the whole image height."""
    from vessel_detect.detector_params import build_detector, load_params_file

    values, _ = load_params_file(params)
    values["appearance_model"] = ""  # the cue is fitted to one camera's geometry and needs its calibration
    detector = build_detector(values, None)
    detector.horizon_y = None
    return detector


def run_folder(detector, paths: list[Path], progress: bool = True) -> FolderRun:
    """Detect in every usable image; unusable ones are named on stderr and recorded in ``skipped``."""
    run = FolderRun()
    for index, path in enumerate(paths, 1):
        image, problem = read_image(path)
        if image is None:
            print(f"skipped {path}: {problem}", file=sys.stderr)
            run.skipped.append((path.name, problem))
            continue
        dets = detector.detect(image)
        run.boxes[path.name] = (dets.boxes_xyxy, dets.scores, dets.class_ids, dets.target_confidences())
        run.sizes[path.name] = (image.shape[1], image.shape[0])
        if progress and (index % 20 == 0 or index == len(paths)):
            print(f"  {index}/{len(paths)} images", file=sys.stderr, flush=True)
    return run


def boxes_csv_text(run: FolderRun) -> str:
    """``file,x1,y1,x2,y2,score,class_id,p_target``, one row per box (an image without boxes has none)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(CSV_HEADER)
    for name in sorted(run.boxes):
        boxes, scores, classes, p_target = run.boxes[name]
        for box, score, cls, target in zip(boxes, scores, classes, p_target, strict=True):
            writer.writerow([name, *(f"{v:.1f}" for v in box), f"{score:.4f}", int(cls), f"{target:.4f}"])
    return buffer.getvalue()


def read_boxes_csv(path: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """File name -> (boxes, scores) of a ``detect images`` CSV."""
    try:
        with open(path, newline="") as handle:
            reader = csv.DictReader(handle)
            if not reader.fieldnames or not set(CSV_HEADER[:6]) <= set(reader.fieldnames):
                raise DataError(f"--detections {path}: not a `detect images` CSV (needs {','.join(CSV_HEADER)})")
            rows: dict[str, list] = {}
            for row in reader:
                rows.setdefault(row["file"], []).append([float(row[k]) for k in CSV_HEADER[1:6]])
    except OSError as error:
        raise DataError(f"--detections {path}: {error.strerror}") from None
    except ValueError:
        raise DataError(f"--detections {path}: a box or score is not a number") from None
    return {name: (np.asarray(v)[:, :4], np.asarray(v)[:, 4]) for name, v in rows.items()}


def read_yolo_labels(label_dirs: list[str], name: str, size: tuple[int, int], wanted: int) -> np.ndarray | None:
    """Pixel boxes of class ``wanted`` in ``<label dir>/<stem>.txt`` (the first dir that has it); None: no file."""
    stem = Path(name).stem
    for folder in label_dirs:
        path = Path(folder) / f"{stem}.txt"
        if path.is_file():
            return parse_yolo_file(path, size, wanted)
    return None


def parse_yolo_file(path: Path, size: tuple[int, int], wanted: int) -> np.ndarray:
    """``(N, 4)`` xyxy pixel boxes of class ``wanted`` in a YOLO label file (``class cx cy w h``, normalised)."""
    width, height = size
    boxes = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        fields = line.split()
        if not fields:
            continue
        try:
            cls, cx, cy, w, h = int(float(fields[0])), *(float(v) for v in fields[1:5])
        except (ValueError, TypeError):
            raise DataError(f"{path}:{number}: not a YOLO label line 'class cx cy w h': {line[:60]!r}") from None
        if cls == wanted:
            boxes.append([(cx - w / 2) * width, (cy - h / 2) * height, (cx + w / 2) * width, (cy + h / 2) * height])
    return np.asarray(boxes, float).reshape(-1, 4)
