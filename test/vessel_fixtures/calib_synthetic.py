"""Synthetic cameras and scenes for tests and studies: upright pinhole cameras over the sea plane, pairs, frames."""

from __future__ import annotations

import math

import numpy as np

from vessel_calib import geodesy
from vessel_calib.camera_model import CameraModel

CAMERA_LAT = 32.70297
CAMERA_LON = -117.234631


def pinhole_h(height_m: float, heading_deg: float, tilt_down_deg: float, focal_px: float,
              roll_deg: float = 0.0, center=(640.0, 360.0)) -> np.ndarray:
    """Sea-plane homography of an upright pinhole camera at (0, 0, height), in the paper's sign (z_p < 0 ahead)."""
    psi = math.radians(heading_deg)
    theta = math.radians(tilt_down_deg)
    phi = math.radians(roll_deg)
    forward = np.array([math.sin(psi) * math.cos(theta), math.cos(psi) * math.cos(theta), -math.sin(theta)])
    right0 = np.array([math.cos(psi), -math.sin(psi), 0.0])
    down0 = np.cross(forward, right0)
    right = math.cos(phi) * right0 + math.sin(phi) * down0
    down = -math.sin(phi) * right0 + math.cos(phi) * down0
    R = np.vstack([right, down, forward])
    K = np.array([[focal_px, 0, center[0]], [0, focal_px, center[1]], [0, 0, 1.0]])
    Hc = K @ np.column_stack([R[:, 0], R[:, 1], -height_m * R[:, 2]])
    return -0.5 * Hc / np.linalg.norm(Hc[2, :2])


def pinhole_camera(height_m=8.0, heading_deg=76.5, tilt_down_deg=-1.5, focal_px=1100.0, roll_deg=0.5,
                   K1=-4.0e-7) -> CameraModel:
    """A camera close to the challenge one (its horizon sits ~30-60 px below the image centre)."""
    H = pinhole_h(height_m, heading_deg, tilt_down_deg, focal_px, roll_deg)
    return CameraModel(H, K1, center=(640.0, 360.0), image_size=(1280, 720), camera_lat=CAMERA_LAT,
                       camera_lon=CAMERA_LON)


def synthetic_pairs(cam: CameraModel, n: int, seed: int = 0, max_dist_m: float = 250.0, min_y_below: float = 6.0):
    """N (screen, gps) pairs of ``cam`` spread over the visible sea up to ``max_dist_m``."""
    rng = np.random.default_rng(seed)
    screen, gps = [], []
    while len(screen) < n:
        xs = rng.uniform(30, 1250, 4 * n)
        ys = rng.uniform(0, 715, 4 * n)
        yh = cam.horizon_y(xs)
        xw, yw, valid = cam.screen_to_world(xs, ys)
        keep = valid & (ys > yh + min_y_below) & (np.hypot(xw, yw) < max_dist_m) & (np.hypot(xw, yw) > 10)
        for x, y, a, b in zip(xs[keep], ys[keep], xw[keep], yw[keep], strict=True):
            if len(screen) < n:
                screen.append((x, y))
                gps.append(cam.world_to_gps(a, b))
    return np.array(screen), np.array(gps)


def _vessel_box(cam: CameraModel, xw: float, yw: float, anchor: float, rng) -> np.ndarray | None:
    xs, ys, ok = cam.world_to_screen(np.array([xw]), np.array([yw]))
    if not ok[0] or not cam.in_image(xs, ys)[0]:
        return None
    height = max(6.0, 1200.0 / max(math.hypot(xw, yw), 1.0))
    x, y = xs[0] + rng.normal(0, 1.0), ys[0] + rng.normal(0, 1.0)
    return np.array([x - 1.2 * height, y - anchor * height, x + 1.2 * height, y + (1 - anchor) * height])


def search_frames(cam: CameraModel, seed: int = 0, runs: int = 5, frames_per_run: int = 24, miss_rate: float = 0.2,
                  clutter: int = 5, dropout_rate: float = 0.15, anchor: float = 0.65, bearing_offset_deg: float = 0.0):
    """Frames of a boat running out and in across ``cam``'s view, as a detector and a GPS logger would give them.

    Each run goes from 30 m to 450 m and back along a bearing inside the view (``bearing_offset_deg`` turns them
    all, e.g. 180 to put every run behind the camera); the boat's box is missed in ``miss_rate`` of the frames; each
    frame has ``clutter`` boxes of other boats in the band below the horizon and one static box (a post); GPS drops
    out in ``dropout_rate`` of the frames (they get NaN positions). Returns a list of ``FrameBoxes``.
    """
    from vessel_tools.calib.gps_association import FrameBoxes

    rng = np.random.default_rng(seed)
    heading = cam.heading_deg
    frames = []
    stamp = 1.6e9
    for run in range(runs):
        bearing = math.radians(heading + bearing_offset_deg + (run - (runs - 1) / 2) * 12.0)
        out = np.linspace(30.0, 450.0, frames_per_run // 2)
        for k, dist in enumerate(np.concatenate([out, out[::-1] + 7.0])):
            xw, yw = dist * math.sin(bearing) + 15.0 * math.sin(k), dist * math.cos(bearing)
            boxes, scores = [], []
            vessel = _vessel_box(cam, xw, yw, anchor, rng)
            if vessel is not None and rng.random() > miss_rate:
                boxes.append(vessel)
                scores.append(rng.uniform(0.2, 0.8))
            for _ in range(clutter):
                x = rng.uniform(20, 1260)
                y = cam.horizon_y(np.array([x]))[0] + rng.uniform(2, 200)
                h = rng.uniform(6, 40)
                boxes.append([x - h, y - h * anchor, x + h, y + h * (1 - anchor)])
                scores.append(rng.uniform(0.1, 0.6))
            boxes.append([800.0, 650.0, 860.0, 710.0])
            scores.append(0.5)
            lat, lon = cam.world_to_gps(xw, yw)
            if rng.random() < dropout_rate:
                lat = lon = math.nan
            frames.append(FrameBoxes(run, k, stamp, float(lat), float(lon), np.array(boxes, dtype=float),
                                     np.array(scores, dtype=float)))
            stamp += 4.0
    return frames


def write_search_folder(folder, frames, camera_lat: float = CAMERA_LAT, camera_lon: float = CAMERA_LON):
    """A data folder without labels, and a ``detect run`` CSV of ``search_frames`` output; returns the CSV's path.

    The folder has camera.json, frames.csv and target_gps_fixes.csv; videos are numbered from 1, frames 0, 100...
    """
    import datetime
    import json
    from pathlib import Path

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "camera.json").write_text(json.dumps({"camera_lat": camera_lat, "camera_lon": camera_lon,
                                                    "image_width": 1280, "image_height": 720}))
    frame_rows = ["video,frame,utc,has_label,file"]
    gps_rows = ["utc_s,lat,lon"]
    box_rows = ["video,frame,x1,y1,x2,y2,score,class_id,p_target"]
    for f in frames:
        video, frame = f.video + 1, f.frame * 100
        utc = datetime.datetime.fromtimestamp(f.stamp, datetime.UTC)
        frame_rows.append(f"{video},{frame},{utc.strftime('%Y-%m-%dT%H:%M:%S.%f')[:-3]}Z,0,")
        if math.isfinite(f.lat):
            seconds_of_day = f.stamp % 86400.0
            gps_rows += [f"{seconds_of_day + dt:.3f},{f.lat!r},{f.lon!r}" for dt in (-0.5, 0.5)]
        for (x1, y1, x2, y2), score in zip(f.boxes, f.scores, strict=True):
            box_rows.append(f"{video},{frame},{x1:.2f},{y1:.2f},{x2:.2f},{y2:.2f},{score:.3f},8,")
    (folder / "frames.csv").write_text("\n".join(frame_rows) + "\n")
    (folder / "target_gps_fixes.csv").write_text("\n".join(gps_rows) + "\n")
    detections = folder / "detections.csv"
    detections.write_text("\n".join(box_rows) + "\n")
    return detections


T0 = 1601494200.0
"""2020-09-30 19:30:00 UTC: the start of the synthetic tide."""


def offset_pinhole(height_m: float, nadir=(1.5, -2.0), focal_px=950.0, tilt_down_deg=-1.2, roll_deg=0.4,
                   water_level_m=math.nan) -> CameraModel:
    """A pinhole camera ``height_m`` above the sea, standing over ``nadir`` (world metres)."""
    shift = np.array([[1.0, 0.0, -nadir[0]], [0.0, 1.0, -nadir[1]], [0.0, 0.0, 1.0]])
    H = pinhole_h(height_m, 76.5, tilt_down_deg, focal_px, roll_deg) @ shift
    return CameraModel(H, -3.5e-7, camera_lat=CAMERA_LAT, camera_lon=CAMERA_LON, box_anchor=0.65,
                       water_level_m=water_level_m)


def tidal_pairs(n: int = 60, seed: int = 1):
    """Pairs seen by a camera 2.6 m over the sea while the tide falls 0.35 m an hour for 30 minutes."""
    rng = np.random.default_rng(seed)
    stamps = T0 + np.sort(rng.uniform(0, 1800, n))
    levels = 0.97 - 0.35 * (stamps - T0) / 3600
    screen, gps = [], []
    for level in levels:
        camera = offset_pinhole(2.6 + (0.9 - level))  # water lower -> camera higher
        while True:
            x, y = rng.uniform(60, 1220), rng.uniform(0, 715)
            xw, yw, ok = camera.screen_to_world(x, y)
            if ok and 20 < math.hypot(xw, yw) < 250 and y > float(camera.horizon_y(x)) + 8:
                break
        screen.append((x, y))
        gps.append(geodesy.local_to_gps(xw, yw, CAMERA_LAT, CAMERA_LON))
    return np.array(screen), np.array(gps, dtype=float), levels
