"""The paper's trajectory score, ``score = c_0.8 * log(l)``, and the path length it is made of.

``c_0.8`` is the 80th percentile of the detector confidences of a trajectory's points (or, with the ``evidence``
score, the sum of their clipped log-odds); ``l`` its path length in metres on the sea plane. Path length uses
``log(max(l, 1 m))``, so a trajectory that does not move (a mooring post detected as a boat) scores 0 rather than a
negative number. The length is measured on filtered positions (online: the world filter's; offline: the smoothed
trajectory), and only motion that stands out of the position covariance counts (``path_noise_sigmas``): the noise
of per-frame positions (metres to hundreds of metres per pixel near the horizon) would otherwise make up most of the
length of a distant vessel's path and of a standing object's.

Both selections use it: ``vessel_track.selection`` (online) and ``vessel_track.offline_selection``.
"""
from __future__ import annotations

import math

import numpy as np


def clipped_log_odds(confidences, clip: float) -> np.ndarray:
    """``log(c / (1 - c))`` of probabilities, each bounded to +-``clip``."""
    p = np.clip(np.asarray(confidences, dtype=float), 1e-9, 1.0 - 1e-9)
    return np.clip(np.log(p / (1.0 - p)), -clip, clip)


def path_length_m(positions, min_step_m: float = 0.0, covariances=None, noise_sigmas: float = 0.0) -> float:
    """Sum of the steps between consecutive positions (N, 2), skipping NaN rows and steps below min_step_m.

    With ``covariances`` (N, 2, 2) and ``noise_sigmas`` > 0 only significant motion counts: a step is taken from
    the last counted point to the first later point that is more than ``noise_sigmas`` standard deviations of
    their difference away from it (``significant_step``), so slow but steady motion adds up while jitter does not.
    """
    p = np.asarray(positions, dtype=float).reshape(-1, 2)
    keep = np.all(np.isfinite(p), axis=1)
    if keep.sum() < 2:
        return 0.0
    total = 0.0
    idx = np.flatnonzero(keep)
    anchor = idx[0]
    for b in idx[1:]:
        if covariances is not None and noise_sigmas > 0:
            step = significant_step(p[anchor], p[b], covariances[anchor], covariances[b], noise_sigmas)
        else:
            step = float(np.hypot(*(p[b] - p[anchor])))
        if step > 0 and step >= min_step_m:
            total += step
            anchor = b
    return total


def significant_step(p0, p1, cov0, cov1, noise_sigmas: float) -> float:
    """Length of the step p0 -> p1 if it exceeds ``noise_sigmas`` standard deviations of it, else 0.

    Near the horizon a pixel is tens to hundreds of metres: the positions of a distant sailboat jitter by more
    than the vessel of interest moves. Counting a step only once it stands out of the covariances keeps that
    jitter out of the path length.
    """
    d = np.asarray(p1, dtype=float) - np.asarray(p0, dtype=float)
    length = float(np.hypot(*d))
    if length == 0.0:
        return 0.0
    u = d / length
    variance = float(u @ (np.asarray(cov0, dtype=float) + np.asarray(cov1, dtype=float)) @ u)
    if not math.isfinite(variance) or variance < 0:
        return length
    return length if length > noise_sigmas * math.sqrt(variance) else 0.0


def trajectory_score(confidences, path_m: float, percentile: float = 80.0, mode: str = "percentile",
                     evidence_clip: float = 4.0, path_log_floor: float = 0.0) -> float:
    """The paper's ``c_0.8 * log(l)`` with ``log(max(l, 1))``; 0 for no confidences.

    ``mode="evidence"`` replaces ``c_0.8`` by the sum of the confidences' clipped log-odds
    (``SelectionConfig.confidence_score``); ``path_log_floor`` bounds the path factor from below.
    """
    c = np.asarray(confidences, dtype=float).reshape(-1)
    c = c[np.isfinite(c)]
    if c.size == 0 or not math.isfinite(path_m):
        return 0.0
    if mode == "evidence":
        confidence = float(np.sum(clipped_log_odds(c, evidence_clip)))
    else:
        confidence = float(np.percentile(c, percentile))
    return confidence * max(math.log(max(path_m, 1.0)), path_log_floor)
