"""Correctness of the shortcuts the default calibrate_pair path takes for speed (no timing asserts here:
benchmarks/speed.py measures the speed): each gives what the longer way gives."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_gyrocal import Moments, calibrate_pair
from fusion_gyrocal.core.moments import column_extremes, moments_with_extremes, random_walk_bias_moments
from fusion_gyrocal.errors import InputError
from fusion_gyrocal.evaluate.sim import PAPER_BIAS_WALK_STD, simulate_pair
from fusion_gyrocal.pipeline.flex import _window_means
from fusion_gyrocal.pipeline.streams import saturation_mask
from fusion_gyrocal.pipeline.timing import estimate_timing
from fusion_gyrocal.units import _row_norms


def _naive_extremes(x):
    hi, lo = x.max(axis=0), x.min(axis=0)
    return hi, lo, (x == hi).sum(axis=0) >= 2, (x == lo).sum(axis=0) >= 2


@pytest.mark.parametrize("n", [1, 2, 5, 1023, 1024, 1025, 4096 + 7, 50_000])
def test_column_extremes_matches_numpy(n):
    rng = np.random.default_rng(n)
    x = rng.standard_normal((n, 3))
    if n > 10:
        x[3:9, 1] = x[:, 1].max() + 1.0          # a repeated maximum
        x[-2:, 2] = x[:, 2].min() - 1.0           # a repeated minimum at the tail
    for arr in (x, np.asfortranarray(x), x[::-1]):
        for got, want in zip(column_extremes(arr), _naive_extremes(arr)):
            assert np.array_equal(got, want)


def test_column_extremes_nan_propagates_and_empty_refused():
    x = np.random.default_rng(0).standard_normal((5000, 3))
    x[1234, 0] = np.nan
    hi, lo, _, _ = column_extremes(x)
    assert np.isnan(hi[0]) and np.isnan(lo[0]) and np.isfinite(hi[1:]).all()
    with pytest.raises(InputError, match="at least one row"):
        column_extremes(np.zeros((0, 3)))


@pytest.mark.parametrize("n, chunk, threads", [(10, 4, 1), (100_003, 8192, 2), (70_000, 1000, 2), (8192, 8192, 2)])
def test_moments_with_extremes_equals_separate_passes(n, chunk, threads):
    rng = np.random.default_rng(n)
    w1 = rng.standard_normal((n, 3)) + 5.0
    w2 = np.clip(rng.standard_normal((n, 3)), -1.5, 2.0)     # clipped: repeated extremes
    m, e1, e2 = moments_with_extremes(w1, w2, chunk_size=chunk, threads=threads)
    ref = Moments.from_samples(w1, w2, chunk_size=chunk, threads=threads)
    assert m.count == ref.count
    assert np.array_equal(m.mean, ref.mean) and np.array_equal(m.scatter, ref.scatter)
    for got, w in ((e1, w1), (e2, w2)):
        for a, b in zip(got, _naive_extremes(w)):
            assert np.array_equal(a, b)


def test_moments_with_extremes_refuses_nonfinite():
    w = np.random.default_rng(1).standard_normal((100, 3))
    w[50, 1] = np.inf
    with pytest.raises(InputError, match="non-finite"):
        moments_with_extremes(w, w.copy())


def test_saturation_mask_with_known_extremes_is_the_same():
    rng = np.random.default_rng(2)
    w = np.clip(3.0 * rng.standard_normal((30_000, 3)), -4.0, 4.0)
    full = saturation_mask(w)
    assert full.any()
    assert np.array_equal(saturation_mask(w, extremes=column_extremes(w)), full)
    clean = rng.standard_normal((30_000, 3))
    assert not saturation_mask(clean, extremes=column_extremes(clean)).any()


def test_calibrate_pair_clipped_input_masked_as_with_the_mask_given():
    sim = simulate_pair(n=40_000, rng=3)
    w1 = np.clip(sim.omega_1, -2.0, 2.0)
    clipped = (np.abs(w1) >= 2.0).any(axis=1)
    assert 0 < clipped.mean() < 0.5
    auto = calibrate_pair(w1, sim.omega_2)
    given = calibrate_pair(w1, sim.omega_2, mask=~clipped)
    assert any("sit flat at an axis's extreme" in n for n in auto.notes)
    assert np.array_equal(auto.A, given.A) and np.array_equal(auto.bias, given.bias)


@pytest.mark.parametrize("window", [1, 7, 100, 10**12])
def test_window_means_equals_loop(window):
    rng = np.random.default_rng(window % 97)
    r = rng.standard_normal((1000, 3)) + 3.0
    used = rng.random(1000) < 0.8
    used[200:400] = False                        # windows with no used row keep their values
    ref = r.copy()
    for k in range(0, len(r), min(window, len(r))):
        u = used[k:k + window]
        if u.any():
            ref[k:k + window] -= ref[k:k + window][u].mean(axis=0)
    assert np.array_equal(r - _window_means(r, used, window), ref)


def test_random_walk_moments_window_budget():
    sim = simulate_pair(n=300_000, bias_walk_std=100 * PAPER_BIAS_WALK_STD, rng=4)
    args = (sim.omega_1, sim.omega_2, 100 * PAPER_BIAS_WALK_STD, 1.7e-3)
    m_all, _, all_windows = random_walk_bias_moments(*args, window=100, max_windows=10**9)
    m_few, _, few = random_walk_bias_moments(*args, window=100)
    assert np.array_equal(m_all.scatter, m_few.scatter) and m_all.count == m_few.count
    assert all_windows.n_windows > 1024 >= few.n_windows > 512
    assert all_windows.weight == pytest.approx(m_all.count / all_windows.count.sum())
    assert few.weight == pytest.approx(m_few.count / few.count.sum()) and few.weight > 2.0
    assert np.unique(few.run).size > 4                  # chunks spread over the log, not one stretch
    assert few.run.max() - few.run.min() > 0.8 * 300_000


def test_estimate_timing_without_index_is_the_same():
    rng = np.random.default_rng(5)
    n = 80_000
    t = np.arange(n, dtype=float)
    w2 = np.column_stack([np.sin(2 * np.pi * t / f) for f in (300.0, 470.0, 830.0)])
    delay = 0.4 + 0.3 * np.sin(2 * np.pi * 0.0031 * t)           # samples, a beat tone
    w1 = w2 + np.gradient(w2, axis=0) * delay[:, None] + rng.normal(0, 1e-4, (n, 3))
    a = estimate_timing(t, w1, w2, np.eye(3), np.zeros(3))
    b = estimate_timing(None, w1, w2, np.eye(3), np.zeros(3))
    assert a.significant and a.tones_hz == b.tones_hz
    assert np.array_equal(a.coefficients, b.coefficients) and a.explained == b.explained


def test_row_norms_equal_linalg_norm():
    x = np.random.default_rng(6).standard_normal((10_000, 3)) * 1e3
    assert np.array_equal(_row_norms(x), np.linalg.norm(x, axis=1))
