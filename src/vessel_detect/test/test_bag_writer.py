"""bag_writer: rosbag2 MCAP folders written and read back with rosbags and with the mcap library."""

import numpy as np
import pytest
import yaml

from vessel_common.errors import DataError
from vessel_detect import bag_messages, bag_reader, bag_topics, bag_writer
from vessel_fixtures import detect_synthetic as synthetic


def test_round_trip_with_rosbags_and_mcap(tmp_path):
    path = tmp_path / "bag"
    stamps = synthetic.write_bag(path, frames=8, frame_step_s=0.25)
    meta = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["storage_identifier"] == "mcap"
    assert meta["message_count"] == 1 + 8 + 8
    assert meta["starting_time"]["nanoseconds_since_epoch"] == stamps[0]
    assert meta["duration"]["nanoseconds"] == stamps[-1] - stamps[0]
    qos = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"][0] for t in
           meta["topics_with_message_count"]}
    assert qos[bag_topics.DEFAULT_CAMERA_FIX_TOPIC]["durability"] == "transient_local"
    assert qos[bag_topics.DEFAULT_IMAGE_TOPIC]["reliability"] == "best_effort"

    with bag_reader.BagReader(path) as reader:
        images = list(reader.images())
        assert [bag_messages.sec_to_ns(t) for t, _ in images] == stamps
        assert [data for _, data in images] == [synthetic.frame_jpeg(k) for k in range(8)]
        # log time == header stamp for every message
        for message in reader.messages():
            assert message.log_time_ns == bag_messages.ns_of_stamp(reader.decode(message).header.stamp)
        truth = reader.fixes(bag_topics.DEFAULT_GPS_TRUTH_TOPIC)
        expected = np.array([synthetic.vessel_position(k * 0.25) for k in range(8)])
        np.testing.assert_array_equal(truth.lats, expected[:, 0])
        np.testing.assert_array_equal(truth.lons, expected[:, 1])
        assert np.all(truth.covariance_type == bag_topics.COVARIANCE_TYPE_UNKNOWN)
        assert np.all(np.isnan(truth.alts))

    # The mcap library, independently: same bytes, chunks compressed.
    from mcap.reader import make_reader

    with bag_reader.mcap_file_of(path).open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        assert reader.get_header().profile == "ros2"
    store = bag_messages.typestore()
    via_mcap = [m for m in bag_reader.iter_mcap(path) if m.topic == bag_topics.DEFAULT_IMAGE_TOPIC]
    assert [bytes(store.deserialize_cdr(m.cdr, bag_topics.COMPRESSED_IMAGE).data) for m in via_mcap] == [
        synthetic.frame_jpeg(k) for k in range(8)
    ]
    assert [m.log_time_ns for m in via_mcap] == stamps


def test_writer_refuses_to_overwrite_and_leaves_nothing_on_failure(tmp_path):
    path = tmp_path / "bag"
    synthetic.write_bag(path, frames=2)
    with pytest.raises(DataError, match="exists already.*overwrite"):
        bag_writer.BagWriter(path)
    before = bag_reader.mcap_file_of(path).read_bytes()
    with pytest.raises(RuntimeError):
        with bag_writer.BagWriter(path, overwrite=True) as writer:
            writer.add_topic(bag_topics.DEFAULT_IMAGE_TOPIC, bag_topics.COMPRESSED_IMAGE)
            writer.write(bag_topics.DEFAULT_IMAGE_TOPIC, bag_messages.compressed_image(1, synthetic.frame_jpeg(0)))
            raise RuntimeError("build failed half way")
    assert bag_reader.mcap_file_of(path).read_bytes() == before  # the old bag is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]  # no staging folder left
    synthetic.write_bag(tmp_path / "new", frames=3)
    with bag_writer.BagWriter(path, overwrite=True) as writer:  # replaced only on success
        writer.add_topic("/x", bag_topics.NAV_SAT_FIX)
        writer.write("/x", bag_messages.nav_sat_fix(5, 1.0, 2.0))
    with bag_reader.BagReader(path) as reader:
        assert reader.topics == {"/x": bag_topics.NAV_SAT_FIX}


def test_unknown_type_and_unadded_topic(tmp_path):
    with bag_writer.BagWriter(tmp_path / "bag") as writer:
        with pytest.raises(DataError, match="unknown message type"):
            writer.add_topic("/a", "nopkg/msg/Nothing")
        with pytest.raises(DataError, match="not added"):
            writer.write_cdr("/b", b"\x00\x01\x00\x00", 1)
        writer.add_topic("/a", bag_topics.NAV_SAT_FIX)
        with pytest.raises(DataError, match="already has type"):
            writer.add_topic("/a", bag_topics.COMPRESSED_IMAGE)
