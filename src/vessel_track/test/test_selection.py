"""Vessel-of-interest selection: the paper's score, joining, online hysteresis (ROS-free)."""
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_fixtures.presets import paper_selection
from vessel_track.offline_selection import Trajectory, join_trajectories, select_target
from vessel_track.selection import OnlineTargetSelector
from vessel_track.trajectory_scoring import path_length_m, trajectory_score


def test_score_is_the_papers_formula():
    conf = np.linspace(0.1, 1.0, 10)
    assert trajectory_score(conf, 500.0) == pytest.approx(np.percentile(conf, 80) * math.log(500.0))
    assert trajectory_score(conf, 0.3) == 0.0          # does not move: 0, never negative
    assert trajectory_score([], 100.0) == 0.0
    assert path_length_m([[0, 0], [3, 4], [np.nan, 1], [3, 10]]) == pytest.approx(11.0)


def test_evidence_score_accumulates_log_odds_and_prefers_the_steady_track():
    """Evidence: many frames that look like the vessel beat a few that look very much like it."""
    steady = np.full(20, 0.8)                      # log-odds 1.386 each
    brief = np.array([0.999, 0.999, 0.3, 0.3])     # clipped at 4, then -0.847 each
    evidence = paper_selection(confidence_score="evidence", evidence_clip=4.0)
    assert trajectory_score(steady, 500.0, mode="evidence") == pytest.approx(20 * math.log(4.0) * math.log(500.0))
    assert trajectory_score(brief, 500.0, mode="evidence", evidence_clip=4.0) == pytest.approx(
        (8.0 + 2 * math.log(0.3 / 0.7)) * math.log(500.0))
    assert trajectory_score(np.full(5, 0.2), 500.0, mode="evidence") < 0   # looks unlike the vessel: negative
    a = Trajectory("A", np.arange(20) * 4.0, np.column_stack([np.arange(20) * 8.0, np.zeros(20)]), steady)
    b = Trajectory("B", np.arange(4) * 4.0, np.column_stack([np.arange(4) * 50.0, np.ones(4) * 500]), brief)
    assert a.score(evidence) > b.score(evidence)
    # The paper's 80th percentile would prefer the brief one.
    assert b.score(paper_selection(confidence_percentile=80)) > a.score(paper_selection(confidence_percentile=80))


def test_path_log_floor_lets_confidence_rank_tracks_that_have_not_moved():
    assert trajectory_score([0.9], 0.5) == 0.0 == trajectory_score([0.3], 0.5)
    assert trajectory_score([0.9], 0.5, path_log_floor=1.0) > trajectory_score([0.3], 0.5, path_log_floor=1.0)
    assert trajectory_score([0.9], 500.0, path_log_floor=1.0) == pytest.approx(0.9 * math.log(500.0))
    with pytest.raises(DataError, match="path_log_floor"):
        paper_selection(path_log_floor=-1.0)


def _line(tid, t0, t1, start, velocity, conf=0.8, dt=4.0):
    t = np.arange(t0, t1 + 1e-9, dt)
    pos = np.asarray(start, float) + np.outer(t - t0, velocity)
    return Trajectory(tid, t, pos, np.full(t.size, conf))


def test_a_trajectory_cut_in_the_middle_is_joined_and_wins():
    vessel_a = _line("A", 0, 60, [100, 0], [2.0, 1.0])
    vessel_b = _line("B", 72, 140, [100 + 2 * 72, 72], [2.0, 1.0])       # same vessel after a 12 s gap
    sailboat = _line("S", 0, 140, [-200, 400], [1.0, 0.0], conf=0.9)       # longer alone, elsewhere
    post = _line("P", 0, 140, [20, -5], [0.0, 0.0], conf=0.95)            # the mooring post: never moves
    unrelated = _line("U", 80, 140, [600, -300], [-1.0, 0.0])              # starts far from A's end
    chains = join_trajectories([vessel_a, vessel_b, sailboat, post, unrelated])
    members = sorted(sorted(c.members) for c in chains)
    assert ["A", "B"] in members and ["U"] in members
    best, scored = select_target([vessel_a, vessel_b, sailboat, post, unrelated], paper_selection())
    assert best.members == ["A", "B"]
    assert dict((c.track_id, s) for c, s in scored)["P"] == 0.0
    # Without joining, the sailboat's single long trajectory would have won.
    best_unjoined, _ = select_target([vessel_a, vessel_b, sailboat, post, unrelated], paper_selection(), join=False)
    assert best_unjoined.track_id == "S"


def test_overlapping_or_distant_pieces_are_not_joined():
    a = _line("A", 0, 60, [100, 0], [2.0, 1.0])
    overlapping = _line("O", 40, 100, [180, 40], [2.0, 1.0])
    assert len(join_trajectories([a, overlapping])) == 2
    assert len(join_trajectories([a, overlapping], paper_selection(join_max_overlap_s=25.0))) == 1
    late = _line("L", 200, 260, [500, 200], [2.0, 1.0])
    assert len(join_trajectories([a, late])) == 2
    with pytest.raises(DataError):
        Trajectory("x", [], np.zeros((0, 2)), [])


def _wt(tid, pos, conf=0.8, status=1, updated=True, velocity=(0.0, 0.0)):
    return SimpleNamespace(screen=SimpleNamespace(track_id=tid, status=status, updated=updated, confidence=conf),
                           has_world=True, position=np.asarray(pos, float), velocity=np.asarray(velocity, float))


def test_online_selection_has_hysteresis():
    selector = OnlineTargetSelector(paper_selection(switch_ratio=1.2, switch_margin=0.5, switch_hold_s=8.0))
    # Two similar vessels: the first chosen stays chosen while the other is only slightly better.
    targets = []
    for k in range(30):
        t = 4.0 * k
        targets.append(selector.update(t, [_wt("A", [100 + 2.0 * t, 0], velocity=(2.0, 0)),
                                           _wt("B", [0, 100 + 2.1 * t], velocity=(0, 2.1))]))
    assert set(targets) == {"A"} and selector.switches == 0
    # A stops, B becomes clearly better (fast, confident): it takes over, but only after the hold time.
    switched_at, ahead_since = None, None
    for k in range(30, 80):
        t = 4.0 * k
        target = selector.update(t, [_wt("A", [332, 0]),
                                     _wt("B", [0, 343.6 + 20.0 * (t - 116)], conf=0.95, velocity=(0, 20.0))])
        if ahead_since is None and selector.score("B") > 1.2 * selector.score("A") + 0.5:
            ahead_since = t
        if target == "B" and switched_at is None:
            switched_at = t
    assert switched_at is not None and selector.switches == 1
    assert switched_at - ahead_since >= 8.0


def test_online_evidence_leaves_a_first_track_that_looks_unlike_the_vessel():
    """Video 11's start: the first of two tracks that have not moved yet looks less like the vessel.

    Confidences 0.8 against 0.99. The paper's score is 0 for both and keeps the first; the evidence score with a
    path floor hands over after the hold time.
    """
    def run(config):
        selector = OnlineTargetSelector(config)
        targets = []
        for k in range(12):
            tracks = [_wt("A", [340, 50], conf=0.8)]
            if k >= 1:
                tracks.append(_wt("B", [260, -48], conf=0.99))
            targets.append(selector.update(4.0 * k, tracks))
        return targets

    assert set(run(paper_selection())) == {"A"}
    targets = run(paper_selection(confidence_score="evidence", path_log_floor=1.0, switch_hold_s=8.0))
    assert targets[0] == "A" and targets[-1] == "B"
    assert targets.index("B") >= 3                      # not before the hold time


def test_online_join_keeps_the_target_through_a_new_track_id():
    selector = OnlineTargetSelector(paper_selection())
    for k in range(10):
        selector.update(4.0 * k, [_wt("A", [100 + 8.0 * k, 50], velocity=(2.0, 0)),
                                  _wt("S", [-300, 300 + 0.4 * k], conf=0.6, velocity=(0, 0.1))])
    assert selector.target == "A"
    selector.update(40.0, [_wt("A", [180, 50], status=3), _wt("S", [-300, 304], conf=0.6)])
    # The vessel reappears as a new, still tentative track where A would be now.
    target = selector.update(48.0, [_wt("C", [196, 50], status=0, velocity=(2.0, 0)),
                                    _wt("S", [-300, 304.4], conf=0.6, velocity=(0, 0.1))])
    assert target == "C" and selector.joins == 1
    assert selector.score("C") > selector.score("S") > 0


def _no_world(tid, conf=0.8, status=0):
    """A track whose box gave no sea position this frame (cut at the lens model's edge, above the horizon)."""
    return SimpleNamespace(screen=SimpleNamespace(track_id=tid, status=status, updated=True, confidence=conf),
                           has_world=False, position=np.full(2, np.nan), velocity=np.full(2, np.nan))


def test_a_track_whose_first_box_had_no_position_continues_the_lost_history():
    """The vessel comes back at the image edge: its new track's first box has no position, its second does."""
    config = paper_selection(reacquire_window_s=3600.0)
    selector = OnlineTargetSelector(config)
    for k in range(10):
        selector.update(4.0 * k, [_wt("A", [100 + 8.0 * k, 50], velocity=(2.0, 0)),
                                  _wt("S", [-300, 300], conf=0.6)])
    assert selector.target == "A"
    selector.update(40.0, [_wt("A", [180, 50], status=3), _wt("S", [-300, 300], conf=0.6)])
    assert selector.update(44.0, [_no_world("C"), _wt("S", [-300, 300], conf=0.6)]) is None
    target = selector.update(48.0, [_wt("C", [196, 50], status=0, velocity=(2.0, 0)),
                                    _wt("S", [-300, 300], conf=0.6)])
    assert target == "C" and selector.continued == {"C": "A"} and selector.joins == 1
    assert selector.score("C") > selector.score("S")


def test_a_track_that_ran_beside_the_ended_one_does_not_take_its_history():
    """Two tracks at the same time are two boats, whatever the positions say later."""
    selector = OnlineTargetSelector(paper_selection(reacquire_window_s=3600.0))
    for k in range(10):
        selector.update(4.0 * k, [_wt("A", [100 + 8.0 * k, 50], velocity=(2.0, 0)), _no_world("C")])
    selector.update(40.0, [_wt("A", [180, 50], status=3), _no_world("C")])
    target = selector.update(44.0, [_wt("C", [188, 50], status=1, velocity=(2.0, 0))])
    assert selector.continued == {} and selector.joins == 0
    assert target is None  # the wait for the lost vessel holds: no stand-in


def test_tentative_target_only_while_nothing_established():
    selector = OnlineTargetSelector(paper_selection())
    assert selector.update(0.0, [_wt("T", [100, 0], status=0)]) == "T"
    assert selector.update(4.0, [_wt("T", [104, 0], status=0), _wt("E", [0, 100], status=1)]) == "E"
    assert selector.update(8.0, []) is None


def test_config_validation():
    with pytest.raises(DataError):
        paper_selection(switch_ratio=0.5)
    with pytest.raises(DataError):
        paper_selection(confidence_percentile=120)
    with pytest.raises(DataError, match="confidence_score"):
        paper_selection(confidence_score="mean")
    with pytest.raises(DataError, match="evidence_clip"):
        paper_selection(evidence_clip=0.0)


def test_handover_to_a_new_track_while_the_target_coasts():
    selector = OnlineTargetSelector(paper_selection())
    for k in range(8):
        selector.update(4.0 * k, [_wt("A", [100 + 8.0 * k, 50], velocity=(2.0, 0))])
    assert selector.target == "A"
    # The tracker lost the vessel in a turn: A coasts on, a new tentative track B starts where the vessel is.
    target = selector.update(32.0, [_wt("A", [164, 50], status=2, updated=False, velocity=(2.0, 0)),
                                    _wt("B", [166, 58], status=0, velocity=(0.0, 0.0))])
    assert target == "B" and selector.joins == 1
    # Far from where A should be: no handover.
    selector2 = OnlineTargetSelector(paper_selection())
    for k in range(8):
        selector2.update(4.0 * k, [_wt("A", [100 + 8.0 * k, 50], velocity=(2.0, 0))])
    target = selector2.update(32.0, [_wt("A", [164, 50], status=2, updated=False, velocity=(2.0, 0)),
                                     _wt("B", [400, -300], status=0)])
    assert target == "A"


def test_no_stand_in_right_after_the_target_is_lost():
    selector = OnlineTargetSelector(paper_selection(reacquire_fraction=0.9, join_max_gap_s=30.0))
    for k in range(20):
        selector.update(4.0 * k, [_wt("A", [100 + 12.0 * k, 50], velocity=(3.0, 0)),
                                  _wt("S", [-300, 300 + 0.4 * k], conf=0.6, velocity=(0, 0.1))])
    assert selector.target == "A"
    assert selector.update(80.0, [_wt("A", [340, 50], status=3), _wt("S", [-300, 308], conf=0.6)]) is None
    assert selector.update(100.0, [_wt("S", [-300, 310], conf=0.6, velocity=(0, 0.1))]) is None
    # Long after the loss, the best remaining vessel is the target again.
    assert selector.update(120.0, [_wt("S", [-300, 312], conf=0.6, velocity=(0, 0.1))]) == "S"


def test_a_long_reacquire_window_never_puts_a_stand_in_in_the_lost_targets_place():
    """Video 17: the vessel runs off beyond detection; another boat is not published as the vessel."""
    selector = OnlineTargetSelector(paper_selection(reacquire_fraction=0.9, join_max_gap_s=30.0,
                                                    reacquire_window_s=3600.0))
    for k in range(20):
        selector.update(4.0 * k, [_wt("A", [100 + 12.0 * k, 50], velocity=(3.0, 0)),
                                  _wt("S", [-300, 300 + 0.4 * k], conf=0.6, velocity=(0, 0.1))])
    selector.update(80.0, [_wt("A", [340, 50], status=3), _wt("S", [-300, 308], conf=0.6)])
    assert selector.update(120.0, [_wt("S", [-300, 312], conf=0.6, velocity=(0, 0.1))]) is None
    assert selector.update(2000.0, [_wt("S", [-300, 312], conf=0.6, velocity=(0, 0.1))]) is None
    # A vessel that earns the lost target's share of the score does take over.
    for k in range(60):
        target = selector.update(2004.0 + 4.0 * k, [_wt("B", [100 + 12.0 * k, -50], conf=0.95, velocity=(3.0, 0))])
    assert target == "B"
    with pytest.raises(DataError, match="reacquire_window_s"):
        paper_selection(reacquire_window_s=-1.0)


def test_identity_change_ends_the_targets_history_and_a_join_can_give_it_back():
    """The target's world filter stopped fitting it: its history ends; it comes back only through a join."""
    def warmed_up():
        selector = OnlineTargetSelector(paper_selection(reacquire_window_s=3600.0))
        for k in range(10):
            selector.update(4.0 * k, [_wt("A", [100 + 8.0 * k, 50], velocity=(2.0, 0)),
                                      _wt("S", [-300, 300], conf=0.6)])
        assert selector.target == "A"
        return selector

    # The track now follows another boat, far from where the vessel would be: no target, no stand-in.
    selector = warmed_up()
    score_before = selector.score("A")
    selector.identity_changed("A", 40.0)
    target = selector.update(40.0, [_wt("A", [-100, 400]), _wt("S", [-300, 300], conf=0.6)])
    assert target is None and selector.identity_changes == 1
    assert selector.score("A") < score_before
    # Unknown tracks are ignored.
    selector.identity_changed("nobody", 40.0)
    assert selector.identity_changes == 1

    # A bias, not another boat: the new position still continues the history, which the join gives back.
    selector = warmed_up()
    selector.identity_changed("A", 40.0)
    target = selector.update(40.0, [_wt("A", [185, 52], velocity=(2.0, 0)), _wt("S", [-300, 300], conf=0.6)])
    assert target == "A" and selector.continued == {"A": "A~1"}
    assert selector.score("A") >= score_before


def test_continued_names_this_frames_joins_and_handovers():
    selector = OnlineTargetSelector(paper_selection())
    for k in range(8):
        selector.update(4.0 * k, [_wt("A", [100 + 8.0 * k, 50], velocity=(2.0, 0))])
    assert selector.continued == {}
    selector.update(32.0, [_wt("A", [164, 50], status=2, updated=False, velocity=(2.0, 0)),
                           _wt("B", [166, 58], status=0)])
    assert selector.continued == {"B": "A"}
    selector.update(36.0, [_wt("B", [170, 58], status=0)])
    assert selector.continued == {}


def test_a_tentative_first_guess_gives_way_at_once_to_a_likelier_track():
    """Video 11's start: both tracks are still tentative; the hold time protects established targets only."""
    config = paper_selection(confidence_score="evidence", path_log_floor=1.0, switch_hold_s=8.0)
    selector = OnlineTargetSelector(config)
    first = selector.update(0.0, [_wt("A", [340, 50], conf=0.93, status=0), _wt("B", [290, -48], conf=0.9, status=0)])
    assert first == "A"
    second = selector.update(4.0, [_wt("A", [340, 50], conf=0.7, status=0), _wt("B", [290, -48], conf=0.99, status=0)])
    assert second == "B" and selector.switches == 1
    # Once established, the same change of fortunes waits for the hold time.
    selector = OnlineTargetSelector(config)
    assert selector.update(0.0, [_wt("A", [340, 50], conf=0.93), _wt("B", [290, -48], conf=0.9)]) == "A"
    assert selector.update(4.0, [_wt("A", [340, 50], conf=0.7), _wt("B", [290, -48], conf=0.99)]) == "A"


def test_a_boat_the_detector_calls_unlikely_is_never_the_target_with_positive_evidence_only():
    unlikely = np.full(10, 0.05)
    other = Trajectory("B", np.arange(10) * 4.0, np.column_stack([np.arange(10) * 20.0, np.zeros(10)]), unlikely)
    config = paper_selection(confidence_score="evidence", path_log_floor=1.0)
    assert select_target([other], config)[0] is other  # the best there is, however unlikely
    strict = paper_selection(confidence_score="evidence", path_log_floor=1.0, positive_evidence_only=True)
    assert select_target([other], strict)[0] is None
    selector = OnlineTargetSelector(strict)
    published = [selector.update(4.0 * k, [_wt("B", [20.0 * k, 0], conf=0.05)]) for k in range(6)]
    assert published == [None] * 6
    # The vessel (likely) becomes the target; when its evidence turns negative it is dropped.
    selector = OnlineTargetSelector(strict)
    assert [selector.update(4.0 * k, [_wt("A", [10.0 * k, 0], conf=0.9)]) for k in range(3)][-1] == "A"
    for k in range(3, 12):
        last = selector.update(4.0 * k, [_wt("A", [10.0 * k, 0], conf=0.02)])
    assert last is None


def _evidence_config(**kw):
    return paper_selection(confidence_score="evidence", path_log_floor=1.0, positive_evidence_only=True,
                           reacquire_window_s=3600.0, **kw)


def _followed_then_swapped(config):
    """A follows the vessel for 40 s, then the screen tracker moves it onto another boat beside it (low p)."""
    selector = OnlineTargetSelector(config)
    for k in range(10):
        selector.update(4.0 * k, [_wt("A", [100 + 8.0 * k, 50], conf=0.8, velocity=(2.0, 0))])
    assert selector.target == "A"
    published = [selector.update(4.0 * k, [_wt("A", [180 + 2.0 * (k - 10), 60], conf=0.05, velocity=(0.5, 0))])
                 for k in range(10, 13)]
    return selector, published


def test_a_target_whose_recent_boxes_say_another_boat_loses_the_role():
    """Video 12's far turn: without the recent-evidence rule the long history keeps the swapped track published."""
    _, kept = _followed_then_swapped(_evidence_config())
    assert kept == ["A", "A", "A"]
    selector, published = _followed_then_swapped(_evidence_config(recent_evidence_s=8.0))
    assert published[-1] is None and selector.identity_changes == 1
    # The same track, on the other boat, does not take the vessel's history back ...
    assert selector.update(52.0, [_wt("A", [182, 60], conf=0.05, velocity=(0.5, 0))]) is None
    # ... but a new track where the vessel goes on does.
    target = selector.update(56.0, [_wt("A", [183, 60], conf=0.05), _wt("V", [228, 50], conf=0.8, velocity=(2.0, 0))])
    assert target == "V" and selector.continued == {"V": "A~1"}


@pytest.mark.parametrize("value", [-1.0, math.nan, math.inf])
def test_the_recent_evidence_window_is_validated(value):
    with pytest.raises(DataError, match="recent_evidence_s"):
        paper_selection(recent_evidence_s=value)


def test_a_history_is_continued_only_by_a_track_that_looks_the_same_way():
    """A vessel's new track must not take the negative history of another boat that ended beside it.

    Video 12 of training: without the rule the vessel's new track took that boat's history and could not become
    the target for a minute.
    """
    def after_the_other_boat_ended(appearance_joins):
        selector = OnlineTargetSelector(_evidence_config(appearance_joins=appearance_joins))
        for k in range(8):
            selector.update(4.0 * k, [_wt("B", [200 + 5.0 * k, 60], conf=0.02, velocity=(1.25, 0))])
        selector.update(32.0, [_wt("B", [240, 60], status=3)])  # B ends (LOST)
        target = selector.update(36.0, [_wt("V", [246, 60], conf=0.8)])  # the vessel, right where B would be
        return selector, target

    joined, target = after_the_other_boat_ended(False)
    assert joined.continued == {"V": "B"} and target is None  # it inherited B's -32 of evidence
    kept_apart, target = after_the_other_boat_ended(True)
    assert kept_apart.continued == {} and target == "V"


def _swapped_then_back(config):
    """A follows the vessel, is moved onto another boat (the target is dropped), and then follows the vessel again.

    Video 10 of training: the same track came back onto the vessel, its boxes said so again, but its history
    (the other boat) kept it from being the target, and NO_FIX was published for the rest of the pass.
    """
    selector, _ = _followed_then_swapped(config)
    assert selector.target is None
    published = []
    for k in range(13, 20):
        published.append(selector.update(4.0 * k, [_wt("A", [180 + 8.0 * (k - 12), 50], conf=0.8, velocity=(2.0, 0)),
                                                   _wt("B", [100, -80], conf=0.3)]))
    return selector, published


def test_a_track_whose_recent_boxes_say_the_vessel_again_takes_the_role_back():
    _, without = _swapped_then_back(_evidence_config(recent_evidence_s=8.0))
    assert without == [None] * 7  # the lost target's share of evidence is never reached
    selector, published = _swapped_then_back(_evidence_config(recent_evidence_s=8.0, reacquire_recent_evidence=2.0))
    # A box at p 0.8 is +1.39 of log-odds, one at p 0.05 -2.94; the window (8 s, both ends counted) still
    # holds a box of the other boat at the second frame, and none at the third, which brings the role back.
    assert published[:2] == [None, None] and published[2:] == ["A"] * 5
    assert selector.reacquisitions == 1 and selector.switches == 0
    # A boat whose boxes never say the vessel is never taken, however long it is tracked.
    assert "B" not in published


def test_reacquisition_drops_only_a_history_that_says_another_boat():
    config = _evidence_config(recent_evidence_s=8.0, reacquire_recent_evidence=2.0)
    selector = OnlineTargetSelector(config)
    for k in range(6):  # C follows another boat: negative evidence
        selector.update(4.0 * k, [_wt("C", [300 + 4.0 * k, 0], conf=0.05, velocity=(1.0, 0))])
    assert selector.target is None and selector.score("C") < 0
    targets = [selector.update(4.0 * k, [_wt("C", [300 + 4.0 * k, 0], conf=0.9, velocity=(1.0, 0))])
               for k in range(6, 9)]
    assert targets == [None, None, "C"] and selector.score("C") > 0  # its earlier history is gone
    assert selector.update(36.0, [_wt("C", [336, 0], conf=0.9, velocity=(1.0, 0))]) == "C"  # and it stays the target
    # A history that says the vessel is kept: D had boxes at p 0.6 while A was the target, too little to stand in
    # for A when A ended; its next boxes at p 0.9 bring the role, and its older boxes still count.
    selector = OnlineTargetSelector(config)
    for k in range(10):
        selector.update(4.0 * k, [_wt("A", [100 + 8.0 * k, 50], conf=0.9, velocity=(2.0, 0)),
                                  _wt("D", [300 + 4.0 * k, 0], conf=0.6, velocity=(1.0, 0))])
    assert selector.target == "A"
    target = selector.update(40.0, [_wt("A", [180, 50], status=3), _wt("D", [340, 0], conf=0.6, velocity=(1.0, 0))])
    assert target is None  # D has not a tenth of A's score: no stand-in
    target = selector.update(44.0, [_wt("D", [344, 0], conf=0.9, velocity=(1.0, 0))])
    assert target == "D" and selector.reacquisitions == 1
    assert len(selector._running["D"].confidences) == 12  # nothing forgotten


def test_the_track_dropped_for_its_boxes_does_not_take_the_role_back_with_one_good_box():
    """The boxes that made the target lose the role still count in the window of the same track."""
    config = _evidence_config(recent_evidence_s=8.0, reacquire_recent_evidence=2.0)
    selector = OnlineTargetSelector(config)
    for k in range(10):
        selector.update(4.0 * k, [_wt("A", [100 + 8.0 * k, 50], conf=0.8, velocity=(2.0, 0))])
    published = [selector.update(4.0 * k, [_wt("A", [100 + 8.0 * k, 50], conf=c, velocity=(2.0, 0))])
                 for k, c in ((10, 0.05), (11, 0.9), (12, 0.9), (13, 0.9))]
    # t 40: dropped. t 44: +2.20 (p 0.9) against -2.94 (p 0.05) and +1.39 (p 0.8) still in the 8 s; t 48: +4.39
    # against -2.94; t 52: the p 0.05 box is out of the window.
    assert published == [None, None, None, "A"] and selector.reacquisitions == 1


def test_a_reacquired_track_must_be_eligible_as_any_target():
    """With the paper's path factor (floor 0) a track that has not moved scores 0: never a target, never retaken."""
    config = paper_selection(confidence_score="evidence", positive_evidence_only=True, recent_evidence_s=8.0,
                             reacquire_recent_evidence=2.0)
    selector = OnlineTargetSelector(config)
    published = [selector.update(4.0 * k, [_wt("S", [300, 0], conf=0.95)]) for k in range(6)]
    assert published == [None] * 6 and selector.reacquisitions == 0
    # A track not taken keeps its whole history, even one that would have been dropped had it been taken.
    selector = OnlineTargetSelector(config)
    for k, c in enumerate((0.05, 0.05, 0.05, 0.95, 0.95, 0.95)):
        assert selector.update(4.0 * k, [_wt("S", [300, 0], conf=c)]) is None
    assert len(selector._running["S"].confidences) == 6


@pytest.mark.parametrize("value", [-1.0, math.nan, math.inf, "2"])
def test_reacquire_recent_evidence_is_validated(value):
    with pytest.raises(DataError, match="reacquire_recent_evidence"):
        _evidence_config(recent_evidence_s=8.0, reacquire_recent_evidence=value)


def test_reacquire_recent_evidence_needs_its_window():
    with pytest.raises(DataError, match="recent_evidence_s > 0"):
        _evidence_config(reacquire_recent_evidence=2.0)
    with pytest.raises(DataError, match="confidence_score: evidence"):
        paper_selection(recent_evidence_s=8.0, reacquire_recent_evidence=2.0)


def _far_vessel_judged_another_boat(config):
    """A follows the vessel; far out, the detector calls it another boat while B, a nearer boat, looks like it.

    Video 11 of training with a model that never saw it: the nearer boat was taken as the vessel for ten frames.
    Frames every 4 s: A at p 0.8 (k 0-9), p 0.02 (k 10-13), then p 0.9 again (k 14-17); B at p 0.8 from k 8.
    """
    selector = OnlineTargetSelector(config)
    published = []
    for k in range(18):
        conf_a = 0.8 if k < 10 else 0.02 if k < 14 else 0.9
        tracks = [_wt("A", [100 + 8.0 * k, 50], conf=conf_a, velocity=(2.0, 0))]
        if k >= 8:
            tracks.append(_wt("B", [60, -40 + 2.0 * k], conf=0.8, velocity=(0, 0.5)))
        published.append(selector.update(4.0 * k, tracks))
    return selector, published


def test_while_the_dropped_track_runs_no_other_boat_takes_the_role():
    config = _evidence_config(recent_evidence_s=8.0, reacquire_recent_evidence=2.0)
    _, without = _far_vessel_judged_another_boat(config)
    assert without[:10] == ["A"] * 10 and without[10:] == ["B"] * 8
    selector, published = _far_vessel_judged_another_boat(replace(config, reacquire_waits_for_dropped_track=True))
    # t 40: A's 8 s window sums to 2 x 1.39 - 3.89 < 0, it is dropped; B's boxes would reacquire the role, but A
    # still runs: NO_FIX until A's own boxes of the window say the vessel again (t 64: 3 x 2.20).
    assert published[:10] == ["A"] * 10 and published[10:16] == [None] * 6 and published[16:] == ["A", "A"]
    assert selector.reacquisitions == 1
    # Once the vessel's track has ended, the rule no longer holds: B's boxes bring it the role.
    assert selector.update(72.0, [_wt("A", [236, 50], status=3), _wt("B", [60, -4], conf=0.8)]) == "B"


def test_a_track_that_continues_the_dropped_targets_history_may_take_the_role():
    """Video 12 of training: the dropped track lived on beside a new track that continued the vessel's history."""
    config = _evidence_config(recent_evidence_s=8.0, reacquire_recent_evidence=2.0,
                              reacquire_waits_for_dropped_track=True)
    selector, published = _followed_then_swapped(config)
    assert published[-1] is None and selector._dropped_track == "A"
    target = selector.update(56.0, [_wt("A", [183, 60], conf=0.05), _wt("V", [228, 50], conf=0.8, velocity=(2.0, 0))])
    assert target == "V" and selector.continued == {"V": "A~1"}


def test_the_lost_history_handed_down_twice_still_may_take_the_role():
    """V continues the dropped target's history without winning the role, V ends, W continues V: W carries it."""
    config = _evidence_config(recent_evidence_s=8.0, reacquire_recent_evidence=2.0,
                              reacquire_waits_for_dropped_track=True)
    selector, _ = _followed_then_swapped(config)
    selector.update(52.0, [_wt("A", [182, 60], conf=0.05), _wt("V", [228, 50], conf=0.3, velocity=(2.0, 0))])
    assert selector.continued == {"V": "A~1"} and selector.target is None
    selector.update(56.0, [_wt("A", [183, 60], conf=0.05), _wt("V", [236, 50], status=3)])
    published = [selector.update(4.0 * k, [_wt("A", [184, 60], conf=0.05),
                                           _wt("W", [236 + 8.0 * (k - 14), 50], conf=0.9, velocity=(2.0, 0))])
                 for k in range(15, 19)]
    assert selector.joins >= 2 and published[-1] == "W"


def test_the_wait_holds_through_an_identity_change_the_join_undoes():
    """A far track's filter may restart (noisy range) and the join give it its history back: it is still A."""
    config = _evidence_config(recent_evidence_s=8.0, reacquire_recent_evidence=2.0,
                              reacquire_waits_for_dropped_track=True)
    selector = OnlineTargetSelector(config)
    published = []
    for k in range(18):
        conf_a = 0.8 if k < 10 else 0.02 if k < 14 else 0.9
        if k == 12:
            selector.identity_changed("A", 4.0 * k)
        tracks = [_wt("A", [100 + 8.0 * k, 50], conf=conf_a, velocity=(2.0, 0))]
        if k >= 8:
            tracks.append(_wt("B", [60, -40 + 2.0 * k], conf=0.8, velocity=(0, 0.5)))
        published.append(selector.update(4.0 * k, tracks))
    assert "B" not in published and published[10:14] == [None] * 4


def test_reacquire_waits_for_dropped_track_needs_the_recent_evidence_rule():
    with pytest.raises(DataError, match="reacquire_waits_for_dropped_track"):
        _evidence_config(reacquire_waits_for_dropped_track=True)
