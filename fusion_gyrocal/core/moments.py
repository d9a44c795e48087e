"""Sufficient statistics of a gyroscope pair: the one O(N) pass over the samples.

Everything downstream (direct solve, maximum-likelihood refinement, covariance, the
EKF seed, the GTSAM window factors, the streaming and distributed reductions) reads
only these few numbers, so the pass over raw samples is written once, here.

For the stacked sample ``x_k = [omega_1_meas(k); omega_2_meas(k)]`` (6,) the moments are
the sample count, the mean and the *centred* scatter ``sum_k (x_k - mean)(x_k - mean)^T``.
Centring happens per chunk and chunks are combined with Chan's pairwise update, so long
logs with large biases lose no precision (no raw sums of squares are ever formed).

Two ways to combine moments:

* :meth:`Moments.merge` (also ``a + b``): the samples share one constant bias; the
  between-chunk spread enters the scatter (Eq. 12-17 of the paper are then exact).
* :meth:`Moments.pool`: each part has its own bias (piecewise-constant bias); only the
  within-part scatters add and ``segments`` counts the bias segments.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import Iterable

import numpy as np

from ..errors import InputError, OptionError

CHUNK_SIZE = 8192    # rows per chunk: the (8, 8192) float64 buffer (512 KiB per thread) stays in the L2 cache


# ---------------------------------------------------------------------------------------------- row helpers
# numpy reduces an (N, 3) array along its short rows (``.all(axis=1)``, ``linalg.norm(axis=1)``) or down
# its columns (``.max(axis=0)``) 3-15x slower than these equivalents; the whole library uses them.
def finite_rows(x) -> np.ndarray:
    """``np.isfinite(x).all(axis=1)`` of a 2-D array: bool (N,), True where every entry of the row is finite."""
    x = np.asarray(x)
    if x.dtype.kind in "biu":
        return np.ones(x.shape[0], dtype=bool)
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(x.sum()):        # the usual case, one summed test (overflow falls through to the full one)
            return np.ones(x.shape[0], dtype=bool)
    f = np.isfinite(x)
    out = f[:, 0].copy()
    for j in range(1, x.shape[1]):
        out &= f[:, j]
    return out


def column_means(x) -> np.ndarray:
    """``x.mean(axis=0, dtype=float64)`` of an (N, k) array, the same numbers: for C-ordered float64 rows by
    ``einsum``, which adds them in the same order ~5x faster than numpy's reduction down a narrow array (0.16 ms for
    8192 x 3)."""
    if x.dtype == np.float64 and x.flags.c_contiguous and x.shape[0] > 0:
        return np.einsum("ij->j", x) / x.shape[0]
    return x.mean(axis=0, dtype=np.float64)


_ROW_BLOCK = 1024   # rows of an (N, 3) array minus_row lays side by side: one (3072,) row of the vector tiled


def minus_row(x: np.ndarray, v: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``x - v`` of an (N, k) float64 array and a (k,) vector, equal to it bit for bit (the same subtraction of
    each element), into ``out`` (C-contiguous; may be ``x``). numpy broadcasts a (k,) vector along short rows one
    row at a time (0.5 ms for 64k rows of 3); :data:`_ROW_BLOCK` rows of a C-contiguous ``x`` laid side by side
    against the vector tiled as often are one contiguous subtraction (0.1 ms). Another layout is numpy's own
    subtraction (its result in the layout numpy gives it)."""
    if not x.flags.c_contiguous:
        return x - v if out is None else np.subtract(x, v, out=out)
    out = np.empty(x.shape) if out is None else out
    head = x.shape[0] // _ROW_BLOCK * _ROW_BLOCK
    width = _ROW_BLOCK * x.shape[1]
    np.subtract(x[:head].reshape(-1, width), np.tile(v, _ROW_BLOCK), out=out[:head].reshape(-1, width))
    np.subtract(x[head:], v, out=out[head:])
    return out


def row_sumsq(x) -> np.ndarray:
    """``(x ** 2).sum(axis=1)`` of an (N, k) float array (squared row norms)."""
    x = np.asarray(x, dtype=np.float64)
    return np.einsum("ij,ij->i", x, x)


def row_norms(x) -> np.ndarray:
    """``np.linalg.norm(x, axis=1)`` of an (N, k) float array."""
    return np.sqrt(row_sumsq(x))


def median(x, axis=None, overwrite_input: bool = False):
    """``np.median(x, axis)`` of a float64 array, the same values, partitioned at one point instead of numpy's three
    (the two middle ones and the last, its NaN test: about 4x the time): the lower middle value of an even count is
    the largest below the upper one, and the two are averaged as numpy's mean does. ``axis``: None (all values) or
    the last; any other, another dtype, no values, or a NaN or inf among them: ``np.median`` itself.
    ``overwrite_input``: ``x`` (a temporary of the caller's) may be partitioned in place, as numpy's option: no
    copy of it."""
    x = np.asarray(x)
    last = axis is None or axis == -1 or axis == x.ndim - 1
    if x.dtype != np.float64 or not last or x.size == 0 or x.ndim == 0:
        return np.median(x, axis=axis, overwrite_input=overwrite_input)
    with np.errstate(invalid="ignore", over="ignore"):
        if not np.isfinite(np.add.reduce(x, axis=None)):
            return np.median(x, axis=axis, overwrite_input=overwrite_input)
    if axis is None:
        x = x.reshape(-1)
    n = x.shape[-1]
    k = n // 2
    if overwrite_input and x.flags.writeable:
        x.partition(k, axis=-1)
        part = x
    else:
        part = np.partition(x, k, axis=-1)
    hi = part[..., k]
    if n % 2:
        return hi
    return (np.maximum.reduce(part[..., :k], axis=-1) + hi) / 2.0


_PRODUCT_ROWS = 16384   # rows per product of rows_times: one BLAS call each, below OpenBLAS's threading threshold


def rows_times(x, M) -> np.ndarray:
    """``x @ M`` of an (N, k) float array and a small (k, j) matrix, equal to it bit for bit, in blocks of rows.

    One product of a tall (N, 3) array with a 3 x 3 matrix is shared by OpenBLAS between its threads, which on a
    host whose cores are busy wait for one another: measured 16-32 ms instead of 0.25 ms for (65536, 3) @ (3, 3)
    at load 3.5 on 2 cores; each block's product runs on one thread, at the same speed when the cores are free.
    """
    x = np.asarray(x, dtype=np.float64)
    M = np.asarray(M, dtype=np.float64)
    out = np.empty((x.shape[0], M.shape[1]))
    for lo in range(0, x.shape[0], _PRODUCT_ROWS):
        np.matmul(x[lo:lo + _PRODUCT_ROWS], M, out=out[lo:lo + _PRODUCT_ROWS])
    return out


_EXTREME_BLOCK = 1024   # rows per block of column_extremes: (1024 * k,) rows reduced element-wise, contiguous


def column_extremes(x) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(hi, lo, hi_repeats, lo_repeats)`` of a 2-D float array: each column's largest and smallest value and
    whether that exact value occurs in at least two rows, in two passes over the data.

    A C-contiguous ``x`` is read as blocks of rows laid side by side (``(N // B, B * k)``): reducing those down
    the long axis is element-wise and contiguous, and the position in the block of each column's extreme tells
    where it sits, so the repeats are counted on the few block columns that hold it. A NaN anywhere makes its
    column's ``hi`` and ``lo`` NaN (as ``max``/``min`` do).
    """
    x = np.asarray(x)
    n, k = x.shape
    if n == 0:
        raise InputError("x: expected at least one row to take the extremes of, got 0")
    block = _EXTREME_BLOCK
    head = n // block * block if x.flags.c_contiguous else 0
    his, los, h_hi, h_lo = [], [], None, None
    if head:
        h = x[:head].reshape(-1, block * k)
        h_hi, h_lo = h.max(axis=0), h.min(axis=0)
        his.append(h_hi.reshape(block, k).max(axis=0))
        los.append(h_lo.reshape(block, k).min(axis=0))
    tail = x[head:]
    if len(tail):
        his.append(np.array([tail[:, j].max() for j in range(k)]))
        los.append(np.array([tail[:, j].min() for j in range(k)]))
    hi, lo = np.max(his, axis=0), np.min(los, axis=0)
    reps = []
    for level, reduced in ((hi, h_hi), (lo, h_lo)):
        out = np.zeros(k, dtype=bool)
        for j in range(k):
            count = 0
            if head:
                for p in np.flatnonzero(reduced[j::k] == level[j]):   # block positions holding the extreme
                    count += int(np.count_nonzero(h[:, p * k + j] == level[j]))
                    if count >= 2:
                        break
            if count < 2 and len(tail):
                count += int(np.count_nonzero(tail[:, j] == level[j]))
            out[j] = count >= 2
        reps.append(out)
    return hi, lo, reps[0], reps[1]


def as_rates(name: str, omega, *, length: int | None = None) -> np.ndarray:
    """Return ``omega`` as a read-only ``(N, 3)`` float array (no copy when already fine).

    Parameters
    ----------
    name : str
        Name used in error messages.
    omega : array_like, shape (N, 3)
        Angular rates in rad/s.
    length : int, optional
        Required number of rows.

    Raises
    ------
    InputError
        If the shape is not ``(N, 3)`` or the length differs from ``length``.
    """
    if omega is None:
        raise InputError(f"{name}: expected a numeric (N, 3) array of rad/s, got None")
    try:
        arr = np.asarray(omega)
    except (ValueError, TypeError) as exc:  # ragged nested lists
        raise InputError(f"{name}: expected a numeric (N, 3) array of rad/s, got a ragged {type(omega).__name__} "
                         f"(rows of different lengths: {exc.__class__.__name__})") from None
    if arr.dtype.kind not in "fiu":
        raise InputError(f"{name}: expected a numeric (N, 3) array of rad/s, got dtype {arr.dtype} "
                         f"(shape {arr.shape})")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name}: expected shape (N, 3), got {arr.shape} ({arr.dtype} rates)")
    if length is not None and arr.shape[0] != length:
        raise InputError(
            f"{name}: expected {length} samples (the length of omega_1), got {arr.shape[0]}; "
            "sample-aligned input needs equal lengths (pass t_1/t_2 to align streams)"
        )
    if arr.dtype.kind in "iu":
        arr = arr.astype(np.float64)
    return arr


def as_rate_pair(omega_1, omega_2, mask=None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Sample-aligned ``(omega_1, omega_2, mask)`` checked once: two (N, 3) rate arrays (:func:`as_rates`) and
    a bool mask of shape (N,) or None."""
    w1 = as_rates("omega_1", omega_1)
    w2 = as_rates("omega_2", omega_2, length=w1.shape[0])
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (w1.shape[0],):
            raise InputError(f"mask: expected shape ({w1.shape[0]},), got {mask.shape}")
    return w1, w2, mask


def noise_pair(noise_std) -> tuple[float, float]:
    """``(sigma_1, sigma_2)`` from one value or one per gyro (rad/s per sample), checked positive and finite."""
    arr = np.broadcast_to(np.asarray(noise_std, dtype=float), (2,))
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise OptionError(f"noise_std: expected positive rad/s per sample (one value or one per gyro), got {noise_std}")
    return float(arr[0]), float(arr[1])


_THREADS = max(1, min(2, os.cpu_count() or 1))   # default worker threads of a long pass
_PARTS_PER_WORKER = 4    # parts of a long pass per worker thread,
_MIN_PART_CHUNKS = 16    # each of at least this many chunks
_MIN_THREAD_CHUNKS = 32  # fewer chunks: the parts one after the other (starting the threads cost more than the second
#                          core saved: 8 chunks 2.4 ms in threads against 1.6 ms in turn, 16 chunks 3.4 against 2.6)


def _accumulate(w1, w2, mask, lo, hi, chunk_size, extremes=None):
    """Count, mean and centred scatter of rows ``lo:hi`` in one pass at memory speed.

    Each chunk is copied (transposed, rows contiguous, which numpy copies fastest) into a
    cache-resident float64 buffer ``[omega_1^T; omega_2^T; 1; 0]`` (8, chunk) whose product with its
    first six rows, one BLAS call, gives the sums and products (the row of zeros makes the product
    8 x 6, which OpenBLAS's kernels take ~1/3 faster than 7 x 6); the products of all chunks are
    added. The data are shifted by the mean of the first chunk (shifted-data algorithm), so the
    sums are O(spread), not O(bias). Where the shift is poor against the spread (cancellation
    would cost more than ~6 of 16 digits, e.g. a large drift), the range is redone chunk by chunk
    with Chan's pairwise update (:func:`_accumulate_chan`).

    ``extremes``: ``(hi, lo, shift)``, two (chunks, 6) arrays (``mask`` None) that receive each chunk's largest and
    smallest shifted value per channel, read from the cache-resident buffer (:func:`moments_with_extremes`), and a
    (6,) array that receives the shift.
    """
    whole = _chunk_views(_buffer(chunk_size))   # the views of a whole chunk, made once (not per chunk)
    top, bottom = (None, None) if extremes is None else extremes[:2]
    sub, dot, hi_of, lo_of = np.subtract, np.dot, np.maximum.reduce, np.minimum.reduce
    G = np.zeros((8, 6))
    n_tot = 0
    shift = None
    with np.errstate(over="ignore", invalid="ignore"):   # non-finite or overflowing sums are checked once below
        for i, start in enumerate(range(lo, hi, chunk_size)):
            stop = min(start + chunk_size, hi)
            keep = None if mask is None else mask[start:stop]
            if shift is None:                 # the first chunk with a kept sample: its mean is the shift
                if keep is not None and not keep.any():
                    continue
                first = [np.asarray(w[start:stop] if keep is None else w[start:stop][keep]) for w in (w1, w2)]
                shift = np.concatenate([column_means(f) for f in first])
                if not np.isfinite(shift).all():
                    shift = np.zeros(6)       # the non-finite sums below name the first bad row
                s1, s2 = shift[:3, None], shift[3:, None]
                if extremes is not None:
                    extremes[2][:] = shift
            # a short last chunk in a buffer of its own: BLAS reads a row-strided slice of the full buffer several
            # times slower (the same products, bit for bit)
            x, x1, x2, x6, x6t = whole if stop - start == chunk_size else _chunk_views(_buffer(stop - start))
            sub(w1[start:stop].T, s1, out=x1)
            sub(w2[start:stop].T, s2, out=x2)
            if top is not None:               # of the shifted values: rounding keeps their order
                hi_of(x6, axis=1, out=top[i])  # the ufuncs' own reductions: no wrappers
                lo_of(x6, axis=1, out=bottom[i])
            if keep is not None and not keep.all():
                x = x[:, keep]
                x6t = x[:6].T
            G += dot(x, x6t)                  # products and (row of ones) sums; a plain gemm, measured faster
            n_tot += x.shape[1]               # than numpy's syrk for A A^T at this shape
    if n_tot == 0:
        return 0, np.zeros(6), np.zeros((6, 6))
    _check_gram(G, w1, w2, lo, hi)
    s = G[6, :6]
    d = s / n_tot
    scat = G[:6, :6] - np.outer(s, d)
    if np.any(d**2 > 1e6 * np.maximum(np.diag(scat) / n_tot, 1e-300)):
        return _accumulate_chan(w1, w2, mask, lo, hi, chunk_size)
    return n_tot, shift + d, 0.5 * (scat + scat.T)


def _buffer(m: int) -> np.ndarray:
    """The (8, m) chunk buffer of :func:`_accumulate`: rows 0-5 written per chunk, a row of ones, a row of zeros."""
    buf = np.empty((8, m))
    buf[6], buf[7] = 1.0, 0.0
    return buf


def _chunk_views(x):
    """``(x, x[:3], x[3:6], x[:6], x[:6].T)`` of an (8, m) chunk buffer: the rows each step of :func:`_accumulate`
    writes or reads."""
    return x, x[:3], x[3:6], x[:6], x[:6].T


def _check_gram(G, w1, w2, lo: int, hi: int) -> None:
    """Refuse a non-finite Gram matrix of samples ``lo:hi``: a non-finite sample (its sums), else values whose
    squares overflow."""
    s = G[6, :6]
    if not np.isfinite(s).all():
        name, arr = ("omega_1", w1) if not np.isfinite(s[:3]).all() else ("omega_2", w2)
        raise _first_bad_row(name, np.asarray(arr[lo:hi]), lo)
    if not np.isfinite(G).all():
        raise _too_large(w1, w2, lo, hi)


def _accumulate_chan(w1, w2, mask, lo, hi, chunk_size):
    """:func:`_accumulate` chunk by chunk, each chunk centred on its own and combined with Chan's update.

    Where a chunk's mean is large against its spread, the chunk is shifted by its first sample
    and recomputed (shifted-data algorithm), so large biases never lose precision.
    """
    buf = np.empty((7, chunk_size))
    buf[6] = 1.0
    n_tot, mean, scat = 0, np.zeros(6), np.zeros((6, 6))
    for start in range(lo, hi, chunk_size):
        stop = min(start + chunk_size, hi)
        x = buf[:, : stop - start]
        np.copyto(x[:3], w1[start:stop].T)
        np.copyto(x[3:6], w2[start:stop].T)
        if mask is not None:
            keep = mask[start:stop]
            if not keep.all():
                x = x[:, keep]
        m = x.shape[1]
        if m == 0:
            continue
        with np.errstate(over="ignore", invalid="ignore"):
            G = np.dot(x, x.T)
        _check_gram(G, w1, w2, start, stop)
        s = G[6, :6]
        c_mean = s / m
        c_scat = G[:6, :6] - np.outer(s, c_mean)
        spread = np.diag(c_scat) / m
        if np.any(c_mean**2 > 1e6 * np.maximum(spread, 1e-300)):
            shift = x[:6, 0].copy()
            x[:6] -= shift[:, None]  # shifted data: sums are O(spread), not O(bias)
            G = np.dot(x, x.T)
            c_mean = shift + G[6, :6] / m
            c_scat = G[:6, :6] - np.outer(G[6, :6], G[6, :6]) / m
        n_new = n_tot + m
        delta = c_mean - mean
        scat += c_scat + np.outer(delta, delta) * (n_tot * m / n_new)
        mean += delta * (m / n_new)
        n_tot = n_new
    return n_tot, mean, scat


def _too_large(w1, w2, lo: int, hi: int) -> InputError:
    """The error for finite rates whose products overflow float64 (values beyond ~1e154)."""
    top = [float(np.max(np.abs(np.asarray(w[lo:hi], dtype=np.float64)))) for w in (w1, w2)]
    name, value = ("omega_1", top[0]) if top[0] >= top[1] else ("omega_2", top[1])
    return InputError(f"{name}: expected angular rates in rad/s, got values up to {value:.3g} rad/s (their squares "
                      "overflow float64); convert the rates to rad/s first")


def _first_bad_row(name: str, arr: np.ndarray, offset: int) -> InputError:
    bad = np.flatnonzero(~finite_rows(arr))
    idx = offset + int(bad[0]) if bad.size else offset
    count = int(bad.size)
    return InputError(
        f"{name}: expected finite rates, got a non-finite value (NaN or inf) at sample {idx} "
        f"({count} non-finite row(s) in that block); mask or drop those samples first"
    )


@dataclass(frozen=True)
class Moments:
    """Count, mean and centred scatter of the stacked samples ``[omega_1; omega_2]``.

    Attributes
    ----------
    count : float
        Number of samples (a float so that forgetting factors can down-weight it).
    mean : ndarray, shape (6,)
        Mean of ``[omega_1_meas, omega_2_meas]`` in rad/s.
    scatter : ndarray, shape (6, 6)
        Sum of outer products of the centred samples, within each bias segment.
    segments : int
        Number of independent bias segments pooled into ``scatter`` (1 for a constant bias).
    """

    count: float
    mean: np.ndarray
    scatter: np.ndarray
    segments: int = 1

    def __post_init__(self):
        mean = np.array(self.mean, dtype=np.float64).reshape(6)
        scatter = np.array(self.scatter, dtype=np.float64).reshape(6, 6)
        mean.flags.writeable = False
        scatter.flags.writeable = False
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "scatter", scatter)
        object.__setattr__(self, "count", float(self.count))

    @classmethod
    def _of(cls, count: float, mean: np.ndarray, scatter: np.ndarray, segments: int) -> "Moments":
        """Moments from read-only float64 arrays of the right shapes computed here (no checks, no copies)."""
        out = object.__new__(cls)
        object.__setattr__(out, "count", float(count))
        object.__setattr__(out, "mean", mean)
        object.__setattr__(out, "scatter", scatter)
        object.__setattr__(out, "segments", segments)
        return out

    # ------------------------------------------------------------------ construction
    @classmethod
    def empty(cls) -> "Moments":
        """Moments of no samples (the identity of :meth:`merge` and :meth:`pool`)."""
        return cls(0.0, np.zeros(6), np.zeros((6, 6)), 0)

    @classmethod
    def from_samples(cls, omega_1, omega_2, *, mask=None, weights=None, chunk_size: int = CHUNK_SIZE,
                     threads: int | None = None) -> "Moments":
        """Accumulate the moments of two sample-aligned rate streams in bounded memory.

        Parameters
        ----------
        omega_1, omega_2 : array_like, shape (N, 3)
            Measured rates of gyro 1 and gyro 2 (rad/s) at the same instants; float32
            or float64 (accumulation is always float64).
        mask : array_like of bool, shape (N,), optional
            Samples to use (True = keep).
        weights : array_like, shape (N,), optional
            A non-negative weight per sample (:func:`weighted_moments`): ``count`` is the sum of the used
            samples' weights, ``mean`` their weighted mean and ``scatter`` the weighted centred scatter. With
            weights ``sigma^2 / sigma_k^2`` (sample ``k``'s residual variance against a reference white noise
            ``sigma``) the cost of Eq. 12-17 and its refinement is the likelihood of heteroscedastic samples.
            None (default): every sample weighs 1 (the unweighted pass, unchanged).
        chunk_size : int
            Rows per chunk; memory beyond the inputs is ``O(chunk_size * threads)``.
        threads : int, optional
            Worker threads for long inputs (default: up to 2, bounded by the CPU count).

        Raises
        ------
        InputError
            On a wrong shape, unequal lengths or a non-finite sample.
        """
        w1, w2, mask = as_rate_pair(omega_1, omega_2, mask)
        if weights is not None:
            return weighted_moments(w1, w2, sample_weights(weights, w1.shape[0]), mask=mask, chunk_size=chunk_size)
        return _moments(w1, w2, mask, chunk_size, threads)

    # ------------------------------------------------------------------ algebra
    def merge(self, other: "Moments") -> "Moments":
        """Combine with moments of more samples that share the same bias (Chan et al.)."""
        if other.count == 0:
            return self
        if self.count == 0:
            return other
        n = self.count + other.count
        delta = other.mean - self.mean
        mean = self.mean + delta * (other.count / n)
        scatter = self.scatter + other.scatter + np.outer(delta, delta) * (self.count * other.count / n)
        return Moments(n, mean, scatter, max(self.segments, other.segments))

    __add__ = merge

    def pool(self, other: "Moments") -> "Moments":
        """Combine with moments of samples that have their own (different) bias.

        Only the within-part scatters add; the between-part spread, which a changed bias
        would corrupt, is dropped. The pooled mean is the overall sample mean.
        """
        if other.count == 0:
            return self
        if self.count == 0:
            return other
        n = self.count + other.count
        mean = (self.count * self.mean + other.count * other.mean) / n
        return Moments(n, mean, self.scatter + other.scatter, self.segments + other.segments)

    @staticmethod
    def pool_all(parts: Iterable["Moments"]) -> "Moments":
        """Pool a sequence of per-segment moments (piecewise-constant bias)."""
        out = Moments.empty()
        for p in parts:
            out = out.pool(p)
        return out

    @staticmethod
    def merge_all(parts: Iterable["Moments"]) -> "Moments":
        """Merge a sequence of moments that share one bias (tree-free left fold)."""
        out = Moments.empty()
        for p in parts:
            out = out.merge(p)
        return out

    def decayed(self, factor: float) -> "Moments":
        """Down-weight all samples by ``factor`` in (0, 1] (exponential forgetting)."""
        return Moments(self.count * factor, self.mean, self.scatter * factor, self.segments)

    # ------------------------------------------------------------------ views
    @property
    def dof(self) -> float:
        """Degrees of freedom of the scatter: samples minus bias segments."""
        return self.count - self.segments

    @property
    def mean_1(self) -> np.ndarray:
        return self.mean[:3]

    @property
    def mean_2(self) -> np.ndarray:
        return self.mean[3:]

    @property
    def S11(self) -> np.ndarray:
        return self.scatter[:3, :3]

    @property
    def S12(self) -> np.ndarray:
        return self.scatter[:3, 3:]

    @property
    def S22(self) -> np.ndarray:
        return self.scatter[3:, 3:]

    def to_dict(self) -> dict:
        return {"count": self.count, "mean": self.mean.tolist(), "scatter": self.scatter.tolist(),
                "segments": self.segments}

    @classmethod
    def from_dict(cls, d: dict) -> "Moments":
        return cls(d["count"], np.asarray(d["mean"]), np.asarray(d["scatter"]), int(d.get("segments", 1)))


_BLOCK_ROWS = 65536         # samples per block of the window moments and the drifting-bias filter (a few MiB)


def _chunk_rows(chunk_size) -> int:
    """``chunk_size`` as a positive number of rows per chunk."""
    chunk_size = int(chunk_size)
    if chunk_size < 1:
        raise OptionError(f"chunk_size: expected a positive number of rows, got {chunk_size}")
    return chunk_size


def _moments(w1, w2, mask, chunk_size, threads, extremes: bool = False):
    """:meth:`Moments.from_samples` of checked rates; with ``extremes`` (``mask`` None) also the per-chunk
    ``(hi, lo)`` (chunks, 6) of :func:`_accumulate` with each part's shift (parts, 6), the chunk size and the first
    chunk of each part (each shifts by its own mean), as ``(moments, (hi, lo, shifts), chunk_size, bounds)``. Long
    inputs are cut into up to :data:`_PARTS_PER_WORKER` parts per worker thread, merged in order
    (:meth:`Moments.merge`)."""
    n = w1.shape[0]
    chunk_size = min(_chunk_rows(chunk_size), max(n, 1))   # the buffer is bounded by the data
    n_chunks = -(-n // chunk_size)
    ext = (np.empty((n_chunks, 6)), np.empty((n_chunks, 6))) if extremes else None
    workers = max(1, min(threads or _THREADS, n_chunks // 4))
    # several parts per worker, taken in turn: a worker slowed by the host's other work takes fewer of them
    parts_n = 1 if workers == 1 else max(workers, min(_PARTS_PER_WORKER * workers, n_chunks // _MIN_PART_CHUNKS))
    bounds = np.linspace(0, n_chunks, parts_n + 1).astype(int)
    if ext is not None:
        ext = ext + (np.full((parts_n, 6), np.nan),)     # each part's shift

    def part(i):
        lo, hi = int(bounds[i]), int(bounds[i + 1])
        sub = None if ext is None else (ext[0][lo:hi], ext[1][lo:hi], ext[2][i])
        return _accumulate(w1, w2, mask, lo * chunk_size, min(hi * chunk_size, n), chunk_size, sub)

    if workers == 1:
        c, mu, sc = part(0) if n else (0, np.zeros(6), np.zeros((6, 6)))
        out = Moments(c, mu, sc, 1 if c else 0)
    else:
        from concurrent.futures import ThreadPoolExecutor

        if n_chunks < _MIN_THREAD_CHUNKS:          # the same parts (the same sums), in turn
            parts = [part(i) for i in range(parts_n)]
        else:
            with ThreadPoolExecutor(workers) as pool:  # numpy releases the GIL in BLAS and copies
                parts = list(pool.map(part, range(parts_n)))
        out = Moments.merge_all(Moments(c, mu, sc, 1 if c else 0) for c, mu, sc in parts)
    return out if not extremes else (out, ext, chunk_size, bounds)


def sample_weights(weights, n: int) -> np.ndarray:
    """``weights`` as a float64 (n,) array of finite non-negative values (one per sample).

    Raises
    ------
    InputError
        On another shape, a negative or non-finite weight.
    """
    try:
        w = np.asarray(weights, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"weights: expected one non-negative number per sample ({n},), got "
                         f"{type(weights).__name__}") from None
    if w.shape != (n,):
        raise InputError(f"weights: expected one weight per sample, shape ({n},), got {w.shape}")
    bad = ~np.isfinite(w) | (w < 0)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"weights: expected finite non-negative weights, got {w[k]!r} at sample {k} "
                         f"({int(bad.sum())} such weight(s))")
    return w


def weighted_moments(w1, w2, weights, *, mask=None, chunk_size: int = CHUNK_SIZE) -> Moments:
    """The moments of checked sample-aligned rates with a weight per sample (:meth:`Moments.from_samples`).

    ``count = sum_k w_k``, ``mean = sum_k w_k x_k / count`` and ``scatter = sum_k w_k (x_k - mean)(x_k - mean)^T``
    over the used samples: each chunk centred on its own weighted mean, chunks combined with Chan's update (the
    weighted form of :meth:`Moments.merge`), so a large bias costs no precision. ``weights`` (N,) float64, checked
    (:func:`sample_weights`); samples of weight 0 play no part (they may be non-finite).

    Raises
    ------
    InputError
        A non-finite used sample of positive weight, or values whose squares overflow.
    """
    n = w1.shape[0]
    chunk_size = _chunk_rows(chunk_size)
    count, mean, scat = 0.0, np.zeros(6), np.zeros((6, 6))
    for start in range(0, n, chunk_size):
        stop = min(start + chunk_size, n)
        wt = weights[start:stop]
        keep = wt > 0 if mask is None else (mask[start:stop] & (wt > 0))
        if not keep.any():
            continue
        x = np.concatenate([np.asarray(w1[start:stop][keep], dtype=np.float64).T,
                            np.asarray(w2[start:stop][keep], dtype=np.float64).T])     # (6, m)
        wt = wt[keep]
        c = float(wt.sum())
        with np.errstate(over="ignore", invalid="ignore"):
            mu = (x @ wt) / c
            if not np.isfinite(mu).all():
                name, arr = ("omega_1", w1) if not np.isfinite(mu[:3]).all() else ("omega_2", w2)
                rows = np.asarray(arr[start:stop])
                bad = np.flatnonzero(keep & ~finite_rows(rows))
                if bad.size:
                    raise InputError(f"{name}: expected finite rates, got a non-finite value (NaN or inf) at sample "
                                     f"{start + int(bad[0])} ({bad.size} non-finite used row(s) in that block); "
                                     "mask or drop those samples first")
                raise _too_large(w1, w2, start, stop)
            x -= mu[:, None]
            sc = (x * wt) @ x.T
        if not np.isfinite(sc).all():
            raise _too_large(w1, w2, start, stop)
        total = count + c                       # Chan's update, weighted
        delta = mu - mean
        scat += sc + np.outer(delta, delta) * (count * c / total)
        mean += delta * (c / total)
        count = total
    return Moments(count, mean, 0.5 * (scat + scat.T), 1 if count > 0 else 0)


def moments_with_extremes(omega_1, omega_2, *, chunk_size: int = CHUNK_SIZE, threads: int | None = None):
    """``(moments, extremes_1, extremes_2)``: :meth:`Moments.from_samples` of every sample and each stream's
    :func:`column_extremes` ``(hi, lo, hi_repeats, lo_repeats)``, read in the same pass (what the clipping test
    of :func:`~fusion_gyrocal.pipeline.streams.saturation_mask` needs, at the cost of the chunks' extremes from
    the cache-resident buffer and a count on the few chunks that hold each extreme).

    Raises
    ------
    InputError
        As :meth:`Moments.from_samples` (a non-finite sample, values whose squares overflow, wrong shapes).
    """
    w1, w2, _ = as_rate_pair(omega_1, omega_2)
    if w1.shape[0] == 0:
        raise InputError("omega_1 and omega_2: expected samples to take the moments of, got 0")
    m, (hi, lo, shifts), size, bounds = _moments(w1, w2, None, chunk_size, threads, extremes=True)
    used = np.flatnonzero(bounds[1:] > bounds[:-1])     # the parts that hold chunks, in order, end to end
    starts = bounds[used]
    owner = np.repeat(np.arange(used.size), np.diff(np.append(starts, hi.shape[0])))   # each chunk's part
    tops = _exact_extremes((w1, w2), hi, np.maximum.reduceat(hi, starts, axis=0), shifts[used], owner, size, 1.0)
    bottoms = _exact_extremes((w1, w2), lo, np.minimum.reduceat(lo, starts, axis=0), shifts[used], owner, size, -1.0)
    return m, *((tops[0][k], bottoms[0][k], tops[1][k], bottoms[1][k]) for k in (slice(0, 3), slice(3, 6)))


def _exact_extremes(ws, per_chunk, best, shifts, owner, size: int, sign: float) -> tuple[np.ndarray, np.ndarray]:
    """The largest (``sign`` 1) or smallest (-1) value of each of the six columns of the streams ``ws`` and whether
    it occurs in two rows or more, as (6,) arrays, from each chunk's shifted extreme ``per_chunk`` (chunks, 6), each
    part's extreme ``best`` (parts, 6) and shift ``shifts`` (parts, 6) and each chunk's part ``owner``: only the
    parts whose extreme, shifted back, comes within rounding of the best part's can hold it (a row equal to it is
    its part's extreme), and within them only the chunks holding the part's extreme are read again, exactly."""
    bests = sign * best
    back = bests + sign * shifts                                            # in the data's values (times sign)
    slack = 4.0 * np.finfo(np.float64).eps * (np.abs(bests) + np.abs(back))  # two roundings, generously
    cols = np.arange(6)
    g = np.argmax(back, axis=0)
    near = back + slack >= back[g, cols] - slack[g, cols]     # the parts whose extreme may equal the best part's
    cands = (per_chunk == best[owner]) & near[owner]
    level, rep = np.empty(6), np.zeros(6, dtype=bool)
    for c in range(6):
        x = ws[c // 3][:, c % 3]
        rows = [x[i * size:(i + 1) * size] for i in np.flatnonzero(cands[:, c])]
        level[c] = max(r.max() for r in rows) if sign > 0 else min(r.min() for r in rows)
        count = 0
        for r in rows:
            count += int(np.count_nonzero(r == level[c]))
            if count >= 2:
                break
        rep[c] = count >= 2
    return level, rep


def window_moments(omega_1, omega_2, window: int, *, mask=None, with_starts: bool = False) -> list:
    """Moments of consecutive windows of ``window`` samples (one bias segment each).

    ``Moments.pool_all(window_moments(...))`` gives the statistics of a piecewise-constant
    bias; ``Moments.merge_all`` of the same list equals :meth:`Moments.from_samples`. Windows with
    fewer than two (unmasked) samples are left out; ``with_starts=True`` gives
    ``(start sample index, Moments)`` pairs instead of the Moments alone. The whole windows are
    computed a block of windows at a time (each window centred on its own mean, then its scatter:
    two passes, exact for any bias); the partial window at the end by :meth:`Moments.from_samples`.

    Raises
    ------
    InputError
        On a wrong shape, unequal lengths or a non-finite sample among the used ones.
    OptionError
        If ``window`` is below 2.
    """
    w1, w2, mask = as_rate_pair(omega_1, omega_2, mask)
    window = int(window)
    if window < 2:
        raise OptionError(f"window: expected at least 2 samples per window, got {window}")
    n = w1.shape[0]
    n_full = n // window if window <= _BLOCK_ROWS else 0     # longer windows: one bounded pass each, below
    per = max(1, _BLOCK_ROWS // window)
    out = []
    for lo in range(0, n_full, per):
        hi = min(n_full, lo + per)
        a, b = lo * window, hi * window
        cnt, mean, scat = _window_block(w1, w2, None if mask is None else mask[a:b], a, b, window)
        mean.flags.writeable = False      # each window's Moments holds read-only views of these
        scat.flags.writeable = False
        for j in np.flatnonzero(cnt > 1):
            m = Moments._of(cnt[j], mean[j], scat[j], 1)
            out.append(((lo + int(j)) * window, m) if with_starts else m)
    for start in range(n_full * window, n, window):
        stop = min(start + window, n)
        m = Moments.from_samples(w1[start:stop], w2[start:stop], mask=None if mask is None else mask[start:stop])
        if m.count > 1:
            out.append((start, m) if with_starts else m)
    return out


def _window_block(w1, w2, keep, a: int, b: int, window: int):
    """Count (W,), mean (W, 6) and centred scatter (W, 6, 6) of the whole windows of samples ``a:b`` (read-only
    arrays); ``keep`` (b - a,) marks the used samples (None: all). Refuses a non-finite used sample."""
    W = (b - a) // window
    x = np.empty((W, 6, window))          # windows x channels x samples: sums run along contiguous rows
    x[:, :3, :] = w1[a:b].reshape(W, window, 3).transpose(0, 2, 1)
    x[:, 3:, :] = w2[a:b].reshape(W, window, 3).transpose(0, 2, 1)
    if keep is not None and keep.all():
        keep = None
    if keep is not None:
        np.copyto(x, 0.0, where=~keep.reshape(W, 1, window))  # unused samples (finite or not) count as 0
    with np.errstate(over="ignore", invalid="ignore"):
        if not np.isfinite(x.sum()):
            bad = ~np.isfinite(x).all(axis=2)                 # (W, 6): which window and channel
            w = int(np.flatnonzero(bad.any(axis=1))[0])
            g = 0 if bad[w, :3].any() else 1
            raise _first_bad_row(f"omega_{g + 1}", x[w, 3 * g:3 * g + 3].T, a + w * window)
        if keep is None:
            cnt = np.full(W, float(window))
            mean = x.mean(axis=2)
            x -= mean[:, :, None]
        else:
            m = keep.reshape(W, window)
            cnt = m.sum(axis=1).astype(np.float64)
            mean = x.sum(axis=2) / np.maximum(cnt, 1.0)[:, None]
            x -= mean[:, :, None]
            x *= m[:, None, :]
        scat = np.matmul(x, x.transpose(0, 2, 1))
    if not np.isfinite(scat).all():
        raise _too_large(w1, w2, a, b)
    return cnt, mean, 0.5 * (scat + scat.transpose(0, 2, 1))


NOMINAL_WINDOW = 100      # samples per window (noise model, robust covariance) when the sample rate is unknown


def window_samples(rate_hz: float | None) -> int:
    """Samples in a window of about one second at ``rate_hz`` (at least 16); :data:`NOMINAL_WINDOW` without a rate."""
    return max(16, int(round(rate_hz))) if rate_hz else NOMINAL_WINDOW


MAX_SCORE_WINDOWS = 1024   # windows behind a block-robust covariance: all of them up to this many
_RUN = 16                  # else runs of this many consecutive windows, spread evenly over the log
#: samples window_stats copies at a time (each window's statistics are its own: the same numbers at any size); a
#: (windows, 6, window) copy under a MiB reuses memory just freed, where the 3 MiB of 65536 samples were fresh pages
#: from the OS on every call
_GATHER_SAMPLES = 16384


@dataclass(frozen=True)
class WindowStats:
    """Count, mean and centred scatter of ``[omega_1; omega_2]`` in consecutive windows of one log.

    What a block-robust (sandwich) covariance needs (:mod:`fusion_gyrocal.core.robust`): the
    per-window scores of the likelihood are linear in these scatters. Windows are consecutive
    within runs; ``run`` numbers the runs, so only neighbours of the same run are adjacent.

    Attributes
    ----------
    count : ndarray (W,)
        Valid samples in each window.
    mean : ndarray (W, 6)
        (W, 3 k) for k stacked gyros (:func:`stacked_window_stats`).
    scatter : ndarray (W, 6, 6)
        Scatter of each window about its own mean.
    run : ndarray (W,) of int
    window : int
        Samples per window.
    weight : float
        Samples of the log over samples in these windows (1 when every window is here): the sums
        over windows are scaled by it to stand for the whole log.
    pooled : bool
        True when each window is a bias segment of its own (``bias_window``): scores use the
        within-window scatter only; else the log's mean centres every window.
    weighted : bool
        True when the samples carry weights (``weights`` of :func:`window_stats`): ``count`` is then each
        window's sum of weights.
    """

    count: np.ndarray
    mean: np.ndarray
    scatter: np.ndarray
    run: np.ndarray
    window: int
    weight: float = 1.0
    pooled: bool = False
    weighted: bool = False

    @property
    def n_windows(self) -> int:
        return int(self.count.size)


def window_stats(omega_1, omega_2, window: int, *, mask=None, weights=None, pooled: bool = False,
                 max_windows: int = MAX_SCORE_WINDOWS) -> WindowStats:
    """:class:`WindowStats` of consecutive windows of ``window`` samples, in one vectorised pass.

    Up to ``max_windows`` full windows all are used; beyond, runs of 16 consecutive windows spread
    evenly over the log (work bounded per log, not per sample). Windows with fewer than two valid
    samples are left out; the partial window at the end is left out. ``weights`` (N,): a weight per
    sample, as in :meth:`Moments.from_samples` (each window's count is the sum of its samples' weights,
    its mean and scatter weighted), so the per-window sums add up to the weighted moments.
    """
    w1 = as_rates("omega_1", omega_1)
    w2 = as_rates("omega_2", omega_2, length=w1.shape[0])
    if weights is not None:
        weights = sample_weights(weights, w1.shape[0])
    return stacked_window_stats([w1, w2], window, mask=mask, pooled=pooled, max_windows=max_windows,
                                weights=weights)


def stacked_window_stats(streams, window: int, *, mask=None, pooled: bool = False,
                         max_windows: int = MAX_SCORE_WINDOWS, weights=None) -> WindowStats:
    """:func:`window_stats` of any number of checked, sample-aligned (N, 3) streams (stacked ``3 k`` wide);
    ``weights`` checked (:func:`sample_weights`) or None."""
    window = int(window)
    if window < 2:
        raise OptionError(f"window: expected at least 2 samples per window, got {window}")
    width = 3 * len(streams)
    n_win = streams[0].shape[0] // window
    if n_win == 0:
        return _join([], window, 0.0, pooled, width)
    if n_win <= max_windows:      # every window: one run
        starts, run_len = np.array([0]), n_win
    else:                         # runs of consecutive windows spread evenly over the log
        starts, run_len = np.linspace(0, n_win - _RUN, max_windows // _RUN).astype(int), _RUN
    mask = None if mask is None else np.asarray(mask, bool)
    parts = []
    per_chunk = max(1, _GATHER_SAMPLES // (run_len * window))   # runs per gather: under a MiB at a time
    for lo in range(0, starts.size, per_chunk):
        sl = [slice(int(st) * window, (int(st) + run_len) * window) for st in starts[lo:lo + per_chunk]]
        # a long run in pieces: every window of a log (one run) by _GATHER_SAMPLES, a run of _RUN windows beyond
        # 65536 samples by those (each piece then numbered as a run of its own)
        piece = max(1, (_GATHER_SAMPLES if run_len == n_win else 65536) // window) * window
        if run_len * window > piece:
            sl = [slice(a, min(a + piece, s.stop)) for s in sl for a in range(s.start, s.stop, piece)]
        wins = sum((q.stop - q.start) // window for q in sl)
        x = np.empty((wins, width, window))   # windows x channels x samples: sums run along contiguous rows
        at = 0
        for q in sl:                          # each slice straight into its windows (no joined copy first)
            k_q = (q.stop - q.start) // window
            for k, w in enumerate(streams):
                x[at:at + k_q, 3 * k:3 * k + 3, :] = w[q].reshape(k_q, window, 3).transpose(0, 2, 1)
            at += k_q
        m = None if mask is None else np.concatenate([mask[q] for q in sl]).reshape(-1, window)
        run = np.repeat(np.arange(lo, lo + len(sl)) if run_len != n_win else np.zeros(len(sl), int),
                        [(q.stop - q.start) // window for q in sl])
        if weights is None:
            parts.append(_stats_of(x, m, run))
        else:
            parts.append(_stats_of(x, m, run, np.concatenate([weights[q] for q in sl]).reshape(-1, window)))
    if weights is None:
        total = float(n_win * window if mask is None else np.count_nonzero(mask[: n_win * window]))
    else:
        head = weights[: n_win * window]
        total = float(head.sum() if mask is None else head[mask[: n_win * window]].sum())
    out = _join(parts, window, total, pooled, width)
    return out if weights is None else replace(out, weighted=True)


def _stats_of(x, m, run, wt=None):
    """Per-window (count, mean, scatter, run) of ``x`` (W, width, n), overwritten; ``m`` (W, n) marks valid samples,
    ``wt`` (W, n) weighs them (None: 1; each window's count is then its samples' weight, its mean and scatter
    weighted). Windows with fewer than two valid samples (of positive weight) are left out.

    The layout keeps each window's channel contiguous: numpy reduces an (n, 6) block along its rows
    several times slower than a (6, n) one along its columns."""
    if wt is None and np.isfinite(x.sum()) and (m is None or m.all()):      # the common case: every sample valid
        cnt = np.full(x.shape[0], float(x.shape[2]))
        mean = x.mean(axis=2)
        x -= mean[:, :, None]
        return cnt, mean, np.matmul(x, x.transpose(0, 2, 1)), run
    ok = np.isfinite(x).all(axis=1)
    if wt is not None:
        ok &= wt > 0
    m = ok if m is None else (m & ok)
    x = np.where(m[:, None, :], x, 0.0)
    keep = m.sum(axis=1) >= 2
    x, m, run = x[keep], m[keep], run[keep]
    w = m.astype(np.float64) if wt is None else np.where(m, wt[keep], 0.0)
    cnt = w.sum(axis=1)
    mean = np.einsum("wcn,wn->wc", x, w) / cnt[:, None]
    x -= mean[:, :, None]
    return cnt, mean, np.matmul(x * w[:, None, :], x.transpose(0, 2, 1)), run


def _join(parts, window: int, total: float, pooled: bool, width: int = 6) -> WindowStats:
    cnt, mean, scatter, run = (np.concatenate([p[i] for p in parts]) if parts else None for i in range(4))
    if cnt is None or cnt.size == 0:
        return WindowStats(np.zeros(0), np.zeros((0, width)), np.zeros((0, width, width)), np.zeros(0, int), window,
                           1.0, pooled)
    return WindowStats(cnt, mean, scatter, run, window, max(total / cnt.sum(), 1.0), pooled)


_WALK_BLOCK_ROWS = 16384   # samples per block of the drifting-bias filter: its (6, block) input and output (768 KiB
#                            each) stay in the cache for the reductions that read them (blocks of 65536: 1.2x the time)


def random_walk_gain(bias_walk_std, noise_std) -> tuple[float, float]:
    """Steady-state Kalman gain ``K`` of a random-walk bias seen in white noise, and ``sqrt((P + R) / R)``.

    ``q = sum(bias_walk_std^2)`` and ``R = sum(noise_std^2)`` combine both gyros (``A A^T ~ I``);
    ``P = (q + sqrt(q^2 + 4 q R)) / 2`` is the steady-state prior variance of the bias.
    """
    qs = np.broadcast_to(np.asarray(bias_walk_std, float), (2,))
    rs = np.broadcast_to(np.asarray(noise_std, float), (2,))
    if np.any(~np.isfinite(qs)) or np.any(qs <= 0) or np.any(~np.isfinite(rs)) or np.any(rs <= 0):
        raise OptionError(f"bias_walk_std and noise_std: expected positive rad/s per sample, got {qs} and {rs}")
    q, R = float((qs**2).sum()), float((rs**2).sum())
    P = 0.5 * (q + np.sqrt(q * q + 4.0 * q * R))
    return P / (P + R), float(np.sqrt((P + R) / R))


def random_walk_bias_moments(omega_1, omega_2, bias_walk_std, noise_std, *, mask=None,
                             chunk_size: int = CHUNK_SIZE, settle: int | None = None,
                             window: int | None = None, max_windows: int = MAX_SCORE_WINDOWS) -> tuple:
    """Moments for a bias that drifts as a random walk, by the Kalman innovations filter.

    With ``r_k = omega_1(k) - A omega_2(k) = b_k + n_k``, a random-walk bias
    ``b_{k+1} = b_k + nu_k`` (``Var nu = q``) and white noise (``Var n = R``), the steady-state
    Kalman filter of ``b`` turns ``r`` into white innovations with variance ``P + R`` through the
    fixed first-order high-pass ``G(z) = (1 - z^-1) / (1 - (1 - K) z^-1)``. Because ``G`` is
    linear and the same for both gyros, ``G r = G omega_1 - A G omega_2``: the exact likelihood of
    A with the drifting bias profiled out is the constant-bias cost of the *filtered* streams,
    so the direct solver and its refinement apply unchanged to these moments (a direct,
    non-iterative core; Eq. 8 with ``b(k)`` no longer constant).

    Parameters
    ----------
    omega_1, omega_2 : (N, 3) sample-aligned rates (rad/s).
    bias_walk_std : float or (float, float)
        Bias random-walk step std per sample of gyro 1 and gyro 2 (rad/s).
    noise_std : float or (float, float)
        White-noise std per sample (rad/s).
    settle : int, optional
        Leading filtered samples dropped while the filter settles (default ``5 / K``).
    window : int, optional
        Also return the :class:`WindowStats` of the innovations in windows of this many samples
        (each chunk's whole windows; for the block-robust covariance). As in :func:`window_stats`, work is
        bounded per log: beyond ``max_windows`` windows, those of chunks spread evenly over the log (each chunk's
        windows one run), ``max_windows`` at most.

    Returns
    -------
    moments : Moments
        ``scatter`` of the innovations; ``mean`` is the mean of the raw samples, so that
        ``mean_1 - A mean_2`` is the mean combined bias over the log.
    noise_scale : float
        ``sqrt((P + R) / R)``: multiply the noise std by it for the innovations' likelihood.
    stats : WindowStats
        Only with ``window``.
    """
    w1, w2, mask = as_rate_pair(omega_1, omega_2, mask)
    chunk_size = _chunk_rows(chunk_size)
    K, noise_scale = random_walk_gain(bias_walk_std, noise_std)
    settle = int(np.ceil(5.0 / K)) if settle is None else int(settle)
    filt = _WalkFilter(w1, w2, mask, K, chunk_size * max(1, _WALK_BLOCK_ROWS // chunk_size))  # whole chunks a block
    count, mean, scatter = 0, np.zeros(6), np.zeros((6, 6))
    parts = []
    chosen = None if window is None else _window_chunks(filt.n, chunk_size, int(window), int(max_windows))
    for start, y in filt.blocks():
        lo = max(0, settle - start)
        if lo >= y.shape[1]:
            continue
        c, mu, sc = _centred(y[:, lo:])
        if not np.isfinite(sc).all():
            raise _too_large(w1, w2, 0, w1.shape[0])
        n_new = count + c                   # Chan's update across blocks
        delta = mu - mean
        scatter += sc + np.outer(delta, delta) * (count * c / n_new)
        mean += delta * (c / n_new)
        count = n_new
        if window is not None:
            parts.extend(_innovation_windows(y, start, lo, chunk_size, int(window), chosen))
    if count < 4:
        raise InputError(f"expected more than {settle} samples for the drifting-bias filter to settle, got {filt.n}")
    moments = Moments(count, filt.mean(), 0.5 * (scatter + scatter.T), 1)
    if window is None:
        return moments, noise_scale
    return moments, noise_scale, _join(parts, int(window), float(count), False)


class _WalkFilter:
    """The used samples of a pair through ``G(z)`` of :func:`random_walk_bias_moments`, a block at a time.

    Blocks of ``block`` used samples are gathered transposed into one reused (6, block) buffer and filtered with
    the state carried from block to block; the state starts at the first used sample's steady state (``-x_0``:
    the filter kills constants, so the first innovation is 0 and there is no transient). The raw sums are kept
    for the samples' mean.
    """

    def __init__(self, w1, w2, mask, gain: float, block: int):
        self.w1, self.w2, self.block = w1, w2, block
        self.idx = None if mask is None else np.flatnonzero(mask)
        self.n = w1.shape[0] if self.idx is None else self.idx.size
        self.b, self.a = np.array([1.0, -1.0]), np.array([1.0, -(1.0 - gain)])
        self.zi = None
        self.buf = np.empty((6, min(block, self.n)))
        self.raw = np.zeros(6)               # sum of the used samples

    def filtered(self, start: int) -> np.ndarray:
        """The filtered block of used samples ``start:start + block`` (the blocks in order, once each)."""
        from scipy.signal import lfilter

        stop = min(start + self.block, self.n)
        x = self.buf[:, : stop - start]
        if self.idx is None:
            np.copyto(x[:3], self.w1[start:stop].T)
            np.copyto(x[3:], self.w2[start:stop].T)
        else:
            sel = self.idx[start:stop]
            np.copyto(x[:3], self.w1[sel].T)
            np.copyto(x[3:], self.w2[sel].T)
        with np.errstate(over="ignore", invalid="ignore"):
            s = x.sum(axis=1)
        if not np.isfinite(s).all():
            self._refuse(start, stop)
        self.raw += s
        if self.zi is None:   # the steady state of a constant first sample: its innovation is 0, no transient
            self.zi = -x[:, :1]
        y, self.zi = lfilter(self.b, self.a, x, axis=-1, zi=self.zi)
        return y

    def blocks(self):
        """``(start, filtered block)`` in order. The filter's state makes the blocks sequential, and scipy's
        ``lfilter`` holds the GIL, so a thread filtering the next block while this one is reduced only contends
        with the reduction (measured: 1.2x the time at 1e6 samples, 1.4x the CPU time)."""
        for start in range(0, self.n, self.block):
            yield start, self.filtered(start)

    def mean(self) -> np.ndarray:
        """Mean of the used samples (after every block)."""
        return self.raw / self.n

    def _refuse(self, start: int, stop: int):
        """Raise the error naming the first non-finite used sample among used samples ``start:stop``."""
        for name, w in (("omega_1", self.w1), ("omega_2", self.w2)):
            rows = np.asarray(w[start:stop] if self.idx is None else w[self.idx[start:stop]])
            bad = np.flatnonzero(~finite_rows(rows))
            if bad.size:
                at = start + int(bad[0]) if self.idx is None else int(self.idx[start + int(bad[0])])
                raise InputError(f"{name}: expected finite rates, got a non-finite value (NaN or inf) at sample "
                                 f"{at} ({bad.size} non-finite row(s) in that block); mask or drop those samples first")
        raise _too_large(self.w1, self.w2, 0, self.w1.shape[0])


def _centred(y):
    """Count, mean and centred scatter of the columns of ``y`` (6, m): one product with the sums, redone about
    the mean where the mean is large against the spread (more than ~6 of 16 digits would cancel)."""
    m = y.shape[1]
    with np.errstate(over="ignore", invalid="ignore"):
        s = y.sum(axis=1)
        mu = s / m
        sc = np.dot(y, y.T) - np.outer(s, mu)
        if np.any(mu**2 > 1e6 * np.maximum(np.diag(sc) / m, 1e-300)):
            yc = y - mu[:, None]
            d = yc.sum(axis=1) / m
            mu = mu + d
            sc = np.dot(yc, yc.T) - np.outer(d, d) * m
    return m, mu, sc


def _window_chunks(n: int, chunk_size: int, window: int, max_windows: int) -> frozenset | None:
    """Indices of the chunks whose innovation windows the block-robust covariance reads: None (every chunk) up to
    ``max_windows`` windows, else chunks spread evenly over the ``n`` used samples, ``max_windows`` windows at most
    (at least one chunk)."""
    n_chunks = -(-n // chunk_size)
    per_chunk = max(chunk_size // window, 1)
    if n_chunks * per_chunk <= max_windows:
        return None
    return frozenset(np.linspace(0, n_chunks - 1, max(1, max_windows // per_chunk)).round().astype(int).tolist())


def _innovation_windows(y, start: int, lo: int, chunk_size: int, window: int, chosen=None) -> list:
    """``_stats_of`` parts of the filtered block ``y`` (6, m) that begins at used sample ``start``: in each chunk of
    ``chunk_size`` samples (of the chunk indices ``chosen``; None: all), the whole windows from its first settled
    sample (``lo`` in the block), each run labelled by its chunk's first sample."""
    views, runs = [], []
    m = y.shape[1]
    for c0 in range(0, m, chunk_size):
        if chosen is not None and (start + c0) // chunk_size not in chosen:
            continue
        c1 = min(c0 + chunk_size, m)
        a = max(c0, lo)
        k = (c1 - a) // window if c1 > a else 0
        if k:
            views.append(y[:, a:a + k * window].reshape(6, k, window).transpose(1, 0, 2))
            runs.append(np.full(k, start + c0))
    if not views:
        return []
    return [_stats_of(np.concatenate(views), None, np.concatenate(runs))]
