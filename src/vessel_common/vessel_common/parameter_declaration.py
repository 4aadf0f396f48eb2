"""One parameter declared with a descriptor (description, range, read-only), or one line saying what is wrong.

rclpy checks a value against the descriptor's range and the default's type when the parameter is declared (and
on every later change) and raises; a node started with a bad value stops with one line naming the parameter,
the range and the default instead of rclpy's traceback. ``-p`` values win over the node's own block of a parameter
file because the node runner hands them to rclpy as ``parameter_overrides`` (``vessel_common.run``).
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from vessel_common.errors import DataError


def declare_parameter(
    node: Node,
    name: str,
    default: Any,
    description: str,
    *,
    read_only: bool = False,
    float_range: tuple[float, float] | None = None,
    int_range: tuple[int, int] | None = None,
    additional_constraints: str = "",
) -> Any:
    """Declare one parameter with a descriptor and return its value.

    Ranges are enforced by ROS when the parameter is set at start (``--params-file``, ``-p``) or later; a value
    out of range or of the wrong type is a ``DataError`` naming the parameter, its range and its default.
    """
    descriptor = ParameterDescriptor(
        description=description,
        read_only=read_only,
        additional_constraints=additional_constraints,
    )
    if float_range is not None:
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(float_range[0]), to_value=float(float_range[1]), step=0.0)
        ]
    if int_range is not None:
        descriptor.integer_range = [
            IntegerRange(from_value=int(int_range[0]), to_value=int(int_range[1]), step=0)
        ]
    try:
        return node.declare_parameter(name, default, descriptor).value
    except (ParameterException, TypeError, ValueError) as error:
        bounds = float_range if float_range is not None else int_range
        constraint = f" (allowed: {bounds[0]:g} to {bounds[1]:g})" if bounds is not None else ""
        raise DataError(f"parameter {name} of {node.get_name()}: {error}{constraint}; fix the value in the "
                        f"parameter file or on the command line (default {default!r})") from None
