"""Tests of fusion_gyrocal.pipeline (streams, resample, alignment, selection): stream checks, resampling, time alignment, selection."""

from __future__ import annotations

import numpy as np
import pytest
from _shared import data_folder
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.errors import InputError, OptionError, TimeAlignmentError
from fusion_gyrocal.core.model import ROT
from fusion_gyrocal.core.moments import Moments
from fusion_gyrocal.pipeline.alignment import AlignedPair, TimeOffset, align_streams, estimate_time_offset
from fusion_gyrocal.pipeline.resample import resample
from fusion_gyrocal.pipeline.selection import excitation_report, informative_mask
from fusion_gyrocal.pipeline.streams import check_timestamps, saturation_mask, to_rad_per_s, valid_mask
from fusion_gyrocal.evaluate.sim import (DEG, PAPER_NOISE_STD, HumanMotion, random_rotation, rotation_error,
                                simulate_streams)


# ------------------------------------------------------------------------------------------------ stream checks
def test_check_timestamps_returns_float64_seconds():
    out = check_timestamps("t_1", np.arange(5, dtype=np.int64), length=5)
    assert out.dtype == np.float64
    np.testing.assert_array_equal(out, [0.0, 1.0, 2.0, 3.0, 4.0])


def test_check_timestamps_rejects_2d():
    with pytest.raises(InputError, match=r"t_1: expected a 1-D array of timestamps, got shape \(3, 2\)"):
        check_timestamps("t_1", np.zeros((3, 2)))


def test_check_timestamps_rejects_length_mismatch():
    with pytest.raises(InputError, match="expected 10 timestamps .* got 9"):
        check_timestamps("t_2", np.arange(9.0), length=10)


def test_check_timestamps_rejects_non_finite_naming_sample():
    t = np.arange(10.0)
    t[4] = np.nan
    with pytest.raises(InputError, match="at sample 4"):
        check_timestamps("t_1", t)


def test_check_timestamps_rejects_step_backwards_naming_index_and_step():
    t = np.arange(1000) * 0.01
    t[532] = t[531] - 0.01
    with pytest.raises(InputError, match=r"t_2: expected strictly increasing timestamps, got a step of -0\.01 s at "
                                         r"sample 532"):
        check_timestamps("t_2", t)


def test_check_timestamps_rejects_duplicate():
    t = np.arange(20) * 0.01
    t[8] = t[7]
    with pytest.raises(InputError, match="duplicate timestamp .* samples 7 and 8"):
        check_timestamps("t_1", t)


def test_to_rad_per_s_converts_deg_per_s():
    np.testing.assert_allclose(to_rad_per_s(np.array([[180.0, -90.0, 0.0]]), "deg/s"), [[np.pi, -np.pi / 2, 0.0]])


def test_to_rad_per_s_converts_counts_with_sensitivity():
    out = to_rad_per_s(np.array([[16, -32767, 0]], dtype=np.int16), "counts", sensitivity=16.4)
    np.testing.assert_allclose(out, np.array([[16, -32767, 0]]) / 16.4 * DEG)
    assert out.dtype == np.float64


def test_to_rad_per_s_rejects_counts_without_sensitivity():
    with pytest.raises(OptionError, match="sensitivity: expected a positive LSB per deg/s"):
        to_rad_per_s(np.ones((2, 3)), "counts")


def test_to_rad_per_s_rejects_unknown_unit():
    with pytest.raises(OptionError, match="unit: expected one of"):
        to_rad_per_s(np.ones((2, 3)), "rpm")


def test_to_rad_per_s_never_aliases_input():
    x = np.ones((4, 3))
    out = to_rad_per_s(x, "rad/s")
    out[0, 0] = 5.0
    assert x[0, 0] == 1.0


def test_saturation_mask_limit_flags_samples_at_range():
    w = np.zeros((6, 3))
    w[2, 1], w[4, 0] = 2.0, -2.5
    np.testing.assert_array_equal(saturation_mask(w, limit=2.0), [False, False, True, False, True, False])


def test_saturation_mask_detects_flat_extremes_without_limit():
    rng = np.random.default_rng(0)
    w = HumanMotion(2.0, rng=rng)(np.arange(3000) / 100.0) + rng.normal(0, PAPER_NOISE_STD, (3000, 3))
    clipped = np.clip(w, -2.5, 2.5)
    truth = np.any(np.abs(w) >= 2.5, axis=1)
    assert truth.sum() > 10
    np.testing.assert_array_equal(saturation_mask(clipped), truth)


def test_saturation_mask_flags_nothing_in_unclipped_noisy_motion():
    rng = np.random.default_rng(1)
    w = HumanMotion(1.0, rng=rng)(np.arange(3000) / 100.0) + rng.normal(0, PAPER_NOISE_STD, (3000, 3))
    assert not saturation_mask(w).any()


def test_valid_mask_excludes_non_finite_and_saturated_samples():
    w = np.tile(np.linspace(-1, 1, 10)[:, None], (1, 3))
    w[3, 2] = np.nan
    w[7, 0] = np.inf
    expected = np.ones(10, dtype=bool)
    expected[[0, 3, 7, 9]] = False  # 0 and 9 reach |w| >= limit
    np.testing.assert_array_equal(valid_mask(w, limit=1.0), expected)


def test_saturation_mask_heuristic_matches_mimu_sensor_range():
    path = data_folder("mimu_8imu_array/npz") / "exp_1.npz"
    counts = np.load(path)["gyro_counts"][:, 0, :]
    w = to_rad_per_s(counts, "counts", sensitivity=16.4)
    by_range = saturation_mask(counts, limit=32767)
    assert by_range.sum() > 100  # SOURCE.md: 2-3.5 % of the samples clip
    np.testing.assert_array_equal(saturation_mask(w), by_range)


# ------------------------------------------------------------------------------------------------ resampling
def test_resample_interpolation_error_within_cubic_spline_bound():
    rng = np.random.default_rng(2)
    motion = HumanMotion(1.0, rng=rng)
    h = 0.01
    t = np.arange(2000) * h
    grid = np.sort(rng.uniform(0.5, 19.5, 4000))
    out, ok = resample(t, motion(t), grid)
    assert ok.all()
    f4 = (motion.amp * (2 * np.pi * motion.freq) ** 4).sum(axis=1)  # bound on |f''''| per axis
    bound = 5.0 / 384.0 * h**4 * f4  # classical cubic-spline interpolation error (away from the ends)
    assert np.all(np.abs(out - motion(grid)).max(axis=0) <= bound)


def test_resample_equals_scipy_cubic_spline_on_each_run():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.005, 0.015, 300))
    w = rng.standard_normal((300, 3))
    valid = np.ones(300, dtype=bool)
    valid[[40, 41, 150]] = False
    grid = np.sort(rng.uniform(t[0], t[-1], 2000))
    out, ok = resample(t, w, grid, valid=valid, max_gap_s=1.0)
    for run in (np.arange(0, 40), np.arange(42, 150), np.arange(151, 300)):
        sel = (grid >= t[run[0]]) & (grid <= t[run[-1]])
        assert ok[sel].all()
        np.testing.assert_allclose(out[sel], CubicSpline(t[run], w[run])(grid[sel]), rtol=0, atol=1e-12)


def test_resample_never_bridges_a_gap():
    t = np.r_[np.arange(100) * 0.01, 2.0 + np.arange(100) * 0.01]
    w = np.ones((200, 3))
    out, ok = resample(t, w, np.array([0.5, 1.5, 2.5]))
    np.testing.assert_array_equal(ok, [True, False, True])
    assert np.isnan(out[1]).all()


def test_resample_never_bridges_a_masked_sample():
    t = np.arange(100) * 0.01
    valid = np.ones(100, dtype=bool)
    valid[50] = False
    _, ok = resample(t, np.ones((100, 3)), np.array([0.495, 0.50, 0.505, 0.515]), valid=valid)
    np.testing.assert_array_equal(ok, [False, False, False, True])


def test_resample_masks_non_finite_source_samples():
    t = np.arange(100) * 0.01
    w = np.ones((100, 3))
    w[30, 1] = np.nan
    out, ok = resample(t, w, np.array([0.295, 0.6]))
    np.testing.assert_array_equal(ok, [False, True])
    np.testing.assert_allclose(out[1], 1.0)


def test_resample_default_max_gap_is_two_and_a_half_periods():
    h = 0.01
    t = np.r_[np.arange(50) * h, 49 * h + 2.4 * h + np.arange(50) * h, 49 * h + 2.4 * h + 49 * h + 2.6 * h
              + np.arange(50) * h]
    _, ok = resample(t, np.ones((150, 3)), np.array([t[49] + h, t[99] + h]))
    np.testing.assert_array_equal(ok, [True, False])


def test_resample_grid_outside_source_is_invalid():
    t = np.arange(100) * 0.01
    _, ok = resample(t, np.ones((100, 3)), np.array([-0.001, 0.0, 0.99, 0.991]))
    np.testing.assert_array_equal(ok, [False, True, True, False])


# ------------------------------------------------------------------------------------------------ time offset
@pytest.fixture(scope="module")
def offset_monte_carlo():
    """40 runs: 100 Hz / 200 Hz (alternating which gyro is faster), jitter, offsets in +-0.3 s."""
    rng = np.random.default_rng(20240601)
    err, std = [], []
    for k in range(40):
        offset = rng.uniform(-0.3, 0.3)
        rates = (100.0, 200.0) if k % 2 == 0 else (200.0, 100.0)
        t1, w1, t2, w2, _, _ = simulate_streams(rng, rate_1=rates[0], rate_2=rates[1], offset=offset)
        est = estimate_time_offset(t1, w1, t2, w2)
        err.append(est.offset_s - offset)
        std.append(est.std_s)
    return np.array(err), np.array(std)


def test_estimate_time_offset_rms_error_below_a_tenth_of_a_millisecond(offset_monte_carlo):
    err, _ = offset_monte_carlo
    assert np.sqrt(np.mean(err**2)) <= 1e-4


def test_estimate_time_offset_std_matches_actual_error(offset_monte_carlo):
    err, std = offset_monte_carlo
    z = err / std
    # mean of z^2 over 40 runs: chi^2_40 / 40, inside [0.45, 1.8] with probability > 0.999 if std is right
    assert 0.45 <= np.mean(z**2) <= 1.8


def test_estimate_time_offset_sign_is_added_to_gyro_2_timestamps():
    rng = np.random.default_rng(4)
    motion = HumanMotion(1.0, rng=rng)
    t = np.arange(3000) / 100.0
    clock_2 = t - 0.137  # gyro 2's clock reads 0.137 s less: add 0.137 s to put it on gyro 1's clock
    est = estimate_time_offset(t, motion(t), clock_2, motion(t))
    assert est.offset_s == pytest.approx(0.137, abs=1e-6)


def test_estimate_time_offset_returns_correlation_curve_over_search_range():
    t1, w1, t2, w2, _, _ = simulate_streams(5, duration=20.0, offset=0.05)
    est = estimate_time_offset(t1, w1, t2, w2, max_offset_s=0.5)
    assert isinstance(est, TimeOffset)
    assert est.lags_s[0] <= -0.5 and est.lags_s[-1] >= 0.5 and est.lags_s.shape == est.correlation.shape
    assert est.lags_s[np.nanargmax(est.correlation)] == pytest.approx(0.05, abs=np.diff(est.lags_s)[0])
    assert est.peak_correlation == pytest.approx(np.nanmax(est.correlation))


def test_estimate_time_offset_handles_gaps_and_masks():
    t1, w1, t2, w2, _, _ = simulate_streams(6, offset=-0.2)
    keep = np.ones(t2.size, dtype=bool)
    keep[3000:3400] = False  # a 2 s dropout of gyro 2
    valid_1 = np.ones(t1.size, dtype=bool)
    valid_1[::7] = False
    w1 = w1.copy()
    w1[100:110] = np.nan
    est = estimate_time_offset(t1, w1, t2[keep], w2[keep], valid_1=valid_1)
    assert abs(est.offset_s + 0.2) <= 5 * est.std_s
    assert est.std_s < 2e-5


def test_estimate_time_offset_keeps_precision_with_epoch_timestamps():
    t1, w1, t2, w2, _, _ = simulate_streams(7, offset=0.21)
    epoch = 1.7e9
    est = estimate_time_offset(t1 + epoch, w1, t2 + epoch, w2)
    assert abs(est.offset_s - 0.21) <= 5 * est.std_s + 1e-6  # float64 epoch seconds resolve ~0.24 us


def test_estimate_time_offset_rejects_no_motion():
    t1, w1, t2, w2, _, _ = simulate_streams(8, duration=20.0, rms=0.0)
    with pytest.raises(TimeAlignmentError, match="weak correlation"):
        estimate_time_offset(t1, w1, t2, w2)


def test_estimate_time_offset_rejects_peak_on_search_boundary():
    t1, w1, t2, w2, _, _ = simulate_streams(9, duration=30.0, offset=0.35)
    with pytest.raises(TimeAlignmentError, match="search boundary"):
        estimate_time_offset(t1, w1, t2, w2, max_offset_s=0.3)


def _rotating(t):
    """Rates whose norm repeats every 0.5 s while the vector does not (a slowly varying frame)."""
    v = np.c_[np.sin(np.pi * t), np.cos(np.pi * t), 0.5 * np.sin(2 * np.pi * t)]
    phi = 1.5 * np.sin(2 * np.pi * 0.05 * t)
    return Rotation.from_rotvec(np.c_[0 * t, 0 * t, phi]).apply(v)


def _periodic(t):
    """Exactly periodic rates: a shift by 0.5 s is a constant linear map, which A absorbs."""
    return np.c_[np.sin(np.pi * t), np.cos(np.pi * t), 0.5 * np.sin(2 * np.pi * t)]


def test_estimate_time_offset_rejects_ambiguous_periodic_motion():
    rng = np.random.default_rng(10)
    t1, t2 = np.arange(6000) / 100.0, np.arange(12000) / 200.0 - 0.1
    w1 = _periodic(t1) + rng.normal(0, PAPER_NOISE_STD, (6000, 3))
    w2 = _periodic(t2 + 0.1) + rng.normal(0, PAPER_NOISE_STD, (12000, 3))
    with pytest.raises(TimeAlignmentError, match="ambiguous time offset"):
        estimate_time_offset(t1, w1, t2, w2, max_offset_s=1.5)


def test_estimate_time_offset_resolves_periodic_norm_with_rigid_model():
    rng = np.random.default_rng(11)
    t1, t2 = np.arange(6000) / 100.0, np.arange(12000) / 200.0 - 0.1
    w1 = _rotating(t1) + rng.normal(0, PAPER_NOISE_STD, (6000, 3))
    w2 = _rotating(t2 + 0.1) + rng.normal(0, PAPER_NOISE_STD, (12000, 3))
    est = estimate_time_offset(t1, w1, t2, w2, max_offset_s=1.5)
    assert abs(est.offset_s - 0.1) <= 5 * est.std_s


def test_estimate_time_offset_recovers_shift_between_mimu_imus():
    path = data_folder("mimu_8imu_array/npz") / "exp_1.npz"
    d = np.load(path)
    w1 = to_rad_per_s(d["gyro_counts"][:, 0, :], "counts", sensitivity=16.4)
    w2 = to_rad_per_s(d["gyro_counts"][:, 1, :], "counts", sensitivity=16.4)  # bottom side: rotated 180 deg
    t = d["t_s"]
    shift = 0.1234  # gyro 2's clock ahead by this much; the IMUs are sampled synchronously (SOURCE.md)
    est = estimate_time_offset(t, w1, t + shift, w2, valid_1=valid_mask(w1), valid_2=valid_mask(w2))
    assert abs(est.offset_s + shift) <= 5 * est.std_s


# ------------------------------------------------------------------------------------------------ alignment
def test_align_streams_grid_is_gyro_1_timestamps_inside_overlap():
    t1, w1, t2, w2, _, _ = simulate_streams(12, duration=20.0, offset=0.25)
    pair = align_streams(t1, w1, t2, w2)
    tau = pair.time_offset_s
    inside = (t1 >= t2[0] + tau) & (t1 <= t2[-1] + tau)
    np.testing.assert_array_equal(pair.t, t1[inside])
    np.testing.assert_array_equal(pair.omega_1, w1[inside])
    assert isinstance(pair, AlignedPair) and pair.time_offset is not None and pair.valid.all()


def test_align_streams_given_offset_samples_gyro_2_at_t_minus_offset():
    rng = np.random.default_rng(13)
    motion = HumanMotion(1.0, rng=rng)
    R = random_rotation(rng)
    t1 = np.arange(2000) / 100.0
    t2 = np.arange(4000) / 200.0 + 0.3  # own clock; true time = t2 - 0.3
    pair = align_streams(t1, motion(t1), t2, motion(t2 - 0.3) @ R, time_offset_s=-0.3)
    assert pair.time_offset is None
    ok = pair.valid
    # noise-free: gyro 2 resampled at t - offset is R^T omega_1(t) up to spline error (~1e-5 rad/s at 200 Hz)
    np.testing.assert_allclose(pair.omega_2[ok], motion(pair.t[ok]) @ R, atol=1e-4)


def test_align_streams_rate_hz_gives_uniform_grid():
    t1, w1, t2, w2, _, _ = simulate_streams(14, duration=10.0, offset=0.05)
    pair = align_streams(t1, w1, t2, w2, time_offset_s=0.05, rate_hz=50.0)
    np.testing.assert_allclose(np.diff(pair.t), 0.02, rtol=0, atol=1e-12)
    assert pair.valid.all() and pair.omega_1.shape == pair.omega_2.shape == (pair.t.size, 3)


def test_align_streams_does_not_modify_inputs():
    t1, w1, t2, w2, _, _ = simulate_streams(15, duration=10.0)
    copies = [a.copy() for a in (t1, w1, t2, w2)]
    pair = align_streams(t1, w1, t2, w2)
    for a, c in zip((t1, w1, t2, w2), copies):
        np.testing.assert_array_equal(a, c)
    assert not pair.omega_1.flags.writeable


def test_align_streams_then_calibrate_pair_recovers_rotation_within_covariance():
    t1, w1, t2, w2, R, _ = simulate_streams(16, offset=-0.22)
    pair = align_streams(t1, w1, t2, w2)
    cal = calibrate_pair(pair.omega_1, pair.omega_2, mask=pair.valid, noise_std=PAPER_NOISE_STD)
    sd = np.sqrt(np.trace(cal.covariance[ROT, ROT]))
    assert rotation_error(cal.R_1_2, R) <= 4 * sd


def test_aligned_pair_moments_use_valid_samples_only():
    t1, w1, t2, w2, _, _ = simulate_streams(17, duration=10.0)
    w2 = w2.copy()
    w2[500:520] = np.nan
    pair = align_streams(t1, w1, t2, w2)
    m = pair.moments()
    assert m.count == pair.n_valid < pair.t.size
    ref = Moments.from_samples(pair.omega_1[pair.valid], pair.omega_2[pair.valid])
    np.testing.assert_allclose(m.scatter, ref.scatter, rtol=1e-12)


# ------------------------------------------------------------------------------------------------ selection
def test_informative_mask_keeps_rates_between_limits():
    w = np.zeros((5, 3))
    w[:, 0] = [0.0, 0.01, 0.5, 3.0, 10.0]
    keep = informative_mask(w, w, None, 1e-3, max_rate=5.0)  # default min_rate = 10 * noise = 0.01
    np.testing.assert_array_equal(keep, [False, True, True, True, False])


def test_informative_mask_requires_both_gyros_and_valid():
    w1 = np.full((4, 3), 1.0)
    w2 = w1.copy()
    w2[1] = 0.0
    valid = np.array([True, True, True, False])
    np.testing.assert_array_equal(informative_mask(w1, w2, valid, 1e-3), [True, False, True, False])


def test_excitation_report_final_snr_matches_moments():
    rng = np.random.default_rng(18)
    w = HumanMotion([0.5, 1.0, 2.0], rng=rng)(np.arange(5000) / 100.0) + rng.normal(0, PAPER_NOISE_STD, (5000, 3))
    rep = excitation_report(w, PAPER_NOISE_STD)
    m = Moments.from_samples(w, w)
    expected = np.sqrt(np.diag(m.S11) - (m.count - 1) * PAPER_NOISE_STD**2) / PAPER_NOISE_STD
    np.testing.assert_allclose(rep.snr, expected, rtol=1e-9)
    np.testing.assert_allclose(rep.cumulative_snr[-1], rep.snr)


def test_excitation_report_reached_at_is_first_crossing():
    rng = np.random.default_rng(19)
    w = HumanMotion(1.0, rng=rng)(np.arange(20000) / 100.0) + rng.normal(0, PAPER_NOISE_STD, (20000, 3))
    rep = excitation_report(w, PAPER_NOISE_STD, target_snr=4e3)
    assert rep.all_reached
    for a in range(3):
        k = rep.reached_at[a]
        assert rep.cumulative_snr[k, a] >= 4e3 > rep.cumulative_snr[k - 1, a]
        prefix = w[: k + 1, a]
        direct = np.sqrt(np.sum((prefix - prefix.mean()) ** 2) - k * PAPER_NOISE_STD**2) / PAPER_NOISE_STD
        assert direct == pytest.approx(rep.cumulative_snr[k, a], rel=1e-9)
    assert rep.samples_needed == rep.reached_at.max()


def test_excitation_report_unreached_axis_reports_minus_one():
    rng = np.random.default_rng(20)
    w = HumanMotion([1.0, 1.0, 0.001], rng=rng)(np.arange(5000) / 100.0)
    rep = excitation_report(w + rng.normal(0, PAPER_NOISE_STD, w.shape), PAPER_NOISE_STD, target_snr=1e3)
    np.testing.assert_array_equal(rep.reached, [True, True, False])
    assert rep.reached_at[2] == -1 and rep.samples_needed is None


def test_excitation_report_removes_the_noise_contribution():
    rng = np.random.default_rng(21)
    n = 20000
    rep = excitation_report(rng.normal(0, PAPER_NOISE_STD, (n, 3)), PAPER_NOISE_STD)
    # without the correction the SNR of pure noise would be sqrt(n) = 141; with it, the chi^2 spread only:
    # sqrt(|sum n_k^2 / sigma^2 - (n - 1)|) ~ (2 n)^(1/4) = 14, below 4x that with overwhelming probability
    assert np.all(rep.snr <= 4 * (2 * n) ** 0.25)


def test_excitation_report_skips_invalid_samples():
    rng = np.random.default_rng(22)
    w = HumanMotion(1.0, rng=rng)(np.arange(2000) / 100.0)
    valid = np.ones(2000, dtype=bool)
    valid[::3] = False
    bad = w.copy()
    bad[~valid] = 1e3
    rep = excitation_report(bad, PAPER_NOISE_STD, valid=valid)
    np.testing.assert_allclose(rep.snr, excitation_report(w[valid], PAPER_NOISE_STD).snr)
    assert rep.n_used == valid.sum()


# ------------------------------------------------------------------------------------------------ bounded memory
def test_resample_block_by_block_equals_whole_record_splines(monkeypatch):
    import fusion_gyrocal.pipeline.resample as rs

    rng = np.random.default_rng(11)
    t = np.cumsum(rng.uniform(0.0075, 0.0125, 40000))
    w = np.sin(np.outer(t, [1.0, 2.3, 3.1])) + rng.normal(0, 1e-3, (t.size, 3))
    ok = rng.random(t.size) > 0.002
    ok[5000:5100] = False
    grid = np.arange(t[0] - 1.0, t[-1] + 1.0, 0.0037)
    monkeypatch.setattr(rs, "_GRID_BLOCK", 1000)         # about 270 blocks
    blocked, in_blocked = resample(t, w, grid, valid=ok)
    monkeypatch.setattr(rs, "_GRID_BLOCK", 10**9)        # one spline over the whole record
    whole, in_whole = resample(t, w, grid, valid=ok)
    assert np.array_equal(in_blocked, in_whole)
    np.testing.assert_allclose(blocked[in_whole], whole[in_whole], rtol=0, atol=1e-13)


@pytest.mark.parametrize("masked", [True, False])
def test_masked_correlation_blocks_equal_one_block(monkeypatch, masked):
    import fusion_gyrocal.pipeline.alignment as al

    rng = np.random.default_rng(12)
    f = rng.standard_normal(50000)
    g = rng.standard_normal(48000) + 0.7
    g[100:] += 0.5 * f[:47900]                         # g[k] follows f[k - 100]: the peak at lag -100
    mf, mg = np.ones(f.size, bool), np.ones(g.size, bool)
    if masked:                                         # masked samples everywhere: the six-FFT blocks
        mf, mg = rng.random(f.size) > 0.1, rng.random(g.size) > 0.1
    else:                                              # one gap: the other blocks take the cumsum form
        mg[20000:20300] = False
    f, g = f * mf, g * mg
    one = al._masked_correlation(f, mf, g, mg, -300, 300, 8)
    monkeypatch.setattr(al, "_XC_ONE_FFT", 1000)
    monkeypatch.setattr(al, "_XC_BLOCK", 4096)
    blocks = al._masked_correlation(f, mf, g, mg, -300, 300, 8)
    np.testing.assert_allclose(blocks, one, rtol=0, atol=1e-12)
    assert np.nanargmax(blocks) - 300 == -100


def test_estimate_time_offset_subsample_of_excited_windows_keeps_accuracy():
    # 10 minutes at 100/200 Hz: the refinement on a bounded subsample (a twelfth of the instants) of
    # the most excited windows stays unbiased, its std honest and within a small factor of the full one
    # (a random twelfth would have sqrt(12) = 3.5 times the std)
    t1, w1, t2, w2, _, _ = simulate_streams(13, duration=600.0, offset=0.0731)
    full = estimate_time_offset(t1, w1, t2, w2, max_eval=None)
    sub = estimate_time_offset(t1, w1, t2, w2, max_eval=16384)
    assert sub.n_samples <= 16384 < full.n_samples
    assert abs(sub.offset_s - 0.0731) <= 4 * sub.std_s
    assert abs(full.offset_s - 0.0731) <= 4 * full.std_s
    assert full.std_s < sub.std_s < 3 * full.std_s


def test_align_streams_long_record_memory_is_bounded():
    import tracemalloc

    t1, w1, t2, w2, _, _ = simulate_streams(14, rate_1=200.0, rate_2=200.0, duration=2000.0, offset=0.02)
    n = t1.size                                        # 400k samples per gyro
    tracemalloc.start()
    try:
        pair = align_streams(t1, w1, t2, w2)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert abs(pair.time_offset_s - 0.02) <= 5 * pair.time_offset.std_s
    # the aligned output is 57 bytes a sample; everything else is blocks of bounded size
    assert peak / n <= 57 + 80 + 64e6 / n
