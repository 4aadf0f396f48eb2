"""CPU time, memory and the node's own pid, read from /proc (what the benchmarks report per node)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from vessel_tools import proc_monitor


def test_read_proc_counts_cpu_time_and_memory_of_a_process():
    before = proc_monitor.read_proc(os.getpid())
    deadline = time.process_time() + 0.3
    while time.process_time() < deadline:
        pass
    after = proc_monitor.read_proc(os.getpid())
    assert before is not None and after is not None
    assert after.cpu_s - before.cpu_s >= 0.2
    assert after.hwm_kb >= after.rss_kb > 1000
    assert proc_monitor.read_proc(2**22 + 12345) is None  # above pid_max: no such process


def _wait_for(predicate, timeout_s=10.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return predicate()


def _runs_fake_node(pid: int) -> bool:
    command = proc_monitor.process_cmdline(pid)
    return len(command) >= 2 and Path(command[1]).name == "fake_node"


def test_node_pid_is_the_console_script_process_or_the_child_of_a_wrapper(tmp_path):
    script = tmp_path / "fake_node"
    script.write_text(f"#!{sys.executable}\nimport time\ntime.sleep(30)\n")
    script.chmod(0o755)
    wrapper = tmp_path / "wrapper.sh"
    wrapper.write_text(f"#!/bin/sh\n{script}\n")  # no exec: the node runs as the shell's child
    wrapper.chmod(0o755)
    direct = subprocess.Popen([str(script)])
    wrapped = subprocess.Popen([str(wrapper)])
    try:
        assert proc_monitor.node_pid(direct.pid, "fake_node") == direct.pid
        # Until the kernel has run the shebang's interpreter, /proc/PID/cmdline is empty or the parent's.
        assert _wait_for(lambda: _runs_fake_node(direct.pid))
        assert _wait_for(lambda: proc_monitor.node_pid(wrapped.pid, "fake_node") != wrapped.pid)
        child = proc_monitor.node_pid(wrapped.pid, "fake_node")
        assert _wait_for(lambda: _runs_fake_node(child))
    finally:
        child = proc_monitor.node_pid(wrapped.pid, "fake_node")
        if child != wrapped.pid:
            os.kill(child, 9)
        for process in (direct, wrapped):
            process.kill()
            process.wait()
