"""``./vessel detect images`` and ``./vessel detect score-images``: the detector on folders of any camera's images.

``images`` writes the boxes as CSV; ``score-images`` prints recall, precision and average precision against YOLO
labels, by box width (definitions: :mod:`vessel_tools.detect.image_folder`). Both take the parameter file of a
detector set-up (default ``config/detector_any_camera.yaml``, the preset for a camera with no calibration).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from vessel_common.errors import DataError
from vessel_common.paths import output_file, repo_file
from vessel_tools.detect.image_folder import (
    boxes_csv_text,
    image_paths,
    read_boxes_csv,
    read_image,
    read_yolo_labels,
    run_folder,
    whole_image_detector,
)

DEFAULT_PARAMS = "config/detector_any_camera.yaml"


def add_parsers(sub) -> None:
    """Register ``images`` and ``score-images`` on the ``detect`` sub-command parser."""
    images = sub.add_parser("images", help="detections of every image of a folder (any camera, no calibration)")
    _add_common(images)
    images.add_argument("--out", required=True, help="CSV to write (file,x1,y1,x2,y2,score,class_id,p_target)")
    images.set_defaults(func=cmd_images)
    score = sub.add_parser("score-images", help="recall, precision and AP against YOLO labels, by box width")
    _add_common(score)
    score.add_argument("--labels", nargs="+", required=True,
                       help="folder(s) of YOLO labels, <image stem>.txt with 'class cx cy w h' normalised")
    score.add_argument("--class", dest="class_id", type=int, default=2,
                       help="the labels' class of the boats (default 2: Shore Livecams' watercraft)")
    score.add_argument("--detections", help="a CSV from `detect images` (default: run the detector now)")
    score.add_argument("--score", type=float, help="score threshold (default: the parameter file's)")
    score.add_argument("--out", help="also write the figures as JSON")
    score.set_defaults(func=cmd_score_images)


def _add_common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--images", nargs="+", required=True, help="folder(s) of images (not searched recursively)")
    parser.add_argument("--only", default="", help="comma-separated file-name prefixes to keep (e.g. webcam ids)")
    parser.add_argument("--params", default=repo_file(DEFAULT_PARAMS),
                        help=f"parameter YAML of the detector (default {DEFAULT_PARAMS}); the image is searched "
                             "whole, with no horizon")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def _only(args: argparse.Namespace) -> list[str]:
    return [v.strip() for v in args.only.split(",") if v.strip()]


def cmd_images(args: argparse.Namespace) -> int:
    """``images``: every image's boxes to CSV; unusable files are named and counted."""
    out = output_file(args.out)
    paths = image_paths(args.images, _only(args))
    detector = whole_image_detector(args.params)
    print(f"detecting in {len(paths)} images ({detector.config.mode}, score >= {detector.config.score_threshold:g}, "
          f"model {detector.model.path.name})", file=sys.stderr)
    run = run_folder(detector, paths, not args.quiet)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(boxes_csv_text(run))
    total = sum(len(v[0]) for v in run.boxes.values())
    print(f"wrote {out}: {total} boxes in {len(run.boxes)} images; {len(run.skipped)} file(s) skipped", file=sys.stderr)
    return 0


def cmd_score_images(args: argparse.Namespace) -> int:
    """``score-images``: the figures table, and JSON with ``--out``."""
    from vessel_tools.detect.image_scores import figures_table, score_images

    paths = image_paths(args.images, _only(args))
    for folder in args.labels:
        if not Path(folder).is_dir():
            raise DataError(f"--labels {folder}: no such folder")
    threshold, detections, sizes, skipped = _detections(args, paths)
    truths, unlabelled = {}, 0
    for name, size in sizes.items():
        boxes = read_yolo_labels(args.labels, name, size, args.class_id)
        if boxes is None:
            unlabelled += 1
        else:
            truths[name] = boxes
    if not truths:
        raise DataError(f"no label file in {', '.join(args.labels)} for any of the {len(sizes)} images")
    figures = score_images(detections, truths, threshold)
    print(figures_table(figures, len(truths), threshold))
    if unlabelled or skipped:
        print(f"left out: {unlabelled} image(s) without a label file, {skipped} unusable file(s)")
    if args.out:
        out = output_file(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"images": len(truths), "score_threshold": threshold, "iou": 0.3,
                                   "params": args.params, "detections": args.detections, "figures": figures},
                                  indent=2) + "\n")
    return 0


def _detections(args: argparse.Namespace, paths: list[Path]) -> tuple[float, dict, dict, int]:
    """(threshold, file -> (boxes, scores), file -> image size, files skipped): from the CSV or a run now."""
    if args.detections:
        detections = read_boxes_csv(args.detections)
        sizes, skipped = {}, 0
        for path in paths:
            image, problem = read_image(path)
            if image is None:
                print(f"skipped {path}: {problem}", file=sys.stderr)
                skipped += 1
            else:
                sizes[path.name] = (image.shape[1], image.shape[0])
        return (args.score if args.score is not None else 0.0), detections, sizes, skipped
    detector = whole_image_detector(args.params)
    threshold = args.score if args.score is not None else detector.config.score_threshold
    if threshold < detector.config.score_threshold:
        raise DataError(f"--score {threshold:g} is below the parameter file's score_threshold "
                        f"{detector.config.score_threshold:g}: boxes under it were never kept")
    run = run_folder(detector, paths, not args.quiet)
    detections = {name: (v[0], v[1]) for name, v in run.boxes.items()}
    return threshold, detections, run.sizes, len(run.skipped)
