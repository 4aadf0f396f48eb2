"""``./vessel view``'s command line: bad input is one line naming the problem and the fix, never a traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest

from vessel_tools.view.app import main


@pytest.mark.parametrize(("argv", "message"), [
    (["--port", "70000"], "--port 70000: give a TCP port, 0-65535"),
    (["--foxglove-port", "-1"], "--foxglove-port -1: give a TCP port"),
    (["--update-hz", "0"], "--update-hz 0.0: give a rate above 0"),
    (["--image-hz", "nan"], "--image-hz nan: give a rate above 0"),
    (["--max-clients", "0"], "--max-clients 0: give at least 1"),
    (["--rate", "4"], "--rate and --params go with --source"),
    (["--source", "bags/no_such_bag"], "source bags/no_such_bag does not exist"),
    (["--source", "bags/x", "--rate", "-1"], "--rate -1.0: give 0"),
    (["--chart-image", "chart.png"], "--chart-image and --chart-corners go together"),
    (["--calib", "no_such_calibration.yaml"], "no_such_calibration.yaml"),
    (["--chart", "no_such_chart.json"], "chart file no_such_chart.json not found"),
    (["--chart-image", "chart.png", "--chart-corners", "1,2,3"], "--chart-corners '1,2,3': give LAT,LON,LAT,LON"),
    (["--chart-image", "chart.gif", "--chart-corners", "1,2,3,4"], "chart.gif must be PNG or JPEG"),
])
def test_bad_input_is_one_line_and_status_2(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # relative names resolve here: the calibration falls back to the repository's
    (tmp_path / "chart.png").write_bytes(b"")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err


def test_the_foxglove_layout_is_written_where_asked(tmp_path):
    pytest.importorskip("foxglove", reason="foxglove-sdk is in requirements-view.txt: run ./vessel setup --view")
    assert main(["--foxglove-layout", str(tmp_path / "layout.json")]) == 0
    assert '"imageTopic": "/view/image"' in (tmp_path / "layout.json").read_text()


def test_the_tool_is_registered_with_the_command_line():
    done = subprocess.run([sys.executable, "-m", "vessel_tools.cli", "view", "--help"], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0 and "--foxglove-port" in done.stdout and "--source" in done.stdout
    listing = subprocess.run([sys.executable, "-m", "vessel_tools.cli", "--list"], capture_output=True, text=True,
                             timeout=60).stdout
    assert "  view [--port 8080]" in listing and "  bench view" in listing
