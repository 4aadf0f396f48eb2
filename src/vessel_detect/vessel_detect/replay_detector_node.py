"""A stand-in for the detector that publishes boxes recorded in a CSV for each image it receives.

Used to feed the hand-labelled boxes (or a detector run saved by ``./vessel detect run``) through the same
tracker, fuser and GPS publisher nodes, e.g. ``./vessel demo --detections labels``: the rest of the graph cannot
tell it from the detector. Two ways to pace it:

* ``pace: images``: for every image it publishes a ``Detection2DArray`` with the image's header holding the CSV
  rows whose ``stamp`` matches the image stamp (within ``stamp_tolerance_s``); images with no rows get an empty
  array, so the tracker still sees time pass.
* ``pace: self``: no camera needed (hand labels are drawn on frames that need not be in the image set): it
  publishes one array per distinct CSV stamp in time order, the next one when the tracker's output for the
  previous one has arrived on ``ack_topic`` (or after ``ack_timeout_s``), and exits at the end.

CSV columns: ``stamp`` (UNIX seconds), ``x1, y1, x2, y2`` (full-resolution pixels), ``score``, ``class_name``.

Parameters: ``vessel_detect.parameter_tables.REPLAY_DETECTOR_PARAMETERS``; ``stamp_tolerance_s``, ``ack_timeout_s``
and ``wait_for_subscribers`` may be changed while it runs (``ros2 param set``), the others are read-only.
"""

from __future__ import annotations

import bisect
import csv
import math
from pathlib import Path

from rclpy.node import Node
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

from vessel_common.errors import DataError
from vessel_common.health import NodeHealth, steady_timer
from vessel_common.node_parameters import declare_table
from vessel_common.qos import image_qos_profile, reliable_qos, sec_to_stamp, stamp_to_sec
from vessel_common.run import main_for
from vessel_detect.parameter_tables import REPLAY_CSV_COLUMNS, REPLAY_DETECTOR_PARAMETERS
from vessel_msgs.msg import Detection2D, Detection2DArray, ObjectHypothesisWithPose, VesselTrackArray

CSV_COLUMNS = REPLAY_CSV_COLUMNS


def load_detection_rows(path: Path) -> dict[float, list[tuple[float, float, float, float, float, str]]]:
    """Rows of a detections CSV grouped by stamp; a clear DataError for a missing file or column."""
    if not path.is_file():
        raise DataError(f"detections file {path} not found: give an existing CSV with columns {', '.join(CSV_COLUMNS)}")
    grouped: dict[float, list] = {}
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        missing = [c for c in CSV_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise DataError(f"{path} lacks column(s) {missing}: the columns are {', '.join(CSV_COLUMNS)}")
        for line, row in enumerate(reader, start=2):
            try:
                values = [float(row[c]) for c in CSV_COLUMNS[:6]]
            except ValueError as error:
                raise DataError(f"{path} line {line}: {error}; fix or delete that row") from None
            grouped.setdefault(values[0], []).append((*values[1:], row["class_name"]))
    return grouped


class ReplayDetectorNode(Node):
    """Publishes recorded detections in step with the images, as the detector node would."""

    def __init__(self):
        super().__init__("detector")
        values = declare_table(self, REPLAY_DETECTOR_PARAMETERS, apply=self._apply_parameters)
        self._apply_parameters(values)
        csv_path, self._pace, image_qos = values["detections_csv"], values["pace"], values["image_qos"]
        image_topic, raw_topic = values["compressed_topic"], values["image_topic"]
        output_topic, ack_topic = values["detections_topic"], values["ack_topic"]
        self._frame_id = values["frame_id"]
        qos = image_qos_profile(image_qos)
        self._rows = load_detection_rows(Path(csv_path)) if csv_path else {}
        if not csv_path:
            self.get_logger().warning("detections_csv is empty: every image gets an empty Detection2DArray")
        self._stamps = sorted(self._rows)
        self._health = NodeHealth(self)
        self._publisher = self.create_publisher(Detection2DArray, output_topic, reliable_qos(10))
        self._health.watch_subscribers(self._publisher)
        self._health.set_value("stamps_in_csv", len(self._stamps))
        self.finished = False
        if self._pace == "images":
            if image_topic:
                self.create_subscription(CompressedImage, image_topic, self._on_image, qos)
            if raw_topic:
                self.create_subscription(Image, raw_topic, self._on_image, qos)
            return
        self._next_index = 0
        self._awaiting: float | None = None
        self._sent_at = 0.0
        self.create_subscription(VesselTrackArray, ack_topic, self._on_ack, reliable_qos(10))
        steady_timer(self, 0.01, self._pace_self)

    def _apply_parameters(self, values: dict) -> None:
        """Take the live parameters, at start and on ``ros2 param set`` (checked by the table).

        They are read at the next image or pacing tick.
        """
        self._tolerance_s = values["stamp_tolerance_s"]
        self._ack_timeout_s = values["ack_timeout_s"]
        self._wait_for = values["wait_for_subscribers"]

    @property
    def foreign_parameters(self) -> frozenset[str]:
        """The detector's parameters: standing in for it, this node reads its block of a shared file, ignoring them."""
        from vessel_detect.detector_params import DETECTOR_PARAMETERS

        return frozenset(DETECTOR_PARAMETERS.names)

    def _on_ack(self, tracks) -> None:
        if self._awaiting is not None and abs(stamp_to_sec(tracks.header.stamp) - self._awaiting) < 1e-6:
            self._awaiting = None

    def _pace_self(self) -> None:
        """Send the next stamp once the graph is connected and the previous one has been consumed."""
        now = self.get_clock().now().nanoseconds * 1e-9
        if self._awaiting is not None:
            if now - self._sent_at < self._ack_timeout_s:
                return
            self._health.problem("ack_timeout", f"no tracks came back within {self._ack_timeout_s} s; sending on")
            self._awaiting = None
        if self._publisher.get_subscription_count() < self._wait_for:
            return
        if self._next_index >= len(self._stamps):
            self.get_logger().info(f"all {len(self._stamps)} stamps of the CSV sent")
            self.finished = True
            return
        stamp_s = self._stamps[self._next_index]
        self._next_index += 1
        header = Header(stamp=sec_to_stamp(stamp_s), frame_id=self._frame_id)
        self._publish(header, stamp_s)
        self._awaiting = stamp_s
        self._sent_at = now

    def _rows_for(self, stamp_s: float) -> list:
        index = bisect.bisect_left(self._stamps, stamp_s - self._tolerance_s)
        rows = []
        while index < len(self._stamps) and self._stamps[index] <= stamp_s + self._tolerance_s:
            rows.extend(self._rows[self._stamps[index]])
            index += 1
        return rows

    def _on_image(self, image) -> None:
        self._publish(image.header, stamp_to_sec(image.header.stamp))

    def _publish(self, header, stamp_s: float) -> None:
        array = Detection2DArray()
        array.header = header
        for x1, y1, x2, y2, score, class_name in self._rows_for(stamp_s):
            if not all(math.isfinite(v) for v in (x1, y1, x2, y2, score)) or x2 <= x1 or y2 <= y1:
                self._health.problem("bad_row", f"skipping a detection with a non-finite or empty box at {stamp_s}")
                continue
            detection = Detection2D()
            detection.header = header
            detection.bbox.center.position.x = (x1 + x2) / 2.0
            detection.bbox.center.position.y = (y1 + y2) / 2.0
            detection.bbox.size_x = x2 - x1
            detection.bbox.size_y = y2 - y1
            hypothesis = ObjectHypothesisWithPose()
            hypothesis.hypothesis.class_id = class_name
            hypothesis.hypothesis.score = score
            detection.results.append(hypothesis)
            array.detections.append(detection)
        self._publisher.publish(array)
        self._health.count("images")
        self._health.count("detections", len(array.detections))


main = main_for(ReplayDetectorNode)

if __name__ == "__main__":
    main()
