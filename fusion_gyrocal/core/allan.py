"""The overlapping Allan deviation and its fit with a gyro's standard noise terms (IEEE Std 952).

:func:`allan_deviation` computes the overlapping Allan deviation per axis at octave taus in about two passes;
:func:`edf_table` gives each tau's equivalent degrees of freedom; :func:`fit_allan` fits
``AVAR(tau) = N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3`` (white rate noise, bias instability, bias random walk)
by generalised least squares with the estimator's correlations, each term kept only where it lowers the
chi-square significantly. :mod:`~fusion_gyrocal.core.noise` applies them to a pair's residual.
"""

from __future__ import annotations

import numpy as np

FLICKER = 2.0 * np.log(2.0) / np.pi   # AVAR of bias instability B: (2 ln 2 / pi) B^2 (IEEE Std 952)
SIGNIFICANT_CHI2 = 9.0                # chi-square drop for a term to be kept (3 sigma)
COLOURED_FACTOR = 1.5                 # Allan variance at the shortest tau off the fit by more: coloured
#: correlation of the overlapping Allan variance at neighbouring octave taus, by the dominant noise
#: (white, flicker, random walk), measured on simulated noise
NEIGHBOUR_CORRELATION = np.array([0.5, 0.7, 0.85])


def allan_deviation(y: np.ndarray, rate_hz: float):
    """Overlapping Allan deviation per axis at octave taus, with the phase subsampled by ``b = m // 4`` at
    ``tau = m / rate_hz`` (the overlapping estimator evaluated every ``m / 4`` samples: all taus together
    cost about two passes). Returns taus, adev (T, 3), and per tau the length and averaging factor of the
    subsampled phase (for the degrees of freedom).

    The estimator is the standard one on the phase ``x`` (the integrated rate, IEEE Std 1139):
    ``AVAR(tau) = sum_i (x_{i+2m} - 2 x_{i+m} + x_i)^2 / (2 tau^2 (N - 2m))``. The second difference of the
    phase is the difference of two consecutive sums of ``m`` rates, so it is formed from block sums of
    ``b`` samples (halved level by level) and their moving sums, with no cumulative sum (serial in numpy).
    ``tests/test_noise.py`` checks it against allantools' ``oadev``, whose import (scipy.stats,
    scipy.interpolate) would cost the command line more than the whole calibration of an hour-long log.
    """
    n = y.shape[0]
    ms = 2 ** np.arange(0, int(np.floor(np.log2(max(n / 4.0, 1.0)))) + 1)
    blocks = np.ascontiguousarray(y.T, dtype=np.float64)   # (3, n): numpy reduces (N, 3) along axis 0 slowly
    blocks -= blocks.mean(axis=1)[:, None]
    adev = np.empty((ms.size, 3))
    sub_n, sub_m = np.empty(ms.size), np.empty(ms.size)
    b = 1
    for i, m in enumerate(ms):
        while b < max(1, int(m) // 4):      # sums of 2b samples from those of b
            k = blocks.shape[1] // 2
            blocks = blocks[:, 0:2 * k:2] + blocks[:, 1:2 * k:2]
            b *= 2
        mm = int(m) // b
        s, width = blocks, 1
        while width < mm:                    # moving sums of mm blocks (mm is 1, 2 or 4)
            s = s[:, :-width] + s[:, width:]
            width *= 2
        d = s[:, mm:] - s[:, :-mm]           # (x_{i+2m} - 2 x_{i+m} + x_i) * rate_hz
        adev[i] = np.sqrt(np.einsum("ak,ak->a", d, d) / (2.0 * float(m) ** 2 * d.shape[1]))
        sub_n[i], sub_m[i] = blocks.shape[1] + 1, mm
    return ms / rate_hz, adev, sub_n, sub_m


def edf(alpha: int, m: float, N: float) -> float:
    """Equivalent degrees of freedom of the overlapping Allan variance of ``N`` phase points at averaging
    factor ``m``, for white (alpha 0), flicker (-1) and random-walk (-2) rate noise: the standard closed-form
    approximations (Howe, Allan and Barnes 1981; Riley, NIST SP 1065), within about 15 % of Greenhall's
    algorithm (``tests/test_noise.py`` compares them with allantools' ``edf_greenhall``)."""
    if alpha == 0 or m == 1:   # at one sample the approximations of the others are poor; white dominates there
        return (3.0 * (N - 1.0) / (2.0 * m) - 2.0 * (N - 2.0) / N) * 4.0 * m * m / (4.0 * m * m + 5.0)
    if alpha == -1:
        return 5.0 * N * N / (4.0 * m * (N + 3.0 * m))
    return (N - 2.0) / m * ((N - 1.0) ** 2 - 3.0 * m * (N - 1.0) + 4.0 * m * m) / (N - 3.0) ** 2


def edf_table(sub_n, sub_m):
    """Equivalent degrees of freedom of each tau (3 independent axes) for white, flicker and random-walk
    rate noise (alpha = 0, -1, -2), :func:`edf` on the subsampled phase."""
    out = np.empty((sub_n.size, 3))
    for i, (n, m) in enumerate(zip(sub_n, sub_m)):
        for j, alpha in enumerate((0, -1, -2)):
            out[i, j] = 3.0 * edf(alpha, float(m), float(n))
    return np.maximum(out, 1.0)


def _wls(taus, avar, edf, terms):
    """Non-negative generalised least squares of AVAR on the chosen terms (0: N^2/tau, 1: B^2, 2: K^2 tau/3).

    The variance of each point is ``2 AVAR^2 / edf`` with the degrees of freedom of the dominant noise at
    that tau; neighbouring octaves of the overlapping estimator are correlated (measured for octave taus:
    about 0.5 for white, 0.7 for flicker and 0.85 for random-walk rate noise, decaying geometrically), so
    the points are whitened with that correlation before the fit (without it the uncertainties come out
    about twice too small). Iterated with the weights of the model.
    """
    from scipy.optimize import nnls

    X = np.column_stack([1.0 / taus, np.full_like(taus, FLICKER), taus / 3.0])
    Xs = X[:, terms]
    scale = np.abs(Xs).max(axis=0)
    pred = avar.copy()
    coef = np.zeros(3)
    T = taus.size
    for _ in range(5):
        parts = X * np.where(coef > 0, coef, 0.0)
        dom = np.argmax(parts, axis=1) if coef.any() else np.zeros(T, int)
        e = edf[np.arange(T), dom]
        sd = np.maximum(pred, 1e-300) * np.sqrt(2.0 / e)
        rho = np.minimum(NEIGHBOUR_CORRELATION[dom[:-1]], NEIGHBOUR_CORRELATION[dom[1:]])
        logc = np.concatenate([[0.0], np.cumsum(np.log(rho))])
        C = np.exp(-np.abs(logc[:, None] - logc[None, :]))  # prod of the neighbour correlations between i and j
        L = np.linalg.cholesky(C * np.outer(sd, sd))
        Jw = np.linalg.solve(L, Xs / scale)
        yw = np.linalg.solve(L, avar)
        c = nnls(Jw, yw)[0] / scale
        coef = np.zeros(3)
        coef[terms] = c
        pred = X @ coef
    res = np.linalg.solve(L, avar - pred)
    chi2 = float(res @ res)
    cov = np.full((3, 3), np.nan)
    act = [t for t in terms if coef[t] > 0]
    if act:
        J = np.linalg.solve(L, X[:, act])
        red = max(1.0, chi2 / max(T - len(act), 1))
        cov = np.zeros((3, 3))
        cov[np.ix_(act, act)] = np.linalg.pinv(J.T @ J) * red
    return coef, cov, chi2, pred


def fit_allan(taus, avar, edf, first: int = 0):
    """Forward selection of the terms (white first, then the walk and the flicker term while each lowers
    the chi-square by more than :data:`SIGNIFICANT_CHI2`), from the tau of index ``first`` on. While the shortest
    tau is off the fitted curve by more than a factor :data:`COLOURED_FACTOR` in variance, or the white term does
    not dominate the three shortest (coloured noise: the standard terms do not describe it), it is dropped and
    the fit repeated. Returns coefficients, covariance, the index of the first tau used, the predicted AVAR."""
    lo = min(int(first), max(taus.size - 6, 0))
    while True:
        t, a, e = taus[lo:], avar[lo:], edf[lo:]
        terms = [0]
        best = _wls(t, a, e, terms)
        for extra in (2, 1):
            trial = _wls(t, a, e, terms + [extra])
            red = max(1.0, trial[2] / max(t.size - len(terms) - 1, 1))
            if trial[0][0] > 0 and trial[0][extra] > 0 and best[2] - trial[2] > SIGNIFICANT_CHI2 * red:
                terms, best = terms + [extra], trial
        ratio = a[0] / best[3][0] if best[3][0] > 0 else np.inf
        # a white-noise fit: white dominates its three shortest taus (else the white level is not measured)
        white_first = bool(np.all(best[0][0] / t[:3] >= 0.5 * best[3][:3]))
        if t.size <= 5 or (white_first and 1.0 / COLOURED_FACTOR <= ratio <= COLOURED_FACTOR):
            return best[0], best[1], lo, best[3]
        lo += 1
