"""Where down a detector's boxes the vessel's GPS falls, through a camera fitted on other boxes.

A label-free calibration is fitted on a generic detector's boxes, read at its own ``box_anchor``; the fuser reads
the graph detector's boxes, which sit on the vessel in their own way. ``measure_box_anchor`` finds the anchor of
those from the vessel's GPS alone, projected through the fitted camera (``calibrate`` writes it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vessel_calib.camera_model import CameraModel
from vessel_common.errors import CalibrationError


@dataclass(frozen=True)
class BoxAnchorMeasurement:
    """Where down another detector's boxes the vessel's GPS falls, through a fitted camera.

    anchor: the median over the frames (0 box top, 1 bottom); quartiles: its spread; frames: how many frames had a
    box of that detector around the projected GPS that it calls the vessel of interest.
    """

    anchor: float
    quartiles: tuple[float, float]
    frames: int


def measure_box_anchor(model: CameraModel, gps_latlon, levels, boxes, probabilities, min_probability: float = 0.5,
                       margin_px: float = 3.0, vertical_slack: float = 0.5) -> BoxAnchorMeasurement | None:
    """The box anchor of a detector whose boxes ``model`` was not fitted on, from the vessel's GPS alone.

    ``gps_latlon`` (N, 2) and ``levels`` (N,) (water level, NaN or None: the model's own) per frame; ``boxes`` and
    ``probabilities``: that frame's boxes (k, 4) and each one's probability of being the vessel of interest. A
    frame counts when its GPS projects into the image and into one of its boxes (``margin_px`` across,
    ``vertical_slack`` of the box height above and below) that says the vessel of interest with at least
    ``min_probability``; the likeliest such box gives ``(y - y1) / (y2 - y1)``. The label-free fit reads the
    search detector's boxes at ``model.box_anchor``; the fuser reads the graph's detector's boxes, which sit on the
    vessel in their own way. None when no frame counts.
    """
    gps = np.asarray(gps_latlon, dtype=float).reshape(-1, 2)
    levels = np.full(len(gps), np.nan) if levels is None else np.asarray(levels, dtype=float).reshape(-1)
    if not (len(levels) == len(gps) == len(boxes) == len(probabilities)):
        raise CalibrationError(f"measure_box_anchor: {len(gps)} GPS fixes, {len(levels)} water levels, "
                               f"{len(boxes)} box sets and {len(probabilities)} probability sets: one of each per "
                               "frame")
    fractions = []
    for (lat, lon), level, frame_boxes, frame_p in zip(gps, levels, boxes, probabilities, strict=True):
        b = np.asarray(frame_boxes, dtype=float).reshape(-1, 4)
        p = np.asarray(frame_p, dtype=float).reshape(-1)
        if b.size == 0:
            continue
        camera = model.at_water_level(float(level)) if math.isfinite(level) else model
        xw, yw = camera.gps_to_world(lat, lon)
        xs, ys, in_front = camera.world_to_screen(xw, yw)
        if not (bool(in_front) and camera.in_image(xs, ys)):
            continue
        height = b[:, 3] - b[:, 1]
        around = ((b[:, 0] - margin_px <= xs) & (xs <= b[:, 2] + margin_px) & (height > 0)
                  & (b[:, 1] - vertical_slack * height <= ys) & (ys <= b[:, 3] + vertical_slack * height)
                  & (p >= min_probability))
        if not around.any():
            continue
        best = np.flatnonzero(around)[int(np.argmax(p[around]))]
        fractions.append((float(ys) - b[best, 1]) / height[best])
    if not fractions:
        return None
    f = np.asarray(fractions)
    q1, q3 = np.percentile(f, [25, 75])
    return BoxAnchorMeasurement(float(np.median(f)), (float(q1), float(q3)), int(f.size))
