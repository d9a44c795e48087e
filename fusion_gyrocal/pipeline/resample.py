"""Cubic-spline resampling per contiguous run of valid samples, never across a gap, with an anti-alias
filter when the new instants are much sparser than the samples.

The paper (footnote in Section III) notes that resampling "can be done via cubic-spline
interpolation"; :func:`resample` does it on plain arrays with a validity mask. A stream resampled onto
instants :data:`DECIMATE_RATIO` or more times sparser than its own samples is first low-pass filtered
(:func:`_antialiased`), so its white noise above the new Nyquist frequency is averaged away instead of folded
back onto the motion band.
"""

from __future__ import annotations

import numpy as np

from ..core.moments import median
from ..errors import InputError, OptionError
from .streams import DEFAULT_GAP_PERIODS, _nominal_period, _stream, timed_stream

_GRID_BLOCK = 1 << 16          # grid points per block of a long resampling
_LOCATE_STEPS = 8              # most knot steps from a hint (:meth:`_RunSplines.locate`) before a search
_MARGIN = 40                   # source samples beyond a block's reach: the splines' end conditions act
                               # on a knot k samples away as (2 - sqrt 3)^k, 0.268^40 ~ 1e-23
#: Instants at least this many times sparser than a stream's samples get the samples low-pass filtered first
#: (:func:`_antialiased`); below it the spline alone resamples (the noise that folds back is in
#: :func:`noise_factors`' ``density``).
DECIMATE_RATIO = 4.0
_MAX_SOURCE = 1 << 20          # most source samples behind noise_factors' measurement of a downsampling
_PASS, _STOP = 0.4, 0.5        # the filter's passband and stopband edges, in units of the instants' rate
_ATTENUATION_DB = 100.0        # stopband attenuation and passband ripple (1e-5) of the Kaiser-window design


# ---------------------------------------------------------------------------------------------- resampling
def _runs(t: np.ndarray, valid: np.ndarray, max_gap_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``(first, stop)``: each contiguous run (>= 2 samples) of valid samples without a gap is the range of samples
    ``first[k]:stop[k]`` (found in a few array passes, however many runs a masked record has)."""
    if valid.all():                  # the usual case: the runs are cut by the gaps alone (no index array to gather)
        if t.size < 2:
            return np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp)
        cut = np.flatnonzero(np.diff(t) > max_gap_s) + 1
        a, b = np.r_[0, cut], np.r_[cut, t.size]
        long = b - a >= 2
        return a[long], b[long]
    idx = np.flatnonzero(valid)
    if idx.size < 2:
        return np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp)
    brk = (np.diff(idx) > 1) | (np.diff(t[idx]) > max_gap_s)
    cut = np.flatnonzero(brk) + 1
    a, b = np.r_[0, cut], np.r_[cut, idx.size]
    long = b - a >= 2
    return idx[a[long]], idx[b[long] - 1] + 1


def _ranges(starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """The integers of the ranges ``[starts_i, stops_i)`` (each non-empty), one after the other."""
    n = stops - starts
    return np.repeat(starts - np.cumsum(n) + n, n) + np.arange(int(n.sum()))


def _spline_slopes(x: np.ndarray, dx: np.ndarray, slope: np.ndarray, first: np.ndarray,
                   last: np.ndarray) -> np.ndarray:
    """Knot slopes ``(k, m)`` of the not-a-knot cubic spline of each run ``first[j]..last[j]`` of the knots ``x``
    (``(m,)``, steps ``dx``) through values whose chord slopes are ``slope`` (``(k, m - 1)``).

    The same equations as scipy's ``CubicSpline`` (tridiagonal continuity of the second
    derivative, not-a-knot end rows in their tridiagonal form), with no coupling between runs, solved by
    ``scipy.linalg.solve_banded`` (imported here: off the command line's start-up). The right-hand sides are laid
    out one value channel per row, which is the column-major ``(m, k)`` block LAPACK solves in place (no copy in,
    none out) and the layout :func:`_hermite_coefficients` reads.
    """
    from scipy.linalg import solve_banded

    m = x.size
    ab = np.zeros((3, m))  # banded storage: ab[1 + i - j, j] = a[i, j]
    rhs = np.zeros((slope.shape[0], m))
    ab[1, 1:-1] = 2.0 * (dx[:-1] + dx[1:])
    ab[0, 2:] = dx[:-1]
    ab[2, :-2] = dx[1:]
    inner = rhs[:, 1:-1]                   # 3 (dx[1:] slope[:, :-1] + dx[:-1] slope[:, 1:]), in place
    np.multiply(dx[1:], slope[:, :-1], out=inner)
    inner += dx[:-1] * slope[:, 1:]
    inner *= 3.0
    n = last - first + 1
    # cut the coupling between consecutive runs
    ab[2, first[first > 0] - 1] = 0.0
    ab[0, last[last < m - 1] + 1] = 0.0
    big = n >= 4
    i0, i1 = first[big], last[big]
    d0 = x[i0 + 2] - x[i0]
    ab[1, i0] = dx[i0 + 1]
    ab[0, i0 + 1] = d0
    rhs[:, i0] = ((dx[i0] + 2.0 * d0) * dx[i0 + 1] * slope[:, i0] + dx[i0] ** 2 * slope[:, i0 + 1]) / d0
    d1 = x[i1] - x[i1 - 2]
    ab[1, i1] = dx[i1 - 2]
    ab[2, i1 - 1] = d1
    rhs[:, i1] = (dx[i1 - 1] ** 2 * slope[:, i1 - 2] + (2.0 * d1 + dx[i1 - 1]) * dx[i1 - 2] * slope[:, i1 - 1]) / d1
    # short runs: explicit slopes (two samples: the line; three: the parabola through them)
    fixed, values = [], []
    for k in np.flatnonzero(~big):
        j = first[k]
        if n[k] == 2:
            fixed += [j, j + 1]
            values += [slope[:, j], slope[:, j]]
        else:
            c = (slope[:, j + 1] - slope[:, j]) / (dx[j] + dx[j + 1])
            fixed += [j, j + 1, j + 2]
            values += [slope[:, j] - dx[j] * c, slope[:, j] + dx[j] * c, slope[:, j + 1] + dx[j + 1] * c]
    if fixed:
        fixed = np.asarray(fixed)
        ab[1, fixed] = 1.0
        ab[0, fixed[fixed < m - 1] + 1] = 0.0
        ab[2, fixed[fixed > 0] - 1] = 0.0
        rhs[:, fixed] = np.asarray(values).T
    return solve_banded((1, 1), ab, rhs.T, overwrite_ab=True, overwrite_b=True, check_finite=False).T


def _hermite_coefficients(y: np.ndarray, s: np.ndarray, dx: np.ndarray, slope: np.ndarray) -> np.ndarray:
    """Coefficients ``(4, k, m - 1)`` of the piecewise cubic through the values ``y`` (``(k, m)``, one channel per
    row) at knots ``dx`` apart with knot slopes ``s`` (``(k, m)``) and chord slopes ``slope`` (``(k, m - 1)``).

    On ``[x_i, x_{i+1}]``: ``y = ((c0 d + c1) d + c2) d + c3`` with ``d = x - x_i`` (the cubic Hermite
    interpolant, as scipy's ``CubicHermiteSpline``). Laid out interval-last, so an evaluation gathers
    all ``4 k`` coefficients of its intervals with one ``take`` of 8-byte items.
    """
    c = np.empty((4,) + y.shape[:1] + (dx.size,))
    t = np.add(s[:, :-1], s[:, 1:], out=c[1])
    t -= 2.0 * slope
    t /= dx                                  # c[1] holds t for now
    np.divide(t, dx, out=c[0])
    np.subtract(slope, s[:, :-1], out=c[2])
    c[2] /= dx
    np.subtract(c[2], t, out=c[1])
    c[2] = s[:, :-1]
    c[3] = y[:, :-1]
    return c


class _RunSplines:
    """Cubic splines of ``y(t)`` over each contiguous run of valid samples (no gap, no masked sample).

    Every run gets the not-a-knot cubic spline that scipy's ``CubicSpline`` would fit (a run of
    two samples: a line, of three: a parabola). All runs are solved together as one block-
    tridiagonal system for the knot slopes (one banded solve, however many runs a masked
    record has) and packed into one piecewise cubic (:func:`_hermite_coefficients`, evaluated by
    Horner's rule in numpy); the interval between two runs holds a Hermite bridge that is masked on
    evaluation (values and first derivatives at the run ends are exact).
    """

    def __init__(self, t: np.ndarray, y: np.ndarray, valid: np.ndarray, max_gap_s: float):
        self.width = y.shape[1:]
        self.starts, self.ends, self.knots, self.coef = np.empty(0), np.empty(0), None, None
        run_first, run_stop = _runs(t, valid, max_gap_s)
        if not run_first.size:
            return
        if run_first.size == 1:              # one run: a slice of the samples (no gather)
            a, b = int(run_first[0]), int(run_stop[0])
            x, Y = t[a:b], y[a:b].reshape(b - a, -1)
        else:
            sel = _ranges(run_first, run_stop)
            x, Y = t[sel], y[sel].reshape(sel.size, -1)
        lens = run_stop - run_first
        first = np.r_[0, np.cumsum(lens)[:-1]]
        last = first + lens - 1
        self.starts, self.ends = x[first], x[last]
        self.knots = x
        Yt = np.ascontiguousarray(Y.T)       # one channel per row: each pass below runs along a row
        dx = np.diff(x)
        slope = np.diff(Yt, axis=1)
        slope /= dx
        self.coef = _hermite_coefficients(Yt, _spline_slopes(x, dx, slope, first, last), dx, slope)

    def run_of(self, x: np.ndarray) -> np.ndarray:
        """Index of the run containing each query time, -1 outside every run."""
        if self.coef is None:
            return np.full(x.shape, -1)
        r = np.searchsorted(self.starts, x, side="right") - 1
        inside = (r >= 0) & (x <= self.ends[np.clip(r, 0, None)])
        return np.where(inside, r, -1)

    def locate(self, x: np.ndarray, hint: np.ndarray | None = None) -> np.ndarray:
        """The interval of each instant of ``x`` (1-D): ``searchsorted(knots, x, side="right") - 1``, clipped to the
        intervals.

        ``hint``: the intervals of instants near these (finite ``x`` shifted by a few knot steps at most, e.g. the
        same instants at another trial offset); the exact ones are then found by stepping from them (a few array
        passes instead of a binary search per instant), or by the search where that does not settle.
        """
        last = self.knots.size - 2
        if hint is not None and hint.shape == x.shape:
            k, i = self.knots, hint.astype(np.intp)     # a copy
            for _ in range(_LOCATE_STEPS):
                down = k.take(i) > x                     # the interval starts after x
                down &= i > 0
                up = k.take(i + 1) <= x                  # the next one starts at or before x
                up &= i < last
                if not (down.any() or up.any()):
                    return i
                i -= down
                i += up
        i = np.searchsorted(self.knots, x, side="right") - 1
        np.clip(i, 0, last, out=i)
        return i

    def _gather(self, x: np.ndarray, at: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(d, c)``: the offsets of ``x`` (1-D, inside the knots' span) from their intervals' first knots and
        those intervals' coefficients ``(4, k, len(x))`` (``at``: the intervals, :meth:`locate`, when known)."""
        i = self.locate(x) if at is None else at
        d = x - self.knots.take(i)
        k = self.coef.shape[1]
        return d, self.coef.reshape(4 * k, -1).take(i, axis=1).reshape(4, k, -1)

    def _eval(self, x: np.ndarray, nu: int, at: np.ndarray | None = None) -> np.ndarray:
        """Values (``nu`` = 0) or first derivatives (``nu`` = 1) at ``x`` (1-D, inside the knots' span)."""
        return self._horner(*self._gather(x, at), nu)

    def values_and_slopes(self, x: np.ndarray, at: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Values and first derivatives at ``x`` (1-D, every instant inside a run: ``run_of(x) >= 0``), from one
        lookup of the instants' intervals (``at``: those intervals, :meth:`locate`, when known); each equals
        ``self(x, nu)[0]``."""
        d, c = self._gather(x, at)
        return tuple(self._horner(d, c, nu).reshape(x.shape + self.width) for nu in (0, 1))

    @staticmethod
    def _horner(d: np.ndarray, c: np.ndarray, nu: int) -> np.ndarray:
        """The cubics ``c`` (:meth:`_gather`) or their derivatives (``nu`` = 1) at the offsets ``d``, ``(len(d), k)``."""
        if nu == 0:
            out = c[0] * d
            out += c[1]
        elif nu == 1:
            out = (3.0 * d) * c[0]
            out += 2.0 * c[1]
        else:
            raise OptionError(f"nu: expected 0 (values) or 1 (first derivatives), got {nu!r}")
        out *= d
        if nu == 0:
            out += c[2]
            out *= d
        rows = np.empty(out.shape[::-1])          # one row per instant: the last term added into it (no copy after)
        np.add(out, c[3] if nu == 0 else c[2], out=rows.T)
        return rows

    def __call__(self, x: np.ndarray, nu: int = 0, inside: np.ndarray | None = None, at: np.ndarray | None = None):
        """Values (or ``nu``-th derivatives, ``nu`` <= 1) at ``x``, NaN outside the runs; returns (values, inside)
        (``at``: the intervals of ``x``, :meth:`locate`, used where every instant is inside)."""
        if inside is None:
            inside = self.run_of(x) >= 0
        if inside.all():
            return self._eval(x, nu, at).reshape(x.shape + self.width), inside
        out = np.full(x.shape + self.width, np.nan)
        if inside.any():
            out[inside] = self._eval(x[inside], nu).reshape((-1,) + self.width)
        return out, inside


def resample(t_src, omega_src, t_grid, *, valid=None, max_gap_s: float | None = None):
    """Resample rates onto new instants with cubic splines, never bridging gaps or masked samples.

    A not-a-knot cubic spline (the one scipy's ``CubicSpline`` fits) is fitted to each contiguous run of
    valid samples; a run ends at a masked or non-finite sample or at a step longer than
    ``max_gap_s``. Grid points outside every run are invalid. Instants :data:`DECIMATE_RATIO` or more times
    sparser than the samples (median spacings) get the samples low-pass filtered first (:func:`_antialiased`:
    flat to 0.4 times the instants' rate, 100 dB down from their Nyquist frequency).

    Parameters
    ----------
    t_src : array_like, shape (N,)
        Source timestamps (s), strictly increasing.
    omega_src : array_like, shape (N, 3)
        Source rates (rad/s).
    t_grid : array_like, shape (M,)
        Instants to evaluate at, on the same clock as ``t_src`` (any order).
    valid : array_like of bool, shape (N,), optional
        Source samples that may be used (non-finite samples are always excluded).
    max_gap_s : float, optional
        Longest step bridged (default: 2.5 nominal sample periods, the median step).

    Returns
    -------
    omega : ndarray, shape (M, 3)
        Rates at ``t_grid``; NaN where invalid.
    valid : ndarray of bool, shape (M,)
        True where ``t_grid`` lies inside a run of valid source samples.
    """
    t, w, ok = _stream("t_src", t_src, "omega_src", omega_src, valid)
    grid = np.asarray(t_grid, dtype=np.float64)
    if grid.ndim != 1:
        raise InputError(f"t_grid: expected a 1-D array of instants, got shape {grid.shape}")
    gap = DEFAULT_GAP_PERIODS * _nominal_period(t) if max_gap_s is None else float(max_gap_s)
    if not gap > 0:
        raise OptionError(f"max_gap_s: expected a positive duration, got {max_gap_s!r}")
    return _resample_checked(t, w, ok, grid, gap)


def _query_steps(grid: np.ndarray) -> tuple[float, bool]:
    """``(period, increasing)``: the median spacing (s) of the finite instants of ``grid`` in time order (NaN with
    fewer than two) and whether ``grid`` is finite and strictly increasing.

    One temporary of the steps, partitioned in place at the median (:func:`~fusion_gyrocal.core.moments.median`:
    numpy's value, one partition point); a long grid is not copied (only one with non-finite instants is
    compressed first).
    """
    finite = bool(np.isfinite(grid).all())
    g = grid if finite else grid[np.isfinite(grid)]
    if g.size < 2:
        return float("nan"), finite
    steps = np.diff(g)
    increasing = bool((steps > 0).all())
    if not increasing:
        g = np.unique(g)
        if g.size < 2:
            return float("nan"), False
        steps = np.diff(g)
    return float(median(steps, overwrite_input=True)), finite and increasing


def _lowpass(ratio: float) -> np.ndarray:
    """Taps of :func:`_antialiased`'s filter for instants ``ratio`` times sparser than the samples."""
    from scipy.signal import firwin, kaiserord

    numtaps, beta = kaiserord(_ATTENUATION_DB, 2.0 * (_STOP - _PASS) / ratio)   # width over the source Nyquist
    return firwin(numtaps | 1, (_PASS + _STOP) / ratio, window=("kaiser", beta))


def _antialiased(t: np.ndarray, w: np.ndarray, ok: np.ndarray, gap: float, query_period: float):
    """``(t, w)`` with every run of valid samples low-pass filtered when the instants (spaced ``query_period``)
    are :data:`DECIMATE_RATIO` or more times sparser than the samples; ``(t, w)`` themselves otherwise.

    The filter is a zero-phase (symmetric, odd-length) Kaiser-window FIR with unit gain at 0 Hz, flat to
    1e-5 up to ``0.4 / query_period`` and attenuating 100 dB from the instants' Nyquist frequency
    ``0.5 / query_period``: the motion the sparser instants can carry passes unchanged, the white noise above
    their Nyquist frequency is removed before the spline samples it (so it averages down by about
    ``0.9 f_query / f_src`` in variance rather than folding back). It runs along each run's samples, and on the
    timestamps too, so a jittered sample time moves the filtered value and its time together (exact for a
    rate linear in time). Samples within half the filter's length of a run's end stay as they are (nothing
    is lost at gaps); a run whose filtered timestamps would not increase is left unfiltered.
    """
    period = _nominal_period(t) if t.size > 1 else float("nan")
    ratio = query_period / period if period > 0 else float("nan")
    if not ratio >= DECIMATE_RATIO:
        return t, w
    from scipy.signal import oaconvolve   # off the command line's start-up

    h = _lowpass(ratio)
    numtaps = h.size
    half = numtaps // 2
    t_out, w_out = t.copy(), w.copy()
    for a, b in zip(*(r.tolist() for r in _runs(t, ok, gap))):
        if b - a <= numtaps:
            continue
        tf = t[a] + oaconvolve(t[a:b] - t[a], h, mode="valid")
        edge = np.r_[t[a + half - 1], tf, t[b - half]]
        if not np.all(np.diff(edge) > 0):
            continue
        t_out[a + half:b - half] = tf
        w_out[a + half:b - half] = oaconvolve(w[a:b], h[:, None], mode="valid", axes=0)
    return t_out, w_out


def _resample_checked(t, w, ok, grid, gap: float):
    """:func:`resample` of a checked stream (``_stream``) onto the 1-D float64 ``grid`` with the gap ``gap`` (s)."""
    period, increasing = _query_steps(grid)
    t, w = _antialiased(t, w, ok, gap, period)
    t_ref = t[0]  # splines in relative time: absolute (epoch) seconds lose precision in the cubic terms
    if grid.size <= _GRID_BLOCK or not increasing:
        finite_grid = np.isfinite(grid)
        spl = _RunSplines(t - t_ref, w, ok, gap)
        out, inside = spl(np.where(finite_grid, grid - t_ref, -np.inf))
        inside &= finite_grid
        return out, inside
    # an increasing grid: block by block, each block's splines fitted on the source samples it reaches
    # plus _MARGIN on each side (equal to the whole record's splines to rounding), so memory stays
    # bounded by the block and the output
    out = np.empty((grid.size, 3))
    inside = np.empty(grid.size, dtype=bool)
    for lo in range(0, grid.size, _GRID_BLOCK):
        g = grid[lo:lo + _GRID_BLOCK]
        i0 = max(int(np.searchsorted(t, g[0], side="left")) - _MARGIN, 0)
        i1 = min(int(np.searchsorted(t, g[-1], side="right")) + _MARGIN, t.size)
        spl = _RunSplines(t[i0:i1] - t_ref, w[i0:i1], ok[i0:i1], gap)
        out[lo:lo + g.size], inside[lo:lo + g.size] = spl(g - t_ref)
    return out, inside


def noise_factors(t_src, t_query, *, max_points: int = 1 << 16, block: int = 64,
                  seed: int = 0) -> tuple[float, float, float, int]:
    """What :func:`resample` does to a stream's white noise at the instants ``t_query``:
    ``(variance, diff3, density, white_from)``.

    For unit white noise at the source samples ``t_src``, resampled onto ``t_query``:

    * ``variance``: its variance there (1 where the queries fall on the samples; ~0.75 midway between them);
    * ``diff3``: that of its third differences along the queries over the 20 of white noise (the spline smooths);
    * ``density``: its low-frequency noise density there over the source's ``1 / f_src``, from the spread of
      means over ``block`` queries: 1 when upsampling (interpolation keeps a density), about ``variance f_src /
      f_query`` when downsampling by less than :data:`DECIMATE_RATIO` (the noise above the new Nyquist frequency
      folds down), about 1 again from that ratio on (the anti-alias filter removes it; ``variance`` is then
      about ``0.9 f_query / f_src``).
    * ``white_from``: the number of queries (a power of 2, at most 64) from which its overlapping Allan variance
      is within 5 % of the white line of that density (interpolated noise is smoother over the first few).

    :func:`~fusion_gyrocal.core.noise.identify_noise` uses them to turn what it sees on the grid into each sensor's
    own noise (two-rate pairs, fractional offsets). Measured on seeded white noise over ``max_points``
    consecutive queries from the middle of the record (fewer when downsampling: behind them at most 2^20 source
    samples), ``density`` to ~2 % (~5 % when downsampling 100x), the others to ~0.5 %.
    """
    t = np.asarray(t_src, dtype=np.float64)
    q = np.asarray(t_query, dtype=np.float64)
    if q.size > 1 and np.isfinite(t[0]) and np.isfinite(t[-1]) and bool((q[1:] >= q[:-1]).all()):
        q = q[np.searchsorted(q, t[0], side="left"):np.searchsorted(q, t[-1], side="right")]   # in order: a view
    else:
        q = q[(q >= t[0]) & (q <= t[-1])]
    if q.size < 4 * block or t.size < 16:
        return 1.0, 1.0, 1.0, 1
    mid = q.size // 2
    period = _nominal_period(t)
    ratio = _query_steps(q)[0] / period if period > 0 else float("nan")
    if not np.isfinite(ratio):
        ratio = 1.0
    if ratio > 1.0:       # queries sparser than the samples: at most _MAX_SOURCE samples of noise behind them
        max_points = max(min(max_points, int(_MAX_SOURCE / ratio)), 16 * block)
    q = q[max(mid - max_points // 2, 0):mid + max_points // 2]
    reach = _MARGIN + (_lowpass(ratio).size // 2 if ratio >= DECIMATE_RATIO else 0)   # the filter's too
    i0 = max(int(np.searchsorted(t, q[0])) - reach, 0)
    i1 = min(int(np.searchsorted(t, q[-1])) + reach, t.size)
    noise = np.random.default_rng(seed).standard_normal((i1 - i0, 3))
    ts = timed_stream("t_src", t[i0:i1], "noise", noise, None)[0]   # repaired as the alignment repairs them
    # resample(ts, noise, q) without checking ts a second time (the noise is finite: every sample valid)
    out, inside = _resample_checked(ts, noise, np.ones(noise.shape[0], dtype=bool), q,
                                    DEFAULT_GAP_PERIODS * _nominal_period(ts))
    if not inside.all():        # a gap: the consecutive stretch before it
        stop = int(np.argmin(inside)) if inside[0] else 0
        out, q = out[:stop], q[:stop]
    if out.shape[0] < 4 * block:
        return 1.0, 1.0, 1.0, 1
    var0 = float(np.mean(noise * noise))
    d3 = (out[3:] - out[:-3]) - 3.0 * (out[2:-1] - out[1:-2])
    src = (noise[3:] - noise[:-3]) - 3.0 * (noise[2:-1] - noise[1:-2])
    k = out.shape[0] // block
    means = out[:k * block].reshape(k, block, 3).mean(axis=1)
    span = (q[k * block - 1] - q[0]) * block / (k * block - 1)          # duration of a block (s)
    f_src = (i1 - i0 - 1) / (t[i1 - 1] - t[i0])        # the source's rate over the stretch used
    density = float(np.mean(means * means) * span * f_src / var0)
    from ..core.allan import allan_deviation
    taus, adev, _, _ = allan_deviation(out, (q.size - 1) / (q[-1] - q[0]))
    line = (adev ** 2).mean(axis=1) * taus * f_src / (var0 * density)      # 1 on the white line
    near = np.flatnonzero((line[:7] >= 0.95) & (line[:7] <= 1.05))
    white_from = int(2 ** near[0]) if near.size else 64
    return (float(np.mean(out * out)) / var0, float(np.mean(d3 * d3) / np.mean(src * src)), density, white_from)
