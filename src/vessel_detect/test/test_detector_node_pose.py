"""The detector node poses each image: a camera on a moving ship, its own ship's Imu, the horizon in the image.

A moving copy of challenge video 7 is made once per session with ``../shared/tools/make_motion_set.py`` (every
frame warped by the rotation the ship gave the camera; ``own_ship.csv`` holds the exact attitude at 20 Hz). The node
runs in this process (``node_in_context``) with the shipped parameters (``config/aitas.yaml`` and the calibration
``config/aitas_camera.yaml``, the ship's reference attitude heading 76, level); the test publishes the ship's Imu
and the frames as the camera node does, and reads the Detection2DArray, ``/vessel/camera_pose``, the annotated
image and the node's problem counts (its ``NodeHealth``, and once ``/diagnostics``).

Needs the built workspace, ``../shared/aitas``, ``../shared/tools/make_motion_set.py`` and the shipped model;
skipped without them.
"""

from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.data]

REPO = Path(__file__).resolve().parents[3]
SHARED = REPO.parent / "shared"
DATA = SHARED / "aitas"
MAKER = SHARED / "tools" / "make_motion_set.py"
PARAMS_FILE = REPO / "config" / "aitas.yaml"
CALIBRATION = REPO / "config" / "aitas_camera.yaml"
MODEL = REPO / "models" / "vessel_yolox_nano.onnx"
VIDEO = 7
REFERENCE_ATTITUDE = [76.0, 0.0, 0.0]
# Frames of video 7 with a hand label. FRAME's and BAD_IMU_FRAME's stamps fall between two own_ship.csv rows (0.05 s
# apart): their attitude is interpolated, and a sample stamped exactly on them would be taken as is.
FRAME = 100        # the ship pitched 2.0 deg bow down, rolled 2.8 deg to starboard
STALE_FRAME = 200
NEXT_FRAME = 300
BAD_IMU_FRAME = 1900
COMPASS_FRAME = 1800

if not (DATA.joinpath("frames.csv").is_file() and MAKER.is_file()):
    pytest.skip(f"needs the challenge data at {DATA} and {MAKER} (absent here)", allow_module_level=True)
if not MODEL.is_file():
    pytest.skip(f"the shipped detector model {MODEL} is absent", allow_module_level=True)
rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")
pytest.importorskip("vessel_msgs.msg", reason="vessel_msgs is not built: run ./vessel setup")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import CompressedImage, Image, Imu  # noqa: E402

from vessel_calib.own_ship import OwnShipSample, ShipAttitude, quaternion_of_attitude  # noqa: E402
from vessel_detect.bag_messages import sec_to_ns  # noqa: E402
from vessel_detect.box_ops import box_iou  # noqa: E402
from vessel_detect.own_ship_messages import imu_of_sample  # noqa: E402
from vessel_detect.ros_messages import stamp_ns, time_msg  # noqa: E402
from vessel_msgs.msg import CameraPose, Detection2DArray  # noqa: E402

RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
IMU_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
IDENTITY = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
YELLOW = np.array([0, 230, 255])  # BGR of the measured horizon on the annotated image


# ---------------------------------------------------------------------------------------------------- data
class MotionSet:
    """The moving copy of video 7 and the unmoved original: frames, the ship's samples, the hand labels."""

    def __init__(self, folder: Path):
        from vessel_tools.calib.dataset import Dataset

        self.folder = folder
        self.moved, self.unmoved = Dataset(folder), Dataset(DATA)
        self.samples = [s for s in self.moved.own_ship() if s.attitude is not None]
        self.stamps = np.array([s.stamp for s in self.samples])
        self.frames = {r.frame: r for r in self.moved.frames([VIDEO])}
        self.unmoved_frames = {r.frame: r for r in self.unmoved.frames([VIDEO])}
        self.labels = {lab.frame: np.array([lab.x1, lab.y1, lab.x2, lab.y2])
                       for lab in self.unmoved.labels([VIDEO])}

    def truth(self, stamp: float) -> tuple[float, float, float]:
        """(heading, pitch, roll) of own_ship.csv interpolated at ``stamp``."""
        assert self.stamps[0] < stamp < self.stamps[-1]
        return tuple(float(np.interp(stamp, self.stamps, [getattr(s.attitude, f"{name}_deg") for s in self.samples]))
                     for name in ("heading", "pitch", "roll"))

    def around(self, stamp: float, before_s: float, after_s: float) -> list[OwnShipSample]:
        """The ship's samples from ``before_s`` before ``stamp`` to ``after_s`` after it."""
        return [s for s in self.samples if stamp - before_s <= s.stamp <= stamp + after_s]


@pytest.fixture(scope="session")
def motion_set(tmp_path_factory) -> MotionSet:
    """One moving copy of video 7 per session (about 4 s)."""
    out = tmp_path_factory.mktemp("motion") / "moved"
    result = subprocess.run([sys.executable, str(MAKER), "--data", str(DATA), "--calib", str(CALIBRATION), "--out",
                             str(out), "--videos", str(VIDEO)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return MotionSet(out)


def _file_parameters() -> list[Parameter]:
    """The detector's parameters as ``--params-file config/aitas.yaml --params-file config/aitas_camera.yaml``."""
    import yaml
    from rclpy.parameter import parameter_dict_from_yaml_file

    parameters = []
    for path in (PARAMS_FILE, CALIBRATION):
        nodes = set(yaml.safe_load(path.read_text()))
        assert "detector" in nodes or nodes == {"/**"}, f"{path}: blocks {nodes}"
        found = parameter_dict_from_yaml_file(str(path), use_wildcard=True,
                                              target_nodes=["detector"] if "detector" in nodes else None)
        parameters += [Parameter.from_parameter_msg(message) for message in found.values()]
    return parameters


def _shipped_values():
    """The same parameters as the core's values and the calibration (``CameraModel``)."""
    from vessel_detect.detector_params import load_params_files

    return load_params_files([PARAMS_FILE, CALIBRATION])


# ---------------------------------------------------------------------------------------------------- the rig
class Rig:
    """The detector node and a probe node in one context and executor: Imu and frames in, outputs recorded."""

    def __init__(self, monkeypatch, context, **overrides):
        from vessel_detect.detector_node import DetectorNode
        from vessel_fixtures.ros_nodes import node_in_context

        given = _file_parameters() + [Parameter("image_qos", value="reliable")]  # no 1 MB frame lost in transit
        given += [Parameter(name.replace("__", "."), value=value) for name, value in overrides.items()]
        with monkeypatch.context() as patch:  # the probe below is a plain node
            self.node = node_in_context(patch, context, DetectorNode, given)
        self.attitudes_added: list[float] = []  # stamps the node's poser was given (good samples only)
        add_attitude = self.node.poser.add_attitude

        def recording(stamp, attitude, sigma_deg=math.nan):
            self.attitudes_added.append(stamp)
            add_attitude(stamp, attitude, sigma_deg)

        monkeypatch.setattr(self.node.poser, "add_attitude", recording)
        self.probe = rclpy.create_node("detector_pose_test_probe", context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self.images = self.probe.create_publisher(CompressedImage, "/camera/image_raw/compressed", RELIABLE)
        self.imu = self.probe.create_publisher(Imu, "/own_ship/imu", IMU_QOS)
        self.detections: list[Detection2DArray] = []
        self.poses: list[CameraPose] = []
        self.annotated: list[Image] = []
        self.diagnostics: list[DiagnosticArray] = []
        self.probe.create_subscription(Detection2DArray, "/vessel/detections", self.detections.append, RELIABLE)
        self.probe.create_subscription(CameraPose, "/vessel/camera_pose", self.poses.append, RELIABLE)
        self.probe.create_subscription(Image, "/vessel/detections/image", self.annotated.append,
                                       qos_profile_sensor_data)
        self.probe.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, RELIABLE)
        own_ship = self.node.values["pose.source"] == "own_ship"
        annotated = self.node.annotated_pub
        matched = self.wait(lambda: self.images.get_subscription_count() > 0
                            and (not own_ship or self.imu.get_subscription_count() > 0)
                            and self.node.detections_pub.get_subscription_count() > 0
                            and self.node.pose_pub.get_subscription_count() > 0
                            and (annotated is None or annotated.get_subscription_count() > 0), 30.0)
        assert matched, "the probe and the detector did not match"

    def wait(self, predicate, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.02)
        return bool(predicate())

    def send_attitudes(self, samples, timeout_s: float = 20.0) -> None:
        """The ship's Imu for ``samples`` (in time order), until the node's poser holds them all."""
        wanted = len(self.attitudes_added) + len(samples)
        for sample in samples:
            self.imu.publish(imu_of_sample(sample, sigma_deg=0.1, heading_sigma_deg=0.5))
        assert self.wait(lambda: len(self.attitudes_added) >= wanted, timeout_s), \
            f"the node took {len(self.attitudes_added)} of {wanted} Imu samples"

    def send_frame(self, path: Path, stamp: float, timeout_s: float = 30.0) -> tuple[Detection2DArray, CameraPose]:
        """A frame as the camera node sends it; the node's Detection2DArray and /vessel/camera_pose for it."""
        message = CompressedImage()
        message.header.stamp = time_msg(sec_to_ns(stamp))
        message.header.frame_id = "camera"
        message.format = "jpeg"
        message.data = path.read_bytes()
        self.images.publish(message)
        wanted = stamp_ns(message.header.stamp)
        assert self.wait(lambda: self.output_for(wanted) is not None and self.pose_for(wanted) is not None,
                         timeout_s), f"no output for the frame stamped {stamp}: counts {self.node.health.counts}"
        return self.output_for(wanted), self.pose_for(wanted)

    def output_for(self, wanted_ns: int) -> Detection2DArray | None:
        return next((m for m in self.detections if stamp_ns(m.header.stamp) == wanted_ns), None)

    def pose_for(self, wanted_ns: int) -> CameraPose | None:
        return next((m for m in self.poses if stamp_ns(m.header.stamp) == wanted_ns), None)

    def close(self) -> None:
        self.node.close()
        self.executor.shutdown()
        self.probe.destroy_node()
        self.node.destroy_node()


@pytest.fixture
def start_rig(monkeypatch, ros_context):
    """``start_rig(**overrides)``: a Rig with parameter overrides (``pose__source="own_ship"``: pose.source)."""
    rigs: list[Rig] = []

    def start(**overrides) -> Rig:
        rigs.append(Rig(monkeypatch, ros_context, **overrides))
        return rigs[-1]

    yield start
    for rig in rigs:
        rig.close()


def _own_ship(**more) -> dict:
    return {"pose__source": "own_ship", "camera__reference_attitude_deg": REFERENCE_ATTITUDE, **more}


# ---------------------------------------------------------------------------------------------------- helpers
def _boxes(array: Detection2DArray) -> np.ndarray:
    return np.array([[d.bbox.center.position.x - d.bbox.size_x / 2, d.bbox.center.position.y - d.bbox.size_y / 2,
                      d.bbox.center.position.x + d.bbox.size_x / 2, d.bbox.center.position.y + d.bbox.size_y / 2]
                     for d in array.detections], float).reshape(-1, 4)


def _target_box(array: Detection2DArray) -> np.ndarray:
    """The box most likely the vessel of interest (its hypothesis of class vessel_of_interest)."""
    def p_target(detection) -> float:
        return max((h.hypothesis.score for h in detection.results if h.hypothesis.class_id == "vessel_of_interest"),
                   default=0.0)

    assert array.detections, "nothing detected"
    best = max(range(len(array.detections)), key=lambda i: p_target(array.detections[i]))
    assert p_target(array.detections[best]) > 0.5, "no vessel of interest detected"
    return _boxes(array)[best]


def _centre_distance(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.hypot((a[0] + a[2] - b[0] - b[2]) / 2, (a[1] + a[3] - b[1] - b[3]) / 2))


def _the_same_pose(a: CameraPose, b: CameraPose) -> bool:
    fields = ("valid", "source", "problem", "heading_deg", "pitch_deg", "roll_deg", "focal_px", "lens_k1",
              "horizon_found", "horizon_sigma_px")
    arrays = ("attitude_covariance", "camera_rotation_covariance", "image_to_reference", "horizon_ideal_abc")
    return (a.header == b.header and all(getattr(a, f) == getattr(b, f) for f in fields)
            and all(np.array_equal(getattr(a, f), getattr(b, f)) for f in arrays))


def _bad_imu(stamp: float, quaternion) -> Imu:
    message = imu_of_sample(OwnShipSample(stamp, math.nan, math.nan, ShipAttitude(76.0, 0.0, 10.0)), sigma_deg=0.1)
    message.orientation.x, message.orientation.y, message.orientation.z, message.orientation.w = quaternion
    return message


# ---------------------------------------------------------------------------------------------------- tests
def test_own_ship_pose_of_a_moved_frame_is_fused_with_the_horizon_and_maps_boxes_back(start_rig, motion_set):
    """The ship's Imu around the stamp, then the frame: a fused pose within 0.15 deg of the truth.

    The vessel of interest's box, mapped into the reference image by that pose, lies where the hand label of the
    unmoved frame is.
    """
    from vessel_track.pose_input import boxes_in_reference, pose_refusal

    rig = start_rig(**_own_ship())
    record = motion_set.frames[FRAME]
    assert record.frame in motion_set.labels
    samples = motion_set.around(record.stamp, 1.0, 0.5)
    assert samples[0].stamp < record.stamp < samples[-1].stamp and all(s.stamp != record.stamp for s in samples)
    rig.send_attitudes(samples)
    array, published = rig.send_frame(record.path, record.stamp)

    pose = array.camera_pose
    assert _the_same_pose(pose, published)
    assert pose.header.stamp == array.header.stamp and pose.header.frame_id == "camera"
    assert pose.valid and pose.source == CameraPose.SOURCE_FUSED and pose.problem == "", pose.problem
    heading, pitch, roll = motion_set.truth(record.stamp)
    assert abs(pitch) > 1.0 and abs(roll) > 1.0, "the ship barely moved at this frame: the test would prove little"
    assert abs(pose.pitch_deg - pitch) < 0.15 and abs(pose.roll_deg - roll) < 0.15, (pose, pitch, roll)
    assert abs(pose.heading_deg - heading) < 0.01  # the compass's, interpolated
    assert pose.horizon_found and 0 < pose.horizon_sigma_px < 2.0
    matrix = np.array(pose.image_to_reference).reshape(3, 3)
    assert np.all(np.isfinite(matrix)) and not np.allclose(matrix, np.eye(3), atol=1e-3)
    assert pose.focal_px > 0 and pose_refusal(pose) is None
    assert all(np.isfinite(pose.attitude_covariance)) and pose.attitude_covariance[0] > 0

    label = motion_set.labels[FRAME]
    box = _target_box(array)
    mapped = boxes_in_reference(pose, box[None, :])[0]
    # The detector's box on the unmoved frame is itself 6.5 px from the hand label (IoU 0.60); unmapped, 110 px.
    assert box_iou(label[None, :], mapped[None, :])[0, 0] >= 0.45, (mapped, label)
    assert _centre_distance(mapped, label) < 12.0, (mapped, label)
    assert _centre_distance(box, label) > 50.0, "unmapped, the box is near the label: the frame barely moved"

    counts = rig.node.health.counts
    assert counts["frames_processed"] == 1 and counts["stale_pose"] == counts["bad_attitude"] == 0
    assert counts["horizon_not_found"] == counts["horizon_rejected"] == counts["no_pose"] == 0


def test_a_stale_pose_is_refused_and_counted_and_the_next_frame_is_posed(start_rig, motion_set):
    """Samples only seconds before the stamp: camera_pose not valid (stale), counted on /diagnostics.

    The node goes on and poses the next frame, whose samples arrive.
    """
    rig = start_rig(**_own_ship(pose__wait_s=0.05))
    record = motion_set.frames[STALE_FRAME]
    rig.send_attitudes(motion_set.around(record.stamp - 5.0, 1.0, 0.0))  # 6 s to 5 s before the frame
    array, published = rig.send_frame(record.path, record.stamp)
    pose = array.camera_pose
    assert _the_same_pose(pose, published)
    assert not pose.valid and pose.source == CameraPose.SOURCE_OWN_SHIP and "stale" in pose.problem, pose.problem
    assert all(math.isfinite(v) for v in (pose.pitch_deg, pose.roll_deg, *pose.attitude_covariance))  # no NaN sent
    counts = rig.node.health.counts
    assert counts["stale_pose"] == 1 and counts["frames_processed"] == 1, counts

    rig.node.health.publish()  # the report the node sends every second, now

    def reported() -> dict[str, str]:
        for diagnostics in reversed(rig.diagnostics):
            for status in diagnostics.status:
                if status.name == "detector":
                    return {kv.key: kv.value for kv in status.values}
        return {}

    assert rig.wait(lambda: reported().get("count.stale_pose") == "1", 10.0), reported()
    assert reported()["pose_valid"] == "0"

    following = motion_set.frames[NEXT_FRAME]
    rig.send_attitudes(motion_set.around(following.stamp, 1.0, 0.5))
    array, _ = rig.send_frame(following.path, following.stamp)
    pose = array.camera_pose
    assert pose.valid and pose.source == CameraPose.SOURCE_FUSED, pose.problem
    _, pitch, roll = motion_set.truth(following.stamp)
    assert abs(pose.pitch_deg - pitch) < 0.15 and abs(pose.roll_deg - roll) < 0.15
    assert rig.node.health.counts["stale_pose"] == 1


def test_an_imu_with_a_nan_or_non_unit_quaternion_is_counted_as_bad_attitude_and_not_used(start_rig, motion_set):
    """Bad samples stamped exactly on the frame's (off the 20 Hz grid: used, they would be its attitude) are dropped."""
    rig = start_rig(**_own_ship())
    record = motion_set.frames[BAD_IMU_FRAME]
    samples = motion_set.around(record.stamp, 1.0, 0.5)
    assert all(s.stamp != record.stamp for s in samples)
    rig.send_attitudes(samples)
    taken = len(rig.attitudes_added)
    tilted = quaternion_of_attitude(ShipAttitude(76.0, 0.0, 10.0))  # rolled 10 deg: far off the truth
    rig.imu.publish(_bad_imu(record.stamp, (math.nan, 0.0, 0.0, 1.0)))
    rig.imu.publish(_bad_imu(record.stamp, tuple(1.5 * q for q in tilted)))
    assert rig.wait(lambda: rig.node.health.counts["bad_attitude"] == 2, 20.0), rig.node.health.counts
    assert len(rig.attitudes_added) == taken

    array, _ = rig.send_frame(record.path, record.stamp)
    pose = array.camera_pose
    assert pose.valid and pose.source == CameraPose.SOURCE_FUSED, pose.problem
    _, pitch, roll = motion_set.truth(record.stamp)
    assert abs(pose.pitch_deg - pitch) < 0.15 and abs(pose.roll_deg - roll) < 0.15, (pose, pitch, roll)
    counts = rig.node.health.counts
    assert counts["bad_attitude"] == 2 and counts["horizon_rejected"] == 0 and counts["stale_pose"] == 0


def test_a_compass_alone_gets_pitch_and_roll_from_the_horizon(start_rig, motion_set):
    """Imu with roll and pitch variances -1 and the heading: a valid pose from the horizon (source 3)."""
    rig = start_rig(**_own_ship())
    record = motion_set.frames[COMPASS_FRAME]
    compass = [OwnShipSample(s.stamp, s.lat, s.lon, ShipAttitude(s.attitude.heading_deg))
               for s in motion_set.around(record.stamp, 1.0, 0.5)]
    message = imu_of_sample(compass[0], sigma_deg=0.1, heading_sigma_deg=0.5)
    assert message.orientation_covariance[0] == message.orientation_covariance[4] == -1.0
    rig.send_attitudes(compass)
    array, _ = rig.send_frame(record.path, record.stamp)
    pose = array.camera_pose
    assert pose.valid and pose.source == CameraPose.SOURCE_HORIZON and pose.horizon_found, pose.problem
    heading, pitch, roll = motion_set.truth(record.stamp)
    assert abs(pitch) > 1.0 or abs(roll) > 1.0
    assert abs(pose.pitch_deg - pitch) < 0.3 and abs(pose.roll_deg - roll) < 0.3, (pose, pitch, roll)
    assert abs(pose.heading_deg - heading) < 0.01
    assert not np.allclose(np.array(pose.image_to_reference).reshape(3, 3), np.eye(3), atol=1e-3)
    assert rig.node.health.counts["bad_attitude"] == 0


def test_a_fixed_camera_keeps_the_identity_pose_and_the_detections_of_the_core_without_a_view(start_rig, motion_set):
    """pose.source fixed (the default) on an unmoved frame: FIXED, identity exactly, boxes exactly the core's."""
    from vessel_detect.detector_params import build_detector
    from vessel_detect.image_codec import compressed_to_bgr

    rig = start_rig()
    assert rig.node.values["pose.source"] == "fixed"
    record = motion_set.unmoved_frames[FRAME]
    array, published = rig.send_frame(record.path, record.stamp)
    pose = array.camera_pose
    assert _the_same_pose(pose, published)
    assert pose.valid and pose.source == CameraPose.SOURCE_FIXED and pose.problem == ""
    assert list(pose.image_to_reference) == IDENTITY and pose.focal_px == 0.0
    assert not pose.horizon_found  # a fixed camera measures the horizon only for the annotated image

    values, camera = _shipped_values()
    core = build_detector(values, camera)
    bgr = compressed_to_bgr(record.path.read_bytes(), "jpeg")
    expected = core.detect(bgr).in_calibrated_pixels(bgr.shape[1::-1], core.reference_wh)
    assert len(expected) > 0 and len(array.detections) == len(expected)
    for detection, box, score, label in zip(array.detections, expected.boxes_xyxy, expected.scores,
                                            expected.labels(), strict=True):
        x1, y1, x2, y2 = (float(v) for v in box)
        assert (detection.bbox.center.position.x, detection.bbox.center.position.y) == ((x1 + x2) / 2, (y1 + y2) / 2)
        assert (detection.bbox.size_x, detection.bbox.size_y) == (x2 - x1, y2 - y1)
        assert (detection.results[0].hypothesis.class_id, detection.results[0].hypothesis.score) == (label, score)


def test_the_annotated_image_of_a_moved_frame_draws_the_measured_horizon(start_rig, motion_set):
    """Yellow along the horizon the node measured, where the same frame annotated without a view has none."""
    from vessel_calib.radial_lens import RadialLens
    from vessel_detect.annotation import annotate
    from vessel_detect.detector import Detections
    from vessel_detect.image_codec import compressed_to_bgr

    scale = 0.5
    rig = start_rig(**_own_ship(publish_annotated=True, annotated_scale=scale))
    record = motion_set.frames[FRAME]
    rig.send_attitudes(motion_set.around(record.stamp, 1.0, 0.5))
    pose = None
    for attempt in range(3):  # the annotated image is best effort (sensor data QoS): one may be lost
        stamp = record.stamp + 0.001 * attempt
        _, pose = rig.send_frame(record.path, stamp)
        if rig.wait(lambda: rig.annotated, 10.0):
            break
    assert rig.annotated, "no annotated image"
    assert pose.valid and pose.horizon_found, pose.problem
    message = rig.annotated[0]
    assert (message.encoding, message.width, message.height) == ("bgr8", 640, 360)
    with_view = np.frombuffer(bytes(message.data), np.uint8).reshape(360, 640, 3)
    bgr = compressed_to_bgr(record.path.read_bytes(), "jpeg")
    without = annotate(bgr, Detections.empty(), rig.node.detector, scale, None)

    def yellow(image: np.ndarray) -> np.ndarray:
        return np.all(np.abs(image.astype(int) - YELLOW) <= 30, axis=2)

    drawn = yellow(with_view) & ~yellow(without)
    rows, cols = np.nonzero(drawn)
    assert len(np.unique(cols)) > 0.9 * 640, "the horizon is not drawn across the image"
    a, b, c = pose.horizon_ideal_abc
    norm = math.hypot(a, b)
    lens = RadialLens(pose.lens_k1, (pose.lens_center.x, pose.lens_center.y))
    line_y = np.asarray(lens.line_y((a / norm, b / norm, c / norm), (cols + 0.5) / scale), float) * scale
    assert np.all(np.abs(rows - line_y) < 3.0), np.max(np.abs(rows - line_y))
    assert abs(np.median(rows - line_y)) < 1.0
    assert not yellow(without).any() or yellow(without).sum() < 0.1 * drawn.sum()
