"""wire: rosbags' CDR and rclpy's read each other's track arrays field for field; bad bytes or fields are named."""

from __future__ import annotations

import math

import numpy as np
import pytest

ARRAY = "vessel_msgs/msg/VesselTrackArray"


def _filled(msg, rng: np.random.Generator):
    """``msg`` (an rclpy message) with every field set to a value unlike its default (NaN in some floats)."""
    from rosidl_runtime_py.utilities import get_message

    for name, kind in msg.get_fields_and_field_types().items():
        current = getattr(msg, name)
        if kind.startswith("float64[") or kind.startswith("double["):
            values = rng.normal(size=len(current))
            values[0] = math.nan if rng.random() < 0.5 else values[0]
            setattr(msg, name, values)
        elif kind in ("double", "float64", "float"):
            setattr(msg, name, math.nan if rng.random() < 0.2 else float(rng.normal() * 1e3))
        elif kind == "string":
            setattr(msg, name, f"{name}-{rng.integers(1000)}")
        elif kind == "boolean":
            setattr(msg, name, True)
        elif kind in ("uint8", "octet"):
            setattr(msg, name, int(rng.integers(1, 255)))
        elif kind in ("uint32", "int32"):
            setattr(msg, name, int(rng.integers(1, 2**31 - 1)))
        elif "/" in kind:
            setattr(msg, name, _filled(get_message(kind)(), rng))
        else:
            raise AssertionError(f"the test does not fill {kind} fields ({name}): extend _filled")
    return msg


def _tracks(count: int, seed: int = 0):
    from vessel_msgs.msg import VesselTrack, VesselTrackArray

    rng = np.random.default_rng(seed)
    array = VesselTrackArray()
    array.header.stamp.sec, array.header.stamp.nanosec, array.header.frame_id = 1_700_000_000, 123, "camera"
    array.tracks = [_filled(VesselTrack(), rng) for _ in range(count)]
    return array


@pytest.mark.parametrize("count", [0, 1, 7])
def test_rclpy_and_wire_read_each_others_track_arrays(count):
    from rclpy.serialization import deserialize_message, serialize_message

    from vessel_common.wire import WireType
    from vessel_msgs.msg import VesselTrackArray

    wire = WireType(ARRAY)
    sent = _tracks(count, seed=count)
    decoded = wire.decode(serialize_message(sent))
    assert len(decoded.tracks) == count
    if count:
        first = decoded.tracks[0]
        assert first.id == sent.tracks[0].id
        assert str(first.bbox.center.position.x) == str(sent.tracks[0].bbox.center.position.x)  # NaN or a number
        assert np.array_equal(first.position_covariance, sent.tracks[0].position_covariance, equal_nan=True)
    back = deserialize_message(wire.encode(decoded), VesselTrackArray)
    assert repr(back) == repr(sent)


def test_a_new_message_is_the_rclpy_default_and_an_edited_one_reaches_rclpy():
    from rclpy.serialization import deserialize_message

    from vessel_common.wire import WireType
    from vessel_msgs.msg import VesselTrack, VesselTrackArray

    wire, track_type = WireType(ARRAY), WireType("vessel_msgs/msg/VesselTrack")
    empty = deserialize_message(wire.encode(wire.new(tracks=[track_type.new()])), VesselTrackArray)
    assert repr(empty) == repr(VesselTrackArray(tracks=[VesselTrack()]))
    track = track_type.new(id="T7", distance_m=812.5)
    track.bbox.size_x = 31.0
    track.position_covariance = np.array([4.0, 0.5, 0.5, 9.0])
    received = deserialize_message(wire.encode(wire.new(tracks=[track])), VesselTrackArray).tracks[0]
    assert (received.id, received.distance_m, received.bbox.size_x) == ("T7", 812.5, 31.0)
    assert list(received.position_covariance) == [4.0, 0.5, 0.5, 9.0]


def test_bad_bytes_and_bad_fields_are_named():
    from rclpy.serialization import serialize_message

    from vessel_common.errors import DataError
    from vessel_common.wire import WireType

    wire, track_type = WireType(ARRAY), WireType("vessel_msgs/msg/VesselTrack")
    cdr = serialize_message(_tracks(3))
    for bad in (b"", b"\x07\x07\x00\x00" + cdr[4:], cdr[: len(cdr) // 2]):
        with pytest.raises(DataError, match="VesselTrackArray message that cannot be decoded"):
            wire.decode(bad)
    track = track_type.new()
    track.position_covariance = np.zeros(3)
    with pytest.raises(DataError, match="wrong type or length"):
        wire.encode(wire.new(tracks=[track]))
    with pytest.raises(DataError, match="has no field colour"):
        track_type.new(colour="red")
    with pytest.raises(DataError, match="unknown message type"):
        WireType("vessel_msgs/msg/NoSuchType")


def test_the_callbacks_count_what_they_cannot_decode_or_encode_and_go_on():
    from rclpy.serialization import serialize_message

    from vessel_common.wire import WireType, decoding_callback, encoded_or_none

    class Health:
        def __init__(self):
            self.problems: list[tuple[str, str]] = []

        def problem(self, kind, message):
            self.problems.append((kind, message))

    wire, health, received = WireType(ARRAY), Health(), []
    callback = decoding_callback(wire, received.append, health)
    callback(b"\x00\x01\x00\x00garbage")
    callback(serialize_message(_tracks(2)))
    assert len(received) == 1 and len(received[0].tracks) == 2
    assert [kind for kind, _ in health.problems] == ["undecodable_message"]
    bad = wire.new(tracks=[WireType("vessel_msgs/msg/VesselTrack").new(pose_sigma_px=np.zeros(5))])
    assert encoded_or_none(wire, bad, health) is None
    assert health.problems[-1][0] == "unencodable_message" and "not published" in health.problems[-1][1]
