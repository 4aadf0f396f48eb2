"""Choosing an image source from a string: a bag folder or `.mcap`, a video file, an image folder, or a device."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from vessel_common.errors import DataError
from vessel_detect import bag_topics
from vessel_detect.file_sources import IMAGE_SUFFIXES, BagSource, FolderSource, VideoSource
from vessel_detect.image_source import ImageSource
from vessel_detect.live_sources import DeviceSource, parse_device


def check_source(spec: str | Path) -> int | str | None:
    """The device ``spec`` names (``parse_device``), else None once its path is known to exist; else DataError.

    What ``open_source`` checks first; a launcher checks it before it starts a graph that would wait for a camera
    that cannot start.
    """
    text = str(spec).strip()
    if not text:
        raise DataError("no source given: name a bag folder, .mcap, video file, image folder or device:N")
    device = parse_device(text)
    if device is not None:
        return device
    path = Path(text).expanduser()
    if not path.exists():
        raise DataError(
            f"source {path} does not exist (expected a bag folder, .mcap file, video file, image folder, or "
            "device:N)"
        )
    return None


def open_source(
    spec: str | Path,
    *,
    image_topic: str = bag_topics.DEFAULT_IMAGE_TOPIC,
    aux_topics: Iterable[str] | None = (bag_topics.DEFAULT_CAMERA_FIX_TOPIC, bag_topics.DEFAULT_GPS_TRUTH_TOPIC),
    start_utc: float | None = None,
    fps: float | None = None,
    every: int = 1,
    device_width: int = 0,
    device_height: int = 0,
    **options,
) -> ImageSource:
    """Open what `spec` names: a rosbag2 folder or `.mcap`, a video file, an image folder, or a device/stream.

    `options` go to every source (`start_offset_s`, `loop`, `restamp_loops`, `on_problem`, `strict_order`).
    `fps` is the folder's frame rate, a video's forced rate, or a device's requested rate.
    """
    device = check_source(spec)
    if device is not None:
        return DeviceSource(device, width=device_width, height=device_height, fps=fps or 0.0, **options)
    path = Path(str(spec).strip()).expanduser()
    if path.is_dir():
        if (path / "metadata.yaml").is_file() or any(path.glob("*.mcap")):
            return BagSource(path, image_topic=image_topic, aux_topics=aux_topics, **options)
        return FolderSource(path, fps=fps or 1.0, start_utc=start_utc, **options)
    if path.suffix.lower() in (".mcap", ".db3"):
        return BagSource(path, image_topic=image_topic, aux_topics=aux_topics, **options)
    if path.suffix.lower() in IMAGE_SUFFIXES:
        raise DataError(f"{path} is a single image: give its folder as the source")
    return VideoSource(path, start_utc=start_utc, fps=fps, every=every, **options)
