"""The installed workspace: every node executable is where `ros2 run` looks, indexed, and starts and stops cleanly."""

from __future__ import annotations

import ast
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
INSTALL_DIR = REPO_ROOT / "ros2_ws" / "install"
PYTHON_PACKAGES = ("vessel_calib", "vessel_detect", "vessel_track", "vessel_bringup", "vessel_tools")
TOOLS_NOT_NODES = {("vessel_bringup", "graph"), ("vessel_bringup", "host")} | {("vessel_tools", tool) for tool in (
    "vessel", "demo", "bench", "eval", "pipeline", "fit", "bag_build", "view")}
"""Tools, and the host of other nodes (it starts nothing without its spec): help, not a node's start and stop."""


def declared_executables() -> list[tuple[str, str]]:
    """(package, executable) for every console script declared in the packages' setup.py files."""
    found = []
    for package in PYTHON_PACKAGES:
        tree = ast.parse((REPO_ROOT / "src" / package / "setup.py").read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Dict):
                for key, value in zip(node.keys, node.values, strict=True):
                    if isinstance(key, ast.Constant) and key.value == "console_scripts":
                        for item in value.elts:
                            found.append((package, item.value.split("=")[0].strip()))
    return found


EXECUTABLES = declared_executables()
CONTRACT = {
    ("vessel_tools", "calibrate"),
    ("vessel_detect", "camera"),
    ("vessel_detect", "detector"),
    ("vessel_track", "tracker"),
    ("vessel_track", "fuser"),
    ("vessel_track", "gps_publisher"),
}


def test_every_contract_executable_is_declared():
    assert CONTRACT <= set(EXECUTABLES)


@pytest.mark.parametrize(("package", "executable"), EXECUTABLES)
def test_executable_installed_and_indexed(package, executable):
    if not INSTALL_DIR.is_dir():
        pytest.skip("workspace not built: run ./vessel setup")
    path = INSTALL_DIR / package / "lib" / package / executable
    assert path.is_file() and os.access(path, os.X_OK), f"{path} missing: ros2 run {package} {executable} fails"
    marker = INSTALL_DIR / package / "share" / "ament_index" / "resource_index" / "packages" / package
    assert marker.is_file(), f"ament index marker missing for {package}"
    assert (INSTALL_DIR / package / "share" / package / "package.xml").is_file()


def test_vessel_msgs_is_indexed():
    if not INSTALL_DIR.is_dir():
        pytest.skip("workspace not built: run ./vessel setup")
    share = INSTALL_DIR / "vessel_msgs" / "share"
    assert (share / "ament_index" / "resource_index" / "packages" / "vessel_msgs").is_file()
    for name in ("Detection2DArray", "VesselTrackArray", "BoundingBox2D", "ObjectHypothesisWithPose"):
        assert (share / "vessel_msgs" / "msg" / f"{name}.msg").is_file()


def _node_arguments(package: str, executable: str, tmp_path: Path) -> list[str]:
    """The least a node needs to come up on a machine without the shared data."""
    if (package, executable) in (("vessel_detect", "camera"), ("vessel_detect", "camera_managed")):
        folder = tmp_path / "frames"
        folder.mkdir()
        for index in range(3):
            image = np.full((72, 128, 3), 40 * index, np.uint8)
            cv2.imwrite(str(folder / f"{index:05d}.jpg"), image)
        return ["--ros-args", "-p", f"source:={folder}", "-p", "rate:=1.0", "-p", "loop:=true"]
    if (package, executable) == ("vessel_detect", "recorder"):
        return ["--ros-args", "-p", f"output:={tmp_path / 'recording'}"]
    if (package, executable) == ("vessel_tools", "calibrate"):
        return ["--ros-args", "-p", f"out:={tmp_path / 'camera.yaml'}"]
    if executable in ("detector", "detector_managed", "fuser", "gps_publisher"):  # nodes that read the camera model
        return ["--ros-args", "--params-file", str(REPO_ROOT / "config" / "aitas_camera.yaml")]
    return ["--ros-args"]


@pytest.mark.ros
@pytest.mark.parametrize(("package", "executable"), [e for e in EXECUTABLES if e not in TOOLS_NOT_NODES])
def test_node_starts_and_stops_cleanly_on_sigint(package, executable, ros_env, ros_context, tmp_path, wait_until):
    """Up (visible in the ROS graph, or for the offline calibrate node, printing), a second, then Ctrl-C."""
    import rclpy

    path = INSTALL_DIR / package / "lib" / package / executable
    if not path.is_file():
        pytest.fail(f"{path} is not installed")
    if executable == "detector":
        model = REPO_ROOT.parent / "shared/models/yolox_nano/yolox_nano.onnx"
        if not model.is_file() and not os.environ.get("VESSEL_MODEL"):
            pytest.skip("the detector refuses to start without its model (../shared/models absent)")
    is_ros_node = executable != "calibrate"
    node_name = f"smoke_{executable}"
    args = _node_arguments(package, executable, tmp_path)
    if is_ros_node:
        args = [*args, "-r", f"__node:={node_name}"]
    process = subprocess.Popen([str(path), *args], env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               text=True, start_new_session=True)
    output: list[str] = []
    reader = threading.Thread(target=lambda: output.extend(process.stdout), daemon=True)
    reader.start()
    observer = rclpy.create_node("smoke_observer", context=ros_context)
    try:
        if is_ros_node:
            up = wait_until(lambda: node_name in observer.get_node_names() or process.poll() is not None, 60,
                            spin=lambda: time.sleep(0.1))
        else:
            up = wait_until(lambda: output or process.poll() is not None, 60)
        assert up, f"{package}/{executable} did not come up within 60 s:\n{''.join(output)}"
        assert process.poll() is None or process.returncode == 0, "".join(output)
        time.sleep(1.0)  # the contract: up for a second, then Ctrl-C
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
            pytest.fail(f"{package}/{executable} did not stop within 20 s of SIGINT:\n{''.join(output)}")
    finally:
        observer.destroy_node()
    reader.join(timeout=5)
    text = "".join(output)
    assert "Traceback" not in text, text
    assert process.returncode == 0, f"exit {process.returncode}:\n{text}"


@pytest.mark.ros
@pytest.mark.parametrize(("package", "executable"), [e for e in EXECUTABLES if e not in TOOLS_NOT_NODES])
@pytest.mark.parametrize("flag", ["-h", "--help"])
def test_help_prints_usage_and_starts_nothing(package, executable, flag, ros_env, tmp_path):
    """`recorder -h` used to start recording a bag into the current folder; every node ran on -h."""
    path = INSTALL_DIR / package / "lib" / package / executable
    done = subprocess.run([str(path), flag], env=ros_env, cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"usage: {executable}")  # calibrate is an argparse tool: no --ros-args
    assert "Traceback" not in done.stderr and list(tmp_path.iterdir()) == []


@pytest.mark.ros
@pytest.mark.parametrize(("package", "executable"),
                         sorted(e for e in TOOLS_NOT_NODES if e != ("vessel_bringup", "graph")))
def test_each_tool_script_answers_help(package, executable, ros_env, tmp_path):
    """`ros2 run vessel_tools demo --help` (and `vessel --help`): the tool's usage, nothing started or written."""
    path = INSTALL_DIR / package / "lib" / package / executable
    args = ["--help"] if executable not in ("fit",) else ["error-model", "--help"]
    done = subprocess.run([str(path), *args], env=ros_env, cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "usage:" in done.stdout and "Traceback" not in done.stderr and list(tmp_path.iterdir()) == []



RUNTIME_PACKAGES = ("vessel_msgs", "vessel_common", "vessel_calib", "vessel_track")


@pytest.mark.slow
def test_the_runtime_builds_and_imports_alone(tmp_path):
    """``colcon build --packages-up-to vessel_track``: what a robot installs, without bringup or the offline tools.

    The built nodes import in an environment that has only that install (and the Python packages of the venv).
    """
    venv = REPO_ROOT / ".venv"
    if not (venv / "bin" / "colcon").is_file():
        pytest.skip("no colcon in .venv: run ./vessel setup")
    env = {"HOME": os.environ.get("HOME", "/root"), "PATH": f"{venv / 'bin'}:/usr/bin:/bin",
           "AMENT_PREFIX_PATH": str(venv), "CMAKE_PREFIX_PATH": str(venv), "LD_LIBRARY_PATH": str(venv / "lib"),
           "PYTHONWARNINGS": "ignore", "VIRTUAL_ENV": str(venv)}
    build = subprocess.run(
        ["colcon", "--log-base", str(tmp_path / "log"), "build", "--base-paths", "src", "third_party/ros2",
         "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install"),
         "--metas", "colcon.meta", "--packages-up-to", "vessel_track", "--event-handlers", "console_direct-",
         "--cmake-args", f"-DPython3_EXECUTABLE={venv / 'bin' / 'python'}", "-DPython3_FIND_VIRTUALENV=ONLY"],
        cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    assert sorted(p.name for p in (tmp_path / "install").iterdir() if p.is_dir()) == sorted(RUNTIME_PACKAGES)
    check = ("import importlib.util, vessel_track.tracker_node, vessel_track.fuser_node, "
             "vessel_track.gps_publisher_node; assert importlib.util.find_spec('vessel_tools') is None; "
             "assert importlib.util.find_spec('vessel_detect') is None; print(vessel_track.__file__)")
    imported = subprocess.run(["bash", "-c", f"source {tmp_path / 'install' / 'setup.bash'} && python -c \"{check}\""],
                              env=env, capture_output=True, text=True, timeout=120)
    assert imported.returncode == 0, imported.stderr[-2000:]
    assert str(tmp_path / "install") in imported.stdout
