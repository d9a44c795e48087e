"""The faster paths behind ``gyrocal calibrate``'s end-to-end time (issue 25) give what the paths they replace give.

* One correlation lobe: Newton steps on all the refinement instants start from the correlation peak (no bracketed
  search on the thinned instants first); the offset and its std equal those of the bracketed search's path.
* The splines' knot slopes are solved in place, one value channel per row: the coefficients, values and slopes are
  bit for bit those of the row-major layout they replace, and agree with scipy's ``CubicSpline``.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

import fusion_gyrocal.pipeline.alignment as al
from fusion_gyrocal.evaluate.sim import simulate_streams
from fusion_gyrocal.pipeline.resample import _hermite_coefficients, _RunSplines, _spline_slopes


def _bracketed_first(monkeypatch):
    """Make :func:`_estimate` take the bracketed search's path: its Newton steps from the peak (the first call of
    ``_newton`` in an estimate) do not settle; the later ones (from the bracketed search's minimum) run."""
    real, calls = al._newton, []

    def newton(*args):
        calls.append(args[3])
        return None if len(calls) == 1 else real(*args)

    monkeypatch.setattr(al, "_newton", newton)
    return calls


@pytest.mark.parametrize("seed", range(4))
def test_estimate_time_offset_newton_from_the_peak_matches_the_bracketed_search(monkeypatch, seed):
    rates = ((100.0, 200.0), (200.0, 200.0), (200.0, 100.0), (200.0, 200.0))[seed]
    truth = 0.0371 - 0.011 * seed
    t1, w1, t2, w2, _, _ = simulate_streams(200 + seed, rate_1=rates[0], rate_2=rates[1], duration=240.0,
                                            offset=truth, rms=(1.0, 0.2)[seed % 2])
    refined = []
    real_refine = al._refine

    def counting_refine(*args):
        refined.append(args[3])
        return real_refine(*args)

    with monkeypatch.context() as m:
        m.setattr(al, "_refine", counting_refine)
        new = al.estimate_time_offset(t1, w1, t2, w2)
    assert refined == []                                             # no bracketed search ran
    with monkeypatch.context() as m:
        calls = _bracketed_first(m)
        old = al.estimate_time_offset(t1, w1, t2, w2)
    assert len(calls) >= 2                                           # the bracketed path ran, then Newton's
    assert abs(new.offset_s - old.offset_s) <= al._tolerance(old.offset_s, 0.005)
    assert abs(new.offset_s - old.offset_s) <= 0.01 * old.std_s
    assert new.std_s == pytest.approx(old.std_s, rel=1e-3)
    assert abs(new.n_samples - old.n_samples) <= 1e-4 * old.n_samples  # instants inside gyro 2's runs near it
    assert new.drift_ppm == pytest.approx(old.drift_ppm, abs=0.01 * old.drift_std_ppm)
    assert abs(new.offset_s - truth) <= 5.0 * new.std_s


def test_newton_from_a_peak_beyond_its_reach_gives_way_to_the_bracketed_search():
    t1, w1, t2, w2, _, _ = simulate_streams(5, duration=120.0, offset=0.0371)
    ok1, ok2 = np.ones(t1.size, dtype=bool), np.ones(t2.size, dtype=bool)
    h = 0.005
    spl2, x1, y1 = al._instants(t1, w1, ok1, t2, w2, ok2, h * al._EVAL_STEP, h, 2.5 * h, 2.5 * h, al.MAX_EVAL,
                                [0.0371])
    near = al._newton(spl2, x1, y1, 0.0371 + 0.2 * h, h)
    assert near is not None and abs(near[0] - 0.0371) <= 5.0 * near[2]
    assert al._newton(spl2, x1, y1, 0.0371 + 3.0 * h, h) is None    # the minimum lies beyond +-1.5 steps
    tau, _, std = al._polish(spl2, x1, y1, 0.0371 + 1.2 * h, h)     # the bracketed search then finds it
    assert abs(tau - near[0]) <= al._tolerance(tau, h)


def _row_major_slopes(x, Y, first, last):
    """The knot slopes as the row-major layout solved them (one sample per row, the solver copying in and out)."""
    from scipy.linalg import solve_banded

    m = x.size
    dx = np.diff(x)
    slope = np.diff(Y, axis=0) / dx[:, None]
    ab = np.zeros((3, m))
    rhs = np.zeros_like(Y)
    ab[1, 1:-1] = 2.0 * (dx[:-1] + dx[1:])
    ab[0, 2:] = dx[:-1]
    ab[2, :-2] = dx[1:]
    rhs[1:-1] = 3.0 * (dx[1:, None] * slope[:-1] + dx[:-1, None] * slope[1:])
    ab[2, first[first > 0] - 1] = 0.0
    ab[0, last[last < m - 1] + 1] = 0.0
    i0, i1 = first, last
    d0 = x[i0 + 2] - x[i0]
    ab[1, i0] = dx[i0 + 1]
    ab[0, i0 + 1] = d0
    rhs[i0] = (((dx[i0] + 2.0 * d0) * dx[i0 + 1])[:, None] * slope[i0]
               + (dx[i0] ** 2)[:, None] * slope[i0 + 1]) / d0[:, None]
    d1 = x[i1] - x[i1 - 2]
    ab[1, i1] = dx[i1 - 2]
    ab[2, i1 - 1] = d1
    rhs[i1] = ((dx[i1 - 1] ** 2)[:, None] * slope[i1 - 2]
               + ((2.0 * d1 + dx[i1 - 1]) * dx[i1 - 2])[:, None] * slope[i1 - 1]) / d1[:, None]
    return solve_banded((1, 1), ab, rhs, check_finite=False)


def test_spline_slopes_in_place_equal_the_row_major_solve_bit_for_bit():
    rng = np.random.default_rng(11)
    x = np.cumsum(rng.uniform(0.004, 0.006, 5000))
    Y = rng.normal(size=(x.size, 3))
    first, last = np.array([0, 1200, 3000]), np.array([1199, 2999, 4999])   # three runs, no coupling
    dx = np.diff(x)
    slope = np.diff(np.ascontiguousarray(Y.T), axis=1) / dx
    s = _spline_slopes(x, dx, slope, first, last)
    assert s.shape == (3, x.size) and s.flags.c_contiguous
    np.testing.assert_array_equal(s, _row_major_slopes(x, Y, first, last).T)
    c = _hermite_coefficients(np.ascontiguousarray(Y.T), s, dx, slope)
    np.testing.assert_array_equal(c[3], Y[:-1].T)                    # the values at the knots
    np.testing.assert_array_equal(c[2], s[:, :-1])                   # the slopes at the knots


def test_run_splines_with_short_runs_agree_with_cubic_spline_per_run():
    rng = np.random.default_rng(12)
    t = np.cumsum(rng.uniform(0.004, 0.006, 3000))
    w = rng.normal(size=(t.size, 3))
    ok = np.ones(t.size, dtype=bool)
    ok[[500, 503, 507, 512, 2000]] = False       # runs of 2, 3 and 4 samples between the masked ones
    spl = _RunSplines(t, w, ok, 0.0125)
    for a, b in ((0, 500), (501, 503), (504, 507), (508, 512), (513, 2000), (2001, 3000)):
        q = np.linspace(t[a], t[b - 1], 50)
        values, inside = spl(q)
        assert inside.all()
        if b - a >= 4:
            want = CubicSpline(t[a:b], w[a:b])(q)
        else:   # two samples: the line; three: the parabola through them
            want = np.stack([np.polyval(np.polyfit(t[a:b], w[a:b, j], b - a - 1), q) for j in range(3)], axis=1)
        np.testing.assert_allclose(values, want, rtol=0, atol=1e-9)
