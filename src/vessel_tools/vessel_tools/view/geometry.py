"""Where the camera looks, and an optional chart under the plan, in metres east/north of the camera.

The plan view draws the camera's field of view out to the range of the sea's horizon. Both edges come from the
calibration itself (the screen's left and right columns just below the horizon, back-projected on the sea), not
from a nominal lens angle, so the fan drawn is the water the fuser can place vessels on. ROS-free.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_calib import geodesy
from vessel_calib.camera_model import CameraModel
from vessel_common.errors import DataError

FAN_COLUMNS = 17
"""Screen columns whose bearing outlines the field of view (the lens bends its edges)."""
BELOW_HORIZON_PX = 8.0
"""How far below the horizon a column is back-projected to get its bearing (on the horizon it has none)."""
CHART_SUFFIXES = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}


@dataclass(frozen=True)
class CameraGeometry:
    """A camera on the plan: position, heading, the field-of-view outline (metres) and the horizon's range."""

    lat: float
    lon: float
    heading_deg: float
    horizon_m: float
    fov: tuple[tuple[float, float], ...]
    image_width: int
    image_height: int

    def to_json(self) -> dict:
        """What the page draws the camera with."""
        return {
            "lat": self.lat, "lon": self.lon,
            "heading_deg": round(self.heading_deg, 2) if math.isfinite(self.heading_deg) else None,
            "horizon_m": round(self.horizon_m, 1),
            "fov": [[round(e, 1), round(n, 1)] for e, n in self.fov],
            "image_width": self.image_width, "image_height": self.image_height,
        }


def horizon_range_m(height_m: float) -> float:
    """Distance to the sea's horizon from ``height_m`` above the water, sqrt(2 h R); NaN for no height."""
    return math.sqrt(2.0 * height_m * geodesy.EARTH_RADIUS_M) if math.isfinite(height_m) and height_m > 0 \
        else math.nan


def _bearings(model: CameraModel, xs: np.ndarray) -> list[float]:
    """Bearing (radians from north, clockwise) of each column's sea just below the horizon; NaN where none."""
    ys = model.horizon_y(xs) + BELOW_HORIZON_PX
    east, north, valid = model.screen_to_world(xs, np.nan_to_num(ys, nan=-1.0))
    return [math.atan2(e, n) if ok else math.nan for e, n, ok in zip(east, north, valid, strict=True)]


def camera_geometry(model: CameraModel) -> CameraGeometry:
    """The field of view of a calibration: near edge (the image's bottom row on the sea), far edge at the horizon."""
    width, height = model.image_size
    xs = np.linspace(0.0, width - 1.0, FAN_COLUMNS)
    try:
        height_m = model.height_m
    except Exception:  # a homography that is no pinhole gives no height: the fan ends at the farthest column
        height_m = math.nan
    bearings = [b for b in _bearings(model, xs) if math.isfinite(b)]
    far_m = horizon_range_m(height_m)
    near_e, near_n, near_ok = model.screen_to_world(xs, np.full_like(xs, height - 1.0))
    near = [(float(e), float(n)) for e, n, ok in zip(near_e, near_n, near_ok, strict=True) if ok]
    if not math.isfinite(far_m):
        far_m = max([math.hypot(e, n) for e, n in near] + [1000.0]) * 10.0
    far = [(far_m * math.sin(b), far_m * math.cos(b)) for b in bearings]
    outline = (near or [(0.0, 0.0)]) + list(reversed(far))
    return CameraGeometry(float(model.camera_lat or 0.0), float(model.camera_lon or 0.0), float(model.heading_deg),
                          far_m, tuple(outline), int(width), int(height))


def load_geometry(path: Path) -> CameraGeometry:
    """The geometry of a calibration file (``vessel_calib.params.load_camera_yaml``); CalibrationError if bad."""
    from vessel_calib.params import load_camera_yaml

    return camera_geometry(load_camera_yaml(path))


@dataclass(frozen=True)
class Chart:
    """An offline chart image (north up) and the metres east/north of the camera its edges stand at."""

    image: Path
    west_m: float
    east_m: float
    south_m: float
    north_m: float

    @property
    def content_type(self) -> str:
        """The image's HTTP content type."""
        return CHART_SUFFIXES[self.image.suffix.lower()]

    def to_json(self) -> dict:
        """What the page places the chart with (it fetches the image from ``/chart``)."""
        return {"url": "/chart", "west_m": round(self.west_m, 1), "east_m": round(self.east_m, 1),
                "south_m": round(self.south_m, 1), "north_m": round(self.north_m, 1)}


def _corner(value, what: str) -> tuple[float, float]:
    try:
        lat, lon = (float(v) for v in value)
    except (TypeError, ValueError):
        raise DataError(f"chart {what} must be [lat, lon] in degrees, got {value!r}") from None
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise DataError(f"chart {what} ({lat}, {lon}) is not on the globe: give [lat, lon] in degrees")
    return lat, lon


def chart_from_corners(image: Path, top_left, bottom_right, camera_lat: float, camera_lon: float) -> Chart:
    """A chart from its image and the latitude/longitude of its top-left and bottom-right corners."""
    image = Path(image)
    if image.suffix.lower() not in CHART_SUFFIXES:
        raise DataError(f"chart image {image} must be PNG or JPEG ({', '.join(CHART_SUFFIXES)})")
    if not image.is_file():
        raise DataError(f"chart image {image} not found: give an existing PNG or JPEG")
    (lat1, lon1), (lat2, lon2) = _corner(top_left, "top_left"), _corner(bottom_right, "bottom_right")
    if not (lat1 > lat2 and lon1 < lon2):
        raise DataError(f"chart corners top_left ({lat1}, {lon1}) and bottom_right ({lat2}, {lon2}): the top-left "
                        "corner must be north and west of the bottom-right one (a north-up image)")
    west, north = geodesy.gps_to_local(lat1, lon1, camera_lat, camera_lon)
    east, south = geodesy.gps_to_local(lat2, lon2, camera_lat, camera_lon)
    return Chart(image, float(west), float(east), float(south), float(north))


def load_chart(path: Path, camera_lat: float, camera_lon: float) -> Chart:
    """A chart from its JSON: ``{"image": FILE, "top_left": [lat, lon], "bottom_right": [lat, lon]}``.

    ``image`` is relative to the JSON file's folder unless absolute.
    """
    path = Path(path)
    try:
        spec = json.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(f"chart file {path} not found: give a JSON file with image, top_left, bottom_right") from None
    except (OSError, ValueError) as error:
        raise DataError(f"chart file {path} is not readable JSON ({error}): fix it or leave --chart out") from None
    missing = [key for key in ("image", "top_left", "bottom_right") if not isinstance(spec, dict) or key not in spec]
    if missing:
        raise DataError(f"chart file {path} lacks {', '.join(missing)}: give "
                        '{"image": "chart.png", "top_left": [lat, lon], "bottom_right": [lat, lon]}')
    image = Path(str(spec["image"]))
    return chart_from_corners(image if image.is_absolute() else path.parent / image, spec["top_left"],
                              spec["bottom_right"], camera_lat, camera_lon)
