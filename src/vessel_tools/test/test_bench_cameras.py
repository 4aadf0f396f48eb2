"""``./vessel bench cameras``: its figures from what the watcher saw and /proc said, its command line, its curve."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from vessel_bringup.fleet import CameraSpec, parse_cameras
from vessel_bringup.fleet_watcher import CameraLog
from vessel_common.errors import DataError
from vessel_tools import bench_cameras, bench_cameras_report


def _usage(rss_mb: float, cpu_s: float):
    return SimpleNamespace(rss_mb=rss_mb, cpu_s_measured=cpu_s, as_dict=lambda: {"rss_mb": rss_mb})


def _fake_run(killed: bool):
    """Two cameras, each with its own camera process, sharing one tracking process; cam1 killed or not."""
    stamps = list(range(10))
    cameras = [bench_cameras.CameraRun(CameraSpec("/cam0", "a"), 13, stamps, 2, 8.0, ended=True),
               bench_cameras.CameraRun(CameraSpec("/cam1", "b"), 14, stamps, 2, 8.0, ended=True,
                                       killed_at_s=3.0 if killed else None)]
    logs = {"/cam0": CameraLog(images={s: 1000 * s for s in stamps}, fixes={s: 1000 * s + 200_000_000 for s in stamps
                                                                          if s != 5}),
            "/cam1": CameraLog(images={s: 0 for s in stamps[:6]}, fixes={s: 100_000_000 for s in stamps[:6]})}
    processes = {"cam0/camera": SimpleNamespace(cameras=("/cam0",)), "cam1/camera": SimpleNamespace(cameras=("/cam1",)),
                 "tracking": SimpleNamespace(cameras=("/cam0", "/cam1"))}
    fleet = SimpleNamespace(of_camera=lambda name: [SimpleNamespace(label=label, **vars(p)) for label, p in
                                                    processes.items() if name in p.cameras])
    run = SimpleNamespace(cameras=cameras, watcher=SimpleNamespace(logs=logs), fleet=fleet, labels=processes)
    usage = {"cam0/camera": _usage(100.0, 1.0), "cam1/camera": _usage(100.0, 1.0), "tracking": _usage(300.0, 4.0)}
    return run, usage


def test_a_camera_that_sent_every_frame_offers_them_all_and_shares_the_common_process():
    run, usage = _fake_run(killed=False)
    cam0 = bench_cameras_report.camera_figures(run.cameras[0], run.watcher.logs["/cam0"], run, usage)
    assert cam0["frames_offered"] == 8 and cam0["frames_processed"] == 7  # warm-up 2 out; frame 5 had no fix
    assert cam0["processed_fraction"] == pytest.approx(7 / 8)
    assert cam0["latency_ms_p50"] == pytest.approx(200.0, abs=0.01) and cam0["latency_n"] == 7
    assert cam0["rss_mb_total"] == pytest.approx(100.0 + 300.0 / 2) and cam0["processes"] == pytest.approx(1.5)
    assert cam0["cpu_ms_per_frame"] == pytest.approx(1000.0 * (1.0 + 2.0) / 7)


def test_a_killed_camera_counts_what_it_sent_and_stays_out_of_the_machines_figures():
    run, usage = _fake_run(killed=True)
    per_camera = {c.spec.label: bench_cameras_report.camera_figures(c, run.watcher.logs[c.spec.name], run, usage)
                  for c in run.cameras}
    assert per_camera["cam1"]["frames_offered"] == 4 == per_camera["cam1"]["frames_processed"]  # stamps 2..5 seen
    machine = bench_cameras_report.machine_figures(per_camera, run, usage)
    assert machine["frames_offered"] == 8 and machine["frames_processed"] == 7 and machine["cameras_killed"] == ["cam1"]
    assert machine["rss_mb_total"] == pytest.approx(100.0 + 300.0)  # the killed camera's own process is gone
    assert machine["processes"] == 3
    table = bench_cameras_report.format_table({
        "cameras": 2, "fps": 2.0, "processes_mode": "per-role", "measured_s": 60.0, **machine,
        "per_camera": per_camera, "machine": {"cores": 2, "load_average_before": [1.0, 1.0, 1.0],
                                              "load_average_after": [2.0, 2.0, 2.0]}})
    assert "killed 3 s in" in table and table.splitlines()[-1].startswith("machine")


def test_the_curve_is_drawn_for_each_process_mode(tmp_path):
    pytest.importorskip("matplotlib")
    runs = [{"cameras": n, "fps": 2.0, "minutes": 1.0, "frames_processed": 120 * n, "rss_mb_total": 600.0 * n,
             "processes_mode": mode, "machine": {"cores": 2}} for n in (1, 2, 4) for mode in ("per-node", "per-role")]
    bench_cameras_report.plot_curve(runs, tmp_path / "curve.png")
    assert (tmp_path / "curve.png").stat().st_size > 1000


def test_the_command_line_refuses_what_it_cannot_run(capsys):
    for argv, message in ((["--cameras", "0"], "at least 1"), (["--cameras", "two"], "a number or a list"),
                          (["--fps", "-1"], "--fps must be a positive"), (["--cameras", "2", "--kill", "cam5"],
                                                                          "no such camera")):
        with pytest.raises(SystemExit):
            bench_cameras.parse_args(argv)
        assert message in capsys.readouterr().err
    assert bench_cameras.parse_args(["--cameras", "1,2,4,8"]).counts == [1, 2, 4, 8]
    with pytest.raises(DataError, match="not NAME=SOURCE"):
        parse_cameras("cam0=a,cam1")
    with pytest.raises(DataError, match="named twice"):
        parse_cameras("cam0=a,/cam0=b")
    assert parse_cameras("cam0=bags/video_13")[0] == CameraSpec("/cam0", "bags/video_13")
    assert math.isnan(bench_cameras_report.camera_figures(
        bench_cameras.CameraRun(CameraSpec("/c", "x"), 13, [1, 2], 2, 1.0, ended=True), CameraLog(),
        SimpleNamespace(fleet=SimpleNamespace(of_camera=lambda name: [])), {})["processed_fraction"])


def test_frame_stamps_follow_the_cameras_restamped_loops(tmp_path):
    """The stamps the bench expects are those the camera sends: each loop shifted by the bag's length + 1 step."""
    import cv2
    import numpy as np

    from vessel_detect import bag_messages, bag_topics
    from vessel_detect.bag_writer import BagWriter

    pytest.importorskip("rosbags")
    jpeg = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].tobytes()
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        writer.add_topic(bag_topics.DEFAULT_IMAGE_TOPIC, bag_topics.COMPRESSED_IMAGE, "sensor_data")
        for stamp in (10, 14, 18):
            writer.write(bag_topics.DEFAULT_IMAGE_TOPIC, bag_messages.compressed_image(stamp * 10**9, jpeg),
                         log_time_ns=stamp * 10**9)
    assert bench_cameras.frame_stamps(bag, 5) == [int(s * 1e9) for s in (10, 14, 18, 22, 26)]
    assert bench_cameras.replay_rate(bag, 2.0) == pytest.approx(8.0)
