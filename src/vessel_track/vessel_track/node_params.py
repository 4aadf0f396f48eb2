"""What the tracking nodes share at start: the fuser's settings of its parameters, and a check of ``--params-file``.

Imports rclpy only inside the functions that need a node.
"""
from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from vessel_common.errors import CalibrationError, DataError
from vessel_track.fuser_settings import FUSION_ANCHOR_MOVED, FuserSettings


def fuser_settings_of(values: dict) -> FuserSettings:
    """The ``FuserSettings`` of the fuser node's parameter values (flat names); a bad value is a DataError."""
    blocks = tuple(f"{name}." for name in FuserSettings().to_params())
    return FuserSettings.from_params({name: value for name, value in values.items() if name.startswith(blocks)})


def refuse_moved_parameters(node) -> None:
    """``fusion.anchor`` of a file from before ``camera.box_anchor``: say so rather than ignore it."""
    if "fusion.anchor" in getattr(node, "_parameter_overrides", {}):  # rclpy keeps undeclared overrides there
        raise DataError(FUSION_ANCHOR_MOVED)


def params_file_problem(argv: Sequence[str] | None) -> str | None:
    """Why a ``--params-file`` argument cannot be used (missing, unreadable, not YAML), or None.

    rcl itself would fail on such a file with a traceback; the nodes check first and exit with one line.
    """
    import yaml

    args = list(sys.argv if argv is None else argv)
    for i, arg in enumerate(args):
        if arg != "--params-file":
            continue
        if i + 1 >= len(args):
            return "--params-file needs a file name"
        path = Path(args[i + 1])
        if not path.is_file():
            return f"parameter file {path} does not exist; give the calibration/parameter YAML written by " \
                   f"`calibrate` (e.g. config/aitas.yaml)"
        try:
            document = yaml.safe_load(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError) as error:
            return f"cannot read parameter file {path}: {error}"
        except yaml.YAMLError as error:
            return f"parameter file {path} is not valid YAML ({str(error).splitlines()[0]}); fix or regenerate it"
        if not isinstance(document, dict):
            return f"parameter file {path} is not a ROS parameter file (expected '/**: ros__parameters: ...')"
    return None


def main_with_checks(node_class, argv: Sequence[str] | None = None, preload: Sequence[str] = ()) -> int:
    """Check ``--params-file`` arguments, then run the node with ``vessel_common.run.run_node``."""
    from vessel_common.run import run_node

    args = list(sys.argv if argv is None else argv)
    problem = params_file_problem(args)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    try:
        return run_node(node_class, args, preload=preload)
    except CalibrationError as error:  # raised before the node exists (e.g. by rcl argument parsing)
        print(f"error: {error}", file=sys.stderr)
        return 2
