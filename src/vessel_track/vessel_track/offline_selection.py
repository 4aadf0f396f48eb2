"""The offline selection of the vessel of interest: over whole recorded trajectories, pieces joined.

The paper takes the best-scoring trajectory (``vessel_track.trajectory_scoring``); a trajectory cut in the middle
(a missed stretch, an occlusion) is joined with the pieces before and after it by their timestamps. Pieces are
joined when they do not overlap in time (beyond ``join_max_overlap_s``), the gap is short, and the end of one
extrapolated to the start of the next lands within a gate (``join_trajectories``); ``select_target`` scores the
joined chains. ``vessel_track.selection`` is the online counterpart.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vessel_common.errors import DataError
from vessel_track.deferred_imports import linear_sum_assignment
from vessel_track.selection_config import SelectionConfig
from vessel_track.trajectory_scoring import path_length_m

_FORBIDDEN = 1e9


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
