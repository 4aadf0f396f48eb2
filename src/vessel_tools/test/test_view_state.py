"""The view's ROS-free core: vessels per camera, tracks, JSON, ellipses, throttling, status line, geometry."""

from __future__ import annotations

import ast
import json
import math
from pathlib import Path

import pytest

from vessel_common.errors import DataError
from vessel_tools.view.geometry import chart_from_corners, horizon_range_m, load_chart, load_geometry
from vessel_tools.view.state import (
    HISTORY_POINTS,
    Throttle,
    TrackRecord,
    ViewState,
    covariance_ellipse,
    speed_course,
)
from vessel_tools.view.status import NodeStatus, status_summary

REPO = Path(__file__).resolve().parents[3]
VIEW = REPO / "src" / "vessel_tools" / "vessel_tools" / "view"


def record(track_id: str, stamp: float, east: float = 100.0, north: float = 200.0, **fields) -> TrackRecord:
    values = dict(has_world=True, east=east, north=north, vx=1.0, vy=0.0, covariance=(25.0, 0.0, 0.0, 4.0),
                  lat=32.7, lon=-117.2, class_id="vessel")
    values.update(fields)
    return TrackRecord(id=track_id, stamp=stamp, **values)


def test_the_core_modules_import_no_ros():
    ros = ("rclpy", "launch", "rosbags", "mcap", "builtin_interfaces")
    for name in ("state", "geometry", "status", "server"):
        tree = ast.parse((VIEW / f"{name}.py").read_text())
        imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
        imported |= {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
        assert not [m for m in imported if m.split(".")[0] in ros or m.split(".")[0].endswith("_msgs")], name


def test_a_newer_array_replaces_the_vessels_and_extends_their_tracks():
    state = ViewState()
    assert state.update_tracks("", 10.0, [record("1", 10.0), record("2", 10.0)], now=0.0) == "new"
    assert state.update_tracks("", 11.0, [record("1", 11.0, east=110.0)], now=1.0) == "new"
    vessels = json.loads(state.vessels_json())["vessels"]
    assert [v["id"] for v in vessels] == ["1"]  # 2 is no longer in the array: it ended
    assert vessels[0]["track"] == [[100.0, 200.0], [110.0, 200.0]]
    assert vessels[0]["namespace"] == ""


def test_the_same_stamp_from_the_other_topic_merges_without_doubling_the_track():
    state = ViewState()
    state.update_tracks("", 10.0, [record("1", 10.0)], now=0.0)
    assert state.update_tracks("", 10.0, [record("1", 10.0), record("3", 10.0)], now=0.1) == "merged"
    camera = state.cameras[""]
    assert set(camera.records) == {"1", "3"}
    assert len(camera.tracks["1"]) == 1 and len(camera.tracks["3"]) == 1


def test_old_arrays_are_dropped_and_a_replay_restart_resets():
    state = ViewState()
    state.update_tracks("", 100.0, [record("1", 100.0)], now=0.0)
    assert state.update_tracks("", 99.5, [record("9", 99.5)], now=0.1) == "old"
    assert set(state.cameras[""].records) == {"1"}
    assert state.update_tracks("", 50.0, [record("9", 50.0)], now=0.2) == "reset"
    assert set(state.cameras[""].records) == {"9"}
    assert state.counts == {"old_arrays": 1, "reset_arrays": 1}


def test_lost_tracks_leave_and_histories_stay_bounded():
    state = ViewState()
    for i in range(HISTORY_POINTS + 30):
        state.update_tracks("", 1.0 + i, [record("1", 1.0 + i, east=float(i))], now=float(i))
    assert len(state.cameras[""].tracks["1"]) == HISTORY_POINTS
    state.update_tracks("", 1000.0, [record("1", 1000.0, status=3)], now=1000.0)
    assert state.cameras[""].records == {} and state.cameras[""].tracks == {}


def test_a_track_keeps_one_point_a_second_at_a_live_frame_rate():
    state = ViewState()
    for i in range(100):  # 25 frames/s for 4 s
        state.update_tracks("", 10.0 + i * 0.04, [record("1", 10.0 + i * 0.04, east=float(i))], now=i * 0.04)
    track = list(state.cameras[""].tracks["1"])
    assert len(track) == 4 and track[-1] == (99.0, 200.0)  # one a second, the newest position last


def test_vessels_json_carries_what_a_consumer_needs():
    state = ViewState()
    state.update_tracks("", 5.0, [
        record("7", 5.0, is_target=True, has_cpa=True, cpa_m=120.0, tcpa_s=300.0, cpa_alert=True, distance_m=223.6,
               bearing_deg=26.6),
        record("8", 5.0, has_world=False, east=math.nan, north=math.nan),
    ], now=0.0)
    target, other = json.loads(state.vessels_json())["vessels"]
    assert target["id"] == "7" and target["is_target"] and target["class"] == "vessel"
    assert (target["east_m"], target["north_m"], target["lat"], target["lon"]) == (100.0, 200.0, 32.7, -117.2)
    assert target["speed_mps"] == 1.0 and target["course_deg"] == 90.0 and target["speed_kn"] == 1.9
    assert target["covariance"] == [25.0, 0.0, 0.0, 4.0]
    assert (target["cpa_m"], target["tcpa_s"], target["cpa_alert"]) == (120.0, 300.0, True)
    assert other["east_m"] is None and other["lat"] is None and other["cpa_m"] is None and other["ellipse"] is None


def test_snapshots_are_strict_json_whatever_the_input():
    state = ViewState()
    state.update_tracks("", 5.0, [record("1", 5.0, vx=math.nan, covariance=(math.inf, 0, 0, 1), cpa_m=math.nan,
                                         has_cpa=True)], now=0.0)
    text = state.snapshot_json(now=0.0)
    snapshot = json.loads(text)
    vessel = snapshot["cameras"][0]["vessels"][0]
    assert vessel["speed_mps"] is None and vessel["ellipse"] is None and vessel["cpa_m"] is None
    assert snapshot["type"] == "state" and snapshot["cameras"][0]["namespace"] == ""


def test_cameras_are_kept_apart_by_namespace():
    state = ViewState()
    state.update_tracks("left", 1.0, [record("1", 1.0)], now=0.0)
    state.update_tracks("right", 1.0, [record("1", 1.0, east=-50.0)], now=0.0)
    vessels = json.loads(state.vessels_json())["vessels"]
    assert {(v["namespace"], v["east_m"]) for v in vessels} == {("left", 100.0), ("right", -50.0)}
    assert state.image("left") is None
    assert state.set_image("left", b"jpeg", 1.0) == 1 and state.image("left") == (b"jpeg", 1)
    assert state.image("right") is None


def test_the_ellipse_holds_95_percent_along_the_principal_axes():
    ellipse = covariance_ellipse([9.0, 0.0, 0.0, 1.0])
    assert ellipse["a_m"] == pytest.approx(3.0 * 2.4477, rel=1e-3) and ellipse["b_m"] == pytest.approx(2.4477,
                                                                                                      rel=1e-3)
    assert ellipse["angle_deg"] == pytest.approx(0.0)
    rotated = covariance_ellipse([5.0, 4.0, 4.0, 5.0])  # axes along the diagonals, variances 9 and 1
    assert rotated["angle_deg"] == pytest.approx(45.0) and rotated["a_m"] == pytest.approx(ellipse["a_m"])
    for bad in ([1.0, 2.0, 0.0, 1.0], [1.0, 0.0, 0.0, -4.0], [math.nan, 0, 0, 1], [1.0, 0.0]):
        assert covariance_ellipse(bad) is None


def test_speed_and_course_are_over_ground_from_north():
    assert speed_course(0.0, 2.0) == (2.0, 0.0)
    speed, course = speed_course(-1.0, -1.0)
    assert speed == pytest.approx(math.sqrt(2)) and course == pytest.approx(225.0)
    assert all(math.isnan(v) for v in speed_course(math.nan, 1.0))
    speed, course = speed_course(0.0, 0.0)  # at rest: no course
    assert speed == 0.0 and math.isnan(course)


def test_the_throttle_sends_at_most_once_an_interval_and_never_leaves_the_last_change():
    throttle = Throttle(0.1)
    assert not throttle.due(0.0)  # nothing changed
    throttle.offer()
    assert throttle.due(0.0)
    throttle.offer()
    assert not throttle.due(0.05)  # too soon: kept
    assert throttle.due(0.1)  # the change arrives, late but not lost
    assert not throttle.due(0.3)


def test_the_status_line_names_rate_latency_progress_and_warnings():
    nodes = [NodeStatus("detector", 0, "running", {"frames_per_s": "4.25", "input_to_output_ms_p50": "180.4"}),
             NodeStatus("camera", 0, "running", {"progress": "12/36"}),
             NodeStatus("fuser", 1, "running; problems: bad_stamp=2"),
             NodeStatus("standby_1/tracker", 1, "standby")]
    summary = status_summary(nodes, arrays_per_s=1.0)
    assert summary["frames_per_s"] == 4.25 and summary["latency_ms"] == 180.4 and summary["level"] == "warn"
    assert summary["warnings"] == ["fuser: running; problems: bad_stamp=2"]
    assert "4.2 frames/s" in summary["line"] and "camera 12/36" in summary["line"] and "bad_stamp" in summary["line"]
    assert status_summary([], arrays_per_s=2.0)["line"].startswith("2.0 frames/s")
    assert status_summary([])["line"].startswith("no frames yet")


def test_the_field_of_view_comes_from_the_calibration():
    geometry = load_geometry(REPO / "config" / "aitas_camera.yaml")
    assert geometry.horizon_m == pytest.approx(horizon_range_m(2.6011), rel=1e-3)
    far = [(e, n) for e, n in geometry.fov if math.hypot(e, n) > 1000.0]
    bearings = [math.degrees(math.atan2(e, n)) % 360.0 for e, n in far]
    assert min(bearings) < geometry.heading_deg < max(bearings)  # the fan straddles the heading
    assert 40.0 < max(bearings) - min(bearings) < 120.0
    assert all(math.hypot(e, n) == pytest.approx(geometry.horizon_m) for e, n in far)
    assert geometry.to_json()["image_width"] == 1280


def test_a_chart_is_placed_by_its_corners_and_bad_ones_are_refused(tmp_path):
    image = tmp_path / "chart.png"
    image.write_bytes(b"\x89PNG\r\n\x1a\n")
    chart = chart_from_corners(image, (32.71, -117.24), (32.70, -117.23), 32.70297, -117.234631)
    assert chart.west_m < 0 < chart.east_m and chart.south_m < 0 < chart.north_m
    assert chart.to_json()["url"] == "/chart" and chart.content_type == "image/png"
    spec = tmp_path / "chart.json"
    spec.write_text(json.dumps({"image": "chart.png", "top_left": [32.71, -117.24], "bottom_right": [32.70, -117.23]}))
    assert load_chart(spec, 32.70297, -117.234631) == chart
    with pytest.raises(DataError, match="north and west"):
        chart_from_corners(image, (32.70, -117.23), (32.71, -117.24), 32.7, -117.2)
    with pytest.raises(DataError, match="not found"):
        chart_from_corners(tmp_path / "missing.png", (32.71, -117.24), (32.70, -117.23), 32.7, -117.2)
    with pytest.raises(DataError, match="PNG or JPEG"):
        chart_from_corners(tmp_path / "chart.svg", (32.71, -117.24), (32.70, -117.23), 32.7, -117.2)
    spec.write_text("{}")
    with pytest.raises(DataError, match="lacks image, top_left, bottom_right"):
        load_chart(spec, 32.7, -117.2)
