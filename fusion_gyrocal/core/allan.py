"""The overlapping Allan deviation and its fit with a gyro's noise terms (IEEE Std 952, IEEE Std 1139).

:func:`allan_deviation` computes the overlapping Allan deviation per axis at octave taus in about two passes;
:func:`edf_table` gives each tau's equivalent degrees of freedom; :func:`fit_allan` fits

``AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + F^2 g(tau / T_c) / tau``

(quantisation or white angle noise ``Q``, slope -1: a quantised angle, or a rate differentiated from a noisy
orientation such as motion capture's; white rate noise ``N``; bias instability ``B``; bias random walk ``K``;
white noise ``F`` low-pass filtered with time constant ``T_c``, first order, whose ``g`` is 1 at long taus and
``tau / (3 T_c)`` at short ones, so the curve flattens below ``T_c``) by non-negative generalised least squares
with the estimator's correlations, each term kept only where it lowers the chi-square significantly.
:mod:`~fusion_gyrocal.core.noise` applies them to a pair's residual and to each gyro's steady stretches.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

FLICKER = 2.0 * np.log(2.0) / np.pi   # AVAR of bias instability B: (2 ln 2 / pi) B^2 (IEEE Std 952)
SIGNIFICANT_CHI2 = 9.0                # chi-square drop for a term to be kept (3 sigma)
COLOURED_FACTOR = 1.5                 # Allan variance at the shortest tau off the fit by more: coloured
#: the terms of :func:`fit_allan`, in the order of its coefficients
TERMS = ("white", "flicker", "walk", "quantisation", "filtered")
WHITE, FLICKER_TERM, WALK, QUANTISATION, FILTERED = range(5)
#: the noise type whose degrees of freedom and neighbour correlation a dominant term has (columns of
#: :func:`edf_table`: white, flicker and random-walk rate noise, white angle noise); the filtered term is
#: white at the taus where it matters
TERM_NOISE = np.array([0, 1, 2, 3, 0])
#: correlation of the overlapping Allan variance at neighbouring octave taus, by the dominant noise
#: (white, flicker, random walk, white angle), measured on simulated noise
NEIGHBOUR_CORRELATION = np.array([0.5, 0.7, 0.85, 0.3])
#: a fitted model passes through the points when it is within this factor of every fitted point's Allan
#: deviation beyond the point's own 2-sigma scatter
FIT_FACTOR = 1.2
MAX_FILTER_SAMPLES = 32               # default longest time constant of the filtered term, in samples
MATERIAL_SHARE = 0.25                 # share of the model a quantisation or filtered term makes at some tau


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
    taus, sums, sub_n, sub_m = second_differences([y], rate_hz)
    return taus, np.sqrt(sums[0] / sums[-1][:, None]), sub_n, sub_m


def second_differences(ys, rate_hz: float, pairs=()):
    """Per octave tau, the sums over the overlapping second differences of the phase of each stream of ``ys``
    (same length, (n, 3)), each axis apart, scaled so that ``sums[i] / sums[-1]`` is the Allan variance of
    stream ``i``; with ``pairs`` ``(i, j)``, also the cross sums ``d_i d_j`` (their Allan covariance), appended
    after the streams' in the order given; ``sums[-1]`` holds ``2 tau^2`` times the count. Returns taus, the
    sums, and the subsampled phase's length and averaging factor (see :func:`allan_deviation`)."""
    n = ys[0].shape[0]
    ms = 2 ** np.arange(0, int(np.floor(np.log2(max(n / 4.0, 1.0)))) + 1)
    blocks = [np.ascontiguousarray(y.T, dtype=np.float64) for y in ys]   # (3, n): fast row reductions
    for b_ in blocks:
        b_ -= b_.mean(axis=1)[:, None]
    out = [np.empty((ms.size, 3)) for _ in range(len(ys) + len(pairs))] + [np.empty(ms.size)]
    sub_n, sub_m = np.empty(ms.size), np.empty(ms.size)
    b = 1
    for i, m in enumerate(ms):
        while b < max(1, int(m) // 4):      # sums of 2b samples from those of b
            k = blocks[0].shape[1] // 2
            blocks = [x[:, 0:2 * k:2] + x[:, 1:2 * k:2] for x in blocks]
            b *= 2
        mm = int(m) // b
        ds = []
        for x in blocks:
            s, width = x, 1
            while width < mm:                    # moving sums of mm blocks (mm is 1, 2 or 4)
                s = s[:, :-width] + s[:, width:]
                width *= 2
            ds.append(s[:, mm:] - s[:, :-mm])    # (x_{i+2m} - 2 x_{i+m} + x_i) * rate_hz
        for j, d in enumerate(ds):
            out[j][i] = np.einsum("ak,ak->a", d, d)
        for j, (p, q) in enumerate(pairs):
            out[len(ys) + j][i] = np.einsum("ak,ak->a", ds[p], ds[q])
        out[-1][i] = 2.0 * float(m) ** 2 * ds[0].shape[1]
        sub_n[i], sub_m[i] = blocks[0].shape[1] + 1, mm
    return ms / rate_hz, out, sub_n, sub_m


def edf(alpha: int, m: float, N: float) -> float:
    """Equivalent degrees of freedom of the overlapping Allan variance of ``N`` phase points at averaging
    factor ``m``, for white (alpha 0), flicker (-1) and random-walk (-2) rate noise and white angle noise
    (+2): the standard closed-form approximations (Howe, Allan and Barnes 1981; Riley, NIST SP 1065), within
    about 15 % of Greenhall's algorithm (``tests/test_noise.py`` compares them with allantools'
    ``edf_greenhall``)."""
    if alpha == 2:
        return (N + 1.0) * (N - 2.0 * m) / (2.0 * (N - m))
    if alpha == 0 or m == 1:   # at one sample the approximations of the others are poor; white dominates there
        return (3.0 * (N - 1.0) / (2.0 * m) - 2.0 * (N - 2.0) / N) * 4.0 * m * m / (4.0 * m * m + 5.0)
    if alpha == -1:
        return 5.0 * N * N / (4.0 * m * (N + 3.0 * m))
    return (N - 2.0) / m * ((N - 1.0) ** 2 - 3.0 * m * (N - 1.0) + 4.0 * m * m) / (N - 3.0) ** 2


def edf_table(sub_n, sub_m, axes: int = 3):
    """Equivalent degrees of freedom of each tau (``axes`` independent axes) for white, flicker and random-walk
    rate noise and white angle noise (alpha = 0, -1, -2, +2), :func:`edf` on the subsampled phase."""
    out = np.empty((sub_n.size, 4))
    for i, (n, m) in enumerate(zip(sub_n, sub_m)):
        for j, alpha in enumerate((0, -1, -2, 2)):
            out[i, j] = axes * edf(alpha, float(m), float(n))
    return np.maximum(out, 1.0)


def filtered_shape(taus, tc: float) -> np.ndarray:
    """``g(tau / T_c) / tau``: the Allan variance of first-order low-pass filtered white noise whose white level
    at long taus is 1 (a Gauss-Markov process of time constant ``tc``:
    ``(1 / tau) (1 - (T_c / 2 tau) (3 - 4 e^{-tau/T_c} + e^{-2 tau/T_c}))``), with its short-tau series where the
    closed form loses its digits."""
    x = np.asarray(taus, float) / tc
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        g = 1.0 - (3.0 - 4.0 * np.exp(-x) + np.exp(-2.0 * x)) / (2.0 * x)
    g = np.where(x < 1e-3, x / 3.0 - x * x / 4.0, g)
    return g / np.asarray(taus, float)


def design(taus, tc: float | None = None) -> np.ndarray:
    """The columns of :data:`TERMS` at ``taus``: ``1/tau``, ``2 ln 2 / pi``, ``tau / 3``, ``3 / tau^2`` and
    :func:`filtered_shape` (zero without a time constant)."""
    taus = np.asarray(taus, float)
    f = filtered_shape(taus, tc) if tc else np.zeros_like(taus)
    return np.column_stack([1.0 / taus, np.full_like(taus, FLICKER), taus / 3.0, 3.0 / taus ** 2, f])


class AllanFit(NamedTuple):
    """A fit of :func:`fit_allan`."""

    coef: np.ndarray        # (5,) N^2, B^2, K^2, Q^2, F^2 (0 for a term not kept)
    cov: np.ndarray         # (5, 5) their covariance (NaN without a term)
    first: int              # index of the first tau fitted
    pred: np.ndarray        # the model's AVAR at every tau
    tc: float               # the filtered term's time constant (0 without it)
    chi2: float
    worst: float            # largest ratio of model to point ADEV (or its inverse) beyond the points' 2-sigma

    @property
    def fits(self) -> bool:
        """The model passes through the fitted points (within :data:`FIT_FACTOR` beyond their scatter)."""
        return bool(self.worst <= FIT_FACTOR)

    def white_row(self, tau: float) -> np.ndarray:
        """The linear map of the coefficients to :meth:`white_equivalent` (for its variance: ``g cov g``)."""
        g = tau * design([tau], self.tc)[0]
        g[[FLICKER_TERM, WALK]] = 0.0
        return g

    def white_equivalent(self, tau: float) -> float:
        """``tau AVAR(tau)`` of the short-term terms (white, quantisation, filtered): the white level (N^2) that
        has their Allan variance at ``tau``, what a calibration over that time scale sees of them."""
        return float(self.white_row(tau) @ self.coef)


def _wls(taus, avar, edf, terms, tc=None):
    """Non-negative generalised least squares of AVAR on the chosen terms (indices of :data:`TERMS`).

    The variance of each point is ``2 AVAR^2 / edf`` with the degrees of freedom of the dominant noise at
    that tau; neighbouring octaves of the overlapping estimator are correlated (measured for octave taus:
    about 0.5 for white, 0.7 for flicker, 0.85 for random-walk rate noise and 0.3 for white angle noise,
    decaying geometrically), so the points are whitened with that correlation before the fit (without it the
    uncertainties come out about twice too small). Iterated with the weights of the model.
    """
    from scipy.optimize import nnls

    X = design(taus, tc)
    Xs = X[:, terms]
    scale = np.abs(Xs).max(axis=0)
    pred = avar.copy()
    coef = np.zeros(len(TERMS))
    T = taus.size
    for _ in range(5):
        parts = X * np.where(coef > 0, coef, 0.0)
        dom = TERM_NOISE[np.argmax(parts, axis=1)] if coef.any() else np.zeros(T, int)
        e = edf[np.arange(T), dom]
        sd = np.maximum(pred, 1e-300) * np.sqrt(2.0 / e)
        rho = np.minimum(NEIGHBOUR_CORRELATION[dom[:-1]], NEIGHBOUR_CORRELATION[dom[1:]])
        logc = np.concatenate([[0.0], np.cumsum(np.log(rho))])
        C = np.exp(-np.abs(logc[:, None] - logc[None, :]))  # prod of the neighbour correlations between i and j
        L = np.linalg.cholesky(C * np.outer(sd, sd))
        Jw = np.linalg.solve(L, Xs / scale)
        yw = np.linalg.solve(L, avar)
        c = nnls(Jw, yw)[0] / scale
        coef = np.zeros(len(TERMS))
        coef[terms] = c
        pred = X @ coef
    res = np.linalg.solve(L, avar - pred)
    chi2 = float(res @ res)
    cov = np.full((len(TERMS),) * 2, np.nan)
    act = [t for t in terms if coef[t] > 0]
    if act:
        J = np.linalg.solve(L, X[:, act])
        red = max(1.0, chi2 / max(T - len(act), 1))
        cov = np.zeros((len(TERMS),) * 2)
        cov[np.ix_(act, act)] = np.linalg.pinv(J.T @ J) * red
    # how far the model is from the points, beyond each point's own 2-sigma scatter (in deviation)
    ratio = np.abs(0.5 * np.log(np.maximum(pred, 1e-300) / np.maximum(avar, 1e-300)))
    worst = float(np.exp(np.max(np.maximum(ratio - 2.0 / np.sqrt(2.0 * e), 0.0))))
    return coef, cov, chi2, pred, worst


def _candidates(taus, terms, max_tc):
    """The terms not yet in ``terms`` with their time constants: the filtered term once per octave tau up to an
    eighth of the longest (a time constant the curve shows on both sides) and ``max_tc``."""
    out = [(t, None) for t in (QUANTISATION, WALK, FLICKER_TERM) if t not in terms]
    if FILTERED not in terms:
        out += [(FILTERED, float(tc)) for tc in taus[taus <= min(taus[-1] / 8.0, max_tc)]]
    return out


def _select(t, a, e, max_tc):
    """Forward selection from white noise: the candidate (:func:`_candidates`) that lowers the chi-square most (with
    the white term still positive) is added while it does so by more than :data:`SIGNIFICANT_CHI2` (times the reduced chi-square; plus
    ``2 ln k`` for the filtered term tried at ``k`` time constants, the look-elsewhere of picking the best) and,
    for the quantisation and filtered terms, while it makes at least :data:`MATERIAL_SHARE` of the model at some
    fitted tau."""
    terms, tc = [WHITE], None
    best = _wls(t, a, e, terms)
    while True:
        trials = []
        for term, c in _candidates(t, terms, max_tc):
            fit = _wls(t, a, e, terms + [term], c if term == FILTERED else tc)
            trials.append((best[2] - fit[2], term, c, fit))
        if not trials:
            break
        n_tc = sum(1 for tr in trials if tr[1] == FILTERED)
        look = 2.0 * np.log(max(n_tc, 1))
        trials.sort(key=lambda tr: tr[0] - (look if tr[1] == FILTERED else 0.0), reverse=True)
        for drop, term, c, fit in trials:
            red = max(1.0, fit[2] / max(t.size - len(terms) - 1, 1))
            need = SIGNIFICANT_CHI2 * red + (look if term == FILTERED else 0.0)
            if not (fit[0][term] > 0 and fit[0][WHITE] > 0 and drop > need):   # white noise stays in the model
                continue
            if term in (QUANTISATION, FILTERED):   # a noise kind, not a wrinkle: a material share somewhere
                share = np.max(design(t, c if term == FILTERED else tc)[:, term] * fit[0][term]
                               / np.maximum(fit[3], 1e-300))
                if share < MATERIAL_SHARE:
                    continue
            terms, best = terms + [term], fit
            if term == FILTERED:
                tc = c
            break
        else:
            break
    return best, (tc or 0.0)


def fit_allan(taus, avar, edf, first: int = 0, max_tc: float | None = None) -> AllanFit:
    """Fit :data:`TERMS` to the Allan variance ``avar`` from the tau of index ``first`` on (:func:`_select`; the
    filtered term's time constant at most ``max_tc``, a filter's, not a slow disturbance's: default
    :data:`MAX_FILTER_SAMPLES` times the shortest tau). While the model is
    off the shortest tau by more than a factor :data:`COLOURED_FACTOR` in variance, or off one of the three
    shortest by more than :data:`FIT_FACTOR` beyond their scatter (noise none of the terms describes there), or
    has no short-term term (white, quantisation, filtered) at all, that tau is dropped and the fit repeated, down to
    six taus. Returns an :class:`AllanFit`; its ``worst`` says how
    well it passes through all the fitted points."""
    lo = min(int(first), max(taus.size - 6, 0))
    max_tc = MAX_FILTER_SAMPLES * float(taus[0]) if max_tc is None else max_tc
    while True:
        t, a, e = taus[lo:], avar[lo:], edf[lo:]
        (coef, cov, chi2, pred, worst), tc = _select(t, a, e, max_tc)
        ratio = a[0] / pred[0] if pred[0] > 0 else np.inf
        dof = edf[lo:lo + 3, 0]
        head = np.abs(0.5 * np.log(np.maximum(pred[:3], 1e-300) / np.maximum(a[:3], 1e-300))) - 2.0 / np.sqrt(2 * dof)
        good = (1.0 / COLOURED_FACTOR <= ratio <= COLOURED_FACTOR and float(np.exp(head.max())) <= FIT_FACTOR
                and coef[[WHITE, QUANTISATION, FILTERED]].sum() > 0)   # a level of short-term noise, not drift alone
        if good or t.size <= 6:
            if coef[[WHITE, QUANTISATION, FILTERED]].sum() <= 0:   # drift alone fits: white noise is what is left
                (coef, cov, chi2, pred, worst), tc = _wls(t, a, e, [WHITE]), 0.0
            return AllanFit(coef, cov, lo, design(taus, tc) @ coef, tc if coef[FILTERED] > 0 else 0.0, chi2, worst)
        lo += 1
