"""Which track is the vessel of interest, online: running scores, online joins and a target held by hysteresis.

The paper scores every trajectory (``vessel_track.trajectory_scoring``) and takes the best one, joining the pieces
of a trajectory cut in the middle; ``vessel_track.offline_selection`` does so over whole recorded trajectories.
Here, frame by frame (``OnlineTargetSelector``): a running score per track, a track that starts where a
just-ended track would be now inherits that track's history (the online join), and the target changes only when
a challenger beats it by a margin for ``switch_hold_s`` seconds, so the vessel of interest does not flip every
frame between two similar tracks. The settings are ``vessel_track.selection_config``.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from vessel_track.selection_config import SelectionConfig
from vessel_track.trajectory_scoring import clipped_log_odds, significant_step


def _continuation_cost(cfg: SelectionConfig, last_position, velocity, gap: float, position, jump: float,
                       jump_gap: float) -> float | None:
    """How well ``position`` continues a track last at ``last_position`` moving at ``velocity`` ``gap`` s ago.

    Mismatch with the extrapolation over the join gate (``join_gate_m + join_gate_range_frac * range +
    join_gate_speed_mps * gap``), 0 for a perfect continuation; None outside the gate or when the ``jump`` from
    the old track's end to the new track's start over ``jump_gap`` s would be faster than ``max_speed_mps``.
    """
    if jump_gap > 0 and jump / jump_gap > cfg.max_speed_mps + cfg.join_gate_m / jump_gap:
        return None
    mismatch = float(np.hypot(*(position - (last_position + velocity * gap))))
    gate = cfg.join_gate_m + cfg.join_gate_range_frac * float(np.hypot(*position)) + cfg.join_gate_speed_mps * gap
    return mismatch / gate if mismatch <= gate else None


@dataclass
class _Running:
    confidences: deque
    confidence_stamps: deque
    path_m: float = 0.0
    last_position: np.ndarray | None = None
    anchor_position: np.ndarray | None = None      # last point counted into the path
    anchor_covariance: np.ndarray | None = None
    first_position: np.ndarray | None = None
    last_stamp: float = math.nan
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    first_stamp: float = math.nan
    eligible: bool = False
    established: bool = False
    inherited_from: str = ""
    excluded_heir: str = ""   # the track that may not take this history back (it moved onto another boat)

    def ages(self, now: float) -> np.ndarray:
        return now - np.fromiter(self.confidence_stamps, float)

    # The latest score with what it was computed from (the confidences object, the path, the settings). Not a field:
    # snapshots leave it out. A score is asked for several times a frame for every running and ended track, and
    # computing it reads the whole history (up to ``history_length``); it changes only when the track is updated.
    _score_memo = None

    def score(self, config: SelectionConfig) -> float:
        memo = self._score_memo
        if memo is None or memo[0] is not self.confidences or memo[1] != self.path_m or memo[2] is not config:
            score = config.trajectory_score(np.fromiter(self.confidences, float), self.path_m)
            memo = self._score_memo = (self.confidences, self.path_m, config, score)
        return memo[3]

    def add_confidence(self, confidence: float, stamp: float) -> None:
        """One more confidence of the track, at ``stamp``."""
        self.confidences.append(confidence)
        self.confidence_stamps.append(stamp)
        self._score_memo = None

    def recent_evidence_ok(self, config: SelectionConfig, now: float) -> bool:
        return config.recent_evidence_ok(np.fromiter(self.confidences, float), self.ages(now))

    def recent_evidence(self, config: SelectionConfig, now: float) -> float:
        return config.recent_evidence(np.fromiter(self.confidences, float), self.ages(now))

    def append_evidence(self, later: _Running) -> None:
        """Add the confidences of a later piece of the same vessel's track after this history's."""
        self.confidences.extend(later.confidences)
        self.confidence_stamps.extend(later.confidence_stamps)
        self._score_memo = None

    def forget_before(self, stamp: float) -> None:
        """Drop the confidences older than ``stamp``: they belong to what the track followed before."""
        keep = [(c, t) for c, t in zip(self.confidences, self.confidence_stamps, strict=True) if t >= stamp]
        self.confidences = deque((c for c, _ in keep), maxlen=self.confidences.maxlen)
        self.confidence_stamps = deque((t for _, t in keep), maxlen=self.confidence_stamps.maxlen)


class OnlineTargetSelector:
    """Running trajectory scores, online joining and a target that changes only for a clear, lasting reason.

    ``update(stamp, world_tracks)`` takes the fuser's ``WorldTrack``s of one frame (anything with
    ``screen.track_id``, ``screen.status``, ``screen.updated``, ``screen.confidence``, ``has_world``,
    ``position``, ``velocity``) and returns the id of the vessel of interest (None if there is none).
    """

    def __init__(self, config: SelectionConfig | None = None):
        self.config = config or SelectionConfig()
        self._running: dict[str, _Running] = {}
        self._ended: dict[str, _Running] = {}
        self.target: str | None = None
        self._challenger: str | None = None
        self._challenger_since: float = math.nan
        self._last_target_ended: str | None = None
        self._lost_score = 0.0
        self._lost_stamp = math.nan
        self._pending_target: str | None = None
        self._dropped_track: str | None = None
        self._dropped_history: str | None = None  # the dropped track's history after an identity change this frame
        self._lost_running: _Running | None = None  # the lost target's history, whoever continues it
        self._present: set[str] = set()  # this frame's running tracks (LOST ones not)
        self.switches = 0
        self.joins = 0
        self.identity_changes = 0
        self.reacquisitions = 0
        #: This frame's continuations, new track id -> the id whose history it took (online joins and handovers):
        #: the fuser continues the world filter with them.
        self.continued: dict[str, str] = {}

    def reset(self) -> None:
        """Forget everything (a replay restarted)."""
        self._running.clear()
        self._ended.clear()
        self.target = None
        self._challenger = None
        self._challenger_since = math.nan
        self._last_target_ended = None
        self._lost_score = 0.0
        self._lost_stamp = math.nan
        self._pending_target = None
        self._dropped_track = None
        self._dropped_history = None
        self._lost_running = None
        self._present = set()
        self.continued = {}

    def score(self, track_id: str) -> float:
        """Current score of a track (0 for an unknown one)."""
        running = self._running.get(track_id) or self._ended.get(track_id)
        return running.score(self.config) if running is not None else 0.0

    def _try_inherit(self, track_id: str, stamp: float, position: np.ndarray,
                     confidence: float = math.nan, first_stamp: float = math.inf) -> _Running | None:
        """An ended track whose extrapolation reaches ``position`` now: its history continues in ``track_id``.

        Only a track that ended before ``track_id`` began (``first_stamp``; two tracks at once are two boats).

        With ``appearance_joins`` (evidence score) a history is only continued by a track whose first box looks
        the same way: one that says the vessel of interest does not take another boat's history, nor the other way.
        """
        best, best_cost = None, math.inf
        cfg = self.config
        looks = 0.0
        if cfg.appearance_joins and cfg.confidence_score == "evidence" and math.isfinite(confidence):
            looks = float(clipped_log_odds([confidence], cfg.evidence_clip)[0])
        for ended_id, ended in self._ended.items():
            gap = stamp - ended.last_stamp
            if not (0 <= gap <= cfg.join_max_gap_s) or ended.last_position is None or ended.excluded_heir == track_id:
                continue
            if not ended.last_stamp < first_stamp:
                continue
            if looks * ended.score(cfg) < 0:
                continue
            jump = float(np.hypot(*(position - ended.last_position)))
            cost = _continuation_cost(cfg, ended.last_position, ended.velocity, gap, position, jump, gap)
            if cost is not None and cost < best_cost:
                best, best_cost = ended_id, cost
        if best is None:
            return None
        inherited = self._ended.pop(best)
        inherited.inherited_from = best
        self.continued[track_id] = best
        self.joins += 1
        if best == self._last_target_ended:
            self._pending_target = track_id  # the vessel of interest is back: it takes over at once
        return inherited

    def update(self, stamp: float, world_tracks) -> str | None:
        """Update the running scores with one frame and return the vessel of interest's track id."""
        self.continued = {}
        present: set[str] = set()
        measured_now: set[str] = set()
        for wt in world_tracks:
            tid = wt.screen.track_id
            if wt.screen.status == 3:  # LOST
                self._end_track(tid, stamp)
                continue
            present.add(tid)
            if self._take_frame(wt, stamp):
                measured_now.add(tid)
        self._end_vanished(present, stamp)
        self._present = present
        if self._dropped_history is not None:
            if self.continued.get(self._dropped_track) != self._dropped_history:
                self._dropped_track = None  # its motion broke and the join did not give the history back
            self._dropped_history = None
        self._handover(stamp, measured_now)
        target = self._choose(stamp)
        if target is not None:
            self._dropped_track = None  # the role is held again: an older drop no longer blocks anyone
        return target

    def _end_track(self, tid: str, stamp: float) -> None:
        """A track reported LOST: its history is kept among the ended ones, which a later track may continue."""
        running = self._running.pop(tid, None)
        if running is not None:
            self._ended[tid] = running
            if tid == self.target:
                self._target_lost(tid, running, stamp)

    def _take_frame(self, wt, stamp: float) -> bool:
        """Add one running track's frame to its history; whether it had a measured position."""
        tid = wt.screen.track_id
        running = self._running.get(tid)
        position = np.asarray(wt.position, dtype=float) if wt.has_world else None
        measured = wt.screen.updated and position is not None and np.all(np.isfinite(position))
        # A track continues an ended one's history from its first box with a position: a track whose first
        # boxes had none (cut by the lens model's edge, above the horizon) may still be the vessel come back.
        if running is None or (measured and running.first_position is None and not running.inherited_from):
            running = self._start_history(wt, running, stamp, position, measured)
        if wt.screen.updated and math.isfinite(wt.screen.confidence):
            running.add_confidence(float(wt.screen.confidence), stamp)
        if measured:
            self._add_position(running, wt, position, stamp)
        running.eligible = bool(wt.has_world)
        running.established = wt.screen.status != 0 or bool(running.inherited_from)
        return bool(measured)

    def _start_history(self, wt, running: _Running | None, stamp: float, position, measured) -> _Running:
        """The history a track goes on with: an ended track's it continues (an online join), else its own."""
        cfg = self.config
        tid = wt.screen.track_id
        inherited = None
        if measured:
            inherited = self._try_inherit(tid, stamp, position,
                                          float(wt.screen.confidence) if wt.screen.updated else math.nan,
                                          running.first_stamp if running is not None else math.inf)
        if inherited is not None and running is not None:
            inherited.append_evidence(running)
        if inherited is not None:
            running = inherited
        elif running is None:
            running = _Running(deque(maxlen=cfg.history_length), deque(maxlen=cfg.history_length),
                               first_stamp=stamp)
        self._running[tid] = running
        return running

    def _add_position(self, running: _Running, wt, position: np.ndarray, stamp: float) -> None:
        """A measured position: the path grows by the significant motion, the latest position and velocity."""
        cfg = self.config
        if running.first_position is None:
            running.first_position = position.copy()
        covariance = getattr(wt, "position_covariance", None)
        covariance = None if covariance is None else np.asarray(covariance, dtype=float)
        if running.anchor_position is None:
            running.anchor_position, running.anchor_covariance = position.copy(), covariance
        else:
            # Significant motion since the last counted point (see path_length_m): position noise
            # (metres per pixel near the horizon) must not add up into a long path.
            step = float(np.hypot(*(position - running.anchor_position)))
            if cfg.path_noise_sigmas > 0 and covariance is not None and \
                    running.anchor_covariance is not None:
                step = significant_step(running.anchor_position, position, running.anchor_covariance,
                                        covariance, cfg.path_noise_sigmas)
            if step > 0 and step >= cfg.min_step_m:
                running.path_m += step
                running.anchor_position, running.anchor_covariance = position.copy(), covariance
        running.last_position = position.copy()
        running.last_stamp = stamp
        velocity = np.asarray(wt.velocity, dtype=float)
        running.velocity = velocity if np.all(np.isfinite(velocity)) else np.zeros(2)

    def _end_vanished(self, present: set[str], stamp: float) -> None:
        """Tracks that vanished without a LOST report count as ended; ended ones too old to join are forgotten."""
        cfg = self.config
        for tid in [t for t in self._running if t not in present]:
            self._ended[tid] = self._running.pop(tid)
            if tid == self.target:
                self._target_lost(tid, self._ended[tid], stamp)
        for tid in [t for t, r in self._ended.items() if not (stamp - r.last_stamp <= cfg.join_max_gap_s)]:
            del self._ended[tid]

    def _appearance_changed(self, track_id: str, stamp: float) -> None:
        """The target's recent boxes say another boat (``recent_evidence_s``).

        Like ``identity_changed``, but the same track may not take the history back: it follows the other boat.
        """
        running = self._running.get(track_id)
        self.identity_changed(track_id, stamp)
        if running is not None:
            running.excluded_heir = track_id
            self._dropped_track = track_id
            self._dropped_history = None

    def identity_changed(self, track_id: str, stamp: float) -> None:
        """The track's world motion stopped fitting its history (its filter restarted after repeated outliers).

        The screen tracker may have moved the track onto another vessel: its history ends here (kept under a new
        name, like a track that ended) and the track starts afresh with the next ``update``, where the online join
        gives the history back if its new position still continues it. If it was the vessel of interest, the
        target is lost: no stand-in takes over unless the join brings the history back.
        """
        running = self._running.pop(track_id, None)
        if running is None:
            return
        self.identity_changes += 1
        key = f"{track_id}~{self.identity_changes}"
        self._ended[key] = running
        if track_id == self._dropped_track:
            self._dropped_history = key  # unless the join gives it straight back, its motion broke: the wait ends
        if track_id == self.target:
            self._target_lost(key, running, stamp)

    def _target_lost(self, tid: str, running: _Running, stamp: float) -> None:
        self._last_target_ended = tid
        self._lost_running = running
        self._lost_score = running.score(self.config)
        self._lost_stamp = stamp
        self.target = None

    def _handover(self, stamp: float, measured_now: set[str]) -> None:
        """Hand the target's role to a new track that continues it (the online counterpart of joining).

        The target coasts while a track started after its last detection is where the target should be: the
        tracker lost the vessel and started a new track on it (a turn between sparse frames). The new track takes
        over the target's history and role at once.
        """
        cfg = self.config
        current = self._running.get(self.target) if self.target is not None else None
        if current is None or self.target in measured_now or current.last_position is None:
            return
        best, best_cost = None, math.inf
        for tid in measured_now:
            candidate = self._running[tid]
            if candidate.inherited_from or not (candidate.first_stamp > current.last_stamp):
                continue
            gap = stamp - current.last_stamp
            if not (0 < gap <= cfg.join_max_gap_s):
                continue
            jump = float(np.hypot(*(candidate.first_position - current.last_position)))
            cost = _continuation_cost(cfg, current.last_position, current.velocity, gap, candidate.last_position,
                                      jump, candidate.first_stamp - current.last_stamp)
            if cost is not None and cost < best_cost:
                best, best_cost = tid, cost
        if best is None:
            return
        candidate = self._running[best]
        merged = _Running(deque(current.confidences, maxlen=cfg.history_length),
                          deque(current.confidence_stamps, maxlen=cfg.history_length))
        merged.append_evidence(candidate)
        candidate.confidences, candidate.confidence_stamps = merged.confidences, merged.confidence_stamps
        candidate.path_m += current.path_m + float(np.hypot(*(candidate.first_position - current.last_position)))
        candidate.inherited_from = self.target
        candidate.established = True
        self.continued[best] = self.target
        del self._running[self.target]
        self.target = best
        self._challenger = None
        self.switches += 1
        self.joins += 1

    def _choose(self, stamp: float) -> str | None:
        """The target after this frame: a pending continuation, a first or re-acquired target, or by hysteresis."""
        cfg = self.config
        scores = self._candidate_scores(stamp)
        if self._pending_target is not None:
            if self._pending_target in scores:
                if self.target != self._pending_target:
                    self.switches += 1
                self.target = self._pending_target
                self._pending_target = None
                self._challenger = None
                return self.target
            if self._pending_target not in self._running:
                self._pending_target = None
        if not scores:
            self._challenger = None
            if self.target in self._running:
                return self.target
            return self._reacquired(stamp) if cfg.reacquire_recent_evidence > 0 else None
        best = max(scores, key=lambda t: (scores[t], t == self.target))
        if self.target is None or self.target not in self._running:
            if stamp - self._lost_stamp <= cfg.reacquire_window_s and \
                    scores[best] < cfg.reacquire_fraction * self._lost_score:
                self.target = None  # the vessel of interest was lost a moment ago: no stand-in for it ...
                # ... unless a track's recent boxes say it is back
                return self._reacquired(stamp) if cfg.reacquire_recent_evidence > 0 else None
            self.target = best
            self._challenger = None
            return self.target
        current = scores.get(self.target, self._running[self.target].score(cfg))
        if not self._running[self.target].established and best != self.target and scores[best] > current:
            self.target = best  # the hold time protects an established target, not a tentative first guess
            self._challenger = None
            self.switches += 1
            return self.target
        if best == self.target or scores[best] <= current * cfg.switch_ratio + cfg.switch_margin:
            self._challenger = None
            return self.target
        if self._challenger != best:
            self._challenger = best
            self._challenger_since = stamp
        if stamp - self._challenger_since >= cfg.switch_hold_s:
            self.target = best
            self._challenger = None
            self.switches += 1
        return self.target

    def _candidate_scores(self, stamp: float) -> dict[str, float]:
        """The scores of the tracks that may be the target now; a target whose boxes or evidence turned is dropped.

        Established (confirmed, or continuing a joined track) candidates first; a tentative track only while there
        is nothing else, and it gives way at once to an established one.
        """
        cfg = self.config
        scores = {tid: r.score(cfg) for tid, r in self._running.items() if r.eligible and r.established}
        if not scores:
            scores = {tid: r.score(cfg) for tid, r in self._running.items() if r.eligible}
        elif self.target in self._running and not self._running[self.target].established:
            self.target = None
        if self.target in self._running and not self._running[self.target].recent_evidence_ok(cfg, stamp):
            self._appearance_changed(self.target, stamp)
        scores = {tid: s for tid, s in scores.items() if tid in self._running and cfg.eligible_score(s)
                  and self._running[tid].recent_evidence_ok(cfg, stamp)}
        if self.target in self._running and not cfg.eligible_score(self._running[self.target].score(cfg)):
            self.target = None  # its evidence turned: another boat, not the vessel of interest
        if self.target is None and self._waiting_for_dropped_track():
            scores = {tid: s for tid, s in scores.items() if self._carries_lost_target(tid)}
        return scores

    def _waiting_for_dropped_track(self) -> bool:
        """``reacquire_waits_for_dropped_track`` holds: the track dropped for its recent boxes still runs."""
        return self.config.reacquire_waits_for_dropped_track and self._dropped_track in self._present

    def _carries_lost_target(self, track_id: str) -> bool:
        """The track dropped from the role, or one continuing the lost target's history (the object is handed down)."""
        running = self._running.get(track_id)
        return track_id == self._dropped_track or (running is not None and running is self._lost_running)

    def _reacquired(self, stamp: float) -> str | None:
        """The established track whose recent boxes say most strongly that the vessel of interest is back.

        Only one whose recent evidence reaches ``reacquire_recent_evidence``. The boxes a track had before it was
        dropped for them (``_appearance_changed``) still count in its window, so the same track cannot take the
        role back until its new boxes outweigh them. A history whose evidence is not positive is dropped before the
        window (it followed another boat); the track must then be eligible as any target is. None: no track.
        """
        cfg = self.config
        evidence = {}
        waiting = self._waiting_for_dropped_track()
        for tid, running in self._running.items():
            if not (running.eligible and running.established and running.last_stamp == stamp):
                continue
            if waiting and not self._carries_lost_target(tid):
                continue
            evidence[tid] = running.recent_evidence(cfg, stamp) + sum(
                ended.recent_evidence(cfg, stamp) for ended in self._ended.values() if ended.excluded_heir == tid)
        for tid in sorted(evidence, key=lambda t: (evidence[t], t), reverse=True):
            if evidence[tid] < cfg.reacquire_recent_evidence:
                break
            running = self._running[tid]
            kept = running.confidences, running.confidence_stamps
            confidences = np.fromiter(running.confidences, float)
            if not float(np.sum(clipped_log_odds(confidences[np.isfinite(confidences)], cfg.evidence_clip))) > 0:
                running.forget_before(stamp - cfg.recent_evidence_s)
            if not (cfg.eligible_score(running.score(cfg)) and running.recent_evidence_ok(cfg, stamp)):
                running.confidences, running.confidence_stamps = kept  # not taken: its history stays whole
                continue
            self.target = tid
            self._challenger = None
            self._pending_target = None
            self._last_target_ended = None
            self.reacquisitions += 1
            return tid
        return None
