"""ROS parameter names of nested YAML: ``camera: {H: ...}`` is the parameter ``camera.H``.

A plain helper with no dependency, for the parameter files of every layer (the nodes' checks of them included).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

RCL_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})
"""Parameters every rclpy node declares by itself."""
RCL_PREFIXES = ("qos_overrides.",)
"""Parameters rcl reads when a publisher or subscription is made; no node declares them."""


def is_rcl_parameter(name: str) -> bool:
    """Whether ``name`` is a parameter of rclpy or rcl, valid in any node's block without the node declaring it."""
    return name in RCL_PARAMETERS or name.startswith(RCL_PREFIXES)


def with_closest(name: str, declared) -> str:
    """``name (did you mean close?)``, the declared name closest to a misspelt one, or ``name`` alone."""
    import difflib

    close = difflib.get_close_matches(name, sorted(declared), n=1)
    return f"{name}" + (f" (did you mean {close[0]}?)" if close else "")


def flatten(params: Mapping[str, Any], prefix: str = "") -> dict:
    """Nested mapping -> ``{"a.b": value}``, as ROS names parameters (``camera: {H: ...}`` -> ``camera.H``)."""
    out = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out
