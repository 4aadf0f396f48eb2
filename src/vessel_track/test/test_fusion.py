"""Fusion of position and size cues, covariance, and the per-track TrackFuser (ROS-free)."""
import math

import numpy as np
import pytest

from vessel_calib.camera_model import CameraModel
from vessel_common.errors import DataError
from vessel_common.state_file import StateFile, settings_fingerprint
from vessel_fixtures.presets import paper_selection
from vessel_tools.track.pipeline import screen_track_of
from vessel_tools.track.simulation import challenge_camera, harbour_scenario
from vessel_track.distance_model import BoxSizeDistanceModel, depth_of_world
from vessel_track.fuser_settings import FuserSettings
from vessel_track.fusion import (
    REASON_ABOVE_HORIZON,
    REASON_BEYOND_RANGE,
    REASON_INVALID_INPUT,
    CueStatistics,
    FusionConfig,
    fit_cue_statistics,
    fuse_boxes,
    gls_weights,
)
from vessel_track.track_fuser import ScreenTrack, TrackFuser
from vessel_track.tracker import MultiTargetTracker
from vessel_track.tracker_config import TrackerConfig

MODEL = BoxSizeDistanceModel(a=3000.0, b=5.0, c=1500.0, d=2.0)


def _boxes_at(camera, world, model=MODEL):
    xs, ys, _ = camera.world_to_screen(world[:, 0], world[:, 1])
    w, h = model.size_of_depth(depth_of_world(camera, world[:, 0], world[:, 1]))
    return np.column_stack([xs - w / 2, ys - h / 2, xs + w / 2, ys + h / 2])


def _world(n=200, seed=0, far=500.0):
    rng = np.random.default_rng(seed)
    r = rng.uniform(40, far, n)
    b = np.radians(rng.uniform(55, 100, n))
    return np.column_stack([r * np.sin(b), r * np.cos(b)])


@pytest.mark.parametrize("mode", ["fitted", "paper", "position_only"])
def test_exact_boxes_fuse_to_the_true_position(mode):
    cam = challenge_camera()
    world = _world()
    fused = fuse_boxes(cam, MODEL, _boxes_at(cam, world), FusionConfig(weights_mode=mode))
    assert fused.valid.all()
    np.testing.assert_allclose(fused.world, world, atol=1e-3)
    np.testing.assert_allclose(fused.weights.sum(axis=1), 1.0)


def test_gls_weights_minimise_variance_and_handle_missing_cues():
    cov = np.array([[4.0, -1.0, -1.0], [-1.0, 36.0, 20.0], [-1.0, 20.0, 25.0]])
    w, var = gls_weights(cov, np.ones(3, bool))
    assert w.sum() == pytest.approx(1.0)
    assert var == pytest.approx(w @ cov @ w)
    for other in ([0.5, 0.25, 0.25], [1.0, 0.0, 0.0], [0.6, 0.2, 0.2]):
        assert var <= np.asarray(other) @ cov @ np.asarray(other) + 1e-12
    w2, var2 = gls_weights(cov, np.array([True, False, True]))
    assert w2[1] == 0 and w2.sum() == pytest.approx(1.0) and var2 > var


def test_noisy_boxes_fitted_weights_beat_position_only_and_covariance_is_honest():
    cam = challenge_camera()
    rng = np.random.default_rng(5)
    train, test = _world(400, 1, far=250.0), _world(400, 2, far=250.0)

    def noisy(world, seed):
        r = np.random.default_rng(seed)
        b = _boxes_at(cam, world)
        b[:, [1, 3]] += r.normal(0, 2.0, (len(b), 1))   # the box moves up/down: position cue noise
        b += r.normal(0, 1.5, b.shape)                   # edges jitter: size and position noise
        return b

    stats = fit_cue_statistics(cam, MODEL, noisy(train, 11), train)
    assert stats.std_px[0] == pytest.approx(math.hypot(2.0, 1.5 / math.sqrt(2)), rel=0.25)
    boxes = noisy(test, 12)
    errors = {}
    for mode in ("position_only", "paper", "fitted"):
        fused = fuse_boxes(cam, MODEL, boxes, FusionConfig(weights_mode=mode), stats)
        errors[mode] = np.hypot(*(fused.world - test).T)
        if mode == "fitted":
            e = fused.world - test
            nees = np.einsum("ni,nij,nj->n", e, np.linalg.inv(fused.covariance), e)
            # Chi-square with 2 degrees of freedom: mean 2 when the covariance is right.
            assert 1.2 < np.mean(nees) < 3.5
    print({k: round(float(np.nanmedian(v)), 2) for k, v in errors.items()})
    assert all(np.isfinite(v).all() for v in errors.values())
    assert np.median(errors["fitted"]) < np.median(errors["position_only"])
    assert np.median(errors["fitted"]) <= np.median(errors["paper"]) * 1.05
    assert rng is not None


def test_rejections_horizon_range_and_bad_boxes():
    cam = challenge_camera()
    horizon = float(cam.horizon_y(640.0))
    boxes = np.array([
        [630, horizon - 20, 650, horizon - 10],       # above the horizon
        [630, horizon + 0.05, 650, horizon + 0.35],   # a sliver below it: kilometres away
        [630, 500, 650, np.nan],                      # NaN
        [650, 500, 630, 520],                         # negative width
        [600, 500, 680, 540],                         # fine
    ])
    fused = fuse_boxes(cam, MODEL, boxes, FusionConfig(weights_mode="position_only", max_range_m=2000.0))
    assert fused.reason.tolist() == [REASON_ABOVE_HORIZON, REASON_BEYOND_RANGE, REASON_INVALID_INPUT,
                                     REASON_INVALID_INPUT, 0]
    assert np.isnan(fused.world[:4]).all() and np.isfinite(fused.world[4]).all()
    clipped = fuse_boxes(cam, MODEL, boxes[1:2], FusionConfig(weights_mode="position_only", max_range_m=1e7,
                                                              clip_m=2000.0))
    assert np.all(np.abs(clipped.world) <= 2000.0)


def test_cut_box_drops_its_size_cue():
    cam = challenge_camera()
    world = np.array([[60.0, 10.0]])
    box = _boxes_at(cam, world)
    box[0, 2] = 1280.0  # right edge at the border
    fused = fuse_boxes(cam, MODEL, box, FusionConfig())
    assert np.isnan(fused.cue_y[0, 1]) and np.isfinite(fused.cue_y[0, 2])
    assert fused.weights[0, 1] == 0.0


def _track(tid, center, size=(30.0, 12.0), status=1, updated=True, conf=0.9):
    return ScreenTrack(tid, status, np.array(center, float), np.array(size, float), conf, updated)


def test_track_fuser_filters_selects_and_survives_bad_input():
    cam = challenge_camera()
    fuser = TrackFuser(cam, MODEL)
    world_path = np.column_stack([150.0 + 2.0 * np.arange(12) * 4, 120.0 - 0.5 * np.arange(12) * 4])
    boxes = _boxes_at(cam, world_path)
    outputs = []
    for k in range(12):
        c = (boxes[k, :2] + boxes[k, 2:]) / 2
        s = boxes[k, 2:] - boxes[k, :2]
        tracks = [_track("A", c, s), _track("B", [300.0, 600.0], [40, 20], conf=0.4),
                  _track("N", [np.nan, 500.0])]
        outputs.append(fuser.update(1000.0 + 4 * k, tracks))
    last = {w.screen.track_id: w for w in outputs[-1]}
    assert last["A"].is_target and not last["B"].is_target and not last["N"].has_world
    assert np.hypot(*(last["A"].position - world_path[-1])) < 1.0
    assert last["A"].velocity == pytest.approx([2.0, -0.5], abs=0.2)
    assert last["A"].expected_error_m == pytest.approx(0.0555 * last["A"].distance_m)
    lat, lon = cam.world_to_gps(*last["A"].position)
    assert (last["A"].latitude, last["A"].longitude) == pytest.approx((lat, lon))
    assert fuser.counts["invalid_track"] == 12
    # A replay restarting: stamps go back; everything resets, nothing raises.
    again = fuser.update(1000.0, [_track("A", (boxes[0, :2] + boxes[0, 2:]) / 2, boxes[0, 2:] - boxes[0, :2])])
    assert fuser.counts["stamp_backwards"] == 1 and again[0].has_world
    with pytest.raises(DataError):
        fuser.update(math.nan, [])


def test_cue_statistics_validation():
    with pytest.raises(DataError):
        CueStatistics(covariance=-np.eye(3))
    with pytest.raises(DataError):
        FusionConfig(weights_mode="magic")
    for offset in (2.0, -1.5, float("nan")):
        with pytest.raises(DataError, match="anchor_offset"):
            FusionConfig(anchor_offset=offset)


def test_boxes_are_read_at_the_calibrations_anchor_plus_the_offset():
    """A calibration fitted on points 0.7 of the way down maps that point of a box to the vessel."""
    low = CameraModel.from_params(dict(challenge_camera().to_params(), box_anchor=0.7))
    world = _world(20, seed=3)
    xs, ys, _ = low.world_to_screen(world[:, 0], world[:, 1])
    h = np.full(len(xs), 20.0)
    boxes = np.column_stack([xs - 10, ys - 0.7 * h, xs + 10, ys + 0.3 * h])
    exact = fuse_boxes(low, MODEL, boxes, FusionConfig(weights_mode="position_only"))
    np.testing.assert_allclose(exact.world, world, rtol=1e-6)
    # the same vessels boxed 4 px higher (a detector drawing them differently): read 0.2 box heights lower
    shifted = boxes - np.array([0.0, 4.0, 0.0, 4.0])
    corrected = fuse_boxes(low, MODEL, shifted, FusionConfig(weights_mode="position_only", anchor_offset=0.2))
    np.testing.assert_allclose(corrected.world, world, rtol=1e-6)
    uncorrected = fuse_boxes(low, MODEL, shifted, FusionConfig(weights_mode="position_only"))
    assert not np.any(np.hypot(*(uncorrected.world - world).T) < 0.5)  # metres off, or above the horizon


def test_a_parameter_file_with_the_old_fusion_anchor_says_where_it_went():
    with pytest.raises(DataError, match="camera.box_anchor"):
        FuserSettings.from_params({"fusion": {"anchor": 0.5}})
    settings = FuserSettings.from_params({"fusion": {"anchor_offset": 0.05}})
    assert settings.fusion.anchor_offset == 0.05
    assert settings.for_hand_boxes().fusion.anchor_offset == 0.0
    assert settings.for_hand_boxes().fusion.weights_mode == settings.fusion.weights_mode


def _one_track_through(cam, config, box_rows):
    """(fuser, its output for track "A") of boxes fed one per frame, 4 s apart."""
    fuser = TrackFuser(cam, MODEL, fusion_config=config)
    outs = [{w.screen.track_id: w for w in fuser.update(1000.0 + 4 * k, [_track("A", *_centre_size(b))])}["A"]
            for k, b in enumerate(box_rows)]
    return fuser, outs


def test_a_box_that_took_in_spray_is_trusted_less():
    """A box suddenly taller for its width (spray or wake below a fast hull) reads too near: its covariance grows.

    The track's next position then follows its motion more than that box; a slow change of shape (a vessel
    turning) is not suspect, and hand-drawn boxes are never read this way.
    """
    cam = challenge_camera()
    path = np.column_stack([150.0 + 2.0 * np.arange(10) * 4, 120.0 + 0.0 * np.arange(10)])
    boxes = _boxes_at(cam, path)
    spray = boxes.copy()
    spray[7, 3] += 1.2 * (boxes[7, 3] - boxes[7, 1])   # the same hull, the box 2.2 times as tall below it

    off_fuser, off = _one_track_through(cam, FusionConfig(), spray)
    on_fuser, on = _one_track_through(cam, FusionConfig(shape_jump_ratio=1.5, shape_jump_variance_factor=9.0), spray)
    assert on_fuser.counts.get("shape_jump") == 1 and "shape_jump" not in off_fuser.counts
    np.testing.assert_allclose(on[7].measured_covariance, 9.0 * off[7].measured_covariance)
    np.testing.assert_allclose(on[6].measured_covariance, off[6].measured_covariance)
    assert np.hypot(*(on[7].measured_position - path[7])) > 10.0      # the spray box reads metres too near ...
    error_on, error_off = (np.hypot(*(o[7].position - path[7])) for o in (on, off))
    assert error_on < 0.5 * error_off                                  # ... which the suspicious filter discounts
    turning = boxes.copy()
    centre_x = (boxes[:, 0] + boxes[:, 2]) / 2
    half_width = (boxes[:, 2] - boxes[:, 0]) / 2 * 0.88 ** np.arange(10)   # bow slowly towards the camera
    turning[:, 0], turning[:, 2] = centre_x - half_width, centre_x + half_width
    assert "shape_jump" not in _one_track_through(cam, FusionConfig(shape_jump_ratio=1.5), turning)[0].counts
    hand = FuserSettings.from_params({"fusion": {"shape_jump_ratio": 1.5}}).for_hand_boxes()
    assert hand.fusion.shape_jump_ratio == 0.0
    for bad in ({"shape_jump_ratio": 0.5}, {"shape_jump_ratio": float("nan")}, {"shape_jump_variance_factor": 0.5}):
        with pytest.raises(DataError, match="shape_jump"):
            FusionConfig(**bad)


def _centre_size(box):
    return (box[:2] + box[2:]) / 2, box[2:] - box[:2]


def test_a_joined_track_continues_the_world_filter_of_the_one_it_continues():
    """The new track id of a vessel the tracker lost keeps the old filter's velocity (not a cold start at 0 m/s)."""
    cam = challenge_camera()
    fuser = TrackFuser(cam, MODEL)
    path = np.column_stack([150.0 + 3.0 * np.arange(12) * 4, 120.0 + 0.0 * np.arange(12)])
    boxes = _boxes_at(cam, path)
    for k in range(8):
        fuser.update(1000.0 + 4 * k, [_track("A", *_centre_size(boxes[k]))])
    fuser.update(1032.0, [_track("A", *_centre_size(boxes[7]), status=3, updated=False)])
    out = {w.screen.track_id: w for w in fuser.update(1036.0, [_track("B", *_centre_size(boxes[9]), status=0)])}
    assert fuser.selector.continued == {"B": "A"}
    assert out["B"].is_target
    assert out["B"].velocity == pytest.approx([3.0, 0.0], abs=0.5)
    assert np.hypot(*(out["B"].position - path[9])) < 5.0
    # Without the join (a fuser that never saw A) the same box starts at rest.
    cold = TrackFuser(cam, MODEL).update(1036.0, [_track("B", *_centre_size(boxes[9]), status=0)])
    assert cold[0].velocity == pytest.approx([0.0, 0.0])


def test_a_target_track_that_jumps_onto_another_vessel_stops_being_the_target():
    """A track moved onto another boat stops being the vessel of interest.

    A live camera (10 frames/s): the tracker's track of the vessel moves onto a boat 60 m away, which the world
    filter rejects ``max_rejections`` times in a row; the track's identity changes and no fix is published for the
    other boat.
    """
    cam = challenge_camera()
    fuser = TrackFuser(cam, MODEL, selection_config=paper_selection(reacquire_window_s=3600.0))
    t = np.arange(80) * 0.1
    vessel = np.column_stack([60.0 + 3.0 * t, 40.0 + 0.0 * t])
    other = np.column_stack([120.0 + 0.0 * t, 20.0 + 0.0 * t])
    targets = []
    for k in range(80):
        where = vessel[k] if k < 60 else other[k]
        box = _boxes_at(cam, where[None, :])[0]
        out = fuser.update(1000.0 + t[k], [_track("A", *_centre_size(box))])
        targets.append(out[0].is_target)
    assert all(targets[:60]) and not any(targets[65:])
    assert fuser.counts["identity_changed"] == 1 and fuser.selector.identity_changes == 1


def test_the_fuser_follows_the_tide_at_each_frames_stamp():
    """A vessel moored 150 m out while the tide falls 0.35 m an hour under a camera 2.6 m up.

    The boxes come from the true camera at each instant. With the water-level table the fused range stays right;
    with the calibration's fixed H the vessel seems to come closer by about 13 % an hour.
    """
    from vessel_calib.camera_model import CameraModel
    from vessel_calib.water_level import WaterLevelTable

    base = challenge_camera()
    calibrated = CameraModel(base.H, base.K1, base.center, base.image_size, base.camera_lat, base.camera_lon,
                             base.box_anchor, water_level_m=1.0, height_m=base.pinhole().height_m)
    t0 = 1601494200.0
    table = WaterLevelTable(np.array([t0, t0 + 3600.0]), np.array([1.0, 0.65]), source="falling tide")
    vessel = np.array([[120.0, 90.0]])
    tided = TrackFuser(calibrated, MODEL, water_level=table)
    fixed = TrackFuser(calibrated, MODEL)
    errors = {"tided": [], "fixed": []}
    for k in range(0, 13):
        stamp = t0 + 300.0 * k
        truth = calibrated.at_water_level(table.level_at(stamp))
        box = _boxes_at(truth, vessel)[0]
        for name, fuser in (("tided", tided), ("fixed", fixed)):
            out = fuser.update(stamp, [_track("A", *_centre_size(box))])[0]
            errors[name].append(float(np.hypot(*(out.measured_position - vessel[0]))))
    assert max(errors["tided"]) < 0.5
    assert errors["fixed"][-1] > 15.0 > errors["fixed"][0] + 10.0     # 150 m x 13 %/h after an hour
    # outside the table (plus the hold) the frame is fused at the calibration's level, and counted
    late = t0 + 3600.0 + tided.water_level_max_hold_s + 60.0
    tided.update(late, [_track("A", *_centre_size(_boxes_at(calibrated, vessel)[0]))])
    assert tided.counts.get("water_level_unknown") == 1
    with pytest.raises(DataError, match="no camera.water_level_m"):
        TrackFuser(base, MODEL, water_level=table)


def test_a_box_of_only_the_cabin_is_trusted_less():
    """A box much shorter than its track's last boxes (the detector boxed the console, not the hull) reads too far.

    Its covariance grows, so the filter follows the track's motion through it; a vessel slowly going away
    (its boxes shrinking a few per cent a frame) is not suspect, and hand-drawn boxes are never read this way.
    """
    cam = challenge_camera()
    path = np.column_stack([150.0 + 2.0 * np.arange(10) * 4, 120.0 + 0.0 * np.arange(10)])
    boxes = _boxes_at(cam, path)
    cabin = boxes.copy()
    cabin[7, 3] -= 0.5 * (boxes[7, 3] - boxes[7, 1])   # the top half of the boat only

    off_fuser, off = _one_track_through(cam, FusionConfig(), cabin)
    on_fuser, on = _one_track_through(cam, FusionConfig(height_drop_ratio=0.75, shape_jump_variance_factor=9.0), cabin)
    assert on_fuser.counts.get("height_drop") == 1 and "height_drop" not in off_fuser.counts
    np.testing.assert_allclose(on[7].measured_covariance, 9.0 * off[7].measured_covariance)
    true_range = np.hypot(*path[7])
    assert np.hypot(*on[7].measured_position) > true_range + 10.0       # the cabin box reads metres too far ...
    error_on, error_off = (np.hypot(*(o[7].position - path[7])) for o in (on, off))
    assert error_on < 0.5 * error_off                                    # ... which the suspicious filter discounts
    going_away = _boxes_at(cam, np.column_stack([100.0 + 3.0 * np.arange(10) * 4, 80.0 + 2.0 * np.arange(10) * 4]))
    assert "height_drop" not in _one_track_through(cam, FusionConfig(height_drop_ratio=0.75), going_away)[0].counts
    hand = FuserSettings.from_params({"fusion": {"height_drop_ratio": 0.75}}).for_hand_boxes()
    assert hand.fusion.height_drop_ratio == 0.0
    for bad in (1.0, -0.1, float("nan")):
        with pytest.raises(DataError, match="height_drop_ratio"):
            FusionConfig(height_drop_ratio=bad)


def _run_tracker_and_fuser(frames, tracker, fuser):
    out = []
    for frame in frames:
        states = tracker.update(frame.stamp, frame.boxes_xyxy, frame.scores)
        world = fuser.update(frame.stamp, [screen_track_of(s) for s in states])
        out.append([(w.screen.track_id, w.screen.status, bool(w.is_target), tuple(np.round(w.position, 9)))
                    for w in world])
    return out


def test_a_tracker_and_fuser_restored_from_their_files_carry_on_as_if_never_stopped(tmp_path):
    frames = harbour_scenario(seed=3).run().frames
    camera, model, config = challenge_camera(), BoxSizeDistanceModel(), TrackerConfig()
    straight = _run_tracker_and_fuser(frames, MultiTargetTracker(config), TrackFuser(camera, model))
    assert any(is_target for frame in straight for _, _, is_target, _ in frame)

    tracker, fuser = MultiTargetTracker(config), TrackFuser(camera, model)
    half = len(frames) // 2
    before = _run_tracker_and_fuser(frames[:half], tracker, fuser)
    files = {name: StateFile(tmp_path / f"{name}.state", name, settings_fingerprint(config), period_s=0.0)
             for name in ("tracker", "fuser")}
    files["tracker"].save(frames[half - 1].stamp, tracker.snapshot())
    files["fuser"].save(frames[half - 1].stamp, fuser.snapshot())
    del tracker, fuser  # the process dies

    tracker, fuser = MultiTargetTracker(config), TrackFuser(camera, model)
    for name, core in (("tracker", tracker), ("fuser", fuser)):
        reader = StateFile(tmp_path / f"{name}.state", name, settings_fingerprint(config))
        state, why = reader.resume(frames[half].stamp)
        assert state is not None and why.startswith("resumed"), why
        core.restore(state)
    after = _run_tracker_and_fuser(frames[half:], tracker, fuser)
    # Tracks started after the restart are numbered max_tracks further on, past any published before the crash.
    known = {track_id for frame in before for track_id, _, _, _ in frame}

    def renumbered(track_id):
        if track_id in known:
            return track_id
        number = int(track_id[len(config.id_prefix):])
        assert number > config.max_tracks, track_id
        return f"{config.id_prefix}{number - config.max_tracks}"

    after = [[(renumbered(t), *rest) for t, *rest in frame] for frame in after]
    assert any(t not in known for frame in after for t, _, _, _ in frame)
    assert before + after == straight
