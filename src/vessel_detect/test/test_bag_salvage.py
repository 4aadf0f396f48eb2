"""bag_salvage: what a cut-short or killed recording holds, read and recovered into a readable bag."""

import os
from pathlib import Path

import pytest
import yaml

from vessel_common.errors import DataError
from vessel_detect import bag_messages, bag_reader, bag_salvage, bag_topics, bag_writer
from vessel_fixtures import detect_synthetic as synthetic

_KILLED_WRITER = """
import os, sys
from vessel_detect import bag_messages, bag_topics, bag_writer
from vessel_fixtures import detect_synthetic as synthetic
store = bag_messages.typestore()
writer = bag_writer.BagWriter(sys.argv[1], atomic=False).open()
writer.add_topic(bag_topics.DEFAULT_IMAGE_TOPIC, bag_topics.COMPRESSED_IMAGE, "sensor_data")
for k in range(13):
    message = bag_messages.compressed_image(1_601_494_000_000_000_000 + k * 40_000_000, synthetic.frame_jpeg(k))
    writer.write(bag_topics.DEFAULT_IMAGE_TOPIC, message)
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
        bag_reader.BagReader(bag)
    salvage = bag_salvage.recover_bag(bag)
    assert len(salvage.messages) == 10  # everything up to the last flush; the 3 after it are the bounded loss
    assert (tmp_path / "recording.damaged.mcap").is_file()
    with bag_reader.BagReader(bag) as reader:
        images = list(reader.images())
    assert [data for _, data in images] == [synthetic.frame_jpeg(k) for k in range(10)]
    assert yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["message_count"] == 10


def test_a_bag_cut_in_half_gives_what_it_holds_and_says_where_it_stops(tmp_path):
    path = tmp_path / "bag"
    with bag_writer.BagWriter(path, flush_every_s=1e-9) as writer:  # a chunk per message, as a recorder's bag has
        writer.add_topic(bag_topics.DEFAULT_IMAGE_TOPIC, bag_topics.COMPRESSED_IMAGE, "sensor_data")
        for k in range(40):
            writer.write(bag_topics.DEFAULT_IMAGE_TOPIC,
                         bag_messages.compressed_image(1_601_494_000_000_000_000 + k * 40_000_000,
                                                       synthetic.frame_jpeg(k)))
    file = bag_reader.mcap_file_of(path)
    data = file.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    salvage = bag_salvage.salvage_mcap(cut)
    assert salvage.stopped_at is not None and salvage.stopped_at <= len(data) // 2
    assert "readable to byte" in salvage.describe() and "the rest is lost" in salvage.describe()
    whole = bag_salvage.salvage_mcap(path)
    assert whole.stopped_at is None and len(whole.messages) == 40
    assert 0 < len(salvage.messages) < len(whole.messages)
    assert [m.cdr for m in salvage.messages] == [m.cdr for m in whole.messages[:len(salvage.messages)]]
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(DataError, match="nothing readable"):
        bag_salvage.salvage_mcap(empty)


def test_recover_to_an_existing_folder_needs_overwrite_and_never_deletes_the_damaged_bag(tmp_path):
    """`bag recover --out DIR` used to empty DIR without asking, even when DIR held the bag being recovered."""
    bag = tmp_path / "work" / "recording"
    synthetic.write_bag(bag, frames=3)
    kept = tmp_path / "results"
    kept.mkdir()
    (kept / "results.csv").write_text("keep\n")
    with pytest.raises(DataError, match="exists already.*--overwrite"):
        bag_salvage.recover_bag(bag, kept)
    assert (kept / "results.csv").read_text() == "keep\n"
    for holder in (bag, tmp_path / "work"):
        with pytest.raises(DataError, match="delete what is being recovered"):
            bag_salvage.recover_bag(bag, holder, overwrite=True)
    assert bag_reader.mcap_file_of(bag).is_file()
    bag_salvage.recover_bag(bag, kept, overwrite=True)
    with bag_reader.BagReader(kept) as reader:
        assert reader.message_count(bag_topics.DEFAULT_IMAGE_TOPIC) == 3
    fresh = tmp_path / "fresh"
    bag_salvage.recover_bag(bag, fresh)
    with bag_reader.BagReader(fresh) as reader:
        assert reader.message_count(bag_topics.DEFAULT_IMAGE_TOPIC) == 3


def test_recover_in_place_never_replaces_an_earlier_damaged_file(tmp_path):
    """A second `bag recover BAG` moved the bag's file over the first recovery's BAG.damaged.mcap."""
    bag = tmp_path / "recording"
    synthetic.write_bag(bag, frames=3)
    first = bag_reader.mcap_file_of(bag).read_bytes()
    bag_salvage.recover_bag(bag)
    assert (tmp_path / "recording.damaged.mcap").read_bytes() == first
    second = bag_reader.mcap_file_of(bag).read_bytes()
    salvage = bag_salvage.recover_bag(bag)
    assert salvage.file == tmp_path / "recording.damaged.1.mcap" and salvage.file.read_bytes() == second
    assert (tmp_path / "recording.damaged.mcap").read_bytes() == first  # the first one is kept
    bag_salvage.recover_bag(bag)
    assert (tmp_path / "recording.damaged.2.mcap").is_file()
    with bag_reader.BagReader(bag) as reader:
        assert reader.message_count(bag_topics.DEFAULT_IMAGE_TOPIC) == 3
    with pytest.raises(DataError, match="is a file, not a bag folder"):
        bag_salvage.recover_bag(bag, tmp_path / "recording.damaged.mcap", overwrite=True)
    assert (tmp_path / "recording.damaged.mcap").read_bytes() == first
    (bag / "notes.txt").write_text("mine\n")  # not part of the bag: recovering in place would delete it
    with pytest.raises(DataError, match=r"holds other files than its bag \(notes.txt\).*--out NEW"):
        bag_salvage.recover_bag(bag)
    assert (bag / "notes.txt").read_text() == "mine\n" and not (tmp_path / "recording.damaged.3.mcap").exists()
