"""Maximum-likelihood refinement of the direct solution (the paper's Appendix C, generalised).

The paper's iterative solver linearises the residual ``omega_1 - C omega_2`` (Eq. 59-67) with
the noise of gyro 2 ignored in the regressor. Here the cost is the exact negative log-likelihood
of the errors-in-variables model with the true rates profiled out,

    L(theta) = tr(W(A) [I, -A] S_c [I, -A]^T),   W(A) = (sigma_1^2 I + sigma_2^2 A A^T)^-1,

(``S_c`` the centred, or per-segment pooled, scatter of ``[omega_1; omega_2]``). A prior on the scale
factors plays no part here: it acts only along the directions the data leave undetermined, which the
gauge holds fixed during the refinement (:func:`fusion_gyrocal.core.solve.solve`). The dependence of ``W`` on ``A`` is what removes the
attenuation of the scale factors that plain least squares suffers when gyro 2 is noisy relative
to the motion (slow motion). Steps are Fisher-scoring (Gauss-Newton on the expected Hessian,
Appendix B) with analytic gradients, in the gauge's tangent space, with a backtracking line search.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..lie import exp
from .gauge import null_space
from .moments import Moments
from .observability import A_of, dA_dp, fisher_information, residual_weight, signal_scatter

_E = np.eye(3)


def residual_scatter(A, Sc):
    """``[I, -A] S_c [I, -A]^T``: the scatter of the residual ``omega_1 - A omega_2`` (Eq. 15)."""
    K = np.hstack([_E, -A])
    return K @ Sc @ K.T


def ml_cost(R, s1, s2, moments: Moments, noise_std, k=None) -> float:
    """Negative log-likelihood (times 2, up to a constant) of the calibration given the moments (``k``: the
    cross-axis terms of the full linear map, :mod:`~fusion_gyrocal.core.linear_map`)."""
    return cost_of_A(A_of(R, s1, s2, k), moments, noise_std)


def ml_gradient(R, s1, s2, moments: Moments, noise_std, k=None) -> np.ndarray:
    """Gradient of :func:`ml_cost` w.r.t. ``[dtheta, log s_1, log s_2]`` (and ``k`` when given)."""
    return gradient_of_A(A_of(R, s1, s2, k), dA_dp(R, s1, s2, k), moments, noise_std)


def cost_of_A(A, moments: Moments, noise_std) -> float:
    """:func:`ml_cost` of a map ``A`` however it is parametrised."""
    return float(np.trace(residual_weight(A, noise_std) @ residual_scatter(A, moments.scatter)))


def gradient_of_A(A, D, moments: Moments, noise_std) -> np.ndarray:
    """Gradient of :func:`cost_of_A` w.r.t. the parameters whose derivatives of ``A`` are ``D`` (p, 3, 3)."""
    W = residual_weight(A, noise_std)
    Sc = moments.scatter
    M = residual_scatter(A, Sc)
    S12, S22 = Sc[:3, 3:], Sc[3:, 3:]
    left = S22 @ A.T - S12.T          # dM = D (S22 A^T - S21) + (A S22 - S12) D^T
    WMW = W @ M @ W
    g = np.empty(len(D))
    for p in range(len(D)):
        dM = D[p] @ left
        dM = dM + dM.T
        dAAt = D[p] @ A.T
        dAAt = dAAt + dAAt.T
        g[p] = np.trace(W @ dM) - noise_std[1] ** 2 * np.trace(WMW @ dAAt)
    return g


def retract(R, s1, s2, delta):
    """Apply a step ``[dtheta, dlog s_1, dlog s_2]``: ``R <- Exp(dtheta) R``, ``s <- s exp(dlog s)``."""
    return (exp(delta[:3]) @ R, s1 * np.exp(delta[3:6]), s2 * np.exp(delta[6:9]))


@dataclass(frozen=True)
class Refined:
    R: np.ndarray
    s1: np.ndarray
    s2: np.ndarray
    iterations: int
    information: np.ndarray  # (9, 9) Fisher information of the data (no prior) at the solution
    converged: bool


def fisher_scoring(state, *, cost, gradient, information, retract, constraints=None, max_iter: int = 30,
                   tol: float = 1e-11):
    """Minimise ``cost(state)`` by Fisher scoring with a backtracking line search.

    Each step solves ``(Z^T H Z) d = -Z^T g`` with ``H = information(state)`` (the expected Hessian),
    ``g = gradient(state)`` and ``Z`` a basis of the null space of ``constraints(state)`` (the
    linearised gauge; all of the tangent space when None), then moves by ``retract(state, t d)``,
    halving ``t`` until the cost does not increase. The pair solver and the N-gyro solver share it.

    Returns
    -------
    (state, iterations, converged)
    """
    c = cost(state)
    it = 0
    for it in range(1, max_iter + 1):
        H, g = information(state), gradient(state)
        Z = np.eye(len(g)) if constraints is None else null_space(constraints(state))
        step = -Z @ np.linalg.lstsq(Z.T @ H @ Z, Z.T @ g, rcond=1e-12)[0]
        t = 1.0
        while True:
            candidate = retract(state, t * step)
            new = cost(candidate)
            if new <= c + 1e-12 * abs(c) or t < 1e-4:
                break
            t *= 0.5
        state, decrease, c = candidate, c - new, new
        if np.max(np.abs(t * step)) < tol or (0 <= decrease <= 1e-14 * max(abs(c), 1.0)):
            return state, it, True
    return state, it, False


def refine_ml(moments: Moments, R, s1, s2, noise_std, *, constraints=None, regauge=None,
              max_iter: int = 30, tol: float = 1e-11) -> Refined:
    """Fisher-scoring refinement of ``(R, s1, s2)`` from the moments (:func:`fisher_scoring`).

    Parameters
    ----------
    constraints : callable ``(s1, s2) -> (k, 9)`` or None
        Linearised gauge conditions; steps are restricted to their null space.
    regauge : callable ``(s1, s2) -> (s1, s2)`` or None
        Re-imposes the (nonlinear) gauge after each step (moves along null directions only).
    """
    noise_std = tuple(float(x) for x in noise_std)
    _, Xi_c = signal_scatter(moments, noise_std)

    def information(x):
        return 2.0 * fisher_information(*x, noise_std, Xi_c)

    def step(x, delta):
        R, s1, s2 = retract(*x, delta)
        return (R, *regauge(s1, s2)) if regauge is not None else (R, s1, s2)

    (R, s1, s2), it, converged = fisher_scoring(
        (np.array(R, float), np.array(s1, float), np.array(s2, float)),
        cost=lambda x: ml_cost(*x, moments, noise_std),
        gradient=lambda x: ml_gradient(*x, moments, noise_std),
        information=information, retract=step,
        constraints=None if constraints is None else (lambda x: constraints(x[1], x[2])),
        max_iter=max_iter, tol=tol)
    return Refined(R, s1, s2, it, fisher_information(R, s1, s2, noise_std, Xi_c), converged)
