"""bag_reader: bags read back, damaged input named with its fix, chunks whose CRC fails skipped and counted."""

import os

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_detect import bag_messages, bag_reader, bag_salvage, bag_topics, bag_writer
from vessel_fixtures import detect_synthetic as synthetic


def test_missing_bag_is_a_clear_error(tmp_path):
    with pytest.raises(DataError, match=r"does not exist.*bag build"):
        bag_reader.BagReader(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="not a rosbag2 folder"):
        bag_reader.BagReader(tmp_path / "empty")


@pytest.mark.parametrize("damage", ["truncate", "garbage_middle", "garbage_all", "empty"])
def test_damaged_mcap_names_the_file_and_the_fix(tmp_path, damage):
    path = tmp_path / "bag"
    synthetic.write_bag(path, frames=20)
    mcap = bag_reader.mcap_file_of(path)
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
        with bag_reader.BagReader(path) as reader:
            for _ in reader.images():
                pass
    text = str(caught.value)
    assert str(mcap) in text and "damaged" in text and "rebuild" in text


def test_bag_without_the_image_topic(tmp_path):
    with bag_writer.BagWriter(tmp_path / "fixes") as writer:
        writer.add_topic("/camera/fix", "sensor_msgs/msg/NavSatFix", "latched")
        writer.write("/camera/fix", bag_messages.nav_sat_fix(10**18, 32.7, -117.2))
    with bag_reader.BagReader(tmp_path / "fixes") as reader:
        with pytest.raises(DataError, match=r"no topic /camera/image_raw/compressed.*it has: /camera/fix"):
            list(reader.images())
        with pytest.raises(DataError, match="expected sensor_msgs/msg/CompressedImage"):
            list(reader.images("/camera/fix"))


def test_out_of_order_frames(tmp_path):
    stamps = [bag_messages.sec_to_ns(synthetic.START_UTC + t) for t in (0.0, 0.2, 0.1, 0.4)]
    with bag_writer.BagWriter(tmp_path / "disorder") as writer:
        writer.add_topic(bag_topics.DEFAULT_IMAGE_TOPIC, bag_topics.COMPRESSED_IMAGE)
        for k, stamp in enumerate(stamps):  # logged in arrival order, stamped out of order
            writer.write(bag_topics.DEFAULT_IMAGE_TOPIC, bag_messages.compressed_image(stamp, synthetic.frame_jpeg(k)),
                         log_time_ns=stamps[0] + k * 100_000_000)
    with bag_reader.BagReader(tmp_path / "disorder") as reader:
        with pytest.raises(DataError, match=r"out of time order.*message 2.*not after the previous"):
            list(reader.images())
        assert [bag_messages.sec_to_ns(t) for t, _ in reader.images(strict=False)] == [stamps[0], stamps[1], stamps[3]]


def test_corrupt_message_payload_is_named(tmp_path):
    with bag_writer.BagWriter(tmp_path / "bag") as writer:
        writer.add_topic("/fix", bag_topics.NAV_SAT_FIX)
        writer.write_cdr("/fix", b"\x00\x01\x00\x00\x01\x02", 10**18)
    with bag_reader.BagReader(tmp_path / "bag") as reader:
        with pytest.raises(DataError, match=r"message on /fix .* does not parse as sensor_msgs/msg/NavSatFix"):
            reader.fixes("/fix")


def test_bag_info_lists_topics(tmp_path):
    synthetic.write_bag(tmp_path / "bag", frames=3)
    text = bag_reader.bag_info(tmp_path / "bag")
    assert "/camera/image_raw/compressed [sensor_msgs/msg/CompressedImage] 3 messages" in text
    assert "duration:  0.400 s" in text


def test_single_mcap_file_and_folder_without_metadata(tmp_path):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=3)
    mcap = bag_reader.mcap_file_of(tmp_path / "bag")
    with bag_reader.BagReader(mcap) as reader:
        assert [bag_messages.sec_to_ns(t) for t, _ in reader.images()] == stamps
    (tmp_path / "bag" / "metadata.yaml").unlink()  # e.g. a recording whose metadata was never written
    with bag_reader.BagReader(tmp_path / "bag") as reader:
        assert reader.message_count(bag_topics.DEFAULT_IMAGE_TOPIC) == 3


def _bag_of_chunks(path, frames=36, per_chunk=6):
    """A bag of ``frames`` images, ``per_chunk`` to a chunk (a recorder flushing), and the MCAP chunk indexes."""
    from mcap.reader import make_reader

    with bag_writer.BagWriter(path) as writer:
        writer.add_topic(bag_topics.DEFAULT_IMAGE_TOPIC, bag_topics.COMPRESSED_IMAGE, "sensor_data")
        for k in range(frames):
            writer.write(bag_topics.DEFAULT_IMAGE_TOPIC,
                         bag_messages.compressed_image(1_601_494_000_000_000_000 + k * 40_000_000,
                                                       synthetic.frame_jpeg(k)))
            if (k + 1) % per_chunk == 0:
                writer.flush()
    with bag_reader.mcap_file_of(path).open("rb") as stream:
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
    with bag_reader.mcap_file_of(tmp_path / "bag").open("rb") as stream:
        chunks = [r for r in StreamReader(stream, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) == 6
    for chunk in chunks:
        content, _ = get_chunk_data_stream(chunk)
        assert chunk.uncompressed_crc != 0 and chunk.uncompressed_crc == zlib.crc32(content.read(10**9))
    assert len(list(bag_reader.iter_mcap(tmp_path / "bag"))) == 36  # the mcap library checks them and agrees


def test_a_corrupt_chunk_is_named_its_frames_counted_lost_and_the_other_chunks_played(tmp_path, caplog):
    """Random bytes in a chunk went unnoticed: the camera played 36/36 frames, some of them not the recorded ones."""
    path = tmp_path / "bag"
    chunks = _bag_of_chunks(path)
    _flip_bytes_inside(bag_reader.mcap_file_of(path), chunks[2])
    kept = [synthetic.frame_jpeg(k) for k in range(36) if k // 6 != 2]
    lines = []
    with bag_reader.BagReader(path, on_damage=lines.append) as reader:
        assert [data for _, data in reader.images()] == kept
        assert [data for _, data in reader.images()] == kept  # a second pass (a loop): named once
        assert reader.lost_messages == {bag_topics.DEFAULT_IMAGE_TOPIC: 6}
    assert len(lines) == 1 and lines == [reader.damage], lines
    assert lines[0].startswith(f"bag {path}: chunk 3 of 6 in bag.mcap (bytes {chunks[2].chunk_start_offset}-")
    assert f"its 6 messages are lost ({bag_topics.DEFAULT_IMAGE_TOPIC} 6); the other chunks are read" in lines[0]
    with caplog.at_level("WARNING", logger="vessel_detect.bag_reader"), bag_reader.BagReader(path) as reader:
        assert len(list(reader.messages())) == 30  # without a callback: one warning on the module's logger
    assert [r.getMessage() for r in caplog.records] == lines
    with pytest.raises(DataError, match="damaged"):
        list(bag_reader.iter_mcap(path))  # the independent reader sees it too
    salvaged = bag_salvage.SalvagedBagReader(path)  # what a bag without its index plays
    assert [m.cdr for m in salvaged.messages()] == [m.cdr for m in bag_reader.BagReader(path).messages()]
    assert f"chunk at byte {chunks[2].chunk_start_offset}" in salvaged.damage and "6 messages" in salvaged.damage
    salvage = bag_salvage.recover_bag(path)
    assert not salvage.complete and salvage.lost == {bag_topics.DEFAULT_IMAGE_TOPIC: 6}
    with bag_reader.BagReader(path) as reader:
        assert [data for _, data in reader.images()] == kept and reader.damage == ""


def test_a_bag_whose_only_chunk_is_corrupt_is_refused_as_damaged(tmp_path):
    path = tmp_path / "bag"
    chunks = _bag_of_chunks(path, frames=6)
    _flip_bytes_inside(bag_reader.mcap_file_of(path), chunks[0])
    with bag_reader.BagReader(path, on_damage=lambda line: None) as reader:
        with pytest.raises(DataError, match=r"is damaged .*every chunk with these messages is damaged.*chunk 1 of 1"):
            next(reader.images())


def test_the_camera_source_counts_a_corrupt_chunk_and_plays_the_rest(tmp_path):
    """What the camera node replays: the damaged chunk is a problem of the source, and the source is damaged."""
    from vessel_detect.file_sources import BagSource
    from vessel_detect.image_source import Frame

    path = tmp_path / "bag"
    chunks = _bag_of_chunks(path)
    _flip_bytes_inside(bag_reader.mcap_file_of(path), chunks[2])
    problems = []
    source = BagSource(path, aux_topics=[], on_problem=lambda kind, line: problems.append((kind, line)))
    frames = [item for item in source if isinstance(item, Frame)]
    assert len(frames) == 30
    assert [kind for kind, _ in problems] == ["damaged_chunk"] and "chunk 3 of 6" in problems[0][1]
    assert source.damage == problems[0][1]
