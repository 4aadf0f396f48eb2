"""A node's state file: written atomically, every period of message time, as data that cannot run code.

A snapshot that does not fit (other settings, old, from the future) gives a cold start with the reason; a file that is
not a snapshot of this schema and version (a pickle, damaged, crafted) is refused before any of it is used.
That the tracker and the fuser carry on from their snapshots as if never stopped: here and in
``vessel_track/test/test_fusion.py``; the nodes: ``vessel_track/test/test_tracker_node.py``, ``test_fuser_node.py``.
"""

from __future__ import annotations

import json
import math
import os
import pickle
import subprocess
import sys
from collections import deque

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_common.state_file import (
    VERSION,
    StateFile,
    decode_state,
    encode_state,
    remove_state_file,
    settings_fingerprint,
)
from vessel_track.tracker import MultiTargetTracker
from vessel_track.tracker_config import TrackerConfig


class _CreatesAFileWhenUnpickled:
    """What a crafted pickle can do: unpickling calls ``open(path, "w")``, which creates the file."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return open, (self.path, "w")


def test_a_snapshot_that_does_not_fit_is_a_cold_start_with_the_reason(tmp_path):
    path = tmp_path / "tracker.state"
    writer = StateFile(path, "tracker", settings_fingerprint(TrackerConfig()), period_s=1.0, max_age_s=10.0)
    assert writer.resume(100.0) == (None, f"no state file {path}: cold start")
    writer.save(100.0, {"tracks": []})

    def resumed(stamp, node="tracker", config=None):
        fingerprint = settings_fingerprint(config or TrackerConfig())
        return StateFile(path, node, fingerprint, max_age_s=10.0).resume(stamp)

    assert "other settings" in resumed(105.0, config=TrackerConfig(gate_px=55.0))[1]
    assert f"is not a fuser state file of version {VERSION}: it is schema 'vessel_state', version {VERSION}, " \
           "node 'tracker'; cold start" in resumed(105.0, node="fuser")[1]
    assert "+20.0 s" in resumed(120.0)[1]   # too old: the vessel has moved on
    assert "-5.0 s" in resumed(95.0)[1]     # a replay started again from earlier
    path.write_bytes(path.read_bytes()[:20])  # cut short
    state, why = resumed(105.0)
    assert state is None and why.startswith(f"state file {path} is not a tracker state file of version {VERSION}: "
                                            "not JSON") and why.endswith("; cold start")


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


def test_another_graphs_snapshot_is_refused(tmp_path):
    """Two cameras' trackers given one state_file (a shared parameter file): neither resumes the other's tracks."""
    path = tmp_path / "tracker.state"
    StateFile(path, "tracker", "f", graph="/b").save(10.0, {"tracks": 3})
    state, what = StateFile(path, "tracker", "f", graph="/a").resume(10.2)
    assert state is None and "written by the tracker of graph '/b'" in what and "cold start" in what
    assert StateFile(path, "tracker", "f", graph="/b").resume(10.2)[0] == {"tracks": 3}


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
    with pytest.raises(DataError, match=r"fuser state cannot be saved .*\[1\] is a builtins.function"):
        state_file.save(11.0, [0, lambda: None])  # not plain data: the old snapshot stays whole
    assert json.loads(path.read_text())["state"] == [1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fuser.state"]


@pytest.mark.parametrize("protocol", [0, 2, pickle.HIGHEST_PROTOCOL])
def test_a_pickled_state_file_is_refused_before_it_is_loaded(tmp_path, protocol):
    """A state file of the old format, or one crafted to run code, is never unpickled: one line, and a cold start."""
    marker = tmp_path / "created_by_the_pickle"
    path = tmp_path / "tracker.state"
    fingerprint = settings_fingerprint(TrackerConfig())
    path.write_bytes(pickle.dumps({"format": "vessel_state/1", "node": "tracker", "fingerprint": fingerprint,
                                   "stamp": 100.0, "state": _CreatesAFileWhenUnpickled(marker)}, protocol=protocol))
    reader = StateFile(path, "tracker", fingerprint)
    state, why = reader.resume(101.0)
    assert state is None and not marker.exists()
    assert why.startswith(f"state file {path} is not a tracker state file of version {VERSION}: ")
    assert why.endswith("; cold start") and "\n" not in why and reader.refused
    assert ("it is a pickle" if protocol >= 2 else "not JSON") in why
    assert path.is_file() and not reader.resumed_path.exists()  # left for the node's next snapshot to replace
    pickle.loads(path.read_bytes())  # what the node did before: the file would have run its code
    assert marker.exists()


@pytest.mark.parametrize("state, reason", [
    ({"$ndarray": {"dtype": "O", "shape": [1], "data": [1]}}, "is not a number type"),
    ({"$ndarray": {"dtype": "<f8", "shape": [3], "data": [1.0, 2.0]}}, "2 values for shape (3,)"),
    ({"$ndarray": {"dtype": "<f8", "shape": [1], "data": ["os.system"]}}, "a value is not a number"),
    ({"$pickle": "gASV"}, "unknown tagged value"),
    ({"$float": "1e999"}, "is not nan, inf or -inf"),
    ({"tracks": [{"$set": [[1]]}]}, "state['tracks'][0] is not a valid $set"),
])
def test_a_crafted_json_state_file_is_refused_with_the_reason(tmp_path, state, reason):
    path = tmp_path / "tracker.state"
    StateFile(path, "tracker", "f").save(100.0, None)
    saved = json.loads(path.read_text())
    path.write_text(json.dumps({**saved, "state": state}))
    reader = StateFile(path, "tracker", "f")
    loaded, why = reader.resume(100.0)
    assert loaded is None and reason in why and why.endswith("; cold start") and reason in reader.refused
    for header in ({"version": 1}, {"schema": "other"}, {"stamp": "100"}, {"fingerprint": None}):
        path.write_text(json.dumps({**saved, **header}))
        assert StateFile(path, "tracker", "f").resume(100.0)[0] is None
    path.write_text("[" * 100_000 + "]" * 100_000)  # nested deeper than the parser goes
    assert "not a tracker state file" in StateFile(path, "tracker", "f").resume(100.0)[1]


def test_plain_data_comes_back_with_its_types():
    value = {"floats": [1.5, math.nan, math.inf, -math.inf, 0.1 + 0.2], "int": 2**70, "none": None, "flag": True,
             "tuple": (1, "a"), "set": {"b", "c"}, "frozen": frozenset({3}), 7: "an int key", "$dollar": 1,
             "deque": deque([(1.0, 2.0)], maxlen=5), "empty": deque(), "nested": {"a": [{"b": ()}]},
             "array": np.array([[1.0, math.nan], [math.inf, 2.5]]), "ints": np.arange(6, dtype=np.int16).reshape(3, 2),
             "bools": np.array([True, False]), "f32": np.array([0.1], dtype=np.float32),
             "empty_array": np.zeros((0, 2)), "scalar": np.float64(0.3), "int_scalar": np.int64(-4)}
    back = decode_state(json.loads(json.dumps(encode_state(value), allow_nan=False)))
    assert list(back) == list(value)
    for key, item in value.items():
        assert type(back[key]) is type(item), key
        if isinstance(item, np.ndarray):
            assert back[key].dtype == item.dtype and back[key].shape == item.shape
            np.testing.assert_array_equal(back[key], item)
        elif key != "floats":
            assert back[key] == item, key
    assert back["floats"][0] == 1.5 and math.isnan(back["floats"][1]) and back["floats"][2:] == value["floats"][2:]
    assert back["deque"].maxlen == 5 and back["empty"].maxlen is None
    for not_data in (object(), TrackerConfig(), np.array([object()]), b"text", np.datetime64("2020-01-01")):
        with pytest.raises(DataError, match="which a state file does not hold"):
            encode_state([not_data])


def _tracker_and_fuser_outputs(frames, tracker, fuser):
    from vessel_tools.track.pipeline import screen_track_of

    out = []
    for frame in frames:
        states = tracker.update(frame.stamp, frame.boxes_xyxy, frame.scores)
        world = fuser.update(frame.stamp, [screen_track_of(s) for s in states])
        out.append([(s.track_id, int(s.status), tuple(s.center), tuple(s.center_cov.ravel())) for s in states]
                   + [(w.screen.track_id, bool(w.is_target), bool(w.has_world), tuple(w.position),
                       tuple(np.ravel(w.position_covariance))) for w in world])
    return out


@pytest.mark.parametrize("seed", [3, 7])
def test_the_real_tracker_and_fuser_carry_on_from_their_state_files_as_if_never_stopped(tmp_path, seed):
    """Cut anywhere (tracks ended this frame, a lost target's history handed down): the same outputs after."""
    from vessel_tools.track.simulation import challenge_camera, harbour_scenario
    from vessel_track.distance_model import BoxSizeDistanceModel
    from vessel_track.track_fuser import TrackFuser

    frames = harbour_scenario(seed=seed).run().frames
    camera, model, config = challenge_camera(), BoxSizeDistanceModel(), TrackerConfig()
    straight = _tracker_and_fuser_outputs(frames, MultiTargetTracker(config), TrackFuser(camera, model))
    tracker, fuser = MultiTargetTracker(config), TrackFuser(camera, model)
    done = 0
    for cut in (3, 7, 8, 12, 16, 23, 35):
        _tracker_and_fuser_outputs(frames[done:cut], tracker, fuser)
        done = cut
        for name, core in (("tracker", tracker), ("fuser", fuser)):
            StateFile(tmp_path / name, name, "f").save(frames[cut - 1].stamp, core.snapshot())
        restored = {"tracker": MultiTargetTracker(config), "fuser": TrackFuser(camera, model)}
        for name, core in restored.items():
            state, why = StateFile(tmp_path / name, name, "f").resume(frames[cut].stamp)
            assert state is not None, why
            core.restore(state)
        restored["tracker"]._next_id = tracker._next_id  # the ids a restart gives new tracks: test_fusion.py
        after = _tracker_and_fuser_outputs(frames[cut:], restored["tracker"], restored["fuser"])
        assert after == straight[cut:], f"cut at frame {cut}"


def test_a_snapshot_with_other_fields_than_this_version_does_not_fit_and_changes_nothing():
    from vessel_tools.track.simulation import harbour_scenario

    tracker = MultiTargetTracker(TrackerConfig())
    for frame in harbour_scenario(seed=3).run().frames[:6]:
        tracker.update(frame.stamp, frame.boxes_xyxy, frame.scores)
    snapshot = decode_state(json.loads(json.dumps(encode_state(tracker.snapshot()))))
    del snapshot["tracks"][0]["misses"]
    other = MultiTargetTracker(TrackerConfig())
    with pytest.raises(ValueError, match=r"a track has other fields than this version's \(misses\)"):
        other.restore(snapshot)
    assert other.track_ids == [] and other.last_stamp is None
