"""The recorder node in its own process: records published topics and leaves a readable bag after SIGINT.

Needs the built workspace (rclpy, vessel_msgs, the installed `recorder` executable); skipped without it.
"""

import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from vessel_detect import bag_messages, bag_reader

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[3]
RECORDER_EXE = REPO / "ros2_ws/install/vessel_detect/lib/vessel_detect/recorder"

rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")
pytest.importorskip("vessel_msgs.msg", reason="vessel_msgs is not built: run ./vessel setup")
if not RECORDER_EXE.exists():
    pytest.skip(f"{RECORDER_EXE} is not installed: run ./vessel setup", allow_module_level=True)

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import CompressedImage, NavSatFix  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from vessel_msgs.msg import Detection2D, Detection2DArray, ObjectHypothesisWithPose  # noqa: E402

T0 = 1_601_495_752_884_000_000


def to_time(ns):
    from builtin_interfaces.msg import Time

    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def wait(predicate, executor, timeout_s):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        executor.spin_once(timeout_sec=0.05)
    return predicate()


def test_recorder_writes_a_readable_bag_after_sigint(tmp_path, ros_env, ros_context):
    node = rclpy.create_node("recorder_test_publisher", context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    fix_pub = node.create_publisher(NavSatFix, "/vessel/fix", reliable)
    det_pub = node.create_publisher(Detection2DArray, "/vessel/detections", reliable)
    camera_fix_pub = node.create_publisher(NavSatFix, "/camera/fix", latched)
    image_pub = node.create_publisher(CompressedImage, "/camera/image_raw/compressed", qos_profile_sensor_data)
    note_pub = node.create_publisher(String, "/notes", reliable)
    recorded_counts = []

    def on_diagnostics(array):
        for status in array.status:
            if status.name == "recorder":
                recorded_counts.extend(int(v.value) for v in status.values if v.key == "count.messages")

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, reliable)
    camera_fix = NavSatFix(latitude=32.70297, longitude=-117.234631)
    camera_fix.header.stamp = to_time(T0)
    camera_fix_pub.publish(camera_fix)  # before the recorder starts: it must still get it (transient local)

    output = tmp_path / "recording"
    env = ros_env
    topics = "['/vessel/fix', '/vessel/detections:vessel_msgs/msg/Detection2DArray', '/camera/fix', " \
             "'/camera/image_raw/compressed', '/notes']"
    process = subprocess.Popen(
        [str(RECORDER_EXE), "--ros-args", "-p", f"output:={output}", "-p", f"topics:={topics}",
         "-p", "discovery_period_s:=0.1"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    count = 20
    try:
        publishers = (fix_pub, det_pub, image_pub, note_pub)
        assert wait(lambda: all(p.get_subscription_count() > 0 for p in publishers), executor, 30), \
            "the recorder never subscribed"
        for k in range(count):
            stamp = T0 + k * 250_000_000
            fix = NavSatFix(latitude=32.7 + k * 1e-5, longitude=-117.23)
            fix.header.stamp = to_time(stamp)
            fix_pub.publish(fix)
            detections = Detection2DArray()
            detections.header.stamp = to_time(stamp)
            detections.header.frame_id = "camera"
            detection = Detection2D(id=str(k))
            detection.bbox.center.position.x = 100.0 + k
            hypothesis = ObjectHypothesisWithPose()
            hypothesis.hypothesis.class_id = "boat"
            hypothesis.hypothesis.score = 0.5
            detection.results = [hypothesis]
            detections.detections = [detection]
            det_pub.publish(detections)
            image = CompressedImage(format="jpeg")
            image.header.stamp = to_time(stamp)
            image.data = bytes([k]) * 1000
            image_pub.publish(image)
            note_pub.publish(String(data=f"note {k}"))
            executor.spin_once(timeout_sec=0.01)
        # Wait until the recorder reports them all (its diagnostics count), then stop it like the demo does.
        wait(lambda: recorded_counts and recorded_counts[-1] >= 4 * count + 1, executor, 15)
        process.send_signal(signal.SIGINT)
        log, _ = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        executor.shutdown()
        node.destroy_node()
    assert process.returncode == 0, log
    assert "closed" in log and "Traceback" not in log

    meta = yaml.safe_load((output / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert counts["/vessel/fix"] == count and counts["/vessel/detections"] == count
    assert counts["/camera/fix"] == 1 and counts["/notes"] == count
    assert counts["/camera/image_raw/compressed"] >= count - 2  # best effort: nearly all
    with bag_reader.BagReader(output) as reader:
        fixes = reader.fixes("/vessel/fix")
        assert [bag_messages.sec_to_ns(t) for t in fixes.stamps] == [T0 + k * 250_000_000 for k in range(count)]
        assert list(fixes.lats) == [32.7 + k * 1e-5 for k in range(count)]
        recorded = reader.read_topic("/vessel/detections")
        assert [m.detections[0].id for _, m in recorded] == [str(k) for k in range(count)]
        assert recorded[3][1].detections[0].results[0].hypothesis.class_id == "boat"
        # log time == header stamp where there is one
        assert [bag_messages.sec_to_ns(t) for t, _ in recorded] == [T0 + k * 250_000_000 for k in range(count)]
        assert reader.topics["/notes"] == "std_msgs/msg/String"  # type taken from the graph
        assert reader.fixes("/camera/fix").lats[0] == 32.70297
    assert sum(1 for m in bag_reader.iter_mcap(output) if m.topic == "/vessel/fix") == count  # mcap reads it too


def test_an_output_that_exists_or_cannot_be_made_is_one_error_line_and_nothing_is_touched(tmp_path, ros_env):
    """The recorder used to tell a node user to "pass --overwrite", and to end in a traceback under a file."""
    existing = tmp_path / "bag"
    existing.mkdir()
    (existing / "kept.mcap").write_bytes(b"kept")
    in_the_way = tmp_path / "notes.txt"
    in_the_way.write_text("kept\n")
    for output, message in ((existing, "-p overwrite:=true"), (in_the_way / "bag", "a file stands where a folder")):
        run = subprocess.run([str(RECORDER_EXE), "--ros-args", "-p", f"output:={output}"], env=ros_env,
                             capture_output=True, text=True, timeout=120)
        assert run.returncode == 2, run.stderr[-2000:]
        assert run.stderr.startswith("error: ") and message in run.stderr and "Traceback" not in run.stderr, \
            run.stderr[-2000:]
    assert (existing / "kept.mcap").read_bytes() == b"kept" and in_the_way.read_text() == "kept\n"


def test_ros2_param_set_on_a_recorder_is_refused_with_the_reason(tmp_path, monkeypatch, ros_env):
    """Every recorder parameter is read-only (the bag, its topics and its writer are set up at start).

    A change is refused, saying so, where it used to be answered "successful" and ignored.
    """
    from rclpy.parameter import Parameter

    from vessel_detect.recorder_node import RecorderNode

    context = rclpy.Context()
    rclpy.init(context=context, args=["recorder", "--ros-args", "-p", f"output:={tmp_path / 'bag'}", "-p",
                                      "topics:=['/vessel/fix']"])
    node_init = rclpy.node.Node.__init__
    monkeypatch.setattr(rclpy.node.Node, "__init__",
                        lambda self, name, **kw: node_init(self, name, context=context, **kw))
    node = RecorderNode()
    try:
        for name, value in (("output", str(tmp_path / "other")), ("queue_depth", 5), ("flush_period_s", 0.0),
                            ("topics", ["/vessel/tracks"])):
            result = node.set_parameters([Parameter(name, value=value)])[0]
            assert not result.successful and "read-only" in result.reason, name
            assert f"restart the node with -p {name}:=VALUE" in node.describe_parameter(name).additional_constraints
        assert node.get_parameter("output").value == str(tmp_path / "bag") and node.depth == 100
        assert [plan.name for plan in node.plans] == ["/vessel/fix"]
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert (tmp_path / "bag" / "metadata.yaml").is_file()


def test_a_restarted_recorder_continues_into_the_next_part_and_the_killed_ones_bag_is_recoverable(
        tmp_path, ros_env, ros_context):
    """A killed recorder is restarted into ``OUT.1``; ``OUT`` stays as it was, for ``bag recover``.

    With ``./vessel graph --respawn`` a killed recorder failed five times on "OUT exists already", then the graph
    stopped every node and nothing was recorded after the kill. Started again with the same ``output`` and
    ``resume_file``, it records into ``OUT.1``; ``OUT``, left by the killed one, stays as it was and ``bag recover``
    makes it readable: the two parts hold every message once.
    """
    from vessel_detect.bag_salvage import recover_bag, salvage_mcap
    from vessel_detect.resume_files import recording_parts

    node = rclpy.create_node("recorder_restart_publisher", context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    fix_pub = node.create_publisher(NavSatFix, "/vessel/fix", QoSProfile(depth=100,
                                                                         reliability=ReliabilityPolicy.RELIABLE))
    output, resume_file = tmp_path / "recording", tmp_path / "state" / "recorder.resume"
    args = [str(RECORDER_EXE), "--ros-args", "-p", f"output:={output}", "-p", "topics:=['/vessel/fix']", "-p",
            "discovery_period_s:=0.1", "-p", "flush_period_s:=0.05", "-p", f"resume_file:={resume_file}"]

    def readers() -> set:
        return {bytes(info.endpoint_gid) for info in node.get_subscriptions_info_by_topic("/vessel/fix")}

    def publish(ks) -> None:
        for k in ks:
            fix = NavSatFix(latitude=32.7 + k * 1e-5, longitude=-117.23)
            fix.header.stamp = to_time(T0 + k * 250_000_000)
            fix_pub.publish(fix)

    def recorded(bag) -> int:
        try:
            return len(salvage_mcap(bag).messages)
        except Exception:  # not written yet
            return 0

    first = subprocess.Popen(args, env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    second = None
    try:
        assert wait(lambda: fix_pub.get_subscription_count() > 0, executor, 30), "the recorder never subscribed"
        before = readers()
        publish(range(5))
        assert wait(lambda: recorded(output) == 5, executor, 30), "the first part never held the 5 fixes"
        first.kill()
        first.wait()
        second = subprocess.Popen(args, env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        # Its reader is a new one (the killed one's may be known for a while yet), matched by this publisher.
        subscribed = wait(lambda: second.poll() is not None or (readers() - before)
                          and fix_pub.get_subscription_count() == len(readers()), executor, 30)
        assert second.poll() is None, second.stdout.read()  # it used to stop on "OUT exists already"
        assert subscribed, "the restarted recorder never subscribed"
        publish(range(5, 10))
        assert wait(lambda: recorded(tmp_path / "recording.1") == 5, executor, 30), second.stdout
        second.send_signal(signal.SIGINT)
        log, _ = second.communicate(timeout=30)
    finally:
        for process in (first, second):
            if process is not None and process.poll() is None:
                process.kill()
                process.wait()
        executor.shutdown()
        node.destroy_node()
    assert second.returncode == 0, log
    assert f"continuing the recording {output} into {output}.1" in log and "Traceback" not in log
    assert recording_parts(output) == [output, tmp_path / "recording.1"]
    with bag_reader.BagReader(tmp_path / "recording.1") as reader:  # closed by SIGINT: readable as it is
        later = [bag_messages.sec_to_ns(t) for t in reader.fixes("/vessel/fix").stamps]
    recover_bag(output)  # what `./vessel bag recover` does with the killed recorder's bag
    with bag_reader.BagReader(output) as reader:
        earlier = [bag_messages.sec_to_ns(t) for t in reader.fixes("/vessel/fix").stamps]
    assert earlier + later == [T0 + k * 250_000_000 for k in range(10)]
