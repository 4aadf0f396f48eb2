"""Fit the box-size distance model and the fusion's cue noise on hand boxes whose GPS is known.

Writes the ``distance_model`` and ``fusion.cue_*`` blocks of the fuser's parameters::

    ./vessel fit distance-model --data DIR --videos 7-12 [--calib FILE.yaml] --out FILE.yaml

The runtime model is ``distance_model.BoxSizeDistanceModel``; this module holds its fit, the (box, GPS) pairs it is
fitted on and the cross-validated noise of the cues.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from vessel_calib.params import read_params_yaml, update_params_block
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_common.paths import parse_videos
from vessel_tools.calib.calibration import calibrate_from_labels
from vessel_tools.track.error_model_fit import update_params_file
from vessel_tools.track.offline_data import csv_detections, load_camera, open_dataset
from vessel_track.distance_model import MAD_TO_SIGMA, BoxSizeDistanceModel, box_cut_by_border, depth_of_world
from vessel_track.fuser_settings import load_fuser_settings
from vessel_track.fusion import FusionConfig, cue_residuals, cue_statistics_of_residuals


def _robust_line(u: np.ndarray, s: np.ndarray) -> tuple[float, float, float]:
    """Fit s = k u + offset robustly (soft-L1); returns (k, offset, robust sigma of the residuals)."""
    A = np.column_stack([u, np.ones_like(u)])
    x0, *_ = np.linalg.lstsq(A, s, rcond=None)
    resid0 = s - A @ x0
    scale = max(MAD_TO_SIGMA * float(np.median(np.abs(resid0 - np.median(resid0)))), 0.5)
    fit = least_squares(lambda p: A @ p - s, x0, loss="soft_l1", f_scale=scale)
    resid = s - A @ fit.x
    sigma = max(MAD_TO_SIGMA * float(np.median(np.abs(resid - np.median(resid)))), 0.5)
    return float(fit.x[0]), float(fit.x[1]), sigma


def fit_distance_model(camera, boxes_xyxy, world_xy, source: str = "") -> BoxSizeDistanceModel:
    """Fit a, b, c, d to boxes (N, 4 px) of vessels at known world positions (N, 2 m).

    Boxes cut by the image border are left out of the fit of the dimension they cut; points behind the camera
    are left out. Raises DataError with fewer than 3 usable boxes per dimension or a non-positive slope.
    """
    boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    world = np.asarray(world_xy, dtype=float).reshape(-1, 2)
    if boxes.shape[0] != world.shape[0]:
        raise DataError(f"distance model fit: {boxes.shape[0]} boxes but {world.shape[0]} positions")
    depth = depth_of_world(camera, world[:, 0], world[:, 1])
    sizes = boxes[:, 2:] - boxes[:, :2]
    cut = box_cut_by_border(boxes, camera.image_size)
    usable = np.isfinite(depth) & (depth > 0) & np.all(np.isfinite(sizes), axis=1) & np.all(sizes > 0, axis=1)
    result = []
    for dim, name in ((0, "width"), (1, "height")):
        ok = usable & ~cut[:, dim]
        if ok.sum() < 3:
            raise DataError(f"distance model fit: only {int(ok.sum())} usable box {name}s (need 3); "
                            "use more labelled frames with GPS")
        k, offset, sigma = _robust_line(1.0 / depth[ok], sizes[ok, dim])
        if k <= 0:
            raise DataError(f"distance model fit: box {name} does not shrink with distance in these labels "
                            f"(slope {k:.3g}); check that boxes and GPS positions belong together")
        result.append((k, offset, sigma, int(ok.sum())))
    (a, b, sw, nw), (c, d, sh, nh) = result
    return BoxSizeDistanceModel(a, b, c, d, sw, sh, n_points=min(nw, nh), source=source)


def training_pairs(dataset, camera, videos: list[int] | None, with_stamps: bool = False):
    """Hand boxes (primary, gps_ok) of ``videos`` with the vessel's world position: (boxes (N,4), world (N,2)).

    ``with_stamps`` adds a third array, each box's stamp (Unix seconds).
    """
    labels = [r for r in dataset.labels(videos, primary_only=True) if r.gps_ok]
    if not labels:
        raise DataError(f"no labelled boxes with GPS in videos {videos}; screen_labels.csv needs rows with "
                        f"gps_ok=1 in those videos")
    boxes = np.array([[r.x1, r.y1, r.x2, r.y2] for r in labels], dtype=float)
    xw, yw = camera.gps_to_world(np.array([r.lat for r in labels]), np.array([r.lon for r in labels]))
    if with_stamps:
        return boxes, np.column_stack([xw, yw]), np.array([r.stamp for r in labels], dtype=float)
    return boxes, np.column_stack([xw, yw])


def pixels_from_vessel(track, camera, frame, max_gap_s: float = 3.0):
    """Pixels from each box centre of ``frame`` to the vessel's projected GPS position, and that position.

    ``(distances (N,), (lat, lon))``, or None where the GPS cannot be interpolated (fixes more than ``max_gap_s``
    apart), the vessel is behind the camera or outside the image, or the frame has no boxes. This is how the
    detector's output gets labels without hand labelling (the paper's trick).
    """
    if len(frame.boxes) == 0 or not len(track.stamps):
        return None
    lat, lon, ok = track.interpolate(frame.stamp, max_gap_s=max_gap_s)
    if not ok:
        return None
    xs, ys, in_front = camera.gps_to_screen(lat, lon)
    if not (in_front and camera.in_image(xs, ys)):
        return None
    centres = (frame.boxes[:, :2] + frame.boxes[:, 2:]) / 2.0
    return np.hypot(centres[:, 0] - xs, centres[:, 1] - ys), (lat, lon)


def detector_pairs(dataset, camera, videos: list[int] | None, detections_csv: Path, max_px: float = 30.0,
                   with_stamps: bool = False):
    """Detector boxes of the vessel of interest with its world position: (boxes (N, 4), world (N, 2)).

    For every frame of ``videos`` where the vessel's GPS can be interpolated (fixes at most 3 s apart) and
    projects into the image, the detection whose centre is nearest to the projection, if within ``max_px``.
    Detector boxes are not hand boxes (looser, wake included): fitting the size model and the cue noise to them
    makes the fusion right for the detector the graph runs.
    """
    track = dataset.gps_track()
    boxes, world, stamps = [], [], []
    for frame in csv_detections(detections_csv, dataset, videos):
        found = pixels_from_vessel(track, camera, frame)
        if found is None:
            continue
        distance, (lat, lon) = found
        best = int(np.argmin(distance))
        if distance[best] <= max_px:
            boxes.append(frame.boxes[best])
            world.append(camera.gps_to_world(lat, lon))
            stamps.append(frame.stamp)
    if len(boxes) < 5:
        raise DataError(f"{detections_csv}: only {len(boxes)} detections match the vessel's GPS within {max_px} px "
                        f"in videos {videos}; run the detector on the training videos")
    if with_stamps:
        return np.array(boxes, dtype=float), np.array(world, dtype=float), np.array(stamps, dtype=float)
    return np.array(boxes, dtype=float), np.array(world, dtype=float)


def cue_residuals_at_levels(camera, model, boxes, world, levels=None, config=None):
    """``fusion.cue_residuals`` with each box seen through the camera at its own water level (``levels``, m).

    This is how the fuser sees a box when a water-level file is set (``TrackFuser.camera_at``); without
    ``levels`` every box goes through ``camera`` as it is.
    """
    if levels is None:
        return cue_residuals(camera, model, boxes, world, config)
    parts = [cue_residuals(camera.at_water_level(level), model, box[None], point[None], config)
             for box, point, level in zip(boxes, world, levels, strict=True)]
    return np.vstack([part[0] for part in parts]), np.concatenate([part[1] for part in parts])


def cross_validated_cue_statistics(dataset, videos: list[int] | None, box_anchor: float, config=None,
                                   detections_csv=None, water_level=None):
    """Cue noise measured out of sample (leave one video out), pooled over the training videos.

    For each training video: calibrate (``vessel_tools.calib.calibration``, boxes read ``box_anchor`` of the way down)
    and fit the distance model on the other videos, and take the residuals of its boxes.

    The calibration fitted on the very boxes whose residuals are measured makes in-sample residuals
    optimistic; the fusion weights and covariances should describe boxes the calibration has not seen.
    """
    labelled = sorted({r.video for r in dataset.labels(videos, primary_only=True) if r.gps_ok})
    if len(labelled) < 3:
        raise DataError(f"leave-one-video-out needs labelled boxes with GPS in 3 videos, found {labelled}; use "
                        f"--in-sample")
    resid, x_resid = [], []
    for held_out in labelled:
        others = [v for v in labelled if v != held_out]
        camera = calibrate_from_labels(dataset, others, box_anchor, water_level=water_level)
        if detections_csv is None:
            boxes, world = training_pairs(dataset, camera, others)
            held_boxes, held_world, held_stamps = training_pairs(dataset, camera, [held_out], with_stamps=True)
        else:
            boxes, world = detector_pairs(dataset, camera, others, detections_csv)
            try:
                held_boxes, held_world, held_stamps = detector_pairs(dataset, camera, [held_out], detections_csv,
                                                                     with_stamps=True)
            except DataError:
                continue  # too few matched detections in this video to measure anything
        model = fit_distance_model(camera, boxes, world)
        levels = None if water_level is None else water_level.level_at(held_stamps)
        r, x = cue_residuals_at_levels(camera, model, held_boxes, held_world, levels, config)
        resid.append(r)
        x_resid.append(x)
    return cue_statistics_of_residuals(np.vstack(resid), np.concatenate(x_resid))


def update_detector_size_prior(path: Path, model: BoxSizeDistanceModel) -> bool:
    """Give the file's ``detector.size_prior.model`` the new a, b, c, d, if it has one; True if written.

    The detector's size prior reads the same model as the fuser.
    """
    block = (read_params_yaml(path).get("detector") or {}).get("size_prior")
    if not isinstance(block, dict) or "model" not in block:
        return False
    update_params_block(path, "detector", "size_prior", {**block, "model": [model.a, model.b, model.c, model.d]})
    return True


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="./vessel fit distance-model",
                                     description="Fit the box-size distance model and the fusion weights.")
    parser.add_argument("--data", type=Path, default=None, help="dataset folder (default: $VESSEL_DATA or "
                                                              "../shared/aitas)")
    parser.add_argument("--videos", default="7-12", help="training videos (default 7-12, the paper's training split)")
    parser.add_argument("--calib", type=Path, default=None,
                        help="calibration YAML (default: config/aitas_camera.yaml if present, else the dataset's "
                          "paper-corrected calibration)")
    parser.add_argument("--out", type=Path, required=True, help="parameter YAML to write/update (fuser block)")
    parser.add_argument("--node", default="fuser", help="node block to write into (default: fuser)")
    parser.add_argument("--detections", type=Path, default=None,
                        help="fit to the detector's boxes of the vessel (CSV video,frame,x1,y1,x2,y2,score,class_id "
                          "over the training videos) instead of the hand boxes; the calibration still comes from "
                          "the hand labels")
    parser.add_argument("--in-sample", action="store_true",
                        help="measure the cue noise on the training boxes themselves instead of leave-one-video-out "
                          "(in-sample is optimistic: the calibration was fitted on the same boxes)")
    return parser


@command_line_tool
def main(argv: list[str] | None = None) -> int:
    """Command line: ``--data DIR --videos 7-12 [--calib FILE] --out FILE.yaml``."""
    args = _parser().parse_args(argv)
    dataset = open_dataset(args.data)
    camera, camera_source = load_camera(args.calib, dataset)
    videos = parse_videos(args.videos)
    if args.detections is None:
        boxes, world = training_pairs(dataset, camera, videos)
        source = f"screen_labels videos {args.videos}, camera {Path(camera_source.split(' ')[0]).name}"
    else:
        boxes, world = detector_pairs(dataset, camera, videos, args.detections)
        source = f"detector boxes {args.detections.name} videos {args.videos}, camera " \
                 f"{Path(camera_source.split(' ')[0]).name}"
    model = fit_distance_model(camera, boxes, world, source=source)
    # The file's other fusion settings stay; the cues are measured on boxes read as these boxes are read,
    # and at the water level of each box's instant when the file names a water-level table.
    settings = load_fuser_settings(args.out, args.node) if args.out.is_file() else None
    kept = settings.fusion if settings is not None else FusionConfig()
    water_level = settings.water_level.load() if settings is not None else None
    config = kept if args.detections is not None else dataclasses.replace(kept, anchor_offset=0.0)
    stats, how = _cue_statistics(args, dataset, camera, videos, model, boxes, world, config, water_level)
    update_params_file(args.out, args.node, "distance_model", model.to_params())
    fusion_block = kept.to_params()
    fusion_block.update(stats.to_params())
    update_params_file(args.out, args.node, "fusion", fusion_block)
    detector_prior = update_detector_size_prior(args.out, model)
    print(f"distance model from {model.n_points} boxes: width = {model.a:.0f}/depth + {model.b:.1f} px "
          f"(sigma {model.sigma_width_px:.1f} px), height = {model.c:.0f}/depth + {model.d:.1f} px "
          f"(sigma {model.sigma_height_px:.1f} px)")
    print(f"cue std in ideal y ({how}, px): centre {stats.std_px[0]:.2f}, width {stats.std_px[1]:.2f}, height "
          f"{stats.std_px[2]:.2f}; fitted weights {', '.join(f'{w:.2f}' for w in stats.weights)}")
    print(f"-> {args.out} ({args.node}.distance_model, {args.node}.fusion"
          f"{', detector.size_prior.model' if detector_prior else ''})")
    return 0


def _cue_statistics(args, dataset, camera, videos, model, boxes, world, config, water_level):
    """The cue noise and fusion weights, in-sample or leave-one-video-out, and which of the two it is."""
    if args.in_sample:
        if args.detections is None:
            stamps = training_pairs(dataset, camera, videos, with_stamps=True)[2]
        else:
            stamps = detector_pairs(dataset, camera, videos, args.detections, with_stamps=True)[2]
        levels = None if water_level is None else water_level.level_at(stamps)
        stats = cue_statistics_of_residuals(*cue_residuals_at_levels(camera, model, boxes, world, levels,
                                                                     config))
        return stats, "in-sample"
    stats = cross_validated_cue_statistics(dataset, videos, camera.box_anchor, config, args.detections,
                                           water_level=water_level)
    return stats, "leave-one-video-out"

if __name__ == "__main__":
    sys.exit(main())
