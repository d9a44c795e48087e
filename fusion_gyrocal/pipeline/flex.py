"""Flex and outlier rejection (the paper's Section VI.C), in bounded memory.

The paper runs the calibration once, computes the residuals ``r(k)`` (Eq. 42), removes samples
whose residual exceeds three standard deviations together with their neighbours (hysteresis of
the flex onset), and runs the calibration again. Here (:func:`gate`, the one entry point):

* the residual is that of the unconstrained least-squares A (Eq. 17), which absorbs any linear
  model error (skew, misalignment), so the gate sees noise plus non-linear, time-varying effects;
* the gate is the 3-sigma gate in its 3-D form (chi-square with 3 dof at the same 0.27% false-alarm
  rate) with a robust covariance (median of the squared Mahalanobis distances), iterated;
* a residual that grows with the rate is told apart before anything is removed
  (:func:`rate_dependence`): flex is a rotation of the mounting, ``(Exp(phi) - I) C omega_2 ~
  phi x omega_1``, so its excess residual is perpendicular to the rate; a rate-dependent misfit of
  the sensors (scale non-linearity, cross-axis terms, timing jitter) puts a large part of its excess
  along the rate. Flex is cut from the rate where a rotation fitted per rate bin becomes
  significant (:func:`flex_cut`); a misfit keeps the fast motion (only gross glitches go);
* decisions are taken on a subsample of blocks (about 30k samples), and full passes run only
  when rejection is needed, so the cost on clean data does not grow with N.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..core.moments import finite_rows, median, row_norms, row_sumsq, rows_times

CHI2_3_MEDIAN = 2.365973884375338   # median of chi-square with 3 dof
CHI2_3_GATE = 14.156413609126677    # chi2.ppf(0.9973, 3): the 3-sigma false-alarm rate in 3-D
MAX_FLEX_SHARE = 0.15               # share of the rate-dependent excess along the rate below which it is a bend
#                                     (a rotation: 0; an excess without preferred direction: 1/3; a scale error: 1)
CHI2_3_BEND = 33.23982506341531    # chi2.isf(norm.sf(5), 3): a bend at 5 sigma in one rate bin
MEDIAN_REL_SE = 1.124               # std of the median of m chi-square(3) samples: ~ 1.124 / sqrt(m) x the median
SUBSAMPLE_POINTS = 30_000           # samples on which the gate decides
GLITCH_FACTOR = 10.0                # a gross outlier: this many times the 99th percentile of the log


def block_ranges(n: int, window: int | None, *, max_points: int | None = None, block: int = 4096):
    """Consecutive ``(start, stop)`` blocks covering ``n`` samples (aligned to bias windows);
    with ``max_points``, every k-th block so that about that many samples are covered."""
    size = block if not window else int(window) * max(1, -(-block // int(window)))
    starts = np.arange(0, n, size)
    if max_points is not None and n > max_points:
        starts = starts[:: int(np.ceil(n / max_points))]
    return [(int(s), int(min(s + size, n))) for s in starts]


def gather(ranges, *arrays):
    """The rows of ``ranges`` of each array, concatenated into one contiguous copy (None stays None).

    The decisions on the subsample then run as one vectorised block (``[(0, size)]``); blocks of
    :func:`block_ranges` are whole bias windows, so the windows stay aligned in the copy.
    """
    return tuple(None if a is None else np.concatenate([np.asarray(a[lo:hi]) for lo, hi in ranges])
                 for a in arrays)


def scatter_cov(x: np.ndarray) -> np.ndarray:
    """Sample covariance of the rows of ``x`` (N, 3) (as ``np.cov(x.T)``, by one product: residuals are
    centred near zero, so the uncentred sums lose nothing)."""
    n = x.shape[0]
    m = np.ones(n) @ x / n
    return (x.T @ x - n * np.outer(m, m)) / max(n - 1, 1)


def residual_blocks(w1, w2, A, bias, mask, window, ranges):
    """Yield ``(start, r, used)`` with ``r = omega_1 - A omega_2 - b`` per block (per-window bias if windowed).

    The products by :func:`~fusion_gyrocal.core.moments.rows_times` (``@`` bit for bit, without OpenBLAS's
    threads, which wait for each other on a busy host) and the difference into the product: one (N, 3) temporary."""
    At = np.ascontiguousarray(np.asarray(A, float).T)
    for start, stop in ranges:
        r = rows_times(w2[start:stop], At)
        np.subtract(np.asarray(w1[start:stop], dtype=np.float64), r, out=r)
        used = np.ones(stop - start, bool) if mask is None else np.asarray(mask[start:stop], bool)
        if not window:
            r -= bias
        else:
            r -= _window_means(r, used, int(window))
        yield start, r, used


def _window_means(r, used, w: int) -> np.ndarray:
    """Each sample's window mean of the used rows of ``r`` (N, 3), in consecutive windows of ``w`` rows (the last
    one partial); zero in windows without a used row. One reshaped sum over all windows, not a loop."""
    n = r.shape[0]
    w = max(1, min(w, n))           # a window longer than the rows: one window of all of them
    nw = -(-n // w)
    x = np.zeros((nw * w, 3))
    np.multiply(r, used[:, None], out=x[:n])   # unused rows add nothing
    cnt = np.zeros(nw * w)
    cnt[:n] = used
    cnt = cnt.reshape(nw, w).sum(axis=1)
    means = x.reshape(nw, w, 3).sum(axis=1) / np.maximum(cnt, 1.0)[:, None]
    return np.repeat(means, w, axis=0)[:n]


def robust_whitener(w1, w2, A, bias, mask, window, ranges, *, residuals=None) -> np.ndarray:
    """``L`` with ``||r @ L||^2`` chi-square(3)-distributed for inliers (robust scale by the median);
    ``residuals``: :func:`used_residuals` of the same arguments when the caller has them."""
    sample = (used_residuals(w1, w2, A, bias, mask, window, ranges) if residuals is None else residuals)[0]
    C = scatter_cov(sample) + 1e-300 * np.eye(3)
    L = np.linalg.cholesky(np.linalg.inv(C))
    d2 = row_sumsq(rows_times(sample, L))
    return L * np.sqrt(CHI2_3_MEDIAN / max(float(median(d2)), 1e-300))


def outliers(w1, w2, A, bias, mask, window, ranges, L) -> np.ndarray:
    """Indices of used samples beyond the gate."""
    out = []
    for start, r, used in residual_blocks(w1, w2, A, bias, mask, window, ranges):
        out.append(start + np.flatnonzero(used & (row_sumsq(rows_times(r, L)) > CHI2_3_GATE)))
    return np.concatenate(out) if out else np.zeros(0, int)


def dilate(idx: np.ndarray, margin: int, n: int) -> np.ndarray:
    """Sorted unique indices within ``margin`` samples of ``idx`` (the paper's neighbouring samples)."""
    if idx.size == 0:
        return idx
    out = (idx[:, None] + np.arange(-margin, margin + 1)[None, :]).ravel()
    return np.unique(out[(out >= 0) & (out < n)])


def used_residuals(w1, w2, A, bias, mask, window, ranges):
    """``(r, omega_1)`` of the used samples in ``ranges``: residuals (N_used, 3) and gyro 1's rates."""
    r, w = [], []
    for start, res, used in residual_blocks(w1, w2, A, bias, mask, window, ranges):
        rates = np.asarray(w1[start:start + len(res)], dtype=np.float64)
        whole = mask is None or used.all()   # no copies of the whole subsample
        r.append(res if whole else res[used])
        w.append(rates if whole else rates[used])
    return (r[0], w[0]) if len(r) == 1 else (np.concatenate(r), np.concatenate(w))


def normalised_residuals(w1, w2, A, bias, mask, window, ranges, L):
    """``(d2, rate)`` of the used samples in ``ranges``: squared whitened residual and gyro 1's rate norm."""
    r, w = used_residuals(w1, w2, A, bias, mask, window, ranges)
    return row_sumsq(rows_times(r, L)), row_norms(w)


def _rate_bins(d2: np.ndarray, rate: np.ndarray, bins: int, order: np.ndarray | None = None):
    """Equal-count bins of rate: ``(groups, medians, ref, inflated)``; a bin is inflated when its median
    normalised squared residual exceeds ``ref`` (that of the slower half) by more than 5 standard errors.

    Medians, so that a few spikes (outliers for the 3-sigma gate) do not make a bin grow with the rate.
    ``order`` is ``argsort(rate)`` when the caller has it.
    """
    groups = np.array_split(np.argsort(rate) if order is None else order, bins)
    medians = np.array([median(d2[g]) for g in groups])
    ref = median(medians[: bins // 2])
    se = ref * MEDIAN_REL_SE / np.sqrt(len(groups[0]))
    return groups, medians, ref, medians > ref + 5.0 * se


def bend_per_bin(r: np.ndarray, w: np.ndarray, W: np.ndarray, bins: int = 20):
    """The small rotation that best explains the residuals of each rate bin, and its significance.

    Flex bends the mounting by ``phi``, so the residual is ``r ~ phi x omega_1 = -[omega_1 x] phi``.
    The samples are split into ``bins`` equal-count bins of gyro 1's rate norm and in each bin
    ``phi`` is fitted by weighted least squares (weight ``W``, the residual's inverse covariance);
    ``chi2 = phi' M phi`` (``M`` the bin's information) is chi-square(3)-distributed for a rigid pair.
    Fitting the rotation averages the bend coherently over a bin, so it finds bends far smaller
    than the growth of the squared residual does.

    Returns
    -------
    (edges, chi2, phi) : ndarray (bins,), (bins,), (bins, 3)
        The lowest rate of each bin, the chi-square of its rotation and the rotation (rad).
    """
    from ..lie import skew

    rate = row_norms(w)
    order = np.argsort(rate)
    starts = np.array([g[0] for g in np.array_split(np.arange(order.size), bins)])
    J = -skew(w[order])                                           # r = J phi
    JW = np.einsum("nki,kl->nil", J, W)
    M = np.add.reduceat(np.einsum("nil,nlj->nij", JW, J), starts, axis=0)
    g = np.add.reduceat(np.einsum("nil,nl->ni", JW, r[order]), starts, axis=0)
    phi = np.linalg.solve(M + 1e-300 * np.eye(3), g[..., None])[..., 0]
    return rate[order][starts], np.einsum("bi,bi->b", g, phi), phi


def flex_rate_cut(edges: np.ndarray, chi2: np.ndarray, max_share: float = 0.05) -> float | None:
    """Rate from which the mounting bends, from :func:`bend_per_bin`, or None.

    A bin is bent when the chi-square of its rotation exceeds :data:`CHI2_3_BEND` (5 sigma). If the
    fastest bin is bent, the cut is the lowest rate of the consecutive bent top bins, but never below
    the fastest ``max_share`` of the samples in one step (:func:`flex_cut` looks again after each cut).
    """
    bent = chi2 > CHI2_3_BEND
    if not bent[-1]:
        return None
    bins = bent.size
    first = bins - 1
    while first > bins - max(1, int(round(max_share * bins))) and bent[first - 1]:
        first -= 1
    return float(edges[first])


def _subsample_A(g1, g2, used, window):
    """Least-squares ``(A, b)`` (Eq. 17) of the used samples of the subsample (per-window biases pooled)."""
    from ..core.direct import solve_A
    from ..core.moments import Moments, window_moments

    if not window:
        return solve_A(Moments.from_samples(g1, g2, mask=used))
    return solve_A(Moments.pool_all(window_moments(g1, g2, int(window), mask=used)))


def flex_cut(g1, g2, A, bias, used, window, L, bins: int = 20, max_steps: int = 20) -> float | None:
    """Rate above which the subsample ``g1, g2`` is bent (flex), or None: :func:`flex_rate_cut` repeated.

    A bend above the cut also tilts the least-squares A (Eq. 17) fitted with it, which hides the
    smaller bends just below the cut. So after each cut A and the whitener are fitted again on the
    slower samples and the bend is looked for again, until the fastest kept bin is no longer bent
    (at most ``max_steps`` times; each step works on the subsample only).
    """
    base = np.ones(g1.shape[0], bool) if used is None else np.asarray(used, bool)
    rate = row_norms(g1)
    whole = [(0, g1.shape[0])]
    cut, kept = None, used
    for _ in range(max_steps):
        r, w = used_residuals(g1, g2, A, bias, kept, window, whole)
        if r.shape[0] < 20 * bins:
            break
        step = flex_rate_cut(*bend_per_bin(r, w, L @ L.T, bins)[:2])
        if step is None:
            break
        cut = step
        with np.errstate(invalid="ignore"):
            kept = base & (rate < cut)
        A, bias = _subsample_A(g1, g2, kept, window)
        L = robust_whitener(g1, g2, A, bias, kept, window, whole)
    return cut


class RateDependence(NamedTuple):
    """How the residual grows with the rate (:func:`rate_dependence`).

    ``along_rate`` is the share of the excess residual power (above the noise) that lies along the
    rate, in the inflated rate bins: 0 for a bend, about 1/3 for an excess without a preferred
    direction, 1 for a rate-dependent scale error. ``level`` is the median squared whitened residual of
    the fastest bin over that of the slower half (1 without growth).
    """

    along_rate: float
    level: float

    @property
    def is_flex(self) -> bool:
        """The excess is a rotation of the mounting (across the rate)."""
        return self.along_rate < MAX_FLEX_SHARE


def along_rate_share(r: np.ndarray, w: np.ndarray, noise_cov: np.ndarray) -> float:
    """Share of the excess power of the residuals ``r`` (N, 3) that lies along the rates ``w`` (N, 3).

    Flex bends the mounting by a small rotation ``phi``, so the residual ``phi x omega`` is
    perpendicular to the rate; the noise (covariance ``noise_cov``) puts ``u' C u`` along each rate
    direction ``u`` and the rest across it, and is subtracted from both parts before the share is taken.
    """
    s = row_norms(w)
    ok = s > 0
    u = w[ok] / s[ok, None]
    r = r[ok]
    along = (r * u).sum(axis=1) ** 2
    noise_along = np.einsum("ni,ij,nj->n", u, noise_cov, u)
    ex_along = float(along.sum() - noise_along.sum())
    ex_across = float(((r * r).sum(axis=1) - along).sum() - (np.trace(noise_cov) * u.shape[0] - noise_along.sum()))
    ex_along, ex_across = max(ex_along, 0.0), max(ex_across, 0.0)
    return ex_along / (ex_along + ex_across) if ex_along + ex_across > 0 else 0.0


def rate_dependence(w1, w2, A, bias, mask, window, ranges, L, bins: int = 20,
                    order: np.ndarray | None = None, *, residuals=None) -> RateDependence | None:
    """How the residual grows with the rate, or None when it does not (no inflated rate bin).

    The used samples of ``ranges`` (the subsample) are binned by gyro 1's rate norm (20 equal-count
    bins; a bin is inflated when its median squared whitened residual exceeds that of the slower half
    by 5 standard errors); in the inflated bins the share of the excess residual along the rate is
    measured (:func:`along_rate_share`) against the noise covariance of the slower half. ``order``: the
    argsort of those samples' rate norms, when the caller has it (:class:`RateOrder`); ``residuals``:
    :func:`used_residuals` of the same arguments when the caller has them.
    """
    r, w = used_residuals(w1, w2, A, bias, mask, window, ranges) if residuals is None else residuals
    d2, rate = row_sumsq(rows_times(r, L)), row_norms(w)
    if d2.size < 20 * bins:
        return None
    groups, means, ref, inflated = _rate_bins(d2, rate, bins, order)
    if not inflated.any():
        return None
    fast = np.concatenate([g for g, f in zip(groups, inflated) if f])
    slow = np.concatenate(groups[: bins // 2])
    share = along_rate_share(r[fast], w[fast], np.atleast_2d(np.cov(r[slow].T)))
    return RateDependence(share, float(means[-1] / ref))


def above_rate(w1, cut: float, n: int, chunk: int = 65536) -> np.ndarray:
    """Boolean mask of samples whose gyro-1 rate norm is at least ``cut`` (chunked)."""
    out = np.zeros(n, bool)
    for s in range(0, n, chunk):
        out[s:s + chunk] = row_norms(w1[s:s + chunk]) >= cut
    return out


class RateOrder:
    """The argsort of gyro 1's rate norm over a subsample, sorted once and restricted to any mask of it (the
    ranks of the rate bins of :func:`rate_dependence` and of :func:`spearman`)."""

    def __init__(self, g1: np.ndarray):
        self.order = np.argsort(row_norms(g1))

    def of(self, used: np.ndarray | None) -> np.ndarray:
        """``argsort`` of the rate norms of the ``used`` samples (indices into the used samples)."""
        if used is None or used.all():
            return self.order
        pos = np.cumsum(used) - 1
        return pos[self.order[used[self.order]]]


def spearman(x: np.ndarray, y: np.ndarray, y_order: np.ndarray | None = None) -> float:
    """Spearman rank correlation (the data are continuous; ties in any order); ``y_order`` is ``argsort(y)``
    when the caller has it."""
    if x.size < 10:
        return float("nan")
    rx = np.empty(x.size)
    ry = np.empty(y.size)
    rx[np.argsort(x)] = np.arange(x.size)
    ry[np.argsort(y) if y_order is None else y_order] = np.arange(y.size)
    return float(np.corrcoef(rx, ry)[0, 1])


def subsample_rate_norms(w1, w2, mask, max_points: int | None = 30_000):
    """Rate norms ``(n1, n2)`` of the usable samples of a bounded subsample of the log (about 30k samples)."""
    g1, g2, gm = gather(block_ranges(len(w1), None, max_points=max_points), w1, w2, mask)
    g1, g2 = np.asarray(g1, dtype=np.float64), np.asarray(g2, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):   # beyond ~1e154 the norms are inf: refused by check_rate_units
        n1, n2 = row_norms(g1), row_norms(g2)
    ok = finite_rows(g1) & finite_rows(g2)
    if gm is not None:
        ok &= gm
    return (n1, n2) if ok.all() else (n1[ok], n2[ok])


def gross_outliers(w1, w2, mask=None, chunk: int = 65536) -> np.ndarray:
    """Samples whose rate norm (of either gyro, or their difference) is :data:`GLITCH_FACTOR` times the
    99th percentile of the log's (a comms glitch), as a bool mask of shape (N,).

    The levels come from a bounded subsample; the pass over the log is chunked. A rigid pair has
    equal rate norms up to scale factors and bias, so a glitch in one stream shows in the difference.
    """
    n1, n2 = subsample_rate_norms(w1, w2, mask)
    if n1.size == 0:
        return np.zeros(len(w1), bool)
    lim_rate = GLITCH_FACTOR * float(np.quantile(np.maximum(n1, n2), 0.99))
    lim_diff = GLITCH_FACTOR * float(np.quantile(np.abs(n1 - n2), 0.99))
    out = np.zeros(len(w1), bool)
    for s in range(0, len(w1), chunk):
        a, b = (row_norms(w[s:s + chunk]) for w in (w1, w2))
        with np.errstate(invalid="ignore"):
            out[s:s + chunk] = (np.maximum(a, b) > lim_rate) | (np.abs(a - b) > lim_diff)
    if mask is not None:
        out &= mask
    return out


def gate(w1, w2, mask, cal, mom, bias, solve_on, options):
    """The flex and outlier gate (Section VI.C, Eq. 42): the samples to keep and the pair solved on them.

    1. On a subsample (about 30k samples, :func:`block_ranges`), the residuals of the least-squares A
       (Eq. 17) are whitened robustly (:func:`robust_whitener`) and binned by rate
       (:func:`rate_dependence`). If they grow with the rate with at least :data:`MAX_FLEX_SHARE` of
       the excess along the rate, and still do once the 3-sigma outliers of the subsample are set aside
       and A fitted again (a few spikes tilt A, which also makes the residual grow with the rate), it
       is a rate-dependent misfit, not flex: only gross outliers
       (:func:`gross_outliers`, comms glitches) are removed, the
       fast motion is kept and a note says so.
    2. Otherwise, the 3-sigma gate in 3-D, iterated with the neighbours of each outlier
       (``flex_margin``), when more than 1% of the subsample is beyond it (``flex_rejection="auto"``)
       or always (True); then the samples above the rate from which the mounting bends
       (:func:`flex_cut`: a rotation fitted per rate bin).
    3. The pair is solved again on the kept samples if they retain ``min_kept_energy`` of gyro 1's
       motion energy; otherwise nothing is removed and a note says why.

    Parameters
    ----------
    w1, w2 : array_like (N, 3)
        Sample-aligned rates (rad/s); read only through ``mask``.
    mask : ndarray of bool (N,) or None
        Usable samples (None: all).
    cal : PairCalibration
        The pair solved on ``mask`` (from ``mom``).
    mom : Moments
        The moments of ``mask``.
    bias : BiasModel
        The run's bias model (:class:`~fusion_gyrocal.pipeline.bias.BiasModel`): the moments of the kept samples,
        and the residual windows the bias is removed over (``gate_window``; None: one bias).
    solve_on : callable
        ``solve_on(mask) -> PairCalibration``: the pair solved on those samples with the run's options, noise and
        bias model.
    options : Options
        ``flex_rejection``, ``flex_margin``, ``min_kept_energy``.

    Returns
    -------
    (cal, mask, rejected, corr)
        The calibration (solved again, or ``cal`` with a note), the samples it used, the fraction of
        the used samples rejected, and the Spearman correlation between the residual norm and the rate
        on the kept samples of the subsample.
    """
    from ..core.direct import solve_A

    o, gate_window = options, bias.gate_window
    n, n_used, keep = len(w1), cal.n_samples, mask
    mom0, notes = mom, []
    sub = block_ranges(n, gate_window, max_points=SUBSAMPLE_POINTS)
    g1, g2 = gather(sub, w1, w2)           # the subsample, copied once (about 30k samples)
    whole = [(0, g1.shape[0])]

    def on_sub(m):
        return gather(sub, m)[0]

    ranks = RateOrder(g1)
    A_ls, b_ls = solve_A(mom)
    sub_keep = on_sub(keep)
    first = used_residuals(g1, g2, A_ls, b_ls, sub_keep, gate_window, whole)   # read by the three steps below
    L = robust_whitener(g1, g2, A_ls, b_ls, sub_keep, gate_window, whole, residuals=first)
    grows = rate_dependence(g1, g2, A_ls, b_ls, sub_keep, gate_window, whole, L, order=ranks.of(sub_keep),
                            residuals=first)
    if grows is not None and not grows.is_flex:   # spikes tilt A too: is the growth still there without them?
        clean = np.ones(g1.shape[0], bool) if keep is None else sub_keep.copy()
        clean[dilate(outliers(g1, g2, A_ls, b_ls, sub_keep, gate_window, whole, L), o.flex_margin,
                     g1.shape[0])] = False
        A_c, b_c = _subsample_A(g1, g2, clean, gate_window)
        grows = rate_dependence(g1, g2, A_c, b_c, clean, gate_window, whole,
                                robust_whitener(g1, g2, A_c, b_c, clean, gate_window, whole), order=ranks.of(clean))
    if grows is not None and not grows.is_flex:
        glitch = gross_outliers(w1, w2, mask)
        if glitch.any():
            keep = ~glitch if keep is None else (keep & ~glitch)
            mom = bias.moments(w1, w2, keep)[0]
        notes.append(f"the residual grows with the rate (to {grows.level:.3g}x the noise level in the fastest "
                     f"twentieth) with {100 * grows.along_rate:.0f}% of its excess along the rate, which a bend of the "
                     "mounting (a rotation: residual across the rate) cannot give: a rate-dependent misfit of the "
                     "sensors (scale non-linearity, cross-axis terms, timing), not flex; the fast motion is kept "
                     f"({int(np.count_nonzero(glitch))} gross outlier sample(s) removed)")
    else:
        n_sub = g1.shape[0] if mask is None else int(np.count_nonzero(on_sub(mask)))
        if keep is None:     # every sample of the subsample used: its residuals are those above, in order
            n_out = int(np.count_nonzero(row_sumsq(rows_times(first[0], L)) > CHI2_3_GATE))
        else:
            n_out = outliers(g1, g2, A_ls, b_ls, sub_keep, gate_window, whole, L).size
        frac = n_out / max(n_sub, 1)
        if o.flex_rejection is True or frac > 0.01:  # the paper's gate, iterated until nothing new is rejected
            everything = block_ranges(n, gate_window)
            for _ in range(5):
                out = outliers(w1, w2, A_ls, b_ls, keep, gate_window, everything, L)
                if out.size == 0:
                    break
                gated = np.ones(n, bool) if keep is None else keep.copy()
                gated[dilate(out, o.flex_margin, n)] = False  # the outliers and their neighbours
                keep = gated
                mom = bias.moments(w1, w2, keep)[0]
                A_ls, b_ls = solve_A(mom)
                L = robust_whitener(g1, g2, A_ls, b_ls, on_sub(keep), gate_window, whole)
        # a bend shows as a residual growing with the rate; without that growth there is no rate to cut above
        cut = None if grows is None else flex_cut(g1, g2, A_ls, b_ls, on_sub(keep), gate_window, L)
        if cut is not None:
            fast = above_rate(w1, cut, n)
            keep = ~fast if keep is None else (keep & ~fast)
            mom = bias.moments(w1, w2, keep)[0]
    rejected = 0.0
    kept_energy = float(np.trace(mom.S11) / np.trace(mom0.S11)) if keep is not mask else 1.0
    if keep is not mask and kept_energy >= o.min_kept_energy:
        rejected = 1.0 - mom.count / max(n_used, 1)
        cal = solve_on(keep)
        mask = keep
    elif keep is not mask:
        notes.append(f"the residual grows with the rate across the motion (model error or flex everywhere): "
                     f"rejecting it would keep only {100 * kept_energy:.0f}% of the motion energy, so no sample was "
                     "rejected")
    if notes:
        import dataclasses
        cal = dataclasses.replace(cal, notes=cal.notes + tuple(notes))
    d2, rate = normalised_residuals(g1, g2, cal.A, cal.bias, on_sub(mask), gate_window, whole, np.eye(3))
    return cal, mask, rejected, spearman(np.sqrt(d2), rate, ranks.of(on_sub(mask)))
