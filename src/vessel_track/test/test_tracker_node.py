"""The tracker node in its own process, fed a simulated scenario by this test process.

Checks that the published tracks (ids, statuses, stamps, filtered centres) are those of the ROS-free tracker on
the same detections, that bad messages are counted on /diagnostics without stopping the node, and that SIGINT
ends it with status 0. Needs the built workspace (``source ros2_ws/install/setup.bash``); skipped otherwise.
"""

import math
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")
vessel_msgs = pytest.importorskip("vessel_msgs.msg", reason="vessel_msgs is not built: build ros2_ws first")

REPO = Path(__file__).resolve().parents[3]
PARAMS = REPO / "config" / "parts" / "tracker.yaml"


def detection_array(stamp, boxes, scores, class_id="boat"):
    from vessel_common.qos import sec_to_stamp
    from vessel_msgs.msg import Detection2D, Detection2DArray, ObjectHypothesisWithPose

    msg = Detection2DArray()
    msg.header.stamp = sec_to_stamp(stamp)
    msg.header.frame_id = "camera"
    for box, score in zip(boxes, scores, strict=True):
        x1, y1, x2, y2 = (float(v) for v in box)  # ints in float64 fields are serialised as garbage by rclpy
        det = Detection2D()
        det.header = msg.header
        det.bbox.center.position.x = (x1 + x2) / 2.0
        det.bbox.center.position.y = (y1 + y2) / 2.0
        det.bbox.size_x = x2 - x1
        det.bbox.size_y = y2 - y1
        hyp = ObjectHypothesisWithPose()
        hyp.hypothesis.class_id = class_id
        hyp.hypothesis.score = float(score)
        det.results.append(hyp)
        msg.detections.append(det)
    return msg


@pytest.fixture
def driver(ros_context, wait_until):
    """A driver node in this process, and ``spin_until(predicate, timeout_s)`` spinning it."""
    node = rclpy.create_node("tracker_test_driver", context=ros_context)
    executor = rclpy.executors.SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)

    def spin_until(predicate, timeout_s):
        return wait_until(predicate, timeout_s, spin=lambda: executor.spin_once(timeout_sec=0.05))

    try:
        yield node, spin_until
    finally:
        node.destroy_node()


@pytest.fixture
def ros_graph(start_node, driver):
    """The tracker node started with its part file, and the driver node (the shared fixtures)."""
    tracker = start_node("vessel_track", "tracker", "--ros-args", "--params-file", str(PARAMS))
    node, spin_until = driver
    return tracker, node, spin_until


def test_tracker_node_tracks_a_scenario_and_counts_bad_input(ros_graph):
    from diagnostic_msgs.msg import DiagnosticArray

    from vessel_common.qos import reliable_qos, stamp_to_sec
    from vessel_msgs.msg import Detection2DArray, VesselTrack, VesselTrackArray
    from vessel_tools.track.simulation import harbour_scenario
    from vessel_track.tracker import MultiTargetTracker
    from vessel_track.tracker_config import TrackerConfig

    tracker, node, spin_until = ros_graph
    received: list = []
    diagnostics: list = []
    publisher = node.create_publisher(Detection2DArray, "/vessel/detections", reliable_qos(10))
    node.create_subscription(VesselTrackArray, "/vessel/tracks/screen", received.append, reliable_qos(10))
    node.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 10)
    matched = spin_until(lambda: publisher.get_subscription_count() >= 1
                         and node.count_publishers("/vessel/tracks/screen") >= 1, 30.0)
    assert matched, f"tracker node did not come up:\n{tracker.output()}"

    def send(stamp, boxes, scores):
        before = len(received)
        publisher.publish(detection_array(stamp, boxes, scores))
        assert spin_until(lambda: len(received) > before, 10.0), \
            f"no tracks for stamp {stamp}:\n{tracker.output()}"
        return received[-1]

    result = harbour_scenario(frame_interval_s=4.0, duration_s=100.0, seed=0).run()
    reference = MultiTargetTracker(TrackerConfig())
    for frame in result.frames:
        out = send(frame.stamp, frame.boxes_xyxy, frame.scores)
        expected = reference.update(frame.stamp, frame.boxes_xyxy, frame.scores)
        assert stamp_to_sec(out.header.stamp) == pytest.approx(frame.stamp, abs=1e-6)
        assert out.header.frame_id == "camera"
        assert [(t.id, t.status) for t in out.tracks] == [(s.track_id, int(s.status)) for s in expected]
        for t, s in zip(out.tracks, expected, strict=True):
            assert stamp_to_sec(t.header.stamp) == pytest.approx(frame.stamp, abs=1e-6)
            np.testing.assert_allclose([t.bbox.center.position.x, t.bbox.center.position.y], s.center, atol=1e-6)
            np.testing.assert_allclose([t.bbox.size_x, t.bbox.size_y], s.size, atol=1e-6)
            np.testing.assert_allclose(t.screen_covariance, s.center_cov.ravel(), rtol=1e-9)
            assert stamp_to_sec(t.last_seen) == pytest.approx(s.last_seen, abs=1e-6)
            assert t.detection_count == s.detection_count and not t.is_target and not t.has_world
            assert math.isnan(t.position.x) and math.isnan(t.latitude)
    confirmed = {t.id for t in out.tracks if t.status in (VesselTrack.STATUS_CONFIRMED, VesselTrack.STATUS_COASTING)}
    assert len(confirmed) >= 3

    # Bad input: NaN and negative-size boxes, an empty frame, then stamps going back (a replay restarted).
    t_last = result.frames[-1].stamp
    bad = send(t_last + 1.0, [[np.nan, 400, 420, 430], [500, 400, 480, 430], [150, 600, 180, 616]], [0.9, 0.9, 0.9])
    assert sum(1 for t in bad.tracks if t.status == VesselTrack.STATUS_TENTATIVE and t.detection_count == 1) == 1
    empty = send(t_last + 2.0, [], [])
    assert stamp_to_sec(empty.header.stamp) == pytest.approx(t_last + 2.0)
    assert all(t.status != VesselTrack.STATUS_CONFIRMED for t in empty.tracks)
    restarted = send(result.frames[0].stamp, result.frames[0].boxes_xyxy, result.frames[0].scores)
    lost = [t for t in restarted.tracks if t.status == VesselTrack.STATUS_LOST]
    assert {t.id for t in lost} >= confirmed
    assert all(t.status in (VesselTrack.STATUS_LOST, VesselTrack.STATUS_TENTATIVE) for t in restarted.tracks)
    # A frame slightly out of order is dropped without output: the next message is the next valid frame's.
    publisher.publish(detection_array(result.frames[0].stamp - 0.5, [], []))
    following = send(result.frames[1].stamp, result.frames[1].boxes_xyxy, result.frames[1].scores)
    assert stamp_to_sec(following.header.stamp) == pytest.approx(result.frames[1].stamp, abs=1e-6)
    assert len(received) == len(result.frames) + 4

    def counts():
        for array in reversed(diagnostics):
            for status in array.status:
                if status.name == "tracker":
                    return {kv.key: kv.value for kv in status.values}
        return {}

    assert spin_until(lambda: counts().get("count.resets") == "1"
                      and counts().get("count.detections_invalid") == "2"
                      and counts().get("count.out_of_order_frames") == "1", 10.0), counts()
    assert tracker.process.poll() is None, "the tracker node died on bad input"
    log = tracker.output()
    assert tracker.stop() == 0
    assert log.count("counted as 'detections_invalid'") == 1 and "Traceback" not in log


def test_every_tracker_config_field_is_a_described_parameter():
    from dataclasses import fields

    from vessel_track.parameter_tables import TRACKER_PARAMETERS
    from vessel_track.tracker_config import TrackerConfig

    assert {f.name for f in fields(TrackerConfig)} <= set(TRACKER_PARAMETERS.names)
    assert all(param.description.strip() for param in TRACKER_PARAMETERS)
    defaults = TrackerConfig()
    assert all(TRACKER_PARAMETERS[f.name].default == getattr(defaults, f.name) for f in fields(TrackerConfig))


def test_every_vessel_is_tracked_and_its_confidence_is_the_target_hypothesis():
    from vessel_detect.detector import Detections
    from vessel_detect.detector_node import detections_to_msg
    from vessel_track.tracker_node import detections_to_arrays

    detections = Detections(np.array([[10.0, 20, 50, 40], [100.0, 20, 140, 40]]), np.array([0.9, 0.8]),
                            np.array([0, 1]), ["vessel_of_interest", "vessel"], np.array([0.9, 0.05]))
    msg = detections_to_msg(detections, detection_array(5.0, [], []).header, "vessel_of_interest")
    assert [[r.hypothesis.class_id for r in d.results] for d in msg.detections] == [
        ["vessel_of_interest"], ["vessel", "vessel_of_interest"]]
    boxes, scores = detections_to_arrays(msg, None, "vessel_of_interest")
    assert len(boxes) == 2 and scores.tolist() == pytest.approx([0.9, 0.05])
    _, best = detections_to_arrays(msg, None)
    assert best.tolist() == pytest.approx([0.9, 0.8])
    _, only_vessels = detections_to_arrays(msg, frozenset({"vessel"}), "vessel_of_interest")
    assert only_vessels.tolist() == pytest.approx([0.05])


def test_a_standby_tracker_publishes_only_once_promoted(start_node, driver, ask_service):
    """A hot standby (``standby:=true``) tracks silently and publishes from the message after SIGUSR1.

    ``./vessel graph --hot-standby`` promotes a spare this way when the active tracker dies; the spare has been
    discovered and has run its core on every message, so it carries on at once.
    """
    import signal

    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    from vessel_common.qos import reliable_qos
    from vessel_msgs.msg import Detection2DArray, VesselTrackArray
    from vessel_tools.track.simulation import harbour_scenario
    from vessel_track.tracker import MultiTargetTracker
    from vessel_track.tracker_config import TrackerConfig

    tracker = start_node("vessel_track", "tracker", "--ros-args", "--params-file", str(PARAMS),
                         "-r", "__ns:=/standby_1", "-p", "standby:=true",
                         # a spare's topics are its active node's (the graph runner's standby_topics)
                         "-p", "input_topic:=/vessel/detections", "-p", "output_topic:=/vessel/tracks/screen")
    node, spin_until = driver
    received: list = []
    publisher = node.create_publisher(Detection2DArray, "/vessel/detections", reliable_qos(10))
    node.create_subscription(VesselTrackArray, "/vessel/tracks/screen", received.append, reliable_qos(10))
    assert spin_until(lambda: publisher.get_subscription_count() >= 1
                      and node.count_publishers("/vessel/tracks/screen") >= 1, 30.0), tracker.output()
    frames = harbour_scenario(frame_interval_s=4.0, duration_s=60.0, seed=0).run().frames
    reference = MultiTargetTracker(TrackerConfig())
    half = len(frames) // 2
    for frame in frames[:half]:
        publisher.publish(detection_array(frame.stamp, frame.boxes_xyxy, frame.scores))
        reference.update(frame.stamp, frame.boxes_xyxy, frame.scores)
    spin_until(lambda: False, 2.0)
    assert received == [], "a standby tracker published"

    tracker.process.send_signal(signal.SIGUSR1)
    for frame in frames[half:]:
        before = len(received)
        publisher.publish(detection_array(frame.stamp, frame.boxes_xyxy, frame.scores))
        expected = reference.update(frame.stamp, frame.boxes_xyxy, frame.scores)
        assert spin_until(lambda before=before: len(received) > before, 10.0), tracker.output()
        # It tracked while it waited: the same tracks as a tracker that published all along.
        assert [(t.id, t.status) for t in received[-1].tracks] == [(s.track_id, int(s.status)) for s in expected]
    assert "promoted from standby: publishing from now on" in tracker.output()

    setter = node.create_client(SetParameters, "/standby_1/tracker/set_parameters")
    back = ParameterMsg(name="standby", value=ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=True))
    result = ask_service(setter, SetParameters.Request(parameters=[back]), spin_until).results[0]
    assert not result.successful and "a promoted node stays active" in result.reason
    assert tracker.stop() == 0


def test_a_parameter_change_is_applied_live_or_refused(monkeypatch, ros_context):
    """``ros2 param set`` on a running tracker: a live setting takes effect, a bad or read-only one is refused."""
    from vessel_fixtures.ros_nodes import node_in_context, set_parameter

    pytest.importorskip("vessel_msgs.msg", reason="vessel_msgs is not built: run ./vessel setup")
    from vessel_track.tracker_node import TrackerNode

    node = node_in_context(monkeypatch, ros_context, TrackerNode)
    try:
        assert set_parameter(node, "min_score", 0.95).successful
        assert node.tracker.config.min_score == 0.95
        node.tracker.update(1.0, np.array([[100.0, 100.0, 140.0, 120.0]]), np.array([0.9]))
        assert node.tracker.track_ids == []  # the 0.9 box is below the new min_score
        refused = set_parameter(node, "gate_px", 100.0), set_parameter(node, "max_gate_px", 50.0)
        assert refused[0].successful and not refused[1].successful and "max_gate_px" in refused[1].reason
        assert node.get_parameter("max_gate_px").value == node.tracker.config.max_gate_px != 50.0
        for name, value in (("input_topic", "/elsewhere"), ("history_length", 5)):
            result = set_parameter(node, name, value)
            assert not result.successful and "read-only" in result.reason
        assert not set_parameter(node, "association", "nearest").successful
        assert set_parameter(node, "classes", ["boat"]).successful and node.classes == frozenset({"boat"})
    finally:
        node.destroy_node()


class _CreatesAFileWhenUnpickled:
    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return open, (self.path, "w")


class _Lines:
    """A node's logger that keeps what it is given: ``lines`` of (level, message)."""

    def __init__(self):
        self.lines: list[tuple[str, str]] = []

    def __getattr__(self, level):
        return lambda message, **kwargs: self.lines.append((level, str(message)))


def test_a_restarted_tracker_refuses_a_pickled_state_file_and_carries_on_from_its_own(monkeypatch, ros_context,
                                                                                        tmp_path):
    """A pickle at ``state_file`` (the old format, or crafted to run code) is never loaded: one warning, a cold start.

    The snapshots the node then writes are JSON; a tracker restarted on them publishes what one never stopped does.
    """
    import pickle

    from rclpy.parameter import Parameter

    from vessel_common.state_file import VERSION
    from vessel_fixtures.ros_nodes import node_in_context
    from vessel_tools.track.simulation import harbour_scenario
    from vessel_track.tracker_node import TrackerNode

    marker, path = tmp_path / "created_by_the_pickle", tmp_path / "tracker.state"
    path.write_bytes(pickle.dumps({"format": "vessel_state/1", "state": _CreatesAFileWhenUnpickled(marker)}))
    frames = harbour_scenario(seed=3).run().frames
    half = len(frames) // 2

    def run(frames, state_file):
        from vessel_fixtures.ros_nodes import capture_published
        from vessel_msgs.msg import VesselTrackArray
        overrides = [Parameter("state_file", value=state_file), Parameter("state_period_s", value=0.0)]
        with monkeypatch.context() as patch:  # one process, one node after the other
            node = node_in_context(patch, ros_context, TrackerNode, overrides)
            log = _Lines()
            patch.setattr(node, "get_logger", lambda: log)
            published = capture_published(patch, node.publisher, VesselTrackArray)
            try:
                for frame in frames:
                    node.on_detections(detection_array(frame.stamp, frame.boxes_xyxy, frame.scores))
                tracks = [[(t.id, t.status, round(t.bbox.center.position.x, 6)) for t in m.tracks] for m in published]
                return tracks, log.lines, node.health.counts, node.tracker.config.max_tracks
            finally:
                node.destroy_node()

    straight, _, _, max_tracks = run(frames, "")
    before, lines, counts, _ = run(frames[:half], str(path))
    assert not marker.exists()
    refused = [message for _, message in lines if "state file" in message]
    assert len(refused) == 1 and counts.get("state_file_refused") == 1, lines
    assert refused[0].startswith(f"state file {path} is not a tracker state file of version {VERSION}: it is a pickle")
    assert "; cold start" in refused[0] and before == straight[:half]  # cold: as if there were no file
    after, lines, counts, _ = run(frames[half:], str(path))  # the restart, on the JSON snapshot the first one wrote
    # The snapshot holds the counters too: the restarted node carries on from the first one's (one refusal, then).
    assert counts.get("resumed_from_state_file") == 1 and counts.get("state_file_refused") == 1, lines
    assert not [message for _, message in lines if "not a" in message], lines
    known = {track_id for frame in before for track_id, _, _ in frame}

    def renumbered(track_id):  # a restarted tracker numbers new tracks max_tracks further on
        return track_id if track_id in known else f"T{int(track_id[1:]) - max_tracks}"

    assert [[(renumbered(i), *rest) for i, *rest in frame] for frame in after] == straight[half:]


@pytest.fixture
def tracker_node(monkeypatch, ros_context):
    """A TrackerNode in this process with its defaults, and the arrays it published."""
    from vessel_fixtures.ros_nodes import capture_published, node_in_context
    from vessel_msgs.msg import VesselTrackArray
    from vessel_track.tracker_node import TrackerNode

    node = node_in_context(monkeypatch, ros_context, TrackerNode)
    published = capture_published(monkeypatch, node.publisher, VesselTrackArray)
    try:
        yield node, published
    finally:
        node.destroy_node()


def _stamped(sec, nanosec, boxes=((100.0, 100.0, 140.0, 120.0),), scores=(0.9,)):
    msg = detection_array(1.0, boxes, scores)
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    return msg


def test_findings_8_10_the_tracker_refuses_invalid_repeated_and_zero_stamps(tracker_node):
    """Invalid, repeated and zero or negative stamps are refused; a replay restart still resets the tracker.

    A stamp with nanosec >= 1e9 made the next good frame look out of order, a repeated stamp was a second frame,
    and zero and negative stamps were tracked and published.
    """
    from vessel_common.qos import stamp_to_sec
    from vessel_msgs.msg import VesselTrack

    node, published = tracker_node
    for sec, nanosec in ((100, 0), (100, 1_500_000_000), (101, 0), (101, 0), (0, 0), (-100, 0), (100, 800_000_000)):
        node.on_detections(_stamped(sec, nanosec))
    assert [stamp_to_sec(m.header.stamp) for m in published] == [100.0, 101.0]
    assert all(stamp_to_sec(t.first_seen) > 0 and stamp_to_sec(t.last_seen) > 0 for m in published for t in m.tracks)
    counts = node.health.counts
    assert (counts["bad_stamp"], counts["duplicate_stamp"], counts["out_of_order_frames"]) == (3, 1, 1)
    node.on_detections(_stamped(50, 0))  # back by more than backwards_reset_s: a replay restarted
    assert stamp_to_sec(published[-1].header.stamp) == 50.0 and node.health.counts["resets"] == 1
    assert VesselTrack.STATUS_LOST in {t.status for t in published[-1].tracks}


def test_finding_7_a_score_outside_0_1_drops_the_detection_not_the_frame(tracker_node):
    node, published = tracker_node
    boxes = ((100.0, 100.0, 140.0, 120.0), (600.0, 300.0, 660.0, 330.0))
    node.on_detections(_stamped(100, 0, boxes, (0.9, 0.8)))
    node.on_detections(_stamped(104, 0, boxes, (1e9, 0.7)))
    node.on_detections(_stamped(108, 0, boxes, (0.9, math.nan)))
    assert len(published) == 3 and node.health.counts["bad_score"] == 2
    assert all(0.0 <= t.confidence <= 1.0 for m in published for t in m.tracks)
    assert [t.detection_count for t in published[-1].tracks] == [2, 2]  # each kept its good detections
