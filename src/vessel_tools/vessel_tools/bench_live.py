"""``./vessel bench live``: the whole graph on a stream at the camera's frame rate, for minutes.

A live camera delivers 25-30 frames/s, far more than the detector runs on a small computer. The camera node plays
one challenge video's frames as an image folder at ``--fps`` (real time, looped, stamps moving on), so the graph
sees what a live camera gives it; the detector takes the newest frame and drops the backlog. Reported, from the
nodes' own ``/diagnostics`` counters and an in-process watcher:

- frames offered (the camera's ``frames_sent``), received by the detector, processed, and dropped (the
  detector's ``dropped_frames``: replaced before it took them; the rest of the gap is lost in transport);
- latency from an image's arrival to the ``/vessel/fix`` of the same stamp, p50 and p95, over the run, for the
  first and the last minute and for every minute (a growing queue or a growing cost per frame shows as a growing
  latency), and split by the node it was spent in (from one node's publication of a frame to the next one's:
  queue and work), so that a growing latency points at its node;
- memory (RSS) of every node at the start and at the end, sampled every 30 s, and its growth per minute;
- the tracker's live tracks (its ``live_tracks`` on ``/diagnostics``) at each sample: the cost of a frame in the
  tracker, the fuser and the GPS publisher grows with them.

    ./vessel bench live --minutes 10 --out out/bench/live.json
"""

from __future__ import annotations

import argparse
import datetime
import math
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vessel_bringup.graph import default_calibration_file, default_params_file
from vessel_bringup.graph_watcher import CHAIN, FIX_TOPIC, IMAGE_TOPIC
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_common.paths import default_data_dir
from vessel_tools.bench import GraphError, GraphSession, _domain_id, log, machine_info, print_and_save, summary_ms
from vessel_tools.calib.dataset import Dataset
from vessel_tools.proc_monitor import node_pid, read_proc

DEFAULT_FPS = 25.0
DEFAULT_MINUTES = 10.0
WARMUP_S = 30.0
SAMPLE_EVERY_S = 30.0


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command line."""
    parser = argparse.ArgumentParser(prog="./vessel bench live", description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=None, help="dataset folder (default $VESSEL_DATA or "
                        "../shared/aitas)")
    parser.add_argument("--video", type=int, default=13, help="the video whose frames are streamed (default 13)")
    parser.add_argument("--fps", type=float, default=DEFAULT_FPS, help=f"frame rate of the stream (default "
                        f"{DEFAULT_FPS:g})")
    parser.add_argument("--minutes", type=float, default=DEFAULT_MINUTES, help="measured duration, after the "
                        f"warm-up (default {DEFAULT_MINUTES:g})")
    parser.add_argument("--warmup-s", type=float, default=WARMUP_S, help=f"streamed first and not measured, s "
                        f"(default {WARMUP_S:g})")
    parser.add_argument("--params", type=Path, default=None, help="graph parameter file (default config/aitas.yaml)")
    parser.add_argument("--calib", type=Path, default=None, help="calibration file (default "
                        "config/aitas_camera.yaml)")
    parser.add_argument("--out", type=Path, default=None, help="also write the figures to this JSON file")
    parser.add_argument("--log-dir", type=Path, default=None, help="node logs (default: a temporary folder)")
    args = parser.parse_args(argv)
    if not (args.fps > 0 and math.isfinite(args.fps)):
        parser.error(f"--fps must be a positive number, got {args.fps}")
    if not (args.minutes > 0 and math.isfinite(args.minutes)):
        parser.error(f"--minutes must be a positive number, got {args.minutes}")
    if not (args.warmup_s >= 0 and math.isfinite(args.warmup_s)):
        parser.error(f"--warmup-s must be a number of seconds >= 0, got {args.warmup_s}")
    return args


def _frames_folder(data: Path | None, video: int) -> tuple[Path, str]:

    folder = data or default_data_dir()
    if folder is None:
        raise DataError("no dataset folder: pass --data DIR or set VESSEL_DATA (default ../shared/aitas)")
    frames = Dataset(folder).frames([video])
    if not frames:
        raise DataError(f"video {video} has no frames in {folder / 'frames.csv'}")

    start = datetime.datetime.fromtimestamp(frames[0].stamp, datetime.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    return frames[0].path.parent, start


def _counter(diagnostics: dict[str, dict[str, str]], node: str, key: str) -> int:
    for name, values in diagnostics.items():
        if name.strip("/").split("/")[-1] == node and f"count.{key}" in values:
            return int(values[f"count.{key}"])
    return 0


def _value(diagnostics: dict[str, dict[str, str]], node: str, key: str) -> float:
    """A figure a node reports with ``set_value`` (NaN when it has not reported it)."""
    for name, values in diagnostics.items():
        if name.strip("/").split("/")[-1] == node and key in values:
            try:
                return float(values[key])
            except ValueError:
                return math.nan
    return math.nan


def _latency_by_minute(watcher, since_ns: int, until_ns: int) -> list[dict]:
    """Latency (``summary_ms``) of the images that arrived in each minute from ``since_ns``.

    A last partial minute counts when it is at least half a minute long.
    """
    minute_ns = 60_000_000_000
    out = []
    for index, start in enumerate(range(since_ns, until_ns - minute_ns // 2 + 1, minute_ns)):
        out.append({"minute": index + 1, **summary_ms(_latencies_s(watcher, start, min(start + minute_ns, until_ns)))})
    return out


STAGES = ("detector", "tracker", "fuser", "gps_publisher")
"""The node that publishes each topic of ``CHAIN`` after the image."""


def _stage_latencies_ms(watcher, since_ns: int, until_ns: int) -> dict[str, dict]:
    """Per node, ``summary_ms`` of the time from the previous node's publication of a frame to its own.

    Frames whose image arrived in the window and that reached ``/vessel/fix``; publication times are the DDS source
    timestamps (each node's clock, CLOCK_REALTIME, one machine).
    """
    logs = [watcher.log.by_topic[topic] for topic in CHAIN]
    stages: dict[str, list[float]] = {name: [] for name in STAGES}
    for key, image in logs[0].items():
        chain = [image] + [log.get(key) for log in logs[1:]]
        if any(arrival is None for arrival in chain) or not since_ns <= image.received_ns < until_ns:
            continue
        for name, before, after in zip(STAGES, chain[:-1], chain[1:], strict=True):
            stages[name].append((after.published_ns - before.published_ns) / 1e9)
    return {name: summary_ms(values) for name, values in stages.items()}


def _latencies_s(watcher, since_ns: int, until_ns: int) -> list[float]:
    images = watcher.log.by_topic[IMAGE_TOPIC]
    out = []
    for key, fix in watcher.log.by_topic[FIX_TOPIC].items():
        image = images.get(key)
        if image is not None and since_ns <= image.received_ns < until_ns:
            out.append((fix.received_ns - image.received_ns) / 1e9)
    return out


def run(args: argparse.Namespace) -> dict:
    """Stream, measure, stop; the figures."""
    folder, start_utc = _frames_folder(args.data, args.video)
    params = [args.params or default_params_file(), args.calib or default_calibration_file()]
    log_dir = args.log_dir or Path(tempfile.mkdtemp(prefix="vessel_bench_live_"))
    session = GraphSession(folder, params, frames_in_bag=0, warmup=0, domain_id=_domain_id(), log_dir=log_dir,
                           frame_timeout_s=60.0)
    samples: dict[str, list[tuple[float, float]]] = {}
    live_tracks: list[tuple[float, float]] = []
    try:
        session.start()
        watcher = session.watcher
        camera = session.runner.start(session.nodes["camera"], {
            "source": str(folder), "fps": float(args.fps), "start_utc": start_utc, "rate": 1.0, "loop": True,
            "loop_restamp": True, "wait_for_subscribers": 2, "publish_clock": False,
        })
        session.monitor.add("camera", node_pid(camera.process.pid, session.nodes["camera"].executable))
        log(f"streaming {folder} at {args.fps:g} frames/s: {args.warmup_s:g} s warm-up, then {args.minutes:g} min")
        started = time.monotonic()
        watcher.spin(args.warmup_s)
        measure_from_ns = time.time_ns()
        session.monitor.open_window()
        counters_start = {key: _counter(watcher.diagnostics, node, key) for node, key in _COUNTERS}
        end = time.monotonic() + 60.0 * args.minutes
        next_sample = time.monotonic()
        while time.monotonic() < end:
            if time.monotonic() >= next_sample:
                _sample_rss(session.monitor.pids, time.monotonic() - started, samples)
                live_tracks.append((time.monotonic() - started, _value(watcher.diagnostics, "tracker", "live_tracks")))
                next_sample += SAMPLE_EVERY_S
                elapsed = time.monotonic() - started - args.warmup_s
                log(f"{elapsed / 60:.1f} min: {watcher.log.count(IMAGE_TOPIC)} images, "
                    f"{watcher.log.count(FIX_TOPIC)} fixes")
            failed = session.runner.failed()
            if failed:
                raise GraphError(f"node(s) {', '.join(failed)} exited during the run; logs in {log_dir}")
            watcher.spin(0.5)
        measure_to_ns = time.time_ns()
        session.monitor.close_window()
        watcher.spin(3.0)  # the last frames' diagnostics and fixes
        counters_end = {key: _counter(watcher.diagnostics, node, key) for node, key in _COUNTERS}
        _sample_rss(session.monitor.pids, time.monotonic() - started, samples)
        live_tracks.append((time.monotonic() - started, _value(watcher.diagnostics, "tracker", "live_tracks")))
        minute_ns = 60_000_000_000
        return _figures(args, folder, counters_start, counters_end, samples,
                        all_latencies=_latencies_s(watcher, measure_from_ns, measure_to_ns),
                        first_minute=_latencies_s(watcher, measure_from_ns, measure_from_ns + minute_ns),
                        last_minute=_latencies_s(watcher, measure_to_ns - minute_ns, measure_to_ns),
                        seconds=(measure_to_ns - measure_from_ns) / 1e9,
                        per_minute=_latency_by_minute(watcher, measure_from_ns, measure_to_ns),
                        live_tracks=live_tracks, cpu_s=_cpu_s(session.monitor), stages=(
                            _stage_latencies_ms(watcher, measure_from_ns, measure_from_ns + minute_ns),
                            _stage_latencies_ms(watcher, measure_to_ns - minute_ns, measure_to_ns)))
    finally:
        session.stop()


def _cpu_s(monitor) -> dict[str, float]:
    """Each process's CPU seconds over the measured minutes (this watcher included)."""
    return {usage.name: usage.cpu_s_measured for usage in monitor.usage()}


def _sample_rss(pids: dict[str, int], elapsed_s: float, samples: dict[str, list[tuple[float, float]]]) -> None:
    """Add each node's resident memory (MB) at ``elapsed_s`` to ``samples``."""
    for name, pid in pids.items():
        sample = read_proc(pid)
        if sample is not None:
            samples.setdefault(name, []).append((elapsed_s, sample.rss_kb / 1024.0))


_COUNTERS = (("camera", "frames_sent"), ("detector", "frames_received"), ("detector", "frames_processed"),
             ("detector", "dropped_frames"), ("gps_publisher", "fixes"))


def _figures(args, folder, counters_start, counters_end, samples, all_latencies, first_minute, last_minute,
             seconds, per_minute=(), live_tracks=(), stages=({}, {}), cpu_s=None) -> dict:
    delta = {key: counters_end[key] - counters_start[key] for key in counters_end}
    memory = {}
    for name, values in samples.items():
        t = np.array([v[0] for v in values])
        mb = np.array([v[1] for v in values])
        slope = float(np.polyfit(t / 60.0, mb, 1)[0]) if len(values) >= 3 else float("nan")
        memory[name] = {"start_mb": float(mb[0]), "end_mb": float(mb[-1]), "growth_mb_per_min": slope,
                        "samples_s_mb": [[float(a), float(b)] for a, b in values]}
    first, last = summary_ms(first_minute), summary_ms(last_minute)
    offered = delta["frames_sent"]
    processed = delta["frames_processed"]
    cpu_ms_per_frame = {name: 1000.0 * value / processed if processed else float("nan")
                        for name, value in (cpu_s or {}).items()}
    return {
        "source": str(folder), "fps": args.fps, "minutes_measured": seconds / 60.0,
        "frames_offered": offered,
        "frames_received_by_detector": delta["frames_received"],
        "frames_processed": delta["frames_processed"],
        "frames_dropped_by_detector": delta["dropped_frames"],
        "frames_lost_in_transport": max(0, offered - delta["frames_received"]),
        "fixes": delta["fixes"],
        "processed_per_s": delta["frames_processed"] / seconds if seconds > 0 else float("nan"),
        "offered_per_s": offered / seconds if seconds > 0 else float("nan"),
        "latency_image_to_fix_ms": summary_ms(all_latencies),
        "latency_first_minute_ms": first,
        "latency_last_minute_ms": last,
        "latency_last_over_first_p50": last["p50"] / first["p50"] if first["n"] and last["n"] else float("nan"),
        "latency_per_minute_ms": list(per_minute),
        "stage_latency_first_minute_ms": stages[0], "stage_latency_last_minute_ms": stages[1],
        "live_tracks_s": [[float(a), float(b)] for a, b in live_tracks],
        "memory": memory,
        "cpu_ms_per_processed_frame": cpu_ms_per_frame,
        "cpu_cores_used": {name: value / seconds for name, value in (cpu_s or {}).items()} if seconds > 0 else {},
        "machine": machine_info(),
    }


def format_report(result: dict) -> str:
    """The figures as text."""
    lat = result["latency_image_to_fix_ms"]
    first, last = result["latency_first_minute_ms"], result["latency_last_minute_ms"]
    nan = float("nan")
    per_minute = ", ".join(f"{m['minute']}: {m.get('p50', nan):.0f}/{m.get('p95', nan):.0f}"
                           for m in result.get("latency_per_minute_ms", []))
    tracks = [n for _, n in result.get("live_tracks_s", [])]
    first_stages, last_stages = result.get("stage_latency_first_minute_ms", {}), result.get(
        "stage_latency_last_minute_ms", {})
    stages = ", ".join(f"{name} {first_stages[name]['p50']:.0f}/{first_stages[name]['p95']:.0f} -> "
                       f"{last_stages[name]['p50']:.0f}/{last_stages[name]['p95']:.0f}"
                       for name in first_stages if name in last_stages)
    lines = [
        f"live stream {result['source']} at {result['fps']:g} frames/s, {result['minutes_measured']:.1f} min measured",
        f"  frames offered {result['frames_offered']} ({result['offered_per_s']:.1f}/s), received by the detector "
        f"{result['frames_received_by_detector']}, processed {result['frames_processed']} "
        f"({result['processed_per_s']:.2f}/s), dropped by the detector {result['frames_dropped_by_detector']}, "
        f"lost in transport {result['frames_lost_in_transport']}; fixes {result['fixes']}",
        f"  latency image -> fix: p50 {lat.get('p50', nan):.0f} ms, p95 {lat.get('p95', nan):.0f} ms over "
        f"{lat.get('n', 0)} fixes",
        f"  first minute p50/p95 {first.get('p50', nan):.0f}/{first.get('p95', nan):.0f} ms, last minute "
        f"{last.get('p50', nan):.0f}/{last.get('p95', nan):.0f} ms (last/first p50 "
        f"{result.get('latency_last_over_first_p50', nan):.2f})",
        f"  per minute p50/p95, ms: {per_minute or 'none'}",
        f"  per node p50/p95 first -> last minute, ms: {stages or 'not measured'}",
        f"  tracker live tracks per 30 s: {' '.join(f'{n:.0f}' for n in tracks) or 'not reported'}",
        "  CPU per processed frame, ms (cores in use): " + (", ".join(
            f"{name} {ms:.1f} ({result['cpu_cores_used'].get(name, nan):.2f})"
            for name, ms in sorted(result.get("cpu_ms_per_processed_frame", {}).items())) or "not measured"),
        "  memory (RSS, MB) start -> end (growth per minute):",
    ]
    for name, m in sorted(result["memory"].items()):
        lines.append(f"    {name:<14} {m['start_mb']:7.1f} -> {m['end_mb']:7.1f} ({m['growth_mb_per_min']:+.2f}/min)")
    return "\n".join(lines)


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: 0 done, 2 bad input or a graph that failed, 130 interrupted."""
    args = parse_args(argv)
    result = run(args)
    return print_and_save(format_report(result), result, args.out)


if __name__ == "__main__":
    sys.exit(main())
