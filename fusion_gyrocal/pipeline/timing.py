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
periodogram of ``r_k . u_k``, refined by :func:`_scan` within a resolution cell), and keeps them only where the peak is a spectral line
(far above the periodogram around it) and explains far more than noise would over a search of every frequency.
A tone whose delay is the sawtooth itself (the time since the chip's last sample, wrapping once per beat) is then
fitted as one: ``a (frac(f t + phi) - 1/2)``, its phase and frequency searched (:func:`_sawtooth`), kept where it
explains at least what the harmonics do with one coefficient instead of ``2 x HARMONICS``: the harmonics cannot
follow its jumps, whose residual is otherwise left for the flex gate.
A constant delay alone (a filter's group delay, in sample-aligned input where no offset was estimated) is kept
when it explains far more than noise would. :meth:`TimingModel.compensate` moves gyro 2's samples to the
instants they describe (``omega_2 + d(omega_2)/dt delta``), after which the pair is calibrated again.

An array of N gyros has N chips, hence N delays, not N-1 independent pairs: :func:`estimate_array_timing` fits one
delay per chip (:class:`ArrayTimingModel`) to the residuals of all pairs with the reference, finding the reference
chip's tone once (a line in every pair) and each other chip's once (in its pair); gyro j's delay against the
reference is the difference of the two chips'.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.moments import median

#: Tones searched (one per chip against the read-out clock).
MAX_TONES = 2
#: Harmonics of each tone (a sawtooth's shape).
HARMONICS = 3
#: Zero padding of the periodogram (frequency resolution of the search, before refinement).
PADDING = 4
#: How far the refinement scans around a periodogram peak, in resolution cells (1 / the log's duration; the padded
#: periodogram's peak is within an eighth of a cell of a clean line's; on three MIMU sessions' 23 tones the best was
#: within 0.16), and the points of that scan (then one more at the vertex of the parabola through the best and its
#: neighbours).
SCAN_CELLS, SCAN_POINTS = 1.0, 7
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
        ``[mean, per tone (cos, sin) per harmonic or one sawtooth amplitude]`` of the delay (s; samples without
        timestamps).
    harmonics : int
    explained : float
        Fraction of the residual's energy the delay explains; 0 when neither a constant delay nor a tone is
        significant.
    delay_std : float
        Standard deviation of the modelled delay over the samples used (s; samples without timestamps).
    phases : tuple of float
        Per tone, the phase ``phi`` (cycles) of a sawtooth ``frac(f t + phi) - 1/2`` (one coefficient) where the
        tone was fitted as one, NaN where by its harmonics; empty: every tone by its harmonics.
    """

    tones_hz: tuple
    coefficients: np.ndarray
    harmonics: int
    explained: float
    delay_std: float
    phases: tuple = ()

    @property
    def significant(self) -> bool:
        return self.explained > 0.0

    @property
    def mean_delay(self) -> float:
        """The delay's mean (s; samples without timestamps): a constant group delay, or what the offset left."""
        return float(self.coefficients[0])

    def delay(self, t) -> np.ndarray:
        """The modelled delay at the instants ``t``."""
        return _design(np.asarray(t, dtype=float), self.tones_hz, self.harmonics, self.phases) @ self.coefficients

    def compensate(self, t, omega_2) -> np.ndarray:
        """Gyro 2's rates moved to the instants they describe: ``omega_2 + d(omega_2)/dt * delay(t)``."""
        return _moved(t, np.asarray(omega_2, dtype=float), self.delay(t))


def _moved(t, w, delay) -> np.ndarray:
    """Rates ``w`` moved by ``delay`` (per sample) to the instants they describe, first order:
    ``w + dw/dt * delay``."""
    return w + derivative(t, w) * delay[:, None]


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
    """Start of the stretch of ``length`` samples (from block starts) with the most motion of gyro 2 (the samples
    ``ok``; None: all)."""
    step, stride = length // 4, 64
    starts = np.arange(0, len(w2) - length + 1, step)
    keep = None if ok is None else ok[::stride]
    sub = w2[::stride] if keep is None or keep.all() else np.where(keep[:, None], w2[::stride], 0.0)   # no copy
    energy = np.cumsum(np.concatenate([[0.0], np.nan_to_num(np.einsum("ij,ij->i", sub, sub))]))
    width = length // stride
    first = starts // stride
    return int(starts[int(np.argmax(energy[np.minimum(first + width, len(sub))] - energy[first]))])


def _is_line(power, i: int) -> bool:
    """Whether the periodogram's peak at bin ``i`` is a spectral line: :data:`LINE_FACTOR` times the median power
    of its neighbourhood (:data:`LINE_CELLS` resolution cells either side, the peak's own cells left out). A beat
    tone is a line; coloured noise or a wandering bias is a smooth spectrum, whose peaks are not."""
    lo, hi = max(i - LINE_CELLS * PADDING, 0), min(i + LINE_CELLS * PADDING + 1, len(power))
    around = np.concatenate([power[lo:max(i - 2 * PADDING, lo)], power[min(i + 2 * PADDING + 1, hi):hi]])
    return around.size > 0 and power[i] > LINE_FACTOR * float(median(around))


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


def _design(t, tones, harmonics, phases=()) -> np.ndarray:
    """The delay's design: a column of ones, then ``cos, sin`` of every harmonic of every tone, or one sawtooth
    column for a tone with a phase in ``phases`` (:func:`_rows` transposed)."""
    return _rows(t, tones, harmonics, phases).T


def _high_passed_gram(X, r, u, ok, window: int):
    """``(G, h, energy)`` of the least squares of the residual ``r`` (N, 3) on the delay's columns ``X`` (N, p),
    both high-passed: the residual less its mean over blocks of ``window`` samples, and each column's residual
    ``u X_j`` less its own (the samples ``ok`` only). The search (:func:`estimate_timing`) high-passes the residual
    alone, against a drifting bias; a delay's residual has slow parts too, which that takes from ``r`` alone and
    which would shrink the fitted delay (by 15 % for a sawtooth at 1.7 Hz against a one-second window). ``energy``:
    the high-passed residual's, what the explained energy is a share of. Without an (N, 3, p) array: the block
    means' part is one batched product per block."""
    n, p = X.shape
    used = ok[:, None] & np.isfinite(r)
    rr, uw = np.where(used, r, 0.0), np.where(ok[:, None], u, 0.0)
    G = (X * np.einsum("ka,ka->k", uw, uw)[:, None]).T @ X
    h = X.T @ np.einsum("ka,ka->k", rr, uw)
    blocks = -(-n // window)
    pad = blocks * window - n

    def blocked(a):
        return np.concatenate([a, np.zeros((pad,) + a.shape[1:])]).reshape((blocks, window) + a.shape[1:])

    S = np.matmul(blocked(uw).transpose(0, 2, 1), blocked(X))            # (blocks, 3, p): sums of u X_j
    count = np.maximum(blocked(ok.astype(float)).sum(axis=1), 1.0)
    scaled = S / np.sqrt(count)[:, None, None]
    G -= scaled.reshape(-1, p).T @ scaled.reshape(-1, p)
    R = blocked(rr).sum(axis=1)                                          # (blocks, 3): sums of r
    h -= np.einsum("bap,ba->p", S / count[:, None, None], R)
    return G, h, float(np.einsum("ka,ka->", rr, rr) - np.sum(R ** 2 / count[:, None]))


def _fit_high_passed(t, r, u, ok, window: int, tones, harmonics, phases=()):
    """The delay's coefficients and explained energy as :func:`_fit`, the residual ``r`` and each column high-passed
    alike (:func:`_high_passed_gram`), and the high-passed residual's energy."""
    G, h, energy = _high_passed_gram(_design(t, tones, harmonics, phases), r, u, ok, window)
    c = np.linalg.lstsq(G, h, rcond=None)[0]
    return c, float(h @ c), energy


def estimate_timing(t, omega_1, omega_2, A, bias, mask=None, *, max_tones: int = MAX_TONES,
                    harmonics: int = HARMONICS, max_samples: int = MAX_SAMPLES, sawtooth: bool = True) -> TimingModel:
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
    sawtooth : bool
        Whether a tone may be fitted as a sawtooth (:func:`_sawtooth`); False: by its harmonics only.
    """
    w1, w2 = np.asarray(omega_1, dtype=float), np.asarray(omega_2, dtype=float)
    n = len(w1)
    ok = None if mask is None else np.asarray(mask, bool).copy()
    if n > max_samples:          # the most excited stretch of a long log (the tones are stationary)
        start = _excited_stretch(w2, ok, max_samples)
        part = slice(start, start + max_samples)
        t = np.arange(start, start + max_samples, dtype=float) if t is None else np.asarray(t, dtype=float)[part]
        w1, w2, ok = w1[part], w2[part], None if ok is None else ok[part]
    ok = np.ones(len(w1), bool) if ok is None else ok     # (of the stretch only: no flag per sample of a long log)
    t = np.arange(n, dtype=float) if t is None else np.asarray(t, dtype=float)
    if len(t) > DETECT_SAMPLES and not estimate_timing(t, w1, w2, A, bias, ok, max_tones=1, harmonics=harmonics,
                                                       max_samples=DETECT_SAMPLES, sawtooth=False).significant:
        return NONE                   # nothing on the most excited stretch: not worth the longer search
    ok &= np.all(np.isfinite(w1), axis=1) & np.all(np.isfinite(w2), axis=1)
    if np.count_nonzero(ok) < 100 * (1 + 2 * harmonics * max_tones):
        return NONE
    dt = float(median(np.diff(t)))
    window = max(int(round(1.0 / dt)), 3) if dt < 1.0 else 64   # about a second (64 samples without timestamps)
    u = derivative(t, w2) @ np.asarray(A).T
    raw = w1 - w2 @ np.asarray(A).T - bias
    r = _high_pass(raw, ok, window)
    tt, ru, uu = t[ok], np.einsum("ij,ij->i", r, u)[ok], np.einsum("ij,ij->i", u, u)[ok]
    energy = float(np.einsum("ij,ij->", r[ok], r[ok]))
    keep = uu > 0
    if not keep.any() or energy <= 0:
        return NONE
    sigma2 = float(median(ru[keep] ** 2 / uu[keep])) / 0.455        # the residual along u, robustly (chi2_1)
    slot = np.round((tt - tt[0]) / dt).astype(np.int64)                # each sample's place on a uniform grid
    cells = int(slot[-1]) + 1                                           # (logs with gaps: by time, not by index)
    if cells > 4 * len(t):
        return NONE
    n_freq = cells / 2.0                                                # independent frequencies searched
    series = _PairSeries(ru, uu, 0.0, 1.0)     # the tones found held fixed: each frequency tried adds its columns
    constant = series.explained                                         # one delay: a filter's group delay
    explained = constant if constant / sigma2 > CONSTANT_SIGNIFICANCE else 0.0
    tones, phases = [], []
    nfft = _fast_length(PADDING * cells)
    freq = np.fft.rfftfreq(nfft, dt)
    for _ in range(max_tones):
        series.fix(_rows(tt, tones, harmonics, phases))
        x = np.zeros(cells)
        x[slot] = series.remainder()
        allowed = freq > 2.0 / (cells * dt)                             # at least two periods in the log
        for f, p in zip(tones, phases):          # not a harmonic of a tone found (a sawtooth has them all)
            for h in range(1, (harmonics if np.isnan(p) else int(0.5 / (f * dt))) + 1):
                allowed &= np.abs(freq - h * f) > 2.0 / (cells * dt)
        peak = _peak(np.abs(np.fft.rfft(x, nfft)) ** 2, freq, allowed)
        if peak is None:
            break
        best, gain = _scan(lambda f: series.gain(_tone_rows(tt, f, harmonics)), peak, SCAN_CELLS / (cells * dt))
        if (gain - explained) / sigma2 < SIGNIFICANCE * (1 + 2 * harmonics + 2.0 * np.log(n_freq)):
            break
        tones.append(best)
        phases.append(np.nan)
        explained = gain
        if not sawtooth:
            continue
        f, phase, saw = _sawtooth(tt, ru, uu, tones, harmonics, phases, len(tones) - 1, 1.0 / (cells * dt))
        if saw >= explained:          # the sawtooth itself: one coefficient explains at least the harmonics' share
            tones[-1], phases[-1], explained = f, phase, saw
    if not tones and not explained:
        return NONE
    c, explained, energy = _fit_high_passed(t, raw, u, ok, window, tones, harmonics, phases)
    if explained < MIN_EXPLAINED * energy:                              # significant, but too small to matter
        return NONE
    delay = _design(tt, tones, harmonics, phases) @ c
    return TimingModel(tuple(tones), c, harmonics, explained / energy, float(delay.std()),
                       tuple(phases) if not np.isnan(phases).all() else ())


# ---------------------------------------------------------------------------------------- N gyros: one delay per chip
@dataclass(frozen=True)
class ArrayTimingModel:
    """Every chip's delay against the read-out in an array of N gyros (:func:`estimate_array_timing`).

    Gyro ``j``'s samples lag the reference's by ``delta_j(t) = d_j(t) - d_ref(t)``: the difference of two chips'
    delays, each following its own clock's beat tone. Only the differences are observed, so the reference's delay
    has no constant (its mean is the zero of every other chip's).

    Attributes
    ----------
    reference : int
        Index of the reference gyro.
    tones_hz : tuple of tuple of float (N,)
        The beat tones of every chip's own delay (Hz; cycles per sample without timestamps); the reference's is
        found in all pairs at once, every other chip's in its pair with the reference. Empty where none is
        significant.
    coefficients : tuple of ndarray (N,)
        Every chip's delay, ``[mean, per tone (cos, sin) per harmonic or one sawtooth amplitude]`` (s; samples
        without timestamps); the reference's mean is 0. A chip without a delay has all zeros.
    harmonics : int
    relative : tuple of TimingModel (N,)
        Every gyro's delay against the reference (``d_j - d_ref``) as the pair's :class:`TimingModel` (its own
        tones first, then the reference's), with the fraction of its pair's residual energy that it explains;
        :data:`NONE` for the reference and where the delay explains less than :data:`MIN_EXPLAINED` or nothing
        significant was found.
    phases : tuple of tuple of float (N,)
        Per chip, per tone, the phase of the sawtooth it was fitted as (NaN: by its harmonics), as
        :attr:`TimingModel.phases`; empty: every tone by its harmonics.
    """

    reference: int
    tones_hz: tuple
    coefficients: tuple
    harmonics: int
    relative: tuple
    phases: tuple = ()

    @property
    def significant(self) -> bool:
        return any(m.significant for m in self.relative)

    def delay(self, k: int, t) -> np.ndarray:
        """Chip ``k``'s own delay against the read-out at the instants ``t`` (the reference's mean taken as 0)."""
        phases = self.phases[k] if self.phases else ()
        return self.coefficients[k] @ _rows(np.asarray(t, dtype=float), self.tones_hz[k], self.harmonics, phases)

    def compensate(self, j: int, t, omega_j):
        """Gyro ``j``'s rates moved to the instants the reference's describe (:meth:`TimingModel.compensate` of
        ``relative[j]``) and that delay at ``t``: ``(rates, delay)``."""
        delay = self.relative[j].delay(t)
        return _moved(t, np.asarray(omega_j, dtype=float), delay), delay


def _rows(t, tones, harmonics, phases=()) -> np.ndarray:
    """The delay's design as rows (a row per column of :func:`_design`), its tones by :func:`_tone_rows`, or by
    :func:`_saw_row` where ``phases`` gives the tone a sawtooth's phase (not NaN)."""
    phases = tuple(phases) + (np.nan,) * (len(tones) - len(phases))
    return np.vstack([np.ones((1, len(t)))] + [_tone_rows(t, f, harmonics) if np.isnan(p) else _saw_row(t, f, p)
                                               for f, p in zip(tones, phases)])


def _saw_row(t, f: float, phase: float) -> np.ndarray:
    """A sawtooth of frequency ``f`` and ``phase`` (cycles), zero-mean over a period: ``frac(f t + phase) - 1/2``
    as one row."""
    x = f * t + phase
    return (x - np.floor(x) - 0.5)[None, :]


#: Phases of a tone's sawtooth tried (cycles) at the tone's frequency; then a pattern search of frequency and phase
#: from steps of a quarter resolution cell and one phase step, halved this many times (the jumps make the fit
#: sensitive to both: a frequency off by a tenth of a cell moves the last jump by a twentieth of a period).
SAW_PHASES, SAW_LEVELS = 32, 7


def _sawtooth(t, ru, uu, tones, harmonics, phases, i: int, cell_hz: float):
    """Tone ``i`` of ``tones`` fitted as a sawtooth (the others as they are): ``(frequency, phase, explained)``
    of the best of a scan of phases at its frequency, refined by a pattern search of frequency and phase (the
    phase measured at the middle of ``t``, so that a change of frequency leaves the phase there in place).
    ``cell_hz``: the resolution cell (1 / the log's duration). The other tones' columns are fixed once
    (:class:`_PairSeries`): each trial adds one column."""
    mid = 0.5 * (t[0] + t[-1])
    fixed = _PairSeries(ru, uu, 0.0, 1.0)
    fixed.fix(_rows(t, tones[:i] + tones[i + 1:], harmonics, phases[:i] + phases[i + 1:]))

    def explained(f, mid_phase):
        return fixed.gain(_saw_row(t, f, (mid_phase - f * mid) % 1.0))

    f0 = tones[i]
    grid = np.arange(SAW_PHASES) / SAW_PHASES
    gains = [explained(f0, p) for p in grid]
    best = (max(gains), f0, float(grid[int(np.argmax(gains))]))
    df, dp = 0.25 * cell_hz, 1.0 / SAW_PHASES
    for _ in range(SAW_LEVELS):
        centre = best
        for a in (-1.0, 0.0, 1.0):
            for b in (-1.0, 0.0, 1.0):
                if a or b:
                    f, p = centre[1] + a * df, (centre[2] + b * dp) % 1.0
                    gain = explained(f, p)
                    if gain > best[0]:
                        best = (gain, float(f), float(p))
        df, dp = df / 2.0, dp / 2.0
    gain, f, mid_phase = best
    return f, (mid_phase - f * mid) % 1.0, gain


def _tone_rows(t, f: float, harmonics: int) -> np.ndarray:
    """The columns one tone adds to :func:`_design` (``cos, sin`` per harmonic), as rows (2 x harmonics, samples):
    the harmonics by the angle-addition recurrence from one cosine and one sine."""
    rows = np.empty((2 * harmonics, len(t)))
    phase = (2.0 * np.pi * f) * t
    c1, s1 = np.cos(phase), np.sin(phase)
    rows[0], rows[1] = c1, s1
    for h in range(1, harmonics):
        c, s = rows[2 * h - 2], rows[2 * h - 1]
        rows[2 * h] = c * c1 - s * s1
        rows[2 * h + 1] = s * c1 + c * s1
    return rows


class _PairSeries:
    """One pair's residual along the rate's derivative (``ru``, ``uu`` of :func:`estimate_timing`) and the Gram
    matrix of a fixed design, to which a scanned tone's columns are added cheaply."""

    def __init__(self, ru, uu, energy: float, sigma2: float):
        self.ru, self.uu, self.energy, self.sigma2 = ru, uu, energy, sigma2
        self.fix(np.ones((1, len(ru))))

    def fix(self, X):
        """Make ``X`` (p x samples: the design's columns as rows) the fixed design: its Gram matrix and the
        energy it explains."""
        self.X, self.WX = X, X * self.uu
        self.G, self.h = self.WX @ X.T, X @ self.ru
        self.c = np.linalg.lstsq(self.G, self.h, rcond=None)[0]
        self.explained = float(self.h @ self.c)

    def gain(self, C) -> float:
        """Energy explained by the fixed design and the rows ``C`` together."""
        p = len(self.G)
        G = np.empty((p + len(C), p + len(C)))
        G[:p, :p], G[:p, p:] = self.G, self.WX @ C.T
        G[p:, :p], G[p:, p:] = G[:p, p:].T, (C * self.uu) @ C.T
        h = np.concatenate([self.h, C @ self.ru])
        return float(h @ np.linalg.lstsq(G, h, rcond=None)[0])

    def remainder(self):
        """``ru`` less the fixed design's fit."""
        return self.ru - self.c @ self.WX


def _peak(power, freq, allowed):
    """The strongest allowed bin of ``power`` when it is a spectral line (:func:`_is_line`), else None."""
    if not allowed.any():
        return None
    i = int(np.flatnonzero(allowed)[np.argmax(power[allowed])])
    return float(freq[i]) if _is_line(power, i) else None


def _scan(score, peak: float, span: float):
    """The frequency near ``peak`` (within ``span``) where ``score`` is largest: :data:`SCAN_POINTS` points, then
    the vertex of the parabola through the best and its neighbours. ``(frequency, score)``."""
    grid = np.linspace(peak - span, peak + span, SCAN_POINTS)
    values = np.array([score(f) for f in grid])
    i = int(np.argmax(values))
    best, top = float(grid[i]), float(values[i])
    if 0 < i < SCAN_POINTS - 1:
        left, mid, right = values[i - 1:i + 2]
        curvature = left - 2.0 * mid + right
        if curvature < 0:
            f = best + 0.5 * (grid[1] - grid[0]) * (left - right) / curvature
            s = score(f)
            if s > top:
                best, top = float(f), s
    return best, top


def estimate_array_timing(t, omegas, maps, biases, mask=None, *, reference: int = 0, harmonics: int = HARMONICS,
                          max_samples: int = MAX_SAMPLES) -> ArrayTimingModel:
    """Every chip's delay against the read-out that the residuals of an array's pairs with its reference show.

    Gyro ``j``'s pair residual ``r_j = omega_ref - A_j omega_j - b_j`` lies along ``u_j = A_j d(omega_j)/dt``
    times ``d_j(t) - d_ref(t)`` (first order in the delays, as :func:`estimate_timing`). The reference's beat tone
    is in every pair: it is searched once, in the geometric mean of the pairs' periodograms of ``r_j . u_j`` (a line
    there is a line in every pair; a chip's own tone, in one pair only, is not), refined on the pairs' summed
    explained energy (each over its residual's variance along ``u``), and kept when that sum exceeds what noise
    would give over a search of every frequency. Every other chip's tone is searched once, in its pair's residual
    with the reference's tone fitted (the same line and significance tests as :func:`estimate_timing`; a constant
    delay alone when it explains far more than noise would), and kept as one sawtooth (:func:`_sawtooth`) where that
    explains at least what its harmonics do in its pair. Then one weighted least-squares fit over all pairs
    gives every chip's delay (the reference's shared by all pairs), so the pair ``(i, j)``'s delay is ``d_j - d_i``
    with the reference's part cancelled. With two gyros there is one pair and no telling the chips apart: both
    tones go to gyro ``j`` (then this is :func:`estimate_timing` without its first, cheap look).

    Parameters
    ----------
    t : array_like (N,)
        The samples' instants on one uniform grid (s), or the sample index for input without timestamps.
    omegas : sequence of array_like (N, 3)
        Sample-aligned rates of every gyro (rad/s).
    maps, biases : sequences (per gyro) of the calibration's map and combined bias of every gyro against the
        reference (``omega_ref ~ A_j omega_j + b_j``; the reference's entries are not read).
    mask : array_like of bool (N,), optional
        Samples to use (the derivative is one-sided beside an invalid one).
    reference : int
        Index of the reference gyro.

    Returns
    -------
    ArrayTimingModel
    """
    rates = [np.asarray(w, dtype=float) for w in omegas]
    n_g, n = len(rates), len(rates[0])
    others = [j for j in range(n_g) if j != reference]
    t = np.arange(n, dtype=float) if t is None else np.asarray(t, dtype=float)
    ok = np.ones(n, bool) if mask is None else np.asarray(mask, bool).copy()
    if n > max_samples:          # the most excited stretch of a long log (the tones are stationary)
        start = _excited_stretch(rates[reference], ok, max_samples)
        part = slice(start, start + max_samples)
        t, ok, rates = t[part], ok[part], [w[part] for w in rates]
    for w in rates:
        ok &= np.all(np.isfinite(w), axis=1)
    nothing = ArrayTimingModel(reference, ((),) * n_g, (np.zeros(1),) * n_g, harmonics, (NONE,) * n_g)
    max_own = MAX_TONES - 1 if len(others) > 1 else MAX_TONES     # one tone per chip; one pair: both to gyro j
    if np.count_nonzero(ok) < 100 * (1 + 2 * harmonics * MAX_TONES):
        return nothing
    dt = float(median(np.diff(t)))
    window = max(int(round(1.0 / dt)), 3) if dt < 1.0 else 64   # about a second (64 samples without timestamps)
    tt = t[ok]
    slot = np.round((tt - tt[0]) / dt).astype(np.int64)          # each sample's place on a uniform grid
    cells = int(slot[-1]) + 1
    if cells > 4 * len(t):
        return nothing
    n_freq = cells / 2.0
    nfft = _fast_length(PADDING * cells)
    freq = np.fft.rfftfreq(nfft, dt)
    apart = 2.0 / (cells * dt)                                   # at least two periods in the log; tones apart
    span = SCAN_CELLS / (cells * dt)
    search = SIGNIFICANCE * (1 + 2 * harmonics + 2.0 * np.log(n_freq))

    series = {}
    for j in others:
        A = np.asarray(maps[j], dtype=float)
        u = derivative(t, rates[j]) @ A.T
        raw = rates[reference] - rates[j] @ A.T - np.asarray(biases[j], dtype=float)
        r = _high_pass(raw, ok, window)
        ru, uu = np.einsum("ij,ij->i", r, u)[ok], np.einsum("ij,ij->i", u, u)[ok]
        energy = float(np.einsum("ij,ij->", r[ok], r[ok]))
        keep = uu > 0
        if keep.any() and energy > 0:
            series[j] = _PairSeries(ru, uu, energy, float(median(ru[keep] ** 2 / uu[keep])) / 0.455)
            series[j].raw, series[j].u = raw, u      # for the final fit (:func:`_high_passed_gram`)
    if not series:
        return nothing

    def power(x):
        grid = np.zeros(cells)
        grid[slot] = x
        return np.abs(np.fft.rfft(grid, nfft)) ** 2

    def allowed_for(tones):
        allowed = freq > apart
        for f in tones:                                          # not a harmonic of a tone found
            for h in range(1, harmonics + 1):
                allowed &= np.abs(freq - h * f) > apart
        return allowed

    ref_tones = []
    if len(series) > 1:           # the reference's tone: a line in every pair's periodogram
        logs = np.mean([np.log(power(s.ru) + 1e-300) for s in series.values()], axis=0)
        peak = _peak(np.exp(logs - logs.max()), freq, allowed_for([]))
        if peak is not None:
            base = sum(s.explained / s.sigma2 for s in series.values())
            f, total = _scan(lambda f: sum(s.gain(_tone_rows(tt, f, harmonics)) / s.sigma2
                                           for s in series.values()), peak, span)
            if total - base > SIGNIFICANCE * (len(series) * (1 + 2 * harmonics) + 2.0 * np.log(n_freq)):
                ref_tones.append(f)
    ref_cols = [_tone_rows(tt, f, harmonics) for f in ref_tones]

    own, own_phases, constant = {}, {}, {}
    for j, s in series.items():   # every other chip's tone, in its pair with the reference's tone fitted
        s.fix(np.vstack([np.ones((1, len(tt)))] + ref_cols))
        explained = s.explained
        constant[j] = bool(ref_tones) or s.explained / s.sigma2 > CONSTANT_SIGNIFICANCE
        tones = []
        for _ in range(max_own):
            peak = _peak(power(s.remainder()), freq, allowed_for(ref_tones + tones))
            if peak is None:
                break
            f, gain = _scan(lambda f: s.gain(_tone_rows(tt, f, harmonics)), peak, span)
            if (gain - (explained if (tones or constant[j]) else 0.0)) / s.sigma2 < search:
                break
            tones.append(f)
            explained = gain
            if len(tones) < max_own:          # another tone to search: this one becomes part of the fixed design
                s.fix(np.vstack([s.X, _tone_rows(tt, f, harmonics)]))
        own[j], own_phases[j] = tones, [np.nan] * len(tones)
        for i in range(len(tones)):       # a chip's own tone as one sawtooth where that explains at least its harmonics
            both, phases = tones + ref_tones, own_phases[j] + [np.nan] * len(ref_tones)
            by_harmonics = _PairSeries(s.ru, s.uu, s.energy, s.sigma2)
            by_harmonics.fix(_rows(tt, both, harmonics, phases))
            f, phase, saw = _sawtooth(tt, s.ru, s.uu, both, harmonics, phases, i, 1.0 / (cells * dt))
            if saw >= by_harmonics.explained:
                tones[i], own_phases[j][i] = f, phase
        if tones:
            constant[j] = True

    # one weighted least-squares fit of every chip's delay: [reference's tone coefficients, per gyro: mean, tones]
    n_ref = 2 * harmonics * len(ref_tones)
    offset, columns = {}, n_ref
    width = {j: 1 + sum(2 * harmonics if np.isnan(p) else 1 for p in own_phases[j]) for j in series}
    for j in series:
        if constant[j]:
            offset[j] = columns
            columns += width[j]
    if not offset:
        return nothing
    G, h = np.zeros((columns, columns)), np.zeros(columns)
    grams = {}
    for j, c0 in offset.items():
        s = series[j]
        X = np.vstack([_rows(t, own[j], harmonics, own_phases[j])] + [_tone_rows(t, f, harmonics) for f in ref_tones])
        weighted, along, s.energy = _high_passed_gram(X.T, s.raw, s.u, ok, window)
        grams[j] = weighted, along, X[:, ok] @ X[:, ok].T / len(tt)      # weighted, against r, plain
        idx = np.r_[c0:c0 + len(X) - n_ref, 0:n_ref]
        sign = np.r_[np.ones(len(X) - n_ref), -np.ones(n_ref)]        # d_j - d_ref
        G[np.ix_(idx, idx)] += sign[:, None] * grams[j][0] * sign[None, :] / s.sigma2
        h[idx] += sign * grams[j][1] / s.sigma2
    c = np.linalg.lstsq(G, h, rcond=None)[0]
    ref_c = c[:n_ref]
    coefficients, relative = [np.zeros(1)] * n_g, [NONE] * n_g
    coefficients[reference] = np.r_[0.0, ref_c]
    for j, c0 in offset.items():
        s = series[j]
        chip = c[c0:c0 + width[j]]
        coefficients[j] = chip
        rel = np.r_[chip, -ref_c]
        weighted, along, plain = grams[j]
        explained = float(2.0 * rel @ along - rel @ weighted @ rel)      # the energy removed from the residual
        if explained >= MIN_EXPLAINED * s.energy:
            std = np.sqrt(max(float(rel @ plain @ rel) - float(plain[0] @ rel) ** 2, 0.0))
            phases = tuple(own_phases[j]) + (np.nan,) * len(ref_tones)
            relative[j] = TimingModel(tuple(own[j]) + tuple(ref_tones), rel, harmonics, explained / s.energy, std,
                                      phases if not np.isnan(phases).all() else ())
    tones = [tuple(own.get(j, ())) for j in range(n_g)]
    tones[reference] = tuple(ref_tones)
    chip_phases = [tuple(own_phases.get(j, ())) for j in range(n_g)]
    chip_phases[reference] = (np.nan,) * len(ref_tones)
    return ArrayTimingModel(reference, tuple(tones), tuple(coefficients), harmonics, tuple(relative),
                            tuple(chip_phases) if not all(np.isnan(p).all() for p in chip_phases if p) else ())


def _fast_length(n: int) -> int:
    """A length at least ``n`` whose FFT is fast (few small prime factors)."""
    from scipy.fft import next_fast_len

    return int(next_fast_len(int(n), real=True))
