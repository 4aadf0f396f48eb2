"""Scoring like the paper: predicted vessel positions against its GPS, per video, overall and on the paper's splits.

    ./vessel eval PREDICTIONS.csv [--data DIR] [--videos 13-17] [--out DIR|summary.json]

``PREDICTIONS.csv`` has the columns ``video,t_utc_s,lat,lon`` (``t_utc_s``: seconds since 00:00 UTC of the
recording day, one row per frame where the vessel of interest was estimated).

Method (``../shared/aitas/README.md``, "Scoring like the paper"):

* Truth: the vessel's raw GPS fixes (``target_gps_fixes.csv``, ``t_spread_s``) interpolated linearly at each
  prediction's time, only where the bracketing fixes are at most ``max_gps_gap_s`` (3 s, the rule of
  ``screen_labels.csv``'s ``gps_ok``) apart; predictions at other times are not scored (counted as
  ``n_no_truth``). ``gt_1hz.csv`` is not used: it is the same interpolation on whole seconds with a looser 5 s rule.
* error = Haversine distance prediction - truth; distance = Haversine distance truth - camera (R = 6 371 km).
* ``m_per_100m`` = 100 Σ(e d) / Σ d² (least squares through the origin, the paper's 5.55), ``median_m``,
  ``p80_m``, ``p80_pct`` (80th percentile of 100 e / d), ``mean_m``, ``rmse_m``, ``max_m``.
* ``coverage``: of the frames in ``frames.csv`` (or the labelled frames, ``--frames labels``) whose truth is
  valid and projects inside the image through the calibration, the share with a prediction of the same video
  within ``match_tolerance_s`` (0.5 s) of the frame's time.

Per video, overall, and for the splits ``13-16`` and ``13-17`` (the paper's) and ``7-12`` when their videos
were evaluated. Writes ``summary.json``, ``scores.csv`` (one row per prediction: truth, error, distance) and
the plots (``error_vs_distance.png``, ``error_hist.png``, ``map_video<N>.png``), prints a short table.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vessel_calib import geodesy
from vessel_calib.gps_track import seconds_of_day_to_epoch
from vessel_calib.params import atomic_write_text
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_common.paths import parse_videos
from vessel_tools.track.offline_data import load_camera, open_dataset

PAPER_M_PER_100M = 5.55
PREDICTION_COLUMNS = ("video", "t_utc_s", "lat", "lon")
SPLITS = {"7-12": tuple(range(7, 13)), "13-16": (13, 14, 15, 16), "13-17": (13, 14, 15, 16, 17)}


@dataclass
class Predictions:
    """Predicted positions read from a predictions CSV (sorted by video, time)."""

    video: np.ndarray     # (N,) int
    t_utc_s: np.ndarray   # (N,) seconds since 00:00 UTC
    lat: np.ndarray
    lon: np.ndarray
    skipped_rows: int = 0
    skipped_reasons: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.video.size)


MAX_VIDEO_NUMBER = 1_000_000


def _prediction_row(row: dict) -> tuple[tuple[int, float, float, float] | None, str]:
    """One row's values, or None and why it is skipped."""
    if None in row:
        return None, "more fields than the header"
    values = {(k or "").strip(): (v or "").strip() if isinstance(v, str) else "" for k, v in row.items()}
    try:
        video_value = float(values["video"])
        t, lat, lon = float(values["t_utc_s"]), float(values["lat"]), float(values["lon"])
    except (ValueError, KeyError):
        return None, "not a number"
    if not math.isfinite(video_value) or video_value != int(video_value) or not 0 <= video_value <= MAX_VIDEO_NUMBER:
        return None, f"video not a whole number in 0-{MAX_VIDEO_NUMBER}"
    if not (math.isfinite(t) and math.isfinite(lat) and math.isfinite(lon)):
        return None, "time or position not finite"
    if abs(lat) > 90 or abs(lon) > 180:
        return None, "latitude or longitude out of range"
    return (int(video_value), t, lat, lon), ""


def read_predictions(path: Path) -> Predictions:
    """Read ``video,t_utc_s,lat,lon``; rows that cannot be scored are skipped and counted by reason."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such predictions file; write one with `./vessel demo` or "
                        f"`./vessel pipeline ... --out DIR`")
    videos, times, lats, lons = [], [], [], []
    reasons: dict[str, int] = {}
    try:
        with path.open(newline="") as handle:
            reader = csv.DictReader(handle)
            fields = [f.strip() for f in (reader.fieldnames or [])]
            missing = [c for c in PREDICTION_COLUMNS if c not in fields]
            if missing:
                raise DataError(f"{path}: missing column(s) {', '.join(missing)}; expected the header "
                                f"{','.join(PREDICTION_COLUMNS)}")
            for row in reader:
                values, reason = _prediction_row(row)
                if values is None:
                    reasons[reason] = reasons.get(reason, 0) + 1
                    continue
                videos.append(values[0])
                times.append(values[1])
                lats.append(values[2])
                lons.append(values[3])
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise DataError(f"{path}: cannot read predictions ({error})") from None
    v = np.asarray(videos, dtype=np.int64)
    t = np.asarray(times, dtype=float)
    order = np.lexsort((t, v))
    return Predictions(v[order], t[order], np.asarray(lats, dtype=float)[order], np.asarray(lons, dtype=float)[order],
                       sum(reasons.values()), reasons)


def metrics(error_m, distance_m, predicted_distance_m=None) -> dict:
    """The paper's figures for paired errors and distances (finite pairs with d > 0 only).

    With ``predicted_distance_m`` (the estimate's range from the camera) also ``range_bias_pct``: the mean of
    ``100 (predicted - true range) / true range``, negative when the estimates sit too close to the camera. A
    calibration off in scale shows here at every distance, where the error alone does not say which way it is.
    """
    e = np.asarray(error_m, dtype=float).reshape(-1)
    d = np.asarray(distance_m, dtype=float).reshape(-1)
    p = np.full(d.shape, np.nan) if predicted_distance_m is None else \
        np.asarray(predicted_distance_m, dtype=float).reshape(-1)
    ok = np.isfinite(e) & np.isfinite(d) & (d > 0)
    e, d, p = e[ok], d[ok], p[ok]
    if e.size == 0:
        return {"n": 0, "m_per_100m": None, "median_m": None, "p80_m": None, "p80_pct": None, "mean_m": None,
                "rmse_m": None, "max_m": None, "share_under_20m": None, "distance_median_m": None,
                "range_bias_pct": None}
    bias = 100.0 * (p - d) / d
    return {
        "range_bias_pct": float(np.mean(bias)) if np.all(np.isfinite(bias)) else None,
        "n": int(e.size),
        "m_per_100m": float(100.0 * np.sum(e * d) / np.sum(d * d)),
        "median_m": float(np.median(e)),
        "p80_m": float(np.percentile(e, 80)),
        "p80_pct": float(np.percentile(100.0 * e / d, 80)),
        "mean_m": float(np.mean(e)),
        "rmse_m": float(np.sqrt(np.mean(e * e))),
        "max_m": float(np.max(e)),
        "share_under_20m": float(np.mean(e < 20.0)),
        "distance_median_m": float(np.median(d)),
    }


@dataclass
class ScoredPredictions:
    """Every prediction with its truth (NaN where the GPS cannot be interpolated)."""

    video: np.ndarray
    t_utc_s: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    gt_lat: np.ndarray
    gt_lon: np.ndarray
    error_m: np.ndarray
    distance_m: np.ndarray
    has_truth: np.ndarray
    predicted_distance_m: np.ndarray   # the estimate's range from the camera


def _epoch_of(dataset, video: int, t_utc_s):

    frames = dataset.frames([video])
    if frames:
        reference = frames[0].stamp
    else:
        any_frames = dataset.frames()
        if not any_frames:
            raise DataError(f"{dataset.path / 'frames.csv'} has no rows: cannot tell the recording day")
        reference = any_frames[0].stamp
    return np.asarray(seconds_of_day_to_epoch(np.asarray(t_utc_s, dtype=float), reference), dtype=float)


def score_predictions(predictions: Predictions, dataset, gps_track, max_gps_gap_s: float = 3.0) -> ScoredPredictions:
    """Truth, error and distance for every prediction."""
    n = len(predictions)
    gt_lat = np.full(n, np.nan)
    gt_lon = np.full(n, np.nan)
    for video in np.unique(predictions.video):
        sel = predictions.video == video
        epoch = _epoch_of(dataset, int(video), predictions.t_utc_s[sel])
        lat, lon, valid = gps_track.interpolate(epoch, max_gap_s=max_gps_gap_s)
        gt_lat[sel] = np.where(valid, lat, np.nan)
        gt_lon[sel] = np.where(valid, lon, np.nan)
    has_truth = np.isfinite(gt_lat) & np.isfinite(gt_lon)
    error = np.full(n, np.nan)
    distance = np.full(n, np.nan)
    if has_truth.any():
        error[has_truth] = geodesy.haversine_m(predictions.lat[has_truth], predictions.lon[has_truth],
                                               gt_lat[has_truth], gt_lon[has_truth])
        distance[has_truth] = geodesy.haversine_m(gt_lat[has_truth], gt_lon[has_truth], dataset.camera_lat,
                                                  dataset.camera_lon)
    predicted_distance = np.asarray(geodesy.haversine_m(predictions.lat, predictions.lon, dataset.camera_lat,
                                                        dataset.camera_lon), dtype=float).reshape(-1)
    return ScoredPredictions(predictions.video, predictions.t_utc_s, predictions.lat, predictions.lon, gt_lat, gt_lon,
                             error, distance, has_truth, predicted_distance)


def coverage_frames(dataset, camera, gps_track, videos, which: str = "frames", max_gps_gap_s: float = 3.0):
    """Frames where the vessel is in view: {video: epoch stamps (sorted)}.

    ``which``: ``frames`` (frames.csv) or ``labels`` (the frames of screen_labels.csv's primary boxes).
    In view = truth interpolable and projecting inside the image through ``camera``.
    """
    out: dict[int, np.ndarray] = {}
    for video in videos:
        if which == "labels":
            stamps = np.array(sorted({r.stamp for r in dataset.labels([video])}), dtype=float)
        else:
            stamps = np.array([f.stamp for f in dataset.frames([video])], dtype=float)
        if stamps.size == 0:
            out[video] = stamps
            continue
        lat, lon, valid = gps_track.interpolate(stamps, max_gap_s=max_gps_gap_s)
        xs, ys, in_front = camera.gps_to_screen(np.where(valid, lat, camera.camera_lat),
                                                np.where(valid, lon, camera.camera_lon))
        visible = valid & in_front & camera.in_image(np.nan_to_num(xs, nan=-1.0), np.nan_to_num(ys, nan=-1.0))
        out[video] = stamps[np.asarray(visible, dtype=bool)]
    return out


def coverage(predictions: Predictions, dataset, frames_in_view: dict, tolerance_s: float = 0.5) -> dict:
    """{video: (frames in view, frames with a prediction within tolerance)}."""
    out = {}
    for video, stamps in frames_in_view.items():
        sel = predictions.video == video
        if stamps.size == 0:
            out[video] = (0, 0)
            continue
        if not sel.any():
            out[video] = (int(stamps.size), 0)
            continue
        pred_epoch = np.sort(_epoch_of(dataset, video, predictions.t_utc_s[sel]))
        idx = np.clip(np.searchsorted(pred_epoch, stamps), 1, max(pred_epoch.size - 1, 1))
        after = pred_epoch[np.minimum(idx, pred_epoch.size - 1)]
        nearest = np.minimum(np.abs(pred_epoch[idx - 1] - stamps), np.abs(after - stamps))
        out[video] = (int(stamps.size), int(np.sum(nearest <= tolerance_s)))
    return out


def summarize(scored: ScoredPredictions, cover: dict, videos: list[int]) -> dict:
    """Per video, overall and per split: the metrics plus coverage and counts."""

    def block(selected_videos) -> dict:
        sel = np.isin(scored.video, list(selected_videos))
        keep = sel & scored.has_truth
        result = metrics(scored.error_m[keep], scored.distance_m[keep], scored.predicted_distance_m[keep])
        result["n_predictions"] = int(sel.sum())
        result["n_no_truth"] = int((sel & ~scored.has_truth).sum())
        in_view = sum(cover.get(v, (0, 0))[0] for v in selected_videos)
        covered = sum(cover.get(v, (0, 0))[1] for v in selected_videos)
        result["frames_in_view"] = int(in_view)
        result["frames_covered"] = int(covered)
        result["coverage"] = float(covered / in_view) if in_view else None
        return result

    summary = {"per_video": {str(v): block([v]) for v in videos}, "overall": block(videos), "splits": {}}
    for name, split_videos in SPLITS.items():
        present = [v for v in split_videos if v in videos]
        if present and len(present) == len(split_videos):
            summary["splits"][name] = block(present)
    return summary


#: squared Mahalanobis radius of the 68.3 / 95 / 99 % ellipse of a 2-D Gaussian (chi-square, 2 degrees of freedom)
ELLIPSE_CHI2 = {"68": 2.2958, "95": 5.9915, "99": 9.2103}
FIX_COLUMNS = (*PREDICTION_COLUMNS, "cov_ee_m2", "cov_en_m2", "cov_nn_m2")


def covariance_consistency(east_error_m, north_error_m, covariances) -> dict:
    """How honest 2-D position covariances are, against the errors they describe.

    ``east_error_m``, ``north_error_m`` (N,) estimate minus truth; ``covariances`` (N, 2, 2) m^2 (east, north).
    Honest covariances put 68 / 95 / 99 % of the errors inside their 68 / 95 / 99 % ellipses, with a mean
    squared Mahalanobis distance (NEES) of 2; more inside is a covariance larger than the error (conservative),
    fewer one that claims more than it knows. Rows with a non-finite error or a covariance that is not positive
    definite are left out (``n`` counts the rest).
    """
    e = np.column_stack([np.asarray(east_error_m, dtype=float).reshape(-1),
                         np.asarray(north_error_m, dtype=float).reshape(-1)])
    C = np.asarray(covariances, dtype=float).reshape(-1, 2, 2)
    det = C[:, 0, 0] * C[:, 1, 1] - C[:, 0, 1] * C[:, 1, 0]
    ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(C), axis=(1, 2)) & (C[:, 0, 0] > 0) & (det > 0)
    if not ok.any():
        return {"n": 0, "nees_mean": None, "nees_median": None, **{f"inside_{k}": None for k in ELLIPSE_CHI2}}
    e, C = e[ok], C[ok]
    nees = np.einsum("ni,nij,nj->n", e, np.linalg.inv(C), e)
    return {"n": int(nees.size), "nees_mean": float(np.mean(nees)), "nees_median": float(np.median(nees)),
            **{f"inside_{k}": float(np.mean(nees <= chi2)) for k, chi2 in ELLIPSE_CHI2.items()}}


def score_fix_covariances(fixes_path: Path, dataset, videos: list[int], max_gps_gap_s: float = 3.0) -> dict:
    """``covariance_consistency`` of a fixes CSV against the GPS, per video, overall and per split.

    The CSV has ``FIX_COLUMNS``: the published fixes with their east-north covariance (the demo's ``fixes.csv``).
    """
    rows = []
    with Path(fixes_path).open(newline="") as handle:
        reader = csv.DictReader(handle)
        missing = [c for c in FIX_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise DataError(f"{fixes_path}: missing column(s) {', '.join(missing)}")
        for row in reader:
            try:
                rows.append([float(row[c]) for c in FIX_COLUMNS])
            except ValueError:
                continue
    table = np.array(rows, dtype=float).reshape(-1, len(FIX_COLUMNS))
    video = table[:, 0].astype(int)
    predictions = Predictions(video, table[:, 1], table[:, 2], table[:, 3], 0)
    scored = score_predictions(predictions, dataset, dataset.gps_track(), max_gps_gap_s)
    east, north = geodesy.gps_to_local(scored.lat, scored.lon, np.nan_to_num(scored.gt_lat),
                                       np.nan_to_num(scored.gt_lon))
    east = np.where(scored.has_truth, east, np.nan)
    north = np.where(scored.has_truth, north, np.nan)
    cov = np.stack([np.column_stack([table[:, 4], table[:, 5]]), np.column_stack([table[:, 5], table[:, 6]])], 1)

    def block(selected) -> dict:
        sel = np.isin(video, list(selected))
        return covariance_consistency(east[sel], north[sel], cov[sel])

    summary = {"per_video": {str(v): block([v]) for v in videos}, "overall": block(videos), "splits": {}}
    for name, split_videos in SPLITS.items():
        if all(v in videos for v in split_videos):
            summary["splits"][name] = block(split_videos)
    return summary


def format_covariance_line(name: str, block: dict) -> str:
    """One line: the share of errors inside their 68 / 95 / 99 % ellipses."""
    if not block["n"]:
        return f"{name}: no fix with a truth to compare"
    return (f"{name}: {100 * block['inside_68']:.0f} / {100 * block['inside_95']:.0f} / "
            f"{100 * block['inside_99']:.0f} % of {block['n']} errors inside their 68 / 95 / 99 % ellipses "
            f"(mean NEES {block['nees_mean']:.2f}; honest: 68 / 95 / 99 %, 2)")


def format_table(summary: dict) -> str:
    """The short table printed at the end of a run."""

    def fmt(value, spec):
        return "-" if value is None else format(value, spec)

    lines = [f"{'set':>8} {'n':>5} {'m/100m':>7} {'median':>7} {'p80':>7} {'p80 %':>6} {'<20m':>5} {'coverage':>9}"]

    def row(name, b):
        cov = "-" if b["coverage"] is None else \
            f"{100 * b['coverage']:.0f}% {b['frames_covered']}/{b['frames_in_view']}"
        lines.append(f"{name:>8} {b['n']:>5} {fmt(b['m_per_100m'], '7.2f')} {fmt(b['median_m'], '7.1f')} "
                     f"{fmt(b['p80_m'], '7.1f')} {fmt(b['p80_pct'], '6.1f')} "
                     f"{fmt(None if b['share_under_20m'] is None else 100 * b['share_under_20m'], '4.0f')}% {cov:>9}")

    for video, b in summary["per_video"].items():
        row(f"video {video}", b)
    row("overall", summary["overall"])
    for name, b in summary["splits"].items():
        row(name, b)
    lines.append(f"(m/100m: least squares through the origin, the paper reports {PAPER_M_PER_100M}; errors in m)")
    biases = [(name, b.get("range_bias_pct")) for name, b in [("overall", summary["overall"]),
                                                               *summary["splits"].items()]]
    biases = [f"{name} {value:+.1f} %" for name, value in biases if value is not None]
    if biases:
        lines.append("range bias (mean of estimated/true range - 1; negative: too close): " + ", ".join(biases))
    return "\n".join(lines)


def _atomic_write(path: Path, text: str) -> None:
    atomic_write_text(path, text)


def write_scores_csv(path: Path, scored: ScoredPredictions) -> None:
    """One row per prediction: ``video,t_utc_s,lat,lon,gt_lat,gt_lon,error_m,distance_m`` (truth blank if none)."""
    lines = ["video,t_utc_s,lat,lon,gt_lat,gt_lon,error_m,distance_m"]
    for i in range(scored.video.size):
        truth = scored.has_truth[i]
        lines.append(",".join([
            str(int(scored.video[i])), f"{scored.t_utc_s[i]:.3f}", f"{scored.lat[i]:.8f}", f"{scored.lon[i]:.8f}",
            f"{scored.gt_lat[i]:.8f}" if truth else "", f"{scored.gt_lon[i]:.8f}" if truth else "",
            f"{scored.error_m[i]:.3f}" if truth else "", f"{scored.distance_m[i]:.3f}" if truth else ""]))
    _atomic_write(path, "\n".join(lines) + "\n")


# ---------------------------------------------------------------------------------------------------------
# Plots


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".png")
    os.close(handle)
    try:
        fig.savefig(temp, dpi=110, bbox_inches="tight")
        os.replace(temp, path)
    finally:
        Path(temp).unlink(missing_ok=True)


def plot_error_vs_distance(scored: ScoredPredictions, path: Path, title: str = "") -> Path:
    """Error against distance per video, the fitted line through the origin and the paper's 5.55 m/100 m."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 5))
    ok = scored.has_truth
    for video in np.unique(scored.video[ok]):
        sel = ok & (scored.video == video)
        ax.scatter(scored.distance_m[sel], scored.error_m[sel], s=14, alpha=0.75, label=f"video {video}")
    if ok.any():
        d = scored.distance_m[ok]
        e = scored.error_m[ok]
        slope = float(np.sum(e * d) / np.sum(d * d))
        x = np.linspace(0.0, float(np.max(d)) * 1.05, 50)
        ax.plot(x, slope * x, "k-", lw=1.5, label=f"fit: {100 * slope:.2f} m / 100 m")
        ax.plot(x, PAPER_M_PER_100M / 100.0 * x, "r--", lw=1.2, label=f"paper: {PAPER_M_PER_100M} m / 100 m")
        ax.set_ylim(0, max(float(np.percentile(e, 99)) * 1.15, 1.0))
    ax.set_xlabel("distance of the vessel from the camera (GPS), m")
    ax.set_ylabel("position error (Haversine), m")
    ax.set_title(title or "Error against distance")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    _save(fig, path)
    plt.close(fig)
    return path


def plot_error_histogram(scored: ScoredPredictions, path: Path, title: str = "") -> Path:
    """Distribution of the errors with the median and the 80th percentile."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    e = scored.error_m[scored.has_truth]
    if e.size:
        upper = max(float(np.percentile(e, 98)), 1.0)
        ax.hist(np.clip(e, 0, upper), bins=40, range=(0, upper), color="tab:blue", alpha=0.8)
        median, p80 = float(np.median(e)), float(np.percentile(e, 80))
        ax.axvline(median, color="k", ls="-", label=f"median {median:.1f} m")
        ax.axvline(p80, color="tab:orange", ls="--", label=f"80th percentile {p80:.1f} m")
        ax.axvline(20.0, color="r", ls=":", label="20 m (paper: 80 % below)")
        ax.legend(fontsize=8)
    ax.set_xlabel("position error, m (last bin: everything above the 98th percentile)")
    ax.set_ylabel("predictions")
    ax.set_title(title or "Error distribution")
    ax.grid(alpha=0.3)
    _save(fig, path)
    plt.close(fig)
    return path


def plot_map(scored: ScoredPredictions, gps_track, dataset, video: int, path: Path) -> Path:
    """Predicted track against the GPS track of one video, metres east/north of the camera."""
    plt = _pyplot()
    lat0, lon0 = dataset.camera_lat, dataset.camera_lon
    fig, ax = plt.subplots(figsize=(7, 6))
    frames = dataset.frames([video])
    if frames and len(gps_track):
        t0, t1 = frames[0].stamp, frames[-1].stamp
        sel = (gps_track.stamps >= t0 - 2) & (gps_track.stamps <= t1 + 2)
        gx, gy = geodesy.gps_to_local(gps_track.lats[sel], gps_track.lons[sel], lat0, lon0)
        ax.plot(gx, gy, "-", color="tab:orange", lw=1.5, label="GPS track")
    sel = scored.video == video
    if sel.any():
        px, py = geodesy.gps_to_local(scored.lat[sel], scored.lon[sel], lat0, lon0)
        ax.plot(px, py, "o-", color="tab:blue", ms=3, lw=0.8, label="predicted")
        truth = sel & scored.has_truth
        if truth.any():
            tx, ty = geodesy.gps_to_local(scored.gt_lat[truth], scored.gt_lon[truth], lat0, lon0)
            qx, qy = geodesy.gps_to_local(scored.lat[truth], scored.lon[truth], lat0, lon0)
            for a, b, c, d in zip(tx, ty, qx, qy, strict=True):
                ax.plot([a, c], [b, d], color="grey", lw=0.5, alpha=0.6)
    ax.plot([0], [0], "k^", ms=9, label="camera")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east of the camera, m")
    ax.set_ylabel("north of the camera, m")
    block = metrics(scored.error_m[sel & scored.has_truth], scored.distance_m[sel & scored.has_truth])
    extra = "" if block["n"] == 0 else f": {block['m_per_100m']:.2f} m/100 m, median {block['median_m']:.1f} m"
    ax.set_title(f"video {video}{extra}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    _save(fig, path)
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------------------------------------
# Command line


def evaluate(predictions_path: Path, data_dir: Path | None = None, videos: list[int] | None = None,
             out: Path | None = None, calib: Path | None = None, frames: str = "frames",
             plots: bool = True, max_gps_gap_s: float = 3.0, match_tolerance_s: float = 0.5) -> dict:
    """Score a predictions CSV; write summary/scores/plots under ``out`` when given. Returns the summary."""
    dataset = open_dataset(data_dir)
    if videos is not None:
        videos = dataset.check_videos(videos)
    predictions = read_predictions(predictions_path)
    gps_track = dataset.gps_track()
    if len(gps_track) == 0:
        raise DataError(f"{dataset.path}: no target_gps_fixes.csv (or it is empty): there is no truth to score "
                        f"against")
    if videos is None:
        videos = sorted({int(v) for v in predictions.video})
    if not videos:
        raise DataError(f"{predictions_path}: no predictions and no --videos given: nothing to score")
    keep = np.isin(predictions.video, videos)
    predictions = Predictions(predictions.video[keep], predictions.t_utc_s[keep], predictions.lat[keep],
                              predictions.lon[keep], predictions.skipped_rows, predictions.skipped_reasons)
    camera, camera_source = load_camera(calib, dataset)
    scored = score_predictions(predictions, dataset, gps_track, max_gps_gap_s)
    in_view = coverage_frames(dataset, camera, gps_track, videos, frames, max_gps_gap_s)
    cover = coverage(predictions, dataset, in_view, match_tolerance_s)
    summary = summarize(scored, cover, videos)
    summary["settings"] = {"predictions": str(predictions_path), "data": str(dataset.path), "videos": videos,
                           "camera": camera_source, "coverage_frames": frames, "max_gps_gap_s": max_gps_gap_s,
                           "match_tolerance_s": match_tolerance_s, "skipped_rows": predictions.skipped_rows,
                           "skipped_reasons": predictions.skipped_reasons}
    if out is not None:
        out = Path(out)
        if out.suffix.lower() == ".json":
            summary_path, folder = out, out.parent
        else:
            summary_path, folder = out / "summary.json", out
        write_scores_csv(folder / "scores.csv", scored)
        if plots:
            plot_error_vs_distance(scored, folder / "error_vs_distance.png")
            plot_error_histogram(scored, folder / "error_hist.png")
            for video in videos:
                plot_map(scored, gps_track, dataset, video, folder / f"map_video{video}.png")
        _atomic_write(summary_path, json.dumps(summary, indent=2) + "\n")
    return summary


@command_line_tool
def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    parser = argparse.ArgumentParser(prog="./vessel eval",
                                     description="Score predicted vessel positions against GPS like the paper.")
    parser.add_argument("predictions", type=Path, help="CSV with video,t_utc_s,lat,lon")
    parser.add_argument("--data", type=Path, default=None, help="dataset folder (default $VESSEL_DATA or "
                                                                "../shared/aitas)")
    parser.add_argument("--videos", default=None, help="videos to score, e.g. 13-17 (default: those predicted)")
    parser.add_argument("--out", type=Path, default=None,
                        help="folder (or .json path) for summary.json, scores.csv and the plots")
    parser.add_argument("--calib", type=Path, default=None, help="calibration YAML used for the in-view test")
    parser.add_argument("--frames", choices=("frames", "labels"), default="frames",
                        help="frames the coverage counts: frames.csv (default) or the labelled frames")
    parser.add_argument("--no-plots", action="store_true", help="write no PNG")
    parser.add_argument("--max-gps-gap", type=float, default=3.0, help="longest GPS gap bridged, s (default 3)")
    parser.add_argument("--match-tolerance", type=float, default=0.5,
                        help="a frame is covered by a prediction this close in time, s (default 0.5)")
    args = parser.parse_args(argv)

    summary = evaluate(args.predictions, args.data, parse_videos(args.videos), args.out, args.calib,
                       args.frames, not args.no_plots, args.max_gps_gap, args.match_tolerance)
    print(format_table(summary))
    reasons = summary["settings"].get("skipped_reasons") or {}
    if reasons:
        print(f"skipped {sum(reasons.values())} row(s) of {args.predictions}: "
              + "; ".join(f"{count} {reason}" for reason, count in sorted(reasons.items())))
    if args.out is not None:
        print(f"written: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
