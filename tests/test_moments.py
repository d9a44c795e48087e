import numpy as np
import pytest

from fusion_gyrocal import InputError, Moments
from fusion_gyrocal.core.moments import window_moments


def _data(n=5000, bias=0.0, seed=0):
    rng = np.random.default_rng(seed)
    return rng.standard_normal((n, 3)) + bias, rng.standard_normal((n, 3)) - bias


def test_moments_from_samples_matches_numpy():
    w1, w2 = _data()
    m = Moments.from_samples(w1, w2, chunk_size=700)
    X = np.hstack([w1, w2])
    np.testing.assert_allclose(m.mean, X.mean(axis=0), atol=1e-14)
    np.testing.assert_allclose(m.scatter, (X - X.mean(0)).T @ (X - X.mean(0)), rtol=1e-12, atol=1e-10)
    assert m.count == 5000 and m.segments == 1


def test_moments_merge_halves_equal_whole():
    w1, w2 = _data()
    whole = Moments.from_samples(w1, w2)
    halves = Moments.from_samples(w1[:1234], w2[:1234]) + Moments.from_samples(w1[1234:], w2[1234:])
    np.testing.assert_allclose(halves.scatter, whole.scatter, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(halves.mean, whole.mean, atol=1e-14)
    assert halves.count == whole.count


def test_moments_large_bias_keeps_precision():
    # A bias 1e6 times the spread: naive raw sums of squares would lose ~12 digits.
    w1, w2 = _data(20000, bias=1e6)
    m = Moments.from_samples(w1, w2, chunk_size=1000)
    c1, c2 = w1 - w1.mean(0), w2 - w2.mean(0)
    ref = np.hstack([c1, c2])
    np.testing.assert_allclose(m.scatter, ref.T @ ref, rtol=1e-7, atol=1e-3)


def test_moments_float32_input_accumulates_in_float64():
    w1, w2 = _data()
    m32 = Moments.from_samples(w1.astype(np.float32), w2.astype(np.float32))
    m64 = Moments.from_samples(w1.astype(np.float32).astype(np.float64), w2.astype(np.float32).astype(np.float64))
    assert m32.scatter.dtype == np.float64
    np.testing.assert_allclose(m32.scatter, m64.scatter, rtol=1e-12)


def test_moments_threads_equal_single_thread():
    w1, w2 = _data(300000)
    a = Moments.from_samples(w1, w2, chunk_size=4096, threads=1)
    b = Moments.from_samples(w1, w2, chunk_size=4096, threads=2)
    np.testing.assert_allclose(a.scatter, b.scatter, rtol=1e-11)


def test_moments_mask_selects_rows():
    w1, w2 = _data()
    keep = np.arange(5000) % 3 != 0
    a = Moments.from_samples(w1, w2, mask=keep, chunk_size=512)
    b = Moments.from_samples(w1[keep], w2[keep])
    np.testing.assert_allclose(a.scatter, b.scatter, rtol=1e-12)
    assert a.count == keep.sum()


def test_moments_pool_drops_between_window_spread():
    w1, w2 = _data(4000)
    w1 = w1 + np.repeat(np.arange(4), 1000)[:, None]  # a bias that steps every 1000 samples
    parts = window_moments(w1, w2, 1000)
    pooled = Moments.pool_all(parts)
    assert pooled.segments == 4 and pooled.dof == 3996
    within = sum(((w1[i:i + 1000] - w1[i:i + 1000].mean(0)) ** 2).sum(0) for i in range(0, 4000, 1000))
    np.testing.assert_allclose(np.diag(pooled.S11), within, rtol=1e-12)


def test_moments_decayed_scales_weight():
    w1, w2 = _data()
    m = Moments.from_samples(w1, w2).decayed(0.5)
    assert m.count == 2500
    np.testing.assert_allclose(m.scatter, Moments.from_samples(w1, w2).scatter * 0.5)


def test_moments_nonfinite_names_sample():
    w1, w2 = _data()
    w2 = w2.copy()
    w2[4321, 2] = np.inf
    with pytest.raises(InputError, match="omega_2.*sample 4321"):
        Moments.from_samples(w1, w2, chunk_size=1000)


@pytest.mark.parametrize("bad, msg", [(np.zeros((10, 2)), r"expected shape \(N, 3\), got \(10, 2\)"),
                                      (np.zeros((9, 3)), "expected 10 samples"),
                                      (np.array([["a"] * 3] * 10), "numeric")])
def test_moments_bad_shapes_raise(bad, msg):
    with pytest.raises(InputError, match=msg):
        Moments.from_samples(np.zeros((10, 3)), bad)


def test_moments_dict_round_trip():
    w1, w2 = _data()
    m = Moments.from_samples(w1, w2)
    m2 = Moments.from_dict(m.to_dict())
    np.testing.assert_array_equal(m.scatter, m2.scatter)
    assert m2.count == m.count


def test_moments_from_samples_two_arrays_equal_stacked_centred_scatter():
    # the one-pass Gram sum over two separate arrays, several threads and chunks, against numpy
    w1, w2 = _data(300001, bias=3.0, seed=4)
    m = Moments.from_samples(w1, w2, chunk_size=4096, threads=2)
    X = np.hstack([w1, w2]).astype(np.longdouble)    # an extended-precision reference
    Xc = X - X.mean(axis=0)
    np.testing.assert_allclose(m.scatter, np.asarray(Xc.T @ Xc, dtype=np.float64), rtol=1e-12, atol=1e-8)
    np.testing.assert_allclose(m.mean, np.asarray(X.mean(axis=0), dtype=np.float64), rtol=0, atol=1e-14)


def test_moments_from_samples_drift_far_from_first_chunk_keeps_precision():
    # the mean wanders 1e5 spreads away from the first chunk's mean: the one-shift sum would cancel,
    # the chunk-by-chunk fallback must keep the digits
    rng = np.random.default_rng(5)
    n = 40000
    drift = np.linspace(0.0, 1e5, n)[:, None]
    w1, w2 = rng.standard_normal((n, 3)) + drift, rng.standard_normal((n, 3)) - drift
    m = Moments.from_samples(w1, w2, chunk_size=1000, threads=1)
    X = np.hstack([w1, w2]).astype(np.longdouble)
    Xc = X - X.mean(axis=0)
    ref = np.asarray(Xc.T @ Xc, dtype=np.float64)
    np.testing.assert_allclose(m.scatter, ref, rtol=1e-9)


def test_moments_from_samples_nan_after_first_chunk_names_row():
    w1, w2 = _data(50000)
    w2 = w2.copy()
    w2[43210, 1] = np.nan
    with pytest.raises(InputError, match="omega_2.*sample 43210"):
        Moments.from_samples(w1, w2, chunk_size=4096, threads=1)
