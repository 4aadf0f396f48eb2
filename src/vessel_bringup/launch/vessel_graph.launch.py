"""The whole vessel-tracking graph for ``ros2 launch vessel_bringup vessel_graph.launch.py``.

Arguments: ``params_file`` (graph parameters), ``calib_file`` (calibration written by ``calibrate``),
``source`` (camera source: bag folder, .mcap, video, image folder or device:N), ``rate`` (replay rate, 0 = as
fast as the graph consumes), ``use_sim_time`` (``auto``: true when the source is a recording, whose stamps are
the graph's time, false for a live device), ``record`` (also record the graph's outputs into this bag folder, as
``./vessel graph --record`` does), ``respawn`` (restart a node that fails, as ``./vessel graph --respawn`` does:
see below), ``managed`` (the camera and the detector as lifecycle nodes, configured and activated by this launch:
``camera_managed``, ``detector_managed``), ``namespace`` (the graph of one camera of several: its topics
``/NAME/vessel/fix``, its clock ``/NAME/clock``, the node blocks of the parameter files under ``/NAME/<node>``, as
``./vessel graph --namespace`` does). The node list is ``vessel_bringup.graph_nodes.GRAPH_NODES`` (and its
``RECORDER``), the same one ``./vessel graph`` starts on a pip-only install.

``respawn:=true`` treats every node as ``./vessel graph --respawn`` does (``graph_nodes``): a node that exits with
a non-zero status (killed, crashed) is restarted at once, then after 0.5 s doubling to 8 s; one that failed
``MAX_RESTARTS`` times is left down and the launch stops. A node that exits with 0 (the camera at the end of its
source) is not restarted. The tracker and the fuser keep a state file and carry on from their tracks, the camera
a resume file and carries on after the last frame it sent, the recorder a resume file and continues into the next
part of the recording (``RECORD.1``, ...), all in a state folder that lives as long as the launch
(``graph_nodes.respawn_files``).

The per-run values go on each node's command line as ``-p name:=value``: launch_ros would write them into a
``/**`` block, which the node's own block of ``params_file`` beats, so ``source:=`` and ``rate:=`` would be
ignored. A parameter file that does not exist stops the launch with one line instead of running on defaults.
Every node starts at once, so at a ``rate`` above 0 the camera holds its first frame until the detector has matched
its images (``wait_for_subscribers:=1``, unless the parameter files set another value than the automatic -1), as
``./vessel graph`` does: a replay does not send its first frames to no one.
"""

import atexit
import functools
import shutil
import tempfile
from pathlib import Path

from launch import LaunchDescription
from launch.actions import (
    DeclareLaunchArgument,
    LogInfo,
    OpaqueFunction,
    RegisterEventHandler,
    Shutdown,
    TimerAction,
)
from launch.event_handlers import OnProcessExit
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from vessel_bringup.graph_nodes import (
    GRAPH_NODES,
    MAX_RESTARTS,
    RECORDER,
    camera_command_line,
    camera_waits_for_detector,
    clock_topic,
    file_parameters,
    namespaced_blocks,
    respawn_files,
    restart_delay_s,
    restart_wanted,
    sim_time_for_source,
)
from vessel_common.errors import VesselError
from vessel_common.graph_names import graph_namespace

ARGUMENTS = ("params_file", "calib_file", "source", "rate", "use_sim_time", "record", "respawn", "managed",
             "namespace")


def _nodes(context):
    values = {name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS}
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
    try:
        namespace = graph_namespace(values["namespace"])
    except VesselError as error:
        raise RuntimeError(f"namespace:={values['namespace']}: {error}") from None
    state_dir = Path(tempfile.mkdtemp(prefix="vessel_graph_state_")) if respawn or namespace else None
    entities = []
    for graph_node in GRAPH_NODES + ((RECORDER,) if values["record"].strip() else ()):
        ros_arguments = ["-p", f"use_sim_time:={'true' if use_sim_time else 'false'}"]
        ros_arguments += _per_run_arguments(graph_node.name, values)
        if respawn:
            ros_arguments += _assignments(respawn_files(graph_node.name, state_dir))
        common = dict(package=graph_node.package, name=graph_node.name,
                      parameters=[values["params_file"], values["calib_file"]], ros_arguments=ros_arguments,
                      output="screen", emulate_tty=True)
        if namespace:  # the node's blocks under /NAME/<node>, its own clock
            common.update(namespace=namespace, remappings=[("/clock", clock_topic(namespace))])
            common["parameters"] = [*common["parameters"], _namespaced_file(graph_node.name, namespace, values,
                                                                            state_dir)]
        managed = graph_node.name in ("camera", "detector") and values["managed"].lower() == "true"
        make = functools.partial(_managed if managed else _plain, graph_node.executable, common)
        entities += _respawning(make, graph_node.name) if respawn else make()
    if state_dir is not None:  # the state files live as long as the launch: removed once its nodes are gone
        atexit.register(shutil.rmtree, state_dir, ignore_errors=True)  # (at its shutdown event they still write)
    return entities


def _namespaced_file(name: str, namespace: str, values: dict, folder: Path) -> str:
    """A parameter file with node ``name``'s blocks of the parameter files under its namespaced name."""
    import yaml

    path = folder / f"{name}.namespaced.yaml"
    blocks = namespaced_blocks([values["params_file"], values["calib_file"]], name, namespace)
    path.write_text(yaml.safe_dump(blocks))
    return str(path)


def _assignments(parameters: dict) -> list[str]:
    return [arg for name, value in parameters.items() for arg in ("-p", f"{name}:={value}")]


def _per_run_arguments(name: str, values: dict) -> list[str]:
    """``-p`` assignments of a node's per-run values: the camera's source and rate, the recorder's output."""
    if name == RECORDER.name:
        return _assignments({"output": values["record"].strip()})
    if name != "camera":
        return []
    rate = {"rate": values["rate"]} if values["rate"].strip() else {}
    try:
        waits = camera_waits_for_detector(
            file_parameters([values["params_file"], values["calib_file"]], "camera"), rate, local_detector=True)
    except VesselError as error:
        raise RuntimeError(str(error)) from None
    return camera_command_line(values["source"], values["rate"]) + _assignments(waits)


def _respawning(make, name: str, restarts: int = 0) -> list:
    """The node's entities (``make()``, the node first), restarted as ``./vessel graph --respawn`` restarts one.

    On a non-zero exit (``restart_wanted``) a new node like it starts after ``restart_delay_s``; after
    ``MAX_RESTARTS`` restarts the launch stops instead. A node that exits with 0, or at shutdown, stays down.
    """
    entities = make(restarted=restarts > 0)
    node = entities[0]

    def on_exit(event, context):
        status = event.returncode
        if context.is_shutdown or not restart_wanted(status):
            return None
        if restarts >= MAX_RESTARTS:
            return [LogInfo(msg=f"[graph] {name} failed {restarts + 1} times (exit {status}): not restarted again; "
                                "stopping the launch, see its output"),
                    Shutdown(reason=f"{name} failed {restarts + 1} times")]
        _forget_node_name(context, node)
        for entity in entities[1:]:  # a lifecycle node's: they would act on the new process too (activate it twice)
            if isinstance(entity, RegisterEventHandler):
                context.unregister_event_handler(entity.event_handler)
        delay = restart_delay_s(restarts)
        again = _respawning(make, name, restarts + 1)
        return [LogInfo(msg=f"[graph] {name} exited with status {status}: restarting it (restart {restarts + 1} "
                            f"of at most {MAX_RESTARTS})"),
                *(again if delay == 0.0 else [TimerAction(period=delay, actions=again)])]

    return [RegisterEventHandler(OnProcessExit(target_action=node, on_exit=on_exit)), *entities]


def _forget_node_name(context, node) -> None:
    """launch_ros counts the node names it started and warns of a second one: a restart is the same node."""
    try:
        context.locals.unique_ros_node_names[node.node_name] -= 1
    except (AttributeError, KeyError, RuntimeError):  # another launch_ros: its warning is all that happens
        pass


def _plain(executable: str, common: dict, restarted: bool = False) -> list:
    return [Node(executable=executable, **common)]


def _managed(executable: str, common: dict, restarted: bool = False) -> list:
    """A lifecycle node and the events that configure it, then activate it once it is inactive.

    A ``restarted`` one is configured once its own lifecycle service answers (``_once_answering``).
    """
    from launch.actions import EmitEvent
    from launch.events import matches_action
    from launch_ros.actions import LifecycleNode
    from launch_ros.event_handlers import OnStateTransition
    from launch_ros.events.lifecycle import ChangeState
    from lifecycle_msgs.msg import Transition

    node = LifecycleNode(executable=executable + "_managed", **{"namespace": "", **common})

    def transition(transition_id):
        return ChangeState(lifecycle_node_matcher=matches_action(node), transition_id=transition_id)

    configure = transition(Transition.TRANSITION_CONFIGURE)
    return [
        node,
        RegisterEventHandler(OnStateTransition(target_lifecycle_node=node, goal_state="inactive",
                                               entities=[EmitEvent(event=transition(Transition.TRANSITION_ACTIVATE))])),
        _once_answering(f"{common.get('namespace', '')}/{common['name']}", configure) if restarted
        else EmitEvent(event=configure),
    ]


def _once_answering(name: str, event) -> OpaqueFunction:
    """Emit ``event`` once node ``name``'s ``get_state`` service answers: a restarted node's, not the dead one's.

    ``name``: the node's fully qualified name (``/camera``, ``/a/camera``).

    The killed process's services stay known for a while (its DDS lease): launch_ros sent a restarted node's
    ``configure`` at once, to the dead one alone, and waited for its answer for good (the node stayed unconfigured).
    Only a live process answers ``get_state``; asked again every 2 s until it does.
    """
    def start(context):
        import time

        from launch_ros.ros_adapters import get_ros_node
        from lifecycle_msgs.srv import GetState

        ros_node = get_ros_node(context)
        client = ros_node.create_client(GetState, f"{name}/get_state")

        def ask() -> None:
            while not context.is_shutdown:
                future = client.call_async(GetState.Request())
                deadline = time.monotonic() + 2.0
                while not future.done() and time.monotonic() < deadline and not context.is_shutdown:
                    time.sleep(0.05)
                if future.done():
                    context.asyncio_loop.call_soon_threadsafe(lambda: context.emit_event_sync(event))
                    break
                client.remove_pending_request(future)
            ros_node.destroy_client(client)

        context.add_completion_future(context.asyncio_loop.run_in_executor(None, ask))

    return OpaqueFunction(function=start)


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("params_file", description="graph parameter file, e.g. config/aitas.yaml"),
        DeclareLaunchArgument("calib_file", description="calibration file written by vessel_tools calibrate"),
        DeclareLaunchArgument("source", default_value="", description="camera source (bag, video, folder, device:N)"),
        DeclareLaunchArgument("rate", default_value="1.0", description="replay rate; 0 = as fast as consumed"),
        DeclareLaunchArgument("use_sim_time", default_value="auto",
                              description="follow /clock from the camera: true, false or auto (true for a "
                                          "recording, false for a live device)"),
        DeclareLaunchArgument("record", default_value="",
                              description="also record the graph's outputs into this bag folder (recorder node); "
                                          "'': no recording"),
        DeclareLaunchArgument("managed", default_value="false",
                              description="run the camera and the detector as lifecycle nodes that this launch "
                                          "configures and activates (lifecycle services under /camera, /detector)"),
        DeclareLaunchArgument("respawn", default_value="false",
                              description="restart a node that fails, at once, then after 0.5 s doubling to 8 s, at "
                                          "most five times (then the launch stops); the tracker and the fuser resume "
                                          "from a state file, the camera after its last frame, the recorder into "
                                          "RECORD.1, ..."),
        DeclareLaunchArgument("namespace", default_value="",
                              description="run the graph under this namespace, one camera of several in one ROS "
                                          "domain: /NAME/vessel/fix, ..., its own clock /NAME/clock; '': none"),
        OpaqueFunction(function=_nodes),
    ])
