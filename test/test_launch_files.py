"""The launch files describe the same graph as ./vessel graph (launch itself is not on PyPI: stand-ins record it)."""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


class _Recorded:
    def __init__(self, *args, **kwargs):
        self.args = args
        self.kwargs = kwargs


def _stand_in_modules(monkeypatch):
    launch = types.ModuleType("launch")
    launch.LaunchDescription = _Recorded
    actions = types.ModuleType("launch.actions")
    actions.DeclareLaunchArgument = _Recorded
    substitutions = types.ModuleType("launch.substitutions")
    substitutions.LaunchConfiguration = lambda name: f"$({name})"
    launch_ros = types.ModuleType("launch_ros")
    launch_ros_actions = types.ModuleType("launch_ros.actions")
    launch_ros_actions.Node = _Recorded
    for name, module in {"launch": launch, "launch.actions": actions, "launch.substitutions": substitutions,
                         "launch_ros": launch_ros, "launch_ros.actions": launch_ros_actions}.items():
        monkeypatch.setitem(sys.modules, name, module)


def test_graph_launch_file_starts_every_graph_node_with_both_parameter_files(monkeypatch):
    from vessel_track.graph import GRAPH_NODES

    _stand_in_modules(monkeypatch)
    path = REPO_ROOT / "src/vessel_track/launch/vessel_graph.launch.py"
    spec = importlib.util.spec_from_file_location("vessel_graph_launch", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    entities = description.args[0]
    nodes = [e for e in entities if "executable" in e.kwargs]
    declared = {e.args[0] for e in entities if "executable" not in e.kwargs}
    assert [(n.kwargs["package"], n.kwargs["executable"]) for n in nodes] == [
        (g.package, g.executable) for g in GRAPH_NODES
    ]
    assert {"params_file", "calib_file", "source", "rate", "use_sim_time"} <= declared
    for node in nodes:
        parameters = node.kwargs["parameters"]
        assert parameters[:2] == ["$(params_file)", "$(calib_file)"]


def test_every_launch_file_compiles():
    for path in REPO_ROOT.glob("src/*/launch/*.launch.py"):
        compile(path.read_text(), str(path), "exec")
