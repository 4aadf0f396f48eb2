"""``./vessel bench view``: what 20 clients of ``./vessel view`` cost the graph, in one run.

The graph (``bench_graph.GraphSession``: every node a process, the camera replaying a bag at rate 0, so the graph
runs as fast as it can) and ``./vessel view`` (its own process, the detector publishing its annotated image) are
started once. Rounds alternate without clients and with them (ABBA, so a drift of the shared machine's load weighs
on both alike): with clients, 19 WebSocket clients read every update and fetch each new image as the page does,
and one never reads at all (a stalled tab; its small socket buffer fills after a few updates). The figure is the
graph's frames per second out of the fuser, with clients against without, and their ratio. On a machine shared
with other work that ratio carries the other work's swings too, so the CPU seconds the graph, the view and the
clients used in each round are measured as well (``/proc``): what the clients add, against the graph's own.

    ./vessel bench view --frames 72 --rounds 2 --out out/bench/view.json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from collections.abc import Sequence
from pathlib import Path

import yaml

from vessel_bringup.graph import default_calibration_file, default_params_file
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError, VesselError
from vessel_tools.bench import _domain_id, prepare_bag, read_bag_jpegs
from vessel_tools.bench_graph import GraphSession, graph_figures
from vessel_tools.bench_report import log, machine_info
from vessel_tools.proc_monitor import read_proc

RATIO_TARGET = 0.95
"""The graph with clients keeps at least this share of its frames per second without them."""


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command line of ``./vessel bench view``."""
    parser = argparse.ArgumentParser(prog="./vessel bench view", description=__doc__.split("\n\n")[0])
    parser.add_argument("--video", type=int, default=13, help="the video whose bag is replayed (default 13)")
    parser.add_argument("--frames", type=int, default=72, help="frames measured per round (looped past the bag)")
    parser.add_argument("--warmup", type=int, default=3, help="frames run first in each round and not measured")
    parser.add_argument("--rounds", type=int, default=2, help="pairs of rounds, without and with clients (ABBA)")
    parser.add_argument("--clients", type=int, default=20, help="WebSocket clients in a round with clients (one "
                        "of them never reads)")
    parser.add_argument("--data", type=Path, default=None, help="dataset to build the bag from if it is missing")
    parser.add_argument("--bags", type=Path, default=None, help="folder of the bags (default bags/)")
    parser.add_argument("--log-dir", type=Path, default=None, help="node logs (default: a temporary folder)")
    parser.add_argument("--out", type=Path, default=None, help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    if args.frames < 5 or args.rounds < 1 or args.clients < 2 or args.warmup < 0:
        raise DataError("--frames at least 5, --rounds at least 1, --clients at least 2, --warmup at least 0")
    return args


class ClientSwarm:
    """WebSocket clients of the view in a thread of their own: all but one read, one never does."""

    def __init__(self, port: int, count: int):
        self.port, self.count = port, count
        self.updates: list[int] = [0] * (count - 1)
        self.images: list[int] = [0] * (count - 1)
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="bench-clients", daemon=True)
        self._tasks: list[asyncio.Task] = []
        self._sockets: list = []

    def start(self) -> None:
        """Connect every client (returns once all are connected)."""
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self._connect(), self._loop).result(timeout=60)

    def stop(self) -> None:
        """Disconnect every client and end the thread."""
        asyncio.run_coroutine_threadsafe(self._close(), self._loop).result(timeout=60)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=10)

    async def _connect(self) -> None:
        from websockets.asyncio.client import connect

        uri = f"ws://127.0.0.1:{self.port}/ws"
        silent = socket.socket()
        silent.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        silent.connect(("127.0.0.1", self.port))
        self._sockets.append(await connect(uri, sock=silent, max_size=None))
        for index in range(self.count - 1):
            ws = await connect(uri, max_size=None)
            self._sockets.append(ws)
            self._tasks.append(asyncio.create_task(self._read(index, ws)))

    async def _read(self, index: int, ws) -> None:
        """Receive every update and image, as a page does (what a browser then draws costs this machine nothing)."""
        async for message in ws:
            if isinstance(message, str):
                self.updates[index] += 1
            else:
                self.images[index] += 1

    def cpu_s(self) -> float:
        """CPU seconds the clients' thread has used."""
        return asyncio.run_coroutine_threadsafe(_thread_time(), self._loop).result(timeout=10)

    async def _close(self) -> None:
        for task in self._tasks:
            task.cancel()
        for ws in self._sockets[1:]:
            await ws.close()
        self._sockets[0].transport.abort()  # the silent one vanishes without a closing handshake


async def _thread_time() -> float:
    return time.thread_time()


def cpu_s(pids: Sequence[int]) -> float:
    """CPU seconds (user + system) the processes have used (``/proc``); a process gone counts 0."""
    samples = [read_proc(pid) for pid in pids]
    return sum(sample.cpu_s for sample in samples if sample is not None)


def start_view(log_dir: Path, env: dict[str, str]) -> tuple[subprocess.Popen, int]:
    """``./vessel view --port 0`` as its own process, as a user runs it; it and its port."""
    log_path = log_dir / "view.log"
    process = subprocess.Popen([sys.executable, "-m", "vessel_tools.cli", "view", "--port", "0"], env=env,
                               stdout=open(log_path, "w"), stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        found = re.search(r"serving http://127\.0\.0\.1:(\d+)/", log_path.read_text())
        if found:
            return process, int(found.group(1))
        if process.poll() is not None:
            break
        time.sleep(0.1)
    process.kill()
    raise VesselError(f"./vessel view did not start; its output:\n{log_path.read_text()}")


def wait_until_view_sees_graph(port: int, timeout_s: float = 60.0) -> None:
    """Until the view receives the detector's reports (it is discovered and subscribed)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        state = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/state.json", timeout=10).read())
        if any("detector" in camera["status"]["nodes"] for camera in state["cameras"]):
            return
        time.sleep(0.2)
    raise VesselError(f"./vessel view saw no report of the detector within {timeout_s:g} s")


def run(args: argparse.Namespace) -> dict:
    """Start the graph and the view, run the rounds, and the figures."""
    bag = prepare_bag(args.video, args.data, args.bags)
    frames_in_bag = len(read_bag_jpegs(bag))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    domain_id = _domain_id()
    log_dir = args.log_dir or Path(tempfile.mkdtemp(prefix="vessel_bench_view_"))
    log_dir.mkdir(parents=True, exist_ok=True)
    annotated = log_dir / "view.yaml"
    annotated.write_text(yaml.safe_dump({"detector": {"ros__parameters": {"publish_annotated": True}}}))
    params = [default_params_file(), default_calibration_file(), annotated]
    session = GraphSession(bag, params, frames_in_bag, args.warmup, domain_id, log_dir, 60.0, frames_in_flight=2)
    plan = [kind for i in range(args.rounds) for kind in ((0, args.clients) if i % 2 == 0 else (args.clients, 0))]
    view, swarms, cpu = None, [], []
    try:
        session.start()
        view, port = start_view(log_dir, dict(os.environ))
        wait_until_view_sees_graph(port)
        log(f"graph and view started (ROS_DOMAIN_ID {domain_id}, logs in {log_dir}); rounds: "
            + ", ".join(f"{n} clients" for n in plan))
        for index, clients in enumerate(plan, start=1):
            cpu.append(_round(session, args.frames, port, clients, view.pid, swarms))
            log(f"round {index}/{len(plan)}: {clients} clients, {args.frames} frames; CPU s: view "
                f"{cpu[-1]['view_cpu_s']:.2f}, clients {cpu[-1]['clients_cpu_s']:.2f}")
        graph_run = session.result()
    finally:
        if view is not None and view.poll() is None:
            view.send_signal(2)
            view.wait(timeout=30)
        session.stop()
    fps = graph_figures(graph_run)["graph_fps_per_round"]
    return result(args, plan, fps, cpu, swarms, graph_run.diagnostics.get("view", {}), machine_info())


def _round(session: GraphSession, frames: int, port: int, clients: int, view_pid: int,
           swarms: list[ClientSwarm]) -> dict:
    """One round, with ``clients`` connected throughout; the CPU seconds the graph, the view and the clients used.

    CPU is the figure the machine's other load does not move: the graph's frames/s on a shared machine does.
    The graph's is its lasting nodes' (the camera is a new process each round).
    """
    swarm = ClientSwarm(port, clients) if clients else None
    if swarm is not None:
        swarm.start()
        swarms.append(swarm)
    graph_pids = [pid for name, pid in session.monitor.pids.items() if name != "camera"]
    graph_before, view_before = cpu_s(graph_pids), cpu_s([view_pid])
    clients_before = swarm.cpu_s() if swarm else 0.0
    session.run_round(frames)
    used = {"graph_cpu_s": cpu_s(graph_pids) - graph_before, "view_cpu_s": cpu_s([view_pid]) - view_before,
            "clients_cpu_s": swarm.cpu_s() - clients_before if swarm else 0.0}
    if swarm is not None:
        swarm.stop()
    return used


def result(args, plan: list[int], fps: list[float], cpu: list[dict], swarms: list[ClientSwarm], view_report: dict,
           machine: dict) -> dict:
    """The figures: frames/s per round, mean without and with clients, their ratio, what the clients got."""
    if len(fps) != len(plan):
        raise VesselError(f"{len(fps)} of {len(plan)} rounds delivered frames: see the node logs")
    without = statistics.mean(f for f, n in zip(fps, plan, strict=True) if n == 0)
    with_clients = statistics.mean(f for f, n in zip(fps, plan, strict=True) if n)
    updates = [u for s in swarms for u in s.updates]
    images = [i for s in swarms for i in s.images]
    return {
        "video": args.video, "frames_per_round": args.frames, "clients": args.clients,
        "rounds": [{"clients": n, "graph_fps": f, **c} for n, f, c in zip(plan, fps, cpu, strict=True)],
        "graph_fps_without_clients": without, "graph_fps_with_clients": with_clients,
        "ratio": with_clients / without, "target": RATIO_TARGET,
        "cpu_share_of_clients": _cpu_share(plan, cpu),
        "updates_per_reading_client_median": statistics.median(updates) if updates else 0,
        "images_per_reading_client_median": statistics.median(images) if images else 0,
        "view_dropped_updates": view_report.get("count.dropped_updates"),
        "machine": machine,
    }


def _cpu_share(plan: list[int], cpu: list[dict]) -> float:
    """What the clients add to the machine's work, as a share of the graph's CPU: (view's extra + clients') / graph.

    Per round, in CPU seconds: the view's with clients less its mean without, plus the clients' own.
    """
    view_without = statistics.mean(c["view_cpu_s"] for n, c in zip(plan, cpu, strict=True) if n == 0)
    extra = sum(c["view_cpu_s"] - view_without + c["clients_cpu_s"] for n, c in zip(plan, cpu, strict=True) if n)
    graph = sum(c["graph_cpu_s"] for n, c in zip(plan, cpu, strict=True) if n)
    return extra / graph if graph > 0 else float("nan")


def report(figures: dict) -> str:
    """The table ``./vessel bench view`` prints."""
    lines = [f"graph frames/s with {figures['clients']} WebSocket clients of ./vessel view (one never reading) "
             f"against none, video {figures['video']}, {figures['frames_per_round']} frames a round",
             "round  clients  graph frames/s  graph CPU s  view CPU s  clients CPU s"]
    lines += [f"{i:>5}  {r['clients']:>7}  {r['graph_fps']:>14.2f}  {r['graph_cpu_s']:>11.2f}  "
              f"{r['view_cpu_s']:>10.2f}  {r['clients_cpu_s']:>13.2f}" for i, r in enumerate(figures["rounds"], 1)]
    met = "met" if figures["ratio"] >= figures["target"] else "NOT met"
    lines += [f"without clients {figures['graph_fps_without_clients']:.2f} frames/s, with "
              f"{figures['clients']} clients {figures['graph_fps_with_clients']:.2f} frames/s: ratio "
              f"{figures['ratio']:.3f} (target >= {figures['target']:.2f}: {met})",
              f"CPU the clients add (the view's extra and their own) against the graph's: "
              f"{100 * figures['cpu_share_of_clients']:.1f} %",
              f"each reading client got {figures['updates_per_reading_client_median']:g} updates and "
              f"{figures['images_per_reading_client_median']:g} images (median); updates dropped for slow "
              f"clients (the view's count.dropped_updates): {figures['view_dropped_updates']}"]
    return "\n".join(lines)


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; print the table (and write ``--out``)."""
    args = parse_args(argv)
    try:
        import rclpy  # noqa: F401
        import websockets  # noqa: F401

        import vessel_msgs.msg  # noqa: F401
    except ImportError as error:
        raise VesselError(f"{error}: run ./vessel bench view (it sets the workspace up)") from None
    figures = run(args)
    print(report(figures))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
