"""node_support: the health report survives a publisher destroyed under it; lifecycle publishers are released."""

from __future__ import annotations


def test_health_report_survives_a_watched_publisher_destroyed_without_unwatch(ros_context):
    from rclpy.node import Node
    from std_msgs.msg import String

    from vessel_common.node_support import MATCHED_SUBSCRIBERS, NodeHealth

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


def test_release_publisher_takes_a_lifecycle_publisher_out_of_the_transitions(ros_context):
    from rclpy.lifecycle import LifecycleNode
    from std_msgs.msg import String

    from vessel_common.node_support import release_publisher

    node = LifecycleNode("lifecycle_probe", context=ros_context)
    try:
        publisher = node.create_lifecycle_publisher(String, "/out", 1)
        assert publisher in node._managed_entities
        release_publisher(node, publisher)
        assert publisher not in node._managed_entities
        plain = node.create_publisher(String, "/plain", 1)
        release_publisher(node, plain)
        assert plain not in node.publishers
    finally:
        node.destroy_node()
