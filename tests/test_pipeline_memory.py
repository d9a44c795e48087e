"""Equivalence of the memory-lean steps of the timestamped pipeline (issue 25) with their plain definitions."""

import numpy as np
import pytest

from fusion_gyrocal.pipeline.resample import _GRID_BLOCK, _query_steps, noise_factors, resample
from fusion_gyrocal.pipeline.streams import _nominal_period


def _reference_steps(grid):
    """The median step of the finite instants in time order and the increasing check, as first written."""
    g = grid[np.isfinite(grid)]
    if g.size < 2:
        period = float("nan")
    else:
        if not np.all(np.diff(g) > 0):
            g = np.unique(g)
        period = float(np.median(np.diff(g))) if g.size >= 2 else float("nan")
    return period, bool(np.all(np.diff(grid) > 0))


def _grids():
    rng = np.random.default_rng(4)
    steady = np.cumsum(rng.uniform(0.004, 0.006, 1001))
    with_nan = steady.copy()
    with_nan[[0, 500, -1]] = np.nan
    repeated = np.repeat(steady[:300], 2)
    return {"steady": steady, "nan": with_nan, "shuffled": rng.permutation(steady), "repeated": repeated,
            "even count": steady[:1000], "one": steady[:1], "all nan": np.full(5, np.nan),
            "one finite": np.r_[np.nan, 2.0, np.nan], "constant": np.full(7, 3.0)}


@pytest.mark.parametrize("name", list(_grids()))
def test_query_steps_matches_definition(name):
    grid = _grids()[name]
    before = grid.copy()
    period, increasing = _query_steps(grid)
    ref_period, ref_increasing = _reference_steps(grid)
    np.testing.assert_equal(period, ref_period)
    if grid.size > 1:
        assert increasing == ref_increasing
    np.testing.assert_array_equal(grid, before)       # the steps are partitioned, never the instants


def test_nominal_period_matches_median_of_steps():
    rng = np.random.default_rng(5)
    for t in (np.cumsum(rng.uniform(0.001, 0.01, 2001)), rng.normal(size=1000), np.arange(4.0)):
        before = t.copy()
        assert _nominal_period(t) == float(np.median(np.diff(t)))
        np.testing.assert_array_equal(t, before)


def test_noise_factors_ordered_instants_equal_masked():
    rng = np.random.default_rng(6)
    t = np.arange(40000) / 200.0 + rng.uniform(-1e-3, 1e-3, 40000)
    q = np.arange(-500, 40500) / 200.0 + 0.0013          # beyond the samples on both sides, in time order
    ordered = noise_factors(t, q)
    masked = noise_factors(t, np.r_[q, np.nan])           # out of order: the instants selected by the mask
    assert ordered == masked
    assert 0.5 < ordered[0] < 1.0


def test_resample_long_grid_with_a_nan_equals_blocked():
    rng = np.random.default_rng(7)
    n = 3 * _GRID_BLOCK
    t = np.arange(n) / 100.0 + rng.uniform(-2e-3, 2e-3, n)
    w = np.sin(np.outer(t, [0.7, 1.3, 2.1])) + 0.01 * rng.normal(size=(n, 3))
    grid = t[5:-5] - 0.0021
    blocked, inside = resample(t, w, grid)                 # increasing: block by block
    whole, inside_nan = resample(t, w, np.r_[grid, np.nan])   # a non-finite instant: one pass over the record
    assert inside.all() and not inside_nan[-1] and inside_nan[:-1].all()
    assert np.isnan(whole[-1]).all()
    np.testing.assert_allclose(whole[:-1], blocked, rtol=0, atol=1e-12)
