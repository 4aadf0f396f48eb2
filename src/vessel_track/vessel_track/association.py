"""Association of one frame's detections to the tracker's predicted tracks: the cost of every pair, the assignment.

A pair's cost is the negative log-likelihood of the detection under the track: the Mahalanobis distance of its
centre with the predicted innovation covariance S (and ``ln det S``), the change of its log box size against the
size model, and the agreement of its confidence with the track's recent ones. Pairs outside the gates, or likelier
clutter than the track (``clutter_density_per_mpx``), are forbidden. The assignment is global (Hungarian), where a
track may stay without a detection at the clutter cost, or the paper's nearest-first matching.

The tracks are the tracker's own records (``vessel_track.tracker``): each has its filter ``kf``, its predicted
``center``, the ``size`` of its latest box, its ``stamp`` (predicted to) and ``last_seen`` (latest box), its
``confidence`` and ``recent_confidences(count)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from vessel_track.deferred_imports import linear_sum_assignment
from vessel_track.tracker_config import TrackerConfig

# Cost of a forbidden (gated-out) pair: large enough that the assignment prefers any admissible pairing,
# finite so that linear_sum_assignment never reports the problem infeasible.
_FORBIDDEN_COST = 1.0e9
_LOG_2PI_SQ = 2.0 * math.log(2.0 * math.pi)
# -2 ln of the density of a false detection's (ln w, ln h): spread uniformly over a decade of sizes each.
_CLUTTER_LOG_SIZE_NLL = 4.0 * math.log(math.log(10.0))


def associate(cfg: TrackerConfig, tracks: Sequence, centers: np.ndarray, sizes: np.ndarray,
              confs: np.ndarray | None = None) -> list[tuple[int, int]]:
    """The (track, detection) index pairs of this frame's assignment, by ``cfg.association``."""
    cost = cost_matrix(cfg, tracks, centers, sizes, confs)
    if cfg.association == "global":
        miss = clutter_cost(cfg) if cfg.distance_metric == "mahalanobis" else math.inf
        if math.isfinite(miss) and cost.size:
            # One "no detection" column per track: the assignment may leave a track unmatched rather than
            # take a worse pair for it so that another track gets a barely admissible one.
            dummy = np.full((len(tracks), len(tracks)), _FORBIDDEN_COST)
            np.fill_diagonal(dummy, miss)
            rows, cols = linear_sum_assignment(np.hstack([cost, dummy]))
            keep = cols < cost.shape[1]
            rows, cols = rows[keep], cols[keep]
        else:
            rows, cols = linear_sum_assignment(cost)
    else:
        rows, cols = greedy_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if cost[r, c] < _FORBIDDEN_COST]


def greedy_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-first matching (the paper's rule): repeatedly take the cheapest remaining admissible pair."""
    rows: list[int] = []
    cols: list[int] = []
    if cost.size:
        order = np.argsort(cost, axis=None, kind="stable")
        used_r: set[int] = set()
        used_c: set[int] = set()
        for flat in order:
            r, c = divmod(int(flat), cost.shape[1])
            if cost[r, c] >= _FORBIDDEN_COST:
                break
            if r in used_r or c in used_c:
                continue
            used_r.add(r)
            used_c.add(c)
            rows.append(r)
            cols.append(c)
    return np.array(rows, dtype=int), np.array(cols, dtype=int)


def clutter_cost(cfg: TrackerConfig) -> float:
    """The clutter likelihood on the scale of the mahalanobis cost (``mahalanobis2 + ln det S + size_term``).

    A pair costing more is likelier clutter than the track and is not admissible; in the global assignment it
    is also the cost of leaving a track without a detection. Infinite when the test is off (density 0).
    """
    if cfg.clutter_density_per_mpx <= 0:
        return math.inf
    cost = -2.0 * math.log(cfg.clutter_density_per_mpx * 1e-6) - _LOG_2PI_SQ
    if cfg.size_weight > 0:
        cost += _CLUTTER_LOG_SIZE_NLL - math.log(2.0 * math.pi * cfg.size_log_std**2) - math.log(
            2.0 * math.pi * _base_height_log_std(cfg)**2)
    return cost


def _base_height_log_std(cfg: TrackerConfig) -> float:
    return cfg.height_log_std if cfg.height_log_std > 0 else cfg.size_log_std


def _height_log_var(cfg: TrackerConfig, tracks: Sequence, heights: np.ndarray) -> np.ndarray:
    """(T,) variance of each track's ln(height) change to a box now: ``height_log_std``, grown by the rate."""
    base = _base_height_log_std(cfg)
    elapsed = np.array([max(t.stamp - t.last_seen, 0.0) for t in tracks], dtype=float)
    return base**2 + (cfg.height_log_std_rate * heights * elapsed) ** 2


def confidence_terms(cfg: TrackerConfig, tracks: Sequence, confs: np.ndarray | None) -> np.ndarray:
    """(tracks, detections) ``-2 ln(2 (q p + (1 - q)(1 - p)))`` times ``confidence_weight`` (0 when off)."""
    n_dets = 0 if confs is None else len(confs)
    if cfg.confidence_weight <= 0 or confs is None:
        return np.zeros((len(tracks), n_dets))
    p = np.clip(np.asarray(confs, dtype=float), 0.05, 0.95)
    q = np.array([np.mean(t.recent_confidences(cfg.confidence_memory) or [t.confidence]) for t in tracks],
                 dtype=float)
    q = np.clip(np.where(np.isfinite(q), q, 0.5), 0.05, 0.95)
    agreement = q[:, None] * p[None, :] + (1.0 - q[:, None]) * (1.0 - p[None, :])
    return cfg.confidence_weight * -2.0 * np.log(2.0 * agreement)


def cost_matrix(cfg: TrackerConfig, tracks: Sequence, centers: np.ndarray, sizes: np.ndarray,
                confs: np.ndarray | None = None) -> np.ndarray:
    """(tracks, detections) association cost; gated-out pairs cost ``_FORBIDDEN_COST``."""
    n_tracks, n_dets = len(tracks), len(centers)
    cost = np.full((n_tracks, n_dets), _FORBIDDEN_COST)
    if n_tracks == 0 or n_dets == 0:
        return cost
    centers = np.asarray(centers, dtype=float).reshape(-1, 2)
    sizes = np.asarray(sizes, dtype=float).reshape(-1, 2)
    # Every pair at once: S = P_track + R_det (2x2), its closed-form inverse and determinant.
    P = np.array([t.kf.P[np.ix_((0, 2), (0, 2))] for t in tracks], dtype=float)          # (T, 2, 2)
    R = cfg.measurement_std_px**2 + (cfg.measurement_std_size_frac * sizes) ** 2          # (D, 2) diagonal
    s00 = P[:, None, 0, 0] + R[None, :, 0]
    s11 = P[:, None, 1, 1] + R[None, :, 1]
    s01 = P[:, None, 0, 1] + np.zeros((1, n_dets))
    s10 = P[:, None, 1, 0] + np.zeros((1, n_dets))
    det = s00 * s11 - s01 * s10
    track_centers = np.array([t.center for t in tracks], dtype=float)                   # (T, 2)
    track_sizes = np.array([t.size for t in tracks], dtype=float)                       # (T, 2)
    d = centers[None, :, :] - track_centers[:, None, :]                                  # (T, D, 2)
    dist = np.hypot(d[..., 0], d[..., 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        mahalanobis2 = (d[..., 0] ** 2 * s11 - d[..., 0] * d[..., 1] * (s01 + s10) + d[..., 1] ** 2 * s00) / det
        log_det_S = np.log(det)
        ratio = np.log(sizes[None, :, :] / track_sizes[:, None, :])
    height_var = _height_log_var(cfg, tracks, track_sizes[:, 1])[:, None]                # (T, 1)
    # The height's own normaliser beyond the clutter cost's (0 while it is height_log_std).
    size_term = ((ratio[..., 0] / cfg.size_log_std) ** 2 + ratio[..., 1] ** 2 / height_var
                 + np.log(height_var / _base_height_log_std(cfg)**2))
    confidence = confidence_terms(cfg, tracks, confs)
    if not confidence.size:
        confidence = np.zeros((n_tracks, n_dets))
    admissible = (dist <= cfg.max_gate_px) & ~((dist > cfg.gate_px) & (mahalanobis2 > cfg.gate_sigmas**2))
    if cfg.max_size_ratio > 0:
        admissible &= ~np.any(np.abs(ratio) > math.log(cfg.max_size_ratio), axis=2)
    likelihood = mahalanobis2 + log_det_S + (size_term if cfg.size_weight > 0 else 0.0) + confidence
    admissible &= ~(likelihood > clutter_cost(cfg))  # likelier clutter than this track
    admissible &= np.isfinite(mahalanobis2) & np.isfinite(log_det_S) & np.isfinite(size_term)
    if cfg.distance_metric == "mahalanobis":
        position_term = mahalanobis2 + log_det_S
    else:
        position_term = (dist / cfg.measurement_std_px) ** 2
    pair_cost = position_term + cfg.size_weight * size_term + confidence
    cost[admissible] = pair_cost[admissible]
    return cost
