"""The report of the benchmarks (``./vessel bench`` and its sub-tools): progress, the table, the JSON figures.

Progress goes to stderr, so stdout keeps only the table; ``--out`` writes the figures as JSON, atomically.
"""

from __future__ import annotations

import json
import math
import os
import platform
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

RATIO_TARGET = 0.9
"""The graph's frames/s against the detector core's that the project aims at on two cores."""


def log(message: str) -> None:
    """Progress on stderr, so stdout keeps only the table."""
    print(f"[bench] {message}", file=sys.stderr, flush=True)


def summary_ms(values_s: Sequence[float]) -> dict[str, float | int]:
    """Median, p95, mean, min, max (milliseconds) and count of durations given in seconds; NaN when empty."""
    values = np.asarray([v for v in values_s if math.isfinite(v)], dtype=float) * 1000.0
    if values.size == 0:
        nan = float("nan")
        return {"p50": nan, "p95": nan, "mean": nan, "min": nan, "max": nan, "n": 0}
    return {
        "p50": float(np.percentile(values, 50)),
        "p95": float(np.percentile(values, 95)),
        "mean": float(values.mean()),
        "min": float(values.min()),
        "max": float(values.max()),
        "n": int(values.size),
    }


def machine_info() -> dict[str, object]:
    """Cores, CPU model, load average, versions."""
    import onnxruntime

    model = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cores": os.cpu_count(),
        "cpu_model": model or platform.processor(),
        "load_average_before": list(os.getloadavg()),
        "onnxruntime_version": onnxruntime.__version__,
        "python": platform.python_version(),
    }


def _fmt(value: float, digits: int = 1) -> str:
    return f"{value:.{digits}f}" if isinstance(value, (int, float)) and math.isfinite(value) else "-"


def format_table(result: dict) -> str:
    """The figures as a plain-text table."""
    core, graph, machine = result["detector_core"], result["graph"], result["machine"]
    lines = [
        f"vessel bench: video {result['video']}, {graph['frames_measured']}/{result['frames']} frames measured "
        f"(+{result['warmup']} warm-up), detector mode {machine['detector_mode']} "
        f"({machine['windows_per_frame']} network runs/frame), onnxruntime {machine['onnxruntime_version']} "
        f"{machine['onnxruntime_threads']} threads, {result.get('frames_in_flight', 1)} frame(s) in flight",
        f"machine: {machine['cores']} cores ({machine['cpu_model']}), load average before "
        + " ".join(f"{v:.2f}" for v in machine["load_average_before"])
        + ", after " + " ".join(f"{v:.2f}" for v in machine["load_average_after"]),
        "",
        f"{'':40s}{'frames/s':>10s}{'ms p50':>10s}{'ms p95':>10s}",
        f"{'detector core (decode + detect)':40s}{_fmt(result['detector_core_fps'], 2):>10s}"
        f"{_fmt(core['total_ms']['p50']):>10s}{_fmt(core['total_ms']['p95']):>10s}",
        f"{'  of which decode':40s}{'':>10s}{_fmt(core['decode_ms']['p50']):>10s}{_fmt(core['decode_ms']['p95']):>10s}",
        f"{'graph end to end (frame interval)':40s}{_fmt(result['graph_fps'], 2):>10s}"
        f"{_fmt(graph['graph_interval_ms']['p50']):>10s}{_fmt(graph['graph_interval_ms']['p95']):>10s}",
        f"{'ratio graph / core':40s}{_fmt(result['ratio_graph_to_core'], 2):>10s}   target >= {RATIO_TARGET:.2f}: "
        + ("met" if result["ratio_graph_to_core"] >= RATIO_TARGET else "NOT met"),
        f"{'  per round: core':40s}" + " ".join(_fmt(v, 2) for v in core["fps_per_round"]),
        f"{'  per round: graph':40s}" + " ".join(_fmt(v, 2) for v in graph["graph_fps_per_round"]),
        f"{'latency image -> /vessel/fix':40s}{'':>10s}{_fmt(result['latency_ms_p50']):>10s}"
        f"{_fmt(result['latency_ms_p95']):>10s}",
        f"{'  (publication times)':40s}{'':>10s}{_fmt(graph['latency_fix_published_ms']['p50']):>10s}"
        f"{_fmt(graph['latency_fix_published_ms']['p95']):>10s}",
        f"{'latency image -> /vessel/tracks':40s}{'':>10s}{_fmt(graph['latency_tracks_ms']['p50']):>10s}"
        f"{_fmt(graph['latency_tracks_ms']['p95']):>10s}",
        "",
        "per stage, publication to publication (ms):",
    ]
    for name, stats in graph["stages_ms"].items():
        lines.append(f"{'  ' + name:40s}{'':>10s}{_fmt(stats['p50']):>10s}{_fmt(stats['p95']):>10s}")
    turnaround = graph["camera_turnaround_ms"]
    lines.append(f"{'  camera: detections -> next image':40s}{'':>10s}{_fmt(turnaround['p50']):>10s}"
                 f"{_fmt(turnaround['p95']):>10s}")
    lines += ["", "CPU over the measured frames (100 % = one core) and peak memory (VmHWM):",
              f"{'process':18s}{'pid':>8s}{'CPU s total':>13s}{'CPU s meas.':>13s}{'CPU %':>8s}"
              f"{'CPU ms/frame':>14s}{'peak MB':>9s}"]
    lines.append(f"{'detector core':18s}{'':>8s}{'':>13s}{'':>13s}{_fmt(core['cpu_percent'], 0):>8s}"
                 f"{_fmt(core['cpu_ms_per_frame'], 0):>14s}{'':>9s}")
    for name, usage in result["nodes"].items():
        lines.append(f"{name:18s}{usage['pid']:>8d}{_fmt(usage['cpu_s_total'], 2):>13s}"
                     f"{_fmt(usage['cpu_s_measured'], 2):>13s}{_fmt(usage['cpu_percent'], 0):>8s}"
                     f"{_fmt(usage['cpu_ms_per_frame'], 0):>14s}{_fmt(usage['peak_mb'], 0):>9s}")
    if result.get("warnings"):
        lines += [""] + [f"warning: {w}" for w in result["warnings"]]
    return "\n".join(lines)


def _json_safe(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def print_and_save(table: str, result: dict, out: Path | None) -> int:
    """A benchmark's end: its table on stdout; with ``--out`` its figures as JSON, said on stderr. Exit status 0."""
    print(table)
    if out is not None:
        write_json(out, result)
        log(f"figures written to {out}")
    return 0


def write_json(path: Path, result: dict) -> None:
    """Write the result atomically (temp file + rename); non-finite numbers become null, paths strings."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(handle, "w") as stream:
        json.dump(_json_safe(result), stream, indent=2)
        stream.write("\n")
    os.replace(temp, path)

