"""The faster paths behind ``gyrocal calibrate``'s end-to-end time (issue 25) give what the paths they replace give.

The splines' knot slopes are solved in place, one value channel per row: the coefficients, values and slopes are
bit for bit those of the row-major layout they replace, and agree with scipy's ``CubicSpline``.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from fusion_gyrocal.pipeline.resample import _hermite_coefficients, _RunSplines, _spline_slopes


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
