"""The camera, recorder and replay-detector parameter tables: their names and defaults, as the part files say."""

from pathlib import Path

import pytest
import yaml

from vessel_calib.calibration_parameters import DEFAULT_CAMERA_PARAMETERS
from vessel_common.parameter_names import flatten
from vessel_common.parameter_table import part_file_text
from vessel_detect import bag_topics
from vessel_detect.parameter_tables import (
    CAMERA_FIX_TOPIC,
    CAMERA_PARAMETERS,
    DETECTION_2D_ARRAY,
    GPS_TRUTH_TOPIC,
    IMAGE_TOPIC,
    RECORDER_PARAMETERS,
    REPLAY_DETECTOR_PARAMETERS,
    TABLES,
)

REPO = Path(__file__).resolve().parents[3]


def test_the_topic_names_are_those_of_the_bags():
    assert (IMAGE_TOPIC, CAMERA_FIX_TOPIC, GPS_TRUTH_TOPIC, DETECTION_2D_ARRAY) == (
        bag_topics.DEFAULT_IMAGE_TOPIC, bag_topics.DEFAULT_CAMERA_FIX_TOPIC, bag_topics.DEFAULT_GPS_TRUTH_TOPIC,
        bag_topics.DETECTION_2D_ARRAY)


@pytest.mark.parametrize("table", [CAMERA_PARAMETERS, RECORDER_PARAMETERS], ids=lambda table: table.node)
def test_the_part_file_holds_the_tables_defaults(table):
    """Every value of config/parts/NODE.yaml is the table's default (the file is written from the table)."""
    part = flatten(yaml.safe_load((REPO / "config" / "parts" / f"{table.node}.yaml").read_text())[table.node]
                   ["ros__parameters"])
    assert set(part) <= set(table.names)
    assert {name: value for name, value in part.items() if value != table[name].default} == {}


@pytest.mark.parametrize("table", TABLES, ids=lambda table: table.node)
def test_a_table_renders_to_a_part_file_that_reads_back(table):
    text = part_file_text(table)
    assert flatten(yaml.safe_load(text)[table.node]["ros__parameters"]) == table.defaults()


def test_what_is_live():
    assert {p.name for p in CAMERA_PARAMETERS if p.live} == {
        "rate", "jpeg_quality", "clock_rate_hz", "ack_timeout_s", "frames_in_flight", "drop_late", "max_lag_s",
        "max_frames", "end_linger_s"}
    assert not any(p.live for p in RECORDER_PARAMETERS)
    assert {p.name for p in REPLAY_DETECTOR_PARAMETERS if p.live} == {
        "stamp_tolerance_s", "ack_timeout_s", "wait_for_subscribers"}
    assert CAMERA_PARAMETERS["camera.camera_lat"].default == DEFAULT_CAMERA_PARAMETERS["camera_lat"]


def test_the_tables_check_values():
    assert CAMERA_PARAMETERS.problems({"rate": -1.0, "image_qos": "fast", "frames_in_flight": 2}) == [
        "rate: -1.0 is outside 0 to 1000", "image_qos: 'fast' is not one of sensor_data, reliable"]
    assert REPLAY_DETECTOR_PARAMETERS.problems({"pace": "tracks"}) == ["pace: 'tracks' is not one of images, self"]
