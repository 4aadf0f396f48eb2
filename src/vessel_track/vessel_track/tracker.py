"""Multi-target tracker in screen pixels: one constant-velocity Kalman filter per vessel, global association.

This is the paper's post-processing step 1 ("Each trajectory uses a Kalman filter to predict the location in
the next frame ... accounted to the closest trajectory if within 80 pixels ... finished if not updated for
more than 10 frames"), made independent of the frame rate: the time step of the filter is the difference of
the stamps in seconds, and the track lifetime is in seconds, so the same configuration tracks the challenge
data (one frame every ~4 s) and a live camera (one frame every 30 ms).

Differences from the paper, each a config field so the paper's behaviour can be approached:

* Full-resolution pixels (the paper worked at half resolution, so its R = 10² px² and 80 px gate are
  20² px² and 160 px here). The defaults are not those: they were chosen by measurement on simulated harbour
  traffic at 4 s, 1 s and 0.1 s between frames (``./vessel simulate``) and on the hand-labelled
  boxes of the challenge videos (``test/test_tracker_labels.py``); the paper-scaled values split the labelled
  vessel into more tracks and let clutter confirm at live frame rates.
* Association is a global assignment (Hungarian, ``scipy.optimize.linear_sum_assignment``) of detections to
  predicted positions, not the paper's per-detection nearest trajectory; confirmed and coasting tracks are
  matched before tentative ones so a burst of clutter cannot steal a vessel's detection, and a track may stay
  unmatched (at the clutter likelihood's cost) rather than take a worse box so that another track gets one.
* The gate grows with the predicted uncertainty (``gate_sigmas`` standard deviations of the innovation),
  between ``gate_px`` and ``max_gate_px``, so a vessel coasting through an occlusion is found again where it
  reappears; a likelihood-ratio test against a clutter density keeps such wide gates from taking stray boxes.
* Box-size similarity is part of the association cost, duplicate boxes of one vessel start no track, and a
  tentative track must collect ``min_hits`` detections before it is CONFIRMED.
* The process noise defaults to the continuous white-noise-acceleration model, whose prediction over 4 s is
  the same whether made in one step or in 133 steps of 30 ms; the paper's ``diag(0, qΔ², 0, qΔ²)`` is
  available as ``process_noise_model="paper"``.

The settings are ``vessel_track.tracker_config``, the association cost and assignment
``vessel_track.association``, a track's record and its state-file form ``vessel_track.track_record``. The
module never imports ROS; ``vessel_track.tracker_node`` wraps it.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass
from enum import IntEnum
from typing import TYPE_CHECKING

import numpy as np

from vessel_common.errors import DataError
from vessel_track.association import associate
from vessel_track.deferred_imports import kalman_filter
from vessel_track.track_record import TrackRecord, track_from_state, track_to_state
from vessel_track.tracker_config import PROCESS_NOISE_MODELS, TrackerConfig

if TYPE_CHECKING:
    from filterpy.kalman import KalmanFilter

MAX_PIXEL_COORDINATE = 1.0e5
"""A box corner farther than this from the image origin, px, is not a detection of a camera image."""


class TrackStatus(IntEnum):
    """Life-cycle state of a track; the values are those of ``vessel_msgs/VesselTrack.STATUS_*``."""

    TENTATIVE = 0
    CONFIRMED = 1
    COASTING = 2
    LOST = 3


@dataclass
class TrackerCounters:
    """Counts of what the tracker saw and did, for diagnostics; never reset except by ``reset_counters``."""

    frames: int = 0
    detections_in: int = 0
    detections_invalid: int = 0
    """NaN/inf coordinates or beyond ``MAX_PIXEL_COORDINATE``, or width/height below ``min_box_size_px``
    (including negative), or a NaN score."""
    detections_low_score: int = 0
    detections_associated: int = 0
    duplicates_suppressed: int = 0
    capacity_drops: int = 0
    tracks_created: int = 0
    tracks_confirmed: int = 0
    tracks_lost: int = 0
    resets: int = 0
    """Stamps went back by ``backwards_reset_s`` or more (a replay restarted)."""
    out_of_order_frames: int = 0
    """Frames stamped slightly before the previous one: dropped."""
    gaps: int = 0
    """Frames arriving more than ``max_coast_s`` after the previous one: every track timed out."""

    def as_dict(self) -> dict[str, int]:
        """The counters by name."""
        return asdict(self)


@dataclass
class TrackState:
    """One track as reported after an update (the shared contract of the team's CONTEXT.md)."""

    track_id: str
    status: TrackStatus
    stamp: float
    """Stamp of the frame this state refers to, epoch seconds."""
    center: np.ndarray
    """(2,) filtered box centre, px."""
    velocity: np.ndarray
    """(2,) filtered centre velocity, px/s."""
    center_cov: np.ndarray
    """(2, 2) covariance of ``center``, px²."""
    size: np.ndarray
    """(2,) width, height of the latest associated detection, px."""
    measured_center: np.ndarray | None
    """(2,) centre of the detection associated in this update, px; None when not updated."""
    measured_size: np.ndarray | None
    """(2,) width, height of the detection associated in this update, px; None when not updated."""
    confidence: float
    """Detector score of the latest associated detection."""
    first_seen: float
    last_seen: float
    """Stamp of the latest associated detection."""
    detection_count: int
    label: str = ""
    """Class of the latest associated detection ('' when the detector gave none)."""

    @property
    def updated(self) -> bool:
        """True when a detection was associated to the track in this update."""
        return self.measured_center is not None

    @property
    def box_xyxy(self) -> np.ndarray:
        """(4,) box around the filtered centre with the latest size, px."""
        half = self.size / 2.0
        return np.array([*(self.center - half), *(self.center + half)])


@dataclass
class TrackHistory:
    """The associated detections of one track, oldest first, at most ``history_length`` of them."""

    stamps: np.ndarray
    """(N,) epoch seconds."""
    measured_centers: np.ndarray
    """(N, 2) px."""
    measured_sizes: np.ndarray
    """(N, 2) width, height, px."""
    confidences: np.ndarray
    """(N,) detector scores."""
    filtered_centers: np.ndarray
    """(N, 2) filtered centre right after each update, px."""


def transition_matrix(dt: float) -> np.ndarray:
    """F of the state (x, vx, y, vy) for a step of ``dt`` seconds (the paper's F with Δ = dt)."""
    return np.array([[1.0, dt, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, dt], [0.0, 0.0, 0.0, 1.0]])


def process_noise_matrix(dt: float, q: float, model: str, q_y: float | None = None) -> np.ndarray:
    """Q of the state (x, vx, y, vy) for a step of ``dt`` seconds under ``model`` (see ``TrackerConfig``).

    ``q`` applies to x and, unless ``q_y`` is given, to y.
    """
    if model == "continuous_wna":
        unit = np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
    elif model == "discrete_wna":
        unit = np.array([[dt**4 / 4.0, dt**3 / 2.0], [dt**3 / 2.0, dt**2]])
    elif model == "paper":
        unit = np.array([[0.0, 0.0], [0.0, dt**2]])
    else:
        raise DataError(f"unknown process noise model {model!r}; "
                        f"use one of {', '.join(PROCESS_NOISE_MODELS)}")
    Q = np.zeros((4, 4))
    Q[0:2, 0:2] = q * unit
    Q[2:4, 2:4] = (q if q_y is None else q_y) * unit
    return Q


_H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])


def _iou_matrix(a_xyxy: np.ndarray, b_xyxy: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) intersection over union of axis-aligned boxes."""
    if len(a_xyxy) == 0 or len(b_xyxy) == 0:
        return np.zeros((len(a_xyxy), len(b_xyxy)))
    x1 = np.maximum(a_xyxy[:, None, 0], b_xyxy[None, :, 0])
    y1 = np.maximum(a_xyxy[:, None, 1], b_xyxy[None, :, 1])
    x2 = np.minimum(a_xyxy[:, None, 2], b_xyxy[None, :, 2])
    y2 = np.minimum(a_xyxy[:, None, 3], b_xyxy[None, :, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    area_a = (a_xyxy[:, 2] - a_xyxy[:, 0]) * (a_xyxy[:, 3] - a_xyxy[:, 1])
    area_b = (b_xyxy[:, 2] - b_xyxy[:, 0]) * (b_xyxy[:, 3] - b_xyxy[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)


class MultiTargetTracker:
    """Tracks every vessel on screen from per-frame boxes; call ``update`` once per image, in stamp order.

    ``update`` returns one ``TrackState`` per live track (TENTATIVE, CONFIRMED or COASTING) and, once, one per
    track that ended in this update (LOST). Invalid boxes are dropped and counted in ``counters``.
    """

    def __init__(self, config: TrackerConfig | None = None):
        self.config = config if config is not None else TrackerConfig()
        self.counters = TrackerCounters()
        self._tracks: list[TrackRecord] = []
        self._ended: dict[str, TrackRecord] = {}
        self._next_id = 1
        self._last_stamp: float | None = None

    # ------------------------------------------------------------------ public API

    @property
    def last_stamp(self) -> float | None:
        """Stamp of the latest processed frame, or None before the first (and after ``reset``)."""
        return self._last_stamp

    @property
    def track_ids(self) -> list[str]:
        """Ids of the live tracks, oldest first."""
        return [t.track_id for t in self._tracks]

    def reset(self) -> list[str]:
        """Forget every track (ids keep counting up); returns the ids that were live."""
        ids = self.track_ids
        self._tracks = []
        self._ended = {}
        self._last_stamp = None
        return ids

    def snapshot(self) -> dict:
        """The tracks and counters ``restore`` needs to carry on in another process, as plain data (a copy).

        Numbers, strings, containers and numpy arrays only: what a state file holds (``vessel_common.state_file``).
        """
        return {"tracks": [track_to_state(track) for track in self._tracks],
                "ended": {track_id: track_to_state(track) for track_id, track in self._ended.items()},
                "next_id": self._next_id, "last_stamp": self._last_stamp}

    def restore(self, snapshot: dict) -> None:
        """Carry on from ``snapshot()`` of a tracker with the same config (a node restarted after a crash).

        New ids start ``max_tracks`` past the snapshot's, beyond any track started between it and the crash.
        ValueError (KeyError, TypeError) for a snapshot with other fields than this version's: the tracker is then
        left as it was.
        """
        tracks = [track_from_state(state) for state in snapshot["tracks"]]
        ended = {str(track_id): track_from_state(state) for track_id, state in dict(snapshot["ended"]).items()}
        last_stamp = None if snapshot["last_stamp"] is None else float(snapshot["last_stamp"])
        next_id = int(snapshot["next_id"])
        self._tracks, self._ended, self._last_stamp = tracks, ended, last_stamp
        # Tracks started after the snapshot were published before the crash: their ids are not given again.
        self._next_id = max(self._next_id, next_id + self.config.max_tracks)

    def history(self, track_id: str) -> TrackHistory:
        """History of a live track, or of one reported LOST by the latest update; KeyError otherwise."""
        track = next((t for t in self._tracks if t.track_id == track_id), None) or self._ended.get(track_id)
        if track is None:
            raise KeyError(f"no live or just-ended track {track_id!r}")
        items = list(track.history)
        if not items:
            empty2 = np.zeros((0, 2))
            return TrackHistory(np.zeros(0), empty2, empty2.copy(), np.zeros(0), empty2.copy())
        stamps, centers, sizes, confs, filtered = zip(*items, strict=True)
        return TrackHistory(np.array(stamps), np.array(centers), np.array(sizes), np.array(confs),
                            np.array(filtered))

    def update(self, stamp_s: float, boxes_xyxy, scores=None, labels=None) -> list[TrackState]:
        """Advance every track to ``stamp_s`` and associate this frame's boxes.

        ``boxes_xyxy``: (N, 4) x1, y1, x2, y2 in full-resolution px (N may be 0); ``scores``: (N,) detector
        confidences (None: all 1); ``labels``: (N,) class names carried to the tracks (None: none). Raises
        DataError for a non-finite stamp or arrays of the wrong shape.
        """
        stamp = self._check_stamp(stamp_s)
        boxes, confs = self._check_arrays(boxes_xyxy, scores)
        names = self._check_labels(labels, len(boxes))
        self._ended = {}
        reported = self._start_frame(stamp)
        if reported is None:
            return []
        reported += self._time_out(stamp)

        boxes, confs, kept = self._filter_detections(boxes, confs)
        names = [names[i] for i in kept]
        centers = (boxes[:, :2] + boxes[:, 2:]) / 2.0
        sizes = boxes[:, 2:] - boxes[:, :2]
        matches, free_dets = self._match(centers, sizes, confs)
        measured = self._correct_matched(stamp, matches, centers, sizes, confs, names)
        new_tracks = self._spawn(stamp, boxes, centers, sizes, confs, free_dets, list(matches.values()), names)
        return reported + self._report(stamp, measured, new_tracks)

    # ------------------------------------------------------------------ the steps of an update

    def _start_frame(self, stamp: float) -> list[TrackState] | None:
        """Take ``stamp`` as the current frame's: the tracks it ends, or None for a frame to drop (out of order).

        A stamp ``backwards_reset_s`` or more before the previous one means a replay restarted: every track ends.
        """
        cfg = self.config
        reported: list[TrackState] = []
        if self._last_stamp is not None and stamp < self._last_stamp:
            if self._last_stamp - stamp < cfg.backwards_reset_s:
                self.counters.out_of_order_frames += 1
                return None
            self.counters.resets += 1
            for track in self._tracks:
                reported.append(self._end(track, stamp))
            self._tracks = []
        elif self._last_stamp is not None and stamp - self._last_stamp > cfg.max_coast_s:
            self.counters.gaps += 1
        self.counters.frames += 1
        self._last_stamp = stamp
        return reported

    def _time_out(self, stamp: float) -> list[TrackState]:
        """End the tracks not updated for too long (their LOST states), then predict the others to ``stamp``.

        Time-outs come first, from the last update, so that a gap of minutes never predicts anything far ahead.
        """
        cfg = self.config
        reported: list[TrackState] = []
        alive: list[TrackRecord] = []
        for track in self._tracks:
            limit = cfg.max_coast_s if track.ever_confirmed else cfg.tentative_max_coast_s
            if stamp - track.last_seen > limit or (
                    not track.ever_confirmed and track.misses > cfg.tentative_max_misses):
                reported.append(self._end(track, stamp))
            else:
                alive.append(track)
        self._tracks = alive
        steps: dict[float, tuple[np.ndarray, np.ndarray]] = {}  # F and Q by time step: most tracks share one
        for track in self._tracks:
            self._predict(track, stamp, steps)
        return reported

    def _match(self, centers: np.ndarray, sizes: np.ndarray, confs: np.ndarray) -> tuple[dict[int, int], list[int]]:
        """The detection of each track that gets one (track index -> detection index), and the detections left.

        A cascade: established tracks get first pick, tentative ones share what is left, so a burst of clutter
        cannot steal a vessel's detection.
        """
        established = [i for i, t in enumerate(self._tracks) if t.ever_confirmed]
        tentative = [i for i, t in enumerate(self._tracks) if not t.ever_confirmed]
        matches: dict[int, int] = {}
        free_dets = list(range(len(centers)))
        for group in (established, tentative):
            if not group or not free_dets:
                continue
            pairs = associate(self.config, [self._tracks[i] for i in group], centers[free_dets], sizes[free_dets],
                              confs[free_dets])
            for g, d in pairs:
                matches[group[g]] = free_dets[d]
            taken = {free_dets[d] for _, d in pairs}
            free_dets = [d for d in free_dets if d not in taken]
        return matches, free_dets

    def _correct_matched(self, stamp: float, matches: dict[int, int], centers: np.ndarray, sizes: np.ndarray,
                         confs: np.ndarray, names: list[str]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Correct each matched track with its detection; the measured centre and size by track index."""
        measured: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for ti, di in matches.items():
            self._correct(self._tracks[ti], stamp, centers[di], sizes[di], float(confs[di]))
            self._tracks[ti].label = names[di]
            measured[ti] = (centers[di].copy(), sizes[di].copy())
        self.counters.detections_associated += len(matches)
        return measured

    def _report(self, stamp: float, measured: dict[int, tuple[np.ndarray, np.ndarray]],
                new_tracks: list[TrackRecord]) -> list[TrackState]:
        """The state of every live track after this frame; the new tracks join the live ones, last."""
        reported: list[TrackState] = []
        for ti, track in enumerate(self._tracks):
            if ti not in measured:
                track.misses += 1
            m = measured.get(ti)
            reported.append(self._state(track, stamp, self._status(track, ti in measured),
                                        None if m is None else m[0], None if m is None else m[1]))
        for track in new_tracks:
            self._tracks.append(track)
            reported.append(self._state(track, stamp, self._status(track, True), track.center,
                                        track.size.copy()))
        return reported

    # ------------------------------------------------------------------ input checks

    def _check_stamp(self, stamp_s) -> float:
        try:
            stamp = float(stamp_s)
        except (TypeError, ValueError) as exc:
            raise DataError(f"tracker: stamp must be a number of seconds, got {stamp_s!r}") from exc
        if not math.isfinite(stamp):
            raise DataError(f"tracker: stamp must be finite, got {stamp}; check the message header")
        return stamp

    def _check_arrays(self, boxes_xyxy, scores) -> tuple[np.ndarray, np.ndarray]:
        boxes = np.asarray(boxes_xyxy if boxes_xyxy is not None else np.zeros((0, 4)), dtype=float)
        if boxes.size == 0:
            boxes = boxes.reshape(0, 4)
        if boxes.ndim != 2 or boxes.shape[1] != 4:
            raise DataError(f"tracker: boxes must have shape (N, 4) x1, y1, x2, y2, got {boxes.shape}")
        if scores is None:
            confs = np.ones(len(boxes))
        else:
            confs = np.asarray(scores, dtype=float).reshape(-1)
            if confs.shape != (len(boxes),):
                raise DataError(f"tracker: {len(confs)} scores for {len(boxes)} boxes; "
                                "give one score per box")
        return boxes, confs

    @staticmethod
    def _check_labels(labels, count: int) -> list[str]:
        if labels is None:
            return [""] * count
        names = [str(v) for v in labels]
        if len(names) != count:
            raise DataError(f"tracker: {len(names)} labels for {count} boxes; give one label per box")
        return names

    def _filter_detections(self, boxes: np.ndarray, confs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        cfg = self.config
        self.counters.detections_in += len(boxes)
        if len(boxes) == 0:
            return boxes, confs, np.zeros(0, dtype=np.int64)
        finite = np.isfinite(boxes).all(axis=1) & np.isfinite(confs)
        with np.errstate(invalid="ignore"):
            finite &= (np.abs(boxes) <= MAX_PIXEL_COORDINATE).all(axis=1)
        with np.errstate(invalid="ignore"):
            big_enough = ((boxes[:, 2] - boxes[:, 0]) >= cfg.min_box_size_px) & (
                (boxes[:, 3] - boxes[:, 1]) >= cfg.min_box_size_px)
        valid = finite & big_enough
        self.counters.detections_invalid += int((~valid).sum())
        scored = valid & (confs >= cfg.min_score)
        self.counters.detections_low_score += int((valid & ~scored).sum())
        return boxes[scored], confs[scored], np.flatnonzero(scored)

    # ------------------------------------------------------------------ filter

    def _new_filter(self, center: np.ndarray, size: np.ndarray) -> KalmanFilter:
        cfg = self.config
        kf = kalman_filter(dim_x=4, dim_z=2)
        kf.x = np.array([[center[0]], [0.0], [center[1]], [0.0]])
        kf.H = _H.copy()
        R = self._measurement_cov(size)
        kf.P = np.diag([R[0, 0], cfg.init_velocity_std_x_px_s**2, R[1, 1], cfg.init_velocity_std_y_px_s**2])
        kf.R = R
        return kf

    def _measurement_cov(self, size: np.ndarray) -> np.ndarray:
        cfg = self.config
        base = cfg.measurement_std_px**2
        extra = (cfg.measurement_std_size_frac * np.asarray(size, dtype=float)) ** 2
        return np.diag([base + extra[0], base + extra[1]])

    def _predict(self, track: TrackRecord, stamp: float,
                 steps: dict[float, tuple[np.ndarray, np.ndarray]] | None = None) -> None:
        """Predict ``track`` to ``stamp``; ``steps``: F and Q by time step, filled as they are first needed."""
        dt = stamp - track.stamp
        steps = {} if steps is None else steps
        if dt > 0:
            if dt not in steps:
                cfg = self.config
                steps[dt] = (transition_matrix(dt), process_noise_matrix(dt, cfg.process_noise,
                                                                         cfg.process_noise_model, cfg.process_noise_y))
            transition, noise = steps[dt]
            track.kf.predict(F=transition, Q=noise)
        track.stamp = stamp

    def _correct(self, track: TrackRecord, stamp: float, center: np.ndarray, size: np.ndarray,
                 conf: float) -> None:
        track.kf.update(center.reshape(2, 1), R=self._measurement_cov(size))
        track.last_seen = stamp
        track.size = size.copy()
        track.confidence = conf
        track.hits += 1
        track.misses = 0
        if not track.ever_confirmed and track.hits >= self.config.min_hits:
            track.ever_confirmed = True
            self.counters.tracks_confirmed += 1
        track.history.append((stamp, center.copy(), size.copy(), conf, track.center))

    # ------------------------------------------------------------------ life cycle

    def _spawn(self, stamp: float, boxes: np.ndarray, centers: np.ndarray, sizes: np.ndarray,
               confs: np.ndarray, free_dets: list[int], used_dets: list[int], names: list[str]) -> list[TrackRecord]:
        cfg = self.config
        created: list[TrackRecord] = []
        if not free_dets:
            return created
        references = [boxes[used_dets]] if used_dets else []
        if self._tracks:
            references.append(np.array([t.box_xyxy for t in self._tracks]))
        # Strongest detections first, so a duplicate pair keeps the better box.
        for di in sorted(free_dets, key=lambda k: -confs[k]):
            box = boxes[di:di + 1]
            if cfg.duplicate_iou > 0:
                others = references + ([np.array([t.box_xyxy for t in created])] if created else [])
                if others and _iou_matrix(box, np.vstack(others)).max(initial=0.0) > cfg.duplicate_iou:
                    self.counters.duplicates_suppressed += 1
                    continue
            if len(self._tracks) + len(created) >= cfg.max_tracks:
                self.counters.capacity_drops += 1
                continue
            track = TrackRecord(track_id=f"{cfg.id_prefix}{self._next_id}",
                                kf=self._new_filter(centers[di], sizes[di]), stamp=stamp, first_seen=stamp,
                                last_seen=stamp, size=sizes[di].copy(),
                                confidence=float(confs[di]), label=names[di],
                                history=deque(maxlen=cfg.history_length))
            self._next_id += 1
            self.counters.tracks_created += 1
            if cfg.min_hits <= 1:
                track.ever_confirmed = True
                self.counters.tracks_confirmed += 1
            track.history.append((stamp, centers[di].copy(), sizes[di].copy(), float(confs[di]),
                                  track.center))
            created.append(track)
        return created

    @staticmethod
    def _status(track: TrackRecord, updated: bool) -> TrackStatus:
        if not track.ever_confirmed:
            return TrackStatus.TENTATIVE
        return TrackStatus.CONFIRMED if updated else TrackStatus.COASTING

    def _end(self, track: TrackRecord, stamp: float) -> TrackState:
        self.counters.tracks_lost += 1
        self._ended[track.track_id] = track
        return self._state(track, stamp, TrackStatus.LOST, None, None)

    @staticmethod
    def _state(track: TrackRecord, stamp: float, status: TrackStatus, measured_center,
               measured_size) -> TrackState:
        return TrackState(track_id=track.track_id, status=status, stamp=stamp, center=track.center,
                          velocity=track.velocity, center_cov=track.center_cov, size=track.size.copy(),
                          measured_center=measured_center, measured_size=measured_size,
                          confidence=track.confidence, first_seen=track.first_seen, last_seen=track.last_seen,
                          detection_count=track.hits, label=track.label)
