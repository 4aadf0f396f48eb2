"""``detect images`` and ``detect score-images``: unusable files, the CSV, the matching and the figures."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from vessel_common.paths import repo_file
from vessel_detect.detector import Detections
from vessel_tools.detect import image_cli
from vessel_tools.detect.detect_cli import main
from vessel_tools.detect.image_scores import average_precision, match_image, score_images


class _FakeDetector:
    """Finds the white rectangles of the test images, scoring each by its brightness."""

    config = SimpleNamespace(mode="tiled", score_threshold=0.1)
    model = SimpleNamespace(path=Path("fake.onnx"))

    def detect(self, image):
        mask = (image.min(axis=2) > 200).astype(np.uint8)
        count, _, stats, _ = cv2.connectedComponentsWithStats(mask)
        boxes = np.array([[x, y, x + w, y + h] for x, y, w, h, _ in stats[1:]], float).reshape(-1, 4)
        scores = np.full(len(boxes), 0.9)
        return Detections(boxes, scores, np.ones(len(boxes), np.int64), ["vessel_of_interest", "vessel"],
                          np.zeros(len(boxes)))


def _folder(tmp_path: Path) -> tuple[Path, Path]:
    images, labels = tmp_path / "images", tmp_path / "labels"
    images.mkdir()
    labels.mkdir()
    for name, boxes in (("camA_1", [(100, 50, 30, 12)]), ("camA_2", [(300, 200, 60, 20), (40, 40, 10, 6)]),
                        ("camB_1", [])):
        image = np.full((360, 640, 3), (90, 110, 80), np.uint8)
        lines = []
        for x, y, w, h in boxes:
            image[y : y + h, x : x + w] = 255
            lines.append(f"2 {(x + w / 2) / 640:.6f} {(y + h / 2) / 360:.6f} {w / 640:.6f} {h / 360:.6f}")
        lines.append("0 0.5 0.5 0.1 0.1")  # a person: not a boat
        cv2.imwrite(str(images / f"{name}.jpg"), image)
        (labels / f"{name}.txt").write_text("\n".join(lines) + "\n")
    (images / "empty.jpg").write_bytes(b"")
    (images / "broken.jpg").write_text("not an image")
    cv2.imwrite(str(images / "grey.png"), np.zeros((100, 100), np.uint8))
    cv2.imwrite(str(images / "tiny.png"), np.zeros((8, 300, 3), np.uint8))
    return images, labels


def test_images_writes_every_box_and_names_each_unusable_file(tmp_path, monkeypatch, capsys):
    images, _ = _folder(tmp_path)
    monkeypatch.setattr(image_cli, "whole_image_detector", lambda params: _FakeDetector())
    out = tmp_path / "boxes.csv"
    assert main(["images", "--images", str(images), "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    for name, why in (("empty.jpg", "empty file"), ("broken.jpg", "unreadable"), ("grey.png", "grayscale"),
                      ("tiny.png", "odd size")):
        assert f"{name}: {why}" in err
    assert "4 file(s) skipped" in err and "Traceback" not in err
    rows = out.read_text().splitlines()
    assert rows[0] == "file,x1,y1,x2,y2,score,class_id,p_target"
    assert sorted(r.split(",")[0] for r in rows[1:]) == ["camA_1.jpg", "camA_2.jpg", "camA_2.jpg"]


def test_score_images_finds_every_boat_by_width_and_reads_a_saved_run(tmp_path, monkeypatch, capsys):
    images, labels = _folder(tmp_path)
    monkeypatch.setattr(image_cli, "whole_image_detector", lambda params: _FakeDetector())
    out = tmp_path / "figures.json"
    assert main(["score-images", "--images", str(images), "--labels", str(labels), "--only", "camA",
                 "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "2 images" in printed and "<20 px" in printed
    figures = json.loads(out.read_text())["figures"]
    assert figures["all"]["boxes"] == 3 and figures["all"]["recall"] == 1.0 and figures["all"]["ap"] == 1.0
    assert figures["<20 px"]["boxes"] == 1 and figures[">50 px"]["boxes"] == 1 and figures["20-50 px"]["boxes"] == 1
    saved = tmp_path / "boxes.csv"
    main(["images", "--images", str(images), "--out", str(saved), "--quiet"])
    assert main(["score-images", "--images", str(images), "--labels", str(labels), "--detections", str(saved),
                 "--out", str(out), "--quiet"]) == 0
    assert json.loads(out.read_text())["figures"]["all"]["recall"] == 1.0


@pytest.mark.parametrize("argv, message", [
    (["images", "--images", "/no/such/folder", "--out", "x.csv"], "no such folder"),
    (["score-images", "--images", "IMAGES", "--labels", "/no/such/labels"], "--labels /no/such/labels"),
])
def test_bad_input_is_one_line(tmp_path, capsys, argv, message):
    images, _ = _folder(tmp_path)
    argv = [str(images) if a == "IMAGES" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_matching_is_greedy_by_score_one_box_each_and_ap_ranks_by_score():
    truth = np.array([[0, 0, 10, 10], [100, 100, 140, 120]], float)
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [300, 300, 310, 310]], float)
    assert list(match_image(boxes, np.array([0.5, 0.9, 0.8]), truth)) == [-1, 0, -1]
    assert average_precision(np.array([0.9, 0.8]), np.array([True, False]), 2) == pytest.approx(0.5)
    assert average_precision(np.array([0.9, 0.8]), np.array([False, True]), 2) == pytest.approx(0.25)
    figures = score_images({"a": (boxes, np.array([0.5, 0.9, 0.8]))}, {"a": truth}, 0.6)
    assert figures["all"]["recall"] == 0.5 and figures["all"]["precision"] == 0.5
    assert figures["<20 px"]["detections"] == 2 and figures["20-50 px"]["recall"] == 0.0


def test_the_any_camera_preset_searches_the_whole_height_without_a_calibration():
    from vessel_detect.detector import CHALLENGE_HORIZON_Y, VesselDetector
    from vessel_detect.detector_params import detector_config, load_params_file

    values, camera = load_params_file(repo_file("config/detector_any_camera.yaml"))
    assert camera is None and values["size_prior.dimension"] == "none" and not values["appearance_model"]
    model = SimpleNamespace(class_names=[*values["classes"], "other"], input_hw=(352, 1280))
    # What the node builds with no camera.* parameters: the challenge camera's horizon, opened by the margin.
    detector = VesselDetector(model, detector_config(values), CHALLENGE_HORIZON_Y, (1280, 720))
    assert detector.band((1920, 1080)) == (0.0, 1080.0) and detector.band((1280, 720)) == (0.0, 720.0)


def test_the_shipped_preset_finds_the_boats_of_a_webcam_it_never_trained_on(shorecams_dir):
    """The preset's model and tiling on held-out webcam images: most boats 20 px wide or more are found."""
    from vessel_tools.detect.image_folder import read_image, read_yolo_labels, whole_image_detector

    detector = whole_image_detector(str(repo_file("config/detector_any_camera.yaml")))
    labels = [str(shorecams_dir / "labels" / split) for split in ("train", "test")]
    found = wanted = images = 0
    held_out = [path for split in ("test", "train") for webcam in ("hyovmh0t", "519srew5")
                for path in sorted((shorecams_dir / "images" / split).glob(f"{webcam}*"))]
    for path in held_out:
        image, problem = read_image(path)
        assert image is not None, problem
        truth = read_yolo_labels(labels, path.name, (image.shape[1], image.shape[0]), 2)
        truth = truth[(truth[:, 2] - truth[:, 0]) >= 20] if truth is not None else np.zeros((0, 4))
        if not len(truth):
            continue
        dets = detector.detect(image)
        found += int((match_image(dets.boxes_xyxy, dets.scores, truth) >= 0).sum())
        wanted += len(truth)
        images += 1
        if images == 4:
            break
    assert wanted >= 3, "too few labelled boats of 20 px or more in the held-out webcams"
    assert found >= 0.6 * wanted, f"{found} of {wanted} boats of 20 px or more found"
