"""``./vessel graph --cameras``: how many cameras' nodes go into processes (no process is started here)."""

from __future__ import annotations

import json

import pytest
import yaml

from vessel_bringup import fleet, graph, node_host
from vessel_common.errors import DataError


class _FakeProcess:
    pid = 0

    def poll(self):
        return None


def _fake_fleet(tmp_path, monkeypatch, mode: str, respawn: bool = False) -> tuple[fleet.Fleet, list]:
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"tracker": {"ros__parameters": {"gate_px": 55.0}}}))
    spawned = []

    def fake_spawn(self, node, args, label, append_log, parameters, ignore_sigusr1=False):
        spawned.append((self.namespace, node.name, args))
        return graph.RunningNode(node, _FakeProcess(), None, None, parameters)

    monkeypatch.setattr(graph.GraphRunner, "_spawn", fake_spawn)
    cameras = fleet.parse_cameras("cam0=bags/video_13,cam1=bags/video_14")
    return fleet.Fleet(cameras, [params], log_dir=tmp_path / "logs", mode=mode, respawn=respawn), spawned


def test_per_node_runs_every_cameras_graph_as_its_own_namespaced_processes(tmp_path, monkeypatch):
    cameras, spawned = _fake_fleet(tmp_path, monkeypatch, "per-node")
    cameras.start_consumers(lambda camera: {"use_sim_time": False})
    assert [(ns, name) for ns, name, _ in spawned] == [
        (ns, name) for ns in ("/cam0", "/cam1") for name in ("gps_publisher", "fuser", "tracker", "detector")]
    assert sorted(p.label for p in cameras.of_camera("cam1")) == [
        "cam1/detector", "cam1/fuser", "cam1/gps_publisher", "cam1/tracker"]


def test_per_role_hosts_every_cameras_detector_in_one_process_and_the_tracking_in_another(tmp_path, monkeypatch):
    """Each hosted node gets the command line it would have as a process of its own: its namespace, clock, blocks."""
    cameras, spawned = _fake_fleet(tmp_path, monkeypatch, "per-role", respawn=True)
    cameras.start_consumers(lambda camera: {"use_sim_time": False})
    assert [(ns, name) for ns, name, _ in spawned] == [("", "tracking"), ("", "detectors")]
    assert [p.label for p in cameras.processes] == ["tracking", "detectors"]
    assert cameras.processes[0].cameras == ("/cam0", "/cam1")
    tracking = json.loads((tmp_path / "logs" / "tracking.spec.json").read_text())
    assert [entry["node"] for entry in tracking] == ["gps_publisher", "fuser", "tracker"] * 2
    tracker = tracking[5]["args"]
    assert tracker[:9] == ["--ros-args", "-r", "__node:=tracker", "-r", "__ns:=/cam1", "-r", "/clock:=/cam1/clock",
                           "--params-file", str(tmp_path / "params.yaml")]
    overrides = yaml.safe_load((tmp_path / "logs" / "cam1" / "tracker.overrides.yaml").read_text())
    assert overrides == {"/cam1/tracker": {"ros__parameters": {
        "gate_px": 55.0, "use_sim_time": False, "state_file": str(tmp_path / "logs" / "cam1" / "tracker.state")}}}
    detectors = json.loads((tmp_path / "logs" / "detectors.spec.json").read_text())
    assert [entry["node"] for entry in detectors] == ["detector", "detector"]
    host_block = yaml.safe_load((tmp_path / "logs" / "detectors.overrides.yaml").read_text())
    assert host_block == {"detectors": {"ros__parameters": {"spec": str(tmp_path / "logs" / "detectors.spec.json")}}}
    args = spawned[1][2]
    assert node_host.read_spec(args) == detectors  # what the host reads back from its own command line


def test_a_host_refuses_a_spec_it_cannot_run(tmp_path):
    params = tmp_path / "host.yaml"
    args = ["host", "--ros-args", "-r", "__node:=tracking", "--params-file", str(params)]
    params.write_text(yaml.safe_dump({"tracking": {"ros__parameters": {}}}))
    with pytest.raises(DataError, match="no spec parameter"):
        node_host.read_spec(args)
    spec = tmp_path / "spec.json"
    params.write_text(yaml.safe_dump({"tracking": {"ros__parameters": {"spec": str(spec)}}}))
    with pytest.raises(DataError, match="cannot be read"):
        node_host.read_spec(args)
    spec.write_text(json.dumps([{"node": "radar", "args": []}]))
    with pytest.raises(DataError, match="is not a list of"):
        node_host.read_spec(args)
    with pytest.raises(DataError, match="choose per-node or per-role"):
        fleet.Fleet([], [params], mode="per-camera")
