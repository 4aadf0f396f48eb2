"""``ros2 launch vessel_bringup vessel_graph.launch.py`` with the real ``ros2`` command line, launch and launch_ros.

They are not on PyPI: ``./vessel setup`` builds their jazzy sources (vendored in third_party/ros2) into the
workspace, so this runs in CI. A workspace built without them (or without a ROS 2 install sourced) skips, saying so.
"""

from __future__ import annotations

import shutil
import subprocess
import time

import pytest

from vessel_fixtures.challenge_bags import build_video_bags

pytestmark = [pytest.mark.ros, pytest.mark.data, pytest.mark.slow]


def _launch_available() -> str | None:
    try:
        import launch  # noqa: F401
        import launch_ros  # noqa: F401
    except ImportError as error:
        return (f"launch/launch_ros are not importable ({error}); they are not on PyPI: source a ROS 2 Jazzy install "
                "(or a colcon build of ros2/ros2cli, ros2/launch and ros2/launch_ros) to run this test")
    if shutil.which("ros2") is None:
        return "no `ros2` command on PATH (ros2cli with ros2launch): source a ROS 2 Jazzy install to run this test"
    return None


@pytest.fixture(scope="module")
def video_bag(data_dir, tmp_path_factory):
    return build_video_bags(data_dir, tmp_path_factory.mktemp("bags"), "13") / "video_13"


@pytest.mark.parametrize("managed", ["false", "true"])
def test_the_readme_launch_line_publishes_fixes_at_the_rate_given(managed, ros_env, ros_context, video_bag,
                                                                  model_path, tmp_path, wait_until, interrupt):
    """managed:=true: the detector is a lifecycle node that the launch configures and activates."""
    reason = _launch_available()
    if reason:
        pytest.skip(reason)
    import rclpy
    from sensor_msgs.msg import NavSatFix

    from vessel_common.qos import reliable_qos

    repo = __import__("pathlib").Path(__file__).resolve().parents[1]
    log = open(tmp_path / "launch.log", "w")
    launch = subprocess.Popen(
        ["ros2", "launch", "vessel_bringup", "vessel_graph.launch.py", f"params_file:={repo}/config/aitas.yaml",
         f"calib_file:={repo}/config/aitas_camera.yaml", f"source:={video_bag}", "rate:=4.0", f"managed:={managed}"],
        env=ros_env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    probe = rclpy.create_node("launch_probe", context=ros_context)
    fixes: list[NavSatFix] = []
    probe.create_subscription(NavSatFix, "/vessel/fix", fixes.append, reliable_qos(100))
    executor = rclpy.executors.SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    try:
        arrived = wait_until(lambda: len(fixes) >= 3 or launch.poll() is not None, 120,
                             spin=lambda: executor.spin_once(timeout_sec=0.1))
        output = (tmp_path / "launch.log").read_text(errors="replace")
        assert arrived and fixes, f"no /vessel/fix from the launch:\n{output[-3000:]}"
        assert f"publishing 36 frames of bag {video_bag} at 4x" in output  # rate:= took effect
        assert fixes[0].header.stamp.sec > 1_500_000_000
        assert ("detector_managed" in output and "camera_managed" in output) == (managed == "true")
    finally:
        probe.destroy_node()
        interrupt(launch, 30.0)
        log.close()
    time.sleep(0.5)


def _kill_child(launch: subprocess.Popen, node: str) -> None:
    """``kill -9`` the launched process of node ``node`` (a child of ``ros2 launch``)."""
    children = subprocess.run(["pgrep", "-P", str(launch.pid)], capture_output=True, text=True).stdout.split()
    pids = [pid for pid in children if f"__node:={node}\0" in
            __import__("pathlib").Path(f"/proc/{pid}/cmdline").read_text(errors="replace")]
    assert len(pids) == 1, (node, pids)
    subprocess.run(["kill", "-9", pids[0]], check=True)


@pytest.mark.parametrize("managed", ["false", "true"])
def test_respawn_restarts_a_killed_camera_and_recorder_which_carry_on(managed, ros_env, ros_context, video_bag,
                                                                     model_path, tmp_path, wait_until, interrupt):
    """Issue 48: ``respawn:=true`` never restarted the camera (26 of 36 frames lost), and had no recorder.

    The camera killed after 8 fixes carries on after its last frame, the recorder killed after 16 into ``RECORD.1``:
    from the first fix on, every frame's fix comes once, in order. A managed camera is configured and activated
    again.
    """
    reason = _launch_available()
    if reason:
        pytest.skip(reason)
    import rclpy
    from sensor_msgs.msg import NavSatFix

    from vessel_common.qos import reliable_qos
    from vessel_detect.bag_messages import ns_of_stamp
    from vessel_detect.bag_reader import BagReader
    from vessel_detect.resume_files import recording_parts

    repo = __import__("pathlib").Path(__file__).resolve().parents[1]
    recording = tmp_path / "recording"
    log = open(tmp_path / "launch.log", "w")
    launch = subprocess.Popen(
        ["ros2", "launch", "vessel_bringup", "vessel_graph.launch.py", f"params_file:={repo}/config/aitas.yaml",
         f"calib_file:={repo}/config/aitas_camera.yaml", f"source:={video_bag}", "rate:=4.0", "respawn:=true",
         f"record:={recording}", f"managed:={managed}"], env=ros_env, stdout=log, stderr=subprocess.STDOUT,
        start_new_session=True)
    probe = rclpy.create_node("launch_probe", context=ros_context)
    fixes: list[int] = []
    probe.create_subscription(NavSatFix, "/vessel/fix", lambda fix: fixes.append(ns_of_stamp(fix.header.stamp)),
                              reliable_qos(100))
    executor = rclpy.executors.SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    with BagReader(video_bag) as reader:
        images = [ns_of_stamp(m.header.stamp) for _, m in reader.read_topic("/camera/image_raw/compressed")]
    try:
        for node, after in (("camera", 8), ("recorder", 16)):
            assert wait_until(lambda: len(fixes) >= after or launch.poll() is not None, 180,  # noqa: B023
                              spin=lambda: executor.spin_once(timeout_sec=0.1)), "the graph did not get going"
            _kill_child(launch, node)
        wait_until(lambda: fixes and fixes[-1] == images[-1] or launch.poll() is not None, 240,
                   spin=lambda: executor.spin_once(timeout_sec=0.1))
    finally:
        probe.destroy_node()
        interrupt(launch, 30.0)
        log.close()
    output = (tmp_path / "launch.log").read_text(errors="replace")
    for node in ("camera", "recorder"):
        assert f"[graph] {node} exited with status -9: restarting it (restart 1 of at most 5)" in output, output[-3000:]
    assert "there are now at least 2 nodes" not in output
    state_dir = __import__("re").search(r"resume file (\S+)/camera\.resume", output).group(1)
    assert not __import__("os").path.exists(state_dir), "the launch left its state folder behind"
    assert fixes == images[images.index(fixes[0]):], output[-3000:]  # none lost or sent twice after the first
    assert recording_parts(recording) == [recording, tmp_path / "recording.1"]
    # Launch may stop the last recorder before it closes its bag (SIGTERM after SIGINT): what it wrote recovers.
    from vessel_detect.bag_salvage import SalvagedBagReader

    with SalvagedBagReader(tmp_path / "recording.1") as reader:
        assert reader.message_count("/vessel/fix") > 0


def test_a_mistyped_parameter_file_stops_the_launch(ros_env, tmp_path):
    reason = _launch_available()
    if reason:
        pytest.skip(reason)
    done = subprocess.run(["ros2", "launch", "vessel_bringup", "vessel_graph.launch.py",
                           f"params_file:={tmp_path}/aitas_typo.yaml", "calib_file:=config/aitas_camera.yaml"],
                          env=ros_env, capture_output=True, text=True, timeout=60)
    assert done.returncode != 0
    assert "aitas_typo.yaml is not a file" in done.stdout + done.stderr
