"""The options of ``calibrate``: its command line, the same options as ROS parameters, what the fits take.

``ros2 run vessel_tools calibrate --ros-args -p data:=DIR --params-file FILE`` works like the plain options:
``-p name:=value`` and the ``calibrate:`` block of a parameter file become ``--name value``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

from vessel_calib.params import read_params_yaml
from vessel_common.errors import CalibrationError
from vessel_common.parameter_table import Param, ParameterTable
from vessel_tools.calib.calibration import DEFAULT_BOX_ANCHOR, LOSSES, PAPER_OPTIONS, FitOptions
from vessel_tools.calib.gps_association import SearchOptions

DEFAULT_TRAIN_VIDEOS = "7-12"
PAIR_SOURCES = ("auto", "labels", "detections", "both")
DEFAULT_EVAL_VIDEOS = "13-17"
NODE_NAME = "calibrate"
_FLAG_PARAMS = {"no_picture"}


class _Parser(argparse.ArgumentParser):
    """argparse with the project's one-line ``error: ...`` and exit status 2."""

    def error(self, message):
        print(f"error: {message} (see calibrate --help)", file=sys.stderr)
        raise SystemExit(2)


def build_parser(description: str = "") -> argparse.ArgumentParser:
    """The command-line interface; ``description`` heads its ``--help``."""
    p = _Parser(prog="calibrate", description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_input_options(p.add_argument_group("input"))
    _add_fit_options(p.add_argument_group("fit"))
    out = p.add_argument_group("output")
    out.add_argument("--out", help="parameter YAML to write (default out/calibration/<name>_camera.yaml)")
    out.add_argument("--picture", help="calibration picture PNG (default next to the YAML)")
    out.add_argument("--no-picture", action="store_true", help="do not draw the picture")
    out.add_argument("--frame", help="camera frame to draw the picture on (default: a frame of the data set)")
    _add_label_free_options(p.add_argument_group("without labels (--from detections, --video)"),
                            p.add_argument_group("the graph's boxes (--from detections on a data folder)"))
    study = p.add_argument_group("study")
    study.add_argument("--evaluate-on", help="videos to evaluate on (e.g. 13-17): validation figures")
    study.add_argument("--draws", type=int, help="repeat the fit on this many random draws of --pairs pairs")
    return p


def _add_input_options(src) -> None:
    """Where the (screen, GPS) pairs come from: a data folder, a pairs CSV or a video, and the camera."""
    src.add_argument("--data", help="data folder laid out like ../shared/aitas")
    src.add_argument("--videos", help=f"videos to fit on (default {DEFAULT_TRAIN_VIDEOS})")
    src.add_argument("--pairs", type=int, help="use a random draw of this many pairs (the paper used 11)")
    src.add_argument("--seed", type=int, default=0, help="random seed of --pairs / --draws (default 0)")
    src.add_argument("--box-anchor", type=float, default=DEFAULT_BOX_ANCHOR,
                     help="point of a labelled box that stands for the vessel's GPS: its horizontal centre, this "
                          f"share of the way down (0 top, 0.5 centre as in the paper, 1 bottom; default "
                          f"{DEFAULT_BOX_ANCHOR}, see vessel_tools.calib.calibration.DEFAULT_BOX_ANCHOR). Written to "
                          "the file as camera.box_anchor, so the fuser reads boxes the same way")
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


def _add_fit_options(fit) -> None:
    fit.add_argument("--method", choices=("refined", "paper"), default="refined",
                     help="refined: joint H+K1 refinement (default); paper: K1 scan + DLT only")
    fit.add_argument("--loss", choices=LOSSES, default="soft_l1", help="refinement loss (default soft_l1)")
    fit.add_argument("--robust", nargs="?", const="soft_l1", choices=LOSSES[1:], metavar="LOSS",
                     help="robust loss (soft_l1 if no LOSS given); the default loss is already soft_l1")
    fit.add_argument("--robust-scale", type=float, default=3.0, help="robust loss scale, px (default 3)")
    fit.add_argument("--far-weight", type=float, default=0.0,
                     help="weight pairs by (distance/100 m)^A to favour far accuracy (default 0)")
    fit.add_argument("--k1", type=float, help="fix K1 to this value instead of fitting it")


def _add_label_free_options(search, graph) -> None:
    """The search among detected boats, and the graph detector whose boxes give the written box anchor."""
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
    graph.add_argument("--graph-params", help="the graph's parameter file (default config/aitas.yaml): where the "
                       "vessel's GPS falls down its detector's boxes, through the camera found, becomes "
                       "camera.box_anchor, the point the fuser reads them at")
    graph.add_argument("--graph-detections", help="a `detect run` CSV of that detector over the same frames (its "
                       "p_target), instead of running it")
    graph.add_argument("--keep-box-anchor", action="store_true", help="write --box-anchor (the search detector's) "
                       "instead of measuring the graph detector's")


# --------------------------------------------------------------------------- ROS arguments
def ros_params_to_cli(argv: list[str]) -> list[str]:
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


# --------------------------------------------------------------------------- what the options say
def parse_size(text: str | None, default: tuple[int, int]) -> tuple[int, int]:
    """``--image-size WIDTHxHEIGHT`` (``default`` when not given)."""
    if not text:
        return default
    try:
        w, h = (int(v) for v in text.lower().replace(",", "x").split("x"))
        if w <= 0 or h <= 0:
            raise ValueError
        return w, h
    except ValueError:
        raise CalibrationError(f"--image-size must look like 1280x720, got {text!r}") from None


def parse_center(text: str | None, size: tuple[int, int]) -> tuple[float, float]:
    """``--center X,Y`` (the image centre when not given)."""
    if not text:
        return size[0] / 2.0, size[1] / 2.0
    try:
        x, y = (float(v) for v in text.split(","))
        return x, y
    except ValueError:
        raise CalibrationError(f"--center must look like 640,360, got {text!r}") from None


def fit_options(args) -> FitOptions:
    """FitOptions from the command line."""
    if args.method == "paper":
        options = PAPER_OPTIONS
    else:
        options = FitOptions(loss=args.robust or args.loss, loss_scale_px=args.robust_scale,
                             far_weight=args.far_weight)
    if args.k1 is not None:
        options = replace(options, k1_fixed=args.k1, fit_k1=False)
    return options.checked()


def search_options(args) -> SearchOptions:
    """SearchOptions of the label-free search from the command line."""
    return SearchOptions(box_anchor=args.box_anchor, seed=args.seed, hypotheses=args.hypotheses,
                         min_associations=args.min_associations, max_nadir_m=args.max_camera_offset).checked()


# --------------------------------------------------------------------------- its part file
PART_OPTIONS = ("data", "videos", "label_passes", "pairs_csv", "gps", "max_gap_s", "image_size", "method", "loss",
                "robust_scale", "far_weight", "out", "picture", "evaluate_on")
"""The options ``config/parts/calibrate.yaml`` lists as ROS parameters (every option is one: ``-p name:=value``)."""


def calibrate_parameters() -> ParameterTable:
    """The main options of calibrate as the rows of a parameter table, written from its argparse options.

    The tool is not a node, but takes ``--ros-args -p`` and a ``calibrate:`` block of a parameter file; its part
    file comes from the same option definitions as ``--help``, so the two cannot drift.
    """
    actions = {action.dest: action for action in build_parser()._actions}
    rows = []
    for name in PART_OPTIONS:
        action = actions[name]
        default = action.default if action.default is not None else ""
        if name == "videos" and default == "":
            default = DEFAULT_TRAIN_VIDEOS
        rows.append(Param(name, default, action.help.replace("%%", "%"), choices=tuple(action.choices or ())))
    return ParameterTable(NODE_NAME, "Offline calibration tool (vessel_tools calibrate): fits H and K1 from "
                          "(screen, GPS) pairs and writes the `camera:` block every node loads.", tuple(rows),
                          notes=("It runs once, not in the graph: its options, overridden by -p name:=value or the "
                                 "--options of `calibrate --help`.", "Empty strings mean \"not set\"."), is_node=False)
