"""The replay detector in this process: its parameters at start and under ``ros2 param set``."""

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")
pytest.importorskip("vessel_msgs.msg", reason="vessel_msgs is not built: run ./vessel setup")

from builtin_interfaces.msg import Time  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import CompressedImage  # noqa: E402

from vessel_common.errors import VesselError  # noqa: E402
from vessel_detect.replay_detector_node import CSV_COLUMNS, ReplayDetectorNode  # noqa: E402


@pytest.fixture
def make_node(tmp_path, monkeypatch, ros_context):
    """``make_node(**parameters)``: a replay detector of a two-row CSV (stamps 100.0 and 100.02 s)."""
    csv = tmp_path / "detections.csv"
    csv.write_text(",".join(CSV_COLUMNS) + "\n100.0,10,10,50,40,0.9,boat\n100.02,12,10,52,40,0.8,boat\n")
    made = []
    node_init = rclpy.node.Node.__init__

    def make(**parameters):
        overrides = [Parameter(name, value=value) for name, value in {"detections_csv": str(csv), **parameters}.items()]
        monkeypatch.setattr(rclpy.node.Node, "__init__", lambda self, name, **kw: node_init(
            self, name, context=ros_context, parameter_overrides=overrides, **kw))
        node = ReplayDetectorNode()
        made.append(node)
        return node

    yield make
    for node in made:
        node.destroy_node()


def _image(sec: int, nanosec: int) -> CompressedImage:
    image = CompressedImage()
    image.header.stamp = Time(sec=sec, nanosec=nanosec)
    return image


def test_a_live_change_takes_effect_and_bad_or_read_only_changes_are_refused(make_node):
    node = make_node()
    published = []
    node._publisher.publish = published.append
    node._on_image(_image(100, 10_000_000))  # 10 ms from either row: beyond the default 5 ms tolerance
    assert len(published[-1].detections) == 0

    assert node.set_parameters([Parameter("stamp_tolerance_s", value=0.015)])[0].successful
    node._on_image(_image(100, 10_000_000))
    assert len(published[-1].detections) == 2  # both rows are within 15 ms now

    refused = node.set_parameters([Parameter("stamp_tolerance_s", value=-1.0)])[0]
    assert not refused.successful and "stamp_tolerance_s" in refused.reason and "range" in refused.reason
    assert node.get_parameter("stamp_tolerance_s").value == 0.015
    for name, value in (("pace", "self"), ("detections_csv", "/etc/passwd"), ("detections_topic", "/other")):
        refused = node.set_parameters([Parameter(name, value=value)])[0]
        assert not refused.successful and "read-only" in refused.reason, name
        assert f"restart the node with -p {name}:=VALUE" in node.describe_parameter(name).additional_constraints


def test_a_bad_pace_stops_the_node_at_start_with_one_line(make_node):
    with pytest.raises(VesselError, match="pace: 'tracks' is not one of images, self; fix the value"):
        make_node(pace="tracks")
