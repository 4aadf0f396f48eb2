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
    ReplayPosition,
    ReplayStats,
    ResumeCursor,
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
    topic: str = ""


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


# ------------------------------------------------------------------------------------------------ restarts (resume)
FIX, TRUTH = "/camera/fix", "/vessel/gps_truth"


def recorded_source(passes: int = 1, restamp: bool = True) -> list[Item]:
    """A bag's items: the camera's fix first, then a frame and a GPS truth message sharing each stamp.

    A later pass of a loop is shifted by the source's length (``restamp``), or repeats the stamps.
    """
    items = []
    for loop in range(passes):
        start = T0 + (5 * loop * NS_PER_S if restamp else 0)
        items.append(Item(start, loop, aux=True, topic=FIX))
        for k in range(5):
            items += [Item(start + k * NS_PER_S, loop), Item(start + k * NS_PER_S, loop, aux=True, topic=TRUTH)]
    return items


def replay_with_resume(items, after=None, **settings):
    """A replay of ``items`` carrying on after ``after``; (what it published in order, the positions it saved, sink)."""
    timing, stats = FakeTiming(), ReplayStats()
    sink = Sink(timing, stats)
    published, saved = [], []
    sink.published_at = []

    def publish(item):
        published.append(item)
        sink.published_at.append(timing.now)

    hooks = ReplayHooks(publish_frame=lambda item: publish(item) or sink.publish_frame(item), publish_aux=publish,
                        publish_clock=sink.clock.append, count=sink.count, log=sink.logs.append,
                        progress=lambda: "progress")
    cursor = ResumeCursor(after, save=saved.append, latched=lambda item: item.topic == FIX)
    Replay(PacingSettings(**settings), hooks, timing, AckWindow(timing), stats, is_frame=lambda item: not item.aux,
           resume=cursor).run(items)
    return published, saved, sink


@pytest.mark.parametrize("loop_restamp", [True, False])
def test_a_restarted_replay_carries_on_after_the_last_item_sent_whenever_the_crash_came(loop_restamp):
    """``./vessel graph --respawn`` replayed from frame 0: every frame again, the tracker reset by stamps going back.

    Here a crash after each item in turn (the position saved then is what the resume file holds): the restarted
    replay sends exactly the rest, at once, with /clock going on; a frame and a message of one stamp are told apart;
    the camera's latched fix is sent again first (a late subscriber of the new publisher gets it).
    """
    items = recorded_source(passes=2, restamp=loop_restamp)
    everything, saved, _ = replay_with_resume(items, rate=1.0, loop_restamp=loop_restamp)
    assert everything == items and len(saved) == len(items)
    assert [position.frames_sent for position in saved][-1] == 10
    for crash in range(len(items)):
        rest, _, sink = replay_with_resume(items, after=saved[crash], rate=1.0, loop_restamp=loop_restamp)
        resent_fix = [item for item in rest if item.topic == FIX and items.index(item) <= crash]
        assert rest == resent_fix + items[crash + 1:], crash
        assert len(resent_fix) == 1 and rest[:1] == resent_fix
        if rest[1:]:  # no pause for what was skipped: the first item goes at once, /clock on from the last one sent
            assert sink.published_at[0] == 100.0 and sink.clock[0] == items[crash + 1].stamp_ns
            assert sink.clock[0] >= saved[crash].stamp_ns or not loop_restamp and items[crash + 1].loop == 1


def test_max_frames_counts_the_frames_sent_before_a_restart():
    items = recorded_source()
    _, saved, _ = replay_with_resume(items, max_frames=3)
    after_two = next(position for position in saved if position.frames_sent == 2)
    rest, _, sink = replay_with_resume(items, after=after_two, max_frames=3)
    assert len(sink.frames) == 1 and sink.logs == ["max_frames=3 reached"]
    rest, _, sink = replay_with_resume(items, after=saved[-1], max_frames=3)  # all three sent before the restart
    assert sink.frames == [] and sink.logs == ["max_frames=3 reached"]


def test_replay_positions_as_json():
    position = ReplayPosition(loop=1, stamp_ns=T0, at_stamp=2, frames_sent=7)
    assert ReplayPosition.from_dict(position.as_dict()) == position
    for bad in (None, {"loop": 1}, {**position.as_dict(), "at_stamp": -1}, {**position.as_dict(), "loop": "1"},
                {**position.as_dict(), "extra": 0}):
        with pytest.raises(ValueError):
            ReplayPosition.from_dict(bad)


def test_the_cameras_resume_file(tmp_path):
    from vessel_detect.resume_files import (
        ResumeFileError,
        camera_record,
        camera_resume_point,
        camera_start_utc,
        read_resume_file,
        write_json_atomically,
    )

    path = tmp_path / "state" / "camera.resume"
    assert read_resume_file(path, "camera") is None
    position = ReplayPosition(0, T0 + 3 * NS_PER_S, 1, 3)
    write_json_atomically(path, camera_record("bags/video_13", T0, 1_601_494_000.25, position))
    assert [p.name for p in path.parent.iterdir()] == ["camera.resume"]  # no temporary file left
    data = read_resume_file(path, "camera")
    assert camera_resume_point(data, "bags/video_13", T0)[0] == position
    assert camera_start_utc(data, "bags/video_13") == 1_601_494_000.25  # a video is stamped from it again
    # Another source, or the same one starting at another time (a video stamped from a new start): from the start.
    assert camera_resume_point(data, "bags/video_14", T0)[0] is None and camera_start_utc(data, "bags/video_14") is None
    assert camera_resume_point(data, "bags/video_13", T0 + 1)[0] is None
    assert camera_resume_point(None, "bags/video_13", T0) == (None, "no resume file: from the first frame")
    for text in ("not json", '{"schema": "vessel_state", "version": 2, "node": "camera"}', "[1]"):
        path.write_text(text)
        with pytest.raises(ResumeFileError):
            read_resume_file(path, "camera")
    write_json_atomically(path, camera_record("bags/video_13", T0, None, position))
    with pytest.raises(ResumeFileError):
        read_resume_file(path, "recorder")


def test_a_restarted_recorder_continues_into_the_next_part(tmp_path):
    from vessel_detect.resume_files import recorder_output, recorder_record, recording_parts

    out = tmp_path / "recording"
    assert recorder_output(None, str(out)) == (None, [])  # a first start: the output as given
    out.mkdir()
    data = recorder_record([out])
    assert recorder_output(data, str(out)) == (tmp_path / "recording.1", [out])
    assert recorder_output(data, "") == (tmp_path / "recording.1", [out])  # no output given: the recording's
    assert recorder_output(data, str(tmp_path / "other")) == (None, [])  # another recording: a first start
    for name in ("recording.1", "recording.2", "recording.10", "recording.x", "recording.01", "recordings.3"):
        (tmp_path / name).mkdir()
    (tmp_path / "recording.damaged.mcap").write_bytes(b"")  # what bag recover keeps aside
    assert recording_parts(out) == [out] + [tmp_path / f"recording.{n}" for n in (1, 2, 10)]
    parts = [out, tmp_path / "recording.1", tmp_path / "recording.2", tmp_path / "recording.10"]
    assert recorder_output(recorder_record(parts), str(out)) == (tmp_path / "recording.11", parts)
