"""Which track is the vessel of interest: the paper's trajectory score, trajectory joining, hysteresis.

The paper scores every trajectory as ``score = c_0.8 * log(l)``: the 80th percentile of the detector
confidences of its points times the log of its path length in metres on the sea plane, and takes the best
one; a trajectory cut in the middle (a missed stretch, an occlusion) is joined with the pieces before and
after it by their timestamps. Both exist here twice:

* offline (``join_trajectories``, ``select_target``): for recorded data, over whole trajectories; pieces are
  joined when they do not overlap in time (beyond ``max_overlap_s``), the gap is short, and the end of one
  extrapolated to the start of the next lands within a gate;
* online (``OnlineTargetSelector``): a running score per track, a track that starts where a just-ended
  track would be now inherits that track's history (the online join), and the target changes only when a
  challenger beats it by a margin for ``switch_hold_s`` seconds, so the vessel of interest does not flip
  every frame between two similar tracks.

Path length uses ``log(max(l, 1 m))``, so a trajectory that does not move (a mooring post detected as a
boat) scores 0 rather than a negative number. The length is measured on filtered positions (online: the world
filter's; offline: the smoothed trajectory), and only motion that stands out of the position covariance counts
(``path_noise_sigmas``): the noise of per-frame positions (metres to hundreds of metres per pixel near the
horizon) would otherwise make up most of the length of a distant vessel's path and of a standing object's.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from vessel_common.errors import DataError
from vessel_track.deferred_imports import linear_sum_assignment

_FORBIDDEN = 1e9
CONFIDENCE_SCORES = ("percentile", "evidence")


@dataclass(frozen=True)
class SelectionConfig:
    """Parameters of the trajectory score, the joining and the online hysteresis.

    confidence_percentile: percentile of the detector confidences in the score (the paper: 80). 50 (the median)
        by default: chosen on training videos 7-12 with the appearance cue as confidence
        (``vessel_tools.track.appearance``), where a track that swapped onto the vessel of interest for a few frames
        must not inherit its high confidences.
    min_step_m: path steps shorter than this are not added (filters jitter of a standing object).
    path_noise_sigmas: a path step counts once the displacement from the last counted point exceeds this many
        standard deviations of it (from the position covariances), so position noise does not count as travel
        while slow steady motion still adds up (0: the paper's plain length).
    join_max_gap_s: longest time between the end of one piece and the start of the next to join them.
    join_max_overlap_s: pieces may overlap this long (a track coasting on while its successor starts).
    join_gate_m, join_gate_range_frac, join_gate_speed_mps: the gate around the extrapolated end:
        gate = join_gate_m + join_gate_range_frac * range + join_gate_speed_mps * gap.
    max_speed_mps: a join implying a faster motion is refused.
    switch_ratio, switch_margin: a challenger must score above ``current * ratio + margin`` ...
    switch_hold_s: ... for this long before it becomes the target. The hysteresis holds an established target;
        a target that is still tentative (the first guess at the start) gives way at once to any better score.
    reacquire_fraction: for ``reacquire_window_s`` after the target's track ended, another track becomes the target
        only with at least this share of the lost target's score (so a sailboat does not inherit the role the
        moment the vessel of interest leaves the view; the vessel itself is re-acquired by joining).
    reacquire_window_s: how long that rule holds (default 30 s, the join gap). Long (the challenge config: an
        hour) means no stand-in: the GPS publisher sends NO_FIX rather than another boat as the vessel of interest
        until a track has earned the lost one's share of evidence.
    history_length: confidences kept per track for the percentile.
    confidence_score: how a trajectory's confidences enter its score: ``percentile`` (the paper's
        ``confidence_percentile`` of them) or ``evidence``, the sum of their log-odds ``log(c / (1 - c))``, each
        clipped to +-``evidence_clip``. With confidences that are probabilities of being the vessel of interest
        (the appearance cue with ``appearance_combine: replace``) evidence accumulates with every frame that
        looks like the vessel and drains with every frame that does not, so a track that swapped onto the
        vessel for a few frames does not overtake the one that has followed it all along.
    evidence_clip: bound of one confidence's log-odds in the ``evidence`` score.
    positive_evidence_only: with the ``evidence`` score, a track becomes (or stays) the target only while its
        evidence is positive: its detections say it is more likely the vessel of interest than not. For a
        detector that tracks every vessel and gives each its probability of being the target, where a track of
        another boat scores below zero and must never be published as the vessel, however it ranks.
    recent_evidence_s: with the ``evidence`` score, a track whose confidences of the last ``recent_evidence_s``
        seconds (at least its newest one) sum to non-positive (clipped) log-odds may not be (or stay) the target,
        however much evidence it gathered before (0: off). The screen tracker can move a track that followed the
        vessel of interest onto another boat; its long history would keep it the target while its boxes now say
        it is not the vessel. Online only: the offline pass scores whole trajectories.
    reacquire_recent_evidence: with ``recent_evidence_s``, where the other rules leave no target (no eligible
        track, or none with ``reacquire_fraction`` of the lost target's score), a track whose confidences of the
        last ``recent_evidence_s`` seconds sum to at least this many (clipped) log-odds becomes the target (0: off).
        The network's recent boxes are the evidence that the vessel of interest is back, on a new track or on one
        that followed another boat before; a history whose evidence is not positive is dropped, as at an identity
        change. A track dropped for its recent boxes counts them still. Online only.
    reacquire_waits_for_dropped_track: with ``recent_evidence_s``, while the track that was dropped from the role
        for its recent boxes still runs, only a track that carries the lost target's history may take the role:
        that track itself (by ``reacquire_recent_evidence`` of its own boxes) or a track that continued the
        history by the online joins. No other track takes over by any rule meanwhile: NO_FIX. The wait ends when
        that track ends, when its motion breaks and the join does not give it its history back, or when any track
        holds the role again. A detector that has not seen the scene may call the far vessel of interest another
        boat, and a nearer boat the vessel; the track that followed the vessel all along is then still the better
        guess, and NO_FIX is safer than another boat published as the vessel. Online only.
    appearance_joins: with the ``evidence`` score, an ended track's history is continued (online join) only by a
        track whose first box looks the same way (both likely the vessel of interest, or both not). Online only.
    path_log_floor: the path factor is ``max(log(max(l, 1)), path_log_floor)``. The paper's 0 makes every track
        without significant motion yet score 0, so among them the first one established stays the target
        however unlike the vessel it looks; 1 (a path of e metres) lets the confidences rank them while any
        track that has moved farther still wins by its path.
    """

    confidence_percentile: float = 50.0
    min_step_m: float = 0.0
    path_noise_sigmas: float = 2.0
    join_max_gap_s: float = 30.0
    join_max_overlap_s: float = 0.0
    join_gate_m: float = 30.0
    join_gate_range_frac: float = 0.15
    join_gate_speed_mps: float = 3.0
    max_speed_mps: float = 25.0
    switch_ratio: float = 1.0
    switch_margin: float = 0.3
    switch_hold_s: float = 8.0
    reacquire_fraction: float = 0.9
    reacquire_window_s: float = 3600.0
    history_length: int = 1000
    confidence_score: str = "evidence"
    evidence_clip: float = 4.0
    path_log_floor: float = 1.0
    positive_evidence_only: bool = True
    recent_evidence_s: float = 24.0
    reacquire_recent_evidence: float = 2.0
    reacquire_waits_for_dropped_track: bool = True
    appearance_joins: bool = True

    def recent_evidence_ok(self, confidences, ages) -> bool:
        """Whether the confidences of the last ``recent_evidence_s`` still say the vessel of interest.

        ``ages``: seconds before now of each confidence, same order; the newest always counts.
        """
        if self.recent_evidence_s <= 0 or self.confidence_score != "evidence":
            return True
        evidence = self._window_evidence(confidences, ages, with_newest=True)
        return evidence is None or evidence > 0

    def recent_evidence(self, confidences, ages) -> float:
        """Sum of the clipped log-odds of the confidences of the last ``recent_evidence_s`` (0 when off)."""
        if self.recent_evidence_s <= 0 or self.confidence_score != "evidence":
            return 0.0
        evidence = self._window_evidence(confidences, ages, with_newest=False)
        return 0.0 if evidence is None else evidence

    def _window_evidence(self, confidences, ages, with_newest: bool) -> float | None:
        """Clipped log-odds summed over the finite confidences of the window (and the newest one, ``with_newest``).

        None when there is none.
        """
        c = np.asarray(confidences, dtype=float).reshape(-1)
        a = np.asarray(ages, dtype=float).reshape(-1)
        keep = a <= self.recent_evidence_s
        if with_newest and c.size:
            keep[-1] = True
        c = c[keep & np.isfinite(c)]
        return float(np.sum(clipped_log_odds(c, self.evidence_clip))) if c.size else None

    def eligible_score(self, score: float) -> bool:
        """Whether a trajectory of this score may be the vessel of interest (``positive_evidence_only``)."""
        return not (self.positive_evidence_only and self.confidence_score == "evidence" and not score > 0)

    def __post_init__(self) -> None:
        """Validate the fields."""
        if not 0 <= self.confidence_percentile <= 100:
            raise DataError(f"selection: confidence_percentile must be in [0, 100], got {self.confidence_percentile}")
        if not 0 <= self.reacquire_fraction <= 1:
            raise DataError(f"selection: reacquire_fraction must be in [0, 1], got {self.reacquire_fraction!r}")
        for name in ("min_step_m", "path_noise_sigmas", "join_max_gap_s", "join_max_overlap_s", "reacquire_window_s",
                     "join_gate_m", "join_gate_range_frac", "join_gate_speed_mps", "switch_margin", "switch_hold_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise DataError(f"selection: {name} must be a finite number >= 0, got {value!r}")
        if not (math.isfinite(self.max_speed_mps) and self.max_speed_mps > 0):
            raise DataError(f"selection: max_speed_mps must be > 0, got {self.max_speed_mps!r}")
        if not (math.isfinite(self.switch_ratio) and self.switch_ratio >= 1):
            raise DataError(f"selection: switch_ratio must be >= 1, got {self.switch_ratio!r}")
        if self.confidence_score not in CONFIDENCE_SCORES:
            raise DataError(f"selection: confidence_score must be one of {', '.join(CONFIDENCE_SCORES)}, got "
                            f"{self.confidence_score!r}")
        if not (math.isfinite(self.evidence_clip) and self.evidence_clip > 0):
            raise DataError(f"selection: evidence_clip must be > 0, got {self.evidence_clip!r}")
        if not (math.isfinite(self.path_log_floor) and self.path_log_floor >= 0):
            raise DataError(f"selection: path_log_floor must be a finite number >= 0, got {self.path_log_floor!r}")
        if self.history_length < 1:
            raise DataError(f"selection: history_length must be >= 1, got {self.history_length!r}")
        threshold = self.reacquire_recent_evidence
        if not (isinstance(threshold, int | float) and math.isfinite(threshold) and threshold >= 0):
            raise DataError(f"selection: reacquire_recent_evidence must be a finite number of log-odds >= 0 (0: off), "
                            f"got {threshold!r}")
        value = self.recent_evidence_s
        if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
            raise DataError(f"selection: recent_evidence_s must be a finite number of seconds >= 0 (0: off), got "
                            f"{value!r}")
        recent_window = self.recent_evidence_s > 0 and self.confidence_score == "evidence"
        for name, is_on, why, off in (
                ("reacquire_recent_evidence", threshold > 0, "it sums the confidences of that window", "to 0"),
                ("reacquire_waits_for_dropped_track", self.reacquire_waits_for_dropped_track,
                 "a target is dropped for the boxes of that window", "to false")):
            if is_on and not recent_window:
                raise DataError(f"selection: {name} needs confidence_score: evidence and recent_evidence_s > 0 "
                                f"({why}); set them, or set {name} {off}")

    def trajectory_score(self, confidences, path_m: float) -> float:
        """``trajectory_score`` with this configuration."""
        return trajectory_score(confidences, path_m, self.confidence_percentile, self.confidence_score,
                                self.evidence_clip, self.path_log_floor)


def clipped_log_odds(confidences, clip: float) -> np.ndarray:
    """``log(c / (1 - c))`` of probabilities, each bounded to +-``clip``."""
    p = np.clip(np.asarray(confidences, dtype=float), 1e-9, 1.0 - 1e-9)
    return np.clip(np.log(p / (1.0 - p)), -clip, clip)


def path_length_m(positions, min_step_m: float = 0.0, covariances=None, noise_sigmas: float = 0.0) -> float:
    """Sum of the steps between consecutive positions (N, 2), skipping NaN rows and steps below min_step_m.

    With ``covariances`` (N, 2, 2) and ``noise_sigmas`` > 0 only significant motion counts: a step is taken from
    the last counted point to the first later point that is more than ``noise_sigmas`` standard deviations of
    their difference away from it (``significant_step``), so slow but steady motion adds up while jitter does not.
    """
    p = np.asarray(positions, dtype=float).reshape(-1, 2)
    keep = np.all(np.isfinite(p), axis=1)
    if keep.sum() < 2:
        return 0.0
    total = 0.0
    idx = np.flatnonzero(keep)
    anchor = idx[0]
    for b in idx[1:]:
        if covariances is not None and noise_sigmas > 0:
            step = significant_step(p[anchor], p[b], covariances[anchor], covariances[b], noise_sigmas)
        else:
            step = float(np.hypot(*(p[b] - p[anchor])))
        if step > 0 and step >= min_step_m:
            total += step
            anchor = b
    return total


def significant_step(p0, p1, cov0, cov1, noise_sigmas: float) -> float:
    """Length of the step p0 -> p1 if it exceeds ``noise_sigmas`` standard deviations of it, else 0.

    Near the horizon a pixel is tens to hundreds of metres: the positions of a distant sailboat jitter by more
    than the vessel of interest moves. Counting a step only once it stands out of the covariances keeps that
    jitter out of the path length.
    """
    d = np.asarray(p1, dtype=float) - np.asarray(p0, dtype=float)
    length = float(np.hypot(*d))
    if length == 0.0:
        return 0.0
    u = d / length
    variance = float(u @ (np.asarray(cov0, dtype=float) + np.asarray(cov1, dtype=float)) @ u)
    if not math.isfinite(variance) or variance < 0:
        return length
    return length if length > noise_sigmas * math.sqrt(variance) else 0.0


def trajectory_score(confidences, path_m: float, percentile: float = 80.0, mode: str = "percentile",
                     evidence_clip: float = 4.0, path_log_floor: float = 0.0) -> float:
    """The paper's ``c_0.8 * log(l)`` with ``log(max(l, 1))``; 0 for no confidences.

    ``mode="evidence"`` replaces ``c_0.8`` by the sum of the confidences' clipped log-odds
    (``SelectionConfig.confidence_score``); ``path_log_floor`` bounds the path factor from below.
    """
    c = np.asarray(confidences, dtype=float).reshape(-1)
    c = c[np.isfinite(c)]
    if c.size == 0 or not math.isfinite(path_m):
        return 0.0
    if mode == "evidence":
        confidence = float(np.sum(clipped_log_odds(c, evidence_clip)))
    else:
        confidence = float(np.percentile(c, percentile))
    return confidence * max(math.log(max(path_m, 1.0)), path_log_floor)


# ---------------------------------------------------------------------------------------------------------
# Offline


@dataclass
class Trajectory:
    """A track's (or a joined chain's) measured points on the sea plane, sorted by time."""

    track_id: str
    stamps: np.ndarray          # (N,)
    positions: np.ndarray       # (N, 2) metres
    confidences: np.ndarray     # (N,)
    members: list[str] = field(default_factory=list)
    covariances: np.ndarray | None = None  # (N, 2, 2) position covariances, m^2 (for the significant path)

    def __post_init__(self) -> None:
        """Sort by time and check shapes."""
        self.stamps = np.asarray(self.stamps, dtype=float).reshape(-1)
        self.positions = np.asarray(self.positions, dtype=float).reshape(-1, 2)
        self.confidences = np.asarray(self.confidences, dtype=float).reshape(-1)
        if self.covariances is not None:
            self.covariances = np.asarray(self.covariances, dtype=float).reshape(-1, 2, 2)
            if self.covariances.shape[0] != self.stamps.size:
                raise DataError(f"trajectory {self.track_id}: {self.covariances.shape[0]} covariances for "
                                f"{self.stamps.size} points")
        if not (self.stamps.size == self.positions.shape[0] == self.confidences.size):
            raise DataError(f"trajectory {self.track_id}: stamps, positions and confidences differ in length")
        if self.stamps.size == 0:
            raise DataError(f"trajectory {self.track_id}: no points")
        order = np.argsort(self.stamps, kind="stable")
        self.stamps, self.positions = self.stamps[order], self.positions[order]
        self.confidences = self.confidences[order]
        if self.covariances is not None:
            self.covariances = self.covariances[order]
        if not self.members:
            self.members = [self.track_id]

    @property
    def start(self) -> float:
        """First stamp."""
        return float(self.stamps[0])

    @property
    def end(self) -> float:
        """Last stamp."""
        return float(self.stamps[-1])

    def path_length(self, min_step_m: float = 0.0, noise_sigmas: float = 0.0) -> float:
        """Path length in metres (steps shortened by ``noise_sigmas`` of their noise when covariances are known)."""
        return path_length_m(self.positions, min_step_m, self.covariances, noise_sigmas)

    def score(self, config: SelectionConfig | None = None) -> float:
        """The paper's trajectory score."""
        config = config or SelectionConfig()
        return config.trajectory_score(self.confidences, self.path_length(config.min_step_m, config.path_noise_sigmas))

    def end_velocity(self, window_s: float = 20.0) -> np.ndarray:
        """Velocity (m/s) over the last ``window_s`` seconds (least squares); zeros with one point."""
        return _velocity(self.stamps, self.positions, self.stamps >= self.end - window_s)

    def start_velocity(self, window_s: float = 20.0) -> np.ndarray:
        """Velocity (m/s) over the first ``window_s`` seconds."""
        return _velocity(self.stamps, self.positions, self.stamps <= self.start + window_s)


def _velocity(stamps: np.ndarray, positions: np.ndarray, select: np.ndarray) -> np.ndarray:
    ok = select & np.all(np.isfinite(positions), axis=1)
    t = stamps[ok]
    if t.size < 2 or np.ptp(t) <= 0:
        return np.zeros(2)
    A = np.column_stack([t - t.mean(), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(A, positions[ok], rcond=None)
    return coef[0]


def join_cost(first: Trajectory, second: Trajectory, config: SelectionConfig) -> float:
    """Cost of appending ``second`` after ``first`` (gate-normalised mismatch), or ``inf`` if not allowed."""
    gap = second.start - first.end
    if gap < -config.join_max_overlap_s or gap > config.join_max_gap_s:
        return math.inf
    keep_first = first.stamps <= second.start if gap < 0 else np.ones(first.stamps.size, dtype=bool)
    if not keep_first.any():
        return math.inf
    end_t = float(first.stamps[keep_first][-1])
    end_p = first.positions[keep_first][-1]
    start_p = second.positions[0]
    if not (np.all(np.isfinite(end_p)) and np.all(np.isfinite(start_p))):
        return math.inf
    dt = max(second.start - end_t, 0.0)
    jump = float(np.hypot(*(start_p - end_p)))
    if dt > 0 and jump / dt > config.max_speed_mps + config.join_gate_m / dt:
        return math.inf
    # Extrapolate both ways and take the better: the end of one piece and the start of the other.
    forward = end_p + first.end_velocity() * dt
    backward = start_p - second.start_velocity() * dt
    mismatch = min(float(np.hypot(*(start_p - forward))), float(np.hypot(*(end_p - backward))))
    gate = config.join_gate_m + config.join_gate_range_frac * float(np.hypot(*start_p)) + \
        config.join_gate_speed_mps * dt
    if mismatch > gate:
        return math.inf
    return mismatch / gate


def concatenate(first: Trajectory, second: Trajectory) -> Trajectory:
    """``first`` then ``second``; points of ``first`` after ``second`` starts are dropped (overlap)."""
    keep = first.stamps < second.start
    covariances = None
    if first.covariances is not None and second.covariances is not None:
        covariances = np.concatenate([first.covariances[keep], second.covariances])
    return Trajectory(first.track_id, np.concatenate([first.stamps[keep], second.stamps]),
                      np.concatenate([first.positions[keep], second.positions]),
                      np.concatenate([first.confidences[keep], second.confidences]),
                      members=first.members + second.members, covariances=covariances)


def join_trajectories(trajectories: list[Trajectory], config: SelectionConfig | None = None) -> list[Trajectory]:
    """Join pieces of the same vessel cut in time: one optimal assignment of piece ends to piece starts.

    Returns the chains (a piece that joins nothing is a chain of one), each with ``members`` in time order.
    """
    config = config or SelectionConfig()
    n = len(trajectories)
    if n < 2:
        return list(trajectories)
    cost = np.full((n, n), _FORBIDDEN)
    for i, a in enumerate(trajectories):
        for j, b in enumerate(trajectories):
            if i != j and b.start > a.start:
                c = join_cost(a, b, config)
                if math.isfinite(c):
                    cost[i, j] = c
    rows, cols = linear_sum_assignment(cost)
    successor = {int(r): int(c) for r, c in zip(rows, cols, strict=True) if cost[r, c] < _FORBIDDEN}
    has_predecessor = set(successor.values())
    chains: list[Trajectory] = []
    for i in range(n):
        if i in has_predecessor:
            continue
        chain = trajectories[i]
        j = i
        seen = {i}
        while j in successor and successor[j] not in seen:
            j = successor[j]
            seen.add(j)
            chain = concatenate(chain, trajectories[j])
        chains.append(chain)
    return chains


def select_target(trajectories: list[Trajectory], config: SelectionConfig | None = None,
                  join: bool = True) -> tuple[Trajectory | None, list[tuple[Trajectory, float]]]:
    """The vessel of interest: the best-scoring (joined) trajectory; also every candidate with its score."""
    config = config or SelectionConfig()
    candidates = join_trajectories(trajectories, config) if join else list(trajectories)
    scored = sorted(((c, c.score(config)) for c in candidates), key=lambda cs: -cs[1])
    best = scored[0] if scored and config.eligible_score(scored[0][1]) else None
    return (best[0] if best else None), scored


# ---------------------------------------------------------------------------------------------------------
# Online


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
        cfg = self.config
        self.continued = {}
        present: set[str] = set()
        measured_now: set[str] = set()
        for wt in world_tracks:
            tid = wt.screen.track_id
            if wt.screen.status == 3:  # LOST
                running = self._running.pop(tid, None)
                if running is not None:
                    self._ended[tid] = running
                    if tid == self.target:
                        self._target_lost(tid, running, stamp)
                continue
            present.add(tid)
            running = self._running.get(tid)
            position = np.asarray(wt.position, dtype=float) if wt.has_world else None
            measured = wt.screen.updated and position is not None and np.all(np.isfinite(position))
            # A track continues an ended one's history from its first box with a position: a track whose first
            # boxes had none (cut by the lens model's edge, above the horizon) may still be the vessel come back.
            if running is None or (measured and running.first_position is None and not running.inherited_from):
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
            if wt.screen.updated and math.isfinite(wt.screen.confidence):
                running.add_confidence(float(wt.screen.confidence), stamp)
            if measured:
                measured_now.add(tid)
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
            running.eligible = bool(wt.has_world)
            running.established = wt.screen.status != 0 or bool(running.inherited_from)
        # Tracks that vanished without a LOST report count as ended.
        for tid in [t for t in self._running if t not in present]:
            self._ended[tid] = self._running.pop(tid)
            if tid == self.target:
                self._target_lost(tid, self._ended[tid], stamp)
        for tid in [t for t, r in self._ended.items() if not (stamp - r.last_stamp <= cfg.join_max_gap_s)]:
            del self._ended[tid]
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
        cfg = self.config
        # Established (confirmed, or continuing a joined track) candidates first; a tentative track only
        # while there is nothing else, and it gives way at once to an established one.
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
