"""The linear part of the camera fit: Hartley-normalised DLT, the K1 lens model, the K1 scan and the MSAC start.

The paper's method finds K1 by brute force (``scan_k1``: for each K1 on a grid, undistort the screen points,
solve H by the DLT, score the reprojection); ``robust_initial_fit`` starts from the consensus of 4-pair samples
instead when a gross outlier would pull the DLT over all pairs off. ``vessel_tools.calib.calibration`` refines
the result.
"""

from __future__ import annotations

import math

import numpy as np

from vessel_common.errors import CalibrationError


def normaliser(points: np.ndarray) -> np.ndarray:
    """Hartley normalisation: centroid to the origin, mean distance sqrt(2)."""
    c = points.mean(axis=0)
    mean_dist = np.mean(np.hypot(points[:, 0] - c[0], points[:, 1] - c[1]))
    s = math.sqrt(2.0) / mean_dist if mean_dist > 0 else 1.0
    return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])


def dlt_normalised(ideal: np.ndarray, world: np.ndarray):
    """Return (H, Tw, Tp, Hn) with H = Tp^-1 Hn Tw; Hn has unit Frobenius norm."""
    Tw = normaliser(world)
    Tp = normaliser(ideal)
    wn = world @ Tw[:2, :2].T + Tw[:2, 2]
    pn = ideal @ Tp[:2, :2].T + Tp[:2, 2]
    n = len(world)
    A = np.zeros((2 * n, 9))
    X, Y = wn[:, 0], wn[:, 1]
    x, y = pn[:, 0], pn[:, 1]
    one = np.ones(n)
    A[0::2, 0:3] = np.column_stack([X, Y, one])
    A[0::2, 6:9] = -x[:, None] * np.column_stack([X, Y, one])
    A[1::2, 3:6] = np.column_stack([X, Y, one])
    A[1::2, 6:9] = -y[:, None] * np.column_stack([X, Y, one])
    _, s, Vt = np.linalg.svd(A, full_matrices=A.shape[0] < 9)  # thin SVD: U of 2N x 2N is not needed
    s = np.concatenate([s, np.zeros(9 - s.size)]) if s.size < 9 else s
    if s[-2] < 1e-9 * s[0]:
        raise CalibrationError(
            "the pairs do not determine a homography (degenerate layout, e.g. three of four points on a line); "
            "add pairs at other distances and bearings")
    Hn = Vt[-1].reshape(3, 3)
    H = np.linalg.inv(Tp) @ Hn @ Tw
    return H, Tw, Tp, Hn


def normalized_dlt(ideal_xy, world_xy) -> np.ndarray:
    """H (paper convention, z_p (x_p, y_p, 1) = H (x_w, y_w, 1)) by Hartley-normalised DLT, scaled so |H| = 1."""
    ideal = np.asarray(ideal_xy, dtype=float).reshape(-1, 2)
    world = np.asarray(world_xy, dtype=float).reshape(-1, 2)
    if len(ideal) < 4 or len(ideal) != len(world):
        raise CalibrationError(f"the DLT needs at least 4 matching pairs, got {len(ideal)} and {len(world)}")
    H = dlt_normalised(ideal, world)[0]
    return H / np.linalg.norm(H)


def project(H, K1, center, world):
    """Screen projection and a mask of pairs in front of the camera and inside the lens domain."""
    q = world @ H[:, :2].T + H[:, 2]
    zp = q[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        p = q[:, :2] / zp[:, None]
    d = p - center
    r2 = np.sum(d * d, axis=1)
    ok = np.isfinite(r2)
    if K1 < 0:
        ok &= r2 < -1.0 / (3.0 * K1)
    s = center + d * (1.0 + K1 * r2)[:, None]
    return s, zp, ok


def undistort_points(screen, K1, center):
    """Ideal points of screen points under K1 (NaN where the lens model has no inverse)."""
    d = screen - center
    rs = np.hypot(d[:, 0], d[:, 1])
    if K1 == 0:
        return screen.copy()
    u = rs.copy()
    if K1 < 0:
        r_fold = math.sqrt(-1.0 / (3.0 * K1))
        if np.any(rs > r_fold * (2.0 / 3.0)):
            return np.full_like(screen, np.nan)
        u = np.minimum(u, r_fold)
    for _ in range(80):
        f = u + K1 * u ** 3 - rs
        step = f / (1.0 + 3.0 * K1 * u * u)
        u = u - step
        if np.max(np.abs(step)) < 1e-12 * max(1.0, float(np.max(u))):
            break
    scale = np.where(rs > 0, u / np.where(rs > 0, rs, 1.0), 1.0)
    return center + d * scale[:, None]


def front_sign(H, world) -> np.ndarray:
    """Flip H so the labelled points are in front (z_p < 0), the paper's sign."""
    zp = world @ H[2, :2] + H[2, 2]
    return -H if np.median(zp) > 0 else H


def scan_k1(screen, world, center, k1_values, weights=None):
    """The paper's brute force: for each K1, undistort, DLT, score the (weighted) squared reprojection error.

    Returns (best_k1, best_H, losses) with losses (inf where K1 cannot undistort every point or the DLT fails).
    """
    screen = np.asarray(screen, dtype=float)
    world = np.asarray(world, dtype=float)
    center = np.asarray(center, dtype=float)
    w = np.ones(len(screen)) if weights is None else np.asarray(weights, dtype=float)
    losses = np.full(len(k1_values), np.inf)
    best = (math.inf, None, None)
    for i, k1 in enumerate(k1_values):
        ideal = undistort_points(screen, float(k1), center)
        if not np.isfinite(ideal).all():
            continue
        try:
            H = front_sign(normalized_dlt(ideal, world), world)
        except (CalibrationError, np.linalg.LinAlgError):
            continue
        proj, zp, ok = project(H, float(k1), center, world)
        if not (ok.all() and np.all(zp < 0)):
            continue
        loss = float(np.sum(w * np.sum((proj - screen) ** 2, axis=1)))
        losses[i] = loss
        if loss < best[0]:
            best = (loss, float(k1), H)
    if best[1] is None:
        raise CalibrationError(
            "no K1 in the scan gives a usable fit: the pairs are inconsistent (wrong camera position, swapped "
            "lat/lon, or screen points from another image size)")
    return best[1], best[2], losses


def robust_initial_fit(screen, world, center, K1, threshold_px: float, iterations: int = 600, seed: int = 0):
    """MSAC over 4-pair samples at a fixed K1: (H, inlier mask) of the best consensus, refitted on its inliers.

    The algebraic DLT over all pairs is pulled far off by a single gross outlier (a label in the sky can
    drag the horizon above the image), and the refinement then stays in that basin; starting from the
    consensus of the well-behaved pairs lets the robust loss do its job. Returns (None, None) if no sample works.
    """
    ideal = undistort_points(screen, K1, center)
    if not np.isfinite(ideal).all():
        return None, None
    n = len(screen)
    rng = np.random.default_rng(seed)
    if math.comb(n, 4) <= iterations:
        from itertools import combinations

        samples = [np.array(c) for c in combinations(range(n), 4)]
    else:
        samples = [rng.choice(n, size=4, replace=False) for _ in range(iterations)]
    t2 = threshold_px ** 2
    best_cost, best_inliers = math.inf, None
    for idx in samples:
        try:
            H = front_sign(dlt_normalised(ideal[idx], world[idx])[0], world[idx])
        except (CalibrationError, np.linalg.LinAlgError):
            continue
        proj, zp, ok = project(H, K1, center, world)
        r2 = np.sum((proj - screen) ** 2, axis=1)
        r2 = np.where(ok & (zp < 0) & np.isfinite(r2), r2, np.inf)
        cost = float(np.sum(np.minimum(r2, t2)))
        if cost < best_cost:
            best_cost, best_inliers = cost, r2 < t2
    if best_inliers is None or best_inliers.sum() < 4:
        return None, None
    try:
        H = front_sign(dlt_normalised(ideal[best_inliers], world[best_inliers])[0], world[best_inliers])
    except CalibrationError:
        return None, None
    return H, best_inliers


def msac_cost(H, K1, center, screen, world, threshold_px) -> float:
    """MSAC cost of (H, K1) over all pairs: squared reprojection errors truncated at ``threshold_px``."""
    proj, zp, ok = project(H, K1, center, world)
    r2 = np.sum((proj - screen) ** 2, axis=1)
    r2 = np.where(ok & (zp < 0) & np.isfinite(r2), r2, np.inf)
    return float(np.sum(np.minimum(r2, threshold_px ** 2)))
