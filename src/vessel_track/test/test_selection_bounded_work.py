"""The selection's work per frame does not grow with its histories (#48, finding 17).

On a live stream (``./vessel bench live``: 25 frames/s, a challenge video looped) every running history fills up to
``selection.history_length`` confidences over minutes; a score is asked for several times a frame for every running
and ended track, and computing it reads the whole history: frames get slower until the fuser falls behind.
"""

import numpy as np

from vessel_tools.track.pipeline import screen_track_of
from vessel_tools.track.simulation import challenge_camera, fuser_settings_of_simulation, harbour_scenario
from vessel_track.selection_config import SelectionConfig
from vessel_track.track_fuser import TrackFuser
from vessel_track.tracker import MultiTargetTracker
from vessel_track.tracker_config import TrackerConfig

FPS = 25.0


def looped_frames(count: int):
    """The simulated harbour as 37 frames 4 s apart, played at 25 frames/s over and over, stamps moving on."""
    base = harbour_scenario(frame_interval_s=4.0, duration_s=144.0).run().frames
    start = base[0].stamp
    for k in range(count):
        yield start + k / FPS, base[k % len(base)].boxes_xyxy, base[k % len(base)].scores


def run_cores(frames, on_frame=None):
    camera = challenge_camera()
    settings = fuser_settings_of_simulation(camera)
    tracker = MultiTargetTracker(TrackerConfig())
    fuser = TrackFuser(camera, settings.distance_model, settings.fusion, settings.cue_stats, settings.motion,
                       settings.selection, settings.error_model)
    for stamp, boxes, scores in frames:
        fuser.update(stamp, [screen_track_of(state) for state in tracker.update(stamp, boxes, scores)])
        if on_frame is not None:
            on_frame(fuser)
    return tracker, fuser


def test_a_frame_that_changes_no_history_computes_no_score(monkeypatch):
    computed = []
    original = SelectionConfig.trajectory_score

    def counting(self, confidences, path_m):
        computed.append(len(confidences))
        return original(self, confidences, path_m)

    monkeypatch.setattr(SelectionConfig, "trajectory_score", counting)
    tracker, fuser = run_cores(looped_frames(300))
    assert len(fuser.selector._running) >= 20 and computed  # tracks of every loop, coasting
    stamp = tracker.last_stamp
    computed.clear()
    for k in range(1, 11):  # no detection for 0.4 s: every track coasts, no confidence and no path is added
        fuser.update(stamp + k / FPS, [screen_track_of(s) for s in tracker.update(stamp + k / FPS, [], [])])
    assert len(fuser.selector._running) >= 20 and computed == []


def test_remembered_scores_are_those_of_the_histories_now():
    checked = []

    def check(fuser):
        config = fuser.selector.config
        for running in [*fuser.selector._running.values(), *fuser.selector._ended.values()]:
            assert running.score(config) == config.trajectory_score(np.fromiter(running.confidences, float),
                                                                    running.path_m)
            checked.append(1)

    _, fuser = run_cores(looped_frames(400), check)
    assert fuser.selector.joins > 0 and len(checked) > 5000  # histories continued by the online joins too
