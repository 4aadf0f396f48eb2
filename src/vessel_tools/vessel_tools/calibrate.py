"""``calibrate``: fit the camera model from labelled (screen, GPS) pairs and write the ROS parameter YAML.

Offline tool (an executable of the package so ``ros2 run vessel_tools calibrate`` finds it); it does not need a
ROS graph. Inputs, one of:

* ``--data DIR --videos 7-12 [--pairs 11 --seed N]``: a folder laid out like ``../shared/aitas``; pairs are the
  primary boxes with ``gps_ok=1`` (labels of the same frame averaged), each read at its horizontal centre,
  ``--box-anchor`` of the way down (default 0.65, chosen on the training videos; 0.5 is the paper's centre);
  ``--label-passes all`` also averages in the second labelling pass (``primary=0``) of the same frames.
* ``--data DIR`` without ``screen_labels.csv`` (or ``--from detections``): no labels; the vessel is found among
  the boats a generic detector finds, as the one its GPS track explains (``vessel_tools.calib.gps_association``);
  ``--from both`` adds such pairs to the labelled ones. ``--video FILE --start-utc T --gps TRACK``: the same from a
  video file and a GPS track.
* ``--pairs-csv FILE``: columns ``x,y,lat,lon`` (or ``x1,y1,x2,y2`` box corners instead of ``x,y``), or
  ``x,y,t`` with ``--gps FILE`` (CSV or GPX fixes, interpolated at ``t``; ``t`` in the same clock as the fixes:
  epoch seconds or ISO-8601), with ``--camera-lat/--camera-lon`` and ``--image-size``.

Output: ``--out FILE.yaml`` (``/**: ros__parameters: camera: {...}``, atomic), a report on stdout and a picture
(``--picture``, default next to the YAML). ``--evaluate-on 13-17`` prints validation figures, ``--draws 20``
the spread over random draws of ``--pairs`` training pairs (the paper's protocol).

ROS style works too: ``ros2 run vessel_tools calibrate --ros-args -p data:=DIR -p out:=FILE.yaml``. With no
input at all it calibrates the default data set (``$VESSEL_DATA`` or ``../shared/aitas``) into
``out/calibration/``, or says what it needs and exits 0. Bad input: ``error: ...`` on stderr, exit 2, nothing
written. Ctrl-C: ``interrupted, nothing written``, exit 0.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import math
import os
import shlex
import signal
import sys
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vessel_calib import geodesy
from vessel_tools.calib.calibration import (
    DEFAULT_BOX_ANCHOR,
    FEW_PAIRS,
    LOSSES,
    MIN_PAIRS_TO_WRITE,
    PAPER_OPTIONS,
    FitOptions,
    calibrate,
    degrees_of_freedom,
    evaluate,
    leave_one_pair_out_errors,
    study_draws,
)
from vessel_calib.camera_model import PAPER_BOX_ANCHOR, box_points
from vessel_tools.calib.dataset import Dataset
from vessel_tools.calib.gps_association import SearchOptions, associate_and_calibrate
from vessel_calib.gps_track import GpsTrack, parse_time
from vessel_calib.params import read_params_yaml, write_camera_yaml
from vessel_common.command_line import command_line_tool
from vessel_common.errors import CalibrationError, DataError, VesselError
from vessel_common.paths import default_data_dir, parse_videos, repo_root

if TYPE_CHECKING:
    from vessel_tools.calib.calibration import CalibrationResult, FitOptions
    from vessel_tools.calib.dataset import Dataset

# Heavy modules (numpy, scipy, matplotlib) are imported inside the functions, after main() has taken over
# SIGINT, so Ctrl-C during start-up still ends with "interrupted, nothing written" instead of a traceback.

DEFAULT_TRAIN_VIDEOS = "7-12"
PAIR_SOURCES = ("auto", "labels", "detections", "both")
DEFAULT_EVAL_VIDEOS = "13-17"

_X_NAMES = ("x", "xs", "x_s", "screen_x", "u")
_Y_NAMES = ("y", "ys", "y_s", "screen_y", "v")
_LAT_NAMES = ("lat", "latitude")
_LON_NAMES = ("lon", "lng", "long", "longitude")
_T_NAMES = ("t", "time", "stamp", "utc", "t_utc_s", "timestamp")


class _Parser(argparse.ArgumentParser):
    """argparse with the project's one-line ``error: ...`` and exit status 2."""

    def error(self, message):
        print(f"error: {message} (see calibrate --help)", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    """The command-line interface."""
    p = _Parser(prog="calibrate", description=__doc__.split("\n\n")[0],
                formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_argument_group("input")
    src.add_argument("--data", help="data folder laid out like ../shared/aitas")
    src.add_argument("--videos", help=f"videos to fit on (default {DEFAULT_TRAIN_VIDEOS})")
    src.add_argument("--pairs", type=int, help="use a random draw of this many pairs (the paper used 11)")
    src.add_argument("--seed", type=int, default=0, help="random seed of --pairs / --draws (default 0)")
    src.add_argument("--box-anchor", type=float, default=DEFAULT_BOX_ANCHOR,
                     help="point of a labelled box that stands for the vessel's GPS: its horizontal centre, this "
                          f"share of the way down (0 top, 0.5 centre as in the paper, 1 bottom; default "
                          f"{DEFAULT_BOX_ANCHOR}, see vessel_tools.calib.calibration.DEFAULT_BOX_ANCHOR). Written to the "
                          "file as camera.box_anchor, so the fuser reads boxes the same way")
    src.add_argument("--label-passes", choices=("primary", "all"), default="primary",
                     help="data folder: average only primary labels per frame, or all labelling passes")
    src.add_argument("--from", dest="pairs_from", choices=PAIR_SOURCES, default="auto",
                     help="where the data folder's (screen, GPS) pairs come from: labels (screen_labels.csv), "
                          "detections (no labels: the vessel is found among detected boats as the one its GPS track "
                          "explains), both (labelled frames keep their label); auto (default): labels if the folder "
                          "has screen_labels.csv, else detections")
    src.add_argument("--labels", dest="pairs_from", action="store_const", const="labels",
                     help="same as --from labels")
    src.add_argument("--pairs-csv", help="CSV of labelled pairs: x,y,lat,lon or x,y,t (with --gps)")
    src.add_argument("--gps", help="GPS fixes (CSV or GPX) to look up the position at each pair's t (--pairs-csv) "
                                   "or each frame's time (--video)")
    src.add_argument("--video", help="a video file of the camera (instead of --data): calibrated without labels from "
                                     "the boats detected in it and the --gps track of one of them")
    src.add_argument("--start-utc", help="--video: UTC time of its first frame (ISO-8601 or epoch seconds)")
    src.add_argument("--every", type=int, default=25, help="--video: use one frame in N (default 25)")
    src.add_argument("--max-gap-s", type=float, default=3.0, help="longest GPS gap to interpolate across (s)")
    src.add_argument("--water-level", metavar="CSV",
                     help="water level (tide) against time (utc or utc_s, level_m): the fit allows for the camera's "
                          "height above the sea changing and writes camera.water_level_m; the fuser then needs the "
                          "same file as water_level.file")
    src.add_argument("--camera-lat", type=float, help="camera latitude (degrees; default from camera.json)")
    src.add_argument("--camera-lon", type=float, help="camera longitude (degrees; default from camera.json)")
    src.add_argument("--image-size", help="WIDTHxHEIGHT of the labelled frames (default 1280x720 or camera.json)")
    src.add_argument("--center", help="distortion centre X,Y (default: image centre)")
    fit = p.add_argument_group("fit")
    fit.add_argument("--method", choices=("refined", "paper"), default="refined",
                     help="refined: joint H+K1 refinement (default); paper: K1 scan + DLT only")
    fit.add_argument("--loss", choices=LOSSES, default="soft_l1", help="refinement loss (default soft_l1)")
    fit.add_argument("--robust", nargs="?", const="soft_l1", choices=LOSSES[1:], metavar="LOSS",
                     help="robust loss (soft_l1 if no LOSS given); the default loss is already soft_l1")
    fit.add_argument("--robust-scale", type=float, default=3.0, help="robust loss scale, px (default 3)")
    fit.add_argument("--far-weight", type=float, default=0.0,
                     help="weight pairs by (distance/100 m)^A to favour far accuracy (default 0)")
    fit.add_argument("--k1", type=float, help="fix K1 to this value instead of fitting it")
    out = p.add_argument_group("output")
    out.add_argument("--out", help="parameter YAML to write (default out/calibration/<name>_camera.yaml)")
    out.add_argument("--picture", help="calibration picture PNG (default next to the YAML)")
    out.add_argument("--no-picture", action="store_true", help="do not draw the picture")
    out.add_argument("--frame", help="camera frame to draw the picture on (default: a frame of the data set)")
    search = p.add_argument_group("without labels (--from detections, --video)")
    search.add_argument("--detections", help="a `detect run` CSV of the data folder's frames (default: run the "
                                             "generic COCO detector over the whole frames)")
    search.add_argument("--detector-params", help="parameter YAML of that detector (default "
                                                  "config/detector_coco.yaml; its cue and masks are left out)")
    search.add_argument("--save-detections", help="write the detector's boxes to this CSV (re-use with --detections)")
    search.add_argument("--hypotheses", type=int, default=SearchOptions.hypotheses,
                        help=f"camera hypotheses of the consensus search (default {SearchOptions.hypotheses})")
    search.add_argument("--min-associations", type=int, default=SearchOptions.min_associations,
                        help="refuse a fit resting on fewer frames whose vessel box was found (default "
                             f"{SearchOptions.min_associations})")
    search.add_argument("--max-camera-offset", type=float, default=SearchOptions.max_nadir_m,
                        help="refuse a camera standing further than this from --camera-lat/--camera-lon, m (default "
                             f"{SearchOptions.max_nadir_m:g})")
    graph = p.add_argument_group("the graph's boxes (--from detections on a data folder)")
    graph.add_argument("--graph-params", help="the graph's parameter file (default config/aitas.yaml): where the "
                       "vessel's GPS falls down its detector's boxes, through the camera found, becomes "
                       "camera.box_anchor, the point the fuser reads them at")
    graph.add_argument("--graph-detections", help="a `detect run` CSV of that detector over the same frames (its "
                       "p_target), instead of running it")
    graph.add_argument("--keep-box-anchor", action="store_true", help="write --box-anchor (the search detector's) "
                       "instead of measuring the graph detector's")
    study = p.add_argument_group("study")
    study.add_argument("--evaluate-on", help="videos to evaluate on (e.g. 13-17): validation figures")
    study.add_argument("--draws", type=int, help="repeat the fit on this many random draws of --pairs pairs")
    return p


# --------------------------------------------------------------------------- ROS arguments
def _ros_params_to_cli(argv: list[str]) -> list[str]:
    """Strip ``--ros-args ... [--]`` and turn its ``-p name:=value`` into the equivalent CLI options."""
    if "--ros-args" not in argv:
        return list(argv)
    try:
        from rclpy.utilities import remove_ros_args

        plain = list(remove_ros_args(args=["calibrate", *argv]))[1:]
    except Exception:  # rclpy missing or too old: strip by hand
        plain = _strip_ros_args(argv)
    extra: list[str] = []
    from_file: list[str] = []
    in_ros = False
    i = 0
    while i < len(argv):
        arg = argv[i]
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--" and in_ros:
            in_ros = False
        elif in_ros and arg in ("-p", "--param") and i + 1 < len(argv):
            name, sep, value = argv[i + 1].partition(":=")
            i += 1
            if not sep:
                raise CalibrationError(f"ROS parameter {argv[i]!r} must look like name:=value")
            extra += _param_to_option(name.strip(), value.strip())
        elif in_ros and arg == "--params-file" and i + 1 < len(argv):
            i += 1
            from_file += _params_file_options(argv[i])
        i += 1
    # argparse keeps the last value: parameter files first, then -p, then plain options win.
    return from_file + extra + plain


def _strip_ros_args(argv: list[str]) -> list[str]:
    out, in_ros, skip = [], False, False
    for arg in argv:
        if skip:
            skip = False
            continue
        if arg == "--ros-args":
            in_ros = True
        elif in_ros and arg == "--":
            in_ros = False
        elif in_ros:
            skip = arg in ("-p", "--param", "-r", "--remap", "--params-file", "--log-level", "-e", "--enclave")
        else:
            out.append(arg)
    return out


_FLAG_PARAMS = {"no_picture"}
NODE_NAME = "calibrate"


def _params_file_options(path: str) -> list[str]:
    """Options from the ``calibrate:`` block of a ROS parameter file (other nodes' blocks are ignored)."""
    blocks = read_params_yaml(path)
    options: list[str] = []
    for node, params in blocks.items():
        if node.strip("/").split("/")[-1] != NODE_NAME:
            continue
        for name, value in params.items():
            if value is None or value == "" or isinstance(value, dict):
                continue
            if isinstance(value, bool):
                value = "true" if value else "false"
            options += _param_to_option(str(name), str(value))
    return options


def _param_to_option(name: str, value: str) -> list[str]:
    key = name.replace(".", "_").replace("-", "_")
    value = value.strip("'\"")
    if key in _FLAG_PARAMS:
        return [f"--{key.replace('_', '-')}"] if value.lower() in ("true", "1", "yes") else []
    if key == "robust":
        if value.lower() in ("false", "0", "no", ""):
            return []
        return ["--robust"] if value.lower() in ("true", "1", "yes") else ["--robust", value]
    options = {a.dest: a.option_strings[-1] for a in build_parser()._actions
               if a.option_strings and a.option_strings[-1].startswith("--") and a.nargs != 0}
    if key not in options:
        raise CalibrationError(f"unknown parameter {name!r}; see calibrate --help for the options (use_ in names)")
    return [options[key], value]


# --------------------------------------------------------------------------- inputs
def _parse_size(text: str | None, default: tuple[int, int]) -> tuple[int, int]:
    if not text:
        return default
    try:
        w, h = (int(v) for v in text.lower().replace(",", "x").split("x"))
        if w <= 0 or h <= 0:
            raise ValueError
        return w, h
    except ValueError:
        raise CalibrationError(f"--image-size must look like 1280x720, got {text!r}") from None


def _parse_center(text: str | None, size: tuple[int, int]) -> tuple[float, float]:
    if not text:
        return size[0] / 2.0, size[1] / 2.0
    try:
        x, y = (float(v) for v in text.split(","))
        return x, y
    except ValueError:
        raise CalibrationError(f"--center must look like 640,360, got {text!r}") from None


def _column(fields_lower: dict[str, str], names) -> str | None:
    return next((fields_lower[n] for n in names if n in fields_lower), None)


def read_pairs_csv(path, gps_path=None, max_gap_s: float = 3.0, anchor: float = PAPER_BOX_ANCHOR):
    """Labelled pairs from a CSV -> (screen (N,2), gps (N,2), notes, stamps (N,)).

    Box corners become the box's horizontal centre, ``anchor`` of the way down it; x,y columns are used as given.
    ``stamps`` are the time column's Unix seconds (NaN without one: needed only for ``--water-level``).
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            fields = [f.strip() for f in (reader.fieldnames or [])]
            rows = [{(k or "").strip(): (v or "").strip() for k, v in r.items()} for r in reader]
    except OSError as exc:
        raise DataError(f"cannot read pairs CSV {path}: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise DataError(f"{path}: not a readable CSV file ({exc})") from None
    lower = {f.lower(): f for f in fields}
    xcol, ycol = _column(lower, _X_NAMES), _column(lower, _Y_NAMES)
    box = all(c in lower for c in ("x1", "y1", "x2", "y2"))
    if (xcol is None or ycol is None) and not box:
        raise DataError(f"{path}: missing screen columns x,y (or box x1,y1,x2,y2); found: {', '.join(fields)}")
    latcol, loncol = _column(lower, _LAT_NAMES), _column(lower, _LON_NAMES)
    tcol = _column(lower, _T_NAMES)
    use_time = latcol is None or loncol is None
    stamps = []
    if use_time and (tcol is None or gps_path is None):
        raise DataError(
            f"{path}: missing columns lat,lon (or a time column t plus --gps FIXES); found: {', '.join(fields)}")
    track = GpsTrack.from_file(gps_path) if use_time else None
    if track is not None and len(track) < 2:
        raise DataError(f"{gps_path}: fewer than 2 usable GPS fixes ({track.skipped_rows} rows skipped)")

    def num(i, col):
        text = rows[i].get(col, "")
        try:
            value = float(text)
        except ValueError:
            raise DataError(f"{path}, row {i + 2}, column '{col}': expected a number, got {text!r}") from None
        if not math.isfinite(value):
            raise DataError(f"{path}, row {i + 2}, column '{col}': expected a finite number, got {text!r}; fix or "
                            "drop that row")
        return value

    screen, gps = [], []
    dropped = 0
    for i in range(len(rows)):
        if xcol is not None and ycol is not None:
            x, y = num(i, xcol), num(i, ycol)
        else:
            x, y = box_points([num(i, lower[c]) for c in ("x1", "y1", "x2", "y2")], anchor)[0]
        t = math.nan
        if tcol is not None:
            try:
                t = parse_time(rows[i].get(tcol, ""))
            except ValueError:
                raise DataError(f"{path}, row {i + 2}, column '{tcol}': expected epoch seconds or ISO-8601 time, "
                                f"got {rows[i].get(tcol)!r}") from None
        if use_time:
            lat, lon, ok = track.interpolate(t, max_gap_s=max_gap_s)
            if not ok:
                dropped += 1
                continue
        else:
            lat, lon = num(i, latcol), num(i, loncol)
        screen.append((x, y))
        gps.append((lat, lon))
        stamps.append(t)
    notes = []
    if dropped:
        notes.append(f"{dropped} pair(s) dropped: no GPS fix within {max_gap_s:g} s of their time")
    if track is not None and track.skipped_rows:
        notes.append(f"{track.skipped_rows} unusable GPS row(s) skipped in {gps_path}")
    return (np.array(screen, dtype=float).reshape(-1, 2), np.array(gps, dtype=float).reshape(-1, 2), notes,
            np.array(stamps, dtype=float))


def _utc(stamp: float) -> str:

    return datetime.datetime.fromtimestamp(stamp, datetime.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def _picture_frame(ds: Dataset | None, videos) -> Path | None:
    if ds is None:
        return None
    for frame in ds.frames(videos) + ds.frames():
        if frame.path.is_file():
            return frame.path
    return None


def _fit_options(args) -> FitOptions:
    """FitOptions from the command line."""
    if args.method == "paper":
        options = PAPER_OPTIONS
    else:
        options = FitOptions(loss=args.robust or args.loss, loss_scale_px=args.robust_scale,
                             far_weight=args.far_weight)
    if args.k1 is not None:
        options = replace(options, k1_fixed=args.k1, fit_k1=False)
    return options.checked()


# --------------------------------------------------------------------------- main
@dataclass
class _Pairs:
    """The (screen, GPS) pairs a calibration is fitted to, and where they came from."""

    screen: Any
    gps: Any
    stamps: Any
    source: str
    name: str
    image_size: tuple[int, int]
    center: tuple[float, float]
    notes: list[str] = field(default_factory=list)
    videos: list[int] | None = None
    association: Any = None
    picture_frame: Any = None
    anchor_note: str = ""  # how box_anchor was measured, when it is not the boxes' the fit read


def run(args) -> int:
    """Do the work for parsed ``args``; raises VesselError for bad input."""
    data_dir = args.data
    if not data_dir and not args.pairs_csv and not args.video:
        found = default_data_dir()
        if found is None:
            print("calibrate: nothing to do. Give --data DIR (a folder like ../shared/aitas) or --pairs-csv FILE "
                  "with --camera-lat/--camera-lon; see calibrate --help.")
            return 0
        data_dir = str(found)
        print(f"calibrate: no input given; calibrating the default data set {found}")
    ds = Dataset(data_dir) if data_dir else None
    camera_lat = args.camera_lat if args.camera_lat is not None else (ds.camera_lat if ds is not None else None)
    camera_lon = args.camera_lon if args.camera_lon is not None else (ds.camera_lon if ds is not None else None)
    if camera_lat is None or camera_lon is None:
        raise CalibrationError("give the camera position: --camera-lat and --camera-lon (WGS-84 degrees)")
    geodesy.validate_lat_lon(camera_lat, camera_lon, "camera position (--camera-lat/--camera-lon)")
    if not 0.0 <= args.box_anchor <= 1.0:  # NaN fails too
        raise CalibrationError(f"--box-anchor (camera.box_anchor) must be a number in [0, 1] (0 box top, 0.5 centre, "
                               f"1 bottom), got {args.box_anchor}")
    _check_graph_inputs(args)
    water_level = None
    if args.water_level:
        from vessel_calib.water_level import load_water_level

        water_level = load_water_level(args.water_level)
    pairs = _collect_pairs(args, ds, camera_lat, camera_lon, water_level)
    available = len(pairs.screen)
    all_screen, all_gps = pairs.screen, pairs.gps
    _draw_pairs(args, pairs)
    options = _fit_options(args)
    levels = _pair_levels(args, pairs, water_level)
    result = calibrate(pairs.screen, pairs.gps, camera_lat, camera_lon, pairs.image_size, pairs.center, options,
                       box_anchor=args.box_anchor, water_levels=levels)
    _report_fit(args, pairs, available, result, options, levels, camera_lat, camera_lon)
    result = _graph_box_anchor(args, ds, pairs, result, water_level)
    eval_pairs = _evaluate(args, ds, result, water_level, all_screen, all_gps, camera_lat, camera_lon, pairs, options)
    _write(args, pairs, result, ds, eval_pairs)
    return 0


def _collect_pairs(args, ds, camera_lat: float, camera_lon: float, water_level) -> _Pairs:
    """The pairs from a video file, a pairs CSV or a data folder (its labels, detections or both)."""
    image_size = _parse_size(args.image_size, ds.image_size if ds is not None else (1280, 720))
    center = _parse_center(args.center, image_size) if args.center or ds is None else ds.center
    if args.video:
        if args.data or args.pairs_csv:
            raise CalibrationError("--video replaces --data and --pairs-csv: give one of them")
        association, picture_frame, image_size = _search_video(args, camera_lat, camera_lon, args.center,
                                                               water_level)
        screen, gps, stamps = association.pairs(args.box_anchor)
        return _Pairs(screen, gps, stamps, f"video {args.video} without labels ({association.associated} frames "
                      "associated)", Path(args.video).stem, image_size, _parse_center(args.center, image_size),
                      association=association, picture_frame=picture_frame)
    if args.pairs_csv:
        screen, gps, notes, stamps = read_pairs_csv(args.pairs_csv, args.gps, args.max_gap_s, args.box_anchor)
        return _Pairs(screen, gps, stamps, f"pairs {args.pairs_csv}", Path(args.pairs_csv).stem, image_size, center,
                      notes)
    spec = args.videos or DEFAULT_TRAIN_VIDEOS
    videos = parse_videos(spec)
    pairs_from = _pairs_source(args.pairs_from, ds)
    pairs = _Pairs(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2)), "", ds.path.name, image_size, center,
                   videos=videos)
    if pairs_from in ("labels", "both"):
        pairs.screen, pairs.gps, pairs.stamps = ds.calibration_pairs(videos, anchor=args.box_anchor,
                                                                     label_passes=args.label_passes, with_stamps=True)
        pairs.source = f"{ds.path} videos {spec} ({args.label_passes} labels)"
        if len(pairs.screen) == 0:
            raise DataError(f"{ds.path}: no labelled pairs with gps_ok=1 in videos {spec}"
                            + ("" if pairs_from == "labels" else "; use --from detections"))
    if pairs_from in ("detections", "both"):
        association = _search_dataset(args, ds, videos, camera_lat, camera_lon, image_size, center, water_level)
        pairs.association = association
        found_screen, found_gps, found_stamps, keys = association.pairs(args.box_anchor, with_keys=True)
        if pairs_from == "both":
            labelled = {(lab.video, lab.frame) for lab in ds.labels(videos, args.label_passes == "primary")
                        if lab.gps_ok}
            extra = np.array([key not in labelled for key in keys], dtype=bool)
            pairs.screen = np.vstack([pairs.screen, found_screen[extra]])
            pairs.gps = np.vstack([pairs.gps, found_gps[extra]])
            pairs.stamps = np.concatenate([pairs.stamps, found_stamps[extra]])
            pairs.source += f" and {int(extra.sum())} frames without a label associated from detections"
        else:
            pairs.screen, pairs.gps, pairs.stamps = found_screen, found_gps, found_stamps
            pairs.source = (f"{ds.path} videos {spec} without labels ({association.associated} frames associated "
                            "from detections)")
    return pairs


#: Fewest frames whose graph-detector box gives the box anchor; with fewer the search detector's anchor is kept.
MIN_ANCHOR_FRAMES = 12


def _graph_box_anchor(args, ds, pairs: _Pairs, result, water_level):
    """A label-free fit on a data folder: ``camera.box_anchor`` becomes where the GPS falls down the graph's boxes.

    The search reads the generic detector's boxes (often the cabin without the hull) at ``--box-anchor``; the
    fuser will read the graph detector's boxes, which sit on the vessel in their own way, at the calibration's
    ``box_anchor``. Measured from the vessel's GPS through the camera just found: no label enters.
    """
    if not _graph_anchor_applies(args, ds, pairs):
        if args.graph_params or args.graph_detections:
            print("calibrate: warning: --graph-params/--graph-detections are used by a label-free fit of a data "
                  "folder (--from detections) only; ignored here")
        return result
    from vessel_calib.camera_model import CameraModel
    from vessel_tools.calib.gps_association import measure_box_anchor

    frame_boxes = _frame_boxes_module()
    track = ds.gps_track()
    records = ds.frames(pairs.videos)
    lat, lon, valid = track.interpolate(np.array([r.stamp for r in records], dtype=float), max_gap_s=args.max_gap_s)
    records = [r for r, ok in zip(records, valid, strict=True) if ok]
    gps = np.column_stack([lat[valid], lon[valid]])
    graph_params = args.graph_params or str(repo_root() / frame_boxes.GRAPH_PARAMS)
    print(f"calibrate: the graph's detector ({args.graph_detections or graph_params}) over {len(records)} frames, "
          "for the point of its boxes the fuser reads", flush=True)
    try:
        boxes = frame_boxes.graph_detector_boxes(records, result.model, graph_params, args.graph_detections)
    except VesselError as error:  # the camera is found: say why its anchor is kept rather than lose the fit
        print(f"calibrate: warning: the graph's detector could not run ({error}); box_anchor stays "
              f"{args.box_anchor:g}, the search detector's. Fix --graph-params/--graph-detections, or pass "
              "--keep-box-anchor")
        return result
    keys = [(r.video, r.frame) for r in records]
    levels = None if water_level is None else water_level.level_at(np.array([r.stamp for r in records]))
    found = measure_box_anchor(result.model, gps, levels, [boxes[k][0] for k in keys], [boxes[k][1] for k in keys])
    if found is None or found.frames < MIN_ANCHOR_FRAMES:
        print(f"calibrate: warning: the graph's detector called a box around the vessel's GPS the vessel of interest "
              f"in {0 if found is None else found.frames} frames (fewer than {MIN_ANCHOR_FRAMES}); box_anchor stays "
              f"{args.box_anchor:g}, the search detector's. Check the graph's detector (--graph-params), or pass "
              "--keep-box-anchor to silence this")
        return result
    if not 0.0 <= found.anchor <= 1.0:
        print(f"calibrate: warning: the vessel's GPS falls {found.anchor:.3f} of the way down the graph detector's "
              f"boxes, outside them (0 top, 1 bottom; {found.frames} frames); box_anchor stays {args.box_anchor:g}. "
              "Its boxes may hold part of the vessel only")
        return result
    anchor = round(found.anchor, 3)
    print(f"calibrate: box_anchor {anchor:g}: the vessel's GPS falls {anchor:g} of the way down the graph detector's "
          f"boxes (quartiles {found.quartiles[0]:.3f}-{found.quartiles[1]:.3f}, {found.frames} frames); the search "
          f"read its own boxes at {args.box_anchor:g}")
    model = CameraModel.from_params({**result.model.to_params(), "box_anchor": anchor})
    pairs.source += (f"; box_anchor {anchor:g} measured on the graph detector's boxes of {found.frames} frames "
                     f"({Path(args.graph_detections or graph_params).name})")
    pairs.anchor_note = (f"box_anchor {anchor:g}: the vessel's GPS falls {anchor:g} of the way down the graph "
                         f"detector's boxes through H (median of {found.frames} frames); H was fitted on the search "
                         f"detector's boxes read at {args.box_anchor:g}; the fuser reads boxes at {anchor:g}.")
    return replace(result, model=model)


def _graph_anchor_applies(args, ds, pairs: _Pairs) -> bool:
    """Whether the fit is label-free on a data folder, so the graph detector's box anchor is measured."""
    return (pairs.association is not None and ds is not None and pairs.videos is not None
            and not args.keep_box_anchor and args.pairs_from != "both"
            and _pairs_source(args.pairs_from, ds) == "detections")


def _check_graph_inputs(args) -> None:
    """A mistyped --graph-params/--graph-detections is refused before the search, not after it."""
    for option, value in (("--graph-params", args.graph_params), ("--graph-detections", args.graph_detections)):
        if value and not Path(value).is_file():
            raise DataError(f"{option} {value}: no such file; give an existing file or leave the option out")


def _draw_pairs(args, pairs: _Pairs) -> None:
    """``--pairs N --seed S``: keep a random draw of N pairs (the paper's protocol)."""
    if args.pairs is None:
        return
    if args.pairs < MIN_PAIRS_TO_WRITE:
        raise CalibrationError(f"--pairs must be at least {MIN_PAIRS_TO_WRITE}, got {args.pairs}: 4 pairs fit the "
                               "homography exactly, so no error of the calibration could be measured")
    if args.pairs > len(pairs.screen):
        raise CalibrationError(f"--pairs {args.pairs} but only {len(pairs.screen)} pairs are available")
    idx = np.sort(np.random.default_rng(args.seed).choice(len(pairs.screen), size=args.pairs, replace=False))
    pairs.screen, pairs.gps, pairs.stamps = pairs.screen[idx], pairs.gps[idx], pairs.stamps[idx]
    pairs.source += f", random draw of {args.pairs} (seed {args.seed})"


def _pair_levels(args, pairs: _Pairs, water_level):
    """The water level at each pair (None without ``--water-level``); refuses too few pairs to measure a fit."""
    levels = None
    if water_level is not None:
        if not np.all(np.isfinite(pairs.stamps)):
            raise CalibrationError("--water-level needs the time of every pair: give the pairs CSV a time column t "
                                   "(epoch seconds or ISO-8601 UTC)")
        levels = _levels_at(water_level, pairs.stamps, "pair(s)")
        pairs.source += f", water level from {args.water_level}"
    if len(pairs.screen) < MIN_PAIRS_TO_WRITE:
        raise CalibrationError(
            f"{len(pairs.screen)} pairs: a homography fitted to 4 pairs passes through them exactly (0 px, 0 m "
            f"whatever the labels), so nothing says how wrong it is; give at least {MIN_PAIRS_TO_WRITE} pairs (more "
            "than 8 for a calibration to rely on)")
    return levels


def _report_fit(args, pairs: _Pairs, available: int, result, options, levels, camera_lat, camera_lon) -> None:
    """The fit's report; with few pairs, each one back-projected by a fit of the others."""
    screen = pairs.screen
    print(f"calibrate: fitted on {pairs.source}: {len(screen)} of {available} pairs", flush=True)
    for note in pairs.notes:
        print(f"  note: {note}")
    if pairs.association is not None:
        print("\n".join(pairs.association.report_lines()), flush=True)
    print("\n".join(result.report_lines()), flush=True)
    if len(screen) < FEW_PAIRS:
        dof = degrees_of_freedom(len(screen), result.options.fit_k1 and result.options.k1_fixed is None)
        held_out = leave_one_pair_out_errors(screen, pairs.gps, camera_lat, camera_lon, pairs.image_size,
                                             pairs.center, options, args.box_anchor)
        finite = held_out[np.isfinite(held_out)]
        figure = (f"median {np.median(finite):.2f} m, max {np.max(finite):.2f} m over {finite.size} pairs"
                  if finite.size else "no pair could be held out")
        print(f"  warning: only {len(screen)} pairs, {dof} degree(s) of freedom left: the fit's own errors above "
              f"understate; each pair back-projected by a fit of the others: {figure}. Label more pairs.",
              flush=True)
    if levels is not None:
        geometry = result.model.pinhole()
        print(f"  water level {result.model.water_level_m:.3f} m (pairs {levels.min():.3f} to {levels.max():.3f} m); "
              f"camera {geometry.height_m:.2f} m above it, focal {geometry.focal_px:.0f} px, nadir "
              f"({geometry.nadir_xy[0]:.1f}, {geometry.nadir_xy[1]:.1f}) m", flush=True)


def _evaluate(args, ds, result, water_level, all_screen, all_gps, camera_lat, camera_lon, pairs: _Pairs, options):
    """``--evaluate-on`` and ``--draws``: figures on held-out labelled videos; their pairs (None without)."""
    if ds is None:
        if args.evaluate_on or args.draws:
            raise CalibrationError("--evaluate-on and --draws need a data folder (--data DIR)")
        return None
    if not (args.evaluate_on or args.draws):
        return None
    eval_videos = parse_videos(args.evaluate_on or DEFAULT_EVAL_VIDEOS)
    *eval_pairs, eval_stamps = ds.calibration_pairs(eval_videos, anchor=args.box_anchor, with_stamps=True)
    if len(eval_pairs[0]) == 0:
        raise DataError(f"{ds.path}: no labelled pairs with gps_ok=1 in videos {eval_videos}")
    spec = args.evaluate_on or DEFAULT_EVAL_VIDEOS
    eval_levels = None if water_level is None else water_level.level_at(eval_stamps)
    if eval_levels is not None and not np.all(np.isfinite(eval_levels)):
        raise CalibrationError(f"videos {spec} fall outside the water-level file {water_level.source}")
    print("\n".join(evaluate(result.model, *eval_pairs, eval_levels).lines(
        f"evaluation on videos {spec} (box points {args.box_anchor:g} of the way down)")))
    try:
        paper = ds.camera_model()
    except DataError:
        paper = None
    if paper is not None:
        fig = evaluate(paper, *ds.calibration_pairs(eval_videos, anchor=paper.box_anchor))
        print("\n".join(fig.lines(f"paper calibration (camera.json, H[0][0] sign corrected) on videos {spec}")))
        print(f"  heading {paper.heading_deg:.2f} deg (paper: 76.5)")
    if args.draws:
        study = study_draws(all_screen, all_gps, *eval_pairs, camera_lat, camera_lon, args.pairs or 11, args.draws,
                            args.seed, pairs.image_size, pairs.center, options)
        print("\n".join(study.lines()))
    return eval_pairs


def _write(args, pairs: _Pairs, result, ds, eval_pairs) -> None:
    """The calibration YAML and its picture, atomically."""
    out = Path(args.out) if args.out else repo_root() / "out" / "calibration" / f"{pairs.name}_camera.yaml"
    if out.suffix.lower() not in (".yaml", ".yml"):
        raise CalibrationError(f"--out must be a .yaml file, got {out}")
    picture = None if args.no_picture else Path(args.picture) if args.picture else out.with_suffix(".png")
    header = _yaml_header(result, pairs.source, sys.argv, pairs.anchor_note)
    overlay = {}
    if pairs.association is not None:
        overlay = {"boxes": pairs.association.boxes(), "track_gps": pairs.association.track_gps(),
                   "pair_label": "associated detections (fit pairs)"}
    frame = args.frame or pairs.picture_frame or _picture_frame(ds, pairs.videos)
    _commit(result, out, picture, header, frame, eval_pairs, pairs.source, overlay)


def _search_options(args):

    return SearchOptions(box_anchor=args.box_anchor, seed=args.seed, hypotheses=args.hypotheses,
                         min_associations=args.min_associations, max_nadir_m=args.max_camera_offset).checked()


def _pairs_source(requested: str, ds) -> str:
    if requested != "auto":
        return requested
    return "labels" if (ds.path / "screen_labels.csv").is_file() else "detections"


def _levels_at(water_level, stamps, what: str):
    """The water level at each of ``stamps`` (None without a water-level file).

    CalibrationError naming how many ``what`` fall outside the file.
    """
    if water_level is None:
        return None
    levels = water_level.level_at(np.asarray(stamps, dtype=float))
    if not np.all(np.isfinite(levels)):
        raise CalibrationError(f"{int(np.sum(~np.isfinite(levels)))} {what} fall outside the water-level file "
                               f"{water_level.source} ({_utc(water_level.start_s)} to {_utc(water_level.end_s)}); "
                               "extend the file to cover them")
    return levels


def _search_dataset(args, ds, videos, camera_lat, camera_lon, image_size, center, water_level):
    """The label-free association over a data folder's frames (detector boxes + the vessel's GPS)."""
    frame_boxes = _frame_boxes_module()
    frames, without_gps = frame_boxes.dataset_frame_boxes(ds, videos, args.detections, args.detector_params,
                                                          args.max_gap_s, args.save_detections)
    print(f"calibrate: {len(frames)} frames of videos {args.videos or DEFAULT_TRAIN_VIDEOS} with a GPS fix of the "
          f"vessel ({without_gps} without one, left out); searching for the camera", flush=True)
    return associate_and_calibrate(frames, camera_lat, camera_lon, image_size, center, _search_options(args),
                                   _fit_options(args), _levels_at(water_level, [f.stamp for f in frames], "frame(s)"))


def _search_video(args, camera_lat, camera_lon, center_text, water_level):
    """The label-free association over a video file's frames; (association, a saved frame, image size)."""
    if not args.gps or not args.start_utc:
        raise CalibrationError("--video needs --gps TRACK (CSV or GPX of the boat in view) and --start-utc TIME (the "
                               "video's first frame, ISO-8601 UTC or epoch seconds)")
    try:
        start = parse_time(args.start_utc)
    except ValueError:
        raise CalibrationError(f"--start-utc {args.start_utc!r} is not a time: give ISO-8601 UTC "
                               "(2024-05-01T10:00:00Z) or epoch seconds") from None
    if args.every < 1:
        raise CalibrationError(f"--every must be at least 1, got {args.every}")
    if args.detections:
        raise CalibrationError("--detections applies to --data folders; with --video the detector runs on the video's "
                               "frames (--save-detections keeps its boxes)")
    track = GpsTrack.from_file(args.gps)
    if len(track) < 2:
        raise DataError(f"{args.gps}: fewer than 2 usable GPS fixes")
    frame_boxes = _frame_boxes_module()
    frames, without_gps, first_image = frame_boxes.video_frame_boxes(
        args.video, start, track, args.every, args.max_gap_s, args.detector_params, args.save_detections)
    image_size = _parse_size(args.image_size, (first_image.shape[1], first_image.shape[0]))
    frame_file = _temporary_frame(first_image)
    print(f"calibrate: {len(frames)} frames of {args.video} with a GPS fix ({without_gps} without one, left out); "
          "searching for the camera", flush=True)
    center = _parse_center(center_text, image_size)
    association = associate_and_calibrate(frames, camera_lat, camera_lon, image_size, center, _search_options(args),
                                          _fit_options(args),
                                          _levels_at(water_level, [f.stamp for f in frames], "frame(s)"))
    return association, frame_file, image_size


def _temporary_frame(image) -> Path:
    """``image`` saved as a JPEG for the picture, removed when the process ends."""
    import atexit

    import cv2

    fd, name = tempfile.mkstemp(prefix="calibrate_frame_", suffix=".jpg")
    os.close(fd)
    cv2.imwrite(name, image)
    atexit.register(lambda: Path(name).unlink(missing_ok=True))
    return Path(name)


def _frame_boxes_module():
    try:
        from vessel_tools.detect import frame_boxes
    except ImportError as exc:
        raise CalibrationError(f"calibrating without labels needs the vessel_detect package (its detector): {exc}; "
                               "build the workspace (./vessel setup)") from None
    return frame_boxes


def _yaml_header(result: CalibrationResult, source: str, argv, anchor_note: str = "") -> str:
    f = result.figures
    anchor_line = anchor_note or (
        f"box_anchor {result.model.box_anchor:g}: H maps the point {result.model.box_anchor:g} of the way down a "
        "vessel's box (0 top, 0.5 centre) to its GPS; the fuser reads boxes there.")
    return "\n".join([
        "Camera calibration written by vessel_tools calibrate (load with --params-file).",
        f"command: calibrate {' '.join(shlex.quote(a) for a in argv[1:])}",
        f"fitted on: {source}",
        f"pairs {f.pairs}: reprojection RMSE {f.reproj_rmse_px:.2f} px, median {f.reproj_median_px:.2f} px; "
        f"back-projected median {f.backproj_median_m:.2f} m, p80 {f.backproj_p80_m:.2f} m",
        "H: z_p (x_p, y_p, 1) = H (x_w, y_w, 1), world metres east/north of (camera_lat, camera_lon), z_p < 0 in "
        "front; K1: x_s = x_c + (x_p - x_c)(1 + K1 r_p^2).",
        anchor_line,
        "heading_deg, horizon_* are derived from H (informational).",
    ] + ([f"water_level_m {result.model.water_level_m:.4f}: H belongs to the sea at this level of the water-level "
          f"file; height_m {result.model.height_m:.3f}: the camera's height above it (derived from H); the fuser "
          "corrects ranges for the tide with the same file (water_level.file)."]
         if math.isfinite(result.model.water_level_m) else []))


_WRITTEN: list[Path] = []
_INTERRUPTED: list[bool] = []


def _commit(result, out: Path, picture: Path | None, header: str, frame, eval_pairs, source, overlay=None) -> None:
    """Draw the picture into a temporary file, then move it and write the YAML with SIGINT held off.

    Either both files appear complete or neither does (an interrupt before the commit leaves nothing behind).
    """
    tmp_picture = None
    try:
        if picture is not None:
            from vessel_tools.calib.calibration_plot import render_calibration_picture

            picture.parent.mkdir(parents=True, exist_ok=True)
            tmp_picture = picture.with_name(f".{picture.stem}.partial.png")
            render_calibration_picture(tmp_picture, result, frame, title=f"calibration from {source}",
                                       extra_points=eval_pairs, **(overlay or {}))
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            write_camera_yaml(out, result.model, header=header)
            _WRITTEN.append(out)
            if tmp_picture is not None:
                os.replace(tmp_picture, picture)
                tmp_picture = None
                _WRITTEN.append(picture)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
    finally:
        if tmp_picture is not None and tmp_picture.exists():
            tmp_picture.unlink()
    for path in _WRITTEN:
        print(f"wrote {path}")


@command_line_tool
def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the exit status (0 ok or interrupted, 2 bad input)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    _WRITTEN.clear()
    _INTERRUPTED.clear()
    try:
        # Ctrl-C must work even when started with SIGINT ignored (background jobs of a non-interactive shell).
        signal.signal(signal.SIGINT, signal.default_int_handler)
    except ValueError:  # not the main thread (called from a test's worker thread): leave it
        pass
    try:
        args = build_parser().parse_args(_ros_params_to_cli(argv))
        if args.draws is not None and args.draws < 1:
            raise CalibrationError(f"--draws must be at least 1, got {args.draws}")
        if args.robust_scale is not None and not (args.robust_scale > 0 and math.isfinite(args.robust_scale)):
            raise CalibrationError(f"--robust-scale must be a positive number of pixels, got {args.robust_scale}")
        return run(args)
    except KeyboardInterrupt:
        _INTERRUPTED.append(True)
        if _WRITTEN:
            print(f"interrupted after writing {', '.join(map(str, _WRITTEN))}", file=sys.stderr)
        else:
            print("interrupted, nothing written", file=sys.stderr)
        return 0
    except SystemExit as exc:  # argparse --help / errors
        return int(exc.code or 0) if isinstance(exc.code, int) else 2


def _run_as_script() -> None:
    """``python -m vessel_tools.calibrate``: exit with main's status.

    After a KeyboardInterrupt caught inside main, CPython's ``-m`` runner still reports the run as killed by
    SIGINT (status 130); ``os._exit`` makes the interrupt exit 0 as promised (files are already closed).
    """
    status = main()
    if _INTERRUPTED:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)


if __name__ == "__main__":
    _run_as_script()
