"""Online drift tracking: an error-state EKF (filterpy) seeded by the batch calibration.

The tracker follows the rotation ``R_1_2``, the scale factors and the combined bias of a gyro
pair while they drift (temperature, humidity) or jump (a shock), sample by sample or block by
block. It is built on :class:`filterpy.kalman.ExtendedKalmanFilter`.

Model
-----
Measurement (Eq. 4-9 of the paper, one sample)::

    z_k = omega_1_meas(k) = A(x) omega_2_meas(k) + b + n(k),
    A(x) = diag(s_1) Exp(dtheta) R_ref diag(1 / s_2),   s_i = s_i,ref * exp(delta_i),
    Cov n(k) = sigma_1^2 I + sigma_2^2 A A^T     (gyro 2's noise enters through A)

Error state (12): ``[dtheta (3, rad, gyro 1 frame), delta_1 (3), delta_2 (3) log-scales, db (3, rad/s)]``.
After every update the error is folded into the reference (``R_ref <- Exp(dtheta) R_ref``,
``s_ref <- s_ref exp(delta)``, ``b <- b + db``) and reset to zero (multiplicative EKF).

Process model: independent random walks with densities (:class:`DriftNoise`) in physical
units: rad/sqrt(s) for the rotation, 1/sqrt(s) for the log-scales (relative scale per
sqrt(s)) and rad/s/sqrt(s) for the combined bias. ``Q = q^2 dt``, so gaps simply grow the
covariance by their duration.

Unobservable directions
-----------------------
The scale factors are linked in groups (Theorem 2; :func:`fusion_gyrocal.core.observability.classify`):
all six in the general configuration, plus one group per parallel axis pair in the degenerate
ones (Lemmas 2-3). Scaling every member of a group by the same factor leaves ``A`` unchanged,
so the data never inform the group's common factor. The tracker holds each such direction:

* the group containing the gauge's members follows the :class:`~fusion_gyrocal.core.direct.Gauge`
  (default the library's unit prior on both x axes, Eq. 32-34), as in
  :func:`fusion_gyrocal.calibrate_pair`; its common factor has no variance *in the gauge*;
* every other group (a parallel axis pair) keeps the log-mean of its scale factors at the seed's
  value with a prior standard deviation ``scale_prior_std``: the reported 1-sigma of those scale
  factors stays at the prior (it neither diverges nor shrinks).

Process noise and every update are projected so that they never move a held direction.

Modes
-----
* per-sample (:meth:`GyroPairTracker.update`): one filterpy update per sample, chi-square gate
  on the 3-dof innovation;
* fast (:meth:`GyroPairTracker.update_block`): a block of B samples is linearised at one point
  and folded into ONE update. The stacked block update is an information update
  ``Lambda = sum_k H_k^T W H_k``, ``eta = sum_k H_k^T W r_k``; since ``H_k`` is affine in
  ``omega_2(k)`` and ``r_k`` affine in ``[omega_1(k); omega_2(k)]``, both follow exactly from the
  block's :class:`~fusion_gyrocal.core.moments.Moments` (count, mean, centred scatter), the same
  statistics the batch solver uses. The information is applied through filterpy as one
  update with a whitened pseudo-measurement of dimension 12 (``H_p^T H_p = Lambda``,
  ``H_p^T z_p = eta``, ``R = I``), which is algebraically the same update.

Robustness
----------
* gating: every sample's normalised innovation ``d^2 = r^T S^-1 r`` is tested against the
  chi-square(3) quantile (flex spikes; in the fast mode vectorised over the block, with the
  neighbouring samples also removed as in the paper's flex rejection);
* step changes: a CUSUM on the (clipped) normalised innovation detects a shock; the tracker
  opens its covariance by a step prior (so it follows the step at once and its bands say so),
  solves :func:`fusion_gyrocal.calibrate_pair` (with its flex rejection) over a window after the
  estimated onset (ring buffer of recent samples) and re-seeds from it if it differs
  significantly from the filter's state at the alarm (chi-square test on the difference);
  otherwise (a false alarm, e.g. a long flex burst) it restores that state and replays the
  buffered samples;
* gaps and unsynchronised streams: :meth:`GyroPairTracker.run_streams` resamples gyro 2 onto
  gyro 1's clock (cubic spline, after adding ``time_offset_s``) only inside gyro 2's contiguous
  segments; blocks never straddle a gap.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from ..core.gauge import Gauge
from ..errors import ConfigurationError, GyroCalError, InputError
from ..core.model import BIAS, ROT, S1, S2, PairCalibration
from ..core.moments import Moments, as_rates
from ..core.observability import A_of, classify
from ..lie import skew
from ..pipeline.resample import resample
from ..pipeline.streams import check_timestamps

__all__ = ["DriftNoise", "GyroPairTracker", "PairTruth", "ReseedEvent", "StepPrior", "TrackHistory",
           "plot_history", "simulate_drifting_pair", "track_figure_for_report"]

_DIM = 12
_LOG = slice(3, 9)
_REFRESH = 50     # folds between re-linearisations of the gauge projector and the measurement noise
                  # (they change at second order only: the scale factors move by < 1e-3 between them)


# ====================================================================== configuration types
@dataclass(frozen=True)
class DriftNoise:
    """Random-walk densities of the tracked parameters (physical units).

    Attributes
    ----------
    rotation : float
        Rotation random walk, rad/sqrt(s) per axis (default 3e-5, about 0.1 deg/sqrt(h)).
    log_scale : float
        Relative scale-factor random walk, 1/sqrt(s) per scale factor (default 1e-4, about
        0.6 %/sqrt(h)).
    bias : float
        Combined-bias random walk, rad/s/sqrt(s) per axis (default 1.41e-5: the paper's bias
        walk, 57.3 micro-deg/s per 10 ms step for each gyro, Section V).
    """

    rotation: float = 3e-5
    log_scale: float = 1e-4
    bias: float = 1.41e-5

    def __post_init__(self):
        for name in ("rotation", "log_scale", "bias"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"DriftNoise.{name}: expected a finite density >= 0, got {v}")

    @classmethod
    def constant(cls) -> "DriftNoise":
        """No drift: the filter becomes a recursive least-squares estimator of constant parameters."""
        return cls(0.0, 0.0, 0.0)


@dataclass(frozen=True)
class StepPrior:
    """1-sigma size of a step change (a shock), added to the covariance when one is detected.

    Attributes
    ----------
    rotation : float
        rad per axis (default 1 deg).
    log_scale : float
        Relative scale-factor change (default 0.01).
    bias : float
        rad/s per axis (default 0.5 deg/s).
    """

    rotation: float = np.pi / 180.0
    log_scale: float = 0.01
    bias: float = 0.5 * np.pi / 180.0

    def __post_init__(self):
        for name in ("rotation", "log_scale", "bias"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"StepPrior.{name}: expected a finite std >= 0, got {v}")


@dataclass(frozen=True)
class PairTruth:
    """Ground truth of a pair per sample (for NEES and plots), in any gauge; ``truth[rows]`` selects samples.

    Attributes
    ----------
    R_1_2 : ndarray (N, 3, 3)
    scale_1, scale_2 : ndarray (N, 3)
    bias : ndarray (N, 3)
        Combined bias ``b_1 - A b_2`` (Eq. 5), rad/s.
    """

    R_1_2: np.ndarray
    scale_1: np.ndarray
    scale_2: np.ndarray
    bias: np.ndarray

    def __post_init__(self):
        n = np.asarray(self.scale_1).shape[0]
        for name, tail in (("R_1_2", (3, 3)), ("scale_1", (3,)), ("scale_2", (3,)), ("bias", (3,))):
            arr = np.array(getattr(self, name), dtype=np.float64)
            if arr.shape != (n,) + tail:
                raise InputError(f"PairTruth.{name}: expected shape {(n,) + tail}, got {arr.shape}")
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return self.scale_1.shape[0]

    def __getitem__(self, rows) -> "PairTruth":
        """The truth at some samples (a slice or an index array), e.g. those a tracker runs over."""
        return PairTruth(self.R_1_2[rows], self.scale_1[rows], self.scale_2[rows], self.bias[rows])


@dataclass(frozen=True)
class ReseedEvent:
    """A detected step change and what the tracker did about it.

    Attributes
    ----------
    t_detected : float
        Time of the CUSUM alarm (s).
    t_onset : float
        Estimated change time (the CUSUM's last zero), start of the re-seed window.
    t_applied : float
        End of the re-seed window (when the batch solve ran); NaN if it never ran.
    accepted : bool
        True if the filter was re-seeded (the batch solve differed significantly from the
        filter's state at the alarm).
    statistic : float
        Chi-square of the batch-minus-filter (at the alarm) difference in the observable
        coordinates (NaN if the solve failed).
    threshold : float
        Chi-square quantile the statistic was compared with.
    reason : str
        Short explanation.
    """

    t_detected: float
    t_onset: float
    t_applied: float
    accepted: bool
    statistic: float
    threshold: float
    reason: str


def _ro(a):
    arr = np.array(a, dtype=np.float64)
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class TrackHistory:
    """Estimate history of a :class:`GyroPairTracker` with 1-sigma bands.

    One row per filter update (per sample in the per-sample mode, per block in the fast mode).

    Attributes
    ----------
    t : ndarray (M,)
        Time of each row (s); in the fast mode the mean time of the block.
    R_1_2 : ndarray (M, 3, 3)
    rotation_std : ndarray (M, 3)
        1-sigma of the rotation error ``dtheta`` (rad, gyro 1's frame; ``R_true = Exp(dtheta) R``).
    scale_1, scale_2, scale_1_std, scale_2_std : ndarray (M, 3)
        Scale factors in the tracker's gauge and their 1-sigma.
    bias, bias_std : ndarray (M, 3)
        Combined bias (rad/s) and its 1-sigma.
    nis : ndarray (M,)
        Normalised innovation squared per degree of freedom of the accepted samples (about 1
        when consistent; NaN when every sample of the row was rejected).
    n_used : ndarray (M,) of int
        Samples folded into each row's update.
    nees : ndarray (M,) or None
        Normalised estimation error squared against the truth (observable coordinates,
        ``nees_dof`` degrees of freedom), when a truth was given.
    nees_dof : int
    truth_R_1_2, truth_scale_1, truth_scale_2, truth_bias : ndarray or None
        The truth at each row, scales expressed in the tracker's gauge.
    reseeds : tuple of ReseedEvent
    n_samples, n_rejected : int
        Samples seen and samples rejected by the gate.
    gauge : str
        How the unobservable scale directions are held.
    mode : str
        ``"sample"``, ``"fast"``, ``"mixed"`` (both kinds of rows) or ``"none"`` (no update yet).
    """

    t: np.ndarray
    R_1_2: np.ndarray
    rotation_std: np.ndarray
    scale_1: np.ndarray
    scale_1_std: np.ndarray
    scale_2: np.ndarray
    scale_2_std: np.ndarray
    bias: np.ndarray
    bias_std: np.ndarray
    nis: np.ndarray
    n_used: np.ndarray
    nees: np.ndarray | None
    nees_dof: int
    truth_R_1_2: np.ndarray | None
    truth_scale_1: np.ndarray | None
    truth_scale_2: np.ndarray | None
    truth_bias: np.ndarray | None
    reseeds: tuple
    n_samples: int
    n_rejected: int
    gauge: str
    mode: str

    def __post_init__(self):
        for f in ("t", "R_1_2", "rotation_std", "scale_1", "scale_1_std", "scale_2", "scale_2_std", "bias",
                  "bias_std", "nis", "nees", "truth_R_1_2", "truth_scale_1", "truth_scale_2", "truth_bias"):
            v = getattr(self, f)
            if v is not None:
                object.__setattr__(self, f, _ro(v))
        n_used = np.array(self.n_used, dtype=np.int64)
        n_used.flags.writeable = False
        object.__setattr__(self, "n_used", n_used)
        object.__setattr__(self, "reseeds", tuple(self.reseeds))

    def __len__(self) -> int:
        return self.t.shape[0]

    @property
    def rotation_change(self) -> np.ndarray:
        """(M, 3) rotation of ``R_1_2`` relative to the first row, ``Log(R_k R_0^T)`` (rad, gyro 1 frame)."""
        if len(self) == 0:
            return np.zeros((0, 3))
        return Rotation.from_matrix(self.R_1_2 @ self.R_1_2[0].T).as_rotvec()

    @property
    def rotation_error(self) -> np.ndarray | None:
        """(M, 3) ``Log(R_true R_k^T)``: the rotation error in the ``dtheta`` convention, or None."""
        if self.truth_R_1_2 is None:
            return None
        return Rotation.from_matrix(self.truth_R_1_2 @ np.swapaxes(self.R_1_2, 1, 2)).as_rotvec()

    @property
    def normalised_error(self) -> np.ndarray | None:
        """(M, 12) truth minus estimate over its 1-sigma, or None: :attr:`rotation_error`, then
        ``truth_scale_1 - scale_1``, ``truth_scale_2 - scale_2`` and ``truth_bias - bias``, each
        divided by its ``*_std`` (about N(0, 1) per component when the bands are consistent)."""
        if self.truth_R_1_2 is None:
            return None
        return np.hstack([self.rotation_error / self.rotation_std,
                          (self.truth_scale_1 - self.scale_1) / self.scale_1_std,
                          (self.truth_scale_2 - self.scale_2) / self.scale_2_std,
                          (self.truth_bias - self.bias) / self.bias_std])


# ====================================================================== helpers
def _exp_so3(v) -> np.ndarray:
    """Rodrigues' formula ``Exp(v)`` for a rotation vector (rad)."""
    th2 = float(v @ v)
    K = skew(v)
    if th2 < 1e-12:
        return np.eye(3) + K + 0.5 * (K @ K)
    th = np.sqrt(th2)
    return np.eye(3) + (np.sin(th) / th) * K + ((1.0 - np.cos(th)) / th2) * (K @ K)


def _jacobian(R, s1, s2, w2):
    """Measurement Jacobians ``dh/dx`` (B, 3, 12) at zero error for gyro-2 samples ``w2`` (B, 3)."""
    u = (w2 / s2) @ R.T                      # R diag(1/s2) omega_2: gyro 2's rate in gyro 1's frame
    A = A_of(R, s1, s2)
    H = np.zeros((w2.shape[0], 3, _DIM))
    H[:, :, 0:3] = -s1[None, :, None] * skew(u)           # d(diag(s1) Exp(th) u)/dth
    idx = np.arange(3)
    H[:, idx, 3 + idx] = s1 * u                                  # d/d delta_1 = diag(A omega_2)
    H[:, :, 6:9] = -A[None, :, :] * w2[:, None, :]               # d/d delta_2 = -A diag(omega_2)
    H[:, idx, 9 + idx] = 1.0                                     # d/d b
    return H


def _innovation_d2(H, P, Rm, r):
    """Per-sample ``r_k^T (H_k P H_k^T + R)^-1 r_k`` for stacked ``H`` (B, 3, 12), ``r`` (B, 3)."""
    S = (H @ P) @ np.swapaxes(H, 1, 2) + Rm
    return np.einsum("ka,ka->k", r, np.linalg.solve(S, r[:, :, None])[:, :, 0])


def _log_so3(R) -> np.ndarray:
    """Rotation vector of a rotation matrix (scipy for large angles)."""
    c = 0.5 * (np.trace(R) - 1.0)
    v = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if c > 0.5:   # below 60 deg: asin of the axial vector's norm is accurate
        s = np.linalg.norm(v)
        return v if s < 1e-12 else v * (np.arcsin(min(s, 1.0)) / s)
    return Rotation.from_matrix(R).as_rotvec()


class _Ring:
    """Fixed-capacity ring buffer of ``[t, omega_1, omega_2]`` rows."""

    def __init__(self, capacity: int):
        self.buf = np.empty((capacity, 7))
        self.cap = capacity
        self.n = 0       # rows stored
        self.head = 0    # next write position

    def push(self, t, w1, w2):
        rows = np.column_stack([np.atleast_1d(t), np.atleast_2d(w1), np.atleast_2d(w2)])
        m = rows.shape[0]
        if m >= self.cap:
            self.buf[:] = rows[-self.cap:]
            self.head, self.n = 0, self.cap
            return
        end = self.head + m
        if end <= self.cap:
            self.buf[self.head:end] = rows
        else:
            k = self.cap - self.head
            self.buf[self.head:] = rows[:k]
            self.buf[: m - k] = rows[k:]
        self.head = end % self.cap
        self.n = min(self.cap, self.n + m)

    def since(self, t0) -> np.ndarray:
        if self.n < self.cap:
            data = self.buf[: self.n]
        else:
            data = np.concatenate([self.buf[self.head:], self.buf[: self.head]])
        return data[data[:, 0] >= t0]

    def oldest(self) -> float:
        if self.n == 0:
            return np.inf
        return float(self.buf[0 if self.n < self.cap else self.head, 0])


def _batch(w1, w2, noise_std, gauge) -> PairCalibration:
    """Batch calibration of a window (:func:`fusion_gyrocal.calibrate_pair`, which applies the paper's
    flex rejection, Section VI.C, when the residuals call for it)."""
    from ..pipeline.pipeline import calibrate_pair

    return calibrate_pair(w1, w2, noise_std=noise_std, gauge=gauge)


# ====================================================================== the tracker
class GyroPairTracker:
    """Online EKF tracker of a gyro pair's calibration, seeded by a :class:`PairCalibration`.

    Ready to use once constructed: the filterpy filter's state, covariance, transition and
    noise matrices are all set from the seed.

    Parameters
    ----------
    calibration : PairCalibration
        Seed (estimate and covariance), e.g. from :func:`fusion_gyrocal.calibrate_pair`.
        Its ``noise_std`` (per-sample white noise of each gyro, rad/s) sets the measurement
        noise; its ``time_offset_s`` is used by :meth:`run_streams`.
    t0 : float
        Time (s) at which the seed is valid (usually the end of its data).
    drift : DriftNoise
        Random-walk densities of the tracked parameters.
    gauge : "unit_prior", "fixed" or Gauge
        Gauge of the scale group that holds its members (see the module docstring). Give the
        same gauge as the seed's calibration (default: the library default).
    seed_span_s : float
        Duration of the data the seed was estimated from. The seed estimates the window
        average, the filter starts at its end: the seed covariance is inflated by the drift over
        a third of the span (the error variance of a random walk's window mean at its end).
    scale_prior_std : float
        Prior 1-sigma (relative) of the common factor of each parallel axis pair in a degenerate
        configuration; also replaces the seed's infinite scale variances.
    gate_probability : float
        Per-sample chi-square(3) acceptance probability of the innovation gate.
    gate_neighbours : int
        Samples removed on each side of a gated sample (fast mode; the per-sample mode removes
        the following ones).
    cusum_drift, cusum_threshold : float
        CUSUM on ``min(d^2, gate) / 3 - 1``: allowance per sample and alarm level.
    reseed_window_s : float
        Data after the estimated onset used for the re-seeding batch solve.
    reseed_max_s : float
        Give up re-seeding (the motion never excited all axes enough) after this long.
    reseed_probability : float
        Chi-square quantile for accepting a re-seed (batch vs filter difference).
    step_prior : StepPrior
        Covariance added at an alarm so the filter follows a step at once (and says so in its
        bands) while the confirming batch window fills. If the batch solve then agrees with
        the filter's state at the alarm (a false alarm, e.g. a long flex burst), that state is
        restored and the buffered samples are replayed.
    buffer_samples : int
        Capacity of the ring buffer of recent samples.
    reseed_solver : callable ``(omega_1, omega_2) -> PairCalibration``, optional
        Batch solver for re-seeding; default :func:`fusion_gyrocal.calibrate_pair` with the
        tracker's noise and gauge (and its flex rejection).
    """

    def __init__(self, calibration: PairCalibration, *, t0: float = 0.0, drift: DriftNoise = DriftNoise(),
                 gauge="unit_prior", seed_span_s: float = 0.0, scale_prior_std: float = 0.01,
                 gate_probability: float = 0.999, gate_neighbours: int = 1, cusum_drift: float = 0.5,
                 cusum_threshold: float = 25.0, reseed_window_s: float = 10.0, reseed_max_s: float = 60.0,
                 reseed_probability: float = 0.999, step_prior: StepPrior = StepPrior(),
                 buffer_samples: int = 1 << 15, reseed_solver: Callable | None = None):
        if not isinstance(calibration, PairCalibration):
            raise InputError(f"calibration: expected a PairCalibration, got {type(calibration).__name__}")
        if not isinstance(drift, DriftNoise):
            raise InputError(f"drift: expected a DriftNoise, got {type(drift).__name__}")
        if not (0 < gate_probability < 1 and 0 < reseed_probability < 1):
            raise InputError(f"gate_probability and reseed_probability: expected values in (0, 1), got "
                             f"{gate_probability} and {reseed_probability}")
        if not scale_prior_std > 0:
            raise InputError(f"scale_prior_std: expected > 0, got {scale_prior_std}")
        if not (reseed_window_s > 0 and reseed_max_s >= reseed_window_s):
            raise InputError(f"reseed_window_s, reseed_max_s: expected 0 < window <= max, got {reseed_window_s}, "
                             f"{reseed_max_s}")
        noise = np.asarray(calibration.noise_std, dtype=float)
        if not (np.isfinite(noise).all() and (noise > 0).all()):
            raise InputError(f"calibration.noise_std: expected two positive rad/s values, got {noise}")
        self.drift = drift
        self.noise_std = (float(noise[0]), float(noise[1]))
        self.time_offset_s = float(calibration.time_offset_s)
        self.gauge = Gauge.parse(gauge)
        self.scale_prior_std = float(scale_prior_std)
        self.gate = float(chi2.ppf(gate_probability, 3))
        self.gate_neighbours = int(gate_neighbours)
        self.cusum_drift = float(cusum_drift)
        self.cusum_threshold = float(cusum_threshold)
        self.reseed_window_s = float(reseed_window_s)
        self.reseed_max_s = float(reseed_max_s)
        self.reseed_probability = float(reseed_probability)
        if not isinstance(step_prior, StepPrior):
            raise InputError(f"step_prior: expected a StepPrior, got {type(step_prior).__name__}")
        self.step_prior = step_prior
        self._reseed_solver = reseed_solver
        self._buffer = _Ring(int(buffer_samples))

        self.kf = ExtendedKalmanFilter(dim_x=_DIM, dim_z=3)
        self.kf.F = np.eye(_DIM)
        self.kf.Q = np.zeros((_DIM, _DIM))
        self._t = float(t0)
        self._seed(calibration, span_s=float(seed_span_s))

        # diagnostics and history
        self.n_samples = 0
        self.n_rejected = 0
        self._suppress = 0            # per-sample mode: samples still to drop after a gated one
        self._cusum = 0.0
        self._cusum_zero_t = self._t  # time of the CUSUM's last zero (change-point estimate)
        self._alarm: tuple | None = None   # (t_detected, t_onset)
        self._next_try_t = -np.inf
        self._snapshot: tuple | None = None
        self._replaying = False
        self._events: list[ReseedEvent] = []
        self._rows: list[tuple] = []
        self._modes: set[str] = set()

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def from_samples(cls, t, omega_1, omega_2, *, noise_std=None, gauge="unit_prior", **kwargs) -> "GyroPairTracker":
        """Seed a tracker from sample-aligned data with :func:`fusion_gyrocal.calibrate_pair`.

        The batch solve applies the paper's flex rejection; ``noise_std`` (rad/s per sample, one
        value or one per gyro) defaults to its residual estimate. The tracker starts at
        ``t[-1]`` with the seed inflated for the drift over the window (``seed_span_s``).
        Further keyword arguments go to the constructor.
        """
        t = check_timestamps("t", t)
        w1 = as_rates("omega_1", omega_1, length=t.shape[0])
        w2 = as_rates("omega_2", omega_2, length=t.shape[0])
        cal = _batch(w1, w2, noise_std, gauge)
        return cls(cal, t0=float(t[-1]), gauge=gauge, seed_span_s=float(t[-1] - t[0]), **kwargs)

    def _seed(self, cal: PairCalibration, span_s: float = 0.0) -> None:
        """Set references, gauge structure and covariance from a calibration (construction, re-seed)."""
        R = np.array(cal.R_1_2, dtype=float)
        s1, s2 = np.array(cal.scale_1, dtype=float), np.array(cal.scale_2, dtype=float)
        config = classify(R)
        if config.name != cal.configuration:
            config = self._config_like(R, cal.configuration)  # trust the seed's class
        self.configuration = config
        # groups of at least four linked scale factors follow the gauge; parallel pairs are held by the prior
        self._gauge_groups = [g for g in config.groups if len(g) >= 4 and self.gauge.members_in(g)]
        self._prior_groups = [g for g in config.groups if g not in self._gauge_groups]

        P = self._log_covariance(cal)
        # held values: the prior groups keep the seed's log-mean (or the current one on a re-seed)
        old_hold = getattr(self, "_hold", None)
        self._R, self._s1, self._s2 = R, s1, s2
        self._b = np.array(cal.bias, dtype=float)
        self._s1, self._s2 = self._regauge(self._s1, self._s2)
        self._hold = {}
        for g in self._prior_groups:
            key = tuple(sorted(g))
            self._hold[key] = old_hold[key] if old_hold and key in old_hold else self._group_logmean(g)
        self._enforce_hold()
        self._set_structure()
        self._update_projection()
        P = self._project_cov(P)
        if span_s > 0:
            P = P + self._Q(span_s / 3.0)
        self.kf.x = np.zeros((_DIM, 1))
        self.kf.P = 0.5 * (P + P.T)
        self._G_cache = None

    def _log_covariance(self, cal: PairCalibration) -> np.ndarray:
        """``cal``'s covariance in ``[dtheta, log s1, log s2, b]``; undetermined scale factors get the prior."""
        cov = np.array(cal.covariance, dtype=float)
        bad = ~np.isfinite(cov).all(axis=1)
        cov[bad, :], cov[:, bad] = 0.0, 0.0
        J = np.ones(_DIM)
        J[S1], J[S2] = 1.0 / np.asarray(cal.scale_1), 1.0 / np.asarray(cal.scale_2)
        P = cov * np.outer(J, J)
        P[bad, bad] = self.scale_prior_std**2
        return P

    @staticmethod
    def _config_like(R, name):
        """Classify ``R`` with the tolerance that reproduces the seed's configuration class."""
        for tol in (1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 40.0):
            c = classify(R, tol)
            if c.name == name:
                return c
        raise ConfigurationError(f"calibration.configuration is {name!r} but R_1_2 is not close to that class")

    # ------------------------------------------------------------------ gauge machinery
    def _group_logmean(self, group) -> float:
        s = np.concatenate([self._s1, self._s2])
        return float(np.mean([np.log(s[3 * g + a]) for g, a in group]))

    def _regauge(self, s1, s2):
        for g in self._gauge_groups:
            s1, s2 = self.gauge.apply((g,), [s1, s2])
        return np.asarray(s1, float), np.asarray(s2, float)

    def _enforce_hold(self):
        s = np.concatenate([self._s1, self._s2])
        for g in self._prior_groups:
            idx = [3 * gy + a for gy, a in g]
            c = self._hold[tuple(sorted(g))] - np.mean(np.log(s[idx]))
            s[idx] *= np.exp(c)
        self._s1, self._s2 = s[:3].copy(), s[3:].copy()

    def _set_structure(self):
        """Null directions ``N`` (one per scale group), their held covariance and the observable basis."""
        groups = list(self._gauge_groups) + list(self._prior_groups)
        N = np.zeros((6, len(groups)))
        for j, g in enumerate(groups):
            for gy, a in g:
                N[3 * gy + a, j] = 1.0
        self._N = N
        Nf = np.zeros((_DIM, len(groups)))
        Nf[_LOG] = N
        # held covariance: zero for the gauge group, the prior for each parallel pair (variance of its log-mean)
        var = np.array([0.0] * len(self._gauge_groups) + [self.scale_prior_std**2] * len(self._prior_groups))
        self._held_cov = (Nf * var) @ Nf.T
        # observable coordinates: orthonormal complement of the held directions
        Q, _ = np.linalg.qr(Nf, mode="complete")
        self._obs_basis = Q[:, len(groups):]

    def _update_projection(self):
        """Oblique projector ``T = I - N (G^T N)^-1 G^T`` (G: the linearised gauge conditions)."""
        N = self._N
        G = np.zeros_like(N)
        ng = len(self._gauge_groups)
        if ng:
            G[:, :ng] = self.gauge.constraints(tuple(self._gauge_groups), [self._s1, self._s2]).T
        G[:, ng:] = N[:, ng:] / N[:, ng:].sum(axis=0)   # log-mean of each parallel pair
        T = np.eye(6) - N @ np.linalg.solve(G.T @ N, G.T)
        Pi = np.eye(_DIM)
        Pi[_LOG, _LOG] = T
        self._T, self._Pi = T, Pi
        TT = T @ T.T

        def projected_cov(std):     # independent per-parameter std (DriftNoise, StepPrior), off the held directions
            C = np.zeros((_DIM, _DIM))
            C[ROT, ROT] = std.rotation**2 * np.eye(3)
            C[_LOG, _LOG] = std.log_scale**2 * TT
            C[BIAS, BIAS] = std.bias**2 * np.eye(3)
            return C

        self._q = projected_cov(self.drift)                   # process noise per second
        self._shock = projected_cov(self.step_prior)
        self.kf.R = self._measurement_cov()
        self._folds = 0

    def _project_cov(self, P):
        P = self._Pi @ P @ self._Pi.T + self._held_cov
        return 0.5 * (P + P.T)

    def _Q(self, dt: float) -> np.ndarray:
        """Random-walk process noise over ``dt`` seconds, projected off the held directions."""
        return self._q * max(dt, 0.0)

    # ------------------------------------------------------------------ current estimate
    @property
    def t(self) -> float:
        """Time (s) of the current estimate."""
        return self._t

    @property
    def R_1_2(self) -> np.ndarray:
        return self._R.copy()

    @property
    def scale_1(self) -> np.ndarray:
        return self._s1.copy()

    @property
    def scale_2(self) -> np.ndarray:
        return self._s2.copy()

    @property
    def bias(self) -> np.ndarray:
        return self._b.copy()

    @property
    def A(self) -> np.ndarray:
        return A_of(self._R, self._s1, self._s2)

    @property
    def error_covariance(self) -> np.ndarray:
        """(12, 12) covariance of the error state ``[dtheta, log s_1, log s_2, b]``."""
        return np.array(self.kf.P)

    @property
    def covariance(self) -> np.ndarray:
        """(12, 12) covariance in :class:`PairCalibration`'s order ``[dtheta, scale_1, scale_2, bias]``."""
        J = np.ones(_DIM)
        J[S1], J[S2] = self._s1, self._s2
        return self.kf.P * np.outer(J, J)

    @property
    def gauge_description(self) -> str:
        parts = []
        if self._gauge_groups:
            parts.append(self.gauge.describe())
        for g in self._prior_groups:
            names = " * ".join(f"scale_{gy + 1}[{a}]" for gy, a in g)
            parts.append(f"common factor of {names} held at the seed (prior std {self.scale_prior_std:g})")
        return "; ".join(parts)

    @property
    def nees_dof(self) -> int:
        return int(self._obs_basis.shape[1])

    @property
    def calibration(self) -> PairCalibration:
        """The current estimate as a :class:`PairCalibration` (``method="ekf"``)."""
        notes = [f"EKF estimate at t = {self._t:.3f} s; {self.n_rejected} of {self.n_samples} samples gated"]
        if self._prior_groups:
            notes.append("scale factors of parallel axis pairs: only their ratio is tracked; the common factor is "
                         f"held by a prior of std {self.scale_prior_std:g}")
        return PairCalibration(
            R_1_2=self._R, scale_1=self._s1, scale_2=self._s2, bias=self._b, configuration=self.configuration.name,
            scale_observable=self.configuration.scale_observable, covariance=self.covariance,
            gauge=self.gauge_description, snr=np.full(3, np.nan), n_samples=int(self.n_samples),
            noise_std=np.array(self.noise_std), noise_source="seed", method="ekf",
            time_offset_s=self.time_offset_s, rejected_fraction=self.n_rejected / max(self.n_samples, 1),
            notes=tuple(notes))

    def express_in_gauge(self, scale_1, scale_2) -> tuple[np.ndarray, np.ndarray]:
        """Express scale factors (e.g. a ground truth) in the tracker's gauge.

        The gauge group is rescaled by the gauge; each parallel pair's common factor is replaced
        by the value the tracker holds. Only the determined ratios are left to compare.
        """
        s1, s2 = self._regauge(np.asarray(scale_1, float).copy(), np.asarray(scale_2, float).copy())
        s = np.concatenate([s1, s2])
        for g in self._prior_groups:
            idx = [3 * gy + a for gy, a in g]
            s[idx] *= np.exp(self._hold[tuple(sorted(g))] - np.mean(np.log(s[idx])))
        return s[:3], s[3:]

    def nees(self, R_1_2, scale_1, scale_2, bias) -> float:
        """NEES of the current estimate against a truth, over the observable coordinates.

        The error is ``[Log(R_true R^T), log s_true - log s, b_true - b]`` with the truth's scale
        factors expressed in the gauge; it has :attr:`nees_dof` degrees of freedom.
        """
        return self._chi2(R_1_2, scale_1, scale_2, bias, (self._R, self._s1, self._s2, self._b), self.kf.P)

    def _chi2(self, R_1_2, scale_1, scale_2, bias, state, P) -> float:
        """``e^T P^-1 e`` in the observable coordinates for ``e`` the given values minus ``state``
        ``(R, s1, s2, b)``: ``[Log(R_1_2 R^T), log scale - log s, bias - b]``, scales expressed in the gauge."""
        R, s1, s2, b = state
        t1, t2 = self.express_in_gauge(scale_1, scale_2)
        e = np.concatenate([_log_so3(np.asarray(R_1_2) @ R.T), np.log(t1 / s1), np.log(t2 / s2),
                            np.asarray(bias) - b])
        V = self._obs_basis
        eo = V.T @ e
        return float(eo @ np.linalg.solve(V.T @ P @ V, eo))

    # ------------------------------------------------------------------ filter steps
    def _measurement_cov(self) -> np.ndarray:
        A = self.A
        return self.noise_std[0] ** 2 * np.eye(3) + self.noise_std[1] ** 2 * (A @ A.T)

    def _predict_to(self, t: float) -> None:
        dt = t - self._t
        if not (np.isfinite(t) and dt >= 0):
            raise InputError(f"t: expected finite, non-decreasing times, got {t!r} after {self._t!r} "
                             f"(a step of {dt:.6g} s)")
        if dt > 0:
            self.kf.Q = self._Q(dt)
            self.kf.predict()
            self._t = float(t)

    def _fold(self, refresh: bool = False) -> None:
        """Fold the error state into the references and reset it (multiplicative EKF).

        The correction is projected off the held directions (exact for the linear conditions of
        a fixed scale and of the pairs' log-means). Every ``_REFRESH`` folds (or when asked) the
        nonlinear gauge is re-imposed and the projector, process noise and measurement noise
        are re-linearised at the new estimate (they change only at second order in between).
        """
        x = self.kf.x[:, 0]
        x[_LOG] = self._T @ x[_LOG]    # never move a held direction
        self._R = _exp_so3(x[ROT]) @ self._R
        self._s1 = self._s1 * np.exp(x[S1])
        self._s2 = self._s2 * np.exp(x[S2])
        self._b = self._b + x[BIAS]
        self.kf.x = np.zeros((_DIM, 1))
        self.kf.P = self._project_cov(self.kf.P)
        self._G_cache = None
        self._folds += 1
        if refresh or self._folds >= _REFRESH:
            self._s1, self._s2 = self._regauge(self._s1, self._s2)
            self._enforce_hold()
            self._update_projection()

    def _cusum_step(self, t, d2):
        """Vectorised CUSUM over per-sample ``d2`` at times ``t``; returns (alarm index or None)."""
        if self._alarm is not None or self._replaying:   # replays re-process a span judged transient
            return None
        x = np.minimum(d2, self.gate) / 3.0 - 1.0 - self.cusum_drift
        S = np.cumsum(x)
        g0 = self._cusum
        level = g0 + S
        floor = np.minimum(np.minimum.accumulate(level), 0.0)
        g = level - floor
        over = np.flatnonzero(g > self.cusum_threshold)
        zeros = np.flatnonzero(g <= 0.0)
        if over.size:
            k = int(over[0])
            z = zeros[zeros < k]
            onset = float(t[z[-1]]) if z.size else self._cusum_zero_t
            self._raise_alarm(float(t[k]), onset)
            return k
        if zeros.size:
            self._cusum_zero_t = float(t[zeros[-1]])
        self._cusum = float(g[-1])
        return None

    def _raise_alarm(self, t_det: float, onset: float) -> None:
        """Step suspected: remember the state, open the covariance by the step prior."""
        self._alarm = (t_det, onset)
        self._cusum = 0.0
        self._snapshot = (self._R.copy(), self._s1.copy(), self._s2.copy(), self._b.copy(), self.kf.P.copy(),
                          self._t, self.n_rejected)
        self.kf.P = self._project_cov(self.kf.P + self._shock)

    def _cusum_sample(self, t, d2) -> bool:
        """Scalar CUSUM step (per-sample mode); same recursion as :meth:`_cusum_step`. True on an alarm."""
        if self._alarm is not None or self._replaying:
            return False
        g = self._cusum + min(d2, self.gate) / 3.0 - 1.0 - self.cusum_drift
        if g <= 0.0:
            self._cusum, self._cusum_zero_t = 0.0, t
        elif g > self.cusum_threshold:
            self._raise_alarm(t, self._cusum_zero_t)
            return True
        else:
            self._cusum = g
        return False

    def update(self, t: float, omega_1, omega_2) -> bool:
        """Per-sample mode: predict to ``t`` and fold one sample pair (rad/s, shape (3,) each).

        Returns True if the sample passed the innovation gate and was used.
        """
        w1 = np.asarray(omega_1, dtype=float).reshape(3)
        w2 = np.asarray(omega_2, dtype=float).reshape(3)
        if not (np.isfinite(w1).all() and np.isfinite(w2).all()):
            raise InputError(f"omega_1/omega_2: expected finite rates, got {w1} and {w2} at t = {t}")
        t = float(t)
        self._predict_to(t)
        if not self._replaying:
            self._modes.add("sample")
            self._buffer.push(t, w1, w2)
            self.n_samples += 1
        H = _jacobian(self._R, self._s1, self._s2, w2[None])[0]
        hx = self.A @ w2 + self._b
        R = self.kf.R
        y = w1 - hx
        S = H @ self.kf.P @ H.T + R
        d2 = float(y @ np.linalg.solve(S, y))
        if self._cusum_sample(t, d2):
            S = H @ self.kf.P @ H.T + R           # covariance opened by the step prior
            d2 = float(y @ np.linalg.solve(S, y))
            self._suppress = 0
        accepted = d2 <= self.gate and self._suppress == 0
        if d2 > self.gate:
            self._suppress = self.gate_neighbours + 1
        if self._suppress:
            self._suppress -= 1
        if accepted:
            self.kf.update(w1[:, None], HJacobian=lambda x: H, Hx=lambda x: hx[:, None] + H @ x, R=R)
            self._fold()
        else:
            self.n_rejected += 1
        self._record(t, d2 / 3.0 if accepted else np.nan, int(accepted))
        self._maybe_reseed()
        return bool(accepted)

    def _block_generators(self):
        """``G`` (4, 3, 12): ``H_k = sum_m y_k[m] G[m]`` for ``y_k = [omega_2(k); 1]``."""
        if self._G_cache is None:
            H0 = _jacobian(self._R, self._s1, self._s2, np.zeros((1, 3)))[0]
            He = _jacobian(self._R, self._s1, self._s2, np.eye(3)) - H0
            self._G_cache = np.concatenate([He, H0[None]], axis=0)
        return self._G_cache

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
        All samples of the block are linearised at the current estimate, so the block is
        assumed short compared with the drift (a second or so). Each sample's innovation
        ``d^2 = r^T (H P H^T + R)^-1 r`` is gated (and the neighbours of a gated sample
        dropped); the accepted samples' moments give ``Lambda`` and ``eta`` exactly:
        with ``Y = sum_k y_k y_k^T`` of ``y_k = [omega_1; omega_2; 1]`` (from count, mean and
        centred scatter), ``Lambda = sum_mn Y_mn G_m^T W G_n`` and
        ``eta = sum_m G_m^T W L Y[:, m]`` where ``r_k = L y_k``, ``L = [I, -A, -b]``.
        """
        t = np.asarray(t)
        if t.shape == (1,) and t.dtype.kind in "fiu" and np.isfinite(t[0]):
            t = t.astype(np.float64)            # one sample is a block too (check_timestamps asks for two)
        else:
            t = check_timestamps("t", t)
        w1 = as_rates("omega_1", omega_1, length=t.shape[0])
        w2 = as_rates("omega_2", omega_2, length=t.shape[0])
        B = t.shape[0]
        if not (np.isfinite(w1).all() and np.isfinite(w2).all()):
            bad = int(np.flatnonzero(~(np.isfinite(w1).all(1) & np.isfinite(w2).all(1)))[0])
            raise InputError(f"omega_1/omega_2: expected finite rates, got a non-finite value at sample {bad} "
                             "of the block; mask or drop it first")
        t_mid = float(t.mean())
        if t[0] < self._t:
            raise InputError(f"t: expected block times at or after the current time {self._t!r}, got {t[0]!r}")
        self._predict_to(t_mid)
        if not self._replaying:                # a replay adds no rows, so it does not set the mode
            self._modes.add("fast")
            self._buffer.push(t, w1, w2)
            self.n_samples += B

        A, b, P, Rm = self.A, self._b, self.kf.P, self.kf.R
        G = self._block_generators()
        # ---- per-sample gate, vectorised
        H = (w2 @ G[:3].reshape(3, 3 * _DIM)).reshape(B, 3, _DIM) + G[3]
        r = w1 - w2 @ A.T - b
        d2 = _innovation_d2(H, P, Rm, r)
        if self._cusum_step(t, d2) is not None:
            P = self.kf.P                          # covariance opened by the step prior
            d2 = _innovation_d2(H, P, Rm, r)
        keep = d2 <= self.gate
        if not keep.all():
            bad = ~keep
            for _ in range(self.gate_neighbours):
                bad[1:] |= bad[:-1].copy()
                bad[:-1] |= bad[1:].copy()
            keep = ~bad
        n_used = int(keep.sum())
        self.n_rejected += B - n_used
        nis = np.nan
        if n_used > 0:
            m = Moments.from_samples(w1, w2, mask=None if n_used == B else keep, chunk_size=B)
            W = np.linalg.inv(Rm)
            n = m.count
            mu2 = m.mean_2
            rbar = m.mean_1 - A @ mu2 - b                        # mean residual L ybar
            Lc = np.hstack([np.eye(3), -A])                      # centred part of L
            # Y restricted to y' = [omega_2; 1] (the regressors of H)
            Yp = np.empty((4, 4))
            Yp[:3, :3] = m.S22 + n * np.outer(mu2, mu2)
            Yp[:3, 3] = Yp[3, :3] = n * mu2
            Yp[3, 3] = n
            Gf = G.reshape(12, _DIM)
            Lam = Gf.T @ np.kron(Yp, W) @ Gf
            # L Y[:, m'] for m' over y' = [omega_2; 1]: centred part uses the scatter columns of omega_2
            LY = np.empty((3, 4))
            LY[:, :3] = Lc @ m.scatter[:, 3:] + n * np.outer(rbar, mu2)
            LY[:, 3] = n * rbar
            eta = np.einsum("mai,am->i", G, W @ LY)
            rWr = float(np.trace(W @ (Lc @ m.scatter @ Lc.T)) + n * rbar @ W @ rbar)
            # block innovation statistic (Woodbury): r^T S^-1 r = rWr - eta^T P (I + Lam P)^-1 eta
            stat = rWr - float(eta @ P @ np.linalg.solve(np.eye(_DIM) + Lam @ P, eta))
            nis = stat / (3.0 * n)
            # whitened 12-d pseudo-measurement: H_p^T H_p = Lam, H_p^T z_p = eta, R = I
            lam, V = np.linalg.eigh(0.5 * (Lam + Lam.T))
            ok = lam > 1e-12 * max(lam.max(), 1e-300)
            sq = np.sqrt(np.where(ok, lam, 0.0))
            Hp = sq[:, None] * V.T
            zp = np.where(ok, (V.T @ eta) / np.where(ok, sq, 1.0), 0.0)
            self.kf.update(zp[:, None], HJacobian=lambda x: Hp, Hx=lambda x: Hp @ x, R=np.eye(_DIM))
            self._fold()
        self._record(t_mid, nis, n_used)
        self._maybe_reseed()
        return n_used

    # ------------------------------------------------------------------ step changes
    def _maybe_reseed(self) -> None:
        if self._alarm is None or self._replaying:
            return
        t_det, onset = self._alarm
        if self._t - onset < self.reseed_window_s or self._t < self._next_try_t:
            return
        data = self._buffer.since(onset)
        thr = float(chi2.ppf(self.reseed_probability, self.nees_dof))
        try:
            if self._reseed_solver is not None:
                cal = self._reseed_solver(data[:, 1:4], data[:, 4:7])
            else:
                cal = _batch(data[:, 1:4], data[:, 4:7], self.noise_std, self.gauge)
        except GyroCalError as exc:
            if self._t - onset < self.reseed_max_s and self._buffer.oldest() <= onset:
                self._next_try_t = self._t + 0.5 * self.reseed_window_s  # wait for more motion
                return
            self._events.append(ReseedEvent(t_det, onset, self._t, False, np.nan, thr,
                                            f"batch solve failed ({exc}); kept the filter with the step prior"))
            self._close_alarm()
            return
        R0, s10, s20, b0, P0, _, _ = self._snapshot       # batch minus the filter at the alarm
        stat = self._chi2(cal.R_1_2, cal.scale_1, cal.scale_2, cal.bias, (R0, s10, s20, b0),
                          self._project_cov(self._log_covariance(cal)) + P0)
        accepted = stat > thr
        if accepted:
            self._seed(cal, span_s=float(data[-1, 0] - data[0, 0]))
            reason = "step change confirmed by the batch solve over the window after the onset; re-seeded"
        else:
            self._restore_and_replay()
            reason = "batch solve agrees with the filter before the alarm (transient, e.g. flex); restored and replayed"
        self._events.append(ReseedEvent(t_det, onset, self._t, bool(accepted), float(stat), thr, reason))
        self._close_alarm()

    def _close_alarm(self):
        self._alarm, self._snapshot = None, None
        self._cusum, self._cusum_zero_t, self._next_try_t = 0.0, self._t, -np.inf

    def _restore_and_replay(self) -> None:
        """False alarm: return to the state at the alarm and re-process the buffered samples after its time."""
        R0, s10, s20, b0, P0, t0, rej0 = self._snapshot
        t_now = self._t
        self._R, self._s1, self._s2, self._b = R0, s10, s20, b0
        self.kf.x = np.zeros((_DIM, 1))
        self.kf.P = P0
        self._t = t0
        self._update_projection()
        self._G_cache = None
        data = self._buffer.since(t0)
        data = data[data[:, 0] > t0]             # every buffered sample the restored state has not seen
        self._alarm, self._snapshot = None, None
        self._replaying = True
        self.n_rejected = rej0
        try:
            for lo in range(0, data.shape[0], 100):
                blk = data[lo:lo + 100]
                self.update_block(blk[:, 0], blk[:, 1:4], blk[:, 4:7])
        finally:
            self._replaying = False
        self._predict_to(max(t_now, self._t))

    # ------------------------------------------------------------------ history
    def _record(self, t, nis, n_used):
        if self._replaying:
            return
        d = np.sqrt(np.clip(np.diag(self.kf.P), 0.0, None))
        self._rows.append((t, self._R.copy(), d[ROT].copy(), self._s1.copy(), self._s1 * d[S1],
                           self._s2.copy(), self._s2 * d[S2], self._b.copy(), d[BIAS].copy(), nis, n_used))

    def history(self) -> TrackHistory:
        """The estimate history so far (one row per update)."""
        return self._history(None, None)

    def _history(self, nees, truth_rows) -> TrackHistory:
        rows = self._rows
        M = len(rows)

        def col(i, shape):
            return np.array([r[i] for r in rows], dtype=float).reshape((M,) + shape)

        mode = "mixed" if len(self._modes) > 1 else (next(iter(self._modes)) if self._modes else "none")
        tr = truth_rows
        return TrackHistory(
            t=col(0, ()), R_1_2=col(1, (3, 3)), rotation_std=col(2, (3,)), scale_1=col(3, (3,)),
            scale_1_std=col(4, (3,)), scale_2=col(5, (3,)), scale_2_std=col(6, (3,)), bias=col(7, (3,)),
            bias_std=col(8, (3,)), nis=col(9, ()), n_used=np.array([r[10] for r in rows], dtype=np.int64),
            nees=None if nees is None else np.asarray(nees, float), nees_dof=self.nees_dof,
            truth_R_1_2=None if tr is None else tr[0], truth_scale_1=None if tr is None else tr[1],
            truth_scale_2=None if tr is None else tr[2], truth_bias=None if tr is None else tr[3],
            reseeds=tuple(self._events), n_samples=int(self.n_samples), n_rejected=int(self.n_rejected),
            gauge=self.gauge_description, mode=mode)

    # ------------------------------------------------------------------ drivers
    def run(self, t, omega_1, omega_2, *, mode: str = "fast", block_size: int = 100, max_gap_s: float | None = None,
            truth: PairTruth | None = None) -> TrackHistory:
        """Track over sample-aligned arrays and return the history (from construction on).

        Parameters
        ----------
        t : array_like (N,)
            Strictly increasing times (s), after the tracker's current time.
        omega_1, omega_2 : array_like (N, 3)
            Sample-aligned rates (rad/s).
        mode : {"fast", "sample"}
            Fold blocks of ``block_size`` samples into one update, or update per sample.
        block_size : int
            Samples per block in the fast mode.
        max_gap_s : float, optional
            A larger step between samples is a gap: no block straddles it (the covariance grows
            over it by the random walk). Default: 5 times the median sample interval.
        truth : PairTruth, optional
            Per-sample truth (N rows) for the NEES and the truth columns of the history.
        """
        if mode not in ("fast", "sample"):
            raise InputError(f"mode: expected 'fast' or 'sample', got {mode!r}")
        if int(block_size) < 1:
            raise InputError(f"block_size: expected >= 1, got {block_size}")
        t = check_timestamps("t", t)
        w1 = as_rates("omega_1", omega_1, length=t.shape[0])
        w2 = as_rates("omega_2", omega_2, length=t.shape[0])
        if truth is not None and len(truth) != t.shape[0]:
            raise InputError(f"truth: expected {t.shape[0]} rows (one per sample), got {len(truth)}")
        n0 = len(self._rows)
        nees_rows, truth_idx = [], []
        if mode == "sample":
            for k in range(t.shape[0]):
                self.update(t[k], w1[k], w2[k])
                if truth is not None:
                    truth_idx.append(k)
                    nees_rows.append(self.nees(truth.R_1_2[k], truth.scale_1[k], truth.scale_2[k], truth.bias[k]))
        else:
            if max_gap_s is None:
                max_gap_s = 5.0 * float(np.median(np.diff(t))) if t.shape[0] > 1 else np.inf
            cuts = np.flatnonzero(np.diff(t) > max_gap_s) + 1
            bounds = np.concatenate([[0], cuts, [t.shape[0]]])
            B = int(block_size)
            for lo, hi in zip(bounds[:-1], bounds[1:]):
                for s in range(lo, hi, B):
                    e = min(s + B, hi)
                    if hi - e < B // 2 and e < hi:   # fold a short tail into this block
                        e = hi
                    self.update_block(t[s:e], w1[s:e], w2[s:e])
                    if truth is not None:
                        k = int(s + np.searchsorted(t[s:e], t[s:e].mean()))
                        k = min(k, e - 1)
                        truth_idx.append(k)
                        nees_rows.append(self.nees(truth.R_1_2[k], truth.scale_1[k], truth.scale_2[k],
                                                   truth.bias[k]))
                    if e == hi:
                        break
        if truth is None:
            return self.history()
        # truth columns aligned with the rows of this run; earlier rows get NaN
        M = len(self._rows)
        nees = np.full(M, np.nan)
        nees[n0:] = nees_rows
        tR = np.full((M, 3, 3), np.nan)
        ts1, ts2, tb = (np.full((M, 3), np.nan) for _ in range(3))
        for row, k in zip(range(n0, M), truth_idx):
            tR[row] = truth.R_1_2[k]
            ts1[row], ts2[row] = self.express_in_gauge(truth.scale_1[k], truth.scale_2[k])
            tb[row] = truth.bias[k]
        return self._history(nees, (tR, ts1, ts2, tb))

    def run_streams(self, t_1, omega_1, t_2, omega_2, *, mode: str = "fast", block_size: int = 100,
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
        t2 = check_timestamps("t_2", t_2) + self.time_offset_s
        w1 = as_rates("omega_1", omega_1, length=t1.shape[0])
        w2 = as_rates("omega_2", omega_2, length=t2.shape[0])
        gap2 = 5.0 * float(np.median(np.diff(t2))) if max_gap_s is None else max_gap_s
        w2i, keep = resample(t2, w2, t1, max_gap_s=gap2)
        if not keep.any():
            raise InputError("t_1/t_2: the streams do not overlap in time (after adding time_offset_s = "
                             f"{self.time_offset_s} s to t_2)")
        return self.run(t1[keep], w1[keep], w2i[keep], mode=mode, block_size=block_size, max_gap_s=max_gap_s)


# ====================================================================== plotting
def plot_history(history: TrackHistory, *, title: str | None = None):
    """Figure of the tracked rotation change, scale factors and bias with 1-sigma bands.

    Rows: rotation of ``R_1_2`` relative to the first estimate (deg, gyro 1's axes), scale
    factors of both gyros (deviation from 1 in %), combined bias (deg/s). Re-seeds are marked
    with vertical lines (solid: accepted, dotted: rejected); the truth is dashed when present.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    deg = 180.0 / np.pi
    fig = Figure(figsize=(9, 8), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    t = history.t
    colors = ("tab:red", "tab:green", "tab:blue")
    if len(history):
        rot = history.rotation_change * deg
        for i in range(3):
            c = colors[i]
            axes[0].plot(t, rot[:, i], color=c, label="xyz"[i])
            axes[0].fill_between(t, rot[:, i] - history.rotation_std[:, i] * deg,
                                 rot[:, i] + history.rotation_std[:, i] * deg, color=c, alpha=0.2)
            for gy, (s, sd, ls) in enumerate(((history.scale_1, history.scale_1_std, "-"),
                                              (history.scale_2, history.scale_2_std, "--"))):
                v = (s[:, i] - 1.0) * 100
                axes[1].plot(t, v, color=c, ls=ls, label=f"scale_{gy + 1}[{'xyz'[i]}]")
                axes[1].fill_between(t, v - sd[:, i] * 100, v + sd[:, i] * 100, color=c, alpha=0.15)
            b = history.bias[:, i] * deg
            axes[2].plot(t, b, color=c, label="xyz"[i])
            axes[2].fill_between(t, b - history.bias_std[:, i] * deg, b + history.bias_std[:, i] * deg,
                                 color=c, alpha=0.2)
        if history.truth_R_1_2 is not None:
            ok = np.isfinite(history.truth_R_1_2).all(axis=(1, 2))
            rt = np.full((len(history), 3), np.nan)
            rt[ok] = Rotation.from_matrix(history.truth_R_1_2[ok] @ history.R_1_2[0].T).as_rotvec() * deg
            for i in range(3):
                axes[0].plot(t, rt[:, i], color=colors[i], ls=":", lw=1)
                axes[1].plot(t, (history.truth_scale_1[:, i] - 1) * 100, color=colors[i], ls=":", lw=1)
                axes[1].plot(t, (history.truth_scale_2[:, i] - 1) * 100, color=colors[i], ls=":", lw=1)
                axes[2].plot(t, history.truth_bias[:, i] * deg, color=colors[i], ls=":", lw=1)
    for ev in history.reseeds:
        for ax in axes:
            ax.axvline(ev.t_detected, color="k", ls="-" if ev.accepted else ":", lw=0.8)
    axes[0].set_ylabel("R_1_2 change [deg]")
    axes[1].set_ylabel("scale - 1 [%]")
    axes[2].set_ylabel("bias [deg/s]")
    axes[2].set_xlabel("time [s]")
    axes[0].legend(loc="upper left", fontsize="small", ncol=3)
    axes[1].legend(loc="upper left", fontsize="x-small", ncol=3)
    fig.suptitle(title or f"EKF drift tracking ({history.mode} mode; gauge: {history.gauge})", fontsize="small")
    return fig


def track_figure_for_report(run, *, seed_fraction: float = 0.2, rate_hz: float = 100.0, drift: DriftNoise = DriftNoise(),
                            block_size: int | None = None):
    """Drift-tracking figure for ``gyrocal report --track``: seed on the start, track the rest.

    Parameters
    ----------
    run : fusion_gyrocal.pipeline.pipeline.PipelineRun
        Sample-aligned rates the batch solver used (``run.omega_1``, ``run.omega_2``, ``run.t`` on
        gyro 1's clock, ``run.valid``).
    seed_fraction : float
        Leading fraction of the samples used to seed the tracker (not re-used by it).
    rate_hz : float
        Sample rate assumed when ``run.t`` is None (sample-aligned input without timestamps).
    drift : DriftNoise
    block_size : int, optional
        Samples per fast-mode block (default: about one second).

    Returns
    -------
    matplotlib.figure.Figure
    """
    w1, w2 = np.asarray(run.omega_1, float), np.asarray(run.omega_2, float)
    n = w1.shape[0]
    t = np.arange(n) / float(rate_hz) if run.t is None else np.asarray(run.t, float)
    keep = np.isfinite(w1).all(axis=1) & np.isfinite(w2).all(axis=1)
    if run.valid is not None:
        keep = keep & np.asarray(run.valid, bool)       # never modify the run's arrays
    t, w1, w2 = t[keep], w1[keep], w2[keep]
    if t.size < 20:
        raise InputError(f"run: expected at least 20 valid samples to track, got {t.size}")
    k = max(int(seed_fraction * t.size), 10)
    tracker = GyroPairTracker.from_samples(t[:k], w1[:k], w2[:k], noise_std=tuple(run.calibration.noise_std),
                                           drift=drift)
    if block_size is None:
        block_size = max(1, int(round(1.0 / float(np.median(np.diff(t))))))
    h = tracker.run(t[k:], w1[k:], w2[k:], block_size=block_size) if k < t.size else tracker.history()
    return plot_history(h, title=f"Drift tracking (EKF, seeded on the first {100 * seed_fraction:.0f} %; "
                                 f"{len(h.reseeds)} step alarm(s); gauge: {h.gauge})")


# ====================================================================== simulation with drifting parameters
def simulate_drifting_pair(t, R_1_2, scale_1, scale_2, *, bias_1=None, bias_2=None, noise_std=0.1 * np.pi / 180,
                           omega_true_1=None, rms=1.0, rng=None) -> tuple[np.ndarray, np.ndarray, PairTruth]:
    """Simulate a pair whose calibration changes over time (the paper's Eq. 1 per sample).

    Parameters
    ----------
    t : array_like (N,)
        Sample times (s).
    R_1_2 : array_like (3, 3) or (N, 3, 3)
        True rotation per sample.
    scale_1, scale_2 : array_like (3,) or (N, 3)
        True scale factors per sample.
    bias_1, bias_2 : array_like (3,) or (N, 3), optional
        True biases per sample (rad/s); default zero.
    noise_std : float or (float, float)
        White noise per sample (rad/s).
    omega_true_1 : array_like (N, 3), optional
        True rate in gyro 1's frame (rad/s), e.g. recorded motion from
        :func:`fusion_gyrocal.evaluate.sim.load_broad_rates`. Default: :class:`fusion_gyrocal.evaluate.sim.HumanMotion`.
    rms : float
        RMS rate of the default human-like motion (rad/s per axis).
    rng : numpy.random.Generator or int, optional

    Returns
    -------
    omega_1, omega_2 : ndarray (N, 3)
    truth : PairTruth
    """
    from ..evaluate.sim import HumanMotion

    rng = np.random.default_rng(rng)
    t = np.asarray(t, dtype=float)
    n = t.shape[0]
    R = np.broadcast_to(np.asarray(R_1_2, float), (n, 3, 3))
    s1 = np.broadcast_to(np.asarray(scale_1, float), (n, 3))
    s2 = np.broadcast_to(np.asarray(scale_2, float), (n, 3))
    b1 = np.broadcast_to(np.zeros(3) if bias_1 is None else np.asarray(bias_1, float), (n, 3))
    b2 = np.broadcast_to(np.zeros(3) if bias_2 is None else np.asarray(bias_2, float), (n, 3))
    sig = np.broadcast_to(np.asarray(noise_std, float), (2,))
    if omega_true_1 is None:
        w_true_1 = HumanMotion(rms, rng=rng)(t)
    else:
        w_true_1 = as_rates("omega_true_1", omega_true_1, length=n).astype(float)
    w_true_2 = np.einsum("kji,kj->ki", R, w_true_1)          # R^T omega_1
    w1 = s1 * w_true_1 + b1 + rng.normal(0, sig[0], (n, 3))
    w2 = s2 * w_true_2 + b2 + rng.normal(0, sig[1], (n, 3))
    A = (s1[:, :, None] * R) / s2[:, None, :]
    bias = b1 - np.einsum("kij,kj->ki", A, b2)
    return w1, w2, PairTruth(R, s1, s2, bias)
