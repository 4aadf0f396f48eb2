"""``vessel_bringup.graph``: how a hot standby is started and promoted (no processes); a camera and detector alone."""

from __future__ import annotations

import signal

import pytest
import yaml

from vessel_bringup import graph
from vessel_bringup.graph_nodes import GRAPH_NODES
from vessel_common.errors import VesselError


class _FakeProcess:
    def __init__(self):
        self.signals: list[int] = []

    def poll(self):
        return None

    def send_signal(self, number):
        self.signals.append(number)


def test_a_spare_gets_its_nodes_blocks_under_its_namespaced_name(tmp_path, monkeypatch):
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"use_sim_time": False}},
        "fuser": {"ros__parameters": {"selection": {"recent_evidence_s": 16.0, "evidence_clip": 4.0}}},
        "/fuser": {"ros__parameters": {"selection": {"recent_evidence_s": 8.0}}},
    }))
    no_wildcard = tmp_path / "dump.yaml"  # like `ros2 param dump`: the node's block only
    no_wildcard.write_text(yaml.safe_dump({"/fuser": {"ros__parameters": {"qos_depth": 7}}}))
    spawned = []

    def fake_spawn(self, node, args, label, append_log, parameters, ignore_sigusr1=False):
        spawned.append((args, label, ignore_sigusr1))
        return graph.RunningNode(node, _FakeProcess(), None, None, parameters)

    monkeypatch.setattr(graph.GraphRunner, "_spawn", fake_spawn)
    runner = graph.GraphRunner([params, no_wildcard], log_dir=tmp_path / "logs")
    fuser = next(node for node in GRAPH_NODES if node.name == "fuser")
    runner.start(fuser, {"state_file": "/tmp/fuser.state"})
    spare = runner.start_spare("fuser")
    args, label, ignore_sigusr1 = spawned[-1]
    assert ignore_sigusr1 and label == "fuser.standby_1" and spare.namespace == "/standby_1"
    assert args[args.index("-r") + 1:args.index("-r") + 4] == ["__node:=fuser", "-r", "__ns:=/standby_1"]
    written = yaml.safe_load((tmp_path / "logs" / "fuser.standby_1.overrides.yaml").read_text())
    assert written == {"/standby_1/fuser": {"ros__parameters": {
        "selection.recent_evidence_s": 8.0, "selection.evidence_clip": 4.0, "qos_depth": 7,
        "state_file": "/tmp/fuser.state", "standby": True,
        # one namespace deeper, its relative topics would be /standby_1/vessel/...: given as the active node's
        "input_topic": "/vessel/tracks/screen", "output_topic": "/vessel/tracks",
        "collision_alerts_topic": "/vessel/collision_alerts"}}}

    active = runner.running["fuser"].process
    promoted = runner.promote_spare("fuser")
    assert promoted is spare and runner.running["fuser"] is spare and "fuser" not in runner.spares
    assert spare.process.signals == [signal.SIGUSR1] and active.signals == []
    runner.repeat_promotions()  # in case it was still starting and ignored the first
    assert spare.process.signals == [signal.SIGUSR1, signal.SIGUSR1]
    assert runner.promote_spare("fuser") is None  # no spare left until a new one is started


class _ExitedProcess(_FakeProcess):
    def __init__(self, status):
        super().__init__()
        self.returncode = status

    def poll(self):
        return self.returncode


def test_a_namespaced_graph_keeps_its_nodes_blocks_clock_files_and_spares_apart(tmp_path, monkeypatch):
    """``--namespace cam_a``: one camera of several, nothing of it keyed by a bare node name another camera shares."""
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"use_sim_time": False}},
                                      "tracker": {"ros__parameters": {"gate_px": 55.0}}}))
    spawned = []

    def fake_spawn(self, node, args, label, append_log, parameters, ignore_sigusr1=False):
        spawned.append((args, label))
        return graph.RunningNode(node, _FakeProcess(), None, None, parameters)

    monkeypatch.setattr(graph.GraphRunner, "_spawn", fake_spawn)
    runner = graph.GraphRunner([params], log_dir=tmp_path / "logs", namespace="cam_a")
    assert runner.namespace == "/cam_a" and runner.log_dir == tmp_path / "logs" / "cam_a"
    tracker = next(node for node in GRAPH_NODES if node.name == "tracker")
    runner.start(tracker, runner.respawn_files("tracker"))
    args, _ = spawned[-1]
    assert ["-r", "__ns:=/cam_a", "-r", "/clock:=/cam_a/clock"] == args[4:8]
    state_file = str(tmp_path / "logs" / "cam_a" / "tracker.state")
    written = yaml.safe_load((tmp_path / "logs" / "cam_a" / "tracker.overrides.yaml").read_text())
    assert written == {"/cam_a/tracker": {"ros__parameters": {"gate_px": 55.0, "state_file": state_file}}}
    spare = runner.start_spare("tracker")
    args, label = spawned[-1]
    assert spare.namespace == "/cam_a/standby_1" and label == "tracker.standby_1"
    assert ["-r", "__ns:=/cam_a/standby_1", "-r", "/clock:=/cam_a/clock"] == args[4:8]
    written = yaml.safe_load((tmp_path / "logs" / "cam_a" / "tracker.standby_1.overrides.yaml").read_text())
    assert written["/cam_a/standby_1/tracker"]["ros__parameters"] == {
        "gate_px": 55.0, "state_file": state_file, "standby": True,
        "input_topic": "/cam_a/vessel/detections", "output_topic": "/cam_a/vessel/tracks/screen"}
    with pytest.raises(VesselError, match="namespace '2cams'"):
        graph.GraphRunner([params], namespace="2cams")


def test_under_respawn_every_node_keeps_its_files_and_a_failed_one_is_restarted_with_them(tmp_path, monkeypatch):
    """Issue 48: the respawned camera replayed from frame 0 and the respawned recorder failed on "OUT exists already".

    Under ``--respawn`` each node gets the files of ``graph_nodes.respawn_files`` (the launch file's too): the
    tracker and fuser a state file, the camera and the recorder a resume file, stale ones from an earlier run
    removed. A node that fails (the camera killed, too) is restarted with the same files; a camera that ended its
    source (status 0) is the end of the source for ``--exit-at-end``, a killed one is not.
    """
    from vessel_bringup.graph_nodes import RECORDER, respawn_files

    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"camera": {"ros__parameters": {"rate": 0.0}}}))
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "camera.resume").write_text("{}")  # an earlier run's
    spawned = []

    def fake_spawn(self, node, args, label, append_log, parameters, ignore_sigusr1=False):
        spawned.append((label, dict(parameters or {})))
        return graph.RunningNode(node, _FakeProcess(), None, None, parameters)

    monkeypatch.setattr(graph.GraphRunner, "_spawn", fake_spawn)
    runner = graph.GraphRunner([params], log_dir=logs)
    args = graph.parse_args(["--source", "bags/video_13", "--respawn", "--record", str(tmp_path / "rec"),
                             "--no-wait", "--exit-at-end"])
    wanted = [node.name for node in GRAPH_NODES]
    graph._start_consumers(args, runner, wanted, False)
    graph._start_camera(args, runner, wanted, False, graph.StopRequest())
    assert sorted(runner.running) == sorted(wanted + [RECORDER.name])
    for name, running in runner.running.items():
        files = {key: value for key, value in running.parameters.items() if key.endswith("_file")}
        assert files == respawn_files(name, logs), name
    assert not (logs / "camera.resume").exists()
    assert runner.running["recorder"].parameters["output"] == str(tmp_path / "rec")

    for name in ("camera", "recorder"):
        before = runner.running[name].parameters
        runner.running[name].process = _ExitedProcess(-9)  # kill -9
        assert runner.failed() == [name]
        if name == "camera":
            assert not graph._source_ended(runner, respawn=True)  # restarted, not the end of the source
            assert graph._source_ended(runner, respawn=False)
        assert graph._respawn(runner, [name], {})
        assert spawned[-1] == (name, before) and runner.running[name].restarts == 1
    runner.running["camera"].process = _ExitedProcess(0)  # the end of the source
    assert runner.failed() == [] and graph._source_ended(runner, respawn=True)


def test_a_replayed_camera_holds_its_first_frame_for_the_graphs_own_detector(tmp_path):
    """At a rate above 0 the camera's automatic wait is none: the graph makes it wait for its detector.

    Seen in CI: a replay at rate 4 whose first three frames went out before the detector's subscription matched.
    """
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"use_sim_time": False}},
        "camera": {"ros__parameters": {"rate": 2.0, "wait_for_subscribers": -1}},
    }))
    later = tmp_path / "later.yaml"
    later.write_text(yaml.safe_dump({"/camera": {"ros__parameters": {"rate": 4.0}}}))
    values = graph.GraphRunner([params, later]).file_parameters("camera")
    assert values == {"use_sim_time": False, "rate": 4.0, "wait_for_subscribers": -1}
    assert graph.camera_waits_for_detector(values, {}, local_detector=True) == {"wait_for_subscribers": 1}
    assert graph.camera_waits_for_detector({}, {}, local_detector=True) == {"wait_for_subscribers": 1}
    # Rate 0 keeps the automatic wait, which also waits for the detector's acknowledgements.
    assert graph.camera_waits_for_detector(values, {"rate": 0.0}, local_detector=True) == {}
    assert graph.camera_waits_for_detector({"rate": 0.0}, {}, local_detector=True) == {}
    # A value the user set, and a graph with no detector of its own (or --no-wait), are left alone.
    assert graph.camera_waits_for_detector({"wait_for_subscribers": 0}, {}, local_detector=True) == {}
    assert graph.camera_waits_for_detector(values, {}, local_detector=False) == {}


@pytest.mark.ros
def test_a_camera_and_detector_alone_start_at_once_with_no_wait(ros_env, tmp_path):
    """`--nodes camera,detector` waits for a tracker elsewhere; `--no-wait` runs the two alone to the source's end."""
    import subprocess
    import sys

    from vessel_fixtures import detect_synthetic as synthetic

    synthetic.write_bag(tmp_path / "bag", frames=4)
    run = subprocess.run([sys.executable, "-m", "vessel_bringup.graph", "--source", str(tmp_path / "bag"), "--nodes",
                          "camera,detector", "--no-wait", "--exit-at-end", "--connect-timeout", "1", "--log-dir",
                          str(tmp_path / "logs")], env=ros_env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "started camera" in run.stderr and "did not connect" not in run.stderr


def test_ctrl_c_ends_the_wait_for_the_graph_to_connect():
    """Ctrl-C (the handler sets ``stop``) used to go unheeded until the connection time-out, a minute later."""
    import threading
    import time

    class NeverConnected:
        def connected(self, **links):
            return False

        def detector_connected(self):
            return False

        def spin(self, seconds):
            time.sleep(0.01)

    class NothingFailed:
        def failed(self):
            return []

    stop = threading.Event()
    threading.Timer(0.2, stop.set).start()
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        graph.wait_until_connected(NothingFailed(), NeverConnected(), 60.0, "nowhere", stop, detector_only=True)
    assert time.monotonic() - started < 30.0


def test_a_camera_source_that_does_not_exist_is_refused_before_any_node_starts(tmp_path, capsys, monkeypatch):
    def no_process(*args, **kwargs):
        raise AssertionError("a node was started")

    monkeypatch.setattr(graph.GraphRunner, "start", no_process)
    for nodes in ("camera,detector", "camera,detector,tracker,fuser,gps_publisher"):
        assert graph.main(["--source", str(tmp_path / "video_99"), "--nodes", nodes]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: source ") and "video_99 does not exist" in err, err


class _RunnerOfNoProcess:
    """A ``GraphRunner`` that starts nothing; it reports a failure after ``patience_s`` so a hung stop cannot hang."""

    patience_s = 30.0
    made: list[_RunnerOfNoProcess] = []

    def __init__(self, params, log_dir=None, echo=False, namespace=""):
        import time

        self.running, self.spares, self.spares_wanted, self.stops = {}, {}, set(), 0
        self.namespace = namespace
        self.give_up = time.monotonic() + self.patience_s
        self.made.append(self)

    def start(self, node, parameters=None):
        self.running[node.name] = graph.RunningNode(node, _FakeProcess(), None, None, parameters or {})

    def failed(self):
        import time

        return ["tracker"] if time.monotonic() > self.give_up else []

    def repeat_promotions(self):
        pass

    def stop(self, names=None, timeout_s=15.0):
        self.stops += 1
        return {name: 0 for name in self.running}


def _signal_inside_its_own_handler(before, handled):
    """Once the runner's SIGINT handler is in place, run it with another run of it at every line, then once more."""
    import sys
    import time

    while signal.getsignal(signal.SIGINT) is before:
        time.sleep(0.01)
    handler, nested = signal.getsignal(signal.SIGINT), [False]

    def at_every_line(frame, event, arg):  # a second signal arriving between any two lines of the first's handler
        if event == "line" and not nested[0]:
            nested[0] = True
            try:
                handler(signal.SIGTERM, None)
            finally:
                nested[0] = False
        return at_every_line

    sys.settrace(at_every_line)
    try:
        handler(signal.SIGINT, None)
    finally:
        sys.settrace(None)
    handler(signal.SIGINT, None)  # and a third one right after
    handled.set()


def test_a_signal_arriving_inside_the_signal_handler_neither_deadlocks_nor_keeps_the_graph_running(monkeypatch,
                                                                                                    capsys):
    """The SIGINT/SIGTERM handler called ``threading.Event.set()``, which holds a lock while it runs.

    Python runs a signal handler between any two lines of the main thread, the handler itself included: a second
    signal there (Ctrl-C twice) ran the handler again, which waited for the lock its first run held, and the runner
    hung for good with every node running. Here the runner's own handler is run again at every line of its first
    run (what a signal arriving there does), then once more; the runner must stop at once.
    """
    import threading
    import time

    monkeypatch.setattr(graph, "GraphRunner", _RunnerOfNoProcess)
    monkeypatch.setattr(_RunnerOfNoProcess, "made", [])
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    handled = threading.Event()
    threading.Thread(target=_signal_inside_its_own_handler, args=(before[0], handled), daemon=True).start()
    started = time.monotonic()
    status = graph.main(["--nodes", "tracker"])
    assert handled.wait(5.0), "the signal handler deadlocked on its own lock"
    assert time.monotonic() - started < _RunnerOfNoProcess.patience_s / 2, "the runner did not stop on the signal"
    err = capsys.readouterr().err
    assert status == 0 and [runner.stops for runner in _RunnerOfNoProcess.made] == [1], err
    assert "[graph] SIGINT: stopping every node" in err or "[graph] SIGTERM: stopping every node" in err
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before  # handlers put back
