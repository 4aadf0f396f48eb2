"""Where one image sits relative to the calibration: the detector's view of a camera that moves.

The calibration (horizon, masks of things fixed to the world, the size prior's depths) belongs to the reference
image, the one taken at the attitude the calibration holds for. A camera on a ship or a swaying pole takes each
image at another attitude; the image's pose (``vessel_calib.attitude.PoseEstimate``) maps its pixels into the
reference image. The detector warps the band below the horizon into the reference image's geometry and detects
there: a network trained on one camera has learnt that band at one scale and boats upright, and the masks and the
size prior hold there unchanged. Boxes go back into the image's pixels by the inverse map.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vessel_calib.camera_pose import boxes_to_reference, map_ideal_points
from vessel_calib.radial_lens import RadialLens

_HORIZON_SAMPLES = 65
GRID_STEP_PX = 8
"""Spacing of the grid on which the warp into the reference image is computed exactly (bilinear in between)."""


class ReferenceGrid:
    """Where each reference pixel lies in an image at another attitude, for ``cv2.remap``, made cheaply per image.

    The map is smooth (a homography between two lenses), so it is computed exactly on a grid every ``GRID_STEP_PX``
    pixels and interpolated bilinearly between; the grid's ideal pixels are computed once (the lens is fixed).
    """

    def __init__(self, lens: RadialLens, image_wh: tuple[int, int]):
        width, height = image_wh
        self.width = width
        xs = np.arange(0, width - 1 + GRID_STEP_PX, GRID_STEP_PX, dtype=np.float64)
        ys = np.arange(0, height - 1 + GRID_STEP_PX, GRID_STEP_PX, dtype=np.float64)
        xp, yp, ok = lens.undistort(*np.meshgrid(xs, ys))
        self.xp, self.yp = np.where(ok, xp, np.nan), np.where(ok, yp, np.nan)
        self._fractions: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def screen_of_reference(self, reference_to_image: np.ndarray, top: int, bottom: int,
                            lens: RadialLens) -> tuple[np.ndarray, np.ndarray]:
        """For each reference pixel of rows top..bottom, where it lies in the image (cv2.remap's maps)."""
        xi, yi = map_ideal_points(reference_to_image, self.xp, self.yp)
        xs, ys = lens.distort(xi, yi)
        bad = ~(np.isfinite(xs) & np.isfinite(ys))
        coarse_x = np.where(bad, -1e4, xs).astype(np.float32)
        coarse_y = np.where(bad, -1e4, ys).astype(np.float32)
        fx, fy = self._fraction_maps(top, bottom)
        return (cv2.remap(coarse_x, fx, fy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
                cv2.remap(coarse_y, fx, fy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))

    def _fraction_maps(self, top: int, bottom: int) -> tuple[np.ndarray, np.ndarray]:
        """Each pixel's position on the grid, in grid cells (the interpolation's sample coordinates)."""
        key = (top, bottom)
        if key not in self._fractions:
            fx, fy = np.meshgrid(np.arange(self.width, dtype=np.float32) / GRID_STEP_PX,
                                 np.arange(top, bottom, dtype=np.float32) / GRID_STEP_PX)
            self._fractions = {key: (fx, fy)}
        return self._fractions[key]


@dataclass(frozen=True)
class ImageView:
    """One image's map into the reference image and the horizons to draw.

    ``image_to_reference``: 3x3 homography of ideal pixels (calibrated image size). ``lens``: the calibration's.
    ``horizon_top_px``: the highest screen y, across the width, of the calibration's horizon in this image (the
    band starts above it); None when it is not in view. ``measured_abc``: the far edge measured in this image (ideal
    pixels), None when not found; ``expected_abc``: where the pose puts it.
    """

    image_to_reference: np.ndarray
    lens: RadialLens
    horizon_top_px: float | None
    measured_abc: tuple[float, float, float] | None = None
    expected_abc: tuple[float, float, float] | None = None

    def warp_to_reference(self, bgr: np.ndarray, rows: tuple[float, float], grid: ReferenceGrid) -> np.ndarray:
        """The image as the reference camera would have seen it, for ``rows`` (top, bottom) only; black elsewhere."""
        top, bottom = int(np.floor(rows[0])), int(np.ceil(rows[1]))
        xs, ys = grid.screen_of_reference(np.linalg.inv(self.image_to_reference), top, bottom, self.lens)
        canvas = np.zeros_like(bgr)
        canvas[top:bottom] = cv2.remap(bgr, xs, ys, cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return canvas

    def boxes_to_image(self, boxes_xyxy) -> np.ndarray:
        """Boxes of the reference image -> boxes of this image (the inverse of ``boxes_in_reference``)."""
        return boxes_to_reference(boxes_xyxy, np.linalg.inv(self.image_to_reference), self.lens)

    @classmethod
    def of_pose(cls, camera, image_to_reference: np.ndarray, measured_abc=None, expected_abc=None) -> ImageView:
        """The view of an image whose pose gives ``image_to_reference``; ``camera`` is the ``CameraModel``."""
        lens = RadialLens(camera.K1, camera.center)
        line = np.asarray(image_to_reference, float).T @ np.asarray(camera.horizon_line_ideal, float)
        xs = np.linspace(0.0, float(camera.image_size[0]), _HORIZON_SAMPLES)
        ys = np.asarray(lens.line_y(tuple(line / np.hypot(line[0], line[1])), xs), dtype=float)
        ys = ys[np.isfinite(ys)]
        top = float(ys.min()) if ys.size else None
        return cls(np.asarray(image_to_reference, float), lens, top,
                   None if measured_abc is None else tuple(float(v) for v in measured_abc),
                   None if expected_abc is None else tuple(float(v) for v in expected_abc))

    def boxes_in_reference(self, boxes_xyxy, image_wh, reference_wh) -> np.ndarray:
        """Boxes in pixels of an image of ``image_wh`` -> boxes of the reference image (``reference_wh`` pixels)."""
        sx, sy = reference_wh[0] / image_wh[0], reference_wh[1] / image_wh[1]
        boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4) * np.array([sx, sy, sx, sy])
        return boxes_to_reference(boxes, self.image_to_reference, self.lens)

    def draw_horizon(self, image: np.ndarray, image_wh, scale: float) -> None:
        """Draw the measured far edge (yellow) and where the pose expects it (thin grey) on an annotated image."""
        for line, color, thickness in ((self.expected_abc, (160, 160, 160), 1),
                                       (self.measured_abc, (0, 230, 255), 2)):
            if line is None:
                continue
            xs = np.linspace(0.0, float(image_wh[0]), _HORIZON_SAMPLES)
            ys = np.asarray(self.lens.line_y(line, xs), dtype=float)
            ok = np.isfinite(ys)
            if ok.sum() < 2:
                continue
            points = np.stack([xs[ok], ys[ok]], axis=1) * scale
            cv2.polylines(image, [np.round(points).astype(np.int32)], False, color, thickness, cv2.LINE_AA)
