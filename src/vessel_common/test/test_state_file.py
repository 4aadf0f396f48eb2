"""A node's state file: written atomically, every period of message time.

A snapshot that does not fit (other settings, old, from the future, unreadable) gives a cold start with the reason.
That the tracker and the fuser carry on from their snapshots as if never stopped: ``vessel_track/test/test_fusion.py``.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys

import pytest

from vessel_common.errors import DataError
from vessel_common.state_file import StateFile, remove_state_file, settings_fingerprint
from vessel_track.tracker import TrackerConfig


def test_a_snapshot_that_does_not_fit_is_a_cold_start_with_the_reason(tmp_path):
    path = tmp_path / "tracker.state"
    writer = StateFile(path, "tracker", settings_fingerprint(TrackerConfig()), period_s=1.0, max_age_s=10.0)
    assert writer.resume(100.0) == (None, f"no state file {path}: cold start")
    writer.save(100.0, {"tracks": []})

    def resumed(stamp, node="tracker", config=None):
        fingerprint = settings_fingerprint(config or TrackerConfig())
        return StateFile(path, node, fingerprint, max_age_s=10.0).resume(stamp)

    assert "other settings" in resumed(105.0, config=TrackerConfig(gate_px=55.0))[1]
    assert "not a fuser snapshot" in resumed(105.0, node="fuser")[1]
    assert "+20.0 s" in resumed(120.0)[1]   # too old: the vessel has moved on
    assert "-5.0 s" in resumed(95.0)[1]     # a replay started again from earlier
    path.write_bytes(path.read_bytes()[:20])  # cut short
    state, why = resumed(105.0)
    assert state is None and "unreadable" in why


def test_a_snapshot_is_resumed_once_so_a_state_that_crashes_the_node_cannot_loop(tmp_path):
    path = tmp_path / "fuser.state"
    StateFile(path, "fuser", "f").save(100.0, [1])
    first = StateFile(path, "fuser", "f")
    assert first.resume(101.0)[0] == [1]
    state, why = StateFile(path, "fuser", "f").resume(102.0)  # it stopped again before writing a new one
    assert state is None and "resumed once already" in why
    first.save(103.0, [2])  # a node that carried on writes a new snapshot: that one can be resumed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fuser.state"]
    assert StateFile(path, "fuser", "f").resume(104.0)[0] == [2]
    remove_state_file(path)  # what a new run does first: neither the snapshot nor its marker is left
    assert list(tmp_path.iterdir()) == []


def test_a_standby_reads_its_active_nodes_snapshot_without_taking_it(tmp_path):
    path = tmp_path / "tracker.state"
    fingerprint = settings_fingerprint(TrackerConfig())
    StateFile(path, "tracker", fingerprint).save(100.0, {"tracks": ["T1"]})
    spare = StateFile(path, "tracker", fingerprint)
    state, why = spare.resume(100.0, consume=False)
    assert state == {"tracks": ["T1"]} and "resumed" in why
    assert spare.resumed_stamp == 100.0  # the message stamped 100 is in it: the node skips that message
    assert path.is_file() and not (tmp_path / "tracker.state.resumed").exists()  # still the active node's


def test_the_fingerprint_of_a_set_is_the_same_in_every_process():
    """Pickled sets follow the per-process string hash; a restarted node must still recognise its settings."""
    code = ("from vessel_common.state_file import settings_fingerprint; "
            "print(settings_fingerprint(frozenset({'boat', 'ship', 'kayak', 'vessel'}), 'vessel_of_interest'))")
    prints = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                             env=dict(os.environ, PYTHONHASHSEED=str(seed))).stdout for seed in (1, 2, 3, 4)}
    assert len(prints) == 1


def test_snapshots_are_written_every_period_of_message_time_and_atomically(tmp_path):
    path = tmp_path / "fuser.state"
    state_file = StateFile(path, "fuser", "f", period_s=1.0)
    assert state_file.due(10.0)
    state_file.save(10.0, [1])
    assert not state_file.due(10.5) and state_file.due(11.0) and state_file.due(9.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fuser.state"]  # no temporary left behind
    with pytest.raises(DataError, match="fuser state cannot be saved"):
        state_file.save(11.0, lambda: None)  # cannot be pickled: the old snapshot stays whole
    assert pickle.loads(path.read_bytes())["state"] == [1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fuser.state"]
