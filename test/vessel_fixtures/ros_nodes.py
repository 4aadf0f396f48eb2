"""Nodes in the test's own process and rclpy context.

The project's nodes built there, for checks that need no DDS traffic, and the probe node through which a test
watches nodes that run in processes of their own.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence


def node_in_context(monkeypatch, context, factory: Callable[[], object], overrides: Sequence = ()):
    """``factory()`` (a node class) built in ``context`` with ``overrides`` (rclpy Parameters) as if from ``-p``."""
    import rclpy.node

    node_init = rclpy.node.Node.__init__
    given = list(overrides)
    monkeypatch.setattr(rclpy.node.Node, "__init__", lambda self, name, **kw: node_init(
        self, name, context=context, parameter_overrides=given + list(kw.pop("parameter_overrides", [])), **kw))
    return factory()


def set_parameter(node, name: str, value):
    """What ``ros2 param set NODE name value`` answers: the SetParametersResult of the change."""
    from rclpy.parameter import Parameter

    (result,) = node.set_parameters([Parameter(name, value=value)])
    return result


class ProbeNode:
    """The test's own node in ``context``, spun only when the test spins ``executor``; subclasses subscribe.

    Spinning on demand lets a test read what has arrived between spins, with no thread of its own.
    """

    def __init__(self, context, name: str) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.node = rclpy.create_node(name, context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)

    def close(self) -> None:
        """Shut the executor down, then destroy the node; the context stays the test's to shut down."""
        self.executor.shutdown()
        self.node.destroy_node()


def status_values(diagnostics, name: str) -> dict[str, str]:
    """The values of the last ``name`` status in ``diagnostics`` (DiagnosticArrays, oldest first); {} before one."""
    for array in reversed(diagnostics):
        for status in array.status:
            if status.name == name:
                return {value.key: value.value for value in status.values}
    return {}


def capture_published(patch, publisher, msg_type) -> list:
    """What ``publisher`` publishes from now on, as ``msg_type`` messages (serialised ones are deserialised).

    The tracking chain publishes CDR bytes (``vessel_common.wire``): reading them back with rclpy also checks that
    they are the message an ordinary subscriber receives.
    """
    from rclpy.serialization import deserialize_message

    published: list = []

    def publish(msg) -> None:
        published.append(deserialize_message(msg, msg_type) if isinstance(msg, bytes) else msg)

    patch.setattr(publisher, "publish", publish)
    return published
