"""Offline detector tools over a dataset folder laid out like ``../shared/aitas`` (``./vessel detect ...``).

- ``run``: the detector core with the node's parameters over every frame; writes
  ``video,frame,x1,y1,x2,y2,score,class_id,p_target`` (full-resolution pixels, class_id indexes the model's
  classes, p_target the probability of being the vessel of interest).
- ``recall``: recall of the vessel of interest on the hand-labelled frames (a hit: IoU >= 0.3 with a primary
  hand box) and the mean number of other detections per frame below the horizon.
- ``rank``: on every frame with the vessel's GPS in view, whether a box and the most likely box lie at its GPS
  point, by range (no hand labels: far frames count too).
- ``images`` / ``score-images``: the detector over folders of any camera's images, and its figures against
  YOLO labels (:mod:`vessel_tools.detect.image_cli`).
- ``export-labels``: YOLO training data from the vessel's GPS projected through the calibration (the paper's
  trick: no hand labelling).

Errors in the input print ``error: <message>`` and exit with status 2.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_common.paths import output_file, repo_file
from vessel_detect.detections_csv import read_detections_csv, require_rows_for
from vessel_detect.detector import VesselDetector
from vessel_detect.detector_params import build_detector, load_params_file
from vessel_tools.detect.dataset_detection import (
    camera_for,
    dataset_poser,
    detect_frames,
    detections_csv_text,
    open_dataset,
    parse_video_spec,
)
from vessel_tools.detect.recall import GPS_MARGIN_PX, HIT_IOU, RecallResult, gps_ranking, recall_at  # noqa: F401

# Box size of a vessel from |z_p| (full-resolution pixels): size = a / |z_p| + b.
PAPER_BOX = ((3000.0, 50.0), (1700.0, 50.0))  # the paper's half-resolution formula, doubled
FITTED_BOX = ((2070.0, 16.0), (1328.0, 3.0))  # least squares on the hand boxes of videos 7-12 (gps_ok)


def _atomic_write(path: Path, text: str) -> None:
    from vessel_calib.params import atomic_write_text

    atomic_write_text(path, text)


# ---------------------------------------------------------------------------------------------------- run
def cmd_run(args: argparse.Namespace) -> int:
    """``run``: detections of every frame to CSV."""
    out = output_file(args.out)
    dataset = open_dataset(args.data)
    values, params_camera = load_params_file(args.params)
    if args.no_cue:
        values["appearance_model"] = ""
    camera = camera_for(dataset, params_camera, args.calib)
    detector = build_detector(values, camera)
    frames = dataset.frames(parse_video_spec(args.videos))
    if not frames:
        raise DataError(f"no frames for videos {args.videos or 'all'} in {dataset.path / 'frames.csv'}")
    poser = dataset_poser(dataset, camera, values)
    print(f"detecting in {len(frames)} frames of {dataset.path} ({_describe(detector)})", file=sys.stderr)
    rows = [(r.video, r.frame, d) for r, d in detect_frames(detector, frames, not args.quiet, poser)]
    if poser is not None:
        print(f"own_ship.csv: boxes written in the calibration's reference image; {poser.skipped} frame(s) without "
              "a pose skipped", file=sys.stderr)
    _atomic_write(out, detections_csv_text(rows))
    total = sum(len(d) for _, _, d in rows)
    print(f"wrote {out}: {total} detections in {len(rows)} frames", file=sys.stderr)
    return 0


def _describe(detector: VesselDetector) -> str:
    config = detector.config
    windows = len(detector.windows(detector.reference_wh))
    return (
        f"mode {config.mode}, {windows} network run(s) per frame, score >= {config.score_threshold}, "
        f"classes {','.join(config.classes)}, model {detector.model.path.name}"
    )


# ---------------------------------------------------------------------------------------------------- recall
def labelled_frames(dataset, videos) -> tuple[list, dict[tuple[int, int], np.ndarray]]:
    """Frames with hand labels (and an image) and their primary boxes."""
    frames = {(r.video, r.frame): r for r in dataset.frames(videos)}
    boxes: dict[tuple[int, int], list] = {}
    for label in dataset.labels(videos, primary_only=True):
        key = (label.video, label.frame)
        if key in frames:
            boxes.setdefault(key, []).append([label.x1, label.y1, label.x2, label.y2])
    chosen = [frames[k] for k in sorted(boxes)]
    return chosen, {k: np.asarray(v, dtype=float) for k, v in boxes.items()}


def cmd_recall(args: argparse.Namespace) -> int:
    """``recall``: recall of the vessel of interest on the hand-labelled frames."""
    dataset = open_dataset(args.data)
    videos = parse_video_spec(args.videos)
    frames, labels = labelled_frames(dataset, videos)
    if not labels:
        raise DataError(f"no hand-labelled frames for videos {args.videos} in {dataset.path}")
    values, params_camera = load_params_file(args.params)
    camera = camera_for(dataset, params_camera, args.calib)
    if args.detections:
        detections = read_detections_csv(Path(args.detections))
        require_rows_for(detections, videos, Path(args.detections))
        source = f"detections from {args.detections}"
        default_threshold = 0.0
    else:
        lowest = min(args.thresholds) if args.thresholds else args.score
        if lowest is not None:
            values["score_threshold"] = float(lowest)
        default_threshold = float(values["score_threshold"])
        detector = build_detector(values, camera)
        source = _describe(detector)
        print(f"detecting in {len(frames)} labelled frames ({source})", file=sys.stderr)
        detections = {(r.video, r.frame): (d.boxes_xyxy, d.target_confidences())
                      for r, d in detect_frames(detector, frames)}
    horizon = camera.horizon_y if camera is not None else None
    thresholds = args.thresholds or [args.score if args.score is not None else default_threshold]
    results = [recall_at(labels, detections, t, horizon) for t in thresholds]
    print(f"recall of the vessel of interest, videos {args.videos}, hit = IoU >= {HIT_IOU} with a primary hand box")
    print(f"  {source}")
    print("  confidence is p_target (the probability of being the vessel of interest) where the detector gives it")
    print("  conf>=   boxes  recall   frames  recall   most likely box is the vessel   other detections/frame")
    for r in results:
        print(
            f"  {r.threshold:6.2f}  {r.box_hits:3d}/{r.boxes:<3d} {100 * r.box_recall:5.1f} %  "
            f"{r.frame_hits:3d}/{r.frames:<3d} {100 * r.frame_recall:5.1f} %  "
            f"{r.top_hits:3d}/{r.frames:<3d} {100 * r.top_rate:5.1f} %                  {r.other_per_frame:6.2f}"
        )
    first = results[0]
    print("  per video (boxes hit/labelled): " + ", ".join(
        f"{v}: {h}/{n}" for v, (n, h) in sorted(first.per_video.items())))
    if args.out:
        _atomic_write(Path(args.out), json.dumps({"videos": args.videos, "source": source,
                                                  "results": [r.as_dict() for r in results]}, indent=2))
    return 0


# ---------------------------------------------------------------------------------------------------- rank
def gps_points(dataset, videos) -> dict[tuple[int, int], tuple[float, float, float]]:
    """(video, frame) -> (x, y, range_m): the dataset's screen point of the vessel's GPS (``gt_1hz.csv``).

    Frames whose whole second has valid GPS in view with a screen point; a frame takes the second it rounds to.
    """
    truth = {(g.video, round(g.stamp)): g for g in dataset.gt_1hz(videos)
             if g.valid and g.in_view and math.isfinite(g.x_ref) and math.isfinite(g.y_ref)}
    points = {}
    for frame in dataset.frames(videos):
        g = truth.get((frame.video, round(frame.stamp)))
        if g is not None:
            points[(frame.video, frame.frame)] = (g.x_ref, g.y_ref, g.dist_m)
    return points


def cmd_rank(args: argparse.Namespace) -> int:
    """``rank``: how often the most likely box is at the vessel's GPS, on every frame with the GPS in view."""
    if not (math.isfinite(args.margin_px) and args.margin_px >= 0):
        raise DataError(f"--margin-px must be a number of pixels >= 0, got {args.margin_px}")
    dataset = open_dataset(args.data)
    videos = parse_video_spec(args.videos)
    points = gps_points(dataset, videos)
    if not points:
        raise DataError(f"no frame of videos {args.videos} in {dataset.path} has the vessel's GPS in view with a "
                        "screen point: the ranking needs gt_1hz.csv with valid, in_view, x_ref and y_ref")
    detections = read_detections_csv(Path(args.detections))
    require_rows_for(detections, videos, Path(args.detections))
    summary = gps_ranking(points, detections, args.margin_px).as_dict()
    print(f"the vessel of interest at its GPS, videos {args.videos}, detections {args.detections}: a box within "
          f"{args.margin_px:g} px of the GPS point (gt_1hz.csv), and the box of highest p_target there")
    print("     range m   frames   a box there   top box there")
    for band in summary["bands"]:
        upper = f"{band['to_m']:.0f}" if band["to_m"] is not None else "..."
        print(f"  {band['from_m']:5.0f}-{upper:<5}  {band['frames']:5d}   {band['found']:5d}         {band['top']:5d}")
    print(f"  all          {summary['frames']:5d}   {summary['found']:5d}         {summary['top']:5d}  "
          f"({100 * summary['top_rate']:.1f} % of frames)")
    if args.out:
        _atomic_write(Path(args.out), json.dumps({"videos": args.videos, "detections": args.detections, **summary},
                                                 indent=2))
    return 0


# ---------------------------------------------------------------------------------------------------- export
def box_size_px(zp_abs: np.ndarray, model: tuple[tuple[float, float], tuple[float, float]]) -> tuple:
    """(width, height) in full-resolution pixels of a vessel at projective depth ``|z_p|``."""
    (a, b), (c, d) = model
    zp_abs = np.asarray(zp_abs, dtype=float)
    return a / zp_abs + b, c / zp_abs + d


def fit_box_model(zp_abs: np.ndarray, widths: np.ndarray, heights: np.ndarray):
    """Least-squares ``size = a / |z_p| + b`` for widths and heights."""
    A = np.c_[1.0 / np.asarray(zp_abs, float), np.ones(len(zp_abs))]
    (a, b), *_ = np.linalg.lstsq(A, np.asarray(widths, float), rcond=None)
    (c, d), *_ = np.linalg.lstsq(A, np.asarray(heights, float), rcond=None)
    return (float(a), float(b)), (float(c), float(d))


@dataclass
class ExportedFrame:
    """What the exporter decided for one frame."""

    video: int
    frame: int
    status: str  # labelled | out_of_view | gps_invalid | unreadable
    box: tuple[float, float, float, float] | None = None
    zp: float = math.nan


def plan_export(dataset, camera, frames, box_model, max_gap_s: float, min_box_px: float) -> list[ExportedFrame]:
    """Decide each frame's box from the vessel's GPS at the frame's stamp, projected through ``camera``."""
    from vessel_calib import geodesy

    track = dataset.gps_track()
    if len(frames) == 0:
        return []
    stamps = np.array([f.stamp for f in frames])
    if len(track.stamps) == 0:
        raise DataError(f"{dataset.path / 'target_gps_fixes.csv'} is missing or empty: no GPS to make labels from")
    lat, lon, valid = track.interpolate(stamps, max_gap_s=max_gap_s)
    width, height = camera.image_size
    decisions = []
    for i, record in enumerate(frames):
        if not valid[i] or not (np.isfinite(lat[i]) and np.isfinite(lon[i])):
            decisions.append(ExportedFrame(record.video, record.frame, "gps_invalid"))
            continue
        xw, yw = geodesy.gps_to_local(lat[i], lon[i], camera.camera_lat, camera.camera_lon)
        xs, ys, in_front = camera.world_to_screen(xw, yw)
        zp = abs(float(camera.zp_of_world(xw, yw)))
        if not bool(in_front) or not (np.isfinite(xs) and np.isfinite(ys)) or zp <= 0:
            decisions.append(ExportedFrame(record.video, record.frame, "out_of_view", zp=zp))
            continue
        w, h = box_size_px(zp, box_model)
        x1, y1 = max(0.0, float(xs) - w / 2), max(0.0, float(ys) - h / 2)
        x2, y2 = min(float(width), float(xs) + w / 2), min(float(height), float(ys) + h / 2)
        inside = 0 <= xs < width and 0 <= ys < height
        if not inside or x2 - x1 < min_box_px or y2 - y1 < min_box_px:
            decisions.append(ExportedFrame(record.video, record.frame, "out_of_view", zp=zp))
            continue
        decisions.append(ExportedFrame(record.video, record.frame, "labelled", (x1, y1, x2, y2), zp))
    return decisions


def cmd_export_labels(args: argparse.Namespace) -> int:
    """``export-labels``: YOLO-format training data from the vessel's GPS."""
    dataset = open_dataset(args.data)
    videos = parse_video_spec(args.videos)
    val_videos = set(parse_video_spec(args.val_videos) or []) if args.val_videos else set()
    _, params_camera = load_params_file(args.params)
    camera = params_camera or dataset.camera_model()
    if camera.camera_lat is None or camera.camera_lon is None:
        raise DataError("the calibration has no camera position (camera_lat/camera_lon): needed to project GPS")
    frames = dataset.frames(sorted(set(videos or dataset.videos()) | val_videos))
    if not frames:
        raise DataError(f"no frames for videos {args.videos} in {dataset.path / 'frames.csv'}")
    box_model = _export_box_model(args, dataset, camera, videos)
    decisions = plan_export(dataset, camera, frames, box_model, args.max_gap_s, args.min_box_px)
    out = Path(args.out)
    _empty_export_folders(out, ("train", "val") if val_videos else ("train",))
    counts, manifest = _write_exported_frames(args, out, decisions, frames, camera.image_size, val_videos)
    _atomic_write(out / "data.yaml", _data_yaml(args, out, val_videos))
    _atomic_write(out / "frames.csv", manifest)
    summary = ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
    written = sum(1 for d in decisions if d.status == "labelled") + (
        counts.get("out_of_view", 0) if args.negatives == "out-of-view" else 0)
    print(f"wrote {out}: {written} images ({summary}); data.yaml, frames.csv", file=sys.stderr)
    return 0


def _export_box_model(args: argparse.Namespace, dataset, camera, videos):
    """The box size from |z_p| of ``--box`` (fitted to the hand boxes when there are enough), printed."""
    box_model = PAPER_BOX if args.box == "paper" else FITTED_BOX
    if args.box == "fitted":
        box_model = _fit_on_labels(dataset, camera, videos) or FITTED_BOX
    print(
        f"box size from |z_p| ({args.box}): w = {box_model[0][0]:.0f}/|z_p| + {box_model[0][1]:.0f}, "
        f"h = {box_model[1][0]:.0f}/|z_p| + {box_model[1][1]:.0f} (full-resolution px)",
        file=sys.stderr,
    )
    return box_model


def _empty_export_folders(out: Path, splits: tuple[str, ...]) -> None:
    """``out/images/SPLIT`` and ``out/labels/SPLIT``, created empty (an earlier export's files are removed)."""
    for split in splits:
        for sub in ("images", "labels"):
            target = out / sub / split
            if target.exists():
                shutil.rmtree(target)
            target.mkdir(parents=True)


def _write_exported_frames(args: argparse.Namespace, out: Path, decisions, frames, image_size,
                           val_videos: set) -> tuple[dict[str, int], str]:
    """Copy the images and write the YOLO label files; frames per status and the ``frames.csv`` manifest."""
    record_of = {(r.video, r.frame): r for r in frames}
    width, height = image_size
    counts: dict[str, int] = {}
    manifest = io.StringIO()
    writer = csv.writer(manifest, lineterminator="\n")
    writer.writerow(["video", "frame", "split", "status", "written", "x1", "y1", "x2", "y2", "abs_zp"])
    for decision in decisions:
        split = "val" if decision.video in val_videos else "train"
        record = record_of[(decision.video, decision.frame)]
        write = decision.status == "labelled" or (decision.status == "out_of_view" and args.negatives == "out-of-view")
        if write and not record.path.is_file():
            decision.status, write = "unreadable", False
        counts[decision.status] = counts.get(decision.status, 0) + 1
        stem = f"{decision.video}_{decision.frame:05d}"
        if write:
            shutil.copyfile(record.path, out / "images" / split / f"{stem}{record.path.suffix.lower()}")
            text = ""
            if decision.box is not None:
                x1, y1, x2, y2 = decision.box
                text = (f"{args.class_id} {(x1 + x2) / 2 / width:.6f} {(y1 + y2) / 2 / height:.6f} "
                        f"{(x2 - x1) / width:.6f} {(y2 - y1) / height:.6f}\n")
            (out / "labels" / split / f"{stem}.txt").write_text(text)
        box = [f"{v:.1f}" for v in decision.box] if decision.box else ["", "", "", ""]
        writer.writerow([decision.video, decision.frame, split, decision.status, int(write), *box,
                         f"{decision.zp:.3f}" if np.isfinite(decision.zp) else ""])
    return counts, manifest.getvalue()


def _data_yaml(args: argparse.Namespace, out: Path, val_videos: set) -> str:
    """The YOLO ``data.yaml`` of the export."""
    names = {int(args.class_id): args.class_name}
    return (
        "# YOLO training data generated from the vessel's GPS through the calibration (vessel_detect export-labels).\n"
        "# Frames with invalid GPS are left out (the boat may be visible but unlabelled). Out-of-view frames are\n"
        f"# {'included with empty label files (negatives)' if args.negatives == 'out-of-view' else 'left out'}."
        " Other boats in the frames are not labelled.\n"
        f"path: {out.resolve()}\n"
        "train: images/train\n"
        f"val: images/{'val' if val_videos else 'train'}\n"
        f"names:\n" + "".join(f"  {k}: {v}\n" for k, v in names.items())
    )


def _fit_on_labels(dataset, camera, videos):
    """Fit the box-size model on the hand boxes (gps_ok) of ``videos``; None with fewer than 6."""
    from vessel_calib import geodesy

    labels = [lab for lab in dataset.labels(videos, primary_only=True) if lab.gps_ok]
    if len(labels) < 6:
        return None
    lat = np.array([lab.lat for lab in labels])
    lon = np.array([lab.lon for lab in labels])
    xw, yw = geodesy.gps_to_local(lat, lon, camera.camera_lat, camera.camera_lon)
    zp = np.abs(np.asarray(camera.zp_of_world(xw, yw), float))
    ok = np.isfinite(zp) & (zp > 0)
    if ok.sum() < 6:
        return None
    widths = np.array([lab.x2 - lab.x1 for lab in labels])[ok]
    heights = np.array([lab.y2 - lab.y1 for lab in labels])[ok]
    return fit_box_model(zp[ok], widths, heights)


# ---------------------------------------------------------------------------------------------------- main
def build_parser() -> argparse.ArgumentParser:
    """The command-line interface."""
    parser = argparse.ArgumentParser(prog="./vessel detect", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    _add_run_parser(sub)
    _add_recall_parser(sub)
    _add_rank_parser(sub)
    _add_export_labels_parser(sub)
    from vessel_tools.detect.image_cli import add_parsers as add_image_parsers
    from vessel_tools.detect.training.train_cli import add_parser as add_train_parser

    add_train_parser(sub)
    add_image_parsers(sub)
    return parser


def _add_run_parser(sub) -> None:
    run = sub.add_parser("run", help="detections of every frame of a dataset folder to CSV")
    run.add_argument("--data", help="dataset folder (default: $VESSEL_DATA or ../shared/aitas)")
    run.add_argument("--videos", help="e.g. 13-17 or 7,9 (default: all)")
    run.add_argument("--out", required=True, help="CSV to write (video,frame,x1,y1,x2,y2,score,class_id,p_target)")
    run.add_argument("--params", default=repo_file("config/aitas.yaml"),
                     help="parameter YAML: its detector: and camera: blocks (default: the shipped config/aitas.yaml; "
                          "'' for the node's defaults)")
    run.add_argument("--calib", default=repo_file("config/aitas_camera.yaml"),
                     help="calibration parameter YAML (default: the shipped config/aitas_camera.yaml; '' for the "
                          "params file's camera block, else the dataset's camera.json)")
    run.add_argument("--no-cue", action="store_true", help="leave out the params file's appearance_model (the raw "
                     "detector output a cue is fitted on: `./vessel appearance fit`)")
    run.add_argument("--quiet", action="store_true", help="no progress line")
    run.set_defaults(func=cmd_run)


def _add_recall_parser(sub) -> None:
    recall = sub.add_parser("recall", help="recall of the vessel of interest on the hand-labelled frames")
    recall.add_argument("--data")
    recall.add_argument("--videos", default="6-17")
    recall.add_argument("--detections", help="a CSV from 'run' (default: run the detector on the labelled frames)")
    recall.add_argument("--params", default=repo_file("config/aitas.yaml"),
                        help="parameter YAML (default as for run)")
    recall.add_argument("--calib", default=repo_file("config/aitas_camera.yaml"),
                        help="calibration parameter YAML (default as for run)")
    recall.add_argument("--score", type=float, help="score threshold (default: the detector's)")
    recall.add_argument("--thresholds", type=lambda s: [float(v) for v in s.split(",")],
                        help="comma-separated score thresholds to report (a sweep)")
    recall.add_argument("--out", help="also write the figures as JSON")
    recall.set_defaults(func=cmd_recall)


def _add_rank_parser(sub) -> None:
    rank = sub.add_parser("rank", help="how often the most likely box is the vessel, against its GPS (every frame "
                          "with the GPS in view, by range; no hand labels)")
    rank.add_argument("--data")
    rank.add_argument("--videos", default="6-17")
    rank.add_argument("--detections", required=True, help="a CSV from 'run'")
    rank.add_argument("--margin-px", type=float, default=GPS_MARGIN_PX,
                      help=f"a box is at the GPS point when the point lies within this many pixels of it "
                           f"(default {GPS_MARGIN_PX:g}: the dataset's point is good to about that)")
    rank.add_argument("--out", help="also write the figures as JSON")
    rank.set_defaults(func=cmd_rank)


def _add_export_labels_parser(sub) -> None:
    export = sub.add_parser("export-labels", help="YOLO training data from the vessel's GPS (no hand labels)")
    export.add_argument("--data")
    export.add_argument("--videos", default="7-12")
    export.add_argument("--val-videos", default="", help="videos for the val split (default: none, val = train)")
    export.add_argument("--out", required=True)
    export.add_argument("--params", help="parameter YAML with the camera: calibration (default: the dataset's)")
    export.add_argument("--box", choices=("fitted", "paper"), default="fitted",
                        help="box size from |z_p|: fitted to the hand boxes (tight), or the paper's loose formula")
    export.add_argument("--negatives", choices=("none", "out-of-view"), default="none",
                        help="out-of-view: also write frames where the vessel is out of view, with empty labels")
    export.add_argument("--max-gap-s", type=float, default=3.0, help="GPS fixes further apart are not interpolated")
    export.add_argument("--min-box-px", type=float, default=4.0, help="smaller boxes (after clipping) are skipped")
    export.add_argument("--class-id", type=int, default=0)
    export.add_argument("--class-name", default="boat")
    export.set_defaults(func=cmd_export_labels)


@command_line_tool
def main(argv: list[str] | None = None) -> int:
    """Entry point: exit status 0, or 2 with one ``error:`` line for bad input."""
    args = build_parser().parse_args(argv)
    args.command_line = list(sys.argv[1:] if argv is None else argv)  # what a model card records
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
