"""A stand-in for the detector that publishes boxes recorded in a CSV for each image it receives.

Used to feed the hand-labelled boxes (or a detector run saved by ``./vessel detect run``) through the same
tracker, fuser and GPS publisher nodes, e.g. ``./vessel demo --detections labels``: the rest of the graph cannot
tell it from the detector. For every image it publishes a ``Detection2DArray`` with the image's header holding
the CSV rows whose ``stamp`` matches the image stamp (within ``stamp_tolerance_s``); images with no rows get an
empty array, so the tracker still sees time pass.

CSV columns: ``stamp`` (UNIX seconds), ``x1, y1, x2, y2`` (full-resolution pixels), ``score``, ``class_name``.
"""

from __future__ import annotations

import bisect
import csv
import math
from pathlib import Path

from rclpy.node import Node
from sensor_msgs.msg import CompressedImage, Image

from vessel_calib.errors import DataError
from vessel_calib.node_support import (
    SENSOR_DATA_QOS,
    NodeHealth,
    declare_parameter,
    main_for,
    reliable_qos,
    stamp_to_sec,
)
from vessel_msgs.msg import Detection2D, Detection2DArray, ObjectHypothesisWithPose

CSV_COLUMNS = ("stamp", "x1", "y1", "x2", "y2", "score", "class_name")


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
        csv_path = declare_parameter(self, "detections_csv", "", "CSV of detections to replay (columns: "
                                     + ", ".join(CSV_COLUMNS) + ")", read_only=True)
        self._tolerance_s = declare_parameter(self, "stamp_tolerance_s", 0.005, "largest stamp difference "
                                              "between an image and its CSV rows, seconds", float_range=(0.0, 10.0))
        image_topic = declare_parameter(self, "compressed_topic", "/camera/image_raw/compressed",
                                        "CompressedImage topic to follow ('' to not subscribe)")
        raw_topic = declare_parameter(self, "image_topic", "", "Image topic to follow ('' to not subscribe)")
        output_topic = declare_parameter(self, "detections_topic", "/vessel/detections", "Detection2DArray output")
        self._rows = load_detection_rows(Path(csv_path)) if csv_path else {}
        if not csv_path:
            self.get_logger().warning("detections_csv is empty: every image gets an empty Detection2DArray")
        self._stamps = sorted(self._rows)
        self._health = NodeHealth(self)
        self._publisher = self.create_publisher(Detection2DArray, output_topic, reliable_qos(10))
        if image_topic:
            self.create_subscription(CompressedImage, image_topic, self._on_image, SENSOR_DATA_QOS)
        if raw_topic:
            self.create_subscription(Image, raw_topic, self._on_image, SENSOR_DATA_QOS)
        self._health.set_value("stamps_in_csv", len(self._stamps))

    def _rows_for(self, stamp_s: float) -> list:
        index = bisect.bisect_left(self._stamps, stamp_s - self._tolerance_s)
        rows = []
        while index < len(self._stamps) and self._stamps[index] <= stamp_s + self._tolerance_s:
            rows.extend(self._rows[self._stamps[index]])
            index += 1
        return rows

    def _on_image(self, image) -> None:
        stamp_s = stamp_to_sec(image.header.stamp)
        array = Detection2DArray()
        array.header = image.header
        for x1, y1, x2, y2, score, class_name in self._rows_for(stamp_s):
            if not all(math.isfinite(v) for v in (x1, y1, x2, y2, score)) or x2 <= x1 or y2 <= y1:
                self._health.problem("bad_row", f"skipping a detection with a non-finite or empty box at {stamp_s}")
                continue
            detection = Detection2D()
            detection.header = image.header
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
