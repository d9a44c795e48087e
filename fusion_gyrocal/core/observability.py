"""Observability: configuration classes (Lemmas 2-4), excitation (Lemma 1), information and SNR.

The Fisher information generalises the paper's Appendix B to the full model. With the
gyro-2 signal ``xi_k`` (true rate in gyro 2's measurement units) as nuisance, the
measurements are ``y_2 = xi + n_2`` and ``y_1 = A xi + b + n_1``; eliminating ``xi_k``
gives, per sample, the residual ``y_1 - A y_2 - b`` with covariance
``Sigma_r = sigma_1^2 I + sigma_2^2 A A^T`` and the information (bias profiled out)

    I_pq = tr(D_p^T W D_q Xi_c),   W = Sigma_r^-1,   D_p = dA/dp,

where ``Xi_c`` is the centred scatter of the gyro-2 signal (Eq. 52-53 of Appendix B with
the scale factors added). The parameters ``p`` are ``[dtheta (3), log scale_1 (3), log scale_2 (3)]``
with ``A = diag(s_1) Exp(dtheta) R diag(1/s_2)``. The global scale (all six log-scales together)
is always a null direction (Theorem 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigurationError, ExcitationError, InputError
from ..lie import skew
from .gauge import Gauge, constrained_inverse, null_directions
from .moments import Moments

AXES = "xyz"
CONFIG_GENERAL, CONFIG_ONE_PAIR, CONFIG_ALL = "general", "one_axis_pair_parallel", "all_axes_parallel"


#: Index pairs of the symmetric relative cross-axis terms ``k = (K_xy, K_yz, K_zx)`` (:func:`cross_matrix`).
CROSS_AXIS_PAIRS = ((0, 1), (1, 2), (2, 0))


def cross_matrix(k) -> np.ndarray:
    """The symmetric, zero-diagonal matrix ``K`` of the relative cross-axis terms ``k = (K_xy, K_yz, K_zx)``."""
    K = np.zeros((3, 3))
    for m, (i, j) in enumerate(CROSS_AXIS_PAIRS):
        K[i, j] = K[j, i] = k[m]
    return K


def A_of(R, s1, s2, k=None) -> np.ndarray:
    """``A = S_1 R S_2^-1`` (Eq. 4), or the full linear map ``(I + K) S_1 R S_2^-1`` with the symmetric relative
    cross-axis terms ``k`` (:mod:`~fusion_gyrocal.core.linear_map`)."""
    A = (np.asarray(s1)[:, None] * R) / np.asarray(s2)[None, :]
    return A if k is None else (np.eye(3) + cross_matrix(k)) @ A


def dA_dp(R, s1, s2, k=None) -> np.ndarray:
    """Derivatives (9, 3, 3) of A w.r.t. ``[dtheta, log s_1, log s_2]`` at ``(R, s1, s2)``; (12, 3, 3) with the
    cross-axis terms ``k`` appended (``A = (I + K) S_1 Exp(dtheta) R S_2^-1``)."""
    B = A_of(R, s1, s2)
    D = np.empty((9 if k is None else 12, 3, 3))
    for m in range(3):
        e = np.zeros(3)
        e[m] = 1.0
        D[m] = (s1[:, None] * (skew(e) @ R)) / s2[None, :]
        if k is not None:
            D[9 + m] = cross_matrix(e) @ B
    for i in range(3):
        D[3 + i] = 0.0
        D[3 + i][i, :] = B[i, :]
        D[6 + i] = 0.0
        D[6 + i][:, i] = -B[:, i]
    if k is not None:
        D[:9] = np.einsum("ij,pjk->pik", np.eye(3) + cross_matrix(k), D[:9])
    return D


def residual_weight(A, noise_std) -> np.ndarray:
    """``W = (sigma_1^2 I + sigma_2^2 A A^T)^-1``: the per-sample residual information."""
    s1, s2 = noise_std
    return np.linalg.inv(s1**2 * np.eye(3) + s2**2 * A @ A.T)


def signal_scatter(moments: Moments, noise_std) -> tuple[np.ndarray, np.ndarray]:
    """Noise-corrected centred scatters of the two gyros' signals (clipped to be PSD)."""
    out = []
    for block, sig in ((moments.S11, noise_std[0]), (moments.S22, noise_std[1])):
        X = block - moments.dof * sig**2 * np.eye(3)
        w, V = np.linalg.eigh(0.5 * (X + X.T))
        out.append((V * np.clip(w, 0.0, None)) @ V.T)
    return out[0], out[1]


def fisher_information(R, s1, s2, noise_std, Xi_c, k=None) -> np.ndarray:
    """Fisher information (9, 9) of ``[dtheta, log s_1, log s_2]`` with the bias profiled out; (12, 12) with the
    cross-axis terms ``k`` of the full linear map appended.

    Parameters
    ----------
    R, s1, s2 : the calibration at which to evaluate.
    noise_std : (sigma_1, sigma_2) per-sample noise (rad/s).
    Xi_c : (3, 3) centred scatter of gyro 2's signal (see :func:`signal_scatter`).
    k : (3,) relative cross-axis terms, optional (:func:`cross_matrix`).
    """
    return information_of_A(A_of(R, s1, s2, k), dA_dp(R, s1, s2, k), noise_std, Xi_c)


def information_of_A(A, D, noise_std, Xi_c) -> np.ndarray:
    """:func:`fisher_information` of a map ``A`` whose derivatives w.r.t. its parameters are ``D`` (p, 3, 3)."""
    W = residual_weight(A, noise_std)
    WDX = np.einsum("ij,qjk,kl->qil", W, D, Xi_c)
    return np.einsum("pab,qab->pq", D, WDX)  # tr(D_p^T W D_q Xi_c)


@dataclass(frozen=True)
class Configuration:
    """Structure of the pair: class, parallel axis pairs and the groups of linked scale factors.

    ``groups`` are tuples of ``(gyro, axis)`` (gyro 0 = gyro 1) whose ratios the data determine;
    scale factors in a group of fewer than four are determined only as a ratio.
    """

    name: str
    parallel_pairs: tuple  # ((axis of gyro 1, axis of gyro 2, angle_deg), ...)
    groups: tuple

    @property
    def scale_observable(self) -> np.ndarray:
        obs = np.zeros((2, 3), dtype=bool)
        for g in self.groups:
            if len(g) >= 4:
                for gyro, axis in g:
                    obs[gyro, axis] = True
        return obs


def _angle(c) -> float:
    return float(np.rad2deg(np.arccos(min(1.0, c))))


def _configuration(R, n_pairs: int) -> Configuration:
    """The configuration with the ``n_pairs`` (0, 1 or 3) most nearly parallel axis pairs of ``R``."""
    C = np.abs(np.asarray(R, dtype=float))
    everyone = tuple((g, a) for g in (0, 1) for a in range(3))
    if n_pairs == 0:
        return Configuration(CONFIG_GENERAL, (), (everyone,))
    if n_pairs == 1:
        i, j = np.unravel_index(int(np.argmax(C)), C.shape)
        pair = ((0, int(i)), (1, int(j)))
        rest = tuple(m for m in everyone if m not in pair)
        return Configuration(CONFIG_ONE_PAIR, ((int(i), int(j), _angle(C[i, j])),), (rest, pair))
    # two near-parallel pairs force the third (R is orthogonal); use the full signed permutation
    perm = np.argmax(C, axis=1)
    if len(set(perm.tolist())) != 3:
        raise ConfigurationError(f"R_1_2 is not close to a signed permutation although two axes are parallel: {R}")
    pairs = tuple((i, int(perm[i]), _angle(C[i, perm[i]])) for i in range(3))
    return Configuration(CONFIG_ALL, pairs, tuple(((0, i), (1, int(perm[i]))) for i in range(3)))


def classify(R, parallel_tol_deg: float = 5.0) -> Configuration:
    """Classify the configuration of a pair from its rotation (Lemmas 2-4).

    An axis of gyro 1 and an axis of gyro 2 within ``parallel_tol_deg`` of (anti)parallel are
    treated as parallel: there the decomposition of A into scale factors is ill-conditioned
    (a model error ``e`` such as skew becomes a scale error ``~ e / sin(angle)``), so the
    scale factors of that pair are reported as a ratio only.
    """
    C = np.abs(np.asarray(R))
    n = int(np.sum(C.max(axis=1) >= np.cos(np.deg2rad(parallel_tol_deg))))
    return _configuration(R, n if n < 2 else 3)


def parallel_tilt_bias(A, R, s1, s2, config: Configuration, rotation_variance) -> np.ndarray:
    """Rotation bias per axis of gyro 1 (rad, >= 0) of the paper's model ``A = S_1 R S_2^-1`` on an
    ``all_axes_parallel`` pair: what the unknown ratios of the axes' common scale factors do to the tilt.

    With every axis parallel (Lemma 2) only each axis's ratio ``s_1 / s_2`` is determined; the common factor
    ``c_i`` of each axis is set by the gauge. Write ``R = Exp(theta) P`` (``P`` the signed permutation of the
    parallel axes, ``theta`` the tilt) and ``delta = log(c_i / c_j)`` for the gauge's error between two axes:
    ``G = S_1^-1 A S_2 P^T`` is then ``C Exp(theta) C^-1``, so about the third axis ``k`` the fit's tilt is
    ``theta' = theta cosh(delta)`` (the antisymmetric part of ``G``) and the symmetric part left unexplained is
    ``e = -theta sinh(delta)`` (to first order in the tilt; ``e`` is read from ``G Exp(theta')^T``, which holds
    none of the tilt's own second-order terms). The tilt is overstated by ``theta' - sqrt(theta'^2 - e^2)``
    (``~ theta delta^2 / 2``: second order, but not averaged away by more samples). ``e^2`` is taken above its
    noise (``rotation_variance``, the variances of the rotation about each axis, which ``e`` shares), so a pair
    that is exactly parallel, or whose axes share one factor, gets nothing. Other configurations: zeros.

    Parameters
    ----------
    A : ndarray (3, 3)
        The least-squares estimate of ``A`` (Eq. 17).
    R, s1, s2 : ndarray
        The rigid model's fit (gauge-fixed scale factors).
    config : Configuration
    rotation_variance : ndarray (3,)
        Variance of the rotation about each axis of gyro 1 (rad^2).
    """
    if config.name != CONFIG_ALL:
        return np.zeros(3)
    P = np.zeros((3, 3))
    for i, j, _ in config.parallel_pairs:
        P[i, j] = np.sign(R[i, j])
    if abs(abs(np.linalg.det(P)) - 1.0) > 1e-9:
        return np.zeros(3)
    from ..lie import log

    G = (np.asarray(A, dtype=float) * (np.asarray(s2, dtype=float)[None, :] / np.asarray(s1, dtype=float)[:, None])) @ P.T
    Q = np.asarray(R, dtype=float) @ P.T               # the fit's tilt Exp(theta')
    theta = log(Q)
    E = G @ Q.T                                        # the misfit relative to it (the tilt's own terms removed)
    sym = 0.5 * np.array([E[2, 1] + E[1, 2], E[0, 2] + E[2, 0], E[1, 0] + E[0, 1]])
    e2 = np.clip(sym ** 2 - np.asarray(rotation_variance, dtype=float), 0.0, None)
    return np.abs(theta) - np.sqrt(np.clip(theta ** 2 - e2, 0.0, None))


def seed_configuration(R, name: str, parallel_tol_deg: float | None = None) -> Configuration:
    """The configuration of a seed calibration (rotation ``R``, class ``name``) for the trackers built on it.

    Without a tolerance the seed's class is kept as its solver decided it, with the most nearly
    parallel axis pairs of ``R``. With one, ``classify(R, parallel_tol_deg)`` must give that class.

    Raises
    ------
    ConfigurationError
        ``name`` is no configuration class, or ``R`` does not classify as ``name`` at the tolerance.
    """
    if name not in (CONFIG_GENERAL, CONFIG_ONE_PAIR, CONFIG_ALL):
        raise ConfigurationError(f"configuration: expected one of {(CONFIG_GENERAL, CONFIG_ONE_PAIR, CONFIG_ALL)}, "
                                 f"got {name!r}")
    if parallel_tol_deg is None:
        return _configuration(R, {CONFIG_GENERAL: 0, CONFIG_ONE_PAIR: 1, CONFIG_ALL: 3}[name])
    config = classify(R, parallel_tol_deg)
    if config.name != name:
        raise ConfigurationError(f"seed: its configuration is {name!r} but its R_1_2 classifies as {config.name!r} at "
                                 f"parallel_tol_deg={parallel_tol_deg:g}; pass the tolerance the seed was solved with "
                                 "(or none, to keep the seed's class)")
    return config


#: A Gaussian prior N(1, std^2) on every scale factor, along the one direction of a group of linked scale factors
#: that the data leave free (a common factor), is at its maximum where the group's unit convention holds
#: (``argmin_c sum (c s - 1)^2``, Eq. 32-34): the gauge of every member of every group.
PRIOR_GAUGE = Gauge(tuple((g, a) for g in (0, 1) for a in range(3)))


def prior_held_covariance(F, groups, s1, s2, prior_std: float) -> np.ndarray:
    """Covariance (9, 9) of ``[dtheta, log s_1, log s_2]`` when a scale prior holds what the data leave free.

    The data (information ``F``) determine everything but one common factor per group of linked scale
    factors (Theorem 2 and Lemmas 2-4: the global scale, and each parallel axis pair's common factor).
    A Gaussian prior N(1, ``prior_std``^2) on every scale factor acts only along those directions:
    the determined part is ``F`` inverted inside :data:`PRIOR_GAUGE`'s tangent space, and each group's
    common log-factor ``c`` adds the prior's variance ``prior_std^2 / sum_m s_m^2`` along the group's null
    direction (``d log s_m = dc`` for its members), independent of the data. The sum of two PSD parts,
    so PSD for any ``prior_std``.

    Parameters
    ----------
    F : ndarray (9, 9)
        Fisher information of the data (:func:`fisher_information`).
    groups : tuple
        Groups of linked scale factors (:attr:`Configuration.groups`).
    s1, s2 : ndarray (3,)
        Scale factors at which to evaluate (in :data:`PRIOR_GAUGE`).
    prior_std : float
        The prior's standard deviation of each scale factor.
    """
    s = np.stack([np.asarray(s1, float), np.asarray(s2, float)])
    C = PRIOR_GAUGE.constraints(groups, s, 3)
    C = np.hstack([C, np.zeros((len(C), F.shape[0] - 9))])     # cross-axis terms (full map): not a gauge's
    P = constrained_inverse(F, C)
    N = np.zeros((F.shape[0], len(groups)))
    N[3:9] = null_directions(groups, 2)
    information = (N[3:9] * s.reshape(6, 1) ** 2).sum(axis=0) / prior_std**2
    P = P + (N / information) @ N.T
    return 0.5 * (P + P.T)


def per_axis_snr(moments: Moments, noise_std) -> np.ndarray:
    """Per-axis SNR of gyro 1's centred signal: ``sqrt(sum omega_i^2) / sigma`` (Eq. 36 per axis)."""
    X1, _ = signal_scatter(moments, noise_std)
    sigma = float(np.hypot(*noise_std))
    return np.sqrt(np.clip(np.diag(X1), 0.0, None)) / sigma


def check_samples(moments: Moments) -> None:
    """Raise :class:`InputError` for fewer than 4 samples, a constant stream (Lemma 1) or rates too large for float64.

    Moments of finite samples are finite unless the squares of the rates overflow; such values
    (beyond ~1e154) are no angular rates in rad/s.
    """
    if moments.count < 4:
        raise InputError(f"expected at least 4 samples (Lemma 1), got {int(moments.count)}")
    for name, sl in (("omega_1", slice(0, 3)), ("omega_2", slice(3, 6))):
        block = moments.scatter[sl, sl]
        if not (np.isfinite(moments.mean[sl]).all() and np.isfinite(block).all()):
            raise InputError(f"{name}: expected angular rates in rad/s, got moments that overflow float64 (mean "
                             f"{moments.mean[sl].tolist()}, scatter trace {np.trace(block):.3g}); convert the rates to "
                             "rad/s first")
    for name, block in (("omega_1", moments.S11), ("omega_2", moments.S22)):
        if np.trace(block) == 0.0:
            raise InputError(f"{name}: constant input (every sample identical); the calibration needs rotation "
                             "about all three axes")


def explained_scatter(moments: Moments) -> np.ndarray:
    """Scatter of gyro 1 explained by gyro 2: ``E = S_12 S_22^-1 S_21`` (centred or pooled, gyro 1's frame).

    ``E = S_11 - M`` with ``M`` the residual scatter of the least-squares ``A`` (Eq. 15-17). The two
    gyros' noises are independent, so along a direction of gyro 1 that does not move ``E`` holds
    only the noise gyro 2's regressors fit by chance, ``~ sigma_1^2 chi2(3)`` however many samples
    there are; along a moving direction it holds the motion (attenuated where gyro 2's noise
    per sample exceeds the motion). Unlike ``S_11 - N sigma_1^2`` it does not hinge on the noise level
    being known to a fraction of ``1 / sqrt(N)``.
    """
    S12, S22 = moments.S12, moments.S22
    try:
        E = S12 @ np.linalg.solve(S22, S12.T)
    except np.linalg.LinAlgError:
        E = S12 @ np.linalg.pinv(S22, hermitian=True) @ S12.T
    return 0.5 * (E + E.T)


#: Smallest ratio of gyro 2's motion power to its noise power per sample along any direction (errors in
#: variables: below it the least-squares A is attenuated by more than a third and the likelihood is not quadratic).
MIN_SIGNAL_POWER = 0.5


def check_excitation(moments: Moments, noise_std, min_snr: float = 10.0) -> None:
    """Raise :class:`ExcitationError` unless the motion spans all three axes (Lemma 1).

    The scatter of gyro 1 that gyro 2 explains (:func:`explained_scatter`) is decomposed into
    principal directions; any direction whose SNR (``sqrt(eigenvalue) / sigma``, ``sigma^2 =
    sigma_1^2 + sigma_2^2``, Eq. 36 per direction) is below ``min_snr`` makes A (and the rotation
    about the other axes' cross products) undetermined. A direction along which only noise moves
    has an SNR of about ``sqrt(3) sigma_1 / sigma`` whatever the length of the log and however
    roughly the noise is estimated; a moving one has the paper's SNR (less where gyro 2's noise per
    sample exceeds the motion along it). The reported per-axis SNR (:func:`per_axis_snr`) keeps the
    paper's definition. Every direction of gyro 2's motion must also carry at least
    :data:`MIN_SIGNAL_POWER` times the noise power per sample.
    """
    check_samples(moments)
    E = explained_scatter(moments)
    w, V = np.linalg.eigh(E)
    sigma = float(np.hypot(*noise_std))
    snr_dir = np.sqrt(np.clip(w, 0.0, None)) / sigma
    weak = [k for k in range(3) if snr_dir[k] < min_snr]
    if weak:
        snr_axes = np.sqrt(np.clip(np.diag(E), 0.0, None)) / sigma
        parts = []
        for k in weak:
            v = V[:, k] * np.sign(V[np.argmax(np.abs(V[:, k])), k])
            axis = AXES[int(np.argmax(np.abs(v)))]
            parts.append(f"direction {np.round(v, 2).tolist()} (mostly {axis}) has SNR {snr_dir[k]:.3g}")
        msg = "; ".join(parts)
        # axes to add: those within 45 deg of the weak subspace, and the main axis of each weak direction
        reach = np.linalg.norm(V[:, weak], axis=1)
        axes = sorted({AXES[i] for i in range(3) if reach[i] >= np.sqrt(0.5)}
                      | {AXES[int(np.argmax(np.abs(V[:, k])))] for k in weak})
        raise ExcitationError(
            f"too little motion to calibrate: {msg} (need >= {min_snr:g}; per-axis SNR of gyro 1's motion "
            f"that gyro 2 explains: x={snr_axes[0]:.3g}, y={snr_axes[1]:.3g}, z={snr_axes[2]:.3g}). Rotate the "
            f"device about its {' and '.join(axes)} axis/axes as well, or record longer."
        )
    # the regressor: where gyro 2's motion is below its noise per sample, least squares attenuate A and the
    # likelihood is far from quadratic (the Fisher covariance then under-states the error many times over)
    noise_power = moments.dof * float(noise_std[1]) ** 2
    w2, V2 = np.linalg.eigh(moments.S22)
    power = w2 / max(noise_power, 1e-300) - 1.0
    if power.min() < MIN_SIGNAL_POWER:
        k = int(np.argmin(power))
        v = V2[:, k] * np.sign(V2[np.argmax(np.abs(V2[:, k])), k])
        axis = AXES[int(np.argmax(np.abs(v)))]
        raise ExcitationError(
            f"too little motion to calibrate: along direction {np.round(v, 2).tolist()} (mostly {axis}) of gyro 2 "
            f"the motion's power is {max(power[k], 0.0):.2g}x its noise's per sample (need >= {MIN_SIGNAL_POWER:g}): "
            f"the noise in the regressor biases the estimate and its covariance there. Rotate the device faster "
            f"about its {axis} axis.")


@dataclass(frozen=True)
class Bound:
    """Cramer-Rao bound of a calibration problem in the paper's error metrics (Eq. 37-38).

    Attributes
    ----------
    rotation_rmse : float
        ``sqrt(trace(P_rot))``: the bound on the RMSE of ``||Log(R_hat R^T)||`` (rad).
    scale_rmse : float
        Bound on the RMSE of the paper's scale error (Eq. 38), gauge invariant.
    covariance : ndarray (9, 9)
        Bound on the covariance of ``[dtheta, log s_1, log s_2]`` in the gauge ``log s_1[0] = 0``
        (or with the prior, when one is given).
    """

    rotation_rmse: float
    scale_rmse: float
    covariance: np.ndarray


def cramer_rao_bound(R, s1, s2, noise_std, signal_2, *, scale_prior_std=None) -> Bound:
    """Cramer-Rao bound for the pair model (Appendix B generalised to scales and biases).

    Parameters
    ----------
    R, s1, s2 : true rotation and scale factors.
    noise_std : (sigma_1, sigma_2) white noise per sample (rad/s).
    signal_2 : (N, 3) array or (3, 3) matrix
        The true gyro-2 signal ``S_2 omega_2`` (noise-free, rad/s) as samples, or its centred
        scatter; the bias is profiled out, so only its variation matters.
    scale_prior_std : float, optional
        Gaussian prior N(1, std^2) on every scale factor, acting only along the directions the data
        leave free in the configuration of ``R`` (:func:`classify`, :func:`prior_held_covariance`), as
        :func:`fusion_gyrocal.solve` applies it; then the bound is the Bayesian one.
    """
    sig = np.asarray(signal_2, dtype=float)
    if sig.shape != (3, 3):
        c = sig - sig.mean(axis=0)
        sig = c.T @ c
    s1, s2 = np.asarray(s1, float), np.asarray(s2, float)
    F = fisher_information(np.asarray(R, float), s1, s2, tuple(noise_std), sig)
    if scale_prior_std is not None:
        P = prior_held_covariance(F, classify(R).groups, s1, s2, scale_prior_std)
    else:
        keep = [0, 1, 2, 4, 5, 6, 7, 8]  # gauge log s_1[0] = 0 (the paper's normalisation)
        P = np.zeros((9, 9))
        P[np.ix_(keep, keep)] = np.linalg.inv(F[np.ix_(keep, keep)])
    s = np.concatenate([s1, s2])
    J = np.zeros((6, 9))  # e_k = (s_k / s_1x)(dlog s_k - dlog s_1x), Eq. (38) linearised
    for k in range(6):
        J[k, 3 + k] += s[k] / s[0]
        J[k, 3] -= s[k] / s[0]
    return Bound(float(np.sqrt(np.trace(P[:3, :3]))), float(np.sqrt(np.trace(J @ P @ J.T) / 5.0)), P)
