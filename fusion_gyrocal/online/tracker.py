"""Online drift tracking: an error-state EKF (filterpy) seeded by the batch calibration.

The tracker follows the rotation ``R_1_2``, the scale factors and the combined bias of a gyro
pair while they drift (temperature, humidity) or jump (a shock), sample by sample or block by
block. It is built on :class:`filterpy.kalman.ExtendedKalmanFilter`.

Parts (one mechanism per module)
--------------------------------
* :mod:`.config`: :class:`TrackerConfig` (frozen), :class:`DriftNoise`, :class:`StepPrior`;
* :mod:`.ekf`: the filter and the fold of the error state into the estimate (the model, Eq. 4-9);
* :mod:`.hold`: the scale directions the data never inform (Theorem 2), held by the gauge or by a prior;
* :mod:`.steps`: the innovation gate, the CUSUM step detector, the buffer of recent samples, the blocks;
* :mod:`.adapt`: the measurement noise adapted per rate bin;
* :mod:`.seed`: the batch solve of a window and the filter started from a calibration;
* :mod:`.stepper`: the tracker's state and its one update path (a block; one sample is a block of one);
* :mod:`.reseed`: step alarms: alarm -> batch solve -> re-seed, or restore and replay;
* :mod:`.history`: :class:`TrackHistory` and its recording; :mod:`.figures`: its plots;
* this module: :class:`GyroPairTracker`, which is constructed, seeded and fed samples or blocks.

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

import numpy as np

from ..core.linear_map import hold_cross_axis, restore_cross_axis
from ..core.model import S1, S2, PairCalibration
from ..core.moments import as_rates
from ..core.noise import NoiseModel
from ..errors import InputError, OptionError
from ..pipeline.resample import resample
from ..pipeline.streams import check_timestamps
from .config import DriftNoise, StepPrior, TrackerConfig
from .figures import plot_history, track_figure_for_report
from .history import PairTruth, ReseedEvent, TrackHistory
from .hold import DIM
from .reseed import observable_chi2
from .seed import model_error, seed_from_samples, seed_noise
from .stepper import Stepper
from .steps import block_spans

__all__ = ["DriftNoise", "GyroPairTracker", "PairTruth", "ReseedEvent", "StepPrior", "TrackHistory",
           "TrackerConfig", "plot_history", "track_figure_for_report"]

_CONFIG_FIELDS = frozenset(f.name for f in dataclasses.fields(TrackerConfig))


def _finite_rates(t, omega_1, omega_2, where: str):
    """``omega_1``, ``omega_2`` as float (N, 3) arrays of finite rates, one row per time of ``t``."""
    w1 = np.asarray(as_rates("omega_1", omega_1, length=t.shape[0]), dtype=float)
    w2 = np.asarray(as_rates("omega_2", omega_2, length=t.shape[0]), dtype=float)
    if not (np.isfinite(w1).all() and np.isfinite(w2).all()):
        bad = int(np.flatnonzero(~(np.isfinite(w1).all(1) & np.isfinite(w2).all(1)))[0])
        raise InputError(f"omega_1/omega_2: expected finite rates, got a non-finite value at sample {bad}{where}; "
                         "mask or drop it first")
    return w1, w2


def _check_start(f, t0) -> None:
    """Refuse block times before the filter ``f``'s current time."""
    if t0 < f.t:
        raise InputError(f"t: expected block times at or after the current time {f.t!r}, got {t0!r}")


def _truth_columns(tracker, rows: PairTruth, nees_rows) -> tuple:
    """``(nees, truth)`` columns of a tracker's history whose last ``len(rows)`` rows are the updates a run with
    the truth ``rows`` (one per update) made: scales in the tracker's gauge, NaN in the earlier rows."""
    scales = np.array([np.concatenate(tracker.express_in_gauge(a, b)) for a, b in zip(rows.scale_1, rows.scale_2)])
    n0 = len(tracker._track.recorder) - len(rows)

    def pad(x):
        return np.concatenate([np.full((n0,) + x.shape[1:], np.nan), x])

    scales = pad(scales.reshape(-1, 6))
    return pad(np.array(nees_rows)), (pad(rows.R_1_2), scales[:, :3], scales[:, 3:], pad(rows.bias))


class GyroPairTracker:
    """Online EKF tracker of a gyro pair's calibration, seeded by a :class:`PairCalibration`.

    Ready to use once constructed: the filterpy filter's state, covariance, transition and
    noise matrices are all set from the seed. The configuration is a frozen :class:`TrackerConfig`
    (:attr:`config`, e.g. ``tracker.config.drift``), never assigned on the tracker: a tracker with
    another configuration is built by :meth:`reconfigured` (or by the constructor).

    Parameters
    ----------
    calibration : PairCalibration
        Seed (estimate and covariance), e.g. from :func:`fusion_gyrocal.calibrate_pair`.
        Its ``noise_std`` (per-sample white noise of each gyro, rad/s) sets the measurement
        noise unless ``noise_model`` flags a misfit; its ``time_offset_s`` is used by :meth:`run_streams`.
        A seed with the full linear map (``linear_map="full"``) keeps its cross-axis terms fixed
        (:attr:`cross_axis_terms`, :func:`~fusion_gyrocal.core.linear_map.hold_cross_axis`): the filter tracks
        the rotation in the batch's convention, scale factors and bias. A seed with ``linear_map="reference"``
        is refused.
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
    >>> tracker.reconfigured(drift=DriftNoise.constant()).config.drift == DriftNoise.constant()
    True
    """

    __slots__ = ("_track", "_noise_model", "_time_offset_s", "_unmix", "_held")

    def __init__(self, calibration: PairCalibration, *, t0: float = 0.0, seed_span_s: float = 0.0,
                 noise_model: NoiseModel | None | str = "seed", config: TrackerConfig | None = None, **options):
        if not isinstance(calibration, PairCalibration):
            raise InputError(f"calibration: expected a PairCalibration, got {type(calibration).__name__}")
        seed, self._unmix = hold_cross_axis(calibration)
        self._held = calibration           # the seed: its cross-axis terms, when it has them, are held
        config = TrackerConfig.of(config, **options)
        noise_model, noise_std, misfit = seed_noise(calibration, noise_model)
        self._noise_model = noise_model
        self._time_offset_s = float(calibration.time_offset_s)
        self._track = Stepper(seed, float(t0), float(seed_span_s), config, noise_std, misfit,
                              model_error(calibration))

    def _gyro_1(self, w1) -> np.ndarray:
        """Gyro 1's samples in the filter's model: through ``(I + K)^-1`` when the seed has cross-axis terms
        (:func:`~fusion_gyrocal.core.linear_map.hold_cross_axis`)."""
        return w1 if self._unmix is None else w1 @ self._unmix.T

    def __setattr__(self, name, value):           # the configuration's fields: a helpful refusal
        if name in _CONFIG_FIELDS:
            raise AttributeError(f"{name}: the tracker's configuration is frozen; tracker.reconfigured({name}=...) "
                                 "returns a tracker with the new value that continues from the current state")
        object.__setattr__(self, name, value)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_samples(cls, t, omega_1, omega_2, *, noise_std=None, noise_model: NoiseModel | None = None, gauge=None,
                     config: TrackerConfig | None = None, **options) -> "GyroPairTracker":
        """Seed a tracker from sample-aligned data with :func:`fusion_gyrocal.calibrate_pair`.

        The batch solve applies the paper's flex rejection and the tracker's gauge (``gauge``, else the
        configuration's); ``noise_std`` (rad/s per sample, one value or one per gyro) defaults to its residual
        estimate. The noise is then identified on the window (unless ``noise_model`` is given); when it flags a
        rate-dependent misfit, the tracker weighs each sample by the white noise plus the misfit's variance and the
        seed is solved again with the window's effective noise (:func:`~.seed.seed_from_samples`). The tracker
        starts at ``t[-1]`` with the seed inflated for the drift over the window (``seed_span_s``), its adapted
        noise started on the window. ``config`` and ``options`` configure the tracker.
        """
        if gauge is not None:
            options["gauge"] = gauge
        config = TrackerConfig.of(config, **options)
        cal, noise_model, t, w1, w2 = seed_from_samples(t, omega_1, omega_2, noise_std, noise_model, config)
        tracker = cls(cal, t0=float(t[-1]), seed_span_s=float(t[-1] - t[0]), noise_model=noise_model, config=config)
        tracker._track.learn_noise(t, tracker._gyro_1(w1), w2)
        return tracker

    def reconfigured(self, **changes) -> "GyroPairTracker":
        """A new tracker with ``changes`` to :attr:`config` that continues from the current state.

        The estimate, covariance, time, counters, history, buffered samples, CUSUM and an open alarm
        carry over; the new noise densities act from now on (e.g. on the next prediction). A new
        ``gauge`` or ``scale_prior_std`` re-expresses the estimate and the covariance in the new hold.
        This tracker is left unchanged.
        """
        new = object.__new__(type(self))
        new._noise_model, new._time_offset_s = self._noise_model, self._time_offset_s
        new._unmix, new._held = self._unmix, self._held
        new._track = self._track.reconfigured(self._track.config.replace(**changes))
        return new

    # ------------------------------------------------------------------ configuration, state (read-only)
    @property
    def config(self) -> TrackerConfig:
        """The tracker's configuration (frozen; see :meth:`reconfigured`)."""
        return self._track.config

    @property
    def noise_std(self) -> tuple[float, float]:
        """White noise per sample of each gyro (rad/s), from the seed."""
        return self._track.noise_std

    @property
    def noise_model(self) -> NoiseModel | None:
        """The identified noise the tracker was seeded with (None: given white noise)."""
        return self._noise_model

    @property
    def misfit_gain(self) -> tuple[float, float]:
        """``(a, b)`` of the rate-dependent misfit in the measurement covariance (``(0, 0)``: white noise)."""
        return self._track.misfit

    @property
    def time_offset_s(self) -> float:
        """The seed's time offset (s), added to gyro 2's timestamps by :meth:`run_streams`."""
        return self._time_offset_s

    @property
    def configuration(self):
        """The seed's :class:`~fusion_gyrocal.core.observability.Configuration`."""
        return self._track.configuration

    @property
    def kf(self):
        """The :class:`filterpy.kalman.ExtendedKalmanFilter` on the error state (zero between updates)."""
        return self._track.filter.kf

    @property
    def filter(self):
        """The :class:`~.ekf.ErrorStateEKF` (filterpy's filter and the nominal estimate), to inspect."""
        return self._track.filter

    @property
    def noise_scale(self):
        """The adapted measurement noise (:class:`~.adapt.NoiseScale`; None when ``config.noise_memory`` is 0)."""
        return self._track.noise_scale

    @property
    def n_samples(self) -> int:
        """Samples seen."""
        return self._track.n_samples

    @property
    def n_rejected(self) -> int:
        """Samples rejected by the innovation gate."""
        return self._track.n_rejected

    # ------------------------------------------------------------------ current estimate
    @property
    def t(self) -> float:
        """Time (s) of the current estimate."""
        return self._track.filter.t

    @property
    def R_1_2(self) -> np.ndarray:
        return self._track.filter.R.copy()

    @property
    def scale_1(self) -> np.ndarray:
        return self._track.filter.s1.copy()

    @property
    def scale_2(self) -> np.ndarray:
        return self._track.filter.s2.copy()

    @property
    def bias(self) -> np.ndarray:
        return self._track.filter.b.copy()

    @property
    def A(self) -> np.ndarray:
        """The linear map ``omega_1 ~ A omega_2 + (I + K) b``: ``(I + K) S_1 R S_2^-1`` with the seed's fixed
        cross-axis terms (:attr:`cross_axis_terms`), ``S_1 R S_2^-1`` without."""
        A = self._track.filter.A
        return A if self._unmix is None else np.linalg.solve(self._unmix, A)

    @property
    def cross_axis_terms(self) -> np.ndarray:
        """The seed's relative cross-axis terms ``(xy, yz, zx)``, held fixed (zeros for a rigid seed). With them the
        filter's bias, history and NEES are those of gyro 1's samples through ``(I + K)^-1``."""
        return np.array(self._held.cross_axis_terms) if self._unmix is not None else np.zeros(3)

    @property
    def error_covariance(self) -> np.ndarray:
        """(12, 12) covariance of the error state ``[dtheta, log s_1, log s_2, b]``."""
        return np.array(self._track.filter.kf.P)

    @property
    def covariance(self) -> np.ndarray:
        """(12, 12) covariance in :class:`PairCalibration`'s order ``[dtheta, scale_1, scale_2, bias]``."""
        J = np.ones(DIM)
        J[S1], J[S2] = self._track.filter.s1, self._track.filter.s2
        return self._track.filter.kf.P * np.outer(J, J)

    @property
    def gauge_description(self) -> str:
        return self._track.filter.hold.describe()

    @property
    def nees_dof(self) -> int:
        return self._track.filter.hold.nees_dof

    @property
    def reseeds(self) -> tuple:
        """The step alarms decided so far (:class:`~.history.ReseedEvent`, accepted re-seeds and rejected alarms),
        oldest first; the same events as the history's ``reseeds``, without building it."""
        return tuple(self._track.reseeder.events)

    @property
    def open_alarm(self) -> tuple[float, float] | None:
        """``(t_detected, onset)`` (s) of a step alarm still open, None otherwise: a step of the mounting is
        suspected and not yet confirmed or rejected (that takes ``reseed_window_s`` of exciting motion after the
        onset), so the covariance carries the step prior until then."""
        a = self._track.reseeder.alarm
        return None if a is None else (float(a.t_detected), float(a.onset))

    @property
    def state_at_alarm(self) -> tuple | None:
        """``(R_1_2, scale_1, scale_2, bias, error_covariance, t)`` of the filter when the open step alarm rose
        (the state a rejected alarm returns to), None when no alarm is open (:attr:`open_alarm`)."""
        a = self._track.reseeder.alarm
        return None if a is None else tuple(x.copy() if isinstance(x, np.ndarray) else x for x in a.state)

    @property
    def calibration(self) -> PairCalibration:
        """The current estimate as a :class:`PairCalibration` (``method="ekf"``); a note says when a step alarm is
        open (:attr:`open_alarm`)."""
        tr = self._track
        f, a = tr.filter, tr.reseeder.alarm
        notes = [f"EKF estimate at t = {f.t:.3f} s; {tr.n_rejected} of {tr.n_samples} samples gated"]
        if a is not None:
            notes.append(f"a step of the mounting is suspected since t = {a.t_detected:.3f} s (onset "
                         f"{a.onset:.3f} s), not yet confirmed or rejected: the covariance carries the step "
                         "prior until the data after the onset decide")
        if f.hold.prior_groups:
            notes.append("scale factors of parallel axis pairs: only their ratio is tracked; the common factor is "
                         f"held by a prior of std {tr.config.scale_prior_std:g}")
        return restore_cross_axis(PairCalibration(
            R_1_2=f.R, scale_1=f.s1, scale_2=f.s2, bias=f.b, configuration=tr.configuration.name,
            scale_observable=tr.configuration.scale_observable, covariance=self.covariance,
            gauge=self.gauge_description, snr=np.full(3, np.nan), n_samples=int(tr.n_samples),
            noise_std=np.array(tr.noise_std), noise_source="seed", method="ekf",
            time_offset_s=self._time_offset_s, rejected_fraction=tr.n_rejected / max(tr.n_samples, 1),
            notes=tuple(notes)), self._held)

    def express_in_gauge(self, scale_1, scale_2) -> tuple[np.ndarray, np.ndarray]:
        """Express scale factors (e.g. a ground truth) in the tracker's gauge.

        The gauge group is rescaled by the gauge; each parallel pair's common factor is replaced
        by the value the tracker holds. Only the determined ratios are left to compare.
        """
        return self._track.filter.hold.express(scale_1, scale_2)

    def nees(self, R_1_2, scale_1, scale_2, bias) -> float:
        """NEES of the current estimate against a truth, over the observable coordinates.

        The error is ``[Log(R_true R^T), log s_true - log s, b_true - b]`` with the truth's scale
        factors expressed in the gauge; it has :attr:`nees_dof` degrees of freedom.
        """
        f = self._track.filter
        return observable_chi2(f.hold, R_1_2, scale_1, scale_2, bias, (f.R, f.s1, f.s2, f.b), f.kf.P)

    # ------------------------------------------------------------------ updates
    def predict(self, t: float) -> None:
        """Predict the estimate to time ``t`` without a measurement (the covariance grows by the random walk)."""
        self._track.filter.predict_to(float(t))

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
        return self._track.step(np.array([float(t)]), self._gyro_1(w1.reshape(1, 3)), w2.reshape(1, 3), "sample") == 1

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
        w1, w2 = _finite_rates(t, omega_1, omega_2, " of the block")
        _check_start(self._track.filter, t[0])
        return self._track.step(t, self._gyro_1(w1), w2, "fast")

    # ------------------------------------------------------------------ history
    def history(self) -> TrackHistory:
        """The estimate history so far (one row per update)."""
        return self._history_with(None, None)

    def _history_with(self, nees, truth) -> TrackHistory:
        tr = self._track
        return tr.recorder.build(reseeds=tr.reseeder.events, n_samples=tr.n_samples, n_rejected=tr.n_rejected,
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
        B = self._track.config.block_size if block_size is None else block_size
        if isinstance(B, bool) or not isinstance(B, (int, np.integer)) or B < 1:
            raise OptionError(f"block_size: expected an integer >= 1, got {block_size!r}")
        B = int(B)
        t = check_timestamps("t", t)
        w1, w2 = _finite_rates(t, omega_1, omega_2, "")
        w1 = self._gyro_1(w1)
        if truth is not None:     # the truth columns: one history row per update of this run
            self._track.recorder.require_every_update(
                t.shape[0] if mode == "sample" else len(block_spans(t, B, max_gap_s)), "truth")
        if truth is not None and len(truth) != t.shape[0]:
            raise InputError(f"truth: expected {t.shape[0]} rows (one per sample), got {len(truth)}")
        _check_start(self._track.filter, t[0])
        step, truth_idx, nees_rows = self._track.step, [], []
        if mode == "sample" and truth is None:      # blocks of one, as views made by numpy's iteration
            for tk, a, b in zip(t[:, None], w1[:, None], w2[:, None]):
                step(tk, a, b, mode)
            return self.history()
        n = t.shape[0]
        for s, e in zip(range(n), range(1, n + 1)) if mode == "sample" else block_spans(t, B, max_gap_s):
            step(t[s:e], w1[s:e], w2[s:e], mode)
            if truth is not None:
                k = min(int(s + np.searchsorted(t[s:e], t[s:e].mean())), e - 1)
                truth_idx.append(k)
                nees_rows.append(self.nees(truth.R_1_2[k], truth.scale_1[k], truth.scale_2[k], truth.bias[k]))
        if truth is None:
            return self.history()
        return self._history_with(*_truth_columns(self, truth[np.asarray(truth_idx, dtype=int)], nees_rows))

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
