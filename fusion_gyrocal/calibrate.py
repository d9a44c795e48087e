"""Calibrate a gyroscope pair: from samples (:func:`calibrate_pair`) or moments (:func:`solve`).

Pipeline: moments -> direct least squares for A (Eq. 17) -> configuration class (Lemmas 2-4)
-> decomposition -> gauge (Theorem 2, Eq. 32-34) -> maximum-likelihood refinement (Appendix C
generalised, default) -> covariance from the Fisher information (Appendix B generalised).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .direct import Gauge, decompose, solve_A
from .errors import ConfigurationError, InputError, NotRigidError
from .model import BIAS, ROT, PairCalibration, mark_undetermined
from .moments import Moments, noise_pair
from .observability import (A_of, check_excitation, check_samples, classify, dA_dp, fisher_information,
                            nearest_rotation, per_axis_snr, residual_weight, signal_scatter)
from .refine import residual_scatter, refine_ml

METHODS = ("ml", "direct")


def check_keyword_options(func, options: dict, *, reserved=()) -> None:
    """Raise :class:`ConfigurationError` for keyword options that ``func`` does not take (or that the
    caller sets itself, ``reserved``), naming the ones it accepts."""
    import inspect

    allowed = set(inspect.signature(func).parameters) - set(reserved)
    unknown = sorted(set(options) - allowed)
    if unknown:
        raise ConfigurationError(f"unknown option(s) {unknown} for {func.__name__}(); expected some of "
                                 f"{sorted(allowed)}")


def difference_noise_std(omega) -> float:
    """White-noise std per sample of one stream from its third differences (robust, MAD).

    ``Var(Delta^3 n) = 20 sigma^2`` for white noise, while smooth motion contributes little to the
    third difference; fast motion at a low sample rate biases the value upwards, so the library
    uses it only to split the residual variance between the gyros, never for its level.
    """
    w = np.asarray(omega, dtype=float)
    d = np.diff(w[np.isfinite(w).all(axis=1)], n=3, axis=0)
    if d.shape[0] < 10:
        return float("nan")
    return float(np.median(1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0)) / np.sqrt(20.0))


def _residual_noise(moments: Moments, A, ratio: float = 1.0) -> tuple[float, float]:
    """Noise per gyro from the least-squares residual, split in the ratio ``sigma_1 / sigma_2``."""
    M = residual_scatter(A, moments.scatter)
    dof = max(moments.dof - 3.0, 1.0)
    total = float(np.trace(M)) / (3.0 * dof)
    floor = 1e-24 * float(np.trace(moments.S11)) / (3.0 * dof)  # noise-free input: keep weights finite
    s2 = max(total, floor) / (1.0 + ratio**2)
    return float(np.sqrt(s2) * ratio), float(np.sqrt(s2))


def _skew_compensation(intrinsics, name):
    """``U^-1`` for an upper-triangular intrinsic matrix ``S = U D`` (U unit upper triangular)."""
    if intrinsics is None:
        return np.eye(3)
    S = np.asarray(intrinsics, dtype=float)
    if S.shape != (3, 3) or np.any(np.tril(S, -1) != 0) or np.any(np.diag(S) <= 0):
        raise InputError(f"{name}: expected an upper-triangular (3, 3) intrinsic matrix with a positive "
                         f"diagonal, got {S.tolist()}")
    U = S / np.diag(S)[None, :]
    return np.linalg.inv(U)


def _transform(moments: Moments, T1, T2) -> Moments:
    T = np.zeros((6, 6))
    T[:3, :3], T[3:, 3:] = T1, T2
    return Moments(moments.count, T @ moments.mean, T @ moments.scatter @ T.T, moments.segments)


def solve(moments: Moments, *, method: str = "ml", noise_std=None, gauge="unit_prior",
          scale_prior_std: float | None = None, parallel_tol_deg: float = 5.0,
          intrinsics_1=None, intrinsics_2=None, skew_std=0.0, min_snr: float = 10.0,
          max_unexplained: float = 0.05, on_not_rigid: str = "raise", noise_ratio: float | None = None,
          target_snr: float = 4e3) -> PairCalibration:
    """Calibrate a pair from its sufficient statistics.

    Parameters
    ----------
    moments : Moments
        Statistics of sample-aligned ``[omega_1; omega_2]`` (pooled per segment for a
        piecewise-constant bias).
    method : {"ml", "direct"}
        ``"direct"``: the paper's closed form (Eq. 17, Lemmas 2-4, Eq. 32-34), covariance by first-
        order propagation of the least-squares covariance of A. ``"ml"`` (default): the direct
        solution refined to the maximum-likelihood estimate of the errors-in-variables model;
        covariance = inverse Fisher information (the Cramer-Rao bound at the estimate).
    noise_std : float or (float, float), optional
        White-noise std per sample of gyro 1 and gyro 2 (rad/s). Default: from the
        least-squares residual, split between the gyros by ``noise_ratio`` (only the sum of the
        variances is observable there; :func:`calibrate_pair` estimates the ratio from the data).
    gauge : "unit_prior", "fixed" or Gauge
        How the global scale is fixed (ignored when ``scale_prior_std`` is given).
    scale_prior_std : float, optional
        Gaussian prior N(1, std^2) on every scale factor (``"ml"`` only); directions the data do
        not fix then take the prior and the covariance says so.
    parallel_tol_deg : float
        Axes closer than this to parallel are treated as parallel (ill-conditioned decomposition).
    intrinsics_1, intrinsics_2 : (3, 3) upper-triangular, optional
        Manufacturer intrinsic matrices; their skew (off-diagonal) part is compensated before the
        solve; the scale factors are then estimated.
    skew_std : float or (float, float)
        Standard deviation of the remaining skew error of each gyro; its rotation error
        (Appendix D, Eq. 40-41) is reported in ``skew_rotation_covariance`` and added to the
        covariance.
    min_snr : float
        Smallest SNR of any principal motion direction accepted (Lemma 1).
    max_unexplained : float
        Rigidity test: the pair is "not rigid" when the least-squares fit leaves more than this
        fraction of gyro 1's (centred) motion energy unexplained.
    on_not_rigid : {"raise", "flag"}
        Raise :class:`NotRigidError` (default), or return the result with ``rigid=False`` and the
        covariance from the residual scatter.
    noise_ratio : float, optional
        ``sigma_1 / sigma_2`` used to split the residual variance when ``noise_std`` is not given
        (only the sum ``sigma_1^2 + sigma_2^2`` is observable from the residual); default 1.
    target_snr : float
        Per-axis SNR the data should reach (Section VI accumulates to 4e3); a note names the axes
        below it.
    """
    if on_not_rigid not in ("raise", "flag"):
        raise InputError(f"on_not_rigid: expected 'raise' or 'flag', got {on_not_rigid!r}")
    if method not in METHODS:
        raise InputError(f"method: expected one of {METHODS}, got {method!r}")
    if scale_prior_std is not None and (method != "ml" or not scale_prior_std > 0):
        raise ConfigurationError("scale_prior_std: expected a positive value with method='ml'")
    gauge = Gauge.parse(gauge)
    T1, T2 = _skew_compensation(intrinsics_1, "intrinsics_1"), _skew_compensation(intrinsics_2, "intrinsics_2")
    moments = _transform(moments, T1, T2) if (intrinsics_1 is not None or intrinsics_2 is not None) else moments
    noise = None if noise_std is None else noise_pair(noise_std)
    check_samples(moments)
    A_ls, _ = solve_A(moments)
    unexplained = float(np.trace(residual_scatter(A_ls, moments.scatter)) / np.trace(moments.S11))
    rigid = unexplained <= max_unexplained
    if not rigid and on_not_rigid == "raise":
        raise NotRigidError(
            f"not rigid: a single rotation and scale factors leave {100 * unexplained:.1f}% of gyro 1's motion "
            f"unexplained (a rigid pair leaves <= {100 * max_unexplained:g}%); the gyros move relative to each "
            "other, the streams are misaligned in time, or they are not the same device")
    if noise is None:
        ratio = 1.0 if noise_ratio is None or not np.isfinite(noise_ratio) else float(noise_ratio)
        noise = _residual_noise(moments, A_ls, ratio)
        noise_source = ("residual (split equally between the gyros)" if noise_ratio is None else
                        f"residual, split {ratio:.3g}:1 by the third differences of each stream")
    else:
        noise_source = "user"
    if rigid:
        check_excitation(moments, noise, min_snr=min_snr)
    # classify from the polar factor of A (scales ~1), then again from the decomposed rotation
    config = classify(nearest_rotation(A_ls), parallel_tol_deg)
    notes = []
    iterations = 0
    if rigid:
        R, s1, s2 = decompose(A_ls, config)
        config = classify(R, parallel_tol_deg)
        R, s1, s2 = decompose(A_ls, config)
    else:  # no rigid model fits: report the nearest rotation with unit scales, flagged, never refined
        R, s1, s2 = nearest_rotation(A_ls), np.ones(3), np.ones(3)
    s1, s2 = gauge.apply(config.groups, s1, s2)
    if method == "ml" and rigid:
        use_prior = scale_prior_std is not None
        ref = refine_ml(moments, R, s1, s2, noise, scale_prior_std=scale_prior_std,
                        constraints=None if use_prior else (lambda a, b: gauge.constraints(config.groups, a, b)),
                        regauge=None if use_prior else (lambda a, b: gauge.apply(config.groups, a, b)))
        R, s1, s2, iterations = ref.R, ref.s1, ref.s2, ref.iterations
        if not ref.converged:
            notes.append(f"maximum-likelihood refinement stopped after {iterations} iterations without converging")
    A = A_of(R, s1, s2)
    bias = moments.mean_1 - A @ moments.mean_2
    _, Xi_c = signal_scatter(moments, noise)
    F = fisher_information(R, s1, s2, noise, Xi_c)
    if method == "ml":
        P9 = _ml_covariance(F, s1, s2, config, gauge, scale_prior_std)
    else:
        P9 = _direct_covariance(moments, A_ls, noise, config, gauge)
    # residual consistency: inflate when the data scatter more than the stated noise explains
    W = residual_weight(A, noise)
    M = residual_scatter(A, moments.scatter)
    chi2 = float(np.trace(W @ M))
    dof = max(3.0 * moments.dof - 8.0, 1.0)
    ratio = chi2 / dof
    if not rigid:
        notes.append(f"NOT RIGID: {100 * unexplained:.1f}% of the motion is unexplained; do not use this estimate")
    if noise_source == "user" and ratio > 1.5:
        P9 = P9 * ratio
        notes.append(f"residuals are {np.sqrt(ratio):.2f}x larger than noise_std explains (flex, skew, time offset "
                     f"or a wrong noise_std?); covariance inflated by {ratio:.2f}")
    cov = pair_covariance(P9, R, s1, s2, A, moments, noise)
    if scale_prior_std is None:
        mark_undetermined(cov, config.scale_observable)
    sk = np.broadcast_to(np.asarray(skew_std, dtype=float), (2,))
    skew_cov = 0.25 * (sk[0] ** 2 + sk[1] ** 2) * np.eye(3)  # Appendix D: theta ~ (w_1 - C w_2) / 2
    cov[ROT, ROT] += skew_cov
    snr = per_axis_snr(moments, noise)
    weak = [f"{'xyz'[i]} ({snr[i]:.3g})" for i in range(3) if snr[i] < target_snr]
    if weak:
        notes.append(f"per-axis SNR below the target {target_snr:g} (the paper accumulates to 4e3) on axis "
                     f"{', '.join(weak)}: rotate more about those axes of gyro 1, or record longer")
    if config.name != "general" and scale_prior_std is None:
        pairs = ", ".join(f"gyro 1 {'xyz'[i]} ~ gyro 2 {'xyz'[j]} ({ang:.2f} deg)"
                          for i, j, ang in config.parallel_pairs)
        notes.append(f"{config.name}: {pairs}; only the ratio of those scale factors is determined (Lemma "
                     f"{'2' if config.name == 'all_axes_parallel' else '3'})")
    gauge_text = (f"Gaussian prior N(1, {scale_prior_std:g}^2) on every scale factor" if scale_prior_std is not None
                  else gauge.describe())
    return PairCalibration(
        R_1_2=R, scale_1=s1, scale_2=s2, bias=bias, configuration=config.name,
        scale_observable=config.scale_observable, covariance=cov, gauge=gauge_text, snr=snr,
        n_samples=int(moments.count), noise_std=np.array(noise), noise_source=noise_source,
        residual_rms=float(np.sqrt(max(np.trace(M), 0.0) / (3.0 * max(moments.dof, 1.0)))), method=method,
        iterations=iterations, skew_rotation_covariance=skew_cov, bias_segments=moments.segments,
        rigid=rigid, unexplained_fraction=unexplained, notes=tuple(notes))


def _ml_covariance(F, s1, s2, config, gauge, scale_prior_std):
    if scale_prior_std is not None:
        s = np.concatenate([s1, s2])
        H = F.copy()
        H[3:, 3:] += np.diag(s**2 / scale_prior_std**2)
        return np.linalg.inv(H)
    from scipy.linalg import null_space
    Z = null_space(gauge.constraints(config.groups, s1, s2))
    return Z @ np.linalg.pinv(Z.T @ F @ Z, rcond=1e-12, hermitian=True) @ Z.T


def _direct_covariance(moments, A_ls, noise, config, gauge):
    """First-order propagation of Cov(vec A) through the decomposition and gauge (numerical Jacobian)."""
    from scipy.spatial.transform import Rotation
    W_inv = np.linalg.inv(residual_weight(A_ls, noise))
    cov_A = np.kron(W_inv, np.linalg.inv(moments.S22))  # row-major vec(A)

    def params(A):
        R, s1, s2 = decompose(A, config)
        s1, s2 = gauge.apply(config.groups, s1, s2)
        return R, np.log(s1), np.log(s2)

    R0, l10, l20 = params(A_ls)
    J = np.zeros((9, 9))
    h = 1e-7
    for k in range(9):
        dA = np.zeros(9)
        dA[k] = h
        R, l1, l2 = params(A_ls + dA.reshape(3, 3))
        J[:3, k] = Rotation.from_matrix(R @ R0.T).as_rotvec() / h
        J[3:6, k] = (l1 - l10) / h
        J[6:, k] = (l2 - l20) / h
    return J @ cov_A @ J.T


def pair_covariance(P9, R, s1, s2, A, moments, noise):
    """12x12 covariance of ``[dtheta, scale_1, scale_2, bias]`` from that of ``[dtheta, log s]``."""
    Jl = np.diag(np.concatenate([np.ones(3), s1, s2]))
    D = dA_dp(R, s1, s2)
    G = np.einsum("pij,j->ip", D, moments.mean_2)  # d(A m_2)/dp, so db = -G dp
    Sigma_r = np.linalg.inv(residual_weight(A, noise))
    cov = np.zeros((12, 12))
    cov[:9, :9] = Jl @ P9 @ Jl.T
    cov[BIAS, BIAS] = Sigma_r / moments.count + G @ P9 @ G.T
    cov[BIAS, :9] = -G @ P9 @ Jl.T
    cov[:9, BIAS] = cov[BIAS, :9].T
    return cov


def calibrate_pair(omega_1, omega_2, *, t_1=None, t_2=None, time_offset_s: float | None = None,
                   max_offset_s: float = 1.0, rate_hz: float | None = None, saturation_limit=None,
                   method: str = "ml", noise_std=None, gauge="unit_prior", scale_prior_std: float | None = None,
                   bias_window: int | None = None, bias_walk_std=None, mask=None, flex_rejection="auto",
                   flex_margin: int = 2,
                   parallel_tol_deg: float = 5.0, intrinsics_1=None, intrinsics_2=None, skew_std=0.0,
                   min_snr: float = 10.0, max_unexplained: float = 0.05, on_not_rigid: str = "raise",
                   max_rate: float | None = None) -> PairCalibration:
    """Calibrate two rigidly mounted gyroscopes from their angular rates.

    Parameters
    ----------
    omega_1, omega_2 : array_like, shape (N, 3) and (M, 3)
        Measured angular rates (rad/s) of gyro 1 (the reference) and gyro 2, float32 or
        float64. Without timestamps they must be sample-aligned (N == M, same instants).
    t_1, t_2 : array_like (N,) and (M,), optional
        Timestamps (s) of each stream on its own clock. When given, saturated and non-finite
        samples are masked, the time offset is estimated by correlating the rate norms and
        refined below one sample (unless ``time_offset_s`` is given), and gyro 2 is resampled
        onto gyro 1's timestamps (or a ``rate_hz`` grid) with cubic splines that never cross
        a gap (see :mod:`fusion_gyrocal.preprocess`).
    time_offset_s : float, optional
        Known offset, ADDED to gyro 2's timestamps to put them on gyro 1's clock.
    max_offset_s : float
        Search range of the offset estimate.
    rate_hz : float, optional
        Resample both streams onto a uniform grid at this rate.
    saturation_limit : float or (float, float), optional
        Sensor range (rad/s) of each gyro for masking clipped samples (default: detect samples
        sitting flat at the extreme values).
    method : {"ml", "direct"}
        Estimator (see :func:`solve`); ``"ml"`` is the default and the best available.
    noise_std : float or (float, float), optional
        White-noise std per sample (rad/s); estimated from the residual when omitted.
    gauge : "unit_prior", "fixed" or Gauge
        Global-scale gauge (Theorem 2): the paper's unit prior on both x axes (default),
        ``scale_1[0] == 1``, or ``Gauge.known_scale(gyro, axis, value)``.
    scale_prior_std : float, optional
        Gaussian prior N(1, std^2) on the scale factors.
    bias_window : int, optional
        Model the bias as piecewise constant over windows of this many samples (for drifting
        biases); default: one constant bias (Eq. 8).
    bias_walk_std : float or (float, float), optional
        Model the bias of each gyro as a random walk with this step std per sample (rad/s); the
        streams are whitened by the Kalman innovations filter of that model
        (:func:`~fusion_gyrocal.moments.random_walk_bias_moments`), which is the exact likelihood.
        Needs ``noise_std``. The best choice for temperature drift over long logs.
    mask : array_like of bool (N,), optional
        Samples to use (sample-aligned input only).
    flex_rejection : {"auto", True, False}
        The paper's flex rejection (Section VI.C): residuals beyond the 3-sigma gate (in its 3-D
        form, chi-square with the same 0.27% false-alarm rate) and ``flex_margin`` samples on each
        side are removed and the pair is solved again. ``"auto"`` applies it only when more than
        1% of the samples exceed the gate (four times what white noise explains).
    max_rate : float, optional
        Drop samples where either gyro's rate norm exceeds this (rad/s): a known flex or saturation
        limit (the paper's advice to avoid the fastest motion). Slow samples are kept: they cost
        nothing in accuracy, and selecting on gyro 1's noisy measurement would bias the fit.
    parallel_tol_deg, intrinsics_1, intrinsics_2, skew_std, min_snr, max_unexplained, on_not_rigid
        See :func:`solve`.

    Returns
    -------
    PairCalibration

    Raises
    ------
    InputError
        Wrong shapes or lengths, non-finite values, fewer than 4 samples, constant input, bad
        timestamps (unsorted, duplicate, non-finite).
    ExcitationError
        Motion that does not determine all parameters (Lemma 1); the message names the weak
        axes, their SNR and the motion to add.
    NotRigidError
        The gyros do not move as one rigid body (unless ``on_not_rigid="flag"``).
    TimeAlignmentError
        The time offset cannot be determined from the data.

    Examples
    --------
    >>> from fusion_gyrocal import calibrate_pair
    >>> from fusion_gyrocal.sim import simulate_pair
    >>> sim = simulate_pair(rng=0)
    >>> cal = calibrate_pair(sim.omega_1, sim.omega_2)
    >>> cal.configuration
    'general'
    """
    return run_pipeline(omega_1, omega_2, t_1=t_1, t_2=t_2, time_offset_s=time_offset_s, max_offset_s=max_offset_s,
                        rate_hz=rate_hz, saturation_limit=saturation_limit, method=method, noise_std=noise_std,
                        gauge=gauge, scale_prior_std=scale_prior_std, bias_window=bias_window,
                        bias_walk_std=bias_walk_std, mask=mask, flex_rejection=flex_rejection,
                        flex_margin=flex_margin, parallel_tol_deg=parallel_tol_deg,
                        intrinsics_1=intrinsics_1, intrinsics_2=intrinsics_2, skew_std=skew_std, min_snr=min_snr,
                        max_unexplained=max_unexplained, on_not_rigid=on_not_rigid,
                        max_rate=max_rate).calibration


@dataclass(frozen=True)
class PipelineRun:
    """Everything :func:`calibrate_pair` saw and decided, for reports and plots.

    ``omega_1``/``omega_2`` are the sample-aligned rates the solver used (zero where ``valid`` is
    False), ``t`` their times on gyro 1's clock (None for sample-aligned input), ``used`` the
    samples kept after masking and flex rejection, and ``aligned`` the
    :class:`~fusion_gyrocal.preprocess.AlignedPair` (None for sample-aligned input).
    """

    calibration: PairCalibration
    t: np.ndarray | None
    omega_1: np.ndarray
    omega_2: np.ndarray
    valid: np.ndarray | None
    used: np.ndarray | None
    aligned: object | None


def run_pipeline(omega_1, omega_2, *, t_1=None, t_2=None, time_offset_s=None, max_offset_s=1.0, rate_hz=None,
                 saturation_limit=None, method="ml", noise_std=None, gauge="unit_prior", scale_prior_std=None,
                 bias_window=None, bias_walk_std=None, mask=None, flex_rejection="auto", flex_margin=2,
                 parallel_tol_deg=5.0, intrinsics_1=None, intrinsics_2=None, skew_std=0.0, min_snr=10.0,
                 max_unexplained=0.05,
                 on_not_rigid="raise", min_kept_energy=0.05, max_rate=None) -> PipelineRun:
    """:func:`calibrate_pair` returning its intermediate products too (same parameters).

    ``min_kept_energy``: flex rejection is applied only when the kept samples retain at least this
    fraction of gyro 1's motion energy; otherwise the rate-dependent residual is not a flex burst
    but pervasive, removing it would remove the excitation itself, and a note says so.
    """
    if flex_rejection not in ("auto", True, False):
        raise InputError(f"flex_rejection: expected 'auto', True or False, got {flex_rejection!r}")
    offset, offset_std = 0.0, 0.0
    pair, t_grid = None, None
    if (t_1 is None) != (t_2 is None):
        raise InputError("t_1 and t_2: expected both timestamps or neither (sample-aligned input)")
    if t_1 is not None:
        from .preprocess import align_streams, valid_mask
        if mask is not None:
            raise InputError("mask: only for sample-aligned input; with timestamps, saturated and non-finite "
                             "samples are masked automatically")
        lim = (None, None) if saturation_limit is None else np.broadcast_to(np.asarray(saturation_limit, float), (2,))
        pair = align_streams(t_1, omega_1, t_2, omega_2, time_offset_s=time_offset_s, max_offset_s=max_offset_s,
                             rate_hz=rate_hz, valid_1=valid_mask(omega_1, limit=lim[0]),
                             valid_2=valid_mask(omega_2, limit=lim[1]))
        w1 = np.where(pair.valid[:, None], pair.omega_1, 0.0)
        w2 = np.where(pair.valid[:, None], pair.omega_2, 0.0)
        mask = pair.valid
        t_grid = pair.t
        offset = pair.time_offset_s
        offset_std = pair.time_offset.std_s if pair.time_offset is not None else 0.0
    else:
        w1, w2 = omega_1, omega_2
        if mask is not None:
            mask = np.asarray(mask, dtype=bool)
    if max_rate is not None:
        from .preprocess import informative_mask
        keep = informative_mask(w1, w2, mask, 1.0, min_rate=0.0, max_rate=max_rate)
        mask = keep if mask is None else (mask & keep)
    kw = dict(method=method, noise_std=noise_std, gauge=gauge, scale_prior_std=scale_prior_std,
              parallel_tol_deg=parallel_tol_deg, intrinsics_1=intrinsics_1, intrinsics_2=intrinsics_2,
              skew_std=skew_std, min_snr=min_snr, max_unexplained=max_unexplained, on_not_rigid=on_not_rigid)

    if bias_walk_std is not None:
        if noise_std is None:
            raise ConfigurationError("bias_walk_std: the drifting-bias filter needs noise_std too (rad/s per sample)")
        if bias_window is not None:
            raise ConfigurationError("bias_window and bias_walk_std: expected one bias model, got both")
        from .moments import random_walk_bias_moments, random_walk_gain
        gain, noise_scale = random_walk_gain(bias_walk_std, noise_std)
        kw["noise_std"] = np.broadcast_to(np.asarray(noise_std, float), (2,)) * noise_scale
        gate_window = max(20, int(round(1.0 / gain)))  # residual windows of the filter's time constant
    else:
        gate_window = bias_window

    def moments_of(use):
        if bias_walk_std is not None:
            return random_walk_bias_moments(w1, w2, bias_walk_std, noise_std, mask=use)[0]
        if bias_window is None:
            return Moments.from_samples(w1, w2, mask=use)
        from .moments import window_moments
        return Moments.pool_all(window_moments(w1, w2, int(bias_window), mask=use))

    if noise_std is None:  # split the residual variance by each stream's high-frequency noise
        head = slice(0, 200_000)  # plenty for a noise level; no copy of a long log
        v = slice(None) if mask is None else mask[head]
        d1, d2 = (difference_noise_std(np.asarray(w[head])[v]) for w in (w1, w2))
        kw["noise_ratio"] = d1 / d2 if d1 > 0 and d2 > 0 else None
    valid_in = mask
    mom = mom0 = moments_of(mask)
    cal = solve(mom, **kw)
    rejected = 0.0
    corr = float("nan")
    if flex_rejection is not False and cal.rigid:
        from . import flex

        n, n_used, keep = len(w1), cal.n_samples, mask
        sub = flex.block_ranges(n, gate_window, max_points=30_000)
        A_ls, b_ls = solve_A(mom)
        L = flex.robust_whitener(w1, w2, A_ls, b_ls, keep, gate_window, sub)
        n_sub = sum(b - a for a, b in sub) if mask is None else sum(int(mask[a:b].sum()) for a, b in sub)
        frac = flex.outliers(w1, w2, A_ls, b_ls, keep, gate_window, sub, L).size / max(n_sub, 1)
        if flex_rejection is True or frac > 0.01:  # the paper's gate, iterated until nothing new is rejected
            everything = flex.block_ranges(n, gate_window)
            for _ in range(5):
                out = flex.outliers(w1, w2, A_ls, b_ls, keep, gate_window, everything, L)
                if out.size == 0:
                    break
                gate = np.ones(n, bool) if keep is None else keep.copy()
                gate[flex.dilate(out, flex_margin, n)] = False  # the outliers and their neighbours
                keep = gate
                mom = moments_of(keep)
                A_ls, b_ls = solve_A(mom)
                L = flex.robust_whitener(w1, w2, A_ls, b_ls, keep, gate_window, sub)
        cut = flex.flex_rate_cut(*flex.normalised_residuals(w1, w2, A_ls, b_ls, keep, gate_window, sub, L))
        if cut is not None:
            fast = flex.above_rate(w1, cut, n)
            keep = ~fast if keep is None else (keep & ~fast)
            mom = moments_of(keep)
        kept_energy = float(np.trace(mom.S11) / np.trace(mom0.S11)) if keep is not mask else 1.0
        if keep is not mask and kept_energy >= min_kept_energy:
            rejected = 1.0 - mom.count / max(n_used, 1)
            cal = solve(mom, **kw)
            mask = keep
        elif keep is not mask:
            cal = _replace(cal, notes=cal.notes + (
                f"the residual grows with the rate across the motion (model error or flex everywhere): rejecting it "
                f"would keep only {100 * kept_energy:.0f}% of the motion energy, so no sample was rejected",))
        d2, rate = flex.normalised_residuals(w1, w2, cal.A, cal.bias, mask, gate_window, sub, np.eye(3))
        corr = flex.spearman(np.sqrt(d2), rate)
    cal = _replace(cal, time_offset_s=offset, time_offset_std_s=offset_std, rejected_fraction=rejected,
                   rate_residual_correlation=corr)
    return PipelineRun(cal, t_grid, np.asarray(w1), np.asarray(w2), valid_in, mask, pair)


def _replace(cal: PairCalibration, **changes) -> PairCalibration:
    import dataclasses
    return dataclasses.replace(cal, **changes)
