"""bench messages: figures for each array size, and the codec checked against rclpy before anything is timed."""

from __future__ import annotations

import json

import pytest


def test_bench_messages_writes_both_codecs_figures(tmp_path, capsys):
    from vessel_tools import bench_messages

    out = tmp_path / "messages.json"
    assert bench_messages.main(["--tracks", "0,3", "--rounds", "1", "--repeats", "2", "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["arrays"]
    assert [row["tracks"] for row in rows] == [0, 3]
    assert rows[1]["bytes"] > rows[0]["bytes"]
    assert all(row[k] > 0 for row in rows for k in ("rclpy_decode", "wire_decode", "decode_ratio", "encode_ratio"))
    assert "decode rclpy" in capsys.readouterr().out


@pytest.mark.parametrize("bad", [["--tracks", "ten"], ["--tracks", "-1"], ["--rounds", "0"]])
def test_bench_messages_refuses_bad_arguments(bad):
    from vessel_tools import bench_messages

    with pytest.raises(SystemExit) as exit_info:
        bench_messages.parse_args(bad)
    assert exit_info.value.code == 2
