"""``far_edge``: measure the sea's far edge (``vessel_detect.horizon``) in every frame of a data folder, and how well.

Usage: ``python -m vessel_tools.calib.far_edge --data DIR --videos 7-12 --calib config/aitas_camera.yaml``.

Per video it prints the median line (its ideal y at the centre column and its slope), the frame-to-frame scatter
(standard deviation of that offset and of the slope), the median standard error the finder gives, the failures and
the milliseconds per frame; then the median line over all frames, the value to store in a calibration as
``far_edge_ideal_abc`` (a x + b y + c = 0 in ideal pixels, a^2 + b^2 = 1, b < 0).

On a moving copy (a folder with ``own_ship.csv``, made by ``make_motion_set.py``) it also predicts each frame's line
from an unmoved reference line and the frame's rotation, and prints the residuals (measured minus predicted): the
precision an attitude estimate from the far edge can have. The reference is each video's median line in
``--reference-data DIR`` (the unmoved folder), else ``--reference-abc``, else the calibration's
``far_edge_ideal_abc``. The rotation comes from ``own_ship.csv`` (``--attitude csv``, what the ship's sensors say)
or from the profile in ``motion.json`` (``--attitude exact``); the camera's intrinsics and mounting from the pinhole
decomposition of the calibration's H, the same formulas the copy was made with. Pixels move as
p = K Q K^-1 p_ref, so a line moves as l = (K Q K^-1)^-T l_ref.

Bad input: one ``error:`` line, exit 2.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_calib.camera_model import CameraModel
from vessel_calib.camera_pose import CameraMounting
from vessel_calib.params import load_camera_params, load_camera_yaml
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_common.paths import parse_videos
from vessel_detect.horizon import FarEdge, FarEdgeFinder, FarEdgeSettings, line_of, normalised_line
from vessel_tools.calib.dataset import Dataset, FrameRecord


@dataclass(frozen=True)
class Measured:
    """One frame's far edge and how long finding it took."""

    frame: FrameRecord
    edge: FarEdge
    ms: float


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
    parser = argparse.ArgumentParser(prog="python -m vessel_tools.calib.far_edge",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", required=True, help="a folder laid out like ../shared/aitas (or a moving copy)")
    parser.add_argument("--videos", default=None, help="videos to measure, e.g. 7-12 (default: all)")
    parser.add_argument("--calib", required=True, help="the calibration parameter file (camera: H, K1, ...)")
    parser.add_argument("--attitude", choices=("csv", "exact"), default="csv",
                        help="moving copy: rotation from own_ship.csv (csv) or motion.json's profile (exact)")
    parser.add_argument("--reference-data", default=None,
                        help="moving copy: the unmoved folder; each video's median line there is the reference")
    parser.add_argument("--reference-abc", default=None, help="moving copy: the reference line 'a,b,c' instead")
    parser.add_argument("--predicted", action="store_true",
                        help="moving copy: search about the predicted line (settings.search_px) instead of everywhere")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="a FarEdgeSettings field, e.g. --set strip_px=24 (repeatable)")
    parser.add_argument("--frames", default=None, help="write every frame's line to this CSV")
    return parser


def settings_of(pairs: Sequence[str]) -> FarEdgeSettings:
    """FarEdgeSettings with ``NAME=VALUE`` overrides; DataError for an unknown name or a bad value."""
    fields = {f.name: f for f in dataclasses.fields(FarEdgeSettings)}
    values = {}
    for pair in pairs:
        name, _, text = pair.partition("=")
        if name not in fields or not text:
            raise DataError(f"--set {pair!r}: expected NAME=VALUE with NAME one of {', '.join(fields)}")
        default = getattr(FarEdgeSettings(), name)
        try:
            if isinstance(default, tuple):
                values[name] = tuple(float(v) for v in text.split(","))
            else:
                values[name] = type(default)(float(text)) if isinstance(default, int) else float(text)
        except ValueError:
            raise DataError(f"--set {pair!r}: {text!r} is not a {type(default).__name__}") from None
    try:
        return FarEdgeSettings(**values)
    except ValueError as error:
        raise DataError(str(error)) from None


def measure(frames: Sequence[FrameRecord], camera: CameraModel, finder: FarEdgeFinder,
            predicted: dict | None = None) -> list[Measured]:
    """The far edge of every frame (``predicted``: frame -> line to search about); DataError for an unreadable JPEG."""
    import cv2

    out = []
    for frame in frames:
        image = cv2.imread(str(frame.path))
        if image is None:
            raise DataError(f"{frame.path}: missing or not an image")
        start = time.perf_counter()
        edge = finder.find(image, camera, None if predicted is None else predicted[frame.path])
        out.append(Measured(frame, edge, 1e3 * (time.perf_counter() - start)))
    return out


def offset_and_slope(abc, cx: float) -> tuple[float, float]:
    """A line's ideal y at x = cx and its slope dy/dx."""
    a, b, c = abc
    return -(a * cx + c) / b, -a / b


def median_line(results: Sequence[Measured], cx: float) -> tuple[float, float, float] | None:
    """The line of the median offset at cx and the median slope of the found edges; None if none was found."""
    found = [offset_and_slope(m.edge.abc, cx) for m in results if m.edge.found]
    if not found:
        return None
    offsets, slopes = np.array(found).T
    return line_of(float(np.median(offsets)), float(np.median(slopes)), cx)


def report_lines(results: Sequence[Measured], cx: float) -> None:
    """Per video and over all: median line, scatter, standard errors, failures, ms per frame."""
    print(f"far edge, ideal pixels at the centre column x = {cx:g} (offset: y there; slope: dy/dx)")
    print("video  frames found  offset px  slope      std offset  std slope  median sigma  ms/frame (max)")
    videos = sorted({m.frame.video for m in results})
    for label, rows in [(str(v), [m for m in results if m.frame.video == v]) for v in videos] + [("all", results)]:
        found = [m for m in rows if m.edge.found]
        ms = np.array([m.ms for m in rows])
        if not found:
            print(f"{label:>5}  {len(rows):6d} {0:5d}  (no edge found)  {np.median(ms):8.2f} ({ms.max():.1f})")
            continue
        offsets, slopes = np.array([offset_and_slope(m.edge.abc, cx) for m in found]).T
        sigma = np.median([m.edge.sigma_px for m in found])
        print(f"{label:>5}  {len(rows):6d} {len(found):5d}  {np.median(offsets):9.2f}  {np.median(slopes):+.5f}  "
              f"{offsets.std():10.3f}  {slopes.std():9.5f}  {sigma:12.3f}  {np.median(ms):8.2f} ({ms.max():.1f})")
    for m in results:
        if not m.edge.found:
            print(f"  failed: video {m.frame.video} frame {m.frame.frame}: {m.edge.problem}")
    line = median_line(results, cx)
    if line is not None:
        print(f"far_edge_ideal_abc: [{line[0]:.9f}, {line[1]:.9f}, {line[2]:.6f}]")


# ----------------------------------------------------------------- the rotation of a moving copy
class Motion:
    """A moving copy's attitude at each instant, and the reference line as the rotated camera sees it.

    The camera's mounting is ``vessel_calib.camera_pose.CameraMounting`` from the calibration at the copy's
    reference attitude, the same pinhole ``make_motion_set.py`` warps with.
    """

    def __init__(self, folder: Path, camera: CameraModel, source: str):
        profile = _read_json(folder / "motion.json")
        reference = _read_json(folder / "camera.json").get("reference_attitude") or {}
        self.ref_heading = float(reference.get("heading_deg", profile.get("ref_heading_deg", 76.0)))
        self.mounting = CameraMounting.from_camera(camera, (self.ref_heading, 0.0, 0.0))
        focal = profile.get("focal_px")
        if isinstance(focal, int | float) and abs(focal - self.mounting.K[0, 0]) > 1e-3 * focal:
            raise DataError(f"{folder} was made with another calibration (focal {focal:.1f} px, --calib gives "
                            f"{self.mounting.K[0, 0]:.1f}): pass the calibration it was made with")
        self.attitude = _profile_attitude(profile, self.ref_heading) if source == "exact" else \
            _csv_attitude(folder / "own_ship.csv")

    def line(self, reference_abc, seconds_of_day: float) -> tuple[float, float, float]:
        """The reference line as the rotated camera sees it at ``seconds_of_day``."""
        moved = self.mounting.line_in_image(reference_abc, *self.attitude(seconds_of_day))
        return normalised_line(moved)


def _read_json(path: Path) -> dict:
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(f"{path} is missing: make the moving copy with make_motion_set.py") from None
    except ValueError as error:
        raise DataError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(value, dict):
        raise DataError(f"{path}: expected a JSON object")
    return value


def _profile_attitude(profile: dict, ref_heading: float):
    """Attitude (heading, pitch, roll in degrees) at t from motion.json's sinusoids, as the copy was warped."""
    try:
        ph = [float(v) for v in profile["phases_rad"]]
        amp = [float(profile[k]) for k in ("yaw_amp_deg", "pitch_amp_deg", "roll_amp_deg")]
        period = [float(profile.get(k, d)) for k, d in (("yaw_period_s", 60), ("pitch_period_s", 5),
                                                         ("roll_period_s", 8))]
    except (KeyError, TypeError, ValueError) as error:
        raise DataError(f"motion.json lacks the motion profile ({error}); use --attitude csv") from None

    def attitude(t: float) -> tuple[float, float, float]:
        return (ref_heading + amp[0] * math.sin(2 * math.pi * t / period[0] + ph[0]),
                amp[1] * math.sin(2 * math.pi * t / period[1] + ph[1]),
                amp[2] * math.sin(2 * math.pi * t / period[2] + ph[2]))

    return attitude


def _csv_attitude(path: Path):
    """Attitude at t interpolated in own_ship.csv (utc_s seconds of day; heading unwrapped)."""
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            rows = [(float(r["utc_s"]), float(r["heading_deg"]), float(r["pitch_deg"]), float(r["roll_deg"]))
                    for r in csv.DictReader(handle)]
    except FileNotFoundError:
        raise DataError(f"{path} is missing: not a moving copy") from None
    except (KeyError, TypeError, ValueError) as error:
        raise DataError(f"{path}: needs numbers in utc_s, heading_deg, pitch_deg, roll_deg ({error}); a copy "
                        "without attitude needs --attitude exact") from None
    table = np.array(sorted(rows))
    if len(table) < 2:
        raise DataError(f"{path} has fewer than two rows")
    table[:, 1] = np.degrees(np.unwrap(np.radians(table[:, 1])))

    def attitude(t: float) -> tuple[float, float, float]:
        if not table[0, 0] <= t <= table[-1, 0]:
            raise DataError(f"{path} does not cover the frame at {t:.2f} s of the day")
        return tuple(float(np.interp(t, table[:, 0], table[:, k])) for k in (1, 2, 3))

    return attitude


# ----------------------------------------------------------------- residuals on a moving copy
def reference_lines(args, params: dict, camera: CameraModel, finder: FarEdgeFinder, videos) -> dict:
    """Video -> the unmoved line to predict from (see the module docstring for the order of the sources)."""
    cx = camera.center[0]
    if args.reference_data:
        unmoved = Dataset(args.reference_data)
        results = measure(unmoved.frames(unmoved.check_videos(videos)), camera, finder)
        lines = {v: median_line([m for m in results if m.frame.video == v], cx) for v in videos}
        missing = [v for v, line in lines.items() if line is None]
        if missing:
            raise DataError(f"no far edge found in the unmoved frames of video(s) {missing} in {args.reference_data}")
        return lines
    text = args.reference_abc
    value = [float(v) for v in text.split(",")] if text else params.get("far_edge_ideal_abc")
    if value is None:
        raise DataError("a moving copy needs a reference line: --reference-data DIR (the unmoved folder), "
                        "--reference-abc a,b,c or far_edge_ideal_abc in the calibration file")
    try:
        line = normalised_line(value)
    except (TypeError, ValueError):
        raise DataError(f"reference line {value!r} is not three numbers a,b,c of a non-vertical line") from None
    return {v: line for v in videos}


def report_residuals(results: Sequence[Measured], predicted: dict, cx: float) -> None:
    """Measured minus predicted offset (px at the centre column) and slope, per video and over all."""
    print("measured minus predicted line (offset in px at the centre column, slope dy/dx)")
    print("video  found  bias px  median|off|  p90|off|  max|off|  median|slope|  p90|slope|  |off|<2sigma")
    videos = sorted({m.frame.video for m in results})
    for label, rows in [(str(v), [m for m in results if m.frame.video == v]) for v in videos] + [("all", results)]:
        found = [m for m in rows if m.edge.found]
        if not found:
            print(f"{label:>5}  {0:5d}  (no edge found)")
            continue
        measured = np.array([offset_and_slope(m.edge.abc, cx) for m in found])
        expected = np.array([offset_and_slope(predicted[m.frame.path], cx) for m in found])
        off, slope = (measured - expected).T
        sigma = np.array([m.edge.sigma_px for m in found])
        print(f"{label:>5}  {len(found):5d}  {np.median(off):+7.2f}  {np.median(np.abs(off)):11.2f}  "
              f"{np.percentile(np.abs(off), 90):8.2f}  {np.abs(off).max():8.2f}  {np.median(np.abs(slope)):13.5f}  "
              f"{np.percentile(np.abs(slope), 90):10.5f}  {100 * np.mean(np.abs(off) < 2 * sigma):11.0f}%")


def write_frames(path: str, results: Sequence[Measured], predicted: dict | None, cx: float) -> None:
    """Every frame's line (and the predicted one on a moving copy) as CSV."""
    with open(path, "w", newline="", encoding="utf-8") as handle:
        out = csv.writer(handle)
        out.writerow(["video", "frame", "found", "offset_px", "slope", "sigma_px", "slope_sigma", "inliers",
                      "columns", "ms", "predicted_offset_px", "predicted_slope", "problem"])
        for m in results:
            offset, slope = offset_and_slope(m.edge.abc, cx)
            p_off, p_slope = offset_and_slope(predicted[m.frame.path], cx) if predicted else (math.nan, math.nan)
            out.writerow([m.frame.video, m.frame.frame, int(m.edge.found), f"{offset:.4f}", f"{slope:.6f}",
                          f"{m.edge.sigma_px:.4f}", f"{m.edge.slope_sigma:.6f}", m.edge.inliers, m.edge.columns,
                          f"{m.ms:.2f}", f"{p_off:.4f}", f"{p_slope:.6f}", m.edge.problem])


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """Measure, report; 0 when done."""
    args = build_parser().parse_args(argv)
    finder = FarEdgeFinder(settings_of(args.set))
    camera = load_camera_yaml(args.calib)
    data = Dataset(args.data)
    videos = data.check_videos(parse_videos(args.videos))
    frames = data.frames(videos)
    cx = camera.center[0]
    predicted = None
    if (data.path / "own_ship.csv").is_file():
        motion = Motion(data.path, camera, args.attitude)
        references = reference_lines(args, load_camera_params(args.calib), camera, finder, videos)
        predicted = {f.path: motion.line(references[f.video], f.stamp % 86400.0) for f in frames}
    results = measure(frames, camera, finder, predicted if args.predicted else None)
    report_lines(results, cx)
    if predicted is not None:
        report_residuals(results, predicted, cx)
    if args.frames:
        write_frames(args.frames, results, predicted, cx)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
