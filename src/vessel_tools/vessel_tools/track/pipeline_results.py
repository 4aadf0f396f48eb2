"""What a pipeline run produced per video, and the CSV files it is written to.

A video's result holds the vessel of interest's predictions (``predictions.csv``: ``video,t_utc_s,lat,lon``) and
every track in every frame (``tracks.csv``); ``write_target_measurement_csvs`` sets the online target's own boxes
back-projected beside what the filter published in the same frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vessel_calib import geodesy
from vessel_tools.track.offline_data import PREDICTION_HEADER, atomic_lines, prediction_line, seconds_of_day
from vessel_track.track_fuser import WorldTrack


@dataclass
class Prediction:
    """One predicted position of the vessel of interest."""

    video: int
    stamp: float
    lat: float
    lon: float
    x: float
    y: float
    track_id: str
    measured: bool


@dataclass
class TrackRow:
    """One track in one frame (tracks.csv)."""

    video: int
    frame: int
    stamp: float
    world: WorldTrack


@dataclass
class VideoResult:
    """Everything one video produced."""

    video: int
    predictions: list[Prediction] = field(default_factory=list)
    track_rows: list[TrackRow] = field(default_factory=list)
    target_members: list[str] = field(default_factory=list)
    counts: dict = field(default_factory=dict)



def write_predictions_csv(path: Path, results: list[VideoResult]) -> None:
    """``video,t_utc_s,lat,lon`` for the vessel of interest."""
    lines = [PREDICTION_HEADER]
    for result in results:
        lines += [prediction_line(p.video, p.stamp, p.lat, p.lon) for p in result.predictions]
    atomic_lines(Path(path), lines)


TRACK_COLUMNS = ("video,frame,t_utc_s,track_id,status,is_target,score,confidence,updated,has_world,x_east_m,"
                 "y_north_m,lat,lon,distance_m,bearing_deg,expected_error_m,measured_x_m,measured_y_m")


def write_tracks_csv(path: Path, results: list[VideoResult]) -> None:
    """Every track in every frame, with its filtered position and this frame's fused measurement."""
    lines = [TRACK_COLUMNS]

    def num(value, spec=".3f"):
        return format(value, spec) if value is not None and math.isfinite(value) else ""

    for result in results:
        for row in result.track_rows:
            wt = row.world
            mx, my = (wt.measured_position if wt.measured_position is not None else (math.nan, math.nan))
            lines.append(",".join([
                str(row.video), str(row.frame), f"{seconds_of_day(row.stamp):.3f}", wt.screen.track_id,
                str(int(wt.screen.status)), str(int(wt.is_target)), num(wt.score), num(wt.screen.confidence),
                str(int(wt.screen.updated)), str(int(wt.has_world)), num(wt.position[0]), num(wt.position[1]),
                num(wt.latitude, ".8f"), num(wt.longitude, ".8f"), num(wt.distance_m), num(wt.bearing_deg, ".2f"),
                num(wt.expected_error_m), num(mx), num(my)]))
    atomic_lines(Path(path), lines)


def write_target_measurement_csvs(folder: Path, results: list[VideoResult], camera_lat: float,
                                  camera_lon: float) -> tuple[Path, Path]:
    """The online target's own boxes back-projected, and what the filter published, in the same frames.

    ``target_measured.csv``: the target's fused measurement in each frame that has one (its box back-projected,
    no filter); ``target_filtered.csv``: the filter's position in those frames. Scored side by side they say
    whether the filter improves on the very boxes it was given.
    """
    measured, filtered = [PREDICTION_HEADER], [PREDICTION_HEADER]
    for result in results:
        for row in result.track_rows:
            wt = row.world
            if not (wt.is_target and wt.has_world and wt.measured_position is not None):
                continue
            if not np.all(np.isfinite(wt.measured_position)):
                continue
            lat, lon = geodesy.local_to_gps(wt.measured_position[0], wt.measured_position[1], camera_lat, camera_lon)
            measured.append(prediction_line(row.video, row.stamp, lat, lon))
            filtered.append(prediction_line(row.video, row.stamp, wt.latitude, wt.longitude))
    paths = (Path(folder) / "target_measured.csv", Path(folder) / "target_filtered.csv")
    atomic_lines(paths[0], measured)
    atomic_lines(paths[1], filtered)
    return paths

