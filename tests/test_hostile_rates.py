"""Issue 22, items 4, 5 and a duplicated stream: two very different sample rates, the rigid model on
near-parallel axes, the same stream given for two gyros."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_gyrocal import calibrate_array, calibrate_pair
from fusion_gyrocal.errors import InputError
from fusion_gyrocal.evaluate.sim import HumanMotion, simulate_pair, simulate_streams
from fusion_gyrocal.lie import exp, log

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


def _z2(cal, R_true) -> float:
    """Squared Mahalanobis distance of the rotation error (``R_true = Exp(dtheta) R``) under the covariance."""
    d = log(R_true @ cal.R_1_2.T)
    return float(d @ np.linalg.solve(cal.covariance[:3, :3], d))


# ----------------------------------------------------------------------------- 5: two very different rates
@pytest.mark.parametrize("rates", [(5000.0, 50.0), (50.0, 5000.0)])
def test_calibrate_pair_two_rates_100x_apart_covariance_covers_the_error(rates):
    # 30 seeded pairs, one gyro 100x faster than the other: the rotation error's mean z^2 (3 for an exact
    # covariance; 129 when the slow gyro was interpolated onto the fast one's instants) within [0.75, 6]
    z2 = [_z2(calibrate_pair(s.omega_1, s.omega_2, t_1=s.t_1, t_2=s.t_2), s.R_1_2)
          for s in (simulate_streams(seed, rate_1=rates[0], rate_2=rates[1], duration=8.0) for seed in range(30))]
    assert 0.75 <= np.mean(z2) <= 6.0


def test_calibrate_pair_fast_gyro_1_filtered_onto_gyro_2s_rate_and_said():
    s = simulate_streams(3, rate_1=5000.0, rate_2=50.0, duration=8.0)
    cal = calibrate_pair(s.omega_1, s.omega_2, t_1=s.t_1, t_2=s.t_2)
    assert cal.n_samples < 8.0 * 50.0 * 1.01               # solved on gyro 2's rate, not on 40,000 samples
    assert any("low-pass filtered onto a grid at gyro 2's rate" in n for n in cal.notes)
    given = calibrate_pair(s.omega_1, s.omega_2, t_1=s.t_1, t_2=s.t_2, noise_std=1.75e-3)
    assert given.noise_std == pytest.approx([1.75e-3 * np.sqrt(50.0 / 5000.0), 1.75e-3], rel=0.01)
    assert any("noise_std referred to that grid" in n for n in given.notes)
    kept = calibrate_pair(s.omega_1, s.omega_2, t_1=s.t_1, t_2=s.t_2, bias_window=5000)   # per grid sample:
    assert kept.n_samples > 8.0 * 5000.0 * 0.5              # the grid stays gyro 1's instants
    assert not any("low-pass" in n for n in kept.notes)


def test_calibrate_pair_two_rates_given_noise_covariance_covers_the_error():
    z2 = [_z2(calibrate_pair(s.omega_1, s.omega_2, t_1=s.t_1, t_2=s.t_2, noise_std=1.75e-3), s.R_1_2)
          for s in (simulate_streams(seed, rate_1=5000.0, rate_2=50.0, duration=8.0) for seed in range(30))]
    assert 0.75 <= np.mean(z2) <= 6.0


def test_calibrate_pair_similar_rates_keep_gyro_1s_instants():
    s = simulate_streams(4, rate_1=100.0, rate_2=200.0, duration=20.0)
    cal = calibrate_pair(s.omega_1, s.omega_2, t_1=s.t_1, t_2=s.t_2)
    assert cal.n_samples > 20.0 * 100.0 * 0.9 and not any("low-pass" in n for n in cal.notes)


def test_resample_100x_sparser_instants_filter_the_noise_not_the_motion():
    from fusion_gyrocal.pipeline.resample import noise_factors, resample

    rng = np.random.default_rng(0)
    t = (np.arange(200_000) + rng.uniform(-0.25, 0.25, 200_000)) / 10_000.0      # 20 s at 10 kHz, jittered
    q = np.arange(0.5, 19.5, 0.01)                                               # 100 Hz
    motion = HumanMotion(1.0, rng=1)
    out, ok = resample(t, motion(t) + rng.normal(0.0, 1e-2, (t.size, 3)), q)
    assert ok.all()
    # noise 1e-2 per sample at 10 kHz: ~1e-2 * sqrt(0.9 / 100) ~ 1e-3 left at 100 Hz (a spline alone keeps ~1e-2)
    assert np.std(out - motion(q)) < 1.5e-3
    clean, _ = resample(t, motion(t), q)
    assert np.abs(clean - motion(q)).max() < 1e-4             # the motion passes (flat to 1e-5 up to 40 Hz)
    variance, _, density, _ = noise_factors(t, q)
    assert variance == pytest.approx(0.009, rel=0.15)         # ~0.9 f_query / f_src
    assert density == pytest.approx(1.0, rel=0.1)             # nothing folded back


def test_resample_4x_sparser_instants_filtered_3x_not():
    from fusion_gyrocal.pipeline.resample import noise_factors

    t = np.arange(120_000) / 1200.0
    assert noise_factors(t, np.arange(0.5, 95.0, 1 / 300.0))[2] == pytest.approx(1.0, rel=0.1)   # 4x: filtered
    assert noise_factors(t, np.arange(0.5, 95.0, 1 / 400.0))[2] == pytest.approx(3.0, rel=0.1)   # 3x: aliased


# ----------------------------------------------------------------------------- 4: rigid model, near-parallel axes
@pytest.mark.parametrize("theta_deg", [[0.0, 0.0, 3.0], [3.0, -2.0, 1.0]])
def test_parallel_tilt_bias_recovers_the_overstated_tilt(theta_deg):
    from fusion_gyrocal.core.observability import classify, parallel_tilt_bias
    from fusion_gyrocal.lie import nearest_rotation

    theta = np.deg2rad(theta_deg)
    c = np.exp([0.04, -0.03, 0.0])                  # the axes' common factors the gauge sets to 1
    A = np.diag(c) @ exp(theta) @ np.diag(1.0 / c)
    R_fit = nearest_rotation(A)                     # the rigid fit's rotation: the tilt overstated
    overstated = np.abs(log(R_fit)) - np.abs(theta)
    bias = parallel_tilt_bias(A, R_fit, np.ones(3), np.ones(3), classify(R_fit), np.zeros(3))
    np.testing.assert_allclose(bias, overstated, rtol=0.1, atol=2e-6)
    assert bias.max() > 1e-5
    same = parallel_tilt_bias(exp(theta), exp(theta), np.ones(3), np.ones(3), classify(exp(theta)), np.zeros(3))
    np.testing.assert_allclose(same, 0.0, atol=1e-12)                    # one common factor: no bias
    general = exp(np.deg2rad([30.0, 20.0, 10.0]))
    np.testing.assert_array_equal(parallel_tilt_bias(general, general, np.ones(3), np.ones(3), classify(general),
                                                     np.zeros(3)), 0.0)


def test_calibrate_pair_rigid_all_axes_parallel_tilt_covered():
    # 4 deg tilt, axes' scale factors 8 % apart, 4e4 samples: without the term mean z^2 ~ 30 (rigid forced)
    z2, noted = [], 0
    for seed in range(8):
        rng = np.random.default_rng(100 + seed)
        axis = rng.standard_normal(3)
        R = exp(np.deg2rad(4.0) * axis / np.linalg.norm(axis))
        sim = simulate_pair(n=40_000, R_1_2=R, scale_1=1 + 0.08 * rng.standard_normal(3),
                            scale_2=1 + 0.08 * rng.standard_normal(3), bias_walk_std=0.0, rng=seed)
        cal = calibrate_pair(sim.omega_1, sim.omega_2, linear_map="rigid")
        assert cal.configuration == "all_axes_parallel" and cal.linear_map == "rigid"
        z2.append(_z2(cal, R))
        noted += any("undetermined scale ratios bias the tilt" in n for n in cal.notes)
    assert np.mean(z2) <= 6.0 and noted >= 6


# ----------------------------------------------------------------------------- the same stream twice
def test_calibrate_array_duplicate_gyro_refused_naming_both():
    sim = simulate_pair(n=3000, rng=1)
    with pytest.raises(InputError, match=r"gyro 1 and gyro 3: expected one stream per gyro, got identical"):
        calibrate_array([sim.omega_1, sim.omega_2, sim.omega_1])
    with pytest.raises(InputError, match=r"gyro 2 and gyro 3"):
        calibrate_array(np.stack([sim.omega_1, sim.omega_2, sim.omega_2.copy()], axis=1))


@pytest.mark.parametrize("timestamps", [False, True])
def test_calibrate_pair_identical_streams_refused(timestamps):
    sim = simulate_pair(n=3000, rng=2)
    kw = dict(t_1=sim.t, t_2=sim.t.copy()) if timestamps else {}
    with pytest.raises(InputError, match=r"omega_1 and omega_2: expected one stream per gyro"):
        calibrate_pair(sim.omega_2, sim.omega_2.copy(), **kw)


def test_calibrate_pair_same_rates_other_instants_not_a_duplicate():
    sim = simulate_pair(n=3000, rng=2)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, t_1=sim.t, t_2=sim.t + 0.0)   # same instants, two gyros
    assert cal.rigid
