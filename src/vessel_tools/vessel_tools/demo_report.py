"""Scoring, plots and the closing table of ``./vessel demo`` (ROS-free: it reads the exported CSV files)."""

from __future__ import annotations

import sys
from pathlib import Path

from vessel_tools.track.evaluation import evaluate, format_covariance_line, format_table, score_fix_covariances

PAPER_SPLITS = {"13-16": [13, 14, 15, 16], "13-17": [13, 14, 15, 16, 17]}


def write_report(dataset, videos: list[int], out: Path, predictions: Path, tracks: Path, runs, calibration: Path,
                 offline_predictions: Path | None = None, coverage_frames: str = "frames") -> dict:
    """Score the demo's predictions like the paper (plots into ``out``), print the table, return the summary.

    ``coverage_frames``: the frames coverage counts, ``frames`` (every image) or ``labels`` (the hand-labelled
    frames, when those were the detections).
    """
    has_truth = (dataset.path / "target_gps_fixes.csv").is_file()
    summary: dict = {
        "videos": videos,
        "calibration": str(calibration),
        "runs": [
            {"video": r.video, "frames_expected": r.frames_expected, "frames_out": r.frames_out,
             "seconds": round(r.seconds, 2), "node_exit_statuses": r.node_statuses}
            for r in runs
        ],
    }
    if not has_truth:
        print(f"{dataset.path} has no target_gps_fixes.csv: predictions written, nothing to score against",
              file=sys.stderr)
        return summary
    summary["online"] = evaluate(predictions, dataset.path, videos, out=out / "online", calib=calibration,
                                 frames=coverage_frames)
    print("Vessel of interest as published on /vessel/fix (online):")
    print(format_table(summary["online"]))
    fixes = out / "fixes.csv"
    if fixes.is_file():
        honesty = summary["online_covariance"] = score_fix_covariances(fixes, dataset, videos)
        print("Its covariance (NavSatFix position_covariance) against its error:")
        for name, block in (honesty["splits"] or {"overall": honesty["overall"]}).items():
            print("  " + format_covariance_line(name, block))
    if offline_predictions is not None and offline_predictions.is_file():
        summary["offline"] = evaluate(offline_predictions, dataset.path, videos, out=out / "offline",
                                      calib=calibration, frames=coverage_frames)
        print("\nAfter the offline smoothing pass over the recorded tracks:")
        print(format_table(summary["offline"]))
    return summary
