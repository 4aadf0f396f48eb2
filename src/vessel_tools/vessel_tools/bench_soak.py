"""``./vessel bench soak``: the tracker and fuser cores (no ROS) on a stream of stamps for minutes, minute by minute.

What ``./vessel bench live`` measures on the whole graph, for the two cores alone and in a fraction of the time: a
stream at ``--fps`` (25 frames/s by default) of detections, each simulated minute reported with

- the CPU time of a frame in ``MultiTargetTracker.update`` and in ``TrackFuser.update``, p50 and p95 (CPU time of
  this thread, so that other work on a shared machine does not show; a cost per frame that grows with the run is a
  latency that grows in the graph, once the nodes can no longer keep up);
- the process's resident memory and, with ``--tracemalloc``, the Python heap (slower);
- the size of every structure the cores keep: live tracks and their history entries, world filters (of live and
  of ended tracks), box-shape histories, the selection's running and ended histories and the confidences they hold.

The stream (``--scene``):

- ``looped`` (default): the simulated harbour (``vessel_tools.track.simulation.harbour_scenario``: three vessels,
  clutter, the mooring post) as 37 frames 4 s apart, like a challenge video, played at ``--fps`` over and over with
  the stamps moving on: what ``bench live`` streams (video 13's 36 frames looped), so vessels jump at every loop
  and tracks start, coast and end all the time;
- ``harbour``: the simulated harbour at ``--fps`` itself, real-time motion, for the whole run (the vessels cross
  the view in a few minutes, then clutter only);
- ``--recording DIR``: the ``/vessel/detections`` of a recording (e.g. ``out/demo/recording/video_13`` of
  ``./vessel demo``) looped the same way, with the calibration and the settings of the parameter file.

    ./vessel bench soak --minutes 10 --out out/bench/soak.json
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
import tracemalloc
from collections.abc import Sequence
from pathlib import Path

from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_tools.bench_report import log, print_and_save, summary_ms
from vessel_tools.proc_monitor import read_proc
from vessel_tools.track.pipeline import screen_track_of
from vessel_tools.track.simulation import challenge_camera, fuser_settings_of_simulation, harbour_scenario
from vessel_track.fuser_settings import load_fuser_settings
from vessel_track.track_fuser import TrackFuser
from vessel_track.tracker import MultiTargetTracker
from vessel_track.tracker_config import load_tracker_config

DEFAULT_FPS = 25.0
DEFAULT_MINUTES = 10.0
SCENES = ("looped", "harbour")
LOOPED_FRAME_INTERVAL_S = 4.0
LOOPED_DURATION_S = 144.0
"""37 frames 4 s apart: a challenge video's length."""


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command line."""
    parser = argparse.ArgumentParser(prog="./vessel bench soak", description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=DEFAULT_MINUTES, help=f"minutes of stamps (default "
                        f"{DEFAULT_MINUTES:g})")
    parser.add_argument("--fps", type=float, default=DEFAULT_FPS, help=f"frames per second of stamps (default "
                        f"{DEFAULT_FPS:g})")
    parser.add_argument("--scene", choices=SCENES, default="looped", help="the simulated stream (default looped)")
    parser.add_argument("--recording", type=Path, default=None, help="loop this recording's /vessel/detections "
                        "instead of a simulated scene")
    parser.add_argument("--params", type=Path, default=None, help="parameter file whose tracker and fuser settings "
                        "are used (default config/aitas.yaml; with a simulated scene its camera fits are not)")
    parser.add_argument("--calib", type=Path, default=None, help="with --recording: the calibration (default "
                        "config/aitas_camera.yaml)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated scene (default 0)")
    parser.add_argument("--tracemalloc", action="store_true", help="also trace the Python heap (several times "
                        "slower)")
    parser.add_argument("--out", type=Path, default=None, help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    for name in ("minutes", "fps"):
        value = getattr(args, name)
        if not (value > 0 and math.isfinite(value)):
            parser.error(f"--{name} must be a positive number, got {value}")
    return args


def _params_file(path: Path | None) -> Path | None:
    from vessel_tools.track.offline_data import default_params_path

    return path if path is not None else default_params_path()


def stream(args: argparse.Namespace):
    """(camera, fuser settings, tracker config, frames): ``frames`` yields (stamp, boxes, scores) at ``--fps``."""
    params = _params_file(args.params)
    tracker_config = load_tracker_config(params)
    total = int(round(args.minutes * 60.0 * args.fps))
    if args.recording is not None:
        base, camera, settings = _recording(args.recording, args.calib, params)
    else:
        camera = challenge_camera()
        configured = load_fuser_settings(params)
        settings = dataclasses.replace(fuser_settings_of_simulation(camera), fusion=configured.fusion,
                                       motion=configured.motion, selection=configured.selection)
        if args.scene == "harbour":
            base = [(f.stamp, f.boxes_xyxy, f.scores) for f in harbour_scenario(
                frame_interval_s=1.0 / args.fps, duration_s=args.minutes * 60.0, seed=args.seed).run().frames]
        else:
            base = [(f.stamp, f.boxes_xyxy, f.scores) for f in harbour_scenario(
                frame_interval_s=LOOPED_FRAME_INTERVAL_S, duration_s=LOOPED_DURATION_S, seed=args.seed).run().frames]
    start = base[0][0]
    frames = ((start + k / args.fps, base[k % len(base)][1], base[k % len(base)][2]) for k in range(total))
    return camera, settings, tracker_config, frames


def _recording(recording: Path, calib: Path | None, params: Path | None):
    """A recording's detection frames as the tracker node took them, the camera and the fuser settings."""
    from vessel_tools.demo import recorded_detection_frames
    from vessel_tools.track.offline_data import load_camera
    from vessel_track.tracker_node import load_detection_inputs

    classes, confidence_class = load_detection_inputs(params)
    frames = recorded_detection_frames(recording, 0, classes, confidence_class)
    if not frames:
        raise DataError(f"{recording} holds no /vessel/detections")
    camera, _ = load_camera(calib)
    settings, note = load_fuser_settings(params).for_camera(camera)
    if note:
        log(f"note: {note}")
    return [(f.stamp, f.boxes, f.scores) for f in frames], camera, settings


def structure_sizes(tracker: MultiTargetTracker, fuser: TrackFuser) -> dict[str, int]:
    """How much each structure of the two cores holds now."""
    selector = fuser.selector
    return {
        "live_tracks": len(tracker.track_ids),
        "track_history_entries": sum(len(track.history) for track in tracker._tracks),
        "ended_tracks_kept": len(tracker._ended),
        "world_filters": len(fuser.filters),
        "ended_world_filters": len(fuser._ended_filters),
        "shape_histories": len(fuser._shapes),
        "fuser_count_kinds": len(fuser.counts),
        "selection_running": len(selector._running),
        "selection_ended": len(selector._ended),
        "selection_confidences": sum(len(r.confidences) for r in selector._running.values()),
        "selection_ended_confidences": sum(len(r.confidences) for r in selector._ended.values()),
        "next_track_number": tracker._next_id,
    }


def _rss_mb() -> float:
    sample = read_proc(os.getpid())
    return sample.rss_kb / 1024.0 if sample is not None else math.nan


def _minute_row(minute: int, times_s: list[tuple[float, float]], tracker, fuser, traced: bool) -> dict:
    tracker_s = [t for t, _ in times_s]
    fuser_s = [f for _, f in times_s]
    return {"minute": minute, "frames": len(times_s), "tracker_ms": summary_ms(tracker_s),
            "fuser_ms": summary_ms(fuser_s), "frame_ms": summary_ms([t + f for t, f in times_s]),
            "cpu_s": sum(tracker_s) + sum(fuser_s),
            "rss_mb": _rss_mb(), "traced_mb": tracemalloc.get_traced_memory()[0] / 1e6 if traced else math.nan,
            "sizes": structure_sizes(tracker, fuser)}


def run(args: argparse.Namespace) -> dict:
    """Feed the stream through both cores; a row of figures per simulated minute."""
    camera, settings, tracker_config, frames = stream(args)
    tracker = MultiTargetTracker(tracker_config)
    fuser = TrackFuser(camera, settings.distance_model, settings.fusion, settings.cue_stats, settings.motion,
                       settings.selection, settings.error_model, water_level=settings.water_level.load(),
                       water_level_max_hold_s=settings.water_level.max_hold_s)
    if args.tracemalloc:
        tracemalloc.start()
    rows: list[dict] = []
    times: list[tuple[float, float]] = []
    start = None
    started = time.monotonic()
    try:
        for stamp, boxes, scores in frames:
            start = stamp if start is None else start
            t0 = time.thread_time_ns()
            states = tracker.update(stamp, boxes, scores)
            t1 = time.thread_time_ns()
            fuser.update(stamp, [screen_track_of(state, settings.fusion.screen_source) for state in states])
            times.append(((t1 - t0) / 1e9, (time.thread_time_ns() - t1) / 1e9))
            if stamp - start >= 60.0 * (len(rows) + 1) - 1.5 / args.fps:  # the minute's last frame
                rows.append(_minute_row(len(rows) + 1, times, tracker, fuser, args.tracemalloc))
                times = []
                log(f"minute {len(rows)}: frame p50 {rows[-1]['frame_ms']['p50']:.2f} ms, "
                    f"{rows[-1]['sizes']['live_tracks']} live tracks, RSS {rows[-1]['rss_mb']:.0f} MB")
        if times:
            rows.append(_minute_row(len(rows) + 1, times, tracker, fuser, args.tracemalloc))
    finally:
        if args.tracemalloc:
            tracemalloc.stop()
    return figures(args, rows, time.monotonic() - started)


def figures(args: argparse.Namespace, rows: list[dict], seconds: float) -> dict:
    """The run's figures: every minute's row, first against last, and what kept growing."""
    first, last = rows[0], rows[-1]
    ratio = last["frame_ms"]["p50"] / first["frame_ms"]["p50"] if first["frame_ms"]["n"] else math.nan
    grown = {key: [first["sizes"][key], last["sizes"][key]] for key in first["sizes"]
             if key != "next_track_number" and last["sizes"][key] > 1.2 * first["sizes"][key] + 10}
    return {"source": str(args.recording) if args.recording is not None else f"simulated {args.scene}",
            "fps": args.fps, "minutes": args.minutes, "seconds_taken": seconds, "per_minute": rows,
            "frame_p50_last_over_first": ratio,
            "cpu_per_frame_last_over_first": (last["cpu_s"] / last["frames"]) / (first["cpu_s"] / first["frames"])
            if first["cpu_s"] > 0 else math.nan,
            "rss_growth_mb": last["rss_mb"] - first["rss_mb"],
            "grew_more_than_20_percent": grown}


def format_report(result: dict) -> str:
    """The figures as a table, one line per simulated minute."""
    lines = [f"soak of the tracker and fuser cores: {result['source']} at {result['fps']:g} frames/s, "
             f"{result['minutes']:g} min of stamps in {result['seconds_taken']:.0f} s; CPU ms per frame",
             f"{'min':>3} {'frames':>6} {'tracker p50/p95':>16} {'fuser p50/p95':>14} {'RSS MB':>7} {'heap MB':>7} "
             f"{'tracks':>6} {'history':>7} {'filters':>7} {'ended':>5} {'sel.run':>7} {'sel.end':>7} {'conf':>6}"]
    for row in result["per_minute"]:
        s = row["sizes"]
        lines.append(
            f"{row['minute']:>3} {row['frames']:>6} {row['tracker_ms']['p50']:>7.2f}/{row['tracker_ms']['p95']:<8.2f} "
            f"{row['fuser_ms']['p50']:>6.2f}/{row['fuser_ms']['p95']:<7.2f} {row['rss_mb']:>7.1f} "
            f"{row['traced_mb']:>7.1f} {s['live_tracks']:>6} {s['track_history_entries']:>7} "
            f"{s['world_filters']:>7} {s['ended_world_filters']:>5} {s['selection_running']:>7} "
            f"{s['selection_ended']:>7} {s['selection_confidences'] + s['selection_ended_confidences']:>6}")
    lines.append(f"last/first minute: frame p50 {result['frame_p50_last_over_first']:.2f}, mean "
                 f"{result['cpu_per_frame_last_over_first']:.2f}; RSS "
                 f"{result['rss_growth_mb']:+.1f} MB from the first minute to the last; grew by more than 20 %: "
                 + (", ".join(f"{k} {a} -> {b}" for k, (a, b) in result["grew_more_than_20_percent"].items())
                    or "nothing"))
    return "\n".join(lines)


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: 0 done, 2 bad input, 130 interrupted."""
    args = parse_args(argv)
    result = run(args)
    return print_and_save(format_report(result), result, args.out)


if __name__ == "__main__":
    sys.exit(main())
