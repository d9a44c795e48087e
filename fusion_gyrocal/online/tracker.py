"""Online drift tracking: an error-state EKF (filterpy) seeded by the batch calibration.

The tracker follows the rotation ``R_1_2``, the scale factors and the combined bias of a gyro
pair while they drift (temperature, humidity) or jump (a shock), sample by sample or block by
block. It is built on :class:`filterpy.kalman.ExtendedKalmanFilter`.

Parts (one mechanism per module)
--------------------------------
* :mod:`.config`: :class:`TrackerConfig` (frozen), :class:`DriftNoise`, :class:`StepPrior`;
* :mod:`.ekf`: the filter and the fold of the error state into the estimate (the model, Eq. 4-9);
* :mod:`.hold`: the scale directions the data never inform (Theorem 2), held by the gauge or by a prior;
* :mod:`.steps`: the innovation gate, the CUSUM step detector and the buffer of recent samples;
* :mod:`.history`: :class:`TrackHistory` and its recording; :mod:`.figures`: its plots;
* this module: :class:`GyroPairTracker`, which runs them and handles alarm -> re-seed -> replay.

Process model: independent random walks with densities (:class:`DriftNoise`) in physical
units: rad/sqrt(s) for the rotation, 1/sqrt(s) for the log-scales (relative scale per
sqrt(s)) and rad/s/sqrt(s) for the combined bias. ``Q = q^2 dt``, so gaps simply grow the
covariance by their duration.

Modes
-----
One code path screens and records every block of samples; a block of one sample is the
per-sample mode:

* per-sample (:meth:`GyroPairTracker.update`): one filterpy update per sample, chi-square gate
  on the 3-dof innovation;
* fast (:meth:`GyroPairTracker.update_block`): a block of B samples is linearised at one point
  and folded into ONE update. The stacked block update is an information update
  ``Lambda = sum_k H_k^T W H_k``, ``eta = sum_k H_k^T W r_k``; since ``H_k`` is affine in
  ``omega_2(k)`` and ``r_k`` affine in ``[omega_1(k); omega_2(k)]``, both follow exactly from the
  block's :class:`~fusion_gyrocal.core.moments.Moments` (count, mean, centred scatter), the same
  statistics the batch solver uses (:meth:`~.ekf.ErrorStateEKF.update_block`).

Robustness
----------
* gating: every sample's normalised innovation ``d^2 = r^T S^-1 r`` is tested against the
  chi-square(3) quantile (flex spikes), vectorised over the block, with the neighbouring samples
  also removed as in the paper's flex rejection;
* step changes: a CUSUM on the (clipped) normalised innovation detects a shock; the tracker
  opens its covariance by a step prior (so it follows the step at once and its bands say so),
  solves :func:`fusion_gyrocal.calibrate_pair` (with its flex rejection) over a window after the
  estimated onset (ring buffer of recent samples) once that window excites every direction
  (``reseed_min_spread``; a turn about one axis does not), and re-seeds from it if its rotation
  and scale factors differ significantly from the filter's state at the alarm (chi-square test on
  the difference, the batch covariance raised by the seed's model error, ``robust_inflation``);
  otherwise (a step of the combined bias alone, e.g. a gravity-dependent bias after a change of
  pose, or a false alarm such as a long flex burst) it restores that state with the bias part of
  the step prior opened and replays the buffered samples, so the filter absorbs a bias step;
* gaps and unsynchronised streams: :meth:`GyroPairTracker.run_streams` resamples gyro 2 onto
  gyro 1's clock (cubic spline, after adding ``time_offset_s``) only inside gyro 2's contiguous
  segments; blocks never straddle a gap.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from ..core.model import S1, S2, PairCalibration
from ..core.moments import as_rates, noise_pair
from ..core.noise import NoiseModel
from ..core.observability import explained_scatter
from ..core.observability import seed_configuration
from ..errors import GyroCalError, InputError, OptionError
from ..lie import log
from ..pipeline.resample import resample
from ..pipeline.streams import check_timestamps
from .config import DriftNoise, StepPrior, TrackerConfig
from .ekf import ErrorStateEKF, inflation, misfit_coefficients
from .figures import plot_history, track_figure_for_report
from .history import HistoryRecorder, PairTruth, ReseedEvent, TrackHistory
from .hold import DIM, ScaleHold
from .adapt import NoiseScale
from .steps import Cusum, InnovationGate, SampleRing

__all__ = ["DriftNoise", "GyroPairTracker", "PairTruth", "ReseedEvent", "StepPrior", "TrackHistory",
           "TrackerConfig", "plot_history", "track_figure_for_report"]

_REPLAY_BLOCK = 100      # samples per block when a false alarm's buffered samples are re-processed


def _batch(w1, w2, noise_std, gauge, misfit=None) -> PairCalibration:
    """Batch calibration of a window (:func:`fusion_gyrocal.calibrate_pair`, which applies the paper's
    flex rejection, Section VI.C, when the residuals call for it).

    With a rate-dependent misfit (``misfit``: :func:`~.ekf.misfit_coefficients`, None for white noise) the
    white ``noise_std`` is raised to the window's effective level (:func:`_effective_noise`), so that the
    batch covariance says what the window's fast samples are worth.
    """
    from ..pipeline.pipeline import calibrate_pair

    if misfit is not None and noise_std is not None:
        noise_std = _effective_noise(noise_std, w1, inflation(misfit, w1))
    return calibrate_pair(w1, w2, noise_std=noise_std, gauge=gauge, linear_map="rigid")   # the filter's model


def _effective_noise(noise_std, w1, g) -> tuple[float, float]:
    """White per-sample noise ``noise_std`` scaled to the level of equal weights that carries the same
    information as the samples' covariances ``g_k R``: the rate-weighted harmonic mean
    ``sigma_eff^2 = sigma^2 sum |omega_k|^2 / sum (|omega_k|^2 / g_k)`` (the rotation's information is
    ``sum omega omega^T / (g_k sigma^2)``; Eq. 12-17 weigh every sample alike)."""
    if g is None:
        return noise_std
    sq = np.einsum("ka,ka->k", w1, w1)
    k = float(np.sqrt(sq.sum() / max(float((sq / g).sum()), 1e-300))) if sq.sum() > 0 else 1.0
    n = np.broadcast_to(np.asarray(noise_std, dtype=float), (2,))
    return float(n[0] * k), float(n[1] * k)


def _misfit_gain(noise_model) -> tuple[float, float]:
    """``(a, b)`` of a :class:`~fusion_gyrocal.core.noise.NoiseModel`'s misfit when it flags one (its residual is
    not white noise), else ``(0, 0)``: an insignificant fit is noise of the fit, not a model."""
    if noise_model is None or noise_model.is_white or not noise_model.is_misfit:
        return 0.0, 0.0
    a, b = noise_model.misfit_gain
    return float(a), float(b)


def _model_error(cal: PairCalibration) -> float:
    """Variance factor of the model error a re-seed batch covariance is raised by: the seed's
    ``robust_inflation`` (block-robust over model covariance in its worst direction,
    :mod:`fusion_gyrocal.core.robust`), 1 when it has none. A re-seed window is too short for a sandwich
    of its own (:data:`fusion_gyrocal.core.solve.MIN_ROBUST_WINDOWS`); the pair's misfit is the same."""
    k = float(cal.robust_inflation)
    return k if np.isfinite(k) and k > 1.0 else 1.0


def _spread(w1, w2) -> float:
    """Smallest over largest eigenvalue of the scatter of gyro 1 that gyro 2 explains
    (:func:`~fusion_gyrocal.core.observability.explained_scatter`): 1 for motion about every axis alike,
    near 0 for a turn about one axis."""
    from ..core.moments import Moments

    ev = np.linalg.eigvalsh(explained_scatter(Moments.from_samples(w1, w2)))
    return float(max(ev[0], 0.0) / ev[-1]) if ev[-1] > 0 else 0.0


def _log_covariance(cal: PairCalibration, prior_std: float) -> np.ndarray:
    """``cal``'s covariance in ``[dtheta, log s1, log s2, b]``; undetermined scale factors get the prior."""
    cov = np.array(cal.covariance, dtype=float)
    bad = ~np.isfinite(cov).all(axis=1)
    cov[bad, :], cov[:, bad] = 0.0, 0.0
    J = np.ones(DIM)
    J[S1], J[S2] = 1.0 / np.asarray(cal.scale_1), 1.0 / np.asarray(cal.scale_2)
    P = cov * np.outer(J, J)
    P[bad, bad] = prior_std**2
    return P


def _blocks(t, size: int, max_gap_s: float | None) -> list[tuple[int, int]]:
    """``(start, end)`` of blocks of about ``size`` samples that never straddle a gap (a short tail joins
    the block before it); a step larger than ``max_gap_s`` (default 5 median intervals) is a gap."""
    if max_gap_s is None:
        max_gap_s = 5.0 * float(np.median(np.diff(t))) if t.shape[0] > 1 else np.inf
    bounds = np.concatenate([[0], np.flatnonzero(np.diff(t) > max_gap_s) + 1, [t.shape[0]]])
    spans = []
    for lo, hi in zip(bounds[:-1].tolist(), bounds[1:].tolist()):
        for s in range(lo, hi, size):
            e = min(s + size, hi)
            if hi - e < size // 2 and e < hi:   # fold a short tail into this block
                e = hi
            spans.append((s, e))
            if e == hi:
                break
    return spans


@dataclass
class _Alarm:
    """An open step alarm: when it rose, the estimated onset, and the filter's state to return to."""

    t_detected: float
    onset: float
    state: tuple             # ErrorStateEKF.state() at the alarm
    n_rejected: int
    next_try_t: float = -np.inf


def _read_only(name: str, doc: str):
    def get(self):
        return getattr(self._config, name)

    def refuse(self, value):
        raise AttributeError(f"{name}: the tracker's configuration is frozen; tracker.reconfigured({name}=...) "
                             "returns a tracker with the new value that continues from the current state")

    return property(get, refuse, doc=doc)


class GyroPairTracker:
    """Online EKF tracker of a gyro pair's calibration, seeded by a :class:`PairCalibration`.

    Ready to use once constructed: the filterpy filter's state, covariance, transition and
    noise matrices are all set from the seed. The configuration is a frozen :class:`TrackerConfig`
    (:attr:`config`); its fields are readable on the tracker but never assignable: a tracker with
    another configuration is built by :meth:`reconfigured` (or by the constructor).

    Parameters
    ----------
    calibration : PairCalibration
        Seed (estimate and covariance), e.g. from :func:`fusion_gyrocal.calibrate_pair`.
        Its ``noise_std`` (per-sample white noise of each gyro, rad/s) sets the measurement
        noise unless ``noise_model`` flags a misfit; its ``time_offset_s`` is used by :meth:`run_streams`.
    t0 : float
        Time (s) at which the seed is valid (usually the end of its data).
    seed_span_s : float
        Duration of the data the seed was estimated from. The seed estimates the window
        average, the filter starts at its end: the seed covariance is inflated by the drift over
        a third of the span (the error variance of a random walk's window mean at its end).
    noise_model : NoiseModel, None or "seed", optional
        The pair's identified noise (:func:`fusion_gyrocal.core.noise.identify_noise`). When its residual is
        a rate-dependent misfit (``kind`` says so), each sample's measurement covariance is its white
        ``noise_std`` plus the misfit's variance ``(a + b |omega|)^2 |omega|^2`` spread over the axes
        (``misfit_gain``; :mod:`.ekf`), so fast motion does not raise false step alarms (the factor adapted per
        rate bin, :mod:`.adapt`, corrects its level, also where the seed never reached). Otherwise the
        measurement noise is white, from ``calibration.noise_std``. Default ``"seed"``: the
        calibration's own ``noise_model`` (what :func:`fusion_gyrocal.calibrate_pair` identified), if it
        carries one; None: white noise whatever the seed carries.
    config : TrackerConfig, optional
        The configuration (default: the defaults).
    **options
        Fields of :class:`TrackerConfig` (``drift``, ``gauge``, ``step_prior``, ``scale_prior_std``,
        ``gate_probability``, ``cusum_threshold``, ``reseed_window_s``, ...), applied over ``config``.

    Examples
    --------
    >>> import numpy as np
    >>> from fusion_gyrocal import calibrate_pair
    >>> from fusion_gyrocal.evaluate.sim import general_rotation, simulate_drifting_pair
    >>> rng = np.random.default_rng(0)
    >>> t = np.arange(0.0, 20.0, 0.01)
    >>> w1, w2, _ = simulate_drifting_pair(t, general_rotation(rng, 15.0), np.ones(3), np.ones(3), rng=rng)
    >>> tracker = GyroPairTracker(calibrate_pair(w1[:1000], w2[:1000]), t0=t[999], drift=DriftNoise())
    >>> tracker.run(t[1000:], w1[1000:], w2[1000:]).mode
    'fast'
    >>> tracker.drift = DriftNoise.constant()
    Traceback (most recent call last):
    ...
    AttributeError: drift: the tracker's configuration is frozen; ...
    >>> tracker.reconfigured(drift=DriftNoise.constant()).drift == DriftNoise.constant()
    True
    """

    __slots__ = ("_config", "_noise_std", "_noise_model", "_misfit", "_model_error", "_time_offset_s",
                 "_configuration", "_filter", "_gate", "_cusum", "_noise_scale", "_ring", "_history", "_events",
                 "_alarm", "_replaying", "_n_samples", "_n_rejected")

    def __init__(self, calibration: PairCalibration, *, t0: float = 0.0, seed_span_s: float = 0.0,
                 noise_model: NoiseModel | None | str = "seed", config: TrackerConfig | None = None, **options):
        if not isinstance(calibration, PairCalibration):
            raise InputError(f"calibration: expected a PairCalibration, got {type(calibration).__name__}")
        if isinstance(noise_model, str) and noise_model == "seed":
            noise_model = calibration.noise_model if isinstance(calibration.noise_model, NoiseModel) else None
        if noise_model is not None and not isinstance(noise_model, NoiseModel):
            raise InputError(f"noise_model: expected a NoiseModel (fusion_gyrocal.core.noise.identify_noise), None "
                             f"or 'seed', got {noise_model!r}")
        config = TrackerConfig.of(config, **options)
        self._misfit = _misfit_gain(noise_model)
        noise = np.asarray(calibration.noise_std if self._misfit == (0.0, 0.0) else noise_model.noise_std, dtype=float)
        what = "calibration.noise_std" if self._misfit == (0.0, 0.0) else "noise_model.noise_std"
        if not (np.isfinite(noise).all() and (noise > 0).all()):
            raise InputError(f"{what}: expected two positive rad/s values, got {noise}")
        self._config = config
        self._noise_std = (float(noise[0]), float(noise[1]))
        self._noise_model = noise_model
        self._model_error = _model_error(calibration)
        self._time_offset_s = float(calibration.time_offset_s)
        self._filter = None
        self._seed(calibration, float(t0), span_s=float(seed_span_s))
        self._gate = InnovationGate(config.gate, config.gate_neighbours)
        self._cusum = Cusum(config.cusum_drift, config.cusum_threshold, config.gate, float(t0))
        self._noise_scale = NoiseScale(config.noise_memory, config.gate) if config.noise_memory else None
        self._ring = SampleRing(config.buffer_samples)
        self._history = HistoryRecorder(config.history_max_rows)
        self._events: list[ReseedEvent] = []
        self._alarm: _Alarm | None = None
        self._replaying = False
        self._n_samples = self._n_rejected = 0

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_samples(cls, t, omega_1, omega_2, *, noise_std=None, noise_model: NoiseModel | None = None, gauge=None,
                     config: TrackerConfig | None = None, **options) -> "GyroPairTracker":
        """Seed a tracker from sample-aligned data with :func:`fusion_gyrocal.calibrate_pair`.

        The batch solve applies the paper's flex rejection and the tracker's gauge (``gauge``, else
        the configuration's); ``noise_std`` (rad/s per sample, one value or one per gyro) defaults to
        its residual estimate. The noise is then identified on the window
        (:func:`fusion_gyrocal.core.noise.identify_noise` at the sample rate of ``t``, unless ``noise_model``
        is given; a window shorter than 16 s leaves it white). When it flags a rate-dependent misfit,
        the tracker weighs each sample by the white noise (``noise_std``, else the model's) plus the
        misfit's variance, and the seed is solved again with the window's effective noise
        (:func:`_effective_noise`) so that its covariance says what the window is worth. The tracker
        starts at ``t[-1]`` with the seed inflated for the drift over the window (``seed_span_s``).
        ``config`` and ``options`` configure the tracker.
        """
        from ..core.noise import identify_noise

        if gauge is not None:
            options["gauge"] = gauge
        config = TrackerConfig.of(config, **options)
        t = check_timestamps("t", t)
        w1 = as_rates("omega_1", omega_1, length=t.shape[0])
        w2 = as_rates("omega_2", omega_2, length=t.shape[0])
        cal = _batch(w1, w2, noise_std, config.gauge)
        if noise_model is None:
            try:
                noise_model = identify_noise(w1, w2, cal.A, cal.bias, rate_hz=1.0 / float(np.median(np.diff(t))))
            except InputError:           # too short a window for the noise identification: white noise
                noise_model = None
        misfit = _misfit_gain(noise_model)
        if misfit != (0.0, 0.0):
            if noise_std is not None:    # the caller's white level, the model's misfit
                noise_model = dataclasses.replace(noise_model, noise_std=noise_pair(noise_std))
            cal = _batch(w1, w2, noise_model.noise_std, config.gauge,
                         misfit=misfit_coefficients(noise_model.noise_std, cal.A, misfit))
        tracker = cls(cal, t0=float(t[-1]), seed_span_s=float(t[-1] - t[0]), noise_model=noise_model, config=config)
        tracker._learn_noise(t, np.asarray(w1, dtype=float), np.asarray(w2, dtype=float))
        return tracker

    def _learn_noise(self, t, w1, w2) -> None:
        """Start the adapted measurement noise (:class:`~.adapt.NoiseScale`) on the seed window: its blocks'
        innovations at the seed estimate, without updating the filter (the seed has used them)."""
        ns, f = self._noise_scale, self._filter
        if ns is None:
            return
        for s, e in _blocks(t, self._config.block_size, None):
            H, r = f.linearise(w1[s:e], w2[s:e])
            bins = ns.bins(w1[s:e])
            g, held = self._factors(f.inflation(w1[s:e]), ns.factors(bins))
            ns.learn(bins, f.innovation_d2(H, r, g), held)
        if self._misfit != (0.0, 0.0):
            ns.release_unseen()        # the misfit extrapolated beyond the seed's rates: free to fall below 1

    @staticmethod
    def _factors(g, lam):
        """The measurement covariance's factors (B,) of a block, ``max(lambda_j g_k, 1)`` (never below the white
        noise), from the misfit's :meth:`~.ekf.ErrorStateEKF.inflation` ``g`` (None: white) and the adapted
        ``lam``, and ``held``: ``max(lambda_j g_k, 1) / (lambda_j g_k)`` (None when no sample is held)."""
        if g is None:
            return lam, None              # white noise: lam >= 1
        g = g * lam
        if g.min() >= 1.0:
            return g, None
        gs = np.maximum(g, 1.0)
        return gs, gs / g

    def _seed(self, cal: PairCalibration, t: float, span_s: float = 0.0) -> None:
        """Start the filter from a calibration at time ``t`` (construction, re-seed)."""
        cfg = self._config
        configuration = seed_configuration(np.asarray(cal.R_1_2, dtype=float), cal.configuration)
        hold = ScaleHold(configuration, cfg.gauge, cfg.scale_prior_std, cal.scale_1, cal.scale_2,
                         previous=None if self._filter is None else self._filter.hold)
        self._configuration = configuration
        self._filter = ErrorStateEKF(hold, cfg.drift, cfg.step_prior, self._noise_std, cal.R_1_2, cal.scale_1,
                                     cal.scale_2, cal.bias, _log_covariance(cal, cfg.scale_prior_std), t,
                                     inflate_s=span_s / 3.0, misfit=self._misfit)

    def reconfigured(self, **changes) -> "GyroPairTracker":
        """A new tracker with ``changes`` to :attr:`config` that continues from the current state.

        The estimate, covariance, time, counters, history, buffered samples, CUSUM and an open alarm
        carry over; the new noise densities act from now on (e.g. on the next prediction). A new
        ``gauge`` or ``scale_prior_std`` re-expresses the estimate and the covariance in the new hold.
        This tracker is left unchanged.
        """
        config = self._config.replace(**changes)
        new = object.__new__(type(self))
        new._config, new._noise_std, new._time_offset_s = config, self._noise_std, self._time_offset_s
        new._noise_model, new._misfit, new._model_error = self._noise_model, self._misfit, self._model_error
        new._configuration = self._configuration
        f, alarm = self._filter, self._alarm and dataclasses.replace(self._alarm)
        if config.gauge == self._config.gauge and config.scale_prior_std == self._config.scale_prior_std:
            new._filter = f.copy(drift=config.drift, step_prior=config.step_prior)
        else:
            hold = ScaleHold(self._configuration, config.gauge, config.scale_prior_std, f.s1, f.s2, previous=f.hold)
            new._filter = ErrorStateEKF(hold, config.drift, config.step_prior, self._noise_std, f.R, f.s1, f.s2, f.b,
                                        f.kf.P, f.t, misfit=self._misfit)
            if alarm is not None:
                R0, s10, s20, b0, P0, t0 = alarm.state
                alarm.state = (R0, *hold.express(s10, s20), b0, new._filter.project(P0), t0)
        new._gate = InnovationGate(config.gate, config.gate_neighbours, self._gate.pending)
        new._cusum = Cusum(config.cusum_drift, config.cusum_threshold, config.gate, self._cusum.zero_t)
        new._cusum.level = self._cusum.level
        new._noise_scale = None if not config.noise_memory else (
            self._noise_scale.copy() if self._noise_scale is not None and config.noise_memory ==
            self._noise_scale.memory else NoiseScale(config.noise_memory, config.gate))
        new._ring = self._ring.resized(config.buffer_samples)
        new._history = self._history.copy(config.history_max_rows)
        new._events, new._alarm, new._replaying = list(self._events), alarm, False
        new._n_samples, new._n_rejected = self._n_samples, self._n_rejected
        return new

    # ------------------------------------------------------------------ configuration (read-only)
    @property
    def config(self) -> TrackerConfig:
        """The tracker's configuration (frozen; see :meth:`reconfigured`)."""
        return self._config

    drift = _read_only("drift", "Random-walk densities (:class:`DriftNoise`).")
    step_prior = _read_only("step_prior", "Covariance added at a step alarm (:class:`StepPrior`).")
    gauge = _read_only("gauge", "Gauge of the scale group that holds its members.")
    scale_prior_std = _read_only("scale_prior_std", "Prior 1-sigma of each parallel axis pair's common factor.")
    gate = _read_only("gate", "Chi-square(3) quantile of the innovation gate.")
    gate_neighbours = _read_only("gate_neighbours", "Samples dropped on each side of a gated one.")
    cusum_drift = _read_only("cusum_drift", "CUSUM allowance per sample.")
    cusum_threshold = _read_only("cusum_threshold", "CUSUM alarm level.")
    reseed_window_s = _read_only("reseed_window_s", "Data after the onset used for the re-seeding solve (s).")
    reseed_max_s = _read_only("reseed_max_s", "Give up re-seeding after this long (s).")
    reseed_probability = _read_only("reseed_probability", "Chi-square quantile for accepting a re-seed.")
    noise_memory = _read_only("noise_memory", "Samples per rate bin of the adapted measurement noise (0: none).")

    @property
    def noise_std(self) -> tuple[float, float]:
        """White noise per sample of each gyro (rad/s), from the seed."""
        return self._noise_std

    @property
    def noise_model(self) -> NoiseModel | None:
        """The identified noise the tracker was seeded with (None: given white noise)."""
        return self._noise_model

    @property
    def misfit_gain(self) -> tuple[float, float]:
        """``(a, b)`` of the rate-dependent misfit in the measurement covariance (``(0, 0)``: white noise)."""
        return self._misfit

    @property
    def time_offset_s(self) -> float:
        """The seed's time offset (s), added to gyro 2's timestamps by :meth:`run_streams`."""
        return self._time_offset_s

    @property
    def configuration(self):
        """The seed's :class:`~fusion_gyrocal.core.observability.Configuration`."""
        return self._configuration

    @property
    def kf(self):
        """The :class:`filterpy.kalman.ExtendedKalmanFilter` on the error state (zero between updates)."""
        return self._filter.kf

    @property
    def n_samples(self) -> int:
        """Samples seen."""
        return self._n_samples

    @property
    def n_rejected(self) -> int:
        """Samples rejected by the innovation gate."""
        return self._n_rejected

    # ------------------------------------------------------------------ current estimate
    @property
    def t(self) -> float:
        """Time (s) of the current estimate."""
        return self._filter.t

    @property
    def R_1_2(self) -> np.ndarray:
        return self._filter.R.copy()

    @property
    def scale_1(self) -> np.ndarray:
        return self._filter.s1.copy()

    @property
    def scale_2(self) -> np.ndarray:
        return self._filter.s2.copy()

    @property
    def bias(self) -> np.ndarray:
        return self._filter.b.copy()

    @property
    def A(self) -> np.ndarray:
        return self._filter.A

    @property
    def error_covariance(self) -> np.ndarray:
        """(12, 12) covariance of the error state ``[dtheta, log s_1, log s_2, b]``."""
        return np.array(self._filter.kf.P)

    @property
    def covariance(self) -> np.ndarray:
        """(12, 12) covariance in :class:`PairCalibration`'s order ``[dtheta, scale_1, scale_2, bias]``."""
        J = np.ones(DIM)
        J[S1], J[S2] = self._filter.s1, self._filter.s2
        return self._filter.kf.P * np.outer(J, J)

    @property
    def gauge_description(self) -> str:
        return self._filter.hold.describe()

    @property
    def nees_dof(self) -> int:
        return self._filter.hold.nees_dof

    @property
    def open_alarm(self) -> tuple[float, float] | None:
        """``(t_detected, onset)`` (s) of a step alarm still open, None otherwise: a step of the mounting is
        suspected and not yet confirmed or rejected (that takes ``reseed_window_s`` of exciting motion after the
        onset), so the covariance carries the step prior until then."""
        a = self._alarm
        return None if a is None else (float(a.t_detected), float(a.onset))

    @property
    def calibration(self) -> PairCalibration:
        """The current estimate as a :class:`PairCalibration` (``method="ekf"``); a note says when a step alarm is
        open (:attr:`open_alarm`)."""
        f = self._filter
        notes = [f"EKF estimate at t = {f.t:.3f} s; {self._n_rejected} of {self._n_samples} samples gated"]
        if self._alarm is not None:
            notes.append(f"a step of the mounting is suspected since t = {self._alarm.t_detected:.3f} s (onset "
                         f"{self._alarm.onset:.3f} s), not yet confirmed or rejected: the covariance carries the step "
                         "prior until the data after the onset decide")
        if f.hold.prior_groups:
            notes.append("scale factors of parallel axis pairs: only their ratio is tracked; the common factor is "
                         f"held by a prior of std {self._config.scale_prior_std:g}")
        return PairCalibration(
            R_1_2=f.R, scale_1=f.s1, scale_2=f.s2, bias=f.b, configuration=self._configuration.name,
            scale_observable=self._configuration.scale_observable, covariance=self.covariance,
            gauge=self.gauge_description, snr=np.full(3, np.nan), n_samples=int(self._n_samples),
            noise_std=np.array(self._noise_std), noise_source="seed", method="ekf",
            time_offset_s=self._time_offset_s, rejected_fraction=self._n_rejected / max(self._n_samples, 1),
            notes=tuple(notes))

    def express_in_gauge(self, scale_1, scale_2) -> tuple[np.ndarray, np.ndarray]:
        """Express scale factors (e.g. a ground truth) in the tracker's gauge.

        The gauge group is rescaled by the gauge; each parallel pair's common factor is replaced
        by the value the tracker holds. Only the determined ratios are left to compare.
        """
        return self._filter.hold.express(scale_1, scale_2)

    def nees(self, R_1_2, scale_1, scale_2, bias) -> float:
        """NEES of the current estimate against a truth, over the observable coordinates.

        The error is ``[Log(R_true R^T), log s_true - log s, b_true - b]`` with the truth's scale
        factors expressed in the gauge; it has :attr:`nees_dof` degrees of freedom.
        """
        f = self._filter
        return self._chi2(R_1_2, scale_1, scale_2, bias, (f.R, f.s1, f.s2, f.b), f.kf.P)

    @property
    def _extrinsic_dof(self) -> int:
        """Observable coordinates of the rotation and the scale factors (the bias's three left out)."""
        return self.nees_dof - 3

    def _chi2(self, R_1_2, scale_1, scale_2, bias, state, P, extrinsic: bool = False) -> float:
        """``e^T P^-1 e`` in the observable coordinates for ``e`` the given values minus ``state``
        ``(R, s1, s2, b)``: ``[Log(R_1_2 R^T), log scale - log s, bias - b]``, scales expressed in the gauge;
        ``extrinsic``: the rotation and scale coordinates only (the marginal test without the bias)."""
        R, s1, s2, b = state
        t1, t2 = self.express_in_gauge(scale_1, scale_2)
        e = np.concatenate([log(np.asarray(R_1_2) @ R.T), np.log(t1 / s1), np.log(t2 / s2), np.asarray(bias) - b])
        V = self._filter.hold.obs_basis
        if extrinsic:                   # the held directions lie in the scale block: drop the bias rows, re-orthonormalise
            V = np.linalg.svd(V[:9], full_matrices=False)[0]
            V = np.vstack([V[:, :self._extrinsic_dof], np.zeros((3, self._extrinsic_dof))])
        eo = V.T @ e
        return float(eo @ np.linalg.solve(V.T @ P @ V, eo))

    # ------------------------------------------------------------------ updates
    def predict(self, t: float) -> None:
        """Predict the estimate to time ``t`` without a measurement (the covariance grows by the random walk)."""
        self._filter.predict_to(float(t))

    def update(self, t: float, omega_1, omega_2) -> bool:
        """Per-sample mode: predict to ``t`` and fold one sample pair (rad/s, shape (3,) each).

        The sample is a block of one (:meth:`update_block`), recorded as a per-sample row.
        Returns True if the sample passed the innovation gate and was used.
        """
        w1 = np.asarray(omega_1, dtype=float)
        w2 = np.asarray(omega_2, dtype=float)
        if w1.size != 3 or w2.size != 3:
            raise InputError(f"omega_1/omega_2: expected 3 rates each, got shapes {w1.shape} and {w2.shape}")
        if not (np.isfinite(w1).all() and np.isfinite(w2).all()):
            raise InputError(f"omega_1/omega_2: expected finite rates, got {w1} and {w2} at t = {t}")
        return self._step(np.array([float(t)]), w1.reshape(1, 3), w2.reshape(1, 3), "sample") == 1

    def update_block(self, t, omega_1, omega_2) -> int:
        """Fast mode: fold a block of sample pairs into ONE update through its moments.

        Parameters
        ----------
        t : array_like (B,)
            Strictly increasing sample times (s), none before the current time; ``B >= 1``.
        omega_1, omega_2 : array_like (B, 3)
            Sample-aligned rates (rad/s).

        Returns
        -------
        int
            Samples used (those passing the vectorised innovation gate).

        Notes
        -----
        All samples of the block are linearised at the current estimate (at the block's mean time),
        so the block is assumed short compared with the drift (a second or so). Each sample's
        innovation ``d^2 = r^T (H P H^T + R)^-1 r`` is gated (and the neighbours of a gated sample
        dropped); the accepted samples' moments give the information update exactly
        (:meth:`~.ekf.ErrorStateEKF.update_block`; a single accepted sample is a 3-d update).
        """
        t = np.asarray(t)
        if t.shape == (1,) and t.dtype.kind in "fiu" and np.isfinite(t[0]):
            t = t.astype(np.float64)            # one sample is a block too (check_timestamps asks for two)
        else:
            t = check_timestamps("t", t)
        w1 = as_rates("omega_1", omega_1, length=t.shape[0])
        w2 = as_rates("omega_2", omega_2, length=t.shape[0])
        if not (np.isfinite(w1).all() and np.isfinite(w2).all()):
            bad = int(np.flatnonzero(~(np.isfinite(w1).all(1) & np.isfinite(w2).all(1)))[0])
            raise InputError(f"omega_1/omega_2: expected finite rates, got a non-finite value at sample {bad} "
                             "of the block; mask or drop it first")
        self._check_start(t[0])
        return self._step(t, np.asarray(w1, dtype=float), np.asarray(w2, dtype=float), "fast")

    def _check_start(self, t0) -> None:
        if t0 < self._filter.t:
            raise InputError(f"t: expected block times at or after the current time {self._filter.t!r}, got {t0!r}")

    def _step(self, t, w1, w2, mode: str) -> int:
        """The one update path: predict, gate, CUSUM, ONE filter update, record, maybe re-seed."""
        f = self._filter
        B = t.shape[0]
        if B == 1:
            return self._step_one(float(t[0]), w1[0], w2[0], mode)
        t_mid = float(t.sum()) / B                                 # the block's mean time
        f.predict_to(t_mid)
        if not self._replaying:
            self._ring.push(t, w1, w2)
            self._n_samples += B
        H, r = f.linearise(w1, w2)
        g = f.inflation(w1)
        ns = self._noise_scale
        bins = held = None
        if ns is not None:
            bins = ns.bins(w1)
            g, held = self._factors(g, ns.factors(bins))
        d2 = f.innovation_d2(H, r, g)
        alarm = None
        if self._alarm is None and not self._replaying:
            screened = None if ns is None else ns.mature(bins)
            if screened is None or screened.any():
                ts, d2s = (t, d2) if screened is None else (t[screened], ns.screened(bins, d2)[screened])
                alarm = self._cusum.scan(ts, d2s)
                if alarm is not None:
                    alarm = (float(ts[alarm[0]]), alarm[1])
        if alarm is not None:
            self._raise_alarm(*alarm)
            d2 = f.innovation_d2(H, r, g)              # covariance opened by the step prior
        elif ns is not None and self._alarm is None:
            ns.learn(bins, d2, held)                   # never while a step is suspected
        keep = self._gate.keep(d2, fresh=alarm is not None)
        n_used = int(np.count_nonzero(keep))
        self._n_rejected += B - n_used
        nis = np.nan
        if n_used == 1:
            k = int(np.argmax(keep))
            f.update_one(H[k], r[k], 1.0 if g is None else float(g[k]))
            nis = d2[k] / 3.0
        elif n_used > 1:
            if ns is not None and ns.correlation != 1.0:
                g = g * ns.correlation             # correlated errors: each sample is worth less
            nis = f.update_block(w1, w2, keep, g) / (3.0 * n_used)
            if ns is not None and self._alarm is None:
                ns.learn_block(*f.score)
        if not self._replaying:
            self._history.add(t_mid, f.R, f.s1, f.s2, f.b, f.kf.P, nis, n_used, mode)
            if self._alarm is not None:
                self._maybe_reseed()
        return n_used

    def _step_one(self, t: float, w1, w2, mode: str) -> int:
        """:meth:`_step` for a block of one sample, in scalar form (the per-sample hot path): the same
        predict, gate, CUSUM, filterpy update and record, without the block machinery."""
        f = self._filter
        f.predict_to(t)
        if not self._replaying:
            self._ring.push_one(t, w1, w2)
            self._n_samples += 1
        ns = self._noise_scale
        if ns is None:
            lam = 1.0
        else:
            j, lam, mature = ns.bin_one(w1)
        H, r, S, d2, g = f.linearise_one(w1, w2, lam)
        alarm = None
        if self._alarm is None and not self._replaying:
            if ns is None:
                alarm = self._cusum.scan_one(t, d2)
            elif mature:
                alarm = self._cusum.scan_one(t, ns.screened_one(j, d2))
        if alarm is not None:
            self._raise_alarm(t, alarm[1])
            H, r, S, d2, g = f.linearise_one(w1, w2, lam)    # covariance opened by the step prior
        elif ns is not None and self._alarm is None:
            ns.learn_one(j, d2, 1.0 if g >= 1.0 else 1.0 / g)   # (a sample held at the white noise: 1 / g)
        used = self._gate.keep_one(d2, fresh=alarm is not None)
        if used:
            f.update_one(H, r, g if g > 1.0 else 1.0)
        else:
            self._n_rejected += 1
        if not self._replaying:
            self._history.add(t, f.R, f.s1, f.s2, f.b, f.kf.P, d2 / 3.0 if used else np.nan, int(used), mode)
            if self._alarm is not None:
                self._maybe_reseed()
        return int(used)

    # ------------------------------------------------------------------ step changes
    def _raise_alarm(self, t_detected: float, onset: float) -> None:
        """Step suspected: remember the state, open the covariance by the step prior."""
        self._alarm = _Alarm(t_detected, onset, self._filter.state(), self._n_rejected)
        self._filter.open_step()

    def _maybe_reseed(self) -> None:
        """Once the window after the onset is full and excites every direction: batch solve, then re-seed
        (the rotation or the scale factors changed) or restore, absorb a bias step and replay."""
        a, cfg, f = self._alarm, self._config, self._filter
        if f.t - a.onset < cfg.reseed_window_s or f.t < a.next_try_t:
            return
        data = self._ring.since(a.onset)
        thr = float(chi2.ppf(cfg.reseed_probability, self._extrinsic_dof))
        can_wait = f.t - a.onset < cfg.reseed_max_s and self._ring.oldest() <= a.onset
        spread = _spread(data[:, 1:4], data[:, 4:7])
        if spread < cfg.reseed_min_spread:
            if can_wait:
                a.next_try_t = f.t + 0.5 * cfg.reseed_window_s  # wait for motion about the other axes
                return
            self._restore_and_replay()
            self._events.append(ReseedEvent(a.t_detected, a.onset, self._filter.t, False, np.nan, thr,
                                            f"the window after the onset never excited every direction (spread "
                                            f"{spread:.3g} < {cfg.reseed_min_spread:g}); no step of the rotation or "
                                            "scale can be confirmed: restored, bias step absorbed, replayed"))
            self._close_alarm()
            return
        try:
            if cfg.reseed_solver is not None:
                cal = cfg.reseed_solver(data[:, 1:4], data[:, 4:7])
            else:
                cal = _batch(data[:, 1:4], data[:, 4:7], self._noise_std, cfg.gauge,
                             misfit=misfit_coefficients(self._noise_std, f.A, self._misfit))
        except GyroCalError as exc:
            if can_wait:
                a.next_try_t = f.t + 0.5 * cfg.reseed_window_s  # wait for more motion
                return
            self._events.append(ReseedEvent(a.t_detected, a.onset, f.t, False, np.nan, thr,
                                            f"batch solve failed ({exc}); kept the filter with the step prior"))
            self._close_alarm()
            return
        R0, s10, s20, b0, P0, _ = a.state       # batch minus the filter at the alarm, rotation and scales
        P_batch = self._model_error * f.project(_log_covariance(cal, cfg.scale_prior_std))
        stat = self._chi2(cal.R_1_2, cal.scale_1, cal.scale_2, cal.bias, (R0, s10, s20, b0), P_batch + P0,
                          extrinsic=True)
        accepted = stat > thr
        if accepted:
            self._seed(cal, f.t, span_s=float(data[-1, 0] - data[0, 0]))
            reason = ("step change of the rotation or scale factors confirmed by the batch solve over the window "
                      "after the onset; re-seeded")
        else:
            db = np.asarray(cal.bias) - b0                  # the bias: did it step?
            Pb = P_batch[9:, 9:] + P0[9:, 9:]
            bias_step = float(db @ np.linalg.solve(Pb, db)) > float(chi2.ppf(cfg.reseed_probability, 3))
            self._restore_and_replay(bias_step)
            reason = ("batch solve agrees with the filter before the alarm in rotation and scale factors; " +
                      ("its bias stepped: restored, bias step absorbed, replayed" if bias_step else
                       "a transient (e.g. flex): restored and replayed"))
        self._events.append(ReseedEvent(a.t_detected, a.onset, self._filter.t, bool(accepted), float(stat), thr,
                                        reason))
        self._close_alarm()

    def _close_alarm(self) -> None:
        self._alarm = None
        self._cusum.reset(self._filter.t)

    def _restore_and_replay(self, bias_step: bool = True) -> None:
        """No step of the rotation or scales: return to the state at the alarm, open its bias by the step
        prior's bias part when ``bias_step`` (a step of the combined bias, which the filter then follows)
        and re-process the buffered samples after its time."""
        a, f = self._alarm, self._filter
        t_now = f.t
        f.restore(a.state)
        if bias_step:
            f.open_step(bias_only=True)
        data = self._ring.since(f.t)
        data = data[data[:, 0] > f.t]            # every buffered sample the restored state has not seen
        self._alarm = None
        self._n_rejected = a.n_rejected
        self._gate.pending = 0
        self._replaying = True
        try:
            for lo in range(0, data.shape[0], _REPLAY_BLOCK):
                blk = data[lo:lo + _REPLAY_BLOCK]
                self._step(blk[:, 0], blk[:, 1:4], blk[:, 4:7], "fast")
        finally:
            self._replaying = False
        f.predict_to(max(t_now, f.t))

    # ------------------------------------------------------------------ history
    def history(self) -> TrackHistory:
        """The estimate history so far (one row per update)."""
        return self._history_with(None, None)

    def _history_with(self, nees, truth) -> TrackHistory:
        return self._history.build(reseeds=self._events, n_samples=self._n_samples, n_rejected=self._n_rejected,
                                   gauge=self.gauge_description, nees_dof=self.nees_dof, nees=nees, truth=truth)

    # ------------------------------------------------------------------ drivers
    def run(self, t, omega_1, omega_2, *, mode: str = "fast", block_size: int | None = None,
            max_gap_s: float | None = None, truth: PairTruth | None = None) -> TrackHistory:
        """Track over sample-aligned arrays and return the history (from construction on).

        Parameters
        ----------
        t : array_like (N,)
            Strictly increasing times (s), after the tracker's current time.
        omega_1, omega_2 : array_like (N, 3)
            Sample-aligned rates (rad/s).
        mode : {"fast", "sample"}
            Fold blocks of ``block_size`` samples into one update, or update per sample.
        block_size : int, optional
            Samples per block in the fast mode (default ``config.block_size``).
        max_gap_s : float, optional
            A larger step between samples is a gap: no block straddles it (the covariance grows
            over it by the random walk). Default: 5 times the median sample interval.
        truth : PairTruth, optional
            Per-sample truth (N rows) for the NEES and the truth columns of the history.
        """
        if mode not in ("fast", "sample"):
            raise OptionError(f"mode: expected 'fast' or 'sample', got {mode!r}")
        B = self._config.block_size if block_size is None else block_size
        if isinstance(B, bool) or not isinstance(B, (int, np.integer)) or B < 1:
            raise OptionError(f"block_size: expected an integer >= 1, got {block_size!r}")
        B = int(B)
        t = check_timestamps("t", t)
        w1 = np.asarray(as_rates("omega_1", omega_1, length=t.shape[0]), dtype=float)
        w2 = np.asarray(as_rates("omega_2", omega_2, length=t.shape[0]), dtype=float)
        if not (np.isfinite(w1).all() and np.isfinite(w2).all()):
            bad = int(np.flatnonzero(~(np.isfinite(w1).all(1) & np.isfinite(w2).all(1)))[0])
            raise InputError(f"omega_1/omega_2: expected finite rates, got a non-finite value at sample {bad}; "
                             "mask or drop it first")
        if truth is not None and self._config.history_max_rows is not None:
            raise OptionError("truth: the truth columns need one history row per update; expected "
                              f"history_max_rows=None, got {self._config.history_max_rows}")
        if truth is not None and len(truth) != t.shape[0]:
            raise InputError(f"truth: expected {t.shape[0]} rows (one per sample), got {len(truth)}")
        self._check_start(t[0])
        if mode == "sample" and truth is None:     # the per-sample hot path: no per-sample slicing
            for k, tk in enumerate(t.tolist()):
                self._step_one(tk, w1[k], w2[k], mode)
            return self.history()
        spans = [(k, k + 1) for k in range(t.shape[0])] if mode == "sample" else _blocks(t, B, max_gap_s)
        truth_idx, nees_rows = [], []
        for s, e in spans:
            self._step(t[s:e], w1[s:e], w2[s:e], mode)
            if truth is not None:
                k = min(int(s + np.searchsorted(t[s:e], t[s:e].mean())), e - 1)
                truth_idx.append(k)
                nees_rows.append(self.nees(truth.R_1_2[k], truth.scale_1[k], truth.scale_2[k], truth.bias[k]))
        if truth is None:
            return self.history()
        # truth columns aligned with the rows of this run (scales in the gauge); earlier rows get NaN
        rows = truth[np.asarray(truth_idx, dtype=int)]
        scales = np.array([np.concatenate(self.express_in_gauge(a, b)) for a, b in zip(rows.scale_1, rows.scale_2)])
        n0 = len(self._history) - len(truth_idx)

        def pad(x):
            return np.concatenate([np.full((n0,) + x.shape[1:], np.nan), x])

        scales = pad(scales.reshape(-1, 6))
        return self._history_with(pad(np.array(nees_rows)), (pad(rows.R_1_2), scales[:, :3], scales[:, 3:],
                                                             pad(rows.bias)))

    def run_streams(self, t_1, omega_1, t_2, omega_2, *, mode: str = "fast", block_size: int | None = None,
                    max_gap_s: float | None = None) -> TrackHistory:
        """Track unsynchronised streams: gyro 2 is resampled onto gyro 1's timestamps.

        ``time_offset_s`` of the seed is added to ``t_2`` (ARCHITECTURE convention). Gyro 2 is
        interpolated with :func:`fusion_gyrocal.pipeline.resample.resample` (a cubic spline, the paper's
        footnote 1) separately inside each of its contiguous segments (a step larger than
        ``max_gap_s``, default 5 median intervals, is a gap); gyro 1's samples outside gyro 2's
        segments are dropped. Interpolation averages gyro 2's noise, so its stated variance is an
        upper bound there.
        """
        t1 = check_timestamps("t_1", t_1)
        t2 = check_timestamps("t_2", t_2) + self._time_offset_s
        w1 = as_rates("omega_1", omega_1, length=t1.shape[0])
        w2 = as_rates("omega_2", omega_2, length=t2.shape[0])
        gap2 = 5.0 * float(np.median(np.diff(t2))) if max_gap_s is None else max_gap_s
        w2i, keep = resample(t2, w2, t1, max_gap_s=gap2)
        if not keep.any():
            raise InputError("t_1/t_2: the streams do not overlap in time (after adding time_offset_s = "
                             f"{self._time_offset_s} s to t_2)")
        return self.run(t1[keep], w1[keep], w2i[keep], mode=mode, block_size=block_size, max_gap_s=max_gap_s)
