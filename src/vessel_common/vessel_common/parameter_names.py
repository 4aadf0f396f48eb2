"""ROS parameter names of nested YAML: ``camera: {H: ...}`` is the parameter ``camera.H``.

A plain helper with no dependency, for the parameter files of every layer (the nodes' checks of them included).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


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
