"""``./vessel graph``: the whole graph as processes, started so that no frame is lost at the start."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from vessel_fixtures.challenge_bags import build_video_bags


@pytest.mark.ros
@pytest.mark.data
@pytest.mark.slow
def test_every_frame_of_a_bag_reaches_the_gps_publisher(data_dir, model_path, ros_env, tmp_path):
    """The camera starts only once every link from the detector to the GPS publisher is matched.

    Started with the others, the first frames' detections went out before the tracker (or the fuser, or the GPS
    publisher) had matched its publisher: 24-28 fixes for 36 images, none counted.
    """
    from vessel_detect.bag_reader import BagReader

    bags = build_video_bags(data_dir, tmp_path / "bags", "14", env=ros_env)
    recording = tmp_path / "recording"
    run = subprocess.run([sys.executable, "-m", "vessel_bringup.graph", "--source", str(bags / "video_14"),
                          "--rate", "0", "--exit-at-end", "--record", str(recording), "--log-dir",
                          str(tmp_path / "logs")], env=ros_env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "every link from the detector to the GPS publisher is matched" in run.stderr
    images = BagReader(bags / "video_14").message_count("/camera/image_raw/compressed")
    recorded = BagReader(recording)
    assert images == 36
    for topic in ("/vessel/detections", "/vessel/tracks/screen", "/vessel/tracks", "/vessel/fix"):
        assert recorded.message_count(topic) == images, (topic, recorded.message_count(topic))
    # A replay runs on its own /clock: the recording (/diagnostics included) spans the replay's time, not 2020 to today.
    assert recorded.message_count("/diagnostics") > 0
    assert 1_601_400_000e9 < recorded.start_ns and recorded.end_ns - recorded.start_ns < 3600e9


@pytest.mark.ros
@pytest.mark.data
@pytest.mark.slow
@pytest.mark.parametrize("hot_standby", [False, True], ids=["restart", "hot-standby"])
def test_a_killed_node_is_restarted_and_fixes_flow_again(data_dir, model_path, ros_env, tmp_path, hot_standby):
    """``--respawn``: the tracker killed mid-run is restarted, resumes from its state file, and fixes flow again.

    With ``--hot-standby`` its spare, which tracked every frame without publishing, takes over at the next frame:
    nothing is lost and nothing was published twice.
    """
    import signal
    import time

    from vessel_detect.bag_reader import BagReader

    bags = build_video_bags(data_dir, tmp_path / "bags", "15", env=ros_env)
    logs, recording = tmp_path / "logs", tmp_path / "recording"
    graph = subprocess.Popen([sys.executable, "-m", "vessel_bringup.graph", "--source", str(bags / "video_15"),
                              "--rate", "4" if hot_standby else "2", "--exit-at-end", "--respawn", "--record",
                              str(recording), "--log-dir",
                              str(logs)] + (["--hot-standby"] if hot_standby else []),
                             env=ros_env, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        camera_log = logs / "camera.log"
        while not (camera_log.exists() and "publishing" in camera_log.read_text(errors="replace")):
            assert time.monotonic() < deadline and graph.poll() is None, "the graph did not start"
            time.sleep(0.5)
        time.sleep(10.0 if hot_standby else 20.0)  # some frames through the graph
        marker = str(logs / "tracker.overrides.yaml")
        pids = subprocess.run(["pgrep", "-f", marker], capture_output=True, text=True).stdout.split()
        assert len(pids) == 1, pids
        killed_at = time.monotonic()
        subprocess.run(["kill", "-9", pids[0]], check=True)
        _, stderr = graph.communicate(timeout=300)
    finally:
        if graph.poll() is None:
            graph.send_signal(signal.SIGINT)
            graph.wait(timeout=30)
    print(f"graph ended {time.monotonic() - killed_at:.1f} s after the kill")
    fixes = BagReader(recording).message_count("/vessel/tracks")
    images = BagReader(bags / "video_15").message_count("/camera/image_raw/compressed")
    if hot_standby:
        promoted = re.search(r"tracker exited with status -9: promoted its hot standby /standby_(\d+)/tracker", stderr)
        assert promoted, stderr[-2000:]
        spare_log = (logs / f"tracker.standby_{promoted.group(1)}.log").read_text(errors="replace")
        assert "promoted from standby: publishing from now on" in spare_log, spare_log[-2000:]
        assert fixes <= images, f"{fixes} frames out of the fuser for {images} images: some published twice"
        # Lost around the promotion: at most the frame in flight. Frames lost before the first one recorded are the
        # start-up's, not this: the CI's load once lost the first two, and once the first three, which the camera
        # sent before the detector had matched (the graph now holds its first frame for the detector).
        from vessel_detect.bag_messages import ns_of_stamp

        with BagReader(recording) as reader:
            recorded = {ns_of_stamp(m.header.stamp) for _, m in reader.read_topic("/vessel/tracks")}
        with BagReader(bags / "video_15") as reader:
            sent = [ns_of_stamp(m.header.stamp) for _, m in reader.read_topic("/camera/image_raw/compressed")]
        first = min(i for i, stamp in enumerate(sent) if stamp in recorded)
        lost = [i for i, stamp in enumerate(sent) if stamp not in recorded and i > first]
        assert first <= 2 and len(lost) <= 1, f"frames {lost} lost after the first recorded one ({first})"
    else:
        assert "tracker exited with status -9: restarting it" in stderr, stderr[-2000:]
        tracker_log = (logs / "tracker.log").read_text(errors="replace")
        assert "resumed from state file" in tracker_log, tracker_log[-2000:]  # its tracks, not a cold start
        assert fixes >= images - 12, f"{fixes} frames out of the fuser for {images} images"


def _frames_sent(resume_file) -> int:
    """Frames the camera noted as sent in its resume file (0 before the first)."""
    import json

    try:
        return json.loads(resume_file.read_text())["position"]["frames_sent"]
    except (FileNotFoundError, ValueError, KeyError):
        return 0


def _kill_when(graph, logs, node: str, frames: int) -> None:
    """``kill -9`` node ``node`` of a running ``./vessel graph --log-dir logs`` once the camera sent ``frames``."""
    import time

    deadline = time.monotonic() + 240
    while _frames_sent(logs / "camera.resume") < frames:  # a file the camera rewrites as frames go: no sleep guess
        assert time.monotonic() < deadline and graph.poll() is None, "the graph did not get going"
        time.sleep(0.2)
    pids = subprocess.run(["pgrep", "-f", str(logs / f"{node}.overrides.yaml")], capture_output=True,
                          text=True).stdout.split()
    assert len(pids) == 1, pids
    subprocess.run(["kill", "-9", pids[0]], check=True)


@pytest.mark.ros
@pytest.mark.data
@pytest.mark.slow
@pytest.mark.parametrize("killed", ["camera", "recorder"])
def test_a_killed_camera_or_recorder_carries_on(data_dir, model_path, ros_env, tmp_path, killed):
    """``--respawn`` restarts the camera after its last frame and the recorder into the next part of the recording.

    Issue 48: the restarted camera replayed from frame 0 (10 old fixes published again, the tracker reset by stamps
    going back); a killed recorder failed five times on "OUT exists already", then the graph stopped every node and
    nothing was recorded after the kill.
    """
    import signal

    from vessel_detect.bag_messages import ns_of_stamp
    from vessel_detect.bag_reader import BagReader
    from vessel_detect.bag_salvage import recover_bag
    from vessel_detect.resume_files import recording_parts

    bags = build_video_bags(data_dir, tmp_path / "bags", "14", env=ros_env)
    logs, recording = tmp_path / "logs", tmp_path / "recording"
    graph = subprocess.Popen([sys.executable, "-m", "vessel_bringup.graph", "--source", str(bags / "video_14"),
                              "--rate", "0" if killed == "camera" else "4", "--exit-at-end", "--respawn", "--record",
                              str(recording), "--log-dir", str(logs)], env=ros_env, stderr=subprocess.PIPE, text=True)
    try:
        _kill_when(graph, logs, killed, 10)
        _, stderr = graph.communicate(timeout=400)
    finally:
        if graph.poll() is None:
            graph.send_signal(signal.SIGINT)
            graph.wait(timeout=30)
    assert graph.returncode == 0, stderr[-3000:]
    assert f"{killed} exited with status -9: restarting it (restart 1 of at most 5)" in stderr, stderr[-3000:]
    with BagReader(bags / "video_14") as reader:
        images = [ns_of_stamp(m.header.stamp) for _, m in reader.read_topic("/camera/image_raw/compressed")]
    parts = recording_parts(recording)
    fixes = []
    for part in parts:
        if part == recording and killed == "recorder":
            recover_bag(part)  # what `./vessel bag recover` does with the killed recorder's bag
        with BagReader(part) as reader:
            fixes += [ns_of_stamp(m.header.stamp) for _, m in reader.read_topic("/vessel/fix")]
    assert fixes == sorted(set(fixes)), "a fix recorded twice, or the stamps went back"  # no frame replayed
    if killed == "camera":
        camera_log = (logs / "camera.log").read_text(errors="replace")
        assert "carrying on after the item stamped" in camera_log, camera_log[-2000:]
        assert parts == [recording] and fixes == images  # every frame once
    else:
        assert parts == [recording, tmp_path / "recording.1"]
        assert "the recording is in 2 bags" in stderr
        # Lost: what the killed recorder had not flushed (1 s) and what came before its successor subscribed.
        assert set(fixes) <= set(images) and len(fixes) >= len(images) - 6, (len(fixes), len(images))


def test_restarts_back_off():
    from vessel_bringup.graph_nodes import MAX_RESTARTS, restart_delay_s

    assert [restart_delay_s(k) for k in range(6)] == [0.0, 0.5, 1.0, 2.0, 4.0, 8.0]
    assert restart_delay_s(20) == 8.0 and MAX_RESTARTS == 5
