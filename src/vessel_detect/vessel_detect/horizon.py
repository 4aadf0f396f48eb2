"""The far edge of the sea (where the water meets the sky or the far shore) in one image, as a line in ideal pixels.

Why: a camera on a ship rolls and pitches with it, and a sea-plane homography fitted at rest is then wrong by
many metres near the horizon. The far edge is a straight line in ideal (undistorted) pixels whose offset follows the
camera's pitch and whose tilt follows its roll, so the graph can estimate both from it in every frame, with a
standard error, and check or replace an attitude sensor.

How (``FarEdgeFinder.find``): one image channel that separates water from what lies beyond it (by default blue minus
red: the bay's water is bluer than the shore and its haze, whose brightness changes sign along the line); the
mean profile of every strip of columns inside a search band (around a predicted line, or without one about the
lens's far edge at rest over every plausible pitch and roll); in each profile the strongest rises of the smoothed
vertical derivative, of the expected sign, to sub-pixel by a parabola through the peak; the points undistorted; a
RANSAC line through them (a straight line is what a skyline, a boat or a wave is not), then each strip's peak
searched again close to that line and a Huber-weighted least-squares fit with its covariance. Columns near the
image's sides and parts of columns touching black pixels (outside a warped frame's field of view) are left out.

Conventions: a line ``(a, b, c)`` means ``a x + b y + c = 0`` in ideal pixels of the full-resolution image (the
lens's pixels), normalised to ``a^2 + b^2 = 1`` and ``b < 0``, so ``a x + b y + c`` is negative below the line (the
sea side), as ``CameraModel.horizon_line_ideal``. An image smaller or larger than the lens's ``image_size`` is read
as a scaled copy of it; every length in ``FarEdgeSettings`` is in full-resolution pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import cv2
import numpy as np

#: Pixels whose grey level is at most this are outside a warped frame's field of view (black fill).
BLACK_LEVEL = 10
#: Smallest image (width, height) in pixels that is searched at all.
MIN_IMAGE_SIZE = (32, 16)
#: Columns this close (full-resolution pixels) to the image's left or right side are not searched.
SIDE_MARGIN_PX = 16.0
#: Fewest usable strips of columns, and of agreeing ones, that make a line.
MIN_STRIPS = 6
#: Rises kept per strip for the RANSAC search.
CANDIDATES_PER_STRIP = 4
#: RANSAC hypotheses (pairs of rises, one from each half of the image).
RANSAC_HYPOTHESES = 300
#: Iterations of the reweighted least-squares fit.
FIT_ITERATIONS = 4
#: Huber constant in robust standard deviations.
HUBER_K = 1.5
#: Floor of the robust residual scale (px): sub-pixel peaks are not better than this.
MIN_SCALE_PX = 0.05


class Lens(Protocol):
    """What ``find`` needs of a camera: its distortion centre and the maps between screen and ideal pixels."""

    center: tuple[float, float]

    def undistort(self, xs, ys) -> tuple:
        """Screen -> ideal pixels: (x_p, y_p) or (x_p, y_p, ok), NaN where there is no ideal point."""
        ...

    def distort(self, xp, yp) -> tuple:
        """Ideal -> screen pixels: (x_s, y_s)."""
        ...


@dataclass(frozen=True)
class FarEdge:
    """One image's far edge: the line ``abc`` (module docstring's convention) and how well it is known.

    found: False when no line was measured (``problem`` says why; ``abc`` is then NaN). sigma_px: standard error of
    the line's y at the ideal centre column (px). slope_sigma: standard error of its slope dy/dx. inliers: strips of
    columns whose edge point lies on the line; columns: strips searched.
    """

    found: bool
    abc: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    sigma_px: float = math.inf
    slope_sigma: float = math.inf
    inliers: int = 0
    columns: int = 0
    problem: str = ""

    def y_at(self, x_ideal):
        """Ideal y of the line at ideal x (array in, array out; NaN when not found)."""
        a, b, c = self.abc
        return -(a * np.asarray(x_ideal, dtype=float) + c) / b

    @property
    def slope(self) -> float:
        """dy/dx of the line in ideal pixels (NaN when not found)."""
        a, b, _ = self.abc
        return -a / b


def line_of(y0: float, slope: float, x0: float) -> tuple[float, float, float]:
    """The normalised line (b < 0) through (x0, y0) with slope dy/dx ``slope``."""
    norm = math.hypot(slope, 1.0)
    return (slope / norm, -1.0 / norm, (y0 - slope * x0) / norm)


def normalised_line(abc) -> tuple[float, float, float]:
    """``abc`` scaled to a^2 + b^2 = 1 and b < 0; ValueError for a vertical or degenerate line."""
    a, b, c = (float(v) for v in abc)
    norm = math.hypot(a, b) * (-1.0 if b > 0 else 1.0)
    if not math.isfinite(norm) or abs(b) < 1e-9 * max(abs(a), 1e-300):
        raise ValueError(f"not a usable far-edge line (it must not be vertical): {abc!r}")
    return (a / norm, b / norm, c / norm)


@dataclass(frozen=True)
class FarEdgeSettings:
    """How ``FarEdgeFinder`` searches; lengths in full-resolution pixels.

    search_px: half-height of the search band about a predicted line (``find``'s ``predicted_abc``).
    free_search_px: half-height at the centre column about the lens's far edge when there is no prediction (the
        band then also opens by ``max_tilt_deg`` towards the sides). Covers the shift of the ship's pitch.
    max_tilt_deg: largest tilt of the line from the reference line (degrees): the ship's roll plus a margin.
    strip_px: width of the strips of columns averaged into one profile, one edge point each.
    smooth_px: standard deviation (px) of the Gaussian smoothing of the profiles before the vertical derivative.
    colour_weights: weights of the blue, green and red channels in the searched channel.
    polarity: +1 the channel rises going down across the edge (the water's side), -1 it falls, 0 either. A grey
        image is searched as it is, for either sign.
    min_edge: weakest rise that counts, in grey levels per pixel along the unit vector of ``colour_weights``.
    window_px: half-height (px) of the window about the RANSAC line where each strip's edge point is sought for the
        final fit (all of them enter it, Huber-weighted: leaving out the rougher parts of a shore makes the line
        jump as they come and go).
    inlier_px: largest distance (px) of an edge point from a line that still counts as on it (RANSAC's vote, the
        inlier count).
    min_inlier_fraction: share of the searched strips that must lie on the line for it to be found.
    """

    search_px: float = 12.0
    free_search_px: float = 60.0
    max_tilt_deg: float = 7.0
    strip_px: int = 8
    smooth_px: float = 2.0
    colour_weights: tuple[float, float, float] = (1.0, 0.0, -1.0)
    polarity: int = 1
    min_edge: float = 1.0
    window_px: float = 5.0
    inlier_px: float = 1.5
    min_inlier_fraction: float = 0.4

    def __post_init__(self):
        positive = ("search_px", "free_search_px", "strip_px", "smooth_px", "window_px", "inlier_px")
        bad = [name for name in positive if not float(getattr(self, name)) > 0]
        if bad or not 0 < self.max_tilt_deg < 45 or self.polarity not in (-1, 0, 1) \
                or not 0 <= self.min_inlier_fraction <= 1 or self.min_edge < 0 \
                or len(self.colour_weights) != 3 or not any(self.colour_weights):
            raise ValueError(f"invalid far-edge settings {self!r}: see FarEdgeSettings for the allowed ranges")


class _View:
    """The image's geometry against the lens: scale to full resolution, strips, maps between the two."""

    def __init__(self, shape, lens, settings: FarEdgeSettings):
        self.height, self.width = shape[:2]
        full = getattr(lens, "image_size", None) if lens is not None else None
        self.scale = self.width / float(full[0]) if full else 1.0  # image px per full-resolution px
        self.mismatch = "" if not full or abs(self.height / self.scale - float(full[1])) <= 0.02 * float(full[1]) \
            else f"a {self.width}x{self.height} image is not a scaled copy of the lens's {full[0]}x{full[1]}"
        self.lens = lens
        self.center = tuple(float(v) for v in lens.center) if lens is not None else (
            (self.width / self.scale - 1) / 2.0, (self.height / self.scale - 1) / 2.0)
        self.strip = max(2, int(round(settings.strip_px * self.scale)))
        margin = int(math.ceil(SIDE_MARGIN_PX * self.scale))
        self.n_strips = max(0, (self.width - 2 * margin) // self.strip)
        self.x0 = (self.width - self.n_strips * self.strip) // 2
        centres = self.x0 + self.strip * (np.arange(self.n_strips) + 0.5) - 0.5
        self.strip_x = self.to_full(centres)

    def to_full(self, v):
        """Image pixel coordinate -> full-resolution screen coordinate (pixel centres at integers)."""
        return (np.asarray(v, dtype=float) + 0.5) / self.scale - 0.5

    def to_image(self, v):
        """Full-resolution screen coordinate -> image pixel coordinate."""
        return (np.asarray(v, dtype=float) + 0.5) * self.scale - 0.5

    def undistort(self, xs, ys):
        """Full-resolution screen -> ideal pixels (NaN off the lens)."""
        if self.lens is None:
            return np.asarray(xs, dtype=float), np.asarray(ys, dtype=float)
        out = self.lens.undistort(np.asarray(xs, dtype=float), np.asarray(ys, dtype=float))
        return np.asarray(out[0], dtype=float), np.asarray(out[1], dtype=float)

    def distort(self, xp, yp):
        """Ideal -> full-resolution screen pixels."""
        if self.lens is None:
            return np.asarray(xp, dtype=float), np.asarray(yp, dtype=float)
        out = self.lens.distort(np.asarray(xp, dtype=float), np.asarray(yp, dtype=float))
        return np.asarray(out[0], dtype=float), np.asarray(out[1], dtype=float)

    def screen_y(self, ideal_y_of_x, xs_full) -> np.ndarray:
        """Screen y at screen x ``xs_full`` of the ideal curve y = ``ideal_y_of_x``(x) (NaN off the lens)."""
        span = self.width / self.scale
        xp = np.linspace(-0.5 * span, 1.5 * span, 257)
        sx, sy = self.distort(xp, ideal_y_of_x(xp))
        ok = np.isfinite(sx) & np.isfinite(sy)
        middle = int(np.argmin(np.abs(xp - self.center[0])))
        rising = np.diff(sx) > 0  # beyond the lens's fold the screen x turns back: keep the monotonic run
        lo = middle - int(np.argmin(np.append(rising[:middle][::-1], False)))
        hi = middle + int(np.argmin(np.append(rising[middle:], False)))
        keep = np.zeros_like(ok)
        keep[lo:hi + 1] = True
        keep &= ok
        if keep.sum() < 2:
            return np.full(np.shape(xs_full), np.nan)
        return np.interp(xs_full, sx[keep], sy[keep], left=np.nan, right=np.nan)


def _image_problem(bgr) -> str | None:
    """Why ``bgr`` cannot be searched at all, or None."""
    if not isinstance(bgr, np.ndarray):
        return f"no image (got {type(bgr).__name__})"
    if bgr.ndim not in (2, 3) or (bgr.ndim == 3 and bgr.shape[2] not in (1, 3)):
        return f"not a grey or BGR image (shape {bgr.shape})"
    if bgr.dtype != np.uint8:
        return f"not an 8-bit image ({bgr.dtype})"
    if bgr.size == 0 or bgr.shape[1] < MIN_IMAGE_SIZE[0] or bgr.shape[0] < MIN_IMAGE_SIZE[1]:
        return f"image of {bgr.shape[1]}x{bgr.shape[0]} px is too small (at least {MIN_IMAGE_SIZE[0]}x" \
               f"{MIN_IMAGE_SIZE[1]})"
    return None


def _reference_line(lens) -> tuple[float, float, float] | None:
    """Where the far edge lies at rest: the lens's ``far_edge_line()`` or ``horizon_line_ideal``, else None."""
    for name in ("far_edge_line", "horizon_line_ideal"):
        line = getattr(lens, name, None)
        if line is None:
            continue
        try:
            return normalised_line(line() if callable(line) else line)
        except Exception:  # a camera without a usable line of this kind: try the next, else search everywhere
            continue
    return None


def _band(view: _View, settings: FarEdgeSettings, predicted, search_px) -> tuple[np.ndarray, np.ndarray, Any]:
    """Per strip the top and bottom screen y (full resolution) of the search band, and the band's centre line."""
    cx = view.center[0]
    if predicted is not None:
        line = normalised_line(predicted)
        half = float(settings.search_px if search_px is None else search_px)
        widen = 0.0
    else:
        line = _reference_line(view.lens)
        half = float(settings.free_search_px if search_px is None else search_px)
        widen = math.tan(math.radians(settings.max_tilt_deg))
    if line is None:  # nothing to go by: the whole height
        top = np.full(view.n_strips, view.to_full(0.0))
        return top, np.full(view.n_strips, view.to_full(view.height - 1.0)), None
    a, b, c = line

    def centre(x):
        return -(a * x + c) / b

    top = view.screen_y(lambda x: centre(x) - half - widen * np.abs(x - cx), view.strip_x)
    bottom = view.screen_y(lambda x: centre(x) + half + widen * np.abs(x - cx), view.strip_x)
    return top, bottom, line


def _profiles(bgr: np.ndarray, view: _View, rows: tuple[int, int]):
    """Strip-mean profiles (rows x strips x channels, float32) and where they touch black pixels (rows x strips).

    A pixel is black when every channel is at most ``BLACK_LEVEL``.
    """
    r0, r1 = rows
    crop = bgr[r0:r1, view.x0:view.x0 + view.n_strips * view.strip]
    if crop.ndim == 2:
        crop = crop[:, :, None]
    size = (view.n_strips, r1 - r0)
    profiles = cv2.resize(crop.astype(np.float32), size, interpolation=cv2.INTER_AREA).reshape(r1 - r0, -1,
                                                                                               crop.shape[2])
    black = cv2.inRange(crop, (0,) * crop.shape[2], (BLACK_LEVEL,) * crop.shape[2])
    if cv2.countNonZero(black) == 0:
        return profiles, np.zeros(size[::-1], bool)
    black = cv2.resize(black, size, interpolation=cv2.INTER_AREA) > 0
    return profiles, black


def _derivative(profiles: np.ndarray, view: _View, settings: FarEdgeSettings) -> np.ndarray:
    """Smoothed vertical derivative of every channel's profiles, channel units per full-resolution pixel."""
    sigma = max(0.5, settings.smooth_px * view.scale)
    rows, strips, channels = profiles.shape
    smooth = cv2.GaussianBlur(profiles.reshape(rows, strips * channels), (1, 2 * int(math.ceil(3 * sigma)) + 1),
                              sigmaX=0.1, sigmaY=sigma, borderType=cv2.BORDER_REPLICATE).reshape(profiles.shape)
    d = np.zeros_like(smooth)
    d[1:-1] = 0.5 * (smooth[2:] - smooth[:-2]) * view.scale
    return d


def _signed(d: np.ndarray, weights: np.ndarray, polarity: int) -> np.ndarray:
    """The derivative along colour ``weights`` (per strip, or one for all), positive where it has the polarity."""
    along = np.einsum("rsc,sc->rs", d, np.broadcast_to(weights, d.shape[1:]))
    return np.abs(along) if polarity == 0 else along * polarity


def _peaks(d: np.ndarray, allowed: np.ndarray, k: int, min_edge: float):
    """Up to ``k`` strongest local maxima per column of ``d`` where ``allowed``: (column, sub-pixel row, strength)."""
    rows = d.shape[0]
    if rows < 3:
        return np.zeros(0, int), np.zeros(0), np.zeros(0)
    mid = d[1:-1]
    local = np.zeros_like(allowed)
    local[1:-1] = (mid >= d[:-2]) & (mid > d[2:])
    score = np.where(local & allowed & (d >= min_edge), d, -np.inf)
    if k == 1:
        top = np.argmax(score, axis=0)[None, :]
    else:
        top = np.argpartition(-score, k - 1, axis=0)[:k] if k < rows else np.argsort(-score, axis=0)
    value = np.take_along_axis(score, top, axis=0)
    keep = np.isfinite(value)
    row, col = top[keep], np.nonzero(keep)[1]
    left, centre, right = d[row - 1, col], d[row, col], d[row + 1, col]
    curvature = left - 2.0 * centre + right
    shift = np.where(curvature < 0, 0.5 * (left - right) / np.where(curvature < 0, curvature, -1.0), 0.0)
    return col, row + np.clip(shift, -0.5, 0.5), centre


def _weights(strength: np.ndarray, col: np.ndarray) -> np.ndarray:
    """RANSAC vote of each rise: its strength against a typical strip's strongest rise, at most 1."""
    best = np.zeros(int(col.max()) + 1)
    np.maximum.at(best, col, strength)
    typical = float(np.median(best[best > 0]))
    return np.minimum(1.0, strength / max(typical, 1e-9))


def _ransac(x, y, w, cx: float, ref_slope: float, settings: FarEdgeSettings):
    """(y at cx, slope) of the line through pairs of rises that the most (vote-weighted) rises lie near; or None."""
    split = float(np.median(x))
    left, right = np.flatnonzero(x < split), np.flatnonzero(x >= split)
    if len(left) == 0 or len(right) == 0:
        return None
    rng = np.random.default_rng(0)  # reproducible: the same image gives the same line
    w = np.maximum(w, 1e-6)
    i = rng.choice(left, RANSAC_HYPOTHESES, p=w[left] / w[left].sum())
    j = rng.choice(right, RANSAC_HYPOTHESES, p=w[right] / w[right].sum())
    dx = x[j] - x[i]
    ok = dx > 1.0
    slope = (y[j] - y[i]) / np.where(ok, dx, 1.0)
    tilt = np.abs(np.degrees(np.arctan(slope) - math.atan(ref_slope)))
    ok &= tilt <= settings.max_tilt_deg
    if not ok.any():
        return None
    slope = slope[ok]
    y0 = y[i][ok] + slope * (cx - x[i][ok])
    dist = np.abs(y[None, :] - y0[:, None] - slope[:, None] * (x[None, :] - cx)) / np.sqrt(1 + slope[:, None] ** 2)
    score = (w[None, :] * np.clip(1.0 - (dist / settings.inlier_px) ** 2, 0.0, None)).sum(axis=1)
    best = int(np.argmax(score))
    return float(y0[best]), float(slope[best])


def _huber_weights(r: np.ndarray) -> np.ndarray:
    """Huber weights of the residuals ``r`` about their robust scale."""
    scale = max(MIN_SCALE_PX, 1.4826 * float(np.median(np.abs(r))))
    return np.minimum(1.0, HUBER_K * scale / np.maximum(np.abs(r), 1e-12))


def _fit(x, y, cx: float, start):
    """Huber-weighted least squares y = y0 + m (x - cx) from ``start``: ((y0, m), covariance 2x2, residuals).

    The covariance is the weighted residuals' variance times the inverse normal matrix.
    """
    y0, m = start
    u = x - cx
    for _ in range(FIT_ITERATIONS):
        w = _huber_weights(y - (y0 + m * u))
        s0, s1, s2 = w.sum(), (w * u).sum(), (w * u * u).sum()
        t0, t1 = (w * y).sum(), (w * u * y).sum()
        det = s0 * s2 - s1 * s1
        if not det > 0:
            return None
        y0, m = (s2 * t0 - s1 * t1) / det, (s0 * t1 - s1 * t0) / det
    r = y - (y0 + m * u)
    variance = max(MIN_SCALE_PX ** 2, float((w * r * r).sum() / (len(r) - 2)))
    covariance = variance / det * np.array([[s2, -s1], [-s1, s0]])
    return (float(y0), float(m)), covariance, r


class _Search:
    """One image's search: the band's profiles, their derivatives and where rises may be taken."""

    def __init__(self, bgr: np.ndarray, view: _View, settings: FarEdgeSettings, top, bottom):
        self.view, self.settings = view, settings
        pad = int(math.ceil(3 * max(0.5, settings.smooth_px * view.scale))) + 2
        usable = np.isfinite(top) & np.isfinite(bottom)
        lo = view.to_image(np.where(usable, top, np.inf))
        hi = view.to_image(np.where(usable, bottom, -np.inf))
        self.r0 = int(np.clip(math.floor(np.min(lo)) - pad, 0, view.height)) if usable.any() else 0
        self.r1 = int(np.clip(math.ceil(np.max(hi)) + pad + 1, 0, view.height)) if usable.any() else 0
        if self.r1 - self.r0 < 2 * pad + 3:
            self.allowed = np.zeros((0, view.n_strips), bool)
            return
        self.profiles, black = _profiles(bgr, view, (self.r0, self.r1))
        if black.any():  # the fill's border is blurred by the warp and the JPEG: widen it by a strip and a few rows
            black = cv2.dilate(black.astype(np.uint8), np.ones((2 * pad + 1, 3), np.uint8)) > 0
        self.d3 = _derivative(self.profiles, view, settings)
        colour = self.d3.shape[2] == 3
        weights = np.asarray(settings.colour_weights if colour else (1.0,), dtype=np.float32)
        self.d = _signed(self.d3, weights / np.linalg.norm(weights), settings.polarity if colour else 0)
        rows = np.arange(self.r0, self.r1)[:, None]
        inside = (rows >= np.where(usable, lo, np.inf)[None, :]) & (rows <= np.where(usable, hi, -np.inf)[None, :])
        inside[:pad] = inside[-pad:] = False  # the smoothing needs rows on both sides
        self.allowed = inside & ~black

    @property
    def columns(self) -> int:
        """Strips with at least one searchable row."""
        return int(self.allowed.any(axis=0).sum())

    def candidates(self):
        """Rises for the RANSAC search (up to ``CANDIDATES_PER_STRIP`` in each pair of strips averaged)."""
        n = self.d.shape[1] // 2 * 2
        d = 0.5 * (self.d[:, 0:n:2] + self.d[:, 1:n:2])
        allowed = self.allowed[:, 0:n:2] & self.allowed[:, 1:n:2]
        x = 0.5 * (self.view.strip_x[0:n:2] + self.view.strip_x[1:n:2])
        return self._ideal(d, allowed, CANDIDATES_PER_STRIP, x)

    def edge_points(self, centre: np.ndarray):
        """Each strip's strongest rise within ``window_px`` of the rows ``centre``."""
        return self._ideal(self.d, self.near(centre), 1, self.view.strip_x)

    def _ideal(self, d: np.ndarray, allowed: np.ndarray, k: int, strip_x: np.ndarray):
        """Rises of ``d`` as ideal points: (x, y, strength, column of ``d``), finite only."""
        col, row, strength = _peaks(d, allowed, k, self.settings.min_edge)
        xp, yp = self.view.undistort(strip_x[col], self.view.to_full(row + self.r0))
        ok = np.isfinite(xp) & np.isfinite(yp)
        return xp[ok], yp[ok], strength[ok], col[ok]

    def rows_of(self, y0: float, slope: float, cx: float) -> np.ndarray:
        """Per strip the profile row (from ``r0``) of the ideal line y = y0 + slope (x - cx); NaN off the lens."""
        ys = self.view.screen_y(lambda x: y0 + slope * (x - cx), self.view.strip_x)
        return self.view.to_image(ys) - self.r0

    def near(self, centre: np.ndarray) -> np.ndarray:
        """Where rises may be taken within ``window_px`` of the rows ``centre``."""
        rows = np.arange(self.r1 - self.r0)[:, None]
        with np.errstate(invalid="ignore"):
            return self.allowed & (np.abs(rows - centre[None, :]) <= self.settings.window_px * self.view.scale)


class FarEdgeFinder:
    """Measures the far edge in images (module docstring); stateless apart from its settings, so reusable."""

    def __init__(self, settings: FarEdgeSettings | None = None):
        self.settings = settings or FarEdgeSettings()

    def find(self, bgr, lens: Lens | None = None, predicted_abc=None, search_px: float | None = None) -> FarEdge:
        """The far edge in ``bgr`` (BGR or grey, any size) seen through ``lens`` (None: no distortion).

        ``predicted_abc``: a line (module docstring's convention) to search ``search_px`` (default
        ``settings.search_px``) about. None searches every plausible pitch and roll: ``search_px`` (default
        ``settings.free_search_px``) about the lens's far edge at rest (``far_edge_line()`` or
        ``horizon_line_ideal``, when the lens has one; else the whole height), opening by ``settings.max_tilt_deg``
        towards the sides. Never raises for a bad image or
        prediction: ``found`` is then False and ``problem`` says why.
        """
        problem = _image_problem(bgr)
        if problem is not None:
            return FarEdge(False, problem=problem)
        view = _View(bgr.shape, lens, self.settings)
        if view.mismatch:
            return FarEdge(False, problem=view.mismatch)
        try:
            top, bottom, reference = _band(view, self.settings, predicted_abc, search_px)
        except (TypeError, ValueError) as error:
            return FarEdge(False, problem=f"unusable prediction: {error}")
        search = _Search(bgr, view, self.settings, top, bottom)
        if search.columns < MIN_STRIPS:
            return FarEdge(False, columns=search.columns, problem=(
                f"only {search.columns} strips of columns can be searched: the search band is off the image or "
                "black"))
        return self._measure(search, view, reference)

    def _measure(self, search: _Search, view: _View, reference) -> FarEdge:
        cx, columns = view.center[0], search.columns
        x, y, strength, col = search.candidates()
        if len(np.unique(col)) < MIN_STRIPS // 2:
            return FarEdge(False, columns=columns, problem=(
                f"no edge: a rise of at least {self.settings.min_edge} per px of the expected sign in only "
                f"{len(np.unique(col))} of {columns // 2} pairs of strips"))
        ref_slope = -reference[0] / reference[1] if reference is not None else 0.0
        line = _ransac(x, y, _weights(strength, col), cx, ref_slope, self.settings)
        fit = None
        for _ in range(2 if line is not None else 0):
            centre = search.rows_of(*line, cx)
            x, y, _, _ = search.edge_points(centre)
            fit = _fit(x, y, cx, line) if len(x) >= MIN_STRIPS else None
            if fit is None:
                break
            line = fit[0]
        if fit is None:
            return FarEdge(False, columns=columns, problem=f"no straight edge across the {columns} strips searched")
        (y0, slope), cov, residuals = fit
        inliers = int(np.count_nonzero(np.abs(residuals) <= self.settings.inlier_px))
        needed = max(MIN_STRIPS, math.ceil(self.settings.min_inlier_fraction * columns))
        if inliers < needed:
            return FarEdge(False, columns=columns, inliers=inliers, problem=(
                f"only {inliers} of {columns} strips lie on the best line (need {needed})"))
        return FarEdge(True, line_of(y0, slope, cx), math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1]), inliers, columns)


def draw_far_edge(bgr: np.ndarray, edge: FarEdge, lens: Lens | None, color=(0, 255, 255), scale: float = 1.0,
                  thickness: int = 1) -> np.ndarray:
    """Draw ``edge`` on ``bgr`` (in place, returned) as the screen curve of its line; ``scale``: image/lens pixels."""
    if not edge.found or bgr is None or bgr.ndim < 2 or bgr.size == 0:
        return bgr
    height, width = bgr.shape[:2]
    span = width / scale
    xp = np.linspace(-0.25 * span, 1.25 * span, 301)
    if lens is None:
        xs, ys = xp, edge.y_at(xp)
    else:
        out = lens.distort(xp, edge.y_at(xp))
        xs, ys = np.asarray(out[0], dtype=float), np.asarray(out[1], dtype=float)
        undone = lens.undistort(xs, ys)  # beyond the lens's fold the curve folds back: keep what maps back
        xs = np.where(np.abs(np.asarray(undone[0], dtype=float) - xp) < 0.5, xs, np.nan)
    ok = np.isfinite(xs) & np.isfinite(ys)
    pts = np.column_stack([(xs[ok] + 0.5) * scale - 0.5, (ys[ok] + 0.5) * scale - 0.5])
    inside = (pts[:, 0] > -width) & (pts[:, 0] < 2 * width) & (pts[:, 1] > -height) & (pts[:, 1] < 2 * height)
    if inside.sum() >= 2:
        shift = 4
        poly = np.round(pts[inside] * (1 << shift)).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(bgr, [poly], False, color, thickness, cv2.LINE_AA, shift)
    return bgr
