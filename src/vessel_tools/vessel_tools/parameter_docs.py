"""``./vessel params render``: the part files and the parameter reference, written from the nodes' tables.

Every node declares its parameters from one ``ParameterTable``; ``config/parts/NODE.yaml`` (each node's block
with every default and description) and the table of ``docs/parameters.md`` are written from those tables, so
they cannot drift from the code. ``--check`` says which file differs instead of writing (the tests run it).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from vessel_calib.params import atomic_write_text
from vessel_common.command_line import command_line_tool
from vessel_common.parameter_table import ParameterTable, markdown_rows, part_file_text
from vessel_common.paths import repo_root

BEGIN = "<!-- the table below is written by ./vessel params render: do not edit it -->"
END = "<!-- end of the written table -->"


def node_tables() -> list[ParameterTable]:
    """The table of every node of the graph, in the graph's order."""
    from vessel_detect.detector_params import DETECTOR_PARAMETERS
    from vessel_detect.parameter_tables import CAMERA_PARAMETERS, RECORDER_PARAMETERS
    from vessel_track.parameter_tables import FUSER_PARAMETERS, GPS_PUBLISHER_PARAMETERS, TRACKER_PARAMETERS

    return [CAMERA_PARAMETERS, DETECTOR_PARAMETERS, TRACKER_PARAMETERS, FUSER_PARAMETERS, GPS_PUBLISHER_PARAMETERS,
            RECORDER_PARAMETERS]


def calibration_table() -> ParameterTable:
    """The ``camera.*`` rows every node with a camera model declares (detector, fuser, GPS publisher)."""
    from vessel_calib.calibration_parameters import CALIBRATION_ROWS

    return ParameterTable("camera.*", "The calibration of every node with a camera model.", CALIBRATION_ROWS)


def parameters_markdown(tables: Sequence[ParameterTable]) -> str:
    """The written part of ``docs/parameters.md``: one table, every parameter of every node."""
    lines = [BEGIN, "", "| node | parameter | type | default | range or choices | live | what |",
             "|---|---|---|---|---|---|---|"]
    for table in tables:
        lines += markdown_rows(table)
    return "\n".join(lines + ["", END])


def rendered_files(root: Path) -> dict[Path, str]:
    """Every file ``render`` writes -> its text."""
    from vessel_tools.calibrate_options import calibrate_parameters

    tables = node_tables()
    files = {root / "config" / "parts" / f"{table.node}.yaml": part_file_text(table)
             for table in [*tables, calibrate_parameters()]}
    doc = root / "docs" / "parameters.md"
    text = doc.read_text(encoding="utf-8") if doc.is_file() else f"# Parameters\n\n{BEGIN}\n{END}\n"
    if BEGIN not in text or END not in text:
        text = text.rstrip("\n") + f"\n\n{BEGIN}\n{END}\n"
    head, rest = text.split(BEGIN, 1)
    files[doc] = head + parameters_markdown(tables + [calibration_table()]) + rest.split(END, 1)[1]
    return files


def stale_files(root: Path) -> list[Path]:
    """The files whose text differs from what ``render`` would write."""
    return [path for path, text in rendered_files(root).items()
            if not path.is_file() or path.read_text(encoding="utf-8") != text]


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """``render [--check]``: write (or compare) config/parts/*.yaml and docs/parameters.md."""
    parser = argparse.ArgumentParser(prog="./vessel params")
    sub = parser.add_subparsers(dest="command", required=True)
    render = sub.add_parser("render", help="write config/parts/NODE.yaml and the table of docs/parameters.md from "
                                           "the nodes' parameter tables")
    render.add_argument("--check", action="store_true", help="write nothing; exit 1 naming each file that differs")
    render.add_argument("--root", type=Path, default=None, help="the repository (default: this one)")
    args = parser.parse_args(argv)
    root = args.root or repo_root()
    if args.check:
        stale = stale_files(root)
        for path in stale:
            print(f"{path} differs from the parameter tables: run ./vessel params render", file=sys.stderr)
        return 1 if stale else 0
    for path, text in rendered_files(root).items():
        atomic_write_text(path, text)
        print(f"written: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
