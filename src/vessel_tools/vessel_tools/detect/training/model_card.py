"""The model card written next to a trained model: data, label generation, command, seed and figures."""

from __future__ import annotations

from pathlib import Path

from vessel_tools.detect.training.labels import LabelSettings


def model_card(model_path: Path, summary: dict) -> str:
    """Markdown describing the model from the training run's ``summary`` (the ``.json`` next to it)."""
    lines = [
        f"# {model_path.name}",
        "",
        "YOLOX-Nano fine-tuned to find vessels on the water band of a fixed camera, with two classes:",
        "`vessel_of_interest` (the boat that carried the GPS logger) and `vessel` (every other boat).",
        "",
        *_interface(model_path, summary.get("settings") or {}),
        "",
        *_data_and_labels(model_path, summary),
        "",
        *_training(summary),
        "",
        *_figures(summary),
        "",
        f"Created {summary.get('created_utc')}.",
        "",
    ]
    return "\n".join(lines)


def _interface(model_path: Path, settings: dict) -> list[str]:
    return [
        "## Interface",
        "- input `images`, float32 `[1, 3, height, width]`, usually "
        f"`[1, 3, {settings.get('input_hw', ['?', '?'])[0]}, {settings.get('input_hw', ['?', '?'])[1]}]` "
        "(metadata `input_size`), BGR 0-255, no normalisation: the band "
        "below the horizon (the detector's `band` mode) letterboxed at the top-left, padding 114; the height and "
        "width are free (any multiple of 32 runs);",
        "- output `output`, `[1, anchors, 7]`: YOLOX raw layout (grid-relative x, y, log w, log h; sigmoid "
        "objectness; sigmoid class scores), strides 8, 16, 32;",
        f"- class names in `{model_path.with_suffix('.names').name}`; score = objectness x class score; "
        "`p_target` = objectness x the `vessel_of_interest` score.",
    ]


def _data_and_labels(model_path: Path, summary: dict) -> list[str]:
    size = summary.get("size_model") or {}
    max_gps_gap_s = (summary.get("label_settings") or {}).get("max_gps_gap_s", LabelSettings().max_gps_gap_s)
    counts = ", ".join(f"{k} {v}" for k, v in sorted((summary.get("label_counts") or {}).items()))
    return [
        "## Data and labels (no hand labels)",
        f"- frames: `{summary.get('data')}`, videos {summary.get('videos')}; calibration "
        f"`{summary.get('calibration')}`.",
        "- the vessel's GPS at each frame's stamp, projected through the calibration (at the frame's tide), gives "
        "the screen point of its box; the box is the generic COCO detector's box at that point when one agrees "
        "with the size model, else the size model's box;",
        f"- size model fitted to the COCO boxes at the GPS: w = {size.get('width', [0, 0])[0]:.0f}/|z_p| + "
        f"{size.get('width', [0, 0])[1]:.1f}, h = {size.get('height', [0, 0])[0]:.0f}/|z_p| + "
        f"{size.get('height', [0, 0])[1]:.1f} px ({size.get('n_points')} boxes);",
        "- every other COCO box scoring 0.3 or more is a `vessel`; weaker ones are ignore regions; frames between "
        f"GPS fixes more than {max_gps_gap_s:g} s apart are left out;",
        f"- frames: {counts}. All generated boxes: `{model_path.with_suffix('.labels.csv').name}`.",
        *_webcams(summary.get("webcams")),
    ]


def _webcams(webcams: dict | None) -> list[str]:
    """The other cameras' hand-labelled images the ``vessel`` class also learnt from, when there were any."""
    if not webcams:
        return []
    images = ", ".join(f"{k} {v}" for k, v in sorted((webcams.get("images") or {}).items()))
    return [
        f"- other cameras (hand boxes, `vessel` only): `{webcams.get('folder')}`, train and test splits of the "
        f"webcams {images} (images each), each image cropped {webcams.get('repeats', 1)} time(s) an epoch "
        f"(`--webcam-repeats`); held out: {webcams.get('held_out') or 'none'}. Shore Livecams: D. Ahlers, "
        "P. Bhattacharya, P. Nowak, U. Zölzer, \"Shore Livecams: A Maritime Dataset for Deep Learning based Object "
        "Detection\", SITIS 2023.",
    ]


def _training(summary: dict) -> list[str]:
    history = summary.get("history") or []
    last = history[-1] if history else {}
    settings = summary.get("settings") or {}
    augment = settings.get("augment", {})
    return [
        "## Training",
        f"- command: `{summary.get('command')}`",
        f"- start: `{Path(str(summary.get('init_model'))).name}` (COCO YOLOX-Nano), class head initialised from COCO "
        "`boat`; SimOTA assignment, IoU + objectness + class BCE;",
        f"- {settings.get('epochs')} epochs, batch {settings.get('batch_size')}, AdamW lr "
        f"{settings.get('learning_rate')}, seed {settings.get('seed')}; crops of the band "
        f"{augment.get('crop_wh')} at scales {augment.get('scale_range')}, "
        f"close-ups of the vessel at scales {augment.get('zoom_range')} in "
        f"{augment.get('zoom_target', 0.0):.0%} of the crops, flips, HSV jitter, horizon shifts;",
        f"- {summary.get('seconds', 0) / 60:.1f} min on the CPU; final loss {last.get('loss', float('nan')):.3f}; "
        f"ONNX output matches PyTorch to {summary.get('onnx_max_abs_diff', float('nan')):.1e}.",
    ]


def _figures(summary: dict) -> list[str]:
    validation = summary.get("validation") or {}
    return [
        "## Figures",
        f"- validation ({validation.get('reference', 'none')}, videos {summary.get('val_videos')}): recall "
        f"{100 * validation.get('recall', float('nan')):.1f} %, the likeliest box is the vessel in "
        f"{100 * validation.get('top1', float('nan')):.1f} % of {validation.get('frames')} frames.",
        "- held-out figures (videos never used for training or choices) are in `docs/detector.md` of the repository.",
    ]
