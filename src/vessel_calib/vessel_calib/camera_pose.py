"""A camera with a pose: the calibration's intrinsics, its mounting on the ship, and the ship's attitude per image.

A calibration's sea-plane homography H holds for one attitude of the camera. H = K [r1 r2 t] decomposes into the
intrinsics K (focal length, principal point at the lens centre) and the camera's rotation relative to
east-north-up; given the ship's attitude at which H holds (the reference attitude), that rotation is the camera's
mounting on the ship. Any other attitude then gives the rotation between an image and the reference image, and a
pure rotation about the camera's centre maps ideal pixels by ``K R K^-1`` whatever the scene. So an image's pixels
map into the reference image with one 3x3 product, the calibration (H, the distance model, the masks) holds there
unchanged, and a fixed camera is the case where every image's attitude is the reference.

Attitude follows ``own_ship.csv`` and ``vessel_calib.own_ship``: north-east-down, the ship's body forward-starboard-
down, ``R_nb = Rz(heading) Ry(pitch) Rx(roll)``, degrees; heading clockwise from true north, pitch bow up, roll
starboard down. Each mapping here names its inverse (``image_to_reference`` / ``reference_to_image``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vessel_calib import own_ship
from vessel_calib.radial_lens import RadialLens
from vessel_common.errors import CalibrationError

ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""Swaps north-east-down and east-north-up (its own inverse)."""

LINE_PROBE_PX = 400.0
"""Horizontal distance from the lens centre of the two points a line is compared at when solving for tilt."""


def ned_from_body(heading_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """The rotation R_nb taking the ship's body axes (forward, starboard, down) into north-east-down."""
    return own_ship.ned_from_body(own_ship.ShipAttitude(heading_deg, pitch_deg, roll_deg))


def camera_from_enu_of_homography(H: np.ndarray, center: Sequence[float], focal_px: float) -> np.ndarray:
    """The rotation from east-north-up to the camera (x right, y down, z forward) of H = K [r1 r2 t].

    The camera must be above the sea: of the two signs of H the one that puts the camera centre above the sea
    plane is taken. CalibrationError when neither does.
    """
    cx, cy = center
    K = np.array([[focal_px, 0.0, cx], [0.0, focal_px, cy], [0.0, 0.0, 1.0]])
    M = np.linalg.solve(K, np.asarray(H, dtype=float))
    for sign in (1.0, -1.0):
        m = sign * M
        scale = (np.linalg.norm(m[:, 0]) + np.linalg.norm(m[:, 1])) / 2.0
        r1, r2, t = m[:, 0] / scale, m[:, 1] / scale, m[:, 2] / scale
        U, _, Vt = np.linalg.svd(np.column_stack([r1, r2, np.cross(r1, r2)]))
        R = U @ Vt
        if (-R.T @ t)[2] > 0:
            return R
    raise CalibrationError("H puts the camera under the sea plane whichever its sign: re-run the calibration")


@dataclass(frozen=True)
class CameraMounting:
    """The camera's intrinsics and its rotation relative to the ship's body.

    ``K``: 3x3 intrinsics in ideal pixels; ``camera_from_body``: the rotation from the ship's body axes to the
    camera's; ``reference``: the ship attitude (heading, pitch, roll in degrees) at which the calibration's H
    holds. ``from_camera`` builds it from a calibration.
    """

    K: np.ndarray
    camera_from_body: np.ndarray
    reference: tuple[float, float, float]

    @classmethod
    def from_camera(cls, camera, reference_attitude: Sequence[float] | None = None) -> CameraMounting:
        """The mounting of ``camera`` (a ``CameraModel``) given the ship's attitude at which its H holds.

        Without a reference attitude the ship is taken to point where the camera looks, level: the heading of
        H's horizon, pitch and roll 0 (right for a fixed camera, whose attitude never changes).
        """
        focal = camera.pinhole().focal_px
        R_c_enu = camera_from_enu_of_homography(camera.H, camera.center, focal)
        reference = _reference_attitude(camera, reference_attitude)
        cx, cy = camera.center
        K = np.array([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]])
        camera_from_body = R_c_enu @ ENU_FROM_NED @ ned_from_body(*reference)
        return cls(K, camera_from_body, reference)

    def camera_from_enu(self, heading_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
        """The camera's rotation from east-north-up when the ship has this attitude."""
        return self.camera_from_body @ ned_from_body(heading_deg, pitch_deg, roll_deg).T @ ENU_FROM_NED

    def image_to_reference(self, heading_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
        """The homography of ideal pixels from an image taken at this attitude into the reference image.

        The inverse is ``reference_to_image``. Identity at the reference attitude.
        """
        R_ref = self.camera_from_enu(*self.reference)
        R_img = self.camera_from_enu(heading_deg, pitch_deg, roll_deg)
        return self.K @ R_ref @ R_img.T @ np.linalg.inv(self.K)

    def reference_to_image(self, heading_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
        """The homography of ideal pixels from the reference image into an image at this attitude."""
        return np.linalg.inv(self.image_to_reference(heading_deg, pitch_deg, roll_deg))

    def line_in_image(self, reference_abc: Sequence[float], heading_deg: float, pitch_deg: float,
                      roll_deg: float) -> np.ndarray:
        """Where a line of the reference image (a x + b y + c = 0, ideal pixels) lies in an image at this attitude.

        Normalised to a^2 + b^2 = 1 with b < 0, the convention of ``CameraModel.horizon_line_ideal``'s sea side.
        """
        line = self.image_to_reference(heading_deg, pitch_deg, roll_deg).T @ np.asarray(reference_abc, float)
        return normalised_line(line)

    def tilt_from_line(self, image_abc: Sequence[float], reference_abc: Sequence[float], heading_deg: float,
                       start: tuple[float, float] = (0.0, 0.0)) -> tuple[float, float, np.ndarray] | None:
        """Pitch and roll (degrees) at which the reference line falls on a line measured in the image.

        The heading is given (a compass, or the reference's): a line has two degrees of freedom, so it fixes pitch
        and roll. The lines are compared by their heights at two points either side of the lens centre; Newton's
        method from ``start``. Returns pitch, roll and the 2x2 Jacobian of those heights with respect to (pitch,
        roll) in px per degree, which turns the measured line's uncertainty into the attitude's. None when Newton
        does not converge to a finite attitude within 20 degrees of the start (no attitude fits the line).
        """
        image_abc = np.asarray(image_abc, float)
        if not abs(image_abc[1]) > 1e-6 * np.hypot(image_abc[0], image_abc[1]):
            return None  # a (near) vertical line is no horizon
        target = _heights(image_abc, self.K[0, 2])
        x = np.array(start, dtype=float)
        J = np.eye(2)
        for _ in range(8):
            current = _heights(self.line_in_image(reference_abc, heading_deg, x[0], x[1]), self.K[0, 2])
            J = np.column_stack([
                (_heights(self.line_in_image(reference_abc, heading_deg, x[0] + 1e-3, x[1]), self.K[0, 2])
                 - current) / 1e-3,
                (_heights(self.line_in_image(reference_abc, heading_deg, x[0], x[1] + 1e-3), self.K[0, 2])
                 - current) / 1e-3,
            ])
            try:
                step = np.linalg.solve(J, target - current)
            except np.linalg.LinAlgError:
                return None
            x = x + step
            if not np.all(np.isfinite(x)) or np.max(np.abs(x - np.asarray(start))) > 20.0:
                return None
            if np.max(np.abs(step)) < 1e-6:
                return float(x[0]), float(x[1]), J
        return None


def _reference_attitude(camera, reference_attitude) -> tuple[float, float, float]:
    if reference_attitude is None or not all(math.isfinite(float(v)) for v in reference_attitude):
        heading = camera.heading_deg
        if not math.isfinite(heading):
            raise CalibrationError("the calibration gives no heading (no horizon in the image): set "
                                   "camera.reference_attitude_deg to the ship's heading, pitch and roll at which "
                                   "H holds")
        return (float(heading), 0.0, 0.0)
    values = tuple(float(v) for v in reference_attitude)
    if len(values) != 3:
        raise CalibrationError(f"camera.reference_attitude_deg must be [heading, pitch, roll] in degrees, got "
                               f"{list(reference_attitude)!r}")
    if abs(values[1]) >= 90.0 or abs(values[2]) >= 90.0:
        raise CalibrationError(f"camera.reference_attitude_deg {list(values)!r}: pitch and roll must be within "
                               "+-90 degrees")
    return values


def normalised_line(line) -> np.ndarray:
    """A line a x + b y + c = 0 scaled to a^2 + b^2 = 1 and b < 0 (so one line has one set of numbers)."""
    line = np.asarray(line, dtype=float)
    norm = math.hypot(line[0], line[1])
    if not norm > 0:
        raise CalibrationError(f"not a line: {line.tolist()!r}")
    line = line / norm
    return -line if line[1] > 0 else line


def _heights(line: np.ndarray, cx: float) -> np.ndarray:
    """The line's y at x = cx -+ the probe distance (a near-horizontal line)."""
    xs = np.array([cx - LINE_PROBE_PX, cx + LINE_PROBE_PX])
    return -(line[0] * xs + line[2]) / line[1]


def map_ideal_points(M: np.ndarray, xs, ys) -> tuple[np.ndarray, np.ndarray]:
    """Ideal pixels through a homography M (any broadcastable shapes)."""
    xs, ys = np.asarray(xs, float), np.asarray(ys, float)
    w = M[2, 0] * xs + M[2, 1] * ys + M[2, 2]
    return (M[0, 0] * xs + M[0, 1] * ys + M[0, 2]) / w, (M[1, 0] * xs + M[1, 1] * ys + M[1, 2]) / w


def boxes_to_reference(boxes_xyxy, image_to_reference: np.ndarray, lens: RadialLens) -> np.ndarray:
    """Screen boxes of an image -> screen boxes of the reference image, keeping each box's shape.

    The box centre goes through the lens, the homography and the lens back; width and height are scaled by the
    local scale of that map at the centre (the square root of its Jacobian's determinant). The axis-aligned hull
    of the mapped corners would grow a box by the roll between the images, and the fuser reads distance from box
    size. A box whose centre falls outside the lens's domain comes back as NaN.
    """
    boxes = np.asarray(boxes_xyxy, dtype=float).reshape(-1, 4)
    if len(boxes) == 0:
        return boxes.copy()
    cx = (boxes[:, 0] + boxes[:, 2]) / 2.0
    cy = (boxes[:, 1] + boxes[:, 3]) / 2.0
    step = 2.0
    xs = np.stack([cx, cx + step, cx], axis=1)
    ys = np.stack([cy, cy, cy + step], axis=1)
    xp, yp, _ = lens.undistort(xs, ys)
    xr, yr = map_ideal_points(image_to_reference, xp, yp)
    xo, yo = lens.distort(xr, yr)
    jx = np.stack([xo[:, 1] - xo[:, 0], yo[:, 1] - yo[:, 0]], axis=1) / step
    jy = np.stack([xo[:, 2] - xo[:, 0], yo[:, 2] - yo[:, 0]], axis=1) / step
    scale = np.sqrt(np.abs(jx[:, 0] * jy[:, 1] - jx[:, 1] * jy[:, 0]))
    half_w = (boxes[:, 2] - boxes[:, 0]) / 2.0 * scale
    half_h = (boxes[:, 3] - boxes[:, 1]) / 2.0 * scale
    return np.stack([xo[:, 0] - half_w, yo[:, 0] - half_h, xo[:, 0] + half_w, yo[:, 0] + half_h], axis=1)
