"""The full linear map: rotation, scale factors and the relative cross-axis terms of real MEMS gyros.

The paper's model ``A = S_1 R S_2^-1`` (Eq. 4) assumes the manufacturer removed each gyro's cross-axis
sensitivity. Real MEMS gyros keep 1-2 % of it (datasheets): gyro i measures ``(I + K_i) S_i omega_i`` with
``K_i`` off-diagonal, so, to first order in the ``K_i``,

    A = (I + K_1) S_1 R S_2^-1 (I + K_2)^-1 = (I + K) S_1 R' S_2^-1,

where ``K`` is the symmetric part of the relative cross-axis terms ``K_1 - A K_2 A^-1`` (gyro 1's axes) and
``R' = Exp(a) R`` takes up their antisymmetric part ``a`` as a small rotation. ``K`` acts after the scale factors,
so the scale factors keep the paper's symmetries (Theorem 2, Lemmas 2-3: the common factor of a parallel axis
pair is still free). No data separate ``a`` from the rotation (Appendix D), so the estimate follows one
convention: **the relative cross-axis matrix is symmetric**; ``R_1_2`` is the rotation under it and
``k = (K_xy, K_yz, K_zx)`` (:func:`~fusion_gyrocal.core.observability.cross_matrix`) are the cross-axis terms. It is the stable choice: unique, independent of the order and signs of the axes (a
triangular convention is not), and with all axes parallel (the usual multi-IMU board) ``R_1_2`` is, up to the
scale factors, the rotation of the polar decomposition of ``A``, which every session of a board repeats whatever
its motion.

Parameters ``p = [dtheta (3), log s_1 (3), log s_2 (3), k (3)]``: the nine entries of ``A`` (Eq. 17) determine
all of them when every axis pair is parallel (three scale ratios, rotation, ``k``), all but two in the general
configuration (the paper's eight plus one combination of ``k``). A Gaussian prior ``N(0, cross_axis_std^2)`` on
each ``k`` (:class:`~fusion_gyrocal.options.Options`, a MEMS datasheet's cross-axis figure) holds what the data
leave, so the covariance of the rotation includes what the data cannot separate. The physical chip-to-chip
rotation differs from ``R_1_2`` by ``a``, which no data see: with the full map the rotation's covariance carries
:func:`cross_axis_budget` per axis for it (``skew_rotation_covariance``, Appendix D), which the difference of two
sessions of one board cancels.

A calibrated reference (``intrinsics_1`` given, ``intrinsics_2`` not): with gyro 1's intrinsic matrix known, the
nine entries of ``A = D_1 R S_2^-1`` determine the rotation and gyro 2's whole upper-triangular intrinsic matrix
``S_2`` (its scale factors and cross-axis terms; :func:`decompose_reference`, :func:`refine_reference`), in
absolute scale: a cheap gyro's intrinsic calibration against a good one, without a rate table. The triangular
convention is then gyro 2's own (its x axis and xy plane define its frame, as in Kalibr's and imucal's intrinsic
matrices), and the rotation is the physical one in it.

:func:`choose_full_map` decides from the data (the cross-axis chi-square of
:func:`~fusion_gyrocal.core.robust.cross_axis`) whether the full map is used (``linear_map="auto"``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..lie import exp, skew
from .moments import Moments
from .observability import cross_matrix, fisher_information, information_of_A, signal_scatter
from .refine import cost_of_A, fisher_scoring, gradient_of_A, ml_cost, ml_gradient, retract

#: 99.9 % points of the chi-square distribution with 1..9 degrees of freedom (the cross-axis test).
CHI2_999 = (10.83, 13.82, 16.27, 18.47, 20.52, 22.46, 24.32, 26.12, 27.88)


def choose_full_map(linear_map: str, method: str, cross_chi2: float, cross_dof: int) -> tuple[bool, bool]:
    """Whether the estimate uses the full linear map, and whether the data show cross-axis terms (the cross-axis
    chi-square of :func:`~fusion_gyrocal.core.robust.cross_axis` beyond its 99.9 % point).

    ``"full"`` always (``method="ml"``), ``"rigid"`` never; ``"auto"`` when the data show the terms, or when they
    determine all three (every axis pair parallel, ``cross_dof == 3``: the usual multi-IMU board). There the
    full map costs the rotation no precision (the cross-axis terms are the symmetric part of ``A R^T``, the rotation
    its antisymmetric part) and keeps terms too small to test from leaking into the rotation differently in
    every session.
    """
    shown = bool(cross_dof) and cross_chi2 > CHI2_999[cross_dof - 1]
    if method != "ml" or linear_map == "rigid":
        return False, shown
    return linear_map == "full" or shown or cross_dof == 3, shown


def prior_information(prior_std: float) -> np.ndarray:
    """Information (12, 12) of the prior ``N(0, prior_std^2)`` on each cross-axis term (zero elsewhere)."""
    F = np.zeros((12, 12))
    F[9:, 9:] = np.eye(3) / prior_std**2
    return F


def cross_axis_budget(k, cov_k, prior_std: float | None) -> float:
    """Variance per axis of the rotation the convention cannot see: the antisymmetric part of the relative
    cross-axis terms.

    Each gyro's cross-axis entries are as likely on either side of the diagonal, so the antisymmetric part of
    the relative terms is as large as their symmetric part ``k``. Its variance is estimated from the three
    ``k_m`` (their posterior second moments ``k_m^2 + Var k_m``: the data's where they determine ``k``, the prior's
    where they do not). Where the data show cross-axis terms (``prior_std`` given) they are pooled with the prior
    ``prior_std^2`` counted as three terms' worth: a variance from three numbers alone would often be far too small
    (``E[1 / chi2_3] = 1``) and the rotation's ``z^2`` heavy-tailed. Where the data show none (``prior_std`` None),
    the terms are within their own noise and so is the budget.
    """
    second = np.asarray(k) ** 2 + np.clip(np.diag(cov_k), 0.0, None)
    if prior_std is None:
        return float(second.mean())
    return float((3.0 * prior_std**2 + second.sum()) / 6.0)


@dataclass(frozen=True)
class FullMap:
    """The maximum a-posteriori full linear map (:func:`refine_full`)."""

    R: np.ndarray
    s1: np.ndarray
    s2: np.ndarray
    k: np.ndarray
    iterations: int
    converged: bool


def refine_full(moments: Moments, R, s1, s2, noise_std, prior_std: float, *, constraints, regauge,
                max_iter: int = 50, tol: float = 1e-11) -> FullMap:
    """Fisher scoring of the full map from the rigid estimate ``(R, s1, s2)`` with ``k = 0``.

    The cost is the errors-in-variables likelihood of :func:`~fusion_gyrocal.core.refine.ml_cost` with
    ``A = (I + K) S_1 R S_2^-1`` plus the prior ``|k|^2 / prior_std^2``; ``constraints(s1, s2)`` (k, 9) and
    ``regauge(s1, s2)`` are the gauge's, as in :func:`~fusion_gyrocal.core.refine.refine_ml`.
    """
    noise_std = tuple(float(x) for x in noise_std)
    _, Xi_c = signal_scatter(moments, noise_std)
    prior = prior_information(prior_std)

    def cost(x):
        return ml_cost(*x[:3], moments, noise_std, x[3]) + float(x[3] @ x[3]) / prior_std**2

    def gradient(x):
        g = ml_gradient(*x[:3], moments, noise_std, x[3])
        g[9:] += 2.0 * x[3] / prior_std**2
        return g

    def step(x, delta):
        R, s1, s2 = retract(x[0], x[1], x[2], delta[:9])
        return (R, *regauge(s1, s2), x[3] + delta[9:])

    def gauge(x):
        C = constraints(x[1], x[2])
        return np.hstack([C, np.zeros((len(C), 3))])

    (R, s1, s2, k), it, converged = fisher_scoring(
        (np.array(R, float), np.array(s1, float), np.array(s2, float), np.zeros(3)),
        cost=cost, gradient=gradient, information=lambda x: 2.0 * (fisher_information(*x[:3], noise_std, Xi_c, x[3])
                                                                    + prior),
        retract=step, constraints=gauge, max_iter=max_iter, tol=tol)
    return FullMap(R, s1, s2, k, it, converged)


# ---------------------------------------------------------------------------------------- a calibrated reference
#: The entries of an upper-triangular intrinsic matrix, in the order of its parameters and covariance.
UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def reference_map(R, S2, scale_1) -> np.ndarray:
    """``A = D_1 R S_2^-1``: gyro 1's skew compensated (``D_1`` its known scale factors), gyro 2's intrinsic matrix
    ``S_2`` upper triangular (its scale factors on the diagonal, its cross-axis terms above)."""
    return (np.asarray(scale_1)[:, None] * R) @ np.linalg.inv(S2)


def reference_derivatives(R, S2, scale_1) -> np.ndarray:
    """Derivatives (9, 3, 3) of :func:`reference_map` w.r.t. ``[dtheta (3), S_2's upper entries (6, UPPER)]``."""
    A = reference_map(R, S2, scale_1)
    S2_inv = np.linalg.inv(S2)
    D = np.empty((9, 3, 3))
    for m in range(3):
        D[m] = (np.asarray(scale_1)[:, None] * (skew(np.eye(3)[m]) @ R)) @ S2_inv
    for p, (a, b) in enumerate(UPPER):
        D[3 + p] = -np.outer(A[:, a], S2_inv[b])          # -A E_ab S_2^-1
    return D


def decompose_reference(A, scale_1) -> tuple[np.ndarray, np.ndarray]:
    """``(R, S_2)`` from ``A = D_1 R S_2^-1`` (Appendix D's structure): ``D_1^-1 A = R T`` is a QR decomposition
    with ``T = S_2^-1`` upper triangular with a positive diagonal (unique for ``det(A) > 0``)."""
    Q, T = np.linalg.qr(np.asarray(A, float) / np.asarray(scale_1)[:, None])
    sign = np.sign(np.diag(T))
    return Q * sign[None, :], np.linalg.inv(sign[:, None] * T)


def refine_reference(moments: Moments, R, S2, scale_1, noise_std, *, max_iter: int = 50,
                     tol: float = 1e-11) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """Maximum-likelihood ``(R, S_2)`` of :func:`reference_map` by Fisher scoring (the likelihood of
    :func:`~fusion_gyrocal.core.refine.cost_of_A`); no gauge: gyro 1's known scale factors fix the global scale."""
    noise_std = tuple(float(x) for x in noise_std)
    _, Xi_c = signal_scatter(moments, noise_std)

    def step(x, delta):
        S2 = x[1].copy()
        for p, (a, b) in enumerate(UPPER):
            S2[a, b] += delta[3 + p]
        return exp(delta[:3]) @ x[0], S2

    (R, S2), it, converged = fisher_scoring(
        (np.array(R, float), np.array(S2, float)),
        cost=lambda x: cost_of_A(reference_map(*x, scale_1), moments, noise_std),
        gradient=lambda x: gradient_of_A(reference_map(*x, scale_1), reference_derivatives(*x, scale_1), moments,
                                         noise_std),
        information=lambda x: 2.0 * information_of_A(reference_map(*x, scale_1), reference_derivatives(*x, scale_1),
                                                     noise_std, Xi_c),
        retract=step, max_iter=max_iter, tol=tol)
    return R, S2, it, converged


def hold_cross_axis(cal):
    """``(rigid, unmix)``: a calibration with the full linear map as one of the paper's model (rotation + scale
    factors, Eq. 4) on gyro 1's samples through ``unmix = (I + K)^-1``, its cross-axis terms held fixed.

    The chips' cross-axis sensitivity does not change, so an estimator that follows the rotation, the scale factors
    and the bias (the tracker, the factor graph) takes ``K`` from a full-map result and works on
    ``unmix omega_1 = S_1 R S_2^-1 omega_2 + unmix b``: its rotation stays in the same (symmetric) convention. The
    returned calibration drops the convention's skew budget (``skew_rotation_covariance``: constant) and has the
    bias ``unmix b``; :func:`restore_cross_axis` undoes both. A rigid calibration is returned as it is with
    ``unmix`` None; one with ``linear_map="reference"`` is refused.
    """
    import dataclasses

    from ..errors import ConfigurationError

    if cal.linear_map == "rigid":
        return cal, None
    if cal.linear_map != "full":
        raise ConfigurationError(
            f"calibration: expected the paper's model (rotation + scale factors, Eq. 4) or the full linear map, whose "
            f"cross-axis terms are held fixed; got linear_map {cal.linear_map!r} (gyro 2's intrinsics from gyro 1's): "
            "solve it with calibrate_pair(...) without intrinsics_1")
    unmix = np.linalg.inv(np.eye(3) + cross_matrix(cal.cross_axis_terms))
    cov = np.array(cal.covariance, dtype=float)
    cov[:3, :3] -= np.asarray(cal.skew_rotation_covariance)
    return dataclasses.replace(cal, linear_map="rigid", cross_axis_terms=np.zeros(3), bias=unmix @ cal.bias,
                               covariance=_bias_transformed(cov, unmix),
                               skew_rotation_covariance=np.zeros((3, 3))), unmix


def restore_cross_axis(rigid, held):
    """The result ``rigid`` of an estimator that worked on :func:`hold_cross_axis`'s samples, back in the full linear
    map of ``held`` (the full-map calibration whose cross-axis terms were held): ``K``, its covariance, the skew
    budget and the bias ``(I + K) b`` in gyro 1's own frame. ``rigid`` as it is when ``held`` is rigid."""
    import dataclasses

    if held.linear_map != "full":
        return rigid
    mix = np.eye(3) + cross_matrix(held.cross_axis_terms)
    cov = _bias_transformed(np.array(rigid.covariance, dtype=float), mix)
    cov[:3, :3] += np.asarray(held.skew_rotation_covariance)
    return dataclasses.replace(rigid, linear_map="full", cross_axis_terms=np.array(held.cross_axis_terms),
                               cross_axis_covariance=np.array(held.cross_axis_covariance), bias=mix @ rigid.bias,
                               covariance=cov, skew_rotation_covariance=np.array(held.skew_rotation_covariance),
                               notes=tuple(rigid.notes) + (
                                   "cross-axis terms held at those of the full-map calibration it started from "
                                   "(gyro 1's samples through (I + K)^-1; the bias here in gyro 1's own frame)",))


def _bias_transformed(cov, M) -> np.ndarray:
    """A (12, 12) covariance with its bias block taken through ``b -> M b`` (its finite rows and columns)."""
    J = np.eye(len(cov))
    J[9:12, 9:12] = M
    finite = np.isfinite(cov).all(axis=1)
    out = cov.copy()
    out[np.ix_(finite, finite)] = (J @ np.where(np.isfinite(cov), cov, 0.0) @ J.T)[np.ix_(finite, finite)]
    return out
