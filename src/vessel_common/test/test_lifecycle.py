"""lifecycle: a publisher released by a managed node leaves the transitions."""

from __future__ import annotations


def test_release_publisher_takes_a_lifecycle_publisher_out_of_the_transitions(ros_context):
    from rclpy.lifecycle import LifecycleNode
    from std_msgs.msg import String

    from vessel_common.lifecycle import release_publisher

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
