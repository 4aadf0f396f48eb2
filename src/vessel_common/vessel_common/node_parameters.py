"""A node's parameters from its ``ParameterTable``: declared with descriptors, and changes applied or refused.

rclpy accepts any ``ros2 param set`` of a declared parameter of the right type and range, and a node that read the
value once keeps using the old one: the change is accepted and ignored. Here every parameter is either live (the
node's ``apply`` callback takes the new values, with the same checks as at start, or refuses them with the reason)
or read-only (rclpy refuses the change, and the descriptor says to restart the node with ``-p``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node

from vessel_common.errors import VesselError
from vessel_common.parameter_declaration import declare_parameter
from vessel_common.parameter_table import READ_ONLY_HINT, ParameterTable

ApplyChanges = Callable[[dict[str, Any]], None]
"""Takes every parameter's value after a change (flat names) and puts it to use; raises VesselError to refuse."""


def declare_table(node: Node, table: ParameterTable, apply: ApplyChanges | None = None) -> dict[str, Any]:
    """Declare every parameter of ``table`` on ``node`` and return their values (flat names).

    A value out of the table's range or choices stops the node at start with one line naming it. With ``apply``,
    the table's live parameters may be changed while the node runs: the change is checked against the table,
    then handed to ``apply`` with every other value as it is; ``apply`` raising ``VesselError`` refuses it with
    its message. Without ``apply`` every parameter is read-only.
    """
    values = {}
    for param in table:
        live = param.live and apply is not None
        int_like = param.type_name in ("int", "int[]")
        bounds = param.value_range
        values[param.name] = declare_parameter(
            node, param.name, param.default, param.description, read_only=not live,
            float_range=bounds if bounds is not None and not int_like else None,
            int_range=(int(bounds[0]), int(bounds[1])) if bounds is not None and int_like else None,
            additional_constraints=_constraints(param, live))
    problems = table.problems(values)
    if problems:
        raise VesselError(f"{node.get_name()}: {problems[0]}; fix the value in the parameter file or on the "
                          "command line")
    if apply is not None:
        node.add_on_set_parameters_callback(lambda changed: _on_set(node, table, changed, apply))
    return values


def _constraints(param, live: bool) -> str:
    parts = [f"one of {', '.join(param.choices)}"] if param.choices else []
    if not live:
        parts.append(READ_ONLY_HINT.format(name=param.name))
    return "; ".join(parts)


def current_values(node: Node, table: ParameterTable) -> dict[str, Any]:
    """Every parameter of ``table`` as the node holds it now."""
    return {param.name: node.get_parameter(param.name).value for param in table}


def _on_set(node: Node, table: ParameterTable, changed, apply: ApplyChanges) -> SetParametersResult:
    mine = {parameter.name: parameter.value for parameter in changed if parameter.name in table}
    if not mine:
        return SetParametersResult(successful=True)
    problems = table.problems(mine)
    if problems:
        return _refused(node, problems[0])
    values = current_values(node, table)
    values.update(mine)
    try:
        apply(values)
    except VesselError as error:
        return _refused(node, str(error))
    node.get_logger().info("applied " + ", ".join(f"{name}={value!r}" for name, value in mine.items()))
    return SetParametersResult(successful=True)


def _refused(node: Node, reason: str) -> SetParametersResult:
    node.get_logger().warning(f"parameter change refused: {reason}")
    return SetParametersResult(successful=False, reason=reason)
