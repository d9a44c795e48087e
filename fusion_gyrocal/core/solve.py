"""Calibrate a gyroscope pair: from samples (:func:`calibrate_pair`) or moments (:func:`solve`).

Pipeline: moments -> direct least squares for A (Eq. 17) -> configuration class (Lemmas 2-4)
-> decomposition -> gauge (Theorem 2, Eq. 32-34) -> maximum-likelihood refinement (Appendix C
generalised, default) -> covariance from the Fisher information (Appendix B generalised).
"""

from __future__ import annotations

import numpy as np

from .direct import Gauge, decompose, solve_A
from ..errors import ConfigurationError, InputError, NotRigidError
from .model import BIAS, ROT, PairCalibration, mark_undetermined
from .moments import Moments, noise_pair
from .observability import (A_of, check_excitation, check_samples, classify, dA_dp, fisher_information,
                            nearest_rotation, per_axis_snr, residual_weight, signal_scatter)
from .refine import residual_scatter, refine_ml

METHODS = ("ml", "direct")


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
