import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from vessel_calib import geodesy
from vessel_calib.params import load_camera_yaml
from vessel_common.errors import CalibrationError
from vessel_fixtures.calib_synthetic import CAMERA_LAT, CAMERA_LON, pinhole_camera, synthetic_pairs
from vessel_tools import calibrate as calibrate_tool
from vessel_tools.calib.calibration import evaluate
from vessel_tools.calibrate_options import ros_params_to_cli

SRC = ":".join(str(p) for p in sorted(Path(__file__).resolve().parents[2].glob("vessel_*")) if p.is_dir())
REPO = Path(__file__).resolve().parents[3]
CAM_ARGS = ["--camera-lat", str(CAMERA_LAT), "--camera-lon", str(CAMERA_LON), "--image-size", "1280x720"]


def write_pairs(path, screen, gps, header="x,y,lat,lon"):
    rows = [header] + [",".join(repr(float(v)) for v in (*s, *g)) for s, g in zip(screen, gps, strict=True)]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.fixture
def pairs_csv(tmp_path):
    screen, gps = synthetic_pairs(pinhole_camera(), 20, seed=21)
    return write_pairs(tmp_path / "pairs.csv", screen, gps)


def run_cli(args, capsys):
    status = calibrate_tool.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return status, out, err


def test_pairs_csv_to_yaml_and_picture(tmp_path, pairs_csv, capsys):
    out = tmp_path / "cal" / "camera.yaml"
    status, stdout, err = run_cli(["--pairs-csv", pairs_csv, *CAM_ARGS, "--out", out], capsys)
    assert status == 0, err
    assert "reprojection" in stdout and "back-projected" in stdout and "heading" in stdout
    doc = yaml.safe_load(out.read_text())
    block = doc["/**"]["ros__parameters"]["camera"]
    assert len(block["H"]) == 9 and block["image_width"] == 1280
    model = load_camera_yaml(out)
    assert model.heading_deg == pytest.approx(pinhole_camera().heading_deg, abs=1e-3)
    picture = out.with_suffix(".png")
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in out.parent.iterdir()) == ["camera.png", "camera.yaml"]


def test_a_non_finite_pair_is_refused_by_its_file_row(tmp_path, pairs_csv, capsys):
    """A nan used to reach the fit and be reported as "pair 3", an index that is not the file's row 5."""
    lines = pairs_csv.read_text().splitlines()
    lines[4] = ",".join([*lines[4].split(",")[:2], "nan", lines[4].split(",")[3]])
    pairs_csv.write_text("\n".join(lines) + "\n")
    out = tmp_path / "camera.yaml"
    status, _, err = run_cli(["--pairs-csv", pairs_csv, *CAM_ARGS, "--out", out, "--no-picture"], capsys)
    assert status == 2 and "pairs.csv, row 5, column 'lat': expected a finite number, got 'nan'" in err, err
    assert not out.exists()


def test_pairs_with_times_and_gpx(tmp_path, capsys):
    cam = pinhole_camera()
    screen, gps = synthetic_pairs(cam, 12, seed=22)
    t0 = 1601494588.0
    times = t0 + 10.0 * np.arange(len(screen))
    points = "".join(f'<trkpt lat="{float(la)!r}" lon="{float(lo)!r}"><time>{t}</time></trkpt>'
                     for la, lo, t in zip(gps[:, 0], gps[:, 1],
                                          [time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t)) for t in times],
                                          strict=True))
    gpx = tmp_path / "track.gpx"
    gpx.write_text(f'<gpx xmlns="http://www.topografix.com/GPX/1/1"><trk><trkseg>{points}</trkseg></trk></gpx>')
    rows = ["x,y,t"] + [",".join(repr(float(v)) for v in (*s, t)) for s, t in zip(screen, times, strict=True)]
    rows.append(f"640,500,{t0 + 5000.0}")  # no fix near this time: dropped with a note
    csv_path = tmp_path / "timed.csv"
    csv_path.write_text("\n".join(rows) + "\n")
    out = tmp_path / "cal.yaml"
    status, stdout, err = run_cli(["--pairs-csv", csv_path, "--gps", gpx, *CAM_ARGS, "--out", out, "--no-picture"],
                                  capsys)
    assert status == 0, err
    assert "1 pair(s) dropped" in stdout
    assert evaluate(load_camera_yaml(out), screen, gps).reproj_max_px < 1e-3


@pytest.mark.parametrize("case, match", [
    ("few", "at least 5"),
    ("four", "passes through them exactly"),
    ("nan", "row 3, column 'x': expected a finite number"),  # the file's row, not the pair's index
    ("dup", "same screen point"),
    ("collinear", "collinear"),
    ("sky", "above the fitted horizon"),
    ("columns", "missing columns lat,lon"),
    ("camera", "camera position"),
    ("garbage", "row 3, column 'y'"),
])
def test_bad_input_one_line_error_and_no_file(tmp_path, capsys, case, match):
    cam = pinhole_camera()
    screen, gps = synthetic_pairs(cam, 12, seed=23)
    args = [*CAM_ARGS]
    path = tmp_path / "pairs.csv"
    if case == "few":
        write_pairs(path, screen[:3], gps[:3])
    elif case == "four":  # reported 0.00 px and 0.00 m with no warning
        write_pairs(path, screen[:4], gps[:4])
    elif case == "nan":
        screen[1, 0] = np.nan
        write_pairs(path, screen, gps)
    elif case == "dup":
        screen[3] = screen[0]
        write_pairs(path, screen, gps)
    elif case == "collinear":
        t = np.linspace(0, 1, 8)
        xs, ys, _ = cam.world_to_screen(60 + 100 * t, 10 + 25 * t)
        lat, lon = cam.world_to_gps(60 + 100 * t, 10 + 25 * t)
        write_pairs(path, np.column_stack([xs, ys]), np.column_stack([lat, lon]))
    elif case == "sky":
        write_pairs(path, np.vstack([screen, [640.0, 120.0]]),
                    np.vstack([gps, geodesy.local_to_gps(300.0, 60.0, CAMERA_LAT, CAMERA_LON)]))
    elif case == "columns":
        path.write_text("x,y,latitude_deg\n1,2,3\n")
    elif case == "camera":
        write_pairs(path, screen, gps)
        args = ["--camera-lat", "132.7", "--camera-lon", "-117.2"]
    elif case == "garbage":
        write_pairs(path, screen, gps)
        lines = path.read_text().splitlines()
        lines[2] = lines[2].split(",")[0] + ",abc," + ",".join(lines[2].split(",")[2:])
        path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out" / "cal.yaml"
    status, stdout, err = run_cli(["--pairs-csv", path, *args, "--out", out], capsys)
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err
    assert match in lines[0]
    assert not out.exists() and not (tmp_path / "out").exists()


def test_box_corners_are_read_at_the_box_anchor_and_the_anchor_is_written(tmp_path, capsys):
    cam = pinhole_camera()
    screen, gps = synthetic_pairs(cam, 16, seed=24)
    height = np.linspace(8.0, 30.0, len(screen))
    boxes = np.column_stack([screen[:, 0] - 15, screen[:, 1] - 0.8 * height, screen[:, 0] + 15,
                             screen[:, 1] + 0.2 * height])  # the vessel's point 0.8 of the way down each box
    path = tmp_path / "boxes.csv"
    rows = ["x1,y1,x2,y2,lat,lon"] + [",".join(repr(float(v)) for v in (*b, *g)) for b, g in zip(boxes, gps,
                                                                                               strict=True)]
    path.write_text("\n".join(rows) + "\n")
    out = tmp_path / "cal.yaml"
    status, _, err = run_cli(["--pairs-csv", path, *CAM_ARGS, "--box-anchor", "0.8", "--out", out, "--no-picture"],
                             capsys)
    assert status == 0, err
    model = load_camera_yaml(out)
    assert model.box_anchor == 0.8
    assert "box_anchor 0.8" in out.read_text()
    assert evaluate(model, model.box_reference_points(boxes), gps).reproj_max_px < 1e-3


@pytest.mark.parametrize("anchor", ["1.5", "-0.2", "nan"])
def test_box_anchor_outside_the_box_is_refused(tmp_path, pairs_csv, capsys, anchor):
    out = tmp_path / "cal.yaml"
    status, _, err = run_cli(["--pairs-csv", pairs_csv, *CAM_ARGS, "--box-anchor", anchor, "--out", out], capsys)
    assert status == 2 and err.startswith("error: ") and "box_anchor" in err and len(err.strip().splitlines()) == 1
    assert "[0, 1]" in err
    assert not out.exists()


def test_argparse_errors_are_one_line(capsys):
    status, _, err = run_cli(["--pairs", "many"], capsys)
    assert status == 2 and err.startswith("error: ") and len(err.strip().splitlines()) == 1


def test_ros_args_parameters(tmp_path, pairs_csv, capsys):
    out = tmp_path / "ros.yaml"
    status, stdout, err = run_cli(["--ros-args", "-p", f"pairs_csv:={pairs_csv}", "-p", f"camera_lat:={CAMERA_LAT}",
                                   "-p", f"camera_lon:={CAMERA_LON}", "-p", f"out:={out}", "-p", "no_picture:=true",
                                   "-r", "__node:=calib", "--"], capsys)
    assert status == 0, err
    assert out.exists() and not out.with_suffix(".png").exists()


def test_ros_params_file_block(tmp_path, pairs_csv, capsys):
    out = tmp_path / "from_file.yaml"
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"use_sim_time": False}},
        "calibrate": {"ros__parameters": {"pairs_csv": str(pairs_csv), "camera_lat": CAMERA_LAT,
                                          "camera_lon": CAMERA_LON, "out": str(out), "no_picture": True,
                                          "robust": True, "evaluate_on": ""}},
        "tracker": {"ros__parameters": {"anything": 1}}}))
    status, stdout, err = run_cli(["--ros-args", "--params-file", params], capsys)
    assert status == 0, err
    assert out.exists()
    status, _, err = run_cli(["--ros-args", "-p", "no_such_option:=1"], capsys)
    assert status == 2 and "unknown parameter 'no_such_option'" in err


def test_only_ros_args_without_data_says_what_it_needs(monkeypatch, capsys):
    monkeypatch.setattr(calibrate_tool, "default_data_dir", lambda: None)
    status, stdout, err = run_cli(["--ros-args"], capsys)
    assert status == 0 and "nothing to do" in stdout and "--data" in stdout


def test_interrupt_writes_nothing(tmp_path, pairs_csv, monkeypatch, capsys):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(calibrate_tool, "calibrate", interrupted)
    out = tmp_path / "cal.yaml"
    status, _, err = run_cli(["--pairs-csv", pairs_csv, *CAM_ARGS, "--out", out], capsys)
    assert status == 0 and "interrupted, nothing written" in err
    assert list(tmp_path.iterdir()) == [pairs_csv]


def test_interrupt_while_drawing_the_picture_leaves_nothing(tmp_path, pairs_csv, monkeypatch, capsys):
    import vessel_tools.calib.calibration_plot as plot_module

    def interrupted(path, *args, **kwargs):
        Path(path).write_bytes(b"half a png")
        raise KeyboardInterrupt

    monkeypatch.setattr(plot_module, "render_calibration_picture", interrupted)
    status, _, err = run_cli(["--pairs-csv", pairs_csv, *CAM_ARGS, "--out", tmp_path / "cal.yaml"], capsys)
    assert status == 0 and "interrupted, nothing written" in err
    assert list(tmp_path.iterdir()) == [pairs_csv]


# ----------------------------------------------------------------------------- shared data
def test_sigint_during_a_real_run_exits_zero_and_writes_nothing(dataset, tmp_path):
    out = tmp_path / "cal.yaml"
    env = {"PYTHONPATH": SRC, "PATH": "/usr/bin:/bin", "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "vessel_tools.calibrate", "--data", str(dataset.path),
                             "--out", str(out), "--evaluate-on", "13-17", "--draws", "200"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    # wait until it is fitting (its first report line), then interrupt
    first = proc.stdout.readline()
    assert first.startswith("calibrate: fitted on"), first
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "interrupted, nothing written" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_command_contract_on_shared_data(dataset, tmp_path, capsys):
    out = tmp_path / "c.yaml"
    status, stdout, err = run_cli(["--data", dataset.path, "--videos", "7-12", "--out", out, "--pairs", "11",
                                   "--seed", "3", "--no-picture"], capsys)
    assert status == 0, err
    assert "11 of 64 pairs" in stdout
    block = yaml.safe_load(out.read_text())["/**"]["ros__parameters"]["camera"]
    for key in ("camera_lat", "camera_lon", "image_width", "image_height", "H", "K1", "center_x", "center_y",
                "heading_deg"):
        assert key in block
    status, _, err = run_cli(["--data", dataset.path, "--videos", "6", "--out", tmp_path / "d.yaml"], capsys)
    assert status == 2 and "no labelled pairs" in err and not (tmp_path / "d.yaml").exists()


def test_water_level_with_a_pairs_csv(tmp_path, capsys):
    """--water-level fits pairs with a time column for the tide and writes the level.

    Without times, or outside the file: a one-line error and no file.
    """
    from vessel_fixtures.calib_synthetic import T0, tidal_pairs

    screen, gps, levels = tidal_pairs(40, seed=3)
    stamps = T0 + (0.97 - levels) / 0.35 * 3600  # the times the synthetic tide gave these levels
    tide = tmp_path / "tide.csv"
    tide.write_text(f"utc_s,level_m\n{T0},0.97\n{T0 + 3600},0.62\n")
    rows = ["x,y,lat,lon,t"] + [",".join(repr(float(v)) for v in (*s, *g, t))
                                for s, g, t in zip(screen, gps, stamps, strict=True)]
    pairs = tmp_path / "pairs.csv"
    pairs.write_text("\n".join(rows) + "\n")
    out = tmp_path / "camera.yaml"
    status, stdout, err = run_cli(["--pairs-csv", pairs, *CAM_ARGS, "--box-anchor", "0.65", "--water-level", tide,
                                   "--out", out, "--no-picture"], capsys)
    assert status == 0, err
    assert "water level" in stdout and "camera 2." in stdout
    model = load_camera_yaml(out)
    assert model.water_level_m == pytest.approx(levels.mean(), abs=1e-6)
    assert model.height_m == pytest.approx(2.6 + 0.9 - levels.mean(), abs=0.02)
    assert "water_level_m" in out.read_text().split("/**")[0]  # said in the header too
    untimed = write_pairs(tmp_path / "untimed.csv", screen, gps)
    status, _, err = run_cli(["--pairs-csv", untimed, *CAM_ARGS, "--water-level", tide, "--out",
                              tmp_path / "untimed.yaml", "--no-picture"], capsys)
    assert status == 2 and "time column" in err and not (tmp_path / "untimed.yaml").exists()
    short = tmp_path / "short.csv"
    short.write_text(f"utc_s,level_m\n{T0},0.97\n{T0 + 600},0.91\n")
    status, _, err = run_cli(["--pairs-csv", pairs, *CAM_ARGS, "--water-level", short, "--out",
                              tmp_path / "short.yaml", "--no-picture"], capsys)
    assert status == 2 and "outside the water-level file" in err and not (tmp_path / "short.yaml").exists()


def test_a_fit_with_few_pairs_warns_and_gives_a_leave_one_out_figure(tmp_path, capsys):
    """6 pairs leave 3 degrees of freedom: the in-sample error understates, the held-out one does not."""
    screen, gps = synthetic_pairs(pinhole_camera(), 6, seed=5)
    screen = screen + np.random.default_rng(5).normal(0.0, 2.0, screen.shape)  # label noise
    path = tmp_path / "pairs.csv"
    write_pairs(path, screen, gps)
    out = tmp_path / "camera.yaml"
    status, stdout, err = run_cli(["--pairs-csv", str(path), *CAM_ARGS, "--out", str(out), "--no-picture"], capsys)
    assert status == 0, err
    assert "warning: only 6 pairs, 3 degree(s) of freedom left" in stdout
    assert "each pair back-projected by a fit of the others: median" in stdout


def test_ros_parameters_reach_options_whose_flag_differs_from_their_name():
    # --from stores into pairs_from; -p pairs_from:=... must reach it, and -p from:=... is not a parameter name.
    assert ros_params_to_cli(["--ros-args", "-p", "pairs_from:=detections", "-p",
                              "max_camera_offset:=20"]) == ["--from", "detections", "--max-camera-offset", "20"]
    with pytest.raises(CalibrationError, match="unknown parameter 'from'"):
        ros_params_to_cli(["--ros-args", "-p", "from:=detections"])
