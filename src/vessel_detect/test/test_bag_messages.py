"""bag_messages: time stamps, the type store with the project's vessel_msgs types, message constructors."""

import math

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_detect import bag_messages, bag_reader, bag_topics, bag_writer
from vessel_fixtures import detect_synthetic as synthetic


def test_sec_to_ns_keeps_millisecond_stamps_exact():
    assert bag_messages.sec_to_ns(1601495752.884) == 1601495752_884000000
    assert bag_messages.sec_to_ns(0.0) == 0
    assert bag_messages.sec_to_ns(1.9999996) == 2_000_000_000
    with pytest.raises(DataError, match="finite"):
        bag_messages.sec_to_ns(math.nan)


def test_vessel_msgs_round_trip(tmp_path):
    store = bag_messages.typestore()
    assert "vessel_msgs/msg/VesselTrackArray" in store.fielddefs
    Track = store.types["vessel_msgs/msg/VesselTrack"]
    Array = store.types[bag_topics.VESSEL_TRACK_ARRAY]
    types = store.types
    stamp = bag_messages.sec_to_ns(synthetic.START_UTC)
    track = Track(
        header=bag_messages.header(stamp, "camera"),
        id="7",
        is_target=True,
        score=1.5,
        confidence=0.8,
        class_id="vessel",
        status=Track.STATUS_CONFIRMED,
        detection_count=12,
        first_seen=bag_messages.header(stamp, "").stamp,
        last_seen=bag_messages.header(stamp, "").stamp,
        bbox=types["vessel_msgs/msg/BoundingBox2D"](
            center=types["vessel_msgs/msg/Pose2D"](position=types["vessel_msgs/msg/Point2D"](x=640.0, y=420.0),
                                                   theta=0.0),
            size_x=40.0,
            size_y=20.0,
        ),
        screen_velocity=types["vessel_msgs/msg/Point2D"](x=1.0, y=0.0),
        screen_covariance=np.array([4.0, 0.0, 0.0, 4.0]),
        detection_bbox=types["vessel_msgs/msg/BoundingBox2D"](
            center=types["vessel_msgs/msg/Pose2D"](position=types["vessel_msgs/msg/Point2D"](x=641.0, y=421.0),
                                                   theta=0.0),
            size_x=42.0,
            size_y=19.0,
        ),
        has_world=True,
        position=types["geometry_msgs/msg/Point"](x=150.0, y=40.0, z=0.0),
        velocity=types["geometry_msgs/msg/Vector3"](x=0.0, y=2.5, z=0.0),
        position_covariance=np.array([25.0, 0.0, 0.0, 25.0]),
        velocity_covariance=np.array([1.0, 0.0, 0.0, 1.0]),
        latitude=32.7033,
        longitude=-117.233,
        distance_m=155.2,
        bearing_deg=75.0,
        expected_error_m=8.0,
        pose_sigma_px=np.array([0.0, 0.0]),
        distance_sigma_m=3.0,
        bearing_sigma_deg=0.5,
        has_cpa=True,
        cpa_m=40.0,
        cpa_sigma_m=6.0,
        tcpa_s=30.0,
        tcpa_sigma_s=4.0,
        cpa_alert=True,
    )
    with bag_writer.BagWriter(tmp_path / "tracks") as writer:
        writer.add_topic("/vessel/tracks", "vessel_msgs/VesselTrackArray")
        writer.write("/vessel/tracks", Array(header=bag_messages.header(stamp, "camera"), tracks=[track]))
    with bag_reader.BagReader(tmp_path / "tracks") as reader:
        [(t, message)] = reader.read_topic("/vessel/tracks")
    assert t == pytest.approx(synthetic.START_UTC)
    got = message.tracks[0]
    assert (got.id, got.is_target, got.detection_count, got.latitude) == ("7", True, 12, 32.7033)
    assert got.class_id == "vessel"
    assert got.bbox.center.position.y == 420.0
    assert (got.detection_bbox.center.position.x, got.detection_bbox.size_y) == (641.0, 19.0)
    np.testing.assert_array_equal(got.position_covariance, [25.0, 0.0, 0.0, 25.0])
    assert (got.has_cpa, got.cpa_m, got.tcpa_s, got.cpa_alert) == (True, 40.0, 30.0, True)
