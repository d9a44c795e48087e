"""The tracker's state and its one update path: predict, screen, ONE filter update, record.

:class:`Stepper` holds everything a :class:`~.tracker.GyroPairTracker` updates (the filter, the gate, the
CUSUM, the adapted noise, the buffer of recent samples, the history, the open alarm) and runs one block of
samples through it (:meth:`Stepper.step`); a block of one sample is the per-sample mode. An alarm is handed to
its :class:`~.reseed.Reseeder` (alarm -> re-seed -> replay).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.model import PairCalibration
from .adapt import NoiseScale
from .history import HistoryRecorder
from .hold import ScaleHold
from .ekf import ErrorStateEKF
from .reseed import Reseeder
from .seed import seed_filter
from .steps import Cusum, InnovationGate, SampleRing, block_spans


class Stepper:
    """A tracker's state and its update path (see the module docstring).

    Parameters
    ----------
    calibration : PairCalibration
        The seed.
    t0, span_s : float
        Time of the seed and duration of its data (:func:`~.seed.seed_filter`).
    config : TrackerConfig
    noise_std : (float, float)
        White noise per sample of each gyro (rad/s).
    misfit : (float, float)
        Gains of the rate-dependent misfit (``(0, 0)``: white noise).
    model_error : float
        Variance factor of a re-seed batch covariance (:func:`~.seed.model_error`).
    """

    __slots__ = ("config", "noise_std", "misfit", "model_error", "configuration", "filter", "gate", "cusum",
                 "noise_scale", "ring", "recorder", "reseeder", "replaying", "n_samples", "n_rejected")

    def __init__(self, calibration: PairCalibration, t0: float, span_s: float, config, noise_std, misfit,
                 model_error: float):
        self.config, self.noise_std, self.misfit, self.model_error = config, noise_std, misfit, model_error
        self.filter = None
        self.seed(calibration, t0, span_s)
        self.gate = InnovationGate(config.gate, config.gate_neighbours)
        self.cusum = Cusum(config.cusum_drift, config.cusum_threshold, config.gate, t0)
        self.noise_scale = NoiseScale(config.noise_memory, config.gate) if config.noise_memory else None
        self.ring = SampleRing(config.buffer_samples)
        self.recorder = HistoryRecorder(config.history_max_rows)
        self.reseeder = Reseeder()
        self.replaying = False
        self.n_samples = self.n_rejected = 0

    def seed(self, cal: PairCalibration, t: float, span_s: float = 0.0) -> None:
        """Start the filter from a calibration at time ``t`` (construction, re-seed)."""
        self.configuration, self.filter = seed_filter(
            cal, t, self.config, self.noise_std, self.misfit, span_s=span_s,
            previous=None if self.filter is None else self.filter.hold)

    def learn_noise(self, t, w1, w2) -> None:
        """Start the adapted measurement noise (:class:`~.adapt.NoiseScale`) on the seed window: its blocks'
        innovations at the seed estimate, without updating the filter (the seed has used them)."""
        ns, f = self.noise_scale, self.filter
        if ns is None:
            return
        for s, e in block_spans(t, self.config.block_size, None):
            bins, lam = ns.factors(w1[s:e])
            _, _, d2, _, held = f.innovations(w1[s:e], w2[s:e], lam)
            ns.learn(bins, d2, held)
        if self.misfit != (0.0, 0.0):
            ns.release_unseen()        # the misfit extrapolated beyond the seed's rates: free to fall below 1

    def reconfigured(self, config) -> "Stepper":
        """A copy with another configuration that continues from the current state (the estimate, covariance,
        time, counters, history, buffered samples, CUSUM and an open alarm); a new gauge or scale prior
        re-expresses the estimate and the covariance in the new hold."""
        new = object.__new__(Stepper)
        new.config, new.noise_std, new.misfit, new.model_error = config, self.noise_std, self.misfit, self.model_error
        new.configuration = self.configuration
        f, alarm = self.filter, self.reseeder.alarm and dataclasses.replace(self.reseeder.alarm)
        if config.gauge == self.config.gauge and config.scale_prior_std == self.config.scale_prior_std:
            new.filter = f.copy(drift=config.drift, step_prior=config.step_prior)
        else:
            hold = ScaleHold(self.configuration, config.gauge, config.scale_prior_std, f.s1, f.s2, previous=f.hold)
            new.filter = ErrorStateEKF(hold, config.drift, config.step_prior, self.noise_std, f.R, f.s1, f.s2, f.b,
                                       f.kf.P, f.t, misfit=self.misfit)
            if alarm is not None:
                R0, s10, s20, b0, P0, t0 = alarm.state
                alarm.state = (R0, *hold.express(s10, s20), b0, new.filter.project(P0), t0)
        new.gate = InnovationGate(config.gate, config.gate_neighbours, self.gate.pending)
        new.cusum = Cusum(config.cusum_drift, config.cusum_threshold, config.gate, self.cusum.zero_t)
        new.cusum.level = self.cusum.level
        new.noise_scale = None if not config.noise_memory else (
            self.noise_scale.copy() if self.noise_scale is not None and config.noise_memory ==
            self.noise_scale.memory else NoiseScale(config.noise_memory, config.gate))
        new.ring = self.ring.resized(config.buffer_samples)
        new.recorder = self.recorder.copy(config.history_max_rows)
        new.reseeder, new.replaying = Reseeder(alarm, self.reseeder.events), False
        new.n_samples, new.n_rejected = self.n_samples, self.n_rejected
        return new

    def step(self, t, w1, w2, mode: str) -> int:
        """The one update path of a block (``t`` (B,), ``w1``/``w2`` (B, 3)); a block of one sample is the
        per-sample mode: predict, gate, CUSUM, ONE filter update, record, maybe re-seed. Returns the samples
        used."""
        f, ns, rs = self.filter, self.noise_scale, self.reseeder
        B = len(t)
        t_mid = float(t[0]) if B == 1 else float(t.sum()) / B       # the block's mean time
        times = (t_mid,) if B == 1 else t
        f.predict_to(t_mid)
        if not self.replaying:
            self.ring.push(t, w1, w2)
            self.n_samples += B
        bins = lam = None
        if ns is not None:
            bins, lam = ns.factors(w1)
        H, r, d2, g, held = f.innovations(w1, w2, lam)
        alarm = None
        if rs.alarm is None and not self.replaying:
            alarm = self.cusum.scan(times, d2) if ns is None else self.cusum.scan(*ns.screened(bins, times, d2))
        if alarm is not None:
            rs.raise_alarm(self, *alarm)
            H, r, d2, g, held = f.innovations(w1, w2, lam)         # covariance opened by the step prior
        elif ns is not None and rs.alarm is None:
            ns.learn(bins, d2, held)                               # never while a step is suspected
        keep = self.gate.keep(d2, fresh=alarm is not None)
        n_used = keep.count(True)
        self.n_rejected += B - n_used
        nis = np.nan
        if n_used == 1:
            k = keep.index(True)
            f.update_one(H[k], r[k], 1.0 if g is None else float(g[k]))
            nis = d2[k] / 3.0
        elif n_used > 1:
            if ns is not None and ns.correlation != 1.0:
                g = g * ns.correlation             # correlated errors: each sample is worth less
            nis = f.update_block(w1, w2, np.array(keep), g) / (3.0 * n_used)
            if ns is not None and rs.alarm is None:
                ns.learn_block(*f.score)
        if not self.replaying:
            self.recorder.add(t_mid, f.R, f.s1, f.s2, f.b, f.kf.P, nis, n_used, mode)
            if rs.alarm is not None:
                rs.maybe_reseed(self)
        return n_used
