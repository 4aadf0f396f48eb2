"""The fuser node's message path and ``pipeline --mode online`` fuse the same boxes and give the same output.

The detections of a simulated scene go (a) through ``pipeline.run_video`` and (b) through the node functions:
``MultiTargetTracker`` -> ``tracker_node.track_to_msg`` -> ``fuser_node.screen_track_from_msg`` ->
``TrackFuser`` -> ``fuser_node.fill_world_fields``, for both ``fusion.screen_source`` values. Needs the built
message package (``source ros2_ws/install/setup.bash``); skipped otherwise. No processes, no DDS.
"""
import dataclasses
import math

import numpy as np
import pytest

pytest.importorskip("rclpy", reason="rclpy is not importable: source ros2_ws/install/setup.bash")
pytest.importorskip("vessel_msgs.msg", reason="vessel_msgs is not built: build ros2_ws first")

from std_msgs.msg import Header

from vessel_common.qos import sec_to_stamp, stamp_to_sec
from vessel_tools.track import pipeline as pl
from vessel_tools.track.simulation import LinePath, Scenario, SimVessel, bearing_point
from vessel_track.fuser_node import fill_world_fields, screen_track_from_msg
from vessel_track.fuser_settings import FuserSettings
from vessel_track.fusion import FusionConfig
from vessel_track.track_fuser import TrackFuser
from vessel_track.tracker import MultiTargetTracker
from vessel_track.tracker_config import TrackerConfig
from vessel_track.tracker_node import track_to_msg


def _scene():
    vessels = [SimVessel(0, LinePath(bearing_point(220.0, 55.0), heading_deg=167.0, speed_mps=2.5)),
               SimVessel(1, LinePath(bearing_point(120.0, 95.0), heading_deg=-20.0, speed_mps=1.5))]
    return Scenario(vessels=vessels, duration_s=80.0, frame_interval_s=4.0, seed=5).run()


def _node_path(frames, camera, settings: FuserSettings):
    """(stamp, track id) -> (x, y, is_target, has_world) through the messages the nodes exchange."""
    tracker = MultiTargetTracker(TrackerConfig())
    s = settings
    fuser = TrackFuser(camera, s.distance_model, s.fusion, s.cue_stats, s.motion, s.selection, s.error_model)
    out = {}
    for frame in frames:
        header = Header(frame_id="camera")
        header.stamp = sec_to_stamp(frame.stamp)
        stamp = frame.stamp
        messages = [track_to_msg(state, header) for state in tracker.update(stamp, frame.boxes, frame.scores)]
        # What the fuser node receives: the stamp converted from the header, as the node does.
        received = stamp_to_sec(header.stamp)
        screen = [screen_track_from_msg(m, received, s.fusion.screen_source) for m in messages]
        world = fuser.update(received, screen)
        by_id = {id(w.screen): w for w in world}
        for msg, st in zip(messages, screen, strict=True):
            filled = fill_world_fields(msg, by_id[id(st)])
            out[(round(stamp, 3), filled.id)] = (filled.position.x, filled.position.y, filled.is_target,
                                                 filled.has_world)
    return out


@pytest.mark.parametrize("source", ["measured", "filtered"])
def test_node_functions_and_online_pipeline_agree(source):
    result = _scene()
    frames = [pl.DetectionFrame(0, k, f.stamp, f.boxes_xyxy, f.scores) for k, f in enumerate(result.frames)]
    settings = dataclasses.replace(FuserSettings(), fusion=FusionConfig(screen_source=source))
    config = pl.PipelineConfig(mode="online", settings=settings)
    assert config.screen_source == source  # the pipeline follows the fuser parameter, as the node does
    (video,) = pl.run(frames, result.camera, config)
    expected = {(round(r.stamp, 3), r.world.screen.track_id): (float(r.world.position[0]),
                                                               float(r.world.position[1]), r.world.is_target,
                                                               r.world.has_world)
                for r in video.track_rows}
    got = _node_path(frames, result.camera, settings)
    assert set(got) == set(expected)
    assert sum(v[2] for v in expected.values()) > 5  # a target was chosen, so the comparison means something
    for key, (x, y, is_target, has_world) in expected.items():
        gx, gy, g_target, g_world = got[key]
        assert (g_target, g_world) == (is_target, has_world), key
        if has_world:
            assert math.isclose(gx, x, abs_tol=1e-6) and math.isclose(gy, y, abs_tol=1e-6), (key, gx, x, gy, y)


def test_measured_source_uses_the_detection_box_and_filtered_the_tracker_box():
    result = _scene()
    tracker = MultiTargetTracker(TrackerConfig())
    header = Header()
    used = 0
    for frame in result.frames:
        header.stamp = sec_to_stamp(frame.stamp)
        stamp = stamp_to_sec(header.stamp)
        for state in tracker.update(frame.stamp, frame.boxes_xyxy, frame.scores):
            msg = track_to_msg(state, header)
            measured = screen_track_from_msg(msg, stamp, "measured")
            filtered = screen_track_from_msg(msg, stamp, "filtered")
            np.testing.assert_allclose(filtered.center, state.center)
            if state.measured_center is not None:
                np.testing.assert_allclose(measured.center, state.measured_center)
                np.testing.assert_allclose(measured.size, state.measured_size)
                used += not np.allclose(measured.center, filtered.center)
            else:
                np.testing.assert_allclose(measured.center, state.center)  # coasting: the filtered box
    assert used > 10
