"""``./vessel bench``: its measuring parts on known inputs, its errors, and a short run of the real graph.

No test asserts on speed: the machine is shared; the figures come from running the benchmark.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from vessel_bringup import graph_watcher
from vessel_tools import bench, bench_graph, bench_report, proc_monitor

REPO_ROOT = Path(__file__).resolve().parents[3]


# ----------------------------------------------------------------------------------------------------------------
# Pieces
# ----------------------------------------------------------------------------------------------------------------
def test_summary_ms_gives_median_and_p95_in_milliseconds():
    summary = bench_report.summary_ms([0.001 * v for v in range(1, 101)])  # 1..100 ms
    assert summary["n"] == 100
    assert summary["p50"] == pytest.approx(50.5)
    assert summary["p95"] == pytest.approx(95.05)
    assert summary["min"] == pytest.approx(1.0) and summary["max"] == pytest.approx(100.0)
    empty = bench_report.summary_ms([float("nan")])
    assert empty["n"] == 0 and math.isnan(empty["p50"])


def test_node_parameters_follow_the_ros_rules_of_parameter_files(tmp_path):
    first = tmp_path / "graph.yaml"
    first.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"use_sim_time": False}},
        "detector": {"ros__parameters": {"mode": "band", "score_threshold": 0.3}},
        "tracker": {"ros__parameters": {"mode": "not for the detector"}},
    }))
    second = tmp_path / "calib.yaml"
    second.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"camera": {"K1": -3e-7, "H": [1, 2, 3]}}},
        "/detector": {"ros__parameters": {"score_threshold": 0.4}},
    }))
    values = bench.node_parameters([first, second], "detector")
    assert values == {"use_sim_time": False, "mode": "band", "score_threshold": 0.4, "camera.K1": -3e-7,
                      "camera.H": [1, 2, 3]}


def _synthetic_run(stamps_s, detect_s, warmup):
    """Arrivals of frames published 1 s apart; the detector takes detect_s[i], later stages fixed times."""
    log = graph_watcher.ArrivalLog(graph_watcher.CHAIN)
    offsets = {graph_watcher.SCREEN_TOPIC: 0.02, graph_watcher.TRACKS_TOPIC: 0.05, graph_watcher.FIX_TOPIC: 0.06}
    for i, (stamp, detect) in enumerate(zip(stamps_s, detect_s, strict=True)):
        sent = 100.0 + i
        times = {graph_watcher.IMAGE_TOPIC: sent, graph_watcher.DETECTIONS_TOPIC: sent + detect}
        times.update({topic: sent + detect + offset for topic, offset in offsets.items()})
        for topic, published in times.items():
            log.add(topic, int(stamp * 1e9), int(published * 1e9), int((published + 0.001) * 1e9))
    return bench_graph.GraphRun(log, warmup, len(stamps_s) - warmup, [], {}, 0, {}, None)


def test_graph_figures_of_one_round_with_restamped_loops():
    # One round of 4 frames (a loop shifts the stamps), the first is warm-up; each frame has its own latency.
    detect = [0.5, 0.6, 0.7, 0.8]
    figures = bench_graph.graph_figures(_synthetic_run([10.0, 14.0, 18.0, 22.0], detect, warmup=1))
    assert figures["frames_measured"] == 3
    latencies = [d + 0.06 for d in detect[1:]]  # frames 1-3
    assert figures["latency_fix_ms"]["p50"] == pytest.approx(1000 * latencies[1])
    assert figures["latency_fix_ms"]["max"] == pytest.approx(1000 * latencies[2])
    assert figures["latency_tracks_ms"]["min"] == pytest.approx(1000 * (detect[1] + 0.05))
    assert figures["stages_ms"]["camera -> detector"]["p50"] == pytest.approx(700.0)
    assert figures["stages_ms"]["fuser -> gps_publisher"]["p50"] == pytest.approx(10.0)
    # From the first measured image (frame 1, at 101 s) to the last track array (frame 3: 103 + 0.8 + 0.05 s).
    assert figures["graph_fps"] == pytest.approx(3 / (2 + 0.8 + 0.05))
    # The camera sends each frame 1 s after the previous one, i.e. 1 s - detect after the previous detections.
    assert figures["camera_turnaround_ms"]["p50"] == pytest.approx(1000 * (1 - 0.6))


def test_graph_figures_match_the_repeated_stamps_of_rounds_in_order_of_occurrence():
    # Two rounds replaying the same 2 frames: stamps repeat; the first frame of each round is warm-up.
    detect = [0.5, 0.6, 0.7, 0.8]
    figures = bench_graph.graph_figures(_synthetic_run([10.0, 14.0, 10.0, 14.0], detect, warmup=1))
    assert figures["frames_measured"] == 2
    assert figures["latency_fix_ms"]["min"] == pytest.approx(1000 * (0.6 + 0.06))  # frame 1, round 1
    assert figures["latency_fix_ms"]["max"] == pytest.approx(1000 * (0.8 + 0.06))  # frame 3, round 2
    walls = [0.6 + 0.05, 0.8 + 0.05]  # each round: from its measured image to its last track array
    assert figures["graph_fps_per_round"] == pytest.approx([1 / walls[0], 1 / walls[1]])
    assert figures["graph_fps"] == pytest.approx(2 / sum(walls))
    # Turnaround within a round only (not from round 1's last frame to round 2's first).
    assert figures["camera_turnaround_ms"]["n"] == 2
    assert figures["camera_turnaround_ms"]["p50"] == pytest.approx(1000 * ((1 - 0.5) + (1 - 0.7)) / 2)


def test_frames_are_shared_out_over_rounds():
    assert bench.split_frames(72, 3) == [24, 24, 24]
    assert bench.split_frames(7, 3) == [3, 2, 2]
    assert bench.split_frames(2, 5) == [1, 1]


def test_looped_frames_repeat_the_bag_in_order():
    frames = [(1.0, b"a"), (2.0, b"b"), (3.0, b"c")]
    assert bench.looped(frames, 7) == [b"a", b"b", b"c", b"a", b"b", b"c", b"a"]


def test_write_json_is_atomic_and_writes_null_for_non_finite(tmp_path):
    path = tmp_path / "sub" / "bench.json"
    bench_report.write_json(path, {"graph_fps": float("nan"), "nested": [1.5, float("inf")]})
    assert json.loads(path.read_text()) == {"graph_fps": None, "nested": [1.5, None]}
    assert [p.name for p in path.parent.iterdir()] == ["bench.json"]


# ----------------------------------------------------------------------------------------------------------------
# Errors
# ----------------------------------------------------------------------------------------------------------------
def test_missing_bag_and_no_data_is_one_error_line_naming_the_fix(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "99")
    status = bench.main(["--data", str(tmp_path / "no_data"), "--bags", str(tmp_path / "bags"), "--frames", "1"])
    err = capsys.readouterr().err
    assert status == 2
    error_lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(error_lines) == 1
    assert "./vessel bag build" in error_lines[0] and "video_13" in error_lines[0]
    assert "Traceback" not in err


def test_more_than_one_video_is_refused(tmp_path, capsys):
    assert bench.main(["--videos", "13,14", "--bags", str(tmp_path)]) == 2
    assert "one video" in capsys.readouterr().err


def test_missing_model_is_one_error_line(tmp_path, capsys, ros_env, data_dir):
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"detector": {"ros__parameters": {
        "model_path": str(tmp_path / "missing.onnx"), "allow_download": False}}}))
    status = bench.main(["--data", str(data_dir), "--bags", str(tmp_path / "bags"), "--params", str(params),
                         "--calib", str(REPO_ROOT / "config" / "aitas_camera.yaml"), "--frames", "1"])
    err = capsys.readouterr().err
    assert status == 2
    assert "error:" in err and "missing.onnx" in err and "Traceback" not in err
    assert (tmp_path / "bags" / "video_13" / "metadata.yaml").is_file()  # the missing bag was built


def _run_bench(args, env, timeout=150):
    return subprocess.run([sys.executable, "-m", "vessel_tools.bench", *args], env=env, capture_output=True,
                          text=True, timeout=timeout)


def test_a_node_that_dies_stops_the_benchmark_with_its_log_tail(tmp_path, ros_env, model_path, data_dir):
    params = tmp_path / "params.yaml"
    original = yaml.safe_load((REPO_ROOT / "config" / "aitas.yaml").read_text())
    original.setdefault("tracker", {"ros__parameters": {}})["ros__parameters"]["association"] = "telepathy"
    params.write_text(yaml.safe_dump(original))
    bags = REPO_ROOT / "bags" if (REPO_ROOT / "bags" / "video_13" / "metadata.yaml").is_file() else tmp_path
    result = _run_bench(["--data", str(data_dir), "--bags", str(bags), "--params", str(params), "--frames", "1",
                         "--warmup", "0", "--log-dir", str(tmp_path / "logs")], ros_env)
    assert result.returncode == 1, result.stderr
    assert "error: node tracker exited with status" in result.stderr
    assert "telepathy" in result.stderr  # the tracker's own message, from its log
    assert not _processes_mentioning(str(params))  # every node was stopped


def _processes_mentioning(text: str) -> list[int]:
    """Pids of running processes with ``text`` on their command line."""
    return [int(entry.name) for entry in Path("/proc").iterdir()
            if entry.name.isdigit() and text in " ".join(proc_monitor.process_cmdline(int(entry.name)))]


# ----------------------------------------------------------------------------------------------------------------
# The real thing, a few frames
# ----------------------------------------------------------------------------------------------------------------
def test_benchmark_of_a_few_frames_reports_every_figure(tmp_path, ros_env, model_path, data_dir):
    out = tmp_path / "bench.json"
    bags = REPO_ROOT / "bags" if (REPO_ROOT / "bags" / "video_13" / "metadata.yaml").is_file() else tmp_path
    result = _run_bench(["--data", str(data_dir), "--bags", str(bags), "--frames", "6", "--warmup", "1",
                         "--rounds", "2", "--out", str(out), "--log-dir", str(tmp_path / "logs")], ros_env)
    assert result.returncode == 0, result.stderr[-3000:]
    figures = json.loads(out.read_text())
    for key in ("graph_fps", "detector_core_fps", "latency_ms_p50", "latency_ms_p95", "ratio_graph_to_core"):
        assert isinstance(figures[key], float) and math.isfinite(figures[key]) and figures[key] > 0, key
    assert figures["latency_ms_p95"] >= figures["latency_ms_p50"]
    assert figures["graph"]["frames_measured"] == 6
    assert figures["graph"]["counts"][graph_watcher.TRACKS_TOPIC] == 8  # two rounds of 1 warm-up + 3 frames
    assert len(figures["graph"]["graph_fps_per_round"]) == 2 and len(figures["detector_core"]["fps_per_round"]) == 2
    assert figures["detector_core"]["frames"] == 6
    for name in ("camera", "detector", "tracker", "fuser", "gps_publisher"):
        node = figures["nodes"][name]
        assert node["cpu_s_total"] > 0 and node["peak_mb"] > 10, name
        assert math.isfinite(node["cpu_percent"]), name
    assert figures["node_exit_statuses"] == {name: 0 for name in figures["node_exit_statuses"]}
    stages = figures["graph"]["stages_ms"]
    assert all(stage["n"] >= 1 and stage["p50"] > 0 for stage in stages.values())
    machine = figures["machine"]
    assert machine["cores"] >= 1 and machine["onnxruntime_threads"] >= 1 and machine["detector_mode"]
    assert "graph / core" in result.stdout and "detector core" in result.stdout
    stopped = [name for name, node in figures["nodes"].items()
               if name in figures["node_exit_statuses"] and proc_monitor.read_proc(node["pid"]) is None]
    assert sorted(stopped) == sorted(figures["node_exit_statuses"])
