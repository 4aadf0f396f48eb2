"""A box far larger than the vessel of interest could be where it sits is not the vessel of interest.

The calibration gives each box a depth from its position (its reference point on the sea plane), and the
box-size distance model (the fuser's ``distance_model``: ``width = a / depth + b``, ``height = c / depth + d``,
fitted to the vessel's own boxes) the size the vessel would have at that depth. A network that has learnt the vessel
from close-ups can still give a large nearby boat a high ``p_target``; its box is then several times the vessel's
size for its position. The prior lowers the log-odds of ``p_target`` by ``strength`` per unit of
``ln(size / expected size)`` beyond ``tolerance``; boxes at or below the tolerance, and boxes whose position gives no
depth (on or above the horizon, off the lens model), keep their value. It never raises a value: a small box may be
a far part of the vessel's boat or a box cut by the band.

Inverse and counterpart: the fuser reads the same model the other way, from a box size to a depth
(``vessel_track.distance_model``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vessel_common.errors import VesselError

DIMENSIONS = ("none", "width", "height")
"""Which box size the prior compares: none (off), the width, or the height. Not "off": YAML and ``-p x:=off`` read
that as false."""
DEFAULT_SIZE_MODEL = (4838.3043242984, 6.0449776177, 2844.3419953655, -0.2718582771)
"""a, b, c, d of the box-size distance model fitted on the challenge camera's hand boxes (the fuser's default)."""
PROBABILITY_FLOOR = 1e-9
"""Probabilities are kept this far from 0 and 1 when their log-odds are lowered."""


@dataclass(frozen=True)
class SizePrior:
    """How much a box larger than the vessel's size at its depth lowers its probability of being the vessel."""

    dimension: str = "none"
    tolerance: float = 0.3
    strength: float = 10.0
    size_model: tuple[float, float, float, float] = DEFAULT_SIZE_MODEL

    def __post_init__(self) -> None:
        """Reject values the prior cannot work with; the message names the parameter and the fix."""
        if self.dimension not in DIMENSIONS:
            raise VesselError(f"detector configuration: size_prior.dimension '{self.dimension}' unknown: use one of "
                              f"{', '.join(DIMENSIONS)}")
        if not (math.isfinite(self.tolerance) and self.tolerance >= 0):
            raise VesselError(f"detector configuration: size_prior.tolerance must be >= 0 (a natural log of a size "
                              f"ratio), got {self.tolerance!r}")
        if not (math.isfinite(self.strength) and self.strength >= 0):
            raise VesselError(f"detector configuration: size_prior.strength must be >= 0 (log-odds per unit of log "
                              f"size ratio), got {self.strength!r}")
        if len(self.size_model) != 4 or not all(math.isfinite(float(v)) for v in self.size_model):
            raise VesselError("detector configuration: size_prior.model must be four finite numbers a, b, c, d (the "
                              f"fuser's distance_model), got {list(self.size_model)!r}")
        a, _, c, _ = (float(v) for v in self.size_model)
        if not (a > 0 and c > 0):
            raise VesselError("detector configuration: size_prior.model a and c must be > 0 (px x m, as the fuser's "
                              f"distance_model a and c), got a={a!r}, c={c!r}")

    @property
    def enabled(self) -> bool:
        """True unless the dimension is ``none`` or the strength 0."""
        return self.dimension != "none" and self.strength > 0

    def log_size_ratios(self, camera, boxes_xyxy) -> np.ndarray:
        """``ln(size / expected size)`` of each box (calibrated pixels); NaN where its position gives no depth."""
        boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
        if boxes.shape[0] == 0:
            return np.zeros(0)
        a, b, c, d = (float(v) for v in self.size_model)
        size = boxes[:, 2] - boxes[:, 0] if self.dimension == "width" else boxes[:, 3] - boxes[:, 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            depth = camera.box_depths_m(boxes)
            depth = np.where(depth > 0, depth, np.nan)
            expected = a / depth + b if self.dimension == "width" else c / depth + d
            ratio = np.log(size / expected)
        return np.where(np.isfinite(ratio), ratio, np.nan)

    def apply(self, p_target, log_size_ratios) -> np.ndarray:
        """``p_target`` with each log-odds lowered by ``strength`` per unit of log size ratio above ``tolerance``.

        NaN probabilities stay NaN; unknown ratios change nothing.
        """
        p = np.asarray(p_target, dtype=float)
        excess = np.maximum(0.0, np.nan_to_num(np.asarray(log_size_ratios, dtype=float), nan=0.0) - self.tolerance)
        clipped = np.clip(np.nan_to_num(p, nan=0.5), PROBABILITY_FLOOR, 1.0 - PROBABILITY_FLOOR)
        log_odds = np.log(clipped / (1.0 - clipped)) - self.strength * excess
        return np.where((excess > 0) & np.isfinite(p), 1.0 / (1.0 + np.exp(-log_odds)), p)
