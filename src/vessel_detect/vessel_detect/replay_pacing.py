"""When the camera node publishes each item of a recorded source: its replay loop, without ROS.

At a rate factor (``rate`` > 0) an item is due when its stamp, measured from the pass's first item, has elapsed
divided by the rate; ``/clock`` advances along the stamps meanwhile. At ``rate`` 0 a frame is published as soon as
the detections of the one before (``frames_in_flight`` 1) or of the one before that (2) have arrived, or after
``ack_timeout_s``. A loop that repeats its stamps (``loop_restamp`` false) starts the pacing, ``/clock`` and the wait
for detections over. A change of rate while the replay runs applies from the moment it is made: the time to the next
item and on is paced at the new rate (a frame already waiting for detections at rate 0 waits on).

A replay restarted after a crash carries on after the last item the one before handled (``ResumeCursor``): the
items up to that ``ReplayPosition`` are skipped without pacing or ``/clock``, the latest skipped one of each latched
topic is published again before the first new item, and ``max_frames`` counts the frames sent before the restart.

The node (``vessel_detect.camera_node``) gives the publishing as ``ReplayHooks`` and the time as a ``Timing``
(``WallTiming``: the monotonic clock and the node's stop event); the tests give a fake one.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, fields
from typing import Any, Protocol

NS_PER_S = 1_000_000_000
LONGEST_PAUSE_S = 0.1
"""A wait for the next item wakes at least this often, so a change of rate or a stop is seen."""
SUBSCRIBER_POLL_S = 0.05
SUBSCRIBER_SETTLE_S = 0.3
"""After the subscribers matched on this side, the time their side takes to match too (the first frame is
best-effort)."""
PROGRESS_PERIOD_S = 10.0

ANSWERED, UNANSWERED, TIMED_OUT = "answered", "unanswered", "timed out"


class Timing(Protocol):
    """The time a replay runs on: a monotonic clock, pauses that a stop ends early, and the stop itself."""

    def monotonic(self) -> float:
        """Seconds of a clock that never goes back."""

    def stopped(self) -> bool:
        """Whether the replay is to stop."""

    def pause(self, seconds: float) -> None:
        """Wait ``seconds``, or less when stopped (or woken: callers check the time again)."""

    def wait_on(self, condition: threading.Condition, seconds: float) -> None:
        """Wait on ``condition`` (held) for at most ``seconds``."""


class WallTiming:
    """``Timing`` of the real world: ``time.monotonic`` and a ``threading.Event`` that stops the replay."""

    def __init__(self, stop: threading.Event) -> None:
        self._stop = stop

    def monotonic(self) -> float:
        """``time.monotonic()``."""
        return time.monotonic()

    def stopped(self) -> bool:
        """Whether the stop event is set."""
        return self._stop.is_set()

    def pause(self, seconds: float) -> None:
        """Wait on the stop event."""
        self._stop.wait(seconds)

    def wait_on(self, condition: threading.Condition, seconds: float) -> None:
        """``condition.wait(seconds)``."""
        condition.wait(seconds)


@dataclass
class ReplayStats:
    """Frames and messages the node handled."""

    sent: int = 0
    dropped: int = 0
    bad: int = 0
    aux_sent: int = 0
    ack_timeouts: int = 0
    unanswered: int = 0
    late: int = 0


@dataclass(frozen=True)
class PacingSettings:
    """The camera parameters the pacing reads, each at its next use (so a live change takes effect)."""

    rate: float = 1.0
    loop_restamp: bool = True
    clock_rate_hz: float = 50.0
    ack_timeout_s: float = 2.0
    frames_in_flight: int = 1
    drop_late: bool = False
    max_lag_s: float = 0.5
    max_frames: int = 0

    @classmethod
    def from_values(cls, values: Mapping[str, Any]) -> PacingSettings:
        """The settings among a node's parameter values (flat names, as ``declare_table`` returns them)."""
        return cls(**{f.name: values[f.name] for f in fields(cls) if f.name in values})


class RateSchedule:
    """When an item is due at the rate factor: measured from an anchor (wall time, stamp), the pass's first item.

    A change of rate moves the anchor to where the replay is at that moment (the stamp the time since the anchor
    reached at the old rate; at rate 0 the last item sent), so from there the stamps go at the new rate without a
    jump, and /clock goes on from where it was. At one rate the anchor stays, so lateness adds up as the stamps say.
    Thread-safe: the rate changes from a parameter callback while the replay thread asks.
    """

    def __init__(self, rate: float) -> None:
        self._lock = threading.Lock()
        self._rate = rate
        self._anchor: tuple[float, int] | None = None
        self._last_ns: int | None = None

    @property
    def rate(self) -> float:
        """The rate factor now (0: as fast as consumed)."""
        return self._rate

    def started(self) -> bool:
        """Whether the pass's first item came."""
        return self._anchor is not None

    def start(self, wall: float, stamp_ns: int) -> None:
        """The pass's first item, at ``wall`` (monotonic s)."""
        with self._lock:
            self._anchor = (wall, stamp_ns)
            self._last_ns = stamp_ns

    def restart(self) -> None:
        """Forget the anchor: the stamps start over (a loop that repeats them)."""
        with self._lock:
            self._anchor = self._last_ns = None

    def sent(self, stamp_ns: int) -> None:
        """The item at ``stamp_ns`` went: where a change of rate from rate 0 goes on from."""
        with self._lock:
            self._last_ns = stamp_ns

    def set_rate(self, rate: float, now: float) -> None:
        """Pace at ``rate`` from ``now`` (monotonic s) on."""
        with self._lock:
            if self._anchor is not None and rate != self._rate:
                self._anchor = (now, self._position_ns(now))
            self._rate = rate

    def _position_ns(self, now: float) -> int:
        wall0, stamp0 = self._anchor
        if self._rate <= 0:
            return self._last_ns
        return max(stamp0 + round((now - wall0) * self._rate * NS_PER_S), self._last_ns)

    def due(self, stamp_ns: int) -> float | None:
        """Monotonic time the item at ``stamp_ns`` is due; None at rate 0 or before the first item (at once)."""
        with self._lock:
            if self._rate <= 0 or self._anchor is None:
                return None
            wall0, stamp0 = self._anchor
            return wall0 + (stamp_ns - stamp0) / NS_PER_S / self._rate

    def clock_ns(self, now: float, next_ns: int) -> int | None:
        """The stamp ``/clock`` shows at ``now``, short of the next item's (None when nothing is paced)."""
        with self._lock:
            if self._rate <= 0 or self._anchor is None:
                return None
            wall0, stamp0 = self._anchor
            return min(stamp0 + round((now - wall0) * self._rate * NS_PER_S), next_ns - 1)


class AckWindow:
    """At rate 0: the detections (acks) that arrived for the frames sent, by stamp.

    Acks of stamps later than the newest frame sent are stale (a loop that repeats its stamps): ignored. Detections
    of a later frame alone release a frame too (the detector keeps only its newest image): "unanswered".
    """

    def __init__(self, timing: Timing, recent: int = 64) -> None:
        self._timing = timing
        self._condition = threading.Condition()
        self._acked_ns: int | None = None
        self._recent: deque[int] = deque(maxlen=recent)  # stamps whose detections arrived
        self._newest_sent_ns: int | None = None

    def sent(self, stamp_ns: int) -> None:
        """The frame at ``stamp_ns`` is being published: acks up to it count."""
        with self._condition:
            self._newest_sent_ns = stamp_ns

    def acknowledge(self, stamp_ns: int) -> bool:
        """Detections with ``stamp_ns`` arrived; False when they answer no frame of this pass."""
        with self._condition:
            if self._newest_sent_ns is None or stamp_ns > self._newest_sent_ns:
                return False
            self._acked_ns = stamp_ns
            self._recent.append(stamp_ns)
            self._condition.notify_all()
            return True

    def forget(self) -> None:
        """The stamps start over: no ack of the pass before counts."""
        with self._condition:
            self._acked_ns = self._newest_sent_ns = None
            self._recent.clear()

    def wake(self) -> None:
        """Wake a wait (the replay is stopping)."""
        with self._condition:
            self._condition.notify_all()

    def wait_for(self, stamp_ns: int, timeout_s: float) -> str:
        """Wait until the detections of the frame at ``stamp_ns`` or of a later one arrive.

        ANSWERED, UNANSWERED (only a later frame's came) or TIMED_OUT (after ``timeout_s``, or stopped).
        """
        deadline = self._timing.monotonic() + timeout_s
        with self._condition:
            while self._acked_ns is None or self._acked_ns < stamp_ns:
                remaining = deadline - self._timing.monotonic()
                if remaining <= 0 or self._timing.stopped():
                    return TIMED_OUT
                self._timing.wait_on(self._condition, min(remaining, LONGEST_PAUSE_S))
            return ANSWERED if stamp_ns in self._recent else UNANSWERED


@dataclass(frozen=True)
class ReplayPosition:
    """Where a replay is in its source, to carry on from after a restart.

    The pass (``loop``) and stamp of the last item it handled (sent, or dropped as late or unreadable), how many
    items it handled at exactly that pass and stamp (a frame and another message may share one), and the frames it
    sent in all.
    """

    loop: int = 0
    stamp_ns: int = 0
    at_stamp: int = 0
    frames_sent: int = 0

    def as_dict(self) -> dict[str, int]:
        """The position as JSON data."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, data: object) -> ReplayPosition:
        """The position ``as_dict`` made; ValueError for anything else."""
        names = [f.name for f in fields(cls)]
        if not isinstance(data, dict) or sorted(data) != sorted(names):
            raise ValueError(f"not a replay position (the fields {', '.join(names)})")
        if not all(type(data[name]) is int and data[name] >= 0 for name in names):
            raise ValueError("a field of the replay position is not a whole number >= 0")
        return cls(**{name: data[name] for name in names})


class ResumeCursor:
    """Where a replay carries on after a restart, and where it is now, for the next one.

    Items at or before ``after`` (at its very pass and stamp: its first ``at_stamp`` items) are skipped; of the skipped
    items, the latest of each topic that ``latched(item)`` holds is kept and published again before the first new
    item (or at the end if none comes), so a restarted node's latched publisher has it for late subscribers. ``save``
    gets the position after every item handled (the node writes it to its resume file).
    """

    def __init__(self, after: ReplayPosition | None = None,
                 save: Callable[[ReplayPosition], None] | None = None,
                 latched: Callable[[Any], bool] | None = None) -> None:
        self.after = after
        self.position = after or ReplayPosition()
        self._save = save
        self._latched = latched
        self._skipping = after is not None
        self._skipped_at_stamp = 0
        self._held: dict[object, Any] = {}
        self.skipped = 0

    @property
    def frames_sent(self) -> int:
        """Frames sent before the restart and since."""
        return self.position.frames_sent

    def skips(self, item) -> bool:
        """Whether ``item`` was handled before the restart (then it is skipped, a latched one kept)."""
        if not self._skipping:
            return False
        key, after = (item.loop, item.stamp_ns), (self.after.loop, self.after.stamp_ns)
        if key == after and self._skipped_at_stamp < self.after.at_stamp:
            self._skipped_at_stamp += 1
        elif key >= after:
            self._skipping = False
            return False
        self.skipped += 1
        if self._latched is not None and self._latched(item):
            self._held[getattr(item, "topic", None)] = item
        return True

    def take_held(self) -> list:
        """The latched items skipped, to publish again now (once)."""
        held, self._held = list(self._held.values()), {}
        return held

    def handled(self, item, sent_frame: bool) -> None:
        """``item`` was handled (``sent_frame``: a frame that went out): the position moves past it and is saved."""
        same = (item.loop, item.stamp_ns) == (self.position.loop, self.position.stamp_ns)
        self.position = ReplayPosition(item.loop, item.stamp_ns, self.position.at_stamp + 1 if same else 1,
                                       self.position.frames_sent + int(sent_frame))
        if self._save is not None:
            self._save(self.position)


@dataclass(frozen=True)
class ReplayHooks:
    """What the replay does with items, given by the node.

    ``publish_frame`` returns whether the frame went out (and counts it in the stats); ``publish_clock`` is None
    without ``/clock``; ``count(kind, problem)`` reports a count (with a problem text: a problem of that kind);
    ``log`` writes an info line; ``progress`` is the line logged every ``PROGRESS_PERIOD_S``.
    """

    publish_frame: Callable[[Any], bool]
    publish_aux: Callable[[Any], None]
    publish_clock: Callable[[int], None] | None
    count: Callable[[str, str], None]
    log: Callable[[str], None]
    progress: Callable[[], str]


class Replay:
    """One replay of a source's items (frames and other messages, each with ``stamp_ns`` and ``loop``)."""

    def __init__(self, settings: PacingSettings, hooks: ReplayHooks, timing: Timing, acks: AckWindow,
                 stats: ReplayStats, *, live: bool = False, is_frame: Callable[[Any], bool],
                 resume: ResumeCursor | None = None) -> None:
        self.settings = settings
        self.hooks = hooks
        self.timing = timing
        self.acks = acks
        self.stats = stats
        self.live = live
        self.is_frame = is_frame
        self.resume = resume or ResumeCursor()
        self.schedule = RateSchedule(settings.rate)
        self._in_flight: deque[int] = deque()  # stamps of frames sent whose detections have not arrived (rate 0)
        self._last_clock_ns: int | None = None

    def update(self, settings: PacingSettings) -> None:
        """New settings (a live change): the rate from the next item, the others at their next use."""
        self.schedule.set_rate(settings.rate, self.timing.monotonic())
        self.settings = settings

    def waits_for_acks(self) -> bool:
        """Whether each frame waits for detections (rate 0, a recorded source)."""
        return not self.live and self.schedule.rate == 0

    def run(self, items: Iterable) -> None:
        """Publish ``items`` in time; return at their end, at ``max_frames`` or when stopped."""
        last_log = self.timing.monotonic()
        pass_index = 0
        for item in items:
            if self.timing.stopped():
                return
            if self.resume.skips(item):
                continue
            self._publish_held()
            if self._max_frames_reached():  # a restart after the last of them
                return
            if item.loop != pass_index:
                pass_index = item.loop
                if not self.settings.loop_restamp:
                    self._start_over()
            late_s = self._wait_until_due(item)
            if late_s is None:
                return
            if not self.is_frame(item):
                self.hooks.publish_aux(item)
                self.resume.handled(item, False)
                continue
            if self._dropped_late(item, late_s):
                self.resume.handled(item, False)
                continue
            self._send(item)
            if self._max_frames_reached():
                return
            if self.timing.monotonic() - last_log > PROGRESS_PERIOD_S:
                last_log = self.timing.monotonic()
                self.hooks.log(self.hooks.progress())
        self._publish_held()
        self._drain()

    def _max_frames_reached(self) -> bool:
        """Whether ``max_frames`` frames went out (before a restart too); then the frames in flight are waited for."""
        if not 0 < self.settings.max_frames <= self.resume.frames_sent:
            return False
        self.hooks.log(f"max_frames={self.settings.max_frames} reached")
        self._drain()
        return True

    def _publish_held(self) -> None:
        """The latched items skipped after a restart, again: before the first new item, or at the end."""
        for held in self.resume.take_held():
            self.hooks.publish_aux(held)

    def _start_over(self) -> None:
        """The stamps start over (a loop that repeats them), so the pacing, /clock and the acks do too."""
        self._drain()
        self.acks.forget()
        self.schedule.restart()
        self._last_clock_ns = None

    def _wait_until_due(self, item) -> float | None:
        """Wait for the item's time, advancing /clock meanwhile, then /clock at its stamp.

        Returns how late the item is, s (0 unless paced by the rate); None when stopped meanwhile.
        """
        if not self.schedule.started():
            self.schedule.start(self.timing.monotonic(), item.stamp_ns)
            self._clock(item.stamp_ns)
        late_s = 0.0
        if not self.live and self.schedule.rate > 0:
            due = self._sleep_until_due(item.stamp_ns)
            if self.timing.stopped():
                return None
            late_s = self.timing.monotonic() - due if due is not None else 0.0
        self.schedule.sent(item.stamp_ns)
        self._clock(item.stamp_ns)
        return late_s

    def _sleep_until_due(self, stamp_ns: int) -> float | None:
        """Wait until the item is due (its time is asked again on every wake: the rate may change)."""
        while True:
            due = self.schedule.due(stamp_ns)
            now = self.timing.monotonic()
            if due is None or now >= due or self.timing.stopped():
                return due
            if self.hooks.publish_clock is not None:
                sim_ns = self.schedule.clock_ns(now, stamp_ns)
                if sim_ns is not None:
                    self._clock(sim_ns)
                self.timing.pause(min(1.0 / self.settings.clock_rate_hz, due - now, LONGEST_PAUSE_S))
            else:
                self.timing.pause(min(due - now, LONGEST_PAUSE_S))

    def _clock(self, stamp_ns: int) -> None:
        """/clock at ``stamp_ns`` unless it showed that or later already (it never goes back within a pass)."""
        if self.hooks.publish_clock is not None and (self._last_clock_ns is None or stamp_ns > self._last_clock_ns):
            self.hooks.publish_clock(stamp_ns)
            self._last_clock_ns = stamp_ns

    def _dropped_late(self, frame, late_s: float) -> bool:
        """Count a frame later than ``max_lag_s``; True when ``drop_late`` drops it."""
        if late_s <= self.settings.max_lag_s:
            return False
        self.stats.late += 1
        self.hooks.count("frames_late", "")
        if not self.settings.drop_late:
            return False
        self.stats.dropped += 1
        self.hooks.count("frames_dropped", f"frame at {frame.stamp_ns / 1e9:.3f} s was {late_s:.2f} s late; dropped "
                                           "(drop_late)")
        return True

    def _send(self, frame) -> None:
        """Publish a frame; at rate 0 then wait for the detections it needs before the next one."""
        self.acks.sent(frame.stamp_ns)
        published = self.hooks.publish_frame(frame)
        self.resume.handled(frame, published)  # before the wait for detections: a crash there resumes after it
        if not self.waits_for_acks():
            self._in_flight.clear()  # paced by the rate (now): no frame waits for detections
        elif published:
            self._in_flight.append(frame.stamp_ns)
            while len(self._in_flight) >= self.settings.frames_in_flight:
                self._wait_for_ack(self._in_flight.popleft())

    def _drain(self) -> None:
        """At the end of a paced replay: wait for the detections of the frames still in flight."""
        while self._in_flight and not self.timing.stopped():
            self._wait_for_ack(self._in_flight.popleft())

    def _wait_for_ack(self, stamp_ns: int) -> None:
        outcome = self.acks.wait_for(stamp_ns, self.settings.ack_timeout_s)
        if outcome == TIMED_OUT:
            self.stats.ack_timeouts += 1
            self.hooks.count("ack_timeouts", "")
        elif outcome == UNANSWERED:
            self.stats.unanswered += 1
            self.hooks.count("frames_unanswered", "")


def subscribers_to_wait_for(setting: int, paced_by_acks: bool) -> tuple[int, bool]:
    """(image subscribers to wait for, whether to wait for a publisher of the acks) before the first frame.

    ``setting`` is the ``wait_for_subscribers`` parameter: -1 (automatic) waits for one image subscriber and the
    detector at rate 0, for nothing else.
    """
    if setting >= 0:
        return setting, False
    return (1, True) if paced_by_acks else (0, False)


def wait_until(ready: Callable[[], bool], timeout_s: float, timing: Timing) -> bool:
    """Poll ``ready`` until it holds (True) or ``timeout_s`` passes (False); True when stopped meanwhile."""
    deadline = timing.monotonic() + timeout_s
    while not timing.stopped() and not ready():
        if timing.monotonic() > deadline:
            return False
        timing.pause(SUBSCRIBER_POLL_S)
    return True

