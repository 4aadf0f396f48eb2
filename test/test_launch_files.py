"""The launch files describe the same graph as ./vessel graph (launch itself is not on PyPI: stand-ins record it)."""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


class _Recorded:
    def __init__(self, *args, **kwargs):
        self.args = args
        self.kwargs = kwargs


class _Configuration:
    def __init__(self, name):
        self.name = name

    def perform(self, context):
        return context[self.name]


STAND_INS = {
    "launch": ("LaunchDescription",),
    "launch.actions": ("DeclareLaunchArgument", "OpaqueFunction", "RegisterEventHandler", "LogInfo", "Shutdown",
                       "TimerAction"),
    "launch.event_handlers": ("OnProcessExit",),
    "launch_ros": (),
    "launch_ros.actions": ("Node",),
}
"""The launch classes the launch file uses, each a ``_Recorded`` of its own name (tests tell them apart by it)."""


def _stand_in_modules(monkeypatch):
    for name, classes in STAND_INS.items():
        module = types.ModuleType(name)
        for class_name in classes:
            setattr(module, class_name, type(class_name, (_Recorded,), {}))
        monkeypatch.setitem(sys.modules, name, module)
    substitutions = types.ModuleType("launch.substitutions")
    substitutions.LaunchConfiguration = _Configuration
    monkeypatch.setitem(sys.modules, "launch.substitutions", substitutions)


def _load_graph_launch(monkeypatch):
    _stand_in_modules(monkeypatch)
    path = REPO_ROOT / "src/vessel_bringup/launch/vessel_graph.launch.py"
    spec = importlib.util.spec_from_file_location("vessel_graph_launch", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_graph_launch_file_starts_every_graph_node_with_both_parameter_files(monkeypatch):
    """Stand-ins; test_launch_graph.py runs the real ros2 launch where it is installed."""
    from vessel_bringup.graph_nodes import GRAPH_NODES

    module = _load_graph_launch(monkeypatch)
    entities = module.generate_launch_description().args[0]
    declared = {e.args[0] for e in entities if e.args}
    assert {"params_file", "calib_file", "source", "rate", "use_sim_time", "respawn", "managed", "record"} <= declared
    context = {"params_file": str(REPO_ROOT / "config/aitas.yaml"), "calib_file": str(REPO_ROOT /
               "config/aitas_camera.yaml"), "source": "bags/video_13", "rate": "4", "use_sim_time": "auto",
               "respawn": "false", "managed": "false", "record": "",
               "namespace": ""}
    nodes = module._nodes(context)
    assert [(n.kwargs["package"], n.kwargs["executable"]) for n in nodes] == [
        (g.package, g.executable) for g in GRAPH_NODES
    ]
    for node in nodes:
        assert node.kwargs["parameters"] == [context["params_file"], context["calib_file"]]
        # The per-run values are -p assignments, which beat the node's own block of the parameter file.
        assert node.kwargs["ros_arguments"][:2] == ["-p", "use_sim_time:=true"]  # a recording: its /clock
    camera = nodes[0].kwargs["ros_arguments"]
    # Every node starts at once: at a rate above 0 the camera holds its first frame for the detector.
    assert camera[2:] == ["-p", "source:=bags/video_13", "-p", "rate:=4.0", "-p", "wait_for_subscribers:=1"]


@pytest.mark.parametrize("rate, camera_block, waits", [
    ("1.0", {}, True),
    ("0", {}, False),  # the camera's automatic wait at rate 0 already waits for the detector
    ("", {"rate": 2.0}, True),  # no rate:= given: the file's
    ("", {"rate": 0.0}, False),
    ("1.0", {"wait_for_subscribers": 0}, False),  # a value the user set is kept
    ("1.0", {"wait_for_subscribers": -1}, True),  # -1 is the automatic value, as in config/aitas.yaml
])
def test_the_launched_camera_waits_for_the_detector_unless_told_otherwise(monkeypatch, tmp_path, rate, camera_block,
                                                                         waits):
    import yaml

    module = _load_graph_launch(monkeypatch)
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"camera": {"ros__parameters": camera_block}}))
    context = {"params_file": str(params), "calib_file": str(REPO_ROOT / "config/aitas_camera.yaml"),
               "source": "bags/video_13", "rate": rate, "use_sim_time": "auto", "respawn": "false",
               "managed": "false", "record": "", "namespace": ""}
    camera = module._nodes(context)[0].kwargs["ros_arguments"]
    assert ("wait_for_subscribers:=1" in camera) == waits


@pytest.mark.parametrize("rate, blocks, message", [
    ("", {"/**": {"ros__parameters": {"wait_for_subscribers": 2}}}, None),  # set for every node: kept
    ("fast", {}, "rate:=fast is not a number"),
    ("", {"camera": {"ros__parameters": {"rate": "fast"}}}, "the camera's rate in the parameter files is 'fast'"),
])
def test_the_launched_cameras_wait_follows_the_shared_block_and_a_bad_rate_stops_the_launch(monkeypatch, tmp_path,
                                                                                            rate, blocks, message):
    import yaml

    module = _load_graph_launch(monkeypatch)
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump(blocks))
    context = {"params_file": str(params), "calib_file": str(REPO_ROOT / "config/aitas_camera.yaml"),
               "source": "bags/video_13", "rate": rate, "use_sim_time": "auto", "respawn": "false",
               "managed": "false", "record": "", "namespace": ""}
    if message is None:
        assert "wait_for_subscribers:=1" not in module._nodes(context)[0].kwargs["ros_arguments"]
    else:
        with pytest.raises(RuntimeError, match=message):
            module._nodes(context)


def test_a_namespaced_launch_puts_every_node_its_blocks_and_its_clock_under_the_namespace(monkeypatch, tmp_path):
    """``namespace:=cam_a``: one camera of several in one domain, each node's blocks reach ``/cam_a/<node>``."""
    import shutil

    import yaml

    module = _load_graph_launch(monkeypatch)
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"qos_depth": 3}},
                                      "tracker": {"ros__parameters": {"gate_px": 55.0}}}))
    context = {"params_file": str(params), "calib_file": str(REPO_ROOT / "config/aitas_camera.yaml"),
               "source": "bags/video_13", "rate": "4", "use_sim_time": "auto", "respawn": "false",
               "managed": "false", "record": "", "namespace": "cam_a"}
    nodes = {node.kwargs["name"]: node.kwargs for node in module._nodes(context)}
    try:
        for name, kwargs in nodes.items():
            assert kwargs["namespace"] == "/cam_a" and kwargs["remappings"] == [("/clock", "/cam_a/clock")]
            files, extra = kwargs["parameters"][:2], yaml.safe_load(Path(kwargs["parameters"][2]).read_text())
            assert files == [context["params_file"], context["calib_file"]] and list(extra) == [f"/cam_a/{name}"]
        assert nodes["tracker"]["parameters"][2] != nodes["fuser"]["parameters"][2]
        tracker = yaml.safe_load(Path(nodes["tracker"]["parameters"][2]).read_text())["/cam_a/tracker"]
        assert tracker["ros__parameters"] == {"gate_px": 55.0}  # its own block; the /** one applies as it is
    finally:
        shutil.rmtree(Path(nodes["camera"]["parameters"][2]).parent, ignore_errors=True)
    with pytest.raises(RuntimeError, match="namespace:=2cams"):
        module._nodes({**context, "namespace": "2cams"})


def test_a_mistyped_parameter_file_stops_the_graph_launch(monkeypatch):
    module = _load_graph_launch(monkeypatch)
    context = {"params_file": "config/aitas_typo.yaml", "calib_file": "config/aitas_camera.yaml", "source": "",
               "rate": "1.0", "use_sim_time": "auto", "respawn": "false", "managed": "false", "record": "",
               "namespace": ""}
    with pytest.raises(RuntimeError, match="aitas_typo.yaml is not a file"):
        module._nodes(context)


def _handlers(entities) -> dict:
    """The on-exit handler the launch registered for each node: ``{node: on_exit}``."""
    return {handler.args[0].kwargs["target_action"]: handler.args[0].kwargs["on_exit"] for handler in entities
            if type(handler).__name__ == "RegisterEventHandler" and type(handler.args[0]).__name__ == "OnProcessExit"}


def test_respawn_treats_every_node_as_the_graph_runner_does(monkeypatch, tmp_path):
    """``respawn:=true`` restarts a failed node, the camera and the recorder too, as ``./vessel graph --respawn`` does.

    Issue 48: ``respawn:=true`` never restarted the camera (26 of 36 frames lost) and restarted the others however
    they exited, half a second later; ``./vessel graph --respawn`` restarts every node that fails, with back-off.
    Now each node (the recorder of ``record:=`` too) gets ``graph_nodes.respawn_files`` (the camera and the recorder
    a resume file) and is restarted as the graph runner restarts one: on a non-zero exit only, after
    ``restart_delay_s``, a node like the first; after ``MAX_RESTARTS`` the launch stops.
    """
    import shutil
    from collections import defaultdict
    from types import SimpleNamespace

    from vessel_bringup.graph_nodes import GRAPH_NODES, MAX_RESTARTS, RECORDER, respawn_files, restart_delay_s

    module = _load_graph_launch(monkeypatch)
    context = {"params_file": str(REPO_ROOT / "config/aitas.yaml"), "calib_file": str(REPO_ROOT /
               "config/aitas_camera.yaml"), "source": "bags/video_13", "rate": "4", "use_sim_time": "auto",
               "respawn": "true", "managed": "false", "record": str(tmp_path / "rec"),
               "namespace": ""}
    entities = module._nodes(context)
    nodes = [entity for entity in entities if type(entity).__name__ == "Node"]
    assert [node.kwargs["name"] for node in nodes] == [g.name for g in GRAPH_NODES] + [RECORDER.name]
    arguments = {node.kwargs["name"]: node.kwargs["ros_arguments"] for node in nodes}
    state_dir = Path(next(arg for arg in arguments["camera"] if arg.startswith("resume_file:=")).split(":=")[1]).parent
    try:
        for node in nodes:
            name = node.kwargs["name"]
            assert not node.kwargs.get("respawn"), name  # launch's own respawn restarts on any exit
            files = dict(arg.split(":=") for arg in arguments[name] if "_file:=" in arg)
            assert files == respawn_files(name, state_dir), name
        assert f"output:={tmp_path / 'rec'}" in arguments["recorder"]

        failed = SimpleNamespace(returncode=-9)
        launch = SimpleNamespace(is_shutdown=False, locals=SimpleNamespace(unique_ros_node_names=defaultdict(int)))
        for node in nodes:
            on_exit = _handlers(entities)[node]
            assert on_exit(SimpleNamespace(returncode=0), launch) is None  # the camera at the end of its source
            assert on_exit(failed, SimpleNamespace(is_shutdown=True)) is None  # Ctrl-C
            for restarts in range(MAX_RESTARTS):
                actions = on_exit(failed, launch)
                assert type(actions[0]).__name__ == "LogInfo"
                assert f"restart {restarts + 1} of at most {MAX_RESTARTS}" in actions[0].kwargs["msg"]
                delay = restart_delay_s(restarts)
                if delay:
                    (timer,) = actions[1:]
                    assert type(timer).__name__ == "TimerAction" and timer.kwargs["period"] == delay
                    actions = [None, *timer.kwargs["actions"]]
                again = next(entity for entity in actions[1:] if type(entity).__name__ == "Node")
                assert again.kwargs == node.kwargs  # the same node with the same files: it carries on
                on_exit = _handlers(actions[1:])[again]
            assert [type(action).__name__ for action in on_exit(failed, launch)] == ["LogInfo", "Shutdown"]
    finally:
        shutil.rmtree(state_dir, ignore_errors=True)


def test_every_launch_file_compiles():
    for path in REPO_ROOT.glob("src/*/launch/*.launch.py"):
        compile(path.read_text(), str(path), "exec")
