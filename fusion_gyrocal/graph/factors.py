"""GTSAM factors of the gyro-pair calibration: window moments, the gauge, rotation increments.

Each factor is a ``gtsam.CustomFactor`` whose error function is a plain function bound with
:func:`functools.partial`; Jacobians are filled only when GTSAM asks for them, and the tests check
them against numerical derivatives. Perturbations follow GTSAM: ``R.retract(d) = R Exp(d)`` for the
``gtsam.Rot3`` ``R_1_2``, additive for vectors.

Gyro-pair window factor
-----------------------
For window ``w`` with moments ``(n_w, m_w = [m_1; m_2], Sc_w)`` (:mod:`fusion_gyrocal.core.moments`),
``A = S_1 R_1_2 S_2^-1`` (Eq. 4) and the errors-in-variables weight
``W(A) = (sigma_1^2 I + sigma_2^2 A A^T)^-1``, the per-sample cost of Eq. (8),
``sum_k r_k^T W(A) r_k`` with ``r_k = omega_1(k) - A omega_2(k) - b_w``, equals exactly (the
centring of Eq. 12-15, with the bias kept as a variable)::

    ||V [I, -A] L_w||_F^2  +  n_w ||V (m_1 - A m_2 - b_w)||^2,   Sc_w = L_w L_w^T,  V^T V = W(A)

so each window is one fixed-size factor with a 21-dimensional residual (18 + 3), whatever
``n_w``: a million samples cost no more than a few hundred factors. ``W`` is evaluated at the
current ``A`` (``V`` the inverse Cholesky factor of ``W^-1``) and differentiated analytically, so
the graph minimises the same profiled likelihood as the batch maximum-likelihood refinement
(:mod:`fusion_gyrocal.core.refine`) and agrees with it on the same data.

Gauge factor
------------
One tight prior per linked group of scale factors on the condition of
:class:`~fusion_gyrocal.core.gauge.Gauge` (Theorem 2, Eq. 32-34).

Rotation-increment (camera) factor
----------------------------------
The pair alone cannot fix the global scale (Theorem 2). An external orientation increment
``dR_cam`` between two keyframes compared with gyro 1's preintegrated rate
(:mod:`fusion_gyrocal.graph.preintegration`) fixes the absolute ``scale_1`` (and through the pair
factors ``scale_2``): the residual is ``Log(dR_cam^T dR_hat Exp(J_s dlog_s + J_b db_1))`` on the
global log-scale ``g``, the relative log-scales and gyro 1's bias ``b_1``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from ..core.gauge import Gauge
from ..extras import require

gtsam = require("gtsam", "graph", "the factor-graph calibration (calibrate_pair_graph)")
from ..core.moments import Moments
from ..core.observability import A_of, dA_dp
from ..errors import InputError
from .preintegration import PreintegratedRotations

__all__ = ["WindowStatistics", "gyro_pair_factor", "gauge_factor", "rotation_increment_factor"]


# ---------------------------------------------------------------------------------------------- pair factor
@dataclass(frozen=True)
class WindowStatistics:
    """One window's moments in factor form: ``sqrt(n)``, the means and a square root of the scatter.

    ``L = [L_1; L_2]`` (6, 6) satisfies ``L L^T = Sc`` (centred scatter of ``[omega_1; omega_2]``);
    any square root gives the same cost (an eigen-decomposition is used, so a merely
    semi-definite scatter is fine).
    """

    count: float
    mean_1: np.ndarray
    mean_2: np.ndarray
    L_1: np.ndarray
    L_2: np.ndarray

    @classmethod
    def from_moments(cls, moments: Moments) -> "WindowStatistics":
        if moments.count < 2:
            raise InputError(f"window moments: expected at least 2 samples, got {moments.count:g}")
        w, V = np.linalg.eigh(0.5 * (moments.scatter + moments.scatter.T))
        L = V * np.sqrt(np.clip(w, 0.0, None))[None, :]
        return cls(float(moments.count), moments.mean_1.copy(), moments.mean_2.copy(), L[:3].copy(), L[3:].copy())

    def cost(self, A, bias) -> float:
        """Unweighted sum of squared residuals ``sum_k ||omega_1 - A omega_2 - b||^2`` of the window."""
        E = self.L_1 - A @ self.L_2
        r = self.mean_1 - A @ self.mean_2 - bias
        return float(np.sum(E * E) + self.count * (r @ r))


def _pair_residual(R, log_scale, bias, stats: WindowStatistics, noise_std, jacobians: bool):
    """Whitened 21-residual of one window and (optionally) its Jacobians w.r.t. (R, log-scale, bias).

    ``Sigma(A) = sigma_1^2 I + sigma_2^2 A A^T = C C^T`` (Cholesky), ``V = C^-1``; residual
    ``[vec(V [I, -A] L), sqrt(n) V (m_1 - A m_2 - b)]``, so ``||e||^2 = tr(W(A) M(A)) + n r^T W(A) r``
    with ``W(A) = Sigma(A)^-1``: the profiled errors-in-variables likelihood (the same cost as
    :func:`fusion_gyrocal.core.refine.ml_cost`, plus the window's mean term).

    Perturbations: ``R Exp(d)`` (GTSAM's Rot3 retraction), ``log_scale + e``, ``bias + beta``;
    ``dA = S_1 R [d x] S_2^-1``, ``diag(e_1) A`` and ``-A diag(e_2)``. The weight's derivative uses
    the Cholesky differential ``dV = -Phi(V dSigma V^T) V`` (``Phi``: lower triangle, halved diagonal).
    """
    s1, s2 = np.exp(log_scale[:3]), np.exp(log_scale[3:])
    sig1, sig2 = noise_std
    A = A_of(R, s1, s2)
    Sigma = sig1**2 * np.eye(3) + sig2**2 * (A @ A.T)
    V = np.linalg.inv(np.linalg.cholesky(Sigma))
    E = V @ (stats.L_1 - A @ stats.L_2)                         # (3, 6)
    sqn = np.sqrt(stats.count)
    em = sqn * (V @ (stats.mean_1 - A @ stats.mean_2 - bias))
    e = np.concatenate([E.T.reshape(-1), em])
    if not jacobians:
        return e, None
    dA = dA_dp(R, s1, s2)                                        # left perturbation Exp(dtheta) R
    dA[:3] = np.einsum("nm,nij->mij", R, dA[:3])                 # right: R [d x] = [R d x] R, dtheta = R d
    dAAt = dA @ A.T
    X = V @ (sig2**2 * (dAAt + np.swapaxes(dAAt, 1, 2))) @ V.T
    Phi = np.tril(X)
    Phi[:, [0, 1, 2], [0, 1, 2]] *= 0.5
    VdA = V @ dA
    dE = -Phi @ E - VdA @ stats.L_2                              # (9, 3, 6)
    dem = -Phi @ em - sqn * (VdA @ stats.mean_2)                 # (9, 3)
    H = np.empty((21, 9))
    H[:18] = np.swapaxes(dE, 1, 2).reshape(9, 18).T
    H[18:] = dem.T
    H_b = np.zeros((21, 3))
    H_b[18:] = -sqn * V
    return e, [H[:, :3].copy(), H[:, 3:].copy(), H_b]


def _pair_error(stats, noise_std, this, values, H):
    keys = this.keys()
    e, J = _pair_residual(values.atRot3(keys[0]).matrix(), values.atVector(keys[1]), values.atVector(keys[2]),
                          stats, noise_std, H is not None)
    if H is not None:
        H[0], H[1], H[2] = J
    return e


def gyro_pair_factor(moments: Moments | WindowStatistics, noise_std, *, rotation_key: int, log_scale_key: int,
                     bias_key: int) -> gtsam.CustomFactor:
    """One window of gyro-pair samples as a single 21-dimensional GTSAM factor.

    Parameters
    ----------
    moments : Moments or WindowStatistics
        The window's sufficient statistics (one bias segment).
    noise_std : (float, float)
        White-noise standard deviation per sample of gyro 1 and gyro 2 (rad/s).
    rotation_key, log_scale_key, bias_key : int
        Keys of ``R_1_2`` (Rot3), ``[log scale_1, log scale_2]`` (6-vector) and the window's combined
        bias (3-vector).

    Returns
    -------
    gtsam.CustomFactor
        Unit noise model (the weight is inside the residual). ``0.5 * ||residual||^2`` equals
        ``0.5 * sum_k (omega_1 - A omega_2 - b)^T W(A) (omega_1 - A omega_2 - b)`` over the window
        (Eq. 8 with the errors-in-variables weight ``W(A) = (sigma_1^2 I + sigma_2^2 A A^T)^-1``),
        computed from the moments alone. Jacobians are analytic, including the weight's dependence on A.
    """
    stats = moments if isinstance(moments, WindowStatistics) else WindowStatistics.from_moments(moments)
    sig = np.broadcast_to(np.asarray(noise_std, dtype=float), (2,))
    if not np.all(np.isfinite(sig)) or np.any(sig <= 0):
        raise InputError(f"noise_std: expected two positive finite standard deviations (rad/s), got {noise_std}")
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(21), [rotation_key, log_scale_key, bias_key],
                              partial(_pair_error, stats, (float(sig[0]), float(sig[1]))))


def _gauge_error(gauge, group, this, values, H):
    s = np.exp(values.atVector(this.keys()[0])).reshape(-1, 3)
    if H is not None:
        H[0] = gauge.constraints([group], s)
    return gauge.condition([group], s)


def gauge_factor(gauge: Gauge, group, sigma: float, *, log_scale_key: int) -> gtsam.CustomFactor:
    """A tight prior imposing ``gauge``'s condition on one linked group of scale factors (Theorem 2).

    The condition is the one :meth:`Gauge.apply` imposes (:meth:`Gauge.condition`), its Jacobian the
    group's row of :meth:`Gauge.constraints`, so the graph and the batch refinement solve the same
    constrained problem.

    Parameters
    ----------
    gauge : Gauge
    group : tuple of (gyro, axis)
        One linked group of :attr:`~fusion_gyrocal.core.observability.Configuration.groups`.
    sigma : float
        Standard deviation of the condition's value.
    log_scale_key : int
        Key of ``[log scale_1, log scale_2]`` (6-vector).
    """
    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, sigma), [log_scale_key],
                              partial(_gauge_error, gauge, tuple(group)))


# ---------------------------------------------------------------------------------------------- camera factor
def _increment_residual(g, log_scale, bias_1, delta_R_meas, delta_R, J_s, J_b, ls_lin, b_lin, jacobians: bool):
    """``Log(dR_meas^T dR_hat Exp(xi))`` with ``xi = J_s (g + l_1 - ls_lin) + J_b (b_1 - b_lin)``."""
    xi = J_s @ (g + log_scale[:3] - ls_lin) + J_b @ (bias_1 - b_lin)
    E = gtsam.Rot3(delta_R_meas.T @ delta_R) * gtsam.Rot3.Expmap(xi)
    e = gtsam.Rot3.Logmap(E)
    if not jacobians:
        return e, None
    Jx = gtsam.Rot3.LogmapDerivative(e) @ gtsam.Rot3.ExpmapDerivative(xi)
    JxS = Jx @ J_s
    H_l = np.zeros((3, 6))
    H_l[:, :3] = JxS
    return e, [JxS.sum(axis=1, keepdims=True), H_l, Jx @ J_b]


def _increment_error(delta_R_meas, delta_R, J_s, J_b, ls_lin, b_lin, this, values, H):
    keys = this.keys()
    e, J = _increment_residual(values.atVector(keys[0])[0], values.atVector(keys[1]), values.atVector(keys[2]),
                               delta_R_meas, delta_R, J_s, J_b, ls_lin, b_lin, H is not None)
    if H is not None:
        H[0], H[1], H[2] = J
    return e


def rotation_increment_factor(preintegrated: PreintegratedRotations, k: int, delta_R_meas, sigma_rad: float, *,
                              global_scale_key: int, log_scale_key: int, bias_1_key: int) -> gtsam.CustomFactor:
    """Factor tying gyro 1's integrated, scaled rate over interval ``k`` to a measured increment.

    Parameters
    ----------
    preintegrated : PreintegratedRotations
        Output of :func:`~fusion_gyrocal.graph.preintegration.preintegrate_rotations`.
    k : int
        Which interval.
    delta_R_meas : array_like (3, 3)
        The measured increment in gyro 1's frame (``RotationIncrements.in_gyro_frame()[k]``).
    sigma_rad : float
        Standard deviation per axis of the residual (measurement and integrated gyro noise).
    global_scale_key, log_scale_key, bias_1_key : int
        Keys of ``g`` (1-vector), ``[log scale_1, log scale_2]`` (6-vector) and ``b_1`` (3-vector);
        the absolute log-scale of gyro 1 is ``g + log scale_1``.
    """
    p = preintegrated
    return gtsam.CustomFactor(
        gtsam.noiseModel.Isotropic.Sigma(3, float(sigma_rad)), [global_scale_key, log_scale_key, bias_1_key],
        partial(_increment_error, np.array(delta_R_meas, float), p.delta_R[k].copy(), p.J_scale[k].copy(),
                p.J_bias[k].copy(), p.log_scale_1.copy(), p.bias_1.copy()))
