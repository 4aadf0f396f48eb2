"""The box anchor a label-free calibration writes: where the vessel's GPS falls down the graph detector's boxes.

The label-free search reads the generic detector's boxes (often the cabin without the hull) at ``--box-anchor``;
the fuser will read the graph detector's boxes, which sit on the vessel in their own way, at the calibration's
``camera.box_anchor``. So after the fit, that anchor is measured on the graph detector's boxes, from the vessel's
GPS through the camera just found (``vessel_tools.calib.box_anchor``): no label enters.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from vessel_common.errors import DataError, VesselError
from vessel_common.paths import repo_root
from vessel_tools.calibrate_pairs import FitPairs, frame_boxes_module, pairs_source

#: Fewest frames whose graph-detector box gives the box anchor; with fewer the search detector's anchor is kept.
MIN_ANCHOR_FRAMES = 12


def check_graph_inputs(args) -> None:
    """A mistyped --graph-params/--graph-detections is refused before the search, not after it."""
    for option, value in (("--graph-params", args.graph_params), ("--graph-detections", args.graph_detections)):
        if value and not Path(value).is_file():
            raise DataError(f"{option} {value}: no such file; give an existing file or leave the option out")


def graph_box_anchor(args, ds, pairs: FitPairs, result, water_level):
    """A label-free fit on a data folder: ``camera.box_anchor`` becomes where the GPS falls down the graph's boxes.

    ``result`` with that anchor (and ``pairs`` saying so), or ``result`` as it is, with a warning, when it cannot
    be measured.
    """
    if not _graph_anchor_applies(args, ds, pairs):
        if args.graph_params or args.graph_detections:
            print("calibrate: warning: --graph-params/--graph-detections are used by a label-free fit of a data "
                  "folder (--from detections) only; ignored here")
        return result
    from vessel_calib.camera_model import CameraModel
    from vessel_tools.calib.box_anchor import measure_box_anchor

    frame_boxes = frame_boxes_module()
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
    if not _measured_anchor_usable(args, found):
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


def _graph_anchor_applies(args, ds, pairs: FitPairs) -> bool:
    """Whether the fit is label-free on a data folder, so the graph detector's box anchor is measured."""
    return (pairs.association is not None and ds is not None and pairs.videos is not None
            and not args.keep_box_anchor and args.pairs_from != "both"
            and pairs_source(args.pairs_from, ds) == "detections")


def _measured_anchor_usable(args, found) -> bool:
    """Whether the measured anchor rests on enough frames and lies inside the boxes; a warning when not."""
    if found is None or found.frames < MIN_ANCHOR_FRAMES:
        print(f"calibrate: warning: the graph's detector called a box around the vessel's GPS the vessel of interest "
              f"in {0 if found is None else found.frames} frames (fewer than {MIN_ANCHOR_FRAMES}); box_anchor stays "
              f"{args.box_anchor:g}, the search detector's. Check the graph's detector (--graph-params), or pass "
              "--keep-box-anchor to silence this")
        return False
    if not 0.0 <= found.anchor <= 1.0:
        print(f"calibrate: warning: the vessel's GPS falls {found.anchor:.3f} of the way down the graph detector's "
              f"boxes, outside them (0 top, 1 bottom; {found.frames} frames); box_anchor stays {args.box_anchor:g}. "
              "Its boxes may hold part of the vessel only")
        return False
    return True
