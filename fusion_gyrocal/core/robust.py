"""A covariance that covers the real error: the block-robust (sandwich) covariance of the pair.

The inverse Fisher information (Appendix B) is the covariance of the estimate only when the noise
model holds: white noise of the stated level, nothing else in the residual. Real residuals are
coloured (a digital low-pass), heteroscedastic and structured (a rate-dependent scale or cross-axis
error, timing, flex), and the estimate then scatters more than the Fisher information says.

The estimate minimises ``L(theta) = sum_w L_w(theta)`` over windows ``w`` of the log (the cost of
:mod:`~fusion_gyrocal.core.refine` is linear in the scatter, so ``L_w`` is the same cost of window
``w``'s scatter about the log's mean). To first order ``theta_hat - theta = -H^-1 sum_w g_w``
with ``g_w`` the window's score (gradient of ``L_w`` at the estimate) and ``H = 2 F`` the expected
Hessian, so

    Cov(theta_hat) = H^-1 V H^-1,    V = Var(sum_w g_w),

whatever the noise is, as long as windows far apart are independent. ``V`` is estimated from the
scores themselves (Newey-West: their outer products plus the Bartlett-weighted cross products of
neighbours up to :data:`LAGS` windows apart). Under the noise model ``V = 4 F`` and this is the
Fisher covariance again; with model error it grows by exactly what the model error moves the
estimate across windows of different motion. The gauge is the same constrained inverse as the
Fisher covariance's (:func:`~fusion_gyrocal.core.gauge.constrained_inverse`); what a scale prior
holds (the directions the data leave free) keeps the prior's variance.

``covariance="auto"`` (:class:`~fusion_gyrocal.options.Options`) reports the larger of the two in
every direction (:func:`larger`): the model's where the model explains the scatter, the robust one
where it does not; the variance ratio in the worst direction is reported as ``robust_inflation``, and what
was reported as a :class:`CovarianceBasis`.
"""

from __future__ import annotations

from enum import Enum

import numpy as np

from .moments import WindowStats
from .observability import A_of, dA_dp, residual_weight

LAGS = 2   # neighbouring windows whose scores may be correlated (Bartlett weights)
#: Fewest windows behind a block-robust covariance (fewer give too noisy an estimate of the scores' variance).
MIN_ROBUST_WINDOWS = 20


def centred_scatters(stats: WindowStats) -> np.ndarray:
    """Each window's scatter about the log's mean (W, d, d): what its share of the log's centred
    scatter is; about its own mean for bias segments (``pooled``)."""
    if stats.pooled:
        return stats.scatter
    d = stats.mean - (stats.count[:, None] * stats.mean).sum(axis=0) / stats.count.sum()
    return stats.scatter + stats.count[:, None, None] * d[:, :, None] * d[:, None, :]


def window_scores(R, s1, s2, noise_std, stats: WindowStats) -> np.ndarray:
    """Scores ``g_w`` (W, 9): gradient of each window's cost w.r.t. ``[dtheta, log s_1, log s_2]``.

    The cost is ``tr(W(A) [I, -A] S [I, -A]^T)`` (:func:`~fusion_gyrocal.core.refine.ml_cost`) with
    ``S`` the window's scatter about the log's mean (about its own mean for bias segments); its
    gradient (:func:`~fusion_gyrocal.core.refine.ml_gradient`) is linear in ``S``.
    """
    return scores_of_A(A_of(R, s1, s2), dA_dp(R, s1, s2), noise_std, stats)


def scores_of_A(A, D, noise_std, stats: WindowStats) -> np.ndarray:
    """:func:`window_scores` of a map ``A`` whose derivatives w.r.t. its parameters are ``D`` (p, 3, 3)."""
    W = residual_weight(A, noise_std)
    S = centred_scatters(stats)
    S11, S12, S22 = S[:, :3, :3], S[:, :3, 3:], S[:, 3:, 3:]
    AS22 = A @ S22                                     # (W, 3, 3)
    M = S11 - S12 @ A.T - A @ S12.transpose(0, 2, 1) + AS22 @ A.T
    left = S22 @ A.T - S12.transpose(0, 2, 1)          # dM_p = D_p left + (D_p left)^T
    WD = np.einsum("ij,pjk->pik", W, D)                # W D_p
    g = 2.0 * np.einsum("pij,wji->wp", WD, left)       # tr(W dM_p) = 2 tr(W D_p left)
    WMW = W @ M @ W
    g -= 2.0 * noise_std[1] ** 2 * np.einsum("wij,pjk,ik->wp", WMW, D, A, optimize=True)  # tr(WMW (D A^T + A D^T))
    return g


def _newey_west(e: np.ndarray, stats: WindowStats, lags: int) -> np.ndarray:
    """``sum_w e_w e_w^T`` plus Bartlett-weighted cross products of neighbours (same run) up to ``lags`` apart."""
    V = e.T @ e
    for lag in range(1, min(lags, e.shape[0] - 1) + 1):
        same_run = stats.run[lag:] == stats.run[:-lag]
        C = e[:-lag][same_run].T @ e[lag:][same_run]
        V += (1.0 - lag / (lags + 1.0)) * (C + C.T)
    return V


def score_variance(g: np.ndarray, stats: WindowStats, lags: int = LAGS) -> np.ndarray:
    """Newey-West estimate of ``Var(sum_w g_w)`` over the whole log from the windows' scores."""
    if g.shape[0] == 0:
        return np.zeros((g.shape[1], g.shape[1]))
    return _newey_west(g - g.mean(axis=0), stats, lags) * stats.weight


def sandwich(F, V, constraints) -> np.ndarray:
    """``H^-1 (V / 4) H^-1`` with ``H^-1`` the inverse of the Fisher information ``F`` in the tangent
    space of the gauge (``constraints @ dx = 0``): the robust covariance of ``[dtheta, log s_1, log s_2]``."""
    from .gauge import constrained_inverse

    Hinv = constrained_inverse(F, constraints)
    C = Hinv @ (0.25 * V) @ Hinv
    return 0.5 * (C + C.T)


def effective_windows(stats: WindowStats, lags: int = LAGS) -> float:
    """Windows' worth of independent information in a Newey-West estimate with Bartlett weights."""
    w = 1.0 - np.arange(1, lags + 1) / (lags + 1.0)
    return stats.n_windows / (1.0 + 2.0 * float(np.sum(w * w)))


TRACY_WIDOM_99 = 2.02   # 99th percentile of the Tracy-Widom (beta = 1) law of the largest eigenvalue


def significant_ratio(p: int, n: float) -> float:
    """Largest eigenvalue a ``p``-dimensional sample covariance of ``n`` independent windows of white
    noise (true covariance the identity) exceeds in only 1 % of cases: the Marchenko-Pastur edge
    ``(1 + sqrt(p / n))^2`` plus 2.02 Tracy-Widom scales (Johnstone 2001)."""
    n = max(float(n), 1.0)
    edge = (1.0 + np.sqrt(p / n)) ** 2
    scale = (np.sqrt(n) + np.sqrt(p)) * (1.0 / np.sqrt(n) + 1.0 / np.sqrt(p)) ** (1.0 / 3.0) / n
    return float(edge + TRACY_WIDOM_99 * scale)


def larger(P_model, P_robust, n_effective: float | None = None, rtol: float = 1e-10) -> tuple[np.ndarray, float]:
    """The model's covariance raised to the robust one in every direction where the robust one is
    significantly larger, and the largest variance ratio.

    In the coordinates where ``P_model`` is the identity (on its range; the gauge's null directions
    stay null), the robust covariance is a sample covariance of ``n_effective`` windows: under the
    noise model its largest eigenvalue stays below :func:`significant_ratio` in 99 % of logs. An
    eigenvalue beyond it is model error and is kept; the others are set to 1 (the model's, which is
    exact when the model holds). ``n_effective`` None keeps every eigenvalue above 1.
    Returns ``(P, ratio)`` with ``ratio`` the largest eigenvalue (how many times the model's variance
    the robust one is, in the worst direction).
    """
    lam, U = np.linalg.eigh(0.5 * (P_model + P_model.T))
    keep = lam > rtol * max(lam.max(), 0.0)
    if not keep.any():
        return P_robust, float("nan")
    T = U[:, keep] * np.sqrt(lam[keep])                # P_model = T T^T on its range
    Tinv = (U[:, keep] / np.sqrt(lam[keep])).T
    Q = Tinv @ P_robust @ Tinv.T
    mu, V = np.linalg.eigh(0.5 * (Q + Q.T))
    edge = 1.0 if n_effective is None else significant_ratio(mu.size, n_effective)
    big = mu > edge
    if not big.any():
        return P_model, float(mu.max())
    TV = T @ V[:, big]                                 # P_model plus the excess where it is significant
    P = P_model + (TV * (mu[big] - 1.0)) @ TV.T
    return 0.5 * (P + P.T), float(mu.max())


class CovarianceBasis(str, Enum):
    """What a reported covariance rests on (``covariance_kind`` of the results); :meth:`describe` gives the
    ``covariance_basis`` sentence. Decisions test the member, never the sentence.

    ``MODEL``: the noise model alone (no block-robust check); ``CHECKED``: the noise model, the block-robust check
    agrees; ``RAISED``: the noise model raised to the block-robust covariance where that is larger; ``ROBUST``: the
    block-robust covariance (asked for); ``INFLATED``: the noise model inflated by the residual's chi2/dof.
    """

    MODEL = "model"
    CHECKED = "checked"
    RAISED = "raised"
    ROBUST = "robust"
    INFLATED = "inflated"

    def describe(self, model_basis: str, where: str = "", lack_of_fit: float = float("nan")) -> str:
        """The ``covariance_basis`` sentence: ``model_basis`` names the noise model's covariance, ``where`` the
        windows of the block-robust one, ``lack_of_fit`` the residual's chi2/dof that inflated it."""
        if self is CovarianceBasis.ROBUST:
            return f"block-robust (sandwich over {where})"
        if self is CovarianceBasis.RAISED:
            return f"noise model raised to the block-robust sandwich ({where}) where that is significantly larger"
        if self is CovarianceBasis.CHECKED:
            return f"{model_basis}; the block-robust sandwich ({where}) is not significantly larger"
        if self is CovarianceBasis.INFLATED:
            return f"{model_basis}, inflated by the residual's chi2/dof {lack_of_fit:.3g}"
        return model_basis

    @classmethod
    def read(cls, value, what: str = "calibration") -> "CovarianceBasis":
        """The member a file's ``covariance_kind`` names (:class:`~fusion_gyrocal.errors.FormatError` otherwise)."""
        try:
            return cls(value)
        except ValueError:
            from ..errors import FormatError
            raise FormatError(f"{what}: expected covariance_kind one of {[k.value for k in cls]}, got {value!r}") from None

    @classmethod
    def from_text(cls, basis: str) -> "CovarianceBasis":
        """The basis a ``covariance_basis`` sentence of a file of format 1.0-1.2 names (those files store the
        sentence only), read by the beginnings and ends those versions wrote."""
        if basis.startswith("noise model raised to the block-robust sandwich"):
            return cls.RAISED
        if basis.startswith("block-robust (sandwich"):
            return cls.ROBUST
        if basis.endswith("is not significantly larger"):
            return cls.CHECKED
        return cls.INFLATED if ", inflated by the residual's chi2/dof" in basis else cls.MODEL


def inflated(P, lack_of_fit: float, basis: str, what: str):
    """The covariance ``P`` inflated by the residual's chi-square per dof (a user's noise that the residual
    exceeds, with no block-robust check), :attr:`CovarianceBasis.INFLATED`, its basis text and note; ``what``
    lists the usual causes."""
    kind = CovarianceBasis.INFLATED
    return (P * lack_of_fit, kind, kind.describe(basis, lack_of_fit=lack_of_fit),
            f"residuals are {np.sqrt(lack_of_fit):.2f}x larger than noise_std explains ({what} or a wrong noise_std?); "
            f"covariance inflated by {lack_of_fit:.2f}")


def choose(P_model, P_robust, windows: WindowStats, covariance: str, model_basis: str, lack_of_fit: float):
    """What is reported for ``covariance`` ("auto", "robust"; "model" never gets here): the covariance, the
    largest variance ratio, the :class:`CovarianceBasis`, its ``covariance_basis`` text and the notes (one place
    for the pair and the array)."""
    where = f"{windows.n_windows} windows of {windows.window} samples"
    P_max, inflation = larger(P_model, P_robust, effective_windows(windows))
    notes = []
    if inflation > 2.0:
        notes.append(f"the estimate scatters up to {np.sqrt(inflation):.3g}x more than the noise model explains "
                     f"(residual chi2/dof {lack_of_fit:.3g}: rate-dependent scale or cross-axis error, coloured noise, "
                     "timing, flex); the covariance is the block-robust one in those directions")
    if covariance == "robust":
        P, kind = P_robust, CovarianceBasis.ROBUST
    elif P_max is not P_model:
        P, kind = P_max, CovarianceBasis.RAISED
    else:
        P, kind = P_model, CovarianceBasis.CHECKED
    return P, inflation, kind, kind.describe(model_basis, where), notes


def bias_variance(A, bias, stats: WindowStats, lags: int = LAGS) -> np.ndarray:
    """Newey-West long-run covariance of the mean residual ``omega_1 - A omega_2 - bias`` (3, 3).

    The variance of the bias estimate when the residual is coloured or drifts slowly (window means
    that wander), without the model's assumption of white noise. Not for bias segments (each window
    then has a bias of its own).
    """
    r = stats.mean[:, :3] - stats.mean[:, 3:] @ A.T - bias
    n = stats.count.sum()
    e = stats.count[:, None] * (r - (stats.count[:, None] * r).sum(axis=0) / n)
    return _newey_west(e, stats, lags) / (n * n * stats.weight)   # Var(sum over the log) / N_log^2


def cross_axis(A_ls, R, s1, s2, moments, noise_std, windows: WindowStats | None = None,
               lags: int = LAGS, n_null: int | None = None) -> tuple[np.ndarray, float, int]:
    """What the full linear map explains beyond rotation + scale factors: the observable relative
    cross-axis terms (Appendix D).

    The least-squares ``A`` (Eq. 17, nine free entries) against the rigid ``A = S_1 R S_2^-1`` (Eq. 4):
    their difference, with the directions the rigid model can absorb (rotation, scales: the tangent
    ``dA/dp``) projected out in the metric of ``Cov(vec A)``, is what no rotation and scales explain;
    it is tested by its chi-square (``k = 9 - rank(dA/dp)`` degrees of freedom: 1 in the general
    configuration, more with parallel axes; ``n_null``, the configuration's null directions (Theorem 2,
    Lemmas 2-3), fixes the rank where an estimated rotation a hair from axis-parallel would make it
    numerically full). ``Cov(vec A)`` is ``W^-1 (x) S22^-1`` under the noise model, or
    with ``windows`` the block-robust one from the windows' influence on ``A``
    (``(S12_w - A S22_w) S22^-1``, Newey-West), whichever is larger.

    Returns
    -------
    E : ndarray (3, 3)
        The unexplained part as relative cross-axis terms in gyro 1's frame, ``S_1^-1 dA S_2 R^T``.
    chi2 : float
    dof : int
    """
    A_r = A_of(R, s1, s2)
    S22 = moments.S22
    S22_inv = np.linalg.inv(S22)
    cov = np.kron(np.linalg.inv(residual_weight(A_r, noise_std)), S22_inv)     # row-major vec(A)
    if windows is not None and windows.n_windows >= 2:
        S = centred_scatters(windows)
        U = (S[:, :3, 3:] - A_ls @ S[:, 3:, 3:]) @ S22_inv                       # each window's pull on A
        V = _newey_west(U.reshape(U.shape[0], 9) - U.reshape(U.shape[0], 9).mean(axis=0), windows, lags)
        cov = larger(cov, V * windows.weight)[0]
    J = dA_dp(R, s1, s2).reshape(9, 9).T                                         # columns: vec(dA/dp_k)
    if n_null is not None:                                                       # the tangent without the null space
        J = np.linalg.svd(J)[0][:, :9 - n_null]
    info = np.linalg.pinv(cov, hermitian=True)
    P = J @ np.linalg.pinv(J.T @ info @ J, hermitian=True) @ J.T @ info          # oblique projector on the tangent
    Q = np.eye(9) - P
    d = Q @ (A_ls - A_r).reshape(9)
    chi2 = float(d @ np.linalg.pinv(Q @ cov @ Q.T, rcond=1e-10, hermitian=True) @ d)
    dof = n_null if n_null is not None else 9 - int(np.linalg.matrix_rank(J, tol=1e-9 * np.abs(J).max()))
    E = (d.reshape(3, 3) / s1[:, None]) * s2[None, :] @ R.T
    return E, chi2, dof


def reported_covariance(P_model, robust, windows: WindowStats | None, covariance: str, basis: str,
                        lack_of_fit: float, *, user_noise: bool, what: str):
    """The covariance a solve reports, and why: one policy for the pair and the array.

    The block-robust check (:func:`choose`) when the solve has one (``robust`` not None), per-window statistics
    are given, ``covariance`` is not ``"model"`` and there are at least :data:`MIN_ROBUST_WINDOWS` windows;
    otherwise the noise model's covariance, inflated by the residual's chi2/dof (:func:`inflated`) when a
    user's noise explains less than the residual (``lack_of_fit > 1.5``).

    Parameters
    ----------
    P_model : ndarray
        The noise model's covariance (inverse Fisher information in the gauge).
    robust : callable or None
        ``robust()`` gives the block-robust covariance (computed only when used); None when the solve has none.
    windows : WindowStats or None
    covariance : {"auto", "model", "robust"}
        As :class:`~fusion_gyrocal.options.Options`' ``covariance``. A caller that cannot honour ``"robust"``
        (the check did not run) decides whether to refuse.
    basis : str
        What ``P_model`` rests on (the ``covariance_basis`` text).
    lack_of_fit : float
        The residual's chi-square per degree of freedom against the noise used.
    user_noise : bool
        The noise was given, not estimated from the residual.
    what : str
        The usual causes of a lack of fit, for the note.

    Returns
    -------
    (P, inflation, kind, basis, notes)
        The covariance, the largest robust-to-model variance ratio (NaN without the check), what it rests on
        (:class:`CovarianceBasis`: ``MODEL`` when neither the check nor the inflation applied), its basis text and
        the notes.
    """
    if robust is not None and windows is not None and covariance != "model" and windows.n_windows >= MIN_ROBUST_WINDOWS:
        return choose(P_model, robust(), windows, covariance, basis, lack_of_fit)
    if user_noise and lack_of_fit > 1.5:
        P, kind, basis, note = inflated(P_model, lack_of_fit, basis, what)
        return P, float("nan"), kind, basis, [note]
    return P_model, float("nan"), CovarianceBasis.MODEL, basis, []
