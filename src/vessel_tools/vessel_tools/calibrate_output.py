"""What ``calibrate`` writes: the camera parameter YAML with its header, and the calibration picture.

Both appear complete or neither does: the picture is drawn into a temporary file first, then the YAML is written
and the picture moved into place with SIGINT held off. ``WRITTEN`` lists the files written so far, for the
message of an interrupted run.
"""

from __future__ import annotations

import math
import os
import shlex
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from vessel_calib.params import write_camera_yaml
from vessel_common.errors import CalibrationError
from vessel_common.paths import repo_root
from vessel_tools.calibrate_pairs import FitPairs

if TYPE_CHECKING:
    from vessel_tools.calib.calibration import CalibrationResult
    from vessel_tools.calib.dataset import Dataset

WRITTEN: list[Path] = []


def write_outputs(args, pairs: FitPairs, result, ds, eval_pairs) -> None:
    """The calibration YAML and its picture, atomically."""
    out = Path(args.out) if args.out else repo_root() / "out" / "calibration" / f"{pairs.name}_camera.yaml"
    if out.suffix.lower() not in (".yaml", ".yml"):
        raise CalibrationError(f"--out must be a .yaml file, got {out}")
    picture = None if args.no_picture else Path(args.picture) if args.picture else out.with_suffix(".png")
    header = yaml_header(result, pairs.source, sys.argv, pairs.anchor_note)
    overlay = {}
    if pairs.association is not None:
        overlay = {"boxes": pairs.association.boxes(), "track_gps": pairs.association.track_gps(),
                   "pair_label": "associated detections (fit pairs)"}
    frame = args.frame or pairs.picture_frame or _picture_frame(ds, pairs.videos)
    commit(result, out, picture, header, frame, eval_pairs, pairs.source, overlay)


def _picture_frame(ds: Dataset | None, videos) -> Path | None:
    if ds is None:
        return None
    for frame in ds.frames(videos) + ds.frames():
        if frame.path.is_file():
            return frame.path
    return None


def yaml_header(result: CalibrationResult, source: str, argv, anchor_note: str = "") -> str:
    """The comment heading the YAML: the command, the pairs, the fit's figures and how to read H."""
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


def commit(result, out: Path, picture: Path | None, header: str, frame, eval_pairs, source, overlay=None) -> None:
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
            WRITTEN.append(out)
            if tmp_picture is not None:
                os.replace(tmp_picture, picture)
                tmp_picture = None
                WRITTEN.append(picture)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
    finally:
        if tmp_picture is not None and tmp_picture.exists():
            tmp_picture.unlink()
    for path in WRITTEN:
        print(f"wrote {path}")
