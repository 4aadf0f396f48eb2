"""Frames missing from an input stream, seen from its stamps: the gap a restart upstream leaves.

A node that dies and is restarted loses the messages sent while it was down, and the node after it in the graph is
the one that can see it: its input's stamps, usually a steady interval apart, jump by several intervals. The
restarted node itself starts its counters at zero and cannot know what it missed. ROS-free.
"""

from __future__ import annotations

import math
from collections import deque
from statistics import median

GAP_FACTOR = 2.5
"""An interval this many times the usual one is a gap (a detector dropping a frame now and then is not)."""
KNOWN_INTERVALS = 5
"""Intervals seen before the usual one is trusted."""


class InputGaps:
    """Counts the messages missing before each stamp of one input: a gap of several usual intervals.

    The usual interval is the median of the last ``window`` ones; a step back (a replay restarted) starts over.
    """

    def __init__(self, window: int = 50):
        self._intervals: deque[float] = deque(maxlen=window)
        self._last: float | None = None
        self.missing = 0
        self.gaps = 0
        self.last_gap_s = math.nan

    def observe(self, stamp_s: float) -> int:
        """The messages missing just before ``stamp_s`` (0 when none); counts them in ``missing``."""
        previous, self._last = self._last, stamp_s
        if previous is None or not math.isfinite(stamp_s):
            return 0
        interval = stamp_s - previous
        if interval <= 0:
            self._intervals.clear()
            return 0
        lost = 0
        if len(self._intervals) >= KNOWN_INTERVALS:
            usual = median(self._intervals)
            if interval > GAP_FACTOR * usual:
                lost = max(round(interval / usual) - 1, 1)
                self.missing += lost
                self.gaps += 1
                self.last_gap_s = interval
        if not lost:
            self._intervals.append(interval)
        return lost
