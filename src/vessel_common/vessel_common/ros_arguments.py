"""What a node's command line says in its ``--ros-args`` parts: ``-p`` assignments, parameter files, remaps, ``-h``.

ROS-free reading of the arguments rcl parses too: the node runner uses it for what rcl leaves out (a ``-p`` that
wins over the node's own block of a parameter file, names nobody declares, ``--help``).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

from vessel_common.parameter_names import flatten


def ros_arguments(args: Sequence[str], options: tuple[str, ...]) -> Iterator[str]:
    """The argument after each of ``options`` inside the ``--ros-args`` parts of ``args`` (up to ``--``)."""
    inside = False
    args = list(args)
    for i, arg in enumerate(args):
        if arg == "--ros-args":
            inside = True
        elif arg == "--":
            inside = False
        elif inside and arg in options and i + 1 < len(args):
            yield args[i + 1]


def remapped_node_name(args: Sequence[str], name: str) -> str:
    """The name a node created as ``name`` gets: the last ``-r __node:=NEW`` (or ``-r name:__node:=NEW``) wins."""
    for rule in ros_arguments(args, ("-r", "--remap")):
        source, _, target = rule.partition(":=")
        node, _, what = source.rpartition(":")
        if what in ("__node", "__name") and node in ("", name) and target:
            name = target
    return name


def command_line_parameters(args: Sequence[str], name: str) -> dict[str, str]:
    """``parameter -> value text`` of the ``-p name:=value`` / ``--param name:=value`` assignments for node ``name``.

    Only the ``--ros-args`` parts count (up to ``--`` or the next ``--ros-args``); ``-p other_node:name:=value``
    is for another node. rcl files these under ``/**``, which a node's own block in a parameter file beats;
    a ROS user who types ``-p`` expects it to win, so the node runner hands them to rclpy as overrides.
    """
    found: dict[str, str] = {}
    for assignment in ros_arguments(args, ("-p", "--param")):
        if ":=" not in assignment:
            continue
        parameter, value = assignment.split(":=", 1)
        target, _, bare = parameter.rpartition(":")
        if target and target.lstrip("/") != name:
            continue
        found[bare] = value
    return found


def params_file_parameters(args: Sequence[str], node_fqn: str) -> dict[str, str]:
    """Parameter names that the ``--params-file`` files in ``args`` give the node ``node_fqn`` -> the file.

    Only a block that names this node (``tracker``, ``/tracker``, ``/ns/tracker``, ``/**/tracker``, or the node
    nested under its namespace), not ``/**``, which every node reads and no node owns. A file that cannot be read
    is left to rcl, which has already refused it.
    """
    import yaml

    base = node_fqn.rsplit("/", 1)[-1]
    found: dict[str, str] = {}
    for path in ros_arguments(args, ("--params-file",)):
        try:
            with open(path, encoding="utf-8") as stream:
                document = yaml.safe_load(stream)
        except (OSError, UnicodeDecodeError, yaml.YAMLError):
            continue
        if not isinstance(document, dict):
            continue
        for name, body in _blocks(document, ()):
            if name in (node_fqn, f"/**/{base}"):
                found.update(dict.fromkeys(flatten(body), path))
    return found


def _blocks(mapping: dict, parts: tuple[str, ...]) -> Iterator[tuple[str, dict[str, Any]]]:
    """``(node name, its ros__parameters)`` of each block of a parameter file, nested namespaces joined."""
    for key, body in mapping.items():
        if not isinstance(body, dict):
            continue
        if key == "ros__parameters":
            yield "/" + "/".join(parts), body
        else:
            yield from _blocks(body, parts + tuple(p for p in str(key).split("/") if p))


def wants_help(args: Sequence[str]) -> bool:
    """``-h`` / ``--help`` among the arguments that are not ROS arguments (a node must not start then)."""
    inside = False
    for arg in list(args)[1:]:
        if arg == "--ros-args":
            inside = True
        elif arg == "--":
            inside = False
        elif not inside and arg in ("-h", "--help"):
            return True
    return False
