"""config/parts/tracker.yaml holds every tracker setting with the defaults of ``TrackerConfig`` (ROS-free)."""

from dataclasses import fields
from pathlib import Path

import yaml

from vessel_track.tracker_config import TrackerConfig

PART = Path(__file__).resolve().parents[3] / "config" / "parts" / "tracker.yaml"


def test_parameter_file_part_matches_the_config_defaults():
    params = yaml.safe_load(PART.read_text())["tracker"]["ros__parameters"]
    defaults = TrackerConfig().to_dict()
    assert {f.name for f in fields(TrackerConfig)} <= set(params)
    assert {k: params[k] for k in defaults} == defaults
    assert TrackerConfig.from_dict({k: params[k] for k in defaults}) == TrackerConfig()
    assert params["input_topic"] == "vessel/detections" and params["output_topic"] == "vessel/tracks/screen"
