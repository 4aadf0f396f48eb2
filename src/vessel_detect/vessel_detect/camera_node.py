"""Camera ingest node: feeds images into the graph from a bag, video, image folder or live camera.

Recorded sources replay with their original stamps at a rate factor (1 = real time, 10 = ten times faster, 0 = as
fast as the graph consumes: each frame waits for the detector's output for the previous one or a timeout), publish
`/clock` from the stamps so the graph can run with `use_sim_time`, and republish the camera's fix, the vessel's
GPS truth and the own ship's position and attitude (a camera on a ship) recorded in a bag, in stamp order with
the images. A frame that cannot be read is skipped, counted and logged once; the node never
stops on a bad frame. At the end of a recorded source (without `loop`) it logs a summary and exits with status 0,
so scripts can wait for it. Progress and frame counts go to `/diagnostics`.

The parameters are `vessel_detect.parameter_tables.CAMERA_PARAMETERS`. `rate` and the other live ones can be changed
while it runs (`ros2 param set /camera rate 8.0`: the replay paces at the new rate from the next frame); the rest
are read-only (a restart with `-p NAME:=VALUE` changes them). The pacing is `vessel_detect.replay_pacing`.

With a `resume_file` (the graph runners give one under respawn) a recorded source's replay notes where it is after
every frame or message sent, and a camera restarted after a crash carries on after the last one (same stamps, the
latest camera fix sent again) instead of replaying from the first frame (`vessel_detect.resume_files`).

    ros2 run vessel_detect camera --ros-args -p source:=bags/video_13 -p rate:=10.0
    ros2 run vessel_detect camera --ros-args -p source:=device:0 -p publish_raw:=true
"""

from __future__ import annotations

import array
import threading
import time
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CompressedImage, Image, Imu, NavSatFix, NavSatStatus

from vessel_common.errors import DataError, VesselError
from vessel_common.health import NodeHealth
from vessel_common.lifecycle import PhasedLifecycle, release_publisher
from vessel_common.node_parameters import declare_table
from vessel_common.qos import LATCHED_QOS, image_qos_profile, reliable_qos
from vessel_common.run import main_for
from vessel_detect.bag_topics import in_bag
from vessel_detect.file_sources import parse_utc
from vessel_detect.image_source import AuxMessage, Frame, ImageSource
from vessel_detect.parameter_tables import CAMERA_PARAMETERS
from vessel_detect.replay_pacing import (
    SUBSCRIBER_SETTLE_S,
    AckWindow,
    PacingSettings,
    Replay,
    ReplayHooks,
    ReplayPosition,
    ReplayStats,
    ResumeCursor,
    WallTiming,
    subscribers_to_wait_for,
    wait_until,
)
from vessel_detect.resume_files import (
    ResumeFileError,
    camera_record,
    camera_resume_point,
    camera_start_utc,
    read_resume_file,
    write_json_atomically,
)
from vessel_detect.ros_messages import message_class, stamp_ns, time_msg
from vessel_detect.source_spec import open_source

RESUME_MARGIN_S = 0.001
"""A restarted replay opens its source this much before the last item sent (the replay skips up to it by stamp)."""
OWN_SHIP_QOS_DEPTH = 200
"""The own ship's fixes and attitudes come at 20 Hz and reach a subscriber in bursts between frames (every frame
sent as fast as consumed); this holds 10 s of them."""


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
        self._timing = WallTiming(self._stop)
        self.acks = AckWindow(self._timing)
        self.replay: Replay | None = None
        self.source: ImageSource | None = None
        self.live = False
        self._worker: threading.Thread | None = None
        self._camera_publishers: list = []
        self._ack_subscription = None
        self._resume_point: ReplayPosition | None = None  # where the next activation carries on (resume_file)
        self._start_utc: float | None = None
        self._first_ns: int | None = None

    def _make_publisher(self, message_type, topic: str, qos):
        publisher = self.create_publisher(message_type, topic, qos)
        self._camera_publishers.append(publisher)
        return publisher

    def _configure(self) -> None:
        p = self.params
        resume_data = self._read_resume_file()
        self._start_utc = parse_utc(p["start_utc"]) if p["start_utc"] else None
        if self._start_utc is None and p["resume_file"]:  # the start before a restart: the frames keep their stamps
            self._start_utc = camera_start_utc(resume_data, p["source"]) or time.time()
        self.source = open_source(
            p["source"],
            image_topic=in_bag(p["image_topic"]),
            aux_topics=self._aux_topics(),
            start_utc=self._start_utc,
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
        self._first_ns = self.source.first_stamp_ns()
        self._resume_point = self._resume_point_of(resume_data)
        self.health.set_value("source", self.source.description)
        self.damage = getattr(self.source, "damage", "")
        if self.damage:
            self.health.problem("source_damaged", f"the source is damaged; playing what can be read: {self.damage}")
        self._show_rate()

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
        self.aux_pubs[in_bag(p["camera_fix_topic"])] = (self.camera_fix_pub, NavSatFix)
        self._make_aux_publishers()
        if self.rate == 0:
            self._subscribe_acks()

    def _aux_topics(self) -> list[str]:
        """The bag topics republished beside the images (none without ``republish``)."""
        p = self.params
        if not p["republish"]:
            return []
        topics = (p["camera_fix_topic"], p["gps_truth_topic"], p["own_ship_fix_topic"], p["own_ship_imu_topic"])
        return list(dict.fromkeys(in_bag(topic) for topic in topics))

    def _make_aux_publishers(self) -> None:
        """Publishers of the GPS truth and own-ship topics the source has (the camera fix has its own)."""
        p = self.params
        if not (p["republish"] and getattr(self.source, "aux_topics", None)):
            return
        for topic, message_type, depth in ((p["gps_truth_topic"], NavSatFix, 50),
                                           (p["own_ship_fix_topic"], NavSatFix, OWN_SHIP_QOS_DEPTH),
                                           (p["own_ship_imu_topic"], Imu, OWN_SHIP_QOS_DEPTH)):
            if in_bag(topic) in self.source.aux_topics and in_bag(topic) not in self.aux_pubs:
                self.aux_pubs[in_bag(topic)] = (self._make_publisher(message_type, topic, reliable_qos(depth)),
                                                message_type)

    def _read_resume_file(self) -> dict | None:
        """What the resume file holds (None without one, or when it is not a camera's: then from the first frame)."""
        if not self.params["resume_file"]:
            return None
        try:
            return read_resume_file(Path(self.params["resume_file"]).expanduser(), "camera")
        except ResumeFileError as error:
            self.health.problem("resume_file_refused", f"{error}: replaying from the first frame")
            return None

    def _resume_point_of(self, data: dict | None) -> ReplayPosition | None:
        """Where a restarted replay carries on; a source that is not looped then starts just before it (its offset)."""
        if not self.params["resume_file"] or self.live:
            if self.live and self.params["resume_file"]:
                self.get_logger().info("a live camera just continues: resume_file is not used")
            return None
        try:
            point, message = camera_resume_point(data, self.params["source"], self._first_ns)
        except ResumeFileError as error:
            self.health.problem("resume_file_refused", f"{error}: replaying from the first frame")
            return None
        if data is not None:
            self.get_logger().info(f"resume file {self.params['resume_file']}: {message}")
        if point is not None and point.loop == 0 and not self.params["loop"] and self._first_ns is not None:
            # Skip what was sent without reading it (a bag or video seeks); the replay skips the rest by stamp.
            offset_s = (point.stamp_ns - self._first_ns) / 1e9 - RESUME_MARGIN_S
            self.source.start_offset_s = max(self.source.start_offset_s, offset_s)
        return point

    def _save_resume(self, position: ReplayPosition) -> None:
        """Note where the replay is (after each item sent), for a restart."""
        self._resume_point = position
        record = camera_record(self.params["source"], self._first_ns, self._start_utc, position)
        try:
            write_json_atomically(Path(self.params["resume_file"]).expanduser(), record)
        except OSError as error:
            self.health.problem("resume_file_unwritable", f"cannot write resume file {self.params['resume_file']} "
                                f"({error.strerror or error}): a restart would replay from the first frame")

    def _subscribe_acks(self) -> None:
        """At rate 0: the detections whose arrival releases the next frame."""
        if self._ack_subscription is None:
            self._ack_subscription = self.create_subscription(
                message_class(self.params["ack_type"]), self.params["ack_topic"], self._on_ack, reliable_qos(10)
            )

    def _show_rate(self) -> None:
        self.health.set_value("rate", "live" if self.live else ("as consumed" if self.rate == 0 else self.rate))

    def _activate(self) -> None:
        p = self.params
        if p["camera_fix_from_parameters"] and in_bag(p["camera_fix_topic"]) not in getattr(self.source, "aux_topics",
                                                                                             []):
            self._publish_parameter_fix()
        how = "live" if self.live else ("as fast as consumed" if self.rate == 0 else f"at {self.rate:g}x")
        count = f"{self.total_frames} frames" if self.total_frames else "frames"
        self.get_logger().info(
            f"publishing {count} of {self.source.description} {how}"
            f"{', with /clock' if self.publish_clock else ''}{', looping' if p['loop'] else ''}"
        )
        self._stop.clear()
        hooks = ReplayHooks(publish_frame=self._publish_frame, publish_aux=self._publish_aux,
                            publish_clock=self._publish_clock if self.clock_pub is not None else None,
                            count=self._count, log=self.get_logger().info, progress=self._progress_text)
        saves = bool(p["resume_file"]) and not self.live
        resume = ResumeCursor(self._resume_point, save=self._save_resume if saves else None,
                              latched=lambda item: isinstance(item, AuxMessage)
                              and item.topic == in_bag(p["camera_fix_topic"]))
        self.replay = Replay(self._pacing_settings(), hooks, self._timing, self.acks, self.stats, live=self.live,
                             is_frame=lambda item: not isinstance(item, AuxMessage), resume=resume)
        self._worker = threading.Thread(target=self._run, name="camera-replay", daemon=True)
        self._worker.start()

    def _deactivate(self) -> None:
        self._stop.set()
        self.acks.wake()
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
        values = declare_table(self, CAMERA_PARAMETERS, apply=self._apply_parameters)
        if not (values["publish_compressed"] or values["publish_raw"]):
            raise DataError("publish_compressed and publish_raw are both false: the node would publish no image")
        if not values["source"]:
            raise DataError(
                "parameter 'source' is empty: set it to a bag folder, .mcap, video file, image folder or device:N "
                "(e.g. --ros-args -p source:=bags/video_13)"
            )
        return values

    def _apply_parameters(self, values: dict) -> None:
        """A change of the live parameters (``ros2 param set``), checked by the table: in use from the next frame."""
        if values["rate"] != self.params["rate"] and self.source is not None and self.live:
            raise DataError(f"rate: {self.source.description} is a live camera, published as it delivers frames; "
                            "rate paces recorded sources only, leave it as it is")
        self.params.update(values)  # the read-only ones stay as they are: rclpy refuses a change of them
        if self.source is not None:  # configured: the replay paces at the new rate from the next frame
            self.rate = 1.0 if self.live else values["rate"]
            self._show_rate()
            if self.rate == 0:
                self._subscribe_acks()
        if self.replay is not None:
            self.replay.update(self._pacing_settings())

    def _pacing_settings(self) -> PacingSettings:
        return PacingSettings.from_values({**self.params, "rate": 1.0 if self.live else self.params["rate"]})

    # ------------------------------------------------------------------------------------------------ callbacks
    def _source_problem(self, kind: str, message: str) -> None:
        if kind == "unreadable":
            self.stats.bad += 1
            self.health.problem("frames_bad", message)
        elif kind == "damaged_chunk":
            self.damage = getattr(self.source, "damage", "") or message
            self.health.problem("source_damaged", message)
        else:
            self.stats.dropped += 1
            self.health.problem("frames_dropped", message)

    def _on_ack(self, message) -> None:
        self.acks.acknowledge(stamp_ns(message.header.stamp))

    def _count(self, kind: str, problem: str) -> None:
        if problem:
            self.health.problem(kind, problem)
        else:
            self.health.count(kind)

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
            self.replay.run(self.source)
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
        wanted, wants_ack = subscribers_to_wait_for(self.params["wait_for_subscribers"],
                                                    self.rate == 0 and not self.live)
        if wanted == 0 and not wants_ack:
            return
        ack_topic = self.params["ack_topic"]
        publisher = self.compressed_pub or self.raw_pub

        def ready() -> bool:
            subscribers_ok = publisher.get_subscription_count() >= wanted
            return subscribers_ok and (not wants_ack or self.count_publishers(ack_topic) > 0)

        if wait_until(ready, self.params["wait_timeout_s"], self._timing):
            # Matching is seen from this side first; give the subscribers' side a moment to match as well, so the
            # first (best-effort) frame is not sent into a half-open connection.
            self._timing.pause(SUBSCRIBER_SETTLE_S)
            return
        acks = f", {self.count_publishers(ack_topic)} publishers on {ack_topic}" if wants_ack else ""
        self.get_logger().warning(
            f"after {self.params['wait_timeout_s']:g} s: {publisher.get_subscription_count()} of {wanted} "
            f"image subscribers{acks}; starting anyway"
        )

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
            + (f"; carried on after a restart ({self.replay.resume.after.frames_sent} frames sent before it)"
               if self.replay is not None and self.replay.resume.after is not None else "")
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
    publishers; activate starts streaming (a recorded source from its first frame; with a ``resume_file``, after the
    last frame sent, by this process or the one before a restart); deactivate stops; cleanup closes the source;
    shutdown from any state.
    """

    def __init__(self) -> None:
        super().__init__("camera")
        self._declare()


main = main_for(CameraNode)
main_managed = main_for(ManagedCameraNode)

if __name__ == "__main__":
    main()
