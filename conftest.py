"""Fixtures shared by every test of the repository: shared data, the model, and ROS processes.

Tests that need the shared challenge data or the model skip with a message saying where they looked; tests that
need the built workspace skip when rclpy or vessel_msgs cannot be imported (run them through ``./vessel test``).
Every ROS test gets its own ``ROS_DOMAIN_ID`` and localhost-only discovery so parallel runs cannot talk to each
other.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent
INSTALL_DIR = REPO_ROOT / "ros2_ws" / "install"
# The tests' own synthetic cameras, frames and models (test/vessel_fixtures), which no package installs.
sys.path.insert(0, str(REPO_ROOT / "test"))


ROS_FIXTURES = {"ros_env", "ros_context", "start_node"}
DATA_FIXTURES = {"data_dir", "dataset", "model_path"}


@pytest.hookimpl(tryfirst=True)  # before ``-m`` deselects
def pytest_collection_modifyitems(config, items) -> None:
    """A test that takes a ROS or shared-data fixture carries that marker (``--fast`` deselects both)."""
    for item in items:
        used = set(getattr(item, "fixturenames", ()))
        if used & ROS_FIXTURES:
            item.add_marker(pytest.mark.ros)
        if used & DATA_FIXTURES:
            item.add_marker(pytest.mark.data)


def _shared_dir(env_var: str, relative: str) -> Path:
    explicit = os.environ.get(env_var)
    return Path(explicit) if explicit else (REPO_ROOT.parent / "shared" / relative)


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The challenge dataset folder (``$VESSEL_DATA`` or ``../shared/aitas``); skips the test when absent."""
    path = _shared_dir("VESSEL_DATA", "aitas")
    if not (path / "frames.csv").is_file():
        pytest.skip(f"challenge data not found at {path}: set VESSEL_DATA or put the dataset at ../shared/aitas")
    return path


@pytest.fixture(scope="session")
def dataset(data_dir):
    """The challenge dataset (``vessel_tools.calib.dataset.Dataset``) of ``data_dir``; skips when absent."""
    from vessel_tools.calib.dataset import Dataset

    return Dataset(data_dir)


@pytest.fixture(scope="session")
def shorecams_dir() -> Path:
    """The Shore Livecams webcam images (``$VESSEL_SHORECAMS`` or ``../shared/shorecams``); skips when absent."""
    path = _shared_dir("VESSEL_SHORECAMS", "shorecams")
    if not (path / "images").is_dir() or not (path / "labels").is_dir():
        pytest.skip(f"Shore Livecams images not found at {path}: set VESSEL_SHORECAMS or put them at "
                    "../shared/shorecams")
    return path


@pytest.fixture(scope="session")
def model_path() -> Path:
    """The YOLOX-Nano ONNX model (``$VESSEL_MODEL`` or ``../shared/models``); skips the test when absent."""
    path = Path(os.environ.get("VESSEL_MODEL") or REPO_ROOT.parent / "shared/models/yolox_nano/yolox_nano.onnx")
    if not path.is_file():
        pytest.skip(f"detector model not found at {path}: set VESSEL_MODEL or put it at ../shared/models")
    return path


def _ros_available() -> str | None:
    try:
        import rclpy  # noqa: F401

        import vessel_msgs.msg  # noqa: F401
    except ImportError as error:
        return f"ROS 2 workspace not sourced ({error}): run the tests with ./vessel test"
    return None


@pytest.fixture
def ros_env(monkeypatch) -> dict[str, str]:
    """Environment for ROS processes of one test: a private domain id, localhost-only discovery."""
    reason = _ros_available()
    if reason:
        pytest.skip(reason)
    domain_id = str(random.randint(1, 100))
    monkeypatch.setenv("ROS_DOMAIN_ID", domain_id)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("PYTHONUNBUFFERED", "1")
    return dict(os.environ)


@pytest.fixture
def ros_context(ros_env) -> Iterator[object]:
    """An initialised rclpy context in the test's domain; shut down after the test."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


def executable_path(package: str, executable: str) -> Path:
    """Where colcon installed a node's console script (what ``ros2 run`` starts)."""
    return INSTALL_DIR / package / "lib" / package / executable


def interrupt(process: subprocess.Popen, timeout_s: float = 10.0) -> int:
    """SIGINT like Ctrl-C, wait, kill if it hangs; the exit status."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    return process.returncode


class NodeProcess:
    """A node started as its own process, as ``ros2 run`` would; stopped with SIGINT like Ctrl-C."""

    def __init__(self, package: str, executable: str, args: list[str], env: dict[str, str], log_path: Path):
        path = executable_path(package, executable)
        if not path.is_file():
            pytest.fail(f"{path} is not installed: run ./vessel setup")
        self.name = f"{package}/{executable}"
        self.log_path = log_path
        self._log = open(log_path, "w")
        self.process = subprocess.Popen(
            [str(path), *args], env=env, stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True
        )

    def output(self) -> str:
        """Everything the process printed so far (all of it once stopped)."""
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def stop(self, timeout_s: float = 10.0) -> int:
        """SIGINT, wait, and return the exit status (killing it if it hangs)."""
        status = interrupt(self.process, timeout_s)
        self._log.close()
        return status


@pytest.fixture
def start_node(ros_env, tmp_path) -> Iterator[object]:
    """Factory: ``start_node(package, executable, *args)`` starts a node process; all are stopped after."""
    started: list[NodeProcess] = []

    def start(package: str, executable: str, *args: str, env: dict[str, str] | None = None) -> NodeProcess:
        log_path = tmp_path / f"{package}.{executable}.{len(started)}.log"
        node = NodeProcess(package, executable, list(args), env or ros_env, log_path)
        started.append(node)
        return node

    yield start
    for node in started:
        node.stop()


def _wait_until(predicate, timeout_s: float, poll_s: float = 0.05, spin=None) -> bool:
    """Poll ``predicate`` until true or ``timeout_s``; ``spin`` (a callable) runs between polls."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        if spin is not None:
            spin()
        else:
            time.sleep(poll_s)
    return bool(predicate())


def ask_service(client, request, wait, timeout_s: float = 30.0, retry_s: float = 5.0):
    """The response of a read-only service (state, parameters), asked again when an answer goes missing.

    Under load the first response after a client matched a service can be lost: the service's response writer has
    not matched the client's reader yet (rmw_fastrtps waits a little, then drops it). A request that changes
    nothing may simply be sent again; never use this for one that does (a lifecycle transition).
    ``wait(predicate, seconds)`` spins the caller's executor.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        future = client.call_async(request)
        if wait(future.done, max(0.0, min(retry_s, deadline - time.monotonic()))):
            return future.result()
        client.remove_pending_request(future)
    raise AssertionError(f"no answer from {client.srv_name} within {timeout_s:g} s")


@pytest.fixture(name="ask_service")
def ask_service_fixture():
    """``ask_service(client, request, wait)``: a read-only service's response, asked again if it goes missing."""
    return ask_service


@pytest.fixture(name="interrupt")
def interrupt_fixture():
    """``interrupt(process, timeout_s)``: SIGINT like Ctrl-C, wait, kill if it hangs; the exit status."""
    return interrupt


@pytest.fixture
def wait_until():
    """``wait_until(predicate, timeout_s, spin=callable)``: poll instead of sleeping (DDS matching takes seconds)."""
    return _wait_until


@pytest.fixture
def python_exe() -> str:
    """The interpreter running the tests (the project's .venv under ./vessel test)."""
    return sys.executable
