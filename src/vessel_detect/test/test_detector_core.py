"""The detector core end to end.

Model checks, every output layout through a synthetic ONNX model with known boxes, the band and tiles, masks, and
the real YOLOX-Nano on a real challenge frame (the letterbox: test_network_input.py).
"""

import numpy as np
import pytest

from vessel_common.errors import ModelError, VesselError
from vessel_detect.decoders import grid_point_count
from vessel_detect.detector import (
    Detections,
    DetectorConfig,
    OnnxModel,
    VesselDetector,
)
from vessel_detect.detector_params import build_detector, default_values
from vessel_fixtures.onnx_synthetic import write_constant_output_model

POINTS = grid_point_count((416, 416))
BOAT = 8


def _yolox_output_with_boat(cx, cy, w, h, score=0.9, stride=16):
    out = np.zeros((1, POINTS, 85), np.float32)
    out[0, :, 2:4] = -5
    gx, gy = int(cx // stride), int(cy // stride)
    row = (52 * 52 if stride == 16 else 0) + gy * (416 // stride) + gx
    out[0, row, :5] = [cx / stride - gx, cy / stride - gy, np.log(w / stride), np.log(h / stride), 1.0]
    out[0, row, 5 + BOAT] = score
    return out


def _model(tmp_path, output, name="m.onnx", **kwargs) -> OnnxModel:
    path = write_constant_output_model(tmp_path / name, output, **kwargs)
    return OnnxModel(path, intra_op_threads=1)


@pytest.mark.parametrize("layout", ["yolox", "yolov5", "yolov8"])
def test_every_layout_end_to_end_in_full_frame_pixels(tmp_path, layout):
    # A boat at (208, 104) 64x32 in network pixels; a 1280x720 frame is scaled by 416/1280 into the network.
    cx, cy, w, h = 208.0, 104.0, 64.0, 32.0
    if layout == "yolox":
        output = _yolox_output_with_boat(cx, cy, w, h, 0.9)
    elif layout == "yolov5":
        output = np.zeros((1, 3 * POINTS, 85), np.float32)
        output[0, 42, :5] = [cx, cy, w, h, 1.0]
        output[0, 42, 5 + BOAT] = 0.9
    else:
        output = np.zeros((1, 84, POINTS), np.float32)
        output[0, :4, 42] = [cx, cy, w, h]
        output[0, 4 + BOAT, 42] = 0.9
    model = _model(tmp_path, output)
    assert model.layout.value == layout
    assert model.class_names[BOAT] == "boat"
    detector = VesselDetector(model, DetectorConfig(mode="full", exclusion_polygons=()), horizon_y=None)
    result = detector.detect(np.zeros((720, 1280, 3), np.uint8))
    assert len(result) == 1
    scale = 1280 / 416
    np.testing.assert_allclose(result.boxes_xyxy[0], np.array([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2]) * scale,
                               atol=1e-2)
    assert result.scores[0] == pytest.approx(0.9)
    assert result.labels() == ["boat"]


def test_a_model_whose_input_is_not_a_3_channel_image_is_refused(tmp_path):
    path = write_constant_output_model(tmp_path / "gray.onnx", _yolox_output_with_boat(100, 100, 20, 20),
                                       input_shape=[1, 1, 416, 416])
    with pytest.raises(ModelError, match="3-channel"):
        OnnxModel(path)


def test_a_file_that_is_not_onnx_is_refused_naming_it(tmp_path):
    path = tmp_path / "broken.onnx"
    path.write_bytes(b"\x00\x01 definitely not a model")
    with pytest.raises(ModelError, match="broken.onnx.*not a usable ONNX model"):
        OnnxModel(path)


def test_unknown_class_names_and_bad_configuration_are_refused(tmp_path):
    model = _model(tmp_path, _yolox_output_with_boat(100, 100, 20, 20))
    with pytest.raises(ModelError, match="submarine"):
        VesselDetector(model, DetectorConfig(classes=("submarine",)))
    with pytest.raises(VesselError, match="mode"):
        VesselDetector(model, DetectorConfig(mode="sideways"))
    with pytest.raises(VesselError, match="tile_scales"):
        VesselDetector(model, DetectorConfig(tile_scales=(0.0,)))


def test_class_names_file_next_to_the_model_must_match_the_class_count(tmp_path):
    (tmp_path / "classes.txt").write_text("boat\nbuoy\n")
    path = write_constant_output_model(tmp_path / "two.onnx", _yolox_output_with_boat(100, 100, 20, 20))
    with pytest.raises(ModelError, match="80 classes but 2 class names"):
        OnnxModel(path)


def test_band_and_tiles_follow_the_horizon_and_scale_with_the_frame(tmp_path):
    model = _model(tmp_path, np.zeros((1, POINTS, 85), np.float32))
    detector = VesselDetector(model, DetectorConfig(), horizon_y=400.0, reference_wh=(1280, 720))
    assert detector.band((1280, 720)) == (360.0, 720.0)
    assert detector.band((640, 360)) == (180.0, 360.0)
    windows = detector.windows((1280, 720))
    assert windows[0].fixed_scale is False and (windows[0].window.y0, windows[0].window.y1) == (360, 720)
    tiles = [run.window for run in windows if run.fixed_scale]
    assert all(w.x1 - w.x0 == 333 for w in tiles)
    assert min(w.y0 for w in tiles) == 360 and max(w.y1 for w in tiles) == 720
    assert VesselDetector(model, DetectorConfig(mode="band"), 400.0).windows((1280, 720))[0].window.y0 == 360
    assert len(VesselDetector(model, DetectorConfig(mode="full"), 400.0).windows((1280, 720))) == 1


def test_the_usual_input_size_of_a_free_size_model_comes_from_its_metadata():
    from types import SimpleNamespace

    from vessel_detect.detector import _nominal_input_size

    def session(metadata):
        return SimpleNamespace(get_modelmeta=lambda: SimpleNamespace(custom_metadata_map=metadata))

    assert _nominal_input_size(session({"input_size": "1280x352"}), "m.onnx") == (1280, 352)
    assert _nominal_input_size(session({}), "m.onnx") is None
    with pytest.raises(ModelError, match="input_size='wide' is not WIDTHxHEIGHT.*re-export"):
        _nominal_input_size(session({"input_size": "wide"}), "m.onnx")
    with pytest.raises(ModelError, match="must be positive multiples of 32"):
        _nominal_input_size(session({"input_size": "1280x350"}), "m.onnx")


def test_detections_above_the_band_and_inside_masks_are_dropped(tmp_path):
    # Tiles at scale 1 are 416 px high: with the band at 360-720 they start at y = 304, above the band. A
    # constant network output puts the same box in every tile.
    config = DetectorConfig(tile_scales=(1.0,), global_pass=False, exclusion_polygons=())
    frame = np.zeros((720, 1280, 3), np.uint8)
    high = VesselDetector(_model(tmp_path, _yolox_output_with_boat(200, 20, 40, 20)), config, 400.0)
    assert {(run.window.y0, run.window.y1) for run in high.windows((1280, 720))} == {(304, 720)}
    assert len(high.detect(frame)) == 0  # frame y 314-334: its bottom is above the band top (360)
    low = VesselDetector(_model(tmp_path, _yolox_output_with_boat(200, 200, 40, 20), "b.onnx"), config, 400.0)
    kept = low.detect(frame)
    assert len(kept) >= 1 and np.all(kept.boxes_xyxy[:, 1] == pytest.approx(494.0, abs=0.01))
    masked_config = DetectorConfig(tile_scales=(1.0,), global_pass=False,
                                   exclusion_polygons=("0,480 1280,480 1280,540 0,540",))
    masked = VesselDetector(_model(tmp_path, _yolox_output_with_boat(200, 200, 40, 20), "c.onnx"), masked_config,
                            400.0)
    assert len(masked.detect(frame)) == 0


def test_tiled_mode_reports_one_box_per_object_seen_by_several_windows(tmp_path):
    # The constant output puts the same box in every window; the merge must not multiply real objects beyond
    # one per distinct place, and every box must lie inside the frame.
    detector = VesselDetector(_model(tmp_path, _yolox_output_with_boat(150, 150, 40, 20)), DetectorConfig(), 400.0)
    result = detector.detect(np.zeros((720, 1280, 3), np.uint8))
    windows = detector.windows((1280, 720))
    assert 0 < len(result) <= len(windows)
    assert np.all(result.boxes_xyxy[:, [0, 2]] <= 1280) and np.all(result.boxes_xyxy[:, [1, 3]] <= 720)
    from vessel_detect.box_ops import box_iou

    iou = box_iou(result.boxes_xyxy, result.boxes_xyxy)
    assert np.all(iou[~np.eye(len(result), dtype=bool)] <= 0.45)


def test_detect_rejects_non_images(tmp_path):
    detector = VesselDetector(_model(tmp_path, np.zeros((1, POINTS, 85), np.float32)), DetectorConfig(), 400.0)
    with pytest.raises(VesselError, match="BGR"):
        detector.detect(np.zeros((720, 1280), np.uint8))
    with pytest.raises(VesselError, match="BGR"):
        detector.detect(np.zeros((0, 1280, 3), np.uint8))


@pytest.mark.data
def test_real_model_finds_the_vessel_on_a_real_frame_and_not_the_post(model_path, data_dir):
    import cv2

    from vessel_detect.box_ops import box_iou
    from vessel_tools.calib.dataset import Dataset

    dataset = Dataset(data_dir)
    values = default_values()
    values["model_path"] = str(model_path)
    values["model_sha256"] = ""
    detector = build_detector(values, dataset.camera_model())
    label = next(lab for lab in dataset.labels([16]) if lab.frame == 900)
    image = cv2.imread(str(data_dir / "frames" / "16" / "00900.jpg"))
    result = detector.detect(image)
    hand = np.array([[label.x1, label.y1, label.x2, label.y2]])
    assert len(result) and box_iou(hand, result.boxes_xyxy).max() >= 0.3
    post = np.array([[695, 648, 926, 718]])
    assert len(result) == 0 or box_iou(post, result.boxes_xyxy).max() < 0.3
    assert set(result.labels()) == {"boat"}


def test_the_node_parameter_file_holds_the_defaults():
    from pathlib import Path

    from vessel_detect.detector_params import load_params_file

    path = Path(__file__).resolve().parents[3] / "config" / "parts" / "detector.yaml"
    values, camera = load_params_file(path)
    assert values == default_values() and camera is None


def test_annotate_draws_band_masks_and_boxes_at_the_requested_scale(tmp_path):
    from vessel_detect.annotation import annotate
    from vessel_detect.detector import Detections

    detector = VesselDetector(_model(tmp_path, np.zeros((1, POINTS, 85), np.float32)), DetectorConfig(), 400.0)
    frame = np.zeros((720, 1280, 3), np.uint8)
    detections = Detections(np.array([[100.0, 500.0, 200.0, 540.0]]), np.array([0.5]), np.array([BOAT]),
                            detector.class_names)
    image = annotate(frame, detections, detector, 0.5)
    assert image.shape == (360, 640, 3) and image.dtype == np.uint8
    assert image[180, 300].tolist() == [255, 200, 0]  # the band top (y = 360) at half scale
    assert image[250, 50].tolist() == [0, 255, 0]  # the box's left edge
    assert (image[:, :, 2] == 255).any()  # the mooring post polygon in red
    assert not frame.any()  # the input is left alone


def test_detections_of_a_scaled_stream_are_published_in_calibrated_pixels():
    """A 640x360 stream of a 1280x720 calibration: boxes scale; another aspect ratio is refused, named."""
    from vessel_detect.image_codec import ImageError

    found = Detections(np.array([[10.0, 20.0, 30.0, 50.0]]), np.array([0.9]), np.array([0]), ["boat"],
                       np.array([0.7]))
    assert found.in_calibrated_pixels((1280, 720), (1280, 720)) is found
    half = found.in_calibrated_pixels((640, 360), (1280, 720))
    np.testing.assert_allclose(half.boxes_xyxy, [[20.0, 40.0, 60.0, 100.0]])
    np.testing.assert_allclose(half.p_target, [0.7])
    np.testing.assert_allclose(found.in_calibrated_pixels((5120, 2880), (1280, 720)).boxes_xyxy,
                               [[2.5, 5.0, 7.5, 12.5]])
    with pytest.raises(ImageError, match="640x480 but the calibration is for 1280x720") as error:
        found.in_calibrated_pixels((640, 480), (1280, 720))
    assert error.value.kind == "wrong_image_size"
