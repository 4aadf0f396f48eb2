"""The gap a restart upstream leaves in an input's stamps, at 4 s and at 40 ms between frames."""

import pytest

from vessel_common.input_gaps import InputGaps


@pytest.mark.parametrize("interval", [4.0, 0.04])
def test_a_restart_upstream_is_counted_as_the_frames_it_lost(interval):
    gaps = InputGaps()
    stamps = [1000.0 + k * interval for k in range(20)]
    lost = stamps[10:12]  # two frames never arrive: the node before this one was down
    assert [gaps.observe(s) for s in stamps if s not in lost] == [0] * 10 + [2] + [0] * 7
    assert (gaps.missing, gaps.gaps) == (2, 1) and gaps.last_gap_s == pytest.approx(3 * interval)


def test_jitter_and_a_replay_restart_are_not_gaps():
    gaps = InputGaps()
    jittered = [100.0, 104.1, 107.9, 112.0, 116.2, 119.9, 124.0, 129.5, 132.0]  # 5.5 s once: not 2.5 intervals
    assert sum(gaps.observe(s) for s in jittered) == 0
    assert gaps.observe(50.0) == 0 and gaps.observe(54.0) == 0  # back in time: the usual interval starts over
    assert gaps.missing == 0


def test_nothing_is_counted_before_the_usual_interval_is_known():
    gaps = InputGaps()
    assert [gaps.observe(s) for s in (0.0, 1.0, 10.0, 11.0)] == [0, 0, 0, 0]
