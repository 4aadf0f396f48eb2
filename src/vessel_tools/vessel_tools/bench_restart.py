"""``./vessel bench restart``: kill -9 one node of ``./vessel graph --respawn`` and time the graph's recovery.

For each node named, the graph replays a bag at ``--rate``; after ``--kill-after`` fixes the node is killed with
SIGKILL and restarted by the graph runner. Measured against an uninterrupted run of the same bag, in the same
process:

- seconds from the kill to the next ``/vessel/fix``;
- fixes of the uninterrupted run that never came (frames lost while the node was down);
- how far the first fixes after the restart are from the uninterrupted run's at the same stamps (metres), and,
  where the dataset has the vessel's GPS, their error against the uninterrupted run's error at those stamps: a
  restarted node that resumes from its state file should publish fixes as good as if nothing had happened; one
  that starts cold has to confirm tracks and choose the target again.

Each node is measured with state files (the default of ``--respawn``) and, with ``--compare-cold``, without
(``--no-state-files``).

    ./vessel bench restart --compare-cold --out out/bench/restart.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vessel_bringup.graph_watcher import GraphWatcher
from vessel_calib import geodesy
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError, VesselError
from vessel_common.paths import default_data_dir
from vessel_tools.bench import _domain_id, log, machine_info, print_and_save
from vessel_tools.track.offline_data import open_dataset

RESTARTABLE = ("tracker", "fuser", "gps_publisher", "detector")
FIRST_AFTER = 10
"""Fixes after the restart whose distance to the uninterrupted run is reported."""


@dataclass
class Run:
    """The fixes one graph run published: stamp (ns) -> (lat, lon), and when each arrived (monotonic s)."""

    fixes: dict[int, tuple[float, float]] = field(default_factory=dict)
    arrivals: list[tuple[float, int]] = field(default_factory=list)
    killed_at: float | None = None
    stderr: str = ""


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command line."""
    parser = argparse.ArgumentParser(prog="./vessel bench restart", description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=None, help="dataset folder (default $VESSEL_DATA or "
                        "../shared/aitas)")
    parser.add_argument("--video", type=int, default=15, help="the video replayed (default 15)")
    parser.add_argument("--source", type=Path, default=None, help="a bag folder to replay instead of --video")
    parser.add_argument("--rate", type=float, default=4.0, help="replay rate (default 4: the challenge frames, 4 s "
                        "apart, arrive once a second)")
    parser.add_argument("--nodes", default="tracker,fuser,gps_publisher",
                        help=f"comma-separated nodes to kill, one run each (from {', '.join(RESTARTABLE)})")
    parser.add_argument("--kill-after", type=int, default=10, help="fixes before the kill (default 10)")
    parser.add_argument("--repeat", type=int, default=1, help="runs per node and mode (discovery after a kill "
                        "varies from run to run; default 1)")
    parser.add_argument("--compare-cold", action="store_true", help="also measure each node restarted cold "
                        "(--no-state-files)")
    parser.add_argument("--hot-standby", action="store_true", help="run the graph with --hot-standby: the killed "
                        "node is replaced by its spare instead of a new process")
    parser.add_argument("--out", type=Path, default=None, help="also write the figures as JSON here")
    args = parser.parse_args(argv)
    args.node_list = [n.strip() for n in args.nodes.split(",") if n.strip()]
    unknown = [n for n in args.node_list if n not in RESTARTABLE]
    if unknown:
        parser.error(f"--nodes: unknown {unknown}; choose from {', '.join(RESTARTABLE)}")
    if args.kill_after < 1:
        parser.error("--kill-after must be at least 1")
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")
    return args


def _bag(args: argparse.Namespace, work: Path) -> Path:
    if args.source is not None:
        if not args.source.exists():
            raise DataError(f"--source {args.source} does not exist: give a bag folder written by ./vessel bag build")
        return args.source
    data = args.data or default_data_dir()
    done = subprocess.run([sys.executable, "-m", "vessel_tools.detect.bag_build", "--data", str(data), "--videos",
                           str(args.video), "--out", str(work / "bags")], capture_output=True, text=True)
    if done.returncode != 0:
        raise DataError(f"could not build the bag of video {args.video}: {done.stderr.strip()[-500:]}")
    return work / "bags" / f"video_{args.video}"


def _graph_run(watcher: GraphWatcher, bag: Path, rate: float, log_dir: Path, env: dict[str, str], kill: str | None,
               kill_after: int, cold: bool, hot_standby: bool = False) -> Run:
    """One run of ``./vessel graph --respawn`` to the end of the bag, killing ``kill`` after ``kill_after`` fixes."""
    watcher.fixes.clear()
    run = Run()
    log_dir.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, "-m", "vessel_bringup.graph", "--source", str(bag), "--rate", f"{rate:g}",
               "--exit-at-end", "--respawn", "--log-dir", str(log_dir)] + (["--no-state-files"] if cold else []) + (
                   ["--hot-standby"] if hot_standby else [])
    with open(log_dir / "graph.stderr", "w") as stderr:
        graph = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=stderr, text=True,
                                 start_new_session=True)
        try:
            deadline = time.monotonic() + 600.0
            while graph.poll() is None:
                if time.monotonic() > deadline:
                    raise VesselError(f"the graph did not end within 10 minutes; logs in {log_dir}")
                watcher.spin(0.05)
                if kill is not None and run.killed_at is None and len(watcher.fixes) >= kill_after:
                    run.killed_at = _kill(kill, log_dir)
            if kill is not None and run.killed_at is None:
                raise VesselError(f"the graph gave {len(watcher.fixes)} fixes, not {kill_after}, before it ended; "
                                  f"logs in {log_dir}")
        finally:
            if graph.poll() is None:
                graph.send_signal(signal.SIGINT)
                try:
                    graph.wait(timeout=30)
                except subprocess.TimeoutExpired:  # its nodes are in its process group
                    os.killpg(graph.pid, signal.SIGKILL)
                    graph.wait()
    watcher.spin(0.5)  # the last fixes in flight
    run.stderr = (log_dir / "graph.stderr").read_text(errors="replace")
    for received, stamp, lat, lon in watcher.fixes:
        run.fixes[stamp] = (lat, lon)
        run.arrivals.append((received, stamp))
    return run


def _kill(node: str, log_dir: Path) -> float:
    """SIGKILL the node the graph runner started with ``log_dir``; when (monotonic s)."""
    marker = str(log_dir / f"{node}.overrides.yaml")
    pids = subprocess.run(["pgrep", "-f", marker], capture_output=True, text=True).stdout.split()
    if len(pids) != 1:
        raise VesselError(f"found {len(pids)} processes of {node} (marker {marker})")
    killed_at = time.monotonic()
    os.kill(int(pids[0]), signal.SIGKILL)
    return killed_at


def _truth_errors(gps_track, run: Run) -> dict[int, float]:
    """Each fix's distance to the vessel's GPS at its stamp (m), where the track has it; {} without a track."""
    if gps_track is None or not run.fixes:
        return {}
    stamps = sorted(run.fixes)
    lat, lon, valid = gps_track.interpolate(np.array(stamps) / 1e9, max_gap_s=3.0)
    return {stamp: float(geodesy.haversine_m(*run.fixes[stamp], lat[i], lon[i]))
            for i, stamp in enumerate(stamps) if valid[i]}


def _figures(reference: Run, run: Run, node: str, mode: str, errors: dict[int, float],
             reference_errors: dict[int, float]) -> dict:
    assert run.killed_at is not None
    after = [(t, stamp) for t, stamp in run.arrivals if t > run.killed_at]
    next_fix_s = after[0][0] - run.killed_at if after else math.nan
    kill_stamp = max((stamp for t, stamp in run.arrivals if t <= run.killed_at), default=0)
    expected = [stamp for stamp in sorted(reference.fixes) if stamp > kill_stamp]
    lost = [stamp for stamp in expected if stamp not in run.fixes]
    shared = [stamp for _, stamp in after if stamp in reference.fixes][:FIRST_AFTER]
    deviations = [float(geodesy.haversine_m(*reference.fixes[s], *run.fixes[s])) for s in shared]
    scored = [s for _, s in after if s in errors and s in reference_errors][:FIRST_AFTER]
    excess = [errors[s] - reference_errors[s] for s in scored]
    return {
        "node": node, "restart": mode,
        "next_fix_s": round(next_fix_s, 2),
        "fixes_lost": len(lost), "fixes_expected_after_kill": len(expected),
        "max_deviation_m_first_fixes": round(max(deviations), 2) if deviations else math.nan,
        "fixes_deviating_over_1m": sum(d > 1.0 for d in deviations), "fixes_compared": len(deviations),
        "fixes_worse_than_uninterrupted_by_over_5m": sum(e > 5.0 for e in excess),
        "mean_error_m_first_fixes": round(float(np.mean([errors[s] for s in scored])), 2) if scored else math.nan,
        "mean_error_m_uninterrupted_same_stamps": (round(float(np.mean([reference_errors[s] for s in scored])), 2)
                                                   if scored else math.nan),
        "restarted": (f"{node} exited with status -9: restarting it" in run.stderr
                      or f"{node} exited with status -9: promoted its hot standby" in run.stderr),
    }


def run(args: argparse.Namespace) -> dict:
    """The reference run, then one run per node (and mode); the figures."""
    work = Path(tempfile.mkdtemp(prefix="vessel_bench_restart_"))
    domain_id = _domain_id()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED="1")
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    bag = _bag(args, work)
    watcher = GraphWatcher(domain_id)
    try:
        log(f"uninterrupted run of {bag} at rate {args.rate:g}")
        reference = _graph_run(watcher, bag, args.rate, work / "reference", env, None, 0, False, args.hot_standby)
        if len(reference.fixes) <= args.kill_after:
            raise VesselError(f"the uninterrupted run gave {len(reference.fixes)} fixes: nothing left to measure "
                              f"after --kill-after {args.kill_after}; logs in {work / 'reference'}")
        gps_track = None if args.source is not None else open_dataset(args.data).gps_track()
        reference_errors = _truth_errors(gps_track, reference)
        results = []
        for node in args.node_list:
            for cold in ((False, True) if args.compare_cold else (False,)):
                for repeat in range(args.repeat):
                    mode = ("hot standby, " if args.hot_standby else "") + ("cold" if cold else "state file")
                    log(f"kill -9 {node} after {args.kill_after} fixes ({mode}, run {repeat + 1} of {args.repeat})")
                    folder = work / f"{node}_{'cold' if cold else 'state'}_{repeat + 1}"
                    one = _graph_run(watcher, bag, args.rate, folder, env, node, args.kill_after, cold,
                                     args.hot_standby)
                    results.append(_figures(reference, one, node, mode, _truth_errors(gps_track, one),
                                           reference_errors))
                    log(json.dumps(results[-1]))
    finally:
        watcher.close()
    return {"bag": str(bag), "rate": args.rate, "kill_after": args.kill_after,
            "reference_fixes": len(reference.fixes), "runs": results, "logs": str(work), "machine": machine_info()}


def format_report(result: dict) -> str:
    """The figures as a table: one row per run, then the median and worst time to the next fix per node and mode."""
    lines = [f"bag {result['bag']} at rate {result['rate']:g}: {result['reference_fixes']} fixes uninterrupted; "
             f"kill -9 after {result['kill_after']}",
             f"{'node':<14}{'restart':<24}{'next fix s':>11}{'lost':>6}{'max dev m':>11}{'error m':>9}"
             f"{'uninterrupted m':>17}{'worse >5 m':>12}"]
    for r in result["runs"]:
        lines.append(f"{r['node']:<14}{r['restart']:<24}{r['next_fix_s']:>11.2f}{r['fixes_lost']:>6}"
                     f"{r['max_deviation_m_first_fixes']:>11.2f}{r['mean_error_m_first_fixes']:>9.2f}"
                     f"{r['mean_error_m_uninterrupted_same_stamps']:>17.2f}"
                     f"{r['fixes_worse_than_uninterrupted_by_over_5m']:>12}")
    groups: dict[tuple[str, str], list[float]] = {}
    for r in result["runs"]:
        groups.setdefault((r["node"], r["restart"]), []).append(r["next_fix_s"])
    lines.append("next fix after the kill, median / worst (s):")
    for (node, restart), times in groups.items():
        lines.append(f"  {node:<14}{restart:<24}{float(np.median(times)):>6.2f} / {max(times):.2f}  "
                     f"({len(times)} runs)")
    return "\n".join(lines)


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; print the table (and write JSON with --out)."""
    args = parse_args(argv)
    result = run(args)
    return print_and_save(format_report(result), result, args.out)


if __name__ == "__main__":
    sys.exit(main())
