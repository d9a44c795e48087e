"""The joint calibration of N gyros as a result: :class:`ArrayCalibration` (and its JSON).

What :func:`~fusion_gyrocal.core.array.solve_array` returns: the rotations, scale factors and biases of
every gyro against the reference gyro, their covariance in the gauge, and the moments they came from,
so that any pair can be viewed as a :class:`~fusion_gyrocal.core.model.PairCalibration`
(:meth:`ArrayCalibration.pair`).
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, field, fields
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ConfigurationError, FormatError, InputError
from .model import (PairCalibration, from_json_list, mark_undetermined, parallel_axes, ratio_std, restore_non_finite,
                    rotation_forms, rotation_text, scale_ratios, strict_json, to_json_list, to_json_number)
from .moments import Moments
from ..lie import exp, log
from .observability import CROSS_AXIS_PAIRS, dA_dp, per_axis_snr, residual_weight
from .refine import residual_scatter
from .robust import CovarianceBasis
from .solve import parameter_covariance

if TYPE_CHECKING:
    from .array import ArrayMoments

ARRAY_KIND = "array_calibration"
#: Format of :meth:`ArrayCalibration.to_dict` (``kind`` tells it from a pair's JSON).
ARRAY_FORMAT_VERSION = "1.3"
#: Versions :meth:`ArrayCalibration.from_dict` reads (1.1 adds the cross-axis fields, ``nominal_R_ref_k``,
#: ``provenance`` and the derived ``rotations``, ``relative_scale``, ``deviation`` entries, which are recomputed on
#: reading; 1.2 the timing fields ``timing_tones_hz``, ``timing_delay_s``, ``timing_delay_std_s``,
#: ``timing_explained``, read as "no delay found" from earlier files; 1.3 writes non-finite numbers as ``null``
#: named in ``non_finite`` (:func:`~fusion_gyrocal.core.model.strict_json`; 1.0-1.2 wrote strings) and adds
#: ``rates_hz`` and ``noise_density``, None in earlier files).
ARRAY_READABLE_VERSIONS = ("1.0", "1.1", "1.2", ARRAY_FORMAT_VERSION)
_ARRAY_FIELDS = ("R_ref_k", "scale", "bias", "scale_observable", "covariance", "snr", "noise_std", "residual_rms",
                 "time_offset_s", "time_offset_std_s", "cross_axis_terms", "cross_axis_covariance", "cross_axis_chi2",
                 "skew_rotation_covariance", "timing_delay_s", "timing_delay_std_s", "timing_explained")
#: Per-gyro arrays that are None where not known (sample-aligned input, files before format 1.3).
_OPTIONAL_FIELDS = ("nominal_R_ref_k", "rates_hz", "noise_density")


def _json_ready(v):
    """Nested tuples as lists (for JSON)."""
    return [_json_ready(x) for x in v] if isinstance(v, (tuple, list)) else v


@dataclass(frozen=True)
class ArrayCalibration:
    """Joint calibration of N rigidly mounted gyroscopes (indices from 0).

    Attributes
    ----------
    R_ref_k : ndarray (N, 3, 3)
        ``R_ref_k[k]`` maps gyro k's frame into the reference gyro's frame
        (``omega_ref = R_ref_k[k] @ omega_k``); ``R_ref_k[reference]`` is the identity.
    scale : ndarray (N, 3)
        Scale factors of every gyro in the gauge named by ``gauge``.
    bias : ndarray (N, 3)
        Combined bias of every gyro against the reference, ``b_ref - A_ref_k b_k`` (Eq. 5) in rad/s
        (the individual biases are not observable: a common rate offset is indistinguishable from
        them); ``bias[reference]`` is zero.
    reference : int
        Index of the reference gyro.
    scale_observable : ndarray (N, 3) of bool
        Scale factors determined up to the one global scale (Theorem 2). Where False, only ratios
        inside its group of linked axes (``scale_groups``) are determined (Lemmas 2-3).
    scale_groups : tuple of tuple of (gyro, axis)
        Scale factors whose ratios the data determine; each group has one undetermined common factor.
    configurations : tuple of tuple of str, (N, N)
        Configuration class (Lemmas 2-4) of every pair; ``""`` on the diagonal.
    covariance : ndarray (9N, 9N)
        Covariance of ``[dtheta_0..dtheta_{N-1}, scale_0..scale_{N-1}, bias_0..bias_{N-1}]`` (3 entries
        each) with ``R_ref_k_true = Exp(dtheta_k) @ R_ref_k[k]``, in the gauge. For scale factors whose
        ``scale_observable`` is False the marginal variances belong to the gauge convention; only
        ratios within a group are meaningful (:meth:`scale_ratio`). The reference's rotation and bias
        blocks are zero (its scale factors have a variance unless the gauge fixes them).
    gauge : str
        How the global scale (one factor per group) was fixed.
    snr : ndarray (3,)
        Per-axis SNR of the common angular rate (reference frame) against the reference gyro's noise.
    n_samples : int
    noise_std : ndarray (N,)
        White-noise std per sample of every gyro (rad/s) used for the weights and the covariance.
    noise_source : str
    residual_rms : ndarray (N,)
        RMS per axis of every gyro's residual against the fitted common rate (rad/s).
    iterations : int
    bias_segments : int
    notes : tuple of str
    moments : ArrayMoments
        The statistics the calibration was computed from (used by :meth:`pair`).
    time_offset_s : ndarray (N,)
        Seconds ADDED to gyro k's timestamps to put them on the reference gyro's clock (0 for the
        reference and for sample-aligned input).
    time_offset_std_s : ndarray (N,)
        Standard deviation of ``time_offset_s`` (0 where it was given, not estimated).
    covariance_basis : str
        What ``covariance`` rests on (see :attr:`PairCalibration.covariance_basis`).
    covariance_kind : CovarianceBasis
        Which of those it is (:class:`~fusion_gyrocal.core.robust.CovarianceBasis`).
    robust_inflation : float
        Largest ratio of the block-robust variance to the noise model's (NaN when not computed).
    nominal_R_ref_k : ndarray (N, 3, 3) or None
        The nominal mounting of every gyro the user gave (``--nominal``); :meth:`deviation` is the estimate
        against it.
    provenance : Provenance or None
        What the result was computed from (:class:`~fusion_gyrocal.provenance.Provenance`).
    time_offset_source : tuple of str (N,)
        Where each offset came from: ``"reference"``, ``"estimated"`` (rate-norm correlation refined by
        the rigid-model misfit, :func:`~fusion_gyrocal.pipeline.alignment.align_streams`), ``"given"``,
        ``"one clock"`` (recordings with identical timestamps) or ``"sample-aligned"`` (input without
        timestamps).
    linear_map : tuple of str (N,)
        Every gyro's sensor model against the reference (:mod:`~fusion_gyrocal.core.linear_map`, chosen as the
        pair solver chooses it, ``linear_map`` option): ``"rigid"`` (``A = S_ref R_ref_k S_k^-1``, Eq. 4) or
        ``"full"`` (``omega_ref = (I + K_k) S_ref R_ref_k S_k^-1 omega_k``, ``K_k`` the symmetric relative
        cross-axis terms, so ``R_ref_k`` is the rotation under the pair's symmetric convention); ``""`` for the
        reference.
    cross_axis_terms : ndarray (N, 3)
        ``k = (K_xy, K_yz, K_zx)`` of every gyro against the reference (:func:`~fusion_gyrocal.core.observability.
        cross_matrix`, reference axes); zero for the reference and the ``"rigid"`` gyros.
    cross_axis_covariance : ndarray (3N, 12N)
        Covariance of ``[k_0..k_{N-1}]`` (rows) with ``[dtheta, scale, bias, k]`` (columns, ``covariance``'s order
        followed by the cross-axis terms); its last 3N columns are the cross-axis terms' own covariance. Zero
        where a gyro's terms are not estimated.
    cross_axis_chi2 : ndarray (N,)
        Every gyro's cross-axis chi-square against the reference (:func:`~fusion_gyrocal.core.robust.cross_axis`
        on its pair at the joint rigid estimate; NaN for the reference), with ``cross_axis_dof`` degrees of freedom.
    cross_axis_dof : tuple of int (N,)
    skew_rotation_covariance : ndarray (3N, 3N)
        The part of the rotation blocks of ``covariance`` that no data see: the antisymmetric cross-axis parts
        (:func:`~fusion_gyrocal.core.linear_map.cross_axis_budget` of every pair's relative terms: the rotation
        between any two gyros carries its own pair's budget, as far as a covariance can); zero with the rigid
        model. Two sessions of one
        board share it, so their difference cancels it.
    timing_tones_hz : tuple of tuple of float (N,)
        Beat tones of every gyro's delay against the reference beyond the time offset
        (:func:`~fusion_gyrocal.pipeline.timing.estimate_array_timing`: its own chip's tone first, then the
        reference chip's, found once for all pairs; Hz, cycles per sample without a time base); empty where none
        was found (a constant delay may still be). Every gyro with a delay had its samples
        moved to the instants the reference's describe before the final solve.
    timing_delay_s : ndarray (N,)
        Mean of every gyro's delay beyond the time offset (s; samples without a time base); 0 for the reference
        and where no delay was found.
    timing_delay_std_s : ndarray (N,)
        Standard deviation of that delay over the samples used (s; samples without a time base).
    timing_explained : ndarray (N,)
        Fraction of its pair's residual energy the delay explained; 0 where none was found or compensated.
    rates_hz : ndarray (N,) or None
        Every gyro's own sample rate (Hz) before it was put on the grid; None for input without timestamps.
    noise_density : ndarray (N,) or None
        Every gyro's own white rate-noise density (rad/s/sqrt(Hz)): ``noise_std`` (per grid sample) referred back
        to the sensor through what the resampling did to its white noise, ``noise_std[k] / sqrt(v_k rates_hz[k])``
        with ``v_k`` the variance a unit white noise keeps on the grid
        (:func:`~fusion_gyrocal.pipeline.resample.noise_factors`; 1 where the grid is the gyro's own samples).
        None for input without timestamps (the figures are then per sample: divide by the square root of the
        rate the samples were taken at).
    """

    R_ref_k: np.ndarray
    scale: np.ndarray
    bias: np.ndarray
    reference: int
    scale_observable: np.ndarray
    scale_groups: tuple
    configurations: tuple
    covariance: np.ndarray
    gauge: str
    snr: np.ndarray
    n_samples: int
    noise_std: np.ndarray
    noise_source: str
    residual_rms: np.ndarray
    iterations: int
    bias_segments: int
    notes: tuple
    moments: ArrayMoments = field(repr=False)
    time_offset_s: np.ndarray | None = None
    time_offset_std_s: np.ndarray | None = None
    time_offset_source: tuple | None = None
    covariance_basis: str = "noise model"
    covariance_kind: CovarianceBasis = CovarianceBasis.MODEL
    robust_inflation: float = float("nan")
    nominal_R_ref_k: np.ndarray | None = None
    provenance: object = None
    linear_map: tuple | None = None
    cross_axis_terms: np.ndarray | None = None
    cross_axis_covariance: np.ndarray | None = None
    cross_axis_chi2: np.ndarray | None = None
    cross_axis_dof: tuple | None = None
    skew_rotation_covariance: np.ndarray | None = None
    timing_tones_hz: tuple | None = None
    timing_delay_s: np.ndarray | None = None
    timing_delay_std_s: np.ndarray | None = None
    timing_explained: np.ndarray | None = None
    rates_hz: np.ndarray | None = None
    noise_density: np.ndarray | None = None

    def __post_init__(self):
        n = np.asarray(self.scale).shape[0]
        defaults = {"linear_map": tuple("" if k == self.reference else "rigid" for k in range(n)),
                    "cross_axis_terms": np.zeros((n, 3)), "cross_axis_covariance": np.zeros((3 * n, 12 * n)),
                    "cross_axis_chi2": np.full(n, np.nan), "cross_axis_dof": (0,) * n,
                    "skew_rotation_covariance": np.zeros((3 * n, 3 * n)), "timing_tones_hz": ((),) * n,
                    "timing_delay_s": np.zeros(n), "timing_delay_std_s": np.zeros(n), "timing_explained": np.zeros(n)}
        for name, value in defaults.items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)
        for name in ("linear_map", "cross_axis_dof", "timing_tones_hz"):
            if len(getattr(self, name)) != n:
                raise InputError(f"{name}: expected {n} entries, got {len(getattr(self, name))}")
        object.__setattr__(self, "linear_map", tuple(str(x) for x in self.linear_map))
        object.__setattr__(self, "cross_axis_dof", tuple(int(x) for x in self.cross_axis_dof))
        object.__setattr__(self, "timing_tones_hz", tuple(tuple(float(f) for f in row) for row in self.timing_tones_hz))
        if self.time_offset_s is None:
            object.__setattr__(self, "time_offset_s", np.zeros(n))
        if self.time_offset_std_s is None:
            object.__setattr__(self, "time_offset_std_s", np.zeros(n))
        if self.time_offset_source is None:
            object.__setattr__(self, "time_offset_source", tuple(
                "reference" if k == self.reference else "sample-aligned" for k in range(n)))
        if len(self.time_offset_source) != n:
            raise InputError(f"time_offset_source: expected {n} entries, got {len(self.time_offset_source)}")
        shapes = {"R_ref_k": (n, 3, 3), "scale": (n, 3), "bias": (n, 3), "scale_observable": (n, 3),
                  "covariance": (9 * n, 9 * n), "snr": (3,), "noise_std": (n,), "residual_rms": (n,),
                  "time_offset_s": (n,), "time_offset_std_s": (n,), "cross_axis_terms": (n, 3),
                  "cross_axis_covariance": (3 * n, 12 * n), "cross_axis_chi2": (n,),
                  "skew_rotation_covariance": (3 * n, 3 * n), "timing_delay_s": (n,), "timing_delay_std_s": (n,),
                  "timing_explained": (n,)}
        for name, shape in shapes.items():
            arr = np.array(getattr(self, name), dtype=bool if name == "scale_observable" else np.float64)
            if arr.shape != shape:
                raise InputError(f"{name}: expected shape {shape}, got {arr.shape}")
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "notes", tuple(self.notes))
        object.__setattr__(self, "time_offset_source", tuple(str(x) for x in self.time_offset_source))
        object.__setattr__(self, "covariance_kind", CovarianceBasis(self.covariance_kind))
        for name in ("rates_hz", "noise_density"):
            if getattr(self, name) is not None:
                arr = np.array(getattr(self, name), dtype=np.float64)
                if arr.shape != (n,):
                    raise InputError(f"{name}: expected shape {(n,)}, got {arr.shape}")
                arr.flags.writeable = False
                object.__setattr__(self, name, arr)
        if self.nominal_R_ref_k is not None:
            nom = np.array(self.nominal_R_ref_k, dtype=np.float64)
            if nom.shape != (n, 3, 3):
                raise InputError(f"nominal_R_ref_k: expected shape {(n, 3, 3)}, got {nom.shape}")
            bad = [k + 1 for k in range(n) if not np.allclose(nom[k] @ nom[k].T, np.eye(3), atol=1e-6)
                   or np.linalg.det(nom[k]) < 0]
            if bad:
                raise InputError(f"nominal_R_ref_k: expected rotation matrices, got others for gyro(s) {bad}")
            nom.flags.writeable = False
            object.__setattr__(self, "nominal_R_ref_k", nom)

    def __repr__(self) -> str:
        """One short line per gyro: rotation into the reference frame and relative scale factors."""
        rel, _ = self.relative_scales()
        rot = self.rotation_std_rad
        rows = "; ".join(f"gyro {k + 1}: {rotation_text(self.R_ref_k[k], rot[k])}, scale/ref "
                         f"[{', '.join(f'{r:.5f}' for r in rel[k])}]" for k in range(self.n_gyros)
                         if k != self.reference)
        return (f"ArrayCalibration({self.n_gyros} gyros, reference gyro {self.reference + 1}, {self.n_samples} "
                f"samples; {rows})")

    @property
    def n_gyros(self) -> int:
        return self.scale.shape[0]

    def rotation(self, k: int):
        """``R_ref_k[k]`` (gyro k's frame into the reference's, k from 0) as a
        :class:`scipy.spatial.transform.Rotation`."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_matrix(self.R_ref_k[self._index(k)])

    def _index(self, k: int) -> int:
        if not (isinstance(k, (int, np.integer)) and 0 <= k < self.n_gyros):
            raise InputError(f"gyro index: expected 0..{self.n_gyros - 1} (gyro 1..{self.n_gyros}), got {k!r}")
        return int(k)

    def relative_scales(self) -> tuple[np.ndarray, np.ndarray]:
        """``(N, 3)`` scale factors of every gyro over the reference's on the parallel axis
        (``scale[k, a] / scale[ref, p_k(a)]``, :func:`~fusion_gyrocal.core.model.parallel_axes`), and their 1-sigma
        (:meth:`scale_ratio`; NaN where the two are in different groups of linked axes). The reference's are
        exactly 1 with zero uncertainty."""
        n, ref = self.n_gyros, self.reference
        val, sd = np.ones((n, 3)), np.zeros((n, 3))
        for k in range(n):
            if k == ref:
                continue
            p = parallel_axes(self.R_ref_k[k])
            for a in range(3):
                val[k, a] = self.scale[k, a] / self.scale[ref, p[a]]
                try:
                    sd[k, a] = self.scale_ratio(k, a, ref, int(p[a]))[1]
                except ConfigurationError:
                    sd[k, a] = np.nan
        return val, sd

    def deviation(self, k: int):
        """``(d, covariance)`` of gyro k (from 0) against its nominal mounting: ``R_ref_k[k] = Exp(d) nominal``
        (rad, reference frame) and its (3, 3) covariance; None without :attr:`nominal_R_ref_k`."""
        from .model import rotation_deviation

        k = self._index(k)
        if self.nominal_R_ref_k is None:
            return None
        C = self.covariance[3 * k:3 * k + 3, 3 * k:3 * k + 3]
        return rotation_deviation(self.R_ref_k[k], self.nominal_R_ref_k[k], C)

    @property
    def repeatable_rotation_covariance(self) -> np.ndarray:
        """(3N, 3N) the rotation blocks of ``covariance`` without ``skew_rotation_covariance``: what the data
        determine, and what two sessions of one board differ by (see :attr:`PairCalibration.
        repeatable_rotation_covariance`); the reference's block is zero."""
        n = self.n_gyros
        return self.covariance[:3 * n, :3 * n] - self.skew_rotation_covariance

    @property
    def rotation_std_rad(self) -> np.ndarray:
        """(N, 3) 1-sigma rotation uncertainty per axis of the reference frame (rad)."""
        return np.sqrt(np.clip(np.diag(self.covariance)[:3 * self.n_gyros], 0, None)).reshape(-1, 3)

    def scale_ratio(self, i: int, axis_i: int, j: int, axis_j: int) -> tuple[float, float]:
        """``scale[i, axis_i] / scale[j, axis_j]`` and its 1-sigma uncertainty.

        Gauge-invariant (and reported) only for two scale factors in the same group of linked
        axes; for all-axes-parallel gyros (Lemma 2) that is ``axis_j = perm(axis_i)``.

        Raises
        ------
        ConfigurationError
            If the two scale factors are in different groups (their ratio is not determined).
        """
        a, b = (i, axis_i), (j, axis_j)
        if not any(a in g and b in g for g in self.scale_groups):
            raise ConfigurationError(f"scale_ratio: scale[{i}, {axis_i}] and scale[{j}, {axis_j}] are in different "
                                     "groups of linked axes; the data do not determine their ratio")
        r = self.scale[i, axis_i] / self.scale[j, axis_j]
        ka, kb = 3 * self.n_gyros + 3 * i + axis_i, 3 * self.n_gyros + 3 * j + axis_j
        C = self.covariance
        return float(r), ratio_std(r, C[ka, ka], C[kb, kb], C[ka, kb], self.scale[i, axis_i], self.scale[j, axis_j])

    def pair_map(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """``(A_ij, bias)`` of :meth:`pair`, ``omega_i ~ A_ij omega_j + bias`` (Eq. 12), without the view's
        covariance (what a residual of the pair needs)."""
        m = self.moments.pair(i, j)  # checks the indices
        full = "full" in (self.linear_map[i], self.linear_map[j])
        A = _pair_A(self.R_ref_k, self.scale, self.cross_axis_terms if full else None, self.reference, i, j)
        return A, m.mean_1 - A @ m.mean_2

    def pair(self, i: int, j: int) -> PairCalibration:
        """The joint estimate seen as the calibration of the pair (gyro i as "gyro 1", gyro j as "gyro 2").

        The pair's map ``A_ij`` of the joint model (``H_i H_j^-1``, :mod:`~fusion_gyrocal.core.array`) in the pair
        solver's parameters (:func:`pair_convention`): without cross-axis terms ``R_1_2 = R_ref_k[i]^T R_ref_k[j]``
        (so loops close exactly) and the array's scale factors; with them (``linear_map`` ``"full"`` for either
        gyro) the rotation, gyro i's scale factors and the symmetric cross-axis terms of
        ``A_ij = (I + K) S_i R_1_2 S_j^-1``, the pair's convention. For a pair with the reference that is the
        array's own parametrisation; for two other gyros ``R_1_2`` differs from ``R_ref_k[i]^T R_ref_k[j]`` by the
        antisymmetric part of ``S^-1 K S`` (``K`` the difference of their cross-axis terms, ``S`` the scale
        factors): ``O(|K| * dscale)``, said in the notes. Bias ``mean_i - A_ij mean_j`` (Eq. 12); the 12x12
        covariance and the view's cross-axis covariance follow from the joint one to first order (undetermined
        scale factors: infinite variance, as in :class:`PairCalibration`); ``skew_rotation_covariance`` is the
        pair's part of the joint one.
        """
        from .array import _retract

        m = self.moments.pair(i, j)  # checks the indices
        n, ref = self.n_gyros, self.reference
        full = "full" in (self.linear_map[i], self.linear_map[j])
        R0, s0, k0 = self.R_ref_k, self.scale, (self.cross_axis_terms if full else None)

        def view(delta):
            """``[dtheta, log s_1, log s_2 (, k)]`` of the pair after the joint step ``delta``, and its state."""
            R, s = _retract(R0, s0, delta)
            k = None if k0 is None else k0 + delta[6 * n:].reshape(n, 3)
            A = _pair_A(R, s, k, ref, i, j)
            Rp, s1, kp = pair_convention(A, s[i], s[j], R[i].T @ R[j]) if full else (R[i].T @ R[j], s[i], None)
            return Rp, s1, s[j], kp, A

        Rv, s1, s2, kv, A = view(np.zeros((9 if full else 6) * n))
        P_joint = _log_parameter_covariance(self, full)
        J = np.zeros((12 if full else 9, len(P_joint)))   # d[dtheta_ij, log s_1, log s_2 (, k)] / d[joint]
        h = 1e-7
        for p in range(len(P_joint)):
            d = np.zeros(len(P_joint))
            d[p] = h
            out = [view(d), view(-d)]
            J[:3, p] = (log(out[0][0] @ Rv.T) - log(out[1][0] @ Rv.T)) / (2 * h)
            J[3:9, p] = (np.log(np.concatenate(out[0][1:3])) - np.log(np.concatenate(out[1][1:3]))) / (2 * h)
            if full:
                J[9:, p] = (out[0][3] - out[1][3]) / (2 * h)
        P = J @ P_joint @ J.T
        skew_cov = J[:3, :3 * n] @ self.skew_rotation_covariance @ J[:3, :3 * n].T
        noise = (float(self.noise_std[i]), float(self.noise_std[j]))
        Jv = np.zeros((9, len(P)))
        Jv[:3, :3] = np.eye(3)
        Jv[3:9, 3:9] = np.diag(np.concatenate([s1, s2]))
        cov = parameter_covariance(P, Jv, dA_dp(Rv, s1, s2, kv), m, np.linalg.inv(residual_weight(A, noise)) / m.count)
        cov[:3, :3] += skew_cov
        obs = np.stack([self.scale_observable[i], self.scale_observable[j]])
        ratio_sd = scale_ratios(Rv, s1, s2, cov)[1]   # gauge-invariant: kept before the marking hides it
        mark_undetermined(cov, obs)
        M = residual_scatter(A, m.scatter)
        notes = (f"view of the joint calibration of {n} gyros (gyro {i + 1} as gyro 1, gyro {j + 1} as gyro 2)",)
        if full and ref not in (i, j):
            shift = float(np.linalg.norm(log(Rv @ (self.R_ref_k[j].T @ self.R_ref_k[i]))))
            notes += (f"R_1_2 in the pair's symmetric cross-axis convention differs from R_ref_k[{i}]^T R_ref_k[{j}] "
                      f"by {np.rad2deg(shift) * 1e3:.3g} mdeg (the antisymmetric part of S^-1 K S: |K| x dscale)",)
        tested = ref in (i, j)
        timing = {}
        if tested and self.timing_explained[i + j - ref] > 0:   # gyro 2's delay against gyro 1: the other's, signed
            other, sign = i + j - ref, (1.0 if i == ref else -1.0)
            timing = dict(timing_tones_hz=self.timing_tones_hz[other],
                          timing_delay_s=float(sign * self.timing_delay_s[other]),
                          timing_delay_std_s=float(self.timing_delay_std_s[other]),
                          timing_explained=float(self.timing_explained[other]))
        elif np.any(self.timing_explained[[i, j]] > 0):
            notes += ("both gyros' samples were moved to the instants the reference's describe (timing_delay_s of "
                      "the joint calibration); the view's own timing fields hold only a pair with the reference",)
        return PairCalibration(
            R_1_2=Rv, scale_1=s1, scale_2=s2, bias=m.mean_1 - A @ m.mean_2,
            configuration=self.configurations[i][j], scale_observable=obs, covariance=cov,
            gauge=self.gauge, snr=per_axis_snr(m, noise), n_samples=int(m.count), noise_std=np.array(noise),
            noise_source=self.noise_source, covariance_basis=self.covariance_basis,
            covariance_kind=self.covariance_kind, robust_inflation=self.robust_inflation,
            residual_rms=float(np.sqrt(max(np.trace(M), 0.0) / (3.0 * max(m.dof, 1.0)))),
            method="ml_array", iterations=self.iterations, bias_segments=m.segments,
            time_offset_s=float(self.time_offset_s[j] - self.time_offset_s[i]),
            time_offset_std_s=float(np.hypot(self.time_offset_std_s[i], self.time_offset_std_s[j])),
            scale_ratio_std=ratio_sd,
            skew_rotation_covariance=skew_cov, linear_map="full" if full else "rigid",
            cross_axis_terms=np.zeros(3) if kv is None else kv,
            cross_axis_covariance=P[9:, 9:] if full else np.zeros((3, 3)),
            cross_axis_chi2=float(self.cross_axis_chi2[i + j - ref]) if tested else float("nan"),
            cross_axis_dof=int(self.cross_axis_dof[i + j - ref]) if tested else 0,
            notes=notes + self.notes, **timing)

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict:
        """JSON-ready dictionary with ``kind`` and ``format_version`` (:data:`ARRAY_FORMAT_VERSION`).

        Strict JSON as :meth:`PairCalibration.to_dict`: every number a number, non-finite ones ``null`` and named
        in ``non_finite`` (:func:`~fusion_gyrocal.core.model.strict_json`); the moments are kept, so :meth:`pair`
        works on a loaded result.
        """
        out = {"kind": ARRAY_KIND, "format_version": ARRAY_FORMAT_VERSION, "units": {"rate": "rad/s", "time": "s"},
               "convention": "omega_ref = R_ref_k[k] @ omega_k; omega_k_meas = diag(scale[k]) omega_k + b_k; "
                             "where linear_map[k] is 'full', omega_ref_meas = (I + K_k) diag(scale[ref]) R_ref_k[k] "
                             "diag(scale[k])^-1 omega_k_meas + bias[k], K_k the symmetric zero-diagonal matrix of "
                             "cross_axis_terms[k] = (xy, yz, zx); time_offset_s[k] is added to gyro k's timestamps; "
                             "where timing_explained[k] > 0, gyro k's samples were moved to the instants the "
                             "reference's describe (omega_k + d(omega_k)/dt delay_k(t), mean timing_delay_s[k]) "
                             "before the solve",
               "covariance_order": "[dtheta_0..dtheta_N-1, scale_0..scale_N-1, bias_0..bias_N-1], 3 entries each"}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "moments":
                v = {"n_gyros": v.n_gyros, "pairs": [m.to_dict() for m in v.pairs]}
            elif f.name == "provenance" and v is not None:
                v = v.to_dict()
            elif v is None:
                pass
            elif isinstance(v, np.ndarray):
                v = to_json_list(v)
            elif isinstance(v, (float, np.floating)):
                v = to_json_number(float(v))
            elif isinstance(v, (int, np.integer)):
                v = int(v)
            elif isinstance(v, tuple):
                v = _json_ready(v)
            elif isinstance(v, CovarianceBasis):
                v = v.value
            out[f.name] = v
        out.update(self._derived())
        return strict_json(out)

    def _derived(self) -> dict:
        """For readers (not read back): every gyro's rotation in every form, the relative scale factors with their
        1-sigma (finite numbers; null where not determined) and the deviations from the nominal mounting."""
        def num(x):
            return float(x) if np.isfinite(x) else None

        rel, sd = self.relative_scales()
        rot_sd = self.rotation_std_rad
        out = {"rotations": [{"gyro": k + 1, "of": f"R_ref_k[{k}]: gyro {k + 1}'s frame into the reference's",
                              **rotation_forms(self.R_ref_k[k]), "std_rad": [num(x) for x in rot_sd[k]]}
                             for k in range(self.n_gyros)],
               "relative_scale": {"of": "scale[k, a] / scale[reference, axis_of_reference[k][a]]",
                                  "axis_of_reference": [parallel_axes(R).tolist() for R in self.R_ref_k],
                                  "value": [[num(x) for x in row] for row in rel],
                                  "std": [[num(x) for x in row] for row in sd]},
               "deviation": None}
        if self.nominal_R_ref_k is not None:
            devs = []
            for k in range(self.n_gyros):
                dk, C = self.deviation(k)
                devs.append({"gyro": k + 1, "rotvec_rad": dk.tolist(), "angle_deg": float(np.degrees(np.linalg.norm(dk))),
                             "std_rad": [num(x) for x in np.sqrt(np.clip(np.diag(C), 0.0, None))]})
            out["deviation"] = devs
        return out

    @classmethod
    def from_dict(cls, d: dict) -> "ArrayCalibration":
        """Rebuild a result written by :meth:`to_dict`.

        Raises
        ------
        FormatError
            Another ``kind`` or ``format_version``, a missing field, or values of the wrong shape.
        """
        if d.get("kind") != ARRAY_KIND:
            raise FormatError(f"array calibration: expected kind {ARRAY_KIND!r}, got {d.get('kind')!r}")
        if d.get("format_version") not in ARRAY_READABLE_VERSIONS:
            raise FormatError(f"array calibration: expected format_version {ARRAY_FORMAT_VERSION!r} (or an earlier "
                              f"{', '.join(repr(v) for v in ARRAY_READABLE_VERSIONS[:-1])}), "
                              f"got {d.get('format_version')!r}")
        d = restore_non_finite(d)
        missing = [f.name for f in fields(cls) if f.default is MISSING and f.name not in d]
        if missing:
            raise FormatError(f"array calibration: expected the fields {missing}, got none of them")
        kw = {}
        for f in fields(cls):
            if f.name not in d:
                continue
            v = d[f.name]
            if f.name == "moments":
                from .array import ArrayMoments

                v = ArrayMoments(int(v["n_gyros"]), tuple(Moments.from_dict(m) for m in v["pairs"]))
            elif f.name == "provenance":
                if v is not None:
                    from ..provenance import Provenance
                    v = Provenance.from_dict(v)
            elif f.name in _OPTIONAL_FIELDS:
                v = None if v is None else from_json_list(v, np.float64)
            elif f.name in _ARRAY_FIELDS:
                v = from_json_list(v, bool if f.name == "scale_observable" else np.float64)
            elif f.name == "scale_groups":
                v = tuple(tuple((int(g), int(a)) for g, a in group) for group in v)
            elif f.name == "configurations":
                v = tuple(tuple(str(c) for c in row) for row in v)
            elif f.name in ("notes", "time_offset_source", "linear_map", "cross_axis_dof", "timing_tones_hz"):
                v = tuple(v)
            elif f.name == "covariance_kind":
                v = CovarianceBasis.read(v, "array calibration")
            kw[f.name] = v
        if "covariance_kind" not in d and "covariance_basis" in d:   # written before the kind was stored
            kw["covariance_kind"] = CovarianceBasis.from_text(d["covariance_basis"])
        try:
            return cls(**kw)
        except InputError as exc:
            raise FormatError(f"array calibration: {exc}") from None


def _pair_A(R, s, k, ref: int, i: int, j: int) -> np.ndarray:
    """``A_ij = H_i H_j^-1`` of the joint model's rotations ``R``, scale factors ``s`` and cross-axis terms ``k``
    (None: none) (:mod:`~fusion_gyrocal.core.array`)."""
    from .array import _G_of

    H = [(s[g][:, None] * R[g].T) @ (np.eye(3) if k is None else _G_of(s[ref], k[g])) for g in (i, j)]
    return H[0] @ np.linalg.inv(H[1])


def _log_parameter_covariance(cal: ArrayCalibration, full: bool = False) -> np.ndarray:
    """(6N, 6N) covariance of ``[dtheta_all, log scale_all]`` from the stored one, without the rotations' skew budget
    (``skew_rotation_covariance``); (9N, 9N) with the cross-axis terms ``k_all`` appended when ``full``."""
    n = cal.n_gyros
    d = np.concatenate([np.ones(3 * n), 1.0 / cal.scale.ravel()])
    P = cal.covariance[:6 * n, :6 * n] * np.outer(d, d)
    P[:3 * n, :3 * n] -= cal.skew_rotation_covariance
    if not full:
        return P
    X = cal.cross_axis_covariance
    out = np.zeros((9 * n, 9 * n))
    out[:6 * n, :6 * n] = P
    out[6 * n:, :6 * n] = X[:, :6 * n] * d[None, :]
    out[:6 * n, 6 * n:] = out[6 * n:, :6 * n].T
    out[6 * n:, 6 * n:] = X[:, 9 * n:]
    return out


def pair_convention(A, s1, s2, R0, iterations: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(R, s_1, k)`` with ``A = (I + K) S_1 R S_2^-1``, ``K = cross_matrix(k)`` symmetric with a zero diagonal
    (the pair solver's full linear map, :mod:`~fusion_gyrocal.core.linear_map`), for given ``s_2`` near
    ``(R0, s1)``.

    ``Y = A S_2 R^T`` must be ``(I + K) S_1``: ``s_1 = diag(Y)`` and ``R`` turned by the antisymmetric part of
    ``Y S_1^-1`` until it vanishes (a contraction by the scale factors' spread; a few steps reach float precision).
    """
    R, s1 = np.array(R0, float), np.array(s1, float)
    for _ in range(iterations):
        Y = (np.asarray(A) * np.asarray(s2)[None, :]) @ R.T
        s1 = np.diag(Y).copy()
        X = Y / s1[None, :]
        phi = 0.5 * np.array([X[2, 1] - X[1, 2], X[0, 2] - X[2, 0], X[1, 0] - X[0, 1]])
        R = exp(phi) @ R
        if np.max(np.abs(phi)) < 1e-15:
            break
    Y = (np.asarray(A) * np.asarray(s2)[None, :]) @ R.T
    s1 = np.diag(Y).copy()
    X = Y / s1[None, :]
    k = np.array([0.5 * (X[a, b] + X[b, a]) for a, b in CROSS_AXIS_PAIRS])
    return R, s1, k
