"""The README's ``ros2`` lines, run with the real ``ros2`` command line (ros2cli, vendored in third_party/ros2).

``./vessel setup`` builds the jazzy ros2cli into the workspace, so these run in CI. On a machine where ``ros2``
is missing (a workspace built without third_party/ros2) they skip, saying so. The launch file has its own test
(test_launch_graph.py).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

pytestmark = [pytest.mark.ros]

REPO = Path(__file__).resolve().parents[1]
GRAPH_FILE = REPO / "config" / "aitas.yaml"
CALIBRATION = REPO / "config" / "aitas_camera.yaml"


@pytest.fixture
def ros2(ros_env):
    """``ros2(*args)``: the command's CompletedProcess, run in the test's ROS domain without the CLI daemon."""
    if shutil.which("ros2", path=ros_env.get("PATH")) is None:
        pytest.skip("no `ros2` command on PATH: ./vessel setup builds it from third_party/ros2 into ros2_ws")

    def run(*args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess:
        return subprocess.run(["ros2", *args], env=ros_env, capture_output=True, text=True, timeout=timeout_s,
                              cwd=REPO)

    return run


def _until_answered(ros2, *args: str, attempts: int = 20) -> subprocess.CompletedProcess:
    """A node started a moment ago may not be discovered yet: ask again until it answers."""
    done = ros2(*args)
    for _ in range(attempts):
        if done.returncode == 0 and "not found" not in done.stdout + done.stderr:
            break
        done = ros2(*args)
    return done


def test_pkg_executables_lists_the_nodes(ros2):
    done = ros2("pkg", "executables", "vessel_track")
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n")[:3] == ["vessel_track fuser", "vessel_track gps_publisher", "vessel_track tracker"]


def test_interface_show_finds_the_messages_and_their_dependencies(ros2):
    """`Unknown package 'std_msgs'` here meant the venv's ROS packages were missing from AMENT_PREFIX_PATH."""
    done = ros2("interface", "show", "vessel_msgs/msg/Detection2DArray")
    assert done.returncode == 0, done.stderr
    assert "std_msgs/Header header" in done.stdout and "Detection2D[] detections" in done.stdout


def test_a_node_override_wins_over_the_files_and_the_dump_reloads(ros2, start_node, tmp_path):
    """`ros2 run … --params-file config/aitas.yaml -p gate_px:=55.0`, then `ros2 param get` and `ros2 param dump`."""
    first = start_node("vessel_track", "tracker", "--ros-args", "--params-file", str(GRAPH_FILE),
                       "-p", "gate_px:=55.0")
    got = _until_answered(ros2, "param", "get", "--no-daemon", "/tracker", "gate_px")
    assert got.returncode == 0, got.stderr + first.output()
    assert "55.0" in got.stdout  # the file's tracker block says otherwise
    dumped = _until_answered(ros2, "param", "dump", "--no-daemon", "/tracker")
    assert dumped.returncode == 0, dumped.stderr
    parameters = yaml.safe_load(dumped.stdout)["/tracker"]["ros__parameters"]
    assert parameters["gate_px"] == 55.0 and len(parameters) > 10
    assert first.stop() == 0
    dump_file = tmp_path / "tracker.yaml"
    dump_file.write_text(dumped.stdout)
    again = start_node("vessel_track", "tracker", "--ros-args", "--params-file", str(dump_file))
    redumped = _until_answered(ros2, "param", "dump", "--no-daemon", "/tracker")
    assert redumped.returncode == 0, redumped.stderr + again.output()
    assert yaml.safe_load(redumped.stdout) == yaml.safe_load(dumped.stdout)


@pytest.mark.parametrize("override, expected", [("gate_pxx:=50.0", "did you mean gate_px"),
                                                ("gate_px:=-5.0", "out of range")])
def test_ros2_run_refuses_a_bad_override_in_one_line(ros2, override, expected):
    done = ros2("run", "vessel_track", "tracker", "--ros-args", "--params-file", str(GRAPH_FILE), "-p", override,
                timeout_s=60.0)
    assert done.returncode == 2, done.stdout + done.stderr
    assert expected in done.stderr and "Traceback" not in done.stderr


def test_ros2_run_help_describes_the_node_without_starting_it(ros2, ros_env, tmp_path):
    """`recorder -h` used to start recording into the current folder."""
    done = subprocess.run(["ros2", "run", "vessel_detect", "recorder", "-h"], capture_output=True, text=True,
                          timeout=60, cwd=tmp_path, env=ros_env)
    assert done.returncode == 0, done.stderr
    assert "usage" in done.stdout.lower() and not any(tmp_path.iterdir())


def test_ros2_lifecycle_drives_the_managed_detector(ros2, start_node):
    """`ros2 lifecycle set /detector configure`, then activate (detector_managed keeps the node name detector)."""
    node = start_node("vessel_detect", "detector_managed", "--ros-args", "--params-file", str(GRAPH_FILE),
                      "--params-file", str(CALIBRATION))
    state = _until_answered(ros2, "lifecycle", "get", "--no-daemon", "/detector")
    assert state.returncode == 0 and state.stdout.startswith("unconfigured"), state.stderr + node.output()
    for transition, reached in (("configure", "inactive"), ("activate", "active")):
        done = _until_answered(ros2, "lifecycle", "set", "--no-daemon", "/detector", transition)
        assert done.returncode == 0 and "Transitioning successful" in done.stdout, done.stderr + node.output()
        assert _until_answered(ros2, "lifecycle", "get", "--no-daemon", "/detector").stdout.startswith(reached)
