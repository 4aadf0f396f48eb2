"""The label-free calibration's search on synthetic cameras: found when the data allow, refused when they do not."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from vessel_calib import geodesy
from vessel_common.errors import CalibrationError
from vessel_fixtures.calib_synthetic import CAMERA_LAT, CAMERA_LON, pinhole_camera, search_frames
from vessel_tools.calib.box_anchor import measure_box_anchor
from vessel_tools.calib.gps_association import FrameBoxes, SearchOptions, associate_and_calibrate

FAST = SearchOptions(hypotheses=20000, candidates_refined=4)


def _grid_error_px(found, truth) -> float:
    xw, yw = np.meshgrid(np.linspace(-150, 150, 7), np.linspace(40, 400, 7))
    bearing_ok = np.abs(np.degrees(np.arctan2(xw, yw)) - truth.heading_deg) < 25
    x0, y0, ok0 = truth.world_to_screen(xw[bearing_ok], yw[bearing_ok])
    x1, y1, ok1 = found.world_to_screen(xw[bearing_ok], yw[bearing_ok])
    inside = ok0 & ok1 & truth.in_image(x0, y0)
    return float(np.max(np.hypot(x1 - x0, y1 - y0)[inside]))


@pytest.mark.parametrize("seed", [0, 1])
def test_search_recovers_the_camera_through_clutter_misses_and_dropouts(seed):
    truth = pinhole_camera(height_m=4.0, heading_deg=76.0, tilt_down_deg=-1.0, focal_px=950.0, K1=-3.5e-7)
    frames = search_frames(truth, seed=seed)
    found = associate_and_calibrate(frames, CAMERA_LAT, CAMERA_LON, options=FAST)
    model = found.result.model
    # The box noise is 1 px; the tolerances are a few times what that noise moves a fit of ~60 pairs.
    assert abs(model.heading_deg - truth.heading_deg) < 0.2
    assert abs(model.K1 - truth.K1) < 5e-8
    assert _grid_error_px(model, truth) < 3.0
    assert math.isclose(model.pinhole().height_m, 4.0, rel_tol=0.1)
    # Every associated box is the vessel's: no clutter box and no post was taken for it.
    vessel_boxes = found.boxes()
    assert found.associated >= 40
    assert np.all(vessel_boxes[:, 1] != 650.0)
    assert "camera found: height" in "\n".join(found.report_lines())


def test_search_refuses_a_track_that_never_comes_into_view():
    truth = pinhole_camera(height_m=4.0, heading_deg=76.0, tilt_down_deg=-1.0, focal_px=950.0, K1=-3.5e-7)
    frames = search_frames(truth, seed=0, bearing_offset_deg=180.0)
    with pytest.raises(CalibrationError, match="no camera puts the vessel.s GPS track on detected boats|only "
                                               r"\d frames could be associated with a detected boat"):
        associate_and_calibrate(frames, CAMERA_LAT, CAMERA_LON, options=FAST)


def test_search_refuses_a_camera_position_1_km_off():
    truth = pinhole_camera(height_m=4.0, heading_deg=76.0, tilt_down_deg=-1.0, focal_px=950.0, K1=-3.5e-7)
    frames = search_frames(truth, seed=0)
    wrong_lat, wrong_lon = geodesy.local_to_gps(np.array([0.0]), np.array([1000.0]), CAMERA_LAT, CAMERA_LON)
    with pytest.raises(CalibrationError, match=r"stand (9[5-9]\d|10[0-4]\d) m from the given camera position"):
        associate_and_calibrate(frames, float(wrong_lat[0]), float(wrong_lon[0]), options=FAST)


def test_search_refuses_frames_with_no_boats_and_too_few_frames():
    truth = pinhole_camera()
    frames = search_frames(truth, seed=0)
    empty = [FrameBoxes(f.video, f.frame, f.stamp, f.lat, f.lon, np.zeros((0, 4)), np.zeros(0)) for f in frames]
    with pytest.raises(CalibrationError, match="found no boat"):
        associate_and_calibrate(empty, CAMERA_LAT, CAMERA_LON, options=FAST)
    few = [f for f in frames if math.isfinite(f.lat)][:8]
    with pytest.raises(CalibrationError, match="only 8 frames with a GPS fix"):
        associate_and_calibrate(few, CAMERA_LAT, CAMERA_LON, options=FAST)


def test_search_refuses_associations_all_at_one_range():
    truth = pinhole_camera(height_m=4.0, heading_deg=76.0, tilt_down_deg=-1.0, focal_px=950.0, K1=-3.5e-7)
    frames = search_frames(truth, seed=0, clutter=0)
    ranges = [math.hypot(*geodesy.gps_to_local(f.lat, f.lon, CAMERA_LAT, CAMERA_LON)) for f in frames]
    one_range = [f for f, r in zip(frames, ranges, strict=True) if 150 < r < 200]
    with pytest.raises(CalibrationError, match="all at about one range"):
        associate_and_calibrate(one_range, CAMERA_LAT, CAMERA_LON,
                                options=SearchOptions(hypotheses=5000, min_associations=6))


def test_search_options_are_checked():
    with pytest.raises(CalibrationError, match="box_anchor"):
        SearchOptions(box_anchor=1.5).checked()
    with pytest.raises(CalibrationError, match="min_associations"):
        SearchOptions(min_associations=3).checked()


def _graph_boxes(camera, frames, anchor: float, height_px: float = 20.0):
    """Boxes of another detector: the vessel's GPS ``anchor`` of the way down (p 0.9), and a boat beside it (p 0.1)."""
    boxes, probabilities = [], []
    for f in frames:
        if not math.isfinite(f.lat):
            boxes.append(np.zeros((0, 4)))
            probabilities.append(np.zeros(0))
            continue
        xs, ys, _ = camera.gps_to_screen(f.lat, f.lon)
        xs, ys = float(xs), float(ys)
        vessel = [xs - 15, ys - anchor * height_px, xs + 15, ys + (1 - anchor) * height_px]
        beside = [xs - 10, ys - 5, xs + 10, ys + 5]  # a likelier box position, but another boat
        boxes.append(np.array([vessel, beside]))
        probabilities.append(np.array([0.9, 0.1]))
    return boxes, probabilities


def test_the_box_anchor_of_another_detector_is_measured_from_the_gps():
    truth = pinhole_camera(height_m=4.0, heading_deg=76.0, tilt_down_deg=-1.0, focal_px=950.0, K1=-3.5e-7)
    frames = search_frames(truth, seed=3)
    gps = [(f.lat, f.lon) for f in frames]
    boxes, probabilities = _graph_boxes(truth, frames, anchor=0.55)
    found = measure_box_anchor(truth, gps, None, boxes, probabilities)
    seen = [math.isfinite(f.lat) and truth.in_image(*truth.gps_to_screen(f.lat, f.lon)[:2]) for f in frames]
    assert found.anchor == pytest.approx(0.55, abs=1e-6) and found.frames == sum(seen)
    # Of the boxes around the GPS that the detector calls the vessel of interest, the likeliest gives the anchor ...
    likelier_beside = [np.where(p > 0.5, 0.6, 0.95) for p in probabilities]
    assert measure_box_anchor(truth, gps, None, boxes, likelier_beside).anchor == pytest.approx(0.5, abs=1e-6)
    # ... and a box it does not call the vessel of interest never counts.
    assert measure_box_anchor(truth, gps, None, boxes, [np.full_like(p, 0.1) for p in probabilities]) is None
    with pytest.raises(CalibrationError, match="one of each per frame"):
        measure_box_anchor(truth, gps[:-1], None, boxes, probabilities)


# --------------------------------------------------------------------------- the calibrate command without labels
def _cli(args, capsys):
    from vessel_tools import calibrate as calibrate_tool

    status = calibrate_tool.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return status, out, err


def _truth():
    return pinhole_camera(height_m=4.0, heading_deg=76.0, tilt_down_deg=-1.0, focal_px=950.0, K1=-3.5e-7)


def test_calibrate_a_folder_without_labels(tmp_path, capsys):
    from vessel_calib.params import load_camera_yaml
    from vessel_fixtures.calib_synthetic import write_search_folder

    detections = write_search_folder(tmp_path / "data", search_frames(_truth(), seed=3))
    out = tmp_path / "cal" / "camera.yaml"
    status, stdout, err = _cli(["--data", tmp_path / "data", "--videos", "1-5", "--detections", detections,
                                "--hypotheses", 20000, "--out", out], capsys)
    assert status == 0, err
    assert "without labels" in stdout and "association:" in stdout and "camera found: height" in stdout
    model = load_camera_yaml(out)
    assert abs(model.heading_deg - 76.0) < 0.2
    assert out.with_suffix(".png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_a_folder_without_labels_gets_the_graph_detector_s_box_anchor(tmp_path, capsys):
    """The search reads its detector's boxes at 0.65; the graph's detector sits the GPS 0.55 down its boxes."""
    from vessel_calib.params import load_camera_yaml
    from vessel_fixtures.calib_synthetic import write_search_folder

    frames = search_frames(_truth(), seed=3)
    detections = write_search_folder(tmp_path / "data", frames)
    boxes, probabilities = _graph_boxes(_truth(), frames, anchor=0.55)
    rows = ["video,frame,x1,y1,x2,y2,score,class_id,p_target"]
    for f, frame_boxes, frame_p in zip(frames, boxes, probabilities, strict=True):
        rows += [f"{f.video + 1},{f.frame * 100},{b[0]:.2f},{b[1]:.2f},{b[2]:.2f},{b[3]:.2f},0.8,0,{p}"
                 for b, p in zip(frame_boxes, frame_p, strict=True)]
    graph = tmp_path / "graph.csv"
    graph.write_text("\n".join(rows) + "\n")
    common = ["--data", tmp_path / "data", "--videos", "1-5", "--detections", detections, "--hypotheses", 20000]
    status, stdout, err = _cli([*common, "--graph-detections", graph, "--out", tmp_path / "a.yaml"], capsys)
    assert status == 0, err
    assert "the vessel's GPS falls 0.5" in stdout and "the search read its own boxes at 0.65" in stdout
    assert load_camera_yaml(tmp_path / "a.yaml").box_anchor == pytest.approx(0.55, abs=0.03)
    assert "of the way down the graph detector's boxes through H" in (tmp_path / "a.yaml").read_text()
    common[-1] = 5000  # quicker; the camera found is not what the rest is about
    status, stdout, err = _cli([*common, "--graph-detections", graph, "--keep-box-anchor", "--no-picture",
                                "--out", tmp_path / "b.yaml"], capsys)
    assert status == 0 and load_camera_yaml(tmp_path / "b.yaml").box_anchor == 0.65
    # Frames the graph's detector cannot read (this folder has no images): said, and the search's anchor kept.
    status, stdout, err = _cli([*common, "--no-picture", "--out", tmp_path / "c.yaml"], capsys)
    assert status == 0, err
    assert "box_anchor stays 0.65" in stdout and "could not be read" in err
    assert load_camera_yaml(tmp_path / "c.yaml").box_anchor == 0.65


def test_a_mistyped_graph_detections_file_is_refused_before_the_search(tmp_path, capsys):
    from vessel_fixtures.calib_synthetic import write_search_folder

    detections = write_search_folder(tmp_path / "data", search_frames(_truth(), seed=3))
    out = tmp_path / "cal" / "camera.yaml"
    status, stdout, err = _cli(["--data", tmp_path / "data", "--videos", "1-5", "--detections", detections,
                                "--graph-detections", tmp_path / "grpah.csv", "--out", out], capsys)
    assert status == 2 and err.startswith("error: --graph-detections") and "no such file" in err
    assert "searching" not in stdout and not out.parent.exists()


@pytest.mark.parametrize("case, match", [
    ("behind", r"no camera puts the vessel's GPS track on detected boats|only \d frames could be associated"),
    ("no boats", "found no boat"),
    ("camera 1 km off", r"stand (9[5-9]\d|10[0-4]\d) m from the given camera position"),
    ("too few frames", "only 8 frames with a GPS fix"),
])
def test_calibrate_without_labels_refuses_bad_input(tmp_path, capsys, case, match):
    from vessel_fixtures.calib_synthetic import write_search_folder

    frames = search_frames(_truth(), seed=3, bearing_offset_deg=180.0 if case == "behind" else 0.0)
    if case == "too few frames":
        frames = [f for f in frames if math.isfinite(f.lat)][:8]
    camera_lat = CAMERA_LAT + (1000.0 / 111195.0 if case == "camera 1 km off" else 0.0)
    detections = write_search_folder(tmp_path / "data", frames, camera_lat=camera_lat)
    if case == "no boats":
        detections.write_text(detections.read_text().splitlines()[0] + "\n")
    out = tmp_path / "cal" / "camera.yaml"
    status, stdout, err = _cli(["--data", tmp_path / "data", "--videos", "1-5", "--detections", detections,
                                "--hypotheses", 5000, "--out", out], capsys)
    assert status == 2, stdout
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1
    assert re.search(match, err), err
    assert not out.parent.exists()


def test_calibrate_a_video_without_boats_is_refused_and_writes_nothing(tmp_path, capsys, model_path):
    import cv2

    video = tmp_path / "sea.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 1.0, (320, 180))
    for _ in range(14):
        writer.write(np.full((180, 320, 3), 110, dtype=np.uint8))
    writer.release()
    track = tmp_path / "boat.csv"
    track.write_text("stamp,lat,lon\n" + "".join(f"{1.6e9 + t},{CAMERA_LAT + 0.001 + 1e-5 * t},{CAMERA_LON + 0.002}\n"
                                                 for t in range(-5, 25)))
    out = tmp_path / "cal" / "camera.yaml"
    status, stdout, err = _cli(["--video", video, "--start-utc", "1600000000", "--gps", track, "--every", 1,
                                "--camera-lat", CAMERA_LAT, "--camera-lon", CAMERA_LON, "--out", out], capsys)
    assert status == 2, stdout
    assert "14 frames of" in stdout and "found no boat" in err
    assert not out.parent.exists()
    status, _, err = _cli(["--video", video, "--start-utc", "2001-01-01T00:00:00Z", "--gps", track, "--camera-lat",
                           CAMERA_LAT, "--camera-lon", CAMERA_LON, "--out", out], capsys)
    assert status == 2 and "no frame of" in err and "--start-utc" in err
