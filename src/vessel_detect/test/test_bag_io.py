"""bag_io: rosbag2 MCAP folders written and read back with rosbags and with the mcap library; damaged input."""

import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from vessel_common.errors import DataError
from vessel_detect import bag_io
from vessel_fixtures import detect_synthetic as synthetic


def test_sec_to_ns_keeps_millisecond_stamps_exact():
    assert bag_io.sec_to_ns(1601495752.884) == 1601495752_884000000
    assert bag_io.sec_to_ns(0.0) == 0
    assert bag_io.sec_to_ns(1.9999996) == 2_000_000_000
    with pytest.raises(DataError, match="finite"):
        bag_io.sec_to_ns(math.nan)


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
    assert qos[bag_io.DEFAULT_CAMERA_FIX_TOPIC]["durability"] == "transient_local"
    assert qos[bag_io.DEFAULT_IMAGE_TOPIC]["reliability"] == "best_effort"

    with bag_io.BagReader(path) as reader:
        images = list(reader.images())
        assert [bag_io.sec_to_ns(t) for t, _ in images] == stamps
        assert [data for _, data in images] == [synthetic.frame_jpeg(k) for k in range(8)]
        # log time == header stamp for every message
        for message in reader.messages():
            assert message.log_time_ns == bag_io.ns_of_stamp(reader.decode(message).header.stamp)
        truth = reader.fixes(bag_io.DEFAULT_GPS_TRUTH_TOPIC)
        expected = np.array([synthetic.vessel_position(k * 0.25) for k in range(8)])
        np.testing.assert_array_equal(truth.lats, expected[:, 0])
        np.testing.assert_array_equal(truth.lons, expected[:, 1])
        assert np.all(truth.covariance_type == bag_io.COVARIANCE_TYPE_UNKNOWN)
        assert np.all(np.isnan(truth.alts))

    # The mcap library, independently: same bytes, chunks compressed.
    from mcap.reader import make_reader

    with bag_io.mcap_file_of(path).open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        assert reader.get_header().profile == "ros2"
    store = bag_io.typestore()
    via_mcap = [m for m in bag_io.iter_mcap(path) if m.topic == bag_io.DEFAULT_IMAGE_TOPIC]
    assert [bytes(store.deserialize_cdr(m.cdr, bag_io.COMPRESSED_IMAGE).data) for m in via_mcap] == [
        synthetic.frame_jpeg(k) for k in range(8)
    ]
    assert [m.log_time_ns for m in via_mcap] == stamps


def test_vessel_msgs_round_trip(tmp_path):
    store = bag_io.typestore()
    assert "vessel_msgs/msg/VesselTrackArray" in store.fielddefs
    Track = store.types["vessel_msgs/msg/VesselTrack"]
    Array = store.types[bag_io.VESSEL_TRACK_ARRAY]
    types = store.types
    stamp = bag_io.sec_to_ns(synthetic.START_UTC)
    track = Track(
        header=bag_io.header(stamp, "camera"),
        id="7",
        is_target=True,
        score=1.5,
        confidence=0.8,
        class_id="vessel",
        status=Track.STATUS_CONFIRMED,
        detection_count=12,
        first_seen=bag_io.header(stamp, "").stamp,
        last_seen=bag_io.header(stamp, "").stamp,
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
    )
    with bag_io.BagWriter(tmp_path / "tracks") as writer:
        writer.add_topic("/vessel/tracks", "vessel_msgs/VesselTrackArray")
        writer.write("/vessel/tracks", Array(header=bag_io.header(stamp, "camera"), tracks=[track]))
    with bag_io.BagReader(tmp_path / "tracks") as reader:
        [(t, message)] = reader.read_topic("/vessel/tracks")
    assert t == pytest.approx(synthetic.START_UTC)
    got = message.tracks[0]
    assert (got.id, got.is_target, got.detection_count, got.latitude) == ("7", True, 12, 32.7033)
    assert got.class_id == "vessel"
    assert got.bbox.center.position.y == 420.0
    assert (got.detection_bbox.center.position.x, got.detection_bbox.size_y) == (641.0, 19.0)
    np.testing.assert_array_equal(got.position_covariance, [25.0, 0.0, 0.0, 25.0])


def test_missing_bag_is_a_clear_error(tmp_path):
    with pytest.raises(DataError, match=r"does not exist.*bag build"):
        bag_io.BagReader(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="not a rosbag2 folder"):
        bag_io.BagReader(tmp_path / "empty")


@pytest.mark.parametrize("damage", ["truncate", "garbage_middle", "garbage_all", "empty"])
def test_damaged_mcap_names_the_file_and_the_fix(tmp_path, damage):
    path = tmp_path / "bag"
    synthetic.write_bag(path, frames=20)
    mcap = bag_io.mcap_file_of(path)
    data = bytearray(mcap.read_bytes())
    if damage == "truncate":
        data = data[: len(data) * 2 // 3]
    elif damage == "garbage_middle":
        rng = np.random.default_rng(1)
        middle = len(data) // 2
        data[middle : middle + 2000] = rng.integers(0, 256, 2000, dtype=np.uint8).tobytes()
    elif damage == "garbage_all":
        data = bytearray(os.urandom(len(data)))
    else:
        data = bytearray()
    mcap.write_bytes(bytes(data))
    with pytest.raises(DataError) as caught:
        with bag_io.BagReader(path) as reader:
            for _ in reader.images():
                pass
    text = str(caught.value)
    assert str(mcap) in text and "damaged" in text and "rebuild" in text


def test_bag_without_the_image_topic(tmp_path):
    with bag_io.BagWriter(tmp_path / "fixes") as writer:
        writer.add_topic("/camera/fix", "sensor_msgs/msg/NavSatFix", "latched")
        writer.write("/camera/fix", bag_io.nav_sat_fix(10**18, 32.7, -117.2))
    with bag_io.BagReader(tmp_path / "fixes") as reader:
        with pytest.raises(DataError, match=r"no topic /camera/image_raw/compressed.*it has: /camera/fix"):
            list(reader.images())
        with pytest.raises(DataError, match="expected sensor_msgs/msg/CompressedImage"):
            list(reader.images("/camera/fix"))


def test_out_of_order_frames(tmp_path):
    stamps = [bag_io.sec_to_ns(synthetic.START_UTC + t) for t in (0.0, 0.2, 0.1, 0.4)]
    with bag_io.BagWriter(tmp_path / "disorder") as writer:
        writer.add_topic(bag_io.DEFAULT_IMAGE_TOPIC, bag_io.COMPRESSED_IMAGE)
        for k, stamp in enumerate(stamps):  # logged in arrival order, stamped out of order
            writer.write(bag_io.DEFAULT_IMAGE_TOPIC, bag_io.compressed_image(stamp, synthetic.frame_jpeg(k)),
                         log_time_ns=stamps[0] + k * 100_000_000)
    with bag_io.BagReader(tmp_path / "disorder") as reader:
        with pytest.raises(DataError, match=r"out of time order.*message 2.*not after the previous"):
            list(reader.images())
        assert [bag_io.sec_to_ns(t) for t, _ in reader.images(strict=False)] == [stamps[0], stamps[1], stamps[3]]


def test_writer_refuses_to_overwrite_and_leaves_nothing_on_failure(tmp_path):
    path = tmp_path / "bag"
    synthetic.write_bag(path, frames=2)
    with pytest.raises(DataError, match="exists already.*overwrite"):
        bag_io.BagWriter(path)
    before = bag_io.mcap_file_of(path).read_bytes()
    with pytest.raises(RuntimeError):
        with bag_io.BagWriter(path, overwrite=True) as writer:
            writer.add_topic(bag_io.DEFAULT_IMAGE_TOPIC, bag_io.COMPRESSED_IMAGE)
            writer.write(bag_io.DEFAULT_IMAGE_TOPIC, bag_io.compressed_image(1, synthetic.frame_jpeg(0)))
            raise RuntimeError("build failed half way")
    assert bag_io.mcap_file_of(path).read_bytes() == before  # the old bag is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]  # no staging folder left
    synthetic.write_bag(tmp_path / "new", frames=3)
    with bag_io.BagWriter(path, overwrite=True) as writer:  # replaced only on success
        writer.add_topic("/x", bag_io.NAV_SAT_FIX)
        writer.write("/x", bag_io.nav_sat_fix(5, 1.0, 2.0))
    with bag_io.BagReader(path) as reader:
        assert reader.topics == {"/x": bag_io.NAV_SAT_FIX}


def test_unknown_type_and_unadded_topic(tmp_path):
    with bag_io.BagWriter(tmp_path / "bag") as writer:
        with pytest.raises(DataError, match="unknown message type"):
            writer.add_topic("/a", "nopkg/msg/Nothing")
        with pytest.raises(DataError, match="not added"):
            writer.write_cdr("/b", b"\x00\x01\x00\x00", 1)
        writer.add_topic("/a", bag_io.NAV_SAT_FIX)
        with pytest.raises(DataError, match="already has type"):
            writer.add_topic("/a", bag_io.COMPRESSED_IMAGE)


def test_corrupt_message_payload_is_named(tmp_path):
    with bag_io.BagWriter(tmp_path / "bag") as writer:
        writer.add_topic("/fix", bag_io.NAV_SAT_FIX)
        writer.write_cdr("/fix", b"\x00\x01\x00\x00\x01\x02", 10**18)
    with bag_io.BagReader(tmp_path / "bag") as reader:
        with pytest.raises(DataError, match=r"message on /fix .* does not parse as sensor_msgs/msg/NavSatFix"):
            reader.fixes("/fix")


def test_bag_info_lists_topics(tmp_path):
    synthetic.write_bag(tmp_path / "bag", frames=3)
    text = bag_io.bag_info(tmp_path / "bag")
    assert "/camera/image_raw/compressed [sensor_msgs/msg/CompressedImage] 3 messages" in text
    assert "duration:  0.400 s" in text


def test_single_mcap_file_and_folder_without_metadata(tmp_path):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=3)
    mcap = bag_io.mcap_file_of(tmp_path / "bag")
    with bag_io.BagReader(mcap) as reader:
        assert [bag_io.sec_to_ns(t) for t, _ in reader.images()] == stamps
    (tmp_path / "bag" / "metadata.yaml").unlink()  # e.g. a recording whose metadata was never written
    with bag_io.BagReader(tmp_path / "bag") as reader:
        assert reader.message_count(bag_io.DEFAULT_IMAGE_TOPIC) == 3


_KILLED_WRITER = """
import os, sys
from vessel_detect import bag_io
from vessel_fixtures import detect_synthetic as synthetic
store = bag_io.typestore()
writer = bag_io.BagWriter(sys.argv[1], atomic=False).open()
writer.add_topic(bag_io.DEFAULT_IMAGE_TOPIC, bag_io.COMPRESSED_IMAGE, "sensor_data")
for k in range(13):
    message = bag_io.compressed_image(1_601_494_000_000_000_000 + k * 40_000_000, synthetic.frame_jpeg(k))
    writer.write(bag_io.DEFAULT_IMAGE_TOPIC, message)
    if k == 9:
        writer.flush()  # what flush_every_s does once a second
os._exit(9)  # like kill -9: no close, no Python buffer flushed
"""


def test_a_writer_killed_without_closing_leaves_a_bag_that_recovers_to_its_last_flush(tmp_path):
    """A recorder killed with -9 used to leave a 0-byte MCAP and no metadata.yaml: the whole recording lost."""
    import subprocess
    import sys

    bag = tmp_path / "recording"
    fixtures = str(Path(synthetic.__file__).parents[1])  # test/, where vessel_fixtures is (no package installs it)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [fixtures, os.environ.get("PYTHONPATH")])))
    done = subprocess.run([sys.executable, "-c", _KILLED_WRITER, str(bag)], capture_output=True, text=True,
                          timeout=60, env=env)
    assert done.returncode == 9, done.stderr
    assert not (bag / "metadata.yaml").exists()
    with pytest.raises(DataError):
        bag_io.BagReader(bag)
    salvage = bag_io.recover_bag(bag)
    assert len(salvage.messages) == 10  # everything up to the last flush; the 3 after it are the bounded loss
    assert (tmp_path / "recording.damaged.mcap").is_file()
    with bag_io.BagReader(bag) as reader:
        images = list(reader.images())
    assert [data for _, data in images] == [synthetic.frame_jpeg(k) for k in range(10)]
    assert yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["message_count"] == 10


def test_a_bag_cut_in_half_gives_what_it_holds_and_says_where_it_stops(tmp_path):
    path = tmp_path / "bag"
    with bag_io.BagWriter(path, flush_every_s=1e-9) as writer:  # a chunk per message, as a recorder's bag has
        writer.add_topic(bag_io.DEFAULT_IMAGE_TOPIC, bag_io.COMPRESSED_IMAGE, "sensor_data")
        for k in range(40):
            writer.write(bag_io.DEFAULT_IMAGE_TOPIC,
                         bag_io.compressed_image(1_601_494_000_000_000_000 + k * 40_000_000, synthetic.frame_jpeg(k)))
    file = bag_io.mcap_file_of(path)
    data = file.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    salvage = bag_io.salvage_mcap(cut)
    assert salvage.stopped_at is not None and salvage.stopped_at <= len(data) // 2
    assert "readable to byte" in salvage.describe() and "the rest is lost" in salvage.describe()
    whole = bag_io.salvage_mcap(path)
    assert whole.stopped_at is None and len(whole.messages) == 40
    assert 0 < len(salvage.messages) < len(whole.messages)
    assert [m.cdr for m in salvage.messages] == [m.cdr for m in whole.messages[:len(salvage.messages)]]
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(DataError, match="nothing readable"):
        bag_io.salvage_mcap(empty)


def test_recover_to_an_existing_folder_needs_overwrite_and_never_deletes_the_damaged_bag(tmp_path):
    """`bag recover --out DIR` used to empty DIR without asking, even when DIR held the bag being recovered."""
    bag = tmp_path / "work" / "recording"
    synthetic.write_bag(bag, frames=3)
    kept = tmp_path / "results"
    kept.mkdir()
    (kept / "results.csv").write_text("keep\n")
    with pytest.raises(DataError, match="exists already.*--overwrite"):
        bag_io.recover_bag(bag, kept)
    assert (kept / "results.csv").read_text() == "keep\n"
    for holder in (bag, tmp_path / "work"):
        with pytest.raises(DataError, match="delete what is being recovered"):
            bag_io.recover_bag(bag, holder, overwrite=True)
    assert bag_io.mcap_file_of(bag).is_file()
    bag_io.recover_bag(bag, kept, overwrite=True)
    with bag_io.BagReader(kept) as reader:
        assert reader.message_count(bag_io.DEFAULT_IMAGE_TOPIC) == 3
    fresh = tmp_path / "fresh"
    bag_io.recover_bag(bag, fresh)
    with bag_io.BagReader(fresh) as reader:
        assert reader.message_count(bag_io.DEFAULT_IMAGE_TOPIC) == 3


def _bag_of_chunks(path, frames=36, per_chunk=6):
    """A bag of ``frames`` images, ``per_chunk`` to a chunk (a recorder flushing), and the MCAP chunk indexes."""
    from mcap.reader import make_reader

    with bag_io.BagWriter(path) as writer:
        writer.add_topic(bag_io.DEFAULT_IMAGE_TOPIC, bag_io.COMPRESSED_IMAGE, "sensor_data")
        for k in range(frames):
            writer.write(bag_io.DEFAULT_IMAGE_TOPIC,
                         bag_io.compressed_image(1_601_494_000_000_000_000 + k * 40_000_000, synthetic.frame_jpeg(k)))
            if (k + 1) % per_chunk == 0:
                writer.flush()
    with bag_io.mcap_file_of(path).open("rb") as stream:
        return sorted(make_reader(stream).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)


def _flip_bytes_inside(file, chunk, count=8):
    """Change ``count`` bytes in the middle of a chunk's compressed records (what a bad disk or copy does)."""
    data = bytearray(file.read_bytes())
    records_start = chunk.chunk_start_offset + 1 + 8 + 8 + 8 + 8 + 4 + 4 + len(chunk.compression) + 8
    middle = records_start + chunk.compressed_size // 2
    data[middle:middle + count] = bytes(b ^ 0x5A for b in data[middle:middle + count])
    file.write_bytes(bytes(data))


def test_every_chunk_carries_the_crc_of_its_content(tmp_path):
    """The rosbags writer leaves chunk CRCs 0 ("not computed"): no reader could tell changed bytes from good ones."""
    import zlib

    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader, get_chunk_data_stream

    _bag_of_chunks(tmp_path / "bag")
    with bag_io.mcap_file_of(tmp_path / "bag").open("rb") as stream:
        chunks = [r for r in StreamReader(stream, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) == 6
    for chunk in chunks:
        content, _ = get_chunk_data_stream(chunk)
        assert chunk.uncompressed_crc != 0 and chunk.uncompressed_crc == zlib.crc32(content.read(10**9))
    assert len(list(bag_io.iter_mcap(tmp_path / "bag"))) == 36  # the mcap library checks them and agrees


def test_a_corrupt_chunk_is_named_its_frames_counted_lost_and_the_other_chunks_played(tmp_path, caplog):
    """Random bytes in a chunk went unnoticed: the camera played 36/36 frames, some of them not the recorded ones."""
    path = tmp_path / "bag"
    chunks = _bag_of_chunks(path)
    _flip_bytes_inside(bag_io.mcap_file_of(path), chunks[2])
    kept = [synthetic.frame_jpeg(k) for k in range(36) if k // 6 != 2]
    lines = []
    with bag_io.BagReader(path, on_damage=lines.append) as reader:
        assert [data for _, data in reader.images()] == kept
        assert [data for _, data in reader.images()] == kept  # a second pass (a loop): named once
        assert reader.lost_messages == {bag_io.DEFAULT_IMAGE_TOPIC: 6}
    assert len(lines) == 1 and lines == [reader.damage], lines
    assert lines[0].startswith(f"bag {path}: chunk 3 of 6 in bag.mcap (bytes {chunks[2].chunk_start_offset}-")
    assert f"its 6 messages are lost ({bag_io.DEFAULT_IMAGE_TOPIC} 6); the other chunks are read" in lines[0]
    with caplog.at_level("WARNING", logger="vessel_detect.bag_io"), bag_io.BagReader(path) as reader:
        assert len(list(reader.messages())) == 30  # without a callback: one warning on the module's logger
    assert [r.getMessage() for r in caplog.records] == lines
    with pytest.raises(DataError, match="damaged"):
        list(bag_io.iter_mcap(path))  # the independent reader sees it too
    salvaged = bag_io.SalvagedBagReader(path)  # what a bag without its index plays
    assert [m.cdr for m in salvaged.messages()] == [m.cdr for m in bag_io.BagReader(path).messages()]
    assert f"chunk at byte {chunks[2].chunk_start_offset}" in salvaged.damage and "6 messages" in salvaged.damage
    salvage = bag_io.recover_bag(path)
    assert not salvage.complete and salvage.lost == {bag_io.DEFAULT_IMAGE_TOPIC: 6}
    with bag_io.BagReader(path) as reader:
        assert [data for _, data in reader.images()] == kept and reader.damage == ""


def test_a_bag_whose_only_chunk_is_corrupt_is_refused_as_damaged(tmp_path):
    path = tmp_path / "bag"
    chunks = _bag_of_chunks(path, frames=6)
    _flip_bytes_inside(bag_io.mcap_file_of(path), chunks[0])
    with bag_io.BagReader(path, on_damage=lambda line: None) as reader:
        with pytest.raises(DataError, match=r"is damaged .*every chunk with these messages is damaged.*chunk 1 of 1"):
            next(reader.images())


def test_recover_in_place_never_replaces_an_earlier_damaged_file(tmp_path):
    """A second `bag recover BAG` moved the bag's file over the first recovery's BAG.damaged.mcap."""
    bag = tmp_path / "recording"
    synthetic.write_bag(bag, frames=3)
    first = bag_io.mcap_file_of(bag).read_bytes()
    bag_io.recover_bag(bag)
    assert (tmp_path / "recording.damaged.mcap").read_bytes() == first
    second = bag_io.mcap_file_of(bag).read_bytes()
    salvage = bag_io.recover_bag(bag)
    assert salvage.file == tmp_path / "recording.damaged.1.mcap" and salvage.file.read_bytes() == second
    assert (tmp_path / "recording.damaged.mcap").read_bytes() == first  # the first one is kept
    bag_io.recover_bag(bag)
    assert (tmp_path / "recording.damaged.2.mcap").is_file()
    with bag_io.BagReader(bag) as reader:
        assert reader.message_count(bag_io.DEFAULT_IMAGE_TOPIC) == 3
    with pytest.raises(DataError, match="is a file, not a bag folder"):
        bag_io.recover_bag(bag, tmp_path / "recording.damaged.mcap", overwrite=True)
    assert (tmp_path / "recording.damaged.mcap").read_bytes() == first
    (bag / "notes.txt").write_text("mine\n")  # not part of the bag: recovering in place would delete it
    with pytest.raises(DataError, match=r"holds other files than its bag \(notes.txt\).*--out NEW"):
        bag_io.recover_bag(bag)
    assert (bag / "notes.txt").read_text() == "mine\n" and not (tmp_path / "recording.damaged.3.mcap").exists()


def test_the_camera_source_counts_a_corrupt_chunk_and_plays_the_rest(tmp_path):
    """What the camera node replays: the damaged chunk is a problem of the source, and the source is damaged."""
    from vessel_detect.sources import BagSource, Frame

    path = tmp_path / "bag"
    chunks = _bag_of_chunks(path)
    _flip_bytes_inside(bag_io.mcap_file_of(path), chunks[2])
    problems = []
    source = BagSource(path, aux_topics=[], on_problem=lambda kind, line: problems.append((kind, line)))
    frames = [item for item in source if isinstance(item, Frame)]
    assert len(frames) == 30
    assert [kind for kind, _ in problems] == ["damaged_chunk"] and "chunk 3 of 6" in problems[0][1]
    assert source.damage == problems[0][1]
