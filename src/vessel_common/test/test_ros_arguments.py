"""ros_arguments: what a node's ``--ros-args`` say, read without ROS."""

from __future__ import annotations

from vessel_common.ros_arguments import command_line_parameters, params_file_parameters, remapped_node_name, wants_help


def test_command_line_assignments_are_read_for_this_node_only():
    args = ["tracker", "--ros-args", "--params-file", "f.yaml", "-p", "gate_px:=55.0", "--param", "min_hits:=2",
            "-p", "fuser:max_range_m:=9.0", "-p", "tracker:size_weight:=0.5", "--", "-p", "not_ros:=1"]
    assert command_line_parameters(args, "tracker") == {"gate_px": "55.0", "min_hits": "2", "size_weight": "0.5"}
    assert command_line_parameters(["tracker", "-p", "gate_px:=1.0"], "tracker") == {}  # outside --ros-args


def test_a_parameter_files_names_are_read_from_the_blocks_that_name_this_node(tmp_path):
    own = tmp_path / "own.yaml"
    own.write_text("/**:\n  ros__parameters:\n    use_sim_time: false\n    everyone: 1\n"
                   "tracker:\n  ros__parameters:\n    gate_pxx: 30.0\n    nested:\n      name: 2\n"
                   "/fuser:\n  ros__parameters:\n    other: 3\n"
                   "/**/tracker:\n  ros__parameters:\n    anywhere: 4\n"
                   "/standby_1:\n  tracker:\n    ros__parameters:\n      in_namespace: 5\n")
    broken = tmp_path / "broken.yaml"
    broken.write_text("tracker: [unclosed\n")  # rcl refuses such a file itself, before any node code
    args = ["tracker", "--ros-args", "--params-file", str(own), "--params-file", str(broken)]
    assert params_file_parameters(args, "/tracker") == {"gate_pxx": str(own), "nested.name": str(own),
                                                        "anywhere": str(own)}
    assert params_file_parameters(args, "/standby_1/tracker") == {"anywhere": str(own), "in_namespace": str(own)}
    assert params_file_parameters(args, "/fuser") == {"other": str(own)}
    assert params_file_parameters(["tracker", "--params-file", str(own)], "/tracker") == {}  # outside --ros-args


def test_the_node_name_follows_the_node_remaps():
    def name(*args):
        return remapped_node_name(["x", *args], "tracker")

    assert name("--ros-args", "-r", "__node:=smoke_tracker") == "smoke_tracker"
    assert name("--ros-args", "--remap", "tracker:__node:=spare") == "spare"
    assert name("--ros-args", "-r", "fuser:__node:=other", "-r", "/a:=/b") == "tracker"
    assert name("-r", "__node:=outside") == "tracker"  # not a ROS argument


def test_help_is_asked_outside_the_ros_arguments_only():
    assert wants_help(["tracker", "--help"]) and wants_help(["tracker", "--ros-args", "-p", "a:=1", "--", "-h"])
    assert not wants_help(["tracker", "--ros-args", "-h"]) and not wants_help(["-h"])
