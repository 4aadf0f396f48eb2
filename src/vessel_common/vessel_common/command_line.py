"""The end every command-line tool of the project shares: one ``error:`` line and exit 2, or exit 130 on Ctrl-C.

A tool's ``main(argv)`` raises ``VesselError`` for bad input (a missing file, a wrong value) and lets Ctrl-C
through; ``@command_line_tool`` turns either, and a file-system error on a path (an output folder under a file,
no permission, a full disk), into the documented exit, with no traceback. ``vessel_tools.cli``
runs every tool through the same ``main`` functions, so ``./vessel TOOL``, ``python -m MODULE`` and
``ros2 run vessel_tools TOOL`` end the same way.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable, Sequence

from vessel_common.errors import VesselError, file_system_problem

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130

Main = Callable[[Sequence[str] | None], int | None]


def command_line_tool(run: Main | None = None, *, interrupted: str = "interrupted") -> Callable:
    """Decorate a tool's ``main(argv) -> status``; ``interrupted``: what Ctrl-C prints (e.g. what was kept)."""

    def decorate(function: Main) -> Callable[[Sequence[str] | None], int]:
        @functools.wraps(function)
        def main(argv: Sequence[str] | None = None) -> int:
            try:
                status = function(argv)
            except VesselError as error:
                print(f"error: {error}", file=sys.stderr)
                return EXIT_BAD_INPUT
            except OSError as error:
                problem = file_system_problem(error)
                if problem is None:
                    raise
                print(f"error: {problem}", file=sys.stderr)
                return EXIT_BAD_INPUT
            except KeyboardInterrupt:
                print(interrupted, file=sys.stderr)
                # An interrupt in the middle of an import leaves half-built objects whose __del__ fails while the
                # interpreter shuts down ("Exception ignored in ..." and a traceback): noise after a Ctrl-C.
                sys.unraisablehook = _ignore_unraisable
                return EXIT_INTERRUPTED
            return int(status or 0)

        return main

    return decorate(run) if run is not None else decorate


def _ignore_unraisable(unraisable) -> None:
    """``sys.unraisablehook`` after an interrupt: what fails in a destructor then is not reported."""
