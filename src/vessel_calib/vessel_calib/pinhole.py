"""The pinhole camera behind a sea-plane homography: focal length, height above the water, the point below it.

H = K [r1 r2 t] for a camera with square pixels and its principal point at the distortion centre; the water-level
correction scales about the camera's nadir at its height (``CameraModel.at_water_level``), and the label-free
calibration search rejects hypotheses no upright camera above the sea can produce.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PinholeGeometry:
    """The pinhole camera a sea-plane homography implies (``CameraModel.pinhole``).

    focal_px: focal length, ideal pixels. height_m: camera height above the water. nadir_xy: the sea point below
    the camera, world metres (near (0, 0) when the camera's GPS position is right). skew: |cos| of the angle
    between H's first two rotation columns after the fit (0 for an exact pinhole), aspect their length ratio (1).
    above_water: False when the camera centre H implies lies under the sea plane (no real camera: a wrong match).
    """

    focal_px: float
    height_m: float
    nadir_xy: tuple[float, float]
    skew: float
    aspect: float
    above_water: bool = True


def pinhole_decomposition(H: np.ndarray, center) -> tuple[np.ndarray, ...]:
    """The pinhole cameras behind (B, 3, 3) sea-plane homographies: ``CameraModel.pinhole`` for many at once.

    Returns focal (B,), camera centre (B, 3) in world metres, skew (B,), aspect (B,), valid (B,); the label-free
    search decomposes its hypotheses with it.
    H = K [r1 r2 t] for a camera with square pixels and its principal point at ``center``: the focal length is the
    one that makes r1 and r2 orthogonal and of equal length (least squares of the two conditions). ``valid`` is
    False where no positive focal length fits; the other values there are meaningless.
    """
    cx, cy = center
    a = H[:, 0, :] - cx * H[:, 2, :]
    b = H[:, 1, :] - cy * H[:, 2, :]
    c = H[:, 2, :]
    p, q = a[:, 0] * a[:, 1] + b[:, 0] * b[:, 1], c[:, 0] * c[:, 1]
    r = a[:, 0] ** 2 + b[:, 0] ** 2 - a[:, 1] ** 2 - b[:, 1] ** 2
    s = c[:, 0] ** 2 - c[:, 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = p * p + r * r
        inv_f2 = np.where(denom > 0, -(p * q + r * s) / np.where(denom > 0, denom, 1.0), np.nan)
        valid = np.isfinite(inv_f2) & (inv_f2 > 0)
        f = 1.0 / np.sqrt(np.where(valid, inv_f2, 1.0))
        M = np.stack([a / f[:, None], b / f[:, None], c], axis=1)
        n1, n2 = np.linalg.norm(M[:, :, 0], axis=1), np.linalg.norm(M[:, :, 1], axis=1)
        scale = -1.0 / np.sqrt(n1 * n2)  # z_p < 0 in front: the camera's z is -z_p
        r1, r2, t = (M[:, :, k] * scale[:, None] for k in range(3))
        skew = np.abs(np.sum(r1 * r2, axis=1)) / (np.linalg.norm(r1, axis=1) * np.linalg.norm(r2, axis=1))
        aspect = n1 / n2
    finite = valid & np.isfinite(r1).all(axis=1) & np.isfinite(r2).all(axis=1) & np.isfinite(t).all(axis=1)
    rotation = np.where(finite[:, None, None], np.stack([r1, r2, np.cross(r1, r2)], axis=2), np.eye(3))
    u, _, vt = np.linalg.svd(rotation)
    centre = -np.einsum("bji,bj->bi", u @ vt, np.where(finite[:, None], t, 0.0))
    return f, centre, skew, aspect, valid


def pinhole_geometry(H: np.ndarray, center) -> PinholeGeometry | None:
    """The ``PinholeGeometry`` of one homography; None where no positive focal length fits."""
    focal, centre, skew, aspect, valid = pinhole_decomposition(H[None], center)
    if not valid[0]:
        return None
    return PinholeGeometry(focal_px=float(focal[0]), height_m=float(abs(centre[0, 2])),
                           nadir_xy=(float(centre[0, 0]), float(centre[0, 1])), skew=float(skew[0]),
                           aspect=float(aspect[0]), above_water=bool(centre[0, 2] > 0))
