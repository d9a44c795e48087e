"""The shortcuts of the default calibrate_pair pass give what the longer way gives (no timing asserts:
benchmarks/speed.py measures the speed)."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_gyrocal.core.array import check_distinct
from fusion_gyrocal.core.moments import PASS_ROWS, Moments, median, moments_with_extremes
from fusion_gyrocal.errors import InputError


@pytest.mark.parametrize("shape", [(1,), (2,), (7,), (1638,), (3, 16), (3, 17), (2, 4, 9)])
def test_median_equals_numpy(shape):
    rng = np.random.default_rng(sum(shape))
    for x in (rng.standard_normal(shape), np.round(rng.standard_normal(shape), 1)):   # ties too
        for axis in (None, -1, len(shape) - 1):
            got, want = median(x, axis=axis), np.median(x, axis=axis)
            assert np.shape(got) == np.shape(want)
            assert np.array_equal(got, want)


def test_median_non_finite_and_other_axes_as_numpy():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((3, 101))
    x[1, 7] = np.nan
    x[2, 9] = np.inf
    assert np.array_equal(median(x, axis=1), np.median(x, axis=1), equal_nan=True)
    assert np.array_equal(median(x, axis=0), np.median(x, axis=0), equal_nan=True)
    f = rng.standard_normal(50).astype(np.float32)
    assert median(f) == np.median(f) and np.asarray(median(f)).dtype == np.float32


def test_check_distinct_refuses_the_same_stream_and_passes_constant_ones():
    rng = np.random.default_rng(4)
    w = rng.standard_normal((20_000, 3))
    with pytest.raises(InputError, match="identical samples"):
        check_distinct(("omega_1", "omega_2"), (w, w.copy()))
    late = np.zeros((20_000, 3))
    late[-1] = 1.0                         # constant over its first rows, not over all: compared
    with pytest.raises(InputError, match="identical samples"):
        check_distinct(("a", "b"), (late, late.copy()))
    check_distinct(("a", "b"), (np.ones((20_000, 3)), np.ones((20_000, 3))))   # constant: its own message elsewhere
    other = w.copy()
    other[-1, 2] += 1e-12
    check_distinct(("a", "b"), (w, other))


@pytest.mark.parametrize("threads", [1, 2])
def test_moments_pass_chunks_agree_to_rounding(threads):
    """The pass's chunk size (PASS_ROWS) changes only the order of the sums: the moments agree to rounding with
    another chunking, and with numpy's own mean and centred scatter, for a large bias too."""
    rng = np.random.default_rng(5)
    n = 3 * PASS_ROWS + 17
    w1 = rng.standard_normal((n, 3)) + np.array([0.3, -0.2, 0.1])
    w2 = 1e-3 * rng.standard_normal((n, 3)) + 5.0
    a = Moments.from_samples(w1, w2, threads=threads)
    b = Moments.from_samples(w1, w2, chunk_size=8192, threads=threads)
    x = np.hstack([w1, w2])
    c = x - x.mean(axis=0)
    for m in (a, b):
        assert m.count == n
        assert np.allclose(m.mean, x.mean(axis=0), rtol=1e-13, atol=0)
        assert np.allclose(m.scatter, c.T @ c, rtol=1e-11, atol=1e-12 * np.abs(c.T @ c).max())
    m, e1, e2 = moments_with_extremes(w1, w2, threads=threads)
    assert np.array_equal(m.scatter, a.scatter) and np.array_equal(e1[0], w1.max(axis=0))
    assert np.array_equal(e2[1], w2.min(axis=0))
