"""Screen tracks of vessels at chosen positions, as the tracker would publish them to the fuser."""

from __future__ import annotations

import math


def screen_track(header, track_id: str, east_m: float, north_m: float, camera, *, confidence: float,
                 detection_count: int, first_seen):
    """A confirmed ``VesselTrack`` boxing a vessel at (east, north) m from ``camera``; a NaN east gives a bad box.

    The box is where ``camera`` sees that point, sized by the default box-size distance model, so the fuser places
    the vessel back where it was put up to its filter's smoothing; the bad box (a NaN centre) is one it must refuse.
    The track was last seen at ``header.stamp``.
    """
    from vessel_msgs.msg import VesselTrack
    from vessel_track.distance_model import BoxSizeDistanceModel, depth_of_world

    msg = VesselTrack()
    msg.header = header
    msg.id, msg.status, msg.confidence = track_id, VesselTrack.STATUS_CONFIRMED, confidence
    msg.detection_count = detection_count
    msg.first_seen, msg.last_seen = first_seen, header.stamp
    if math.isnan(east_m):
        msg.bbox.center.position.x, msg.bbox.center.position.y = math.nan, 500.0
        msg.bbox.size_x = msg.bbox.size_y = 10.0
    else:
        xs, ys, _ = camera.world_to_screen(east_m, north_m)
        w, h = BoxSizeDistanceModel().size_of_depth(depth_of_world(camera, east_m, north_m))
        msg.bbox.center.position.x, msg.bbox.center.position.y = float(xs), float(ys)
        msg.bbox.size_x, msg.bbox.size_y = float(w), float(h)
    msg.screen_covariance = [16.0, 0.0, 0.0, 16.0]
    return msg
