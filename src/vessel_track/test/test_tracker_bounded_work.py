"""The tracker's work per frame does not grow with its tracks' histories (#48, finding 17).

On a live stream (``./vessel bench live``: 25 frames/s, a challenge video looped) every track's history fills up to
``history_length`` over minutes: a frame that reads whole histories gets slower until the node falls behind.
"""

from collections import deque

import numpy as np

from vessel_track.tracker import MultiTargetTracker
from vessel_track.tracker_config import TrackerConfig

FPS = 25.0


class CountingHistory(deque):
    """A track history that counts the entries read from it."""

    reads = 0

    def __iter__(self):
        for entry in super().__iter__():
            CountingHistory.reads += 1
            yield entry

    def __getitem__(self, index):
        CountingHistory.reads += 1
        return super().__getitem__(index)


def test_an_update_reads_only_the_newest_confidences_of_each_history():
    config = TrackerConfig(history_length=2000)  # a long history, as a state file or a user may keep
    tracker = MultiTargetTracker(config)
    box = np.array([[600.0, 400.0, 640.0, 420.0]])
    for k in range(300):  # one vessel seen in every frame for 12 s: a history of 300 updates
        tracker.update(1000.0 + k / FPS, box, [0.8])
    (track,) = tracker._tracks
    assert len(track.history) == 300
    track.history = CountingHistory(track.history, maxlen=config.history_length)
    CountingHistory.reads = 0
    tracker.update(1000.0 + 300 / FPS, box, [0.8])
    assert CountingHistory.reads <= config.confidence_memory
    assert len(tracker.history(track.track_id).stamps) == 301  # the history itself is kept whole
