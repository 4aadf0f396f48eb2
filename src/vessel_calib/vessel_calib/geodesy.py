"""GPS <-> local metres about the camera (the paper's equirectangular projection), Haversine and bearing.

The world frame is the paper's: origin at the camera, x east, y north, metres,
``x_w = R * rad(lon - lon0) * cos(rad(lat0))``, ``y_w = R * rad(lat - lat0)``, R = 6 371 000 m.
Within a few kilometres of the camera this differs from a proper local tangent plane by far less than the
calibration error, and it is what the camera model was fitted in, so every package must use these functions.

All functions accept scalars or numpy arrays (broadcast together) and return floats for scalar input.
"""

from __future__ import annotations

import numpy as np

from vessel_common.errors import CalibrationError, VesselError

EARTH_RADIUS_M = 6371000.0


def _out(value: np.ndarray):
    """Return a Python float for 0-d results, the array otherwise."""
    value = np.asarray(value, dtype=float)
    return float(value) if value.ndim == 0 else value


def _wrap_deg(delta_deg):
    """Wrap a longitude difference into [-180, 180) so the antimeridian does not produce 40 000 km jumps."""
    return (np.asarray(delta_deg, dtype=float) + 180.0) % 360.0 - 180.0


def gps_to_local(lat, lon, lat0, lon0):
    """Latitude/longitude (degrees) -> (x_east_m, y_north_m) relative to (lat0, lon0)."""
    lat, lon = np.broadcast_arrays(np.asarray(lat, dtype=float), np.asarray(lon, dtype=float))
    x = EARTH_RADIUS_M * np.radians(_wrap_deg(lon - lon0)) * np.cos(np.radians(lat0))
    y = EARTH_RADIUS_M * np.radians(lat - lat0)
    return _out(x), _out(y)


def local_to_gps(x, y, lat0, lon0):
    """(x_east_m, y_north_m) relative to (lat0, lon0) -> latitude/longitude in degrees (exact inverse)."""
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    lat = lat0 + np.degrees(y / EARTH_RADIUS_M)
    lon = lon0 + np.degrees(x / (EARTH_RADIUS_M * np.cos(np.radians(lat0))))
    lon = _wrap_deg(lon)
    return _out(lat), _out(lon)


def haversine_m(lat1, lon1, lat2, lon2):
    """Great-circle distance in metres (Haversine, R = 6 371 000 m), the paper's error metric."""
    p1 = np.radians(np.asarray(lat1, dtype=float))
    p2 = np.radians(np.asarray(lat2, dtype=float))
    dphi = p2 - p1
    dlmb = np.radians(_wrap_deg(np.asarray(lon2, dtype=float) - np.asarray(lon1, dtype=float)))
    a = np.sin(dphi / 2.0) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dlmb / 2.0) ** 2
    return _out(2.0 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0))))


def bearing_deg(lat1, lon1, lat2, lon2):
    """Initial great-circle bearing from point 1 to point 2, degrees in [0, 360): 0 = north, clockwise."""
    p1 = np.radians(np.asarray(lat1, dtype=float))
    p2 = np.radians(np.asarray(lat2, dtype=float))
    dlmb = np.radians(_wrap_deg(np.asarray(lon2, dtype=float) - np.asarray(lon1, dtype=float)))
    yy = np.sin(dlmb) * np.cos(p2)
    xx = np.cos(p1) * np.sin(p2) - np.sin(p1) * np.cos(p2) * np.cos(dlmb)
    return _out(np.degrees(np.arctan2(yy, xx)) % 360.0)


def _show(values: np.ndarray):
    """Plain numbers for messages (no ``np.float64(...)``), the first offending few for arrays."""
    return float(values) if values.ndim == 0 else values.ravel()[:5].tolist()


def validate_lat_lon(lat, lon, what: str, error: type[VesselError] = CalibrationError) -> None:
    """Raise ``error`` naming ``what`` unless every lat is in [-90, 90] and lon in [-180, 180], all finite.

    Also rejects the (0, 0) "null island" position, which GPS loggers write when they have no fix.
    """
    try:
        lat_a = np.asarray(lat, dtype=float)
        lon_a = np.asarray(lon, dtype=float)
    except (TypeError, ValueError):
        raise error(f"{what}: latitude/longitude must be numbers in degrees, got {lat!r}, {lon!r}") from None
    lat, lon = _show(lat_a), _show(lon_a)
    if not (np.all(np.isfinite(lat_a)) and np.all(np.isfinite(lon_a))):
        raise error(f"{what}: latitude/longitude must be finite, got {lat}, {lon}; give WGS-84 degrees")
    if np.any(np.abs(lat_a) > 90.0):
        raise error(f"{what}: latitude {lat} is outside [-90, 90]; are latitude and longitude swapped?")
    if np.any(np.abs(lon_a) > 180.0):
        raise error(f"{what}: longitude {lon} is outside [-180, 180]; give WGS-84 degrees, east positive")
    if np.any((lat_a == 0.0) & (lon_a == 0.0)):
        raise error(f"{what}: position (0, 0) is the GPS 'no fix' value, not a real position")
