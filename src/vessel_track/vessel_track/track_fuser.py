"""Per-track online fusion: each track's box to the sea plane, a world Kalman filter per track, the target.

``TrackFuser`` takes every screen track of one image (``ScreenTrack``, from a ``TrackState`` or a ``VesselTrack``
message), fuses the boxes measured in it (``vessel_track.fusion.fuse_boxes``), runs a ``WorldKalmanFilter`` per
track and the online vessel-of-interest selection (``vessel_track.selection``), and returns a ``WorldTrack`` per
track: it is the core of the ``fuser`` node and of the pipeline's online mode.

The world filters live in one fixed frame: metres east/north of the calibration's camera position
(``camera_lat``/``camera_lon``). A camera on a moving platform measures each box relative to where it is at that
moment; ``update(..., camera_offset=)`` gives that position in the fixed frame, and each measurement is shifted by
it before it meets a filter, so the filters track the vessels over ground, not relative to a moving camera. The
camera's heading needs no correction here: the tracker maps the boxes into the calibration's reference image.
"""
from __future__ import annotations

import copy
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from vessel_calib import geodesy
from vessel_common.errors import CalibrationError, DataError
from vessel_common.state_file import fields_of, object_state, restore_object, set_fields
from vessel_track.distance_model import BoxSizeDistanceModel
from vessel_track.error_model import ErrorModel
from vessel_track.fusion import (
    HEIGHT_HISTORY,
    REASON_INVALID_INPUT,
    REASON_NAMES,
    SHAPE_HISTORY,
    CueStatistics,
    FusedBoxes,
    FusionConfig,
    boxes_from_centers,
    fuse_boxes,
)
from vessel_track.selection import OnlineTargetSelector, _Running
from vessel_track.selection_config import SelectionConfig
from vessel_track.smoothing import FilterOutput, MotionConfig, WorldKalmanFilter


@dataclass
class ScreenTrack:
    """One tracked vessel as the fuser receives it (from a ``TrackState`` or a ``VesselTrack`` message)."""

    track_id: str
    status: int                 # TrackStatus / VesselTrack.STATUS_*
    center: np.ndarray          # (2,) px
    size: np.ndarray            # (2,) px
    confidence: float
    updated: bool               # a detection was associated in this frame
    detection_count: int = 0
    first_seen: float = math.nan
    last_seen: float = math.nan
    center_cov: np.ndarray | None = None
    velocity_px: np.ndarray | None = None
    pose_sigma_px: np.ndarray | None = None  # (2,) the camera pose's share of the box's ideal x, y std, px

    @property
    def box_xyxy(self) -> np.ndarray:
        """(4,) box around the centre."""
        return boxes_from_centers(self.center, self.size)[0]


STATUS_LOST = 3
STATUS_TENTATIVE = 0


@dataclass
class WorldTrack:
    """A track after fusion: the screen track plus its filtered sea-plane state (NaN when unknown).

    ``position`` and ``velocity`` are in the fixed frame (east/north of the calibration's camera position, over
    ground); ``camera_offset`` is the camera's position in that frame at this stamp (None: the calibration's, a
    fixed camera), so ``relative_position`` is the vessel east/north of the camera now. ``distance_m`` and
    ``bearing_deg`` are from the camera now. ``velocity_known``: the filter has taken a second measurement since it
    started, so its velocity is measured rather than its zero prior.
    """

    screen: ScreenTrack
    stamp: float
    has_world: bool = False
    position: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    velocity: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    position_covariance: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    velocity_covariance: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    latitude: float = math.nan
    longitude: float = math.nan
    distance_m: float = math.nan
    bearing_deg: float = math.nan
    expected_error_m: float = math.nan
    is_target: bool = False
    score: float = 0.0
    measured_position: np.ndarray | None = None   # this frame's fused (unfiltered) position, if any
    measured_covariance: np.ndarray | None = None
    measured_screen: np.ndarray | None = None     # the fused point on screen, px
    rejected_reason: str = ""                     # why this frame's box gave no position ("" if it did)
    position_velocity_covariance: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    camera_offset: np.ndarray | None = None
    velocity_known: bool = False

    @property
    def relative_position(self) -> np.ndarray:
        """The position east/north of the camera at this stamp (``position`` itself for a fixed camera)."""
        return self.position if self.camera_offset is None else self.position - self.camera_offset


class TrackFuser:
    """Per-frame fusion, per-track world Kalman filter and online target selection.

    The filters follow the selection's view of identity: a track the selection joins to an earlier one continues
    that one's filter, and a track whose filter restarts after ``motion.max_rejections`` outliers in a row has its
    selection history ended (``OnlineTargetSelector.identity_changed``).

    ``update(stamp, tracks, camera_offset)`` takes every track of one image (``ScreenTrack``) and the camera's
    position then (see the module docstring) and returns a ``WorldTrack`` for each. ``counts`` records bad input
    and rejections by kind (for the node's diagnostics).
    """

    def __init__(self, camera, distance_model: BoxSizeDistanceModel | None = None,
                 fusion_config: FusionConfig | None = None, cue_stats: CueStatistics | None = None,
                 motion_config: MotionConfig | None = None, selection_config: SelectionConfig | None = None,
                 error_model: ErrorModel | None = None, water_level=None, water_level_max_hold_s: float = 900.0):
        if camera.camera_lat is None:
            raise DataError("fuser: the camera model has no position (camera_lat/camera_lon); set them in the "
                            "calibration file")
        if water_level is not None and not math.isfinite(camera.water_level_m):
            raise DataError(f"fuser: a water-level file is set ({water_level.source or 'water_level.file'}) but the "
                            "calibration has no camera.water_level_m to correct from; re-run calibrate with "
                            "--water-level FILE.csv, or set water_level.file to ''")
        self.camera = camera
        self.water_level = water_level
        self.water_level_max_hold_s = float(water_level_max_hold_s)
        self.distance_model = distance_model or BoxSizeDistanceModel()
        self.fusion_config = fusion_config or FusionConfig()
        self.cue_stats = cue_stats or CueStatistics()
        self.motion_config = motion_config or MotionConfig()
        self.selector = OnlineTargetSelector(selection_config or SelectionConfig())
        self.error_model = error_model or ErrorModel()
        self.filters: dict[str, WorldKalmanFilter] = {}
        self._ended_filters: dict[str, WorldKalmanFilter] = {}   # of ended tracks, while a join may continue them
        self._shapes: dict[str, deque] = {}   # recent (aspect, height) of each track's boxes (shape_jump, height_drop)
        self._velocity_known: set[str] = set()  # filters (by track id) that took a second measurement since start
        self._camera_offset: np.ndarray | None = None  # this frame's camera position in the fixed frame
        self.last_stamp: float | None = None
        self.counts: dict[str, int] = {}

    def _count(self, kind: str) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + 1

    def reset(self) -> None:
        """Forget every track (a replay restarted)."""
        self.filters.clear()
        self._ended_filters.clear()
        self._shapes.clear()
        self._velocity_known.clear()
        self.selector.reset()
        self.last_stamp = None

    def snapshot(self) -> dict:
        """The world filters and selection history ``restore`` needs to carry on in another process, as plain data.

        Numbers, strings, containers and numpy arrays only: what a state file holds (``vessel_common.state_file``).
        Each world filter and the selector by its attributes, except the settings (the restored fuser's own).
        """
        def filters(by_id: dict) -> dict:
            return {track_id: fields_of(kf, skip=("config",)) for track_id, kf in by_id.items()}

        return {"filters": filters(self.filters), "ended_filters": filters(self._ended_filters),
                "shapes": {track_id: list(shapes) for track_id, shapes in self._shapes.items()},
                "selector": object_state(self.selector, _Running, skip=("config",)), "last_stamp": self.last_stamp}

    def restore(self, snapshot: dict) -> None:
        """Carry on from ``snapshot()`` of a fuser with the same settings (a node restarted after a crash).

        ValueError (KeyError, TypeError) for a snapshot with other fields than this version's: the fuser is then
        left as it was. Which filters have measured a velocity is not in the snapshot (it would change the state
        file's fields): each restored track counts as not having one until its next accepted measurement.
        """
        def filters(by_id: dict) -> dict:
            return {str(track_id): set_fields(WorldKalmanFilter(self.motion_config), fields, "a world filter",
                                              skip=("config",)) for track_id, fields in dict(by_id).items()}

        shapes = {str(track_id): deque(((float(aspect), float(height)) for aspect, height in history),
                                       maxlen=SHAPE_HISTORY) for track_id, history in dict(snapshot["shapes"]).items()}
        selector = restore_object(OnlineTargetSelector(self.selector.config), snapshot["selector"], _Running,
                                  "the target selection", skip=("config",))
        restored = (filters(snapshot["filters"]), filters(snapshot["ended_filters"]), shapes, selector,
                    None if snapshot["last_stamp"] is None else float(snapshot["last_stamp"]))
        self.filters, self._ended_filters, self._shapes, self.selector, self.last_stamp = restored
        self._velocity_known = set()

    def update(self, stamp: float, tracks: list[ScreenTrack], camera_offset=None) -> list[WorldTrack]:
        """Fuse one frame's tracks; raises DataError only for a non-finite stamp or camera offset.

        ``camera_offset``: the camera's position at ``stamp``, metres east/north of the calibration's camera
        position (None: there, a fixed camera).
        """
        offset = None if camera_offset is None else _checked_offset(camera_offset)
        stamp = self._take_stamp(stamp)
        self._camera_offset = offset
        out, good = self._refuse_invalid(stamp, tracks)
        world_tracks, changed_identity = self._world_tracks(stamp, good)
        present = {t.track_id for t in tracks}
        for tid in [t for t in self.filters if t not in present]:
            self._ended_filters[tid] = self.filters.pop(tid)  # vanished without a LOST report
        live = {t.track_id for t in good if t.status != STATUS_LOST}
        self._shapes = {tid: history for tid, history in self._shapes.items() if tid in live}
        for tid in changed_identity:
            self.selector.identity_changed(tid, stamp)
        target = self.selector.update(stamp, world_tracks)
        self._continue_filters(stamp, world_tracks)
        max_gap = self.selector.config.join_max_gap_s
        self._ended_filters = {tid: kf for tid, kf in self._ended_filters.items()
                               if kf.stamp is not None and 0 <= stamp - kf.stamp <= max_gap}
        self._velocity_known &= set(self.filters) | set(self._ended_filters)
        for wt in world_tracks:
            wt.score = self.selector.score(wt.screen.track_id)
            wt.is_target = target is not None and wt.screen.track_id == target and wt.screen.status != STATUS_LOST
        return out + world_tracks

    def _take_stamp(self, stamp: float) -> float:
        """The frame's stamp as seconds; stamps going back reset the fuser (a replay restarted)."""
        stamp = float(stamp)
        if not math.isfinite(stamp):
            raise DataError(f"fuser: stamp must be finite seconds, got {stamp}")
        if self.last_stamp is not None and stamp < self.last_stamp:
            self._count("stamp_backwards")
            self.reset()
        elif self.last_stamp is not None and stamp - self.last_stamp > self.motion_config.max_gap_s:
            self._count("gap")
        self.last_stamp = stamp
        return stamp

    def _refuse_invalid(self, stamp: float, tracks: list[ScreenTrack]) -> tuple[list[WorldTrack], list[ScreenTrack]]:
        """The world tracks of the tracks with a non-finite or empty box (no position), and the good tracks."""
        out: list[WorldTrack] = []
        good: list[ScreenTrack] = []
        for track in tracks:
            if not (np.all(np.isfinite(track.center)) and np.all(np.isfinite(track.size)) and
                    np.all(np.asarray(track.size) > 0)):
                self._count("invalid_track")
                out.append(WorldTrack(track, stamp, rejected_reason=REASON_NAMES[REASON_INVALID_INPUT]))
                if track.status == STATUS_LOST:
                    self.filters.pop(track.track_id, None)
                continue
            good.append(track)
        return out, good

    def _world_tracks(self, stamp: float, good: list[ScreenTrack]) -> tuple[list[WorldTrack], list[str]]:
        """Each good track's world state after this frame, and the tracks whose world motion broke (identity)."""
        measured = [t for t in good if t.updated and t.status != STATUS_LOST]
        fused = None
        if measured:
            boxes = np.array([t.box_xyxy for t in measured]).reshape(-1, 4)
            pose_sigma = np.array([t.pose_sigma_px if t.pose_sigma_px is not None else (0.0, 0.0) for t in measured])
            fused = fuse_boxes(self.camera_at(stamp), self.distance_model, boxes, self.fusion_config, self.cue_stats,
                               pose_sigma)
            if self._camera_offset is not None:
                fused.world = fused.world + self._camera_offset  # camera-relative -> the filters' fixed frame
        fused_by_id = {t.track_id: i for i, t in enumerate(measured)}
        world_tracks: list[WorldTrack] = []
        changed_identity: list[str] = []
        for track in good:
            wt = WorldTrack(track, stamp)
            kf = self.filters.get(track.track_id)
            result: FilterOutput | None = None
            if track.status == STATUS_LOST:
                if kf is not None and kf.initialised:
                    result = kf.predict(stamp)
                    self._ended_filters[track.track_id] = kf
                self.filters.pop(track.track_id, None)
            elif track.track_id in fused_by_id:
                if kf is None:
                    kf = self.filters[track.track_id] = WorldKalmanFilter(self.motion_config)
                result = self._measure(stamp, track, wt, kf, fused, fused_by_id[track.track_id])
                if result is not None and result.restart_reason == "rejections":
                    changed_identity.append(track.track_id)
                self._note_velocity(track.track_id, result, track.track_id)
            elif kf is not None and kf.initialised:
                result = kf.predict(stamp)
            if result is not None:
                self._fill_world(wt, result)
                wt.velocity_known = track.track_id in self._velocity_known
            world_tracks.append(wt)
        return world_tracks, changed_identity

    def _measure(self, stamp: float, track: ScreenTrack, wt: WorldTrack, kf: WorldKalmanFilter, fused: FusedBoxes,
                 i: int) -> FilterOutput | None:
        """Box ``i`` of this frame's fusion into the track's world filter, or why it gave no position."""
        if not fused.valid[i]:
            wt.rejected_reason = REASON_NAMES[int(fused.reason[i])]
            self._count(wt.rejected_reason)
            return kf.predict(stamp) if kf.initialised else None
        wt.measured_position = fused.world[i].copy()
        wt.measured_covariance = fused.covariance[i] * self._shape_factor(track)
        wt.measured_screen = fused.screen[i].copy()
        result = kf.update(stamp, fused.world[i], wt.measured_covariance)
        if result is not None and not result.accepted and not result.restarted:
            self._count("outlier_rejected")
        if result is not None and result.restart_reason == "rejections":
            self._count("identity_changed")
        return result

    def camera_at(self, stamp: float):
        """The camera for the water level at ``stamp`` (the calibration's own without a water-level file)."""
        if self.water_level is None:
            return self.camera
        level = self.water_level.level_at(stamp, self.water_level_max_hold_s)
        if not math.isfinite(level):
            self._count("water_level_unknown")
            return self.camera
        try:
            return self.camera.at_water_level(level)
        except CalibrationError:
            self._count("water_level_unusable")
            return self.camera

    def _shape_factor(self, track: ScreenTrack) -> float:
        """Covariance multiplier of this frame's box: ``shape_jump_variance_factor`` if it is suspect, else 1.

        Suspect: its aspect jumped up, or its height dropped, against the track's recent boxes.
        """
        config = self.fusion_config
        history = self._shapes.setdefault(track.track_id, deque(maxlen=SHAPE_HISTORY))
        aspect = float(track.size[1] / track.size[0])
        height = float(track.size[1])
        aspects = [a for a, _ in history]
        heights = [h for _, h in history][-HEIGHT_HISTORY:]
        jumped = config.shape_jump_ratio > 0 and len(aspects) >= 2 and aspect > config.shape_jump_ratio * float(
            np.median(aspects))
        dropped = config.height_drop_ratio > 0 and len(heights) >= 2 and height < config.height_drop_ratio * float(
            np.median(heights))
        history.append((aspect, height))
        if jumped:
            self._count("shape_jump")
        if dropped:
            self._count("height_drop")
        return config.shape_jump_variance_factor if jumped or dropped else 1.0

    def _continue_filters(self, stamp: float, world_tracks: list[WorldTrack]) -> None:
        """A track the selection joined to an earlier one (``selector.continued``) continues that one's filter too.

        Its own filter started from this frame's measurement with no velocity; the earlier track's filter knows
        how the vessel was moving, so the next frames are gated against that motion (a track that then jumps onto
        another vessel is seen by the world gate: ``identity_changed``).
        """
        by_id = {wt.screen.track_id: wt for wt in world_tracks}
        for new_id, old_id in self.selector.continued.items():
            wt = by_id.get(new_id)
            old = self._ended_filters.pop(old_id, None)
            if old is None and old_id in self.filters:
                old = copy.deepcopy(self.filters[old_id])  # a handover: the old track still coasts on its own
            if wt is None or old is None or not old.initialised or wt.measured_position is None:
                continue
            result = old.update(stamp, wt.measured_position, wt.measured_covariance)
            if result is None:
                continue
            if not result.accepted and not result.restarted:
                self._count("outlier_rejected")
            self.filters[new_id] = old
            self._note_velocity(new_id, result, old_id)
            self._fill_world(wt, result)
            wt.velocity_known = new_id in self._velocity_known

    def _note_velocity(self, track_id: str, result: FilterOutput | None, previous_id: str) -> None:
        """Whether ``track_id``'s filter has measured a velocity after this step (``previous_id``'s before it).

        A (re)start leaves only the zero prior; an accepted measurement after it is the second, which measures it;
        a rejected one or a prediction leaves it as it was.
        """
        known = previous_id in self._velocity_known
        if result is not None and result.restarted:
            known = False
        elif result is not None and result.accepted:
            known = True
        if known:
            self._velocity_known.add(track_id)
        else:
            self._velocity_known.discard(track_id)

    def _fill_world(self, wt: WorldTrack, result: FilterOutput) -> None:
        clip = self.fusion_config.clip_m
        offset = self._camera_offset
        if offset is None:
            position = np.clip(result.position, -clip, clip)
            relative = position
            camera_lat, camera_lon = self.camera.camera_lat, self.camera.camera_lon
        else:  # clipped about the camera, where fusion.clip_m means it
            relative = np.clip(result.position - offset, -clip, clip)
            position = offset + relative
            camera_lat, camera_lon = geodesy.local_to_gps(offset[0], offset[1], self.camera.camera_lat,
                                                          self.camera.camera_lon)
        wt.has_world = True
        wt.position = position
        wt.camera_offset = None if offset is None else offset.copy()
        wt.velocity = result.velocity
        wt.position_covariance = result.position_covariance
        wt.velocity_covariance = result.velocity_covariance
        wt.position_velocity_covariance = result.covariance[:2, 2:].copy()
        lat, lon = geodesy.local_to_gps(position[0], position[1], self.camera.camera_lat, self.camera.camera_lon)
        wt.latitude, wt.longitude = float(lat), float(lon)
        wt.distance_m = float(np.hypot(relative[0], relative[1]))
        wt.bearing_deg = float(geodesy.bearing_deg(camera_lat, camera_lon, lat, lon))
        wt.expected_error_m = float(self.error_model.expected_error_m(wt.distance_m))


def _checked_offset(camera_offset) -> np.ndarray:
    offset = np.asarray(camera_offset, dtype=float).reshape(-1)
    if offset.shape != (2,) or not np.all(np.isfinite(offset)):
        raise DataError(f"fuser: camera_offset must be 2 finite metres (east, north), got {camera_offset!r}")
    return offset
