"""Names of a graph under a namespace: one camera of several in one ROS domain."""

from __future__ import annotations

import pytest

from vessel_common.errors import DataError
from vessel_common.graph_names import file_label, graph_namespace, node_graph, resolve_topic, status_name


def test_a_namespace_is_written_as_ros_writes_it_and_a_bad_one_is_one_line():
    assert graph_namespace("cam0") == graph_namespace("/cam0/") == "/cam0"
    assert graph_namespace("") == graph_namespace("/") == graph_namespace(None) == ""
    assert graph_namespace("harbour/east") == "/harbour/east"
    for bad in ("2cams", "cam-a", "cam a", "a//b/ c"):
        with pytest.raises(DataError, match="letters, digits and underscores"):
            graph_namespace(bad)


def test_relative_topics_resolve_under_the_graph_and_absolute_ones_stay():
    assert resolve_topic("vessel/fix", "a") == "/a/vessel/fix"
    assert resolve_topic("vessel/fix", "") == "/vessel/fix"  # the names of a graph without a namespace
    assert resolve_topic("/diagnostics", "a") == "/diagnostics" and resolve_topic("/own_ship/imu", "/a") == \
        "/own_ship/imu"
    assert resolve_topic("", "a") == ""  # a topic switched off


def test_a_hot_standby_belongs_to_its_active_nodes_graph():
    assert node_graph("/a/standby_3") == node_graph("/a") == "/a"
    assert node_graph("/standby_1") == node_graph("/") == ""
    assert node_graph("/standby_x") == "/standby_x"
    assert status_name("/a", "tracker") == "a/tracker" and status_name("", "tracker") == "tracker"
    assert file_label("/harbour/east") == "harbour.east" and file_label("") == ""
