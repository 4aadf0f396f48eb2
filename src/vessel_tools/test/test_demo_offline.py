"""The demo's offline pass reads the recorded detections as the tracker node read them."""
import numpy as np
import pytest

from vessel_detect import bag_messages, bag_writer
from vessel_tools.demo import recorded_detection_frames
from vessel_track.tracker_node import load_detection_inputs


def _detection(types, x, hypotheses):
    return types["vessel_msgs/msg/Detection2D"](
        header=bag_messages.header(0, "camera"),
        results=[types["vessel_msgs/msg/ObjectHypothesisWithPose"](
            hypothesis=types["vessel_msgs/msg/ObjectHypothesis"](class_id=c, score=s),
            pose=types["geometry_msgs/msg/PoseWithCovariance"](
                pose=types["geometry_msgs/msg/Pose"](position=types["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                                                     orientation=types["geometry_msgs/msg/Quaternion"](
                                                         x=0.0, y=0.0, z=0.0, w=1.0)),
                covariance=np.zeros(36))) for c, s in hypotheses],
        bbox=types["vessel_msgs/msg/BoundingBox2D"](
            center=types["vessel_msgs/msg/Pose2D"](position=types["vessel_msgs/msg/Point2D"](x=x, y=420.0), theta=0.0),
            size_x=40.0, size_y=20.0),
        id="")


def _params(tmp_path, tracker_block):
    path = tmp_path / "params.yaml"
    path.write_text(f"tracker:\n  ros__parameters:\n{tracker_block}")
    return path


def test_the_offline_pass_takes_each_box_s_probability_of_being_the_vessel_of_interest(tmp_path):
    store = bag_messages.typestore()
    types = store.types
    stamp = bag_messages.sec_to_ns(1_600_000_000.5)
    array = types["vessel_msgs/msg/Detection2DArray"](header=bag_messages.header(stamp, "camera"), detections=[
        _detection(types, 100.0, [("vessel_of_interest", 0.9)]),
        _detection(types, 300.0, [("vessel", 0.8), ("vessel_of_interest", 0.05)]),  # another boat, surely
    ], camera_pose=bag_messages.camera_pose_not_given(stamp))
    with bag_writer.BagWriter(tmp_path / "recording") as writer:
        writer.add_topic("/vessel/detections", "vessel_msgs/Detection2DArray")
        writer.write("/vessel/detections", array)
    trained = _params(tmp_path, "    classes: ['*']\n    confidence_class: vessel_of_interest\n")
    classes, confidence_class = load_detection_inputs(trained)
    assert (classes, confidence_class) == (None, "vessel_of_interest")
    [frame] = recorded_detection_frames(tmp_path / "recording", 14, classes, confidence_class)
    assert (frame.video, frame.frame, frame.stamp) == (14, 0, pytest.approx(1_600_000_000.5))
    assert frame.boxes[:, 0].tolist() == [80.0, 280.0]
    assert frame.scores.tolist() == pytest.approx([0.9, 0.05])  # not the other boat's class score, 0.8
    # The COCO preset: boats only, each box's own score.
    coco = _params(tmp_path, "    classes: [vessel]\n    confidence_class: ''\n")
    [frame] = recorded_detection_frames(tmp_path / "recording", 14, *load_detection_inputs(coco))
    assert frame.scores.tolist() == pytest.approx([0.8])


@pytest.mark.parametrize(("block", "message"), [("    classes: vessel\n", "tracker.classes must be a list"),
                                                ("    confidence_class: 3\n", "tracker.confidence_class must be")])
def test_mistyped_tracker_inputs_are_named(tmp_path, block, message):
    from vessel_common.errors import DataError

    with pytest.raises(DataError, match=message):
        load_detection_inputs(_params(tmp_path, block))


def test_the_coco_preset_over_the_shipped_parameters_gives_settings_every_node_accepts(tmp_path):
    """``./vessel demo --detector-params config/detector_coco.yaml`` (the README's comparison) must start."""
    from pathlib import Path

    from vessel_detect.detector_params import load_params_files
    from vessel_tools.demo import merged_params_file
    from vessel_track.fuser_settings import load_fuser_settings
    from vessel_track.tracker_config import load_tracker_config

    config = Path(__file__).resolve().parents[3] / "config"
    merged = merged_params_file(config / "aitas.yaml", config / "detector_coco.yaml", tmp_path / "params.yaml")
    settings = load_fuser_settings(merged)
    assert settings.selection.recent_evidence_s == 0.0 and settings.fusion.anchor_offset == 0.05
    load_tracker_config(merged)
    values, _ = load_params_files([merged, config / "aitas_camera.yaml"])
    assert values["size_prior.dimension"] == "none" and values["classes"] == ["boat"]
