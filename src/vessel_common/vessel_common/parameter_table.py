"""One table type for every node's parameters: declared, checked, documented and written out from one place.

A node's parameters are a ``ParameterTable`` of ``Param`` rows (name, default, description, range, choices,
whether a change applies while the node runs). The node declares them from it (``node_parameters.declare_table``),
checks a value given at start or by ``ros2 param set`` against it, the part files ``config/parts/NODE.yaml`` and
the table of ``docs/parameters.md`` are written from it, and tests compare those files with it. No ROS import, so
the tables and what is written from them can be tested anywhere.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import yaml

READ_ONLY_HINT = "read-only: restart the node with -p {name}:=VALUE"
"""What ``ros2 param describe`` says of a parameter that only a restart changes."""


@dataclass(frozen=True)
class Param:
    """One parameter of a node.

    ``default``: the value without a parameter file, and its type (bool, int, float, str or a list of one of
    them). ``value_range``: inclusive bounds of a number. ``choices``: the words a string may be. ``live``: a
    change while the node runs takes effect (after the same checks as at start); otherwise the parameter is
    read-only and ``ros2 param set`` is refused.
    """

    name: str
    default: Any = field(hash=False)
    description: str = ""
    value_range: tuple[float, float] | None = None
    choices: tuple[str, ...] = ()
    live: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.default, tuple):
            object.__setattr__(self, "default", list(self.default))
        if self.value_range is not None and self.type_name not in ("int", "float", "float[]", "int[]"):
            raise ValueError(f"parameter {self.name}: a range needs a number, not a {self.type_name}")
        if self.choices and self.type_name not in ("str", "str[]"):
            raise ValueError(f"parameter {self.name}: choices need a string, not a {self.type_name}")
        if self.choices and self.problem(self.default) is not None:
            raise ValueError(f"parameter {self.name}: default {self.default!r} is not one of {self.choices}")

    @property
    def type_name(self) -> str:
        """``bool``, ``int``, ``float``, ``str``, or one of them with ``[]`` for a list."""
        if isinstance(self.default, list):
            items = {_scalar_type(v) for v in self.default}
            return f"{items.pop() if len(items) == 1 else 'str'}[]"
        return _scalar_type(self.default)

    def problem(self, value: Any) -> str | None:
        """Why ``value`` cannot be this parameter's (range or choices), or None. ROS itself checks the type."""
        values = value if isinstance(value, (list, tuple)) else [value]
        for item in values:
            if self.choices and item not in self.choices:
                return f"{self.name}: {item!r} is not one of {', '.join(self.choices)}"
            if self.value_range is not None and isinstance(item, (int, float)) and not isinstance(item, bool):
                low, high = self.value_range
                if not (low <= item <= high):
                    return f"{self.name}: {item!r} is outside {low:g} to {high:g}"
        return None


def _scalar_type(value: Any) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "float"
    return "str"


@dataclass(frozen=True)
class ParameterTable:
    """Every parameter of one node, in the order its part file lists them.

    ``node``: the node's default name (its block in a parameter file). ``title``: the part file's first comment
    line, what the node is. ``notes``: further comment lines of the part file. ``is_node``: false for a tool that
    reads its options as ROS parameters but does not run (nothing of it is read-only while running).
    """

    node: str
    title: str
    params: tuple[Param, ...]
    notes: tuple[str, ...] = field(default=())
    is_node: bool = True

    def __post_init__(self) -> None:
        names = [p.name for p in self.params]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"{self.node}: parameters declared twice: {twice}")

    def __iter__(self) -> Iterator[Param]:
        return iter(self.params)

    def __contains__(self, name: object) -> bool:
        return any(p.name == name for p in self.params)

    def __getitem__(self, name: str) -> Param:
        for param in self.params:
            if param.name == name:
                return param
        raise KeyError(name)

    @property
    def names(self) -> list[str]:
        """Every parameter name, in the table's order."""
        return [p.name for p in self.params]

    def defaults(self) -> dict[str, Any]:
        """Flat ``name -> default``."""
        return {p.name: p.default for p in self.params}

    def problems(self, values: Mapping[str, Any]) -> list[str]:
        """Every value of ``values`` (flat names) out of range or choices; unknown names are not this check's."""
        found = (self[name].problem(value) for name, value in values.items() if name in self)
        return [problem for problem in found if problem is not None]

    def with_defaults(self, defaults: Mapping[str, Any]) -> ParameterTable:
        """The same table with other defaults for the names in ``defaults`` (each must be declared)."""
        unknown = sorted(set(defaults) - set(self.names))
        if unknown:
            raise KeyError(f"{self.node} declares no {unknown}")
        return replace(self, params=tuple(replace(p, default=defaults[p.name]) if p.name in defaults else p
                                          for p in self.params))


def yaml_scalar(value: Any) -> str:
    """One YAML value on one line: floats exactly (``repr``), NaN and infinities as YAML writes them."""
    if isinstance(value, float):
        if math.isnan(value):
            return ".nan"
        return repr(value) if math.isfinite(value) else (".inf" if value > 0 else "-.inf")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(yaml_scalar(v) for v in value) + "]"
    if isinstance(value, str) and value == "":
        return '""'
    return yaml.safe_dump([value], default_flow_style=True, width=10000).strip()[1:-1]


def part_file_text(table: ParameterTable) -> str:
    """``config/parts/NODE.yaml``: the node's block with every default and its description as a comment."""
    lines = [f"# {table.title}", *(f"# {note}" for note in table.notes),
             "# Written by `./vessel params render` from the node's parameter table; do not edit.",
             f"{table.node}:", "  ros__parameters:"]
    opened: list[str] = []
    for param in grouped(table.params):
        *groups, key = param.name.split(".")
        common = 0
        while common < min(len(opened), len(groups)) and opened[common] == groups[common]:
            common += 1
        opened = opened[:common]
        for group in groups[common:]:
            lines.append(f"{'  ' * (len(opened) + 2)}{group}:")
            opened.append(group)
        indent = "  " * (len(groups) + 2)
        comment = f"  # {param.description}" + ("" if param.live or not table.is_node else " [read-only]")
        value = yaml_scalar(param.default)
        if isinstance(param.default, list) and param.default and len(indent) + len(key) + len(value) > 100:
            lines.append(f"{indent}{key}:{comment}")
            lines += [f"{indent}  - {yaml_scalar(item)}" for item in param.default]
        else:
            lines.append(f"{indent}{key}: {value}{comment}")
    return "\n".join(lines) + "\n"


def grouped(params: Sequence[Param]) -> list[Param]:
    """``params`` with each dotted group together, where its first member stands (a YAML block opens once)."""
    first: dict[str, int] = {}
    for index, param in enumerate(params):
        groups = param.name.split(".")[:-1]
        for depth in range(1, len(groups) + 1):
            first.setdefault(".".join(groups[:depth]), index)

    def key(item: tuple[int, Param]) -> tuple[int, ...]:
        index, param = item
        groups = param.name.split(".")[:-1]
        return tuple(first[".".join(groups[:depth])] for depth in range(1, len(groups) + 1)) + (index,)

    return [param for _, param in sorted(enumerate(params), key=key)]


def markdown_rows(table: ParameterTable) -> list[str]:
    """Rows of ``docs/parameters.md``: node, name, type, default, range or choices, live, description."""
    rows = []
    for param in table.params:
        allowed = (", ".join(param.choices) if param.choices else
                   f"{param.value_range[0]:g} to {param.value_range[1]:g}" if param.value_range else "")
        description = param.description.replace("|", "\\|")
        rows.append(f"| {table.node} | `{param.name}` | {param.type_name} | `{yaml_scalar(param.default)}` | "
                    f"{allowed} | {'yes' if param.live else 'no'} | {description} |")
    return rows


def state_rows() -> tuple[Param, ...]:
    """``state_file``, ``state_period_s``, ``state_max_age_s``: a node that resumes after a restart (NodeState)."""
    from vessel_common.state_file import STATE_PARAMETERS

    return tuple(Param(name, default, description, value_range=bounds)
                 for name, (default, description, bounds) in STATE_PARAMETERS.items())


def standby_row() -> Param:
    """``standby``: a node that can wait as a hot spare (node_state.Standby applies a change itself)."""
    from vessel_common.state_file import STANDBY_DESCRIPTION

    return Param("standby", False, STANDBY_DESCRIPTION, live=True)
