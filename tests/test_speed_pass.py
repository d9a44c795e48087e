"""The shortcuts of the default calibrate_pair pass give what the longer way gives (no timing asserts:
benchmarks/speed.py measures the speed)."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_gyrocal.core.array import check_distinct
from fusion_gyrocal.core.moments import CHUNK_SIZE, Moments, median, moments_with_extremes
from fusion_gyrocal.errors import InputError


@pytest.mark.parametrize("shape", [(1,), (2,), (7,), (1638,), (3, 16), (3, 17), (2, 4, 9)])
def test_median_equals_numpy(shape):
    rng = np.random.default_rng(sum(shape))
    for x in (rng.standard_normal(shape), np.round(rng.standard_normal(shape), 1)):   # ties too
        for axis in (None, -1, len(shape) - 1):
            got, want = median(x, axis=axis), np.median(x, axis=axis)
            assert np.shape(got) == np.shape(want)
            assert np.array_equal(got, want)
            scratch = x.copy()      # partitioned in place: the same value, the same values in other places
            assert np.array_equal(median(scratch, axis=axis, overwrite_input=True), want)
            along = None if axis is None else -1                  # (all values: the flattened array)
            assert np.array_equal(np.sort(scratch, axis=along), np.sort(x, axis=along))


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
def test_moments_pass_parts_agree_to_rounding(threads, monkeypatch):
    """The parts a long pass is cut into (several per worker) change only the order of the sums: the moments agree
    to rounding with one part per worker, and with numpy's own mean and centred scatter, for a large bias too."""
    import fusion_gyrocal.core.moments as moments

    rng = np.random.default_rng(5)
    n = 70 * CHUNK_SIZE + 17
    w1 = rng.standard_normal((n, 3)) + np.array([0.3, -0.2, 0.1])
    w2 = 1e-3 * rng.standard_normal((n, 3)) + 5.0
    a = Moments.from_samples(w1, w2, threads=threads)
    m, e1, e2 = moments_with_extremes(w1, w2, threads=threads)
    monkeypatch.setattr(moments, "_PARTS_PER_WORKER", 1)
    b = Moments.from_samples(w1, w2, threads=threads)
    x = np.hstack([w1, w2])
    c = x - x.mean(axis=0)
    for mom in (a, b):
        assert mom.count == n
        assert np.allclose(mom.mean, x.mean(axis=0), rtol=1e-13, atol=0)
        assert np.allclose(mom.scatter, c.T @ c, rtol=1e-11, atol=1e-12 * np.abs(c.T @ c).max())
    assert np.array_equal(m.scatter, a.scatter) and np.array_equal(e1[0], w1.max(axis=0))
    assert np.array_equal(e2[1], w2.min(axis=0))



def _cases():
    """Simulated pairs the default path is checked on: nominal, a drifting bias, clipped input with a mask, and
    a pair whose gyro 2 lags by beat tones (the timing model)."""
    from fusion_gyrocal.evaluate.sim import PAPER_BIAS_WALK_STD, HumanMotion, random_rotation, simulate_pair

    sim = simulate_pair(n=200_000, rng=3)
    yield "nominal", (sim.omega_1, sim.omega_2), {}
    sim = simulate_pair(n=120_000, bias_walk_std=100 * PAPER_BIAS_WALK_STD, rng=1)
    yield "drifting bias", (sim.omega_1, sim.omega_2), {}
    sim = simulate_pair(n=80_000, rng=5, rms=2.0)
    keep = np.ones(80_000, bool)
    keep[1000:5000] = False
    yield "clipped and masked", (np.clip(sim.omega_1, -3.0, 3.0), np.clip(sim.omega_2, -3.0, 3.0)), {"mask": keep}
    rng = np.random.default_rng([42, 0])
    t = np.arange(40_000) / 200.0
    motion = HumanMotion(3.0, max_freq_hz=4.0, rng=rng)
    d2 = 0.5e-3 * (1.0 + np.sin(2 * np.pi * 0.35 * t)) + 0.4e-3 * np.sin(2 * np.pi * 2.5 * t + 1.0)
    R = random_rotation(rng)
    w1 = motion(t) + rng.normal(0, 1e-3, (t.size, 3)) + 0.01
    w2 = motion(t - d2) @ R + rng.normal(0, 1e-3, (t.size, 3)) - 0.01
    yield "timing model", (w1, w2), {"t_1": t, "t_2": t}


def _relative(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(a)), 1e-300))


@pytest.mark.parametrize("case", [c[0] for c in _cases()])
def test_calibrate_pair_pass_layout_changes_only_rounding(case, monkeypatch):
    """The moments pass as it was (one part per worker thread) and as it is (several) give the same calibration:
    estimate and bias within 1e-9, covariance within 1e-8 relative (the residual's cancellation amplifies the
    sums' rounding: the same spread as between one and two worker threads), and the same decisions."""
    import warnings

    import fusion_gyrocal.core.moments as moments
    from fusion_gyrocal import calibrate_pair

    name, args, keywords = next(c for c in _cases() if c[0] == case)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        monkeypatch.setattr(moments, "_MIN_PART_CHUNKS", 1)    # these short logs cut into parts as long ones are
        now = calibrate_pair(*args, **keywords)
        monkeypatch.setattr(moments, "_PARTS_PER_WORKER", 1)
        before = calibrate_pair(*args, **keywords)
    assert now.rigid == before.rigid and now.configuration == before.configuration
    assert now.n_samples == before.n_samples and now.rejected_fraction == before.rejected_fraction
    assert now.noise_model.bias_model == before.noise_model.bias_model
    assert now.noise_model.noise_kind == before.noise_model.noise_kind
    assert len(now.notes) == len(before.notes)
    assert _relative(now.R_1_2, before.R_1_2) < 1e-9
    assert _relative(now.scale_1, before.scale_1) < 1e-9 and _relative(now.scale_2, before.scale_2) < 1e-9
    assert _relative(now.bias, before.bias) < 1e-9
    assert _relative(now.covariance, before.covariance) < 1e-8
    assert _relative(now.noise_std, before.noise_std) < 1e-9
    if case == "timing model":
        assert now.timing_tones_hz and len(now.timing_tones_hz) == len(before.timing_tones_hz)
        assert _relative(now.timing_tones_hz, before.timing_tones_hz) < 1e-9


@pytest.mark.parametrize("threads", [1, 2])
def test_moments_with_extremes_exact_over_many_parts(threads, monkeypatch):
    """Each part shifts by its own mean; the column extremes and their repeats stay exact when the extreme sits in
    two parts, or in one part only with another part's extreme a rounding away from it."""
    import fusion_gyrocal.core.moments as moments

    monkeypatch.setattr(moments, "_MIN_PART_CHUNKS", 1)
    rng = np.random.default_rng(8)
    n = 40 * 1000 + 321
    w1 = rng.standard_normal((n, 3)) * 1e-3 + np.array([7.0, -3.0, 0.25])
    w1[:20_000] += 1e-6 * np.arange(20_000)[:, None]          # parts with quite different means (shifts)
    w2 = np.clip(rng.standard_normal((n, 3)), -2.0, 2.5)
    top = w1[:, 0].max()
    w1[500, 0] = w1[39_000, 0] = top + 1e-9                   # a repeated maximum in the first and the last part
    near = np.nextafter(w1[:, 1].max(), np.inf)
    w1[12_345, 1] = near                                       # a maximum one rounding above the next part's
    w1[30_000, 1] = np.nextafter(near, -np.inf)
    for w in (w1, w2):
        w[-1] = w[:-1].min(axis=0)                            # repeated minima at the very end
    m, e1, e2 = moments_with_extremes(w1, w2, chunk_size=1000, threads=threads)
    for got, w in ((e1, w1), (e2, w2)):
        hi, lo = w.max(axis=0), w.min(axis=0)
        assert np.array_equal(got[0], hi) and np.array_equal(got[1], lo)
        assert np.array_equal(got[2], (w == hi).sum(axis=0) >= 2)
        assert np.array_equal(got[3], (w == lo).sum(axis=0) >= 2)
    assert e1[2][0] and not e1[2][1] and e1[3].all() and e2[2].all()
