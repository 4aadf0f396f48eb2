"""A camera on a moving ship: every frame's pose, from own_ship.csv and the horizon, must be applied, and rightly.

Moving copies of a challenge video are made with ``../shared/tools/make_motion_set.py`` (each frame warped by the
rotation the ship gave the camera; its hand-labelled boxes moved likewise). Mapping a moved box through its
frame's pose must land on the unmoved box; ignoring the pose, or applying it the wrong way round, must not.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
DATA = SHARED / "aitas"
MAKER = SHARED / "tools" / "make_motion_set.py"
CALIBRATION = REPO / "config" / "aitas_camera.yaml"
VIDEO = 7

pytestmark = pytest.mark.skipif(not (DATA.is_dir() and MAKER.is_file()),
                                reason="needs ../shared/aitas and ../shared/tools/make_motion_set.py (absent here)")


def _moving_copy(out: Path, *options: str) -> Path:
    subprocess.run([sys.executable, str(MAKER), "--data", str(DATA), "--calib", str(CALIBRATION), "--out", str(out),
                    "--videos", str(VIDEO), *options], check=True, capture_output=True)
    return out


def _labels_by_frame(dataset) -> dict[int, np.ndarray]:
    return {label.frame: np.array([label.x1, label.y1, label.x2, label.y2])
            for label in dataset.labels([VIDEO])}


def _mapped_boxes(folder: Path):
    """(moved label boxes mapped by each frame's pose, the same boxes unmapped, the unmoved boxes, poses)."""
    from vessel_calib.params import load_camera_yaml
    from vessel_detect.detector_params import default_values
    from vessel_tools.calib.dataset import Dataset
    from vessel_tools.detect.dataset_detection import dataset_poser, read_frame

    moved, unmoved = Dataset(folder), Dataset(DATA)
    camera = load_camera_yaml(CALIBRATION)
    poser = dataset_poser(moved, camera, default_values())
    truth, moved_boxes = _labels_by_frame(unmoved), _labels_by_frame(moved)
    mapped, raw, expected, poses = [], [], [], []
    for record in moved.frames([VIDEO]):
        if record.frame not in truth:
            continue
        image = read_frame(record.path)
        for sample in poser.samples[poser.next_index:]:
            if sample.stamp > record.stamp + poser.LOOK_AHEAD_S:
                break
            poser.poser.add_attitude(sample.stamp, sample.attitude)
            poser.next_index += 1
        pose = poser.poser.pose_of(record.stamp, image)
        assert pose.estimate.valid, pose.estimate.problem
        box = moved_boxes[record.frame][None, :]
        mapped.append(pose.view.boxes_in_reference(box, camera.image_size, camera.image_size)[0])
        raw.append(box[0])
        expected.append(truth[record.frame])
        poses.append(pose)
    return np.array(mapped), np.array(raw), np.array(expected), poses


def _centre_errors(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.hypot((a[:, 0] + a[:, 2] - b[:, 0] - b[:, 2]) / 2, (a[:, 1] + a[:, 3] - b[:, 1] - b[:, 3]) / 2)


@pytest.mark.parametrize("options, tolerance_px", [((), 1.5), (("--no-attitude", "--heading-noise-deg", "0.2"), 4.0),
                                                   (("--imu-noise-deg", "0.05", "--imu-bias-deg", "0.3"), 3.0)],
                         ids=["exact", "compass_only", "imu_with_bias"])
def test_each_frame_pose_puts_moved_boxes_back_where_the_calibration_sees_them(tmp_path, options, tolerance_px):
    folder = _moving_copy(tmp_path / "moved", *options)
    mapped, raw, expected, poses = _mapped_boxes(folder)
    assert len(mapped) >= 20
    applied = _centre_errors(mapped, expected)
    ignored = _centre_errors(raw, expected)
    assert np.median(applied) < tolerance_px, applied
    assert np.median(ignored) > 10 * tolerance_px, "the motion set barely moved: the test would prove nothing"
    kept = (mapped[:, 2:] - mapped[:, :2]) / (raw[:, 2:] - raw[:, :2])
    assert np.median(np.abs(kept - 1.0)) < 0.03  # a box keeps its size (but for the lens): the fuser reads it
    if options and options[0] == "--no-attitude":
        assert all(pose.estimate.horizon_used for pose in poses)


def test_a_pose_applied_the_wrong_way_round_misses(tmp_path):
    from vessel_calib.camera_pose import boxes_to_reference
    from vessel_calib.params import load_camera_yaml
    from vessel_calib.radial_lens import RadialLens

    folder = _moving_copy(tmp_path / "moved")
    _, raw, expected, poses = _mapped_boxes(folder)
    camera = load_camera_yaml(CALIBRATION)
    lens = RadialLens(camera.K1, camera.center)
    inverted = np.array([boxes_to_reference(box[None, :], np.linalg.inv(pose.estimate.image_to_reference), lens)[0]
                         for box, pose in zip(raw, poses, strict=True)])
    assert np.median(_centre_errors(inverted, expected)) > 15.0
