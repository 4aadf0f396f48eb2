"""The fuser node's collision figures: CPA fields, alerts on their topic, the own ship from NavSatFix.

The fuser runs in this process on the built-in calibration (the challenge camera); the boxes are made from chosen
positions through that camera, so the fused positions are those positions up to the filter's smoothing.
"""
import math

import numpy as np
import pytest

from vessel_fixtures.track_synthetic import screen_track

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")
vessel_msgs = pytest.importorskip("vessel_msgs.msg", reason="vessel_msgs is not built: build ros2_ws first")

T0 = 1601496000.0
OWN_SHIP_TOPIC = "/own_ship/fix"


def tracks_at(stamp, positions, first_stamp=T0):
    """One image's screen tracks, a box per ``positions`` id -> (east, north) m from the camera (NaN: a bad box)."""
    from vessel_common.qos import sec_to_stamp
    from vessel_msgs.msg import VesselTrackArray
    from vessel_tools.track.simulation import challenge_camera

    camera = challenge_camera()
    out = VesselTrackArray()
    out.header.stamp = sec_to_stamp(stamp)
    out.header.frame_id = "camera_link"
    for tid, (x, y) in positions.items():
        out.tracks.append(screen_track(out.header, tid, x, y, camera, confidence=0.9,
                                       detection_count=int(round(stamp - first_stamp)) + 1,
                                       first_seen=sec_to_stamp(first_stamp)))
    return out


def own_ship_fix(stamp, lat, lon, status=0):
    """A NavSatFix of the own ship (``status`` 0: STATUS_FIX, -1: NO_FIX), 2 m deviation each way."""
    from sensor_msgs.msg import NavSatFix

    from vessel_common.qos import sec_to_stamp

    fix = NavSatFix()
    fix.header.stamp = sec_to_stamp(stamp)
    fix.header.frame_id = "base_link"
    fix.status.status = status
    fix.latitude, fix.longitude = lat, lon
    fix.position_covariance = [4.0, 0.0, 0.0, 0.0, 4.0, 0.0, 0.0, 0.0, 9.0]
    fix.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
    return fix


class _Lines:
    """A node's logger that keeps what it is given: ``lines`` of (level, message)."""

    def __init__(self):
        self.lines: list[tuple[str, str]] = []

    def __getattr__(self, level):
        return lambda message, **kwargs: self.lines.append((level, str(message)))


def _fuser(monkeypatch, context, *overrides):
    from rclpy.parameter import Parameter

    from vessel_fixtures.ros_nodes import node_in_context
    from vessel_track.fuser_node import FuserNode

    params = [Parameter("camera.builtin_calibration", value=True)]
    params += [Parameter(name, value=value) for name, value in overrides]
    return node_in_context(monkeypatch, context, FuserNode, params)


FRAMES = 20


def _closing_in(k):
    """A vessel 335 m out heading straight for the camera at 5 m/s, position after k seconds."""
    start = np.array([300.0, 150.0])
    return start * (1.0 - 5.0 * k / float(np.hypot(*start)))


def test_cpa_fields_and_alerts_reach_subscribers(ros_context, monkeypatch, wait_until):
    """A vessel on a collision course alerts on /vessel/collision_alerts; one at anchor does not.

    Through DDS, in this process: a test node publishes the tracker's arrays and reads both outputs.
    """
    from vessel_common.qos import reliable_qos, stamp_to_sec
    from vessel_msgs.msg import VesselTrackArray

    test_node = rclpy.create_node("tracker_and_consumer", context=ros_context)  # before the fuser patches Node
    tracks, alerts = [], []
    test_node.create_subscription(VesselTrackArray, "/vessel/tracks", tracks.append, reliable_qos(50))
    test_node.create_subscription(VesselTrackArray, "/vessel/collision_alerts", alerts.append, reliable_qos(50))
    publisher = test_node.create_publisher(VesselTrackArray, "/vessel/tracks/screen", reliable_qos(50))
    fuser = _fuser(monkeypatch, ros_context)
    executor = rclpy.executors.SingleThreadedExecutor(context=ros_context)
    executor.add_node(test_node)
    executor.add_node(fuser)

    def spin():
        executor.spin_once(timeout_sec=0.05)

    try:
        assert wait_until(lambda: publisher.get_subscription_count() > 0
                          and fuser.publisher.get_subscription_count() > 0
                          and fuser.alert_publisher.get_subscription_count() > 0, 30.0, spin=spin), "no match"
        for k in range(FRAMES):
            stamp = T0 + k
            publisher.publish(tracks_at(stamp, {"T1": _closing_in(k), "T2": (260.0, 150.0),
                                                "T3": (math.nan, math.nan)}))
            assert wait_until(lambda s=stamp: any(stamp_to_sec(a.header.stamp) == s for a in tracks), 10.0,
                              spin=spin), f"no tracks for frame {k}"
        assert wait_until(lambda: len(alerts) > 0 and stamp_to_sec(alerts[-1].header.stamp) == T0 + FRAMES - 1,
                          10.0,
                          spin=spin), "no alert for the last frame"
    finally:
        executor.remove_node(fuser)
        fuser.destroy_node()
        test_node.destroy_node()
    first, last = tracks[0], {t.id: t for t in tracks[-1].tracks}
    # The first frame: positions with deviations, but no velocity yet, so no CPA.
    assert all(t.has_world and not t.has_cpa and math.isnan(t.cpa_m) for t in first.tracks if t.id != "T3")
    assert all(t.distance_sigma_m > 0 and t.bearing_sigma_deg > 0 for t in first.tracks if t.id != "T3")
    bad = last["T3"]
    assert not bad.has_world and not bad.has_cpa and math.isnan(bad.distance_sigma_m)
    # Closing in at 5 m/s straight for the camera: CPA 0. The world filter, trusting a box 300 m out little along
    # the line of sight, has not reached the full speed yet, so its TCPA is later than the truth's
    # ((335.4 - 5 * 19) / 5 = 48 s); the figures are those of its published position and velocity:
    # TCPA = -(p . v) / |v|^2, CPA = |p + v TCPA|.
    t1 = last["T1"]
    p, v = np.array([t1.position.x, t1.position.y]), np.array([t1.velocity.x, t1.velocity.y])
    tcpa = -float(p @ v) / float(v @ v)
    assert t1.has_cpa and t1.cpa_alert
    assert t1.tcpa_s == pytest.approx(tcpa) and t1.cpa_m == pytest.approx(float(np.hypot(*(p + v * tcpa))))
    assert t1.cpa_m < 10.0 and 40.0 < t1.tcpa_s < 120.0
    assert t1.cpa_sigma_m > 0 and t1.tcpa_sigma_s > 0 and t1.distance_sigma_m > 0
    # At anchor 300 m out: CPA = the range (or near it), no alert.
    t2 = last["T2"]
    assert t2.has_cpa and not t2.cpa_alert and t2.cpa_m > 200.0
    # Only frames with an alert go out on the alert topic, and only the tracks in alert.
    assert len(alerts) < len(tracks)
    assert {t.id for a in alerts for t in a.tracks} == {"T1"}
    assert all(t.cpa_alert for a in alerts for t in a.tracks)
    assert fuser.health.counts["cpa_alerts"] == len(alerts)


def test_a_stale_or_bad_own_ship_fix_gives_no_cpa_and_is_counted(ros_context, monkeypatch):
    """No own ship known at a frame: has_cpa false, counted on /diagnostics, named once in the log; the node goes on."""
    from vessel_calib import geodesy
    from vessel_fixtures.ros_nodes import capture_published
    from vessel_msgs.msg import VesselTrackArray

    fuser = _fuser(monkeypatch, ros_context, ("own_ship_fix_topic", OWN_SHIP_TOPIC))
    log = _Lines()
    monkeypatch.setattr(fuser, "get_logger", lambda: log)
    published = capture_published(monkeypatch, fuser.publisher, VesselTrackArray)
    lat0, lon0 = fuser.camera.camera_lat, fuser.camera.camera_lon
    positions = {"T1": _closing_in(0), "T2": (260.0, 150.0)}
    try:
        fuser.on_tracks(tracks_at(T0, positions))  # before any fix: own_ship_missing
        for k in range(1, 8):  # fixes at each frame, at the calibration's position: a camera at rest
            fuser.on_own_ship_fix(own_ship_fix(T0 + k - 0.1, lat0, lon0))
            fuser.on_tracks(tracks_at(T0 + k, positions))
        fresh = {t.id: t for t in published[-1].tracks}
        fuser.on_tracks(tracks_at(T0 + 9, positions))  # the newest fix 2.1 s old: stale
        stale = published[-1].tracks
        lat, lon = geodesy.local_to_gps(5.0, 0.0, lat0, lon0)
        fuser.on_own_ship_fix(own_ship_fix(T0 + 9.5, math.nan, lon0))            # NaN: refused
        fuser.on_own_ship_fix(own_ship_fix(T0 + 9.6, lat, lon, status=-1))       # NO_FIX: refused
        fuser.on_own_ship_fix(own_ship_fix(T0 + 6.0, lat0, lon0))                # out of order: refused
        fuser.on_tracks(tracks_at(T0 + 10, positions))  # still stale: the refused fixes did not count
        fuser.on_own_ship_fix(own_ship_fix(T0 + 11.0, lat0, lon0))
        fuser.on_tracks(tracks_at(T0 + 11, positions))
        counts = fuser.health.counts
    finally:
        fuser.destroy_node()
    assert len(published) == 11  # every frame went out
    assert all(t.has_world and not t.has_cpa for t in published[0].tracks)
    assert fresh["T1"].has_cpa and fresh["T2"].has_cpa
    assert all(t.has_world and not t.has_cpa and not t.cpa_alert and math.isnan(t.cpa_m) for t in stale)
    assert all(t.has_world and not t.has_cpa for t in published[-2].tracks)
    assert all(t.has_cpa for t in published[-1].tracks)  # back once a fresh fix came
    assert (counts["own_ship_missing"], counts["own_ship_stale"]) == (1, 2)
    assert (counts["own_ship_bad_fix"], counts["own_ship_no_fix"], counts["own_ship_fix_out_of_order"]) == (1, 1, 1)
    assert counts["own_ship_fixes"] == 8
    warnings = [message for level, message in log.lines if level == "warning"]
    for kind in ("own_ship_missing", "own_ship_stale", "own_ship_bad_fix", "own_ship_no_fix"):
        assert sum(f"'{kind}'" in message for message in warnings) == 1, (kind, warnings)


def _run_moving(monkeypatch, ros_context, own_speed, world, frames=12, topic=OWN_SHIP_TOPIC):
    """The published arrays of frames 1 s apart of one vessel at rest at ``world`` (the fixed frame).

    The own ship goes east at ``own_speed`` from the calibration's position, a fix every 0.5 s (none without a topic).
    """
    from vessel_calib import geodesy
    from vessel_fixtures.ros_nodes import capture_published
    from vessel_msgs.msg import VesselTrackArray

    with monkeypatch.context() as patch:  # one node after the other
        fuser = _fuser(patch, ros_context, ("own_ship_fix_topic", topic))
        published = capture_published(patch, fuser.publisher, VesselTrackArray)
        lat0, lon0 = fuser.camera.camera_lat, fuser.camera.camera_lon
        try:
            for k in range(frames):
                for dt in (-0.5, 0.0) if topic else ():
                    lat, lon = geodesy.local_to_gps(own_speed * (k + dt), 0.0, lat0, lon0)
                    fuser.on_own_ship_fix(own_ship_fix(T0 + k + dt, lat, lon))
                relative = np.asarray(world) - [own_speed * k, 0.0]
                fuser.on_tracks(tracks_at(T0 + k, {"V": relative}))
        finally:
            fuser.destroy_node()
    return published, (lat0, lon0)


def test_a_moving_own_ship_shifts_the_world_positions(ros_context, monkeypatch):
    """A vessel at rest seen from an own ship going east at 4 m/s: at rest over ground, at its true lat/lon.

    The boxes are measured from the moving camera, so relative to the camera the vessel goes west at 4 m/s; the
    fuser places each measurement by the camera's position then, so its filter sees a vessel at rest.
    """
    from vessel_calib import geodesy

    world, speed, frames = np.array([320.0, 180.0]), 4.0, 12
    published, (lat0, lon0) = _run_moving(monkeypatch, ros_context, speed, world, frames)
    last = published[-1].tracks[0]
    k = frames - 1
    relative = world - [speed * k, 0.0]  # (276, 180) from the camera now
    true_lat, true_lon = geodesy.local_to_gps(*world, lat0, lon0)
    assert last.has_world
    assert geodesy.haversine_m(last.latitude, last.longitude, true_lat, true_lon) < 3.0
    assert [last.position.x, last.position.y] == pytest.approx(relative, abs=3.0)
    assert last.distance_m == pytest.approx(float(np.hypot(*relative)), abs=3.0)
    assert last.bearing_deg == pytest.approx(math.degrees(math.atan2(*relative)), abs=0.5)
    assert math.hypot(last.velocity.x, last.velocity.y) < 0.5  # over ground: at rest
    # CPA against the moving own ship: r = (276, 180), w = (-4, 0) -> TCPA = 276 * 4 / 16 = 69 s, CPA = 180 m.
    assert last.has_cpa and not last.cpa_alert
    assert last.tcpa_s == pytest.approx(69.0, rel=0.1) and last.cpa_m == pytest.approx(180.0, abs=10.0)
    # Every frame's published position follows the camera: relative to it, the vessel goes west at 4 m/s.
    xs = [a.tracks[0].position.x for a in published[4:]]
    assert np.diff(xs) == pytest.approx(-speed, abs=0.5)
    # A fixed camera (no topic) fed the same boxes: the same first frame (the own ship starts at the calibration's
    # position), then a vessel going west (its filter still catching up with 4 m/s) and placed about the
    # calibration's position, tens of metres west of the truth by the end.
    fixed, _ = _run_moving(monkeypatch, ros_context, speed, world, frames, topic="")
    start, still_start = published[0].tracks[0], fixed[0].tracks[0]
    assert (start.position.x, start.position.y, start.latitude, start.longitude) == pytest.approx(
        (still_start.position.x, still_start.position.y, still_start.latitude, still_start.longitude), abs=1e-6)
    still = fixed[-1].tracks[0]
    assert still.velocity.x < -1.0
    assert geodesy.haversine_m(still.latitude, still.longitude, true_lat, true_lon) > 25.0


def test_the_alert_parameters_are_live_and_checked(ros_context, monkeypatch):
    from vessel_fixtures.ros_nodes import set_parameter

    fuser = _fuser(monkeypatch, ros_context)
    try:
        assert set_parameter(fuser, "collision.cpa_alert_m", 80.0).successful
        assert set_parameter(fuser, "collision.cpa_sigma_k", 1.0).successful
        assert (fuser.alert_rule.cpa_alert_m, fuser.alert_rule.cpa_sigma_k) == (80.0, 1.0)
        assert not set_parameter(fuser, "collision.tcpa_alert_s", -1.0).successful
        assert not set_parameter(fuser, "own_ship_fix_topic", "/elsewhere").successful  # read-only: a restart
    finally:
        fuser.destroy_node()
