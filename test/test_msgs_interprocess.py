"""vessel_msgs travel between two processes: a publisher subprocess and a subscriber in the test process."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

PUBLISHER = textwrap.dedent(
    """
    import math, sys, time
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from vessel_msgs.msg import Detection2D, Detection2DArray, ObjectHypothesisWithPose, VesselTrack, VesselTrackArray

    rclpy.init()
    node = rclpy.create_node("msgs_publisher")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    detections_pub = node.create_publisher(Detection2DArray, "/test/detections", qos)
    tracks_pub = node.create_publisher(VesselTrackArray, "/test/tracks", qos)
    deadline = time.monotonic() + 30
    while (detections_pub.get_subscription_count() == 0 or tracks_pub.get_subscription_count() == 0):
        if time.monotonic() > deadline:
            sys.exit("no subscriber matched")
        time.sleep(0.05)
    for index in range(5):
        detections = Detection2DArray()
        detections.header.stamp.sec = 1601494800 + index
        detections.header.frame_id = "camera"
        detection = Detection2D()
        detection.header = detections.header
        detection.bbox.center.position.x = 640.5 + index
        detection.bbox.center.position.y = 430.25
        detection.bbox.size_x = 48.0
        detection.bbox.size_y = 20.0
        hypothesis = ObjectHypothesisWithPose()
        hypothesis.hypothesis.class_id = "boat"
        hypothesis.hypothesis.score = 0.75
        detection.results.append(hypothesis)
        detection.id = f"det{index}"
        detections.detections.append(detection)
        detections_pub.publish(detections)

        tracks = VesselTrackArray()
        tracks.header = detections.header
        track = VesselTrack()
        track.header = detections.header
        track.id = "7"
        track.is_target = True
        track.status = VesselTrack.STATUS_CONFIRMED
        track.has_world = True
        track.position.x = 120.0 + index
        track.position.y = 30.0
        track.position_covariance = [4.0, 0.5, 0.5, 9.0]
        track.latitude = 32.703
        track.longitude = -117.2333
        track.distance_m = 123.7
        track.expected_error_m = math.nan
        track.detection_count = index + 1
        tracks.tracks.append(track)
        tracks_pub.publish(tracks)
        time.sleep(0.05)
    time.sleep(1.0)
    node.destroy_node()
    rclpy.shutdown()
    """
)


@pytest.mark.ros
def test_detections_and_tracks_cross_processes(ros_context, ros_env, wait_until):
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from vessel_msgs.msg import Detection2DArray, VesselTrack, VesselTrackArray

    node = rclpy.create_node("msgs_subscriber", context=ros_context)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    detections, tracks = [], []
    node.create_subscription(Detection2DArray, "/test/detections", detections.append, qos)
    node.create_subscription(VesselTrackArray, "/test/tracks", tracks.append, qos)
    executor = rclpy.executors.SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    publisher = subprocess.Popen([sys.executable, "-c", PUBLISHER], env=ros_env, stderr=subprocess.PIPE, text=True)
    try:
        assert wait_until(lambda: len(detections) == 5 and len(tracks) == 5, 40,
                          spin=lambda: executor.spin_once(timeout_sec=0.05)), publisher.stderr
    finally:
        publisher.wait(timeout=30)
        node.destroy_node()
    assert publisher.returncode == 0, publisher.stderr.read()
    assert [d.header.stamp.sec for d in detections] == [1601494800 + i for i in range(5)]
    first = detections[0].detections[0]
    assert first.bbox.center.position.x == 640.5
    assert first.bbox.size_x == 48.0
    assert first.results[0].hypothesis.class_id == "boat"
    assert first.results[0].hypothesis.score == 0.75
    assert first.id == "det0"
    track = tracks[4].tracks[0]
    assert track.id == "7" and track.is_target and track.has_world
    assert track.status == VesselTrack.STATUS_CONFIRMED
    assert list(track.position_covariance) == [4.0, 0.5, 0.5, 9.0]
    assert track.position.x == 124.0 and track.detection_count == 5
    assert track.expected_error_m != track.expected_error_m  # NaN survives the wire
