"""Checks of labelled (screen, GPS) pairs before a homography is fitted to them.

A homography needs at least 4 pairs, finite and distinct, not (nearly) on one line, on screen and on the sea
within reach of the camera; anything else raises CalibrationError naming the pair (its index in the input).
"""

from __future__ import annotations

import numpy as np

from vessel_calib import geodesy
from vessel_common.errors import CalibrationError

#: A pair further than this from the camera is a wrong camera position or swapped lat/lon, not a vessel in view.
MAX_PAIR_DISTANCE_M = 30000.0
#: Ratio of the singular values of centred coordinates below which points count as collinear.
COLLINEAR_RATIO = 1e-3
#: Screen points this far outside the image are a wrong image size or a unit mistake.
OUTSIDE_IMAGE_MARGIN = 0.1


def as_pairs(values, name: str, n: int | None = None) -> np.ndarray:
    """``values`` as an (N, 2) float array (``n`` rows when given); CalibrationError naming ``name`` otherwise."""
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise CalibrationError(f"{name} must be numbers, shape (N, 2)") from None
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise CalibrationError(f"{name} must have shape (N, 2), got {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise CalibrationError(f"{name} has {arr.shape[0]} rows but there are {n} screen points")
    return arr


def _collinear(points: np.ndarray) -> bool:
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    return bool(s[0] == 0 or s[1] / s[0] < COLLINEAR_RATIO)


def _check_collinear(points: np.ndarray, what: str) -> None:
    """A homography needs 4 points with no 3 on a line: refuse all-on-a-line and all-but-one-on-a-line."""
    if _collinear(points):
        raise CalibrationError(
            f"the {what} points are (nearly) collinear: a homography needs pairs spread over the sea, not "
            "along one line; label the vessel at several distances and bearings")
    for i in range(len(points)):
        if _collinear(np.delete(points, i, axis=0)):
            raise CalibrationError(
                f"all {what} points but pair {i} lie on one line: the homography is not determined; add pairs "
                "away from that line (other distances and bearings)")


def _check_duplicates(points: np.ndarray, tol: float, what: str) -> None:
    order = np.lexsort(points.T[::-1])
    sorted_pts = points[order]
    for k in range(len(points) - 1):
        j = k + 1
        while j < len(points) and sorted_pts[j, 0] - sorted_pts[k, 0] <= tol:
            if np.all(np.abs(sorted_pts[j] - sorted_pts[k]) <= tol):
                a, b = sorted(int(v) for v in (order[k], order[j]))
                raise CalibrationError(
                    f"pairs {a} and {b} have the same {what} point ({points[a, 0]:.6g}, {points[a, 1]:.6g}): a "
                    "duplicated row or a copy/paste error; remove one of them")
            j += 1


def validate_pairs(screen, gps, camera_lat: float, camera_lon: float, image_size=(1280, 720)):
    """Check labelled pairs; returns (screen (N,2), gps (N,2), world (N,2)) or raises CalibrationError."""
    geodesy.validate_lat_lon(camera_lat, camera_lon, "camera position (--camera-lat/--camera-lon)")
    screen = as_pairs(screen, "screen points")
    n = screen.shape[0]
    gps = as_pairs(gps, "GPS positions", n)
    if n < 4:
        raise CalibrationError(f"need at least 4 labelled pairs to fit a homography, got {n}")
    for name, arr in (("screen x/y", screen), ("GPS lat/lon", gps)):
        bad = ~np.isfinite(arr).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise CalibrationError(f"pair {i}: {name} is not finite ({arr[i, 0]}, {arr[i, 1]}); fix or drop that row")
    for i in range(n):
        geodesy.validate_lat_lon(gps[i, 0], gps[i, 1], f"pair {i} GPS position")
    width, height = image_size
    mx, my = OUTSIDE_IMAGE_MARGIN * width, OUTSIDE_IMAGE_MARGIN * height
    outside = (screen[:, 0] < -mx) | (screen[:, 0] > width + mx) | (screen[:, 1] < -my) | (screen[:, 1] > height + my)
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        raise CalibrationError(
            f"pair {i}: screen point ({screen[i, 0]:g}, {screen[i, 1]:g}) is outside the {width}x{height} image; "
            "give full-resolution pixels and the right --image-size")
    xw, yw = geodesy.gps_to_local(gps[:, 0], gps[:, 1], camera_lat, camera_lon)
    world = np.column_stack([xw, yw])
    dist = np.hypot(xw, yw)
    if np.any(dist > MAX_PAIR_DISTANCE_M):
        i = int(np.argmax(dist))
        raise CalibrationError(
            f"pair {i} is {dist[i] / 1000:.0f} km from the camera: wrong camera position, or lat/lon swapped")
    _check_duplicates(screen, 1e-6, "screen")
    _check_duplicates(world, 1e-3, "GPS")
    _check_collinear(world, "GPS (world)")
    _check_collinear(screen, "screen")
    return screen, gps, world
