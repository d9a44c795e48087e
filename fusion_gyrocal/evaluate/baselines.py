"""The paper's baselines beside the library's solver: Appendix C's iterative solver and rotation-only Kabsch.

* :func:`solve_appendix_c`: the paper's Gauss-Newton solver of Appendix C, faithful to the appendix
  (the library's own maximum-likelihood refinement is :func:`fusion_gyrocal.core.refine.refine_ml`);
* :func:`rotation_only`: what rotation-only extrinsic tools do, Kabsch (Wahba) alignment of the
  bias-removed rates, scale factors not modelled.

Equations of Appendix C are cited by the LaTeX label of the paper's source (``residual``, ``Gamma``,
``residual_linear``, ``eq:Jk``, ``eq:obj_iter_cost_2``, ``Jk_iterative``), since the appendix's
numbering is not printed in the source.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.moments import Moments, as_rates
from ..core.observability import A_of
from ..errors import ConvergenceError, ExcitationError, OptionError
from ..lie import skew

__all__ = ["AppendixCResult", "solve_appendix_c", "rotation_only"]


@dataclass(frozen=True)
class AppendixCResult:
    """Result of :func:`solve_appendix_c` (a converged iteration; one that does not converge raises).

    ``scale_1[0]`` keeps its initial value (the paper fixes ``1s_x`` to remove the global scale).
    """

    R_1_2: np.ndarray
    scale_1: np.ndarray
    scale_2: np.ndarray
    bias: np.ndarray
    iterations: int


_GAMMA_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _appendix_c_basis() -> np.ndarray:
    """Matrices ``B_p`` (9, 3, 3) with ``J(k) x = (sum_p x_p B_p) omega(k)``.

    From Eq. (residual_linear) and (eq:Jk): ``J(k) x = [omega x] theta + Omega(k) gamma
    = (Gamma - [theta x]) omega``; gamma = (g11, g12, g13, g22, g23, g33) fills the symmetric
    ``Gamma`` (Eq. Gamma).
    """
    B = np.zeros((9, 3, 3))
    B[:3] = -skew(np.eye(3))                    # -[e_m x]:  [omega x] e_m = -[e_m x] omega
    for p, (i, j) in enumerate(_GAMMA_INDEX):
        B[3 + p, i, j] = B[3 + p, j, i] = 1.0
    return B


_B = _appendix_c_basis()


def _phi(C) -> np.ndarray:
    """``Phi`` (6, 6) of Appendix C: ``gamma = Phi [1s~; 2s~]`` from ``Gamma = S~1' - C S~2' C^T``."""
    Phi = np.zeros((6, 6))
    for row, (i, j) in enumerate(_GAMMA_INDEX):
        if i == j:
            Phi[row, i] = 1.0
        Phi[row, 3:] = -C[i] * C[j]
    return Phi


def _gauss_newton_step(H, g, iteration, s1, s2) -> np.ndarray:
    """Solve the normal equations ``H x = g`` of (eq:obj_iter_cost_2); a singular or non-finite system
    means the iteration has diverged (a failure of the method, raised as such)."""
    if np.isfinite(H).all() and np.isfinite(g).all():
        try:
            return np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            pass  # exactly singular: reported below
    raise ConvergenceError(f"appendix C: the Gauss-Newton iteration diverged at iteration {iteration} (singular or "
                           f"non-finite normal matrix; {_scales_text(s1, s2)})")


def _scales_text(s1, s2) -> str:
    return f"scale_1 {np.array2string(s1, precision=3)}, scale_2 {np.array2string(s2, precision=3)}"


def solve_appendix_c(moments: Moments, R_1_2=None, scale_1=None, scale_2=None, *, max_iter: int = 10,
                     tol: float = 1e-10) -> AppendixCResult:
    """The paper's iterative (Gauss-Newton) solver of Appendix C, from the sufficient statistics.

    Each iteration compensates the rates with the current scales, ``omega_i' = S_i_hat^-1 omega_i``,
    forms the centred residual ``r(k) = omega_1'(k) - C_hat omega_2'(k)`` (Eq. residual,
    equ:residual) and the Jacobian ``J(k) = [[omega(k) x], Omega(k)]`` of (eq:Jk, Jk_iterative) with
    the true rate ``omega(k)`` replaced by the compensated measurement ``omega_1'(k)`` (as the
    appendix says, "J can be computed using the measurements"), solves the linear least squares
    (eq:obj_iter_cost_2) for ``x = [theta~, gamma]`` and recovers the scale errors from
    ``Phi s~ = gamma`` with ``1s~_x = 0`` (the global scale is not observable, Theorem 2). The
    update is ``C <- (I - [theta~ x]) C_hat`` (applied as ``Exp(-theta~) C_hat``) and
    ``S_i <- S_i_hat (I + S~_i')``.

    Both ``sum_k J^T J`` and ``sum_k J^T r`` are quadratic in the centred samples, so the whole
    iteration runs on the centred scatter of the moments: ``sum_k (B_p w)^T (B_q w) =
    tr(B_p^T B_q S11')`` and ``sum_k (B_p w)^T r = tr(B_p^T (S11' - C S12'^T))``.

    Parameters
    ----------
    moments : Moments
        Statistics of the sample-aligned pair (the bias is profiled out by the centring).
    R_1_2, scale_1, scale_2 : array_like, optional
        Initial estimate; default identity and unit scales.
    max_iter : int
        Iteration limit ("typically the algorithm converges in fewer than 5 iterations").
    tol : float
        Stop when the largest applied correction (rad or relative scale) is below this.

    Raises
    ------
    ConvergenceError
        The iteration diverged: its normal matrix became singular or not finite, or a scale factor
        left (0, inf) (from a poor start, e.g. identity far from the truth, or in a degenerate
        configuration, the scale factors can change sign and run away); or it did not converge in
        ``max_iter`` iterations. A result is returned only when the iteration converged to
        positive finite scale factors.

    Notes
    -----
    In a degenerate configuration (Lemmas 2-3) ``Phi`` loses further rank; the remaining
    undetermined combinations of scale errors are then set by the minimum-norm least-squares
    solution, i.e. left at their initial values, which is the paper's "fix more elements".
    """
    from scipy.spatial.transform import Rotation

    C = np.eye(3) if R_1_2 is None else np.array(R_1_2, dtype=float)
    s1 = np.ones(3) if scale_1 is None else np.array(scale_1, dtype=float)
    s2 = np.ones(3) if scale_2 is None else np.array(scale_2, dtype=float)
    Sc = moments.scatter
    if int(max_iter) < 1:
        raise OptionError(f"max_iter: expected at least 1 iteration, got {max_iter!r}")
    converged = False
    it, step = 0, np.inf
    for it in range(1, int(max_iter) + 1):
        d1, d2 = 1.0 / s1, 1.0 / s2
        S11 = Sc[:3, :3] * np.outer(d1, d1)
        S12 = Sc[:3, 3:] * np.outer(d1, d2)
        BS = _B @ S11                                  # B_q S11'
        H = np.einsum("pij,qij->pq", _B, BS)           # tr(B_p^T B_q S11')
        g = np.einsum("pij,ij->p", _B, S11 - C @ S12.T)
        x = _gauss_newton_step(H, g, it, s1, s2)
        theta, gamma = x[:3], x[3:]
        Phi = _phi(C)
        s_err = np.zeros(6)
        s_err[1:] = np.linalg.lstsq(Phi[:, 1:], gamma, rcond=1e-8)[0]   # 1s~_x = 0
        C = Rotation.from_rotvec(-theta).as_matrix() @ C
        s1, s2 = s1 * (1.0 + s_err[:3]), s2 * (1.0 + s_err[3:])
        if not (np.isfinite(C).all() and np.isfinite(s1).all() and np.isfinite(s2).all()
                and (s1 > 0).all() and (s2 > 0).all()):
            raise ConvergenceError(f"appendix C: the Gauss-Newton iteration diverged at iteration {it} (a scale "
                                   f"factor left (0, inf): {_scales_text(s1, s2)})")
        step = max(np.abs(theta).max(), np.abs(s_err).max())
        if step < tol:
            converged = True
            break
    if not converged:
        raise ConvergenceError(f"appendix C: no convergence in {it} iterations (last step {step:.3g}, expected "
                               f"below {tol:g}; {_scales_text(s1, s2)})")
    bias = moments.mean_1 - A_of(C, s1, s2) @ moments.mean_2
    return AppendixCResult(C, s1, s2, bias, it)


def _check_two_directions(m: Moments, w1, w2, min_snr: float = 10.0) -> None:
    """Refuse motion about one direction only: the rotation about it is then undetermined (Kabsch needs two
    directions; the SNR of Eq. 36 along the second principal direction of the motion gyro 2 explains, the noise
    from each stream's third differences)."""
    from ..core.noise import difference_noise_std
    from ..core.observability import explained_scatter, check_samples

    check_samples(m)
    sigma = float(np.hypot(difference_noise_std(w1), difference_noise_std(w2)))
    lam = np.sort(np.clip(np.linalg.eigvalsh(explained_scatter(m)), 0.0, None))
    snr = float(np.sqrt(lam[1]) / sigma) if sigma > 0 else (np.inf if lam[1] > 1e-20 * lam[2] else 0.0)
    if not snr >= min_snr:
        raise ExcitationError(f"rotation_only: expected motion about at least two directions, got one (the second "
                              f"direction's SNR is {snr:.3g}, need >= {min_snr:g}): the rotation about the moving "
                              "axis is undetermined")


def rotation_only(omega_1, omega_2) -> tuple[np.ndarray, np.ndarray]:
    """Rotation-only baseline: Kabsch (Wahba) alignment of the bias-removed rates.

    Minimises ``sum_k ||w1(k) - R w2(k)||^2`` over rotations ``R`` with ``w_i`` the rates minus
    their mean (the mean removes constant biases), using
    :meth:`scipy.spatial.transform.Rotation.align_vectors`. Scale factors are not modelled
    (taken as 1), which is what rotation-only extrinsic tools do.

    Returns
    -------
    R_1_2 : ndarray (3, 3)
        ``omega_1 ~ R_1_2 @ omega_2``.
    bias : ndarray (3,)
        ``mean_1 - R_1_2 mean_2``.
    """
    from scipy.spatial.transform import Rotation

    w1 = as_rates("omega_1", omega_1)
    w2 = as_rates("omega_2", omega_2, length=w1.shape[0])
    m = Moments.from_samples(w1, w2)
    _check_two_directions(m, w1, w2)
    rot, _ = Rotation.align_vectors(w1 - m.mean_1, w2 - m.mean_2)
    R = rot.as_matrix()
    return R, m.mean_1 - R @ m.mean_2
