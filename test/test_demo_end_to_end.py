"""A short ./vessel demo: the whole graph as separate processes on two challenge videos, scored and plotted."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys

import pytest

from vessel_calib import geodesy


@pytest.mark.ros
@pytest.mark.slow
def test_short_demo_writes_sane_outputs(data_dir, model_path, ros_env, tmp_path):
    out = tmp_path / "demo"
    command = [sys.executable, "-m", "vessel_tools.demo", "--data", str(data_dir), "--videos", "13,14",
               "--max-frames", "6", "--out", str(out), "--bags", str(tmp_path / "bags")]
    result = subprocess.run(command, env=ros_env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Traceback" not in result.stderr

    with (out / "predictions.csv").open() as handle:
        reader = csv.DictReader(handle)
        assert reader.fieldnames == ["video", "t_utc_s", "lat", "lon"]
        rows = list(reader)
    assert rows, "the vessel of interest was never published on /vessel/fix"
    camera = json.loads((data_dir / "camera.json").read_text())
    for row in rows:
        assert int(row["video"]) in (13, 14)
        assert 0 <= float(row["t_utc_s"]) < 86400
        distance = geodesy.haversine_m(float(row["lat"]), float(row["lon"]), camera["camera_lat"],
                                       camera["camera_lon"])
        assert distance < 3000, row

    summary = json.loads((out / "summary.json").read_text())
    assert [run["video"] for run in summary["runs"]] == [13, 14]
    assert all(run["frames_out"] == 6 for run in summary["runs"]), summary["runs"]
    overall = summary["online"]["overall"]
    assert overall["n"] > 0
    for key in ("m_per_100m", "median_m", "p80_m"):
        assert math.isfinite(overall[key]) and overall[key] >= 0, (key, overall)
    with (out / "fixes.csv").open() as handle:
        assert len(list(csv.DictReader(handle))) == len(rows)
    honesty = summary["online_covariance"]["overall"]
    assert honesty["n"] > 0 and 0 <= honesty["inside_95"] <= 1 and honesty["nees_mean"] > 0, honesty
    assert "inside their 68 / 95 / 99 % ellipses" in result.stdout
    assert (out / "tracks.csv").stat().st_size > 0
    assert (out / "predictions_offline.csv").is_file()
    for picture in ("online/error_vs_distance.png", "online/error_hist.png", "online/map_video13.png"):
        assert (out / picture).stat().st_size > 1000, picture
    for video in (13, 14):
        assert (out / "recording" / f"video_{video}" / "metadata.yaml").is_file()
    assert "m/100m" in result.stdout


@pytest.mark.ros
@pytest.mark.slow
def test_demo_replays_a_saved_detector_run_in_step_with_the_camera(data_dir, ros_env, tmp_path):
    """--detections FILE.csv: a `detect run` CSV goes through the graph frame for frame (no model needed)."""
    from vessel_tools.calib.dataset import Dataset

    frames = Dataset(data_dir).frames([13])[:6]
    saved = tmp_path / "run.csv"
    lines = ["video,frame,x1,y1,x2,y2,score,class_id"]
    lines += [f"13,{f.frame},600,425,640,440,0.9,8" for f in frames[::2]]   # every other frame has a box
    saved.write_text("\n".join(lines) + "\n")
    out = tmp_path / "demo"
    command = [sys.executable, "-m", "vessel_tools.demo", "--data", str(data_dir), "--videos", "13",
               "--max-frames", "6", "--detections", str(saved), "--out", str(out), "--bags", str(tmp_path / "bags")]
    result = subprocess.run(command, env=ros_env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"][0]["frames_out"] == 6, summary["runs"]
    with (out / "tracks.csv").open() as handle:
        rows = [r for r in csv.DictReader(handle)]
    assert rows and all(abs(float(r["x_px"]) - 620) < 15 for r in rows)
    measured = {round(float(r["t_utc_s"]), 3) for r in rows}
    assert len(measured) >= 3     # the track exists from the first box on, through the frames without one


def test_a_missing_saved_detections_file_is_a_clear_error(data_dir, tmp_path):
    command = [sys.executable, "-m", "vessel_tools.demo", "--data", str(data_dir), "--videos", "13",
               "--detections", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "demo"),
               "--bags", str(tmp_path / "bags")]
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 2 and "nope.csv" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.ros
@pytest.mark.slow
def test_demo_feeds_the_hand_labels_through_the_graph_without_losing_one(data_dir, ros_env, tmp_path):
    """--detections labels: the self-paced replay starts once the graph after it is connected; every frame out."""
    out = tmp_path / "demo"
    command = [sys.executable, "-m", "vessel_tools.demo", "--data", str(data_dir), "--videos", "17",
               "--detections", "labels", "--out", str(out), "--bags", str(tmp_path / "bags")]
    result = subprocess.run(command, env=ros_env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    run = summary["runs"][0]
    assert run["frames_expected"] > 0 and run["frames_out"] == run["frames_expected"], summary["runs"]
    with (out / "predictions.csv").open() as handle:
        assert list(csv.DictReader(handle)), "no fix published for the hand-labelled vessel"


def test_a_recording_whose_recorder_died_is_recovered_and_kept(tmp_path):
    """The demo used to abort with no output at all when the recorder was killed with -9."""
    from vessel_detect import bag_messages, bag_reader, bag_topics, bag_writer
    from vessel_fixtures import detect_synthetic as synthetic
    from vessel_tools.demo import VideoRun, readable_recording

    recording = tmp_path / "video_13"
    writer = bag_writer.BagWriter(recording, atomic=False).open()
    writer.add_topic(bag_topics.DEFAULT_IMAGE_TOPIC, bag_topics.COMPRESSED_IMAGE, "sensor_data")
    for k in range(5):
        writer.write(bag_topics.DEFAULT_IMAGE_TOPIC,
                     bag_messages.compressed_image(1_601_494_000_000_000_000 + k * 40_000_000, synthetic.frame_jpeg(k)))
    writer.flush()  # what the recorder does every flush_period_s; then it is killed: no summary, no metadata.yaml
    messages: list[str] = []
    run = VideoRun(13, 36, 5, 1.0, recording, {"recorder": -9}, ("recorder",))
    assert readable_recording(run, messages.append)
    assert any("5 messages recovered" in m for m in messages), messages
    with bag_reader.BagReader(recording) as reader:
        assert reader.message_count() == 5
    nothing = VideoRun(14, 36, 0, 1.0, tmp_path / "video_14", {}, ("recorder",))
    (tmp_path / "video_14").mkdir()
    assert not readable_recording(nothing, messages.append)
    assert "left out of the scores" in messages[-1]
