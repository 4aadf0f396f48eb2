"""Small generated inputs (dataset folders, bags, videos, GPS files) for tests and try-outs without shared data.

Images are tiny but real JPEGs whose content encodes the frame number (a bright bar moves across), so a reader
can tell frames apart; the camera and the vessel sit near the challenge camera in San Diego Bay.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from vessel_detect import bag_messages, bag_topics, bag_writer

CAMERA_LAT = 32.70297
CAMERA_LON = -117.234631
START_UTC = 1601495752.884  # 2020-09-30T19:55:52.884Z, the first frame of challenge video 13


def frame_image(index: int, width: int = 160, height: int = 120) -> np.ndarray:
    """A BGR image that differs per frame: grey sea, a white bar at a position set by `index`."""
    image = np.full((height, width, 3), (120, 90, 60), dtype=np.uint8)
    x = (index * 7) % max(width - 10, 1)
    image[height // 2 :, x : x + 10] = 255
    cv2.putText(image, str(index), (4, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 255, 255), 1)
    return image


def frame_jpeg(index: int, width: int = 160, height: int = 120, quality: int = 90) -> bytes:
    """JPEG bytes of `frame_image(index)`."""
    ok, buffer = cv2.imencode(".jpg", frame_image(index, width, height), [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return buffer.tobytes()


def vessel_position(t_s: float) -> tuple[float, float]:
    """A vessel ~150 m east-north-east of the camera, moving north at 2.5 m/s."""
    metres_per_deg = 6371000.0 * math.pi / 180.0
    north = 40.0 + 2.5 * t_s
    east = 150.0
    return (
        CAMERA_LAT + north / metres_per_deg,
        CAMERA_LON + east / (metres_per_deg * math.cos(math.radians(CAMERA_LAT))),
    )


def iso_utc(stamp_s: float) -> str:
    """`2020-09-30T19:55:52.884Z` for epoch seconds (millisecond precision, as frames.csv)."""
    from datetime import UTC, datetime

    moment = datetime.fromtimestamp(round(stamp_s, 3), tz=UTC)
    return moment.strftime("%Y-%m-%dT%H:%M:%S.") + f"{moment.microsecond // 1000:03d}Z"


@dataclass
class SyntheticDataset:
    """What `write_dataset` wrote: the folder, frame stamps per video, and the GPS fixes (epoch s, lat, lon)."""

    path: Path
    stamps: dict[int, list[float]]
    gps: list[tuple[float, float, float]]


def write_dataset(
    folder: str | Path,
    videos: tuple[int, ...] = (13, 14),
    frames_per_video: int = 6,
    frame_step_s: float = 4.0,
    gps_step_s: float = 0.5,
    bad_gps_rows: int = 0,
) -> SyntheticDataset:
    """A dataset folder laid out like ../shared/aitas.

    It holds camera.json, frames.csv, frames/<video>/<frame>.jpg and target_gps_fixes.csv (with `bad_gps_rows`
    rows of NaN/empty positions mixed in).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "camera.json").write_text(
        json.dumps({"camera_lat": CAMERA_LAT, "camera_lon": CAMERA_LON, "image_width": 160, "image_height": 120})
    )
    stamps: dict[int, list[float]] = {}
    rows = []
    t = START_UTC
    for video in videos:
        stamps[video] = []
        (folder / "frames" / str(video)).mkdir(parents=True, exist_ok=True)
        for k in range(frames_per_video):
            frame = 100 * k
            rel = f"frames/{video}/{frame:05d}.jpg"
            (folder / rel).write_bytes(frame_jpeg(video * 1000 + k))
            stamps[video].append(round(t, 3))
            rows.append((video, frame, iso_utc(t), 0, rel))
            t += frame_step_s
        t += 30.0  # a pause between videos
    with (folder / "frames.csv").open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["video", "frame", "utc", "has_label", "file"])
        writer.writerows(rows)
    day0 = math.floor(START_UTC / 86400.0) * 86400.0
    gps = []
    t_end = t
    t = START_UTC - 20.0
    with (folder / "target_gps_fixes.csv").open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["fix_index", "utc", "utc_s", "t_spread_s", "lat", "lon", "dist_m", "bearing_deg", "video"])
        index = 0
        while t < t_end + 20.0:
            lat, lon = (round(v, 9) for v in vessel_position(t - START_UTC))
            sod = round(t - day0, 3)
            writer.writerow([index, iso_utc(t), math.floor(sod), sod, f"{lat:.9f}", f"{lon:.9f}", "", "", ""])
            gps.append((day0 + sod, lat, lon))
            if index < bad_gps_rows:
                writer.writerow([f"bad{index}", iso_utc(t), math.floor(sod), sod + 0.1, "nan", "", "", "", ""])
            index += 1
            t += gps_step_s
    return SyntheticDataset(folder, stamps, gps)


def write_bag(
    path: str | Path,
    frames: int = 6,
    frame_step_s: float = 0.2,
    start_utc: float = START_UTC,
    *,
    bad_frames: tuple[int, ...] = (),
    with_fixes: bool = True,
    image_topic: str = bag_topics.DEFAULT_IMAGE_TOPIC,
) -> list[int]:
    """A bag like `bag_build` makes, with `frames` images `frame_step_s` apart; returns the image stamps (ns).

    Frames listed in `bad_frames` hold bytes that are not a JPEG (a truncated one), to exercise skipping.
    """
    stamps = [bag_messages.sec_to_ns(start_utc + k * frame_step_s) for k in range(frames)]
    with bag_writer.BagWriter(path) as writer:
        writer.add_topic(image_topic, bag_topics.COMPRESSED_IMAGE, "sensor_data")
        if with_fixes:
            writer.add_topic(bag_topics.DEFAULT_CAMERA_FIX_TOPIC, bag_topics.NAV_SAT_FIX, "latched")
            writer.add_topic(bag_topics.DEFAULT_GPS_TRUTH_TOPIC, bag_topics.NAV_SAT_FIX, "reliable")
            writer.write(
                bag_topics.DEFAULT_CAMERA_FIX_TOPIC,
                bag_messages.nav_sat_fix(stamps[0], CAMERA_LAT, CAMERA_LON, frame_id="camera"),
            )
        for k, stamp in enumerate(stamps):
            data = frame_jpeg(k)
            if k in bad_frames:
                data = data[: len(data) // 2]
            if with_fixes:
                lat, lon = vessel_position(k * frame_step_s)
                writer.write(bag_topics.DEFAULT_GPS_TRUTH_TOPIC,
                             bag_messages.nav_sat_fix(stamp, lat, lon, frame_id="vessel"))
            writer.write(image_topic, bag_messages.compressed_image(stamp, data))
    return stamps


def write_video(path: str | Path, frames: int = 12, fps: float = 10.0, size: tuple[int, int] = (160, 120)) -> Path:
    """A small MJPG .avi (or mp4v .mp4, by suffix) of `frame_image` frames."""
    path = Path(path)
    fourcc = cv2.VideoWriter_fourcc(*("mp4v" if path.suffix.lower() == ".mp4" else "MJPG"))
    writer = cv2.VideoWriter(str(path), fourcc, fps, size)
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write {path}")
    for k in range(frames):
        writer.write(frame_image(k, *size))
    writer.release()
    return path


def write_gps_csv(path: str | Path, start_utc: float, seconds: float, step_s: float = 1.0, garbage: bool = True) -> int:
    """A GPS CSV (`time` ISO, `lat`, `lon`) over [start, start + seconds]; returns the number of good rows.

    With `garbage`, rows with NaN, empty, non-numeric and out-of-range positions are mixed in (3 of them).
    """
    path = Path(path)
    good = 0
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["time", "lat", "lon"])
        t = start_utc - 2.0
        while t <= start_utc + seconds + 2.0:
            lat, lon = vessel_position(t - start_utc)
            writer.writerow([iso_utc(t), f"{lat:.9f}", f"{lon:.9f}"])
            good += 1
            t += step_s
        if garbage:
            writer.writerow([iso_utc(start_utc), "nan", "-117.2"])
            writer.writerow([iso_utc(start_utc + 1), "", ""])
            writer.writerow([iso_utc(start_utc + 2), "north", "123.0.1"])
    return good
