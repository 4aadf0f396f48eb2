"""Detector node: camera images in, ``vessel_msgs/Detection2DArray`` (vision_msgs-style) out.

Subscribes to ``CompressedImage`` and/or ``Image`` (sensor-data QoS by default), runs the ROS-free
:class:`vessel_detect.detector.VesselDetector` on the band below the horizon of the calibration, and publishes
one ``Detection2DArray`` per processed image with the image's header (reliable, depth 10). Each detection has
the box centre and size in full-resolution pixels and one hypothesis: ``class_id`` = the class name, ``score``.

Inference runs in a worker thread on the newest image only: when images arrive faster than the detector runs,
the ones it cannot take are skipped and counted (``dropped_frames``), so the output never lags behind a live
camera. With ``decode_ahead`` a second thread decodes the next waiting image while the network runs on the
current one, so the JPEG decode does not add to the time per frame when images queue up (a replay as fast as the
detector goes). At most one image is decoded ahead per processed frame, so a camera faster than the detector costs
at most one wasted decode per frame; the diagnostics' ``latency_ms_*`` leave out a decode done ahead. Bad images
(unsupported encoding, size 0, undecodable bytes) are logged once per kind, counted and skipped. Latency, rates
and counts go to ``/diagnostics``. A missing or corrupt model stops the node at start with one ``error:`` line
(exit status 2).

    ros2 run vessel_detect detector --ros-args --params-file config/aitas.yaml
    ros2 run vessel_detect detector --ros-args -p mode:=band -p score_threshold:=0.3 -p publish_annotated:=true
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from sensor_msgs.msg import CompressedImage, Image, Imu

from vessel_calib.camera_parameters import declare_camera_model
from vessel_common.errors import VesselError
from vessel_common.health import NodeHealth, steady_timer
from vessel_common.lifecycle import PhasedLifecycle, release_publisher
from vessel_common.node_parameters import declare_table
from vessel_common.qos import SENSOR_DATA_QOS, image_qos_profile, reliable_qos, sensor_stream_qos, stamp_to_sec
from vessel_common.run import main_for
from vessel_detect.annotation import annotate
from vessel_detect.detector import Detections
from vessel_detect.detector_params import (
    DETECTOR_PARAMETERS,
    NODE_NAME,
    attitude_settings,
    build_detector,
    detector_config,
    frame_poser,
    model_spec,
    open_model,
)
from vessel_detect.detector_sharing import SharedDetection
from vessel_detect.image_codec import ImageError, bgr_to_image_fields, compressed_to_bgr, image_to_bgr
from vessel_detect.image_queue import ImageQueue, QueuedImage
from vessel_detect.own_ship_messages import sample_attitude_of_imu
from vessel_detect.pose_messages import camera_pose_msg
from vessel_msgs.msg import CameraPose, Detection2D, Detection2DArray, ObjectHypothesisWithPose

PROBLEM_KINDS = ("bad_encoding", "empty_image", "bad_image_size", "wrong_image_size", "undecodable_image",
                 "detector_error", "stale_pose", "no_pose", "bad_attitude", "horizon_not_found", "horizon_rejected")
EVENT_KINDS = ("frames_received", "frames_processed", "dropped_frames", "detections_published")
LATENCY_WINDOW = 200


def _decoded(kind: str, message) -> np.ndarray:
    """The BGR pixels of a ``CompressedImage`` (``kind`` "compressed") or an ``Image`` ("raw"); ImageError if bad."""
    if kind == "compressed":
        return compressed_to_bgr(message.data, message.format)
    return image_to_bgr(message.encoding, message.height, message.width, message.step, message.data)


def detections_to_msg(detections: Detections, header, target_class: str = "") -> Detection2DArray:
    """A ``Detection2DArray`` with ``header`` for detections in full-resolution pixels.

    Each detection's first hypothesis is its class and score; with ``target_class`` and a finite ``p_target``
    a hypothesis of that class with the probability of being the vessel of interest follows (unless the
    first one already is that class), as vision_msgs' list of hypotheses allows.
    """
    array = Detection2DArray()
    array.header = header
    labels = detections.labels()
    for box, score, label, p_target in zip(detections.boxes_xyxy, detections.scores, labels, detections.p_target,
                                           strict=True):
        detection = Detection2D()
        detection.header = header
        x1, y1, x2, y2 = (float(v) for v in box)
        detection.bbox.center.position.x = (x1 + x2) / 2.0
        detection.bbox.center.position.y = (y1 + y2) / 2.0
        detection.bbox.center.theta = 0.0
        detection.bbox.size_x = x2 - x1
        detection.bbox.size_y = y2 - y1
        hypothesis = ObjectHypothesisWithPose()
        hypothesis.hypothesis.class_id = label
        hypothesis.hypothesis.score = float(score)
        detection.results = [hypothesis]
        if target_class and label != target_class and math.isfinite(float(p_target)):
            target = ObjectHypothesisWithPose()
            target.hypothesis.class_id = target_class
            target.hypothesis.score = float(p_target)
            detection.results.append(target)
        detection.id = ""
        array.detections.append(detection)
    return array


class _DetectorPhases:
    """The detector node's work, phase by phase, shared by the plain node and the managed (lifecycle) one.

    ``_declare`` (parameters, calibration, health reports), ``_configure`` (the model loaded, the output
    publishers), ``_activate`` (image subscriptions and the worker thread), ``_deactivate`` (both stopped) and
    ``_cleanup`` (the model and publishers released). With ``shared`` (the detectors of several cameras in one
    process, ``detector_sharing``) the model and the worker are the process's, not the node's.
    """

    shared: SharedDetection | None = None

    def _size_prior_note(self) -> str:
        """For the start-up log: the size prior when on."""
        prior = self.detector.size_prior
        if not prior.enabled:
            return ""
        return f", p_target lowered for boxes over {math.exp(prior.tolerance):.2f}x the vessel's {prior.dimension}"

    def _declare(self) -> None:
        self.detector = None
        self.values = declare_table(self, DETECTOR_PARAMETERS, apply=self._apply_parameters)
        needs_camera = (self.values["pose.source"] != "fixed" or self.values["size_prior.dimension"] != "none"
                        or bool(self.values["appearance_model"]))
        self.camera = declare_camera_model(self, required=needs_camera)
        if self.camera is None:
            self.get_logger().info("no calibration given: detecting without one (a camera not calibrated yet)")
        values = self.values
        if not (values["subscribe_compressed"] or values["subscribe_raw"]):
            raise VesselError("detector subscribes to nothing: set subscribe_compressed or subscribe_raw to true")
        self.detections_pub = None
        self.annotated_pub = None
        self.pose_pub = None
        self.poser = None
        self._image_subscriptions = []
        self._worker = None
        self._decode_ahead_thread = None
        self._queue: ImageQueue | None = None
        self.health = NodeHealth(self, hardware_id="detector")
        for kind in PROBLEM_KINDS + EVENT_KINDS:
            self.health.count(kind, 0)
        for key in ("latency_ms_last", "latency_ms_p50", "latency_ms_p95", "input_to_output_ms_p50",
                    "frames_per_s", "windows_per_frame", "detections_last"):
            self.health.set_value(key, float("nan"))
        self._latencies: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self._end_to_end: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self._processed_times: deque[float] = deque(maxlen=LATENCY_WINDOW)
        steady_timer(self, 1.0, self._report)

    def _make_publisher(self, message_type, topic: str, qos):
        return self.create_publisher(message_type, topic, qos)

    def _configure(self) -> None:
        values = self.values
        model = None
        if self.shared is not None:
            key = (model_spec(values), int(values["intra_op_threads"]), str(values["layout"]),
                   str(values["class_names_file"]))
            model = self.shared.model(key, lambda: open_model(values))
        self.detector = build_detector(values, self.camera, model=model)
        self.poser = frame_poser(values, self.camera)
        if self.detector.horizon_y is None:
            self.get_logger().warning("the calibration gives no horizon in the image: processing the whole height")
        self.health.set_value("windows_per_frame", len(self.detector.windows(self.detector.reference_wh)))
        self.detections_pub = self._make_publisher(
            Detection2DArray, values["detections_topic"], reliable_qos(int(values["detections_qos_depth"])))
        self.health.watch_subscribers(self.detections_pub)
        if values["publish_annotated"]:
            self.annotated_pub = self._make_publisher(Image, values["annotated_topic"], SENSOR_DATA_QOS)
        self.pose_pub = self._make_publisher(CameraPose, values["pose.topic"], reliable_qos(10))

    def _activate(self) -> None:
        values = self.values
        qos = image_qos_profile(values["image_qos"])
        if self.shared is not None:  # the process's worker takes this camera's newest image in its turn
            self._queue = ImageQueue(int(values["images_waiting"]), _decoded, on_put=self.shared.wake)
            self.shared.join(self)
        else:
            self._queue = queue = ImageQueue(int(values["images_waiting"]), _decoded)
            self._worker = threading.Thread(target=self._work, args=(queue,), name="detector-worker", daemon=True)
            self._worker.start()
        if values["decode_ahead"] and self.shared is None:
            self._decode_ahead_thread = threading.Thread(target=queue.decode_ahead, name="detector-decode-ahead",
                                                         daemon=True)
            self._decode_ahead_thread.start()
        if values["subscribe_compressed"]:
            self._image_subscriptions.append(self.create_subscription(
                CompressedImage, values["compressed_topic"], lambda m: self._on_image("compressed", m), qos))
        if values["subscribe_raw"]:
            self._image_subscriptions.append(self.create_subscription(
                Image, values["raw_topic"], lambda m: self._on_image("raw", m), qos))
        if values["pose.source"] == "own_ship":
            self._image_subscriptions.append(self.create_subscription(
                Imu, values["pose.imu_topic"], self._on_imu, sensor_stream_qos(values["pose.imu_qos"])))
        topics = [values["compressed_topic"]] if values["subscribe_compressed"] else []
        topics += [values["raw_topic"]] if values["subscribe_raw"] else []
        config = self.detector.config
        self.get_logger().info(
            f"detecting {','.join(config.classes)} with {self.detector.model.path} ({self.detector.model.layout}, "
            f"{config.mode}, {len(self.detector.windows(self.detector.reference_wh))} network runs per "
            f"{self.detector.reference_wh[0]}x{self.detector.reference_wh[1]} frame, score >= "
            f"{config.score_threshold}{self._size_prior_note()}) on {', '.join(topics)} -> "
            f"{values['detections_topic']}"
        )

    def _deactivate(self) -> None:
        for subscription in self._image_subscriptions:
            self.destroy_subscription(subscription)
        self._image_subscriptions = []
        self.close()

    def _cleanup(self) -> None:
        for publisher in (self.detections_pub, self.annotated_pub, self.pose_pub):
            if publisher is not None:
                self.health.unwatch(publisher)
                release_publisher(self, publisher)
        self.detections_pub = self.annotated_pub = self.pose_pub = None
        self.detector = None  # the ONNX session and its memory go with it


    def _apply_parameters(self, values) -> None:
        """A live change of the thresholds (the table's live rows), checked as at start, used from the next image."""
        config = detector_config(values)
        settings = attitude_settings(values)
        self.values = values
        if self.detector is not None:  # a managed node not configured yet builds its detector from self.values
            self.detector.config = config
        if self.poser is not None:
            self.poser.settings = self.poser.estimator.settings = settings

    # ------------------------------------------------------------------------------------------------ input
    def _on_image(self, kind: str, message) -> None:
        """Keep the newest ``images_waiting`` images; an older one the worker did not take yet is dropped, counted."""
        queue = self._queue
        if queue is None:
            return
        self.health.count("frames_received")
        self.health.observe_input(stamp_to_sec(message.header.stamp))
        dropped = queue.put(kind, message, time.monotonic())
        if dropped:
            self.health.count("dropped_frames", dropped)

    def _on_imu(self, message) -> None:
        """The ship's attitude: into the poser, or counted as bad_attitude (NaN, not a unit quaternion)."""
        reading = sample_attitude_of_imu(message)
        if not reading.ok:
            self.health.problem("bad_attitude", f"own-ship attitude dropped: {reading.reason}")
            return
        self.poser.add_attitude(stamp_to_sec(message.header.stamp), reading.attitude, reading.sigma_deg)

    # ------------------------------------------------------------------------------------------------ worker
    @property
    def queue(self) -> ImageQueue | None:
        """The images waiting for the network (a ``detector_sharing.Member``'s queue)."""
        return self._queue

    def _work(self, queue: ImageQueue) -> None:
        while True:
            item = queue.take()
            if item is None:
                return
            self.process_safely(item)

    def process_safely(self, item: QueuedImage) -> None:
        """Detect on one image and publish; a bad image or a failure is counted, never raised."""
        try:
            self._process(item)
        except ImageError as error:
            self.health.problem(error.kind, f"bad image skipped: {error}")
        except VesselError as error:
            self.health.problem("detector_error", f"frame skipped: {error}")
        except Exception as error:  # a bug must not silence the camera feed: count it and go on
            self.health.problem("detector_error", f"frame skipped after an unexpected {type(error).__name__}: "
                                f"{error}")

    def _process(self, item: QueuedImage) -> None:
        started = time.monotonic()
        message, received = item.message, item.received
        bgr = item.pixels()
        height, width = bgr.shape[:2]
        pose = self.poser.pose_of(stamp_to_sec(message.header.stamp), bgr)
        if pose.problem_kind:
            self.health.problem(pose.problem_kind, f"camera pose: {pose.estimate.problem or pose.problem_kind}")
        self._report_pose(pose)
        moving = self.values["pose.source"] != "fixed"
        in_image_pixels = self.detector.detect(bgr, pose.view if moving else None)
        detections = in_image_pixels.in_calibrated_pixels((width, height), self.detector.reference_wh)
        header = message.header
        if not header.frame_id and self.values["frame_id"]:
            header.frame_id = self.values["frame_id"]
        out = detections_to_msg(detections, header, self.detector.config.target_class)
        mounting = self.poser.mounting
        out.camera_pose = camera_pose_msg(pose, header, self.camera,
                                          np.eye(3) if mounting is None else mounting.camera_from_body)
        self.pose_pub.publish(out.camera_pose)
        self.detections_pub.publish(out)
        finished = time.monotonic()
        self._latencies.append((finished - started) * 1000.0)
        self._end_to_end.append((finished - received) * 1000.0)
        self._processed_times.append(finished)
        self.health.count("frames_processed")
        self.health.count("detections_published", len(detections))
        self.health.set_value("detections_last", len(detections))
        if self.annotated_pub is not None and self.annotated_pub.get_subscription_count() > 0:
            image = Image()
            image.header = header
            for field, value in bgr_to_image_fields(
                annotate(bgr, in_image_pixels, self.detector, float(self.values["annotated_scale"]), pose.view)
            ).items():
                setattr(image, field, value)
            self.annotated_pub.publish(image)

    # ------------------------------------------------------------------------------------------------ health
    def _report_pose(self, pose) -> None:
        """The attitude used and the horizon measured, on /diagnostics (NaN: none for this image)."""
        estimate, edge = pose.estimate, pose.edge
        self.health.set_value("pose_valid", float(estimate.valid))
        for key, value in (("pose_heading_deg", estimate.heading_deg), ("pose_pitch_deg", estimate.pitch_deg),
                           ("pose_roll_deg", estimate.roll_deg)):
            self.health.set_value(key, float(value))
        found = edge is not None and edge.found
        self.health.set_value("horizon_found", float(found))
        self.health.set_value("horizon_sigma_px", float(edge.sigma_px) if found else float("nan"))

    def _report(self) -> None:
        latencies = np.array(self._latencies)
        if latencies.size:
            self.health.set_value("latency_ms_last", float(latencies[-1]))
            self.health.set_value("latency_ms_p50", float(np.percentile(latencies, 50)))
            self.health.set_value("latency_ms_p95", float(np.percentile(latencies, 95)))
            self.health.set_value("input_to_output_ms_p50", float(np.percentile(np.array(self._end_to_end), 50)))
        times = list(self._processed_times)
        if len(times) >= 2 and times[-1] > times[0]:
            self.health.set_value("frames_per_s", (len(times) - 1) / (times[-1] - times[0]))
        counts = self.health.counts
        if counts.get("frames_received", 0) and not counts.get("frames_processed", 0):
            self.health.set_status(DiagnosticStatus.WARN, "receiving images, none processed yet")
        else:
            self.health.set_status(DiagnosticStatus.OK, "running")

    def close(self) -> None:
        """Stop the worker and decode-ahead threads (run_node at shutdown; a managed node when it deactivates).

        Images still waiting are counted as dropped, so the counters balance.
        """
        if self.shared is not None:
            self.shared.leave(self)
        if self._queue is not None:
            dropped = self._queue.stop()
            if dropped:
                self.health.count("dropped_frames", dropped)
        for thread in (self._worker, self._decode_ahead_thread):
            if thread is not None and thread.is_alive():
                thread.join(timeout=5.0)
        self._worker = self._decode_ahead_thread = self._queue = None


class DetectorNode(_DetectorPhases, Node):
    """Run the vessel detector on the newest camera image; see the module docstring."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self._declare()
        self._configure()
        self._activate()


class ManagedDetectorNode(PhasedLifecycle, _DetectorPhases, LifecycleNode):
    """The detector as a managed (lifecycle) node: ``ros2 run vessel_detect detector_managed``.

    unconfigured -> configure (the model is loaded, publishers made) -> inactive -> activate (images are taken
    and detections published) -> active; deactivate stops taking images, cleanup releases the model, shutdown
    from any state. Parameters are declared at start, so ``ros2 param`` works in every state. A configure that
    fails (no model) logs why and leaves the node unconfigured.
    """

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self._declare()

    def _make_publisher(self, message_type, topic: str, qos):
        return self.create_lifecycle_publisher(message_type, topic, qos)


main = main_for(DetectorNode)
main_managed = main_for(ManagedDetectorNode)


if __name__ == "__main__":
    main()
