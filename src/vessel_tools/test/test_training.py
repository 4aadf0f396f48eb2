"""Training from GPS-generated labels: label generation, augmentation, the loss, a smoke training, the export."""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_tools.detect.training.augment import AugmentSettings, random_sample
from vessel_tools.detect.training.labels import (
    OTHER_CLASS,
    TARGET_CLASS,
    FrameLabels,
    LabelSettings,
    Projection,
    SizeModel,
    fit_size_model,
    frame_labels,
    project_gps,
    robust_line_fit,
)

SIZE = SizeModel((2400.0, 0.0), (1200.0, 0.0))


def test_robust_line_fit_ignores_outliers():
    rng = np.random.default_rng(1)
    x = rng.uniform(0.01, 0.2, 60)
    y = 2000.0 * x + 5.0 + rng.normal(0, 0.5, 60)
    y[:6] += 80.0  # boxes that merged the wake
    a, b = robust_line_fit(x, y)
    assert a == pytest.approx(2000.0, rel=0.05)
    assert b == pytest.approx(5.0, abs=2.0)


def test_the_vessel_takes_the_coco_box_width_and_the_gps_height():
    point, zp = (500.0, 430.0), 40.0  # size model: 60 x 30 px
    coco = np.array([[470.0, 420.0, 532.0, 436.0],   # the vessel's cabin: right width, too short
                     [900.0, 410.0, 960.0, 440.0],   # another boat
                     [100.0, 420.0, 110.0, 425.0]])  # a weak box: unknown
    scores = np.array([0.6, 0.5, 0.1])
    labels = frame_labels(Projection(1, 2, True, True, point, zp), coco, scores, SIZE, 0.65, (1280, 720),
                          LabelSettings())
    assert labels.status == "labelled" and labels.target_source == "coco"
    target = labels.boxes[labels.classes == TARGET_CLASS][0]
    np.testing.assert_allclose(target, [470.0, 430.0 - 0.65 * 30.0, 532.0, 430.0 + 0.35 * 30.0])
    np.testing.assert_allclose(labels.boxes[labels.classes == OTHER_CLASS], coco[1:2])
    np.testing.assert_allclose(labels.ignore, coco[2:3])


def test_without_a_matching_box_the_size_model_places_the_vessel():
    labels = frame_labels(Projection(1, 2, True, True, (640.0, 430.0), 40.0), np.array([[100.0, 400, 160, 440]]),
                          np.array([0.9]), SIZE, 0.65, (1280, 720), LabelSettings())
    assert labels.target_source == "size_model"
    np.testing.assert_allclose(labels.boxes[labels.classes == TARGET_CLASS][0], [610.0, 410.5, 670.0, 440.5])
    assert (labels.classes == OTHER_CLASS).sum() == 1


def _train_is_refused(options: list[str], message: str) -> None:
    """``detect train --out m.onnx OPTIONS`` stops with a DataError matching ``message`` before any work."""
    from vessel_tools.detect.training.train_cli import add_parser, cmd_train

    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())
    with pytest.raises(DataError, match=message):
        cmd_train(parser.parse_args(["train", "--out", "m.onnx", *options]))


def test_the_model_card_records_the_train_command_as_typed(monkeypatch):
    """``./vessel detect train`` reaches detect_cli through vessel_tools.cli, whose argv starts with ``detect``."""
    from vessel_tools.detect import detect_cli
    from vessel_tools.detect.training.train_cli import recorded_command

    seen = []
    parser = argparse.ArgumentParser()
    parser.add_argument("command")
    parser.add_argument("--videos")
    parser.set_defaults(func=lambda args: seen.append(recorded_command(args)) or 0)
    monkeypatch.setattr(detect_cli, "build_parser", lambda: parser)
    monkeypatch.setattr("sys.argv", ["vessel_tools/cli.py", "detect", "train", "--videos", "7-9"])
    assert detect_cli.main(["train", "--videos", "7-9"]) == 0
    assert seen == ["./vessel detect train --videos 7-9"]


def test_a_frame_between_fixes_further_apart_than_max_gps_gap_is_not_projected():
    """The vessel's position is interpolated only inside a gap no longer than ``max_gap_s``."""
    from types import SimpleNamespace

    from vessel_calib.camera_model import CameraModel
    from vessel_calib.camera_parameters import DEFAULT_CAMERA_PARAMETERS
    from vessel_calib.gps_track import GpsTrack

    camera = CameraModel.from_params(DEFAULT_CAMERA_PARAMETERS)
    start_lat, start_lon, _ = camera.screen_to_gps(600.0, 450.0)
    end_lat, end_lon, _ = camera.screen_to_gps(680.0, 450.0)
    dataset = SimpleNamespace(gps_track=lambda: GpsTrack([1000.0, 1008.0], [start_lat, end_lat], [start_lon, end_lon]))
    frames = [SimpleNamespace(video=8, frame=100, stamp=1002.0)]
    stale, = project_gps(dataset, camera, frames, max_gap_s=6.0)
    assert not stale.valid and not stale.in_view
    labelled, = project_gps(dataset, camera, frames, max_gap_s=10.0)
    assert labelled.valid and labelled.in_view
    assert 600.0 < labelled.point[0] < 640.0 and abs(labelled.point[1] - 450.0) < 5.0


def test_stale_gps_leaves_the_frame_out_and_out_of_view_keeps_other_boats():
    coco, scores = np.array([[100.0, 400, 160, 440]]), np.array([0.9])
    stale = frame_labels(Projection(1, 2, False, False), coco, scores, SIZE, 0.65, (1280, 720), LabelSettings())
    assert stale.status == "gps_invalid" and len(stale.boxes) == 0
    away = frame_labels(Projection(1, 2, True, False), coco, scores, SIZE, 0.65, (1280, 720), LabelSettings())
    assert away.status == "out_of_view" and away.classes.tolist() == [OTHER_CLASS]


def test_size_model_needs_enough_boxes_at_the_gps():
    projections = [Projection(1, i, True, True, (500.0, 430.0), 40.0) for i in range(3)]
    detections = {(1, i): (np.array([[470.0, 415, 530, 445]]), np.array([0.5])) for i in range(3)}
    with pytest.raises(DataError, match="too few"):
        fit_size_model(projections, detections, 0.65)


def test_size_model_height_is_the_tall_end_of_the_boxes_at_the_gps():
    rng = np.random.default_rng(3)
    projections, detections = [], {}
    for i in range(40):
        zp = float(rng.uniform(10, 80))
        w, h = 2400.0 / zp, (1200.0 if i % 4 == 0 else 700.0) / zp  # most boxes only the cabin
        point = (600.0, 430.0)
        projections.append(Projection(1, i, True, True, point, zp))
        detections[(1, i)] = (np.array([[600 - w / 2, 430 - 0.6 * h, 600 + w / 2, 430 + 0.4 * h]]), np.array([0.5]))
    model = fit_size_model(projections, detections, 0.65, height_quantile=0.9)
    assert model.width[0] == pytest.approx(2400.0, rel=0.05)
    assert model.height[0] == pytest.approx(1200.0, rel=0.05)


def _frame_with_boat(rng):
    image = np.full((360, 640, 3), (90, 110, 80), np.uint8)
    image[200:215, 300:340] = (250, 250, 250)
    labels = FrameLabels(1, 0, "labelled", np.array([[300.0, 200, 340, 215], [50.0, 190, 70, 205]]),
                         np.array([0, 1]), np.array([[500.0, 190, 520, 200]]), "coco", 30.0)
    return image, labels


def test_augmentation_is_fixed_by_the_seed_and_keeps_boxes_inside():
    image, labels = _frame_with_boat(None)
    settings = AugmentSettings(crop_wh=(256, 128))
    a = random_sample(image, labels, 150.0, np.random.default_rng(7), settings)
    b = random_sample(image, labels, 150.0, np.random.default_rng(7), settings)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.boxes, b.boxes)
    assert a.image.shape == (3, 128, 256)
    for sample in (random_sample(image, labels, 150.0, np.random.default_rng(s), settings) for s in range(30)):
        assert np.all(sample.boxes >= 0) and np.all(sample.boxes[:, [0, 2]] <= 256)
        assert np.all(sample.boxes[:, [1, 3]] <= 128)
        assert len(sample.boxes) == len(sample.classes)


def test_close_ups_show_the_vessel_larger_than_any_ordinary_crop_wherever_it_is():
    """The band reaches the image bottom, where a vessel passing close is several times larger than in training."""
    image, labels = _frame_with_boat(None)
    labels.boxes[0] = [300.0, 300, 340, 315]  # low in the band: near the camera
    ordinary = AugmentSettings(crop_wh=(256, 128), zoom_target=0.0)
    close_up = AugmentSettings(crop_wh=(256, 128), zoom_target=1.0, zoom_range=(2.0, 3.0))
    widest = 0.0
    for seed in range(20):
        sample = random_sample(image, labels, 150.0, np.random.default_rng(seed), ordinary)
        vessel = sample.boxes[sample.classes == 0]
        widest = max([widest, *(vessel[:, 2] - vessel[:, 0])])
        zoomed = random_sample(image, labels, 150.0, np.random.default_rng(seed), close_up)
        vessel = zoomed.boxes[zoomed.classes == 0]
        assert len(vessel) == 1, "the close-up lost the vessel"
        assert 2.0 * 40 - 1e-6 <= vessel[0, 2] - vessel[0, 0] <= 3.0 * 40 + 1e-6
    assert widest <= 1.6 * 40 + 1e-6


def test_the_scale_range_option_is_checked_and_defaults_to_the_augmentation_default():
    from vessel_tools.detect.training.train_cli import _scale_range

    assert _scale_range("0.4,1.6") == (0.4, 1.6)
    assert _scale_range(",".join(f"{v:g}" for v in AugmentSettings().scale_range)) == AugmentSettings().scale_range
    for wrong in ("1.6,0.4", "0,1", "a,b", "0.5", "nan,1"):
        with pytest.raises(DataError, match="--scale-range"):
            _scale_range(wrong)


def test_the_webcam_options_are_checked_before_any_work(tmp_path):
    _train_is_refused(["--webcam-scale-range", "3,1"], "--webcam-scale-range 3,1")
    _train_is_refused(["--webcam-repeats", "0"], "--webcam-repeats 0")
    _webcam_folder(tmp_path)
    from vessel_tools.detect.training.webcams import load_webcams

    with pytest.raises(DataError, match="no images"):
        load_webcams(tmp_path / "images", set())


def test_the_colour_jitter_option_is_checked_and_defaults_to_the_augmentation_default():
    from vessel_tools.detect.training.train_cli import _colour_jitter

    default = AugmentSettings()
    text = f"{default.hue_deg:g},{default.saturation:g},{default.value:g}"
    assert replace(default, **_colour_jitter(text)) == default
    assert _colour_jitter("0,0,0.35") == {"hue_deg": 0.0, "saturation": 0.0, "value": 0.35}
    for wrong in ("6,0.35", "a,b,c", "6,1.0,0.3", "-1,0.3,0.3", "nan,0.3,0.3", "6,0.3,inf"):
        with pytest.raises(DataError, match="--colour-jitter"):
            _colour_jitter(wrong)


def test_without_colour_jitter_the_crops_keep_their_colours_and_draw_the_same_crops():
    """Hue and saturation off: the crop is the same as with them, except for its brightness (paired comparisons)."""
    image, labels = _frame_with_boat(None)
    image = image.copy()
    image[..., 2] = 200  # a coloured scene: the red channel high
    plain = AugmentSettings(crop_wh=(256, 128), hue_deg=0.0, saturation=0.0, value=0.0)
    jittered = AugmentSettings(crop_wh=(256, 128))
    for seed in range(5):
        a = random_sample(image, labels, 150.0, np.random.default_rng(seed), plain)
        b = random_sample(image, labels, 150.0, np.random.default_rng(seed), jittered)
        np.testing.assert_array_equal(a.boxes, b.boxes)
        assert a.image.shape == b.image.shape
        np.testing.assert_allclose(np.median(a.image.reshape(3, -1), axis=1), (90, 110, 200), atol=3.0)  # HSV rounding
    jittered_medians = [np.median(random_sample(image, labels, 150.0, np.random.default_rng(seed),
                                                jittered).image.reshape(3, -1), axis=1) for seed in range(5)]
    assert max(float(np.abs(m - (90, 110, 200)).max()) for m in jittered_medians) > 5.0


def test_a_lower_scale_range_shows_the_boats_smaller():
    image, labels = _frame_with_boat(None)  # the vessel 40 px wide
    small = AugmentSettings(crop_wh=(256, 128), zoom_target=0.0, scale_range=(0.4, 0.5))
    for seed in range(20):
        sample = random_sample(image, labels, 150.0, np.random.default_rng(seed), small)
        vessel = sample.boxes[sample.classes == 0]
        assert len(vessel) == 1 and vessel[0, 2] - vessel[0, 0] <= 0.5 * 40 + 1e-6


# --------------------------------------------------------------------------------- PyTorch from here on
torch = pytest.importorskip("torch", reason="the training extra is not installed: ./vessel setup --train")
pytest.importorskip("onnx2torch", reason="the training extra is not installed: ./vessel setup --train")


class _TinyYolox(torch.nn.Module):
    """A YOLOX-shaped network (three stride levels, box/objectness/class maps concatenated) for the tests."""

    def __init__(self, classes: int = 3):
        super().__init__()
        self.stem = torch.nn.Conv2d(3, 8, 8, 8)
        self.down = torch.nn.ModuleList([torch.nn.Conv2d(8, 8, 2, 2), torch.nn.Conv2d(8, 8, 2, 2)])
        self.box = torch.nn.ModuleList([torch.nn.Conv2d(8, 4, 1) for _ in range(3)])
        self.obj = torch.nn.ModuleList([torch.nn.Conv2d(8, 1, 1) for _ in range(3)])
        self.cls = torch.nn.ModuleList([torch.nn.Conv2d(8, classes, 1) for _ in range(3)])

    def forward(self, x):
        features = [self.stem(x / 255.0)]
        for down in self.down:
            features.append(down(features[-1]))
        outs = []
        for f, box, obj, cls in zip(features, self.box, self.obj, self.cls, strict=True):
            level = torch.cat([box(f), torch.sigmoid(obj(f)), torch.sigmoid(cls(f))], 1)
            outs.append(level.reshape(1, level.shape[1], -1))
        return torch.cat(outs, 2).permute(0, 2, 1)


@pytest.fixture(scope="module")
def tiny_onnx(tmp_path_factory) -> Path:
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("tiny") / "tiny_yolox.onnx"
    with torch.no_grad():
        torch.onnx.export(_TinyYolox().eval(), (torch.zeros(1, 3, 64, 128),), str(path), input_names=["images"],
                          output_names=["output"], opset_version=17, dynamo=False)
    return path


def test_the_converted_graph_takes_any_input_size_and_new_classes(tiny_onnx):
    from vessel_tools.detect.training.model import TrainableYolox, flatten_levels

    model = TrainableYolox(tiny_onnx, ("vessel_of_interest", "vessel"), init_class=1)
    levels = model(torch.zeros(2, 3, 96, 160))
    assert [tuple(level[2].shape) for level in levels] == [(2, 2, 12, 20), (2, 2, 6, 10), (2, 2, 3, 5)]
    boxes, obj, cls, grids, strides = flatten_levels(levels)
    assert boxes.shape == (2, 240 + 60 + 15, 4) and cls.shape[-1] == 2
    assert strides[0] == 8 and strides[-1] == 32


def test_a_graph_without_yolox_heads_is_refused(tmp_path):
    from vessel_common.errors import ModelError
    from vessel_tools.detect.training.model import TrainableYolox

    path = tmp_path / "plain.onnx"
    torch.onnx.export(torch.nn.Conv2d(3, 4, 1), (torch.zeros(1, 3, 32, 32),), str(path), dynamo=False)
    with pytest.raises(ModelError, match="YOLOX head levels"):
        TrainableYolox(path, ("vessel_of_interest", "vessel"))


def test_simota_gives_a_box_the_anchors_near_it():
    from vessel_tools.detect.training.loss import simota_assign

    ys, xs = torch.meshgrid(torch.arange(8), torch.arange(16), indexing="ij")
    grids = torch.stack([xs.flatten(), ys.flatten()], 1).float()
    strides = torch.full((128,), 8.0)
    centres = (grids + 0.5) * 8
    pred = torch.cat([centres, torch.full((128, 2), 16.0)], 1)
    gt = torch.tensor([[40.0, 20.0, 60.0, 36.0]])
    fg, matched, ious = simota_assign(pred, torch.zeros(128), torch.zeros(128, 2), centres, strides, gt,
                                      torch.tensor([0]))
    assert 1 <= int(fg.sum()) <= 10
    chosen = centres[fg]
    assert torch.all((chosen[:, 0] > 40) & (chosen[:, 0] < 60) & (chosen[:, 1] > 20) & (chosen[:, 1] < 36))
    assert torch.all(ious[fg] > 0)


def _synthetic_set(count: int = 4):
    rng = np.random.default_rng(0)
    images, labels = {}, []
    for i in range(count):
        image = np.full((128, 256, 3), (90, 110, 80), np.uint8)
        x = int(rng.integers(40, 200))
        image[60:72, x : x + 24] = (250, 250, 250)
        images[(1, i)] = image
        labels.append(FrameLabels(1, i, "labelled", np.array([[x, 60.0, x + 24, 72.0]]), np.array([0]),
                                  np.zeros((0, 4)), "coco", 30.0))
    return images, labels


def _smoke_settings():
    from vessel_tools.detect.training.settings import TrainSettings

    return TrainSettings(epochs=2, batch_size=2, learning_rate=1e-3, val_every=1, input_hw=(128, 256),
                         band_margin_px=0.0, augment=AugmentSettings(crop_wh=(128, 64), top_jitter_px=4.0))


def test_smoke_training_exports_an_onnx_model_that_matches_pytorch(tiny_onnx, tmp_path):
    from vessel_detect.detector import OnnxModel
    from vessel_detect.network_input import letterbox
    from vessel_tools.detect.training.trainer import band_detector, save_model, train

    images, labels = _synthetic_set()
    references = {(lab.video, lab.frame): lab.boxes for lab in labels}
    lines = []
    model, result = train(tiny_onnx, labels, images, None, _smoke_settings(), references, "synthetic",
                          log=lines.append)
    assert len(result.history) == 2 and all(math.isfinite(h["loss"]) for h in result.history)
    assert "val recall" in lines[-1] and result.validation.frames == 4
    out = tmp_path / "model.onnx"
    probe, _ = letterbox(images[(1, 0)], (128, 256))
    diff = save_model(model, out, _smoke_settings(), probe, tolerance=1e-3)
    assert diff <= 1e-3
    assert out.with_suffix(".names").read_text().split() == ["vessel_of_interest", "vessel"]
    onnx_model = OnnxModel(out)
    assert onnx_model.class_names == ["vessel_of_interest", "vessel"] and onnx_model.input_hw == (128, 256)
    detections = band_detector(onnx_model, None, 0.0, (128, 256)).detect(images[(1, 0)])
    assert len(detections) > 0 and np.all(np.isfinite(detections.p_target))
    assert np.all(detections.p_target <= detections.scores + 1e-6)


def test_the_exported_model_runs_at_any_size(tiny_onnx, tmp_path):
    import onnxruntime as ort

    from vessel_detect.detector import DetectorConfig, OnnxModel, VesselDetector
    from vessel_tools.detect.training.model import TrainableYolox, export_onnx, record_input_size

    out = tmp_path / "free.onnx"
    export_onnx(TrainableYolox(tiny_onnx, ("vessel_of_interest", "vessel"), init_class=1), out, (352, 1280))
    out.with_suffix(".names").write_text("vessel_of_interest\nvessel\n")
    model = OnnxModel(out, intra_op_threads=1)
    assert model.free_input_size and model.input_hw == (352, 1280)
    config = DetectorConfig(mode="band", classes=("vessel_of_interest", "vessel"), score_threshold=0.0,
                            target_class="vessel_of_interest")
    detector = VesselDetector(model, config, horizon_y=400.0)
    (band,) = detector.windows((1280, 720))
    assert (band.window.y0, band.window.y1) == (360, 720)
    frame = np.random.default_rng(0).integers(0, 255, (720, 1280, 3), dtype=np.uint8)
    detections = detector.detect(frame)
    assert len(detections) > 0 and np.all(np.isfinite(detections.boxes_xyxy))
    assert np.all(np.isfinite(detections.p_target)) and np.all(detections.boxes_xyxy[:, 3] <= 720)
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    for height, width in ((96, 2560), (192, 640)):  # any multiple of 32
        output = session.run(None, {"images": np.full((1, 3, height, width), 114.0, np.float32)})[0]
        assert output.shape == (1, sum((height // s) * (width // s) for s in (8, 16, 32)), 7)
    # A model exported at a fixed size is freed in place; its usual size stays what it was.
    fixed = tmp_path / "fixed.onnx"
    fixed.write_bytes(tiny_onnx.read_bytes())
    fixed.with_suffix(".names").write_text("a\nb\nc\n")
    assert OnnxModel(fixed).free_input_size is False
    record_input_size(fixed, (64, 128))
    freed = OnnxModel(fixed)
    assert freed.free_input_size and freed.input_hw == (64, 128)


def test_the_same_seed_gives_the_same_training(tiny_onnx):
    from vessel_tools.detect.training.trainer import train

    images, labels = _synthetic_set()
    first = train(tiny_onnx, labels, images, None, _smoke_settings(), log=lambda m: None)[1].history
    second = train(tiny_onnx, labels, images, None, _smoke_settings(), log=lambda m: None)[1].history
    for a, b in zip(first, second, strict=True):
        assert a["loss"] == pytest.approx(b["loss"], rel=1e-4)


def test_training_without_labels_is_refused(tiny_onnx):
    from vessel_tools.detect.training.trainer import train

    with pytest.raises(DataError, match="no training frames"):
        train(tiny_onnx, [], {}, None, _smoke_settings(), log=lambda m: None)


def _webcam_folder(root: Path) -> None:
    """A Shore Livecams-like folder: two webcams, train and test splits, boats (class 2) and a person (0)."""
    import cv2

    for split, cams in (("train", ("camA", "camB")), ("test", ("camA",))):
        (root / "images" / split).mkdir(parents=True)
        (root / "labels" / split).mkdir(parents=True)
        for i, cam in enumerate(cams):
            image = np.full((180, 320, 3), (100, 90, 70), np.uint8)
            image[80:88, 40 + 30 * i : 52 + 30 * i] = 255
            cv2.imwrite(str(root / "images" / split / f"{cam}_{i}.jpg"), image)
            (root / "labels" / split / f"{cam}_{i}.txt").write_text(
                f"2 {(46 + 30 * i) / 320:.5f} {84 / 180:.5f} {12 / 320:.5f} {8 / 180:.5f}\n0 0.5 0.5 0.1 0.1\n")


def test_webcam_images_become_vessel_boxes_and_held_out_webcams_are_left_out(tmp_path):
    from vessel_tools.detect.training.webcams import WEBCAM_SOURCE, load_webcams, webcam_sample

    _webcam_folder(tmp_path)
    labels, images, counts = load_webcams(tmp_path, {"camB"})
    assert counts == {"camA": 2} and all(lab.target_source == WEBCAM_SOURCE for lab in labels)
    assert all(len(lab.boxes) == 1 and lab.classes.tolist() == [OTHER_CLASS] and lab.video < 0 for lab in labels)
    assert labels[0].boxes[0] == pytest.approx([40, 80, 52, 88], abs=0.1)
    rng = np.random.default_rng(0)
    sample = webcam_sample(images[(labels[0].video, labels[0].frame)], labels[0], rng, AugmentSettings())
    assert sample.image.shape == (3, 352, 640) and set(sample.classes.tolist()) <= {OTHER_CLASS}
    with pytest.raises(DataError, match="no such webcam"):
        load_webcams(tmp_path, {"camZ"})


def test_webcam_repeats_crop_each_webcam_image_that_often_an_epoch(tmp_path):
    from vessel_tools.detect.training.train_cli import _webcam_labels

    _webcam_folder(tmp_path)
    once, twice = ({}, {})
    for images, repeats in ((once, 1), (twice, 2)):
        args = argparse.Namespace(webcams=str(tmp_path), webcam_holdout="camB", webcam_repeats=repeats)
        labels = _webcam_labels(args, images)
        assert len(labels) == 2 * repeats and args.webcam_counts == {"camA": 2}
        assert {(lab.video, lab.frame) for lab in labels} == set(images)
    assert once.keys() == twice.keys() and len(once) == 2
    from vessel_tools.detect.training.model_card import _webcams

    card = "".join(_webcams({"folder": str(tmp_path), "images": {"camA": 2}, "held_out": "camB", "repeats": 2}))
    assert "camA 2 (images each), each image cropped 2 time(s) an epoch" in card


def test_smoke_training_with_webcam_images(tiny_onnx, tmp_path):
    from vessel_tools.detect.training.trainer import train
    from vessel_tools.detect.training.webcams import load_webcams

    _webcam_folder(tmp_path)
    images, labels = _synthetic_set(2)
    webcam_labels, webcam_images, _ = load_webcams(tmp_path, set())
    images.update(webcam_images)
    settings = replace(_smoke_settings(), epochs=1)
    model, result = train(tiny_onnx, labels + webcam_labels, images, None, settings, log=lambda m: None)
    assert len(result.history) == 1 and math.isfinite(result.history[0]["loss"])
    assert result.history[0]["foreground_per_image"] > 0
