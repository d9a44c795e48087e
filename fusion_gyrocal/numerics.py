"""Three small numerical solvers of the calibration path, in numpy alone.

``gyrocal calibrate`` needs a bounded 1-D minimiser (the time offset's sub-sample refinement), a tridiagonal
solve (the knot slopes of the resampling splines) and a small non-negative least squares (the Allan-variance
fit). scipy has all three, but importing ``scipy.optimize`` and ``scipy.linalg`` costs more CPU time than
reading an hour of 200 Hz CSV; these are the classical algorithms, written for the sizes the library uses:

* :func:`minimize_bounded`: Brent's method on an interval (golden-section steps and successive parabolic
  interpolation, as in Forsythe, Malcolm & Moler, *Computer Methods for Mathematical Computations*, 1977,
  procedure ``fmin``, the algorithm behind ``scipy.optimize.minimize_scalar(method="bounded")``);
* :func:`solve_tridiagonal`: odd-even cyclic reduction, vectorised level by level (stable for diagonally
  dominant systems, without pivoting);
* :func:`nnls`: the Lawson & Hanson active-set method (*Solving Least Squares Problems*, 1974, ch. 23).
"""

from __future__ import annotations

import math

import numpy as np

_GOLDEN = 0.5 * (3.0 - math.sqrt(5.0))     # the golden-section fraction, 0.381966...
_SQRT_EPS = math.sqrt(2.2e-16)           # sqrt of the double-precision machine epsilon (rounded to 2.2e-16)


def minimize_bounded(f, lo: float, hi: float, *, xatol: float, maxfun: int = 500) -> tuple[float, float]:
    """Minimise a scalar function on ``[lo, hi]`` by Brent's method; ``(x, f(x))`` at the best point found.

    Each step is a parabola through the three best points when it falls inside the interval and moves less than
    half the step before last, else a golden-section step into the larger part; no evaluation is closer than
    ``tol = sqrt(eps) |x| + xatol / 3`` to another or to the ends. Stops when the interval around the best
    point ``x`` is within ``2 tol`` of it (or after ``maxfun`` evaluations).

    Parameters
    ----------
    f : callable
        ``f(x) -> float``.
    lo, hi : float
        The interval, ``lo < hi``.
    xatol : float
        Absolute tolerance on ``x``.
    maxfun : int
        Most evaluations of ``f``.
    """
    a, b = float(lo), float(hi)
    x = w = v = a + _GOLDEN * (b - a)
    fx = fw = fv = float(f(x))
    d = e = 0.0
    for _ in range(maxfun - 1):
        xm = 0.5 * (a + b)
        tol1 = _SQRT_EPS * abs(x) + xatol / 3.0
        tol2 = 2.0 * tol1
        if abs(x - xm) <= tol2 - 0.5 * (b - a):
            break
        golden = True
        if abs(e) > tol1:                       # try a parabola through (v, fv), (w, fw), (x, fx)
            r = (x - w) * (fx - fv)
            q = (x - v) * (fx - fw)
            p = (x - v) * q - (x - w) * r
            q = 2.0 * (q - r)
            if q > 0.0:
                p = -p
            q = abs(q)
            r, e = e, d
            if abs(p) < abs(0.5 * q * r) and q * (a - x) < p < q * (b - x):
                d = p / q
                u = x + d
                if u - a < tol2 or b - u < tol2:     # not too close to the ends
                    d = tol1 if xm >= x else -tol1
                golden = False
        if golden:
            e = a - x if x >= xm else b - x
            d = _GOLDEN * e
        u = x + (d if abs(d) >= tol1 else (tol1 if d >= 0.0 else -tol1))
        fu = float(f(u))
        if fu <= fx:
            if u >= x:
                a = x
            else:
                b = x
            v, fv, w, fw, x, fx = w, fw, x, fx, u, fu
        else:
            if u < x:
                a = u
            else:
                b = u
            if fu <= fw or w == x:
                v, fv, w, fw = w, fw, u, fu
            elif fu <= fv or v == x or v == w:
                v, fv = u, fu
    return x, fx


def solve_tridiagonal(sub: np.ndarray, diag: np.ndarray, sup: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve ``sub[i] x[i-1] + diag[i] x[i] + sup[i] x[i+1] = rhs[i]`` (``sub[0]``, ``sup[-1]`` unused).

    Odd-even cyclic reduction: every level eliminates the odd-numbered unknowns from their even neighbours'
    rows (one vectorised pass), halving the system until one row is left, then fills the eliminated unknowns
    back in, level by level. No pivoting: the system must be diagonally dominant (every row's diagonal at least
    the sum of its off-diagonals, strictly somewhere in every coupled stretch), which keeps every pivot nonzero
    and the reduction stable.

    Parameters
    ----------
    sub, diag, sup : ndarray, shape (m,)
        The three diagonals.
    rhs : ndarray, shape (m,) or (m, k)
        Right-hand side(s).

    Returns
    -------
    ndarray
        ``x``, shaped as ``rhs``.
    """
    d = np.asarray(rhs, dtype=float)
    one = d.ndim == 1
    d = np.ascontiguousarray(d.reshape(d.shape[0], -1).T)     # (k, m): each right-hand side contiguous
    a = np.array(sub, dtype=float)
    b = np.asarray(diag, dtype=float)
    c = np.array(sup, dtype=float)
    a[0] = 0.0
    c[-1] = 0.0
    levels = []
    while b.size > 1:
        # even rows 0, 2, ... keep their unknowns; odd rows 1, 3, ... are eliminated from them
        ao, co, do = a[1::2], c[1::2], d[:, 1::2]
        inv = 1.0 / b[1::2]
        ne, no = (b.size + 1) // 2, inv.size
        left = a[2::2] * inv[:ne - 1]        # even row i >= 2: its row minus left x row i - 1
        right = c[0:2 * no:2] * inv          # even row i: minus right x row i + 1
        nb = b[0::2].copy()
        nb[1:] -= left * co[:ne - 1]
        nb[:no] -= right * ao
        nd = d[:, 0::2].copy()
        nd[:, 1:] -= left * do[:, :ne - 1]
        nd[:, :no] -= right * do
        na = np.zeros(ne)
        np.multiply(left, ao[:ne - 1], out=na[1:])
        np.negative(na, out=na)
        nc = np.zeros(ne)
        np.multiply(right, co, out=nc[:no])
        np.negative(nc, out=nc)
        levels.append((ao, co, do, inv))
        a, b, c, d = na, nb, nc, nd
    x = d / b
    for ao, co, do, inv in reversed(levels):
        no, ne = inv.size, x.shape[1]
        full = np.empty((x.shape[0], ne + no))
        full[:, 0::2] = x
        odd = do - ao * x[:, :no]
        k = min(no, ne - 1)                      # odd rows with an even row after them
        odd[:, :k] -= co[:k] * x[:, 1:k + 1]
        odd *= inv
        full[:, 1::2] = odd
        x = full
    return x[0] if one else x.T


def nnls(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """Non-negative least squares ``min |A x - b|`` subject to ``x >= 0``; ``(x, |A x - b|)``.

    Lawson & Hanson's active-set method: the variable with the most negative gradient of the residual joins the
    passive (free) set; the unconstrained least squares on the passive set is taken if it is positive, else the
    step goes as far towards it as keeps every variable non-negative and the variables that reach zero leave.
    For a full-column-rank ``A`` the solution is unique. Meant for the few columns of a noise-model fit.
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    n = A.shape[1]
    x = np.zeros(n)
    free = np.zeros(n, dtype=bool)
    # a gradient below rounding of A^T b does not free a variable (relative: the scale of A and b is the caller's)
    tol = 10.0 * max(A.shape) * np.finfo(float).eps * np.abs(A).sum(axis=0).max(initial=0.0) * np.abs(b).max(
        initial=0.0)
    for _ in range(3 * n + 3):
        grad = A.T @ (b - A @ x)
        if free.all() or not (grad[~free] > tol).any():
            break
        free[int(np.argmax(np.where(free, -np.inf, grad)))] = True
        while True:
            s = np.zeros(n)
            s[free] = np.linalg.lstsq(A[:, free], b, rcond=None)[0]
            if (s[free] > 0.0).all():
                x = s
                break
            hit = np.flatnonzero(free & (s <= 0.0))
            ratio = x[hit] / (x[hit] - s[hit])
            x = x + float(ratio.min()) * (s - x)
            x[hit[int(np.argmin(ratio))]] = 0.0      # the variable that reached zero first leaves exactly
            free &= x > 0.0
            x[~free] = 0.0
    return x, float(np.linalg.norm(A @ x - b))
