"""The calibration picture: metric grid, horizon and labelled points against their projections over a frame.

Like the paper's calibration figures: the sea-plane grid (every 50 m, numbered rings of distance) and the
fitted horizon drawn over a camera frame, the labelled screen points (blue) against the projections of their GPS
positions (orange) joined by error lines (green); below, the paper's K1 brute-force curve and the back-projected
error against distance. Rendered with matplotlib's Agg backend (no display needed), saved atomically.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from vessel_calib import geodesy
from vessel_calib.camera_model import CameraModel
from vessel_common.errors import CalibrationError
from vessel_tools.calib.calibration import CalibrationResult


def _polyline(model: CameraModel, xw: np.ndarray, yw: np.ndarray):
    xs, ys, ok = model.world_to_screen(xw, yw)
    width, height = model.image_size
    inside = ok & (xs > -width) & (xs < 2 * width) & (ys > -height) & (ys < 2 * height)
    return np.where(inside, xs, np.nan), np.where(inside, ys, np.nan)


def _grid_extent(model: CameraModel, world: np.ndarray | None) -> float:
    reach = 300.0
    if world is not None and len(world):
        reach = max(reach, float(np.max(np.hypot(world[:, 0], world[:, 1]))) * 1.2)
    return float(min(reach, 2000.0))


def _load_frame(frame_path, model: CameraModel):
    width, height = model.image_size
    if frame_path is not None:
        try:
            import cv2

            image = cv2.imread(str(frame_path), cv2.IMREAD_COLOR)
        except ImportError:  # pragma: no cover - opencv is a dependency
            image = None
        if image is not None:
            return image[:, :, ::-1], True
    return np.full((height, width, 3), 90, dtype=np.uint8), False


def _draw_overlay(ax, model: CameraModel, result: CalibrationResult, image, proj, extra_points, grid_step_m: float,
                  zoomed: bool, boxes=None, track_gps=None, pair_label: str = "labelled (fit pairs)") -> None:
    """Frame, sea grid, distance rings, horizon and labelled-vs-projected points on one axis."""
    width, height = model.image_size
    ax.imshow(image, extent=(0, image.shape[1], image.shape[0], 0), aspect="auto" if zoomed else "equal")
    reach = _grid_extent(model, result.world)
    fine = grid_step_m / 5.0
    samples = np.linspace(-reach, reach, 4000)
    near = np.arange(-100.0, 100.0 + fine, fine)
    far = np.arange(-reach, reach + grid_step_m, grid_step_m)
    for value in np.union1d(near, far):
        limit = reach if value % grid_step_m == 0 else 100.0
        along = samples[np.abs(samples) <= limit]
        for xw, yw in ((np.full_like(along, value), along), (along, np.full_like(along, value))):
            xs, ys = _polyline(model, xw, yw)
            ax.plot(xs, ys, color="white", lw=0.5, alpha=0.45)
    angles = np.linspace(0, 2 * np.pi, 4000)
    for ring in (25.0, 50.0, 100.0, 200.0, 400.0, 800.0):
        if ring > reach * 2:
            continue
        xs, ys = _polyline(model, ring * np.sin(angles), ring * np.cos(angles))
        ax.plot(xs, ys, color="cyan", lw=0.8, alpha=0.8)
        visible = np.flatnonzero(np.isfinite(xs) & (xs > 5) & (xs < 120) & (ys > 0) & (ys < height - 5))
        if visible.size:
            k = visible[np.argmin(xs[visible])]
            ax.text(xs[k] + 2, ys[k], f"{ring:.0f} m", color="cyan", fontsize=8, ha="left", va="bottom")
    hx = np.linspace(0, width, 600)
    ax.plot(hx, model.horizon_y(hx), color="orange", lw=1.5, label="fitted horizon")
    for (x0, y0), (x1, y1) in zip(result.screen, proj, strict=True):
        ax.plot([x0, x1], [y0, y1], color="lime", lw=1.2)
    if track_gps is not None and len(track_gps):
        tx, ty, in_front = model.gps_to_screen(track_gps[:, 0], track_gps[:, 1])
        tx, ty = np.where(in_front, tx, np.nan), np.where(in_front, ty, np.nan)
        ax.plot(tx, ty, ".", color="yellow", ms=3, alpha=0.8, label="GPS track projected (every frame)")
    if boxes is not None and len(boxes):
        from matplotlib.patches import Rectangle

        for x1, y1, x2, y2 in boxes:
            ax.add_patch(Rectangle((x1, y1), x2 - x1, y2 - y1, fill=False, ec="dodgerblue", lw=0.8))
    ax.scatter(result.screen[:, 0], result.screen[:, 1], s=18, c="dodgerblue", label=pair_label, zorder=3)
    ax.scatter(proj[:, 0], proj[:, 1], s=18, c="orange", label="GPS projected", zorder=3)
    ys_all = [result.screen[:, 1], proj[:, 1]]
    if extra_points is not None and len(extra_points[0]):
        es, eg = extra_points
        xs, ys, _ = model.gps_to_screen(eg[:, 0], eg[:, 1])
        for (x0, y0), x1, y1 in zip(es, xs, ys, strict=True):
            ax.plot([x0, x1], [y0, y1], color="magenta", lw=1.0)
        ax.scatter(es[:, 0], es[:, 1], s=22, c="magenta", marker="x", label="validation labelled", zorder=3)
        ys_all.append(es[:, 1])
    ax.set_xlim(0, width)
    if zoomed:
        ys_all = np.concatenate(ys_all)
        ys_all = ys_all[np.isfinite(ys_all)]
        top = float(np.nanmin([np.nanmin(model.horizon_y(hx)), ys_all.min()])) - 12
        bottom = float(np.percentile(ys_all, 95)) + 25
        ax.set_ylim(min(bottom, height), max(top, 0))
    else:
        ax.set_ylim(height, 0)


def render_calibration_picture(path, result: CalibrationResult, frame_path=None, title: str = "",
                               extra_points: tuple[np.ndarray, np.ndarray] | None = None,
                               grid_step_m: float = 50.0, boxes=None, track_gps=None,
                               pair_label: str = "labelled (fit pairs)") -> Path:
    """Save the calibration picture to ``path`` (PNG, atomically); returns the path.

    ``extra_points`` (screen (M,2), gps (M,2)), e.g. validation pairs, are drawn as crosses with their errors;
    ``boxes`` (N,4), the boxes the pairs were read from, as rectangles; ``track_gps`` (M,2), the vessel's GPS at
    every frame, as projected dots.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    model = result.model
    width, height = model.image_size
    image, real_frame = _load_frame(frame_path, model)

    fig = plt.figure(figsize=(14, 15), dpi=100)
    grid = fig.add_gridspec(3, 2, height_ratios=[2.2, 1.3, 1.1], hspace=0.28, wspace=0.22)
    ax = fig.add_subplot(grid[0, :])
    ax_zoom = fig.add_subplot(grid[1, :])
    proj = result.screen + result.reproj_px
    for axis, zoomed in ((ax, False), (ax_zoom, True)):
        _draw_overlay(axis, model, result, image, proj, extra_points, grid_step_m, zoomed, boxes, track_gps,
                      pair_label)
    ax.legend(loc="upper right", fontsize=8, framealpha=0.7)
    f = result.figures
    ax.set_title(
        (title + "\n" if title else "")
        + f"{f.pairs} pairs: reprojection median {f.reproj_median_px:.1f} px (RMSE {f.reproj_rmse_px:.1f}), "
        f"back-projected median {f.backproj_median_m:.1f} m; heading {model.heading_deg:.2f} deg, K1 {model.K1:.3g}"
        + ("" if real_frame else " (no camera frame given)"), fontsize=10)
    ax_zoom.set_title(f"zoom on the labelled band; sea grid every {grid_step_m / 5:g} m to 100 m, then "
                      f"{grid_step_m:g} m; cyan: distance rings; orange line: fitted horizon", fontsize=10)

    _draw_k1_scan(fig.add_subplot(grid[2, 0]), result)
    _draw_backprojection_errors(fig.add_subplot(grid[2, 1]), result, extra_points)
    return _save(fig, Path(path))


def _draw_k1_scan(ax_k1, result: CalibrationResult) -> None:
    """The paper's K1 brute-force curve, with the scan's best K1 and the refined one."""
    model = result.model
    k1_values, losses = result.k1_scan
    finite = np.isfinite(losses)
    if finite.any():
        ax_k1.plot(k1_values[finite], losses[finite] / max(len(result.screen), 1), color="tab:blue")
        ax_k1.axvline(result.scan_k1, color="tab:blue", ls=":", label=f"scan best {result.scan_k1:.3g}")
        ax_k1.axvline(model.K1, color="tab:red", ls="--", label=f"refined {model.K1:.3g}")
        ax_k1.set_yscale("log")
        ax_k1.legend(fontsize=8)
    ax_k1.set_xlabel("K1 (1/px²)")
    ax_k1.set_ylabel("mean squared reprojection (px²)")
    ax_k1.set_title("K1 brute force (DLT per K1)", fontsize=10)


def _draw_backprojection_errors(ax_err, result: CalibrationResult, extra_points) -> None:
    """Back-projected error against distance of the fit pairs and of ``extra_points`` (validation)."""
    model = result.model
    dist = np.hypot(result.world[:, 0], result.world[:, 1])
    ok = np.isfinite(result.backproj_m)
    ax_err.scatter(dist[ok], result.backproj_m[ok], s=14, c="dodgerblue", label="fit pairs")
    if extra_points is not None and len(extra_points[0]):
        es, eg = extra_points
        lat, lon, valid = model.screen_to_gps(es[:, 0], es[:, 1])
        err = geodesy.haversine_m(lat, lon, eg[:, 0], eg[:, 1])
        d_val = geodesy.haversine_m(model.camera_lat, model.camera_lon, eg[:, 0], eg[:, 1])
        ax_err.scatter(d_val[valid], err[valid], s=18, c="magenta", marker="x", label="validation")
    ax_err.set_xlabel("distance from camera (m)")
    ax_err.set_ylabel("back-projected error (m)")
    ax_err.set_title("back-projection error of labelled points", fontsize=10)
    ax_err.grid(alpha=0.3)
    ax_err.legend(fontsize=8)


def _save(fig, path: Path) -> Path:
    """``fig`` saved to ``path`` as a PNG through a temporary file (atomic), then closed."""
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".png", dir=path.parent)
    os.close(fd)
    try:
        fig.savefig(tmp, format="png", bbox_inches="tight")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except OSError as exc:
        raise CalibrationError(f"cannot write the calibration picture {path}: {exc.strerror or exc}") from None
    finally:
        plt.close(fig)
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path
