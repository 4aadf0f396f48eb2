"""``declare_camera_model`` on a node in this process: the calibration is declared read-only from its rows."""

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")

from rclpy.parameter import Parameter  # noqa: E402

from vessel_calib.calibration_parameters import CALIBRATION_ROWS, DEFAULT_CAMERA_PARAMETERS  # noqa: E402
from vessel_calib.camera_parameters import declare_camera_model  # noqa: E402
from vessel_common.errors import CalibrationError  # noqa: E402


def test_the_calibration_is_read_only(ros_context):
    node = rclpy.create_node("fuser", context=ros_context,
                             parameter_overrides=[Parameter("camera.builtin_calibration", value=True)])
    try:
        camera = declare_camera_model(node)
        assert camera is not None
        assert [name for name in node._parameters if name.startswith("camera.")] == [r.name for r in CALIBRATION_ROWS]
        assert list(node.get_parameter("camera.H").value) == DEFAULT_CAMERA_PARAMETERS["H"]
        for name, value in (("camera.H", [1.0] * 9), ("camera.camera_lat", 0.0), ("camera.builtin_calibration", False)):
            refused = node.set_parameters([Parameter(name, value=value)])[0]
            assert not refused.successful and "read-only" in refused.reason, name
            assert f"restart the node with -p {name}:=VALUE" in node.describe_parameter(name).additional_constraints
    finally:
        node.destroy_node()


def test_a_node_without_a_calibration_stops_with_one_line(ros_context):
    node = rclpy.create_node("fuser", context=ros_context)
    try:
        with pytest.raises(CalibrationError, match="no calibration given: pass the calibration file"):
            declare_camera_model(node)
    finally:
        node.destroy_node()
