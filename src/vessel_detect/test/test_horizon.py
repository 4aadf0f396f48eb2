"""The far edge of the sea (vessel_detect.horizon): sub-pixel lines in synthetic images, failures, the real camera."""

from __future__ import annotations

import math
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from vessel_calib.radial_lens import RadialLens
from vessel_detect.horizon import (
    FarEdge,
    FarEdgeFinder,
    FarEdgeSettings,
    draw_far_edge,
    line_of,
    normalised_line,
)

REPO = Path(__file__).resolve().parents[3]
K1 = -3.5e-7  # about the challenge camera's
SIZE = (1280, 720)
# BGR: a light, warm shore over bluer, darker water, a bright sky higher up.
SHORE, WATER, SKY = np.array([140.0, 160.0, 185.0]), np.array([150.0, 140.0, 120.0]), np.array([230.0, 215.0, 200.0])


class Lens:
    """The smallest camera ``find`` accepts: centre, image size, undistort and distort (a ``RadialLens``)."""

    def __init__(self, k1: float = K1, horizon=None):
        self._lens = RadialLens(k1, (640.0, 360.0))
        self.center = (640.0, 360.0)
        self.image_size = SIZE
        if horizon is not None:
            self.horizon_line_ideal = horizon

    def undistort(self, xs, ys):
        return self._lens.undistort(xs, ys)

    def distort(self, xp, yp):
        return self._lens.distort(xp, yp)


def _erf(x):
    """Abramowitz-Stegun 7.1.26 (error below 2e-7), vectorised."""
    sign, x = np.sign(x), np.abs(x)
    t = 1.0 / (1.0 + 0.3275911 * x)
    poly = ((((1.061405429 * t - 1.453152027) * t + 1.421413758) * t - 0.284496736) * t + 0.254829592) * t
    return sign * (1.0 - poly * np.exp(-x * x))


_IDEAL: dict = {}


def _ideal_grid(k1: float):
    """Ideal coordinates of every screen pixel (NaN beyond the lens's fold, which renders black)."""
    if k1 not in _IDEAL:
        ys, xs = np.mgrid[0:SIZE[1], 0:SIZE[0]].astype(float)
        _IDEAL[k1] = RadialLens(k1, (640.0, 360.0)).undistort(xs, ys)[:2]
    return _IDEAL[k1]


def render(abc, k1: float = K1, noise: float = 4.0, blur: float = 1.2, seed: int = 0) -> np.ndarray:
    """A 1280x720 BGR view of shore over water meeting on the ideal line ``abc``, sky 25 px higher, with noise."""
    xp, yp = _ideal_grid(k1)
    a, b, c = abc
    below = -(a * xp + b * yp + c)  # distance below the line
    water = 0.5 * (1.0 + _erf(below / (blur * math.sqrt(2.0))))[..., None]
    shore = 0.5 * (1.0 + _erf((below + 25.0) / (3.0 * math.sqrt(2.0))))[..., None]
    image = SKY * (1.0 - shore) + (SHORE * (1.0 - water) + WATER * water) * shore
    image = image + np.random.default_rng(seed).normal(0.0, noise, image.shape)
    return np.clip(np.round(np.nan_to_num(image, nan=0.0)), 0, 255).astype(np.uint8)


def jpeg(image: np.ndarray, quality: int = 90) -> np.ndarray:
    return cv2.imdecode(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])[1], cv2.IMREAD_COLOR)


def assert_line(edge: FarEdge, y0: float, slope: float, offset_tol: float = 0.05, slope_tol: float = 1e-4):
    assert edge.found, edge.problem
    assert edge.y_at(640.0) == pytest.approx(y0, abs=offset_tol)
    assert edge.slope == pytest.approx(slope, abs=slope_tol)
    a, b, _ = edge.abc
    assert b < 0 and a * a + b * b == pytest.approx(1.0)
    assert 0 < edge.sigma_px < 0.2 and 0 < edge.slope_sigma < 1e-3
    assert edge.inliers <= edge.columns


# ----------------------------------------------------------------- lines
def test_lines_are_normalised_with_the_sea_side_negative():
    a, b, c = line_of(417.3, 0.05, 640.0)
    assert b < 0 and math.hypot(a, b) == pytest.approx(1.0)
    assert a * 640.0 + b * 417.3 + c == pytest.approx(0.0, abs=1e-9)
    assert a * 640.0 + b * 500.0 + c < 0  # below the line: the sea
    assert normalised_line((-2 * a, -2 * b, -2 * c)) == pytest.approx((a, b, c))
    edge = FarEdge(True, (a, b, c))
    assert edge.y_at([640.0, 740.0]) == pytest.approx([417.3, 422.3])
    assert edge.slope == pytest.approx(0.05)
    with pytest.raises(ValueError):
        normalised_line((1.0, 0.0, -5.0))


def test_settings_are_checked():
    with pytest.raises(ValueError):
        FarEdgeSettings(strip_px=0)
    with pytest.raises(ValueError):
        FarEdgeSettings(polarity=2)


# ----------------------------------------------------------------- synthetic images
@pytest.mark.parametrize(("y0", "tilt_deg"), [(417.0, 0.0), (417.3, 3.5), (441.55, -5.5), (389.8, 6.0)])
def test_a_tilted_line_is_found_to_a_fraction_of_a_pixel(y0, tilt_deg):
    slope = math.tan(math.radians(tilt_deg))
    lens = Lens(horizon=line_of(412.0, 0.008, 640.0))  # the search band about it covers pitch and roll
    assert_line(FarEdgeFinder().find(render(line_of(y0, slope, 640.0)), lens), y0, slope)


def test_without_any_reference_the_whole_height_is_searched():
    slope = math.tan(math.radians(-2.0))
    assert_line(FarEdgeFinder().find(render(line_of(300.4, slope, 640.0)), Lens()), 300.4, slope)


def test_without_a_lens_screen_pixels_are_ideal():
    slope = math.tan(math.radians(2.0))
    assert_line(FarEdgeFinder().find(render(line_of(420.2, slope, 640.0), k1=0.0), None), 420.2, slope)


def test_ignoring_the_lens_would_be_wrong():
    """The curved screen image of a straight ideal line: a finder that skipped undistortion would miss it."""
    image = render(line_of(417.3, 0.0, 640.0))
    edge = FarEdgeFinder().find(image, None)
    assert not edge.found or abs(edge.y_at(640.0) - 417.3) > 0.3 or edge.sigma_px > 0.2


def test_black_outside_a_warped_field_of_view_is_left_out():
    y0, slope = 430.25, math.tan(math.radians(4.0))
    image = render(line_of(y0, slope, 640.0), noise=5.0)
    ys, xs = np.mgrid[0:SIZE[1], 0:SIZE[0]]
    image[xs < 260 + 0.5 * (ys - 300)] = 0  # slanted borders across the edge, as a rolled, yawed warp leaves
    image[xs > 1120 - 0.3 * (ys - 300)] = 0
    edge = FarEdgeFinder().find(jpeg(image, 95), Lens(horizon=line_of(412.0, 0.008, 640.0)))
    assert_line(edge, y0, slope, 0.1, 2e-4)
    assert edge.columns < 0.75 * FarEdgeFinder().find(render(line_of(y0, slope, 640.0)), Lens()).columns


def test_a_boat_on_the_line_does_not_move_it():
    y0, slope = 417.4, math.tan(math.radians(-3.0))
    image = render(line_of(y0, slope, 640.0), noise=5.0)
    for x, width in ((560, 110), (900, 40)):
        y = int(round(y0 + slope * (x - 640)))
        image[y - 30:y + 6, x:x + width] = (245, 245, 245)  # white hull and sail across the line
        image[y - 8:y + 3, x + 10:x + width // 2] = (35, 40, 45)  # dark cabin
    for x in range(260, 360):  # a bright blue wake 3 px under the line: a stronger rise there, an outlier
        y = int(round(y0 + slope * (x - 640)))
        image[y + 3:y + 9, x] = (210, 150, 90)
    edge = FarEdgeFinder().find(jpeg(image), Lens(horizon=line_of(412.0, 0.008, 640.0)))
    assert_line(edge, y0, slope, 0.1, 2e-4)


@pytest.mark.parametrize("factor", [0.5, 0.25])
def test_a_scaled_image_gives_the_full_resolution_line(factor):
    y0, slope = 418.6, math.tan(math.radians(2.5))
    image = cv2.resize(render(line_of(y0, slope, 640.0)), None, fx=factor, fy=factor, interpolation=cv2.INTER_AREA)
    edge = FarEdgeFinder().find(image, Lens(horizon=line_of(412.0, 0.008, 640.0)))
    assert_line(edge, y0, slope, 0.15, 3e-4)


def test_a_grey_image_is_searched_for_either_sign():
    """Without colour the sky's edge 25 px higher is as good a candidate: a prediction tells them apart."""
    y0, slope = 417.3, math.tan(math.radians(1.0))
    grey = cv2.cvtColor(render(line_of(y0, slope, 640.0)), cv2.COLOR_BGR2GRAY)  # water darker: a fall
    edge = FarEdgeFinder().find(grey, Lens(), predicted_abc=line_of(y0 + 5.0, slope, 640.0))
    assert_line(edge, y0, slope, 0.1, 2e-4)


def test_a_prediction_narrows_the_search():
    y0, slope = 425.7, math.tan(math.radians(-4.0))
    image = render(line_of(y0, slope, 640.0))
    finder = FarEdgeFinder()
    assert_line(finder.find(image, Lens(), predicted_abc=line_of(y0 + 7.0, slope + 0.01, 640.0)), y0, slope)
    missed = finder.find(image, Lens(), predicted_abc=line_of(y0 - 40.0, slope, 640.0), search_px=10.0)
    assert not missed.found and missed.problem


# ----------------------------------------------------------------- failures
@pytest.mark.parametrize("name", ["grey", "noise", "black", "tiny", "empty", "none", "float", "four channels"])
def test_images_without_an_edge_give_a_problem_not_an_exception(name):
    rng = np.random.default_rng(1)
    image = {
        "grey": np.full((720, 1280, 3), 128, np.uint8),
        "noise": np.clip(128 + rng.normal(0, 25, (720, 1280, 3)), 0, 255).astype(np.uint8),
        "black": np.zeros((720, 1280, 3), np.uint8),
        "tiny": np.full((10, 20, 3), 128, np.uint8),
        "empty": np.zeros((0, 0, 3), np.uint8),
        "none": None,
        "float": np.full((720, 1280, 3), 0.5, np.float32),
        "four channels": np.full((720, 1280, 4), 128, np.uint8),
    }[name]
    edge = FarEdgeFinder().find(image, Lens(horizon=line_of(412.0, 0.008, 640.0)))
    assert not edge.found
    assert edge.problem
    assert math.isnan(edge.y_at(640.0))


@pytest.mark.parametrize("prediction", [(math.nan, -1.0, 400.0), (1.0, 0.0, -640.0), "abc"])
def test_an_unusable_prediction_gives_a_problem(prediction):
    edge = FarEdgeFinder().find(render(line_of(417.0, 0.0, 640.0)), Lens(), predicted_abc=prediction)
    assert not edge.found and "prediction" in edge.problem


def test_an_image_of_another_shape_than_the_lens_is_refused():
    edge = FarEdgeFinder().find(np.full((480, 640, 3), 128, np.uint8), Lens())
    assert not edge.found and "scaled copy" in edge.problem


# ----------------------------------------------------------------- drawing
def test_the_drawn_curve_follows_the_line_on_the_screen():
    lens = Lens()
    edge = FarEdge(True, line_of(417.0, 0.05, 640.0))
    canvas = draw_far_edge(np.zeros((720, 1280, 3), np.uint8), edge, lens, (0, 0, 255))
    for xs in (40.0, 640.0, 1200.0):
        xp, yp = lens.undistort(np.array([xs]), np.array([417.0 + 0.05 * (xs - 640.0)]))[:2]
        # the screen y of the ideal line at screen x: fixed point of distort(x_p, line(x_p)).x = xs
        for _ in range(30):
            sx, _ = lens.distort(xp, edge.y_at(xp))
            xp = xp + (xs - sx)
        _, sy = lens.distort(xp, edge.y_at(xp))
        column = canvas[:, int(xs), 2]
        assert column.max() > 0 and abs(int(np.argmax(column)) - float(sy[0])) <= 1.0
    half = draw_far_edge(np.zeros((360, 640, 3), np.uint8), edge, lens, (0, 0, 255), scale=0.5)
    assert abs(int(np.argmax(half[:, 320, 2])) - (417.0 + 0.5) * 0.5 + 0.5) <= 1.0
    untouched = np.zeros((720, 1280, 3), np.uint8)
    assert not draw_far_edge(untouched, FarEdge(False, problem="none"), lens, (0, 0, 255)).any()


# ----------------------------------------------------------------- the challenge camera
def test_the_unmoved_frames_of_video_7_give_one_line(data_dir):
    """Video 7's 36 frames from the fixed pier camera: the line must not wander (scatter measured 0.07 px)."""
    from vessel_calib.params import load_camera_yaml

    camera = load_camera_yaml(REPO / "config" / "aitas_camera.yaml")
    frames = sorted((data_dir / "frames" / "7").glob("*.jpg"))
    if not frames:
        pytest.skip(f"no frames of video 7 in {data_dir / 'frames' / '7'}")
    finder, edges, seconds = FarEdgeFinder(), [], []
    for path in frames:
        image = cv2.imread(str(path))
        start = time.perf_counter()
        edges.append(finder.find(image, camera))
        seconds.append(time.perf_counter() - start)
    assert all(edge.found for edge in edges), [edge.problem for edge in edges if not edge.found]
    offsets = np.array([edge.y_at(640.0) for edge in edges])
    slopes = np.array([edge.slope for edge in edges])
    assert offsets.std() < 0.25 and slopes.std() < 6e-4
    assert abs(np.median(offsets) - camera.horizon_y(np.array(640.0))) < 3.0  # near the calibration's horizon
    assert np.median(seconds) < 0.05  # a few ms; generous for a shared machine
