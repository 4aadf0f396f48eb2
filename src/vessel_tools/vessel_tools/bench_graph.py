"""The graph half of ``./vessel bench``: the nodes as processes, the camera replaying a bag, and the figures.

``GraphSession`` starts detector, tracker, fuser and gps_publisher once and, per round, the camera replaying the
bag at rate 0 (the next frame goes when the detections of the previous one arrive); an in-process
``GraphWatcher`` notes when each message of a frame was published and arrived. ``graph_figures`` turns that
into frames/s end to end, latencies and per-stage times.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vessel_bringup.graph import GRAPH_NODES, GraphRunner
from vessel_bringup.graph_watcher import (
    CHAIN,
    DETECTIONS_TOPIC,
    FIX_TOPIC,
    IMAGE_TOPIC,
    SCREEN_TOPIC,
    TRACKS_TOPIC,
    ArrivalLog,
    GraphWatcher,
)
from vessel_common.errors import VesselError
from vessel_tools.bench_report import log, summary_ms
from vessel_tools.proc_monitor import NodeUsage, ProcMonitor, node_pid

STAGES = (
    ("camera -> detector", IMAGE_TOPIC, DETECTIONS_TOPIC),
    ("detector -> tracker", DETECTIONS_TOPIC, SCREEN_TOPIC),
    ("tracker -> fuser", SCREEN_TOPIC, TRACKS_TOPIC),
    ("fuser -> gps_publisher", TRACKS_TOPIC, FIX_TOPIC),
)
"""Per-stage time: from the publication of one topic to the publication of the next, same frame.

"camera -> detector" is the image's transport to the detector, its decoding, detection and the publication
of the detections.
"""

CAMERA_ACK_TIMEOUT_S = 10.0
"""The camera sends the next frame after this long without detections (a lost frame); counted, reported."""
CONNECT_TIMEOUT_S = 90.0
END_SETTLE_S = 3.0


class GraphError(VesselError):
    """A node of the graph died or the graph delivered no frame; the message holds the node's log tail."""


@dataclass
class GraphRun:
    """What the watcher saw and /proc said while the graph ran its rounds."""

    log: ArrivalLog
    warmup: int
    requested: int
    usage: list[NodeUsage]
    diagnostics: dict[str, dict[str, str]]
    fixes_with_position: int
    statuses: dict[str, int]
    watcher_usage: NodeUsage | None


def rounds_of(log: ArrivalLog) -> list[list[tuple[int, int]]]:
    """The frames of each round in the order they were sent.

    Every round replays the same (restamped when looping, so unique) stamps from the start of the bag, so a
    frame's occurrence count is its round.
    """
    by_round: dict[int, list[tuple[int, int]]] = {}
    for key in log.frames():
        by_round.setdefault(key[0], []).append(key)
    return [by_round[r] for r in sorted(by_round)]


def measured_frames(log: ArrivalLog, warmup: int) -> list[list[tuple[int, int]]]:
    """Per round, the frames after its warm-up ones."""
    return [frames[warmup:] for frames in rounds_of(log)]


def graph_figures(run: GraphRun) -> dict[str, object]:
    """Frames/s end to end, latency (arrival and publish based), per-stage times, the camera's turnaround."""
    log = run.log
    per_round = measured_frames(log, run.warmup)
    frames = [key for keys in per_round for key in keys]
    tracks = log.by_topic[TRACKS_TOPIC]
    out_frames = [key for key in frames if key in tracks]
    empty = summary_ms([])
    figures: dict[str, object] = {
        "frames_measured": len(out_frames),
        "frames_requested": run.requested,
        "graph_fps": float("nan"),
        "graph_fps_per_round": [],
        "graph_wall_s": float("nan"),
        "graph_interval_ms": empty,
        "latency_fix_ms": empty,
        "latency_tracks_ms": empty,
        "latency_fix_published_ms": empty,
        "stages_ms": {name: empty for name, _, _ in STAGES},
        "camera_turnaround_ms": empty,
        "counts": {topic: log.count(topic) for topic in CHAIN},
        "fixes_with_position": run.fixes_with_position,
    }
    if not out_frames:
        return figures
    figures.update(_rate_figures(log, per_round))

    def between(source: str, target: str, use: str) -> list[float]:
        a, b = log.by_topic[source], log.by_topic[target]
        return [(getattr(b[k], use) - getattr(a[k], use)) / 1e9 for k in frames if k in a and k in b]

    figures["latency_fix_ms"] = summary_ms(between(IMAGE_TOPIC, FIX_TOPIC, "received_ns"))
    figures["latency_tracks_ms"] = summary_ms(between(IMAGE_TOPIC, TRACKS_TOPIC, "received_ns"))
    figures["latency_fix_published_ms"] = summary_ms(between(IMAGE_TOPIC, FIX_TOPIC, "published_ns"))
    figures["stages_ms"] = {name: summary_ms(between(a, b, "published_ns")) for name, a, b in STAGES}
    return figures


def _rate_figures(log: ArrivalLog, per_round: list[list[tuple[int, int]]]) -> dict[str, object]:
    """Frames/s out of the fuser (overall and per round), the interval between outputs, the camera's turnaround.

    A round's wall time runs from the arrival of its first measured image to that of its last track array.
    """
    images = log.by_topic[IMAGE_TOPIC]
    detections = log.by_topic[DETECTIONS_TOPIC]
    tracks = log.by_topic[TRACKS_TOPIC]
    walls, outs, intervals, turnaround = [], [], [], []
    for sent, measured in zip(rounds_of(log), per_round, strict=True):
        out = [key for key in measured if key in tracks]
        if not out:
            continue
        first = measured[0]
        if first in images:
            start_ns = images[first].received_ns
        else:  # the watcher missed that image (best effort): it left the camera after the previous frame's output
            earlier = [tracks[k].received_ns for k in sent[: sent.index(first)] if k in tracks]
            start_ns = max(earlier) if earlier else min(tracks[k].received_ns for k in out)
        walls.append((max(tracks[k].received_ns for k in out) - start_ns) / 1e9)
        outs.append(len(out))
        arrivals = sorted(tracks[k].received_ns for k in out)
        intervals += list(np.diff(arrivals) / 1e9)
        # The camera's part of each frame period: from one frame's detections to the next image's publication.
        turnaround += [
            (images[nxt].published_ns - detections[cur].published_ns) / 1e9
            for cur, nxt in zip(sent, sent[1:], strict=False)
            if cur in detections and nxt in images and nxt in measured
        ]
    total_wall = sum(walls)
    return {
        "graph_wall_s": total_wall,
        "graph_fps": sum(outs) / total_wall if total_wall > 0 else float("nan"),
        "graph_fps_per_round": [n / w if w > 0 else float("nan") for n, w in zip(outs, walls, strict=True)],
        "graph_interval_ms": summary_ms(intervals),
        "camera_turnaround_ms": summary_ms(turnaround),
    }


class GraphSession:
    """The graph as separate processes, started once; the camera replays the bag once per round.

    ``start`` brings up detector, tracker, fuser and gps_publisher and waits until they and the watcher are
    connected; ``run_round`` starts the camera at rate 0 for ``warmup + frames`` frames and waits until they
    came out of the fuser; ``stop`` stops every node (SIGINT).
    """

    def __init__(self, bag: Path, params_files: list[Path], frames_in_bag: int, warmup: int, domain_id: int,
                 log_dir: Path, frame_timeout_s: float, frames_in_flight: int = 1):
        self.bag = bag
        self.frames_in_flight = frames_in_flight
        self.frames_in_bag = frames_in_bag
        self.warmup = warmup
        self.domain_id = domain_id
        self.log_dir = log_dir
        self.frame_timeout_s = frame_timeout_s
        self.nodes = {node.name: node for node in GRAPH_NODES}
        self.runner = GraphRunner(params_files, log_dir=log_dir)
        self.watcher: GraphWatcher | None = None
        self.monitor = ProcMonitor()
        self.requested = 0
        self.statuses: dict[str, int] = {}

    def start(self) -> None:
        """Start the nodes but the camera, consumers first, and wait until everything is connected."""
        self.watcher = GraphWatcher(self.domain_id, log_frames=True)
        for name in ("gps_publisher", "fuser", "tracker", "detector"):
            # the detector keeps as many images waiting as the camera sends ahead, so none is replaced
            overrides = {"images_waiting": self.frames_in_flight} if name == "detector" else None
            started = self.runner.start(self.nodes[name], overrides)
            self.monitor.add(name, node_pid(started.process.pid, self.nodes[name].executable))
        log(f"started {', '.join(self.monitor.pids)}; waiting for the graph to connect (ROS_DOMAIN_ID "
            f"{self.domain_id}, logs in {self.log_dir})")
        deadline = time.monotonic() + CONNECT_TIMEOUT_S
        while not self.watcher.connected(with_recorder=False):
            self.watcher.spin(0.1)
            self._raise_if_failed()
            if time.monotonic() > deadline:
                raise GraphError(f"the graph did not connect within {CONNECT_TIMEOUT_S:.0f} s; node logs in "
                                 f"{self.log_dir}")

    def run_round(self, frames: int) -> int:
        """Replay ``warmup + frames`` frames as fast as the graph consumes them; frames out of the fuser."""
        watcher, monitor = self.watcher, self.monitor
        total = self.warmup + frames
        self.requested += frames
        images_before, tracks_before = watcher.log.count(IMAGE_TOPIC), watcher.log.count(TRACKS_TOPIC)
        previous = self.runner.running.get("camera")
        if previous is not None and previous.log_file is not None:
            previous.log_file.close()
        camera = self.runner.start(self.nodes["camera"], {
            "source": str(self.bag),
            "rate": 0.0,
            "loop": total > self.frames_in_bag,
            "loop_restamp": True,
            "max_frames": total,
            "exit_at_end": True,
            "ack_timeout_s": CAMERA_ACK_TIMEOUT_S,
            "frames_in_flight": self.frames_in_flight,
            "wait_for_subscribers": 2,  # the detector and the watcher
        })
        monitor.add("camera", node_pid(camera.process.pid, self.nodes["camera"].executable))
        progress = Progress(total)
        last_count, last_progress = -1, time.monotonic()
        while True:
            watcher.spin(0.05)
            if not monitor.window_open and watcher.log.count(IMAGE_TOPIC) - images_before > self.warmup:
                monitor.open_window()
            count = watcher.log.count(TRACKS_TOPIC) - tracks_before
            if count != last_count:
                last_count, last_progress = count, time.monotonic()
                progress.show(count)
            if count >= total:
                break
            monitor.sample(min_interval_s=0.5)
            self._raise_if_failed()
            idle = time.monotonic() - last_progress
            camera_done = camera.process.poll() is not None
            if (camera_done and idle > END_SETTLE_S) or idle > self.frame_timeout_s:
                progress.done()
                log(f"only {count}/{total} frames came out of the fuser "
                    f"({'the camera finished' if camera_done else f'nothing for {self.frame_timeout_s:.0f} s'})")
                break
        monitor.close_window()
        progress.done()
        if count == 0:
            raise GraphError(f"no frame came out of the fuser (logs in {self.log_dir}); the end of the detector's "
                             "log:\n" + self.runner.log_tail("detector"))
        # The fixes of the last frames follow their track arrays; the camera exits by itself after the last frame
        # (stopping it in the middle of its exit would be a needless race).
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline and (
            camera.process.poll() is None or watcher.log.count(FIX_TOPIC) < watcher.log.count(TRACKS_TOPIC)
        ):
            watcher.spin(0.1)
        self._raise_if_failed()
        return count

    def result(self) -> GraphRun:
        """What was measured (call before ``stop``)."""
        self.watcher.spin(1.2)  # one more diagnostics period
        usage = self.monitor.usage()
        own = [u for u in usage if u.name == ProcMonitor.OWN]
        return GraphRun(self.watcher.log, self.warmup, self.requested,
                        [u for u in usage if u.name != ProcMonitor.OWN], dict(self.watcher.diagnostics),
                        self.watcher.fixes_with_position, self.statuses, own[0] if own else None)

    def stop(self) -> dict[str, int]:
        """Stop every node (SIGINT, then kill after a time-out) and the watcher; exit statuses."""
        try:
            self.statuses.update(self.runner.stop())
        finally:
            if self.watcher is not None:
                self.watcher.close()
        return self.statuses

    def _raise_if_failed(self) -> None:
        failed = self.runner.failed()
        if failed:
            name = failed[0]
            status = self.runner.running[name].process.returncode
            raise GraphError(f"node {name} exited with status {status}; the end of its log:\n"
                             f"{self.runner.log_tail(name)}")


class Progress:
    """Frames through the graph on stderr: one updating line on a terminal, a line every 10 s otherwise."""

    def __init__(self, total: int):
        self.total = total
        self.tty = sys.stderr.isatty()
        self._last = 0.0
        self._open = False

    def show(self, count: int) -> None:
        """Report ``count`` frames out of the fuser."""
        text = f"[bench] graph: {count}/{self.total} frames out of the fuser"
        if self.tty:
            print(f"\r{text}", end="", file=sys.stderr, flush=True)
            self._open = True
        elif time.monotonic() - self._last > 10.0 or count >= self.total:
            self._last = time.monotonic()
            print(text, file=sys.stderr, flush=True)

    def done(self) -> None:
        """End the updating line."""
        if self._open:
            print(file=sys.stderr)
