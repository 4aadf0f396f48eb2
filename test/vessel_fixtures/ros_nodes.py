"""Nodes of the project built in the test's own process and rclpy context, for checks that need no DDS traffic."""

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
