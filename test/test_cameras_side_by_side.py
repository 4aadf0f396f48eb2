"""Several cameras in one ROS domain: each graph under its own namespace, no message of one reaching another."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from vessel_fixtures.challenge_bags import build_video_bags

pytestmark = [pytest.mark.ros, pytest.mark.data, pytest.mark.slow]


@pytest.fixture(scope="module")
def two_bags(data_dir, tmp_path_factory):
    return build_video_bags(data_dir, tmp_path_factory.mktemp("bags"), "13,14", timeout_s=600)


def _image_stamps(bag) -> set[int]:
    from vessel_detect.bag_reader import BagReader

    return {message.log_time_ns for message in BagReader(bag).messages(["/camera/image_raw/compressed"])}


def test_two_namespaced_graphs_in_one_domain_publish_each_its_own_fixes(two_bags, model_path, ros_env, ros_context,
                                                                        tmp_path):
    """``./vessel graph --namespace a`` on video 13 and ``--namespace b`` on video 14, at once, in one domain.

    A consumer sees ``/a/vessel/fix`` with video 13's frames only and ``/b/vessel/fix`` with video 14's, one fix
    per image; each graph runs on its own replay's clock (``/a/clock``, ``/b/clock``), and each recording holds its
    own graph's topics and ``/diagnostics`` only, in its own video's time.
    """
    import rclpy
    from sensor_msgs.msg import NavSatFix

    from vessel_common.qos import reliable_qos
    from vessel_detect.bag_reader import BagReader

    node = rclpy.create_node("side_by_side_consumer", context=ros_context)
    executor = rclpy.executors.SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    seen: dict[str, list[int]] = {"a": [], "b": []}
    for name in seen:
        node.create_subscription(NavSatFix, f"/{name}/vessel/fix", lambda fix, name=name: seen[name].append(
            fix.header.stamp.sec * 1_000_000_000 + fix.header.stamp.nanosec), reliable_qos(100))
    graphs = {}
    for name, video in (("a", 13), ("b", 14)):
        graphs[name] = subprocess.Popen(
            [sys.executable, "-m", "vessel_bringup.graph", "--namespace", name, "--source",
             str(two_bags / f"video_{video}"), "--rate", "0", "--exit-at-end", "--record", str(tmp_path / name),
             "--log-dir", str(tmp_path / "logs")], env=ros_env, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 400
        while any(graph.poll() is None for graph in graphs.values()) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        errors = {name: graph.communicate(timeout=60)[1] for name, graph in graphs.items()}
    finally:
        for graph in graphs.values():
            if graph.poll() is None:
                graph.kill()
        node.destroy_node()
    for name, video in (("a", 13), ("b", 14)):
        assert graphs[name].returncode == 0, errors[name][-3000:]
        assert f"namespace /{name}: the fix on /{name}/vessel/fix, the clock on /{name}/clock" in errors[name]
        images = _image_stamps(two_bags / f"video_{video}")
        assert sorted(seen[name]) == sorted(images), name  # every frame once, none of the other camera's
        recording = BagReader(tmp_path / name)
        for topic in ("/vessel/detections", "/vessel/tracks/screen", "/vessel/tracks", "/vessel/fix"):
            assert {m.log_time_ns for m in recording.messages([topic])} == images, (name, topic)
        # Its own /diagnostics only: the other graph's, in the other video's time, would stretch the recording.
        assert min(images) - 10e9 < recording.start_ns and recording.end_ns < max(images) + 10e9, name
        assert (tmp_path / "logs" / name / "tracker.log").is_file()
    assert not set(seen["a"]) & set(seen["b"])


def test_per_role_processes_keep_each_cameras_frames_and_restart_the_tracking_from_its_state_files(
        two_bags, model_path, ros_env, tmp_path):
    """``--cameras a=...,b=... --processes per-role --respawn``: 4 processes for 2 cameras, each camera's fixes its own.

    The host of both cameras' trackers, fusers and GPS publishers is killed with -9 mid-run: the runner restarts it,
    every tracker and fuser resumes from its own camera's state file, and fixes flow again for both cameras.
    """
    import signal

    from vessel_detect.bag_reader import BagReader

    logs, recording = tmp_path / "logs", tmp_path / "recording"
    cameras = f"a={two_bags / 'video_13'},b={two_bags / 'video_14'}"
    graph = subprocess.Popen([sys.executable, "-m", "vessel_bringup.graph", "--cameras", cameras, "--processes",
                              "per-role", "--rate", "3", "--exit-at-end", "--respawn", "--record", str(recording),
                              "--log-dir", str(logs)], env=ros_env, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 180
        while not all((logs / name / "camera.log").exists() and "publishing" in (
                logs / name / "camera.log").read_text(errors="replace") for name in ("a", "b")):
            assert time.monotonic() < deadline and graph.poll() is None, "the cameras did not start"
            time.sleep(0.5)
        time.sleep(15.0)  # some frames through both graphs
        marker = str(logs / "tracking.overrides.yaml")
        pids = subprocess.run(["pgrep", "-f", marker], capture_output=True, text=True).stdout.split()
        assert len(pids) == 1, pids
        os.kill(int(pids[0]), signal.SIGKILL)
        _, stderr = graph.communicate(timeout=300)
    finally:
        if graph.poll() is None:
            graph.kill()
    assert graph.returncode == 0, stderr[-3000:]
    assert "of 2 cameras in 4 processes (per-role)" in stderr  # 2 hosts and 2 recorders, then 2 cameras
    assert "tracking exited with status -9: restarting it" in stderr
    host_log = (logs / "tracking.log").read_text(errors="replace")
    for name in ("a", "b"):
        assert f"[{name}.tracker]: resumed from state file {logs / name / 'tracker.state'}" in host_log, name
        assert f"[{name}.fuser]: resumed from state file {logs / name / 'fuser.state'}" in host_log, name
    for name, video in (("a", 13), ("b", 14)):
        images = _image_stamps(two_bags / f"video_{video}")
        fixes = {m.log_time_ns for m in BagReader(recording / name).messages(["/vessel/fix"])}
        assert fixes <= images and max(fixes) == max(images), name  # its own frames, to the last one
        assert len(fixes) >= len(images) - 12, (name, len(fixes))  # a restart costs a few frames, not the rest
