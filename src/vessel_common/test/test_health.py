"""health: the report survives a publisher destroyed under it."""

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
