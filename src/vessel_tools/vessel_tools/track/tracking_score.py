"""A simulated run's frames and the truth behind them, and how well a tracker followed it.

``vessel_tools.track.simulation`` draws the run; ``score_tracking`` scores a tracker's outputs against its truth:
id switches, tracks per vessel, confirmed clutter tracks, screen errors, coverage. A track state's detection is
found from its ``measured_center`` (the raw centre it was updated with), which gives the vessel behind it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from vessel_common.errors import DataError


@dataclass
class SimFrame:
    """What the detector reports for one image, with the truth behind each box."""

    stamp: float
    """Epoch seconds."""
    boxes_xyxy: np.ndarray
    """(N, 4) px."""
    scores: np.ndarray
    """(N,)"""
    gt_ids: np.ndarray
    """(N,) vessel id of each box, -1 for a false detection."""
    static_clutter: np.ndarray
    """(N,) True for the false detections of a fixed object (the mooring post), a subset of ``gt_ids == -1``."""

    @property
    def centers(self) -> np.ndarray:
        """(N, 2) box centres, px."""
        return (self.boxes_xyxy[:, :2] + self.boxes_xyxy[:, 2:]) / 2.0


@dataclass
class VesselTruth:
    """Ground truth of one vessel at every frame stamp (NaN where it is not on the water or behind the camera)."""

    stamps: np.ndarray
    world_xy: np.ndarray
    """(T, 2) metres east, north of the camera."""
    screen_xy: np.ndarray
    """(T, 2) projection of ``world_xy``, px (the true box centre)."""
    box_wh: np.ndarray
    """(T, 2) true box size, px."""
    visible: np.ndarray
    """(T,) on the water, in front of the camera, inside the image, not occluded."""
    detected: np.ndarray
    """(T,) a box of this vessel is in the frame's detections."""


@dataclass
class SimResult:
    """A simulated run: the frames fed to the tracker and the truth to score it against."""

    frames: list[SimFrame]
    truth: dict[int, VesselTruth]
    camera: object

    @property
    def stamps(self) -> np.ndarray:
        """(T,) frame stamps, epoch seconds."""
        return np.array([f.stamp for f in self.frames])

    def truth_gps(self, vessel_id: int) -> tuple[np.ndarray, np.ndarray]:
        """(lat, lon) of a vessel at every frame stamp (needs a camera with a position)."""
        xy = self.truth[vessel_id].world_xy
        lat, lon = self.camera.world_to_gps(xy[:, 0], xy[:, 1])
        return np.asarray(lat), np.asarray(lon)



@dataclass
class TrackingMetrics:
    """How well a tracker followed a simulated run."""

    id_switches: int
    """Times a vessel's detection went to a different CONFIRMED/COASTING track than its previous one."""
    tracks_per_vessel: dict[int, int]
    """Distinct confirmed tracks that received each vessel's detections (1 is perfect)."""
    false_confirmed_tracks: int
    """Confirmed tracks whose detections were mostly random clutter."""
    static_clutter_tracks: int
    """Confirmed tracks of a static false detection (the mooring post): real objects, rejected by selection."""
    confirmed_rmse_px: float
    """RMS distance of confirmed, updated track centres to the vessel's true screen position."""
    detection_rmse_px: float
    """RMS distance of the same updates' raw detection centres to the true position."""
    coverage: float
    """Share of (vessel, frame) pairs with the vessel visible in which a confirmed track held its detection
    or a coasting track was within 40 px of it."""
    samples: int

    def summary(self) -> str:
        """One line for logs and benchmark output."""
        return (f"id_switches={self.id_switches} tracks_per_vessel={self.tracks_per_vessel} "
                f"false_confirmed={self.false_confirmed_tracks} static_clutter_tracks={self.static_clutter_tracks} "
                f"confirmed_rmse={self.confirmed_rmse_px:.2f}px detection_rmse={self.detection_rmse_px:.2f}px "
                f"coverage={self.coverage:.3f} n={self.samples}")


def run_tracker(result: SimResult, update: Callable[[float, np.ndarray, np.ndarray], Iterable]) -> list[list]:
    """Feed every frame to ``update(stamp, boxes, scores)`` (e.g. ``MultiTargetTracker.update``); its outputs."""
    return [list(update(f.stamp, f.boxes_xyxy, f.scores)) for f in result.frames]


_STATIC = -2


def score_tracking(result: SimResult, outputs: Sequence[Sequence]) -> TrackingMetrics:
    """Score tracker outputs (one list of ``TrackState`` per frame of ``result``) against the truth.

    A track state's detection is found from its ``measured_center`` (the raw centre it was updated with),
    which gives the vessel id behind it.
    """
    if len(outputs) != len(result.frames):
        raise DataError(f"{len(outputs)} tracker outputs for {len(result.frames)} frames")
    tally = _Tally()
    for k, (frame, states) in enumerate(zip(result.frames, outputs, strict=True)):
        centers = frame.centers
        held: set[int] = set()
        for s in states:
            _count_state(tally, result, k, frame, centers, s, held)
        for vid, tr in result.truth.items():
            if tr.visible[k]:
                tally.visible_frames += 1
                if vid in held or _coasting_near(states, tr.screen_xy[k]):
                    tally.covered_frames += 1

    def majority(tid: str) -> int:
        values, counts = np.unique(tally.votes.get(tid, [-1]), return_counts=True)
        return int(values[np.argmax(counts)])

    kinds = [majority(tid) for tid in tally.confirmed_ids]
    err_track, err_det = tally.err_track, tally.err_det
    return TrackingMetrics(
        id_switches=tally.switches,
        tracks_per_vessel={vid: len(tally.tracks_of.get(vid, ())) for vid in sorted(result.truth)},
        false_confirmed_tracks=sum(1 for g in kinds if g == -1),
        static_clutter_tracks=sum(1 for g in kinds if g == _STATIC),
        confirmed_rmse_px=float(np.sqrt(np.mean(np.square(err_track)))) if err_track else math.nan,
        detection_rmse_px=float(np.sqrt(np.mean(np.square(err_det)))) if err_det else math.nan,
        coverage=tally.covered_frames / tally.visible_frames if tally.visible_frames else math.nan,
        samples=len(err_track))


@dataclass
class _Tally:
    """What ``score_tracking`` counts over the frames."""

    last_track: dict[int, str] = field(default_factory=dict)  # vessel id -> the track that last held it
    switches: int = 0
    tracks_of: dict[int, set[str]] = field(default_factory=dict)
    votes: dict[str, list[int]] = field(default_factory=dict)  # track id -> the truth behind each detection
    confirmed_ids: set[str] = field(default_factory=set)
    err_track: list[float] = field(default_factory=list)
    err_det: list[float] = field(default_factory=list)
    visible_frames: int = 0
    covered_frames: int = 0


def _count_state(tally: _Tally, result: SimResult, k: int, frame: SimFrame, centers: np.ndarray, s,
                 held: set[int]) -> None:
    """Tally one track state of frame ``k``; a vessel it holds (confirmed or coasting, updated) goes into ``held``."""
    status = int(s.status)
    if status == 3:
        return
    if status in (1, 2):
        tally.confirmed_ids.add(s.track_id)
    if s.measured_center is None or not len(centers):
        return
    d = np.hypot(*(centers - np.asarray(s.measured_center)).T)
    j = int(np.argmin(d))
    if d[j] > 1e-6:
        return
    gt = _STATIC if frame.static_clutter[j] else int(frame.gt_ids[j])
    tally.votes.setdefault(s.track_id, []).append(gt)
    if status == 0 or gt < 0:
        return
    held.add(gt)
    if tally.last_track.get(gt, s.track_id) != s.track_id:
        tally.switches += 1
    tally.last_track[gt] = s.track_id
    tally.tracks_of.setdefault(gt, set()).add(s.track_id)
    true_xy = result.truth[gt].screen_xy[k]
    tally.err_track.append(float(np.hypot(*(np.asarray(s.center) - true_xy))))
    tally.err_det.append(float(np.hypot(*(np.asarray(s.measured_center) - true_xy))))


def _coasting_near(states: Sequence, true_xy: np.ndarray, radius_px: float = 40.0) -> bool:
    return any(int(s.status) == 2 and float(np.hypot(*(np.asarray(s.center) - true_xy))) < radius_px
               for s in states)

