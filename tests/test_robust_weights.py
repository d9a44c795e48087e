"""Per-sample weights: the weighted moments and window statistics, and the pipeline's robust-weights step."""

import itertools

import numpy as np
import pytest
from _shared import data_folder

from fusion_gyrocal import calibrate_array, calibrate_pair
from fusion_gyrocal.core.moments import Moments, window_stats
from fusion_gyrocal.core.robust import centred_scatters
from fusion_gyrocal.errors import InputError, OptionError
from fusion_gyrocal.evaluate.sim import DEG, PAPER_NOISE_STD, HumanMotion, random_rotation, simulate_pair
from fusion_gyrocal.io import read_npz
from fusion_gyrocal.lie import log
from fusion_gyrocal.options import Options
from fusion_gyrocal.core.weights import residual_weights, tail_share


def _streams(n=5000, seed=0):
    rng = np.random.default_rng(seed)
    w1 = rng.normal(size=(n, 3)) + 40.0        # a large bias: the centring must keep the digits
    w2 = rng.normal(size=(n, 3)) @ rng.normal(size=(3, 3)) - 7.0
    return rng, w1, w2


def _direct(w1, w2, weights, keep):
    x = np.hstack([w1, w2])[keep]
    w = weights[keep]
    mean = (w[:, None] * x).sum(axis=0) / w.sum()
    d = x - mean
    return w.sum(), mean, (d.T * w) @ d


def test_from_samples_weights_none_identical():
    _, w1, w2 = _streams()
    a = Moments.from_samples(w1, w2)
    b = Moments.from_samples(w1, w2, weights=None)
    assert a.count == b.count
    assert np.array_equal(a.mean, b.mean) and np.array_equal(a.scatter, b.scatter)


def test_from_samples_unit_weights_equal_unweighted():
    rng, w1, w2 = _streams()
    mask = rng.uniform(size=len(w1)) > 0.2
    a = Moments.from_samples(w1, w2, mask=mask)
    b = Moments.from_samples(w1, w2, mask=mask, weights=np.ones(len(w1)))
    assert b.count == a.count
    np.testing.assert_allclose(b.mean, a.mean, rtol=1e-13)
    np.testing.assert_allclose(b.scatter, a.scatter, rtol=1e-10, atol=1e-10 * np.abs(a.scatter).max())


def test_from_samples_weights_equal_direct_computation():
    rng, w1, w2 = _streams()
    weights = rng.uniform(0.0, 2.0, len(w1))
    mask = rng.uniform(size=len(w1)) > 0.1
    w1 = w1.copy()
    w1[np.flatnonzero(~mask)[:5]] = np.nan        # masked samples may be non-finite
    m = Moments.from_samples(w1, w2, mask=mask, weights=weights, chunk_size=700)
    count, mean, scatter = _direct(w1, w2, weights, mask)
    assert m.count == pytest.approx(count, rel=1e-14)
    np.testing.assert_allclose(m.mean, mean, rtol=1e-13)
    np.testing.assert_allclose(m.scatter, scatter, rtol=1e-11, atol=1e-12 * np.abs(scatter).max())


def test_window_stats_weights_add_up_to_weighted_moments():
    rng, w1, w2 = _streams(n=4000)
    weights = rng.uniform(0.0, 1.0, len(w1))
    stats = window_stats(w1, w2, 100, weights=weights)
    m = Moments.from_samples(w1, w2, weights=weights)
    assert stats.weighted and stats.n_windows == 40
    assert stats.count.sum() == pytest.approx(m.count, rel=1e-12)
    np.testing.assert_allclose(centred_scatters(stats).sum(axis=0), m.scatter, rtol=1e-9,
                               atol=1e-10 * np.abs(m.scatter).max())
    assert not window_stats(w1, w2, 100).weighted


@pytest.mark.parametrize("weights, match", [
    (np.full(10, -1.0), "non-negative"), (np.full(10, np.nan), "non-negative"), (np.ones(9), "shape")])
def test_from_samples_weights_refused(weights, match):
    _, w1, w2 = _streams(n=10)
    with pytest.raises(InputError, match=match):
        Moments.from_samples(w1, w2, weights=weights)


def test_from_samples_weights_non_finite_used_sample_named():
    _, w1, w2 = _streams(n=50)
    w2 = w2.copy()
    w2[17, 1] = np.inf
    with pytest.raises(InputError, match="omega_2.*sample 17"):
        Moments.from_samples(w1, w2, weights=np.ones(50))
    weights = np.ones(50)
    weights[17] = 0.0                             # weight 0: plays no part
    assert Moments.from_samples(w1, w2, weights=weights).count == 49.0


def test_residual_weights_down_weight_spikes_only():
    rng = np.random.default_rng(3)
    n, sigma = 2000, 1e-3
    w2 = rng.normal(size=(n, 3))
    w1 = w2 + rng.normal(0, sigma, (n, 3))
    w1[1000] += 0.5                               # one spike, 500 sigma
    w = residual_weights(w1, w2, np.eye(3), np.zeros(3), (sigma / np.sqrt(2),) * 2)
    assert np.all(w <= 1.0) and w[1000] < 1e-4
    assert np.all(w[998:1003] < 1e-3)            # its neighbourhood (5 samples) shares its local variance
    far = np.r_[0:990, 1010:n]
    assert np.mean(w[far]) > 0.7                  # noise-level samples keep most of their weight


def test_tail_share_gaussian_and_heavy_tailed():
    rng = np.random.default_rng(4)
    gauss = (rng.normal(size=(20000, 3)) ** 2).sum(axis=1) / 3
    heavy = (rng.standard_t(2, size=(20000, 3)) ** 2).sum(axis=1) / 3
    assert 0.035 < tail_share(gauss) < 0.06
    assert tail_share(heavy) > 0.3


def test_options_robust_weights_refused():
    assert Options().robust_weights == "off"
    with pytest.raises(OptionError, match="robust_weights"):
        Options(robust_weights="on")


def _spiky(k, spike_deg_s=20.0, n=6000):
    """A simulated pair whose gyro 1 has 1 % Student-t (2 dof) spikes of ``spike_deg_s`` scale."""
    rng = np.random.default_rng([7, k])
    sim = simulate_pair(n=n, rng=rng, bias_walk_std=0.0)
    return sim, _with_spikes(sim.omega_1, rng, spike_deg_s)


def _with_spikes(w, rng, spike_deg_s):
    """``w`` with 1 % of its samples hit by Student-t (2 dof) spikes of ``spike_deg_s`` scale."""
    w = w.copy()
    idx = rng.choice(len(w), len(w) // 100, replace=False)
    w[idx] += rng.standard_t(2, (idx.size, 3)) * spike_deg_s * DEG
    return w


def test_calibrate_pair_spiky_recovered_and_honest():
    # without the flex gate (which removes isolated spikes on simulated pairs, not on a MEMS board whose residual
    # grows with the rate): the weights alone
    err, z2, noted = {"off": [], "auto": []}, {"off": [], "auto": []}, 0
    for k in range(6):
        sim, w1 = _spiky(k)
        for mode in err:
            cal = calibrate_pair(w1, sim.omega_2, robust_weights=mode, flex_rejection=False)
            d = log(cal.R_1_2 @ sim.R_1_2.T)
            err[mode].append(d @ d)
            z2[mode].append(d @ np.linalg.solve(cal.covariance[:3, :3], d))
            noted += mode == "auto" and any(n.startswith("robust weights") for n in cal.notes)
    assert noted == 6
    rms = {m: np.sqrt(np.mean(v)) for m, v in err.items()}
    assert rms["auto"] < 0.15 * rms["off"]
    assert 0.5 < np.mean(z2["auto"]) < 8.0        # 3 is honest; 6 draws of chi2(3)


def test_calibrate_pair_gaussian_unchanged():
    sim = simulate_pair(n=6000, rng=11)
    a = calibrate_pair(sim.omega_1, sim.omega_2, robust_weights="off")
    b = calibrate_pair(sim.omega_1, sim.omega_2, robust_weights="auto")
    assert np.array_equal(a.R_1_2, b.R_1_2) and np.array_equal(a.covariance, b.covariance)
    assert not any(n.startswith("robust weights") for n in b.notes)


def test_calibrate_pair_heavy_tail_noted_when_weights_off():
    sim, w1 = _spiky(0)
    off = calibrate_pair(w1, sim.omega_2, flex_rejection=False)
    assert sum("the residual is heavy-tailed" in n and "--robust-weights auto" in n for n in off.notes) == 1
    auto = calibrate_pair(w1, sim.omega_2, robust_weights="auto", flex_rejection=False)
    assert not any("the residual is heavy-tailed" in n for n in auto.notes)
    gaussian = simulate_pair(n=6000, rng=11)
    assert not any("heavy-tailed" in n for n in calibrate_pair(gaussian.omega_1, gaussian.omega_2).notes)


def test_calibrate_array_heavy_tail_noted_when_weights_off():
    rates, _ = _spiky_array(0)
    off = calibrate_array(rates, flex_rejection=False)
    assert sum("the residual is heavy-tailed" in n for n in off.notes) == 1
    assert not any("the residual is heavy-tailed" in n
                   for n in calibrate_array(rates, robust_weights="auto", flex_rejection=False).notes)


def test_calibrate_pair_mimu_weighted_sessions_covered_by_the_covariance():
    """IMUs 3 and 4 of the MIMU board (neighbours): with the weights the nine sessions' rotations agree to a few
    mdeg and their differences are explained by the reported covariances (mean z^2 near 3)."""
    d = data_folder("mimu_8imu_array") / "npz"
    cals = []
    for e in range(1, 10):
        s = read_npz(d / f"exp_{e}.npz")
        cals.append(calibrate_pair(s[2].omega, s[3].omega, t_1=s[2].t, t_2=s[3].t, robust_weights="auto"))
    assert sum(any(n.startswith("robust weights") for n in c.notes) for c in cals) >= 7
    z2, d2 = [], []
    for a, b in itertools.combinations(cals, 2):
        diff = log(a.R_1_2 @ b.R_1_2.T)
        P = a.covariance[:3, :3] - a.skew_rotation_covariance + b.covariance[:3, :3] - b.skew_rotation_covariance
        z2.append(diff @ np.linalg.solve(P, diff))
        d2.append(diff @ diff)
    assert 0.75 <= np.mean(z2) <= 6.0
    assert np.sqrt(np.mean(d2)) < 10e-3 * DEG      # measured 6.9 mdeg RMS session-to-session


def _spiky_array(k, n=6000, gyros=3, spike_deg_s=20.0):
    """A simulated array whose reference gyro has 1 % Student-t (2 dof) spikes of ``spike_deg_s`` scale (every pair
    with the reference then has a heavy-tailed residual), and its true rotations ``R_ref_k``."""
    rng = np.random.default_rng([8, k])
    t = np.arange(n) / 100.0
    omega = HumanMotion(rng=rng)(t)
    R = [np.eye(3)] + [random_rotation(rng) for _ in range(gyros - 1)]
    rates = [omega @ Rk + rng.normal(0, PAPER_NOISE_STD, omega.shape) for Rk in R]   # omega_ref = R_ref_k omega_k
    rates[0] = _with_spikes(rates[0], rng, spike_deg_s)
    return rates, R


def test_calibrate_array_spiky_recovered_and_honest():
    err, z2, noted = {"off": [], "auto": []}, {"off": [], "auto": []}, 0
    for k in range(4):
        rates, R = _spiky_array(k)
        for mode in err:
            cal = calibrate_array(rates, rate_hz=100.0, robust_weights=mode)
            for j in (1, 2):
                d = log(cal.R_ref_k[j] @ R[j].T)
                err[mode].append(d @ d)
                z2[mode].append(d @ np.linalg.solve(cal.covariance[3 * j:3 * j + 3, 3 * j:3 * j + 3], d))
            noted += mode == "auto" and any(n.startswith("robust weights") for n in cal.notes)
    assert noted == 4
    rms = {m: np.sqrt(np.mean(v)) for m, v in err.items()}
    assert rms["auto"] < 0.1 * rms["off"]           # measured 4.2 against 137 mdeg
    assert 0.5 < np.mean(z2["auto"]) < 8.0        # 3 is honest; 8 draws of chi2(3)


def test_calibrate_array_gaussian_unchanged():
    rng = np.random.default_rng(12)
    t = np.arange(6000) / 100.0
    omega = HumanMotion(rng=rng)(t)
    rates = [omega @ Rk + rng.normal(0, PAPER_NOISE_STD, omega.shape) for Rk in (np.eye(3), random_rotation(rng))]
    a = calibrate_array(rates, rate_hz=100.0, robust_weights="off")
    b = calibrate_array(rates, rate_hz=100.0, robust_weights="auto")
    assert np.array_equal(a.R_ref_k, b.R_ref_k) and np.array_equal(a.covariance, b.covariance)
    assert not any(n.startswith("robust weights") for n in b.notes)
