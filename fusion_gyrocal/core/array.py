"""More than two gyroscopes: one joint maximum-likelihood calibration of a rigid gyro array.

Every gyro ``k`` of the array measures the same true angular rate ``omega`` (expressed in the
reference gyro's frame, before any scale factor), the paper's measurement model (Eq. 1-3)
written once per gyro::

    y_k = S_k R_ref_k^T omega + b_k + n_k,        n_k ~ N(0, sigma_k^2 I),

with ``R_ref_k`` mapping gyro k's frame into the reference gyro's frame (``R_ref_ref = I``) and
``S_k = diag(scale_k)``. Stacking the N gyros, ``y = H omega + b + n`` with
``H = [S_0 R_ref_0^T; ...; S_{N-1} R_ref_{N-1}^T]`` (3N x 3) and
``Sigma = blockdiag(sigma_k^2 I)``. Profiling the true rate of every sample and the (constant
or per-segment) biases out of the likelihood leaves

    L(theta) = tr(P S_c),   P = Sigma^-1 - Sigma^-1 H (H^T Sigma^-1 H)^-1 H^T Sigma^-1,

where ``S_c`` is the (3N x 3N) centred scatter of the stacked measurements. For two gyros this is
exactly the pair cost :func:`fusion_gyrocal.core.refine.ml_cost` (``A = S_1 R_1_2 S_2^-1``, Eq. 4); for
more it uses every pair at once, and because one true rate drives all gyros the rotations are
consistent around every loop by construction (``R_i_j = R_ref_i^T R_ref_j``).

The full linear map (:mod:`~fusion_gyrocal.core.linear_map`): real MEMS gyros keep 1-2 % cross-axis
sensitivity, so every gyro ``j`` other than the reference may carry its own symmetric relative cross-axis
terms ``K_j`` against the reference, in the pair solver's convention::

    omega_ref_meas = (I + K_j) S_ref R_ref_j S_j^-1 omega_j_meas + bias_j,
    i.e.  H_j = S_j R_ref_j^T S_ref^-1 (I + K_j)^-1 S_ref   (H_ref = S_ref),

so the pair of the reference and gyro j has exactly :func:`~fusion_gyrocal.core.observability.A_of`'s map with
``k_j``, and ``R_ref_j`` is the rotation under the symmetric convention. ``K_j`` acts after the reference's
scale factors, so the groups of linked scale factors keep their common factors free (Lemma 2). Which gyros get
the terms follows the pair solver (``linear_map``: ``"auto"``, the cross-axis test of every gyro against the
reference at the joint rigid estimate, then the full map for every gyro once any one shows the terms; ``"rigid"``;
``"full"``), with the pair's prior ``N(0, cross_axis_std^2)`` on each term and its budget for the antisymmetric
part no data see, for every pair of gyros (:func:`_cross_budget`).

Inter-sensor timing (``timing_model``, :mod:`~fusion_gyrocal.pipeline.timing`): each chip samples on its own clock,
so beyond any constant offset gyro j's samples lag the reference's by ``d_j(t) - d_ref(t)``, the difference of two
chips' delays, each following the beat tone of its clock against the read-out (or a constant group delay).
:func:`calibrate_array` fits one delay per chip to the residuals of all pairs with the reference, each fitted
directly (Eq. 17; :func:`~fusion_gyrocal.pipeline.timing.estimate_array_timing`: the reference chip's tone found
once, in every pair, each other chip's once, in its pair), moves every delayed gyro's samples to the instants the
reference's describe (first order: the rate plus its derivative times the delay) and calibrates the array on them;
every gyro then describes the same instants, so the pairs without the reference are consistent too.

Unknowns are the rotations of every non-reference gyro, the log scale factors of every gyro (and the
cross-axis terms ``k_j``); the scale factors are determined only up to one common factor per group of linked axes
(Theorem 2; for axis-parallel gyros, Lemma 2, one group per axis). The minimisation is Fisher
scoring (Gauss-Newton on the expected Hessian, the Appendix B information generalised to N gyros)
with an analytic gradient, seeded from the pairwise direct solutions (Eq. 17, Lemmas 2-4) of every
gyro to the reference. The covariance is the inverse Fisher information in the gauge (with the cross-axis prior).

The one O(N) pass over the samples is :meth:`ArrayMoments.from_samples`: the
:class:`~fusion_gyrocal.core.moments.Moments` of every pair of gyros, from which the stacked scatter is
assembled. The result, :class:`~fusion_gyrocal.core.array_result.ArrayCalibration`, is in
:mod:`~fusion_gyrocal.core.array_result`; the covariance reported follows the pair solver's policy
(:func:`~fusion_gyrocal.core.robust.reported_covariance`).
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from ..errors import GyroCalError, InputError, OptionError
from ..lie import exp, skew
from ..options import Options
from .array_result import ARRAY_FORMAT_VERSION, ARRAY_KIND, ArrayCalibration  # noqa: F401 (their home before)
from .direct import solve_A
from .gauge import Gauge, constrained_inverse
from .moments import (Moments, WindowStats, as_rates, finite_rows, sample_weights, stacked_window_stats,
                      window_moments, window_samples)
from .linear_map import choose_full_map, cross_axis_budget
from .observability import A_of, classify, cross_matrix, dA_dp
from .refine import fisher_scoring, residual_scatter
from .robust import cross_axis, reported_covariance, sandwich, score_variance
from .solve import solve


# ---------------------------------------------------------------------------------------- statistics
def _pair_index(n: int, i: int, j: int) -> int:
    """Position of pair ``(i, j)``, ``i < j``, in ``itertools.combinations(range(n), 2)`` order."""
    return i * n - i * (i + 1) // 2 + (j - i - 1)


def _swap(m: Moments) -> Moments:
    """Moments of ``[omega_2; omega_1]`` from those of ``[omega_1; omega_2]``."""
    perm = np.r_[3:6, 0:3]
    return Moments(m.count, m.mean[perm], m.scatter[np.ix_(perm, perm)], m.segments)


@dataclass(frozen=True)
class ArrayMoments:
    """Sufficient statistics of N sample-aligned gyros: the :class:`Moments` of every pair.

    The pairwise moments hold every block of the stacked (3N x 3N) centred scatter, so they are
    all the joint estimator needs; they merge, pool and decay pair by pair with the
    :class:`Moments` algebra (streaming, distributed reductions).

    Attributes
    ----------
    n_gyros : int
        Number of gyros N (at least 2).
    pairs : tuple of Moments
        Moments of ``[omega_i; omega_j]`` for ``i < j`` in ``itertools.combinations`` order.
    """

    n_gyros: int
    pairs: tuple = field(repr=False)

    def __post_init__(self):
        n = int(self.n_gyros)
        if n < 2:
            raise InputError(f"expected at least 2 gyros, got {n}")
        pairs = tuple(self.pairs)
        if len(pairs) != n * (n - 1) // 2:
            raise InputError(f"expected {n * (n - 1) // 2} pairwise Moments for {n} gyros, got {len(pairs)}")
        counts = {p.count for p in pairs}
        if max(counts) - min(counts) > 1e-9 * max(max(counts), 1.0):
            raise InputError(f"pairwise Moments: expected the same samples for every pair, got counts {sorted(counts)}")
        object.__setattr__(self, "n_gyros", n)
        object.__setattr__(self, "pairs", pairs)

    # ------------------------------------------------------------------ construction
    @classmethod
    def empty(cls, n_gyros: int) -> "ArrayMoments":
        """Moments of no samples (the identity of :meth:`merge` and :meth:`pool`)."""
        return cls(n_gyros, tuple(Moments.empty() for _ in range(n_gyros * (n_gyros - 1) // 2)))

    @classmethod
    def from_samples(cls, omegas, *, mask=None, weights=None) -> "ArrayMoments":
        """One bounded-memory pass (per pair, :meth:`Moments.from_samples`) over N aligned streams.

        Parameters
        ----------
        omegas : array_like (n_samples, N, 3) or sequence of N arrays (n_samples, 3)
            Measured rates (rad/s) of every gyro at the same instants.
        mask : array_like of bool (n_samples,), optional
            Samples to use (True = keep); a sample is used for all gyros or for none.
        weights : array_like (n_samples,), optional
            A non-negative weight per sample, the same for every gyro (:meth:`Moments.from_samples`).
        """
        rates, mask = _checked_rates(omegas, mask)
        n = len(rates)
        return cls(n, tuple(Moments.from_samples(rates[i], rates[j], mask=mask, weights=weights)
                            for i, j in itertools.combinations(range(n), 2)))

    @classmethod
    def from_windows(cls, omegas, window: int, *, mask=None) -> "ArrayMoments":
        """Pooled moments of consecutive windows of ``window`` samples (piecewise-constant biases)."""
        rates, mask = _checked_rates(omegas, mask)
        n = len(rates)
        return cls(n, tuple(Moments.pool_all(window_moments(rates[i], rates[j], int(window), mask=mask))
                            for i, j in itertools.combinations(range(n), 2)))

    # ------------------------------------------------------------------ algebra (pair by pair)
    def _check_same(self, other: "ArrayMoments"):
        if not isinstance(other, ArrayMoments) or other.n_gyros != self.n_gyros:
            raise InputError(f"expected ArrayMoments of {self.n_gyros} gyros, got "
                             f"{getattr(other, 'n_gyros', type(other).__name__)}")

    def merge(self, other: "ArrayMoments") -> "ArrayMoments":
        """Combine with moments of more samples that share the same biases (:meth:`Moments.merge`)."""
        self._check_same(other)
        return ArrayMoments(self.n_gyros, tuple(a.merge(b) for a, b in zip(self.pairs, other.pairs)))

    __add__ = merge

    def pool(self, other: "ArrayMoments") -> "ArrayMoments":
        """Combine with moments of samples that have their own biases (:meth:`Moments.pool`)."""
        self._check_same(other)
        return ArrayMoments(self.n_gyros, tuple(a.pool(b) for a, b in zip(self.pairs, other.pairs)))

    def decayed(self, factor: float) -> "ArrayMoments":
        """Down-weight all samples by ``factor`` in (0, 1] (exponential forgetting)."""
        return ArrayMoments(self.n_gyros, tuple(p.decayed(factor) for p in self.pairs))

    @staticmethod
    def merge_all(parts: Iterable["ArrayMoments"]) -> "ArrayMoments":
        """Merge a non-empty sequence of moments that share their biases."""
        parts = iter(parts)
        out = next(parts)
        for p in parts:
            out = out.merge(p)
        return out

    # ------------------------------------------------------------------ views
    def pair(self, i: int, j: int) -> Moments:
        """:class:`Moments` of ``[omega_i; omega_j]`` (gyro indices from 0)."""
        n = self.n_gyros
        if not (0 <= i < n and 0 <= j < n) or i == j:
            raise InputError(f"pair: expected two different gyro indices in [0, {n}), got ({i}, {j})")
        if i < j:
            return self.pairs[_pair_index(n, i, j)]
        return _swap(self.pairs[_pair_index(n, j, i)])

    @property
    def count(self) -> float:
        return self.pairs[0].count

    @property
    def segments(self) -> int:
        return self.pairs[0].segments

    @property
    def dof(self) -> float:
        return self.pairs[0].dof

    @property
    def mean(self) -> np.ndarray:
        """(3N,) mean of the stacked measurements."""
        n = self.n_gyros
        return np.concatenate([self.pair(k, (k + 1) % n).mean_1 for k in range(n)])

    @property
    def scatter(self) -> np.ndarray:
        """(3N, 3N) centred (or per-segment pooled) scatter of the stacked measurements."""
        n = self.n_gyros
        S = np.empty((3 * n, 3 * n))
        for k in range(n):
            S[3 * k:3 * k + 3, 3 * k:3 * k + 3] = self.pair(k, (k + 1) % n).S11
        for i, j in itertools.combinations(range(n), 2):
            block = self.pairs[_pair_index(n, i, j)].S12
            S[3 * i:3 * i + 3, 3 * j:3 * j + 3] = block
            S[3 * j:3 * j + 3, 3 * i:3 * i + 3] = block.T
        return S


def as_array_rates(omegas) -> list[np.ndarray]:
    """Return N read-only-safe ``(n_samples, 3)`` arrays from an (n, N, 3) array or a sequence."""
    if isinstance(omegas, np.ndarray) or not isinstance(omegas, Sequence):
        arr = np.asarray(omegas)
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise InputError(f"omegas: expected shape (n_samples, n_gyros, 3) or a sequence of (n_samples, 3) "
                             f"arrays, got shape {arr.shape}")
        rates = [as_rates(f"omegas[:, {k}]", arr[:, k, :]) for k in range(arr.shape[1])]
    else:
        rates = [as_rates(f"omegas[{k}]", w) for k, w in enumerate(omegas)]
    if len(rates) < 2:
        raise InputError(f"omegas: expected at least 2 gyros, got {len(rates)}")
    n = rates[0].shape[0]
    for k, w in enumerate(rates):
        if w.shape[0] != n:
            raise InputError(f"gyro {k + 1}: expected {n} samples (the length of gyro 1), got {w.shape[0]}; "
                             "the array calibration needs sample-aligned streams")
    return rates


def check_distinct(names, rates) -> None:
    """Refuse the same stream given for two gyros: bit-identical ``rates`` (arrays of any shape, at least 4
    samples, not constant: fewer and constant ones have their own messages) under two of ``names``. Two gyros never give identical samples (their noise differs), so it is one recording passed twice;
    the pair it makes has no residual to weigh anything with.

    Raises
    ------
    InputError
        Naming every duplicated pair.
    """
    arrays: dict = {}
    groups: dict = {}
    for k, w in enumerate(rates):          # cheap fingerprint first, full comparison within a group
        try:
            arrays[k] = w = np.asarray(w, dtype=np.float64)
        except (TypeError, ValueError):
            continue                       # not numbers: the rates' own check says so
        if w.ndim == 0 or len(w) < 4:
            continue                       # too few samples: their own check says so
        groups.setdefault((w.shape, w.reshape(-1)[:48].tobytes()), []).append(k)
    # only streams that share a fingerprint are read whole: constant ones have their own message
    groups = {key: [k for k in g if not _constant(arrays[k])] for key, g in groups.items() if len(g) > 1}
    same = [(a, b) for g in groups.values() for a, b in itertools.combinations(g, 2)
            if np.array_equal(arrays[a], arrays[b], equal_nan=True)]
    if same:
        pairs = ", ".join(f"{names[a]} and {names[b]}" for a, b in same)
        raise InputError(f"{pairs}: expected one stream per gyro, got identical samples (the same recording "
                         "given twice?)")


def _constant(w: np.ndarray) -> bool:
    """Every entry of ``w`` equal to its first (a NaN first: never), read whole only when its first rows are."""
    flat = w.reshape(-1)
    if flat.size == 0:
        return True
    return not np.any(flat[:4096] != flat[0]) and not np.any(flat != flat[0])


def _checked_rates(omegas, mask):
    """The rates of :func:`as_array_rates` and the mask as bool, checked: finite wherever the mask keeps, no
    stream given twice (:func:`check_distinct`)."""
    rates = as_array_rates(omegas)
    check_distinct([f"gyro {k + 1}" for k in range(len(rates))], rates)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        n = rates[0].shape[0]
        if mask.shape != (n,):
            raise InputError(f"mask: expected shape ({n},), got {mask.shape}")
    for k, w in enumerate(rates):
        bad = ~finite_rows(w)
        if mask is not None:
            bad &= mask
        if bad.any():
            idx = np.flatnonzero(bad)
            raise InputError(f"gyro {k + 1}: expected finite rates, got a non-finite value at sample {idx[0]} "
                             f"({idx.size} such sample(s)); mask or drop those samples first")
    return rates, mask


def _G_of(s_ref, k) -> np.ndarray:
    """``S_ref^-1 (I + K)^-1 S_ref``: the reference's view of a gyro's relative cross-axis terms ``k``."""
    M = np.linalg.inv(np.eye(3) + cross_matrix(k))
    return (M / s_ref[:, None]) * s_ref[None, :]


def _H_of(R, s, k=None, reference: int = 0):
    """Stacked design ``H = [S_j R_ref_j^T G_j]_j`` (3N, 3), ``G_j`` of :func:`_G_of` (the identity without
    cross-axis terms ``k``, (N, 3))."""
    if k is None:
        return np.concatenate([s[j][:, None] * R[j].T for j in range(len(s))])
    return np.concatenate([(s[j][:, None] * R[j].T) @ _G_of(s[reference], k[j]) for j in range(len(s))])


def _projector(H, sig2):
    """``P = Sigma^-1 - Sigma^-1 H M^-1 H^T Sigma^-1`` and ``K = M^-1 H^T Sigma^-1``, ``M^-1``."""
    w = 1.0 / np.repeat(sig2, 3)
    WH = H * w[:, None]
    Minv = np.linalg.inv(H.T @ WH)
    K = Minv @ WH.T
    P = np.diag(w) - WH @ K
    return 0.5 * (P + P.T), K, Minv


def _dH(R, s, k=None, reference: int = 0):
    """Derivatives (6N, 3N, 3) of H w.r.t. ``[dtheta_0..N-1, log s_0..N-1]``; (9N, 3N, 3) with the cross-axis
    terms ``k_0..N-1`` appended.

    ``R_j <- Exp(dtheta_j) R_j`` gives ``dH_j = -S_j R_j^T [e_m x] G_j``; ``s_j,i <- s_j,i e^dl`` scales row i of
    H_j; with cross-axis terms the reference's scale factors also enter every ``G_j`` (``dG = G E_ii - E_ii G``)
    and ``dG_j / dk_j,m = -S_ref^-1 (I + K_j)^-1 E_m (I + K_j)^-1 S_ref`` (``E_m`` = ``cross_matrix(e_m)``).
    """
    n = len(s)
    full = k is not None
    eye = np.eye(3)
    D = np.zeros(((9 if full else 6) * n, 3 * n, 3))
    for j in range(n):
        rows = slice(3 * j, 3 * j + 3)
        SRt = s[j][:, None] * R[j].T
        G = _G_of(s[reference], k[j]) if full else eye
        Hj = SRt @ G
        for m in range(3):
            D[3 * j + m, rows] = -SRt @ skew(eye[m]) @ G
        for i in range(3):
            D[3 * n + 3 * j + i, 3 * j + i] = Hj[i]
        if full:
            M = np.linalg.inv(eye + cross_matrix(k[j]))
            for i in range(3):
                E = np.zeros((3, 3))
                E[i, i] = 1.0
                D[3 * n + 3 * reference + i, rows] += SRt @ (G @ E - E @ G)
            for m in range(3):
                dG = -(M @ cross_matrix(eye[m]) @ M) / s[reference][:, None] * s[reference][None, :]
                D[6 * n + 3 * j + m, rows] = SRt @ dG
    return D


def joint_cost(R, s, scatter, noise_std, k=None, reference: int = 0) -> float:
    """Negative log-likelihood (times 2, up to a constant) of the array model, ``tr(P S_c)``.

    Parameters
    ----------
    R : (N, 3, 3) rotations ``R_ref_k``; s : (N, 3) scale factors; scatter : (3N, 3N) centred scatter;
    noise_std : (N,) white-noise std per gyro (rad/s); k : (N, 3) relative cross-axis terms of every gyro
    against the reference (the full linear map, zero for the reference), optional; reference : its index.
    """
    P, _, _ = _projector(_H_of(R, s, k, reference), np.asarray(noise_std, float) ** 2)
    return float(np.sum(P * scatter))


def joint_gradient(R, s, scatter, noise_std, k=None, reference: int = 0) -> np.ndarray:
    """Gradient of :func:`joint_cost` w.r.t. ``[dtheta_0..N-1, log s_0..N-1]`` (and ``k_0..N-1`` with ``k``):
    ``-2 tr(P dH K S_c)``."""
    P, K, _ = _projector(_H_of(R, s, k, reference), np.asarray(noise_std, float) ** 2)
    KS = K @ scatter
    return -2.0 * np.einsum("ab,pbc,ca->p", P, _dH(R, s, k, reference), KS)


def joint_information(R, s, noise_std, Omega_c, k=None, reference: int = 0) -> np.ndarray:
    """Fisher information (6N, 6N) of ``[dtheta, log s]`` with rates and biases profiled out ((9N, 9N) with the
    cross-axis terms ``k``).

    ``I_pq = tr(D_p^T P D_q Omega_c)`` with ``D_p = dH/dp`` and ``Omega_c`` the centred scatter of the
    true rate (Appendix B generalised: the information of the errors-in-variables model).
    """
    P, _, _ = _projector(_H_of(R, s, k, reference), np.asarray(noise_std, float) ** 2)
    D = _dH(R, s, k, reference)
    PD = np.einsum("ab,qbc->qac", P, D)
    DO = np.einsum("pab,bc->pac", D, Omega_c)
    F = np.einsum("pac,qac->pq", DO, PD)
    return 0.5 * (F + F.T)


def _window_scores(R, s, noise_std, windows: WindowStats, k=None, reference: int = 0) -> np.ndarray:
    """Scores (W, 6N or 9N) of :func:`joint_cost` per window: :func:`joint_gradient` is linear in the scatter."""
    from .robust import centred_scatters

    P, K, _ = _projector(_H_of(R, s, k, reference), np.asarray(noise_std, float) ** 2)
    PD = np.einsum("ab,pbc->pac", P, _dH(R, s, k, reference))  # (p, 3N, 3)
    KS = np.matmul(K, centred_scatters(windows))                # (W, 3, 3N)
    return -2.0 * np.einsum("pac,wca->wp", PD, KS)


def _signal_scatter(R, s, scatter, noise_std, dof, k=None, reference: int = 0):
    """Noise-corrected centred scatter of the common rate, ``K S_c K^T - dof M^-1`` (clipped PSD)."""
    _, K, Minv = _projector(_H_of(R, s, k, reference), np.asarray(noise_std, float) ** 2)
    X = K @ scatter @ K.T - dof * Minv
    w, V = np.linalg.eigh(0.5 * (X + X.T))
    return (V * np.clip(w, 0.0, None)) @ V.T


def _retract(R, s, delta):
    n = len(s)
    rot = exp(delta[:3 * n].reshape(n, 3))
    return np.einsum("kij,kjl->kil", rot, R), s * np.exp(delta[3 * n:6 * n].reshape(n, 3))


def _describe(gauge: Gauge, n: int, n_groups: int) -> str:
    text = gauge.describe(tuple(f"scale[{k}]" for k in range(n)))
    if n_groups > 1:
        text += f"; {n_groups} groups of linked axes, each other group at its members' unit prior"
    return text


def _scale_groups(R, n, tol):
    """Union of the linked-scale groups of every pair (Lemmas 2-4); also the pair configurations."""
    parent = {(k, a): (k, a) for k in range(n) for a in range(3)}

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    configs = [[""] * n for _ in range(n)]
    for i, j in itertools.combinations(range(n), 2):
        conf = classify(R[i].T @ R[j], tol)
        configs[i][j] = configs[j][i] = conf.name
        for group in conf.groups:
            ms = [(i if g == 0 else j, a) for g, a in group]
            for m in ms[1:]:
                parent[find(m)] = find(ms[0])
    groups = {}
    for k in range(n):
        for a in range(3):
            groups.setdefault(find((k, a)), []).append((k, a))
    groups = tuple(tuple(sorted(g)) for g in sorted(groups.values()))
    return groups, tuple(tuple(c) for c in configs)


def _observable(groups, n):
    """Scale factors determined up to the global scale: the largest group, if it links two axes of a gyro."""
    obs = np.zeros((n, 3), dtype=bool)
    if len(groups) == 1:
        obs[:] = True
        return obs
    best = max(groups, key=len)
    gyros = [g for g, _ in best]
    if len([x for x in groups if len(x) == len(best)]) == 1 and len(set(gyros)) < len(gyros):
        for g, a in best:
            obs[g, a] = True
    return obs


# ---------------------------------------------------------------------------------------- seeds and noise
def _seed(moments: ArrayMoments, reference, noise_std, parallel_tol_deg, min_snr):
    """Rotations from the pairwise direct solutions to the reference; log scales by least squares
    on the ratios every pair determines."""
    n = moments.n_gyros
    R = np.tile(np.eye(3), (n, 1, 1))
    rows, rhs = [], []
    for k in range(n):
        if k == reference:
            continue
        pn = None if noise_std is None else (noise_std[reference], noise_std[k])
        try:
            pc = solve(moments.pair(reference, k), method="direct", noise_std=pn, parallel_tol_deg=parallel_tol_deg,
                       min_snr=min_snr)
        except GyroCalError as err:  # name the gyro: the pair solver only knows "gyro 1" and "gyro 2"
            raise type(err)(f"gyro {k + 1} against the reference gyro {reference + 1} (as gyro 1 / gyro 2): "
                            f"{err}") from err
        R[k] = pc.R_1_2
        lp = np.log(np.stack([pc.scale_1, pc.scale_2]))
        for group in classify(pc.R_1_2, parallel_tol_deg).groups:
            (g0, a0), rest = group[0], group[1:]
            for g, a in rest:
                row = np.zeros(3 * n)
                row[3 * (reference if g == 0 else k) + a] += 1.0
                row[3 * (reference if g0 == 0 else k) + a0] -= 1.0
                rows.append(row)
                rhs.append(lp[g, a] - lp[g0, a0])
    l = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)[0] if rows else np.zeros(3 * n)
    return R, np.exp(l.reshape(n, 3))


def _pair_map(R, s, k, reference: int, i: int, j: int) -> np.ndarray:
    """``A_ij = H_i H_j^-1``, the map of the pair (``omega_i_meas ~ A_ij omega_j_meas``): ``A_of(R_ref_i^T R_ref_j,
    s_i, s_j)`` without cross-axis terms, ``(I + K_j) S_ref R_ref_j S_j^-1`` for ``i`` the reference."""
    H = [(s[g][:, None] * R[g].T) @ (np.eye(3) if k is None else _G_of(s[reference], k[g])) for g in (i, j)]
    return H[0] @ np.linalg.inv(H[1])


def _noise_from_pairs(moments: ArrayMoments, R, s, k=None, reference: int = 0):
    """Per-gyro white-noise std from every pair's residual ``y_i - A_ij y_j`` (three-cornered hat).

    ``E[r r^T] = sigma_i^2 I + sigma_j^2 A A^T``: one linear equation in the variances per pair,
    solved by non-negative least squares; with two gyros only the sum is observable and is split
    equally (as :func:`fusion_gyrocal.solve`).
    """
    n = moments.n_gyros
    X, y = [], []
    for i, j in itertools.combinations(range(n), 2):
        m = moments.pairs[_pair_index(n, i, j)]
        A = _pair_map(R, s, k, reference, i, j)
        row = np.zeros(n)
        row[i] += 3.0
        row[j] += float(np.trace(A @ A.T))
        X.append(row)
        y.append(float(np.trace(residual_scatter(A, m.scatter))) / max(m.dof - 3.0, 1.0))
    X, y = np.array(X), np.array(y)
    if n == 2:
        v = np.full(2, y[0] / X[0].sum())
    else:
        from scipy.optimize import nnls   # only here: keeps scipy.optimize off the command line's start-up

        v = nnls(X, y)[0]
    floor = max(1e-24 * float(np.trace(moments.pairs[0].S11)) / (3.0 * max(moments.dof, 1.0)),
                (0.1 * np.sqrt(np.median(v))) ** 2 if np.median(v) > 0 else 0.0)
    return np.sqrt(np.maximum(v, floor))


def _refine(x, moments_scatter, dof, noise, constraints, regauge, max_iter, prior_std, reference, tol=1e-11):
    """Joint maximum likelihood of ``x = (R, s, k)`` (``k`` None: the rigid model) by
    :func:`~fusion_gyrocal.core.refine.fisher_scoring` in the gauge's tangent space; the cross-axis terms carry the
    prior ``N(0, prior_std^2)`` (:func:`~fusion_gyrocal.core.linear_map.refine_full`'s)."""
    full = x[2] is not None
    n = len(x[1])

    def step(x, delta):
        Rn, sn = _retract(x[0], x[1], delta)
        return Rn, regauge(sn), (x[2] + delta[6 * n:].reshape(n, 3) if full else None)

    def cost(x):
        c = joint_cost(x[0], x[1], moments_scatter, noise, x[2], reference)
        return c + float(np.sum(x[2] ** 2)) / prior_std**2 if full else c

    def gradient(x):
        g = joint_gradient(x[0], x[1], moments_scatter, noise, x[2], reference)
        if full:
            g[6 * n:] += 2.0 * x[2].ravel() / prior_std**2
        return g

    def information(x):
        F = joint_information(x[0], x[1], noise, _signal_scatter(*x[:2], moments_scatter, noise, dof, x[2], reference),
                              x[2], reference)
        return 2.0 * (F + _prior_information(n, prior_std) if full else F)

    x, it, converged = fisher_scoring(x, cost=cost, gradient=gradient, information=information, retract=step,
                                      constraints=lambda x: constraints(x[1]), max_iter=max_iter, tol=tol)
    return x, it, converged


def _prior_information(n: int, prior_std: float) -> np.ndarray:
    """Information (9N, 9N) of the prior ``N(0, prior_std^2)`` on every cross-axis term (zero elsewhere)."""
    F = np.zeros((9 * n, 9 * n))
    F[6 * n:, 6 * n:] = np.eye(3 * n) / prior_std**2
    return F


def _pair_windows(windows: WindowStats | None, i: int, j: int) -> WindowStats | None:
    """The per-window statistics of gyros ``i`` and ``j`` (as gyro 1 and gyro 2) from the stacked ones."""
    if windows is None:
        return None
    idx = np.r_[3 * i:3 * i + 3, 3 * j:3 * j + 3]
    return dataclasses.replace(windows, mean=windows.mean[:, idx], scatter=windows.scatter[:, idx][:, :, idx])


def _cross_axis_tests(moments: ArrayMoments, R, s, noise, windows, reference, o: Options):
    """Every gyro's cross-axis test against the reference (:func:`~fusion_gyrocal.core.robust.cross_axis` on its
    pair's moments at the joint rigid estimate) and the model it gets: :func:`choose_full_map`'s, except that with
    ``linear_map="auto"`` every gyro gets the full map once the data show cross-axis terms on any one of them.
    Outside the axis-parallel configurations one test sees a single combination of a gyro's three terms, which can
    be small by chance while the others turn its rotation by a degree; cross-axis sensitivity is a property of the
    chips, so terms shown on one gyro are expected on all. Returns ``(chi2 (N,), dof (N,), full (N,), shown (N,))``.
    """
    n = moments.n_gyros
    chi2, dof = np.full(n, np.nan), np.zeros(n, int)
    full, shown = np.zeros(n, bool), np.zeros(n, bool)
    for j in range(n):
        if j == reference:
            continue
        m = moments.pair(reference, j)
        A_ls, _ = solve_A(m)
        _, chi2[j], dof[j] = cross_axis(A_ls, R[j], s[reference], s[j], m, (noise[reference], noise[j]),
                                        _pair_windows(windows, reference, j),
                                        n_null=len(classify(R[j], o.parallel_tol_deg).groups))
        full[j], shown[j] = choose_full_map(o.linear_map, "ml", float(chi2[j]), int(dof[j]))
    if o.linear_map == "auto" and shown.any():   # the chips have cross-axis terms: every gyro gets them
        full[np.arange(n) != reference] = True
    return chi2, dof, full, shown


def _cross_budget(k, P, reference, shown, prior_std) -> np.ndarray:
    """The rotations' covariance (3N, 3N) from the antisymmetric cross-axis parts no data see (the array's
    :func:`~fusion_gyrocal.core.linear_map.cross_axis_budget`).

    Every pair's relative terms ``k_j - k_i`` (``k_ref = 0``, reference axes) give, as in the pair solver, a variance
    ``b_ij`` per axis of their antisymmetric part (pooled with the prior where the data show cross-axis terms on
    either gyro). ``R_ref_j`` carries its pair's ``b_j`` (the pair solver's figure) and two rotations share
    ``(b_i + b_j - b_ij) / 2``, so the rotation between gyros i and j, ``R_ref_i^T R_ref_j``, carries its pair's
    ``b_ij``, as far as a covariance can (the nearest positive semi-definite matrix).
    """
    n = len(k)
    Pk = P[6 * n:, 6 * n:]

    def budget(i, j):
        d = k[j] - k[i]
        Pd = (Pk[3 * j:3 * j + 3, 3 * j:3 * j + 3] + Pk[3 * i:3 * i + 3, 3 * i:3 * i + 3]
              - Pk[3 * i:3 * i + 3, 3 * j:3 * j + 3] - Pk[3 * j:3 * j + 3, 3 * i:3 * i + 3])
        return cross_axis_budget(d, Pd, prior_std if (shown[i] or shown[j]) else None)

    C = np.zeros((n, n))
    for j in range(n):
        if j != reference:
            C[j, j] = budget(reference, j)
    for i, j in itertools.combinations(range(n), 2):
        if reference not in (i, j):
            C[i, j] = C[j, i] = 0.5 * (C[i, i] + C[j, j] - budget(i, j))
    w, V = np.linalg.eigh(C)
    C = (V * np.clip(w, 0.0, None)) @ V.T
    return np.kron(C, np.eye(3))


# ---------------------------------------------------------------------------------------- public solvers
def solve_array(moments: ArrayMoments, options: Options | None = None, *, reference: int = 0, max_iter: int = 50,
                windows: WindowStats | None = None, noise_source: str | None = None, **keywords) -> ArrayCalibration:
    """Jointly calibrate N gyros from their pairwise sufficient statistics (maximum likelihood).

    Parameters
    ----------
    moments : ArrayMoments
        Statistics of N sample-aligned gyros (pooled per segment for piecewise-constant biases).
    options : Options, optional
        The options (:class:`~fusion_gyrocal.options.Options`, for ``gyros=N``); those that do not apply to the
        joint calibration are refused (:meth:`~fusion_gyrocal.options.Options.require`), those that act on samples
        (``bias_window``, ``noise_model``) play no part here. The ones used:

        ``noise_std``
            White-noise std per sample of every gyro (rad/s), one value or N. Default: from the pairwise
            residuals (three-cornered hat for N >= 3; equal split for N = 2, where only the sum is observable).
        ``gauge``
            ``"unit_prior"``: the x-axis scale factors of all gyros as close to 1 as their determined ratios
            allow (Eq. 32-34 generalised); ``"fixed"``: ``scale[reference][0] == 1``; or a
            :class:`~fusion_gyrocal.core.gauge.Gauge` (gyros counted from 0). Groups of linked axes that hold no
            gauge member follow the unit prior over their own members.
        ``parallel_tol_deg``
            Axes closer than this to (anti)parallel are treated as parallel (see :func:`classify`).
        ``min_snr``
            Smallest SNR of any principal motion direction accepted for every gyro pair with the reference
            (Lemma 1).
        ``covariance``
            What is reported with ``windows`` (``"auto"``, ``"model"``, ``"robust"``).
        ``linear_map``, ``cross_axis_std``
            Every gyro's sensor model against the reference and the prior of its cross-axis terms (module
            docstring; :class:`~fusion_gyrocal.options.Options`).
    reference : int
        Index of the reference gyro (its frame is the array frame, ``R_ref_k[reference] = I``).
    max_iter : int
        Fisher-scoring iterations at most (per noise update).
    windows : WindowStats, optional
        Per-window statistics of the stacked gyros (:func:`~fusion_gyrocal.core.moments.stacked_window_stats`):
        with them the covariance is also computed block-robustly (:mod:`~fusion_gyrocal.core.robust`) and
        ``covariance`` chooses what is reported (:func:`~fusion_gyrocal.core.robust.reported_covariance`, the
        pair solver's policy).
    noise_source : str, optional
        Where a given ``noise_std`` came from (default ``"user"``).
    **keywords
        Fields of :class:`~fusion_gyrocal.options.Options`, applied on top of ``options``.

    Returns
    -------
    ArrayCalibration

    Raises
    ------
    InputError
        Fewer than 4 samples.
    OptionError
        Reference out of range, bad ``noise_std`` or ``gauge``, an option the joint calibration does not apply.
    ExcitationError
        Motion that does not determine every gyro's rotation (Lemma 1).
    """
    if not isinstance(moments, ArrayMoments):
        raise InputError(f"moments: expected ArrayMoments, got {type(moments).__name__}")
    n = moments.n_gyros
    o = Options.of(options, gyros=n, **keywords).require("array", "solve_array")
    if not (isinstance(reference, (int, np.integer)) and 0 <= reference < n):
        raise OptionError(f"reference: expected a gyro index in [0, {n}), got {reference!r}")
    reference = int(reference)
    if moments.count < 4:
        raise InputError(f"expected at least 4 samples (Lemma 1), got {int(moments.count)}")
    gauge = Gauge.parse(o.gauge, n, reference)
    user_noise = None if o.noise_std is None else np.asarray(o.noise_std, dtype=float)
    parallel_tol_deg = o.parallel_tol_deg

    R, s = _seed(moments, reference, user_noise, parallel_tol_deg, o.min_snr)
    groups, configs = _scale_groups(R, n, parallel_tol_deg)
    s = gauge.apply(groups, s)
    Sc, dof = moments.scatter, moments.dof
    fix_reference = np.eye(3, 6 * n, 3 * reference)   # the reference's rotation is the array frame

    def constraints(sc, held=None):
        """Linearised conditions on ``[dtheta (3n), log s (3n)]``: the reference rotation, then the gauge; with
        ``held`` (N,) bool, on ``[dtheta, log s, k (3n)]`` with those gyros' cross-axis terms held at zero."""
        C = np.vstack([fix_reference, gauge.constraints(groups, sc, leading=3 * n)])
        if held is None:
            return C
        rows = np.eye(9 * n)[[6 * n + 3 * j + m for j in np.flatnonzero(held) for m in range(3)]]
        return np.vstack([np.hstack([C, np.zeros((len(C), 3 * n))]), rows])

    def regauge(sc):
        return gauge.apply(groups, sc)

    (R, s, _), noise, total_it, converged = _fit(moments, (R, s, None), user_noise, constraints, regauge, max_iter,
                                                 o.cross_axis_std, reference)
    # the sensor model every gyro's data call for (the pair solver's test, against the reference)
    chi2, cdof, full, shown = _cross_axis_tests(moments, R, s, noise, windows, reference, o)
    k, held = None, None
    if full.any():
        held = ~full

        def constraints_full(sc):
            return constraints(sc, held)

        (R, s, k), noise, it, converged = _fit(moments, (R, s, np.zeros((n, 3))), user_noise, constraints_full,
                                               regauge, max_iter, o.cross_axis_std, reference)
        total_it += it
    if user_noise is not None:
        noise_source = noise_source or "user"
    else:
        noise_source = ("residual (three-cornered hat over all pairs)" if n > 2
                        else "residual (split equally between the gyros)")
    notes = [] if converged else [f"joint maximum-likelihood refinement stopped after {total_it} iterations without "
                                  "converging"]

    # covariance: inverse Fisher information in the gauge's tangent space (with the cross-axis prior)
    Omega = _signal_scatter(R, s, Sc, noise, dof, k, reference)
    F = joint_information(R, s, noise, Omega, k, reference)
    if k is not None:
        F = F + _prior_information(n, o.cross_axis_std)
    C = constraints(s, held)
    P = constrained_inverse(F, C)
    cost = joint_cost(R, s, Sc, noise, k, reference)
    chi2_dof = max(3.0 * (n - 1) * dof - (len(F) - len(C)), 1.0)
    ratio = cost / chi2_dof

    def robust():
        V = score_variance(_window_scores(R, s, noise, windows, k, reference), windows)
        if k is not None:   # the cross-axis prior's part of the scores' variance (the model's)
            V = V + 4.0 * _prior_information(n, o.cross_axis_std)
        return sandwich(F, V, C)

    P, inflation, basis_kind, basis, more = reported_covariance(
        P, robust, windows, o.covariance, "noise model (inverse Fisher information, Appendix B)", ratio,
        user_noise=user_noise is not None, what="flex, skew, timing")
    notes += more

    bias, cov, cross_cov = _bias_and_covariance(moments, R, s, k, P, noise, reference)
    skew_cov = np.zeros((3 * n, 3 * n)) if k is None else _cross_budget(k, P, reference, shown, o.cross_axis_std)
    cov[:3 * n, :3 * n] += skew_cov
    residual_rms = _residual_rms(R, s, Sc, dof, noise, k, reference)
    snr = np.sqrt(np.clip(np.diag(Omega), 0.0, None)) / noise[reference]
    obs = _observable(groups, n)
    notes += _model_notes(k, P, chi2, cdof, full, shown, skew_cov, reference)
    if len(groups) > 1:
        notes.append(f"{len(groups)} groups of linked scale factors (axis-parallel gyros, Lemmas 2-3); only ratios "
                     "within a group are determined")
    return ArrayCalibration(
        R_ref_k=R, scale=s, bias=bias, reference=reference, scale_observable=obs, scale_groups=groups,
        configurations=configs, covariance=cov, gauge=_describe(gauge, n, len(groups)), snr=snr,
        n_samples=int(moments.count), noise_std=noise, noise_source=noise_source, residual_rms=residual_rms,
        iterations=total_it, bias_segments=moments.segments, notes=tuple(notes), moments=moments,
        covariance_basis=basis, covariance_kind=basis_kind, robust_inflation=inflation,
        linear_map=tuple("" if j == reference else "full" if full[j] else "rigid" for j in range(n)),
        cross_axis_terms=np.zeros((n, 3)) if k is None else k, cross_axis_covariance=cross_cov,
        cross_axis_chi2=chi2, cross_axis_dof=tuple(int(v) for v in cdof), skew_rotation_covariance=skew_cov)


def _model_notes(k, P, chi2, dof, full, shown, skew_cov, reference) -> list:
    """The notes on every gyro's sensor model (as the pair solver's)."""
    n = len(full)
    notes = []
    if k is not None:
        sd = np.sqrt(np.clip(np.diag(P)[6 * n:], 0.0, None)).reshape(n, 3)
        terms = "; ".join(f"gyro {j + 1}: " + ", ".join(f"{a} {100 * v:.3g} +- {100 * e:.2g} %"
                                                     for a, v, e in zip(("xy", "yz", "zx"), k[j], sd[j]))
                          + f" (chi2 {chi2[j]:.3g} for {dof[j]} dof)" for j in np.flatnonzero(full))
        budget = np.sqrt(np.diag(skew_cov)[[3 * j for j in np.flatnonzero(full)]])
        notes.append(f"full linear map (omega_ref = (I + K_j) S_ref R_ref_j S_j^-1 omega_j): symmetric relative "
                     f"cross-axis terms against gyro {reference + 1}: {terms}. R_ref_k are the rotations under the "
                     "symmetric convention, repeatable from session to session; the chip-to-chip rotations differ "
                     "from them by the antisymmetric parts, which no data see: budgeted at "
                     f"{np.rad2deg(budget.min()):.3g}-{np.rad2deg(budget.max()):.3g} deg per axis "
                     "(skew_rotation_covariance, included in the covariance)")
    shown_rigid = [j for j in range(n) if shown[j] and not full[j]]
    if shown_rigid:
        notes.append("the full linear map fits significantly better than rotation + scale factors for gyro(s) "
                     + ", ".join(f"{j} (chi2 {chi2[j]:.3g} for {dof[j]} dof)" for j in shown_rigid)
                     + " (p < 0.001): use linear_map='auto' or 'full'")
    return notes


def _fit(moments, x, user_noise, constraints, regauge, max_iter, prior_std, reference):
    """Fisher scoring with the given noise, or alternating with the noise of the pairwise residuals (weights from
    the current fit, fit with the current weights): ``(x, noise, iterations, converged)``."""
    Sc, dof = moments.scatter, moments.dof
    if user_noise is not None:
        x, it, converged = _refine(x, Sc, dof, user_noise, constraints, regauge, max_iter, prior_std, reference)
        return x, user_noise, it, converged
    noise, total = _noise_from_pairs(moments, *x, reference), 0
    for _ in range(4):
        x, it, converged = _refine(x, Sc, dof, noise, constraints, regauge, max_iter, prior_std, reference)
        total += it
        new = _noise_from_pairs(moments, *x, reference)
        done = np.max(np.abs(new / noise - 1.0)) < 1e-3
        noise = new
        if done:
            break
    return x, noise, total, converged


def _bias_and_covariance(moments, R, s, k, P, noise, reference):
    """The biases against the reference (Eq. 5, 12), the (9N, 9N) covariance of ``[dtheta, scale, bias]`` and
    the (3N, 12N) covariance of the cross-axis terms with ``[dtheta, scale, bias, k]``, from the covariance ``P``
    of ``[dtheta_all, log s_all]`` (and ``k_all`` with the full map)."""
    n = moments.n_gyros
    full = k is not None
    means = moments.mean.reshape(n, 3)
    bias = np.zeros((n, 3))
    T = np.zeros((12 * n, P.shape[0]))   # [dtheta, scale, bias, k] from [dtheta, log s (, k)]
    T[:3 * n, :3 * n] = np.eye(3 * n)
    T[3 * n:6 * n, 3 * n:6 * n] = np.diag(s.ravel())
    if full:
        T[9 * n:, 6 * n:] = np.eye(3 * n)
    noise_part = np.zeros((12 * n, 12 * n))
    for j in range(n):
        if j == reference:
            continue
        kj = None if k is None else k[j]
        A = A_of(R[j], s[reference], s[j], kj)
        bias[j] = means[reference] - A @ means[j]
        Dj = dA_dp(R[j], s[reference], s[j], kj)  # w.r.t. [dtheta_j, log s_ref, log s_j (, k_j)]
        idx = np.r_[3 * j:3 * j + 3, 3 * n + 3 * reference:3 * n + 3 * reference + 3, 3 * n + 3 * j:3 * n + 3 * j + 3]
        if full:
            idx = np.r_[idx, 6 * n + 3 * j:6 * n + 3 * j + 3]
        bj = slice(6 * n + 3 * j, 6 * n + 3 * j + 3)
        T[bj, idx] = -np.einsum("pij,j->ip", Dj, means[j])
        noise_part[bj, bj] += noise[j] ** 2 * A @ A.T / moments.count
        for l in range(n):
            if l != reference:
                noise_part[bj, 6 * n + 3 * l:6 * n + 3 * l + 3] += noise[reference] ** 2 * np.eye(3) / moments.count
    full_cov = T @ P @ T.T + noise_part
    full_cov = 0.5 * (full_cov + full_cov.T)
    return bias, full_cov[:9 * n, :9 * n], (full_cov[9 * n:] if full else np.zeros((3 * n, 12 * n)))


def _residual_rms(R, s, Sc, dof, noise, k=None, reference: int = 0):
    """Per-gyro residual RMS against the fitted common rate: ``e = Sigma P y``."""
    n = len(noise)
    Pm, _, _ = _projector(_H_of(R, s, k, reference), noise**2)
    E = np.repeat(noise**2, 3)[:, None] * Pm
    Res = E @ Sc @ E.T
    return np.sqrt(np.clip([np.trace(Res[3 * g:3 * g + 3, 3 * g:3 * g + 3]) for g in range(n)], 0, None)
                   / (3.0 * max(dof, 1.0)))


def calibrate_array(omegas, options: Options | None = None, *, reference: int = 0, mask=None,
                    rate_hz: float | None = None, t=None, resampling=None, **keywords) -> ArrayCalibration:
    """Jointly calibrate N rigidly mounted gyroscopes from sample-aligned angular rates.

    Parameters
    ----------
    omegas : array_like (n_samples, N, 3) or sequence of N arrays (n_samples, 3)
        Measured rates (rad/s) of every gyro at the same instants.
    options : Options, optional
        :class:`~fusion_gyrocal.options.Options` (``gyros`` is set to N; per-gyro values given in ``options``
        must be for N gyros). An option that does not apply to the joint calibration (``applies_to`` without
        ``"array"``: ``method``, ``scale_prior_std``, the time alignment, ...) set away from its default is
        refused. The ones used:

        ``noise_std``
            White-noise std per sample (rad/s), one value or one per gyro (N); estimated when omitted.
        ``gauge``, ``parallel_tol_deg``, ``min_snr``, ``covariance``, ``linear_map``, ``cross_axis_std``
            See :func:`solve_array`.
        ``bias_window``
            Model every bias as piecewise constant over windows of this many samples.
        ``noise_model``
            Where the noise comes from without ``noise_std``: ``"identify"``, each gyro's white noise identified
            from its pair with the reference (:func:`~fusion_gyrocal.core.noise.identify_noise`: the pair's
            residual, split by steady stretches or third differences), or ``"residual"``, the pairwise
            least-squares residuals (three-cornered hat), which also carry every model error.
        ``flex_rejection``
            Accepted and without effect: the joint calibration has no flex gate (Eq. 42 is per pair).
        ``timing_model``
            ``"auto"`` (default): every gyro's delay against the reference beyond the time offset, found in the
            residuals of its pair with the reference, fitted directly
            (:func:`~fusion_gyrocal.pipeline.timing.estimate_array_timing`:
            one delay per chip, the beat of its sampling clock against the read-out, or a constant group delay;
            gyro j's is the difference of its chip's and the reference chip's), compensated, and the array
            calibrated on the moved samples (the noise identified on those); ``"off"``: none.
    reference : int
        Index of the reference gyro.
    mask : array_like of bool (n_samples,), optional
        Samples to use (e.g. False where any gyro saturates).
    rate_hz : float, optional
        Sample rate (Hz): windows of about a second for the noise model and the block-robust covariance
        (:func:`~fusion_gyrocal.core.moments.window_samples`; per sample without it). Taken from ``t`` when
        only ``t`` is given.
    t : array_like (n_samples,), optional
        The samples' instants (s, one clock, strictly increasing): the timing model's time base. Default: the
        sample index over ``rate_hz``, or the sample index without it (delays then in samples, tones in cycles per
        sample).
    resampling : Resampling, optional
        How each gyro's stream reached the samples (:class:`~fusion_gyrocal.core.noise.Resampling` with one entry
        per gyro in each field, as :func:`~fusion_gyrocal.pipeline.array.calibrate_streams` gives it): the
        identified noise is then split between each pair's gyros as their own rates and resampling make it.
    **keywords
        Fields of :class:`~fusion_gyrocal.options.Options` (``noise_std``, ``gauge``, ``bias_window``, ...),
        applied on top of ``options``.

    Returns
    -------
    ArrayCalibration

    Examples
    --------
    >>> import numpy as np
    >>> from fusion_gyrocal.core.array import calibrate_array
    >>> from fusion_gyrocal.evaluate.sim import HumanMotion, random_rotation
    >>> rng = np.random.default_rng(0)
    >>> omega = HumanMotion(rng=rng)(np.arange(4000) / 100.0)
    >>> R = [np.eye(3)] + [random_rotation(rng) for _ in range(2)]
    >>> omegas = [omega @ Rk + rng.normal(0, 1e-3, omega.shape) for Rk in R]
    >>> cal = calibrate_array(omegas)
    >>> bool(np.allclose(cal.R_ref_k, R, atol=1e-3))
    True
    """
    rates, mask = _checked_rates(omegas, mask)
    o = Options.of(options, gyros=len(rates), **keywords).require("array", "calibrate_array")
    if isinstance(reference, bool) or not (isinstance(reference, (int, np.integer)) and 0 <= reference < len(rates)):
        raise OptionError(f"reference: expected a gyro index in [0, {len(rates)}), got {reference!r}")
    clock = _time_base(t, len(rates[0]), rate_hz)
    if rate_hz is None and t is not None:
        rate_hz = (len(clock) - 1) / (clock[-1] - clock[0])
    moments = _moments(rates, o, mask)
    timed = _timed_samples(rates, moments, o, reference, mask, clock) if o.timing_model == "auto" else None
    if timed is not None:
        rates, moments = timed.rates, timed.moments
    source = None
    if o.noise_std is None and o.noise_model == "identify":
        noise_std, source = _identified_noise(rates, moments, reference, mask, rate_hz, resampling)
        if noise_std is not None:
            o = o.replace(noise_std=noise_std)
    cal = _solve_samples(rates, moments, o, reference, mask, rate_hz, source)
    cal = _with_weights(cal, rates, o, mask, rate_hz, source)
    return cal if timed is None else timed.reported(cal, rate_hz)


def _moments(rates, o: Options, mask) -> ArrayMoments:
    """The array's moments: one pass, or pooled over windows of ``bias_window`` samples."""
    if o.bias_window is None:
        return ArrayMoments.from_samples(rates, mask=mask)
    return ArrayMoments.from_windows(rates, o.bias_window, mask=mask)


def _solve_samples(rates, moments, o: Options, reference, mask, rate_hz, source, weights=None) -> ArrayCalibration:
    """:func:`solve_array` of the samples' ``moments``, with their windows of about a second (or ``bias_window``)
    for the block-robust covariance (weighted as the moments with ``weights``)."""
    window = o.bias_window if o.bias_window is not None else window_samples(rate_hz)
    windows = stacked_window_stats(rates, window, mask=mask, pooled=o.bias_window is not None,
                                   weights=None if weights is None else sample_weights(weights, len(rates[0])))
    return solve_array(moments, o, reference=reference, windows=windows, noise_source=source)


def _with_weights(cal: ArrayCalibration, rates, o: Options, mask, rate_hz, source) -> ArrayCalibration:
    """The array again with each sample weighted against a heavy-tailed residual (``robust_weights``, the pair
    pipeline's rule, :mod:`~fusion_gyrocal.core.weights`): when any gyro's residual against the reference is
    heavy-tailed, each sample weighs its smallest :func:`~fusion_gyrocal.core.weights.residual_weights` over the
    gyros' pairs with the reference (an impact reaches every chip); kept when the rotations are better determined.
    Only for a constant bias and a white noise identified or given. With ``robust_weights`` off, a heavy-tailed
    residual gets a note saying what the weights would do (:func:`~fusion_gyrocal.core.weights.hint`)."""
    from .weights import TAIL_SHARE, WEIGHT_SPAN, hint, residual_tail_share, residual_weights, tail_samples

    if o.noise_std is None or o.bias_window is not None or o.bias_walk_std is not None:
        return cal
    ref = cal.reference
    noise = np.broadcast_to(np.asarray(o.noise_std, dtype=float), (cal.n_gyros,))
    maps = {j: cal.pair_map(ref, j) for j in range(cal.n_gyros) if j != ref}
    samples = tail_samples(o.robust_weights)
    share = max(residual_tail_share(rates[ref], rates[j], A, b, mask, samples) for j, (A, b) in maps.items())
    if share < TAIL_SHARE:
        return cal
    if o.robust_weights == "off":       # what the weights would do, in a note
        return dataclasses.replace(cal, notes=cal.notes + (hint(share),))
    weights = np.minimum.reduce([residual_weights(rates[ref], rates[j], A, b, (noise[ref], noise[j]), mask)
                                 for j, (A, b) in maps.items()])
    moments = ArrayMoments.from_samples(rates, mask=mask, weights=weights)
    again = _solve_samples(rates, moments, o, ref, mask, rate_hz, source, weights)
    before, after = _rotation_sd(cal), _rotation_sd(again)
    if not after < before:
        return cal                      # the weighted estimate is not better determined: kept as it was
    used = float(np.count_nonzero(weights > 0))
    note = (f"robust weights: the largest 1% of a gyro's residual against the reference carried up to "
            f"{100 * share:.0f}% of its energy (4.5% for Gaussian noise): each sample weighted by the white noise's "
            f"variance over its residual's local variance ({WEIGHT_SPAN} samples; the smallest over the gyros), "
            f"{100 * weights.sum() / max(used, 1.0):.0f}% effective samples (n_samples counts the weights); rotation "
            f"1-sigma (RMS over the gyros) {np.rad2deg(before) * 1e3:.3g} -> {np.rad2deg(after) * 1e3:.3g} mdeg "
            "(robust_weights='off': every sample weighs 1)")
    return dataclasses.replace(again, notes=again.notes + (note,))


def _rotation_sd(cal: ArrayCalibration) -> float:
    """RMS 1-sigma of the non-reference gyros' rotations per axis (rad), without the skew budget (what the data
    determine)."""
    n = cal.n_gyros
    var = np.diag(cal.repeatable_rotation_covariance).reshape(n, 3)[[j for j in range(n) if j != cal.reference]]
    return float(np.sqrt(max(var.mean(), 0.0)))


def _identified_noise(rates, moments: ArrayMoments, reference: int, mask, rate_hz, resampling=None):
    """Every gyro's white noise from its pair with the reference (:func:`identify_noise`, with the pair's share
    of ``resampling``): gyro k's from its pair, the reference's the median over its pairs. ``(None, None)`` when a
    pair cannot be identified."""
    from ..errors import GyroCalError
    from .direct import solve_A
    from .noise import Resampling, identify_noise

    n = len(rates)
    noise, ref_noise, kinds = np.zeros(n), [], []
    for k in range(n):
        if k == reference:
            continue
        try:
            A, b = solve_A(moments.pair(reference, k))
            pair = None if resampling is None else Resampling(
                *(tuple(f[i] for i in (reference, k)) for f in (resampling.rates_hz, resampling.variance,
                                                                  resampling.diff3, resampling.density)),
                resampling.white_from)
            nm = identify_noise(rates[reference], rates[k], A, b, rate_hz=rate_hz, mask=mask, resampling=pair)
        except GyroCalError:
            return None, None
        noise[k] = nm.noise_std[1]
        ref_noise.append(nm.noise_std[0])
        kinds.append(nm.kind)
    noise[reference] = float(np.median(ref_noise))
    kind = max(set(kinds), key=kinds.count)
    return noise, (f"identified from each gyro's pair with the reference (core/noise.py; residuals mostly "
                   f"'{kind}'), the reference's the median over its {n - 1} pairs")


# ---------------------------------------------------------------------------------------- inter-sensor timing
def _time_base(t, n: int, rate_hz) -> np.ndarray:
    """The samples' instants for the timing model: ``t`` checked, else the sample index (over ``rate_hz``)."""
    if t is None:
        index = np.arange(n, dtype=float)
        return index if rate_hz is None else index / float(rate_hz)
    clock = np.asarray(t, dtype=float)
    if clock.shape != (n,):
        raise InputError(f"t: expected shape ({n},) (one instant per sample), got {clock.shape}")
    if not np.all(np.isfinite(clock)) or np.any(np.diff(clock) <= 0):
        raise InputError("t: expected finite, strictly increasing instants (s), got "
                         + ("non-finite values" if not np.all(np.isfinite(clock)) else
                            f"a step of {np.min(np.diff(clock)):.3g} s at sample "
                            f"{int(np.argmin(np.diff(clock))) + 1}"))
    return clock


@dataclass(frozen=True)
class _Timed:
    """The samples with every delayed gyro moved to the instants the reference's describe (:func:`_timed_samples`),
    their moments, and what was found: per moved gyro its delay against the reference (``models``) and that delay
    at the samples used (``delays``), the reference chip's own tones, and the residual RMS per axis of every gyro's
    pair with the reference (direct fit; 0 for the reference) before and after the move."""

    rates: list
    moments: ArrayMoments
    models: dict
    delays: dict
    reference_tones: tuple
    before: np.ndarray
    after: np.ndarray

    def reported(self, cal: ArrayCalibration, rate_hz) -> ArrayCalibration:
        """``cal`` (the calibration of :attr:`rates`) with the delays in its timing fields and a note."""
        n = cal.n_gyros
        tones, mean, std, explained = [()] * n, np.zeros(n), np.zeros(n), np.zeros(n)
        for j, model in self.models.items():
            d = self.delays[j]
            tones[j], mean[j], std[j], explained[j] = model.tones_hz, d.mean(), d.std(), model.explained
        note = _timing_note(cal.reference, self, mean, std, rate_hz)
        return dataclasses.replace(cal, timing_tones_hz=tuple(tones), timing_delay_s=mean, timing_delay_std_s=std,
                                   timing_explained=explained, notes=cal.notes + (note,))


def _timed_samples(rates, moments: ArrayMoments, o: Options, ref: int, mask, t) -> _Timed | None:
    """Every gyro's samples moved to the instants the reference's describe, where the pairs' residuals show delays
    (:func:`~fusion_gyrocal.pipeline.timing.estimate_array_timing` on ``omega_ref - A_j omega_j - bias_j`` of every
    pair's direct least-squares fit, Eq. 17: one delay per chip, each following the beat tone of its sampling clock
    against the read-out, or a constant group delay; gyro j's delay against the reference is the difference of the
    two chips'); None when nothing is found or the move does not explain the residuals better.

    A gyro is moved only when the move lowers its pair's residual at that fit, and the moved samples are kept only
    when the pairs fitted again on them have less residual energy in all than before (the pair pipeline's rule).
    The caller then calibrates the array on them once (the noise identified on the moved samples). Every gyro
    describes the reference's sampling instants, so the pairs without the reference are consistent as well (the
    reference chip's delay cancels in them).
    """
    from ..pipeline.timing import estimate_array_timing

    n = len(rates)
    others = [j for j in range(n) if j != ref]
    try:
        fits = {j: solve_A(moments.pair(ref, j)) for j in others}
    except GyroCalError:
        return None                   # a pair without the motion to fit: the solve says what is missing
    ok = np.ones(len(t), bool) if mask is None else mask
    maps = [fits[j][0] if j in fits else np.eye(3) for j in range(n)]
    chips = estimate_array_timing(t, rates, maps, [fits[j][1] if j in fits else np.zeros(3) for j in range(n)], ok,
                                  reference=ref)
    moved, models, delays = list(rates), {}, {}
    for j in others:
        model = chips.relative[j]
        if not model.significant:
            continue
        w = np.where(ok[:, None], rates[j], np.nan)      # the derivative one-sided beside an unused sample
        w_moved, delay = chips.compensate(j, t, w)
        A, b = fits[j]
        before, after = (float(np.mean(np.square(rates[ref][ok] - x[ok] @ A.T - b))) for x in (w, w_moved))
        if after < before:
            moved[j], models[j], delays[j] = np.where(ok[:, None], w_moved, rates[j]), model, delay[ok]
    if not models:
        return None
    again = _moments(moved, o, mask)

    def pair_rms(m: Moments) -> float:               # residual RMS per axis of the pair's direct fit
        return float(np.sqrt(max(np.trace(residual_scatter(solve_A(m)[0], m.scatter)), 0.0) / (3.0 * max(m.dof, 1.0))))

    before, after = np.zeros(n), np.zeros(n)
    for j in others:
        before[j], after[j] = pair_rms(moments.pair(ref, j)), pair_rms(again.pair(ref, j))
    if float(np.sum(after ** 2)) >= float(np.sum(before ** 2)):
        return None                   # the move did not explain the residuals better: the samples as they were
    return _Timed(moved, again, models, delays, chips.tones_hz[ref], before, after)


def _timing_note(reference: int, timed: _Timed, mean, std, rate_hz) -> str:
    """What the timing model found and did, per gyro (and the reference chip's own tone, shared by every pair),
    with the residuals before and after the move."""
    unit = ("Hz", "ms", 1e3) if rate_hz is not None else ("cycles/sample", "samples", 1.0)
    parts = []
    for j, model in sorted(timed.models.items()):
        tones = ", ".join(f"{f:.4g}" for f in model.tones_hz)
        shape = (f"beat tone(s) at {tones} {unit[0]}, std {std[j] * unit[2]:.3g} {unit[1]}, mean" if tones
                 else "constant (a filter's group delay?):")
        parts.append(f"gyro {j + 1} {shape} {mean[j] * unit[2]:.3g} {unit[1]}, {100 * model.explained:.0f}% of its "
                     f"pair's residual energy")
    rms = "; ".join(f"gyro {j + 1} {np.rad2deg(timed.before[j]):.4g} -> {np.rad2deg(timed.after[j]):.4g}"
                    for j in range(len(mean)) if j != reference)
    shared = (f"; the reference chip's own beat, at {', '.join(f'{f:.4g}' for f in timed.reference_tones)} "
              f"{unit[0]}, found once in all pairs, is common to every gyro's delay" if timed.reference_tones else "")
    return (f"inter-sensor timing: delays against the reference gyro {reference + 1} beyond the time offset "
            f"(each chip's sampling clock against the read-out{shared}): {'; '.join(parts)}; those gyros' samples "
            "were moved to the instants the reference's describe and the array calibrated on them: residual RMS per "
            f"axis of each gyro's pair with the reference, fitted directly (Eq. 17; deg/s) {rms} (timing_model='off': "
            "no delay beyond the time offset)")
