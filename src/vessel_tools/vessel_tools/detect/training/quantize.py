"""``./vessel detect quantize``: int8 static quantization of a trained model (onnxruntime.quantization).

The calibration inputs are the band crops of training frames exactly as the detector's ``band`` mode feeds the
network, so the activation ranges are those the model meets at run time. Quantization is kept only where the
recall holds: compare the two with ``./vessel detect recall`` and ``./vessel bench detector``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from vessel_calib.params import atomic_write_text
from vessel_common.errors import DataError, ModelError
from vessel_common.paths import repo_file
from vessel_tools.detect.training.augment import band_input


def quantize_model(model: Path, out: Path, tensors: list[np.ndarray]) -> None:
    """Write ``out``, the int8 (QDQ, per-channel weights) version of ``model`` calibrated on ``tensors``."""
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    if not tensors:
        raise DataError("no calibration frames for the quantization")

    class Reader(CalibrationDataReader):
        def __init__(self):
            self._items = iter({"images": t.astype(np.float32)} for t in tensors)

        def get_next(self):
            return next(self._items, None)

    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise DataError(f"cannot create the folder of {out}: {error.strerror or error}") from None
    prepared = out.with_name(out.stem + ".prep.onnx")
    partial = out.with_name(out.stem + ".partial.onnx")  # an earlier model at ``out`` stays until this one is whole
    try:
        quant_pre_process(str(model), str(prepared), skip_symbolic_shape=True)
        quantize_static(str(prepared), str(partial), Reader(), quant_format=QuantFormat.QDQ, per_channel=True,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8)
        os.replace(partial, out)
    except Exception as error:  # onnxruntime.quantization raises untyped errors
        raise ModelError(f"quantizing {model} failed: {str(error)[:300]}") from None
    finally:
        prepared.unlink(missing_ok=True)
        partial.unlink(missing_ok=True)
    names = model.with_suffix(".names")
    if names.is_file():
        atomic_write_text(out.with_suffix(".names"), names.read_text())


def add_parser(sub) -> None:
    """Register ``quantize`` on the ``detect`` sub-command parser."""
    parser = sub.add_parser("quantize", help="int8 static quantization of a trained model")
    parser.add_argument("--model", required=True, help="the float ONNX model")
    parser.add_argument("--out", required=True, help="the int8 ONNX model to write")
    parser.add_argument("--data", help="dataset folder (default: $VESSEL_DATA or ../shared/aitas)")
    parser.add_argument("--videos", default="7-12", help="calibration frames: training videos only (default 7-12)")
    parser.add_argument("--calib", default=None, help="calibration YAML (default config/aitas_camera.yaml)")
    parser.add_argument("--frames", type=int, default=64, help="calibration frames (spread over the videos)")
    parser.add_argument("--band-margin-px", type=float, default=40.0,
                        help="the detector's band_margin_px the model runs with (default 40)")
    parser.set_defaults(func=cmd_quantize)


def cmd_quantize(args: argparse.Namespace) -> int:
    """Quantize and report the size."""
    import cv2

    from vessel_tools.detect.dataset_detection import open_dataset, parse_video_spec
    from vessel_detect.detector import OnnxModel

    model, out = Path(args.model), Path(args.out)
    onnx = OnnxModel(model)
    from vessel_calib.params import load_camera_yaml

    calib = args.calib or repo_file("config/aitas_camera.yaml")
    camera = load_camera_yaml(calib) if calib else None
    dataset = open_dataset(args.data)
    frames = dataset.frames(parse_video_spec(args.videos))
    step = max(1, len(frames) // max(1, args.frames))
    images = [im for im in (cv2.imread(str(f.path)) for f in frames[::step][: args.frames]) if im is not None]
    quantize_model(model, out, [band_input(image, camera, onnx.input_hw, args.band_margin_px) for image in images])
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB from {model.stat().st_size / 1e6:.1f} MB), calibrated on "
          f"{len(images)} frames of videos {args.videos}", file=sys.stderr)
    return 0
