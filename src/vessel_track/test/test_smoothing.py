"""World Kalman filter and the offline smoother (ROS-free)."""
import numpy as np
import pytest

from vessel_common.errors import DataError
from vessel_track.smoothing import (
    MotionConfig,
    WorldKalmanFilter,
    cv_process_noise,
    cv_transition,
    rts_smooth,
    smooth_with_outlier_masking,
)


def _straight_run(n=60, dt=4.0, seed=1, sigma_range=15.0, sigma_cross=3.0):
    rng = np.random.default_rng(seed)
    t = 1.6e9 + np.arange(n) * dt
    truth = np.column_stack([100.0 + 2.0 * (t - t[0]), 200.0 + 0.5 * (t - t[0])])
    # Anisotropic noise like a fused position: long along the line of sight.
    u = truth / np.linalg.norm(truth, axis=1)[:, None]
    v = np.column_stack([-u[:, 1], u[:, 0]])
    noise = u * rng.normal(0, sigma_range, (n, 1)) + v * rng.normal(0, sigma_cross, (n, 1))
    R = np.array([sigma_range**2 * np.outer(a, a) + sigma_cross**2 * np.outer(b, b) for a, b in zip(u, v, strict=True)])
    return t, truth, truth + noise, R


def test_process_noise_is_consistent_across_frame_rates():
    q = 0.7
    F4, Q4 = cv_transition(4.0), cv_process_noise(4.0, q)
    P = np.zeros((4, 4))
    for _ in range(100):
        P = cv_transition(0.04) @ P @ cv_transition(0.04).T + cv_process_noise(0.04, q)
    np.testing.assert_allclose(P, F4 @ np.zeros((4, 4)) @ F4.T + Q4, rtol=1e-9, atol=1e-12)


def test_online_filter_beats_raw_measurements():
    t, truth, z, R = _straight_run()
    kf = WorldKalmanFilter(MotionConfig(accel_psd=0.05))
    est = np.array([kf.update(ti, zi, Ri).position for ti, zi, Ri in zip(t, z, R, strict=True)])
    raw = np.hypot(*(z - truth).T)[10:].mean()
    filt = np.hypot(*(est - truth).T)[10:].mean()
    print(f"raw {raw:.2f} m, online filter {filt:.2f} m")
    assert filt < 0.7 * raw


def test_rts_smoother_beats_filter_and_interpolates_missing():
    t, truth, z, R = _straight_run()
    z = z.copy()
    z[20:24] = np.nan  # a stretch without measurements
    cfg = MotionConfig(accel_psd=0.05)
    kf = WorldKalmanFilter(cfg)
    online = np.array([(kf.update(ti, zi, Ri) if np.all(np.isfinite(zi)) else kf.predict(ti)).position
                       for ti, zi, Ri in zip(t, z, R, strict=True)])
    smoothed = rts_smooth(t, z, R, cfg)
    e_online = np.hypot(*(online - truth).T)[10:].mean()
    e_smooth = np.hypot(*(smoothed.positions - truth).T)[10:].mean()
    assert e_smooth < e_online
    assert np.all(np.isfinite(smoothed.positions[20:24]))
    assert np.hypot(*(smoothed.positions[20:24] - truth[20:24]).T).max() < 20.0
    assert not smoothed.used[20:24].any()


def test_outlier_masking_drops_a_gross_outlier_and_keeps_the_rest():
    t, truth, z, R = _straight_run(seed=3)
    z = z.copy()
    z[30] += np.array([400.0, 300.0])
    result = smooth_with_outlier_masking(t, z, R, lambda p: np.hypot(*(p - z).T), threshold=60.0, iterations=5,
                                         config=MotionConfig(accel_psd=0.05))
    assert not result.used[30]
    assert result.used.sum() >= len(t) - 4
    assert np.hypot(*(result.positions[30] - truth[30])) < 25.0
    assert 2 <= result.iterations <= 5


def test_filter_restarts_on_backwards_stamps_gaps_and_repeated_outliers():
    kf = WorldKalmanFilter(MotionConfig(max_gap_s=30.0, max_rejections=2))
    R = np.eye(2)
    assert kf.update(100.0, [0, 0], R).restart_reason == "start"
    step = kf.update(104.0, [1, 0], R)
    assert not step.restarted and step.restart_reason == ""
    assert kf.update(50.0, [5, 5], R).restart_reason == "backwards"
    assert kf.events["restart_backwards"] == 1
    assert kf.update(500.0, [6, 6], R).restart_reason == "gap"
    assert kf.events["restart_gap"] == 1
    assert kf.predict(501.0) is not None
    assert not kf.update(502.0, [1000, 1000], R).accepted
    out = kf.update(503.0, [1000, 1000], R)
    assert out.restarted and out.restart_reason == "rejections" and kf.events["restart_rejections"] == 1


def test_invalid_measurements_are_counted_not_fatal():
    kf = WorldKalmanFilter()
    assert kf.update(1.0, [np.nan, 0.0], np.eye(2)) is None
    kf.update(2.0, [0.0, 0.0], np.eye(2))
    out = kf.update(3.0, [1.0, 1.0], -np.eye(2))
    assert out is not None and not out.accepted
    assert kf.events["invalid_measurement"] == 2


def test_smoother_rejects_bad_series():
    with pytest.raises(DataError):
        rts_smooth([2.0, 1.0], np.zeros((2, 2)), np.tile(np.eye(2), (2, 1, 1)))
    with pytest.raises(DataError):
        rts_smooth([1.0, 2.0], np.full((2, 2), np.nan), np.tile(np.eye(2), (2, 1, 1)))
    with pytest.raises(DataError):
        MotionConfig(accel_psd=-1.0)


def test_most_likely_noise_follows_the_trajectory():
    from vessel_track.smoothing import most_likely_noise

    t, truth, z, R = _straight_run(n=40, seed=5, sigma_range=3.0, sigma_cross=1.0)
    q_straight, _ = most_likely_noise(t, z, R)
    # The same noise on a vessel turning tight circles (radius 30 m at 4 m/s).
    angle = (t - t[0]) * 4.0 / 30.0
    circle = np.column_stack([150 + 30 * np.cos(angle), 150 + 30 * np.sin(angle)])
    q_turning, _ = most_likely_noise(t, circle + (z - truth), R)
    assert q_straight <= 0.3 < q_turning
    # Measurements four times less noisy than their covariance says: a smaller scale is chosen.
    _, scale = most_likely_noise(t, truth + (z - truth) / 2.0, R, r_scale_candidates=(0.25, 1.0, 4.0))
    assert scale == 0.25
