"""The camera's replay pacing on a fake clock: no ROS, no sleeping."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import pytest

from vessel_detect.replay_pacing import (
    ANSWERED,
    NS_PER_S,
    TIMED_OUT,
    UNANSWERED,
    AckWindow,
    PacingSettings,
    RateSchedule,
    Replay,
    ReplayHooks,
    ReplayStats,
    subscribers_to_wait_for,
    wait_until,
)

T0 = 1_601_494_000 * NS_PER_S


class FakeTiming:
    """A clock that moves only when the code under test pauses; events run at their fake time."""

    def __init__(self) -> None:
        self.now = 100.0
        self.stop = False
        self.events: list[tuple[float, object]] = []

    def at(self, when: float, action) -> None:
        self.events.append((when, action))
        self.events.sort(key=lambda event: event[0])

    def monotonic(self) -> float:
        return self.now

    def stopped(self) -> bool:
        return self.stop

    def pause(self, seconds: float) -> None:
        assert seconds > 0, "a pause of nothing would spin"
        target = self.now + seconds
        if self.events and self.events[0][0] <= target:  # woken early, as a real wait may be
            when, action = self.events.pop(0)
            self.now = max(self.now, when)
            action()
            return
        self.now = target

    def wait_on(self, condition: threading.Condition, seconds: float) -> None:
        self.pause(seconds)


@dataclass
class Item:
    stamp_ns: int
    loop: int = 0
    aux: bool = False


class Sink:
    """Records what the replay publishes, at which fake time; plays the detector when ``answer`` is set."""

    def __init__(self, timing: FakeTiming, stats: ReplayStats, clock: bool = True) -> None:
        self.timing, self.stats = timing, stats
        self.frames: list[tuple[float, int]] = []
        self.aux: list[int] = []
        self.clock: list[int] = []
        self.counts: dict[str, int] = {}
        self.logs: list[str] = []
        self.acks: AckWindow | None = None
        self.answer_after_s: float | None = None  # the detector's time per image
        self.hooks = ReplayHooks(publish_frame=self.publish_frame,
                                 publish_aux=lambda item: self.aux.append(item.stamp_ns),
                                 publish_clock=self.clock.append if clock else None, count=self.count,
                                 log=self.logs.append, progress=lambda: "progress")

    def publish_frame(self, frame: Item) -> bool:
        self.frames.append((self.timing.now, frame.stamp_ns))
        self.stats.sent += 1
        if self.answer_after_s is not None:
            self.timing.at(self.timing.now + self.answer_after_s, lambda: self.acks.acknowledge(frame.stamp_ns))
        return True

    def count(self, kind: str, problem: str) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + 1

    @property
    def times(self) -> list[float]:
        return [round(when - 100.0, 6) for when, _ in self.frames]


def make_replay(clock: bool = True, live: bool = False, **settings) -> tuple[Replay, Sink, FakeTiming]:
    timing = FakeTiming()
    stats = ReplayStats()
    sink = Sink(timing, stats, clock=clock)
    acks = AckWindow(timing)
    sink.acks = acks
    replay = Replay(PacingSettings(**settings), sink.hooks, timing, acks, stats, live=live,
                    is_frame=lambda item: not item.aux)
    return replay, sink, timing


def frames(count: int, step_s: float, loop: int = 0, start_ns: int = T0) -> list[Item]:
    return [Item(start_ns + round(k * step_s * NS_PER_S), loop) for k in range(count)]


def test_frames_go_when_their_stamps_say_at_the_rate_with_clock_between():
    replay, sink, _ = make_replay(rate=2.0)
    items = frames(5, 1.0)
    replay.run(items)
    assert sink.times == [0.0, 0.5, 1.0, 1.5, 2.0]
    assert [stamp for _, stamp in sink.frames] == [i.stamp_ns for i in items]
    assert sink.clock == sorted(sink.clock) and len(set(sink.clock)) == len(sink.clock)
    assert {i.stamp_ns for i in items} <= set(sink.clock) and len(sink.clock) > 5 * len(items)
    assert sink.counts == {}


def test_a_change_of_rate_applies_from_the_moment_it_is_made():
    """At 1x, frames 10 s apart; at 5 s the rate becomes 10: the replay is at 5 s of stamps, 5 s more take 0.5 s."""
    replay, sink, timing = make_replay(rate=1.0)
    timing.at(105.0, lambda: replay.update(PacingSettings(rate=10.0)))
    replay.run(frames(4, 10.0))
    assert sink.times == [0.0, 5.5, 6.5, 7.5]
    assert sink.counts == {}  # nothing counts as late for the change
    assert sink.clock == sorted(sink.clock)  # /clock goes on from where it was


def test_a_slower_rate():
    """At 0.5 s the rate goes from 1 to 0.5: the 0.5 s of stamps left to the second frame take 1 s."""
    replay, sink, timing = make_replay(rate=1.0, clock=False)
    timing.at(100.5, lambda: replay.update(PacingSettings(rate=0.5)))
    replay.run(frames(3, 1.0))
    assert sink.times == [0.0, 1.5, 3.5] and sink.counts == {}


def test_from_rate_zero_to_a_rate():
    """Paced by detections (0.25 s each), then at 0.6 s rate 2: 4 s of stamps from the last frame take 2 s."""
    replay, sink, timing = make_replay(rate=0.0, clock=False)
    sink.answer_after_s = 0.25
    timing.at(100.6, lambda: replay.update(PacingSettings(rate=2.0)))
    replay.run(frames(4, 4.0))
    assert sink.times == pytest.approx([0.0, 0.25, 0.5, 2.6]) and sink.counts == {}


def test_rate_zero_waits_for_the_detections_of_each_frame():
    replay, sink, _ = make_replay(rate=0.0, ack_timeout_s=5.0)
    sink.answer_after_s = 0.25
    replay.run(frames(4, 4.0))
    assert sink.times == pytest.approx([0.0, 0.25, 0.5, 0.75])
    assert sink.counts == {}
    assert sink.clock == [i.stamp_ns for i in frames(4, 4.0)]  # /clock at each frame only


def test_rate_zero_times_out_without_a_detector_and_two_in_flight_keep_it_busy():
    replay, sink, _ = make_replay(rate=0.0, ack_timeout_s=0.5)
    replay.run(frames(3, 4.0))
    assert sink.times == pytest.approx([0.0, 0.5, 1.0]) and sink.counts == {"ack_timeouts": 3}

    replay, sink, _ = make_replay(rate=0.0, ack_timeout_s=5.0, frames_in_flight=2)
    sink.answer_after_s = 1.0
    replay.run(frames(4, 4.0))
    # the second frame goes at once; each later one when the detections of the one two before arrive
    assert sink.times == pytest.approx([0.0, 0.0, 1.0, 1.0]) and sink.counts == {}


def test_from_a_rate_to_rate_zero():
    """At 0.2 s rate 0: the frame waited for goes at once, then each waits for detections (none come: timeouts)."""
    replay, sink, timing = make_replay(rate=1.0, clock=False, ack_timeout_s=2.0)
    timing.at(100.2, lambda: replay.update(PacingSettings(rate=0.0, ack_timeout_s=2.0)))
    replay.run(frames(3, 1.0))
    assert sink.times == pytest.approx([0.0, 0.2, 2.2])
    assert sink.counts == {"ack_timeouts": 2}


def test_a_loop_that_repeats_its_stamps_starts_pacing_clock_and_acks_over():
    replay, sink, _ = make_replay(rate=1.0, loop_restamp=False)
    replay.run(frames(3, 1.0) + frames(3, 1.0, loop=1))
    assert sink.times == [0.0, 1.0, 2.0, 2.0, 3.0, 4.0]
    first_pass_end = sink.clock.index(T0 + 2 * NS_PER_S)
    assert sink.clock[first_pass_end + 1] == T0  # /clock jumps back once, with the stamps
    assert sink.clock[first_pass_end + 1:] == sorted(sink.clock[first_pass_end + 1:])


def test_acks_of_a_pass_before_the_loop_do_not_release_frames():
    timing = FakeTiming()
    acks = AckWindow(timing)
    acks.sent(T0 + 2)
    assert not acks.acknowledge(T0 + 5)  # later than any frame sent: a stale answer
    assert acks.acknowledge(T0 + 2) and acks.wait_for(T0 + 2, 1.0) == ANSWERED
    acks.sent(T0 + 4)
    acks.sent(T0 + 6)
    assert acks.acknowledge(T0 + 6)
    assert acks.wait_for(T0 + 4, 1.0) == UNANSWERED  # only a later frame's detections came
    acks.forget()
    start = timing.now
    assert acks.wait_for(T0 + 2, 1.0) == TIMED_OUT and timing.now - start == pytest.approx(1.0)


def test_late_frames_are_counted_and_dropped_with_drop_late():
    replay, sink, timing = make_replay(rate=1.0, clock=False, drop_late=True, max_lag_s=0.5)
    original = sink.publish_frame

    def slow_publish(frame):  # a machine that needs 2 s per frame
        timing.now += 2.0
        return original(frame)

    sink.hooks = replay.hooks = ReplayHooks(slow_publish, sink.hooks.publish_aux, None, sink.count, sink.logs.append,
                                            sink.hooks.progress)
    replay.run(frames(4, 1.0))
    assert [stamp for _, stamp in sink.frames] == [T0, T0 + 2 * NS_PER_S]
    assert sink.counts == {"frames_late": 2, "frames_dropped": 2} and replay.stats.dropped == 2


def test_max_frames_aux_messages_live_sources_and_stop():
    replay, sink, _ = make_replay(rate=1.0, max_frames=2)
    items = [Item(T0), Item(T0 + NS_PER_S // 2, aux=True), Item(T0 + NS_PER_S), Item(T0 + 2 * NS_PER_S)]
    replay.run(items)
    assert sink.aux == [T0 + NS_PER_S // 2] and len(sink.frames) == 2 and sink.logs == ["max_frames=2 reached"]

    replay, sink, _ = make_replay(rate=1.0, live=True)
    replay.run(frames(3, 10.0))
    assert sink.times == [0.0, 0.0, 0.0]  # a live source is not paced: frames go as they come

    replay, sink, timing = make_replay(rate=1.0)
    timing.at(101.5, lambda: setattr(timing, "stop", True))
    replay.run(frames(5, 1.0))
    assert sink.times == [0.0, 1.0]


def test_live_settings_are_read_at_their_next_use():
    replay, sink, timing = make_replay(rate=1.0, clock=False)
    timing.at(100.5, lambda: replay.update(PacingSettings(rate=1.0, max_frames=2)))
    replay.run(frames(5, 1.0))
    assert len(sink.frames) == 2


def test_pacing_settings_from_parameter_values():
    values = {"rate": 8.0, "max_frames": 3, "source": "bags/x", "frames_in_flight": 2}
    assert PacingSettings.from_values(values) == PacingSettings(rate=8.0, max_frames=3, frames_in_flight=2)


def test_rate_schedule():
    schedule = RateSchedule(2.0)
    assert schedule.due(T0) is None and not schedule.started()
    schedule.start(10.0, T0)
    assert schedule.due(T0 + 3 * NS_PER_S) == 11.5
    assert schedule.clock_ns(10.5, T0 + 3 * NS_PER_S) == T0 + NS_PER_S
    assert schedule.clock_ns(20.0, T0 + 3 * NS_PER_S) == T0 + 3 * NS_PER_S - 1  # never the next item's stamp
    schedule.set_rate(2.0, 99.0)  # the same rate: nothing moves
    assert schedule.due(T0 + 3 * NS_PER_S) == 11.5
    schedule.set_rate(0.0, 11.0)
    assert schedule.due(T0 + 3 * NS_PER_S) is None and schedule.clock_ns(11.0, T0 + NS_PER_S) is None
    schedule.sent(T0 + 2 * NS_PER_S)
    schedule.set_rate(1.0, 50.0)  # from rate 0: on from the last item sent, now
    assert schedule.due(T0 + 3 * NS_PER_S) == 51.0
    schedule.restart()
    assert not schedule.started() and schedule.due(T0) is None


def test_subscribers_to_wait_for_and_wait_until():
    assert subscribers_to_wait_for(-1, paced_by_acks=True) == (1, True)
    assert subscribers_to_wait_for(-1, paced_by_acks=False) == (0, False)
    assert subscribers_to_wait_for(2, paced_by_acks=True) == (2, False)
    timing = FakeTiming()
    ready = []
    timing.at(101.0, lambda: ready.append(True))
    assert wait_until(lambda: bool(ready), 5.0, timing) and timing.now == pytest.approx(101.0)
    assert not wait_until(lambda: False, 5.0, timing) and timing.now > 106.0
