"""NavSatFix content of the gps_publisher (needs sensor_msgs from the built workspace)."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")
pytest.importorskip("sensor_msgs.msg", reason="sensor_msgs is not importable: source ros2_ws/install/setup.bash")


def _track(**kw):
    from vessel_common.qos import sec_to_stamp

    base = dict(has_world=True, status=1, latitude=32.703, longitude=-117.233, last_seen=sec_to_stamp(100.0),
                position_covariance=[25.0, 5.0, 5.0, 4.0], expected_error_m=10.0, is_target=True)
    base.update(kw)
    return SimpleNamespace(**base)


def test_enu_covariance_modes():
    from vessel_track.error_model import MEAN_RADIAL_ERROR_PER_SIGMA
    from vessel_track.gps_publisher_node import enu_covariance

    sigma2 = (10.0 / MEAN_RADIAL_ERROR_PER_SIGMA) ** 2
    total = np.array(enu_covariance([25.0, 5.0, 5.0, 4.0], 10.0, "sum", 9.0)).reshape(3, 3)
    np.testing.assert_allclose(total[:2, :2], [[25 + sigma2, 5], [5, 4 + sigma2]])
    assert total[2, 2] == 9.0 and total[0, 2] == 0.0
    only_filter = np.array(enu_covariance([25.0, 5.0, 5.0, 4.0], 10.0, "filter")).reshape(3, 3)
    np.testing.assert_allclose(only_filter[:2, :2], [[25, 5], [5, 4]])
    model = np.array(enu_covariance([np.nan] * 4, 10.0, "sum")).reshape(3, 3)
    np.testing.assert_allclose(model[:2, :2], np.eye(2) * sigma2)
    biggest = np.array(enu_covariance([1.0, 0, 0, 1.0], 10.0, "max")).reshape(3, 3)
    np.testing.assert_allclose(biggest[:2, :2], np.eye(2) * sigma2)
    assert all(math.isnan(v) for v in enu_covariance([np.nan] * 4, math.nan, "sum")[:2])


def test_fix_status_follows_the_target():
    from sensor_msgs.msg import NavSatStatus

    from vessel_track.gps_publisher_node import fix_fields_of_track

    ok = fix_fields_of_track(_track(), 104.0, max_coast_s=12.0)
    assert ok.status == NavSatStatus.STATUS_FIX and ok.latitude == 32.703
    for bad in (None, _track(has_world=False), _track(status=3), _track(latitude=math.nan),
                _track(position_covariance=[math.nan] * 4, expected_error_m=math.nan)):
        fields = fix_fields_of_track(bad, 104.0, max_coast_s=12.0)
        assert fields.status == NavSatStatus.STATUS_NO_FIX and math.isnan(fields.latitude)
    stale = fix_fields_of_track(_track(), 130.0, max_coast_s=12.0)
    assert stale.status == NavSatStatus.STATUS_NO_FIX


@pytest.mark.parametrize("bad, problem", [
    (dict(latitude=95.0), "impossible_position"),
    (dict(latitude=1e9), "impossible_position"),
    (dict(longitude=-181.0), "impossible_position"),
    (dict(latitude=33.9), "implausible_target"),            # 133 km north of the camera
    (dict(position_covariance=[-4.0, 0.0, 0.0, 4.0]), "bad_covariance"),   # a negative variance
    (dict(position_covariance=[4.0, 1.0, 3.0, 4.0]), "bad_covariance"),    # not symmetric
    (dict(position_covariance=[1.0, 3.0, 3.0, 1.0]), "bad_covariance"),    # not positive semi-definite
    (dict(position_covariance=[1.0, math.inf, 0.0, 1.0]), "bad_covariance"),
    (dict(latitude=math.nan), "nonfinite_target"),
])
def test_an_impossible_target_is_never_published_as_a_fix(bad, problem):
    from sensor_msgs.msg import NavSatStatus

    from vessel_track.gps_publisher_node import fix_fields_of_track

    camera = (32.70297, -117.234631)
    assert fix_fields_of_track(_track(), 104.0, 12.0, origin=camera).status == NavSatStatus.STATUS_FIX
    fields = fix_fields_of_track(_track(**bad), 104.0, 12.0, origin=camera)
    assert fields.status == NavSatStatus.STATUS_NO_FIX and math.isnan(fields.latitude)
    assert fields.problem == problem and fields.detail


def _track_message(track_id, latitude=32.703, stamp_s=100, **fields):
    """A VesselTrack as the fuser publishes it in an array stamped ``stamp_s``, with ``fields`` replaced."""
    from vessel_msgs.msg import VesselTrack

    track = VesselTrack()
    track.id, track.is_target, track.has_world, track.status = track_id, True, True, 1
    track.latitude, track.longitude = latitude, -117.233
    track.header.stamp.sec = track.last_seen.sec = stamp_s
    track.first_seen.sec = stamp_s - 40
    track.confidence = 0.8
    track.screen_covariance = [16.0, 0.0, 0.0, 16.0]
    track.position_covariance = [25.0, 5.0, 5.0, 4.0]
    track.velocity_covariance = [0.5, 0.0, 0.0, 0.5]
    track.expected_error_m = 10.0
    for name, value in fields.items():
        setattr(track, name, value)
    return track


@pytest.fixture
def gps_node(monkeypatch, ros_context):
    """A GpsPublisherNode in this process: ``send(sec, *tracks, nanosec=0)`` and what it published."""
    import rclpy.parameter
    from sensor_msgs.msg import NavSatFix

    from vessel_fixtures.ros_nodes import capture_published, node_in_context

    pytest.importorskip("vessel_msgs.msg", reason="vessel_msgs is not built: run ./vessel setup")
    from vessel_msgs.msg import VesselTrackArray
    from vessel_track.gps_publisher_node import GpsPublisherNode

    builtin = [rclpy.parameter.Parameter("camera.builtin_calibration", value=True)]
    node = node_in_context(monkeypatch, ros_context, GpsPublisherNode, builtin)
    fixes = capture_published(monkeypatch, node.fix_publisher, NavSatFix)
    arrays = capture_published(monkeypatch, node.fixes_publisher, VesselTrackArray)

    def send(sec, *tracks, nanosec=0):
        message = VesselTrackArray()
        message.header.stamp.sec, message.header.stamp.nanosec = sec, nanosec
        message.tracks = list(tracks)
        node.on_tracks(message)

    try:
        yield SimpleNamespace(node=node, send=send, fixes=fixes, arrays=arrays, counts=lambda: node.health.counts)
    finally:
        node.destroy_node()


def test_the_node_skips_bad_stamps_and_publishes_no_fix_for_two_targets(gps_node):
    """A stamp with nanosec >= 1e9 is invalid; two tracks flagged is_target are ambiguous."""
    from sensor_msgs.msg import NavSatStatus

    send, fixes = gps_node.send, gps_node.fixes
    send(100, _track_message("T1"))
    assert [f.status.status for f in fixes] == [NavSatStatus.STATUS_FIX]
    send(101, _track_message("T1", stamp_s=101), nanosec=1_000_000_000)
    assert len(fixes) == 1 and gps_node.counts().get("bad_stamp") == 1
    send(102, _track_message("T1", stamp_s=102), _track_message("T2", 32.704, stamp_s=102))
    assert fixes[-1].status.status == NavSatStatus.STATUS_NO_FIX and gps_node.counts()["several_targets"] == 1
    send(103, _track_message("T1", 95.0, stamp_s=103))
    assert fixes[-1].status.status == NavSatStatus.STATUS_NO_FIX
    assert gps_node.counts()["impossible_position"] == 1


def test_finding_4_two_tracks_with_one_id_are_refused_and_counted(gps_node):
    from sensor_msgs.msg import NavSatStatus

    gps_node.send(100, _track_message("T1"), _track_message("T1", 32.704), _track_message("T2", is_target=False))
    assert [f.status.status for f in gps_node.fixes] == [NavSatStatus.STATUS_NO_FIX]
    assert [t.id for t in gps_node.arrays[-1].tracks] == ["T2"]
    assert gps_node.counts()["duplicate_track_id"] == 2 and "several_targets" not in gps_node.counts()


@pytest.mark.parametrize("bad, kind", [
    (dict(last_seen=SimpleNamespace(sec=104 + 1_000_000, nanosec=0)), "bad_track_time"),   # finding 5
    (dict(expected_error_m=-5.0), "bad_expected_error"),                                    # finding 6
    (dict(status=200), "bad_track_status"),                                                 # finding 9
    (dict(confidence=math.nan), "bad_confidence"),
    (dict(screen_covariance=[math.nan, 0.0, 0.0, 16.0]), "bad_screen_covariance"),
    (dict(screen_covariance=[-16.0, 0.0, 0.0, 16.0]), "bad_screen_covariance"),
    (dict(first_seen=SimpleNamespace(sec=110, nanosec=0)), "bad_track_time"),
    (dict(position_covariance=[math.nan] * 4), "bad_covariance"),
])
def test_findings_5_6_9_an_impossible_track_is_neither_a_fix_nor_in_the_array(gps_node, bad, kind):
    """Each used to be published: a future last_seen or a negative expected error even as STATUS_FIX."""
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import NavSatStatus

    bad = {name: Time(sec=v.sec, nanosec=v.nanosec) if isinstance(v, SimpleNamespace) else v
           for name, v in bad.items()}
    gps_node.send(100, _track_message("T1"))
    gps_node.send(104, _track_message("T1", stamp_s=104, **bad), _track_message("T2", stamp_s=104, is_target=False))
    assert [f.status.status for f in gps_node.fixes] == [NavSatStatus.STATUS_FIX, NavSatStatus.STATUS_NO_FIX]
    assert [t.id for t in gps_node.arrays[-1].tracks] == ["T2"]
    assert gps_node.counts()[kind] == 1


def test_findings_8_10_one_fix_per_stamp_and_none_stamped_zero_or_negative(gps_node):
    """A duplicate or slightly older stamp and zero or negative stamps publish nothing; a replay restart does."""
    send, fixes = gps_node.send, gps_node.fixes
    send(100, _track_message("T1"))
    send(100, _track_message("T1"))
    send(99, _track_message("T1", stamp_s=99), nanosec=800_000_000)
    send(0, _track_message("T1", stamp_s=0))
    send(-100, _track_message("T1", stamp_s=-100))
    assert [f.header.stamp.sec for f in fixes] == [100] and len(gps_node.arrays) == 1
    counts = gps_node.counts()
    assert (counts["duplicate_stamp"], counts["out_of_order_frames"], counts["bad_stamp"]) == (1, 1, 2)
    send(50, _track_message("T1", stamp_s=50))  # a replay restarted
    assert [f.header.stamp.sec for f in fixes] == [100, 50] and gps_node.counts()["stamp_backwards"] == 1
    assert all(f.header.stamp.sec > 0 for f in fixes)


def test_frames_a_restart_upstream_lost_are_counted(monkeypatch, ros_context):
    """A fuser killed and restarted leaves a gap in the stamps the GPS publisher gets: counted, the status stays."""
    pytest.importorskip("vessel_msgs.msg", reason="vessel_msgs is not built: run ./vessel setup")
    import rclpy.parameter

    from vessel_fixtures.ros_nodes import node_in_context
    from vessel_msgs.msg import VesselTrackArray
    from vessel_track.gps_publisher_node import GpsPublisherNode

    builtin = [rclpy.parameter.Parameter("camera.builtin_calibration", value=True)]
    node = node_in_context(monkeypatch, ros_context, GpsPublisherNode, builtin)
    try:
        node.fix_publisher.publish = lambda fix: None
        for sec in [100 + 4 * k for k in range(12) if k not in (8, 9)]:  # two frames never came
            message = VesselTrackArray()
            message.header.stamp.sec = sec
            message.tracks = [_track_message("T1", stamp_s=sec)]
            node.on_tracks(message)
        counts = node.health.counts
        assert counts.get("frames_missing_upstream") == 2 and counts.get("frames") == 10, counts
    finally:
        node.destroy_node()
