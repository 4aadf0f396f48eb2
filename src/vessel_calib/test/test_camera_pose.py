"""The camera's pose: mounting from a calibration, images mapped into the reference image, tilt from a line."""

import math

import numpy as np
import pytest

from vessel_calib.attitude import SOURCE_FIXED, SOURCE_FUSED, AttitudeEstimator, AttitudeSettings, MeasuredLine
from vessel_calib.camera_model import CameraModel
from vessel_calib.camera_pose import CameraMounting, boxes_to_reference, map_ideal_points, ned_from_body
from vessel_calib.radial_lens import RadialLens

H = [-453.05, 404.64, -1289.19, -216.68, -48.28, -1355.31, -0.51686, -0.12545, -0.10531]
CAMERA = CameraModel(H, -3.5e-7, camera_lat=32.70297, camera_lon=-117.234631, box_anchor=0.65)
REFERENCE = (76.0, 0.0, 0.0)


def _world_to_image(mounting, camera, attitude, xw, yw):
    """A sea point seen from the camera at ``attitude``: project with the rotated camera from first principles."""
    R_ref = mounting.camera_from_enu(*REFERENCE)
    m = np.linalg.solve(mounting.K, camera.H)
    scale = m[:, 0] @ R_ref[:, 0]  # K^-1 H = scale [r1 r2 t]
    centre_enu = -R_ref.T @ (m[:, 2] / scale)
    p = mounting.K @ mounting.camera_from_enu(*attitude) @ (np.array([xw, yw, 0.0]) - centre_enu)
    return p[0] / p[2], p[1] / p[2]


def test_the_reference_attitude_maps_an_image_onto_itself():
    mounting = CameraMounting.from_camera(CAMERA, REFERENCE)
    M = mounting.image_to_reference(*REFERENCE)
    assert np.allclose(M / M[2, 2], np.eye(3), atol=1e-9)


def test_an_image_at_another_attitude_maps_a_sea_point_to_where_the_calibration_sees_it():
    mounting = CameraMounting.from_camera(CAMERA, REFERENCE)
    attitude = (80.0, 1.5, -4.0)
    xw, yw = 145.5, 36.3  # 150 m out along the camera's heading
    xi, yi = _world_to_image(mounting, CAMERA, attitude, xw, yw)
    xr, yr = map_ideal_points(mounting.image_to_reference(*attitude), xi, yi)
    x_expected, y_expected = _world_to_image(mounting, CAMERA, REFERENCE, xw, yw)
    assert abs(xr - x_expected) < 1e-6 and abs(yr - y_expected) < 1e-6
    x_calib, y_calib = CAMERA.world_to_ideal(xw, yw)[:2]
    assert abs(x_expected - x_calib) < 8.0 and abs(y_expected - y_calib) < 8.0  # H is nearly that pinhole
    ignored = abs(xi - x_expected) + abs(yi - y_expected)
    assert ignored > 50  # the pose matters: without it the point is far off


def test_pitch_bow_up_moves_the_horizon_down_in_the_image():
    mounting = CameraMounting.from_camera(CAMERA, REFERENCE)
    level = mounting.line_in_image(CAMERA.horizon_line_ideal, *REFERENCE)
    up = mounting.line_in_image(CAMERA.horizon_line_ideal, 76.0, 1.0, 0.0)
    y_level = -(level[0] * 640 + level[2]) / level[1]
    y_up = -(up[0] * 640 + up[2]) / up[1]
    assert y_up - y_level == pytest.approx(mounting.K[0, 0] * math.radians(1.0), rel=0.02)


def test_tilt_from_a_line_inverts_line_in_image():
    mounting = CameraMounting.from_camera(CAMERA, REFERENCE)
    ref = CAMERA.far_edge_line()
    line = mounting.line_in_image(ref, 70.0, -1.7, 3.2)
    pitch, roll, _ = mounting.tilt_from_line(line, ref, 70.0)
    assert pitch == pytest.approx(-1.7, abs=1e-6) and roll == pytest.approx(3.2, abs=1e-6)


def test_ned_from_body_is_a_rotation_with_heading_clockwise_from_north():
    R = ned_from_body(90.0, 0.0, 0.0)
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0])  # bow east
    assert np.allclose(R @ R.T, np.eye(3))


def test_boxes_keep_their_size_under_roll():
    mounting = CameraMounting.from_camera(CAMERA, REFERENCE)
    lens = RadialLens(CAMERA.K1, CAMERA.center)
    box = np.array([[600.0, 430.0, 660.0, 450.0]])
    mapped = boxes_to_reference(box, mounting.image_to_reference(76.0, 0.0, 5.0), lens)
    assert mapped[0, 2] - mapped[0, 0] == pytest.approx(60.0, rel=0.02)
    assert mapped[0, 3] - mapped[0, 1] == pytest.approx(20.0, rel=0.02)


def _estimator(source, **kw):
    mounting = CameraMounting.from_camera(CAMERA, REFERENCE)
    return mounting, AttitudeEstimator(mounting, CAMERA.far_edge_line(), AttitudeSettings(source=source, **kw))


def test_a_fixed_camera_passes_boxes_untouched():
    _, estimator = _estimator("fixed")
    pose = estimator.estimate(0.0, None, None)
    assert pose.valid and pose.source == SOURCE_FIXED and np.array_equal(pose.image_to_reference, np.eye(3))


def test_the_horizon_removes_an_attitude_sensor_bias():
    mounting, estimator = _estimator("own_ship", sensor_sigma_deg=0.05)
    rng = np.random.default_rng(0)
    errors = []
    for k in range(60):
        true = (76.0, 2.0 * math.sin(k), 5.0 * math.cos(0.7 * k))
        line = mounting.line_in_image(CAMERA.far_edge_line(), *true)
        measured = MeasuredLine(tuple(line + [0, 0, rng.normal(0, 0.3)]), 0.3, 1e-4)
        sensor = (true[0], true[1] + 0.3 + rng.normal(0, 0.05), true[2] + 0.3 + rng.normal(0, 0.05))
        pose = estimator.estimate(4.0 * k, sensor, measured)
        errors.append(abs(pose.pitch_deg - true[1]))
    assert pose.source == SOURCE_FUSED
    assert np.median(errors[20:]) < 0.05  # the 0.3 degree bias is gone


def test_a_compass_alone_needs_the_horizon():
    _, estimator = _estimator("own_ship")
    pose = estimator.estimate(0.0, (76.0, None, None), None)
    assert not pose.valid and "horizon" in pose.problem


def test_no_attitude_fits_a_vertical_line():
    mounting = CameraMounting.from_camera(CAMERA, REFERENCE)
    assert mounting.tilt_from_line((1.0, 0.0, -640.0), CAMERA.far_edge_line(), 76.0) is None


def test_the_horizon_teaches_the_bias_again_after_it_jumps():
    mounting, estimator = _estimator("own_ship", sensor_sigma_deg=0.05)
    truth = (76.0, 0.5, -1.0)
    line = MeasuredLine(tuple(mounting.line_in_image(CAMERA.far_edge_line(), *truth)), 0.2, 1e-4)
    for k in range(40):  # the sensor agrees with the horizon: the bias filter grows confident in zero
        estimator.estimate(4.0 * k, truth, line)
    jumped = (76.0, truth[1] + 1.0, truth[2])  # the sensor's pitch bias jumps by a degree
    poses = [estimator.estimate(160.0 + 4.0 * k, jumped, line) for k in range(20)]
    assert poses[0].problem.startswith("horizon rejected")
    assert poses[-1].horizon_used and abs(poses[-1].pitch_deg - truth[1]) < 0.05
