"""The figures, table and curve of ``./vessel bench cameras`` (``vessel_tools.bench_cameras``).

Per camera: its measured frames offered and processed (a fix came out), the latency from image to fix, and the
memory and CPU of its processes, a process serving several cameras shared out evenly between them. The whole
machine: the same over every camera not killed on purpose, memory and CPU of every process still running.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from vessel_tools.bench_report import summary_ms
from vessel_tools.proc_monitor import ProcMonitor


def _latencies_s(camera, log) -> list[float]:
    measured = camera.stamps[camera.warmup:]
    return [(log.fixes[s] - log.images[s]) / 1e9 for s in measured if s in log.fixes and s in log.images]


def camera_figures(camera, log, run, usage: dict) -> dict:
    """One camera's figures (``CameraRun``, its ``CameraLog``, the ``Run`` and the processes' ``NodeUsage``)."""
    measured = camera.stamps[camera.warmup:]
    sent_all = camera.ended and camera.killed_at_s is None and f"{camera.spec.label}/camera" not in camera.failed
    seen = set(log.images) | set(log.fixes)
    offered = len(measured) if sent_all else sum(1 for stamp in measured if stamp in seen)
    processed = sum(1 for stamp in measured if stamp in log.fixes)
    latency = summary_ms(_latencies_s(camera, log))
    rss = cpu = 0.0
    processes = 0.0
    for process in run.fleet.of_camera(camera.spec.name):
        figures = usage.get(process.label)
        share = 1.0 / len(process.cameras)
        processes += share
        if figures is not None:
            rss += share * figures.rss_mb
            cpu += share * figures.cpu_s_measured
    return {
        "video": camera.video, "source": camera.spec.source, "rate": camera.rate,
        "frames_offered": offered, "frames_processed": processed,
        "processed_fraction": processed / offered if offered else math.nan,
        "latency_ms_p50": latency["p50"], "latency_ms_p95": latency["p95"], "latency_n": latency["n"],
        "rss_mb_total": rss, "cpu_ms_per_frame": 1000.0 * cpu / processed if processed else math.nan,
        "processes": processes, "images_seen_by_watcher": sum(1 for stamp in measured if stamp in log.images),
        "killed_at_s": camera.killed_at_s, "failed": list(camera.failed),
        "counters": _counters(getattr(run, "watcher", None), camera.spec.name),
    }


COUNTERS = {"camera": ("frames_sent",), "detector": ("frames_received", "frames_processed", "dropped_frames"),
            "gps_publisher": ("fixes", "no_fixes")}
"""The nodes' own counts (their last ``/diagnostics``) kept with each camera's figures: where frames went."""


def _counters(watcher, namespace: str) -> dict[str, dict[str, int | None]]:
    counter = getattr(watcher, "counter", None)
    if counter is None:
        return {}
    return {node: {key: counter(namespace, node, key) for key in keys} for node, keys in COUNTERS.items()}


def machine_figures(per_camera: dict[str, dict], run, usage: dict) -> dict:
    """The whole machine's figures: every camera but one killed on purpose; every process still running."""
    kept = [camera for camera in run.cameras if camera.killed_at_s is None]
    offered = sum(per_camera[camera.spec.label]["frames_offered"] for camera in kept)
    processed = sum(per_camera[camera.spec.label]["frames_processed"] for camera in kept)
    latencies = [value for camera in kept for value in _latencies_s(camera, run.watcher.logs[camera.spec.name])]
    latency = summary_ms(latencies)
    killed = {camera.spec.name for camera in run.cameras if camera.killed_at_s is not None}
    alive = [label for label, process in run.labels.items()
             if not (len(process.cameras) == 1 and process.cameras[0] in killed)]
    rss = sum(usage[label].rss_mb for label in alive if label in usage)
    cpu = sum(usage[label].cpu_s_measured for label in alive if label in usage)
    watcher = usage.get(ProcMonitor.OWN)
    return {
        "frames_offered": offered, "frames_processed": processed,
        "processed_fraction": processed / offered if offered else math.nan,
        "latency_ms_p50": latency["p50"], "latency_ms_p95": latency["p95"], "latency_n": latency["n"],
        "rss_mb_total": rss, "cpu_ms_per_frame": 1000.0 * cpu / processed if processed else math.nan,
        "processes": len(run.labels),
        "cameras_killed": sorted(name.strip("/") for name in killed),
        "bench_watcher": watcher.as_dict() if watcher is not None else None,
    }


def _f(value, digits: int = 0) -> str:
    return f"{value:.{digits}f}" if isinstance(value, (int, float)) and math.isfinite(value) else "-"


def format_table(result: dict) -> str:
    """One run as a table: a row per camera and one for the machine."""
    machine = result["machine"]
    load = " ".join(f"{v:.2f}" for v in machine["load_average_before"])
    after = " ".join(f"{v:.2f}" for v in machine.get("load_average_after", []))
    lines = [
        f"{result['cameras']} camera(s) at {result['fps']:g} frames/s, {result['processes']} processes "
        f"({result['processes_mode']}), {result['measured_s'] / 60:.1f} min measured; {machine['cores']} cores, "
        f"load average {load} before, {after} after",
        f"{'camera':<8}{'video':>6}{'offered':>9}{'processed':>10}{'fraction':>9}{'p50 ms':>8}{'p95 ms':>8}"
        f"{'RSS MB':>8}{'CPU ms/frame':>13}{'processes':>10}",
    ]

    def row(name: str, video: str, figures: dict) -> str:
        return (f"{name:<8}{video:>6}{figures['frames_offered']:>9}{figures['frames_processed']:>10}"
                f"{_f(figures['processed_fraction'], 3):>9}{_f(figures['latency_ms_p50']):>8}"
                f"{_f(figures['latency_ms_p95']):>8}{_f(figures['rss_mb_total']):>8}"
                f"{_f(figures['cpu_ms_per_frame'], 1):>13}{_f(figures['processes'], 1):>10}")

    for name, figures in result["per_camera"].items():
        note = f"  killed {figures['killed_at_s']:.0f} s in" if figures.get("killed_at_s") is not None else ""
        note += f"  failed: {', '.join(figures['failed'])}" if figures.get("failed") else ""
        lines.append(row(name, str(figures["video"]), figures) + note)
    lines.append(row("machine", "", result))
    return "\n".join(lines)


def plot_curve(results: Sequence[dict], png: Path) -> None:
    """Frames processed per second (and offered) and memory against the number of cameras, one line per mode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (rate_axes, memory_axes) = plt.subplots(1, 2, figsize=(9, 3.6))
    modes = sorted({result["processes_mode"] for result in results})
    for mode in modes:
        runs = sorted((r for r in results if r["processes_mode"] == mode), key=lambda r: r["cameras"])
        n = [r["cameras"] for r in runs]
        processed = [r["frames_processed"] / (60.0 * r["minutes"]) for r in runs]
        rate_axes.plot(n, processed, "o-", label=f"processed, {mode}")
        memory_axes.plot(n, [r["rss_mb_total"] for r in runs], "o-", label=mode)
    everything = sorted(results, key=lambda r: r["cameras"])
    rate_axes.plot([r["cameras"] for r in everything], [r["cameras"] * r["fps"] for r in everything], "k:",
                   label="offered")
    cores = everything[0]["machine"]["cores"] if everything else "?"
    rate_axes.set(xlabel="cameras", ylabel="frames/s (all cameras)", title=f"frames processed ({cores} cores)")
    memory_axes.set(xlabel="cameras", ylabel="MB", title="resident memory of every process")
    for axes in (rate_axes, memory_axes):
        axes.grid(alpha=0.3)
        axes.legend(fontsize=8)
    figure.tight_layout()
    Path(png).parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(png, dpi=110)
    plt.close(figure)
