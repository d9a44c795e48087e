"""Flex and outlier rejection (the paper's Section VI.C), in bounded memory.

The paper runs the calibration once, computes the residuals ``r(k)`` (Eq. 42), removes samples
whose residual exceeds three standard deviations together with their neighbours (hysteresis of
the flex onset), and runs the calibration again. Here:

* the residual is that of the unconstrained least-squares A (Eq. 17), which absorbs any linear
  model error (skew, misalignment), so the gate sees noise plus non-linear, time-varying effects;
* the gate is the 3-sigma gate in its 3-D form (chi-square with 3 dof at the same 0.27% false-alarm
  rate) with a robust covariance (median of the squared Mahalanobis distances), iterated;
* flex that grows smoothly with the rate, too small per sample for the gate, is found by binning
  the normalised residual by rate (:func:`flex_rate_cut`);
* decisions are taken on a subsample of blocks (about 30k samples), and full passes run only
  when rejection is needed, so the cost on clean data does not grow with N.
"""

from __future__ import annotations

import numpy as np

CHI2_3_MEDIAN = 2.365973884375338   # median of chi-square with 3 dof
CHI2_3_GATE = 14.156413609126677    # chi2.ppf(0.9973, 3): the 3-sigma false-alarm rate in 3-D


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


def residual_blocks(w1, w2, A, bias, mask, window, ranges):
    """Yield ``(start, r, used)`` with ``r = omega_1 - A omega_2 - b`` per block (per-window bias if windowed)."""
    At = np.ascontiguousarray(np.asarray(A, float).T)
    for start, stop in ranges:
        r = np.asarray(w1[start:stop], dtype=np.float64) - np.asarray(w2[start:stop], dtype=np.float64) @ At
        used = np.ones(stop - start, bool) if mask is None else np.asarray(mask[start:stop], bool)
        if not window:
            r -= bias
        else:
            w = int(window)
            for k in range(0, stop - start, w):
                u = used[k:k + w]
                if u.any():
                    r[k:k + w] -= r[k:k + w][u].mean(axis=0)
        yield start, r, used


def robust_whitener(w1, w2, A, bias, mask, window, ranges) -> np.ndarray:
    """``L`` with ``||r @ L||^2`` chi-square(3)-distributed for inliers (robust scale by the median)."""
    sample = np.concatenate([r[u] for _, r, u in residual_blocks(w1, w2, A, bias, mask, window, ranges)])
    C = np.cov(sample.T) + 1e-300 * np.eye(3)
    L = np.linalg.cholesky(np.linalg.inv(C))
    d2 = ((sample @ L) ** 2).sum(axis=1)
    return L * np.sqrt(CHI2_3_MEDIAN / max(float(np.median(d2)), 1e-300))


def outliers(w1, w2, A, bias, mask, window, ranges, L) -> np.ndarray:
    """Indices of used samples beyond the gate."""
    out = []
    for start, r, used in residual_blocks(w1, w2, A, bias, mask, window, ranges):
        out.append(start + np.flatnonzero(used & (((r @ L) ** 2).sum(axis=1) > CHI2_3_GATE)))
    return np.concatenate(out) if out else np.zeros(0, int)


def dilate(idx: np.ndarray, margin: int, n: int) -> np.ndarray:
    """Sorted unique indices within ``margin`` samples of ``idx`` (the paper's neighbouring samples)."""
    if idx.size == 0:
        return idx
    out = (idx[:, None] + np.arange(-margin, margin + 1)[None, :]).ravel()
    return np.unique(out[(out >= 0) & (out < n)])


def normalised_residuals(w1, w2, A, bias, mask, window, ranges, L):
    """``(d2, rate)`` of the used samples in ``ranges``: squared whitened residual and gyro 1's rate norm."""
    d2, rate = [], []
    for start, r, used in residual_blocks(w1, w2, A, bias, mask, window, ranges):
        d2.append(((r[used] @ L) ** 2).sum(axis=1))
        rate.append(np.linalg.norm(np.asarray(w1[start:start + len(r)], dtype=np.float64)[used], axis=1))
    return np.concatenate(d2), np.concatenate(rate)


def flex_rate_cut(d2: np.ndarray, rate: np.ndarray, bins: int = 20) -> float | None:
    """Rate from which the residual grows with the rate in flex bursts, or None.

    The samples are split into ``bins`` equal-count bins of rate. A bin is inflated when its mean
    normalised squared residual exceeds that of the slower half by more than 5 standard errors.
    If the fastest bins are inflated, the cut is the lowest rate of the consecutive inflated top
    bins. Flex comes in bursts at the fastest motion: when the inflation reaches below the
    fastest fifth of the samples, the residual grows with the rate everywhere (a model error such
    as a sampling skew between the gyros, not flex) and there is no cut.
    """
    if d2.size < 20 * bins:
        return None
    order = np.argsort(rate)
    groups = np.array_split(order, bins)
    means = np.array([d2[g].mean() for g in groups])
    ref = np.median(means[: bins // 2])
    se = ref * np.sqrt(2.0 / (3.0 * len(groups[0])))  # chi-square(3) / 3 per sample, mean over a bin
    inflated = means > ref + 5.0 * se
    if not inflated[-1]:
        return None
    first = bins - 1
    while first > 0 and inflated[first - 1]:
        first -= 1
    if first < bins - bins // 5:
        return None
    return float(rate[groups[first][0]])


def above_rate(w1, cut: float, n: int, chunk: int = 65536) -> np.ndarray:
    """Boolean mask of samples whose gyro-1 rate norm is at least ``cut`` (chunked)."""
    out = np.zeros(n, bool)
    for s in range(0, n, chunk):
        out[s:s + chunk] = np.linalg.norm(np.asarray(w1[s:s + chunk], dtype=np.float64), axis=1) >= cut
    return out


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman rank correlation (ties broken by order; the data are continuous)."""
    if x.size < 10:
        return float("nan")
    rx = np.empty(x.size)
    ry = np.empty(y.size)
    rx[np.argsort(x)] = np.arange(x.size)
    ry[np.argsort(y)] = np.arange(y.size)
    return float(np.corrcoef(rx, ry)[0, 1])
