"""The whole vessel-tracking graph for ``ros2 launch vessel_track vessel_graph.launch.py``.

Arguments: ``params_file`` (graph parameters), ``calib_file`` (calibration written by ``calibrate``),
``source`` (camera source: bag folder, .mcap, video, image folder or device:N), ``rate`` (replay rate, 0 = as
fast as the graph consumes), ``use_sim_time``. The node list is ``vessel_track.graph.GRAPH_NODES``, the same one
``./vessel graph`` starts on a pip-only install.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from vessel_track.graph import GRAPH_NODES


def generate_launch_description():
    params_file = LaunchConfiguration("params_file")
    calib_file = LaunchConfiguration("calib_file")
    arguments = [
        DeclareLaunchArgument("params_file", description="graph parameter file, e.g. config/aitas.yaml"),
        DeclareLaunchArgument("calib_file", description="calibration file written by vessel_calib calibrate"),
        DeclareLaunchArgument("source", default_value="", description="camera source (bag, video, folder, device:N)"),
        DeclareLaunchArgument("rate", default_value="1.0", description="replay rate; 0 = as fast as consumed"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="follow /clock from the camera"),
    ]
    nodes = []
    for graph_node in GRAPH_NODES:
        overrides = {"use_sim_time": LaunchConfiguration("use_sim_time")}
        if graph_node.name == "camera":
            overrides.update({"source": LaunchConfiguration("source"), "rate": LaunchConfiguration("rate")})
        nodes.append(
            Node(
                package=graph_node.package,
                executable=graph_node.executable,
                name=graph_node.name,
                parameters=[params_file, calib_file, overrides],
                output="screen",
                emulate_tty=True,
            )
        )
    return LaunchDescription([*arguments, *nodes])
