"""``vessel_msgs/CameraPose`` of an image's pose (``vessel_detect.frame_pose.ImagePose``)."""

from __future__ import annotations

import math

import numpy as np

from vessel_msgs.msg import CameraPose


def _finite(value: float) -> float:
    return float(value) if math.isfinite(float(value)) else 0.0


RAD2 = (math.pi / 180.0) ** 2


def camera_pose_msg(pose, header, camera, camera_from_body) -> CameraPose:
    """The message of ``pose`` (an ``ImagePose``) for the image with ``header``.

    ``camera``: the ``CameraModel``; ``camera_from_body``: the mounting's rotation (``CameraMounting``), which turns
    the ship's attitude covariance into the camera's axes.

    Non-finite numbers (the attitude of an image that got no pose) are sent as 0 with ``valid`` false: a
    consumer never sees NaN.
    """
    estimate = pose.estimate
    msg = CameraPose()
    msg.header = header
    msg.valid = bool(estimate.valid)
    msg.source = int(estimate.source)
    msg.problem = estimate.problem
    msg.heading_deg = _finite(estimate.heading_deg)
    msg.pitch_deg = _finite(estimate.pitch_deg)
    msg.roll_deg = _finite(estimate.roll_deg)
    covariance = np.asarray(estimate.covariance_deg2, dtype=float)
    msg.attitude_covariance = [_finite(v) for v in covariance.ravel()]
    R = np.asarray(camera_from_body, dtype=float)  # body x, y, z: roll, pitch, heading axes (small tilts)
    msg.camera_rotation_covariance = [_finite(v) for v in (R @ np.nan_to_num(covariance) @ R.T).ravel() * RAD2]
    msg.image_to_reference = [_finite(v) for v in np.asarray(estimate.image_to_reference, dtype=float).ravel()]
    msg.focal_px = float(camera.pinhole().focal_px) if estimate.source > 1 and camera is not None else 0.0
    if camera is not None:
        msg.lens_k1 = float(camera.K1)
        msg.lens_center.x, msg.lens_center.y = (float(v) for v in camera.center)
    edge = pose.edge
    if edge is not None and edge.found:
        msg.horizon_found = True
        msg.horizon_ideal_abc = [float(v) for v in edge.abc]
        msg.horizon_sigma_px = float(edge.sigma_px)
    return msg
