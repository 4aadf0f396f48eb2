"""One track inside the tracker: its Kalman filter, its latest box, its history; and the same as plain data.

``TrackRecord`` is what ``vessel_track.tracker.MultiTargetTracker`` keeps per track (``TrackState`` is what it
reports). ``track_to_state`` and ``track_from_state`` carry a record through a state file
(``vessel_common.state_file``), so a restarted tracker node goes on with the same tracks.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING

import numpy as np

from vessel_common.state_file import checked_fields, fields_of
from vessel_track.deferred_imports import kalman_filter

if TYPE_CHECKING:
    from filterpy.kalman import KalmanFilter


@dataclass
class TrackRecord:
    """A live (or just ended) track: state (x, vx, y, vy) in ``kf``, the latest box's size, its life cycle.

    ``history`` holds one entry per associated detection: (stamp, measured centre, measured size, confidence,
    filtered centre right after the update).
    """

    track_id: str
    kf: KalmanFilter
    stamp: float
    first_seen: float
    last_seen: float
    size: np.ndarray
    confidence: float
    label: str = ""
    hits: int = 1
    misses: int = 0
    ever_confirmed: bool = False
    history: deque = field(default_factory=deque)

    @property
    def center(self) -> np.ndarray:
        """(2,) filtered box centre, px."""
        return np.array([self.kf.x[0, 0], self.kf.x[2, 0]])

    @property
    def velocity(self) -> np.ndarray:
        """(2,) filtered centre velocity, px/s."""
        return np.array([self.kf.x[1, 0], self.kf.x[3, 0]])

    @property
    def center_cov(self) -> np.ndarray:
        """(2, 2) covariance of ``center``, px²."""
        P = self.kf.P
        return np.array([[P[0, 0], P[0, 2]], [P[2, 0], P[2, 2]]])

    @property
    def box_xyxy(self) -> np.ndarray:
        """(4,) box around the filtered centre with the latest size, px."""
        half = self.size / 2.0
        return np.array([*(self.center - half), *(self.center + half)])

    def recent_confidences(self, count: int) -> list[float]:
        """The confidences of the latest ``count`` updates, oldest first, read from the history's end.

        Every frame asks this of every track: indexing from the end costs ``count`` reads, where a copy of the
        history would cost up to ``history_length``.
        """
        history = self.history
        return [history[i][3] for i in range(max(len(history) - count, 0), len(history))]


# What of a track's filter the tracker uses (it gives F and Q at each predict), and a history entry's parts.
_FILTER_MATRICES = {"x": (4, 1), "P": (4, 4), "R": (2, 2), "H": (2, 4)}
_HISTORY_COLUMNS = (("stamps", ()), ("centers", (2,)), ("sizes", (2,)), ("confidences", ()), ("filtered", (2,)))


def track_to_state(track: TrackRecord) -> dict:
    """A track as plain data: its fields, its filter's matrices, and its history as one array per column."""
    state = fields_of(track, skip=("kf", "history"))
    state["size"] = np.array(track.size, dtype=float)
    state["kf"] = {name: np.array(getattr(track.kf, name), dtype=float) for name in _FILTER_MATRICES}
    rows = list(track.history)
    state["history"] = {"maxlen": track.history.maxlen}
    for index, (name, shape) in enumerate(_HISTORY_COLUMNS):
        state["history"][name] = np.array([row[index] for row in rows], dtype=float).reshape(len(rows), *shape)
    return state


def track_from_state(state: dict) -> TrackRecord:
    """The track ``track_to_state`` described; ValueError for other fields or shapes."""
    values = dict(checked_fields(state, {f.name for f in fields(TrackRecord)}, "a track"))

    def array(value, shape: tuple[int, ...], what: str) -> np.ndarray:
        value = np.array(value, dtype=float)
        if value.shape != shape:
            raise ValueError(f"{what} has shape {value.shape}, not {shape}")
        return value

    kf = kalman_filter(dim_x=4, dim_z=2)
    for name, shape in _FILTER_MATRICES.items():
        setattr(kf, name, array(values["kf"][name], shape, f"a track's filter {name}"))
    history = checked_fields(values["history"], {"maxlen", *dict(_HISTORY_COLUMNS)}, "a track's history")
    count = len(history["stamps"])
    stamps, centers, sizes, confidences, filtered = (array(history[name], (count, *shape), f"track history {name}")
                                                      for name, shape in _HISTORY_COLUMNS)
    rows = zip(stamps.tolist(), centers, sizes, confidences.tolist(), filtered, strict=True)
    values["history"] = deque(((stamp, center.copy(), size.copy(), confidence, smooth.copy())
                               for stamp, center, size, confidence, smooth in rows), maxlen=history["maxlen"])
    values["kf"], values["size"] = kf, array(values["size"], (2,), "a track's size")
    return TrackRecord(**values)
