"""The paper's direct solution: least squares for A and b, decomposition, global scale.

* :func:`solve_A`: Eq. (12)-(17), from the sufficient statistics (the centred scatter).
* :func:`decompose`: A into R_1_2, scale_1, scale_2 for every configuration class:
  general (Lemma 4, smallest eigenvector of A_0^T A_0, Eq. 30-31), one pair of axes parallel
  (Lemma 3, any pair and any signs, Eq. 26-29) and all axes parallel (Lemma 2, any signed
  permutation).

The global scale (Theorem 2) is fixed afterwards by :class:`~fusion_gyrocal.core.gauge.Gauge`.
"""

from __future__ import annotations

import numpy as np

from ..errors import ConfigurationError, ExcitationError
from ..lie import nearest_rotation
from .moments import Moments
from .observability import CONFIG_ALL, CONFIG_GENERAL, CONFIG_ONE_PAIR, Configuration


def solve_A(moments: Moments) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``A`` and combined bias ``b`` from the moments (Eq. 12-17).

    ``A = S_12 S_22^-1`` from the centred scatters (the normal equations of Eq. 17 written
    with A on the left), and ``b = mean_1 - A mean_2`` (Eq. 12).
    """
    S22 = moments.S22
    cond = np.linalg.cond(S22)
    if not np.isfinite(cond) or cond > 1e12:
        raise ExcitationError(
            f"omega_2 does not span three dimensions (condition number of its scatter {cond:.3g}): "
            "rotate about all three axes (Lemma 1)")
    A = np.linalg.solve(S22, moments.S12.T).T
    return A, moments.mean_1 - A @ moments.mean_2


def _A_I(A):
    return A**2  # Eq. (23)


def _A_0(A):
    return np.stack([A[0] * A[1], A[1] * A[2], A[2] * A[0]])  # Eq. (24)


def _positive(v, what):
    v = v * np.sign(v[np.argmax(np.abs(v))])
    if np.any(v <= 0):
        raise ConfigurationError(
            f"the direct decomposition found a non-positive squared scale factor for {what} ({v}); "
            "the data are too noisy or the pair is not rigid")
    return v


def decompose(A, config: Configuration) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Decompose ``A = S_1 C S_2^-1`` into ``(R_1_2, scale_1, scale_2)`` (Lemmas 2-4).

    Scale factors that the configuration leaves undetermined (the common factor of each
    parallel axis pair) are set by the unit convention of :meth:`~fusion_gyrocal.core.gauge.Gauge.apply`; only their
    ratio comes from the data. The caller applies the gauge afterwards.
    """
    A = np.asarray(A, dtype=float)
    s1, s2 = np.ones(3), np.ones(3)
    if config.name == CONFIG_GENERAL:
        A0 = _A_0(A)
        w, V = np.linalg.eigh(A0.T @ A0)  # Lemma 4: s2 = null(A_0), smallest eigenvector (footnote 3)
        sq2 = _positive(V[:, 0], "gyro 2")
        sq1 = _positive(_A_I(A) @ sq2, "gyro 1")  # s1 = A_I s2 (Eq. 30)
        s1, s2 = np.sqrt(sq1), np.sqrt(sq2)
    elif config.name == CONFIG_ONE_PAIR:
        i, j, _ = config.parallel_pairs[0]
        r = [k for k in range(3) if k != i]
        c = [k for k in range(3) if k != j]
        B = A[np.ix_(r, c)]
        # Lemma 3 (Eq. 27) for any pair (i, j) and any signs: the 2x2 block B of the other axes
        # gives B_I s2 = s1 and (B[0] * B[1]) . s2 = 0.
        sq2 = _positive(np.array([B[0, 1] * B[1, 1], -B[0, 0] * B[1, 0]]), "gyro 2")
        sq1 = _positive((B**2) @ sq2, "gyro 1")
        s2[c], s1[r] = np.sqrt(sq2), np.sqrt(sq1)
        s1[i], s2[j] = abs(A[i, j]), 1.0  # Eq. (26): only s1_i / s2_j = |a_ij| is determined
    elif config.name == CONFIG_ALL:
        for i, j, _ in config.parallel_pairs:  # Lemma 2: A_I s2 = s1 on the signed permutation
            s1[i], s2[j] = abs(A[i, j]), 1.0
    R = nearest_rotation((A * s2[None, :]) / s1[:, None])  # Eq. (31) and its projection onto SO(3)
    return R, s1, s2
