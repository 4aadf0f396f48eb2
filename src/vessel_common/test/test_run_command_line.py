"""``-p name:=value`` on a node's command line: it wins over the parameter files, and a bad one stops the node.

rcl files ``-p`` assignments under ``/**``, which the node's own block of a parameter file beats: with a file that
sets a value per node, every ``-p`` of that value was silently ignored, misspelt names and out-of-range values
included. ``run.with_command_line`` hands them to rclpy as ``parameter_overrides``, which rclpy applies last.
"""

from __future__ import annotations

import subprocess

import pytest

REPO = __import__("pathlib").Path(__file__).resolve().parents[3]
GRAPH_FILE = REPO / "config" / "aitas.yaml"


def _own_block(tmp_path, node: str = "tracker"):
    """A parameter file whose block for ``node`` sets what the tests give with ``-p`` as well."""
    path = tmp_path / "own_block.yaml"
    path.write_text(f"/**:\n  ros__parameters:\n    use_sim_time: false\n"
                    f"{node}:\n  ros__parameters:\n    use_sim_time: false\n    gate_px: 40.0\n    min_hits: 3\n")
    return path


def _context(ros_env, args):
    import rclpy

    context = rclpy.context.Context()
    rclpy.init(context=context, args=args, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    return context


@pytest.mark.parametrize("managed", [False, True])
def test_the_command_line_reaches_rclpy_as_parameter_overrides(ros_env, tmp_path, managed):
    """In the process: a node class made by ``with_command_line`` gets the ``-p`` values over its own block."""
    import rclpy
    from rclpy.lifecycle import LifecycleNode
    from rclpy.node import Node

    from vessel_common.parameter_declaration import declare_parameter
    from vessel_common.run import with_command_line

    class Probe(LifecycleNode if managed else Node):
        """Takes no name, as the project's node classes."""

        def __init__(self, context):
            super().__init__("tracker", context=context)
            self.values = [declare_parameter(self, name, default, "probe") for name, default in
                           (("gate_px", 1.0), ("min_hits", 1), ("size_weight", 1.0))]

    args = ["tracker", "--ros-args", "--params-file", str(_own_block(tmp_path)), "-p", "gate_px:=55.0", "-p",
            "tracker:min_hits:=2", "-p", "fuser:size_weight:=9.0", "-p", "use_sim_time:=true"]
    context = _context(ros_env, args)
    try:
        node = with_command_line(Probe, args)(context)
        assert isinstance(node, Probe) and type(node).__name__ == "Probe"
        assert node.values == [55.0, 2, 1.0]  # fuser's -p is not the tracker's
        assert node.get_parameter("use_sim_time").value is True
        node.destroy_node()
        plain = Probe(context)  # without the runner, rcl's precedence: the node's own block beats a bare -p
        assert plain.values == [40.0, 2, 1.0] and plain.get_parameter("use_sim_time").value is False
        plain.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


@pytest.mark.ros
def test_a_command_line_value_beats_the_nodes_own_block_of_the_parameter_file(ros_env, ros_context, start_node,
                                                                               wait_until, tmp_path):
    import rclpy
    from rcl_interfaces.srv import GetParameters

    node = start_node("vessel_track", "tracker", "--ros-args", "--params-file", str(GRAPH_FILE), "--params-file",
                      str(_own_block(tmp_path)), "-p", "gate_px:=55.0", "-p", "min_hits:=2", "-p",
                      "use_sim_time:=true")
    probe = rclpy.create_node("parameter_probe", context=ros_context)
    client = probe.create_client(GetParameters, "/tracker/get_parameters")
    executor = rclpy.executors.SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    assert wait_until(lambda: client.service_is_ready() or node.process.poll() is not None, 60,
                      spin=lambda: executor.spin_once(timeout_sec=0.1)), node.output()
    future = client.call_async(GetParameters.Request(names=["gate_px", "min_hits", "max_gate_px", "use_sim_time"]))
    assert wait_until(future.done, 30, spin=lambda: executor.spin_once(timeout_sec=0.1))
    values = future.result().values
    assert (values[0].double_value, values[1].integer_value, values[2].double_value) == (55.0, 2, 240.0)
    assert values[3].bool_value  # rclpy declares it before any node code; the tracker's block says false
    probe.destroy_node()


@pytest.mark.ros
@pytest.mark.parametrize("assignment, message", [
    ("gate_px:=-5.0", "parameter gate_px of tracker"),              # out of range
    ("gate_pxx:=50.0", "no parameter gate_pxx (did you mean gate_px?)"),   # misspelt
    ("gate_px:=abc", "parameter gate_px of tracker"),               # wrong type
    ("use_sim_time:=1", "use_sim_time"),                            # refused by rclpy itself, in Node.__init__
])
def test_a_bad_command_line_value_stops_the_node_with_one_line(ros_env, assignment, message):
    path = REPO / "ros2_ws/install/vessel_track/lib/vessel_track/tracker"
    done = subprocess.run([str(path), "--ros-args", "--params-file", str(GRAPH_FILE), "-p", assignment],
                          env=ros_env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert message in done.stderr and "Traceback" not in done.stderr + done.stdout
    error = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(error) == 1 and error[0].count("parameter gate_px") <= 1 and error[0].count("(default") <= 1, error


@pytest.mark.ros
@pytest.mark.parametrize("package, executable, block", [("vessel_track", "tracker", "/tracker"),
                                                        ("vessel_track", "fuser", "fuser"),
                                                        ("vessel_detect", "detector", "/**/detector")])
def test_a_misspelt_name_in_a_parameter_file_stops_the_node_with_one_line(ros_env, tmp_path, package, executable,
                                                                          block):
    """A name the node does not declare, in a block of a parameter file that names the node, is not ignored."""
    misspelt = tmp_path / "misspelt.yaml"
    misspelt.write_text(f"{block}:\n  ros__parameters:\n    qos_depthh: 5\n")
    path = REPO / f"ros2_ws/install/{package}/lib/{package}/{executable}"
    done = subprocess.run([str(path), "--ros-args", "--params-file", str(GRAPH_FILE), "--params-file",
                           str(REPO / "config" / "aitas_camera.yaml"), "--params-file", str(misspelt)],
                          env=ros_env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert f"{executable} has no parameter qos_depthh" in done.stderr and str(misspelt) in done.stderr
    assert "Traceback" not in done.stderr + done.stdout


def _python_value(value):
    """A rcl_interfaces/ParameterValue as the Python value a parameter file holds."""
    fields = {1: "bool_value", 2: "integer_value", 3: "double_value", 4: "string_value", 5: "byte_array_value",
              6: "bool_array_value", 7: "integer_array_value", 8: "double_array_value", 9: "string_array_value"}
    assert value.type in fields, f"parameter of type {value.type} (not set?)"
    got = getattr(value, fields[value.type])
    return list(got) if value.type >= 5 else got


def _all_parameters(executor, probe, node_name, wait_until, ask_service, process):
    from rcl_interfaces.srv import GetParameters, ListParameters

    lister = probe.create_client(ListParameters, f"/{node_name}/list_parameters")
    getter = probe.create_client(GetParameters, f"/{node_name}/get_parameters")
    assert wait_until(lambda: (lister.service_is_ready() and getter.service_is_ready()) or process.poll() is not None,
                      60, spin=lambda: executor.spin_once(timeout_sec=0.1))
    def wait(predicate, seconds):
        return wait_until(predicate, seconds, spin=lambda: executor.spin_once(timeout_sec=0.1))

    names = sorted(ask_service(lister, ListParameters.Request(), wait).result.names)
    values = ask_service(getter, GetParameters.Request(names=names), wait).values
    # rclpy answers a request that names one unset parameter with nothing at all: `ros2 param dump` printed {}.
    assert len(values) == len(names), f"{node_name}: {len(values)} values for {len(names)} parameters"
    return {name: _python_value(value) for name, value in zip(names, values, strict=True)}


@pytest.mark.ros
@pytest.mark.parametrize("package, executable", [("vessel_track", "tracker"), ("vessel_track", "fuser"),
                                                 ("vessel_track", "gps_publisher")])
def test_every_parameter_dumps_and_the_dump_reloads_the_same_node(package, executable, ros_env, ros_context,
                                                                   start_node, wait_until, ask_service, tmp_path):
    """What `ros2 param dump` does (list, then get every name), and the dump back as the only parameter file."""
    import math

    import rclpy
    import yaml

    calibration = REPO / "config" / "aitas_camera.yaml"
    first = start_node(package, executable, "--ros-args", "--params-file", str(GRAPH_FILE), "--params-file",
                       str(calibration))
    probe = rclpy.create_node("dump_probe", context=ros_context)
    executor = rclpy.executors.SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    dumped = _all_parameters(executor, probe, executable, wait_until, ask_service, first.process)
    assert first.stop() == 0
    dump_file = tmp_path / "dump.yaml"
    dump_file.write_text(yaml.safe_dump({f"/{executable}": {"ros__parameters": dumped}}))
    again = start_node(package, executable, "--ros-args", "--params-file", str(dump_file))
    reloaded = _all_parameters(executor, probe, executable, wait_until, ask_service, again.process)
    probe.destroy_node()

    def same(a, b):
        if isinstance(a, list) and isinstance(b, list):
            return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
        if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
            return True
        return a == b

    assert reloaded.keys() == dumped.keys()
    assert all(same(reloaded[k], dumped[k]) for k in dumped), {k: (dumped[k], reloaded[k]) for k in dumped
                                                                if not same(reloaded[k], dumped[k])}
