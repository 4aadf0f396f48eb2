"""The camera node republishes a bag's own-ship fix and attitude (Imu) with the images, every one, in stamp order.

The managed camera is configured first (its publishers exist), the probe waits until each of its subscriptions
has matched the camera, and only then is the camera activated: no message can go out before its reader exists.
Needs the built workspace (rclpy, the installed `camera_managed` executable); skipped without it.
"""

import subprocess
import time
from pathlib import Path

import pytest

from vessel_calib.own_ship import OwnShipSample, ShipAttitude
from vessel_detect import bag_messages, bag_topics, bag_writer
from vessel_fixtures import detect_synthetic as synthetic
from vessel_fixtures.ros_nodes import ProbeNode, status_values

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[3]
CAMERA_EXE = REPO / "ros2_ws/install/vessel_detect/lib/vessel_detect/camera_managed"

rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")
if not CAMERA_EXE.exists():
    pytest.skip(f"{CAMERA_EXE} is not installed: run ./vessel setup", allow_module_level=True)

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from lifecycle_msgs.msg import Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import CompressedImage, Imu, NavSatFix  # noqa: E402

from vessel_detect.own_ship_messages import position_of_navsatfix, sample_attitude_of_imu  # noqa: E402

IMU_TOPIC = "/ship/attitude"  # not the default: the parameter names the topic
FRAMES, FRAME_STEP_S, SAMPLE_STEP_S = 8, 0.5, 0.05


def ship_samples() -> list[OwnShipSample]:
    """20 Hz from half a second before the first frame to half a second after the last; some compass only."""
    first = synthetic.START_UTC - 0.5
    count = round(((FRAMES - 1) * FRAME_STEP_S + 1.0) / SAMPLE_STEP_S) + 1
    samples = []
    for k in range(count):
        attitude = ShipAttitude((350.0 + k) % 360.0, 0.1 * k, -0.2 * k) if k % 5 else ShipAttitude((350.0 + k) % 360)
        samples.append(OwnShipSample(first + k * SAMPLE_STEP_S, 32.7 + 1e-6 * k, -117.2, attitude))
    return samples


def write_bag(path: Path, samples: list[OwnShipSample]) -> list[int]:
    """Images and the own ship's fixes and attitudes in stamp order (as bag_build writes them); image stamps."""
    frames = [(bag_messages.sec_to_ns(synthetic.START_UTC + k * FRAME_STEP_S), k) for k in range(FRAMES)]
    items = [(ns, 1, "image", k) for ns, k in frames]
    items += [(bag_messages.sec_to_ns(s.stamp), 0, "ship", s) for s in samples]
    with bag_writer.BagWriter(path) as writer:
        writer.add_topic(bag_topics.DEFAULT_IMAGE_TOPIC, bag_topics.COMPRESSED_IMAGE, "sensor_data")
        writer.add_topic(bag_topics.DEFAULT_OWN_SHIP_FIX_TOPIC, bag_topics.NAV_SAT_FIX, "reliable")
        writer.add_topic(IMU_TOPIC, bag_topics.IMU, "reliable")
        for stamp_ns, _, kind, item in sorted(items, key=lambda i: i[:2]):
            if kind == "image":
                writer.write(bag_topics.DEFAULT_IMAGE_TOPIC,
                             bag_messages.compressed_image(stamp_ns, synthetic.frame_jpeg(item)))
                continue
            writer.write(bag_topics.DEFAULT_OWN_SHIP_FIX_TOPIC,
                         bag_messages.nav_sat_fix(stamp_ns, item.lat, item.lon, frame_id="base_link"))
            writer.write(IMU_TOPIC, bag_messages.imu(stamp_ns, item.attitude, sigma_deg=0.3))
    return [ns for ns, _ in frames]


def stamp(message) -> int:
    return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec


class Probe(ProbeNode):
    """Subscriptions to the camera's images, own-ship topics and diagnostics, in its own context."""

    def __init__(self, context) -> None:
        super().__init__(context, "own_ship_probe")
        self.images, self.fixes, self.imus, self.diagnostics = [], [], [], []
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.subscriptions = [
            self.node.create_subscription(CompressedImage, bag_topics.DEFAULT_IMAGE_TOPIC, self.images.append,
                                          qos_profile_sensor_data),
            self.node.create_subscription(NavSatFix, bag_topics.DEFAULT_OWN_SHIP_FIX_TOPIC, self.fixes.append,
                                          reliable),
            self.node.create_subscription(Imu, IMU_TOPIC, self.imus.append, reliable),
        ]
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, reliable)

    def spin_until(self, predicate, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not predicate():
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def matched(self) -> bool:
        return all(s.get_publisher_count() >= 1 for s in self.subscriptions)

    def camera_counts(self) -> dict:
        return status_values(self.diagnostics, "camera")


def test_the_camera_republishes_the_own_ship_with_the_images(tmp_path, ros_env, ros_context):
    assert ros_env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    samples = ship_samples()
    image_stamps = write_bag(tmp_path / "bag", samples)
    probe = Probe(ros_context)
    args = [str(CAMERA_EXE), "--ros-args", "-p", f"source:={tmp_path / 'bag'}", "-p", "rate:=5.0",
            "-p", f"own_ship_imu_topic:={IMU_TOPIC}", "-p", "wait_for_subscribers:=1", "-p", "end_linger_s:=0.5"]
    process = subprocess.Popen(args, env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    change = probe.node.create_client(ChangeState, "/camera/change_state")

    def transition(transition_id) -> bool:
        future = change.call_async(ChangeState.Request(transition=Transition(id=transition_id)))
        assert probe.spin_until(future.done, 30)
        return future.result().success

    try:
        assert probe.spin_until(change.service_is_ready, 60), "no lifecycle service from the camera"
        assert transition(Transition.TRANSITION_CONFIGURE)
        assert probe.spin_until(probe.matched, 30), "the probe's subscriptions did not match the camera"
        assert transition(Transition.TRANSITION_ACTIVATE)
        assert probe.spin_until(lambda: process.poll() is not None, 60), "the camera did not exit at the bag's end"
        probe.spin_until(lambda: len(probe.imus) >= len(samples) and len(probe.fixes) >= len(samples), 5)
        output = process.stdout.read()
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    try:
        assert process.returncode == 0, output
        assert [stamp(m) for m in probe.images] == image_stamps
        sample_stamps = [bag_messages.sec_to_ns(s.stamp) for s in samples]
        assert [stamp(m) for m in probe.fixes] == sample_stamps  # every one, in stamp order
        assert [stamp(m) for m in probe.imus] == sample_stamps
        for sample, fix, imu in zip(samples, probe.fixes, probe.imus, strict=True):
            position = position_of_navsatfix(fix)
            assert position.ok and (position.lat, position.lon) == (sample.lat, sample.lon)
            reading = sample_attitude_of_imu(imu)
            assert reading.ok and imu.header.frame_id == "base_link"
            assert reading.attitude.has_tilt == sample.attitude.has_tilt
            assert reading.attitude.heading_deg == pytest.approx(sample.attitude.heading_deg, abs=1e-9)
            if sample.attitude.has_tilt:
                assert reading.attitude.pitch_deg == pytest.approx(sample.attitude.pitch_deg, abs=1e-9)
                assert reading.attitude.roll_deg == pytest.approx(sample.attitude.roll_deg, abs=1e-9)
                assert reading.sigma_deg == pytest.approx(0.3)
        assert f"{2 * len(samples)} other messages" in output
        assert probe.spin_until(lambda: probe.camera_counts().get("count.aux_sent") == str(2 * len(samples)), 5)
        assert probe.camera_counts()["count.aux_bad"] == "0"
    finally:
        probe.close()
