"""The noise of one gyro at rest: its rest stretches and their Allan deviation fitted per axis (IEEE Std 952).

This is what imu_utils and allan_variance_ros are run for, without ROS: a recording of a gyro lying still
(or the still stretches of a longer one, such as the static poses a calibration log starts with) gives per axis
the white rate noise ``N`` (angle random walk, rad/s/sqrt(Hz) = Kalibr's ``gyroscope_noise_density``), the bias
instability ``B`` (rad/s) and the bias random walk ``K`` (rad/s^2/sqrt(Hz) = Kalibr's ``gyroscope_random_walk``),
each with its standard uncertainty.

* :func:`rest_stretches` finds where the gyro is still: windows whose per-axis spread is at the level of the
  quietest windows (motion and its transitions are far above it) and whose mean stays at the rest level, joined
  into stretches, their ends trimmed by one window.
* :func:`static_noise` computes the overlapping Allan variance of every stretch with
  :func:`~fusion_gyrocal.core.allan.allan_deviation` (octave taus), pools the stretches at each tau weighted by
  their number of terms (their degrees of freedom add, :func:`~fusion_gyrocal.core.allan.edf_table`), and fits
  ``AVAR = N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3`` and the short-term terms (quantisation, filtered, tone,
  bounded) per axis with :func:`~fusion_gyrocal.core.allan.fit_allan` (each term kept only where it is
  significant); the white noise is the density of the short-term terms' variance per sample. That variance is
  also what the samples' spread about their means over about a second shows (:func:`short_term_spread`): where the
  fit leaves the shortest taus out (noise none of its terms describes there, such as a comb of tones of the chip)
  or claims more than the spread holds, the white noise is taken from the spread instead, and ``white_from`` says
  so per axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ExcitationError, InputError
from .allan import allan_deviation, edf_table, fit_allan

REST_SPREAD_FACTOR = 2.0     # a rest window's spread is at most this times the quiet level
MIN_STRETCH_S = 4.0          # shorter rest stretches are not used
SPREAD_BLOCK_S = 1.0         # blocks of the short-term spread: a tone above 1 Hz inside one, a drift not
SPREAD_SIGMAS = 3.0          # the fit's variance per sample beyond the spread by more sigmas contradicts it


def _windows(omega, valid, w: int):
    n = (omega.shape[0] // w) * w
    x = omega[:n].reshape(-1, w, 3)
    ok = valid[:n].reshape(-1, w).all(axis=1)
    return x, ok


def rest_stretches(omega, rate_hz: float, *, valid=None, window_s: float = 1.0,
                   min_stretch_s: float = MIN_STRETCH_S) -> list[tuple[int, int]]:
    """``[(start, stop), ...]`` sample ranges where the gyro is at rest.

    A window of ``window_s`` is at rest when its largest per-axis standard deviation is within
    :data:`REST_SPREAD_FACTOR` of the quiet level (the 10th percentile over the valid windows: white noise at
    rest) and its mean is within 5 of those standard deviations of the rest level (the median mean of such
    windows: the bias) on every axis; consecutive rest windows form a stretch, trimmed by one window at each end
    (the settling after a motion), kept when at least ``min_stretch_s`` long. A recording with no motion is one
    stretch.

    Raises
    ------
    InputError
        Rates not of shape (N, 3), or a recording shorter than three windows.
    """
    omega = np.asarray(omega, dtype=float)
    if omega.ndim != 2 or omega.shape[1] != 3:
        raise InputError(f"omega: expected angular rates of shape (N, 3), got {omega.shape}")
    valid = np.isfinite(omega).all(axis=1) if valid is None else (np.asarray(valid, bool) & np.isfinite(omega).all(1))
    w = max(8, int(round(window_s * rate_hz)))
    if omega.shape[0] < 3 * w:
        raise InputError(f"omega: expected at least {3 * w} samples (three {window_s:g} s windows), got "
                         f"{omega.shape[0]}")
    x, ok = _windows(np.where(valid[:, None], omega, 0.0), valid, w)
    sd = x.std(axis=1)                  # (W, 3)
    spread = sd.max(axis=1)
    quiet = np.percentile(spread[ok], 10) if ok.any() else np.inf
    still = ok & (spread <= REST_SPREAD_FACTOR * quiet)
    mean = x.mean(axis=1)
    if still.any():
        level = np.median(mean[still], axis=0)
        tol = 5.0 * np.median(sd[still], axis=0)
        still &= (np.abs(mean - level) <= np.maximum(tol, 1e-12)).all(axis=1)
    out = []
    k, W = 0, still.size
    while k < W:
        if not still[k]:
            k += 1
            continue
        j = k
        while j < W and still[j]:
            j += 1
        a, b = (k + 1 if k > 0 else k), (j - 1 if j < W else j)   # trim the windows next to motion
        if (b - a) * w >= min_stretch_s * rate_hz:
            out.append((a * w, b * w))
        k = j
    return out


@dataclass(frozen=True)
class StaticNoise:
    """Noise of one gyro at rest, per axis (x, y, z of the gyro).

    Attributes
    ----------
    rate_hz : float
        Sample rate (Hz).
    white : ndarray (3,)
        White rate noise ``N`` (angle random walk), rad/s/sqrt(Hz): Kalibr's ``gyroscope_noise_density``. Where the
        Allan fit also keeps quantisation, filtered, tone or bounded noise, the density whose variance per sample
        is that of all the short-term terms (:meth:`~fusion_gyrocal.core.allan.AllanFit.sample_variance`: what a
        filter that takes each sample's noise from the density needs, and what the spread of the samples shows).
    white_std : ndarray (3,)
        Its standard uncertainty.
    bias_instability, bias_instability_std : ndarray (3,)
        ``B`` (rad/s) and its uncertainty; 0 where the fit has no flicker term.
    random_walk, random_walk_std : ndarray (3,)
        ``K`` (rad/s^2/sqrt(Hz)): Kalibr's ``gyroscope_random_walk``; 0 where the fit has no walk term.
    taus : ndarray (T,)
        Averaging times of the pooled Allan deviation (s).
    adev : ndarray (T, 3)
        The pooled overlapping Allan deviation per axis (rad/s).
    adev_fit : ndarray (T, 3)
        The fitted model per axis (NaN below each axis's first fitted tau).
    fit_from : ndarray (3,) of int
        Index of the first tau each axis's fit used (shorter taus dropped as coloured by
        :func:`~fusion_gyrocal.core.allan.fit_allan`).
    white_from : tuple of str
        Per axis, where ``white`` comes from: ``"fit"`` (the Allan fit's short-term terms) or ``"spread"``
        (:func:`short_term_spread`: the fit left the shortest taus out, or its variance per sample exceeded the
        samples' own spread by more than :data:`SPREAD_SIGMAS` sigmas).
    stretches : tuple of (int, int)
        The rest stretches used (sample ranges).
    n_samples : int
        Samples in them.
    """

    rate_hz: float
    white: np.ndarray
    white_std: np.ndarray
    bias_instability: np.ndarray
    bias_instability_std: np.ndarray
    random_walk: np.ndarray
    random_walk_std: np.ndarray
    taus: np.ndarray
    adev: np.ndarray
    adev_fit: np.ndarray
    fit_from: np.ndarray
    stretches: tuple
    n_samples: int
    white_from: tuple = ("fit", "fit", "fit")

    @property
    def white_per_sample(self) -> np.ndarray:
        """White noise std per sample (rad/s): ``N sqrt(rate_hz)``."""
        return self.white * np.sqrt(self.rate_hz)

    def to_dict(self) -> dict:
        """JSON-ready (every number finite: a term the fit did not keep is 0)."""
        out = {"rate_hz": float(self.rate_hz), "n_samples": int(self.n_samples),
               "stretches": [list(map(int, s)) for s in self.stretches],
               "units": {"white": "rad/s/sqrt(Hz)", "bias_instability": "rad/s", "random_walk": "rad/s^2/sqrt(Hz)",
                         "taus": "s", "adev": "rad/s"}}
        for name in ("white", "white_std", "bias_instability", "bias_instability_std", "random_walk",
                     "random_walk_std", "taus", "adev"):
            out[name] = np.asarray(getattr(self, name), float).tolist()
        out["fit_from"] = [int(i) for i in self.fit_from]
        out["white_from"] = list(self.white_from)
        return out


def _sd_of_root(value_sq: float, var: float) -> float:
    """1-sigma of ``sqrt(x)`` from ``x``'s variance (first order), 0 where the term is absent."""
    return float(np.sqrt(max(var, 0.0)) / (2.0 * np.sqrt(value_sq))) if value_sq > 0 and np.isfinite(var) else 0.0


def short_term_spread(omega, pieces, rate_hz: float):
    """Per axis, the variance per sample of the short-term noise as the samples show it, and its standard uncertainty.

    Every piece ``(a, b)`` of contiguous good samples is cut into blocks of about :data:`SPREAD_BLOCK_S` (at most the
    piece); the squared deviations from each block's own mean are pooled, times ``m / (m - 1)`` (unbiased for white
    noise in blocks of ``m``): a tone of more than a cycle per block counts, a drift over many blocks does not. The
    uncertainty is the larger of the white-noise one (``sqrt(2 / n)`` relative) and the scatter of the pieces' own
    values (tones and bursts make the pieces disagree more). ``(None, None)`` without a piece of 8 samples.
    """
    m = max(8, int(round(SPREAD_BLOCK_S * rate_hz)))
    values, counts = [], []
    for a, b in pieces:
        width = min(m, b - a)
        if width < 8:
            continue
        k = (b - a) // width
        x = omega[a:a + k * width].reshape(k, width, 3)
        dev = x - x.mean(axis=1, keepdims=True)
        values.append(np.einsum("kwi,kwi->i", dev, dev) / (k * (width - 1)))
        counts.append(k * width)
    if not values:
        return None, None
    v, c = np.array(values), np.array(counts, float)
    mean = c @ v / c.sum()
    var = 2.0 * mean ** 2 / c.sum()
    if len(c) >= 2:
        var = np.maximum(var, (c ** 2 @ (v - mean) ** 2) / c.sum() ** 2 * len(c) / (len(c) - 1))
    return mean, np.sqrt(var)


def static_noise(omega, rate_hz: float, *, valid=None, stretches=None) -> StaticNoise:
    """Per-axis white noise, bias instability and random walk of a gyro at rest, with their uncertainties.

    Parameters
    ----------
    omega : array_like (N, 3)
        Rates in rad/s.
    rate_hz : float
        Sample rate (Hz).
    valid : array_like (N,) of bool, optional
        Usable samples (saturated / non-finite ones False).
    stretches : sequence of (int, int), optional
        The rest stretches (default :func:`rest_stretches`).

    Raises
    ------
    ExcitationError
        No rest stretch long enough for an Allan analysis.
    """
    omega = np.asarray(omega, dtype=float)
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"rate_hz: expected a positive sample rate, got {rate_hz!r}")
    if stretches is None:
        stretches = rest_stretches(omega, rate_hz, valid=valid)
    ok = np.isfinite(omega).all(axis=1) if valid is None else np.asarray(valid, bool) & np.isfinite(omega).all(1)
    pieces = []
    for a, b in stretches:   # split further at masked samples: the Allan variance needs contiguous samples
        good = ok[a:b]
        edges = np.flatnonzero(np.diff(np.concatenate([[0], good.astype(np.int8), [0]])))
        pieces += [(a + s, a + e) for s, e in zip(edges[::2], edges[1::2]) if e - s >= 16]
    if not pieces:
        raise ExcitationError(f"no rest stretch of at least {MIN_STRETCH_S:g} s: expected a recording of the gyro "
                              "lying still (or with still stretches between motions), got none")
    n_taus = max(allan_deviation(omega[a:b], rate_hz)[0].size for a, b in pieces)
    num = np.zeros((n_taus, 3))
    weight = np.zeros(n_taus)
    edf = np.zeros((n_taus, 4))
    taus = None
    for a, b in pieces:
        t, adev, sub_n, sub_m = allan_deviation(omega[a:b], rate_hz)
        k = t.size
        terms = np.maximum((b - a) - 2.0 * t * rate_hz, 1.0)   # terms of the overlapping estimator at each tau
        num[:k] += adev ** 2 * terms[:, None]
        weight[:k] += terms
        edf[:k] += edf_table(sub_n, sub_m, axes=1)     # one axis at a time
        if taus is None or t.size > taus.size:
            taus = t
    keep = weight > 0
    avar = num[keep] / weight[keep, None]
    taus, edf = taus[keep], edf[keep]
    white, white_sd = np.zeros(3), np.zeros(3)
    bias, bias_sd = np.zeros(3), np.zeros(3)
    walk, walk_sd = np.zeros(3), np.zeros(3)
    fit = np.full(avar.shape, np.nan)
    first = np.zeros(3, int)
    spread, spread_sd = short_term_spread(omega, pieces, rate_hz)
    source = ["fit"] * 3
    for ax in range(3):
        f = fit_allan(taus, avar[:, ax], edf, extra=True)
        coef, cov, lo = f.coef, f.cov, f.first
        first[ax] = lo
        fit[lo:, ax] = np.sqrt(np.maximum(f.pred[lo:], 0.0))
        # the white level the samples show: the short-term terms' variance per sample (white, quantisation,
        # filtered, tone), as a density (times the sample period): what a filter that takes each sample's noise
        # reads from a density; its variance by first order
        g = f.sample_row() * f.tau0
        level, level_var = f.sample_variance() * f.tau0, float(g @ np.nan_to_num(cov) @ g)
        if spread is not None and (lo > 0 or f.sample_variance() > spread[ax] + SPREAD_SIGMAS * spread_sd[ax]):
            # the fit does not describe the noise of one sample (it left those taus out) or claims more than the
            # samples hold: the samples' own spread is that noise
            level, level_var, source[ax] = spread[ax] * f.tau0, (spread_sd[ax] * f.tau0) ** 2, "spread"
        white[ax], white_sd[ax] = np.sqrt(max(level, 0.0)), _sd_of_root(level, level_var)
        bias[ax], bias_sd[ax] = np.sqrt(max(coef[1], 0.0)), _sd_of_root(coef[1], cov[1, 1])
        walk[ax], walk_sd[ax] = np.sqrt(max(coef[2], 0.0)), _sd_of_root(coef[2], cov[2, 2])
    return StaticNoise(rate_hz=float(rate_hz), white=white, white_std=white_sd, bias_instability=bias,
                       bias_instability_std=bias_sd, random_walk=walk, random_walk_std=walk_sd, taus=taus,
                       adev=np.sqrt(avar), adev_fit=fit, fit_from=first, stretches=tuple(pieces),
                       n_samples=int(sum(b - a for a, b in pieces)), white_from=tuple(source))


__all__ = ["REST_SPREAD_FACTOR", "StaticNoise", "rest_stretches", "short_term_spread", "static_noise"]
