"""Equivalence of the drifting-bias path's faster pieces with their plain references (issue 25): the innovations
filter against one ``lfilter`` pass over the whole log, the stretches' ``A`` against a fit per stretch, the stacked
second differences against one call per stretch, ``rows_times`` against ``@``."""

import numpy as np
import pytest
from scipy.signal import lfilter

from fusion_gyrocal.core.allan import allan_points, second_differences
from fusion_gyrocal.core.direct import solve_A
from fusion_gyrocal.core.moments import (CHUNK_SIZE, Moments, random_walk_bias_moments, random_walk_gain,
                                         rows_times)
from fusion_gyrocal.core.noise import _join, _stretch_map, _stretches, identify_noise
from fusion_gyrocal.evaluate.sim import PAPER_BIAS_WALK_STD, PAPER_NOISE_STD, simulate_pair

WALK = 100 * PAPER_BIAS_WALK_STD


@pytest.fixture(scope="module")
def drifting():
    sim = simulate_pair(n=150_001, bias_walk_std=WALK, rng=11)   # not a whole number of filter blocks
    return sim.omega_1, sim.omega_2


def _reference_innovations(w1, w2, use):
    """The used samples through G(z) in one lfilter pass, started from the first sample (no transient)."""
    K, _ = random_walk_gain(WALK, PAPER_NOISE_STD)
    x = np.vstack([w1[use].T, w2[use].T])
    y = lfilter([1.0, -1.0], [1.0, -(1.0 - K)], x - x[:, :1], axis=-1)
    return y, x, int(np.ceil(5.0 / K))


@pytest.mark.parametrize("masked", [False, True])
def test_random_walk_bias_moments_equal_one_filter_pass(drifting, masked):
    w1, w2 = drifting
    use = np.random.default_rng(3).random(len(w1)) > 0.1 if masked else np.ones(len(w1), bool)
    m, scale, win = random_walk_bias_moments(w1, w2, WALK, PAPER_NOISE_STD, mask=use if masked else None,
                                             window=100, max_windows=10 ** 9)
    y, x, settle = _reference_innovations(w1, w2, use)
    ys = y[:, settle:]
    mu = ys.mean(axis=1)
    scatter = (ys - mu[:, None]) @ (ys - mu[:, None]).T
    assert m.count == ys.shape[1] and scale == random_walk_gain(WALK, PAPER_NOISE_STD)[1]
    np.testing.assert_allclose(m.scatter, scatter, rtol=0, atol=1e-12 * np.abs(scatter).max())
    np.testing.assert_allclose(m.mean, x.mean(axis=1), rtol=1e-13)
    # every chunk's whole windows from its first settled sample, in order
    starts = [a for c0 in range(0, y.shape[1], CHUNK_SIZE)
              for a in range(max(c0, settle), min(c0 + CHUNK_SIZE, y.shape[1]) - 99, 100)]
    assert win.n_windows == len(starts)
    blocks = np.stack([y[:, a:a + 100] for a in starts])
    means = blocks.mean(axis=2)
    c = blocks - means[:, :, None]
    np.testing.assert_allclose(win.mean, means, rtol=0, atol=1e-13 * np.abs(means).max())
    np.testing.assert_allclose(win.scatter, c @ c.transpose(0, 2, 1), rtol=0, atol=1e-12 * np.abs(scatter).max()
                               / len(starts))


def test_random_walk_bias_moments_names_the_bad_sample(drifting):
    w1, w2 = (w.copy() for w in drifting)
    w2[40_000, 1] = np.nan
    with pytest.raises(Exception, match="omega_2: expected finite rates.*sample 40000"):
        random_walk_bias_moments(w1, w2, WALK, PAPER_NOISE_STD)


@pytest.mark.parametrize("masked", [False, True])
def test_stretch_map_equals_a_fit_per_stretch(masked):
    sim = simulate_pair(n=400_000, bias_walk_std=WALK, rng=12)
    w1, w2 = sim.omega_1.copy(), sim.omega_2.copy()
    mask = None
    if masked:
        mask = np.random.default_rng(4).random(len(w1)) > 0.05
        w1[[1000, 250_000]] = np.nan            # non-finite samples are left out too
    spans = _stretches(len(w1), 100)
    j1, j2 = _join(w1, spans, np.float64), _join(w2, spans, np.float64)
    jm = None if mask is None else _join(mask, spans, bool)
    parts = []
    for a, b in spans:                          # one fit per stretch, each with a bias of its own
        use = np.isfinite(w1[a:b]).all(axis=1) & np.isfinite(w2[a:b]).all(axis=1)
        if mask is not None:
            use &= mask[a:b]
        parts.append(Moments.from_samples(np.where(use[:, None], w1[a:b], 0.0), np.where(use[:, None], w2[a:b], 0.0),
                                          mask=use))
    expected = solve_A(Moments.pool_all(parts))[0]
    got = _stretch_map(j1, j2, jm, spans[0][1] - spans[0][0], np.eye(3))
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    assert not np.allclose(got, np.eye(3))


def test_second_differences_of_stacked_stretches_equal_one_call_each():
    y = np.random.default_rng(5).standard_normal((7, 640, 3)).cumsum(axis=1)
    taus, sums, sub_n, sub_m = second_differences([y], 2.0)
    for k in range(7):
        t, s, n, m = second_differences([y[k]], 2.0)
        np.testing.assert_array_equal(t, taus)
        np.testing.assert_allclose(sums[0][:, k], s[0], rtol=1e-14)
        np.testing.assert_array_equal(sums[-1], s[-1])
        np.testing.assert_array_equal(n, sub_n)
        np.testing.assert_array_equal(m, sub_m)


def test_allan_points_of_equal_stretches_equal_those_of_unequal_ones():
    """The one-pass path (stretches of one length) against the per-stretch path it replaces."""
    y = np.random.default_rng(6).standard_normal((6 * 800 + 1, 3))
    same = allan_points(y[:6 * 800], 1.0, [800] * 6)
    cut = allan_points(y, 1.0, [800] * 5 + [801])     # the last stretch one longer: one call per stretch
    T = same.taus.size
    np.testing.assert_array_equal(same.taus, cut.taus[:T])
    assert T == cut.taus.size
    part = [second_differences([y[k * 800:(k + 1) * 800]], 1.0) for k in range(6)]
    pooled = sum(p[1][0] for p in part) / sum(p[1][-1] for p in part)[:, None]
    np.testing.assert_allclose(same.adev, np.sqrt(pooled), rtol=1e-14)


def test_rows_times_equals_matmul_bit_for_bit():
    rng = np.random.default_rng(7)
    M = rng.standard_normal((3, 3))
    for n in (0, 5, 16384, 40_001):
        x = rng.standard_normal((n, 3))
        assert np.array_equal(rows_times(x, M.T), x @ M.T)


def test_identify_noise_long_log_finds_the_walk():
    """The long-log path end to end (stretches, their A, the stacked Allan sums): the walk at its simulated size."""
    sim = simulate_pair(n=400_000, bias_walk_std=WALK, rng=13)
    A, b = solve_A(Moments.from_samples(sim.omega_1, sim.omega_2))
    nm = identify_noise(sim.omega_1, sim.omega_2, A, b, rate_hz=None)
    assert nm.bias_model == "random walk"
    assert 0.7 < nm.bias_walk_std[0] / WALK < 1.4
    assert 0.8 < nm.noise_std[0] / PAPER_NOISE_STD < 1.25
