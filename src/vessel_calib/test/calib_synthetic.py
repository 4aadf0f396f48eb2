"""Synthetic cameras for the calibration tests: upright pinhole cameras over the sea plane."""

from __future__ import annotations

import math

import numpy as np

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
