"""Appearance cue: how much a detection's image crop looks like the vessel of interest (logistic regression).

A generic (COCO) detector finds every boat with similar confidences, and the geometry of a box (size agreeing
with the fitted distance model, aspect, motion) does not tell the vessel of interest from other motor boats
moving about the harbour. Its colours do: the paper's trick of generating training boxes from the vessel's GPS
through the calibration gives labelled crops for free. On the training videos, detections whose centre is within
``POSITIVE_PX`` of the vessel's projected GPS position are positives, detections farther than ``NEGATIVE_PX``
negatives; the features are a colour description of the crop (``crop_features``: 8x4 hue-saturation histogram,
8-bin value histogram, mean and std of L*a*b*, 46 numbers), the model a class-balanced L2-regularised logistic
regression. Stored as a small ``.npz`` (mean, scale, weights: under 2 kB).

Used as the detection's confidence (``combine``: ``replace`` by the probability, or ``product`` with the detector
score, the default), so the trajectory score (``selection.confidence_percentile`` of the confidences times
log(path)) ranks the vessel of interest first; detections below ``min_probability`` are dropped. In the node
graph this has to run where the image is, in the detector node (the ROS messages carry no crop features): the
hypothesis score it publishes would be ``score * p`` (the tracker's ``min_score`` cannot express the
probability threshold once multiplied, so the detector node drops those boxes). ``pipeline --appearance
MODEL.npz`` does exactly this to the detections it reads.

    python -m vessel_track.appearance fit --data DIR --videos 7-12 --detections DET.csv --out config/x.npz
    python -m vessel_track.appearance score --data DIR --videos 13-17 --detections DET.csv --model X.npz \
        --out SCORED.csv [--combine product|replace] [--min-probability 0.3] [--leave-one-out 7-12]

``score --leave-one-out`` scores each listed video with a model fitted on the other listed videos (honest
scores on training data). ``--calib`` (default ``config/aitas_camera.yaml``) only matters for ``fit``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from vessel_calib.errors import DataError, VesselError
from vessel_detect.appearance_model import (
    DEFAULT_COMBINE,
    DEFAULT_MIN_PROBABILITY,
    FEATURE_SIZE,
    AppearanceModel,
    crop_features,
)

POSITIVE_PX = 20.0
NEGATIVE_PX = 60.0
COMBINE_MODES = ("replace", "product")


def fit_logistic(features: np.ndarray, labels: np.ndarray, l2: float = 10.0, iterations: int = 50,
                 source: str = "") -> AppearanceModel:
    """Class-balanced, L2-regularised logistic regression by Newton's method on standardised features."""
    X = np.asarray(features, dtype=float).reshape(-1, FEATURE_SIZE)
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
    return AppearanceModel(mean, scale, w[:-1], float(w[-1]), source)


def labelled_crops(dataset, camera, videos, frames) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (N, 46), labels (N,) 1/0/-1 unknown, video (N,)) of every detection of ``frames``.

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
        lat, lon, ok = track.interpolate(frame.stamp, max_gap_s=3.0) if len(track.stamps) else (0, 0, False)
        if ok:
            xs, ys, in_front = camera.gps_to_screen(lat, lon)
            if in_front and camera.in_image(xs, ys):
                centres = (frame.boxes[:, :2] + frame.boxes[:, 2:]) / 2.0
                distance = np.hypot(centres[:, 0] - xs, centres[:, 1] - ys)
                label = np.where(distance > NEGATIVE_PX, 0, -1)
                nearest = int(np.argmin(distance))
                if distance[nearest] <= POSITIVE_PX:
                    label[nearest] = 1
        features.append(crop_features(image, frame.boxes))
        labels.append(label)
        video_of.append(np.full(len(frame.boxes), frame.video))
    if not features:
        raise DataError(f"appearance: no detections in videos {videos}")
    return np.vstack(features), np.concatenate(labels), np.concatenate(video_of)


def rescore(frames, dataset, videos, model_for_video, combine: str = DEFAULT_COMBINE,
            min_probability: float = 0.0) -> list:
    """``frames`` (pipeline ``DetectionFrame``) with scores replaced by (or multiplied with) the appearance cue.

    ``model_for_video(video) -> AppearanceModel`` (one model, or one per video for leave-one-out); detections
    whose probability is below ``min_probability`` are dropped.
    """
    import cv2

    from vessel_track.pipeline import DetectionFrame

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
            p = model_for_video(frame.video).probability(image, frame.boxes)
            keep = p >= min_probability
            boxes, scores = boxes[keep], (p if combine == "replace" else frame.scores * p)[keep]
        out.append(DetectionFrame(frame.video, frame.frame, frame.stamp, boxes, np.asarray(scores, float)))
    return out


def write_detections_csv(path: Path, frames) -> None:
    """The detector CSV layout (``video,frame,x1,y1,x2,y2,score,class_id``; class_id 8 = COCO boat)."""
    from vessel_track.pipeline import _atomic_lines

    lines = ["video,frame,x1,y1,x2,y2,score,class_id"]
    for f in frames:
        for box, score in zip(f.boxes, f.scores, strict=True):
            lines.append(f"{f.video},{f.frame},{box[0]:.1f},{box[1]:.1f},{box[2]:.1f},{box[3]:.1f},{score:.4f},8")
    _atomic_lines(Path(path), lines)


def main(argv: list[str] | None = None) -> int:
    """Command line: ``fit`` a model, ``score`` a detections CSV with one."""
    from vessel_calib.dataset import parse_videos
    from vessel_track.pipeline import csv_detections, load_camera, open_dataset

    parser = argparse.ArgumentParser(prog="python -m vessel_track.appearance", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name in ("fit", "score"):
        p = sub.add_parser(name)
        p.add_argument("--data", type=Path, default=None, help="dataset folder (default ../shared/aitas)")
        p.add_argument("--videos", required=True, help="videos, e.g. 7-12")
        p.add_argument("--detections", type=Path, required=True, help="detector CSV")
        p.add_argument("--calib", type=Path, default=None, help="calibration YAML (default config/aitas_camera.yaml)")
        p.add_argument("--l2", type=float, default=10.0, help="L2 penalty of the logistic regression")
    sub.choices["fit"].add_argument("--out", type=Path, required=True, help="model .npz to write")
    score = sub.choices["score"]
    score.add_argument("--model", type=Path, default=None, help="model .npz (not with --leave-one-out)")
    score.add_argument("--leave-one-out", default=None, metavar="TRAIN_VIDEOS",
                       help="score each video with a model fitted on these videos minus that one")
    score.add_argument("--combine", choices=COMBINE_MODES, default=DEFAULT_COMBINE,
                       help="replace the detector score by the probability, or multiply them")
    score.add_argument("--min-probability", type=float, default=DEFAULT_MIN_PROBABILITY,
                       help="drop detections whose probability is below this")
    score.add_argument("--out", type=Path, required=True, help="rescored detections CSV to write")
    args = parser.parse_args(argv)
    try:
        dataset = open_dataset(args.data)
        videos = parse_videos(args.videos)
        camera, _ = load_camera(args.calib, dataset)
        if args.command == "fit":
            frames = csv_detections(args.detections, dataset, videos)
            features, labels, _ = labelled_crops(dataset, camera, videos, frames)
            model = fit_logistic(features, labels, args.l2,
                                 source=f"{args.detections.name} videos {args.videos}, GPS-labelled crops")
            model.save(args.out)
            print(f"fitted on {int((labels == 1).sum())} positive / {int((labels == 0).sum())} negative crops "
                  f"-> {args.out}")
            return 0
        frames = csv_detections(args.detections, dataset, videos)
        if args.leave_one_out:
            train = parse_videos(args.leave_one_out)
            train_frames = csv_detections(args.detections, dataset, train)
            features, labels, video_of = labelled_crops(dataset, camera, train, train_frames)
            models = {}

            def model_for_video(video):
                if video not in models:
                    keep = video_of != video
                    models[video] = fit_logistic(features[keep], labels[keep], args.l2)
                return models[video]
        else:
            if args.model is None:
                raise DataError("appearance score: give --model FILE.npz or --leave-one-out VIDEOS")
            single = AppearanceModel.load(args.model)

            def model_for_video(video):
                return single
        write_detections_csv(args.out, rescore(frames, dataset, videos, model_for_video, args.combine,
                                               args.min_probability))
        print(f"rescored {sum(len(f.boxes) for f in frames)} detections ({args.combine}) -> {args.out}")
    except VesselError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
