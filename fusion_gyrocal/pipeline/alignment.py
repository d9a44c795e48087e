"""Time alignment of two recordings: the offset between their clocks and one common time grid.

The paper (footnote in Section III): an unknown time offset "is typically computed by correlating
[the gyroscopes'] measurements' norms". :func:`estimate_time_offset` takes the coarse offset from
the FFT cross-correlation of the rate norms (rotation invariant) and refines it below one sample by
minimising the misfit of the rigid-pair model ``omega_1(t) = A omega_2(t - offset) + b`` (Eq. 3-5)
over the offset, with ``A`` and ``b`` profiled out by least squares (Eq. 16-17) at every trial
offset and both gyros evaluated with cubic splines. :func:`align_streams` estimates (or takes) the
offset and resamples gyro 2 onto gyro 1's clock (:func:`~fusion_gyrocal.pipeline.resample.resample`),
giving an :class:`AlignedPair`.

Time convention (ARCHITECTURE.md): ``offset_s`` is what must be ADDED to gyro 2's timestamps
to put them on gyro 1's clock, so gyro 2's sample taken at its own time ``t2`` happened at
``t2 + offset_s`` on gyro 1's clock, and gyro 2's rate at gyro-1 time ``t`` is ``omega_2(t - offset_s)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..core.moments import Moments, row_norms, row_sumsq, rows_times
from ..errors import OptionError, TimeAlignmentError
from .resample import _MARGIN, _RunSplines, _ranges, _resample_checked, _runs
from .streams import DEFAULT_GAP_PERIODS, _freeze, _nominal_period, _stream, timed_stream, valid_mask

_AMBIGUITY_RATIO = 1.5         # a second lobe with misfit (1 - r) below this times the peak's is ambiguous
_MIN_OVERLAP_FRACTION = 0.5    # lags overlapping fewer valid grid points than this fraction are ignored
_EVAL_STEP = 2.0 / (1.0 + 5.0 ** 0.5)  # refinement instants every 0.618 grid steps (golden ratio: equidistributed)
_STD_BLOCK_S = 0.25            # block length of the sandwich estimate of the offset's std
_XC_ONE_FFT = 1 << 17          # grid points up to which the coarse correlation is one FFT
_XC_BLOCK = 1 << 13            # beyond: blocks of f of this length (small FFTs, measured fastest)
_NORM_BLOCK = 1 << 16          # grid points (and samples) per block of the norms and the window scores
MAX_EVAL = 1 << 17             # refinement instants: longer logs use their most excited windows
_COARSE_EVAL = 1 << 14         # instants of the bracketed search of a refinement on 4x as many or more (a thinned set)
_NEWTON_STEPS = 4              # Newton steps on the whole set before falling back to the bracketed search there
_COARSE_BINS = 1 << 18         # grid points and lags of the coarse correlation: beyond, the norms are binned coarser
_LOCAL_POINTS = 1 << 14        # full-rate grid points of the search near a coarse lobe (its peak only starts the
                               # bracketed search; 2^16 gave offsets equal within 1e-6 of their std, 4x the time)
_SEGMENT_POINTS = 1 << 13      # half the full-rate grid points of a drift stretch's own search
_DRIFT_SEGMENTS = 8            # stretches of the overlap whose offsets give the clock drift
_DRIFT_MIN_S = 15.0            # shortest stretch (s): records under 45 s get no drift estimate
_MAX_DRIFT = 1e-3              # largest clock drift searched (1000 ppm: crystal clocks are within 100 ppm)
_DRIFT_SIGMAS = 4.0            # a drift is compensated beyond this many stds (and when it moves the offset more
                               # than the offset's std over half the overlap)


# ---------------------------------------------------------------------------------------------- time offset
@dataclass(frozen=True)
class TimeOffset:
    """Estimated time offset between two gyroscope streams.

    Attributes
    ----------
    offset_s : float
        What must be ADDED to gyro 2's timestamps to put them on gyro 1's clock (s).
    std_s : float
        Standard deviation of ``offset_s`` (s), from the curvature of the misfit and the
        (block-summed) residuals.
    lags_s : ndarray, shape (L,)
        Trial offsets of the coarse search (s), spaced by one grid step.
    correlation : ndarray, shape (L,)
        Normalised cross-correlation of the two rate norms at ``lags_s`` (NaN where the overlap
        was too short).
    peak_correlation : float
        Largest value of ``correlation``.
    n_samples : int
        Instants compared in the sub-sample refinement's last step (gyro 1 interpolated about 1.6 times per
        sample of the faster stream).
    drift_ppm, drift_std_ppm : float
        Clock drift: how fast the offset grows along gyro 1's clock, in 1e-6 (s per s), and its std, from the
        offsets of stretches of the overlap (0 for records too short to tell, under 45 s).
    reference_time_s : float
        The instant on gyro 1's clock (the middle of the overlap) where ``offset_s`` holds when the drift is
        compensated: the offset at gyro-1 time ``t`` is ``offset_s + drift_ppm 1e-6 (t - reference_time_s)``.
    drift_compensated : bool
        Whether the drift is applied (beyond 4 stds, and moving the offset by more than ``std_s`` over half the
        overlap); otherwise ``offset_s`` is the one offset of the whole record.
    """

    offset_s: float
    std_s: float
    lags_s: np.ndarray = field(repr=False)
    correlation: np.ndarray = field(repr=False)
    peak_correlation: float
    n_samples: int
    drift_ppm: float = 0.0
    drift_std_ppm: float = 0.0
    reference_time_s: float = 0.0
    drift_compensated: bool = False

    def offset_at(self, t):
        """The offset (s) to add to gyro 2's timestamps at gyro-1 time(s) ``t``."""
        if not self.drift_compensated:
            return np.full(np.shape(t), self.offset_s)
        return self.offset_s + 1e-6 * self.drift_ppm * (np.asarray(t, dtype=float) - self.reference_time_s)

    def __post_init__(self):
        _freeze(self, ("lags_s", "correlation"), np.float64)


def _masked_correlation(f, mf, g, mg, d_lo, d_hi, min_overlap):
    """Pearson correlation of ``f[k]`` with ``g[k - d]`` over jointly valid k, for d in [d_lo, d_hi], by FFT.

    Each lag uses only the samples valid in both (masked normalised cross-correlation): six FFT
    cross-correlations give, per lag, the overlap count, both sums and sums of squares, and the
    cross sum. Long series are cut into blocks of ``f`` (each with the stretch of ``g`` its lags
    reach) whose sums are added, so memory stays bounded and time linear in the length.
    """
    d = np.arange(d_lo, d_hi + 1)
    nf, ng = f.size, g.size
    if nf + ng - 1 <= _XC_ONE_FFT or d.size > _XC_BLOCK:   # short, or lags spanning much of the record
        spans = [(0, nf, 0, ng)]
    else:
        spans = [(k0, min(k0 + _XC_BLOCK, nf), max(0, k0 - d_hi), min(ng, min(k0 + _XC_BLOCK, nf) - d_lo))
                 for k0 in range(0, nf, _XC_BLOCK)]
    acc = np.zeros((6, d.size))
    for k0, k1, j0, j1 in spans:
        la, lb = k1 - k0, j1 - j0
        if la <= 0 or lb <= 0:
            continue
        nfft = 1 << int(np.ceil(np.log2(max(la + lb - 1, 2))))
        a, b = f[k0:k1], g[j0:j1]
        lag = d - (k0 - j0)                    # lag within the block pair: sum_m a[m] b[m - lag]
        sel = np.mod(lag, nfft)
        if mf[k0:k1].all() and mg[j0:j1].all():
            # a block without masked samples (the usual case): only the cross sum needs an FFT; the
            # counts, sums and sums of squares are those of the overlapping stretches of a and b (cumsums)
            xc = np.fft.irfft(np.fft.rfft(a, nfft) * np.conj(np.fft.rfft(b, nfft)), nfft)
            m0 = np.clip(lag, 0, la)                    # a[m0:m1] meets b[m0 - lag:m1 - lag]
            m1 = np.clip(lb + lag, m0, la)
            ca = np.concatenate(([0.0], np.cumsum(a)))
            qa = np.concatenate(([0.0], np.cumsum(a * a)))
            cb = np.concatenate(([0.0], np.cumsum(b)))
            cq = np.concatenate(([0.0], np.cumsum(b * b)))
            n0, n1 = np.clip(m0 - lag, 0, lb), np.clip(m1 - lag, 0, lb)
            acc[0] += m1 - m0
            acc[1] += ca[m1] - ca[m0]
            acc[2] += cb[n1] - cb[n0]
            acc[3] += qa[m1] - qa[m0]
            acc[4] += cq[n1] - cq[n0]
            acc[5] += np.where(m1 > m0, xc[sel], 0.0)
            continue
        ma, mb = mf[k0:k1].astype(float), mg[j0:j1].astype(float)
        F = np.fft.rfft(np.stack((ma, a, a * a)), nfft)
        G = np.conj(np.fft.rfft(np.stack((mb, b, b * b)), nfft))
        inside = (lag >= -(lb - 1)) & (lag <= la - 1)
        xc = np.fft.irfft(np.stack((F[0] * G[0], F[1] * G[0], F[0] * G[1], F[2] * G[0], F[0] * G[2],
                                    F[1] * G[1])), nfft)
        acc += np.where(inside, xc[:, sel], 0.0)
    cnt = np.rint(acc[0])
    s1, s2, q1, q2, p = acc[1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        cov = p - s1 * s2 / cnt
        v1 = q1 - s1 * s1 / cnt
        v2 = q2 - s2 * s2 / cnt
        r = cov / np.sqrt(v1 * v2)
    r[(cnt < min_overlap) | ~(v1 > 0) | ~(v2 > 0)] = np.nan
    return np.clip(r, -1.0, 1.0)


def _norm_on_grid(t, w, ok, k_lo: int, k_hi: int, h: float, gap):
    """Standardised rate norm on the grid ``k h``, ``k_lo <= k <= k_hi`` (linear interpolation inside runs;
    0 elsewhere) and its mask.

    Linear interpolation is enough for the coarse search (the refinement uses splines) and
    stays cheap for records split into many runs by masked samples. The grid is filled block by
    block from the samples each block reaches, so no per-sample intermediate of the whole record
    is kept.
    """
    size = k_hi - k_lo + 1
    x = np.zeros(size)
    inside = np.zeros(size, dtype=bool)
    for lo in range(0, size, _NORM_BLOCK):
        grid = np.arange(k_lo + lo, min(k_lo + lo + _NORM_BLOCK, k_hi + 1)) * h
        i0 = max(int(np.searchsorted(t, grid[0], side="right")) - 2, 0)
        i1 = min(int(np.searchsorted(t, grid[-1], side="left")) + 2, t.size)
        tl, wl, okl = t[i0:i1], w[i0:i1], ok[i0:i1]
        first, last = _runs(tl, okl, gap)
        if not first.size:
            continue
        last = last - 1
        k = np.searchsorted(tl[first], grid, side="right") - 1
        ins = (k >= 0) & (grid <= tl[last[np.clip(k, 0, None)]])
        sel = np.flatnonzero(okl)
        x[lo:lo + grid.size][ins] = np.interp(grid[ins], tl[sel], row_norms(wl[sel]))
        inside[lo:lo + grid.size] = ins
    if inside.sum() < 2:
        return x, inside
    xin = x[inside]
    mu, sd = xin.mean(), xin.std()
    del xin
    x -= mu
    x /= sd if sd > 0 else 1.0
    x[~inside] = 0.0
    return x, inside


def _profile_fit(w1, w2):
    """Least squares of ``w1 = A w2 + b`` (Eq. 16-17): the moments, ``S22^+`` and ``A = S12 S22^+``."""
    m = Moments.from_samples(w1, w2)
    S22p = np.linalg.pinv(m.S22, rcond=1e-12, hermitian=True)
    return m, S22p, m.S12 @ S22p


def _span_misfit(spl2: _RunSplines, x1, y1, lo: float, hi: float):
    """``(x, y, C)``: the instants of ``x1`` whose gyro-2 time ``x - tau`` lies inside one run of gyro 2 for
    every offset ``tau`` in ``[lo, hi]`` (a fixed set, so ``C`` is smooth), gyro 1's rates ``y`` there and
    the profiled misfit ``C(tau)``: the residual sum of squares of ``y = A omega_2(x - tau) + b`` with A and
    b at their least-squares values, ``tr(S11 - S12 S22^+ S12^T)`` of the centred scatter.
    """
    ra = spl2.run_of(x1 - hi)
    use = ra >= 0
    if use.any():                  # and x - lo in the same run: not beyond its end (the next run starts later)
        use &= x1 - lo <= spl2.ends[np.clip(ra, 0, None)]
    xe, ye = x1[use], y1[use]
    inside = np.ones(xe.size, dtype=bool)
    last = [None]                       # the intervals of the previous trial offset: the next one's start

    def cost(tau):
        q = xe - tau
        last[0] = spl2.locate(q, last[0])
        return _misfit(ye, spl2(q, inside=inside, at=last[0])[0])

    return xe, ye, cost


def _misfit(y, w2) -> float:
    """The profiled misfit of ``y = A w2 + b`` (A and b at their least-squares values, Eq. 16-17):
    ``tr(S11 - S12 S22^+ S12^T)`` of the centred scatter."""
    m, _, A = _profile_fit(y, w2)
    return float(np.trace(m.S11) - np.trace(A @ m.S12.T))


def _excited_instants(t1, w1, ok1, he: float, max_eval: int):
    """Refinement instants (multiples of ``he``) inside the most excited windows of gyro 1, at most ``max_eval``, and
    the first and last instant of each window.

    The information about the offset is in the rate's derivative (the misfit's curvature is
    ``sum |A d/dt omega_2|^2``): the record is cut into windows of ``_STD_BLOCK_S`` seconds, each
    scored by ``sum |d omega_1 / dt|^2`` of its consecutive valid samples (one chunked pass), and
    the best windows are kept, whole, in time order.
    """
    score = np.zeros(int(np.floor((t1[-1] - t1[0]) / _STD_BLOCK_S)) + 1)
    for lo in range(0, t1.size - 1, _NORM_BLOCK):
        hi = min(lo + _NORM_BLOCK + 1, t1.size)
        dt = np.diff(t1[lo:hi])
        dw = np.diff(w1[lo:hi], axis=0)
        e = np.einsum("ij,ij->i", dw, dw) / (dt * dt)
        both = ok1[lo:hi - 1] & ok1[lo + 1:hi]
        if not both.all():
            e[~both] = 0.0
        k = ((t1[lo:hi - 1] - t1[0]) / _STD_BLOCK_S).astype(np.int64)
        score += np.bincount(k, weights=e, minlength=score.size)
    per = _STD_BLOCK_S / he
    n_win = max(1, int(max_eval / (per + 1.0)))
    best = np.sort(np.argsort(score)[::-1][:n_win])
    a = np.ceil((t1[0] + best * _STD_BLOCK_S) / he).astype(np.int64)
    b = np.ceil((t1[0] + (best + 1) * _STD_BLOCK_S) / he).astype(np.int64)
    a, b = a[b > a], b[b > a]
    return _ranges(a, b) * he, (a * he, (b - 1) * he)


def _near(t, w, ok, lo, hi):
    """``(t, w, ok)`` restricted to the samples within ``_MARGIN`` samples of the spans ``[lo_i, hi_i]``.

    Overlapping or close spans are merged (spans that overlap their neighbours, as the instants of a window, give
    the stretches of the window's span); the first sample of every later stretch is marked
    invalid so that a spline never bridges two stretches. A spline on these samples equals the
    one on the whole record (to rounding) at every query inside the spans.
    """
    i0 = np.clip(np.searchsorted(t, lo, side="left") - _MARGIN, 0, t.size)
    i1 = np.clip(np.searchsorted(t, hi, side="right") + _MARGIN, 0, t.size)
    order = np.argsort(i0, kind="stable")
    i0, i1 = i0[order], np.maximum.accumulate(i1[order])
    new = np.r_[True, i0[1:] > i1[:-1] + 2 * _MARGIN]      # a new stretch starts here
    starts = i0[new]
    stops = np.r_[i1[np.flatnonzero(new)[1:] - 1], i1[-1]]
    sel = _ranges(starts, stops)
    keep = ok[sel]
    first = np.cumsum(np.r_[0, stops[:-1] - starts[:-1]])
    keep[first[1:]] = False
    return t[sel], w[sel], keep


def _parabolic_peak(r, i) -> float:
    """Sub-step position (in steps, within +-0.5) of the peak at ``i`` of a sampled curve."""
    if i == 0 or i == r.size - 1 or not (np.isfinite(r[i - 1]) and np.isfinite(r[i + 1])):
        return 0.0
    den = r[i - 1] - 2.0 * r[i] + r[i + 1]
    return float(np.clip(0.5 * (r[i - 1] - r[i + 1]) / den, -0.5, 0.5)) if den < 0 else 0.0


def _refine(spl2: _RunSplines, x1, y1, tau0: float, h: float):
    """Offset minimising the profiled rigid-model misfit near ``tau0`` (Brent, bracket +-1.5 steps).

    ``(x1, y1)`` are the evaluation instants on gyro 1's clock and gyro 1's rates there.
    Returns ``(tau, x_used, y_used, rss / n)``. The instants used are those whose whole
    bracket maps inside one run of gyro 2, so the set is fixed and the cost smooth; the
    bracket moves if the minimum lands on its edge. Brent's bounded method
    (``scipy.optimize.minimize_scalar``, imported here: off the command line's start-up).
    """
    from scipy.optimize import minimize_scalar

    tau, half = tau0, 1.5 * h
    for _ in range(6):
        lo, hi = tau - half, tau + half
        xe, ye, cost = _span_misfit(spl2, x1, y1, lo, hi)
        if xe.size < 16:
            raise TimeAlignmentError(f"only {xe.size} gyro-1 instants overlap valid gyro-2 data near the "
                                     f"offset {tau0:+.4f} s; need at least 16")
        res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": _tolerance(tau, h)})
        tau, fun = float(res.x), res.fun
        if min(tau - lo, hi - tau) >= 0.05 * half:
            return tau, xe, ye, float(fun) / xe.size
    raise TimeAlignmentError(f"the sub-sample refinement did not settle near the correlation peak "
                             f"{tau0:+.4f} s (last {tau:+.6f} s)")


def _tolerance(tau: float, h: float) -> float:
    """How closely the refinement locates the misfit's minimum (s): a ten-thousandth of a step (plus rounding)."""
    return 1e-9 * max(1.0, abs(tau)) + 1e-4 * h


def _thinned(x1, y1):
    """``(x1, y1)`` thinned for the bracketed search: every k-th block of ``_STD_BLOCK_S`` seconds of the instants,
    ``k = len(x1) // _COARSE_EVAL``, when that is 4 or more (else all of them)."""
    k = x1.size // _COARSE_EVAL
    if k < 4:
        return x1, y1
    keep = np.floor((x1 - x1[0]) / _STD_BLOCK_S).astype(np.int64) % k == 0
    return x1[keep], y1[keep]


def _polish(spl2: _RunSplines, x1, y1, tau0: float, h: float):
    """The offset minimising the profiled misfit on all the instants ``x1``, from ``tau0`` (the bracketed search's on
    :func:`_thinned` instants): ``(tau, lin, std)``, ``lin`` the :class:`_Linearised` where ``std`` was taken.

    Newton steps (:meth:`_Linearised.std_step`: the exact derivative ``C'``, the curvature by central differences)
    until one is within :func:`_tolerance`, which is then added: the result is the minimum to well within the
    bracketed search's tolerance (after a step ``s`` the remaining error is ``s`` times the curvature's relative
    error). A step within ``delta`` keeps the instants and the curvature (:meth:`_Linearised.moved`: only the
    values and slopes at the new offset), so the usual two steps cost the evaluations the std needs anyway and
    one more of the values and slopes, where that search on all the instants takes six or more of the misfit.
    Where a step is not finite, longer than half a step of the grid, or the steps do not settle, the bracketed
    search (:func:`_refine`) runs on all the instants.
    """
    tau, lin = tau0, None
    for _ in range(_NEWTON_STEPS):
        if lin is not None and abs(tau - lin.tau_mid) <= lin.delta:
            lin = lin.moved(spl2, tau, half_curv)
        else:
            lin = _linearise(spl2, x1, y1, tau, h)
        std, step, half_curv = lin.std_step()
        if not (np.isfinite(step) and abs(step) <= 0.5 * h):
            break
        if abs(step) <= _tolerance(tau, h):
            return tau + step, lin, std
        tau += step
    tau = _refine(spl2, x1, y1, tau0, h)[0]
    lin = _linearise(spl2, x1, y1, tau, h)
    return tau, lin, lin.std_step()[0]


@dataclass(frozen=True)
class _Linearised:
    """The profiled misfit ``C`` near a trial offset ``tau``, on the instants ``x`` whose gyro-2 times stay inside
    one run of gyro 2 for every offset in ``tau_mid +- delta``: gyro 1's rates ``y`` there, gyro 2's spline values
    ``w2`` and slopes ``dw2`` at ``x - tau`` and its values at ``x - (tau_mid - delta)`` and
    ``x - (tau_mid + delta)`` (the curvature's central differences; ``tau_mid`` is ``tau`` unless moved, then
    ``w2_mid`` holds the values at ``x - tau_mid``, and ``half_curv`` may hold ``C''/2`` of these instants);
    ``at``: the spline intervals of ``x - tau`` (:meth:`~fusion_gyrocal.pipeline.resample._RunSplines.locate`),
    from which those at a nearby offset are found.

    One evaluation of gyro 2's splines serves the whole record's std and Newton step (:meth:`std_step`) and those
    of every stretch of it (:meth:`within`: the same values, sliced): the drift stretches need no evaluation of
    their own.
    """

    tau: float
    delta: float
    x: np.ndarray
    y: np.ndarray
    w2: np.ndarray
    dw2: np.ndarray
    w2_minus: np.ndarray
    w2_plus: np.ndarray
    tau_mid: float | None = None
    w2_mid: np.ndarray | None = None
    half_curv: float | None = None
    at: np.ndarray | None = None

    def __post_init__(self):
        if self.tau_mid is None:
            object.__setattr__(self, "tau_mid", self.tau)

    @cached_property
    def _blocks(self) -> tuple[np.ndarray, np.ndarray]:
        """``(block, used)``: the consecutive ``_STD_BLOCK_S`` block of each instant of ``x`` and the blocks holding
        one (the same for every offset: kept, and passed on by :meth:`moved`)."""
        block = np.floor((self.x - self.x[0]) / _STD_BLOCK_S).astype(np.int64)
        return block, np.bincount(block) > 0

    def within(self, a: float, b: float) -> "_Linearised":
        """The same terms on the instants in ``[a, b)`` (their curvature their own)."""
        j0, j1 = np.searchsorted(self.x, [a, b])
        cut = [None if v is None else v[j0:j1] for v in (self.x, self.y, self.w2, self.dw2, self.w2_minus,
                                                          self.w2_plus, self.w2_mid, self.at)]
        return _Linearised(self.tau, self.delta, *cut[:6], tau_mid=self.tau_mid, w2_mid=cut[6], at=cut[7])

    def moved(self, spl2: _RunSplines, tau: float, half_curv: float | None = None) -> "_Linearised":
        """The terms at ``tau`` (within ``delta`` of ``tau_mid``) on the same instants, with the same central
        differences (and ``half_curv``, the curvature of all these instants, when given): gyro 2's values and
        slopes evaluated again, at ``x - tau``."""
        q = self.x - tau
        at = spl2.locate(q, self.at)          # the intervals from those at the previous offset
        w2, dw2 = spl2.values_and_slopes(q, at)
        out = _Linearised(tau, self.delta, self.x, self.y, w2, dw2, self.w2_minus, self.w2_plus, self.tau_mid,
                          self.w2 if self.w2_mid is None else self.w2_mid, half_curv, at)
        if "_blocks" in self.__dict__:   # the same instants: the same blocks
            out.__dict__["_blocks"] = self._blocks
        return out

    def std_step(self) -> tuple[float, float, float]:
        """``(std, step, half_curv)``: the sandwich standard deviation of the offset that minimises ``C``, the Newton
        step ``-C'/C'' = -sum u / (C''/2)`` from ``tau`` towards it and ``C''/2``; ``(inf, nan, C''/2)`` where ``C``
        is not convex.

        At the minimum, ``tau_hat - tau ~ -sum_m u_m / (C''/2)`` with ``u_m = d_m . r_m``,
        ``d_m = P A d/dt omega_2(x_m - tau)`` (``P`` projects out the directions of the profiled ``A``
        and ``b``) and residuals ``r_m``; ``sum u`` is ``C'/2`` exactly (the residuals are orthogonal to what
        ``P`` removes). ``C''`` is taken by central differences of the profiled misfit about ``tau_mid``, so it
        contains the term ``-sum r . A d2/dt2 omega_2`` that cancels the noise energy of the spline derivative
        (using ``sum |d|^2`` alone would overstate the information). The residuals of neighbouring (interpolated)
        instants are correlated, so ``Var(sum u)`` is estimated from the sums of ``u`` over consecutive blocks
        of about ``_STD_BLOCK_S`` seconds.
        """
        ye, w2, dw2, delta = self.y, self.w2, self.dw2, self.delta
        m, S22p, A = _profile_fit(ye, w2)
        half_curv = self.half_curv
        if half_curv is None:
            at_mid = (float(np.trace(m.S11) - np.trace(A @ m.S12.T)) if self.w2_mid is None   # C(tau), from the fit
                      else _misfit(ye, self.w2_mid))                                         # needed below anyway
            half_curv = 0.5 * (_misfit(ye, self.w2_plus) - 2.0 * at_mid + _misfit(ye, self.w2_minus)) / delta**2
        if not half_curv > 0:
            return float("inf"), float("nan"), half_curv
        # the tall (N, 3) x (3, 3) products in blocks of rows (rows_times: one thread each, not OpenBLAS's spinning
        # threads, which cost more CPU time than the products on a busy machine)
        w2c = w2 - m.mean_2
        resid = ye - m.mean_1
        resid -= rows_times(w2c, A.T)
        md = Moments.from_samples(dw2, w2)  # project d/dt omega_2 on the regressors [omega_2, 1]
        if not np.array_equal(md.mean_2, m.mean_2):   # (the same pass over w2: equal, and w2c serves again)
            w2c = w2 - md.mean_2
        d = dw2 - md.mean_1
        d -= rows_times(w2c, (md.S12 @ S22p).T)
        d = rows_times(d, A.T)
        u = np.einsum("ij,ij->i", d, resid)
        block, used = self._blocks
        sums = np.bincount(block, weights=u)[used]
        nb = sums.size
        var_u = float(np.sum(sums**2)) * nb / max(nb - 1, 1)
        return float(np.sqrt(var_u) / half_curv), -float(sums.sum()) / half_curv, half_curv


def _linearise(spl2: _RunSplines, x1, y1, tau: float, h: float) -> _Linearised:
    """:class:`_Linearised` at ``tau`` on the instants ``x1`` (gyro 1's rates ``y1``), ``delta`` a quarter step."""
    delta = 0.25 * h
    xe, ye, _ = _span_misfit(spl2, x1, y1, tau - delta, tau + delta)
    q = xe - tau
    at = spl2.locate(q)
    w2, dw2 = spl2.values_and_slopes(q, at)   # one lookup of the instants' intervals for both
    inside = np.ones(xe.size, dtype=bool)
    minus, plus = (spl2(p, inside=inside, at=spl2.locate(p, at))[0] for p in (xe - (tau - delta), xe - (tau + delta)))
    return _Linearised(tau, delta, xe, ye, w2, dw2, minus, plus, at=at)


def _offset_std(spl2: _RunSplines, x1, y1, tau: float, h: float, newton: bool = False):
    """Standard deviation of the offset refined on the instants ``x1`` near ``tau`` (``newton``: also the Newton
    step towards the minimum, as ``(std, step)``): :meth:`_Linearised.std_step`."""
    std, step, _ = _linearise(spl2, x1, y1, tau, h).std_step()
    return (std, step) if newton else std


def estimate_time_offset(t_1, omega_1, t_2, omega_2, *, max_offset_s: float | None = None, valid_1=None,
                         valid_2=None, min_correlation: float = 0.5, max_eval: int | None = MAX_EVAL) -> TimeOffset:
    """Estimate the time offset between two rigidly mounted gyroscopes from their rates alone.

    1. Coarse: the rate norms ``|omega_i|`` (invariant to the unknown rotation, as in the paper's
       footnote on time alignment) are interpolated (linearly, inside runs of valid samples) onto
       one uniform grid (step = the shorter nominal sample period of the two streams, so
       different rates are handled) and cross-correlated by FFT, each lag normalised over the
       grid points valid in both streams (gaps and masks allowed). The peak in
       ``[-max_offset_s, max_offset_s]`` (by default every lag that keeps half the shorter record
       overlapping) is located to a fraction of a step by parabolic interpolation. When the grid and
       the lags together exceed 2^18 points, the norms are first averaged in coarser bins (at least two
       samples of the slower stream each) and each lobe's peak is found again at full rate within
       +-3 bins, on gyro 1's 2^14-step stretch whose norm varies most. When several separate lobes
       come close to the peak (norms of periodic motion repeat), each is refined as in step 2 and the one with the smallest rigid-model
       misfit wins; if the misfits are within a factor of 1.5 the offset is ambiguous.
    2. Fine: the offset minimises the residual sum of squares of the rigid-pair model
       ``omega_1(x) = A omega_2(x - offset) + b`` (Eq. 3-5 with ``A = S_1 C S_2^-1``), both gyros
       evaluated with cubic splines at instants ``x`` spaced 0.618 grid steps apart. ``A`` and
       ``b`` are profiled out by least squares (Eq. 16-17) at every trial offset, so the unknown
       rotation, scale factors and biases cannot bias the offset (matching norms alone would be
       biased by unequal scale factors and biases: see ``benchmarks/alignment.py``). The
       golden-ratio spacing keeps the instants' phases relative to gyro 2's samples uniformly
       spread at every trial offset; evaluating at gyro 1's own sample times instead lets the
       phase-dependent variance of the interpolated noise pull the offset (up to ~0.1 ms for
       two 200 Hz streams with slow motion). The 1-D minimisation is Brent's method on a
       +-1.5-step bracket around the coarse peak, on every k-th 0.25 s block of the instants when there
       are 4 x 16384 or more (about 16384 of them; the lobes are compared there), then Newton steps on all
       the instants (the exact derivative of the misfit, its curvature by central differences) until a step
       is within Brent's tolerance (a ten-thousandth of a grid step): the minimum on all the instants with
       the evaluations the uncertainty (step 3) needs there and one more of the values and slopes, where Brent
       took six or more.
    3. Uncertainty: first order, ``offset_hat - offset = -sum_m d_m . r_m / (C''/2)`` with
       ``d_m = P A d/dt omega_2(x_m - offset)`` (``P`` projects out the directions of the profiled
       ``A`` and ``b``), residuals ``r_m`` and ``C''`` the curvature of the profiled misfit (central
       differences); the variance of the numerator is estimated from its sums over 0.25 s
       blocks (a sandwich estimate: the residuals of interpolated neighbours are correlated,
       and model errors are included).
    4. Clock drift: the overlap is cut into up to 8 stretches of at least 15 s; each stretch's offset is
       found as in 1-3 (within ``+-1e-3`` of the overlap's length of the whole-record offset) and a line
       weighted by their variances gives the drift (ppm) and the offset at the overlap's middle. The drift
       is compensated (``drift_compensated``; ``offset_s`` then holds at ``reference_time_s``) when it
       exceeds 4 stds and moves the offset by more than ``std_s`` over half the overlap; the stds are scaled
       up by the stretches' scatter about the line. A whole-record refinement smeared by a large drift
       falls back to the line.

    Parameters
    ----------
    t_1, t_2 : array_like, shape (N_1,), (N_2,)
        Timestamps (s) of gyro 1 and gyro 2, each on its own clock.
    omega_1, omega_2 : array_like, shape (N_1, 3), (N_2, 3)
        Measured rates (rad/s); gyro 2 may be rotated, scaled and biased w.r.t. gyro 1.
    max_offset_s : float or None
        Largest offset magnitude searched; None (default): every offset that leaves at least half of the
        shorter recording overlapping (independent clocks: seconds to hours apart).
    valid_1, valid_2 : array_like of bool, optional
        Samples that may be used (e.g. ``~saturation_mask(omega)``); non-finite samples are
        always excluded.
    min_correlation : float
        Smallest accepted peak of the normalised norm correlation.
    max_eval : int or None
        Most refinement instants (default ``MAX_EVAL`` = 131072, about 400 s of a 200 Hz stream). A
        longer record is refined on its most excited 0.25 s windows (largest ``|d omega_1/dt|``,
        where the offset information is), with splines built locally around them, so the
        refinement's time and memory do not grow with the length; the reported std is that of
        the subsample. None: every instant.

    Returns
    -------
    TimeOffset
        ``offset_s`` is what must be ADDED to gyro 2's timestamps to put them on gyro 1's clock.

    Raises
    ------
    InputError
        Bad shapes, timestamps or ``max_offset_s``.
    TimeAlignmentError
        The streams do not overlap within ``max_offset_s``, the correlation peak is weak (little
        motion, or an offset beyond ``max_offset_s``), lies on the search boundary, or a second
        lobe is nearly as good in both the norm correlation and the rigid-model misfit
        (periodic motion).
    """
    t1, w1, ok1 = _stream("t_1", t_1, "omega_1", omega_1, valid_1)
    t2, w2, ok2 = _stream("t_2", t_2, "omega_2", omega_2, valid_2)
    return _estimate(t1, w1, ok1, t2, w2, ok2, max_offset_s, min_correlation, max_eval)


def _estimate(t1, w1, ok1, t2, w2, ok2, max_offset_s, min_correlation, max_eval, periods=None,
              drift: bool = True) -> TimeOffset:
    """:func:`estimate_time_offset` on checked streams (``_stream``), so a caller that has checked them
    (:func:`align_streams`) does not pay for the checks twice (``periods``: their nominal sample periods)."""
    if max_offset_s is not None and not (np.isfinite(max_offset_s) and max_offset_s > 0):
        raise OptionError(f"max_offset_s: expected a positive duration in seconds or None (every offset), "
                          f"got {max_offset_s!r}")
    for name, ok in (("omega_1", ok1), ("omega_2", ok2)):
        if np.count_nonzero(ok) < 8:
            raise TimeAlignmentError(f"{name}: expected at least 8 valid samples to align, got "
                                     f"{int(np.count_nonzero(ok))}")
    t_ref = t1[int(np.argmax(ok1))]
    t1, t2 = t1 - t_ref, t2 - t_ref  # relative times: keeps spline and grid arithmetic exact
    if max_offset_s is not None:   # no offset beyond both spans together can overlap: the lag grid is bounded by
        max_offset_s = min(float(max_offset_s), float(t1[-1] - t1[0] + t2[-1] - t2[0]))   # the data, not the option
    p1, p2 = (_nominal_period(t1), _nominal_period(t2)) if periods is None else periods
    gap1, gap2 = DEFAULT_GAP_PERIODS * p1, DEFAULT_GAP_PERIODS * p2
    h = min(p1, p2)
    whole = max_offset_s is None
    reach = np.inf if whole else float(max_offset_s)
    what = ("every offset that leaves half the shorter recording overlapping" if whole
            else f"max_offset_s={max_offset_s:g} s")

    # ---- coarse: masked normalised FFT cross-correlation of the norms on a common grid (binned on a
    # coarser grid when the record is long: the peak is then found again at full rate near each lobe)
    span2 = min(t2[-1], t1[-1] + reach) - max(t2[0], t1[0] - reach)
    n_grid = (t1[-1] - t1[0] + max(span2, 0.0) + 2.0 * min(reach, t1[-1] - t1[0] + t2[-1] - t2[0])) / h
    hc = h if n_grid <= _COARSE_BINS else h * float(np.ceil(n_grid / _COARSE_BINS))
    if hc > h:
        hc = max(hc, 2.0 * max(p1, p2))
    k1_lo, k1_hi = int(np.ceil(t1[0] / hc)), int(np.floor(t1[-1] / hc))
    k2_lo = int(np.ceil(max(t2[0], t1[0] - reach) / hc))
    k2_hi = int(np.floor(min(t2[-1], t1[-1] + reach) / hc))
    if k2_hi - k2_lo < 8:
        raise TimeAlignmentError(
            f"the streams do not overlap within {what}: gyro 1 covers "
            f"[{t1[0]:.6g}, {t1[-1]:.6g}] s and gyro 2 [{t2[0]:.6g}, {t2[-1]:.6g}] s relative to gyro 1's first "
            "valid sample (pass a larger max_offset_s or shift t_2 first)")
    if hc == h:
        f, mf = _norm_on_grid(t1, w1, ok1, k1_lo, k1_hi, h, gap1)
        g, mg = _norm_on_grid(t2, w2, ok2, k2_lo, k2_hi, h, gap2)
    else:
        f, mf = _binned_norms(t1, w1, ok1, k1_lo, k1_hi, hc)
        g, mg = _binned_norms(t2, w2, ok2, k2_lo, k2_hi, hc)
    # gyro 2 at own time t - tau matches gyro 1 at t: index j = k - lag  ->  d = lag + (k2_lo - k1_lo)
    shift = k2_lo - k1_lo
    if whole:
        lag_lo, lag_hi = k1_lo - k2_hi, k1_hi - k2_lo
    else:
        L = int(np.ceil(max_offset_s / hc))
        lag_lo, lag_hi = -L, L
    min_overlap = max(8.0, _MIN_OVERLAP_FRACTION * min(np.count_nonzero(mf), np.count_nonzero(mg)))
    r = _masked_correlation(f, mf, g, mg, lag_lo + shift, lag_hi + shift, min_overlap)
    lags = np.arange(lag_lo, lag_hi + 1) * hc
    if not np.isfinite(r).any():
        raise TimeAlignmentError(f"no trial offset within {what} overlaps enough valid samples of both "
                                 f"streams (need {int(min_overlap)} common grid points)")
    rr = np.where(np.isfinite(r), r, -np.inf)
    top = float(rr.max())
    if top < min_correlation:
        raise TimeAlignmentError(
            f"weak correlation of the rate norms: peak {top:.3f} at {lags[int(np.argmax(rr))]:+.4f} s (need >= "
            f"{min_correlation:g}) within {what}; too little motion, "
            + ("" if whole else "an offset beyond it, ") + "streams that are not from one rigid body, or "
            "timestamps that do not follow the samples (see the timestamp diagnosis)")
    # lobes: contiguous lag ranges whose misfit (1 - r) is within _AMBIGUITY_RATIO of the best
    thr = 1.0 - _AMBIGUITY_RATIO * (1.0 - top)
    above = np.r_[False, rr >= thr, False].astype(np.int8)
    edges = np.flatnonzero(np.diff(above))
    cands = [int(lo + np.argmax(rr[lo:hi])) for lo, hi in zip(edges[::2], edges[1::2])]
    if hc == h:
        starts = [lags[i] + _parabolic_peak(rr, i) * h for i in cands]
    else:   # each lobe's peak again at full rate, on gyro 1's most moving stretch
        win = _moving_window(f, mf, k1_lo, hc, _LOCAL_POINTS * h)
        starts = [_local_peak(t1, w1, ok1, t2, w2, ok2, win, lags[i], 3.0 * hc, h, gap1, gap2)
                  for i in cands]

    # evaluation instants: gyro 1 spline-interpolated at a step incommensurate with both sample
    # periods, so their phases w.r.t. gyro 2's samples stay uniformly spread for every trial offset
    # and the variance of the interpolated noise (lowest between samples) cannot pull the offset
    he = h * _EVAL_STEP
    spl2, x1, y1 = _instants(t1, w1, ok1, t2, w2, ok2, he, h, gap1, gap2, max_eval,
                             [s for s in starts if s is not None])

    def on_edge(i):
        return i == 0 or i == lags.size - 1 or not (np.isfinite(r[i - 1]) and np.isfinite(r[i + 1]))

    def boundary_error(i):
        more = ("a larger max_offset_s" if not whole else
                "recordings that overlap more (the lag leaves less than half the shorter one overlapping)")
        return TimeAlignmentError(
            f"the correlation peak ({r[i]:.3f}) lies on the search boundary at {lags[i]:+.4f} s; the offset may "
            f"lie beyond {what}: pass {more}")

    fits, failures = [], []
    for start in starts:
        if start is None:
            fits.append(None)
            failures.append(TimeAlignmentError("the full-rate correlation found no peak near a coarse lobe"))
            continue
        try:
            fits.append(_refine(spl2, *_thinned(x1, y1), start, h))
        except TimeAlignmentError as exc:  # e.g. a lobe on the boundary whose minimum lies outside
            fits.append(None)
            failures.append(exc)
    score = np.array([np.inf if fit is None else fit[3] for fit in fits])
    best = int(np.argmin(score))
    i = cands[best]
    if not np.isfinite(score[best]):
        if on_edge(i):
            raise boundary_error(i)
        if drift and starts[best] is not None:   # a drifting clock smears the whole-log misfit: per stretch
            line = _drift_line(t1, w1, ok1, t2, w2, ok2, starts[best], h, gap1, gap2, max_eval, (spl2, x1, y1))
            if line is not None:
                line = _drift_again(t1, w1, ok1, t2, w2, ok2, line, h, gap1, gap2, max_eval)
                return _drift_offset(line, t_ref, lags, r, float(r[i]), compensated=True)
        raise failures[best]
    if on_edge(i) or not lags[0] - hc <= fits[best][0] <= lags[-1] + hc:
        raise boundary_error(i)
    for j, c in enumerate(cands):  # a lobe on the boundary may hide a better offset outside the range
        if on_edge(c) and not score[j] >= _AMBIGUITY_RATIO * score[best]:
            raise boundary_error(c)
    if len(cands) > 1:  # periodic norms: let the full rigid-model misfit decide, if it can
        k = int(np.argsort(score)[1])
        if score[k] < _AMBIGUITY_RATIO * score[best]:
            raise TimeAlignmentError(
                f"ambiguous time offset: the rate norms correlate at {lags[i]:+.4f} s ({r[i]:.4f}) and at "
                f"{lags[cands[k]]:+.4f} s ({r[cands[k]]:.4f}), and the rigid-model misfits there differ by only "
                f"{score[k] / score[best]:.3g}x; periodic motion? record less repetitive motion, give the offset if you "
                "know it (time_offset_s), or a max_offset_s that leaves the other lobe out")
    peak = float(r[i])
    tau, lin, std = _polish(spl2, x1, y1, fits[best][0], h)
    line = (_drift_line(t1, w1, ok1, t2, w2, ok2, lin.tau, h, gap1, gap2, max_eval, (spl2, x1, y1), lin) if drift
            else None)
    if line is not None:
        mid, tau_mid, sd_mid, ppm, sd_ppm, (lo, hi), _ = line
        half = 0.5 * (hi - lo)
        if abs(ppm) > _DRIFT_SIGMAS * sd_ppm and abs(ppm) * 1e-6 * half > std:   # it matters: compensated
            line = _drift_again(t1, w1, ok1, t2, w2, ok2, line, h, gap1, gap2, max_eval)
            return _drift_offset(line, t_ref, lags, r, peak, compensated=True)
        return TimeOffset(float(tau), std, lags, r, peak, int(lin.x.size), drift_ppm=ppm, drift_std_ppm=sd_ppm,
                          reference_time_s=float(mid + t_ref))
    mid = 0.5 * (max(t1[0], t2[0] + tau) + min(t1[-1], t2[-1] + tau))
    return TimeOffset(float(tau), std, lags, r, peak, int(lin.x.size), reference_time_s=float(mid + t_ref))


def _drift_again(t1, w1, ok1, t2, w2, ok2, line, h: float, gap1, gap2, max_eval):
    """The drift line estimated again on gyro 2's timestamps with the first line's drift taken out.

    Each stretch's offset changes by ``drift x`` its length inside it (15 ms over 75 s at 200 ppm), which smears
    its misfit; on timestamps mapped to gyro 1's clock by the first line, ``s' = t(s) - tau_mid``, the stretches
    see a constant offset and the residual drift is small. The two drifts add (to first order in the drift);
    the offset at the middle is the second line's. The first line is kept when the second cannot be fitted.
    """
    mid, tau_mid, _, ppm, _, span, _ = line
    k = 1e-6 * ppm
    t2c = (t2 + tau_mid - k * mid) / (1.0 - k) - tau_mid
    he = h * _EVAL_STEP
    try:
        spl2, x1, y1 = _instants(t1, w1, ok1, t2c, w2, ok2, he, h, gap1, gap2, max_eval, [tau_mid])
        _, lin, _ = _polish(spl2, x1, y1, _refine(spl2, *_thinned(x1, y1), tau_mid, h)[0], h)
    except TimeAlignmentError:
        return line
    again = _drift_line(t1, w1, ok1, t2c, w2, ok2, lin.tau, h, gap1, gap2, max_eval, (spl2, x1, y1), lin)
    if again is None:
        return line
    return (again[0], again[1], again[2], ppm + again[3], again[4], span, again[6])


def _drift_offset(line, t_ref, lags, r, peak, *, compensated: bool) -> TimeOffset:
    """The :class:`TimeOffset` of a fitted drift line (the offset at the middle of the overlap)."""
    mid, tau_mid, sd_mid, ppm, sd_ppm, _, n = line[0], line[1], line[2], line[3], line[4], line[5], line[6]
    return TimeOffset(float(tau_mid), float(sd_mid), lags, r, peak, int(n), drift_ppm=float(ppm),
                      drift_std_ppm=float(sd_ppm), reference_time_s=float(mid + t_ref),
                      drift_compensated=compensated)


def _binned_norms(t, w, ok, k_lo: int, k_hi: int, hc: float):
    """Standardised mean rate norm of the valid samples in each bin ``[(k - 1/2) hc, (k + 1/2) hc)``,
    ``k_lo <= k <= k_hi``, and the mask of bins holding a sample (one chunked pass, no per-sample copy)."""
    size = k_hi - k_lo + 1
    s = np.zeros(size)
    c = np.zeros(size)
    for lo in range(0, t.size, _NORM_BLOCK):   # t increases: each block's bins are one stretch of the grid
        x = t[lo:lo + _NORM_BLOCK] * (1.0 / hc)
        x += 0.5
        k = np.floor(x, out=x).astype(np.int64)
        k -= k_lo
        a, b = max(int(k[0]), 0), min(int(k[-1]), size - 1)
        if b < a:
            continue
        np.clip(k, a - 1, b + 1, out=k)
        k -= a - 1
        okb = ok[lo:lo + _NORM_BLOCK]
        norms = row_norms(w[lo:lo + _NORM_BLOCK])
        full = okb.all()    # every sample valid (the usual case): no masking pass, the counts as integers
        s[a:b + 1] += np.bincount(k, weights=norms if full else np.where(okb, norms, 0.0),
                                  minlength=b - a + 3)[1:b - a + 2]
        c[a:b + 1] += np.bincount(k, weights=None if full else okb, minlength=b - a + 3)[1:b - a + 2]
    inside = c > 0
    x = np.zeros(size)
    x[inside] = s[inside] / c[inside]
    if np.count_nonzero(inside) < 2:
        return x, inside
    xin = x[inside]
    mu, sd = xin.mean(), xin.std()
    x -= mu
    x /= sd if sd > 0 else 1.0
    x[~inside] = 0.0
    return x, inside


def _moving_window(f, mf, k_lo: int, hc: float, length: float) -> tuple[float, float]:
    """The stretch ``(start, stop)`` (s) of about ``length`` seconds where the coarse norm ``f`` varies most."""
    n = max(2, min(f.size, int(length / hc)))
    x = np.where(mf, f, 0.0)
    c1 = np.concatenate(([0.0], np.cumsum(x)))
    c2 = np.concatenate(([0.0], np.cumsum(x * x)))
    cn = np.concatenate(([0.0], np.cumsum(mf)))
    cnt = cn[n:] - cn[:-n]
    with np.errstate(invalid="ignore", divide="ignore"):
        var = (c2[n:] - c2[:-n]) - (c1[n:] - c1[:-n]) ** 2 / cnt
    var[~(cnt > 0.5 * n)] = -np.inf
    a = int(np.argmax(var))
    return (k_lo + a) * hc, (k_lo + a + n) * hc


def _local_peak(t1, w1, ok1, t2, w2, ok2, win, tau_c: float, half_width: float, h: float, gap1, gap2):
    """The norm-correlation peak at full rate (grid step ``h``) over offsets ``tau_c +- half_width``, on gyro 1's
    stretch ``win`` (s); None when no lag there has enough overlap."""
    k1_lo, k1_hi = int(np.ceil(max(win[0], t1[0]) / h)), int(np.floor(min(win[1], t1[-1]) / h))
    k2_lo = int(np.ceil(max(t2[0], k1_lo * h - tau_c - half_width) / h))
    k2_hi = int(np.floor(min(t2[-1], k1_hi * h - tau_c + half_width) / h))
    if k1_hi - k1_lo < 8 or k2_hi - k2_lo < 8:
        return None
    f, mf = _norm_on_grid(t1, w1, ok1, k1_lo, k1_hi, h, gap1)
    g, mg = _norm_on_grid(t2, w2, ok2, k2_lo, k2_hi, h, gap2)
    L0, L1 = int(np.floor((tau_c - half_width) / h)), int(np.ceil((tau_c + half_width) / h))
    min_overlap = max(8.0, _MIN_OVERLAP_FRACTION * min(np.count_nonzero(mf), np.count_nonzero(mg)))
    r = _masked_correlation(f, mf, g, mg, L0 + k2_lo - k1_lo, L1 + k2_lo - k1_lo, min_overlap)
    if not np.isfinite(r).any():
        return None
    rr = np.where(np.isfinite(r), r, -np.inf)
    i = int(np.argmax(rr))
    return (L0 + i + _parabolic_peak(rr, i)) * h


def _instants(t1, w1, ok1, t2, w2, ok2, he, h, gap1, gap2, max_eval, starts):
    """Gyro 2's splines, the refinement instants (multiples of ``he`` inside gyro 1's runs) and gyro 1's rates there
    (from gyro 1's splines, dropped before gyro 2's are built); long records: the most excited windows, splines
    built near them and the offsets ``starts``."""
    j_lo, j_hi = int(np.ceil(t1[0] / he)), int(np.floor(t1[-1] / he)) + 1
    whole = max_eval is None or j_hi - j_lo <= max_eval or not starts
    if whole:
        spl1 = _RunSplines(t1, w1, ok1, gap1)
        x1 = np.arange(j_lo, j_hi) * he
    else:  # the most excited windows carry the offset information: a bounded subsample of them
        x1, (first, last) = _excited_instants(t1, w1, ok1, he, int(max_eval))
        spl1 = _RunSplines(*_near(t1, w1, ok1, first, last), gap1)
    x1 = x1[spl1.run_of(x1) >= 0]
    y1 = spl1(x1, inside=np.ones(x1.size, dtype=bool))[0]
    del spl1
    if whole:
        spl2 = _RunSplines(t2, w2, ok2, gap2)
    else:
        pad = 12.0 * h                                     # room for the refinement bracket to move (6 x 1.5 steps)
        spl2 = _RunSplines(*_near(t2, w2, ok2, first - max(starts) - pad, last - min(starts) + pad), gap2)
    return spl2, x1, y1


def _drift_line(t1, w1, ok1, t2, w2, ok2, tau: float, h: float, gap1, gap2, max_eval, fitted,
                lin: _Linearised | None = None):
    """Clock drift: the offset refined on ``_DRIFT_SEGMENTS`` stretches of the overlap and a weighted line through
    them, ``offset(t) = tau_mid + drift (t - mid)`` on gyro 1's clock.

    Returns ``(mid, tau_mid, std_mid, drift_ppm, drift_std_ppm, (lo, hi), n_instants)`` or None when the overlap
    is shorter than ``_DRIFT_MIN_S`` per stretch or fewer than 3 stretches give an offset. Each stretch's offset is
    refined from ``tau`` on the whole record's instants in it (``fitted``: gyro 2's splines, the instants and gyro
    1's rates there; its first Newton step from the whole record's :class:`_Linearised` at ``tau``, ``lin`` when
    given) or, when it lies further, searched at full rate within ``tau +- _MAX_DRIFT x`` the overlap
    and refined on instants and splines of its own; its std is estimated as the whole record's
    (:func:`_refine`, :func:`_offset_std`); the line's stds are scaled up by the scatter of the
    stretches about it when that exceeds their own stds.
    """
    lo, hi = max(t1[0], t2[0] + tau), min(t1[-1], t2[-1] + tau)
    n_seg = min(_DRIFT_SEGMENTS, int((hi - lo) / _DRIFT_MIN_S))
    if n_seg < 3:
        return None
    if lin is None or lin.tau != tau:
        lin = _linearise(*fitted, tau, h)
    width = _MAX_DRIFT * (hi - lo) + 3.0 * h
    he = h * _EVAL_STEP
    edges = np.linspace(lo, hi, n_seg + 1)
    mids, taus, sds, n_used = [], [], [], 0
    for a, b in zip(edges[:-1], edges[1:]):
        i0, i1 = int(np.searchsorted(t1, a)), int(np.searchsorted(t1, b))
        s1 = (t1[i0:i1], w1[i0:i1], ok1[i0:i1])
        if np.count_nonzero(s1[2]) < 64:
            continue
        per = None if max_eval is None else max(1024, int(max_eval) // (2 * n_seg))
        fit = None
        for attempt in range(2):   # from the whole record's offset; if it lies too far, from the local peak
            if attempt:
                c = 0.5 * (a + b)
                start = _local_peak(*s1, t2, w2, ok2, (c - _SEGMENT_POINTS * h, c + _SEGMENT_POINTS * h), tau, width,
                                    h, gap1, gap2)
                if start is None:
                    break
                try:
                    spl2, x, y = _instants(*s1, t2, w2, ok2, he, h, gap1, gap2, per, [start])
                except TimeAlignmentError:
                    break
            else:   # the whole record's instants in this stretch, its splines (built for offsets near tau):
                start, spl2 = tau, fitted[0]   # Newton steps on the profiled misfit while they stay small
                j0, j1 = np.searchsorted(fitted[1], [a, b])
                x, y = fitted[1][j0:j1], fitted[2][j0:j1]
                if x.size < 64:
                    continue
                tk = tau
                for k in range(4):   # the first from the whole record's linearisation at tau
                    sk, step = (lin.within(a, b).std_step()[:2] if k == 0 else
                                _offset_std(spl2, x, y, tk, h, newton=True))
                    if not (np.isfinite(step) and abs(step) <= 0.5 * h):
                        break
                    tk += step
                    if abs(step) <= max(0.1 * sk, 1e-3 * h):   # the next step: ~step^2 / h, far below the std
                        fit = (tk, x, sk)
                        break
                if fit is not None:
                    break
            try:
                tk, xe, _, _ = _refine(spl2, x, y, start, h)
                fit = (tk, xe, _offset_std(spl2, x, y, tk, h))
                break
            except TimeAlignmentError:
                continue
        if fit is None:
            continue
        tk, xe, sk = fit
        if not (np.isfinite(sk) and sk > 0):
            continue
        mids.append(float(xe.mean()))
        taus.append(tk)
        sds.append(sk)
        n_used += xe.size
    if len(taus) < 3:
        return None
    m, y, wgt = np.array(mids), np.array(taus), 1.0 / np.square(sds)
    mid = 0.5 * (lo + hi)
    X = np.c_[np.ones_like(m), m - mid]
    cov = np.linalg.inv(X.T @ (wgt[:, None] * X))
    coef = cov @ (X.T @ (wgt * y))
    chi2 = float(np.sum(wgt * (y - X @ coef) ** 2)) / (len(y) - 2)
    cov *= max(1.0, chi2)
    return (mid, float(coef[0]), float(np.sqrt(cov[0, 0])), 1e6 * float(coef[1]), 1e6 * float(np.sqrt(cov[1, 1])),
            (lo, hi), n_used)


# ---------------------------------------------------------------------------------------------- alignment
@dataclass(frozen=True)
class AlignedPair:
    """Two gyroscope streams on one time grid on gyro 1's clock.

    Attributes
    ----------
    t : ndarray, shape (M,)
        Grid instants on gyro 1's clock (s).
    omega_1, omega_2 : ndarray, shape (M, 3)
        Rates (rad/s) of gyro 1 and gyro 2 at ``t`` (NaN where a stream has no value there). On gyro 1's own
        timestamps (no ``rate_hz``), ``t`` and ``omega_1`` are read-only views of the caller's float64 arrays
        (no copy of a long record): changing those arrays later changes them.
    valid : ndarray of bool, shape (M,)
        True where both streams are valid.
    time_offset : TimeOffset or None
        The estimated offset (None when it was given).
    time_offset_s : float
        The offset applied: gyro 2's own time ``t - time_offset_s`` was sampled for grid time ``t`` (at
        ``reference_time_s`` when a clock drift is applied).
    clock_drift_ppm : float
        The clock drift applied (1e-6 s per s; 0 when none): gyro 2 is sampled at its own time
        ``t - time_offset_s - clock_drift_ppm 1e-6 (t - reference_time_s)``.
    reference_time_s : float
        Where ``time_offset_s`` holds on gyro 1's clock (the middle of the overlap).
    timestamp_quality : tuple of TimestampQuality
        The diagnosis of each stream's timestamps (:func:`~fusion_gyrocal.pipeline.streams.timestamp_quality`).
    notes : tuple of str
        What was repaired or masked before the alignment (out-of-place or bursty timestamps, rate glitches).
    """

    t: np.ndarray = field(repr=False)
    omega_1: np.ndarray = field(repr=False)
    omega_2: np.ndarray = field(repr=False)
    valid: np.ndarray = field(repr=False)
    time_offset: TimeOffset | None
    time_offset_s: float
    clock_drift_ppm: float = 0.0
    reference_time_s: float = 0.0
    timestamp_quality: tuple = ()
    notes: tuple = ()

    def __post_init__(self):
        _freeze(self, ("t", "omega_1", "omega_2", "valid"), views=("t", "omega_1"))

    @property
    def n_valid(self) -> int:
        """Number of grid points valid in both streams."""
        return int(np.count_nonzero(self.valid))

    def moments(self, mask=None) -> Moments:
        """:class:`Moments` of the valid samples (and of ``mask``, e.g. :func:`informative_mask`)."""
        keep = self.valid if mask is None else self.valid & np.asarray(mask, dtype=bool)
        return Moments.from_samples(self.omega_1, self.omega_2, mask=keep)

    def calibration_fields(self, notes: tuple = ()) -> dict:
        """What the alignment adds to a :class:`~fusion_gyrocal.core.model.PairCalibration`: the clock drift, the
        timestamp diagnosis and its notes after ``notes``."""
        est = self.time_offset
        return {"clock_drift_ppm": self.clock_drift_ppm,
                "clock_drift_std_ppm": est.drift_std_ppm if est is not None and self.clock_drift_ppm else 0.0,
                "timestamp_quality": tuple(q.summary() for q in self.timestamp_quality),
                "notes": tuple(notes) + tuple(n for n in self.notes if n not in notes)}


#: A uniform ``rate_hz`` grid may hold at most this many times the samples of the densest recording (plus
#: :data:`_GRID_SLACK`): resampling beyond that adds no information, only memory.
MAX_GRID_UPSAMPLING = 4
_GRID_SLACK = 64


def _grid(t1, lo: float, hi: float, rate_hz, n_data: int | None = None):
    """The common time grid over ``[lo, hi]`` on gyro 1's clock: gyro 1's own instants (``keep``: the slice of them)
    or a uniform ``rate_hz`` grid (``keep`` None), of at most :data:`MAX_GRID_UPSAMPLING` times the samples of
    the densest recording (``n_data``, default gyro 1's)."""
    if rate_hz is None:
        keep = slice(int(np.searchsorted(t1, lo, side="left")), int(np.searchsorted(t1, hi, side="right")))
        return t1[keep], keep
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise OptionError(f"rate_hz: expected a positive rate, got {rate_hz!r}")
    limit = MAX_GRID_UPSAMPLING * int(n_data or len(t1)) + _GRID_SLACK
    if (hi - lo) * rate_hz + 1 > limit:
        raise OptionError(f"rate_hz: expected at most {(limit - 1) / (hi - lo):.6g} Hz ({MAX_GRID_UPSAMPLING}x the "
                          f"samples of the densest recording over the common {hi - lo:.6g} s), got {rate_hz!r}")
    return lo + np.arange(int(np.floor((hi - lo) * rate_hz + 1e-9)) + 1) / float(rate_hz), None


def _rate_glitches(w: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Samples whose rate norm is ``GLITCH_FACTOR`` times the 99th percentile of the stream's valid norms (a comms
    glitch; the level from a bounded subsample, the pass chunked)."""
    from .flex import GLITCH_FACTOR

    step = max(1, w.shape[0] // (1 << 16))
    sub = row_norms(w[::step][ok[::step]])
    out = np.zeros(w.shape[0], dtype=bool)
    if sub.size < 100:
        return out
    lim2 = (GLITCH_FACTOR * float(np.quantile(sub, 0.99))) ** 2      # squared norms against it: no square roots
    with np.errstate(invalid="ignore"):
        top = max(abs(float(np.max(w))), abs(float(np.min(w))))        # NaN where a rate is (then the full pass)
    if 3.0 * top * top * (1.0 + 1e-9) < lim2:   # the usual case: no row's squared norm (rounded) can reach it
        return out
    for lo in range(0, w.shape[0], _NORM_BLOCK):
        with np.errstate(invalid="ignore"):
            out[lo:lo + _NORM_BLOCK] = row_sumsq(w[lo:lo + _NORM_BLOCK]) > lim2
    out &= ok
    return out


def _prepared(name_t, t, name_w, omega, valid, notes: list):
    """A stream for the alignment: checked and repaired (:func:`~fusion_gyrocal.pipeline.streams.timed_stream`),
    gross rate glitches masked; what was done is appended to ``notes``."""
    tt, w, ok, q, said = timed_stream(name_t, t, name_w, omega, valid)
    notes.extend(said)
    glitch = _rate_glitches(w, ok)
    n = int(np.count_nonzero(glitch))
    if n and n <= 0.01 * w.shape[0]:
        ok = ok & ~glitch
        notes.append(f"{name_w}: {n} rate glitch(es) (norm over 10x the stream's 99th percentile, first at sample "
                     f"{int(np.argmax(glitch))}) masked before the alignment")
    return tt, w, ok, q


def _period(t, q) -> float:
    """A prepared stream's nominal sample period (from its diagnosis; bursty streams: of the fitted clock)."""
    return q.period_s if q is not None and not q.bursty else _nominal_period(t)


def _offset_of(s1, s2, time_offset_s, max_offset_s, max_eval, notes: list):
    """``(offset, drift_ppm, reference_time_s, TimeOffset or None)`` of two prepared streams ``(t, w, ok, quality)``:
    estimated (the refusal naming the timestamp diagnosis) unless ``time_offset_s`` is given."""
    (t1, w1, ok1, q1), (t2, w2, ok2, q2) = s1, s2
    if time_offset_s is not None:
        tau = float(time_offset_s)
        if not np.isfinite(tau):
            raise OptionError(f"time_offset_s: expected a finite offset in seconds, got {time_offset_s!r}")
        return tau, 0.0, 0.0, None
    quality = tuple(q for q in (q1, q2) if q is not None)
    try:
        est = _estimate(t1, w1, ok1, t2, w2, ok2, max_offset_s, 0.5, max_eval,
                        periods=(_period(t1, q1), _period(t2, q2)))
    except TimeAlignmentError as exc:
        if not quality:
            raise
        raise TimeAlignmentError(f"{exc}. Timestamps: " + " | ".join(q.summary() for q in quality)) from None
    if not est.drift_compensated:
        return est.offset_s, 0.0, 0.0, est
    notes.append(f"clock drift {est.drift_ppm:+.3f} +- {est.drift_std_ppm:.3f} ppm between the gyros' clocks "
                 f"compensated (the offset {1e3 * est.offset_s:+.4f} ms holds at gyro-1 time "
                 f"{est.reference_time_s:.6g} s)")
    return est.offset_s, est.drift_ppm, est.reference_time_s, est


def align_streams(t_1, omega_1, t_2, omega_2, *, time_offset_s: float | None = None,
                  max_offset_s: float | None = None, rate_hz: float | None = None, valid_1=None, valid_2=None,
                  max_eval: int | None = MAX_EVAL) -> AlignedPair:
    """Put two gyroscope streams on one time grid on gyro 1's clock.

    The offset (and the clock drift) is estimated with :func:`estimate_time_offset` unless ``time_offset_s`` is
    given. Gyro 2's sample taken at its own time ``t2`` happened at ``t2 + offset`` on gyro 1's clock,
    so gyro 2 is resampled (:func:`resample`) at ``t - offset(t)`` for every grid time ``t``. Before that each
    stream's timestamps are diagnosed (:class:`~fusion_gyrocal.pipeline.streams.TimestampQuality`) and repaired
    where they can be (isolated out-of-place stamps masked, bursty ones replaced by a fitted steady clock), and
    gross rate glitches are masked; ``notes`` says what was done.

    Parameters
    ----------
    t_1, omega_1, t_2, omega_2 : array_like
        Timestamps (s, each on its own clock) and rates (rad/s) of both gyros.
    time_offset_s : float, optional
        Known offset (added to gyro 2's timestamps to put them on gyro 1's clock).
    max_offset_s : float or None
        Search range of the estimate (None: every offset that leaves half the shorter recording overlapping:
        independent clocks may differ by hours).
    rate_hz : float, optional
        Uniform grid rate; both streams are then resampled. Default: gyro 1's own timestamps
        (gyro 1 is not interpolated).
    valid_1, valid_2 : array_like of bool, optional
        Usable samples of each stream (non-finite samples are always excluded).
    max_eval : int or None
        Most instants of the offset refinement (see :func:`estimate_time_offset`).

    Returns
    -------
    AlignedPair
        Restricted to the time span where both streams have data.

    Raises
    ------
    InputError, TimeAlignmentError
        See :func:`estimate_time_offset`; also when the streams do not overlap after alignment. The messages
        name the timestamp diagnosis of both streams.
    """
    notes: list = []
    t1, w1, ok1, q1 = _prepared("t_1", t_1, "omega_1", omega_1, valid_1, notes)
    t2, w2, ok2, q2 = _prepared("t_2", t_2, "omega_2", omega_2, valid_2, notes)
    tau, drift, ref, est = _offset_of((t1, w1, ok1, q1), (t2, w2, ok2, q2), time_offset_s, max_offset_s, max_eval,
                                      notes)
    p1, p2 = _period(t1, q1), _period(t2, q2)
    quality = tuple(q for q in (q1, q2) if q is not None)
    k = 1e-6 * drift
    # gyro 2's own span mapped to gyro 1's clock: t = (s + tau - k ref) / (1 - k)
    lo = max(t1[0], (t2[0] + tau - k * ref) / (1.0 - k))
    hi = min(t1[-1], (t2[-1] + tau - k * ref) / (1.0 - k))
    if not hi > lo:
        raise TimeAlignmentError(f"the streams do not overlap after applying the offset {tau:+.6g} s: gyro 1 covers "
                                 f"[{t1[0]:.6g}, {t1[-1]:.6g}] s, gyro 2 [{t2[0] + tau:.6g}, {t2[-1] + tau:.6g}] s")
    grid, keep = _grid(t1, lo, hi, rate_hz, max(len(t1), len(t2)))
    if keep is not None:                    # gyro 1 on its own timestamps: read-only views, no copy of the record
        o1 = w1[keep]
        v1 = ok1[keep]
    else:
        o1, v1 = _resample_checked(t1, w1, ok1, grid, DEFAULT_GAP_PERIODS * p1)
    query = grid - tau if k == 0.0 else grid - tau - k * (grid - ref)
    o2, v2 = _resample_checked(t2, w2, ok2, query, DEFAULT_GAP_PERIODS * p2)
    del query
    v2 &= v1
    for arr in (grid, o1, o2, v2):       # ours or read-only views (the caller's arrays stay writeable)
        arr.flags.writeable = False
    return AlignedPair(grid, o1, o2, v2, est, tau, drift, ref, quality, tuple(notes))


@dataclass(frozen=True)
class AlignedArray:
    """N gyros on one grid on gyro 1's clock.

    ``omegas`` (M, N, 3) rad/s (zero where ``valid`` is False), ``t`` (M,) on gyro 1's clock, and per gyro
    the offset ADDED to its timestamps, its std, and where it came from; the clock drift applied to each
    (ppm, None: none) and what was repaired or masked (``notes``, as :attr:`AlignedPair.notes`).
    """

    t: np.ndarray
    omegas: np.ndarray
    valid: np.ndarray
    time_offset_s: np.ndarray
    time_offset_std_s: np.ndarray
    time_offset_source: tuple
    clock_drift_ppm: np.ndarray | None = None
    notes: tuple = ()


def align_to_reference(ts, omegas, *, time_offset_s=None, max_offset_s: float | None = None, rate_hz=None,
                       saturation_limit=None) -> AlignedArray:
    """Put N streams on gyro 1's clock and one grid.

    Streams on one clock (identical timestamps, e.g. a multi-IMU npz) are sample-aligned as they are.
    Otherwise every stream is diagnosed and repaired as in :func:`align_streams`, every gyro k is aligned to
    gyro 1 (the reference: its offset and clock drift estimated, or ``time_offset_s`` for every gyro) and all
    are resampled onto gyro 1's timestamps (or a ``rate_hz`` grid) over the span every gyro covers.

    Parameters
    ----------
    ts, omegas : sequences of N arrays (M_k,) s and (M_k, 3) rad/s
        Each gyro's timestamps and rates (NaN where not measured); gyro 1 first.
    time_offset_s, max_offset_s, rate_hz
        As the options of the same names (:class:`~fusion_gyrocal.options.Options`).
    saturation_limit : sequence of N floats or None, optional
        Sensor ranges for :func:`~fusion_gyrocal.pipeline.streams.valid_mask`.

    Raises
    ------
    OptionError
        ``time_offset_s``, ``max_offset_s`` or ``rate_hz`` for recordings that share one clock.
    TimeAlignmentError
        An offset cannot be estimated, or the gyros have no common span.
    """
    n = len(ts)
    w = list(omegas)
    limits = [None] * n if saturation_limit is None else list(saturation_limit)
    ok = [valid_mask(wk, limit=lim) for wk, lim in zip(w, limits)]
    t1 = np.asarray(ts[0], dtype=float)
    if all(np.shape(t) == t1.shape and np.array_equal(t, t1) for t in ts[1:]):
        timing = [name for name, v in (("time_offset_s", time_offset_s), ("max_offset_s", max_offset_s),
                                       ("rate_hz", rate_hz)) if v is not None]
        if timing:
            raise OptionError(f"{', '.join(timing)}: act on separate clocks; expected recordings with their own "
                              "timestamps, got gyros that share one clock (identical timestamps)")
        valid = np.logical_and.reduce(ok)
        omegas = np.stack([np.where(valid[:, None], wk, 0.0) for wk in w], axis=1)
        return AlignedArray(t1, omegas, valid, np.zeros(n), np.zeros(n),
                            ("reference",) + ("one clock",) * (n - 1))
    notes: list = []
    streams = [_prepared(f"t_{k + 1}", ts[k], f"omega_{k + 1}", w[k], ok[k], notes) for k in range(n)]
    tau, std, drift, ref, source = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), ["reference"]
    for k in range(1, n):
        tau[k], drift[k], ref[k], est = _offset_of(streams[0], streams[k], time_offset_s, max_offset_s, MAX_EVAL,
                                                   notes)
        std[k] = est.std_s if est is not None else 0.0
        source.append("estimated" if est is not None else "given")
    c = 1e-6 * drift
    lo = max((t[0] + tau[k] - c[k] * ref[k]) / (1.0 - c[k]) for k, (t, *_) in enumerate(streams))
    hi = min((t[-1] + tau[k] - c[k] * ref[k]) / (1.0 - c[k]) for k, (t, *_) in enumerate(streams))
    if not hi > lo:
        raise TimeAlignmentError(f"the {n} recordings have no common time span after applying the offsets "
                                 f"{np.round(tau, 6).tolist()} s")
    ts1 = streams[0][0]
    grid, keep = _grid(ts1, lo, hi, rate_hz, max(len(st[0]) for st in streams))
    if keep is not None:
        cols, oks, start = [np.asarray(streams[0][1][keep])], [streams[0][2][keep]], 1
        grid = grid.copy()
    else:
        cols, oks, start = [], [], 0
    for k in range(start, n):
        tk, wk, okk, qk = streams[k]
        query = grid - tau[k] - c[k] * (grid - ref[k])
        wk, vk = _resample_checked(tk, wk, okk, query, DEFAULT_GAP_PERIODS * _period(tk, qk))
        cols.append(wk)
        oks.append(vk)
    valid = np.logical_and.reduce(oks)
    omegas = np.stack([np.where(valid[:, None], c, 0.0) for c in cols], axis=1)
    return AlignedArray(grid, omegas, valid, tau, std, tuple(source), drift, tuple(notes))
