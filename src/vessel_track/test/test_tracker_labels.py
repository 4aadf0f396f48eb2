"""The tracker on the real hand-labelled boxes of the challenge data (skipped when the data is absent).

The primary hand boxes of one video are fed as detections (score 1, stamps from the dataset's clock); the
vessel of interest should end up in as few tracks as the gaps in the labels allow.
"""

from collections import defaultdict

import numpy as np
import pytest

from vessel_track.tracker import MultiTargetTracker
from vessel_track.tracker_config import TrackerConfig

pytestmark = pytest.mark.data

VALIDATION_VIDEOS = (13, 14, 15, 16, 17)


def _dataset():
    from vessel_common.paths import default_data_dir
    from vessel_tools.calib.dataset import Dataset

    root = default_data_dir()
    if root is None or not (root / "screen_labels.csv").exists():
        pytest.skip("challenge data not found: set VESSEL_DATA or put it in ../shared/aitas")
    return Dataset(root)


def tracks_of_labelled_vessel(labels, config: TrackerConfig) -> dict[str, int]:
    """Feed one video's labels frame by frame; detections received by each track id."""
    frames = defaultdict(list)
    for r in labels:
        frames[r.stamp].append([r.x1, r.y1, r.x2, r.y2])
    tracker = MultiTargetTracker(config)
    received: dict[str, int] = defaultdict(int)
    for stamp in sorted(frames):
        boxes = np.array(frames[stamp])
        for state in tracker.update(stamp, boxes, np.ones(len(boxes))):
            if state.updated:
                received[state.track_id] += 1
    return dict(received)


def test_labelled_vessel_is_not_split_more_than_its_label_gaps_force():
    ds = _dataset()
    config = TrackerConfig()
    total = 0
    for video in VALIDATION_VIDEOS:
        labels = ds.labels([video])
        stamps = np.unique([r.stamp for r in labels])
        forced = 1 + int(np.sum(np.diff(stamps) > config.max_coast_s))
        received = tracks_of_labelled_vessel(labels, config)
        print(f"\nvideo {video}: {len(labels)} labels, {len(stamps)} frames, {forced} track(s) forced by gaps > "
              f"{config.max_coast_s:g} s -> {len(received)} track(s), detections per track "
              f"{sorted(received.values(), reverse=True)}")
        total += len(received)
        assert len(received) <= forced + 1
    print(f"validation videos {VALIDATION_VIDEOS}: {total} tracks in total")
    assert total <= len(VALIDATION_VIDEOS) + 3
