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


def test_a_file_system_error_on_a_path_is_one_error_line_naming_it(tmp_path, capsys):
    """An output folder under a file used to end in a FileExistsError traceback."""
    in_the_way = tmp_path / "results.csv"
    in_the_way.write_text("kept\n")

    def tool(argv):
        (in_the_way / "out").mkdir(parents=True)

    assert command_line_tool(tool)(None) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: a file stands where a folder is needed") and str(in_the_way) in err
    assert err.count("\n") == 1
    assert in_the_way.read_text() == "kept\n"


def test_an_os_error_without_a_path_keeps_its_traceback():
    def tool(argv):
        raise ConnectionResetError(104, "Connection reset by peer")

    with pytest.raises(ConnectionResetError):
        command_line_tool(tool)(None)


def test_an_output_file_is_checked_before_the_work(tmp_path):
    from vessel_common.errors import DataError
    from vessel_common.paths import output_file

    assert output_file(tmp_path / "a" / "b.csv") == tmp_path / "a" / "b.csv"
    assert (tmp_path / "a").is_dir()
    with pytest.raises(DataError, match="is a folder"):
        output_file(tmp_path / "a")
    (tmp_path / "file").write_text("")
    with pytest.raises(FileExistsError):  # turned into one error line by command_line_tool
        output_file(tmp_path / "file" / "b.csv")


def test_a_destructor_failing_at_exit_after_ctrl_c_prints_no_traceback(tmp_path):
    """Ctrl-C during an import leaves half-built objects; their failing __del__ at shutdown stays quiet."""
    import subprocess
    import sys
    from pathlib import Path

    script = tmp_path / "tool.py"
    script.write_text(
        "import sys\n"
        "from vessel_common.command_line import command_line_tool\n"
        "class HalfBuilt:\n"
        "    def __del__(self):\n"
        "        self.expr is None\n"
        "@command_line_tool(interrupted='interrupted, nothing written')\n"
        "def main(argv):\n"
        "    global kept\n"
        "    kept = HalfBuilt()\n"
        "    raise KeyboardInterrupt\n"
        "sys.exit(main([]))\n")
    source = Path(__file__).resolve().parents[1]
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60,
                            env={"PYTHONPATH": str(source), "PATH": "/usr/bin:/bin"})
    assert result.returncode == 130, result.stderr
    assert result.stderr.strip() == "interrupted, nothing written", result.stderr
