"""The tracker's online adaptation of its measurement noise: a running scale per rate bin.

The measurement covariance of :mod:`.ekf` is a model: the seed's white noise plus the identified
misfit ``(a + b |omega|) omega`` (:func:`fusion_gyrocal.core.noise.identify_noise`), fitted on the seed
window. On a real board the residual at rates the seed never saw (a violent phase after static poses),
or during fast turns (time misalignment, acceleration sensitivity: errors that grow with the angular
acceleration rather than the rate), is several to hundreds of times larger than the model says. The
filter then (a) counts those samples as information they do not carry, so its covariance is far too
small, and (b) its CUSUM sees normalised innovations far above 1 and raises step alarms on a rigid board.

:class:`NoiseScale` multiplies each sample's modelled covariance by a factor ``lambda_j`` (>= 1 but in the bins
the seed did not reach, below) of its rate bin ``j`` (``|omega_1|`` in the bins :data:`EDGES`, rad/s)::

    Cov n(k) = lambda_j(k) R_k

estimated from the innovations, as adaptive Kalman filters do: ``lambda_j`` is the running mean (the last
``memory`` samples of the bin, exponential forgetting; a plain mean until the bin has that many) of
``lambda_j x_k``, ``x_k = min(d_k^2, c) / 3`` the clipped normalised innovation of sample ``k``
(``d_k^2 = r_k^T S_k^-1 r_k``, ``S_k`` with the current factor, ``c`` the gate's chi-square(3) quantile).
Its fixed point is ``E[min(d^2, c)] = 3``: the statistic the CUSUM screens (:class:`~.steps.Cusum`) then has
its nominal mean and the detector does not fire on the model error; the clip makes a burst of outliers
count as the gate, not as its square.

The factor never drops below 1 (the model's noise is a floor) in the bins where the model was fitted. An
identified misfit ``g_k`` (:func:`~.ekf.inflation`) extrapolated beyond the rates of the seed window can be
far too large, though: on the MIMU board a misfit fitted on static poses and their turns (``|omega|`` < 5
rad/s) predicts a residual of ~36 rad/s at 37 rad/s where the data show 0.6 rad/s; a factor held at 1 keeps
those samples, which carry most of the information, out of the estimate. So the bins the seed window did
not reach (:meth:`NoiseScale.release_unseen`, fewer than :data:`MATURE` samples) may drop below 1, each
sample's covariance then held at the white noise, ``max(lambda_j g_k, 1) R``; a sample held there counts in
the running mean at what it implies, ``max(lambda_j g_k, 1) x_k / g_k`` (the argument ``held`` of
:meth:`NoiseScale.learn`). In the bins the seed filled the factor stays >= 1: there the model was fitted,
and a factor free to fall with the chance scatter of a few hundred samples lets the CUSUM fire on it.

A bin seen for the first time starts at the largest factor of the slower bins already seen, not at 1: the
model error grows with the rate, and a violent phase after a static start would otherwise be taken as
white noise (on the MIMU board this halves the false step alarms: 37 -> 21 over 27 sessions x IMUs).

A step change must not be learnt as noise: the tracker learns only while no alarm is open (a step raises
an alarm within a few samples, the scale of a bin forgets over ``memory`` samples), and samples of a bin
that has not yet seen :data:`MATURE` samples are not screened by the CUSUM (their scale is still being
learnt; the gate still screens them).
"""

from __future__ import annotations

import math
from bisect import bisect_right

import numpy as np

EDGES = (0.03, 0.1, 0.3, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)   # bin edges (rad/s): rest, slow, human, fast, violent
CHI2_3_SPREAD = 2.0 / 3.0                  # variance of chi-square(3) / 3
BLOCK_MEMORY = 100                          # blocks over which the correlation factor is averaged
MATURE = 100                                # samples a bin has seen before the CUSUM screens its samples
MISFIT_FLOOR = 1e-9                         # smallest factor of an unseen bin's misfit (a numerical guard: the white
                                            # noise is the floor of each sample's covariance)


class NoiseScale:
    """Running factor of the modelled measurement covariance per ``|omega_1|`` bin (module docstring).

    Parameters
    ----------
    memory : int
        Samples per bin over which the factor is averaged (exponential forgetting beyond).
    clip : float
        Clip of ``d^2`` (the gate's chi-square(3) quantile; the CUSUM's clip).
    """

    __slots__ = ("memory", "clip", "_floor", "_scale", "_spread", "_count", "_edges", "mature_count", "_prev", "_corr",
                 "_n_blocks")

    def __init__(self, memory: int, clip: float):
        self.memory, self.clip = int(memory), float(clip)
        # per-bin state as Python lists of floats/ints: the per-sample path reads and writes one entry a
        # sample (numpy scalar indexing and arithmetic cost several times more); the block path converts
        self._scale = [1.0] * (len(EDGES) + 1)
        self._floor = [1.0] * (len(EDGES) + 1)     # smallest factor per bin (release_unseen)
        self._spread = [CHI2_3_SPREAD] * (len(EDGES) + 1)
        self._count = [0] * (len(EDGES) + 1)
        self._edges = np.array(EDGES)
        self.mature_count = min(MATURE, self.memory)
        self._prev = None                   # the last gyro-1 sample binned (its change to the next one)
        self._corr, self._n_blocks = 1.0, 0

    def copy(self) -> "NoiseScale":
        new = NoiseScale(self.memory, self.clip)
        new._scale, new._spread, new._count = list(self._scale), list(self._spread), list(self._count)
        new._floor = list(self._floor)
        new._prev, new._corr, new._n_blocks = self._prev, self._corr, self._n_blocks
        return new

    @property
    def scale(self) -> np.ndarray:
        """The factors ``lambda_j`` per bin (a copy)."""
        return np.array(self._scale)

    @property
    def floor(self) -> np.ndarray:
        """The smallest factor per bin (a copy): 1, or :data:`MISFIT_FLOOR` in the bins :meth:`release_unseen`
        released."""
        return np.array(self._floor)

    def release_unseen(self) -> None:
        """Let the factor of every bin with fewer than :data:`MATURE` samples so far drop below 1 (to
        :data:`MISFIT_FLOOR`): called at the end of the seed window when the modelled covariance carries an
        identified misfit, whose extrapolation to rates the seed did not see may be far too large (module
        docstring). The covariance of each sample is then held at the white noise by the caller."""
        for j, c in enumerate(self._count):
            if c < self.mature_count:
                self._floor[j] = MISFIT_FLOOR

    @property
    def spread(self) -> np.ndarray:
        """Running mean of ``(x - 1)^2`` per bin (a copy)."""
        return np.array(self._spread)

    @property
    def count(self) -> np.ndarray:
        """Samples each bin has learnt from (a copy)."""
        return np.array(self._count, dtype=np.int64)

    def _bins(self, w1) -> np.ndarray:
        """Bin index (B,) of consecutive gyro-1 rates (B, 3): by ``max(|omega_k|, |omega_k - omega_{k-1}|)``
        (the previous sample of the first one is the last sample binned before)."""
        v = np.einsum("ka,ka->k", w1, w1)
        d = np.diff(w1, axis=0, prepend=(w1[:1] if self._prev is None else np.array([self._prev])))
        np.maximum(v, np.einsum("ka,ka->k", d, d), out=v)
        self._prev = tuple(w1[-1].tolist())
        return np.searchsorted(self._edges, np.sqrt(v), side="right")

    def _bin(self, w1) -> int:
        """:meth:`_bins` of a block of one sample (1, 3), in scalar arithmetic."""
        (x0, x1, x2), = w1.tolist()
        p = self._prev
        self._prev = (x0, x1, x2)
        v = x0 * x0 + x1 * x1 + x2 * x2
        if p is not None:
            d0, d1, d2 = x0 - p[0], x1 - p[1], x2 - p[2]
            d = d0 * d0 + d1 * d1 + d2 * d2
            v = d if d > v else v
        return bisect_right(EDGES, math.sqrt(v))

    def _inherit(self, j: int) -> None:
        """A bin seen for the first time starts at the largest factor of the slower bins already seen (the
        model error grows with the rate: a violent phase after static poses is not white noise either)."""
        below = [self._scale[i] for i in range(j) if self._count[i] > 0]
        if below:
            self._scale[j] = max(self._scale[j], max(below))

    # A block of one sample (the per-sample mode) is computed in scalar arithmetic in the methods below
    # (numpy's per-call cost on one sample is several times the arithmetic); larger blocks vectorised.
    def factors(self, w1):
        """``(bins, lambda)``: the rate bins (B,) of gyro-1 rates ``w1`` (B, 3) and their factors (B,)."""
        if len(w1) == 1:
            j = self._bin(w1)
            if self._count[j] == 0:
                self._inherit(j)
            return (j,), (self._scale[j],)
        bins = self._bins(w1)
        for j in np.unique(bins).tolist():
            if self._count[j] == 0:
                self._inherit(j)
        return bins, np.array(self._scale)[bins]

    def screened(self, bins, t, d2):
        """``(t, d2)`` (sequences) of the samples the CUSUM screens, ``d2`` as it screens them: only the samples whose bin
        has seen :data:`MATURE` samples (its factor is learnt), ``3 (1 + (x - 1) / k)``, ``x = min(d^2, c) / 3``,
        with ``k = max(1, sqrt(v_j / v_0))`` for ``v_j`` the bin's running mean of ``(x - 1)^2`` and ``v_0`` its
        value for chi-square(3) innovations: a bin whose normalised innovations scatter more than the
        Gaussian model's (heavy tails, bursts) weighs less in the detector, never more."""
        if len(bins) == 1:
            j = bins[0]
            if self._count[j] < self.mature_count:
                return (), ()
            k = self._spread[j] / CHI2_3_SPREAD
            x = d2[0] if d2[0] <= self.clip else self.clip                # NaN counts as the clip
            return t, (x if k <= 1.0 else 3.0 + (x - 3.0) / math.sqrt(k),)
        mature = np.array(self._count)[bins] >= self.mature_count
        k = np.array(self._spread)[bins]
        x = np.minimum(np.nan_to_num(np.asarray(d2), nan=self.clip), self.clip)
        return np.asarray(t)[mature], (3.0 + (x - 3.0) / np.sqrt(np.maximum(k / CHI2_3_SPREAD, 1.0)))[mature].tolist()

    def learn(self, bins, d2, held=None) -> None:
        """Update the factors from a block's normalised innovations ``d2`` (B,) (computed with the factors);
        ``held`` (B,): ``max(lambda g, 1) / (lambda g)`` of samples held at the white noise (None: none)."""
        if len(bins) == 1:
            j = bins[0]
            c = self._count[j] + 1
            self._count[j] = c
            x = (d2[0] if d2[0] <= self.clip else self.clip) / 3.0          # NaN counts as the clip
            n = c if c < self.memory else self.memory
            s = self._scale[j]
            s += s * (x * (1.0 if held is None else held[0]) - 1.0) / n
            f = self._floor[j]
            self._scale[j] = s if s > f else f
            self._spread[j] += ((x - 1.0) ** 2 - self._spread[j]) / n
            return
        nb = len(self._scale)
        m = np.bincount(bins, minlength=nb)
        xk = np.minimum(np.nan_to_num(np.asarray(d2), nan=self.clip), self.clip) / 3.0
        xs = xk if held is None else xk * held
        x = np.bincount(bins, weights=xs, minlength=nb)
        v = np.bincount(bins, weights=(xk - 1.0) ** 2, minlength=nb)
        scale, spread, count = np.array(self._scale), np.array(self._spread), np.array(self._count, dtype=np.int64)
        seen = m > 0
        mm = m[seen]
        n = np.minimum(count[seen] + mm, self.memory)
        beta = np.minimum(mm / n, 1.0)
        s = scale[seen]
        scale[seen] = np.maximum(s * (1.0 - beta + beta * x[seen] / mm), np.array(self._floor)[seen])
        spread[seen] += beta * (v[seen] / mm - spread[seen])
        count[seen] += mm
        self._scale, self._spread, self._count = scale.tolist(), spread.tolist(), count.tolist()

    def learn_block(self, score: float, dof: int) -> None:
        """Update the correlation factor from a block update's score statistic (``score`` ~ chi-square(dof) when
        the block's samples are independent with the adapted covariance; larger when their errors are correlated)."""
        if dof <= 0 or not np.isfinite(score):
            return
        self._n_blocks += 1
        n = min(self._n_blocks, BLOCK_MEMORY)
        self._corr += (self.correlation * score / dof - self._corr) / n    # the running mean itself unclipped

    @property
    def correlation(self) -> float:
        """Factor ``>= 1`` of the block updates' measurement covariance: the running mean over
        :data:`BLOCK_MEMORY` blocks of their score statistic per degree of freedom (times the factor it was
        computed with), 1 for independent samples; the block-robust sandwich of
        :mod:`fusion_gyrocal.core.robust` as one online number."""
        return self._corr if self._corr > 1.0 else 1.0
