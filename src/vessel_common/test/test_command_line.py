"""Every tool ends the same way: its status, one ``error:`` line and 2 on bad input, 130 on Ctrl-C."""

from __future__ import annotations

import pytest

from vessel_common.command_line import command_line_tool
from vessel_common.errors import CalibrationError


def test_a_status_passes_through_and_none_is_success():
    assert command_line_tool(lambda argv: 3)(None) == 3
    assert command_line_tool(lambda argv: None)([]) == 0


def test_bad_input_is_one_error_line_and_status_2(capsys):
    def tool(argv):
        raise CalibrationError("calibration.yaml lacks H: write it again with calibrate")

    assert command_line_tool(tool)(["x"]) == 2
    assert capsys.readouterr().err == "error: calibration.yaml lacks H: write it again with calibrate\n"


def test_ctrl_c_is_status_130_with_what_the_tool_says(capsys):
    def tool(argv):
        raise KeyboardInterrupt

    assert command_line_tool(interrupted="interrupted: no partial bag was left behind")(tool)(None) == 130
    assert capsys.readouterr().err == "interrupted: no partial bag was left behind\n"


def test_other_errors_are_not_hidden():
    def tool(argv):
        raise ZeroDivisionError

    with pytest.raises(ZeroDivisionError):  # a programming error surfaces with its traceback
        command_line_tool(tool)(None)
