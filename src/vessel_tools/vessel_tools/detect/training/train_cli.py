"""``./vessel detect train``: fine-tune the detector on labels generated from the vessel's GPS.

1. The generic COCO detector (the ``coco`` preset: YOLOX-Nano tiled over the band) runs over the training
   frames, or its saved run is read (``--coco-detections``).
2. :mod:`vessel_tools.detect.training.labels` turns the GPS, the calibration and those boxes into two-class labels.
3. :mod:`vessel_tools.detect.training.trainer` fine-tunes, validates every few epochs, exports ONNX, checks it against
   PyTorch and writes the class names, the labels and a model card next to the model.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vessel_common.errors import DataError
from vessel_common.paths import repo_file, repo_root

if TYPE_CHECKING:
    from vessel_tools.detect.training.labels import FrameLabels, LabelSettings, SizeModel
    from vessel_tools.detect.training.settings import TrainSettings


def add_parser(sub) -> None:
    """Register ``train`` on the ``detect`` sub-command parser."""
    train = sub.add_parser("train", help="fine-tune the detector on labels generated from the vessel's GPS")
    _add_data_arguments(train)
    _add_recipe_arguments(train)
    train.set_defaults(func=cmd_train)


def _add_data_arguments(train: argparse.ArgumentParser) -> None:
    """The frames, calibration, seed boxes and start model ``train`` reads, and the model it writes."""
    train.add_argument("--data", help="dataset folder (default: $VESSEL_DATA or ../shared/aitas)")
    train.add_argument("--videos", default="7-12", help="training videos (default 7-12)")
    train.add_argument("--val-videos", default="",
                       help="videos whose frames score the model every --val-every epochs (default: the training "
                            "videos); their hand boxes when the dataset has them (scoring only), else GPS boxes")
    train.add_argument("--out", required=True, help="ONNX model to write, e.g. models/vessel_yolox_nano.onnx")
    train.add_argument("--params", default=repo_file("config/aitas.yaml"),
                       help="parameter YAML of the COCO preset run and the tide (default config/aitas.yaml)")
    train.add_argument("--calib", default=repo_file("config/aitas_camera.yaml"),
                       help="calibration YAML the GPS is projected through (default config/aitas_camera.yaml)")
    train.add_argument("--water-level", help="tide CSV (default: the params file's fuser water_level.file)")
    train.add_argument("--coco-params", default=repo_file("config/detector_coco.yaml"),
                       help="parameter YAML of the generic COCO detector whose boxes seed the labels "
                            "(default config/detector_coco.yaml)")
    train.add_argument("--coco-detections", help="a saved `detect run --params config/detector_coco.yaml` CSV of "
                       "these frames (default: run the COCO detector now)")
    train.add_argument("--init-model", help="start weights, ONNX (default: the shared COCO YOLOX-Nano)")
    train.add_argument("--webcams", default="",
                       help="also learn the vessel class from other cameras' hand-labelled images: a folder laid out "
                            "like Shore Livecams (images/{train,test}, YOLO labels/{train,test}, watercraft class 2), "
                            "e.g. ../shared/shorecams (default: none)")
    train.add_argument("--webcam-holdout", default="",
                       help="comma-separated webcam ids (file-name prefixes) left out of --webcams, to score on")
    train.add_argument("--webcam-repeats", type=int, default=1,
                       help="crops of each webcam image per epoch (default 1): their many boats per image are "
                            "learnt from more views")


def _add_recipe_arguments(train: argparse.ArgumentParser) -> None:
    """The optimisation, augmentation and export settings of ``train``, defaulting to ``TrainSettings``."""
    from vessel_tools.detect.training.settings import TrainSettings

    defaults = TrainSettings()
    train.add_argument("--epochs", type=int, default=defaults.epochs)
    train.add_argument("--batch-size", type=int, default=defaults.batch_size)
    train.add_argument("--lr", type=float, default=defaults.learning_rate)
    train.add_argument("--seed", type=int, default=defaults.seed)
    train.add_argument("--val-every", type=int, default=defaults.val_every)
    scale_range = ",".join(f"{v:g}" for v in defaults.augment.scale_range)
    train.add_argument("--scale-range", default=scale_range,
                       help="LO,HI: ordinary crops are resized by a factor drawn log-uniformly from this range (below "
                            f"1 the boats look smaller, as farther ones do; default {scale_range})")
    jitter = f"{defaults.augment.hue_deg:g},{defaults.augment.saturation:g},{defaults.augment.value:g}"
    train.add_argument("--colour-jitter", default=jitter,
                       help="HUE,SATURATION,VALUE: each crop's hue is shifted by up to HUE degrees and its saturation "
                            f"and brightness scaled by up to 1 +- SATURATION and VALUE (default {jitter}; 0 for none)")
    train.add_argument("--input-size", default=f"{defaults.input_hw[1]}x{defaults.input_hw[0]}",
                       help="exported network input WIDTHxHEIGHT, multiples of 32 (default 1280x352: the band)")
    train.add_argument("--crop-size", default=f"{defaults.augment.crop_wh[0]}x{defaults.augment.crop_wh[1]}",
                       help="training crop WIDTHxHEIGHT, multiples of 32")
    webcam_scales = ",".join(f"{v:g}" for v in defaults.webcam.scale_range)
    train.add_argument("--webcam-scale-range", default=webcam_scales,
                       help=f"LO,HI: webcam crops are resized by a factor drawn log-uniformly from this range (above "
                            f"1 enlarges their many small boats; default {webcam_scales})")


def _colour_jitter(text: str) -> dict[str, float]:
    """``--colour-jitter HUE,SAT,VALUE`` as ``AugmentSettings`` fields, or a clear error."""
    try:
        hue, saturation, value = (float(v) for v in text.split(","))
    except ValueError:
        raise DataError(f"--colour-jitter must be HUE,SATURATION,VALUE such as 6,0.35,0.35, got {text!r}") from None
    if not (0 <= hue <= 90 and 0 <= saturation < 1 and 0 <= value < 1):
        raise DataError(f"--colour-jitter {text}: the hue shift must be 0-90 degrees and the saturation and value "
                        "ranges at least 0 and below 1")
    return {"hue_deg": hue, "saturation": saturation, "value": value}


def _scale_range(text: str, option: str = "--scale-range") -> tuple[float, float]:
    try:
        low, high = (float(v) for v in text.split(","))
    except ValueError:
        raise DataError(f"{option} '{text}' is not LO,HI, e.g. 0.7,1.6") from None
    if not (math.isfinite(low) and math.isfinite(high) and 0 < low <= high):
        raise DataError(f"{option} {text}: give two positive factors, the lower first, e.g. 0.7,1.6")
    return low, high


def _size(text: str, what: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise DataError(f"{what} '{text}' is not WIDTHxHEIGHT, e.g. 1280x352") from None
    if width <= 0 or height <= 0 or width % 32 or height % 32:
        raise DataError(f"{what} {width}x{height}: both sides must be positive multiples of 32")
    return width, height


def _water_levels(args, params_path: str | None):
    from vessel_calib.water_level import load_water_level

    path = args.water_level
    if not path and params_path:
        from vessel_calib.params import read_params_yaml

        fuser = read_params_yaml(params_path).get("fuser") or {}
        path = ((fuser.get("water_level") or {}).get("file") if isinstance(fuser.get("water_level"), dict)
                else fuser.get("water_level.file"))
    return load_water_level(path) if path else None


def coco_detections(args, dataset, frames, camera) -> dict:
    """The COCO preset's boxes of ``frames``: read from ``--coco-detections`` or computed now (and saved)."""
    from vessel_detect.detections_csv import read_detections_csv

    if args.coco_detections:
        return read_detections_csv(Path(args.coco_detections))
    from vessel_detect.detector_params import build_detector, load_params_file
    from vessel_tools.detect.dataset_detection import detect_frames, detections_csv_text

    values, _ = load_params_file(args.coco_params)
    values["appearance_model"] = ""
    detector = build_detector(values, camera)
    print(f"running the COCO detector over {len(frames)} frames for the labels", file=sys.stderr)
    rows = [(r.video, r.frame, d) for r, d in detect_frames(detector, frames)]
    saved = Path(args.out).with_suffix(".coco.csv")
    saved.parent.mkdir(parents=True, exist_ok=True)
    saved.write_text(detections_csv_text(rows))
    print(f"wrote {saved} (pass it as --coco-detections to skip this step)", file=sys.stderr)
    return {(v, f): (d.boxes_xyxy, d.scores) for v, f, d in rows}


def recorded_command(args: argparse.Namespace) -> str:
    """The ``./vessel detect train ...`` line a model card records: the arguments ``detect_cli.main`` was given."""
    return "./vessel detect " + " ".join(getattr(args, "command_line", None) or sys.argv[1:])


@dataclass
class _TrainingData:
    """What ``train`` learns from: the frames, their labels and images, and the validation boxes."""

    dataset: object  # vessel_tools.calib.dataset.Dataset
    camera: object  # vessel_calib.camera_model.CameraModel
    init_model: Path
    labels: list[FrameLabels]  # every frame's
    usable: list[FrameLabels]  # the frames trained on: valid GPS and a readable image
    images: dict  # (video, frame) -> BGR image, training and validation frames
    counts: dict[str, int]
    size_model: SizeModel
    label_settings: LabelSettings
    references: dict  # (video, frame) -> the vessel's boxes the validation scores against
    reference_name: str


def cmd_train(args: argparse.Namespace) -> int:
    """Generate labels, train, export, and describe the model."""
    from vessel_tools.detect.training.trainer import train

    out = Path(args.out)
    if out.suffix != ".onnx":
        raise DataError(f"--out {out}: the model is written as ONNX, give a path ending in .onnx")
    settings = _train_settings(args)
    data = _training_data(args)
    model, result = train(data.init_model, data.usable, data.images, data.camera, settings, data.references,
                          data.reference_name, log=lambda m: print(m, file=sys.stderr, flush=True))
    _write_model(args, out, model, result, settings, data)
    return 0


def _train_settings(args: argparse.Namespace) -> TrainSettings:
    """The ``TrainSettings`` of the command line, or a ``DataError`` naming the option that is out of range."""
    from vessel_tools.detect.training.augment import AugmentSettings
    from vessel_tools.detect.training.settings import TrainSettings
    from vessel_tools.detect.training.webcams import WebcamSettings

    input_w, input_h = _size(args.input_size, "--input-size")
    crop = _size(args.crop_size, "--crop-size")
    scale_range = _scale_range(args.scale_range)
    settings = TrainSettings(epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr, seed=args.seed,
                             val_every=max(1, args.val_every), input_hw=(input_h, input_w),
                             augment=AugmentSettings(crop_wh=crop, scale_range=scale_range,
                                                     **_colour_jitter(args.colour_jitter)),
                             webcam=WebcamSettings(scale_range=_scale_range(args.webcam_scale_range,
                                                                               "--webcam-scale-range")))
    if settings.epochs < 1 or settings.batch_size < 1 or not settings.learning_rate > 0:
        raise DataError("--epochs and --batch-size must be at least 1 and --lr positive")
    if args.webcam_repeats < 1:
        raise DataError(f"--webcam-repeats {args.webcam_repeats}: each webcam image is cropped at least once an epoch")
    return settings


def _training_data(args: argparse.Namespace) -> _TrainingData:
    """Open the dataset and the calibration, generate the labels, read the frames and the validation boxes."""
    from vessel_detect.detector_params import load_params_file
    from vessel_tools.detect.dataset_detection import camera_for, open_dataset, parse_video_spec
    from vessel_tools.detect.training.labels import LabelSettings, generate_labels
    from vessel_tools.detect.training.trainer import read_images

    dataset = open_dataset(args.data)
    videos = parse_video_spec(args.videos)
    val_videos = parse_video_spec(args.val_videos) if args.val_videos else videos
    _, params_camera = load_params_file(args.params)
    camera = camera_for(dataset, params_camera, args.calib)
    if camera is None:
        raise DataError("no calibration: pass --calib FILE.yaml (labels are the GPS projected through it)")
    frames = dataset.frames(videos)
    if not frames:
        raise DataError(f"no frames for videos {args.videos} in {dataset.path / 'frames.csv'}")
    init_model = _init_model(args)
    water = _water_levels(args, args.params)
    detections = coco_detections(args, dataset, frames, camera)
    label_settings = LabelSettings()
    labels, size_model = generate_labels(dataset, camera, frames, detections, label_settings, water)
    usable = [lab for lab in labels if lab.status != "gps_invalid"]
    val_only = [f for f in dataset.frames(val_videos) if f.video not in set(videos)] if val_videos and videos else []
    images = read_images(frames + val_only, log=lambda m: print(m, file=sys.stderr))
    usable = [lab for lab in usable if (lab.video, lab.frame) in images]
    counts = _label_counts(labels)
    _print_labels(labels, usable, counts, size_model)
    usable += _webcam_labels(args, images)
    references, reference_name = _val_references(dataset, val_videos, labels, images)
    return _TrainingData(dataset, camera, init_model, labels, usable, images, counts, size_model, label_settings,
                         references, reference_name)


def _webcam_labels(args: argparse.Namespace, images: dict) -> list[FrameLabels]:
    """The ``--webcams`` images not held out, as ``vessel`` labels; their images are added to ``images``."""
    if not args.webcams:
        return []
    from vessel_tools.detect.training.webcams import load_webcams

    held_out = {v.strip() for v in args.webcam_holdout.split(",") if v.strip()}
    labels, webcam_images, counts = load_webcams(args.webcams, held_out, log=lambda m: print(m, file=sys.stderr))
    images.update(webcam_images)
    args.webcam_counts = counts
    print(f"webcams: {len(labels)} images, {sum(len(lab.boxes) for lab in labels)} vessel boxes "
          f"({', '.join(f'{k} {v}' for k, v in sorted(counts.items()))}), each cropped {args.webcam_repeats} "
          f"time(s) an epoch; held out: {', '.join(sorted(held_out))}", file=sys.stderr)
    return labels * args.webcam_repeats


def _init_model(args: argparse.Namespace) -> Path:
    """The start weights: ``--init-model`` or the shared COCO YOLOX-Nano, which must exist."""
    from vessel_detect.model_store import ModelSpec, resolve_model

    init_model = Path(args.init_model) if args.init_model else resolve_model(ModelSpec("", "", ""),
                                                                             allow_download=False)
    if not Path(init_model).is_file():
        raise DataError(f"start model {init_model} not found: pass --init-model yolox_nano.onnx (the COCO YOLOX-Nano)")
    return init_model


def _label_counts(labels: list[FrameLabels]) -> dict[str, int]:
    """Frames per ``status/target_source``, e.g. ``labelled/coco``."""
    counts = {}
    for lab in labels:
        key = f"{lab.status}{'/' + lab.target_source if lab.target_source else ''}"
        counts[key] = counts.get(key, 0) + 1
    return counts


def _print_labels(labels: list[FrameLabels], usable: list[FrameLabels], counts: dict[str, int],
                  size_model: SizeModel) -> None:
    """One line on stderr: the frames used, their boxes and the size model."""
    print(f"labels: {len(usable)} frames of {len(labels)} ({', '.join(f'{k} {v}' for k, v in sorted(counts.items()))})"
          f"; {sum(int((lab.classes == 1).sum()) for lab in usable)} other vessels, "
          f"{sum(len(lab.ignore) for lab in usable)} ignore regions; size model w = {size_model.width[0]:.0f}/|z_p| "
          f"+ {size_model.width[1]:.1f}, h = {size_model.height[0]:.0f}/|z_p| + {size_model.height[1]:.1f} "
          f"({size_model.n_points} COCO boxes at the GPS)", file=sys.stderr)


def _write_model(args: argparse.Namespace, out: Path, model, result, settings: TrainSettings,
                 data: _TrainingData) -> None:
    """Export ``out`` and write its class names, labels, summary (``.json``) and model card (``.md``)."""
    from vessel_tools.detect.training.augment import band_input
    from vessel_tools.detect.training.model_card import model_card
    from vessel_tools.detect.training.trainer import labels_csv, save_model

    out.parent.mkdir(parents=True, exist_ok=True)
    probe_key = sorted(data.images, key=lambda k: (k[0] < 0, k))[0]  # a frame of the camera, not a webcam
    probe = band_input(data.images[probe_key], data.camera, settings.input_hw, settings.band_margin_px)
    result.onnx_max_abs_diff = save_model(model, out, settings, probe)
    out.with_suffix(".labels.csv").write_text(labels_csv(data.labels))
    summary = _summary(args, result, settings, data)
    out.with_suffix(".json").write_text(json.dumps(summary, indent=2) + "\n")
    out.with_suffix(".md").write_text(model_card(out, summary))
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB; ONNX matches PyTorch to {result.onnx_max_abs_diff:.1e}), "
          f"{out.with_suffix('.names').name}, {out.with_suffix('.labels.csv').name}, {out.with_suffix('.json').name}, "
          f"{out.with_suffix('.md').name} in {result.seconds / 60:.1f} min", file=sys.stderr)


def _summary(args: argparse.Namespace, result, settings: TrainSettings, data: _TrainingData) -> dict:
    """The training run as the ``.json`` next to the model records it (and the model card reads it)."""
    size_model = data.size_model
    return {
        "created_utc": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": recorded_command(args),
        "data": str(data.dataset.path), "videos": args.videos, "val_videos": args.val_videos or args.videos,
        "calibration": _relative(args.calib), "init_model": str(data.init_model), "settings": _jsonable(settings),
        "label_settings": _jsonable(data.label_settings), "label_counts": data.counts,
        "size_model": {"width": size_model.width, "height": size_model.height, "n_points": size_model.n_points},
        "webcams": {"folder": args.webcams, "held_out": args.webcam_holdout, "repeats": args.webcam_repeats,
                    "images": getattr(args, "webcam_counts", {})} if args.webcams else None,
        "history": result.history, "seconds": result.seconds, "onnx_max_abs_diff": result.onnx_max_abs_diff,
        "validation": None if result.validation is None else {
            "reference": data.reference_name, "frames": result.validation.frames,
            "recall": result.validation.frame_recall, "top1": result.validation.top_rate},
    }


def _relative(path: str | None) -> str | None:
    """``path`` relative to the repository when inside it (the model card names files a clone has)."""
    if not path:
        return path
    try:
        return str(Path(path).resolve().relative_to(repo_root()))
    except ValueError:
        return path


def _jsonable(value):
    from dataclasses import asdict

    return json.loads(json.dumps(asdict(value)))


def _val_references(dataset, val_videos, labels, images) -> tuple[dict, str]:
    """Boxes of the vessel per validation frame: hand boxes where the dataset has them, else the GPS labels."""
    hand: dict = {}
    try:
        for label in dataset.labels(val_videos, primary_only=True):
            key = (label.video, label.frame)
            if key in images:
                hand.setdefault(key, []).append([label.x1, label.y1, label.x2, label.y2])
    except DataError:
        hand = {}
    if hand:
        return {k: np.asarray(v, float) for k, v in hand.items()}, "hand boxes (scoring only)"
    wanted = set(val_videos or [])
    generated = {(lab.video, lab.frame): lab.boxes[lab.classes == 0] for lab in labels
                 if lab.status == "labelled" and (not wanted or lab.video in wanted)
                 and (lab.video, lab.frame) in images}
    return generated, "GPS-generated boxes"
