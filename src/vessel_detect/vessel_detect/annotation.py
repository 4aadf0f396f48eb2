"""The annotated image: what the detector saw and found, for people (``publish_annotated``)."""

from __future__ import annotations

import cv2
import numpy as np

from vessel_detect.detector import Detections, VesselDetector
from vessel_detect.image_view import ImageView


def annotate(bgr: np.ndarray, detections: Detections, detector: VesselDetector, scale: float = 0.5,
             view: ImageView | None = None) -> np.ndarray:
    """A copy of the frame at ``scale`` with the processed band, the masks, the boxes and the horizon drawn.

    ``view``: the image's pose (``ImageView``): the far edge measured in it and where the pose expects it are drawn.
    """
    height, width = bgr.shape[:2]
    size = (max(1, int(round(width * scale))), max(1, int(round(height * scale))))
    image = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
    if view is None or np.array_equal(view.image_to_reference, np.eye(3)):  # a moving camera's band is warped
        top, bottom = detector.band((width, height))
        for y in (top, bottom - 1):
            row = int(round(y * scale))
            cv2.line(image, (0, row), (size[0] - 1, row), (255, 200, 0), 1)
    for polygon in detector.mask.scaled_polygons((width, height)):
        cv2.polylines(image, [np.round(polygon * scale).astype(np.int32)], True, (0, 0, 255), 1)
    for box, score, label in zip(detections.boxes_xyxy, detections.scores, detections.labels(), strict=True):
        x1, y1, x2, y2 = (int(round(v * scale)) for v in box)
        cv2.rectangle(image, (x1, y1), (x2, y2), (0, 255, 0), 1)
        cv2.putText(image, f"{label} {score:.2f}", (x1, max(8, y1 - 3)), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                    (0, 255, 0), 1, cv2.LINE_AA)
    if view is not None:
        view.draw_horizon(image, (width, height), scale)
    return image
