"""The camera model's lens: one radial term K1 about the distortion centre, and its inverse.

``x_s = x_c + (x_p - x_c)(1 + K1 r_p^2)`` (y likewise), ``r_p`` the ideal point's distance from the centre. With
K1 < 0 the map folds at ``r_p = sqrt(-1 / (3 K1))``: ideal points beyond the fold and screen points beyond
``rs_max`` have no counterpart, so they come back invalid (NaN) instead of as a point on the wrong branch.
Apart from the homography, ``CameraModel`` reaches the screen only through this class.
"""

from __future__ import annotations

import math

import numpy as np

#: Undistortion must reproduce the screen point to this many pixels.
UNDISTORT_TOLERANCE_PX = 1e-6
_UNDISTORT_MAX_ITER = 80


def _arr(value) -> np.ndarray:
    return np.asarray(value, dtype=float)


class RadialLens:
    """The radial distortion of a ``CameraModel``: K1 (1/px^2, already checked) about ``center`` (screen pixels).

    ``distort`` maps ideal pixels to the screen and ``undistort`` back; ``r_fold`` is the ideal radius where the
    map folds and ``rs_max`` the screen radius it reaches there (both inf when K1 >= 0).
    """

    __slots__ = ("K1", "center", "r_fold", "rs_max")

    def __init__(self, K1: float, center: tuple[float, float]):
        self.K1 = K1
        self.center = center
        if K1 < 0:
            self.r_fold = math.sqrt(-1.0 / (3.0 * K1))
            self.rs_max = self.r_fold * (1.0 + K1 * self.r_fold ** 2)
        else:
            self.r_fold = math.inf
            self.rs_max = math.inf

    def distort(self, xp, yp):
        """Ideal pixel -> screen pixel; the inverse is ``undistort``."""
        cx, cy = self.center
        dx = _arr(xp) - cx
        dy = _arr(yp) - cy
        f = 1.0 + self.K1 * (dx * dx + dy * dy)
        return cx + dx * f, cy + dy * f

    def undistort(self, xs, ys):
        """Screen pixel -> (x_p, y_p, ok), the inverse of ``distort``: Newton on the radius on the monotonic branch.

        ``ok`` is False (and x_p, y_p NaN) where the screen point lies beyond the fold or Newton did not reproduce
        it to ``UNDISTORT_TOLERANCE_PX``.
        """
        cx, cy = self.center
        dx = _arr(xs) - cx
        dy = _arr(ys) - cy
        dx, dy = np.broadcast_arrays(dx, dy)
        shape = dx.shape
        dx = dx.ravel()
        dy = dy.ravel()
        rs = np.hypot(dx, dy)
        finite = np.isfinite(rs)
        if self.K1 == 0.0:
            ok = finite
            with np.errstate(invalid="ignore"):
                return (np.where(ok, cx + dx, np.nan).reshape(shape), np.where(ok, cy + dy, np.nan).reshape(shape),
                        ok.reshape(shape))
        rs_safe = np.where(finite, rs, 0.0)
        reachable = finite & (rs_safe <= self.rs_max)
        u = self._ideal_radius(rs_safe, reachable)
        resid = np.abs(u + self.K1 * u ** 3 - rs_safe)
        ok = reachable & (resid < UNDISTORT_TOLERANCE_PX) & (u >= 0)
        if self.K1 < 0:
            ok &= u <= self.r_fold
        scale = np.where(rs_safe > 0, u / np.where(rs_safe > 0, rs_safe, 1.0), 1.0)
        xp = np.where(ok, cx + dx * scale, np.nan)
        yp = np.where(ok, cy + dy * scale, np.nan)
        return xp.reshape(shape), yp.reshape(shape), ok.reshape(shape)

    def _ideal_radius(self, rs_safe: np.ndarray, reachable: np.ndarray) -> np.ndarray:
        """Newton on u + K1 u^3 = r_s from u = r_s, for the ``reachable`` screen radii."""
        K1 = self.K1
        u = rs_safe.copy()
        if K1 < 0:
            # Newton from r_s approaches the root monotonically from below, but could cross the fold on
            # rounding near the limit; keep iterates on the monotonic branch.
            u = np.minimum(u, self.r_fold)
        active = reachable.copy()
        for _ in range(_UNDISTORT_MAX_ITER):
            if not active.any():
                break
            ua = u[active]
            resid = ua + K1 * ua ** 3 - rs_safe[active]
            deriv = 1.0 + 3.0 * K1 * ua * ua
            step = resid / np.where(deriv > 1e-12, deriv, 1e-12)
            ua = ua - step
            if K1 < 0:
                ua = np.minimum(ua, self.r_fold)
            u[active] = ua
            done = np.abs(step) < 1e-12 * np.maximum(1.0, ua)
            idx = np.flatnonzero(active)
            active[idx[done]] = False
        return u

    def in_domain(self, xp, yp):
        """True where the ideal point lies inside the fold, the part of the plane ``distort`` maps one to one."""
        cx, cy = self.center
        r2 = (_arr(xp) - cx) ** 2 + (_arr(yp) - cy) ** 2
        return np.isfinite(r2) & (r2 < self.r_fold ** 2)

    def undistort_jacobian(self, xp, yp):
        """d(x_p, y_p)/d(x_s, y_s) at ideal points, shape (..., 2, 2): ``distort``'s Jacobian inverted in closed form.

        ``distort``'s Jacobian is f I + 2 K1 d d^T, d the ideal point's offset from the centre.
        """
        cx, cy = self.center
        dx = xp - cx
        dy = yp - cy
        f = 1.0 + self.K1 * (dx * dx + dy * dy)
        k2 = 2.0 * self.K1
        a11 = f + k2 * dx * dx
        a12 = k2 * dx * dy
        a22 = f + k2 * dy * dy
        det = a11 * a22 - a12 * a12
        J = np.empty(np.shape(dx) + (2, 2))
        J[..., 0, 0] = a22 / det
        J[..., 0, 1] = -a12 / det
        J[..., 1, 0] = -a12 / det
        J[..., 1, 1] = a11 / det
        return J

    def line_y(self, line: tuple[float, float, float], xs):
        """Screen y at screen x of the image of the ideal line a x_p + b y_p + c = 0 (``line``, a^2 + b^2 = 1).

        NaN where the line is vertical or its point at ``xs`` lies off the lens domain. The line curves on the screen
        with the lens, so x_p is found by Newton on the screen x of the line's points.
        """
        xs = _arr(xs)
        a, b, c = line
        if abs(b) < 1e-9:
            return np.full(xs.shape, np.nan)
        cx, cy = self.center
        K1 = self.K1
        slope = -a / b
        xp = xs.copy()
        for _ in range(60):
            yp = -(a * xp + c) / b
            dx = xp - cx
            dy = yp - cy
            f = 1.0 + K1 * (dx * dx + dy * dy)
            resid = cx + dx * f - xs
            deriv = f + 2.0 * K1 * dx * (dx + dy * slope)
            step = resid / np.where(np.abs(deriv) > 1e-12, deriv, 1e-12)
            xp = xp - step
            if np.all(~np.isfinite(step) | (np.abs(step) < 1e-10)):
                break
        yp = -(a * xp + c) / b
        ok = self.in_domain(xp, yp)
        _, ys = self.distort(xp, yp)
        ok &= np.isfinite(ys) & (np.abs(self.distort(xp, yp)[0] - xs) < 1e-6)
        return np.where(ok, ys, np.nan)
