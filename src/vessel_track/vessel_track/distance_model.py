"""Distance from box size: the paper's ``s_x = a / |z_p| + b``, ``s_y = c / |z_p| + d``, fitted to hand boxes.

A vessel's box shrinks with its depth in front of the camera, so the box width and height each give a second
and third estimate of where the vessel is, independent of the box position (paper eq. BBToZ_P and BBToY_P).
The paper's constants (1500, 25, 850, 25 at half resolution) describe its deliberately loose training boxes,
2-3x the tight boxes of the data; here a, b, c, d are fitted by robust least squares to hand-drawn boxes
whose vessel GPS is known (``screen_labels.csv``, training videos only), in full-resolution pixels.

Depth convention: ``z_p`` from ``H`` is defined only up to the arbitrary scale of H, so this module uses
``depth = |z_p| / hypot(H[2,0], H[2,1])``, which for a physical camera is the point's depth along the optical
axis in metres divided by the cosine of the camera's tilt (≈ 1): the same model then works with any
normalisation of H, and a is "pixels times metres" (focal length times vessel width).

Inverting: a width gives a depth, the depth and the box's ideal x give the ideal y on the sea plane
(the third row of ``z_p H^-1 (x_p, y_p, 1) = (x_w, y_w, 1)``):

    y_p = (1 / z_p - G[2,0] x_p - G[2,2]) / G[2,1],   G = H^-1,  z_p = -depth * hypot(H[2,0], H[2,1])

Because ``1 / z_p`` is linear in the box size, a constant pixel noise of the size becomes a constant noise
of this y: the variances used for the fusion weights do not depend on distance.

Fit tool (writes the ``distance_model`` and ``fusion.cue_*`` blocks of the fuser's parameters)::

    python -m vessel_track.distance_model fit --data DIR --videos 7-12 [--calib FILE.yaml] --out FILE.yaml
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_calib.errors import CalibrationError, DataError, VesselError

#: Boxes whose edge is within this many pixels of the image border are cut by it: their size says nothing.
BORDER_MARGIN_PX = 1.0

#: Robust scale from the median absolute deviation of a Gaussian.
MAD_TO_SIGMA = 1.4826


def depth_scale(camera) -> float:
    """hypot(H[2,0], H[2,1]) of the camera's homography: divides |z_p| into metres of depth."""
    H = np.asarray(camera.H, dtype=float)
    scale = float(math.hypot(H[2, 0], H[2, 1]))
    if not (math.isfinite(scale) and scale > 0):
        raise CalibrationError("the homography's third row has no horizontal part (H[2,0] = H[2,1] = 0): the "
                               "camera looks straight down, box sizes cannot give depth; re-run the calibration")
    return scale


def depth_of_world(camera, xw, yw):
    """Depth (m, positive in front) of world points: -z_p / hypot(H[2,0], H[2,1])."""
    return -np.asarray(camera.zp_of_world(xw, yw), dtype=float) / depth_scale(camera)


def ideal_y_of_depth(camera, xp, depth):
    """The ideal y of the sea point at ideal x ``xp`` and depth ``depth`` (m): the paper's BBToY_P.

    NaN where the depth is not positive and finite.
    """
    G = np.asarray(camera.H_inv, dtype=float)
    depth = np.asarray(depth, dtype=float)
    xp = np.asarray(xp, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_zp = -1.0 / (depth * depth_scale(camera))
        y = (inv_zp - G[2, 0] * xp - G[2, 2]) / G[2, 1]
    ok = np.isfinite(depth) & (depth > 0) & np.isfinite(y)
    out = np.where(ok, y, np.nan)
    return float(out) if out.ndim == 0 else out


def box_cut_by_border(boxes_xyxy, image_size, margin: float = BORDER_MARGIN_PX):
    """(N, 2) bool: (width cut, height cut) for boxes touching the left/right or top/bottom image border."""
    b = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    width, height = image_size
    cut_w = (b[:, 0] <= margin) | (b[:, 2] >= width - margin)
    cut_h = (b[:, 1] <= margin) | (b[:, 3] >= height - margin)
    return np.column_stack([cut_w, cut_h])


@dataclass(frozen=True)
class BoxSizeDistanceModel:
    """``width = a / depth + b``, ``height = c / depth + d`` (full-resolution px, depth in m, see module doc).

    ``sigma_width_px`` and ``sigma_height_px`` are the robust standard deviations of the fit residuals.
    The defaults are the fit on the 66 hand boxes of training videos 7-12 with the calibration fitted on the
    same videos (``python -m vessel_track.distance_model fit``).
    """

    a: float = 4838.3043242984
    b: float = 6.0449776177
    c: float = 2844.3419953655
    d: float = -0.2718582771
    sigma_width_px: float = 14.0365271393
    sigma_height_px: float = 11.913855257
    n_points: int = 66
    source: str = "screen_labels videos 7-12, camera aitas_camera.yaml"

    def __post_init__(self) -> None:
        """Reject constants that would make the inversion meaningless."""
        for name in ("a", "c"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise DataError(f"distance model: {name} must be a positive number (px x m), got {value!r}")
        for name in ("b", "d"):
            if not math.isfinite(getattr(self, name)):
                raise DataError(f"distance model: {name} must be a finite number of px, got {getattr(self, name)!r}")
        for name in ("sigma_width_px", "sigma_height_px"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise DataError(f"distance model: {name} must be > 0, got {value!r}")

    # ------------------------------------------------------------------ forward and inverse
    def size_of_depth(self, depth):
        """Expected (width, height) in px at ``depth`` metres."""
        depth = np.asarray(depth, dtype=float)
        return self.a / depth + self.b, self.c / depth + self.d

    def depth_from_width(self, width_px):
        """Depth (m) from a box width; NaN where the width is not above ``b`` (no finite depth)."""
        return _invert(width_px, self.a, self.b)

    def depth_from_height(self, height_px):
        """Depth (m) from a box height; NaN where the height is not above ``d``."""
        return _invert(height_px, self.c, self.d)

    def ideal_y_from_sizes(self, camera, xp, width_px, height_px):
        """(y from width, y from height): ideal y of the vessel given its ideal x and box size; NaN if unusable."""
        return (ideal_y_of_depth(camera, xp, self.depth_from_width(width_px)),
                ideal_y_of_depth(camera, xp, self.depth_from_height(height_px)))

    def ideal_y_sigma(self, camera) -> tuple[float, float]:
        """Standard deviation (ideal px) of the y from width and from height implied by the size residuals."""
        G = np.asarray(camera.H_inv, dtype=float)
        n = depth_scale(camera)
        return (self.sigma_width_px / (self.a * n * abs(G[2, 1])),
                self.sigma_height_px / (self.c * n * abs(G[2, 1])))

    # ------------------------------------------------------------------ parameters
    def to_params(self) -> dict:
        """The ``distance_model`` block of the fuser's parameters."""
        return {"a": float(self.a), "b": float(self.b), "c": float(self.c), "d": float(self.d),
                "sigma_width_px": float(self.sigma_width_px), "sigma_height_px": float(self.sigma_height_px),
                "n_points": int(self.n_points), "source": str(self.source)}

    @classmethod
    def from_params(cls, params: dict) -> BoxSizeDistanceModel:
        """Build from a ``distance_model`` block; missing keys take the defaults."""
        defaults = cls()
        try:
            return cls(**{k: type(getattr(defaults, k))(params[k]) for k in
                          ("a", "b", "c", "d", "sigma_width_px", "sigma_height_px", "n_points", "source")
                          if k in params})
        except (TypeError, ValueError) as error:
            raise DataError(f"distance model: a value of the distance_model block is not a number: {error}") from None


def _invert(size, k, offset):
    size = np.asarray(size, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = k / (size - offset)
    ok = np.isfinite(depth) & (size - offset > 0)
    out = np.where(ok, depth, np.nan)
    return float(out) if out.ndim == 0 else out


def _robust_line(u: np.ndarray, s: np.ndarray) -> tuple[float, float, float]:
    """Fit s = k u + offset robustly (soft-L1); returns (k, offset, robust sigma of the residuals)."""
    from scipy.optimize import least_squares

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
    from vessel_track.pipeline import csv_detections

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
    from vessel_track.fusion import cue_residuals

    if levels is None:
        return cue_residuals(camera, model, boxes, world, config)
    parts = [cue_residuals(camera.at_water_level(level), model, box[None], point[None], config)
             for box, point, level in zip(boxes, world, levels, strict=True)]
    return np.vstack([part[0] for part in parts]), np.concatenate([part[1] for part in parts])


def cross_validated_cue_statistics(dataset, videos: list[int] | None, box_anchor: float, config=None,
                                   detections_csv=None, water_level=None):
    """Cue noise measured out of sample (leave one video out), pooled over the training videos.

    For each training video: calibrate (``vessel_calib.calibration``, boxes read ``box_anchor`` of the way down)
    and fit the distance model on the other videos, and take the residuals of its boxes.

    The calibration fitted on the very boxes whose residuals are measured makes in-sample residuals
    optimistic; the fusion weights and covariances should describe boxes the calibration has not seen.
    """
    from vessel_calib.calibration import calibrate_from_labels
    from vessel_track.fusion import cue_statistics_of_residuals

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


def main(argv: list[str] | None = None) -> int:
    """Command line: ``fit --data DIR --videos 7-12 [--calib FILE] --out FILE.yaml``."""
    parser = argparse.ArgumentParser(prog="python -m vessel_track.distance_model",
                                     description="Fit the box-size distance model and the fusion weights.")
    sub = parser.add_subparsers(dest="command", required=True)
    fit = sub.add_parser("fit", help="fit a, b, c, d and the cue covariance to hand boxes with GPS")
    fit.add_argument("--data", type=Path, default=None, help="dataset folder (default: $VESSEL_DATA or "
                                                              "../shared/aitas)")
    fit.add_argument("--videos", default="7-12", help="training videos (default 7-12, the paper's training split)")
    fit.add_argument("--calib", type=Path, default=None,
                     help="calibration YAML (default: config/aitas_camera.yaml if present, else the dataset's "
                          "paper-corrected calibration)")
    fit.add_argument("--out", type=Path, required=True, help="parameter YAML to write/update (fuser block)")
    fit.add_argument("--node", default="fuser", help="node block to write into (default: fuser)")
    fit.add_argument("--detections", type=Path, default=None,
                     help="fit to the detector's boxes of the vessel (CSV video,frame,x1,y1,x2,y2,score,class_id "
                          "over the training videos) instead of the hand boxes; the calibration still comes from "
                          "the hand labels")
    fit.add_argument("--in-sample", action="store_true",
                     help="measure the cue noise on the training boxes themselves instead of leave-one-video-out "
                          "(in-sample is optimistic: the calibration was fitted on the same boxes)")
    args = parser.parse_args(argv)
    try:
        from vessel_calib.dataset import parse_videos
        from vessel_track.error_model import update_params_file
        from vessel_track.fuser_settings import load_fuser_settings
        from vessel_track.fusion import FusionConfig, cue_statistics_of_residuals
        from vessel_track.pipeline import load_camera, open_dataset

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
        if args.in_sample:
            if args.detections is None:
                stamps = training_pairs(dataset, camera, videos, with_stamps=True)[2]
            else:
                stamps = detector_pairs(dataset, camera, videos, args.detections, with_stamps=True)[2]
            levels = None if water_level is None else water_level.level_at(stamps)
            stats = cue_statistics_of_residuals(*cue_residuals_at_levels(camera, model, boxes, world, levels,
                                                                         config))
            how = "in-sample"
        else:
            stats = cross_validated_cue_statistics(dataset, videos, camera.box_anchor, config, args.detections,
                                                   water_level=water_level)
            how = "leave-one-video-out"
        update_params_file(args.out, args.node, "distance_model", model.to_params())
        fusion_block = kept.to_params()
        fusion_block.update(stats.to_params())
        update_params_file(args.out, args.node, "fusion", fusion_block)
    except VesselError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"distance model from {model.n_points} boxes: width = {model.a:.0f}/depth + {model.b:.1f} px "
          f"(sigma {model.sigma_width_px:.1f} px), height = {model.c:.0f}/depth + {model.d:.1f} px "
          f"(sigma {model.sigma_height_px:.1f} px)")
    print(f"cue std in ideal y ({how}, px): centre {stats.std_px[0]:.2f}, width {stats.std_px[1]:.2f}, height "
          f"{stats.std_px[2]:.2f}; fitted weights {', '.join(f'{w:.2f}' for w in stats.weights)}")
    print(f"-> {args.out} ({args.node}.distance_model, {args.node}.fusion)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
