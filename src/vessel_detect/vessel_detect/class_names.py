"""The names of a model's output classes: from a file beside the model, or COCO's for an 80-class model.

The detector selects classes by name (``DetectorConfig.classes``), so a model whose names are wrong or missing
would silently detect the wrong things; the names come from one of these places or the model is refused.
"""

from __future__ import annotations

from pathlib import Path

from vessel_common.errors import ModelError

COCO_CLASSES: tuple[str, ...] = (
    "person", "bicycle", "car", "motorbike", "aeroplane", "bus", "train", "truck", "boat", "traffic light",
    "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat", "dog", "horse", "sheep", "cow",
    "elephant", "bear", "zebra", "giraffe", "backpack", "umbrella", "handbag", "tie", "suitcase", "frisbee",
    "skis", "snowboard", "sports ball", "kite", "baseball bat", "baseball glove", "skateboard", "surfboard",
    "tennis racket", "bottle", "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple",
    "sandwich", "orange", "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair", "sofa",
    "pottedplant", "bed", "diningtable", "toilet", "tvmonitor", "laptop", "mouse", "remote", "keyboard",
    "cell phone", "microwave", "oven", "toaster", "sink", "refrigerator", "book", "clock", "vase", "scissors",
    "teddy bear", "hair drier", "toothbrush",
)  # fmt: skip
"""The 80 COCO class names in the order COCO-trained YOLO models output them (``boat`` is 8)."""

CLASS_FILE_NAMES = ("coco_classes.txt", "classes.txt")


def read_class_names(path: Path) -> list[str]:
    """One class name per line (blank lines ignored)."""
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as error:
        raise ModelError(f"cannot read class names file {path}: {error.strerror}") from None
    names = [line.strip() for line in lines if line.strip()]
    if not names:
        raise ModelError(f"class names file {path} is empty: write one class name per line, in output order")
    return names


def find_class_names(model_path: Path, explicit: str | Path | None = None) -> list[str] | None:
    """Class names from ``explicit``, else from a class file next to the model; None when there is none."""
    if explicit:
        return read_class_names(Path(explicit))
    for name in (model_path.with_suffix(".names").name, *CLASS_FILE_NAMES):
        candidate = model_path.parent / name
        if candidate.is_file():
            return read_class_names(candidate)
    return None
