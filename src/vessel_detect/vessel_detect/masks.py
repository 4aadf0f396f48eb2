"""Static exclusion masks: image regions (polygons) where detections are known to be false.

A fixed camera sees fixed objects a COCO detector takes for boats; the challenge camera's mooring post at the
bottom centre scores 0.27-0.41 as a boat on most frames. A detection whose box lies mostly inside a mask is
dropped. Polygons are in full-resolution pixels of the camera (the calibration's image size) and are scaled
when frames of another size arrive.

Parameter form: one string per polygon, ``"x,y x,y x,y ..."`` (at least three points), because ROS parameters
cannot hold nested lists.
"""

from __future__ import annotations

import cv2
import numpy as np

from vessel_common.errors import VesselError

# The challenge camera (AI Tracks at Sea, 1280x720): the top of the mooring post at the bottom centre,
# traced on the frames of videos 6-17 (it does not move), with a few pixels to spare.
CHALLENGE_MOORING_POST = "693,676 701,662 728,654 770,650 812,649 856,650 898,654 922,662 931,676 931,720 693,720"
DEFAULT_EXCLUSION_POLYGONS: tuple[str, ...] = (CHALLENGE_MOORING_POST,)


class MaskError(VesselError):
    """An exclusion polygon parameter cannot be read."""


def parse_polygon(text: str) -> np.ndarray:
    """Parse ``"x,y x,y x,y ..."`` into a ``(K, 2)`` float array of at least three finite points.

    Raises:
        MaskError: the text is not a list of at least three ``x,y`` pairs of finite numbers.

    """
    points = []
    for token in str(text).replace(";", " ").split():
        parts = token.split(",")
        if len(parts) != 2:
            raise MaskError(f"exclusion polygon {text!r}: point {token!r} is not 'x,y' (write 'x,y x,y x,y ...')")
        try:
            x, y = float(parts[0]), float(parts[1])
        except ValueError:
            raise MaskError(f"exclusion polygon {text!r}: point {token!r} is not two numbers") from None
        if not (np.isfinite(x) and np.isfinite(y)):
            raise MaskError(f"exclusion polygon {text!r}: point {token!r} is not finite")
        points.append((x, y))
    if len(points) < 3:
        raise MaskError(f"exclusion polygon {text!r} has {len(points)} points; a polygon needs at least 3")
    return np.asarray(points, dtype=np.float64)


def format_polygon(points: np.ndarray) -> str:
    """Inverse of :func:`parse_polygon`."""
    return " ".join(f"{x:g},{y:g}" for x, y in np.asarray(points).reshape(-1, 2))


class ExclusionMask:
    """Union of polygons over an image; answers which share of each box lies inside it.

    Args:
        polygons: ``(K, 2)`` arrays or ``"x,y x,y ..."`` strings, in pixels of ``reference_wh``.
        reference_wh: image size the polygons are drawn for (the calibrated camera's).

    """

    def __init__(self, polygons: list, reference_wh: tuple[int, int] = (1280, 720)):
        self.reference_wh = (int(reference_wh[0]), int(reference_wh[1]))
        self.polygons = [parse_polygon(p) if isinstance(p, str) else np.asarray(p, float) for p in polygons]
        for polygon in self.polygons:
            if polygon.ndim != 2 or polygon.shape[1] != 2 or polygon.shape[0] < 3:
                raise MaskError(f"exclusion polygon with shape {polygon.shape}: need (K >= 3, 2) points")
        self._cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def __bool__(self) -> bool:
        return bool(self.polygons)

    def scaled_polygons(self, image_wh: tuple[int, int]) -> list[np.ndarray]:
        """The polygons in pixels of an image of ``image_wh``."""
        sx = image_wh[0] / self.reference_wh[0]
        sy = image_wh[1] / self.reference_wh[1]
        return [p * np.array([sx, sy]) for p in self.polygons]

    def raster(self, image_wh: tuple[int, int]) -> np.ndarray:
        """``(H, W)`` uint8 mask (1 inside) for an image of ``image_wh``."""
        return self._tables(image_wh)[0]

    def _tables(self, image_wh: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        key = (int(image_wh[0]), int(image_wh[1]))
        if key not in self._cache:
            raster = np.zeros((key[1], key[0]), dtype=np.uint8)
            for polygon in self.scaled_polygons(key):
                cv2.fillPoly(raster, [np.round(polygon).astype(np.int32)], 1)
            integral = cv2.integral(raster, sdepth=cv2.CV_64F)
            self._cache = {key: (raster, integral)}
        return self._cache[key]

    def inside_fraction(self, boxes_xyxy: np.ndarray, image_wh: tuple[int, int]) -> np.ndarray:
        """Share of each box's area (clipped to the image) inside the mask; 0 for empty boxes."""
        boxes = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4)
        if not self.polygons or boxes.shape[0] == 0:
            return np.zeros(boxes.shape[0])
        _, integral = self._tables(image_wh)
        width, height = int(image_wh[0]), int(image_wh[1])
        x1 = np.clip(np.floor(boxes[:, 0]), 0, width).astype(np.int64)
        y1 = np.clip(np.floor(boxes[:, 1]), 0, height).astype(np.int64)
        x2 = np.clip(np.ceil(boxes[:, 2]), 0, width).astype(np.int64)
        y2 = np.clip(np.ceil(boxes[:, 3]), 0, height).astype(np.int64)
        x2, y2 = np.maximum(x2, x1), np.maximum(y2, y1)
        inside = integral[y2, x2] - integral[y1, x2] - integral[y2, x1] + integral[y1, x1]
        area = (x2 - x1) * (y2 - y1)
        return np.where(area > 0, inside / np.maximum(area, 1), 0.0)

    def keep(self, boxes_xyxy: np.ndarray, image_wh: tuple[int, int], max_inside: float = 0.5) -> np.ndarray:
        """Boolean ``(N,)``: the box is not mostly inside the mask (inside share <= ``max_inside``)."""
        return self.inside_fraction(boxes_xyxy, image_wh) <= max_inside
