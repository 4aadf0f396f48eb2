"""``tracker`` node: per-image detections in, one screen-space track per vessel out.

Subscribes ``/vessel/detections`` (``vessel_msgs/Detection2DArray``, reliable), runs
``vessel_track.tracker.MultiTargetTracker`` and publishes ``/vessel/tracks/screen``
(``vessel_msgs/VesselTrackArray``, reliable) with the detections' header, so the image stamp travels on. Every
live track is published (TENTATIVE, CONFIRMED or COASTING) and an ended one once as LOST: the box centre is the
Kalman-filtered centre, its size the latest associated box, ``last_seen`` the stamp of the latest associated
detection (equal to the header stamp when the track was updated by this image). World fields are NaN and
``has_world`` false; ``is_target`` is false (the fuser decides).

Bad input never stops the node: NaN or non-positive boxes are dropped, stamps going back by
``backwards_reset_s`` reset the tracker (a replay restarted), a long gap times every track out; each kind is
logged once and counted on ``/diagnostics``. What is refused at the boundary (an invalid, repeated or slightly
older stamp drops the message; a score outside [0, 1] drops the detection) is ``vessel_track.message_checks``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import fields

import numpy as np
from rclpy.node import Node

from vessel_common.errors import DataError, VesselError
from vessel_common.health import NodeHealth
from vessel_common.node_parameters import declare_table
from vessel_common.node_state import NodeState, Standby
from vessel_common.qos import reliable_qos, sec_to_stamp, stamp_to_sec
from vessel_common.state_file import settings_fingerprint
from vessel_common.wire import WireType, encoded_or_none
from vessel_msgs.msg import Detection2DArray, VesselTrackArray
from vessel_track import deferred_imports
from vessel_track.message_checks import (
    TRACK_ARRAY_TYPE,
    checked_detections,
    detection_refusal,
    header_refusal,
    order_refusal,
    report,
)
from vessel_track.node_params import main_with_checks
from vessel_track.parameter_tables import EVERY_CLASS, TRACKER_PARAMETERS
from vessel_track.pose_input import boxes_in_reference, pose_refusal, pose_sigma_px
from vessel_track.tracker import MultiTargetTracker, TrackerCounters, TrackState
from vessel_track.tracker_config import TrackerConfig, node_values

PROBLEMS = {
    "detections_invalid": "detections with NaN/inf coordinates or a width/height below min_box_size_px "
                          "(negative sizes) were dropped",
    "resets": "detection stamps went back by backwards_reset_s or more (replay restarted?): the tracker was reset "
              "and every track reported LOST",
    "out_of_order_frames": "a detection array stamped slightly before the previous one was dropped",
    "gaps": "detections arrived more than max_coast_s after the previous ones: every track timed out",
    "capacity_drops": "max_tracks live tracks reached: detections that would start more were dropped",
}


def tracker_config_of(values) -> TrackerConfig:
    """The ``TrackerConfig`` of the node's parameter values (flat names); a bad combination is a DataError."""
    return TrackerConfig.from_dict({f.name: values[f.name] for f in fields(TrackerConfig)})


def detections_to_arrays(msg: Detection2DArray, classes: frozenset[str] | None,
                         confidence_class: str = "", with_labels: bool = False):
    """(N, 4) xyxy boxes and (N,) scores of the detections whose class is accepted.

    The score of a detection is its best hypothesis among the accepted classes; a detection without
    hypotheses has score 1 and is accepted only when no class filter is set. With ``confidence_class`` (the
    detector's vessel-of-interest class), an accepted detection's score is that hypothesis' score wherever it
    has one: every vessel is tracked, and each track's confidence is its probability of being the target.
    ``with_labels`` also returns each kept detection's class (its first accepted hypothesis, '' without one).
    A detection with a score outside [0, 1] is left out, as the node refuses it (``message_checks``). Boxes come
    back in the calibration's reference image (``pose_input``): the array's pose must have passed ``pose_refusal``;
    a box the map cannot place (beyond the lens's reach in the reference image) is left out.
    """
    boxes = []
    scores = []
    labels = []
    for det in msg.detections:
        if detection_refusal(det) is not None:
            continue
        accepted = [float(r.hypothesis.score) for r in det.results
                    if classes is None or r.hypothesis.class_id in classes]
        target = [float(r.hypothesis.score) for r in det.results
                  if confidence_class and r.hypothesis.class_id == confidence_class]
        if accepted and target:
            score = target[0] if math.isfinite(target[0]) else math.nan
        elif accepted:
            score = max(accepted) if all(math.isfinite(s) for s in accepted) else math.nan  # NaN: counted invalid
        elif not det.results and classes is None:
            score = 1.0
        else:
            continue
        cx, cy = det.bbox.center.position.x, det.bbox.center.position.y
        w, h = det.bbox.size_x, det.bbox.size_y
        boxes.append((cx - w / 2.0, cy - h / 2.0, cx + w / 2.0, cy + h / 2.0))
        scores.append(score)
        labels.append(next((r.hypothesis.class_id for r in det.results
                            if classes is None or r.hypothesis.class_id in classes), ""))
    in_image = np.array(boxes, dtype=float).reshape(-1, 4)
    mapped = boxes_in_reference(msg.camera_pose, in_image)
    placed = np.all(np.isfinite(mapped), axis=1) | ~np.all(np.isfinite(in_image), axis=1)  # lost only by the map
    arrays = mapped[placed], np.array(scores, dtype=float).reshape(-1)[placed]
    return (*arrays, [label for label, keep in zip(labels, placed, strict=True) if keep]) if with_labels else arrays


def load_detection_inputs(path) -> tuple[frozenset[str] | None, str]:
    """The tracker node's ``classes`` (None: every class) and ``confidence_class`` from a parameter YAML.

    What the node would declare from the same file, so a tool that re-reads recorded detections (the demo's
    offline pass) takes the same boxes and the same confidences the node took. A bad value is a DataError.
    """
    if path is None:
        return None, ""
    values = node_values(path, "tracker")
    classes = values.get("classes", [EVERY_CLASS])
    confidence_class = values.get("confidence_class", "")
    if not (isinstance(classes, list) and all(isinstance(c, str) for c in classes)):
        raise DataError(f"{path}: tracker.classes must be a list of class ids, e.g. [boat] or ['*'], got {classes!r}")
    if not isinstance(confidence_class, str):
        raise DataError(f"{path}: tracker.confidence_class must be a class id string, got {confidence_class!r}")
    return accepted_classes(classes), confidence_class


def accepted_classes(classes) -> frozenset[str] | None:
    """The ``classes`` parameter as the set of class ids to track; None for every class (``['*']`` or empty)."""
    return None if not classes or EVERY_CLASS in classes else frozenset(classes)


def track_to_msg(state: TrackState, header, pose_sigma: Sequence[float] = (0.0, 0.0)) -> object:
    """A ``VesselTrack`` of one tracker state: screen fields filled, world fields NaN, not the target.

    Built as ``vessel_common.wire`` encodes it. ``pose_sigma``: what the camera pose's uncertainty adds to the box's
    ideal x, y std (``pose_input``).
    """
    nan = math.nan
    msg = _track_type().new(header=header, id=state.track_id, is_target=False, score=nan,
                            confidence=float(state.confidence), class_id=state.label, status=int(state.status),
                            detection_count=int(state.detection_count), has_world=False,
                            latitude=nan, longitude=nan, distance_m=nan, bearing_deg=nan, expected_error_m=nan)
    _set_stamp(msg.first_seen, state.first_seen)
    _set_stamp(msg.last_seen, state.last_seen)
    box = msg.bbox
    box.center.position.x, box.center.position.y = float(state.center[0]), float(state.center[1])
    box.size_x, box.size_y = float(state.size[0]), float(state.size[1])
    msg.screen_velocity.x, msg.screen_velocity.y = float(state.velocity[0]), float(state.velocity[1])
    msg.screen_covariance = np.array(state.center_cov, dtype=np.float64).ravel()
    msg.pose_sigma_px = np.array(pose_sigma, dtype=np.float64)
    if state.measured_center is not None:
        measured = msg.detection_bbox
        measured.center.position.x = float(state.measured_center[0])
        measured.center.position.y = float(state.measured_center[1])
        measured.size_x, measured.size_y = float(state.measured_size[0]), float(state.measured_size[1])
    msg.position.x = msg.position.y = msg.position.z = nan
    msg.velocity.x = msg.velocity.y = msg.velocity.z = nan
    msg.position_covariance = np.full(4, nan)
    msg.velocity_covariance = np.full(4, nan)
    return msg


@functools.cache
def _track_type() -> WireType:
    return WireType("vessel_msgs/msg/VesselTrack")


def _set_stamp(stamp, seconds: float) -> None:
    """``stamp`` (a ``builtin_interfaces/Time``) set to ``seconds``, as ``sec_to_stamp`` rounds it."""
    rounded = sec_to_stamp(seconds)
    stamp.sec, stamp.nanosec = rounded.sec, rounded.nanosec


class TrackerNode(Node):
    """Thin ROS wrapper around ``MultiTargetTracker``; see the module docstring."""

    def __init__(self):
        super().__init__("tracker")
        values = declare_table(self, TRACKER_PARAMETERS, apply=self._apply_parameters)
        config = tracker_config_of(values)
        input_topic, output_topic, depth = values["input_topic"], values["output_topic"], values["qos_depth"]
        self.classes = accepted_classes(values["classes"])
        self.confidence_class = values["confidence_class"]
        self.tracker = MultiTargetTracker(config)
        self.health = NodeHealth(self)
        self.standby = Standby(self)
        self.state = NodeState(self, self.health, "tracker",
                               settings_fingerprint(config, sorted(self.classes or ()), self.confidence_class),
                               read_only=not self.standby.active)
        self._reported = TrackerCounters()
        self.wire = WireType(TRACK_ARRAY_TYPE)
        self.publisher = self.create_publisher(VesselTrackArray, output_topic, reliable_qos(depth))
        self.health.watch_subscribers(self.publisher)
        self.subscription = self.create_subscription(Detection2DArray, input_topic, self.on_detections,
                                                     reliable_qos(depth))
        self.get_logger().info(
            f"tracker: {input_topic} -> {output_topic}; gate {config.gate_px:g} px/{config.gate_sigmas:g} sigma, "
            f"lost after {config.max_coast_s:g} s, {config.process_noise_model} q={config.process_noise:g}, "
            f"classes {sorted(self.classes) if self.classes else 'all'}")

    def _apply_parameters(self, values) -> None:
        """A live change of the tracker's settings: checked as at start, used from the next frame on."""
        config = tracker_config_of(values)
        self.classes = accepted_classes(values["classes"])
        self.confidence_class = values["confidence_class"]
        self.tracker.config = config

    def on_detections(self, msg: Detection2DArray) -> None:
        """Track one image's detections and publish every track with the image's header.

        Refused first (``message_checks``): a message with an invalid stamp, the previous message's stamp or one
        slightly before it (a step back of ``backwards_reset_s`` or more goes on: the tracker resets), and each
        detection with a score outside [0, 1].
        """
        refusal = header_refusal(msg.header.stamp)
        if refusal is not None:
            report(self.health, [refusal])
            return
        stamp = stamp_to_sec(msg.header.stamp)
        if self.state.resume(stamp, self.tracker):
            return  # the snapshot resumed already holds this frame
        refusal = order_refusal(stamp, self.tracker.last_stamp, self.tracker.config.backwards_reset_s)
        if refusal is not None:
            report(self.health, [refusal])  # nothing published: downstream never sees time go back a little
            return
        self.health.observe_input(stamp)
        refusal = pose_refusal(msg.camera_pose)
        if refusal is not None:
            self.health.problem("no_pose", refusal)
            return
        report(self.health, checked_detections(msg.detections)[1])  # detections_to_arrays leaves them out
        boxes, scores, labels = detections_to_arrays(msg, self.classes, self.confidence_class, with_labels=True)
        try:
            states = self.tracker.update(stamp, boxes, scores, labels)
        except VesselError as error:
            self.health.problem("bad_message", f"detection array dropped: {error}")
            return
        sigmas = pose_sigma_px(msg.camera_pose, np.array([s.center for s in states]).reshape(-1, 2))
        out = self.wire.new(header=msg.header, tracks=[track_to_msg(s, msg.header, sigma)
                                                       for s, sigma in zip(states, sigmas, strict=True)])
        publishing = self.standby.publishing()
        cdr = encoded_or_none(self.wire, out, self.health) if publishing else None
        if cdr is not None:
            self.publisher.publish(cdr)
        self._report(len(boxes), states)
        if publishing:
            self.state.save(stamp, self.tracker)

    def _report(self, n_boxes: int, states: list[TrackState]) -> None:
        counters = self.tracker.counters
        for kind, message in PROBLEMS.items():
            new = getattr(counters, kind) - getattr(self._reported, kind)
            for _ in range(max(new, 0)):
                self.health.problem(kind, message)
        self._reported = TrackerCounters(**counters.as_dict())
        self.health.count("frames")
        self.health.set_value("detections_in", counters.detections_in)
        self.health.set_value("tracks_created", counters.tracks_created)
        self.health.set_value("tracks_confirmed", counters.tracks_confirmed)
        self.health.set_value("live_tracks", len(self.tracker.track_ids))
        self.health.set_value("last_boxes", n_boxes)
        self.health.set_value("last_stamp", float(self.tracker.last_stamp or 0.0))


def main(args=None) -> None:
    """Console entry point: ``ros2 run vessel_track tracker --ros-args --params-file config/aitas.yaml``."""
    import sys

    sys.exit(main_with_checks(TrackerNode, args, preload=deferred_imports.MODULES))


if __name__ == "__main__":
    main()
