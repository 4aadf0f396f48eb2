import math

import numpy as np
import pytest

from vessel_calib.gps_track import GpsTrack, parse_time, seconds_of_day_to_epoch
from vessel_common.errors import DataError

T0 = 1601494588.0  # 2020-09-30T19:36:28Z


def make_track():
    return GpsTrack([T0 + 2, T0, T0 + 1, T0 + 10], [32.0002, 32.0, 32.0001, 32.001], [-117.0, -117.0, -117.0, -117.0])


def test_sorted_and_interpolated():
    track = make_track()
    assert list(track.stamps) == [T0, T0 + 1, T0 + 2, T0 + 10]
    lat, lon, valid = track.interpolate(T0 + 0.5)
    assert valid and lat == pytest.approx(32.00005) and lon == pytest.approx(-117.0)
    assert isinstance(lat, float)


def test_max_gap_rule_and_edges():
    track = make_track()
    lat, lon, valid = track.interpolate(np.array([T0 - 1, T0, T0 + 1.5, T0 + 5, T0 + 10, T0 + 11]), max_gap_s=3.0)
    assert list(valid) == [False, True, True, False, True, False]
    assert np.isnan(lat[~valid]).all() and np.isnan(lon[~valid]).all()
    assert track.interpolate(T0 + 5, max_gap_s=10.0)[2]
    np.testing.assert_allclose(track.bracket_gap(np.array([T0, T0 + 5, T0 + 20])), [0.0, 8.0, np.inf])


def test_duplicate_stamps_are_averaged():
    track = GpsTrack([T0, T0, T0 + 1], [32.0, 32.0002, 32.0003], [-117.0, -117.0, -117.0])
    assert len(track) == 2 and track.duplicate_stamps == 1
    assert track.lats[0] == pytest.approx(32.0001)


def test_constructor_rejects_bad_fixes():
    with pytest.raises(DataError, match="fix 1"):
        GpsTrack([T0, T0 + 1], [32.0, math.nan], [-117.0, -117.0])
    with pytest.raises(DataError, match="length"):
        GpsTrack([T0], [32.0, 32.1], [-117.0])


def test_empty_track():
    track = GpsTrack([], [], [])
    lat, lon, valid = track.interpolate(np.array([T0]))
    assert not valid.any() and len(track) == 0


def test_parse_time():
    assert parse_time("2020-09-30T19:36:28Z") == T0
    assert parse_time("2020-09-30T19:36:28.250+00:00") == T0 + 0.25
    assert parse_time("2020-09-30 19:36:28") == T0
    assert parse_time(str(T0)) == T0
    with pytest.raises(ValueError):
        parse_time("yesterday")
    assert seconds_of_day_to_epoch(70588.0, T0) == T0
    # just after midnight with a reference just before it: next day
    assert seconds_of_day_to_epoch(10.0, 1601510399.0) == 1601510410.0


def test_csv_seconds_of_day_with_iso_date_and_garbage(tmp_path):
    path = tmp_path / "fixes.csv"
    path.write_text(
        "fix_index,utc,utc_s,t_spread_s,lat,lon\n"
        "0,2020-09-30T19:36:28.000Z,70588,70588.0,32.70,-117.23\n"
        "1,2020-09-30T19:36:28.000Z,70588,70588.5,32.71,-117.23\n"
        "2,2020-09-30T19:36:29.000Z,70589,70589.0,nan,-117.23\n"
        "3,2020-09-30T19:36:29.000Z,70589,70589.5,abc,-117.23\n"
        "4,2020-09-30T19:36:30.000Z,70590,70590.0,0,0\n"
        "5,2020-09-30T19:36:30.000Z,70590,,32.72,-117.23\n"
        "6,2020-09-30T19:36:31.000Z,70591,70591.0,32.72,-117.23\n"
    )
    track = GpsTrack.from_csv(path)
    assert track.skipped_rows == 4
    assert list(track.stamps) == [T0, T0 + 0.5, T0 + 3.0]


def test_csv_iso_and_epoch_columns(tmp_path):
    iso = tmp_path / "iso.csv"
    iso.write_text("time,latitude,longitude\n2020-09-30T19:36:28Z,32.7,-117.2\n2020-09-30T19:36:29Z,32.8,-117.2\n")
    assert list(GpsTrack.from_csv(iso).stamps) == [T0, T0 + 1]
    epoch = tmp_path / "epoch.csv"
    epoch.write_text(f"stamp,lat,lon\n{T0},32.7,-117.2\n")
    assert list(GpsTrack.from_csv(epoch).stamps) == [T0]
    sod = tmp_path / "sod.csv"
    sod.write_text("utc_s,lat,lon\n70588,32.7,-117.2\n")
    assert list(GpsTrack.from_csv(sod, day_start=T0 - 70588).stamps) == [T0]


def test_csv_missing_columns(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("time,x,y\n1,2,3\n")
    with pytest.raises(DataError, match="lat"):
        GpsTrack.from_csv(path)
    path.write_text("a,lat,lon\n1,2,3\n")
    with pytest.raises(DataError, match="time column"):
        GpsTrack.from_csv(path)
    with pytest.raises(DataError, match="cannot read"):
        GpsTrack.from_csv(tmp_path / "missing.csv")


def test_gpx(tmp_path):
    path = tmp_path / "track.gpx"
    path.write_text(
        '<?xml version="1.0"?>\n<gpx version="1.1" xmlns="http://www.topografix.com/GPX/1/1"><trk><trkseg>'
        '<trkpt lat="32.70" lon="-117.23"><time>2020-09-30T19:36:29Z</time></trkpt>'
        '<trkpt lat="32.71" lon="-117.23"><time>2020-09-30T19:36:28Z</time></trkpt>'
        '<trkpt lat="32.72" lon="-117.23"></trkpt>'
        '<trkpt lat="nan" lon="-117.23"><time>2020-09-30T19:36:30Z</time></trkpt>'
        "</trkseg></trk></gpx>")
    track = GpsTrack.from_file(path)
    assert list(track.stamps) == [T0, T0 + 1] and track.skipped_rows == 2
    assert track.lats[0] == pytest.approx(32.71)
    bad = tmp_path / "bad.gpx"
    bad.write_text("<gpx><trk>")
    with pytest.raises(DataError, match="not valid"):
        GpsTrack.from_gpx(bad)


def test_shared_fixes_reproduce_label_positions(dataset):
    track = dataset.gps_track()
    labels = [lab for lab in dataset.labels() if lab.gps_ok]
    lat, lon, valid = track.interpolate(np.array([lab.stamp for lab in labels]), max_gap_s=3.0)
    assert valid.all()
    from vessel_calib.geodesy import haversine_m
    err = haversine_m(lat, lon, [lab.lat for lab in labels], [lab.lon for lab in labels])
    assert np.max(err) < 0.05
