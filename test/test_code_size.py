"""Modules and functions small enough to read: at most 600 lines a module and 60 lines a function.

A module that grows past the limit has more than one role (split it by role); a function past it does more than
one thing (name the parts). Counted over the source packages and their launch files, tests excluded.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 60


def _sources() -> list[Path]:
    return sorted(path for path in (REPO / "src").rglob("*.py") if "test" not in path.relative_to(REPO).parts[2:3])


def _long_functions(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    return [f"{path.relative_to(REPO)}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)"
            for node in ast.walk(tree) if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
            and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES]


def test_no_module_is_over_600_lines():
    long = [f"{path.relative_to(REPO)} ({n} lines)" for path in _sources()
            if (n := len(path.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES]
    assert not long, "split these modules by role: " + ", ".join(long)


def test_no_function_is_over_60_lines():
    long = [entry for path in _sources() for entry in _long_functions(path)]
    assert not long, "split these functions into named steps:\n" + "\n".join(long)


def test_the_checks_see_the_sources():
    assert len(_sources()) > 50
    assert all("/test/" not in str(path) for path in _sources())
