"""CPU time and memory of processes, read from ``/proc``: what the benchmarks report per node.

Linux only (``/proc/<pid>/stat`` and ``status``); a process that is gone reads as None, never as an error.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

CLOCK_TICKS_PER_S = os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True)
class ProcSample:
    """CPU seconds (user + system, all threads) and memory of one process at one wall time."""

    wall_s: float
    cpu_s: float
    rss_kb: int
    hwm_kb: int


def read_proc(pid: int) -> ProcSample | None:
    """Sample ``/proc/<pid>/stat`` and ``/proc/<pid>/status``; None when the process is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    # The command name (field 2) may hold spaces and parentheses: the fields after its closing one are fixed.
    fields_after_name = stat[stat.rindex(")") + 2 :].split()
    utime, stime = int(fields_after_name[11]), int(fields_after_name[12])  # fields 14 and 15 of proc(5)
    memory = {}
    for line in status.splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            memory[key] = int(value.split()[0])
    return ProcSample(time.monotonic(), (utime + stime) / CLOCK_TICKS_PER_S, memory.get("VmRSS", 0),
                      memory.get("VmHWM", 0))


def process_cmdline(pid: int) -> list[str]:
    """The command line of a process (empty when it is gone)."""
    try:
        raw = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return []
    return [part.decode(errors="replace") for part in raw.split(b"\0") if part]


def node_pid(pid: int, executable: str) -> int:
    """The pid of the process running ``executable``.

    That is ``pid`` itself for the project's console scripts (the shebang makes the kernel run the interpreter
    in that process); behind a wrapper (a shell script), the child that runs it.
    """
    if any(Path(arg).name == executable for arg in process_cmdline(pid)[:2]):
        return pid
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return pid
    for child in children:
        if any(Path(arg).name == executable for arg in process_cmdline(int(child))[:2]):
            return int(child)
    return pid


@dataclass
class NodeUsage:
    """CPU and memory of one node process over the measured frames and its whole life."""

    name: str
    pid: int
    cpu_s_total: float
    cpu_s_measured: float
    cpu_percent: float
    peak_mb: float
    rss_mb: float

    def as_dict(self) -> dict[str, float | int]:
        """JSON-ready figures."""
        return {"pid": self.pid, "cpu_s_total": self.cpu_s_total, "cpu_s_measured": self.cpu_s_measured,
                "cpu_percent": self.cpu_percent, "peak_mb": self.peak_mb, "rss_mb": self.rss_mb}


def node_usage(name: str, pid: int, start: ProcSample | None, end: ProcSample | None) -> NodeUsage | None:
    """CPU % between two samples (100 % = one core busy) and the peak memory at the end sample."""
    if end is None:
        return None
    measured = end.cpu_s - start.cpu_s if start is not None else float("nan")
    wall = end.wall_s - start.wall_s if start is not None else float("nan")
    percent = 100.0 * measured / wall if start is not None and wall > 0 else float("nan")
    return NodeUsage(name, pid, end.cpu_s, measured, percent, end.hwm_kb / 1024.0, end.rss_kb / 1024.0)




class ProcMonitor:
    """CPU time and memory of the node processes and of this one, from /proc, over the measured frames.

    A measuring window opens when a round's measured frames start and closes after its last one; the CPU time
    of every window adds up. Each process keeps its latest sample (one that has exited keeps the one before);
    a process replaced under the same name (the camera, once per round) adds its totals to its successor's.
    """

    OWN = "(bench watcher)"

    def __init__(self):
        self.pids: dict[str, int] = {}
        self.last: dict[str, ProcSample] = {}
        self._window_start: dict[str, ProcSample | None] | None = None
        self._measured_cpu: dict[str, float] = {}
        self._measured_wall: dict[str, float] = {}
        self._retired_cpu: dict[str, float] = {}
        self._retired_hwm: dict[str, int] = {}
        self._last_sample = 0.0

    def add(self, name: str, pid: int) -> None:
        """Watch a process (replacing, and keeping the totals of, an earlier one of the same name)."""
        previous = self.last.pop(name, None)
        if previous is not None:
            self._retired_cpu[name] = self._retired_cpu.get(name, 0.0) + previous.cpu_s
            self._retired_hwm[name] = max(self._retired_hwm.get(name, 0), previous.hwm_kb)
        self.pids[name] = pid

    def _all_pids(self) -> dict[str, int]:
        return {**self.pids, self.OWN: os.getpid()}

    @property
    def window_open(self) -> bool:
        """A measuring window is open."""
        return self._window_start is not None

    def open_window(self) -> None:
        """Measured frames start now."""
        self._window_start = {name: read_proc(pid) for name, pid in self._all_pids().items()}
        self.sample()

    def sample(self, min_interval_s: float = 0.0) -> None:
        """A new sample of every process still there (at most every ``min_interval_s``)."""
        if time.monotonic() - self._last_sample < min_interval_s:
            return
        self._last_sample = time.monotonic()
        for name, pid in self._all_pids().items():
            value = read_proc(pid)
            if value is not None:
                self.last[name] = value

    def close_window(self) -> None:
        """The measured frames of this round are done: add the window's CPU time and wall time."""
        if self._window_start is None:
            return
        self.sample()
        for name, start in self._window_start.items():
            end = self.last.get(name)
            if start is not None and end is not None:
                self._measured_cpu[name] = self._measured_cpu.get(name, 0.0) + end.cpu_s - start.cpu_s
                self._measured_wall[name] = self._measured_wall.get(name, 0.0) + end.wall_s - start.wall_s
        self._window_start = None

    def usage(self) -> list[NodeUsage]:
        """Per process: CPU over the measured frames, total CPU and peak memory."""
        result = []
        for name, pid in self._all_pids().items():
            last = self.last.get(name)
            if last is None:
                continue
            cpu = self._measured_cpu.get(name, float("nan"))
            wall = self._measured_wall.get(name, float("nan"))
            result.append(NodeUsage(
                name, pid,
                cpu_s_total=self._retired_cpu.get(name, 0.0) + last.cpu_s,
                cpu_s_measured=cpu,
                cpu_percent=100.0 * cpu / wall if wall > 0 else float("nan"),
                peak_mb=max(self._retired_hwm.get(name, 0), last.hwm_kb) / 1024.0,
                rss_mb=last.rss_kb / 1024.0,
            ))
        return result
