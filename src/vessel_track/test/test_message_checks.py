"""What the tracking nodes refuse from their input messages (ROS-free: plain objects stand in for the messages).

Findings 4-10 of issue 48, each at the level of the check; the node tests feed the same fields to the nodes.
"""

import math
from types import SimpleNamespace

import pytest

from vessel_track.message_checks import (
    PROBLEMS,
    checked_detections,
    checked_tracks,
    covariance_problem,
    header_refusal,
    order_refusal,
    stamp_order,
    stamp_problem,
)

STAMP_S = 1601496000


def _time(sec, nanosec=0):
    return SimpleNamespace(sec=sec, nanosec=nanosec)


def _track(track_id="T1", **fields):
    """A VesselTrack as the fuser publishes it, stamped STAMP_S, with ``fields`` replaced."""
    base = dict(id=track_id, header=SimpleNamespace(stamp=_time(STAMP_S)), status=1, confidence=0.8,
                first_seen=_time(STAMP_S - 40), last_seen=_time(STAMP_S), screen_covariance=[16.0, 1.0, 1.0, 9.0],
                screen_velocity=SimpleNamespace(x=1.5, y=-0.5), has_world=True,
                position_covariance=[25.0, 5.0, 5.0, 4.0], velocity_covariance=[0.5, 0.0, 0.0, 0.5],
                expected_error_m=10.0, is_target=False)
    base.update(fields)
    return SimpleNamespace(**base)


def _kinds(tracks, world=True, previous_s=None):
    kept, refusals = checked_tracks(tracks, _time(STAMP_S), previous_s, world=world)
    return [t.id for t in kept], [r.kind for r in refusals]


def test_a_good_track_passes_and_every_kind_has_a_message():
    assert _kinds([_track("T1"), _track("T2", status=3, has_world=False, expected_error_m=math.nan,
                                        position_covariance=[math.nan] * 4, velocity_covariance=[math.nan] * 4)]) \
        == (["T1", "T2"], [])
    assert _kinds([_track(has_world=False, position_covariance=[math.nan] * 4, expected_error_m=math.nan)],
                  world=False) == (["T1"], [])
    _, refusals = checked_tracks([_track(status=200)], _time(STAMP_S))
    assert set(PROBLEMS) >= {"bad_stamp", "duplicate_stamp", "out_of_order_frames", "bad_score"}
    assert refusals[0].message.startswith("track 'T1' has status 200: the track was dropped")


def test_finding_4_tracks_with_one_id_are_all_refused():
    """Two tracks with the same id, both is_target: neither is published (the other tracks are)."""
    kept, kinds = _kinds([_track("T1", is_target=True), _track("T2"), _track("T1", is_target=True)])
    assert kept == ["T2"] and kinds == ["duplicate_track_id"] * 2


def test_finding_5_a_track_seen_in_the_future_is_refused():
    assert _kinds([_track(last_seen=_time(STAMP_S + 1_000_000))]) == ([], ["bad_track_time"])
    assert _kinds([_track(last_seen=_time(STAMP_S, 999))]) == (["T1"], [])  # a float stamp's rounding


def test_a_lost_track_reported_at_a_replay_restart_keeps_its_old_times():
    """A tracker restarted by a replay reports its tracks LOST at the earlier stamp, seen until the previous one."""
    lost = _track(status=3, first_seen=_time(STAMP_S + 20), last_seen=_time(STAMP_S + 60))
    assert _kinds([lost], previous_s=STAMP_S + 60.0) == (["T1"], [])
    assert _kinds([lost], previous_s=STAMP_S + 30.0) == ([], ["bad_track_time"])
    assert _kinds([_track(last_seen=_time(STAMP_S + 60))], previous_s=STAMP_S + 60.0) == ([], ["bad_track_time"])


@pytest.mark.parametrize("error", [-5.0, math.inf, math.nan])
def test_finding_6_an_impossible_expected_error_is_refused(error):
    assert _kinds([_track(expected_error_m=error)]) == ([], ["bad_expected_error"])


def test_finding_7_a_score_outside_0_1_is_refused():
    def detection(*scores):
        return SimpleNamespace(results=[SimpleNamespace(hypothesis=SimpleNamespace(class_id="boat", score=s))
                                        for s in scores])

    good, no_hypothesis = detection(0.0, 1.0), detection()
    kept, refusals = checked_detections([detection(1e9), good, detection(0.5, -0.1), detection(math.nan),
                                         no_hypothesis])
    assert kept == [good, no_hypothesis] and [r.kind for r in refusals] == ["bad_score"] * 3
    assert "1e+09" in refusals[0].detail
    assert _kinds([_track(confidence=1e9)]) == ([], ["bad_confidence"])


def test_finding_8_stamps_must_be_valid_and_strictly_increasing():
    assert stamp_problem(_time(STAMP_S, 999_999_999)) == ""
    assert "nanosec 1000000000" in header_refusal(_time(STAMP_S, 1_000_000_000)).detail
    assert header_refusal(_time(STAMP_S, 1_500_000_000)).kind == "bad_stamp"
    assert [stamp_order(s, p) for s, p in ((5.0, None), (6.0, 5.0), (5.0, 5.0), (4.5, 5.0), (4.0, 5.0))] == [
        "first", "newer", "duplicate", "out_of_order", "restart"]
    assert order_refusal(5.0, 5.0).kind == "duplicate_stamp"
    assert order_refusal(4.5, 5.0).kind == "out_of_order_frames"
    assert order_refusal(4.5, 5.0, backwards_reset_s=0.2) is None  # the tracker's own backwards_reset_s
    assert order_refusal(3.0, 5.0) is None and order_refusal(6.0, 5.0) is None


@pytest.mark.parametrize("bad, kind", [
    (dict(screen_covariance=[math.nan, 0.0, 0.0, 16.0]), "bad_screen_covariance"),
    (dict(screen_covariance=[-16.0, 0.0, 0.0, 16.0]), "bad_screen_covariance"),
    (dict(screen_covariance=[1.0, 3.0, 3.0, 1.0]), "bad_screen_covariance"),   # not positive semi-definite
    (dict(screen_velocity=SimpleNamespace(x=math.nan, y=0.0)), "bad_screen_velocity"),
    (dict(status=200), "bad_track_status"),
    (dict(confidence=math.nan), "bad_confidence"),
    (dict(confidence=-0.1), "bad_confidence"),
    (dict(first_seen=_time(STAMP_S + 5)), "bad_track_time"),                  # after the stamp (and last_seen)
    (dict(first_seen=_time(0)), "bad_track_time"),
    (dict(last_seen=_time(STAMP_S, 1_000_000_000)), "bad_track_time"),
    (dict(header=SimpleNamespace(stamp=_time(0))), "bad_track_time"),         # not the array's stamp
    (dict(position_covariance=[math.nan] * 4), "bad_covariance"),             # unknown, yet has_world
    (dict(velocity_covariance=[1.0, math.inf, 0.0, 1.0]), "bad_covariance"),
    (dict(expected_error_m=math.nan), "bad_expected_error"),
])
def test_finding_9_impossible_track_fields_are_refused(bad, kind):
    assert _kinds([_track("T1", **bad), _track("T2")]) == (["T2"], [kind])


def test_the_fuser_does_not_check_the_world_fields_it_fills_in():
    from_tracker = _track(has_world=False, position_covariance=[math.nan, 0.0, 0.0, 1.0], expected_error_m=-5.0)
    assert _kinds([from_tracker], world=False) == (["T1"], [])
    assert _kinds([from_tracker], world=True) == ([], ["bad_covariance"])


@pytest.mark.parametrize("stamp", [_time(0), _time(-100), _time(-1, 500_000_000)])
def test_finding_10_zero_or_negative_stamps_are_refused(stamp):
    refusal = header_refusal(stamp)
    assert refusal.kind == "bad_stamp" and "zero or negative" in refusal.detail


def test_covariance_problem_names_what_is_wrong():
    assert covariance_problem([4.0, 1.0, 1.0, 4.0]) == ""
    assert covariance_problem([0.0] * 4) == ""
    assert covariance_problem([math.nan] * 4, unknown_allowed=True) == ""
    assert "not finite" in covariance_problem([math.nan] * 4)
    assert "3 values" in covariance_problem([1.0, 0.0, 1.0])
    assert "not symmetric" in covariance_problem([4.0, 1.0, 3.0, 4.0], "screen_covariance")
    assert "positive semi-definite" in covariance_problem([-4.0, 0.0, 0.0, 4.0])
