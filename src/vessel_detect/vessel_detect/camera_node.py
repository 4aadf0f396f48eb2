"""Camera ingest node: feeds images into the graph from a bag, video, image folder or live camera.

Recorded sources replay with their original stamps at a rate factor (1 = real time, 10 = ten times faster, 0 = as
fast as the graph consumes: each frame waits for the detector's output for the previous one or a timeout), publish
`/clock` from the stamps so the graph can run with `use_sim_time`, and republish the camera's fix and the vessel's
GPS truth recorded in a bag. A frame that cannot be read is skipped, counted and logged once; the node never
stops on a bad frame. At the end of a recorded source (without `loop`) it logs a summary and exits with status 0,
so scripts can wait for it. Progress and frame counts go to `/diagnostics`.

    ros2 run vessel_detect camera --ros-args -p source:=bags/video_13 -p rate:=10.0
    ros2 run vessel_detect camera --ros-args -p source:=device:0 -p publish_raw:=true
"""

from __future__ import annotations

import array
import threading
import time
from collections import deque
from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CompressedImage, Image, NavSatFix, NavSatStatus

from vessel_calib.camera_parameters import DEFAULT_CAMERA_PARAMETERS
from vessel_common.errors import DataError, VesselError
from vessel_common.node_support import (
    LATCHED_QOS,
    NodeHealth,
    PhasedLifecycle,
    declare_parameter,
    image_qos_profile,
    main_for,
    release_publisher,
    reliable_qos,
)
from vessel_detect import bag_io
from vessel_detect.ros_messages import NS_PER_S, message_class, stamp_ns, time_msg
from vessel_detect.sources import AuxMessage, Frame, ImageSource, open_source, parse_utc


@dataclass
class ReplayStats:
    """Frames and messages the node handled."""

    sent: int = 0
    dropped: int = 0
    bad: int = 0
    aux_sent: int = 0
    ack_timeouts: int = 0
    unanswered: int = 0
    late: int = 0


class _CameraPhases:
    """The camera node's work, phase by phase, shared by the plain node and the managed (lifecycle) one.

    ``_declare`` (parameters, health reports), ``_configure`` (the source opened, the publishers made),
    ``_activate`` (the replay thread started), ``_deactivate`` (stopped) and ``_cleanup`` (the source closed and
    the publishers released).
    """

    def _declare(self) -> None:
        self.params = self._declare_parameters()
        self.health = NodeHealth(self, hardware_id="camera")
        self.stats = ReplayStats()
        # Every key exists before the replay thread starts: the diagnostics timer iterates these dicts.
        kinds = ("frames_sent", "frames_dropped", "frames_bad", "frames_late", "ack_timeouts", "frames_unanswered",
                 "aux_sent", "aux_bad")
        for kind in kinds:
            self.health.count(kind, 0)
        for key in ("progress", "source", "stamp", "rate"):
            self.health.set_value(key, "")
        self.finished = False
        self.exit_status = 0
        self._stop = threading.Event()
        self._ack = threading.Condition()
        self._acked_ns: int | None = None
        self._acked_recent: deque[int] = deque(maxlen=64)  # stamps whose detections arrived
        self._newest_sent_ns: int | None = None  # acks of later stamps are stale (a loop that kept the stamps)
        self.source: ImageSource | None = None
        self._worker: threading.Thread | None = None
        self._camera_publishers: list = []
        self._ack_subscription = None

    def _make_publisher(self, message_type, topic: str, qos):
        publisher = self.create_publisher(message_type, topic, qos)
        self._camera_publishers.append(publisher)
        return publisher

    def _configure(self) -> None:
        p = self.params
        self.source = open_source(
            p["source"],
            image_topic=p["image_topic"],
            aux_topics=[p["camera_fix_topic"], p["gps_truth_topic"]] if p["republish"] else [],
            start_utc=parse_utc(p["start_utc"]) if p["start_utc"] else None,
            fps=p["fps"] or None,
            device_width=p["device_width"],
            device_height=p["device_height"],
            start_offset_s=p["start_offset_s"],
            loop=p["loop"],
            restamp_loops=p["loop_restamp"],
            on_problem=self._source_problem,
        )
        self.live = self.source.is_live
        self.rate = 1.0 if self.live else p["rate"]
        self.publish_clock = p["publish_clock"] and not self.live
        self.exit_at_end = p["exit_at_end"] and not self.live
        self.total_frames = self.source.frame_count()
        self.health.set_value("source", self.source.description)
        self.damage = getattr(self.source, "damage", "")
        if self.damage:
            self.health.problem("source_damaged", f"the source is damaged; playing what can be read: {self.damage}")
        self.health.set_value("rate", "live" if self.live else ("as consumed" if self.rate == 0 else self.rate))

        image_qos = image_qos_profile(p["image_qos"], reliable_depth=10)
        self.compressed_pub = (
            self._make_publisher(CompressedImage, p["compressed_topic"], image_qos)
            if p["publish_compressed"]
            else None
        )
        self.raw_pub = self._make_publisher(Image, p["raw_topic"], image_qos) if p["publish_raw"] else None
        self.clock_pub = self._make_publisher(Clock, "/clock", 10) if self.publish_clock else None
        self.aux_pubs: dict[str, tuple[object, type]] = {}
        self.camera_fix_pub = self._make_publisher(NavSatFix, p["camera_fix_topic"], LATCHED_QOS)
        self.aux_pubs[p["camera_fix_topic"]] = (self.camera_fix_pub, NavSatFix)
        if p["republish"] and getattr(self.source, "aux_topics", None):
            if p["gps_truth_topic"] in self.source.aux_topics:
                self.aux_pubs[p["gps_truth_topic"]] = (
                    self._make_publisher(NavSatFix, p["gps_truth_topic"], reliable_qos(50)),
                    NavSatFix,
                )
        if self.rate == 0:
            self._ack_subscription = self.create_subscription(
                message_class(p["ack_type"]), p["ack_topic"], self._on_ack, reliable_qos(10)
            )

    def _activate(self) -> None:
        p = self.params
        if p["camera_fix_from_parameters"] and p["camera_fix_topic"] not in getattr(self.source, "aux_topics", []):
            self._publish_parameter_fix()
        how = "live" if self.live else ("as fast as consumed" if self.rate == 0 else f"at {self.rate:g}x")
        count = f"{self.total_frames} frames" if self.total_frames else "frames"
        self.get_logger().info(
            f"publishing {count} of {self.source.description} {how}"
            f"{', with /clock' if self.publish_clock else ''}{', looping' if p['loop'] else ''}"
        )
        self._stop.clear()
        self._worker = threading.Thread(target=self._run, name="camera-replay", daemon=True)
        self._worker.start()

    def _deactivate(self) -> None:
        self._stop.set()
        with self._ack:
            self._ack.notify_all()
        stop = getattr(self.source, "stop", None)
        if stop is not None:
            stop()
        if self._worker is not None and self._worker.is_alive():
            self._worker.join(timeout=2.0)
        self._worker = None

    def _cleanup(self) -> None:
        if self.source is not None:
            self.source.close()
            self.source = None
        for publisher in self._camera_publishers:
            release_publisher(self, publisher)
        self._camera_publishers = []
        if self._ack_subscription is not None:
            self.destroy_subscription(self._ack_subscription)
            self._ack_subscription = None

    def _declare_parameters(self) -> dict:
        d = {}

        def param(name, default, description, **kw):
            d[name] = declare_parameter(self, name, default, description, **kw)

        param("source", "", "What to publish: rosbag2 folder, .mcap file, video file, image folder, or device:N "
              "(OpenCV camera index), /dev/videoN, rtsp://... stream.")
        param("rate", 1.0, "Replay speed factor for recorded sources: 1.0 real time, 10.0 ten times faster, 0 = as "
              "fast as the graph consumes (next frame when the detections of the previous one arrive, or after "
              "ack_timeout_s).", float_range=(0.0, 1000.0))
        param("loop", False, "Replay the source again and again (recorded sources).")
        param("loop_restamp", True, "On loops, shift stamps by the source's length so time keeps increasing; false "
              "repeats the original stamps (time jumps back: the pacing, /clock and the wait for detections start "
              "over).")
        param("start_offset_s", 0.0, "Start this many seconds after the source's first frame.",
              float_range=(0.0, 1.0e6))
        param("publish_compressed", True, "Publish sensor_msgs/CompressedImage (JPEG as stored; others encoded).")
        param("publish_raw", False, "Publish sensor_msgs/Image (bgr8); decoding costs CPU, use for in-process use.")
        param("image_topic", bag_io.DEFAULT_IMAGE_TOPIC, "Image topic read from a bag (CompressedImage).")
        param("compressed_topic", bag_io.DEFAULT_IMAGE_TOPIC, "Topic of the published CompressedImage.")
        param("raw_topic", "/camera/image_raw", "Topic of the published raw Image.")
        param("image_qos", "sensor_data", "QoS of the image topics: sensor_data (best effort, keep last 5) or "
              "reliable (keep last 10; a reliable subscriber needs it).",
              additional_constraints="one of: sensor_data, reliable")
        param("frame_id", "camera", "frame_id of images from sources that carry none (video, folder, device).")
        param("jpeg_quality", 95, "JPEG quality when frames must be encoded (video, device).", int_range=(1, 100))
        param("publish_clock", True, "Publish /clock from the stamps when replaying a recorded source (never for "
              "live cameras), so the graph can run with use_sim_time.")
        param("clock_rate_hz", 50.0, "How often /clock advances between frames (wall clock), at rate > 0.",
              float_range=(1.0, 1000.0))
        param("republish", True, "Republish the camera fix and GPS truth topics recorded in a bag.")
        param("camera_fix_topic", bag_io.DEFAULT_CAMERA_FIX_TOPIC, "Camera position topic (NavSatFix, latched).")
        param("gps_truth_topic", bag_io.DEFAULT_GPS_TRUTH_TOPIC, "Vessel GPS ground truth topic (NavSatFix).")
        param("camera_fix_from_parameters", True, "When the source has no camera fix (video, folder, device, a bag "
              "without one), publish camera.camera_lat/camera_lon once, latched.")
        param("camera.camera_lat", DEFAULT_CAMERA_PARAMETERS["camera_lat"], "Camera latitude, WGS-84 degrees.",
              float_range=(-90.0, 90.0))
        param("camera.camera_lon", DEFAULT_CAMERA_PARAMETERS["camera_lon"], "Camera longitude, WGS-84 degrees.",
              float_range=(-180.0, 180.0))
        param("start_utc", "", "UTC of the first frame of a video or image folder without stamps in its file names "
              "(ISO-8601 or epoch seconds); empty = now.")
        param("fps", 0.0, "Frame rate: of an image folder without stamps (default 1), forced on a video (default: "
              "its own frame times), requested from a device (0 = its default).", float_range=(0.0, 1000.0))
        param("device_width", 0, "Requested device image width (0 = the device's default).", int_range=(0, 10000))
        param("device_height", 0, "Requested device image height (0 = the device's default).",
              int_range=(0, 10000))
        param("ack_topic", "/vessel/detections", "At rate 0: the detector output whose arrival releases the next "
              "frame (vessel_msgs/Detection2DArray with the image's stamp).")
        param("ack_type", bag_io.DETECTION_2D_ARRAY, "At rate 0: message type of ack_topic, any with a header "
              "(e.g. vessel_msgs/msg/VesselTrackArray to pace on the fuser's /vessel/tracks).")
        param("ack_timeout_s", 2.0, "At rate 0: publish the next frame after this long without detections.",
              float_range=(0.01, 600.0))
        param("frames_in_flight", 1, "At rate 0: frames published whose detections have not arrived yet. 1 = lock "
              "step; 2 keeps the next frame waiting at the detector while it works on one, so neither the "
              "transport nor this node's turn-around idles it (give the detector images_waiting 2, else one of two "
              "images arriving before its worker takes the first is dropped).", int_range=(1, 2))
        param("wait_for_subscribers", -1, "Before the first frame, wait until this many subscribers are matched on "
              "the image topic, so no frame is lost while the graph starts. 0 = start at once; -1 = automatic: at "
              "rate 0 wait for one image subscriber and a publisher on ack_topic (the detector), else start at "
              "once.", int_range=(-1, 100))
        param("wait_timeout_s", 30.0, "Longest wait for those subscribers; then start anyway (logged).",
              float_range=(0.0, 3600.0))
        param("drop_late", False, "At rate > 0, drop frames that are late by more than max_lag_s (keeps real time "
              "on a slow machine) instead of sending every frame late.")
        param("max_lag_s", 0.5, "Lateness beyond which a frame counts as late (and is dropped with drop_late).",
              float_range=(0.0, 60.0))
        param("max_frames", 0, "Stop after publishing this many frames (0 = the whole source), e.g. for a short "
              "demo or test.", int_range=(0, 1_000_000_000))
        param("exit_at_end", True, "Exit (status 0) when a recorded source ends without loop; false keeps the node "
              "alive, e.g. to keep the latched camera fix available.")
        param("end_linger_s", 1.0, "Seconds to stay up after the last frame so subscribers receive it.",
              float_range=(0.0, 60.0))
        if d["image_qos"] not in ("sensor_data", "reliable"):
            raise DataError(f"parameter image_qos={d['image_qos']!r}: use sensor_data or reliable")
        if not (d["publish_compressed"] or d["publish_raw"]):
            raise DataError("publish_compressed and publish_raw are both false: the node would publish no image")
        if not d["source"]:
            raise DataError(
                "parameter 'source' is empty: set it to a bag folder, .mcap, video file, image folder or device:N "
                "(e.g. --ros-args -p source:=bags/video_13)"
            )
        return d

    # ------------------------------------------------------------------------------------------------ callbacks
    def _source_problem(self, kind: str, message: str) -> None:
        if kind == "unreadable":
            self.stats.bad += 1
            self.health.problem("frames_bad", message)
        else:
            self.stats.dropped += 1
            self.health.problem("frames_dropped", message)

    def _on_ack(self, message) -> None:
        with self._ack:
            stamp = stamp_ns(message.header.stamp)
            if self._newest_sent_ns is None or stamp > self._newest_sent_ns:
                return  # not a frame of this pass: a late answer to the pass before a loop that kept the stamps
            self._acked_ns = stamp
            self._acked_recent.append(self._acked_ns)
            self._ack.notify_all()

    def _publish_parameter_fix(self) -> None:
        fix = NavSatFix()
        fix.header.stamp = self.get_clock().now().to_msg()
        first = self.source.first_stamp_ns()
        if first is not None and not self.live:
            fix.header.stamp = time_msg(first)
        fix.header.frame_id = self.params["frame_id"]
        fix.status.status = NavSatStatus.STATUS_FIX
        fix.status.service = NavSatStatus.SERVICE_GPS
        fix.latitude = float(self.params["camera.camera_lat"])
        fix.longitude = float(self.params["camera.camera_lon"])
        fix.altitude = float("nan")
        fix.position_covariance_type = NavSatFix.COVARIANCE_TYPE_UNKNOWN
        self.camera_fix_pub.publish(fix)

    # ------------------------------------------------------------------------------------------------ replay
    def _run(self) -> None:
        try:
            self._wait_for_subscribers()
            self._replay()
        except VesselError as error:
            self.get_logger().error(f"source failed: {error}")
            self.health.set_status(DiagnosticStatus.ERROR, f"source failed: {error}")
            self.exit_status = 1
        except Exception as error:  # the worker must report, not vanish silently
            if self._shutting_down():  # Ctrl-C shut the context down under a publish: not an error
                return
            self.get_logger().error(f"replay stopped by an unexpected error: {error!r}")
            self.exit_status = 1
        finally:
            self._end()

    def _shutting_down(self) -> bool:
        """Stop was asked for, or the ROS context is gone (Ctrl-C reaches rclpy before ``close``)."""
        return self._stop.is_set() or not self.context.ok()

    def _wait_for_subscribers(self) -> None:
        """Hold the first frame until the consumers are matched (see the wait_for_subscribers parameter)."""
        wanted = self.params["wait_for_subscribers"]
        paced = self.rate == 0 and not self.live
        if wanted < 0:
            wanted = 1 if paced else 0
        ack_topic = self.params["ack_topic"]
        wants_ack = paced and self.params["wait_for_subscribers"] < 0
        publisher = self.compressed_pub or self.raw_pub

        def ready() -> bool:
            subscribers_ok = publisher.get_subscription_count() >= wanted
            return subscribers_ok and (not wants_ack or self.count_publishers(ack_topic) > 0)

        if wanted == 0 and not wants_ack:
            return
        deadline = time.monotonic() + self.params["wait_timeout_s"]
        while not self._stop.is_set() and not ready():
            if time.monotonic() > deadline:
                acks = f", {self.count_publishers(ack_topic)} publishers on {ack_topic}" if wants_ack else ""
                self.get_logger().warning(
                    f"after {self.params['wait_timeout_s']:g} s: {publisher.get_subscription_count()} of {wanted} "
                    f"image subscribers{acks}; starting anyway"
                )
                return
            self._stop.wait(0.05)
        # Matching is seen from this side first; give the subscribers' side a moment to match as well, so the
        # first (best-effort) frame is not sent into a half-open connection.
        self._stop.wait(0.3)

    def _replay(self) -> None:
        wall0: float | None = None
        stamp0: int | None = None
        last_clock_ns: int | None = None
        last_log = time.monotonic()
        clock_period = 1.0 / self.params["clock_rate_hz"]
        in_flight: deque[int] = deque()  # stamps of published frames whose detections have not arrived (rate 0)
        pass_index = 0
        for item in self.source:
            if self._stop.is_set():
                return
            if item.loop != pass_index:
                pass_index = item.loop
                if not self.params["loop_restamp"]:
                    # the stamps start over, so the pacing, /clock and the acks do too
                    self._drain(in_flight)
                    self._forget_acks()
                    wall0, last_clock_ns = None, None
            if wall0 is None:
                wall0, stamp0 = time.monotonic(), item.stamp_ns
                if self.clock_pub is not None:
                    self._publish_clock(item.stamp_ns)
                    last_clock_ns = item.stamp_ns
            late_s = 0.0
            if not self.live and self.rate > 0:
                due = wall0 + (item.stamp_ns - stamp0) / NS_PER_S / self.rate
                last_clock_ns = self._sleep_until(due, wall0, stamp0, item.stamp_ns, last_clock_ns, clock_period)
                if self._stop.is_set():
                    return
                late_s = time.monotonic() - due
            if self.clock_pub is not None and (last_clock_ns is None or item.stamp_ns > last_clock_ns):
                self._publish_clock(item.stamp_ns)
                last_clock_ns = item.stamp_ns
            if isinstance(item, AuxMessage):
                self._publish_aux(item)
                continue
            if late_s > self.params["max_lag_s"]:
                self.stats.late += 1
                self.health.count("frames_late")
                if self.params["drop_late"]:
                    self.stats.dropped += 1
                    self.health.problem(
                        "frames_dropped", f"frame at {item.stamp:.3f} s was {late_s:.2f} s late; dropped (drop_late)"
                    )
                    continue
            if self._publish_frame(item) and self.rate == 0 and not self.live:
                in_flight.append(item.stamp_ns)
                while len(in_flight) >= self.params["frames_in_flight"]:
                    self._wait_for_ack(in_flight.popleft())
            if 0 < self.params["max_frames"] <= self.stats.sent:
                self.get_logger().info(f"max_frames={self.params['max_frames']} reached")
                self._drain(in_flight)
                return
            if time.monotonic() - last_log > 10.0:
                last_log = time.monotonic()
                self.get_logger().info(self._progress_text())
        self._drain(in_flight)

    def _forget_acks(self) -> None:
        with self._ack:
            self._acked_ns = self._newest_sent_ns = None
            self._acked_recent.clear()

    def _drain(self, in_flight: deque) -> None:
        """At the end of a paced replay: wait for the detections of the frames still in flight."""
        while in_flight and not self._stop.is_set():
            self._wait_for_ack(in_flight.popleft())

    def _sleep_until(
        self, due: float, wall0: float, stamp0: int, next_ns: int, last_clock_ns: int | None, period: float
    ) -> int | None:
        """Wait for `due` (monotonic s), advancing /clock along the stamps meanwhile; return the last clock sent."""
        while True:
            now = time.monotonic()
            if now >= due or self._stop.is_set():
                return last_clock_ns
            if self.clock_pub is not None:
                sim_ns = min(stamp0 + round((now - wall0) * self.rate * NS_PER_S), next_ns - 1)
                if last_clock_ns is None or sim_ns > last_clock_ns:
                    self._publish_clock(sim_ns)
                    last_clock_ns = sim_ns
                self._stop.wait(min(period, due - now))
            else:
                self._stop.wait(due - now)

    def _wait_for_ack(self, stamp_ns: int) -> None:
        """Until the detections of the frame at ``stamp_ns`` (or a later one) arrive, or ``ack_timeout_s``.

        Detections of a later frame alone mean this one got none (the detector keeps only its newest image):
        counted as ``frames_unanswered``.
        """
        deadline = time.monotonic() + self.params["ack_timeout_s"]
        with self._ack:
            while self._acked_ns is None or self._acked_ns < stamp_ns:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._stop.is_set():
                    self.stats.ack_timeouts += 1
                    self.health.count("ack_timeouts")
                    return
                self._ack.wait(min(remaining, 0.1))
            if stamp_ns not in self._acked_recent:
                self.stats.unanswered += 1
                self.health.count("frames_unanswered")

    def _publish_clock(self, stamp_ns: int) -> None:
        self.clock_pub.publish(Clock(clock=time_msg(stamp_ns)))

    def _publish_aux(self, item: AuxMessage) -> None:
        target = self.aux_pubs.get(item.topic)
        if target is None:
            return
        publisher, cls = target
        try:
            message = deserialize_message(item.cdr, cls)
        except Exception as error:  # a damaged payload: count it, keep replaying
            self.health.problem("aux_bad", f"message on {item.topic} does not parse ({error}); skipped")
            return
        if item.loop and hasattr(message, "header"):
            message.header.stamp = time_msg(item.stamp_ns)
        publisher.publish(message)
        self.stats.aux_sent += 1
        self.health.count("aux_sent")

    def _publish_frame(self, frame: Frame) -> bool:
        stamp = time_msg(frame.stamp_ns)
        with self._ack:
            self._newest_sent_ns = frame.stamp_ns
        frame_id = frame.frame_id or self.params["frame_id"]
        try:
            if self.compressed_pub is not None:
                message = CompressedImage()
                message.header.stamp = stamp
                message.header.frame_id = frame_id
                message.format = "jpeg"
                message.data = array.array("B", frame.jpeg_bytes(self.params["jpeg_quality"]))
                self.compressed_pub.publish(message)
            if self.raw_pub is not None:
                bgr = frame.bgr()
                message = Image()
                message.header.stamp = stamp
                message.header.frame_id = frame_id
                message.height, message.width = int(bgr.shape[0]), int(bgr.shape[1])
                message.encoding = "bgr8"
                message.is_bigendian = 0
                message.step = int(bgr.shape[1] * 3)
                message.data = array.array("B", bgr.tobytes())
                self.raw_pub.publish(message)
        except VesselError as error:
            self.stats.bad += 1
            self.health.problem("frames_bad", f"{error}; skipped")
            return False
        self.stats.sent += 1
        self.health.count("frames_sent")
        self.health.set_value("stamp", f"{frame.stamp:.3f}")
        self.health.set_value("progress", self._progress_value())
        return True

    def _progress_value(self) -> str:
        done = self.source.stats.frames
        if self.total_frames and not self.source.loop:
            return f"{done}/{self.total_frames} ({100.0 * done / self.total_frames:.0f} %)"
        return str(done)

    def _progress_text(self) -> str:
        s = self.stats
        return (
            f"frame {self._progress_value()}: sent {s.sent}, dropped {s.dropped}, bad {s.bad}"
            + (f", late {s.late}" if s.late else "")
            + (f", ack timeouts {s.ack_timeouts}" if s.ack_timeouts else "")
            + (f", unanswered {s.unanswered}" if s.unanswered else "")
        )

    def _end(self) -> None:
        s = self.stats
        summary = (
            f"{self.source.description} ended: sent {s.sent} frames, dropped {s.dropped}, bad {s.bad}, "
            f"{s.aux_sent} other messages" + (f", {s.late} late" if s.late else "")
            + (f", {s.ack_timeouts} ack timeouts" if s.ack_timeouts else "")
            + (f", {s.unanswered} without detections (a later frame's came)" if s.unanswered else "")
        )
        if self._shutting_down():
            return
        if self.damage:
            self.exit_status = 1
            summary += f"; the source was damaged, the rest is lost: {self.damage}"
            self.get_logger().error(summary)
            self.health.set_status(DiagnosticStatus.ERROR, f"finished: {summary}")
        else:
            self.get_logger().info(summary)
            self.health.set_status(DiagnosticStatus.OK, f"finished: {summary}")
        self.health.publish()
        if self.exit_at_end:
            self._stop.wait(self.params["end_linger_s"])
            self.finished = True

    def close(self) -> None:
        """Stop the replay thread and release the source (called by run_node at shutdown)."""
        self._deactivate()
        if self.source is not None:
            self.source.close()
            self.source = None


class CameraNode(_CameraPhases, Node):
    """Publish the frames of one source; see the module docstring."""

    def __init__(self) -> None:
        super().__init__("camera")
        self._declare()
        self._configure()
        self._activate()


class ManagedCameraNode(PhasedLifecycle, _CameraPhases, LifecycleNode):
    """The camera as a managed (lifecycle) node: ``ros2 run vessel_detect camera_managed``.

    configure opens the source (a bad one fails the transition, logged, the node stays unconfigured) and makes the
    publishers; activate starts streaming (a recorded source from its first frame); deactivate stops; cleanup
    closes the source; shutdown from any state.
    """

    def __init__(self) -> None:
        super().__init__("camera")
        self._declare()


main = main_for(CameraNode)
main_managed = main_for(ManagedCameraNode)

if __name__ == "__main__":
    main()
