"""Synthetic detections of vessels on known paths, seen through a known camera: ground truth for the tracker.

Vessels move on the sea plane (metres east/north of the camera, the project's world frame) along straight lines,
arcs or waypoints; each frame projects them through a ``CameraModel``, draws a box whose size follows the
box-size model ``w = a_w/|z_p| + b_w``, ``h = a_h/|z_p| + b_h`` (full-resolution pixels, fitted to the tight hand
boxes of the challenge data), and then plays the detector: centre and size noise, misses, random false
detections below the horizon, a static false detection (the mooring post of the challenge camera), vessels
hidden behind nearer ones and scheduled occlusions. Everything is drawn from one seeded generator, so a
scenario is reproducible.

ROS-free; used by the tracker's and the fuser's tests and benchmarks. The frames and truth a run gives, and the
score of a tracker against them, are ``vessel_tools.track.tracking_score``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from vessel_calib.camera_model import CameraModel
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_tools.track.tracking_score import SimFrame, SimResult, VesselTruth, run_tracker, score_tracking
from vessel_track.distance_model import BoxSizeDistanceModel, depth_scale
from vessel_track.fuser_settings import FuserSettings
from vessel_track.fusion import fit_cue_statistics
from vessel_track.tracker import MultiTargetTracker
from vessel_track.tracker_config import TrackerConfig

CHALLENGE_H = ((-441.0, 379.0, -1000.0), (-217.0, -56.5, -548.0), (-0.512, -0.144, 1.0))
"""The paper's homography of the challenge camera with its sign typo corrected (``aitas/camera.json``)."""
CHALLENGE_K1 = -4.053e-7
CHALLENGE_CAMERA_LATLON = (32.70297, -117.234631)
MOORING_POST_XYXY = (697.0, 652.0, 925.0, 720.0)
"""Box of the mooring post at the bottom of every challenge frame, a frequent false detection, px."""


def challenge_camera():
    """The challenge camera: the paper's corrected calibration (H, K1, centre (640, 360), 1280x720)."""
    return CameraModel(CHALLENGE_H, CHALLENGE_K1, center=(640.0, 360.0), image_size=(1280, 720),
                       camera_lat=CHALLENGE_CAMERA_LATLON[0], camera_lon=CHALLENGE_CAMERA_LATLON[1])


def bearing_point(distance_m: float, bearing_deg: float) -> tuple[float, float]:
    """World point (east, north), metres, at ``distance_m`` from the camera on ``bearing_deg`` (0 = north)."""
    b = math.radians(bearing_deg)
    return distance_m * math.sin(b), distance_m * math.cos(b)


# ---------------------------------------------------------------------------------------------------- paths


@dataclass(frozen=True)
class LinePath:
    """Straight line at constant speed: ``start_xy`` (m) at t = 0, moving on ``heading_deg`` (0 = north)."""

    start_xy: tuple[float, float]
    heading_deg: float
    speed_mps: float

    def position(self, t: np.ndarray) -> np.ndarray:
        """(N, 2) east, north in metres at ``t`` seconds after the vessel's start."""
        h = math.radians(self.heading_deg)
        t = np.asarray(t, dtype=float).reshape(-1)
        return np.c_[self.start_xy[0] + self.speed_mps * math.sin(h) * t,
                     self.start_xy[1] + self.speed_mps * math.cos(h) * t]


@dataclass(frozen=True)
class ArcPath:
    """Circular arc at constant speed around ``center_xy`` (m), starting on ``start_bearing_deg`` from it."""

    center_xy: tuple[float, float]
    radius_m: float
    start_bearing_deg: float
    speed_mps: float
    clockwise: bool = True

    def position(self, t: np.ndarray) -> np.ndarray:
        """(N, 2) east, north in metres at ``t`` seconds after the vessel's start."""
        t = np.asarray(t, dtype=float).reshape(-1)
        turn = (1.0 if self.clockwise else -1.0) * self.speed_mps * t / self.radius_m
        b = math.radians(self.start_bearing_deg) + turn
        return np.c_[self.center_xy[0] + self.radius_m * np.sin(b), self.center_xy[1] + self.radius_m * np.cos(b)]


@dataclass(frozen=True)
class WaypointPath:
    """Piecewise-straight path through ``points`` (m) at constant speed; stays at the last point."""

    points: tuple[tuple[float, float], ...]
    speed_mps: float

    def __post_init__(self) -> None:
        """Reject paths that cannot be followed."""
        if len(self.points) < 2 or self.speed_mps <= 0:
            raise DataError("WaypointPath needs at least two points and a positive speed")

    def position(self, t: np.ndarray) -> np.ndarray:
        """(N, 2) east, north in metres at ``t`` seconds after the vessel's start."""
        pts = np.asarray(self.points, dtype=float)
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        s_knots = np.r_[0.0, np.cumsum(seg)]
        s = np.clip(np.asarray(t, dtype=float).reshape(-1) * self.speed_mps, 0.0, s_knots[-1])
        return np.c_[np.interp(s, s_knots, pts[:, 0]), np.interp(s, s_knots, pts[:, 1])]


# ---------------------------------------------------------------------------------------------------- models


@dataclass(frozen=True)
class BoxSizeModel:
    """Box size from the homography's z_p: ``w = a_w/|z_p| + b_w``, ``h = a_h/|z_p| + b_h``, full-res px.

    Defaults: least squares of the relative error on the 144 primary hand boxes of the challenge data with
    valid GPS (videos 7-17; median relative error 20 % in w and h). Within 150-250 m they give the boxes
    measured there (w 22-27 px, h 10-13 px). The paper's training boxes (1500/|z_p| + 25, 850/|z_p| + 25 at
    half resolution) are looser on purpose.
    """

    a_w: float = 2103.0
    b_w: float = 2.7
    a_h: float = 1094.0
    b_h: float = 0.9

    def size(self, abs_zp: np.ndarray) -> np.ndarray:
        """(N, 2) box width and height in px for ``|z_p|``."""
        abs_zp = np.asarray(abs_zp, dtype=float).reshape(-1)
        return np.c_[self.a_w / abs_zp + self.b_w, self.a_h / abs_zp + self.b_h]


@dataclass(frozen=True)
class DetectorModel:
    """How the simulated detector errs. Pixels are full resolution."""

    center_std_px: float = 4.0
    """Gaussian noise of a box centre (hand labels: ~2.7 px between two labelling passes)."""
    size_std_frac: float = 0.08
    """Gaussian noise of the box width and height, as a fraction of the true size."""
    miss_prob: float = 0.1
    """Probability that a visible vessel is not detected in a frame."""
    clutter_rate: float = 0.3
    """Mean number of random false detections per frame (Poisson), anywhere on the water below the horizon."""
    clutter_size_px: tuple[float, float, float, float] = (12.0, 80.0, 8.0, 40.0)
    """Range of false-detection sizes: w_min, w_max, h_min, h_max, px."""
    static_clutter: tuple[tuple[float, float, float, float], ...] = (MOORING_POST_XYXY,)
    """Boxes that are falsely detected at a fixed place (the mooring post), xyxy px."""
    static_clutter_prob: float = 0.5
    """Probability per frame that each static false detection fires."""
    vessel_score_range: tuple[float, float] = (0.45, 0.95)
    clutter_score_range: tuple[float, float] = (0.25, 0.6)
    occlusion_overlap: float = 0.5
    """A vessel is hidden (not detected) when a nearer vessel's box covers more than this fraction of its box."""
    image_margin_px: float = 0.0
    """A vessel whose box centre is closer than this to the image border is not detected."""


@dataclass(frozen=True)
class SimVessel:
    """One vessel: an id (>= 0), a path and when it is on the water (seconds from the scenario start)."""

    vessel_id: int
    path: LinePath | ArcPath | WaypointPath
    start_s: float = 0.0
    end_s: float = math.inf
    occlusions: tuple[tuple[float, float], ...] = ()
    """Intervals (seconds from the scenario start) when the vessel is hidden from the detector."""
    size_scale: float = 1.0
    """Scale of the box-size model for this vessel (2: a vessel twice as large as the labelled boat)."""
    score_range: tuple[float, float] | None = None
    """Detector confidences of this vessel's boxes (uniform); None: ``DetectorModel.vessel_score_range``."""

    def __post_init__(self) -> None:
        """Ids must be non-negative: -1 marks clutter in the output."""
        if self.vessel_id < 0:
            raise DataError(f"vessel ids must be >= 0 (-1 marks clutter), got {self.vessel_id}")


# ---------------------------------------------------------------------------------------------------- scenario


@dataclass
class Scenario:
    """Vessels, a camera, a frame clock and a detector model; ``run()`` draws the frames."""

    vessels: Sequence[SimVessel]
    camera: object = None
    """A ``vessel_calib.camera_model.CameraModel``; None: the challenge camera."""
    duration_s: float = 180.0
    frame_interval_s: float = 4.0
    """Seconds between frames: ~4 s like the challenge frames, 0.03-0.1 s like a live camera."""
    frame_jitter_s: float = 0.0
    """Uniform jitter of each frame's stamp, seconds (a live camera's variable frame rate)."""
    start_stamp: float = 1601494438.0
    """Epoch seconds of the first frame (default: 2020-09-30 19:33:58 UTC, the challenge day)."""
    detector: DetectorModel = field(default_factory=DetectorModel)
    box_size: BoxSizeModel = field(default_factory=BoxSizeModel)
    seed: int = 0

    def run(self) -> SimResult:
        """Simulate every frame; the same scenario and seed always give the same result."""
        if self.frame_interval_s <= 0 or self.duration_s <= 0:
            raise DataError("Scenario needs a positive duration_s and frame_interval_s")
        ids = [v.vessel_id for v in self.vessels]
        if len(set(ids)) != len(ids):
            raise DataError(f"Scenario vessel ids must be unique, got {ids}")
        camera = self.camera if self.camera is not None else challenge_camera()
        rng = np.random.default_rng(self.seed)
        width, height = camera.image_size

        rel = np.arange(0.0, self.duration_s + 1e-9, self.frame_interval_s)
        if self.frame_jitter_s > 0:
            rel = rel + rng.uniform(-self.frame_jitter_s, self.frame_jitter_s, len(rel))
            rel = np.maximum.accumulate(np.maximum(rel, 0.0))
        truth = {v.vessel_id: self._truth_of(v, camera, rel) for v in self.vessels}

        horizon = float(np.nanmax(camera.horizon_y(np.linspace(0.0, width, 9))))
        if not math.isfinite(horizon):
            horizon = height / 2.0
        frames: list[SimFrame] = []
        for k in range(len(rel)):
            self._hide_behind_nearer(truth, k)
            frames.append(self._detections(k, float(self.start_stamp + rel[k]), truth, rng, horizon, (width, height)))
        return SimResult(frames=frames, truth=truth, camera=camera)

    def _truth_of(self, v: SimVessel, camera, rel: np.ndarray) -> VesselTruth:
        """Where vessel ``v`` is at each frame (``rel``: seconds from the start), its true box, when it is visible."""
        width, height = camera.image_size
        n_frames = len(rel)
        on_water = (rel >= v.start_s) & (rel <= v.end_s)
        xy = v.path.position(rel - v.start_s)
        xy[~on_water] = np.nan
        xs, ys, in_front = camera.world_to_screen(xy[:, 0], xy[:, 1])
        zp = np.abs(camera.zp_of_world(xy[:, 0], xy[:, 1]))
        wh = v.size_scale * self.box_size.size(np.where(in_front, zp, np.nan))
        scheduled = np.zeros(n_frames, bool)
        for t0, t1 in v.occlusions:
            scheduled |= (rel >= t0) & (rel <= t1)
        m = self.detector.image_margin_px
        inside = in_front & on_water & (xs >= m) & (xs <= width - m) & (ys >= m) & (ys <= height - m)
        return VesselTruth(stamps=self.start_stamp + rel, world_xy=xy, screen_xy=np.c_[xs, ys], box_wh=wh,
                           visible=inside & ~scheduled, detected=np.zeros(n_frames, bool))

    def _detections(self, k: int, stamp: float, truth: dict[int, VesselTruth], rng, horizon: float,
                    image_size: tuple[int, int]) -> SimFrame:
        """Frame ``k`` as the detector reports it: the visible vessels not missed, random and static clutter."""
        det = self.detector
        width, height = image_size
        boxes: list[np.ndarray] = []
        scores: list[float] = []
        gt: list[int] = []
        static: list[bool] = []
        for v in self.vessels:
            tr = truth[v.vessel_id]
            if not tr.visible[k] or rng.random() < det.miss_prob:
                continue
            c = tr.screen_xy[k] + rng.normal(0.0, det.center_std_px, 2)
            wh = np.maximum(tr.box_wh[k] * (1.0 + rng.normal(0.0, det.size_std_frac, 2)), 2.0)
            boxes.append(np.r_[c - wh / 2, c + wh / 2])
            scores.append(float(rng.uniform(*(v.score_range or det.vessel_score_range))))
            gt.append(v.vessel_id)
            static.append(False)
            tr.detected[k] = True
        for _ in range(rng.poisson(det.clutter_rate)):
            w = rng.uniform(det.clutter_size_px[0], det.clutter_size_px[1])
            h = rng.uniform(det.clutter_size_px[2], det.clutter_size_px[3])
            cx = rng.uniform(w / 2, width - w / 2)
            cy = rng.uniform(min(horizon + h / 2, height - h / 2), height - h / 2)
            boxes.append(np.array([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2]))
            scores.append(float(rng.uniform(*det.clutter_score_range)))
            gt.append(-1)
            static.append(False)
        for box in det.static_clutter:
            if rng.random() < det.static_clutter_prob:
                jitter = rng.normal(0.0, 2.0, 4)
                boxes.append(np.asarray(box, dtype=float) + jitter)
                scores.append(float(rng.uniform(*det.clutter_score_range)))
                gt.append(-1)
                static.append(True)
        order = rng.permutation(len(boxes))
        return SimFrame(
            stamp=stamp,
            boxes_xyxy=np.array(boxes, dtype=float).reshape(-1, 4)[order],
            scores=np.array(scores, dtype=float)[order],
            gt_ids=np.array(gt, dtype=int)[order],
            static_clutter=np.array(static, dtype=bool)[order])

    def _hide_behind_nearer(self, truth: dict[int, VesselTruth], k: int) -> None:
        """Mark vessels mostly covered by a nearer vessel's box as not visible in frame ``k``."""
        limit = self.detector.occlusion_overlap
        ids = [i for i, tr in truth.items() if tr.visible[k]]
        boxes = {i: np.r_[truth[i].screen_xy[k] - truth[i].box_wh[k] / 2,
                          truth[i].screen_xy[k] + truth[i].box_wh[k] / 2] for i in ids}
        depth = {i: float(np.hypot(*truth[i].world_xy[k])) for i in ids}
        hidden = []
        for i in ids:
            for j in ids:
                if j == i or depth[j] >= depth[i]:
                    continue
                a, b = boxes[i], boxes[j]
                iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
                ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
                if iw * ih > limit * (a[2] - a[0]) * (a[3] - a[1]):
                    hidden.append(i)
                    break
        for i in hidden:
            truth[i].visible[k] = False


def vessel_of_interest_scenario(seed: int, duration_s: float = 150.0) -> Scenario:
    """A scene where the paper's score (confidence x log path) singles out vessel 0.

    Vessel 0 runs 2.5 m/s across the view ~250-300 m out; a sailboat (1) barely moves ~180 m out; a launch (2)
    crosses ~120 m out for a minute; clutter and the mooring post as the simulator's detector makes them.
    """
    vessels = [
        SimVessel(0, LinePath(bearing_point(250.0, 52.0), heading_deg=167.0, speed_mps=2.5)),
        SimVessel(1, LinePath(bearing_point(180.0, 80.0), heading_deg=10.0, speed_mps=0.3)),
        SimVessel(2, LinePath(bearing_point(120.0, 100.0), heading_deg=-20.0, speed_mps=1.5), start_s=50.0,
                  end_s=110.0),
    ]
    return Scenario(vessels=vessels, duration_s=duration_s, frame_interval_s=4.0, seed=seed)


def fuser_settings_of_simulation(camera) -> FuserSettings:
    """Distance model from the simulator's box sizes; cue statistics measured on a separate training run."""
    sim = BoxSizeModel()
    n = depth_scale(camera)
    model = BoxSizeDistanceModel(a=sim.a_w / n, b=sim.b_w, c=sim.a_h / n, d=sim.b_h, sigma_width_px=3.0,
                                 sigma_height_px=1.5)
    train = vessel_of_interest_scenario(seed=101).run()
    boxes, world = [], []
    for k, frame in enumerate(train.frames):
        for box, gid in zip(frame.boxes_xyxy, frame.gt_ids, strict=True):
            if gid >= 0:
                boxes.append(box)
                world.append(train.truth[int(gid)].world_xy[k])
    stats = fit_cue_statistics(camera, model, np.array(boxes), np.array(world))
    return FuserSettings(distance_model=model, cue_stats=stats)


def harbour_scenario(frame_interval_s: float = 4.0, duration_s: float = 180.0, seed: int = 0,
                     detector: DetectorModel | None = None, camera=None, frame_jitter_s: float = 0.0) -> Scenario:
    """The standard test scene on the challenge camera: three vessels, clutter and the mooring post.

    * vessel 0 (the "vessel of interest"): ~300 m out, crossing the view from left to right at 2 m/s, detected
      with the highest confidences (0.7-0.95, the others 0.35-0.7) and the longest path, so the paper's
      trajectory score picks it;
    * vessel 1: a larger boat ~90 m out, from t = 30 s crossing right to left at 1.5 m/s: it passes in front of
      vessel 0 around t = 85 s, hiding it for a few seconds;
    * vessel 2: ~200 m out on a gentle arc, left to right at 1.2 m/s, hidden behind an obstacle (a scheduled
      occlusion) from t = 100 s to t = 110 s.
    """
    vessels = [
        SimVessel(0, LinePath(bearing_point(300.0, 48.0), heading_deg=167.0, speed_mps=2.0),
                  score_range=(0.7, 0.95)),
        SimVessel(1, LinePath(bearing_point(90.0, 112.0), heading_deg=-13.0, speed_mps=1.5), start_s=30.0,
                  size_scale=1.3, score_range=(0.35, 0.7)),
        SimVessel(2, ArcPath(center_xy=(0.0, 0.0), radius_m=200.0, start_bearing_deg=70.0, speed_mps=1.2),
                  occlusions=((100.0, 110.0),), score_range=(0.35, 0.7)),
    ]
    return Scenario(vessels=vessels, camera=camera, duration_s=duration_s, frame_interval_s=frame_interval_s,
                    frame_jitter_s=frame_jitter_s, detector=detector or DetectorModel(), seed=seed)


def uturn_scenario(frame_interval_s: float = 4.0, duration_s: float = 120.0, seed: int = 0,
                   detector: DetectorModel | None = None, camera=None) -> Scenario:
    """One boat manoeuvring like the challenge boat: ~200 m out at 3 m/s, then a sharp turn back and in.

    No clutter, no other vessel: it measures how well the motion model follows a manoeuvre.
    """
    points = (bearing_point(200.0, 60.0), bearing_point(200.0, 85.0), bearing_point(150.0, 70.0))
    quiet = detector or DetectorModel(clutter_rate=0.0, static_clutter_prob=0.0)
    return Scenario([SimVessel(0, WaypointPath(points, speed_mps=3.0))], camera=camera, duration_s=duration_s,
                    frame_interval_s=frame_interval_s, detector=quiet, seed=seed)


SCENARIOS = {"harbour": harbour_scenario, "uturn": uturn_scenario}




# ---------------------------------------------------------------------------------------------------- benchmark


def _parse_setting(text: str) -> tuple[str, object]:
    import ast

    if "=" not in text:
        raise DataError(f"--set needs name=value, got {text!r}")
    name, value = text.split("=", 1)
    try:
        return name.strip(), ast.literal_eval(value.strip())
    except (ValueError, SyntaxError):
        return name.strip(), value.strip()


def benchmark(intervals: Sequence[float], seeds: int, settings: dict, duration_s: float = 180.0,
              scenario: str = "harbour") -> list[dict]:
    """Run the tracker on a scenario of ``SCENARIOS`` for every interval and seed; one row per interval."""
    import time


    config = TrackerConfig.from_dict(settings)
    rows = []
    for interval in intervals:
        runs = []
        elapsed = 0.0
        frames = 0
        for seed in range(seeds):
            result = SCENARIOS[scenario](frame_interval_s=interval, duration_s=duration_s, seed=seed).run()
            tracker = MultiTargetTracker(config)
            t0 = time.perf_counter()
            outputs = run_tracker(result, tracker.update)
            elapsed += time.perf_counter() - t0
            frames += len(result.frames)
            runs.append(score_tracking(result, outputs))
        rows.append({
            "interval_s": interval,
            "runs": len(runs),
            "id_switches": sum(m.id_switches for m in runs),
            "extra_tracks": sum(max(n - 1, 0) for m in runs for n in m.tracks_per_vessel.values()),
            "false_confirmed": sum(m.false_confirmed_tracks for m in runs),
            "confirmed_rmse_px": float(np.mean([m.confirmed_rmse_px for m in runs])),
            "detection_rmse_px": float(np.mean([m.detection_rmse_px for m in runs])),
            "coverage": float(np.mean([m.coverage for m in runs])),
            "ms_per_frame": 1000.0 * elapsed / max(frames, 1),
        })
    return rows


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """``./vessel simulate``: tracker metrics on the simulated harbour scenario."""
    import argparse

    parser = argparse.ArgumentParser(prog="./vessel simulate", description=(
        "Track the simulated harbour scenario (crossing, occlusion, clutter, mooring post) and print id switches, "
        "extra tracks per vessel, confirmed clutter tracks, screen RMSE of confirmed tracks vs raw detections."))
    parser.add_argument("--interval", type=float, nargs="+", default=[4.0, 1.0, 0.1],
                        help="seconds between frames (default: 4 1 0.1)")
    parser.add_argument("--seeds", type=int, default=6, help="runs per interval, seeds 0..N-1 (default 6)")
    parser.add_argument("--duration", type=float, default=180.0, help="scenario length, s (default 180)")
    parser.add_argument("--scenario", choices=sorted(SCENARIOS), default="harbour",
                        help="harbour (3 vessels, crossing, occlusion, clutter) or uturn (one manoeuvring boat)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="TrackerConfig field, e.g. --set process_noise_model=paper (repeatable)")
    args = parser.parse_args(argv)
    settings = dict(_parse_setting(s) for s in args.set)
    rows = benchmark(args.interval, args.seeds, settings, args.duration, args.scenario)
    print(f"scenario {args.scenario}, tracker settings: {settings or 'defaults'}")
    for r in rows:
        print(f"dt={r['interval_s']:g}s runs={r['runs']} id_switches={r['id_switches']} "
              f"extra_tracks={r['extra_tracks']} false_confirmed={r['false_confirmed']} "
              f"confirmed_rmse={r['confirmed_rmse_px']:.2f}px detection_rmse={r['detection_rmse_px']:.2f}px "
              f"coverage={r['coverage']:.3f} {r['ms_per_frame']:.2f} ms/frame")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
