"""Inter-sensor timing beyond one constant offset: a delay that follows the beat of each chip's sampling clock.

A MEMS gyro samples on its own clock and the read-out takes its latest sample, so the delay between the instant
a sample describes and the read-out instant drifts as a sawtooth whose period is the beat between the two clocks
(the same for every session of a board, shifting slowly with temperature). With one constant offset removed
(:mod:`~fusion_gyrocal.pipeline.alignment`), the remaining delay ``delta(t)`` of gyro 2 against gyro 1 leaves the
residual

    r_k = omega_1 - A omega_2 - b  ~  u_k delta(t_k) + noise,     u_k = A d(omega_2)/dt (t_k)

(first order in the delay): it lies along the rate's derivative and follows the beat tones (the residual is
high-passed over about a second first: a drifting bias is slow). :func:`estimate_timing`
finds up to :data:`MAX_TONES` tones (one per chip against the read-out), each with :data:`HARMONICS` harmonics
for the sawtooth's shape, by least squares of ``r_k . u_k`` on ``|u_k|^2 delta(t_k)`` (frequencies from the
periodogram of ``r_k . u_k``, refined on a fine grid), and keeps them only where the peak is a spectral line
(far above the periodogram around it) and explains far more than noise would over a search of every frequency.
A constant delay alone (a filter's group delay, in sample-aligned input where no offset was estimated) is kept
when it explains far more than noise would. :meth:`TimingModel.compensate` moves gyro 2's samples to the
instants they describe (``omega_2 + d(omega_2)/dt delta``), after which the pair is calibrated again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Tones searched (one per chip against the read-out clock).
MAX_TONES = 2
#: Harmonics of each tone (a sawtooth's shape).
HARMONICS = 3
#: Zero padding of the periodogram (frequency resolution of the search, before refinement).
PADDING = 4
#: How far the refinement searches around a periodogram peak, in resolution cells (1 / the log's duration).
REFINE_CELLS = 3.0
#: Samples the search looks at (a longer log: its most excited stretch of this many).
MAX_SAMPLES = 2**16
#: Samples of the first, cheap look (one tone or a constant delay on the most excited stretch of this many):
#: only when it finds one is the longer search run.
DETECT_SAMPLES = 2**13
#: A constant delay (no tone: a filter's group delay in sample-aligned input) is kept when it explains this many
#: times the residual's variance along the rate's derivative (chi2_1's 99.9 % point is 10.8).
CONSTANT_SIGNIFICANCE = 30.0
#: A delay is compensated only when it explains at least this fraction of the residual's energy.
MIN_EXPLAINED = 0.01
#: A peak is a line when its power is this many times the median of its neighbourhood (exponential power: a
#: noise peak exceeds 30x the median, 21x the mean, with probability ~1e-9 per bin).
LINE_FACTOR = 30.0
#: The neighbourhood, in resolution cells either side.
LINE_CELLS = 50
#: A tone is kept when it explains this many times what the largest of the searched frequencies would under noise.
SIGNIFICANCE = 4.0


@dataclass(frozen=True)
class TimingModel:
    """The delay of gyro 2's samples against gyro 1's beyond the constant offset (:func:`estimate_timing`).

    Attributes
    ----------
    tones_hz : tuple of float
        Beat frequencies found (Hz; cycles per sample for input without timestamps); empty when none is
        significant (a constant delay may still be).
    coefficients : ndarray
        ``[mean, (cos, sin) per harmonic per tone]`` of the delay (s; samples without timestamps).
    harmonics : int
    explained : float
        Fraction of the residual's energy the delay explains; 0 when neither a constant delay nor a tone is
        significant.
    delay_std : float
        Standard deviation of the modelled delay over the samples used (s; samples without timestamps).
    """

    tones_hz: tuple
    coefficients: np.ndarray
    harmonics: int
    explained: float
    delay_std: float

    @property
    def significant(self) -> bool:
        return self.explained > 0.0

    @property
    def mean_delay(self) -> float:
        """The delay's mean (s; samples without timestamps): a constant group delay, or what the offset left."""
        return float(self.coefficients[0])

    def delay(self, t) -> np.ndarray:
        """The modelled delay at the instants ``t``."""
        return _design(np.asarray(t, dtype=float), self.tones_hz, self.harmonics) @ self.coefficients

    def compensate(self, t, omega_2) -> np.ndarray:
        """Gyro 2's rates moved to the instants they describe: ``omega_2 + d(omega_2)/dt * delay(t)``."""
        w2 = np.asarray(omega_2, dtype=float)
        return w2 + derivative(t, w2) * self.delay(t)[:, None]


def derivative(t, w) -> np.ndarray:
    """``dw/dt`` by central differences, one-sided beside an invalid (NaN) sample, 0 between two."""
    t = np.asarray(t, dtype=float)
    fwd = np.full(w.shape, np.nan)
    fwd[:-1] = (w[1:] - w[:-1]) / (t[1:] - t[:-1])[:, None]
    bwd = np.full(w.shape, np.nan)
    bwd[1:] = fwd[:-1]
    d = 0.5 * (fwd + bwd)
    d = np.where(np.isfinite(d), d, np.where(np.isfinite(fwd), fwd, bwd))
    d[~np.isfinite(d)] = 0.0
    return d


NONE = TimingModel((), np.zeros(1), HARMONICS, 0.0, 0.0)


def _excited_stretch(w2, ok, length: int) -> int:
    """Start of the stretch of ``length`` samples (from block starts) with the most motion of gyro 2."""
    step, stride = length // 4, 64
    starts = np.arange(0, len(w2) - length + 1, step)
    sub = np.where(ok[::stride, None], w2[::stride], 0.0)
    energy = np.cumsum(np.concatenate([[0.0], np.nan_to_num(np.einsum("ij,ij->i", sub, sub))]))
    width = length // stride
    return int(starts[int(np.argmax([energy[min(s // stride + width, len(sub))] - energy[s // stride]
                                     for s in starts]))])


def _is_line(power, i: int) -> bool:
    """Whether the periodogram's peak at bin ``i`` is a spectral line: :data:`LINE_FACTOR` times the median power
    of its neighbourhood (:data:`LINE_CELLS` resolution cells either side, the peak's own cells left out). A beat
    tone is a line; coloured noise or a wandering bias is a smooth spectrum, whose peaks are not."""
    lo, hi = max(i - LINE_CELLS * PADDING, 0), min(i + LINE_CELLS * PADDING + 1, len(power))
    around = np.concatenate([power[lo:max(i - 2 * PADDING, lo)], power[min(i + 2 * PADDING + 1, hi):hi]])
    return around.size > 0 and power[i] > LINE_FACTOR * float(np.median(around))


def _high_pass(r, ok, window: int) -> np.ndarray:
    """The residual less its moving mean over ``window`` samples (about 1 s): a drifting bias is slow, the
    residual of a delay moves with the motion."""
    x = np.where(ok[:, None], np.nan_to_num(r), 0.0)
    c = np.cumsum(np.vstack([np.zeros((1, 3)), x]), axis=0)
    n = np.cumsum(np.concatenate([[0.0], ok.astype(float)]))
    lo = np.clip(np.arange(len(r)) - window // 2, 0, len(r))
    hi = np.clip(lo + window, 0, len(r))
    count = np.maximum(n[hi] - n[lo], 1.0)
    return r - (c[hi] - c[lo]) / count[:, None]


def _design(t, tones, harmonics) -> np.ndarray:
    cols = [np.ones_like(t)]
    for f in tones:
        for h in range(1, harmonics + 1):
            phase = 2.0 * np.pi * h * f * t
            cols += [np.cos(phase), np.sin(phase)]
    return np.stack(cols, axis=1)


def _fit(t, ru, uu, tones, harmonics):
    """Least squares of ``sum |r - u delta|^2`` over the delay's coefficients: ``(coefficients, explained energy)``."""
    X = _design(t, tones, harmonics)
    G = (X * uu[:, None]).T @ X
    h = X.T @ ru
    c = np.linalg.lstsq(G, h, rcond=None)[0]
    return c, float(h @ c)


def estimate_timing(t, omega_1, omega_2, A, bias, mask=None, *, max_tones: int = MAX_TONES,
                    harmonics: int = HARMONICS, max_samples: int = MAX_SAMPLES) -> TimingModel:
    """The delay of gyro 2 against gyro 1 that the residual of ``(A, bias)`` shows (:class:`TimingModel`).

    Parameters
    ----------
    t : array_like (N,) or None
        The samples' instants on one uniform grid (s), or the sample index for input without timestamps (None:
        the index, made only for the stretch searched).
    omega_1, omega_2 : array_like (N, 3)
        Sample-aligned rates (rad/s).
    A, bias : the calibration's map and combined bias (``omega_1 ~ A omega_2 + bias``).
    mask : array_like of bool (N,), optional
        Samples to use (the derivative is one-sided beside an invalid one).
    """
    w1, w2 = np.asarray(omega_1, dtype=float), np.asarray(omega_2, dtype=float)
    n = len(w1)
    ok = np.ones(n, bool) if mask is None else np.asarray(mask, bool).copy()
    if n > max_samples:          # the most excited stretch of a long log (the tones are stationary)
        start = _excited_stretch(w2, ok, max_samples)
        part = slice(start, start + max_samples)
        t = np.arange(start, start + max_samples, dtype=float) if t is None else np.asarray(t, dtype=float)[part]
        w1, w2, ok = w1[part], w2[part], ok[part]
    t = np.arange(n, dtype=float) if t is None else np.asarray(t, dtype=float)
    if len(t) > DETECT_SAMPLES and not estimate_timing(t, w1, w2, A, bias, ok, max_tones=1, harmonics=harmonics,
                                                       max_samples=DETECT_SAMPLES).significant:
        return NONE                   # nothing on the most excited stretch: not worth the longer search
    ok &= np.all(np.isfinite(w1), axis=1) & np.all(np.isfinite(w2), axis=1)
    if np.count_nonzero(ok) < 100 * (1 + 2 * harmonics * max_tones):
        return NONE
    dt = float(np.median(np.diff(t)))
    window = max(int(round(1.0 / dt)), 3) if dt < 1.0 else 64   # about a second (64 samples without timestamps)
    u = derivative(t, w2) @ np.asarray(A).T
    r = _high_pass(w1 - w2 @ np.asarray(A).T - bias, ok, window)
    tt, ru, uu = t[ok], np.einsum("ij,ij->i", r, u)[ok], np.einsum("ij,ij->i", u, u)[ok]
    energy = float(np.einsum("ij,ij->", r[ok], r[ok]))
    keep = uu > 0
    if not keep.any() or energy <= 0:
        return NONE
    sigma2 = float(np.median(ru[keep] ** 2 / uu[keep])) / 0.455        # the residual along u, robustly (chi2_1)
    slot = np.round((tt - tt[0]) / dt).astype(np.int64)                # each sample's place on a uniform grid
    cells = int(slot[-1]) + 1                                           # (logs with gaps: by time, not by index)
    if cells > 4 * len(t):
        return NONE
    n_freq = cells / 2.0                                                # independent frequencies searched
    _, constant = _fit(tt, ru, uu, [], harmonics)                     # one delay: a filter's group delay
    explained = constant if constant / sigma2 > CONSTANT_SIGNIFICANCE else 0.0
    tones = []
    for _ in range(max_tones):
        c, _ = _fit(tt, ru, uu, tones, harmonics)
        x = np.zeros(cells)
        x[slot] = ru - uu * (_design(tt, tones, harmonics) @ c)
        power = np.abs(np.fft.rfft(x, PADDING * cells)) ** 2
        freq = np.fft.rfftfreq(PADDING * cells, dt)
        allowed = freq > 2.0 / (cells * dt)                             # at least two periods in the log
        for f in tones:                                                 # not a harmonic of a tone found
            for h in range(1, harmonics + 1):
                allowed &= np.abs(freq - h * f) > 2.0 / (cells * dt)
        if not allowed.any():
            break
        i = int(np.flatnonzero(allowed)[np.argmax(power[allowed])])
        if not _is_line(power, i):
            break
        peak = freq[i]
        span = REFINE_CELLS / (cells * dt)
        grid = np.linspace(peak - span, peak + span, 41)
        gains = [_fit(tt, ru, uu, tones + [f], harmonics)[1] for f in grid]
        best = float(grid[int(np.argmax(gains))])
        gain = max(gains) - explained
        if gain / sigma2 < SIGNIFICANCE * (1 + 2 * harmonics + 2.0 * np.log(n_freq)):
            break
        tones.append(best)
        explained = max(gains)
    if not tones and not explained:
        return NONE
    c, explained = _fit(tt, ru, uu, tones, harmonics)
    if explained < MIN_EXPLAINED * energy:                              # significant, but too small to matter
        return NONE
    delay = _design(tt, tones, harmonics) @ c
    return TimingModel(tuple(tones), c, harmonics, explained / energy, float(delay.std()))
