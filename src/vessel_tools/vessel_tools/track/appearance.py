"""Appearance cue: how much a detection's image crop looks like the vessel of interest (logistic regression).

A generic (COCO) detector finds every boat with similar confidences. What tells the vessel of interest from
ferries, moored sailboats and jet skis is how it looks, how large its box is for where it sits, and what is
around it; the paper's trick of generating training boxes from the vessel's GPS through the calibration gives
labelled crops for free. On the training videos, the detection nearest to the vessel's projected GPS position
(within ``POSITIVE_PX``) is a positive, detections farther than ``NEGATIVE_PX`` negatives; the features
(``vessel_detect.appearance_model.detection_features``) are a colour description of the crop (8x4
hue-saturation histogram, 8-bin value histogram, mean and std of L*a*b*, 46 numbers), and by default
(``--features colour_geometry_context``) also the box's size against the size the fuser's distance model expects
where the box sits (12 numbers, needs the calibration) and its surroundings (6 numbers: a wake); the model is a
class-balanced L2-regularised logistic regression. Stored as a small ``.npz`` (under 4 kB).

Measured on the detector's output for validation videos 13-17 (fitted on 7-12; the 112 frames where a detection
lies within 20 px of the vessel's projected GPS; ``rank``): the vessel is the highest-scored box in 2.7 % of the
frames by detector score, 61.6 % with the first, colour-only model (score x probability), 89.3 % with colour,
geometry and context, and 92.0 % in the detector node's output (nested boxes suppressed).

Used as the detection's confidence (``combine``: ``replace`` by the probability, the default, or ``product`` with
the detector score), so the trajectory score (``selection.confidence_percentile`` of the confidences times
log(path)) ranks the vessel of interest first; detections below ``min_probability`` are dropped. In the node
graph this has to run where the image is, in the detector node (the ROS messages carry no crop features), which
publishes the probability as the hypothesis score and drops the boxes below the threshold. ``pipeline
--appearance MODEL.npz`` does exactly this to the detections it reads.

    ./vessel appearance fit --data DIR --videos 7-12 --detections DET.csv --out config/x.npz \
        [--features colour|colour_geometry_context] [--params config/aitas.yaml (the fuser's distance_model)]
    ./vessel appearance score --data DIR --videos 13-17 --detections DET.csv --model X.npz \
        --out SCORED.csv [--combine replace|product] [--min-probability 0.5] [--leave-one-out 7-12]
    ./vessel appearance rank --videos 13-17 --detections CSV

``rank`` prints that share per video. ``score --leave-one-out`` scores each listed video with a model fitted on
the other listed videos (honest scores on training data). ``--calib`` (default ``config/aitas_camera.yaml``) is
the camera of the GPS labels and of the geometry features.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_common.paths import parse_videos
from vessel_detect.appearance_model import (
    COMBINE_MODES,
    DEFAULT_COMBINE,
    DEFAULT_FEATURE_SET,
    DEFAULT_MIN_PROBABILITY,
    DEFAULT_NESTED_OVERLAP,
    FEATURE_SETS,
    AppearanceModel,
    detection_features,
    score_with_cue,
)
from vessel_detect.detections_csv import CSV_COLUMNS, csv_row
from vessel_tools.track.distance_model_fit import pixels_from_vessel
from vessel_tools.track.offline_data import (
    PREDICTION_HEADER,
    DetectionFrame,
    atomic_lines,
    csv_detections,
    default_params_path,
    load_camera,
    open_dataset,
    prediction_line,
)
from vessel_track.fuser_settings import load_fuser_settings

POSITIVE_PX = 20.0
NEGATIVE_PX = 60.0


def fit_logistic(features: np.ndarray, labels: np.ndarray, l2: float = 10.0, iterations: int = 50,
                 source: str = "", feature_set: str = "colour", size_model=None) -> AppearanceModel:
    """Class-balanced, L2-regularised logistic regression by Newton's method on standardised features."""
    if feature_set not in FEATURE_SETS:
        raise DataError(f"appearance: unknown feature set {feature_set!r} (known: {', '.join(FEATURE_SETS)})")
    X = np.asarray(features, dtype=float).reshape(-1, FEATURE_SETS[feature_set])
    y = np.asarray(labels, dtype=float).reshape(-1)
    keep = np.all(np.isfinite(X), axis=1) & np.isin(y, (0.0, 1.0))
    X, y = X[keep], y[keep]
    if y.sum() < 5 or (1 - y).sum() < 5:
        raise DataError(f"appearance: need at least 5 positive and 5 negative crops, got {int(y.sum())} and "
                        f"{int((1 - y).sum())}")
    mean, scale = X.mean(0), X.std(0) + 1e-6
    Z = np.column_stack([(X - mean) / scale, np.ones(len(X))])
    sample_weight = np.where(y == 1, 0.5 / y.mean(), 0.5 / (1 - y.mean()))
    penalty = l2 * np.eye(Z.shape[1])
    penalty[-1, -1] = 0.0
    w = np.zeros(Z.shape[1])
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-np.clip(Z @ w, -50, 50)))
        gradient = Z.T @ (sample_weight * (p - y)) + penalty @ w
        hessian = (Z * (sample_weight * p * (1 - p))[:, None]).T @ Z + penalty + 1e-9 * np.eye(Z.shape[1])
        step = np.linalg.solve(hessian, gradient)
        w -= step
        if float(np.max(np.abs(step))) < 1e-8:
            break
    return AppearanceModel(mean, scale, w[:-1], float(w[-1]), source, feature_set, size_model)


def labelled_crops(dataset, camera, videos, frames, feature_set: str = "colour",
                   size_model=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (N, F), labels (N,) 1/0/-1 unknown, video (N,)) of every detection of ``frames``.

    Positive: the detection nearest to the vessel's projected GPS position, within ``POSITIVE_PX``; negative:
    farther than ``NEGATIVE_PX`` from it; unknown: in between, or no GPS (fixes more than 3 s apart) or the vessel
    outside the image.
    """
    import cv2

    track = dataset.gps_track()
    paths = {(f.video, f.frame): f.path for f in dataset.frames(videos)}
    features, labels, video_of = [], [], []
    for frame in frames:
        if len(frame.boxes) == 0:
            continue
        path = paths.get((frame.video, frame.frame))
        image = cv2.imread(str(path)) if path is not None else None
        if image is None:
            raise DataError(f"appearance: cannot read the image of video {frame.video} frame {frame.frame} "
                            f"({path})")
        label = np.full(len(frame.boxes), -1)
        found = pixels_from_vessel(track, camera, frame)
        if found is not None:
            distance = found[0]
            label = np.where(distance > NEGATIVE_PX, 0, -1)
            nearest = int(np.argmin(distance))
            if distance[nearest] <= POSITIVE_PX:
                label[nearest] = 1
        features.append(detection_features(feature_set, image, frame.boxes, frame.scores, camera, size_model))
        labels.append(label)
        video_of.append(np.full(len(frame.boxes), frame.video))
    if not features:
        raise DataError(f"appearance: no detections in videos {videos}")
    return np.vstack(features), np.concatenate(labels), np.concatenate(video_of)


def top_box_share(dataset, camera, frames, radius_px: float = POSITIVE_PX) -> dict[int, tuple[int, int]]:
    """Per video: (frames where the highest-scored box is the vessel, frames where one of the boxes is).

    A box is the vessel when its centre lies within ``radius_px`` of the vessel's GPS position (fixes at most
    3 s apart) projected through ``camera``; frames without such a box do not count. This is what the cue is
    for: the share says how often the vessel is the most likely box of a frame.
    """
    track = dataset.gps_track()
    out: dict[int, list[int]] = {}
    for frame in frames:
        found = pixels_from_vessel(track, camera, frame)
        if found is None:
            continue
        near = found[0] <= radius_px
        if not near.any():
            continue
        counts = out.setdefault(frame.video, [0, 0])
        counts[0] += int(near[int(np.argmax(frame.scores))])
        counts[1] += 1
    return {video: (first, total) for video, (first, total) in sorted(out.items())}


PER_FRAME_PICKS = ("gps", "score")


def per_frame_backprojection(dataset, camera, frames, radius_px: float = POSITIVE_PX,
                             anchor_offset: float = 0.0, pick: str = "gps", water_level=None,
                             water_level_max_hold_s: float = 0.0) -> list[str]:
    """``video,t_utc_s,lat,lon`` lines: one box per frame back-projected, a baseline without tracking.

    ``pick``: ``gps``, the box nearest the vessel's projected GPS (the right box picked by the truth; frames
    without a box within ``radius_px`` give no line), or ``score``, the box the detector scores highest (what a
    system without tracker and selection would publish). The box is read where the fuser reads it: the
    calibration's reference point plus ``anchor_offset``. What the tracker and fuser have to beat, as the
    per-frame back-projection of hand boxes is for hand boxes. With ``water_level`` (a ``WaterLevelTable``) each
    frame is read through the camera at its water level, as the fuser does (the end levels held for
    ``water_level_max_hold_s``, the calibration's level beyond).
    """
    if pick not in PER_FRAME_PICKS:
        raise DataError(f"appearance: pick must be one of {', '.join(PER_FRAME_PICKS)}, got {pick!r}")
    track = dataset.gps_track()
    lines = [PREDICTION_HEADER]
    for frame in frames:
        if pick == "score":
            if not len(frame.boxes):
                continue
            box = frame.boxes[int(np.argmax(frame.scores))]
        else:
            found = pixels_from_vessel(track, camera, frame)
            if found is None or found[0].min() > radius_px:
                continue
            box = frame.boxes[int(np.argmin(found[0]))]
        seen_by = camera
        level = math.nan if water_level is None else water_level.level_at(frame.stamp, water_level_max_hold_s)
        if math.isfinite(level):
            seen_by = camera.at_water_level(level)
        (x, y), = seen_by.box_reference_points(box, anchor_offset)
        lat, lon, valid = seen_by.screen_to_gps(x, y)
        if bool(np.all(valid)):
            lines.append(prediction_line(frame.video, frame.stamp, lat, lon))
    return lines


def rescore(frames, dataset, videos, model_for_video, combine: str = DEFAULT_COMBINE,
            min_probability: float = 0.0, camera=None, nested_overlap: float = 0.0) -> list:
    """``frames`` (pipeline ``DetectionFrame``) with scores replaced by (or multiplied with) the appearance cue.

    ``model_for_video(video) -> AppearanceModel`` (one model, or one per video for leave-one-out); detections
    whose probability is below ``min_probability`` are dropped, and with ``nested_overlap`` > 0 boxes nested in a
    likelier one: ``vessel_detect.appearance_model.score_with_cue``, as the detector node does. ``camera`` is
    needed by models with geometry features.
    """
    import cv2


    if combine not in COMBINE_MODES:
        raise DataError(f"appearance: combine must be one of {', '.join(COMBINE_MODES)}, got {combine!r}")
    paths = {(f.video, f.frame): f.path for f in dataset.frames(videos)}
    out = []
    for frame in frames:
        boxes, scores = frame.boxes, frame.scores
        if len(frame.boxes):
            image = cv2.imread(str(paths.get((frame.video, frame.frame))))
            if image is None:
                raise DataError(f"appearance: cannot read the image of video {frame.video} frame {frame.frame}")
            keep, scores = score_with_cue(model_for_video(frame.video), image, frame.boxes, frame.scores,
                                          min_probability, camera, combine=combine, nested_overlap=nested_overlap)
            boxes = boxes[keep]
        out.append(DetectionFrame(frame.video, frame.frame, frame.stamp, boxes, np.asarray(scores, float)))
    return out


def write_detections_csv(path: Path, frames) -> None:
    """The detector CSV layout (``video,frame,x1,y1,x2,y2,score,class_id``; class_id 8 = COCO boat)."""
    lines = [",".join(CSV_COLUMNS)]
    for f in frames:
        for box, score in zip(f.boxes, f.scores, strict=True):
            lines.append(",".join(csv_row(f.video, f.frame, box, score)))
    atomic_lines(Path(path), lines)


def build_parser() -> argparse.ArgumentParser:
    """``fit``, ``score`` and ``rank``, with their options."""
    parser = argparse.ArgumentParser(prog="./vessel appearance", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name in ("fit", "score"):
        p = sub.add_parser(name)
        p.add_argument("--data", type=Path, default=None, help="dataset folder (default ../shared/aitas)")
        p.add_argument("--videos", required=True, help="videos, e.g. 7-12")
        p.add_argument("--detections", type=Path, required=True, help="detector CSV")
        p.add_argument("--calib", type=Path, default=None, help="calibration YAML (default config/aitas_camera.yaml)")
        p.add_argument("--l2", type=float, default=10.0, help="L2 penalty of the logistic regression")
        p.add_argument("--features", choices=tuple(FEATURE_SETS), default=DEFAULT_FEATURE_SET,
                       help="feature set of the fitted model(s)")
        p.add_argument("--params", type=Path, default=None,
                       help="parameter YAML whose fuser distance_model the geometry features use (default "
                            "config/aitas.yaml)")
    sub.choices["fit"].add_argument("--out", type=Path, required=True, help="model .npz to write")
    score = sub.choices["score"]
    score.add_argument("--model", type=Path, default=None, help="model .npz (not with --leave-one-out)")
    score.add_argument("--leave-one-out", default=None, metavar="TRAIN_VIDEOS",
                       help="score each video with a model fitted on these videos minus that one")
    score.add_argument("--combine", choices=COMBINE_MODES, default=DEFAULT_COMBINE,
                       help="replace the detector score by the probability, or multiply them")
    score.add_argument("--min-probability", type=float, default=DEFAULT_MIN_PROBABILITY,
                       help="drop detections whose probability is below this")
    score.add_argument("--nested-overlap", type=float, default=DEFAULT_NESTED_OVERLAP,
                       help="drop boxes sharing more than this share of the smaller one's area with a likelier box "
                            "(0: off)")
    score.add_argument("--out", type=Path, required=True, help="rescored detections CSV to write")
    rank = sub.add_parser("rank", help="per video: how often the highest-scored box of a frame is the vessel")
    rank.add_argument("--data", type=Path, default=None, help="dataset folder (default ../shared/aitas)")
    rank.add_argument("--videos", required=True, help="videos, e.g. 13-17")
    rank.add_argument("--detections", type=Path, required=True, help="detector CSV (raw or rescored)")
    rank.add_argument("--calib", type=Path, default=None, help="calibration YAML (default config/aitas_camera.yaml)")
    rank.add_argument("--radius", type=float, default=POSITIVE_PX, help="px from the vessel's projected GPS")
    rank.add_argument("--per-frame-out", type=Path, default=None, metavar="PREDICTIONS.csv",
                      help="also write the per-frame back-projection of one box per frame (a baseline; score it "
                           "with ./vessel eval)")
    rank.add_argument("--pick", choices=PER_FRAME_PICKS, default="gps",
                      help="with --per-frame-out: the box nearest the vessel's GPS (gps, the truth picks it) or "
                           "the highest-scored box (score, what a per-frame system would publish)")
    rank.add_argument("--params", type=Path, default=None,
                      help="parameter YAML whose fuser fusion.anchor_offset the per-frame back-projection reads "
                           "boxes with (default config/aitas.yaml)")
    return parser


def _size_model(args) -> tuple[float, float, float, float]:
    """(a, b, c, d) of the fuser's distance model: what a fitted model's geometry features use."""
    fitted = load_fuser_settings(args.params if args.params is not None else default_params_path())
    return (fitted.distance_model.a, fitted.distance_model.b, fitted.distance_model.c, fitted.distance_model.d)


def _rank(args, dataset, videos, camera) -> int:
    """How often the highest-scored box of a frame is the vessel; optionally the per-frame back-projection."""
    frames = csv_detections(args.detections, dataset, videos)
    if args.per_frame_out is not None:
        settings = load_fuser_settings(args.params or default_params_path())
        water_level = settings.water_level.load() if math.isfinite(camera.water_level_m) else None
        lines = per_frame_backprojection(dataset, camera, frames, args.radius, settings.fusion.anchor_offset,
                                         args.pick, water_level, settings.water_level.max_hold_s)
        atomic_lines(args.per_frame_out, lines)
        print(f"wrote {len(lines) - 1} per-frame back-projections -> {args.per_frame_out}")
    shares = top_box_share(dataset, camera, frames, args.radius)
    if not shares:
        raise DataError(f"{args.detections}: no frame of videos {args.videos} has a box within "
                        f"{args.radius:g} px of the vessel's projected GPS")
    for video, (first, total) in shares.items():
        print(f"video {video:>3}: vessel first in {first:>3}/{total:<3} frames ({100 * first / total:.0f} %)")
    first, total = (sum(v[i] for v in shares.values()) for i in (0, 1))
    print(f"    all: vessel first in {first:>3}/{total:<3} frames ({100 * first / total:.1f} %)")
    return 0


def _fit(args, dataset, videos, camera) -> int:
    """Fit a model on GPS-labelled crops of ``videos`` and save it."""
    frames = csv_detections(args.detections, dataset, videos)
    sizes = _size_model(args)
    features, labels, _ = labelled_crops(dataset, camera, videos, frames, args.features, sizes)
    model = fit_logistic(features, labels, args.l2,
                         source=f"{args.detections.name} videos {args.videos}, GPS-labelled crops, "
                                f"{args.features}, l2 {args.l2:g}",
                         feature_set=args.features, size_model=sizes)
    model.save(args.out)
    print(f"fitted on {int((labels == 1).sum())} positive / {int((labels == 0).sum())} negative crops -> {args.out}")
    return 0


def _score(args, dataset, videos, camera) -> int:
    """Rescore a detections CSV with one model, or leave-one-video-out with models fitted on the others."""
    frames = csv_detections(args.detections, dataset, videos)
    if args.leave_one_out:
        train = parse_videos(args.leave_one_out)
        train_frames = csv_detections(args.detections, dataset, train)
        sizes = _size_model(args)
        features, labels, video_of = labelled_crops(dataset, camera, train, train_frames, args.features, sizes)
        models = {}

        def model_for_video(video):
            if video not in models:
                keep = video_of != video
                models[video] = fit_logistic(features[keep], labels[keep], args.l2,
                                             feature_set=args.features, size_model=sizes)
            return models[video]
    else:
        if args.model is None:
            raise DataError("appearance score: give --model FILE.npz or --leave-one-out VIDEOS")
        single = AppearanceModel.load(args.model)

        def model_for_video(video):
            return single
    write_detections_csv(args.out, rescore(frames, dataset, videos, model_for_video, args.combine,
                                           args.min_probability, camera, args.nested_overlap))
    print(f"rescored {sum(len(f.boxes) for f in frames)} detections ({args.combine}) -> {args.out}")
    return 0


@command_line_tool
def main(argv: list[str] | None = None) -> int:
    """Command line: ``fit`` a model, ``score`` a detections CSV with one, ``rank`` how often it comes first."""
    args = build_parser().parse_args(argv)
    dataset = open_dataset(args.data)
    videos = parse_videos(args.videos)
    camera, _ = load_camera(args.calib, dataset)
    return {"rank": _rank, "fit": _fit, "score": _score}[args.command](args, dataset, videos, camera)


if __name__ == "__main__":
    sys.exit(main())
