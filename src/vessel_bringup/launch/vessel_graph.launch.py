"""The whole vessel-tracking graph for ``ros2 launch vessel_bringup vessel_graph.launch.py``.

Arguments: ``params_file`` (graph parameters), ``calib_file`` (calibration written by ``calibrate``),
``source`` (camera source: bag folder, .mcap, video, image folder or device:N), ``rate`` (replay rate, 0 = as
fast as the graph consumes), ``use_sim_time`` (``auto``: true when the source is a recording, whose stamps are
the graph's time, false for a live device), ``respawn`` (restart a node that dies, half a second later, at most
five times; the tracker and the fuser then keep a state file, so a restarted one carries on), ``managed`` (the
camera and the detector as lifecycle nodes, configured and activated by this launch: ``camera_managed``,
``detector_managed``). The node list is
``vessel_bringup.graph_nodes.GRAPH_NODES``, the same one ``./vessel graph`` starts on a pip-only install.

The per-run values go on each node's command line as ``-p name:=value``: launch_ros would write them into a
``/**`` block, which the node's own block of ``params_file`` beats, so ``source:=`` and ``rate:=`` would be
ignored. A parameter file that does not exist stops the launch with one line instead of running on defaults.
Every node starts at once, so at a ``rate`` above 0 the camera holds its first frame until the detector has matched
its images (``wait_for_subscribers:=1``, unless the parameter files set another value than the automatic -1), as
``./vessel graph`` does: a replay does not send its first frames to no one.
"""

import shutil
import tempfile
from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from vessel_bringup.graph_nodes import (
    GRAPH_NODES,
    MAX_RESTARTS,
    STATEFUL_NODES,
    camera_command_line,
    camera_waits_for_detector,
    file_parameters,
    sim_time_for_source,
)
from vessel_common.errors import VesselError


def _nodes(context):
    values = {name: LaunchConfiguration(name).perform(context) for name in
              ("params_file", "calib_file", "source", "rate", "use_sim_time", "respawn", "managed")}
    for key in ("params_file", "calib_file"):
        if not Path(values[key]).is_file():
            raise RuntimeError(f"{key}:={values[key]} is not a file: give the graph's parameter file (e.g. "
                               "config/aitas.yaml) and the calibration written by calibrate (config/aitas_camera.yaml)")
    if values["rate"].strip():
        try:
            float(values["rate"])
        except ValueError:
            raise RuntimeError(f"rate:={values['rate']} is not a number: give the replay rate, e.g. rate:=1.0 "
                               "(real time) or rate:=0 (as fast as the graph consumes)") from None
    use_sim_time = sim_time_for_source(values["source"]) if values["use_sim_time"] == "auto" else \
        values["use_sim_time"].lower() == "true"
    respawn = values["respawn"].lower() == "true"
    state_dir = Path(tempfile.mkdtemp(prefix="vessel_graph_state_")) if respawn else None
    nodes = []
    for graph_node in GRAPH_NODES:
        ros_arguments = ["-p", f"use_sim_time:={'true' if use_sim_time else 'false'}"]
        if graph_node.name == "camera":
            ros_arguments += camera_command_line(values["source"], values["rate"])
            rate = {"rate": values["rate"]} if values["rate"].strip() else {}
            try:
                waits = camera_waits_for_detector(
                    file_parameters([values["params_file"], values["calib_file"]], "camera"), rate, local_detector=True)
            except VesselError as error:
                raise RuntimeError(str(error)) from None
            ros_arguments += [arg for name, value in waits.items() for arg in ("-p", f"{name}:={value}")]
        if state_dir is not None and graph_node.name in STATEFUL_NODES:
            ros_arguments += ["-p", f"state_file:={state_dir / (graph_node.name + '.state')}"]
        common = dict(package=graph_node.package, name=graph_node.name,
                      parameters=[values["params_file"], values["calib_file"]], ros_arguments=ros_arguments,
                      respawn=respawn and graph_node.name != "camera", respawn_delay=0.5,
                      respawn_max_retries=MAX_RESTARTS, output="screen",
                      emulate_tty=True)
        if graph_node.name in ("camera", "detector") and values["managed"].lower() == "true":
            nodes += _managed(graph_node.executable + "_managed", common)
        else:
            nodes.append(Node(executable=graph_node.executable, **common))
    if state_dir is not None:  # the state files live as long as the launch
        from launch.actions import RegisterEventHandler
        from launch.event_handlers import OnShutdown

        nodes.append(RegisterEventHandler(OnShutdown(on_shutdown=[
            OpaqueFunction(function=lambda _context: shutil.rmtree(state_dir, ignore_errors=True))])))
    return nodes


def _managed(executable: str, common: dict) -> list:
    """A lifecycle node and the events that configure it, then activate it once it is inactive."""
    from launch.actions import EmitEvent, RegisterEventHandler
    from launch.events import matches_action
    from launch_ros.actions import LifecycleNode
    from launch_ros.event_handlers import OnStateTransition
    from launch_ros.events.lifecycle import ChangeState
    from lifecycle_msgs.msg import Transition

    node = LifecycleNode(executable=executable, namespace="", **common)

    def transition(transition_id):
        return EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(node), transition_id=transition_id))

    return [
        node,
        RegisterEventHandler(OnStateTransition(target_lifecycle_node=node, goal_state="inactive",
                                               entities=[transition(Transition.TRANSITION_ACTIVATE)])),
        transition(Transition.TRANSITION_CONFIGURE),
    ]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("params_file", description="graph parameter file, e.g. config/aitas.yaml"),
        DeclareLaunchArgument("calib_file", description="calibration file written by vessel_tools calibrate"),
        DeclareLaunchArgument("source", default_value="", description="camera source (bag, video, folder, device:N)"),
        DeclareLaunchArgument("rate", default_value="1.0", description="replay rate; 0 = as fast as consumed"),
        DeclareLaunchArgument("use_sim_time", default_value="auto",
                              description="follow /clock from the camera: true, false or auto (true for a "
                                          "recording, false for a live device)"),
        DeclareLaunchArgument("managed", default_value="false",
                              description="run the camera and the detector as lifecycle nodes that this launch "
                                          "configures and activates (lifecycle services under /camera, /detector)"),
        DeclareLaunchArgument("respawn", default_value="false",
                              description="restart a node (all but the camera) half a second after it dies, at most "
                                          "five times; the tracker and fuser resume from a state file"),
        OpaqueFunction(function=_nodes),
    ])
