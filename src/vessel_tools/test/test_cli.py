"""The one command line: every tool is listed and reachable, and each ends the documented way."""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from vessel_tools import cli

REPO = Path(__file__).resolve().parents[3]
CLI_FILE = REPO / "src" / "vessel_tools" / "vessel_tools" / "cli.py"


def _every_tool():
    for name, entry in cli.TOOLS.items():
        if isinstance(entry, cli.Group):
            yield from ((f"{name} {sub}", tool) for sub, tool in entry.tools.items())
        else:
            yield name, entry


def test_the_help_lists_every_tool_with_the_fitting_ones():
    text = cli.usage()
    for label, tool in _every_tool():
        group, _, sub = label.partition(" ")
        default = isinstance(cli.TOOLS[group], cli.Group) and cli.TOOLS[group].default == sub
        assert (f"  {group} [{sub}]" if default else f"  {label}") in text and tool.summary.split()[0] in text
    assert "fit distance-model" in text and "fit error-model" in text and "params render" in text


def test_the_help_names_every_detect_sub_command():
    """`./vessel help` once left out `detect rank`."""
    import argparse

    from vessel_tools.detect.detect_cli import build_parser

    choices = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    assert cli.TOOLS["detect"].usage.split()[0].split("|") == list(choices)


@pytest.mark.parametrize("group", [name for name, entry in cli.TOOLS.items() if isinstance(entry, cli.Group)])
def test_help_after_a_group_lists_its_sub_tools(group, capsys):
    """`./vessel fit --help` once answered with an error."""
    assert cli.main([group, "--help"]) == 0
    out = capsys.readouterr().out
    assert all(f"  {group} {sub}" in out or f"  {group} [{sub}]" in out for sub in cli.TOOLS[group].tools)


def test_help_of_a_sub_tool_given_as_an_option_prints_the_options():
    """`./vessel bag recover --help` once failed: its --recover took --help as the bag."""
    done = subprocess.run([sys.executable, "-m", "vessel_tools.cli", "bag", "recover", "--help"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "--recover" in done.stdout and "error" not in done.stderr, done.stderr


@pytest.mark.parametrize("argv, module, passed", [
    (["bench"], "vessel_tools.bench", []),
    (["bench", "--out", "F.json"], "vessel_tools.bench", ["--out", "F.json"]),
    (["bench", "live", "--minutes", "1"], "vessel_tools.bench_live", ["--minutes", "1"]),
    (["bag", "info", "B"], "vessel_tools.detect.bag_build", ["--info", "B"]),
    (["params", "render", "--check"], "vessel_tools.parameter_docs", ["render", "--check"]),
    (["fit", "error-model", "S.csv"], "vessel_tools.track.error_model_fit", ["S.csv"]),
    (["demo", "--videos", "13"], "vessel_tools.demo", ["--videos", "13"]),
])
def test_each_command_line_reaches_its_tool_with_its_arguments(argv, module, passed):
    tool, rest = cli.resolve(argv)
    assert tool.module == module and [*tool.prefix, *rest] == passed


@pytest.mark.parametrize("argv, says", [(["demos"], "unknown tool 'demos'"), (["fit"], "'fit': choose fit"),
                                        (["bag", "show"], "'bag show': choose bag build | info | recover")])
def test_a_wrong_tool_name_is_refused_with_the_choices(argv, says, capsys):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {says}") and "Tools (" in err


def test_every_tool_module_has_a_main():
    for label, tool in _every_tool():
        module = importlib.import_module(tool.module)
        assert callable(getattr(module, "main", None)), label


def test_a_tool_ends_bad_input_with_one_error_line(tmp_path, capsys):
    status = cli.main(["eval", str(tmp_path / "missing.csv"), "--data", str(tmp_path)])
    err = capsys.readouterr().err
    assert status == 2 and err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err


def test_the_help_needs_nothing_but_the_standard_library():
    """``./vessel help`` lists the tools with any python3, before set-up."""
    tree = ast.parse(CLI_FILE.read_text())
    imported = {alias.name.split(".")[0] for node in tree.body if isinstance(node, ast.Import) for alias in node.names}
    imported |= {node.module.split(".")[0] for node in tree.body if isinstance(node, ast.ImportFrom) and node.module}
    assert imported <= set(sys.stdlib_module_names) | {"__future__"}, imported
    done = subprocess.run([sys.executable, "-I", str(CLI_FILE), "--list"], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0 and "bench restart" in done.stdout


def test_the_vessel_script_lists_its_own_commands_and_the_tools():
    done = subprocess.run(["bash", str(REPO / "vessel"), "help"], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0
    for word in ("setup [--train]", "test [--fast]", "env", "run PKG EXE", "demo", "fit distance-model"):
        assert word in done.stdout
