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


def _stand_in_modules(monkeypatch):
    launch = types.ModuleType("launch")
    launch.LaunchDescription = _Recorded
    actions = types.ModuleType("launch.actions")
    actions.DeclareLaunchArgument = _Recorded
    actions.OpaqueFunction = _Recorded
    substitutions = types.ModuleType("launch.substitutions")
    substitutions.LaunchConfiguration = _Configuration
    launch_ros = types.ModuleType("launch_ros")
    launch_ros_actions = types.ModuleType("launch_ros.actions")
    launch_ros_actions.Node = _Recorded
    for name, module in {"launch": launch, "launch.actions": actions, "launch.substitutions": substitutions,
                         "launch_ros": launch_ros, "launch_ros.actions": launch_ros_actions}.items():
        monkeypatch.setitem(sys.modules, name, module)


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
    assert {"params_file", "calib_file", "source", "rate", "use_sim_time", "respawn", "managed"} <= declared
    context = {"params_file": str(REPO_ROOT / "config/aitas.yaml"), "calib_file": str(REPO_ROOT /
               "config/aitas_camera.yaml"), "source": "bags/video_13", "rate": "4", "use_sim_time": "auto",
               "respawn": "false", "managed": "false"}
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
               "managed": "false"}
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
               "managed": "false"}
    if message is None:
        assert "wait_for_subscribers:=1" not in module._nodes(context)[0].kwargs["ros_arguments"]
    else:
        with pytest.raises(RuntimeError, match=message):
            module._nodes(context)


def test_a_mistyped_parameter_file_stops_the_graph_launch(monkeypatch):
    module = _load_graph_launch(monkeypatch)
    context = {"params_file": "config/aitas_typo.yaml", "calib_file": "config/aitas_camera.yaml", "source": "",
               "rate": "1.0", "use_sim_time": "auto", "respawn": "false", "managed": "false"}
    with pytest.raises(RuntimeError, match="aitas_typo.yaml is not a file"):
        module._nodes(context)


def test_every_launch_file_compiles():
    for path in REPO_ROOT.glob("src/*/launch/*.launch.py"):
        compile(path.read_text(), str(path), "exec")
