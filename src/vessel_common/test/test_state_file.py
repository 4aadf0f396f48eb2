"""A node's state file: written atomically, every period of message time.

A snapshot that does not fit (other settings, old, from the future, unreadable) gives a cold start with the reason.
That the tracker and the fuser carry on from their snapshots as if never stopped: ``vessel_track/test/test_fusion.py``.
"""

from __future__ import annotations

import pickle

import pytest

from vessel_common.errors import DataError
from vessel_common.state_file import StateFile, settings_fingerprint
from vessel_track.tracker import TrackerConfig


def test_a_snapshot_that_does_not_fit_is_a_cold_start_with_the_reason(tmp_path):
    path = tmp_path / "tracker.state"
    writer = StateFile(path, "tracker", settings_fingerprint(TrackerConfig()), period_s=1.0, max_age_s=10.0)
    assert writer.resume(100.0) == (None, f"no state file {path}: cold start")
    writer.save(100.0, {"tracks": []})

    def resumed(stamp, node="tracker", config=None):
        fingerprint = settings_fingerprint(config or TrackerConfig())
        return StateFile(path, node, fingerprint, max_age_s=10.0).resume(stamp)

    assert resumed(105.0)[0] == {"tracks": []}
    assert "other settings" in resumed(105.0, config=TrackerConfig(gate_px=55.0))[1]
    assert "not a fuser snapshot" in resumed(105.0, node="fuser")[1]
    assert "+20.0 s" in resumed(120.0)[1]   # too old: the vessel has moved on
    assert "-5.0 s" in resumed(95.0)[1]     # a replay started again from earlier
    path.write_bytes(path.read_bytes()[:20])  # cut short
    state, why = resumed(105.0)
    assert state is None and "unreadable" in why


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
