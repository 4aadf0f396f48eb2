"""``./vessel bench soak``: the cores on a looped simulated stream, minute by minute, and its command line."""

from __future__ import annotations

import json
import math

import pytest

from vessel_tools import bench_soak


def test_a_short_soak_reports_every_minute_and_every_structure(tmp_path, capsys):
    out = tmp_path / "soak.json"
    assert bench_soak.main(["--minutes", "2.2", "--fps", "2", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    rows = result["per_minute"]
    assert [row["minute"] for row in rows] == [1, 2, 3] and [row["frames"] for row in rows] == [120, 120, 24]
    first, sizes = rows[0], rows[0]["sizes"]
    assert sizes["live_tracks"] > 0 and sizes["track_history_entries"] >= sizes["live_tracks"]
    assert 0 < sizes["selection_running"] <= sizes["live_tracks"] and sizes["world_filters"] <= sizes["live_tracks"]
    assert first["tracker_ms"]["n"] == 120 and math.isfinite(first["frame_ms"]["p95"]) and first["rss_mb"] > 0
    assert result["source"] == "simulated looped" and math.isfinite(result["cpu_per_frame_last_over_first"])
    table = capsys.readouterr().out
    assert "soak of the tracker and fuser cores: simulated looped at 2 frames/s" in table
    assert "last/first minute: frame p50" in table and len(table.splitlines()) == 2 + 3 + 1


def test_the_harbour_scene_plays_the_simulation_in_real_time():
    args = bench_soak.parse_args(["--scene", "harbour", "--minutes", "0.5", "--fps", "10"])
    _, _, _, frames = bench_soak.stream(args)
    stamps = [stamp for stamp, _, _ in frames]
    assert len(stamps) == 300 and stamps[1] - stamps[0] == pytest.approx(0.1)


@pytest.mark.parametrize("bad", [["--fps", "0"], ["--minutes", "nan"], ["--scene", "sea"]])
def test_bad_arguments_are_one_line_errors(bad, capsys):
    with pytest.raises(SystemExit) as raised:
        bench_soak.parse_args(bad)
    assert raised.value.code == 2 and ("must be" in capsys.readouterr().err or bad[0] == "--scene")
