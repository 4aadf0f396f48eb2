"""run: how a node process ends: its own exit status when it finishes, 2 and one line on a bad start, help alone."""

from __future__ import annotations

import subprocess
import sys

import pytest

PROBE = """
import sys
from rclpy.node import Node
from vessel_common.errors import DataError
from vessel_common.run import run_node

class Finishing(Node):
    '''Finishes at its first timer tick with status 3 (a camera at the end of its bag, with frames lost).'''

    def __init__(self):
        super().__init__("finishing")
        self.finished = False
        self.create_timer(0.01, self._tick)

    def _tick(self):
        self.exit_status = 3
        self.finished = True

class Refusing(Node):
    def __init__(self):
        super().__init__("refusing")
        raise DataError("no source given; set -p source:=PATH")

class Closing(Finishing):
    def close(self):
        print("closed")

sys.exit(run_node({"finishing": Finishing, "refusing": Refusing, "closing": Closing}[sys.argv[1]], sys.argv[1:]))
"""


def _run(ros_env, *args):
    return subprocess.run([sys.executable, "-c", PROBE, *args], env=ros_env, capture_output=True, text=True,
                          timeout=60)


@pytest.mark.ros
def test_a_node_that_finishes_ends_with_its_exit_status_and_is_closed(ros_env):
    done = _run(ros_env, "finishing")
    assert done.returncode == 3, done.stderr
    closed = _run(ros_env, "closing")
    assert closed.returncode == 3 and closed.stdout.strip() == "closed", closed.stderr


@pytest.mark.ros
def test_a_configuration_error_is_one_line_and_status_2(ros_env):
    done = _run(ros_env, "refusing")
    assert done.returncode == 2
    assert done.stderr.strip() == "error: no source given; set -p source:=PATH"


@pytest.mark.ros
def test_help_starts_nothing_and_malformed_ros_arguments_are_one_line(ros_env):
    shown = _run(ros_env, "refusing", "--help")  # the node would refuse to start: it is never made
    assert shown.returncode == 0 and shown.stdout.startswith("usage: refusing [-h] [--ros-args"), shown.stderr
    bad = _run(ros_env, "finishing", "--ros-args", "-p", "gate_px:=")
    errors = [line for line in bad.stderr.splitlines() if line.startswith("error:")]
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert len(errors) == 1 and errors[0].startswith("error: cannot start:"), bad.stderr
