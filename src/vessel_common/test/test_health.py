"""health: the report survives a publisher destroyed under it; matched readers are read per graph."""

from __future__ import annotations


def test_health_report_survives_a_watched_publisher_destroyed_without_unwatch(ros_context):
    from rclpy.node import Node
    from std_msgs.msg import String

    from vessel_common.health import MATCHED_SUBSCRIBERS, NodeHealth

    node = Node("health_probe", context=ros_context)
    try:
        health = NodeHealth(node, hardware_id="probe", period_s=3600.0)
        kept = node.create_publisher(String, "/kept", 1)
        gone = node.create_publisher(String, "/gone", 1)
        health.watch_subscribers(kept, gone)
        node.destroy_publisher(gone)
        health.publish()  # raised InvalidHandle from the timer before, and the executor stopped serving the node
        assert [k for k, _ in health._matched_counts()] == [f"{MATCHED_SUBSCRIBERS}/kept"]
        health.unwatch(kept)
        assert health._matched_counts() == []
    finally:
        node.destroy_node()


def test_matched_readers_are_read_from_the_nodes_of_one_graph_only():
    """Two cameras report on one /diagnostics: graph ``/a``'s readers are its nodes', not ``b``'s or a spare's."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    from vessel_common.health import MATCHED_SUBSCRIBERS, matched_subscribers

    def status(name: str, topic: str, count: int) -> DiagnosticStatus:
        return DiagnosticStatus(name=name, values=[KeyValue(key=f"{MATCHED_SUBSCRIBERS}{topic}", value=str(count))])

    array = DiagnosticArray(status=[status("tracker", "/vessel/tracks/screen", 1),
                                    status("a/tracker", "/a/vessel/tracks/screen", 2),
                                    status("a/standby_1/tracker", "/a/vessel/tracks/screen", 0),
                                    status("b/tracker", "/b/vessel/tracks/screen", 3)])
    assert matched_subscribers(array, graph="/a") == {"/a/vessel/tracks/screen": 2}
    assert matched_subscribers(array, graph="") == {"/vessel/tracks/screen": 1}
    assert len(matched_subscribers(array)) == 3
