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
import math
import os
import signal
import sys

import numpy as np

from vessel_calib import geodesy
from vessel_common.command_line import command_line_tool
from vessel_common.errors import CalibrationError, DataError
from vessel_common.paths import default_data_dir, parse_videos
from vessel_tools.calib.calibration import (
    FEW_PAIRS,
    calibrate,
    degrees_of_freedom,
    evaluate,
    leave_one_pair_out_errors,
    study_draws,
)
from vessel_tools.calib.dataset import Dataset
from vessel_tools.calibrate_box_anchor import check_graph_inputs, graph_box_anchor
from vessel_tools.calibrate_options import DEFAULT_EVAL_VIDEOS, fit_options, ros_params_to_cli
from vessel_tools.calibrate_options import build_parser as _build_parser
from vessel_tools.calibrate_output import WRITTEN, write_outputs
from vessel_tools.calibrate_pairs import FitPairs, collect_pairs, draw_pairs, pair_levels

# Heavy modules (numpy, scipy, matplotlib) are imported inside the functions, after main() has taken over
# SIGINT, so Ctrl-C during start-up still ends with "interrupted, nothing written" instead of a traceback.

_INTERRUPTED: list[bool] = []


def build_parser() -> argparse.ArgumentParser:
    """The command-line interface (``vessel_tools.calibrate_options``), described by this module's summary."""
    return _build_parser(__doc__.split("\n\n")[0])


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
    check_graph_inputs(args)
    water_level = None
    if args.water_level:
        from vessel_calib.water_level import load_water_level

        water_level = load_water_level(args.water_level)
    pairs = collect_pairs(args, ds, camera_lat, camera_lon, water_level)
    available = len(pairs.screen)
    all_screen, all_gps = pairs.screen, pairs.gps
    draw_pairs(args, pairs)
    options = fit_options(args)
    levels = pair_levels(args, pairs, water_level)
    result = calibrate(pairs.screen, pairs.gps, camera_lat, camera_lon, pairs.image_size, pairs.center, options,
                       box_anchor=args.box_anchor, water_levels=levels)
    _report_fit(args, pairs, available, result, options, levels, camera_lat, camera_lon)
    result = graph_box_anchor(args, ds, pairs, result, water_level)
    eval_pairs = _evaluate(args, ds, result, water_level, all_screen, all_gps, camera_lat, camera_lon, pairs, options)
    write_outputs(args, pairs, result, ds, eval_pairs)
    return 0


def _report_fit(args, pairs: FitPairs, available: int, result, options, levels, camera_lat, camera_lon) -> None:
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


def _evaluate(args, ds, result, water_level, all_screen, all_gps, camera_lat, camera_lon, pairs: FitPairs, options):
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


@command_line_tool
def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the exit status (0 ok or interrupted, 2 bad input)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    WRITTEN.clear()
    _INTERRUPTED.clear()
    try:
        # Ctrl-C must work even when started with SIGINT ignored (background jobs of a non-interactive shell).
        signal.signal(signal.SIGINT, signal.default_int_handler)
    except ValueError:  # not the main thread (called from a test's worker thread): leave it
        pass
    try:
        args = build_parser().parse_args(ros_params_to_cli(argv))
        if args.draws is not None and args.draws < 1:
            raise CalibrationError(f"--draws must be at least 1, got {args.draws}")
        if args.robust_scale is not None and not (args.robust_scale > 0 and math.isfinite(args.robust_scale)):
            raise CalibrationError(f"--robust-scale must be a positive number of pixels, got {args.robust_scale}")
        return run(args)
    except KeyboardInterrupt:
        _INTERRUPTED.append(True)
        if WRITTEN:
            print(f"interrupted after writing {', '.join(map(str, WRITTEN))}", file=sys.stderr)
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
