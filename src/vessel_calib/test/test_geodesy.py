import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vessel_calib import geodesy
from vessel_common.errors import CalibrationError, DataError

LAT0, LON0 = 32.70297, -117.234631


def test_equirectangular_matches_paper_formula():
    x, y = geodesy.gps_to_local(LAT0 + 0.001, LON0 + 0.001, LAT0, LON0)
    R = 6371000.0
    assert x == pytest.approx(R * np.radians(0.001) * np.cos(np.radians(LAT0)), rel=1e-9)
    assert y == pytest.approx(R * np.radians(0.001), rel=1e-9)
    assert isinstance(x, float)


@settings(max_examples=200, deadline=None)
@given(st.floats(-80, 80), st.floats(-180, 180), st.floats(-5000, 5000), st.floats(-5000, 5000))
def test_local_gps_round_trip(lat0, lon0, x, y):
    lat, lon = geodesy.local_to_gps(x, y, lat0, lon0)
    x2, y2 = geodesy.gps_to_local(lat, lon, lat0, lon0)
    assert abs(x2 - x) < 1e-6 and abs(y2 - y) < 1e-6


def test_vectorised_shapes():
    lat = np.full((3, 4), LAT0 + 0.01)
    x, y = geodesy.gps_to_local(lat, LON0, LAT0, LON0)
    assert x.shape == (3, 4) and y.shape == (3, 4)
    d = geodesy.haversine_m(lat, LON0, LAT0, LON0)
    assert d.shape == (3, 4)


def test_haversine_and_bearing_known_values():
    # one degree of latitude = R * pi / 180
    assert geodesy.haversine_m(0, 0, 1, 0) == pytest.approx(6371000.0 * np.pi / 180, rel=1e-9)
    assert geodesy.bearing_deg(0, 0, 1, 0) == pytest.approx(0.0)
    assert geodesy.bearing_deg(0, 0, 0, 1) == pytest.approx(90.0)
    assert geodesy.bearing_deg(0, 0, -1, 0) == pytest.approx(180.0)
    assert geodesy.bearing_deg(0, 0, 0, -1) == pytest.approx(270.0)
    # the data set's own figure: fix 0 is 12589.59 m from the camera at bearing 119.48
    assert geodesy.haversine_m(LAT0, LON0, 32.6472595, -117.1175335) == pytest.approx(12589.59, abs=0.01)
    # the data set's bearing is planar in the equirectangular frame; great-circle differs by 0.04 deg at 12.6 km
    assert geodesy.bearing_deg(LAT0, LON0, 32.6472595, -117.1175335) == pytest.approx(119.48, abs=0.05)
    x, y = geodesy.gps_to_local(32.6472595, -117.1175335, LAT0, LON0)
    assert np.degrees(np.arctan2(x, y)) % 360 == pytest.approx(119.48, abs=0.005)


def test_haversine_agrees_with_local_metres_near_camera():
    x, y = 300.0, -120.0
    lat, lon = geodesy.local_to_gps(x, y, LAT0, LON0)
    assert geodesy.haversine_m(LAT0, LON0, lat, lon) == pytest.approx(np.hypot(x, y), rel=1e-5)


def test_antimeridian_wraps():
    x, _ = geodesy.gps_to_local(0.0, -179.9999, 0.0, 179.9999)
    assert x == pytest.approx(6371000.0 * np.radians(0.0002), rel=1e-6)
    assert geodesy.haversine_m(0, 179.9999, 0, -179.9999) < 30.0


@pytest.mark.parametrize("lat, lon", [(91, 0), (0, 181), (np.nan, 0), (0, np.inf), (0, 0), ("x", 1)])
def test_validate_lat_lon_rejects(lat, lon):
    with pytest.raises(CalibrationError, match="camera position"):
        geodesy.validate_lat_lon(lat, lon, "camera position")


def test_validate_lat_lon_error_class_and_ok():
    geodesy.validate_lat_lon(LAT0, LON0, "camera")
    geodesy.validate_lat_lon(np.array([1.0, 2.0]), np.array([3.0, 4.0]), "fixes")
    with pytest.raises(DataError, match="fix 3"):
        geodesy.validate_lat_lon(100.0, 0.0, "fix 3", error=DataError)
