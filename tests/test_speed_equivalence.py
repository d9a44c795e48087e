"""The faster paths of issue 25 compute what the plain ones compute.

* the screening pass of :func:`fusion_gyrocal.core.allan._wls_many` (one pass of many candidate terms weighted by
  the current model, whitened by one factor) gives each candidate the chi-square of its own one-pass
  :func:`~fusion_gyrocal.core.allan._wls` fit;
* :meth:`_RunSplines.values_and_slopes` (one interval lookup) gives the values and slopes of two separate calls.
"""

import numpy as np
import pytest

from fusion_gyrocal.core import allan
from fusion_gyrocal.pipeline.resample import _RunSplines


def _residual_points(seed: int, walk: float):
    """Allan points of white noise plus a random walk (the kind of residual the noise model fits)."""
    rng = np.random.default_rng(seed)
    n, rate = 200_000, 100.0
    y = rng.normal(0.0, 1e-3, (n, 3)) + np.cumsum(rng.normal(0.0, walk, (n, 3)), axis=0)
    taus, adev, sub_n, sub_m, scatter = allan.allan_points(y, rate)
    return taus, (adev ** 2).mean(axis=1), allan.edf_table(sub_n, sub_m), scatter[:, 3]


@pytest.mark.parametrize("measured_scatter", [False, True])
def test_wls_many_screening_pass_matches_one_pass_of_wls(measured_scatter):
    taus, avar, edf, scatter = _residual_points(3, 2e-6)
    sc = scatter if measured_scatter else None
    tau0 = float(taus[0])
    terms = [allan.WHITE]
    best = allan._wls(taus, avar, edf, terms, tau0=tau0, scatter=sc)
    cands = [((term,), c) for term, c in allan._candidates(taus, terms, 1e9, tau0)]   # as _select makes them
    cands += [((allan.QUANTISATION, allan.WALK), None)]     # a pair of fixed terms, as _select tries them
    assert len(cands) > allan.SCREENED       # what _best_addition screens
    par = {allan.FILTERED: None, allan.TONE: None, allan.BOUNDED: None}
    params = []
    for add, c in cands:
        p = dict(par)
        p.update({term: c for term in add if term in allan.SCANNED})
        params.append(p)
    jobs = [(terms + list(add), p[allan.FILTERED], p[allan.TONE], p[allan.BOUNDED]) for (add, _), p in zip(cands, params)]
    got = np.array([f[2] for f in allan._wls_many(taus, avar, edf, jobs, tau0, sc, best[3], 1)])
    want = np.array([allan._wls(taus, avar, edf, terms + list(add), p[allan.FILTERED], p[allan.TONE], tau0, sc,
                                best[3], 1, p[allan.BOUNDED])[2] for (add, _), p in zip(cands, params)])
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * float(np.max(want)))
    # the candidates it would keep for the full fit are the same
    assert list(np.argsort(-(best[2] - got), kind="stable")[:allan.SCREENED]) == \
        list(np.argsort(-(best[2] - want), kind="stable")[:allan.SCREENED])


def test_values_and_slopes_equal_call():
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.004, 0.006, 5000))
    y = np.column_stack([np.sin(3.0 * t), np.cos(2.0 * t), t ** 2]) + rng.normal(0, 1e-3, (t.size, 3))
    ok = np.ones(t.size, dtype=bool)
    ok[[100, 2000, 2001]] = False            # three runs
    spl = _RunSplines(t, y, ok, 0.0125)
    x = np.sort(rng.uniform(t[0], t[-1], 20_000))
    x = x[spl.run_of(x) >= 0]
    values, slopes = spl.values_and_slopes(x)
    assert np.array_equal(values, spl(x)[0])
    assert np.array_equal(slopes, spl(x, nu=1)[0])
    assert values.shape == slopes.shape == (x.size, 3)


@pytest.mark.parametrize("measured_scatter", [False, True])
@pytest.mark.parametrize("added", [1, 2])
def test_wls_many_equals_wls_per_job(measured_scatter, added):
    taus, avar, edf, scatter = _residual_points(4, 5e-6)
    sc = scatter if measured_scatter else None
    tau0 = float(taus[0])
    singles = [((term,), c) for term, c in allan._candidates(taus, [allan.WHITE], 1e9, tau0)]
    fixed = [allan.QUANTISATION, allan.WALK, allan.FLICKER_TERM]
    adds = singles if added == 1 else [((p, q), None) for i, p in enumerate(fixed) for q in fixed[i + 1:]]
    jobs = []
    for add, c in adds:
        p = {allan.FILTERED: None, allan.TONE: None, allan.BOUNDED: None}
        p.update({term: c for term in add if term in allan.SCANNED})
        jobs.append(([allan.WHITE, *add], p[allan.FILTERED], p[allan.TONE], p[allan.BOUNDED]))
    got = allan._wls_many(taus, avar, edf, jobs, tau0, sc)
    assert len(got) == len(jobs) > 1
    for (terms, tc, tone, tb), fit in zip(jobs, got):
        want = allan._wls(taus, avar, edf, terms, tc, tone, tau0, sc, tb=tb)
        np.testing.assert_allclose(fit[0], want[0], rtol=1e-12, atol=0)       # coefficients
        np.testing.assert_allclose(fit[1], want[1], rtol=1e-10, atol=0)       # covariance (NaN where no term)
        np.testing.assert_allclose(fit[2], want[2], rtol=1e-12)               # chi-square
        np.testing.assert_allclose(fit[3], want[3], rtol=1e-12)               # model
        np.testing.assert_allclose(fit[4], want[4], rtol=1e-12)               # worst ratio
