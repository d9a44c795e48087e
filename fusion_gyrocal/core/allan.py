"""The overlapping Allan deviation and its fit with a gyro's noise terms (IEEE Std 952, IEEE Std 1139).

:func:`allan_deviation` computes the overlapping Allan deviation per axis at octave taus in about two passes;
:func:`allan_points` adds each point's scatter measured from batch means of the log (a residual whose level follows
the motion scatters far more than the stationary estimator's degrees of freedom say); :func:`edf_table` gives each
tau's equivalent degrees of freedom; :func:`fit_allan` fits

``AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + F^2 g(tau / T_c) / tau
+ S^2 k(tau) + H^2 h(tau / T_b)``

(quantisation or white angle noise ``Q``, slope -1: a quantised angle, or a rate differentiated from a noisy
orientation such as motion capture's; white rate noise ``N``; bias instability ``B``; bias random walk ``K``;
white noise ``F`` low-pass filtered with time constant ``T_c``, first order, whose ``g`` is 1 at long taus and
``tau / (3 T_c)`` at short ones, so the curve flattens below ``T_c``; with ``extra``, a tone ``S^2``: narrow-band
noise such as a MEMS drive frequency aliased to the output rate, :func:`tone_shape`, and a bounded angle error
``H^2``: a rate differentiated from a Gauss-Markov angle, white below ``T_b`` and slope -1 above,
:func:`bounded_shape`) by non-negative generalised least squares with the estimator's correlations, each term kept
only where it lowers the chi-square significantly. :mod:`~fusion_gyrocal.core.noise` applies them to a pair's
residual and to each gyro's steady stretches, :mod:`~fusion_gyrocal.core.static_noise` to a gyro at rest.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import numpy as np

FLICKER = 2.0 * np.log(2.0) / np.pi   # AVAR of bias instability B: (2 ln 2 / pi) B^2 (IEEE Std 952)
SIGNIFICANT_CHI2 = 9.0                # chi-square drop for a term to be kept (3 sigma)
MAX_RED = 1.0   # the reduced chi-square a term's significance is scaled by, at most (see _best_addition)
COLOURED_FACTOR = 1.5                 # Allan variance at the shortest tau off the fit by more: coloured
#: the terms of :func:`fit_allan`, in the order of its coefficients
TERMS = ("white", "flicker", "walk", "quantisation", "filtered", "tone", "bounded")
WHITE, FLICKER_TERM, WALK, QUANTISATION, FILTERED, TONE, BOUNDED = range(7)
#: the short-term terms: what a calibration over a window, and each sample, sees as noise
SHORT_TERMS = (WHITE, QUANTISATION, FILTERED, TONE, BOUNDED)
#: the noise type whose degrees of freedom and neighbour correlation a dominant term has (columns of
#: :func:`edf_table`: white, flicker and random-walk rate noise, white angle noise); the filtered and tone
#: terms are white at the taus where they matter
TERM_NOISE = np.array([0, 1, 2, 3, 0, 0, 0])
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


class AllanPoints(NamedTuple):
    """The points of :func:`allan_points`."""

    taus: np.ndarray        # (T,) octave taus (s)
    adev: np.ndarray        # (T, 3) overlapping Allan deviation per axis
    sub_n: np.ndarray       # (T,) length of the subsampled phase (for :func:`edf_table`)
    sub_m: np.ndarray       # (T,) its averaging factor
    scatter: np.ndarray     # (T, 4) relative variance of each axis's Allan variance and of their mean, measured


def allan_points(y: np.ndarray, rate_hz: float, stretches=None) -> AllanPoints:
    """:func:`allan_deviation` with each point's scatter measured from the data: the relative variance of the
    Allan variance at each tau from batch means (the log cut into :data:`BATCHES` consecutive batches, each at
    least :data:`BATCH_TAUS` times ``2 tau`` long: the spread of the batches' Allan variances over their number),
    per axis and for the mean of the axes.

    The stationary estimator's variance (``2 AVAR^2 / edf``, :func:`edf_table`) holds for Gaussian noise of one
    level; a residual whose level follows the motion (bursts, rests) scatters far more (on hand-held logs 20 to
    several hundred times). Where the batches show more than the stationary variance significantly (by more than
    three of their own standard errors), that is the scatter; else NaN (the stationary one holds). At the taus
    too long for the batches, the excess over the stationary variance measured at the two longest taus that fit
    them (where both show one) is carried on (the level's fluctuation, about the same at every tau).

    ``stretches``: the lengths of consecutive stretches of ``y`` taken apart in time (a long log's stretches,
    joined): no second difference spans two of them (a drifting bias jumps between them), the sums of every
    stretch are pooled, up to the taus of the shortest stretch, and the stretches are the batches.
    """
    if stretches is not None and len(stretches) > 2:
        return _stretch_points(y, rate_hz, [int(n) for n in stretches])
    taus, sums, sub_n, sub_m, batches = second_differences([y], rate_hz, batches=True)
    adev = np.sqrt(sums[0] / sums[-1][:, None])
    stationary = np.column_stack([2.0 / edf_table(sub_n, sub_m, axes=1)[:, 0]] * 3
                                 + [2.0 / edf_table(sub_n, sub_m, axes=3)[:, 0]])
    return AllanPoints(taus, adev, sub_n, sub_m, _batch_scatter(stationary, batches))


def _batch_scatter(stationary: np.ndarray, batches: list) -> np.ndarray:
    """The measured relative variance of each point (T, 4) from its batches' Allan variances (per tau a (3, K)
    array, K the same at every tau, or None where no batches fit: the excess of the two longest taus before it that
    fit carried on); NaN where the batches show no more than the ``stationary`` relative variance significantly."""
    scatter = np.full((stationary.shape[0], 4), np.nan)
    have = [i for i, b in enumerate(batches) if b is not None]
    excess = np.full((0, 4), np.nan)
    if have:   # every tau with batches at once (the same reductions, along each row)
        b = np.stack([batches[i] for i in have])
        v = np.concatenate([b, b.mean(axis=1)[:, None]], axis=1)          # (taus, 4, K)
        K = v.shape[2]
        rel = v.var(axis=2, ddof=1) / K / np.maximum(v.mean(axis=2), 1e-300) ** 2
        sig = rel > stationary[have] * (1.0 + 3.0 * np.sqrt(2.0 / (K - 1)))
        scatter[have] = np.where(sig, rel, np.nan)
        excess = np.where(sig, rel - stationary[have], np.nan)
    for i in (i for i, b in enumerate(batches) if b is None):
        prior = excess[:np.searchsorted(have, i)]        # the excess of the taus before it that fit
        if len(prior) >= 2:
            carry = np.where(np.isfinite(prior[-2]), prior[-1], np.nan)
            scatter[i] = np.where(np.isfinite(carry), stationary[i] + carry, np.nan)
    return scatter


#: samples of the stretches :func:`_stretch_points` differences in one pass: their copies (a few hundred KiB) reuse
#: memory just freed, where all of a long log's stretches at once (several MiB) were fresh pages from the OS on every
#: call (each stretch's sums are its own: the same numbers either way)
_GROUP_SAMPLES = 16384


def _stretch_points(y: np.ndarray, rate_hz: float, lengths: list) -> AllanPoints:
    """:func:`allan_points` of consecutive stretches of ``lengths`` samples, each on its own (``stretches=``)."""
    if min(lengths) == max(lengths) >= 8:     # stretches of one length (every sample kept): a few in each pass
        n = lengths[0]
        x = y[:n * len(lengths)].reshape(len(lengths), n, 3)
        per = max(1, _GROUP_SAMPLES // n)
        parts = []
        for k0 in range(0, len(lengths), per):
            taus, sums, sub_n, sub_m = second_differences([x[k0:k0 + per]], rate_hz)
            parts += [(taus, (sums[0][:, k], sums[-1]), sub_n, sub_m) for k in range(sums[0].shape[1])]
    else:
        ends = np.cumsum(lengths)
        parts = [second_differences([y[b - n:b]], rate_hz) for n, b in zip(lengths, ends) if n >= 8]
    T = min(q[0].size for q in parts)
    taus = parts[0][0][:T]
    sums = sum(q[1][0][:T] for q in parts)
    counts = sum(q[1][-1][:T] for q in parts)
    sub_n, sub_m = sum(q[2][:T] for q in parts), parts[0][3][:T]   # the stretches' phase points, pooled
    tables: dict = {}     # stretches of one length share their phase points: each table computed once

    def white_edf(q, axes):
        key = (q[2][:T].tobytes(), q[3][:T].tobytes(), axes)
        if key not in tables:
            tables[key] = edf_table(q[2][:T], q[3][:T], axes=axes)[:, 0]
        return tables[key]

    edf_1 = np.sum([white_edf(q, 1) for q in parts], axis=0)
    edf_3 = np.sum([white_edf(q, 3) for q in parts], axis=0)
    stationary = np.column_stack([2.0 / edf_1] * 3 + [2.0 / edf_3])
    each = np.stack([q[1][0][:T] / q[1][-1][:T, None] for q in parts], axis=2)   # (T, 3, K): each stretch's AVAR
    return AllanPoints(taus, np.sqrt(sums / counts[:, None]), sub_n, sub_m,
                       _batch_scatter(stationary, [each[i] for i in range(T)]))


BATCHES = 32        # allan_points cuts the log into this many batches (longer than a level's fluctuations)
BATCH_TAUS = 16     # a batch spans at least this many times 2 tau (else that tau carries the excess on)


def second_differences(ys, rate_hz: float, pairs=(), batches: bool = False):
    """Per octave tau, the sums over the overlapping second differences of the phase of each stream of ``ys``
    (same length, (n, 3), or (K, n, 3): K stretches of n samples, each on its own), each axis apart, scaled so
    that ``sums[i] / sums[-1]`` is the Allan variance of stream ``i``; with ``pairs`` ``(i, j)``, also the cross
    sums ``d_i d_j`` (their Allan covariance), appended after the streams' in the order given; ``sums[-1]`` holds
    ``2 tau^2`` times the count (of one stretch). Returns taus, the sums ((T, 3) per stream, (T, K, 3) for
    stretches), and the subsampled phase's length and averaging factor (see :func:`allan_deviation`); with
    ``batches`` (streams of (n, 3)), also per tau the first stream's mean squared second difference per axis in
    consecutive batches of :data:`BATCH_TAUS` times ``2 tau`` ((3, K) arrays, None where not even one batch fits)."""
    n = ys[0].shape[-2]
    ms = 2 ** np.arange(0, int(np.floor(np.log2(max(n / 4.0, 1.0)))) + 1)
    blocks = [np.ascontiguousarray(np.swapaxes(y, -1, -2), dtype=np.float64) for y in ys]   # (..., 3, n): fast
    for b_ in blocks:                                                                        # row reductions
        b_ -= b_.mean(axis=-1)[..., None]
    out = [np.empty((ms.size,) + ys[0].shape[:-2] + (3,)) for _ in range(len(ys) + len(pairs))] + [np.empty(ms.size)]
    sub_n, sub_m = np.empty(ms.size), np.empty(ms.size)
    batch = []
    b, length = 1, n     # samples per block, blocks in the phase
    # each stream's moving sums of the last tau, and two buffers for all taus (no fresh arrays): a tau's sums go into
    # the one its predecessor's differences are in, its differences into the other
    sums = list(blocks)
    work = [[np.empty_like(x), np.empty_like(x)] for x in blocks]
    for i, m in enumerate(ms):
        mm = min(int(m), 4)      # moving sums of mm blocks of b samples (mm is 1, 2 or 4)
        if m > 4:
            b, length = 2 * b, length // 2
        ds = []
        for j, x in enumerate(blocks):
            work[j].reverse()
            into, diff = work[j]
            s = sums[j]
            if m == 2:
                s = np.add(x[..., :-1], x[..., 1:], out=into[..., :x.shape[-1] - 1])
            elif m >= 4:
                # sums of 2 blocks: at m = 4 those of m = 2; beyond, every other sum of 4 blocks of the last tau
                # (the same additions as halving the blocks and summing them in pairs)
                two = s if m == 4 else s[..., ::2]
                s = np.add(two[..., :-2], two[..., 2:], out=into[..., :two.shape[-1] - 2])
            sums[j] = s
            # (x_{i+2m} - 2 x_{i+m} + x_i) * rate_hz
            ds.append(np.subtract(s[..., mm:], s[..., :-mm], out=diff[..., :s.shape[-1] - mm]))
        for j, d in enumerate(ds):
            out[j][i] = np.einsum("...k,...k->...", d, d)
        if batches:   # BATCHES consecutive batches (elements of d are b samples apart), each >= BATCH_TAUS 2 tau
            w = ds[0].shape[1] // BATCHES
            batch.append((ds[0][:, :BATCHES * w] ** 2).reshape(3, BATCHES, w).mean(axis=2)
                         if w * b >= BATCH_TAUS * 2.0 * float(m) else None)
        for j, (p, q) in enumerate(pairs):
            out[len(ys) + j][i] = np.einsum("...k,...k->...", ds[p], ds[q])
        out[-1][i] = 2.0 * float(m) ** 2 * ds[0].shape[-1]
        sub_n[i], sub_m[i] = length + 1, mm
    if batches:
        return ms / rate_hz, out, sub_n, sub_m, batch
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


def tone_shape(taus, tau0: float, freq_hz: float, rho: float) -> np.ndarray:
    """The Allan variance at ``taus`` (multiples ``m`` of the sample period ``tau0``) of narrow-band noise of unit
    variance per sample centred on ``freq_hz``: a sampled process whose autocovariance at lag ``k`` samples is
    ``rho^k cos(2 pi freq_hz tau0 k)`` (a resonance, or a tone whose frequency wanders, such as a MEMS gyro's
    drive frequency aliased to the output rate; ``1 - rho`` sets the bandwidth, about ``(1 - rho) / (pi tau0)``
    Hz). Exact for the sampled process: with ``z = rho e^{i 2 pi freq_hz tau0}`` the phase's structure function
    is ``V(m) = Re[m + 2 sum_{k<m} (m - k) z^k]`` (a geometric sum) and ``AVAR(m tau0) = (4 V(m) - V(2m)) /
    (2 m^2)``. At ``m = 1`` it is ``1 - rho cos(2 pi freq_hz tau0)``; at long taus it falls as ``1 / tau^2``
    (slope -1 in deviation, as a quantised angle)."""
    m = np.maximum(np.rint(np.asarray(taus, float) / tau0), 1.0)
    z = rho * np.exp(2j * np.pi * freq_hz * tau0)

    def V(k):
        return np.real(k + 2.0 * ((k - (k + 1.0) * z + z ** (k + 1.0)) / (1.0 - z) ** 2 - k))

    return (4.0 * V(m) - V(2.0 * m)) / (2.0 * m * m)


def bounded_shape(taus, tb: float) -> np.ndarray:
    """The Allan variance of a rate differentiated from an angle error that is a first-order Gauss-Markov process
    of time constant ``tb`` (white noise high-pass filtered: the angle stays bounded, as a motion-capture
    orientation's smoothed error or a motion-band residue), scaled to white level 1 at short taus:
    ``tb (3 - 4 e^{-tau/tb} + e^{-2 tau/tb}) / (2 tau^2)`` (from the phase's autocovariance; exact for the
    sampled process), ``1 / tau`` well below ``tb`` and ``3 tb / (2 tau^2)`` (quantisation, slope -1) above."""
    taus = np.asarray(taus, float)
    x = taus / tb
    with np.errstate(over="ignore", invalid="ignore"):
        h = tb * (3.0 - 4.0 * np.exp(-x) + np.exp(-2.0 * x)) / (2.0 * taus * taus)
    return np.where(x < 1e-4, (1.0 - 1.5 * x) / taus, h)


def design(taus, tc: float | None = None, tone: tuple | None = None, tau0: float | None = None,
           tb: float | None = None) -> np.ndarray:
    """The columns of :data:`TERMS` at ``taus``: ``1/tau``, ``2 ln 2 / pi``, ``tau / 3``, ``3 / tau^2``,
    :func:`filtered_shape` (zero without a time constant), :func:`tone_shape` (zero without ``tone``, its
    ``(freq_hz, rho)``, and the sample period ``tau0``) and :func:`bounded_shape` (zero without ``tb``)."""
    return _designs(taus, [(tc, tone, tb)], tau0)[0]


def _designs(taus, params, tau0: float | None = None) -> np.ndarray:
    """:func:`design` at each of ``params`` (``(tc, tone, tb)``), stacked (K, T, terms): the fixed columns and each
    scanned term's column at each of its parameters computed once."""
    taus = np.asarray(taus, float)
    fixed = [1.0 / taus, np.full_like(taus, FLICKER), taus / 3.0, 3.0 / taus ** 2]
    X = np.zeros((len(params), taus.size, len(TERMS)))
    X[:, :, :len(fixed)] = np.column_stack(fixed)
    shapes: dict = {}     # each scanned term's column at each of its parameters

    def column(key, shape):
        if key not in shapes:
            shapes[key] = shape()
        return shapes[key]

    for k, (tc, tone, tb) in enumerate(params):
        if tc:
            X[k, :, FILTERED] = column((FILTERED, tc), partial(filtered_shape, taus, tc))
        if tone and tone[1] > 0 and tau0:
            X[k, :, TONE] = column((TONE, *tone), partial(tone_shape, taus, tau0, *tone))
        if tb:
            X[k, :, BOUNDED] = column((BOUNDED, tb), partial(bounded_shape, taus, tb))
    return X


class AllanFit(NamedTuple):
    """A fit of :func:`fit_allan`."""

    coef: np.ndarray        # (7,) N^2, B^2, K^2, Q^2, F^2, tone variance per sample, H^2 (0 for a term not kept)
    cov: np.ndarray         # (7, 7) their covariance (NaN without a term)
    first: int              # index of the first tau fitted
    pred: np.ndarray        # the model's AVAR at every tau
    tc: float               # the filtered term's time constant (0 without it)
    chi2: float
    worst: float            # largest ratio of model to point ADEV (or its inverse) beyond the points' 2-sigma
    tone: tuple = (0.0, 0.0)   # the tone term's centre frequency (Hz) and pole radius rho ((0, 0) without it)
    tau0: float = 0.0       # the sample period the taus are multiples of
    tb: float = 0.0         # the bounded term's time constant (0 without it)

    @property
    def fits(self) -> bool:
        """The model passes through the fitted points (within :data:`FIT_FACTOR` beyond their scatter)."""
        return bool(self.worst <= FIT_FACTOR)

    def white_row(self, tau: float) -> np.ndarray:
        """The linear map of the coefficients to :meth:`white_equivalent` (for its variance: ``g cov g``)."""
        g = tau * design([tau], self.tc, self.tone, self.tau0, self.tb)[0]
        g[[FLICKER_TERM, WALK]] = 0.0
        g[TONE] = self.tau0   # the tone counts as white noise of its variance per sample (its frequency may wander
        return g              # into the motion's band: conservative)

    def white_equivalent(self, tau: float) -> float:
        """``tau AVAR(tau)`` of the short-term terms (white, quantisation, filtered, bounded): the white level
        (N^2) that has their Allan variance at ``tau``, what a calibration over that time scale sees of them; the
        tone counts with its variance per sample times ``tau0`` (as white noise of that spread)."""
        return float(self.white_row(tau) @ self.coef)

    def sample_row(self) -> np.ndarray:
        """The linear map of the coefficients to :meth:`sample_variance`: each short-term term's variance per
        sample, ``N^2 / tau0``, ``2 Q^2 / tau0^2`` (the difference of two white angle errors),
        ``F^2 / (2 T_c)`` (a Gauss-Markov process's variance), the tone's own variance and the bounded term's
        ``H^2 T_b (1 - e^{-tau0/T_b}) / tau0^2``."""
        tau0 = self.tau0
        g = np.zeros(len(TERMS))
        g[WHITE], g[QUANTISATION], g[TONE] = 1.0 / tau0, 2.0 / tau0 ** 2, 1.0
        g[FILTERED] = 1.0 / (2.0 * self.tc) if self.tc > 0 else 0.0
        g[BOUNDED] = self.tb * -np.expm1(-tau0 / self.tb) / tau0 ** 2 if self.tb > 0 else 0.0
        return g

    def sample_variance(self) -> float:
        """The variance per sample of the short-term noise the model describes: what the spread of a stretch of
        samples about its mean shows (for white noise alone ``N^2 / tau0``, its Allan variance at one sample)."""
        return float(self.sample_row() @ self.coef)


def _wls(taus, avar, edf, terms, tc=None, tone=None, tau0=None, scatter=None, start=None, iterations: int = 5,
         tb=None):
    """Non-negative generalised least squares of AVAR on the chosen terms (indices of :data:`TERMS`).

    The variance of each point is ``2 AVAR^2 / edf`` with the degrees of freedom of the dominant noise at
    that tau, or ``AVAR^2 scatter`` where the point's relative variance measured from the data (``scatter``,
    :func:`allan_points`) is larger; neighbouring octaves of the overlapping estimator are correlated (measured
    for octave taus: about 0.5 for white, 0.7 for flicker, 0.85 for random-walk rate noise and 0.3 for white
    angle noise, decaying geometrically), so the points are whitened with that correlation before the fit
    (without it the uncertainties come out about twice too small). Iterated ``iterations`` times with the
    weights of the model, from those of ``start`` (a model's AVAR; default the points themselves).
    """
    return _wls_many(taus, avar, edf, [(terms, tc, tone, tb)], tau0, scatter, start, iterations)[0]


def _wls_many(taus, avar, edf, jobs, tau0=None, scatter=None, start=None, iterations: int = 5,
              covariance: bool = True) -> list:
    """:func:`_wls` of each of ``jobs`` (``(terms, tc, tone, tb)``): the fits with the same number of terms run in
    lockstep, each step's small matrix operations (weights, Cholesky factors, whitening) one stacked call for all of
    them, one factor for all while no term is kept (the first pass: every job weighs its points as ``start``); only
    the non-negative least squares and the covariance of the kept terms are per fit. A fit whose coefficients and
    model repeat those of its pass before is at its fixed point (every further pass gives the same numbers) and
    leaves the lockstep. Each returns ``(coef, cov, chi2, pred, worst)``, in the order of ``jobs``; without
    ``covariance``, ``cov`` is a function that computes it (the candidates of a selection, where only the one kept
    needs it)."""
    from scipy.optimize import nnls

    if not jobs:
        return []
    widths = sorted({len(terms) for terms, *_ in jobs})
    if len(widths) > 1:     # each width in lockstep
        out = [None] * len(jobs)
        for w in widths:
            idx = [i for i, (terms, *_) in enumerate(jobs) if len(terms) == w]
            for i, fit in zip(idx, _wls_many(taus, avar, edf, [jobs[i] for i in idx], tau0, scatter, start,
                                             iterations, covariance)):
                out[i] = fit
        return out
    K, T = len(jobs), taus.size
    X = _designs(taus, [(tc, tone, tb) for _, tc, tone, tb in jobs], tau0)                 # (K, T, terms)
    cols = np.array([list(terms) for terms, *_ in jobs])                                     # (K, w)
    Xs = np.take_along_axis(X, cols[:, None, :], axis=2)
    scale = np.abs(Xs).max(axis=1)                                                           # (K, w)
    Xy = np.concatenate([Xs / scale[:, None, :], np.broadcast_to(avar[None, :, None], (K, T, 1))], axis=2)
    pred = np.repeat((avar if start is None else np.asarray(start, float))[None], K, axis=0)
    coef = np.zeros((K, len(TERMS)))
    extra = np.zeros(T) if scatter is None else np.nan_to_num(np.asarray(scatter, float), nan=0.0)
    rows = np.arange(T)
    L, C, rel = np.empty((K, T, T)), np.empty((K, T, T)), np.empty((K, T))    # each fit's of its last pass
    live = np.arange(K)     # the fits not yet at their fixed point
    for _ in range(iterations):
        X_, c, p = X[live], coef[live], pred[live]
        parts = X_ * np.where(c > 0, c, 0.0)[:, None, :]
        dom = np.where(c.any(axis=1)[:, None], TERM_NOISE[np.argmax(parts, axis=2)], 0)
        rel[live] = r_ = np.maximum(2.0 / edf[rows[None, :], dom], extra)
        sd = np.maximum(p, 1e-300) * np.sqrt(r_)
        rho = np.minimum(NEIGHBOUR_CORRELATION[dom[:, :-1]], NEIGHBOUR_CORRELATION[dom[:, 1:]])
        logc = np.concatenate([np.zeros((live.size, 1)), np.cumsum(np.log(rho), axis=1)], axis=1)
        C[live] = C_ = np.exp(-np.abs(logc[:, :, None] - logc[:, None, :]))
        if not c.any():    # no term kept yet: every job weighs its points as the start, one factor for all
            L[live] = L_ = np.broadcast_to(np.linalg.cholesky(C_[0] * np.outer(sd[0], sd[0])), (live.size, T, T))
        else:
            L[live] = L_ = np.linalg.cholesky(C_ * (sd[:, :, None] * sd[:, None, :]))
        Jy = np.linalg.solve(L_, Xy[live])
        c_new = np.zeros((live.size, len(TERMS)))
        for i, k in enumerate(live):
            c_new[i, cols[k]] = nnls(Jy[i, :, :-1], Jy[i, :, -1])[0] / scale[k]
        p_new = np.matmul(X_, c_new[:, :, None])[:, :, 0]
        coef[live], pred[live] = c_new, p_new
        live = live[~((c_new == c).all(axis=1) & (p_new == p).all(axis=1))]
        if not live.size:
            break
    if scatter is None:
        res = np.linalg.solve(L, (avar[None] - pred)[:, :, None])[:, :, 0]
    else:
        root = np.sqrt(rel)
        Lr = np.linalg.cholesky(C * (root[:, :, None] * root[:, None, :]))
        logs = np.log(np.maximum(avar, 1e-300)[None] / np.maximum(pred, 1e-300))
        res = np.linalg.solve(Lr, logs[:, :, None])[:, :, 0]
    chi2 = np.einsum("kt,kt->k", res, res)
    ratio = np.abs(0.5 * np.log(np.maximum(pred, 1e-300) / np.maximum(avar, 1e-300)[None]))
    worst = np.exp(np.max(np.maximum(ratio - np.sqrt(rel), 0.0), axis=1))
    out = []
    for k, (terms, *_) in enumerate(jobs):
        cov = partial(_covariance, L[k], X[k], terms, coef[k], float(chi2[k]))
        out.append((coef[k], cov() if covariance else cov, float(chi2[k]), pred[k], float(worst[k])))
    return out


def _covariance(L, X, terms, coef, chi2: float) -> np.ndarray:
    """The covariance of a fit's kept terms (:func:`_wls_many`): the inverse of the whitened design's normal matrix
    (``L`` the whitening factor), scaled by the reduced chi-square where above 1; NaN without a kept term."""
    act = [t for t in terms if coef[t] > 0]
    if not act:
        return np.full((len(TERMS),) * 2, np.nan)
    J = np.linalg.solve(L, X[:, act])
    red = max(1.0, chi2 / max(X.shape[0] - len(act), 1))
    cov = np.zeros((len(TERMS),) * 2)
    cov[np.ix_(act, act)] = np.linalg.pinv(J.T @ J) * red
    return cov


#: the tone term's candidate centre frequencies (fractions of the sample rate) and pole radii
TONE_FREQUENCIES = np.arange(0.1, 0.5001, 0.02)   # above the motion band (its residue is no tone)
TONE_RADII = (0.75, 0.9, 0.97)


def _candidates(taus, terms, max_tc, tau0):
    """The terms not yet in ``terms`` with their parameters: the filtered term once per octave tau up to an eighth
    of the longest (a time constant the curve shows on both sides) and ``max_tc``; the tone term at
    :data:`TONE_FREQUENCIES` and :data:`TONE_RADII` where the fit starts at one sample (the tone shows in the
    shortest taus)."""
    out = [(t, None) for t in (QUANTISATION, WALK, FLICKER_TERM) if t not in terms]
    if FILTERED not in terms:
        out += [(FILTERED, float(tc)) for tc in taus[taus <= min(taus[-1] / 8.0, max_tc)]]
    if BOUNDED not in terms:
        out += [(BOUNDED, float(tb)) for tb in taus[(taus > taus[0]) & (taus <= taus[-1] / 8.0)]]
    if TONE not in terms and tau0 and abs(taus[0] - tau0) < 1e-9 * tau0:
        out += [(TONE, (float(f / tau0), r)) for f in TONE_FREQUENCIES for r in TONE_RADII]
    return out


SCANNED = (FILTERED, TONE, BOUNDED)
LAST = (TONE, BOUNDED)   # terms tried only where none of the others is kept (:func:`_select`)
SCREENED = 12   # a scan of more candidates is screened (:func:`_best_addition`) down to this many   # terms tried at several parameters (their look-elsewhere counts them)


def _best_addition(t, a, e, tau0, scatter, terms, par, best, cands):
    """The candidate of ``cands`` (each ``(added terms, parameter of a scanned one)``) :func:`_select` adds to
    ``terms``, as ``(terms, fit, parameters)``, or None."""
    params = []
    for add, c in cands:
        p = dict(par)
        for term in add:
            if term in SCANNED:
                p[term] = c
        params.append(p)
    jobs = [(terms + list(add), p[FILTERED], p[TONE], p[BOUNDED]) for (add, _), p in zip(cands, params)]
    keep = range(len(cands))
    if len(cands) > SCREENED:   # many parameters of a scanned term: one pass each with the current model's weights,
        drops = best[2] - np.array([f[2] for f in _wls_many(t, a, e, jobs, tau0, scatter, best[3], 1, False)])
        keep = np.argsort(-drops, kind="stable")[:SCREENED]     # then the full fit of the most promising
    fits = _wls_many(t, a, e, [jobs[k] for k in keep], tau0, scatter, covariance=False)
    trials = [(best[2] - fit[2], cands[k][0], fit, params[k]) for k, fit in zip(keep, fits)]
    look = {k: 2.0 * np.log(max(sum(1 for add, _ in cands if k in add), 1)) for k in SCANNED}   # all tried
    trials.sort(key=lambda tr: tr[0] - sum(look.get(k, 0.0) for k in tr[1]), reverse=True)
    for drop, add, fit, p in trials:
        red = max(1.0, fit[2] / max(t.size - len(terms) - len(add), 1))
        need = sum(SIGNIFICANT_CHI2 * (red if scatter is None else min(red, MAX_RED)) + look.get(term, 0.0)
                   for term in add)
        if not (all(fit[0][term] > 0 for term in add) and fit[0][WHITE] > 0 and drop > need):   # white stays
            continue
        X = design(t, p[FILTERED], p[TONE], tau0, p[BOUNDED])
        shares = [np.max(X[:, term] * fit[0][term] / np.maximum(fit[3], 1e-300)) for term in add
                  if term in (QUANTISATION, FILTERED, TONE, BOUNDED)]   # a noise kind, not a wrinkle: a material share
        if shares and min(shares) < MATERIAL_SHARE:
            continue
        return terms + list(add), (fit[0], fit[1](), *fit[2:]), p
    return None


def _select(t, a, e, max_tc, tau0=None, scatter=None, extra: bool = False):
    """Forward selection from white noise: the candidate (:func:`_candidates`) that lowers the chi-square most (with
    the white term still positive) is added while it does so by more than :data:`SIGNIFICANT_CHI2` (times the
    reduced chi-square; plus ``2 ln k`` for a term tried at ``k`` parameters, the look-elsewhere of picking the
    best) and, for the quantisation, filtered and tone terms, while it makes at least :data:`MATERIAL_SHARE` of
    the model at some fitted tau."""
    terms, par = [WHITE], {FILTERED: None, TONE: None, BOUNDED: None}
    best = _wls(t, a, e, terms, tau0=tau0, scatter=scatter)
    while True:
        cands = [((term,), c) for term, c in _candidates(t, terms, max_tc, tau0) if extra or term not in LAST]
        fixed = [c[0][0] for c in cands if c[0][0] not in SCANNED]
        pairs = [((p, q), None) for i, p in enumerate(fixed) for q in fixed[i + 1:]]
        # one term at a time; else two of the fixed ones together (one alone may fit worse than none: the
        # curve needs both ends, e.g. quantisation and a random walk); the tone and bounded terms last (LAST): a
        # narrow band near the Nyquist rate, or a bounded angle, looks like quantisation over the octaves, the
        # simpler term
        # (the pairs and the LAST terms only while the model misses its points: they are there for the curves
        # that one more simple term cannot follow, and a model through its points asks for nothing more)
        groups = [[c for c in cands if c[0][0] not in LAST]]
        if best[4] > FIT_FACTOR:
            groups += [pairs, [c for c in cands if c[0][0] in LAST]]
        for group in groups:
            added = _best_addition(t, a, e, tau0, scatter, terms, par, best, group)
            if added is not None:
                terms, best, par = added
                break
        else:
            break
    if best[4] > FIT_FACTOR:   # still off its points: every fixed term at once, pruned back to the significant
        full = _prune(t, a, e, tau0, scatter, sorted(set(terms) | {FLICKER_TERM, WALK, QUANTISATION}), par)
        if full is not None and full[1][2] < best[2] - SIGNIFICANT_CHI2:
            terms, best = full
    return best, par


def _prune(t, a, e, tau0, scatter, terms, par):
    """Backward elimination from ``terms``: a term the fit sets to zero, or whose removal raises the chi-square
    by less than :data:`SIGNIFICANT_CHI2` times the reduced chi-square, is removed (the least needed first) while
    white noise stays positive. Returns ``(terms, fit)``, or None where white noise does not stay."""
    def fit_of(ts):
        return _wls(t, a, e, ts, par[FILTERED], par[TONE], tau0, scatter, tb=par[BOUNDED])

    fit = fit_of(terms)
    while True:
        if not fit[0][WHITE] > 0:
            return None
        zero = [k for k in terms if k != WHITE and not fit[0][k] > 0]
        if zero:
            terms = [k for k in terms if k not in zero]
            fit = fit_of(terms)
            continue
        red = max(1.0, fit[2] / max(t.size - len(terms), 1))
        trials = [(fit_of([k for k in terms if k != r]), r) for r in terms if r != WHITE]
        trials = [(f[2] - fit[2], r, f) for f, r in trials if f[0][WHITE] > 0]
        if not trials:
            return terms, fit
        rise, r, f = min(trials, key=lambda tr: tr[0])
        if rise >= SIGNIFICANT_CHI2 * (red if scatter is None else min(red, MAX_RED)):
            return terms, fit
        terms, fit = [k for k in terms if k != r], f


def fit_allan(taus, avar, edf, first: int = 0, max_tc: float | None = None, scatter=None,
              tau0: float | None = None, extra: bool = False) -> AllanFit:
    """Fit :data:`TERMS` to the Allan variance ``avar`` from the tau of index ``first`` on (:func:`_select`; the
    filtered term's time constant at most ``max_tc``, a filter's, not a slow disturbance's: default
    :data:`MAX_FILTER_SAMPLES` times the shortest tau). ``scatter`` is each point's relative variance measured
    from the data (:func:`allan_points`; NaN where not measured), used where it exceeds the stationary
    estimator's, and then a term's significance is not scaled by the reduced chi-square (the points' own scatter
    is measured: what is left is the model's); ``tau0`` is the sample period (default the shortest tau); with
    ``extra`` the tone and bounded terms are tried too (:data:`LAST`). While the model is
    off the shortest tau by more than a factor :data:`COLOURED_FACTOR` in variance, or off one of the three
    shortest by more than :data:`FIT_FACTOR` beyond their scatter (noise none of the terms describes there), or
    has no short-term term (white, quantisation, filtered, tone) at all, that tau is dropped and the fit repeated,
    down to six taus. Returns an :class:`AllanFit`; its ``worst`` says how well it passes through all the fitted
    points."""
    taus = np.asarray(taus, float)
    tau0 = float(taus[0]) if tau0 is None else float(tau0)
    lo = min(int(first), max(taus.size - 6, 0))
    max_tc = MAX_FILTER_SAMPLES * float(taus[0]) if max_tc is None else max_tc
    sc = None if scatter is None else np.asarray(scatter, float)
    short = list(SHORT_TERMS)
    while True:
        t, a, e = taus[lo:], avar[lo:], edf[lo:]
        s_ = None if sc is None else sc[lo:]
        (coef, cov, chi2, pred, worst), par = _select(t, a, e, max_tc, tau0, s_, extra)
        ratio = a[0] / pred[0] if pred[0] > 0 else np.inf
        dof = edf[lo:lo + 3, 0]
        rel = 2.0 / dof if s_ is None else np.maximum(2.0 / dof, np.nan_to_num(s_[:3], nan=0.0))
        head = np.abs(0.5 * np.log(np.maximum(pred[:3], 1e-300) / np.maximum(a[:3], 1e-300))) - np.sqrt(rel)
        good = (1.0 / COLOURED_FACTOR <= ratio <= COLOURED_FACTOR and float(np.exp(head.max())) <= FIT_FACTOR
                and coef[short].sum() > 0)   # a level of short-term noise, not drift alone
        if good or t.size <= 6:
            if coef[short].sum() <= 0:   # drift alone fits: white noise is what is left
                (coef, cov, chi2, pred, worst), par = _wls(t, a, e, [WHITE], tau0=tau0, scatter=s_), {}
            tc = par.get(FILTERED) or 0.0
            tone = par.get(TONE) or (0.0, 0.0)
            tb = par.get(BOUNDED) or 0.0
            return AllanFit(coef, cov, lo, design(taus, tc, tone, tau0, tb) @ coef,
                            tc if coef[FILTERED] > 0 else 0.0, chi2, worst,
                            tuple(tone) if coef[TONE] > 0 else (0.0, 0.0), tau0, tb if coef[BOUNDED] > 0 else 0.0)
        lo += 1
