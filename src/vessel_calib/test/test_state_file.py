"""A node restarted after a crash resumes from its state file.

The tracker and the fuser carry on exactly as if they had never stopped, and any snapshot that does not fit
(other settings, old, from the future, unreadable) gives a cold start with the reason.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from vessel_calib.errors import DataError
from vessel_calib.state_file import StateFile, settings_fingerprint
from vessel_track.distance_model import BoxSizeDistanceModel
from vessel_track.fusion import TrackFuser
from vessel_track.pipeline import screen_track_of
from vessel_track.simulation import challenge_camera, harbour_scenario
from vessel_track.tracker import MultiTargetTracker, TrackerConfig


def _run(frames, tracker, fuser):
    out = []
    for frame in frames:
        states = tracker.update(frame.stamp, frame.boxes_xyxy, frame.scores)
        world = fuser.update(frame.stamp, [screen_track_of(s) for s in states])
        out.append([(w.screen.track_id, w.screen.status, bool(w.is_target), tuple(np.round(w.position, 9)))
                    for w in world])
    return out


def test_a_tracker_and_fuser_restored_from_their_files_carry_on_as_if_never_stopped(tmp_path):
    frames = harbour_scenario(seed=3).run().frames
    camera, model, config = challenge_camera(), BoxSizeDistanceModel(), TrackerConfig()
    straight = _run(frames, MultiTargetTracker(config), TrackFuser(camera, model))
    assert any(is_target for frame in straight for _, _, is_target, _ in frame)

    tracker, fuser = MultiTargetTracker(config), TrackFuser(camera, model)
    half = len(frames) // 2
    before = _run(frames[:half], tracker, fuser)
    files = {name: StateFile(tmp_path / f"{name}.state", name, settings_fingerprint(config), period_s=0.0)
             for name in ("tracker", "fuser")}
    files["tracker"].save(frames[half - 1].stamp, tracker.snapshot())
    files["fuser"].save(frames[half - 1].stamp, fuser.snapshot())
    del tracker, fuser  # the process dies

    tracker, fuser = MultiTargetTracker(config), TrackFuser(camera, model)
    for name, core in (("tracker", tracker), ("fuser", fuser)):
        reader = StateFile(tmp_path / f"{name}.state", name, settings_fingerprint(config))
        state, why = reader.resume(frames[half].stamp)
        assert state is not None and why.startswith("resumed"), why
        core.restore(state)
    after = _run(frames[half:], tracker, fuser)
    assert before + after == straight


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
