"""The offline tools on a small generated dataset: ``detect run``, ``detect recall`` and ``detect export-labels``."""

import csv
import json
import math

import cv2
import numpy as np
import pytest
import yaml

from vessel_calib import geodesy
from vessel_calib.camera_model import CameraModel
from vessel_detect.decoders import grid_point_count
from vessel_detect.detections_csv import CSV_COLUMNS
from vessel_fixtures.onnx_synthetic import write_constant_output_model
from vessel_tools.detect import detect_cli

CAMERA_LAT, CAMERA_LON = 32.70297, -117.234631
H = [[-441.0, 379.0, -1000.0], [-217.0, -56.5, -548.0], [-0.512, -0.144, 1.0]]
K1 = -4.053e-07
BOAT = 8
# Frames of video 7: seconds of day and where the vessel is (metres east, north), None = no GPS.
FRAMES = [
    (0, 70588.25, (97.0, 24.0)),  # 100 m ENE: in view
    (100, 70592.25, (150.0, 60.0)),  # in view
    (200, 70600.25, None),  # a GPS gap: invalid
    (300, 70610.25, (-80.0, -20.0)),  # behind the camera: out of view
]


def _iso(seconds_of_day: float) -> str:
    h, rest = divmod(seconds_of_day, 3600)
    m, s = divmod(rest, 60)
    return f"2020-09-30T{int(h):02d}:{int(m):02d}:{s:06.3f}Z"


@pytest.fixture
def tiny_dataset(tmp_path):
    """A dataset folder laid out like ../shared/aitas with four grey frames of video 7."""
    root = tmp_path / "data"
    (root / "frames" / "7").mkdir(parents=True)
    camera = {
        "camera_lat": CAMERA_LAT, "camera_lon": CAMERA_LON, "image_width": 1280, "image_height": 720,
        "distortion_centre": [640, 360],
        "calibrations": {"paper_corrected_H00_negative": {"H": H, "K1": K1}},
    }
    (root / "camera.json").write_text(json.dumps(camera))
    rows, fixes = [], []
    for frame, sod, where in FRAMES:
        image = np.full((720, 1280, 3), 90, np.uint8)
        cv2.imwrite(str(root / "frames" / "7" / f"{frame:05d}.jpg"), image)
        rows.append([7, frame, _iso(sod), 1, f"frames/7/{frame:05d}.jpg"])
        if where is not None:
            lat, lon = geodesy.local_to_gps(where[0], where[1], CAMERA_LAT, CAMERA_LON)
            for dt in (-1.0, 1.0):
                fixes.append([len(fixes), _iso(sod + dt), int(sod + dt), sod + dt, float(lat), float(lon)])
    with open(root / "frames.csv", "w", newline="") as handle:
        csv.writer(handle).writerows([["video", "frame", "utc", "has_label", "file"], *rows])
    with open(root / "target_gps_fixes.csv", "w", newline="") as handle:
        csv.writer(handle).writerows([["fix_index", "utc", "utc_s", "t_spread_s", "lat", "lon"], *fixes])
    return root


def _camera() -> CameraModel:
    return CameraModel(np.array(H), K1, camera_lat=CAMERA_LAT, camera_lon=CAMERA_LON)


def _write_labels(root, boxes):
    header = ["video", "frame", "utc", "t_utc_s", "x1", "y1", "x2", "y2", "primary", "lat", "lon", "gps_ok"]
    with open(root / "screen_labels.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for frame, box in boxes:
            sod = next(s for f, s, _ in FRAMES if f == frame)
            writer.writerow([7, frame, _iso(sod), sod, *box, 1, "", "", 0])


@pytest.fixture
def synthetic_params(tmp_path):
    """A parameter file whose model always sees one boat at network (208, 104), 64x32 (full mode)."""
    points = grid_point_count((416, 416))
    out = np.zeros((1, points, 85), np.float32)
    out[0, :, 2:4] = -5
    row = 52 * 52 + (104 // 16) * 26 + 208 // 16
    out[0, row, :5] = [0.0, 0.5, math.log(64 / 16), math.log(32 / 16), 1.0]
    out[0, row, 5 + BOAT] = 0.75
    model = write_constant_output_model(tmp_path / "boat.onnx", out)
    params = {"detector": {"ros__parameters": {"model_path": str(model), "mode": "full",
                                               "exclusion_polygons": [""], "intra_op_threads": 1}}}
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params))
    return path


EXPECTED_BOX = np.array([208 - 32, 104 - 16 + 0, 208 + 32, 104 + 16]) * (1280 / 416)  # full-frame pixels


def test_run_writes_one_row_per_detection(tiny_dataset, synthetic_params, tmp_path, capsys):
    out = tmp_path / "dets.csv"
    status = detect_cli.main(["run", "--data", str(tiny_dataset), "--videos", "7", "--out", str(out),
                              "--params", str(synthetic_params), "--quiet"])
    assert status == 0
    with open(out) as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0].keys()) == list(CSV_COLUMNS)
    assert [(int(r["video"]), int(r["frame"])) for r in rows] == [(7, f) for f, _, _ in FRAMES]
    for row in rows:
        box = [float(row[k]) for k in ("x1", "y1", "x2", "y2")]
        np.testing.assert_allclose(box, EXPECTED_BOX, atol=0.1)
        assert float(row["score"]) == pytest.approx(0.75, abs=1e-3) and int(row["class_id"]) == BOAT


def test_recall_from_a_detections_file(tiny_dataset, synthetic_params, tmp_path, capsys):
    _write_labels(tiny_dataset, [(0, EXPECTED_BOX + 5), (100, [900, 600, 950, 650])])
    out = tmp_path / "dets.csv"
    assert detect_cli.main(["run", "--data", str(tiny_dataset), "--out", str(out), "--params",
                            str(synthetic_params), "--quiet"]) == 0
    report = tmp_path / "recall.json"
    assert detect_cli.main(["recall", "--data", str(tiny_dataset), "--videos", "7", "--detections", str(out),
                            "--thresholds", "0.5,0.8", "--out", str(report)]) == 0
    printed = capsys.readouterr().out
    assert "50.0 %" in printed
    results = json.loads(report.read_text())["results"]
    assert results[0]["box_hits"] == 1 and results[0]["boxes"] == 2
    assert results[1]["box_hits"] == 0  # the detections score 0.75
    # The unmatched detection of frame 100 (y 271-369) stands above the horizon (y ~ 420): not counted.
    assert results[0]["other_detections_per_frame"] == 0.0


def test_recall_at_counts_hits_and_others():
    labels = {(7, 0): np.array([[100, 450, 160, 480]], float), (7, 1): np.array([[500, 450, 560, 480]], float)}
    detections = {
        (7, 0): (np.array([[105, 452, 158, 478], [800, 500, 850, 520], [800, 100, 850, 120]], float),
                 np.array([0.9, 0.4, 0.9])),
    }
    result = detect_cli.recall_at(labels, detections, 0.3, horizon_y=lambda xs: np.full(np.shape(xs), 420.0))
    assert (result.box_hits, result.boxes, result.frame_hits, result.frames) == (1, 2, 1, 2)
    assert result.other_per_frame == pytest.approx(0.5)  # the sky box does not count
    assert detect_cli.recall_at(labels, detections, 0.95).box_hits == 0


def test_export_labels_in_yolo_format(tiny_dataset, tmp_path):
    out = tmp_path / "yolo"
    assert detect_cli.main(["export-labels", "--data", str(tiny_dataset), "--videos", "7", "--out", str(out),
                            "--box", "paper"]) == 0
    images = sorted(p.name for p in (out / "images" / "train").iterdir())
    labels = sorted(p.name for p in (out / "labels" / "train").iterdir())
    assert images == ["7_00000.jpg", "7_00100.jpg"]  # no image for the GPS gap nor the vessel behind the camera
    assert labels == ["7_00000.txt", "7_00100.txt"]
    data = yaml.safe_load((out / "data.yaml").read_text())
    assert data["names"] == {0: "boat"} and data["train"] == "images/train"
    camera = _camera()
    for name, (xw, yw) in (("7_00000.txt", FRAMES[0][2]), ("7_00100.txt", FRAMES[1][2])):
        cls, cx, cy, w, h = (float(v) for v in (out / "labels" / "train" / name).read_text().split())
        xs, ys, _ = camera.world_to_screen(xw, yw)
        zp = abs(float(camera.zp_of_world(xw, yw)))
        assert cls == 0
        assert cx * 1280 == pytest.approx(float(xs), abs=0.5) and cy * 720 == pytest.approx(float(ys), abs=0.5)
        assert w * 1280 == pytest.approx(2 * (1500 / zp + 25), abs=0.5)  # the paper's box, at full resolution
        assert h * 720 == pytest.approx(2 * (850 / zp + 25), abs=0.5)
    with open(out / "frames.csv") as handle:
        statuses = {int(r["frame"]): r["status"] for r in csv.DictReader(handle)}
    assert statuses == {0: "labelled", 100: "labelled", 200: "gps_invalid", 300: "out_of_view"}


def test_export_labels_with_explicit_negatives(tiny_dataset, tmp_path):
    out = tmp_path / "yolo"
    assert detect_cli.main(["export-labels", "--data", str(tiny_dataset), "--videos", "7", "--out", str(out),
                            "--negatives", "out-of-view"]) == 0
    assert (out / "labels" / "train" / "7_00300.txt").read_text() == ""  # an explicit empty label: a negative
    assert not (out / "images" / "train" / "7_00200.jpg").exists()  # GPS gap: never a negative


def test_bad_input_prints_one_error_line_and_exits_2(tmp_path, capsys):
    assert detect_cli.main(["run", "--data", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Traceback" not in err
    bad = tmp_path / "bad.yaml"
    bad.write_text("detector:\n  ros__parameters:\n    scor_threshold: 0.3\n")
    assert detect_cli.main(["recall", "--detections", str(tmp_path / "none.csv"), "--params", str(bad)]) == 2


def test_recall_at_counts_frames_whose_most_likely_box_is_the_vessel():
    labels = {(7, 0): np.array([[100, 450, 160, 480]], float), (7, 1): np.array([[500, 450, 560, 480]], float)}
    detections = {
        (7, 0): (np.array([[105, 452, 158, 478], [800, 500, 850, 520]], float), np.array([0.9, 0.4])),
        (7, 1): (np.array([[505, 452, 558, 478], [800, 500, 850, 520]], float), np.array([0.3, 0.6])),
    }
    result = detect_cli.recall_at(labels, detections, 0.1)
    assert (result.frame_hits, result.top_hits) == (2, 1) and result.top_rate == pytest.approx(0.5)
    assert detect_cli.recall_at(labels, detections, 0.5).top_hits == 1  # the vessel's 0.3 box is gone at 0.5


def test_gps_ranking_counts_boxes_at_the_gps_point_by_range():
    points = {(7, 0): (130.0, 465.0, 80.0), (7, 1): (530.0, 440.0, 250.0), (7, 2): (900.0, 430.0, 400.0),
              (7, 3): (300.0, 430.0, 120.0)}
    detections = {
        (7, 0): (np.array([[105, 452, 158, 478], [800, 500, 850, 520]], float), np.array([0.9, 0.4])),
        # the point lies 8 px above this box: within the 10 px margin, not within 5; another box ranks first
        (7, 1): (np.array([[505, 448, 558, 478], [800, 500, 850, 520]], float), np.array([0.3, 0.6])),
        (7, 2): (np.array([[10, 500, 40, 520]], float), np.array([0.9])),
    }  # frame 3: no detection
    result = detect_cli.gps_ranking(points, detections, 10.0, (0.0, 100.0, 300.0, math.inf))
    assert (result.frames, result.found, result.top) == ([1, 2, 1], [1, 1, 0], [1, 0, 0])
    assert detect_cli.gps_ranking(points, detections, 5.0, (0.0, 100.0, 300.0, math.inf)).found == [1, 0, 0]
    summary = result.as_dict()
    assert (summary["frames"], summary["top"]) == (4, 1) and summary["bands"][-1]["to_m"] is None
    with pytest.raises(ValueError, match="increase"):
        detect_cli.gps_ranking(points, detections, 10.0, (0.0, 100.0, 100.0))


def _write_gt_1hz(root, rows):
    header = ["video", "t_utc_s", "lat", "lon", "valid", "in_view", "dist_m", "x_ref", "y_ref"]
    with open(root / "gt_1hz.csv", "w", newline="") as handle:
        csv.writer(handle).writerows([header, *rows])


def test_rank_against_the_gps_from_a_detections_file(tiny_dataset, synthetic_params, tmp_path, capsys):
    out = tmp_path / "dets.csv"
    assert detect_cli.main(["run", "--data", str(tiny_dataset), "--out", str(out), "--params",
                            str(synthetic_params), "--quiet"]) == 0
    inside = (EXPECTED_BOX[0] + EXPECTED_BOX[2]) / 2, (EXPECTED_BOX[1] + EXPECTED_BOX[3]) / 2
    _write_gt_1hz(tiny_dataset, [
        [7, 70588, 0, 0, 1, 1, 100.0, *inside],  # frame 0 (70588.25 s): at the detection
        [7, 70592, 0, 0, 1, 1, 160.0, 1000.0, 600.0],  # frame 100: far from it
        [7, 70600, 0, 0, 0, 1, 170.0, *inside],  # frame 200: GPS not valid, not counted
        [7, 70610, 0, 0, 1, 0, 80.0, *inside],  # frame 300: out of view, not counted
    ])
    report = tmp_path / "rank.json"
    assert detect_cli.main(["rank", "--data", str(tiny_dataset), "--videos", "7", "--detections", str(out),
                            "--out", str(report)]) == 0
    assert "50.0 % of frames" in capsys.readouterr().out
    figures = json.loads(report.read_text())
    assert (figures["frames"], figures["found"], figures["top"]) == (2, 1, 1)
    assert [b["frames"] for b in figures["bands"]] == [0, 1, 1, 0, 0]


def test_rank_names_what_is_missing(tiny_dataset, tmp_path, capsys):
    dets = tmp_path / "dets.csv"
    dets.write_text("video,frame,x1,y1,x2,y2,score,class_id,p_target\n")
    assert detect_cli.main(["rank", "--data", str(tiny_dataset), "--detections", str(dets)]) == 2
    assert "gt_1hz.csv" in capsys.readouterr().err
    assert detect_cli.main(["rank", "--data", str(tiny_dataset), "--detections", str(dets),
                            "--margin-px", "nan"]) == 2
    assert "--margin-px" in capsys.readouterr().err
