"""The camera node in its own process, replaying generated bags to a subscriber in this process.

Needs the built workspace (rclpy, vessel_msgs, the installed `camera` executable); skipped without it.
"""

import subprocess
import time
from pathlib import Path

import pytest

from vessel_detect import bag_messages, bag_reader, bag_salvage, bag_topics, bag_writer
from vessel_fixtures import detect_synthetic as synthetic
from vessel_fixtures.ros_nodes import ProbeNode, status_values

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[3]
CAMERA_EXE = REPO / "ros2_ws/install/vessel_detect/lib/vessel_detect/camera"

rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")
pytest.importorskip("vessel_msgs.msg", reason="vessel_msgs is not built: run ./vessel setup")
if not CAMERA_EXE.exists():
    pytest.skip(f"{CAMERA_EXE} is not installed: run ./vessel setup", allow_module_level=True)

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import CompressedImage, NavSatFix  # noqa: E402

from vessel_msgs.msg import Detection2DArray  # noqa: E402


class Probe(ProbeNode):
    """A node in its own rclpy context and DDS domain that records what the camera publishes."""

    def __init__(self, context, ack: bool = False, ack_lag: int = 0, unanswered: frozenset = frozenset()) -> None:
        super().__init__(context, "camera_test_probe")
        self.ack_lag = ack_lag
        self.unanswered = unanswered  # indices of the images this detector never answers (it dropped them)
        self._unacked = []
        self.images, self.clock, self.fixes, self.truth, self.diagnostics = [], [], [], [], []
        self.received_at = []
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.ack_pub = self.node.create_publisher(Detection2DArray, "/vessel/detections", 10) if ack else None
        self.node.create_subscription(CompressedImage, bag_topics.DEFAULT_IMAGE_TOPIC, self._on_image,
                                      qos_profile_sensor_data)
        self.node.create_subscription(Clock, "/clock", lambda m: self.clock.append(stamp(m.clock)), reliable)
        self.node.create_subscription(NavSatFix, "/camera/fix", self.fixes.append, latched)
        self.node.create_subscription(NavSatFix, "/vessel/gps_truth", self.truth.append, reliable)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, reliable)

    def _on_image(self, message):
        self.images.append((stamp(message.header.stamp), bytes(message.data)))
        self.received_at.append(time.monotonic())
        if self.ack_pub is not None:  # play the detector: its output carries the image's header
            if len(self.images) - 1 not in self.unanswered:
                self._unacked.append(message.header)
            while len(self._unacked) > self.ack_lag:  # a detector ack_lag images behind
                self.ack_pub.publish(Detection2DArray(header=self._unacked.pop(0)))

    def spin_while(self, process, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while process.poll() is None and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)
        for _ in range(20):  # drain what is still queued
            self.executor.spin_once(timeout_sec=0.01)

    def camera_counts(self) -> dict:
        """count.* values of the camera's last diagnostics message."""
        return status_values(self.diagnostics, "camera")


def stamp(time_msg) -> int:
    return time_msg.sec * 1_000_000_000 + time_msg.nanosec


def start_camera(env: dict[str, str], *params: str, executable: str = "camera") -> subprocess.Popen:
    """The camera node in its own process (output on a pipe), in the test's ROS domain (``ros_env``)."""
    args = [str(CAMERA_EXE.with_name(executable)), "--ros-args"]
    for p in params:
        args += ["-p", p]
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.fixture
def replay(ros_env, ros_context):
    """``replay(bag, *params, ack=False)``: the camera plays a bag to its end to a probe; (probe, status, output)."""

    def run(bag, *params, ack=False, ack_lag=0, unanswered=frozenset(), timeout_s=60.0):
        probe = Probe(ros_context, ack=ack, ack_lag=ack_lag, unanswered=unanswered)
        process = start_camera(ros_env, f"source:={bag}", "wait_for_subscribers:=1", "end_linger_s:=0.5", *params)
        try:
            probe.spin_while(process, timeout_s)
            assert process.poll() is not None, "camera node did not exit at the end of the bag"
            output = process.stdout.read()
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
            probe.close()
        return probe, process.returncode, output

    return run


@pytest.mark.parametrize(("rate", "frames"), [(1.0, 8), (10.0, 30)])
def test_replay_delivers_every_frame_with_original_stamps_and_clock(tmp_path, rate, frames, replay):
    step = 0.2
    stamps = synthetic.write_bag(tmp_path / "bag", frames=frames, frame_step_s=step)
    probe, status, output = replay(tmp_path / "bag", f"rate:={rate}")
    assert status == 0, output
    assert f"sent {frames} frames, dropped 0, bad 0" in output
    assert "while shutting down" not in output  # the node's own list of publishers once hid rclpy's
    assert [s for s, _ in probe.images] == stamps  # every frame, in order, original stamps
    assert [b for _, b in probe.images] == [synthetic.frame_jpeg(k) for k in range(frames)]
    # /clock follows the stamps: never backwards, hits every frame stamp, from the first to the last.
    assert probe.clock == sorted(probe.clock)
    assert set(stamps) <= set(probe.clock)
    assert probe.clock[0] == stamps[0] and probe.clock[-1] == stamps[-1]
    assert len(probe.clock) > frames  # advanced between frames too
    # paced by the stamps (a lower bound only: a loaded machine can only make it slower)
    assert probe.received_at[-1] - probe.received_at[0] >= 0.5 * (stamps[-1] - stamps[0]) / 1e9 / rate
    # the bag's other topics are republished
    assert len(probe.fixes) == 1 and probe.fixes[0].latitude == synthetic.CAMERA_LAT
    assert [stamp(f.header.stamp) for f in probe.truth] == stamps
    counts = probe.camera_counts()
    assert counts["count.frames_sent"] == str(frames) and counts["count.frames_bad"] == "0"


def test_as_fast_as_consumed_with_a_bad_frame(tmp_path, replay):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=10, frame_step_s=4.0, bad_frames=(4,))
    # wait_for_subscribers -1 (automatic): at rate 0 it holds the first frame for the image subscriber and the
    # detector (here: this probe publishing the acknowledgements)
    probe, status, output = replay(tmp_path / "bag", "rate:=0.0", "ack_timeout_s:=20.0", "wait_for_subscribers:=-1",
                                   ack=True)
    assert status == 0, output
    good = stamps[:4] + stamps[5:]
    assert [s for s, _ in probe.images] == good  # the unreadable frame is skipped, the rest all arrive
    assert "unreadable" in output and output.count("logged once") == 1
    counts = probe.camera_counts()
    assert counts["count.frames_sent"] == "9" and counts["count.frames_bad"] == "1"
    assert counts["count.ack_timeouts"] == "0"  # each frame was released by the detections of the previous one
    assert set(good) <= set(probe.clock) and probe.clock == sorted(probe.clock)


@pytest.mark.parametrize(("in_flight", "timeouts"), [(1, 6), (2, 1)])
def test_frames_in_flight_keep_a_detector_that_answers_one_image_late_busy(tmp_path, replay, in_flight, timeouts):
    """A detector that sends an image's detections when the next image arrives (``ack_lag`` 1).

    In lock step every image waits out ``ack_timeout_s``; with two in flight each is released by the detections
    of the one before, and only the last, which no later image releases, waits at the end.
    """
    stamps = synthetic.write_bag(tmp_path / "bag", frames=6, frame_step_s=4.0, with_fixes=False)
    probe, status, output = replay(tmp_path / "bag", "rate:=0.0", "ack_timeout_s:=1.0", "publish_clock:=false",
                                   f"frames_in_flight:={in_flight}", ack=True, ack_lag=1)
    assert status == 0, output
    assert [s for s, _ in probe.images] == stamps
    assert probe.camera_counts()["count.ack_timeouts"] == str(timeouts)


@pytest.mark.parametrize("restamp", [True, False])
def test_a_loop_paces_on_the_detections_of_its_own_frames(tmp_path, replay, restamp):
    """Without restamping, a loop repeats the stamps: the detections of the first pass must not release the second.

    A detector that answers one image late (``ack_lag`` 1) makes every frame wait out ``ack_timeout_s`` in lock
    step, in both passes.
    """
    stamps = synthetic.write_bag(tmp_path / "bag", frames=3, frame_step_s=4.0, with_fixes=False)
    probe, status, output = replay(tmp_path / "bag", "rate:=0.0", "ack_timeout_s:=0.5", "publish_clock:=false",
                                   "loop:=true", f"loop_restamp:={str(restamp).lower()}", "max_frames:=6", ack=True,
                                   ack_lag=1)
    assert status == 0, output
    sent = [s for s, _ in probe.images]
    assert len(sent) == 6 and (sent[3:] == stamps) != restamp
    assert probe.camera_counts()["count.ack_timeouts"] == "6"


def test_a_frame_whose_detections_never_come_is_counted(tmp_path, replay):
    """With two in flight, the detector may drop an image for the next one: the next one's detections release it."""
    stamps = synthetic.write_bag(tmp_path / "bag", frames=6, frame_step_s=4.0, with_fixes=False)
    probe, status, output = replay(tmp_path / "bag", "rate:=0.0", "ack_timeout_s:=5.0", "publish_clock:=false",
                                   "frames_in_flight:=2", ack=True, unanswered=frozenset({2}))
    assert status == 0, output
    assert [s for s, _ in probe.images] == stamps
    counts = probe.camera_counts()
    assert counts["count.frames_unanswered"] == "1" and counts["count.ack_timeouts"] == "0"
    assert "1 without detections" in output


def test_ack_timeout_keeps_going_without_a_detector_and_max_frames(tmp_path, replay):
    stamps = synthetic.write_bag(tmp_path / "bag", frames=5, frame_step_s=4.0, with_fixes=False)
    probe, status, output = replay(tmp_path / "bag", "rate:=0.0", "ack_timeout_s:=0.2", "publish_clock:=false",
                                   "max_frames:=3")
    assert status == 0, output
    assert [s for s, _ in probe.images] == stamps[:3]
    assert probe.clock == []
    assert probe.camera_counts()["count.ack_timeouts"] == "3"
    assert len(probe.fixes) == 1  # no fix in the bag: published from the camera.* parameters


def _resumed_stamp(resume_file: Path) -> int | None:
    """The stamp of the last item the camera noted in its resume file (None before the first)."""
    import json

    try:
        return json.loads(resume_file.read_text())["position"]["stamp_ns"]
    except FileNotFoundError:
        return None


@pytest.mark.parametrize("kind", ["bag", "folder"])
def test_a_restarted_camera_carries_on_after_the_last_frame_it_sent(tmp_path, ros_env, ros_context, kind):
    """Respawned, the camera replayed from frame 0: every frame again, the graph's tracker reset by stamps going back.

    Killed with -9 while it waits for frame 3's detections (rate 0), the camera started again with the same
    ``resume_file`` sends frame 4 on: every frame once, in order, /clock never back, each GPS truth message once, the
    latched camera fix again. A folder without stamps in its names is stamped from the first start's time again.
    """
    if kind == "bag":
        source = tmp_path / "bag"
        stamps = synthetic.write_bag(source, frames=8, frame_step_s=4.0)
    else:
        source = tmp_path / "frames"
        source.mkdir()
        for k in range(8):
            (source / f"{k:05d}.jpg").write_bytes(synthetic.frame_jpeg(k))
    resume_file = tmp_path / "state" / "camera.resume"
    # end_linger_s: the second camera's latched fix must match the probe before it exits (DDS takes up to seconds).
    params = (f"source:={source}", "rate:=0.0", "ack_timeout_s:=60.0", "wait_for_subscribers:=-1", "fps:=1.0",
              "end_linger_s:=3.0", f"resume_file:={resume_file}")
    probe = Probe(ros_context, ack=True, unanswered=frozenset({3}))  # frame 3's detections never come
    first = start_camera(ros_env, *params)
    second = None
    try:
        deadline = time.monotonic() + 60
        while not (len(probe.images) == 4 and _resumed_stamp(resume_file) == probe.images[3][0]):
            assert time.monotonic() < deadline and first.poll() is None, first.stdout.read() if first.poll() else ""
            probe.executor.spin_once(timeout_sec=0.05)
        first.kill()  # while it waits for frame 3's detections
        first.wait()
        second = start_camera(ros_env, *params)
        probe.spin_while(second, 60)
        output = second.stdout.read()
    finally:
        for process in (first, second):
            if process is not None and process.poll() is None:
                process.kill()
                process.wait()
        probe.close()
    assert second.returncode == 0, output
    sent = [s for s, _ in probe.images]
    assert [b for _, b in probe.images] == [synthetic.frame_jpeg(k) for k in range(8)], output  # each once, in order
    if kind == "bag":
        assert sent == stamps
        assert [stamp(f.header.stamp) for f in probe.truth] == stamps  # frame 3's, sent before it, not again
    else:  # the same stamps as one run would give: 1 s apart from the first start's time
        assert [b - a for a, b in zip(sent[:-1], sent[1:], strict=True)] == [1_000_000_000] * 7
    assert probe.clock == sorted(probe.clock) and set(sent) <= set(probe.clock)
    assert len(probe.fixes) == 2  # the latched camera fix, from each camera
    assert "carrying on after the item stamped" in output and "4 frames were sent before the restart" in output
    assert "sent 4 frames" in output and "carried on after a restart (4 frames sent before it)" in output


def test_bad_source_exits_with_one_error_line(tmp_path, ros_env):
    process = start_camera(ros_env, f"source:={tmp_path / 'missing'}")
    output, _ = process.communicate(timeout=60)
    assert process.returncode == 2
    assert "error: source" in output and "does not exist" in output and "Traceback" not in output


def test_a_bag_cut_short_plays_what_it_holds_says_what_was_lost_and_exits_non_zero(tmp_path, replay):
    """A bag cut at 50 % played nothing, although half of it was intact."""
    bag = tmp_path / "bag"
    start = 1_601_494_000_000_000_000
    with bag_writer.BagWriter(bag, flush_every_s=1e-9) as writer:  # a chunk per message, as a recorder writes
        writer.add_topic(bag_topics.DEFAULT_IMAGE_TOPIC, bag_topics.COMPRESSED_IMAGE, "sensor_data")
        for k in range(20):
            writer.write(bag_topics.DEFAULT_IMAGE_TOPIC,
                         bag_messages.compressed_image(start + k * 100_000_000, synthetic.frame_jpeg(k)))
    file = bag_reader.mcap_file_of(bag)
    data = file.read_bytes()
    file.write_bytes(data[: len(data) // 2])
    readable = len(bag_salvage.salvage_mcap(bag).messages)
    assert 0 < readable < 20
    probe, status, output = replay(bag, "rate:=10.0")
    assert status == 1, output
    assert [b for _, b in probe.images] == [synthetic.frame_jpeg(k) for k in range(readable)]
    assert "the source was damaged, the rest is lost" in output and "readable to byte" in output
    assert "Traceback" not in output


def test_managed_camera_streams_only_while_active(tmp_path, ask_service, ros_env, ros_context):
    """Configure opens the source, activate streams it, deactivate stops, cleanup closes it, shutdown ends."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState

    synthetic.write_bag(tmp_path / "bag", frames=200, frame_step_s=0.1)
    probe = Probe(ros_context)
    process = start_camera(ros_env, f"source:={tmp_path / 'bag'}", "rate:=1.0", "wait_for_subscribers:=1",
                           executable="camera_managed")
    change = probe.node.create_client(ChangeState, "/camera/change_state")
    get = probe.node.create_client(GetState, "/camera/get_state")

    def spin_until(predicate, timeout_s):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not predicate():
            probe.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def transition(transition_id):
        future = change.call_async(ChangeState.Request(transition=Transition(id=transition_id)))
        assert spin_until(future.done, 30)
        return future.result().success

    def state():
        return ask_service(get, GetState.Request(), spin_until).current_state.label

    try:
        assert spin_until(lambda: change.service_is_ready() and get.service_is_ready(), 60)
        assert state() == "unconfigured"
        assert transition(Transition.TRANSITION_CONFIGURE) and state() == "inactive"
        spin_until(lambda: False, 1.5)
        assert probe.images == [], "an inactive camera published"
        assert transition(Transition.TRANSITION_ACTIVATE) and state() == "active"
        assert spin_until(lambda: len(probe.images) >= 5, 30), "the active camera published nothing"
        assert transition(Transition.TRANSITION_DEACTIVATE) and state() == "inactive"
        spin_until(lambda: False, 0.5)
        count = len(probe.images)
        spin_until(lambda: False, 1.5)
        assert len(probe.images) == count, "a deactivated camera kept publishing"
        assert transition(Transition.TRANSITION_CLEANUP) and state() == "unconfigured"
        assert transition(Transition.TRANSITION_UNCONFIGURED_SHUTDOWN) and state() == "finalized"
    finally:
        if process.poll() is None:
            process.send_signal(2)
        output, _ = process.communicate(timeout=30)
        probe.close()
    assert "Traceback" not in output


def test_a_managed_camera_with_a_bad_source_fails_to_configure(tmp_path, ros_env, ros_context):
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState

    probe = Probe(ros_context)
    process = start_camera(ros_env, f"source:={tmp_path / 'missing'}", executable="camera_managed")
    change = probe.node.create_client(ChangeState, "/camera/change_state")
    try:
        deadline = time.monotonic() + 60
        while not change.service_is_ready() and time.monotonic() < deadline:
            probe.executor.spin_once(timeout_sec=0.05)
        future = change.call_async(ChangeState.Request(transition=Transition(id=Transition.TRANSITION_CONFIGURE)))
        while not future.done() and time.monotonic() < deadline:
            probe.executor.spin_once(timeout_sec=0.05)
        assert future.done() and not future.result().success
        assert process.poll() is None
    finally:
        process.send_signal(2)
        output, _ = process.communicate(timeout=30)
        probe.close()
    assert "configure failed" in output and "missing" in output and "Traceback" not in output


def test_a_replay_cut_by_ctrl_c_ends_quietly(tmp_path, monkeypatch, ros_env):
    """A replay whose context Ctrl-C shut down under a publish ends quietly: no traceback, exit status 0.

    rclpy's signal handler shuts the context down before the node's close() stops the replay thread.
    """
    import threading

    import cv2
    import numpy as np

    from vessel_detect.camera_node import CameraNode

    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i:05d}.jpg"), np.full((72, 128, 3), 40 * i, dtype=np.uint8))
    thread_errors = []
    monkeypatch.setattr(threading, "excepthook", thread_errors.append)
    context = rclpy.Context()
    rclpy.init(context=context, args=["camera", "--ros-args", "-p", f"source:={folder}", "-p", "loop:=true",
                                      "-p", "fps:=50.0"])
    monkeypatch.setattr(rclpy.node.Node, "__init__", _with_context(rclpy.node.Node.__init__, context))
    node = CameraNode()
    try:
        deadline = time.monotonic() + 20
        while node.stats.sent < 5 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert node.stats.sent >= 5
        rclpy.shutdown(context=context)  # what Ctrl-C does first
        node._worker.join(timeout=5)
        assert not node._worker.is_alive()
        assert thread_errors == [] and node.exit_status == 0
    finally:
        node.close()
        rclpy.try_shutdown(context=context)


def _with_context(init, context):
    def wrapped(self, *args, **kwargs):
        kwargs.setdefault("context", context)
        init(self, *args, **kwargs)

    return wrapped


def test_ros2_param_set_on_a_running_camera(tmp_path, monkeypatch, ros_env):
    """``ros2 param set``: a live change takes effect, a bad value and a read-only change are refused with a reason.

    Never accepted and ignored: an audit found `rate` and `source` changes answered "successful" while nothing changed.
    """
    from rclpy.parameter import Parameter

    from vessel_common.run import wait_for
    from vessel_detect.camera_node import CameraNode, ManagedCameraNode

    synthetic.write_bag(tmp_path / "bag", frames=3, frame_step_s=60.0, with_fixes=False)
    context = rclpy.Context()
    rclpy.init(context=context, args=["camera", "--ros-args", "-p", f"source:={tmp_path / 'bag'}", "-p",
                                      "wait_for_subscribers:=0", "-p", "end_linger_s:=0.0"])
    monkeypatch.setattr(rclpy.node.Node, "__init__", _with_context(rclpy.node.Node.__init__, context))
    node = CameraNode()
    try:
        assert wait_for(lambda: node.stats.sent >= 1, 20.0)
        # At 1x the next frame is a minute away; at 600x the two minutes left take 0.2 s.
        assert node.set_parameters([Parameter("rate", value=600.0)])[0].successful
        assert node.replay.schedule.rate == 600.0 and node.get_parameter("rate").value == 600.0
        assert wait_for(lambda: node.finished, 20.0), "the replay kept the old rate"
        assert node.stats.sent == 3 and node.stats.late == 0

        refused = node.set_parameters([Parameter("rate", value=-1.0)])[0]
        assert not refused.successful and "rate" in refused.reason and "range" in refused.reason
        assert node.params["rate"] == 600.0 and node.replay.schedule.rate == 600.0
        refused = node.set_parameters([Parameter("source", value="/etc/passwd")])[0]
        assert not refused.successful and "read-only" in refused.reason
        assert node.get_parameter("source").value == str(tmp_path / "bag") == node.params["source"]
        assert "restart the node with -p source:=VALUE" in node.describe_parameter("source").additional_constraints
    finally:
        node.close()
        node.destroy_node()
    managed = ManagedCameraNode()  # unconfigured: the change is what configure will use
    try:
        assert managed.set_parameters([Parameter("rate", value=8.0)])[0].successful and managed.params["rate"] == 8.0
        assert not managed.set_parameters([Parameter("loop", value=True)])[0].successful
    finally:
        managed.destroy_node()
        rclpy.try_shutdown(context=context)
