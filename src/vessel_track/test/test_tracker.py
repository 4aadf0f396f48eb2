"""Unit tests of the multi-target Kalman tracker (ROS-free)."""

import math

import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_track.association import clutter_cost, cost_matrix
from vessel_track.tracker import MultiTargetTracker, TrackStatus, process_noise_matrix, transition_matrix
from vessel_track.tracker_config import TrackerConfig, load_tracker_config

T0 = 1_601_494_438.0


def box(cx, cy, w=30.0, h=16.0):
    return [cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2]


def by_id(states):
    return {s.track_id: s for s in states}


def live(states):
    return [s for s in states if s.status != TrackStatus.LOST]


# --------------------------------------------------------------------------------------------- filter


@pytest.mark.parametrize("dt", [4.0, 0.03])
def test_constant_velocity_with_dt_from_stamps(dt):
    """The same straight motion sampled every 4 s or every 30 ms gives one track with the true state."""
    velocity = np.array([12.0, 1.5])
    start = np.array([200.0, 420.0])
    tracker = MultiTargetTracker()
    ids = set()
    for t in np.arange(0.0, 80.0 + 1e-9, dt):
        c = start + velocity * t
        states = tracker.update(T0 + t, [box(*c)], [0.9])
        ids |= {s.track_id for s in states}
    (final,) = states
    assert ids == {final.track_id}
    assert final.status == TrackStatus.CONFIRMED
    np.testing.assert_allclose(final.center, start + velocity * 80.0, atol=0.5)
    np.testing.assert_allclose(final.velocity, velocity, atol=0.1)
    assert final.detection_count == len(np.arange(0.0, 80.0 + 1e-9, dt))


def test_continuous_process_noise_is_independent_of_the_frame_rate():
    """Predicting 4 s in one step or in 133 steps of 30 ms gives the same covariance (continuous model)."""

    def predict(model, steps, dt, P0=(100.0, 25.0, 100.0, 4.0)):
        P = np.diag(P0)
        for _ in range(steps):
            F = transition_matrix(dt)
            P = F @ P @ F.T + process_noise_matrix(dt, 1.0, model, 0.25)
        return P

    np.testing.assert_allclose(predict("continuous_wna", 1, 3.99), predict("continuous_wna", 133, 0.03),
                               rtol=1e-9)
    # The paper's Q (and the discrete model) add far less noise when the same time is cut into small steps:
    # why they are not the default.
    zero = (0.0, 0.0, 0.0, 0.0)
    assert predict("paper", 1, 3.99, zero)[1, 1] > 10 * predict("paper", 133, 0.03, zero)[1, 1]
    assert predict("discrete_wna", 1, 3.99, zero)[0, 0] > 10 * predict("discrete_wna", 133, 0.03, zero)[0, 0]


def test_paper_matrices():
    F = transition_matrix(2.0)
    np.testing.assert_array_equal(F, [[1, 2, 0, 0], [0, 1, 0, 0], [0, 0, 1, 2], [0, 0, 0, 1]])
    np.testing.assert_array_equal(process_noise_matrix(2.0, 4.0, "paper"), np.diag([0.0, 16.0, 0.0, 16.0]))
    with pytest.raises(DataError, match="process noise model"):
        process_noise_matrix(1.0, 1.0, "brownian")


# --------------------------------------------------------------------------------------------- association


def _two_static_tracks(config):
    tracker = MultiTargetTracker(config)
    for k in range(6):
        tracker.update(T0 + k, [box(100, 400), box(200, 400)], [0.9, 0.9])
    a, b = tracker.track_ids
    return tracker, a, b


@pytest.mark.parametrize("density, vessel_gets_the_boat", [(2.0, True), (0.0, False)])
def test_a_track_may_stay_unmatched_rather_than_give_the_vessel_its_wake(density, vessel_gets_the_boat):
    """Video 13's second frame: the boat moved 33 px; its wake's box (too wide) lies where the boat was.

    A far sailboat's new track could take the boat's box at a stretch (its velocity is still unknown). Forcing
    both tracks to get a box gives the vessel its wake; with a cost for leaving a track unmatched (the clutter
    likelihood), the vessel keeps its boat and the sailboat's track gets nothing this frame.
    """
    tracker = MultiTargetTracker(TrackerConfig(clutter_density_per_mpx=density))
    t1, t2 = (s.track_id for s in tracker.update(T0, [box(835.6, 436.7, 18.2, 11.4), box(960.4, 412.0, 11.5, 7.1)],
                                                  [0.99, 0.63]))
    wake, boat = box(838.8, 440.2, 44.9, 8.2), box(868.4, 435.3, 24.8, 9.8)
    states = by_id(tracker.update(T0 + 3.85, [wake, boat], [0.99, 0.99]))
    if vessel_gets_the_boat:
        assert states[t1].measured_center[0] == pytest.approx(868.4)
        assert not states[t2].updated
    else:  # no clutter test: as many pairs as the gates allow
        assert states[t1].measured_center[0] == pytest.approx(838.8)
        assert states[t2].measured_center[0] == pytest.approx(868.4)


@pytest.mark.parametrize("association", ["global", "greedy"])
def test_global_assignment_where_greedy_fails(association):
    """Tracks at x=100 and x=200; detections at 160 and 245.

    Nearest-first gives 160 to the track at 200 (40 px) and leaves the one at 100 with a detection out of its
    gate (145 px), so a new track starts; the global assignment pairs 100-160 and 200-245.
    """
    config = TrackerConfig(association=association, distance_metric="euclidean", gate_px=100.0,
                           gate_sigmas=1.0, size_weight=0.0, clutter_density_per_mpx=1.0)
    tracker, a, b = _two_static_tracks(config)
    states = by_id(tracker.update(T0 + 6, [box(160, 400), box(245, 400)], [0.9, 0.9]))
    if association == "global":
        assert set(states) == {a, b}
        assert states[a].measured_center[0] == pytest.approx(160.0)
        assert states[b].measured_center[0] == pytest.approx(245.0)
    else:
        assert states[a].status == TrackStatus.COASTING
        assert states[b].measured_center[0] == pytest.approx(160.0)
        assert len(states) == 3


def test_size_term_decides_between_equally_near_detections():
    tracker = MultiTargetTracker(TrackerConfig(gate_px=100.0))
    for k in range(5):
        tracker.update(T0 + k, [box(300, 420, 30, 16)], [0.9])
    (tid,) = tracker.track_ids
    states = by_id(tracker.update(T0 + 5, [box(290, 420, 80, 40), box(310, 420, 31, 16)], [0.9, 0.9]))
    assert states[tid].measured_size[0] == pytest.approx(31.0)


def _far_track_then_two_boxes(config: TrackerConfig) -> float:
    """The height of the box a far boat's track takes: one at its prediction, or one of its own height below.

    The boat is tracked at 30x16 px, a box every 4 s; then come a box at its prediction 0.6 times its height and a
    box of its own height 25 px lower.
    """
    tracker = MultiTargetTracker(config)
    for k in range(5):
        tracker.update(T0 + 4.0 * k, [box(300, 420, 30, 16)], [0.9])
    (tid,) = tracker.track_ids
    states = by_id(tracker.update(T0 + 20.0, [box(300, 420, 30, 9.6), box(300, 445, 30, 16)], [0.9, 0.9]))
    return float(states[tid].measured_size[1])


ONE_SIZE_MODEL = {"height_log_std": 0.0, "height_log_std_rate": 0.0}
"""The tracker's association with one size model for width and height (the paper's)."""


def test_a_tight_height_model_keeps_a_track_off_a_much_lower_box():
    """With ``height_log_std`` a track takes the box of its own height, not a much lower one nearer its prediction.

    The width varies with the heading, the height with the range only.
    """
    assert _far_track_then_two_boxes(TrackerConfig(**ONE_SIZE_MODEL)) == pytest.approx(9.6)
    assert _far_track_then_two_boxes(TrackerConfig(height_log_std=0.15, height_log_std_rate=0.0)) == \
        pytest.approx(16.0)


@pytest.mark.parametrize("dt, height_px, taken", [(0.04, 120.0, False), (4.0, 120.0, True), (4.0, 12.0, False)])
def test_the_height_model_grows_with_time_and_nearness(dt, height_px, taken):
    """``height_log_std_rate``: a box 1.8 times as high suits a near boat seen 4 s ago, not a far or recent one.

    Neither a far boat seen 4 s ago nor a near one seen 40 ms ago takes it: with the clutter test, the track coasts.
    """
    config = TrackerConfig(height_log_std=0.1, height_log_std_rate=0.001, size_log_std=0.4, gate_px=400.0,
                           max_gate_px=400.0, max_size_ratio=0.0)
    tracker = MultiTargetTracker(config)
    width = 2.0 * height_px
    for k in range(5):
        tracker.update(T0 + k * dt, [box(600, 500, width, height_px)], [0.9])
    (tid,) = tracker.track_ids
    states = by_id(tracker.update(T0 + 5 * dt, [box(600, 500, width, 1.8 * height_px)], [0.9]))
    assert (states[tid].measured_size is not None) == taken


def _two_tracks_and_three_boxes(config: TrackerConfig):
    """Two tracks seen every 4 s, predicted to 16 s; the cost matrix to three boxes, and the clutter cost."""
    tracker = MultiTargetTracker(config)
    for k in range(4):
        tracker.update(T0 + 4 * k, [box(300, 420, 30, 16), box(700, 430, 60, 30)], [0.9, 0.9])
    tracks = list(tracker._tracks)
    for track in tracks:
        tracker._predict(track, T0 + 16)
    centers = np.array([[296, 419], [306, 420], [705, 432]], float)
    sizes = np.array([[26, 8], [30, 15], [50, 40]], float)
    return cost_matrix(config, tracks, centers, sizes), clutter_cost(config), tracks, sizes


def test_without_the_height_parameters_the_costs_are_those_of_one_size_model():
    """``height_log_std`` 0 and rate 0 give the costs of a single size model.

    The size term is sum((ln ratio / size_log_std)^2) and the clutter cost's size part -2 ln(2 pi size_log_std^2).
    """
    config = TrackerConfig(**ONE_SIZE_MODEL)
    cost, clutter, tracks, sizes = _two_tracks_and_three_boxes(config)
    one_model, _, _, _ = _two_tracks_and_three_boxes(TrackerConfig(**ONE_SIZE_MODEL, size_weight=0.0))
    ratio = np.log(sizes[None, :, :] / np.array([t.size for t in tracks])[:, None, :])
    size_term = np.sum((ratio / config.size_log_std) ** 2, axis=2)
    admissible = cost < 1e8
    np.testing.assert_allclose(cost[admissible], (one_model + size_term)[admissible], rtol=1e-9)
    clutter_without_size = clutter_cost(TrackerConfig(**ONE_SIZE_MODEL, size_weight=0.0))
    expected = clutter_without_size + 4.0 * math.log(math.log(10.0)) - 2.0 * math.log(
        2.0 * math.pi * config.size_log_std**2)
    assert clutter == pytest.approx(expected, rel=1e-12)
    # A height model of its own: the clutter's height density is spread over the same decade, normalised by it.
    own_height = clutter_cost(TrackerConfig(height_log_std=0.2, height_log_std_rate=0.0))
    assert own_height == pytest.approx(expected + math.log(config.size_log_std**2 / 0.2**2), rel=1e-12)


def test_a_grown_height_model_pays_its_normaliser():
    """With a rate, a pair's height term is ratio^2 / var + ln(var / height_log_std^2), var grown by the rate.

    The normaliser keeps a track whose model has grown from taking any box for free.
    """
    base, _, tracks, sizes = _two_tracks_and_three_boxes(TrackerConfig(height_log_std=0.2, height_log_std_rate=0.0,
                                                                       max_size_ratio=0.0,
                                                                       clutter_density_per_mpx=0.0))
    grown, _, _, _ = _two_tracks_and_three_boxes(TrackerConfig(height_log_std=0.2, height_log_std_rate=0.01,
                                                               max_size_ratio=0.0, clutter_density_per_mpx=0.0))
    ratio_h = np.log(sizes[None, :, 1] / np.array([t.size[1] for t in tracks])[:, None])
    height_var = np.array([[0.2**2 + (0.01 * t.size[1] * 4.0) ** 2] for t in tracks])
    expected_change = ratio_h**2 / height_var + np.log(height_var / 0.2**2) - ratio_h**2 / 0.2**2
    admissible = (base < 1e8) & (grown < 1e8)
    assert admissible.sum() >= 3
    np.testing.assert_allclose((grown - base)[admissible], expected_change[admissible], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("value", [1e-170, 5e-4])
def test_a_height_model_too_tight_to_compute_is_refused(value):
    with pytest.raises(DataError, match="height_log_std 0"):
        TrackerConfig(height_log_std=value)


def test_crossing_vessels_keep_their_ids():
    """Two boats cross on screen (the far one hidden while they overlap); both keep their ids."""
    tracker = MultiTargetTracker()
    ids_of = {0: set(), 1: set()}
    for k in range(60):
        t = float(k)
        near = np.array([900.0 - 15.0 * t, 440.0])
        far = np.array([300.0 + 12.0 * t, 428.0])
        boxes, gts = [box(*near, 70, 36)], [1]
        if abs(near[0] - far[0]) > 45:
            boxes.append(box(*far, 30, 16))
            gts.append(0)
        states = tracker.update(T0 + t, boxes, [0.9] * len(boxes))
        for s in states:
            if s.status == TrackStatus.CONFIRMED:
                j = int(np.argmin([abs(s.measured_center[0] - (b[0] + b[2]) / 2) for b in boxes]))
                ids_of[gts[j]].add(s.track_id)
    assert len(ids_of[0]) == 1 and len(ids_of[1]) == 1 and ids_of[0] != ids_of[1]


@pytest.mark.parametrize("dt", [4.0, 0.1])
def test_occlusion_of_several_seconds_keeps_the_id(dt):
    tracker = MultiTargetTracker()
    velocity = np.array([-9.0, 0.4])
    ids = set()
    coasting_errors = []
    for t in np.arange(0.0, 120.0 + 1e-9, dt):
        c = np.array([1100.0, 425.0]) + velocity * t
        hidden = 50.0 <= t <= 62.0
        states = tracker.update(T0 + t, [] if hidden else [box(*c)], [] if hidden else [0.8])
        ids |= {s.track_id for s in states}
        if hidden:
            (s,) = states
            assert s.status == TrackStatus.COASTING
            coasting_errors.append(np.hypot(*(s.center - c)))
    assert len(ids) == 1
    assert max(coasting_errors) < 3.0


# --------------------------------------------------------------------------------------------- life cycle


def test_status_transitions_tentative_confirmed_coasting_lost():
    config = TrackerConfig(min_hits=3, max_coast_s=10.0)
    tracker = MultiTargetTracker(config)
    statuses = []
    for k in range(3):
        (s,) = tracker.update(T0 + k, [box(500 + k, 420)], [0.7])
        statuses.append(s.status)
    assert statuses == [TrackStatus.TENTATIVE, TrackStatus.TENTATIVE, TrackStatus.CONFIRMED]
    tid = s.track_id
    (s,) = tracker.update(T0 + 5.0, [], [])
    assert s.status == TrackStatus.COASTING and s.measured_center is None and not s.updated
    assert s.last_seen == T0 + 2 and s.first_seen == T0 and s.detection_count == 3
    (s,) = tracker.update(T0 + 12.0, np.zeros((0, 4)), None)
    assert s.status == TrackStatus.COASTING
    (s,) = tracker.update(T0 + 12.5, [], [])
    assert (s.track_id, s.status) == (tid, TrackStatus.LOST)
    assert tracker.history(tid).stamps.tolist() == [T0, T0 + 1, T0 + 2]
    assert tracker.update(T0 + 13.0, [], []) == []
    with pytest.raises(KeyError):
        tracker.history(tid)
    assert tracker.counters.tracks_lost == 1 and tracker.counters.tracks_confirmed == 1


def test_coasting_track_is_reacquired_and_confirmed_again():
    tracker = MultiTargetTracker()
    for k in range(4):
        tracker.update(T0 + k, [box(400 + 10 * k, 420)], [0.9])
    (s,) = tracker.update(T0 + 4, [], [])
    assert s.status == TrackStatus.COASTING
    np.testing.assert_allclose(s.center, [440.0, 420.0], atol=2.0)
    (s2,) = tracker.update(T0 + 5, [box(450, 420)], [0.9])
    assert (s2.track_id, s2.status) == (s.track_id, TrackStatus.CONFIRMED)


def test_tentative_clutter_is_dropped():
    tracker = MultiTargetTracker(TrackerConfig(tentative_max_misses=2))
    (s,) = tracker.update(T0, [box(100, 600)], [0.3])
    assert s.status == TrackStatus.TENTATIVE
    for k in range(1, 4):
        (s,) = tracker.update(T0 + 0.1 * k, [], [])
        assert s.status == TrackStatus.TENTATIVE
    (s,) = tracker.update(T0 + 0.4, [], [])
    assert s.status == TrackStatus.LOST
    assert tracker.track_ids == []


def test_random_clutter_makes_no_confirmed_track():
    rng = np.random.default_rng(3)
    for dt in (4.0, 0.1):
        tracker = MultiTargetTracker()
        confirmed = set()
        for t in np.arange(0.0, 180.0, dt):
            n = rng.poisson(0.3)
            c = np.c_[rng.uniform(0, 1280, n), rng.uniform(425, 720, n)]
            wh = np.c_[rng.uniform(12, 80, n), rng.uniform(8, 40, n)]
            states = tracker.update(T0 + t, np.c_[c - wh / 2, c + wh / 2], rng.uniform(0.2, 0.6, n))
            confirmed |= {s.track_id for s in states if s.status in (TrackStatus.CONFIRMED, TrackStatus.COASTING)}
        print(f"dt={dt}: {tracker.counters.tracks_created} clutter tracks started, {len(confirmed)} confirmed")
        assert not confirmed


def test_duplicate_boxes_of_one_vessel_make_one_track():
    tracker = MultiTargetTracker()
    for k in range(5):
        states = tracker.update(T0 + k, [box(600 + 5 * k, 420, 40, 20), box(601 + 5 * k, 421, 38, 19)], [0.9, 0.5])
    assert len(states) == 1
    assert tracker.counters.duplicates_suppressed >= 1
    assert states[0].confidence == pytest.approx(0.9)


def test_capacity_is_bounded_and_counted():
    tracker = MultiTargetTracker(TrackerConfig(max_tracks=3))
    states = tracker.update(T0, [box(100 * i + 50, 500) for i in range(6)], np.ones(6))
    assert len(states) == 3
    assert tracker.counters.capacity_drops == 3


def test_history_is_bounded():
    tracker = MultiTargetTracker(TrackerConfig(history_length=5))
    for k in range(12):
        tracker.update(T0 + k, [box(300 + k, 420, 30 + k, 16)], [0.5 + k / 100])
    (tid,) = tracker.track_ids
    hist = tracker.history(tid)
    assert len(hist.stamps) == 5 and hist.stamps[-1] == T0 + 11
    np.testing.assert_allclose(hist.measured_centers[-1], [311.0, 420.0])
    np.testing.assert_allclose(hist.measured_sizes[-1], [41.0, 16.0])
    assert hist.confidences[-1] == pytest.approx(0.61)
    assert hist.filtered_centers.shape == (5, 2)


# --------------------------------------------------------------------------------------------- bad input


def test_invalid_boxes_are_dropped_and_counted():
    tracker = MultiTargetTracker()
    boxes = [
        box(500, 420),
        [np.nan, 400, 520, 430],
        [np.inf, 400, 520, 430],
        [520, 400, 500, 430],  # negative width
        [500, 400, 500, 430],  # zero width
        [500, 430, 520, 400],  # negative height
        box(900, 430),  # NaN score
        [1e300, 400, 1.5e300, 430],  # finite, but no camera's pixel
        [-3e5, 400, -2.9e5, 430],
    ]
    states = tracker.update(T0, boxes, [0.9, 0.9, 0.9, 0.9, 0.9, 0.9, np.nan, 0.9, 0.9])
    assert len(states) == 1
    np.testing.assert_allclose(states[0].center, [500.0, 420.0])
    assert tracker.counters.detections_in == 9
    assert tracker.counters.detections_invalid == 8


def test_low_scores_are_ignored_and_counted():
    tracker = MultiTargetTracker(TrackerConfig(min_score=0.4))
    assert len(tracker.update(T0, [box(100, 500), box(400, 500)], [0.3, 0.5])) == 1
    assert tracker.counters.detections_low_score == 1


def test_bad_stamp_or_shapes_raise_data_error():
    tracker = MultiTargetTracker()
    with pytest.raises(DataError, match="stamp"):
        tracker.update(math.nan, [], [])
    with pytest.raises(DataError, match="shape"):
        tracker.update(T0, [[1, 2, 3]], [0.5])
    with pytest.raises(DataError, match="scores"):
        tracker.update(T0, [box(1, 2)], [0.5, 0.6])
    assert tracker.counters.frames == 0


def test_stamps_going_backwards_reset_the_tracker():
    tracker = MultiTargetTracker()
    for k in range(4):
        tracker.update(T0 + 100 + k, [box(300 + 5 * k, 420), box(800, 430)], [0.9, 0.8])
    old = set(tracker.track_ids)
    # A replay restarted: every track ends (reported once), the frame starts new tracks with new ids.
    states = tracker.update(T0, [box(300, 420)], [0.9])
    lost = {s.track_id for s in states if s.status == TrackStatus.LOST}
    new = [s for s in states if s.status != TrackStatus.LOST]
    assert lost == old
    assert len(new) == 1 and new[0].track_id not in old and new[0].status == TrackStatus.TENTATIVE
    assert tracker.counters.resets == 1
    # A frame slightly out of order is dropped, not a reset.
    tracker.update(T0 + 1.0, [box(305, 420)], [0.9])
    assert tracker.update(T0 + 0.7, [box(305, 420)], [0.9]) == []
    assert tracker.counters.out_of_order_frames == 1 and tracker.counters.resets == 1
    assert tracker.last_stamp == T0 + 1.0


def test_gap_of_minutes_times_tracks_out_without_predicting_far():
    tracker = MultiTargetTracker()
    for k in range(5):
        tracker.update(T0 + k, [box(300 + 20 * k, 420)], [0.9])
    (before,) = live(tracker.update(T0 + 5, [], []))
    states = tracker.update(T0 + 305, [box(700, 430)], [0.9])
    (lost,) = [s for s in states if s.status == TrackStatus.LOST]
    assert lost.track_id == before.track_id
    assert np.hypot(*(lost.center - before.center)) < 1.0  # not 300 s x 20 px/s away
    (fresh,) = live(states)
    assert fresh.track_id != before.track_id and fresh.status == TrackStatus.TENTATIVE
    assert tracker.counters.gaps == 1


def test_empty_frames_predict_only():
    tracker = MultiTargetTracker()
    for k in range(5):
        tracker.update(T0 + k, [box(300 + 20 * k, 420)], [0.9])
    previous = None
    for k in range(5, 10):
        (s,) = tracker.update(T0 + k, np.zeros((0, 4)), np.zeros(0))
        assert s.status == TrackStatus.COASTING
        if previous is not None:
            assert s.center[0] - previous.center[0] == pytest.approx(20.0, abs=0.5)
            assert np.trace(s.center_cov) > np.trace(previous.center_cov)
        previous = s


# --------------------------------------------------------------------------------------------- config


def test_config_validation_names_the_field():
    with pytest.raises(DataError, match="measurement_std_px"):
        TrackerConfig(measurement_std_px=-1.0)
    with pytest.raises(DataError, match="max_coast_s"):
        TrackerConfig(max_coast_s=math.nan)
    with pytest.raises(DataError, match="association"):
        TrackerConfig(association="nearest")
    with pytest.raises(DataError, match="min_hits"):
        TrackerConfig(min_hits=0)
    with pytest.raises(DataError, match="max_gate_px"):
        TrackerConfig(gate_px=100.0, max_gate_px=50.0)
    with pytest.raises(DataError, match="unknown field"):
        TrackerConfig.from_dict({"gate": 3})
    config = TrackerConfig.from_dict({"gate_px": 80.0, "min_hits": 2})
    assert config.gate_px == 80.0 and TrackerConfig.from_dict(config.to_dict()) == config


def test_the_pipeline_tracks_with_the_parameter_files_tracker_settings(tmp_path):
    """What the tracker node declares from a parameter file, the ROS-free pipeline reads from it too."""
    from pathlib import Path

    path = tmp_path / "graph.yaml"
    path.write_text("/**:\n  ros__parameters: {use_sim_time: false, gate_px: 50.0}\n"
                    "tracker:\n  ros__parameters:\n    input_topic: /x\n    qos_depth: 5\n    min_hits: 2\n"
                    "    max_coast_s: 12.0\nfuser:\n  ros__parameters: {min_hits: 9}\n")
    config = load_tracker_config(path)
    assert (config.min_hits, config.max_coast_s, config.gate_px) == (2, 12.0, 50.0)
    assert config.measurement_std_px == TrackerConfig().measurement_std_px and load_tracker_config(None) == \
        TrackerConfig()
    path.write_text("tracker:\n  ros__parameters: {min_hits: 0}\n")
    with pytest.raises(DataError, match=r"graph.yaml: .*min_hits"):
        load_tracker_config(path)
    with pytest.raises(DataError, match="no such|cannot read"):
        load_tracker_config(tmp_path / "absent.yaml")
    root = Path(__file__).resolve().parents[3] / "config"
    if (root / "parts" / "tracker.yaml").is_file():
        assert load_tracker_config(root / "parts" / "tracker.yaml") == TrackerConfig()   # the node's defaults
        load_tracker_config(root / "aitas.yaml")


def test_min_hits_one_confirms_at_once():
    tracker = MultiTargetTracker(TrackerConfig(min_hits=1))
    (s,) = tracker.update(T0, [box(100, 500)], [0.9])
    assert s.status == TrackStatus.CONFIRMED


def test_tracks_carry_the_class_of_their_latest_detection():
    from vessel_track.tracker import MultiTargetTracker
    from vessel_track.tracker_config import TrackerConfig

    tracker = MultiTargetTracker(TrackerConfig(min_hits=1))
    first = tracker.update(0.0, [[100, 100, 140, 120], [400, 100, 440, 120]], [0.9, 0.2],
                           ["vessel_of_interest", "vessel"])
    assert sorted(s.label for s in first) == ["vessel", "vessel_of_interest"]
    again = tracker.update(1.0, [[101, 100, 141, 120]], [0.4], ["vessel"])
    by_id = {s.track_id: s.label for s in again}
    assert sorted(by_id.values()) == ["vessel", "vessel"]
    assert [s.label for s in tracker.update(2.0, [[0, 0, 0, 0]], [0.5], ["x"])] == ["vessel", "vessel"]
    with pytest.raises(DataError, match="labels"):
        tracker.update(3.0, [[1, 1, 5, 5]], [0.5], ["a", "b"])


def test_confidence_agreement_keeps_tracks_on_their_vessels_where_they_pass():
    """Two boats pass further than predicted between sparse frames: by motion alone the tracks swap boats."""
    def run(weight):
        tracker = MultiTargetTracker(TrackerConfig(confidence_weight=weight, min_hits=1))
        for k in range(4):  # the vessel of interest (p 0.8) heading east, another boat (p 0.02) heading west
            tracker.update(T0 + 4.0 * k, [box(500 + 10 * k, 420), box(600 - 10 * k, 424)], [0.8, 0.02])
        states = tracker.update(T0 + 16.0, [box(566, 421), box(534, 423)], [0.8, 0.02])
        return {s.track_id: round(float(s.center[0])) for s in states}

    assert run(0.0) == {"T1": 534, "T2": 566}    # swapped: T1 followed the vessel, now it has the other boat
    assert run(2.0) == {"T1": 565, "T2": 535}    # each track keeps its boat
    with pytest.raises(DataError, match="confidence_weight"):
        TrackerConfig(confidence_weight=-1.0)
    with pytest.raises(DataError, match="confidence_memory"):
        TrackerConfig(confidence_memory=0)
