"""Streaming calibration of a gyro pair: chunks in, an estimate out at any time, bounded memory.

The calibrator keeps only sufficient statistics (:class:`~fusion_gyrocal.core.moments.Moments`, a few
dozen numbers), never samples, so its memory does not grow with the length of the log:

* no forgetting: every chunk is merged (:meth:`Moments.merge`); the estimate equals the batch
  estimate of everything seen (:func:`fusion_gyrocal.solve` on the same statistics);
* exponential forgetting (``forgetting=lambda`` per sample): before a chunk of ``m`` samples is
  merged, the statistics so far are down-weighted by ``lambda**m`` (:meth:`Moments.decayed`), so
  the estimate follows slow changes with a memory of about ``1 / (1 - lambda)`` samples;
* sliding window (``window_s``): a ring of ``n_bins`` per-bin moments, each covering
  ``window_s / n_bins`` seconds; bins that leave the window are dropped whole, so the window
  holds the last ``window_s`` seconds rounded up to whole bins.

:meth:`StreamingCalibrator.estimate` solves from the current statistics (cached until the next
update); its cost does not depend on how much data has been seen.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from ..core.model import PairCalibration
from ..core.moments import Moments, as_rates
from ..core.solve import solve
from ..errors import InputError, OptionError
from ..options import Options


class StreamingCalibrator:
    """Calibrate a rigid gyro pair from sample-aligned chunks as they arrive.

    Parameters
    ----------
    noise_std : float or (float, float), optional
        White-noise std per sample (rad/s) of gyro 1 and gyro 2; estimated from the residual of
        the current statistics when omitted (see :func:`fusion_gyrocal.solve`).
    forgetting : float, optional
        Exponential forgetting factor per sample, in (0, 1]; applied chunk-wise (the samples of one
        chunk share one weight). Mutually exclusive with ``window_s``.
    window_s : float, optional
        Length of a sliding window (s). Needs timestamps in :meth:`update` or ``rate_hz``.
    rate_hz : float, optional
        Sample rate used as the clock when :meth:`update` gets no timestamps.
    n_bins : int
        Bins of the sliding window (memory and resolution of its edge: ``window_s / n_bins``).
    options : Options, optional
        Solve options passed to :func:`fusion_gyrocal.solve` (:class:`~fusion_gyrocal.options.Options`);
        options that act on samples (time alignment, bias model, flex gate: not ``applies_to`` ``"moments"``)
        are refused here (:meth:`~fusion_gyrocal.options.Options.require`).
    **keywords
        Fields of :class:`~fusion_gyrocal.options.Options` (``noise_std``, ``method``, ``gauge``,
        ``min_snr``, ...), applied on top of ``options``.

    Examples
    --------
    >>> from fusion_gyrocal.evaluate.sim import simulate_pair
    >>> sim = simulate_pair(rng=0, n=6000)
    >>> cal = StreamingCalibrator(window_s=30.0, rate_hz=100.0)
    >>> for start in range(0, 6000, 500):
    ...     cal.update(sim.omega_1[start:start + 500], sim.omega_2[start:start + 500])
    >>> cal.estimate().configuration
    'general'
    """

    def __init__(self, *, forgetting: float | None = None, window_s: float | None = None,
                 rate_hz: float | None = None, n_bins: int = 32, options: Options | None = None, **keywords):
        if forgetting is not None and window_s is not None:
            raise OptionError("forgetting and window_s: expected at most one way to forget old data, got both")
        if forgetting is not None and not (0.0 < float(forgetting) <= 1.0):
            raise OptionError(f"forgetting: expected a factor per sample in (0, 1], got {forgetting}")
        if window_s is not None and not (np.isfinite(window_s) and window_s > 0):
            raise OptionError(f"window_s: expected a positive duration in seconds, got {window_s}")
        if rate_hz is not None and not (np.isfinite(rate_hz) and rate_hz > 0):
            raise OptionError(f"rate_hz: expected a positive sample rate in Hz, got {rate_hz}")
        if int(n_bins) < 2:
            raise OptionError(f"n_bins: expected at least 2 bins, got {n_bins}")
        self.options = Options.of(options, **keywords).require("moments", "StreamingCalibrator")
        self.forgetting = None if forgetting is None else float(forgetting)
        self.window_s = None if window_s is None else float(window_s)
        self.rate_hz = None if rate_hz is None else float(rate_hz)
        self.n_bins = int(n_bins)
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget everything (the configuration is kept)."""
        self._total = Moments.empty()
        self._bins: deque = deque()  # [bin index, Moments] for the sliding window
        self._samples_seen = 0
        self._t_last = -math.inf
        self._cache: PairCalibration | None = None

    @property
    def samples_seen(self) -> int:
        """Samples consumed since construction or :meth:`reset` (masked ones included)."""
        return self._samples_seen

    @property
    def moments(self) -> Moments:
        """The statistics the next estimate is computed from (weighted, or of the window)."""
        if self.window_s is not None:
            return Moments.merge_all(m for _, m in self._bins)
        return self._total

    @property
    def effective_samples(self) -> float:
        """Weight of the current statistics in samples (after forgetting or windowing)."""
        return self.moments.count

    # ------------------------------------------------------------------ input
    def _times(self, t, n):
        if t is None:
            if self.window_s is None:
                return None
            if self.rate_hz is None:
                raise InputError("t: a sliding window needs timestamps per chunk or rate_hz at construction")
            return (self._samples_seen + np.arange(n)) / self.rate_hz
        t = np.asarray(t, dtype=np.float64)
        if t.shape != (n,):
            raise InputError(f"t: expected shape ({n},) (one timestamp per sample of the chunk), got {t.shape}")
        if n and not np.isfinite(t).all():
            raise InputError("t: expected finite timestamps in seconds, got NaN or inf")
        if n:
            steps = np.diff(np.concatenate([[self._t_last], t]))
            bad = np.flatnonzero(~(steps > 0))
            if bad.size:
                i = int(bad[0])
                raise InputError(f"t: expected strictly increasing timestamps across chunks, got a step of "
                                 f"{steps[i]:.6g} s at sample {self._samples_seen + i}")
        return t

    def update(self, omega_1, omega_2, *, t=None, mask=None) -> None:
        """Consume one chunk of sample-aligned rates.

        Parameters
        ----------
        omega_1, omega_2 : array_like, shape (m, 3)
            The chunk's measured rates (rad/s) of gyro 1 and gyro 2.
        t : array_like, shape (m,), optional
            Timestamps (s), strictly increasing across chunks (needed by ``window_s`` without ``rate_hz``).
        mask : array_like of bool, shape (m,), optional
            Samples to use.

        Raises
        ------
        InputError
            Wrong shapes, non-finite rates (the sample index counts from the start of the stream)
            or timestamps that do not increase. The state is unchanged when this is raised.
        """
        w1 = as_rates("omega_1", omega_1)
        w2 = as_rates("omega_2", omega_2, length=w1.shape[0])
        n = w1.shape[0]
        times = self._times(t, n)
        if mask is not None:
            mask = np.asarray(mask, dtype=bool)
            if mask.shape != (n,):
                raise InputError(f"mask: expected shape ({n},), got {mask.shape}")
        try:
            if self.window_s is None:
                chunk = Moments.from_samples(w1, w2, mask=mask)
                pieces = None
            else:
                width = self.window_s / self.n_bins
                idx = np.floor(times / width).astype(np.int64)
                cuts = np.flatnonzero(np.diff(idx)) + 1
                pieces = [(int(idx[a]), Moments.from_samples(w1[a:b], w2[a:b], mask=None if mask is None else mask[a:b]))
                          for a, b in zip(np.r_[0, cuts], np.r_[cuts, n]) if b > a]
        except InputError as err:
            raise InputError(f"chunk starting at sample {self._samples_seen}: {err}") from None
        if self.window_s is None:
            if self.forgetting is not None and self.forgetting < 1.0:
                self._total = self._total.decayed(self.forgetting ** n)
            self._total = self._total.merge(chunk)
        else:
            for b, m in pieces:
                if self._bins and self._bins[-1][0] == b:
                    self._bins[-1][1] = self._bins[-1][1].merge(m)
                else:
                    self._bins.append([b, m])
            if n:
                oldest = int(idx[-1]) - self.n_bins  # bin of the last sample, minus the window
                while self._bins and self._bins[0][0] < oldest:
                    self._bins.popleft()
        if n and times is not None:
            self._t_last = float(times[-1])
        self._samples_seen += n
        self._cache = None

    # ------------------------------------------------------------------ output
    def estimate(self) -> PairCalibration:
        """The calibration from the current statistics (:func:`fusion_gyrocal.solve`), cached until the next update.

        With a sliding window the bins are the windows of the block-robust covariance
        (:mod:`~fusion_gyrocal.core.robust`, ``options.covariance``); with forgetting the covariance is the
        noise model's.

        Raises
        ------
        InputError
            Before at least 4 samples are in the statistics.
        ExcitationError, NotRigidError, ...
            As :func:`fusion_gyrocal.solve` for the current statistics (e.g. too little motion yet).
        """
        if self._cache is None:
            m = self.moments
            if m.count < 4:
                raise InputError(f"no estimate yet: expected at least 4 samples in the statistics, got "
                                 f"{m.count:.3g} after {self._samples_seen} sample(s)")
            self._cache = solve(m, self.options, windows=self._window_stats())
        return self._cache

    def _window_stats(self):
        """The sliding window's bins as :class:`~fusion_gyrocal.core.moments.WindowStats` (consecutive bins in
        one run), for the block-robust covariance; None with forgetting (no per-window record is kept)."""
        from ..core.moments import WindowStats

        bins = [(i, m) for i, m in self._bins if m.count >= 2]
        if self.window_s is None or len(bins) < 2:
            return None
        idx = np.array([i for i, _ in bins])
        run = np.concatenate([[0], np.cumsum(np.diff(idx) != 1)])
        count = np.array([m.count for _, m in bins])
        return WindowStats(count, np.stack([m.mean for _, m in bins]), np.stack([m.scatter for _, m in bins]), run,
                           int(round(count.mean())))
