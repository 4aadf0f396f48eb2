"""Fine-tune YOLOX on GPS-generated labels, validate, export to ONNX and write the model card.

The run is deterministic for a seed: one NumPy generator draws every crop and transform, PyTorch is seeded and
runs on the CPU with a fixed thread count.
"""

from __future__ import annotations

import csv
import io
import math
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from vessel_common.errors import DataError, ModelError
from vessel_detect.decoders import OutputLayout
from vessel_detect.detector import DetectorConfig, VesselDetector, horizon_band_top
from vessel_tools.detect.recall import RecallResult, recall_at
from vessel_tools.detect.training.augment import band_top_px, random_sample
from vessel_tools.detect.training.labels import CLASS_NAMES, FrameLabels
from vessel_tools.detect.training.loss import yolox_loss
from vessel_tools.detect.training.model import STRIDES, ExportHead, TrainableYolox, export_onnx
from vessel_tools.detect.training.settings import TrainSettings
from vessel_tools.detect.training.webcams import WEBCAM_SOURCE, webcam_sample


class TorchDetectorModel:
    """The model under training, with the interface of ``detector.OnnxModel`` that ``VesselDetector`` uses."""

    def __init__(self, model: TrainableYolox, input_hw: tuple[int, int], path: str = "training"):
        self.model = model
        self.head = ExportHead(model)
        self.input_hw = tuple(input_hw)
        self.layout = OutputLayout.YOLOX
        self.strides = STRIDES
        self.class_names = list(model.class_names)
        self.num_classes = len(self.class_names)
        self.path = Path(path)

    def run(self, tensor: np.ndarray) -> np.ndarray:
        """One ``(1, 3, H, W)`` input -> the ONNX-layout output."""
        with torch.no_grad():
            return self.head(torch.from_numpy(np.ascontiguousarray(tensor))).numpy()


def band_detector(model, camera, score: float, input_hw) -> VesselDetector:
    """The trained model's detector set-up: the band below the horizon in one network run, both classes."""
    config = DetectorConfig(score_threshold=score, classes=CLASS_NAMES, mode="band", target_class=CLASS_NAMES[0],
                            class_agnostic_nms=True, nms_iou=0.5)
    top = horizon_band_top(camera) if camera is not None else None
    return VesselDetector(model, config, top, camera.image_size if camera is not None else (1280, 720))


def validate(detector: VesselDetector, images: dict, references: dict[tuple[int, int], np.ndarray]) -> RecallResult:
    """``detect recall``'s figures of ``detector`` on the frames of ``references`` (the vessel's boxes per frame)."""
    detections = {}
    for key in references:
        if key in images:
            dets = detector.detect(images[key])
            detections[key] = (dets.boxes_xyxy, dets.target_confidences())
    return recall_at({k: np.asarray(v, float).reshape(-1, 4) for k, v in references.items() if k in images},
                     detections, 0.0)


def _targets(samples) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    return [(torch.from_numpy(s.boxes).float(), torch.from_numpy(s.classes).long(),
             torch.from_numpy(s.ignore).float()) for s in samples]


def _sample(image: np.ndarray, lab: FrameLabels, band_top: float, rng: np.random.Generator,
            settings: TrainSettings):
    """A webcam image is cropped anywhere (its horizon is unknown), a frame of the camera along its band."""
    if lab.target_source == WEBCAM_SOURCE:
        return webcam_sample(image, lab, rng, settings.augment, settings.webcam)
    return random_sample(image, lab, band_top, rng, settings.augment)


def _lr_at(step: int, steps_per_epoch: int, settings: TrainSettings) -> float:
    warmup = max(1, int(settings.warmup_epochs * steps_per_epoch))
    total = max(1, settings.epochs * steps_per_epoch)
    if step < warmup:
        return settings.learning_rate * (step + 1) / warmup
    progress = (step - warmup) / max(1, total - warmup)
    return settings.learning_rate * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * progress)))


@dataclass
class TrainResult:
    """What a run produced: per-epoch history and the final validation."""

    history: list[dict]
    validation: RecallResult | None
    seconds: float
    onnx_max_abs_diff: float = math.nan


def train(init_model: Path, labels: list[FrameLabels], images: dict, camera, settings: TrainSettings,
          val_references: dict | None = None, val_reference_name: str = "", log=print) -> tuple[TrainableYolox,
                                                                                                 TrainResult]:
    """Fine-tune from ``init_model`` on ``labels`` (frames without usable labels must be filtered out)."""
    if not labels:
        raise DataError("no training frames with labels: check the videos, the GPS and the calibration")
    torch.manual_seed(settings.seed)
    torch.set_num_threads(max(1, settings.threads))
    rng = np.random.default_rng(settings.seed)
    model = TrainableYolox(init_model, CLASS_NAMES)
    optimiser = torch.optim.AdamW(model.parameters(), lr=settings.learning_rate, weight_decay=settings.weight_decay)
    band_top = band_top_px(camera, settings.band_margin_px)
    steps_per_epoch = max(1, math.ceil(len(labels) / settings.batch_size))
    started = time.monotonic()
    history = []
    validation = None
    step = 0
    for epoch in range(1, settings.epochs + 1):
        model.train()
        order = rng.permutation(len(labels))
        sums = np.zeros(4)
        fg = 0
        for first in range(0, len(order), settings.batch_size):
            batch = [labels[i] for i in order[first : first + settings.batch_size]]
            samples = [_sample(images[(lab.video, lab.frame)], lab, band_top, rng, settings) for lab in batch]
            for group in optimiser.param_groups:
                group["lr"] = _lr_at(step, steps_per_epoch, settings)
            levels = model(torch.from_numpy(np.stack([s.image for s in samples])))
            parts = yolox_loss(levels, _targets(samples))
            if not torch.isfinite(parts.total):
                raise ModelError(f"training diverged at epoch {epoch} (loss {float(parts.total)}): lower --lr")
            optimiser.zero_grad(set_to_none=True)
            parts.total.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
            optimiser.step()
            step += 1
            sums += [float(parts.total), parts.box, parts.objectness, parts.classes]
            fg += parts.foreground
        mean = sums / steps_per_epoch
        entry = {"epoch": epoch, "loss": mean[0], "box": mean[1], "objectness": mean[2], "classes": mean[3],
                 "foreground_per_image": fg / len(labels), "seconds": time.monotonic() - started}
        line = (f"epoch {epoch:3d}/{settings.epochs}  loss {mean[0]:.3f} (box {mean[1]:.3f}, obj {mean[2]:.3f}, "
                f"cls {mean[3]:.3f})  {entry['seconds']:.0f} s")
        if val_references and (epoch % settings.val_every == 0 or epoch == settings.epochs):
            model.eval()
            detector = band_detector(TorchDetectorModel(model, settings.input_hw), camera, settings.val_score,
                                     settings.input_hw)
            validation = validate(detector, images, val_references)
            entry.update(val_recall=validation.frame_recall, val_top1=validation.top_rate, val_frames=validation.frames)
            line += (f"  val recall {100 * validation.frame_recall:.1f} %, likeliest box is the vessel "
                     f"{100 * validation.top_rate:.1f} % ({validation.frames} frames, {val_reference_name})")
        history.append(entry)
        log(line)
    model.eval()
    return model, TrainResult(history, validation, time.monotonic() - started)


def onnx_parity(model: TrainableYolox, onnx_path: Path, sample: np.ndarray) -> float:
    """Largest absolute difference between the exported ONNX model's output and PyTorch's on ``sample``."""
    import onnxruntime as ort

    session = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    ours = session.run(None, {session.get_inputs()[0].name: sample.astype(np.float32)})[0]
    with torch.no_grad():
        theirs = ExportHead(model.eval())(torch.from_numpy(sample.astype(np.float32))).numpy()
    return float(np.max(np.abs(ours - theirs)))


def save_model(model: TrainableYolox, out: Path, settings: TrainSettings, probe: np.ndarray,
               tolerance: float = 1e-3) -> float:
    """Export ``out`` (ONNX) and ``out.names`` (class names); check ONNX against PyTorch on ``probe``."""
    partial = out.with_name(out.name + ".partial")
    export_onnx(model, partial, settings.input_hw)
    diff = onnx_parity(model, partial, probe)
    if not diff <= tolerance:
        partial.unlink(missing_ok=True)
        raise ModelError(f"the exported ONNX differs from the PyTorch model by {diff:.2g} (> {tolerance}): not written")
    partial.replace(out)
    out.with_suffix(".names").write_text("".join(f"{name}\n" for name in model.class_names))
    return diff


def labels_csv(labels: list[FrameLabels]) -> str:
    """Every generated box: ``video,frame,status,source,kind,class_id,x1,y1,x2,y2,abs_zp``."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["video", "frame", "status", "target_source", "kind", "class_id", "x1", "y1", "x2", "y2",
                     "abs_zp"])
    for lab in labels:
        rows = [("box", int(c), b) for b, c in zip(lab.boxes, lab.classes, strict=True)]
        rows += [("ignore", -1, b) for b in lab.ignore]
        if not rows:
            writer.writerow([lab.video, lab.frame, lab.status, lab.target_source, "", "", "", "", "", "",
                             f"{lab.abs_zp:.3f}" if np.isfinite(lab.abs_zp) else ""])
        for kind, cls, box in rows:
            writer.writerow([lab.video, lab.frame, lab.status, lab.target_source, kind, cls,
                             *(f"{v:.1f}" for v in box), f"{lab.abs_zp:.3f}" if np.isfinite(lab.abs_zp) else ""])
    return buffer.getvalue()


def read_images(frames, log=print) -> dict:
    """(video, frame) -> BGR image of every readable frame; unreadable ones are reported and left out."""
    images = {}
    for record in frames:
        image = cv2.imread(str(record.path), cv2.IMREAD_COLOR)
        if image is None or not image.size:
            log(f"warning: cannot read frame {record.path}; left out")
            continue
        images[(record.video, record.frame)] = image
    return images
