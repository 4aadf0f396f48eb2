"""The camera pose a detection array carries (``vessel_msgs/CameraPose``): refused, or the boxes mapped by it.

A camera on a ship or a swaying pole takes each image at its own attitude; the detector says which, as the map of
the image's ideal pixels into the calibration's reference image. The tracker tracks in the reference image, where
the calibration (and the fuser's distance model) holds, so every box goes through that map first. An image whose
pose the detector could not find (``valid`` false) gets no positions: a wrong pose would give wrong ones.
"""

from __future__ import annotations

import math

import numpy as np

from vessel_calib.camera_pose import boxes_to_reference
from vessel_calib.radial_lens import RadialLens

SOURCE_NOT_GIVEN = 0
"""A producer that knows nothing of poses (hand labels, another detector): its boxes are taken as they are."""


def pose_refusal(pose) -> str | None:
    """Why the boxes of an array with this ``CameraPose`` cannot be used, or None."""
    if int(pose.source) == SOURCE_NOT_GIVEN:
        return None
    if not pose.valid:
        return f"image without a camera pose skipped ({pose.problem or 'no reason given'})"
    values = [float(v) for v in pose.image_to_reference]
    if len(values) != 9 or not all(math.isfinite(v) for v in values):
        return "image skipped: its camera pose's image_to_reference is not 9 finite numbers"
    if abs(np.linalg.det(np.array(values).reshape(3, 3))) < 1e-12:
        return "image skipped: its camera pose's image_to_reference is singular"
    if not (math.isfinite(pose.lens_k1) and math.isfinite(pose.lens_center.x) and math.isfinite(pose.lens_center.y)):
        return "image skipped: its camera pose's lens is not finite"
    return None


def pose_sigma_px(pose, centers_xy: np.ndarray) -> np.ndarray:
    """(N, 2) standard deviation of each box centre's ideal x and y owed to the pose's uncertainty, px.

    The camera's rotation uncertainty (``camera_rotation_covariance``, its own axes) moves a pixel at (u, v) from
    the lens centre by the rotational image motion of a pinhole camera of focal length f:
    du = (u v / f) wx - (f + u^2 / f) wy + v wz, dv = (f + v^2 / f) wx - (u v / f) wy - u wz. Zero without a
    focal length (a fixed camera).
    """
    centers = np.asarray(centers_xy, dtype=float).reshape(-1, 2)
    f = float(pose.focal_px)
    if not (f > 0 and math.isfinite(f)) or len(centers) == 0:
        return np.zeros((len(centers), 2))
    C = np.array([float(v) for v in pose.camera_rotation_covariance]).reshape(3, 3)
    u = centers[:, 0] - float(pose.lens_center.x)
    v = centers[:, 1] - float(pose.lens_center.y)
    J = np.zeros((len(centers), 2, 3))
    J[:, 0] = np.stack([u * v / f, -(f + u * u / f), v], axis=1)
    J[:, 1] = np.stack([f + v * v / f, -u * v / f, -u], axis=1)
    cov = J @ C @ np.swapaxes(J, 1, 2)
    return np.sqrt(np.clip(np.stack([cov[:, 0, 0], cov[:, 1, 1]], axis=1), 0.0, None))


def boxes_in_reference(pose, boxes_xyxy: np.ndarray) -> np.ndarray:
    """Boxes of the image -> boxes of the reference image (``pose`` accepted by ``pose_refusal``)."""
    if int(pose.source) == SOURCE_NOT_GIVEN or len(boxes_xyxy) == 0:
        return boxes_xyxy
    M = np.array([float(v) for v in pose.image_to_reference]).reshape(3, 3)
    if np.array_equal(M, np.eye(3)):
        return boxes_xyxy
    lens = RadialLens(float(pose.lens_k1), (float(pose.lens_center.x), float(pose.lens_center.y)))
    return boxes_to_reference(boxes_xyxy, M, lens)
