"""Result types and conventions shared by every module.

Conventions (see ``ARCHITECTURE.md``):

* units: rad/s, seconds, float64;
* ``R_1_2`` maps vectors in gyro 2's frame into gyro 1's frame, ``omega_1 = R_1_2 @ omega_2``
  (the paper's C);
* measurement model ``omega_i_meas = S_i @ omega_i + b_i + n_i`` with ``S_i = diag(scale_i)``,
  ``A = S_1 R_1_2 S_2^-1`` (Eq. 4) and combined bias ``bias = b_1 - A b_2`` (Eq. 5);
* scale factors are determined only up to one global factor (Theorem 2); ``gauge`` names the
  choice that fixes it;
* ``time_offset_s`` is ADDED to gyro 2's timestamps to put them on gyro 1's clock.

The parameter vector used by :attr:`PairCalibration.covariance` is (in this order)::

    [dtheta (3, rad), scale_1 (3), scale_2 (3), bias (3, rad/s)]

where ``dtheta`` is the rotation error in gyro 1's frame, ``R_true = Exp(dtheta) @ R_1_2``
(the paper's Appendix B/C perturbation, up to sign). Undetermined scale factors have an
infinite variance and zero correlations.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields
from enum import Enum
from typing import Any

import numpy as np

from ..errors import FormatError, InputError
from ..lie import canonical_rotvec, log
from .robust import CovarianceBasis

FORMAT_VERSION = "1.5"
#: Versions :meth:`PairCalibration.from_dict` reads: 1.0 wrote every non-finite number as ``null``
#: (read back as inf in arrays, NaN in scalars); 1.1-1.4 wrote them as the strings of :data:`NON_FINITE`;
#: 1.4 adds ``scale_ratio_std``, ``nominal_R_1_2``, ``provenance`` and the derived ``rotation``, ``scale_ratio``,
#: ``deviation`` entries (written for readers, recomputed on reading); 1.5 writes every non-finite number as
#: ``null`` and names each one in ``non_finite`` (:func:`strict_json`), and adds the derived ``undetermined``.
READABLE_VERSIONS = ("1.0", "1.1", "1.2", "1.3", "1.4", FORMAT_VERSION)
#: Non-finite numbers as files of format 1.1-1.4 wrote them (strings); read back, never written.
NON_FINITE = {"NaN": float("nan"), "Infinity": float("inf"), "-Infinity": float("-inf")}
#: The kinds of non-finite number :func:`strict_json` lists, and the value each stands for.
NON_FINITE_KINDS = {"inf": float("inf"), "-inf": float("-inf"), "nan": float("nan")}
CONFIGURATIONS = ("general", "one_axis_pair_parallel", "all_axes_parallel")
PARAMETER_NAMES = (
    "dtheta_x", "dtheta_y", "dtheta_z",
    "scale_1_x", "scale_1_y", "scale_1_z",
    "scale_2_x", "scale_2_y", "scale_2_z",
    "bias_x", "bias_y", "bias_z",
)
ROT, S1, S2, BIAS = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)

_ARRAY_SHAPES = {
    "R_1_2": (3, 3), "scale_1": (3,), "scale_2": (3,), "bias": (3,), "scale_observable": (2, 3),
    "covariance": (12, 12), "snr": (3,), "noise_std": (2,), "skew_rotation_covariance": (3, 3),
    "cross_axis": (3, 3), "cross_axis_terms": (3,), "cross_axis_covariance": (3, 3), "intrinsics_2": (3, 3),
    "intrinsics_2_covariance": (6, 6), "scale_ratio_std": (3,),
}
#: Entries :meth:`PairCalibration.to_dict` derives from the fields for readers (not read back).
DERIVED_KEYS = ("rotation", "scale_ratio", "deviation", "undetermined")


def _pointer_token(key) -> str:
    return str(key).replace("~", "~0").replace("/", "~1")


def strict_json(doc: dict) -> dict:
    """``doc`` with every non-finite float replaced by ``null`` and named in ``doc["non_finite"]``.

    Strict JSON has no NaN or infinity, and a number written as a string is no number to a reader. So every
    non-finite number (an undetermined scale factor's infinite variance, a figure not computed) is written as
    ``null``, and ``non_finite`` maps each kind (``"inf"``, ``"-inf"``, ``"nan"``) to the JSON Pointers
    (RFC 6901, e.g. ``"/covariance/4/4"``) of its entries: what is determined stays a finite number, what is not
    is explicit. :func:`restore_non_finite` is the inverse. Nested dicts and lists are walked; ``doc`` is not
    modified.
    """
    found = {k: [] for k in NON_FINITE_KINDS}

    def walk(v, path):
        if isinstance(v, dict):
            return {k: walk(x, f"{path}/{_pointer_token(k)}") for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [walk(x, f"{path}/{i}") for i, x in enumerate(v)]
        if isinstance(v, float) and not np.isfinite(v):
            found["nan" if np.isnan(v) else "inf" if v > 0 else "-inf"].append(path)
            return None
        return v

    out = walk(doc, "")
    out["non_finite"] = found
    return out


def restore_non_finite(doc: dict) -> dict:
    """The inverse of :func:`strict_json`: a copy of ``doc`` with the value of its kind at every pointer of
    ``doc["non_finite"]`` (a document without ``non_finite`` is returned as it is).

    Raises
    ------
    FormatError
        ``non_finite`` is not a mapping of the kinds to lists of pointers, or a pointer names an entry that is not
        ``null`` (a pointer to an entry the file does not hold is ignored).
    """
    marks = doc.get("non_finite")
    if marks is None:
        return doc
    if not isinstance(marks, dict) or set(marks) - set(NON_FINITE_KINDS) or \
            not all(isinstance(v, list) and all(isinstance(p, str) for p in v) for v in marks.values()):
        raise FormatError(f"non_finite: expected a mapping of {sorted(NON_FINITE_KINDS)} to lists of JSON Pointers, "
                          f"got {marks!r}"[:300])
    import copy

    out = copy.deepcopy({k: v for k, v in doc.items() if k != "non_finite"})
    for kind, pointers in marks.items():
        for pointer in pointers:
            tokens = [t.replace("~1", "/").replace("~0", "~") for t in pointer.split("/")[1:]]
            node = out
            try:
                for t in tokens[:-1]:
                    node = node[int(t)] if isinstance(node, list) else node[t]
                key = int(tokens[-1]) if isinstance(node, list) else tokens[-1]
                value = node[key]
            except (KeyError, IndexError, ValueError, TypeError):
                continue   # an entry the file does not hold (a field left out): nothing to restore
            if value is not None:
                raise FormatError(f"non_finite: expected {pointer!r} to name a null entry of the file, got {value!r}"[:200])
            node[key] = NON_FINITE_KINDS[kind]
    return out


def mark_undetermined(cov: np.ndarray, scale_observable) -> np.ndarray:
    """Give the scale factors the data do not determine an infinite variance and no correlations.

    ``cov`` is a (12, 12) covariance in the order of :data:`PARAMETER_NAMES` (modified in place and
    returned); ``scale_observable`` is the (2, 3) flag array.
    """
    for g, a in zip(*np.nonzero(~np.asarray(scale_observable, dtype=bool))):
        k = 3 + 3 * int(g) + int(a)
        cov[k, :], cov[:, k] = 0.0, 0.0
        cov[k, k] = np.inf
    return cov


def rotation_forms(R) -> dict[str, list]:
    """A rotation matrix in the forms its consumers read, as plain lists (JSON-ready).

    ``quaternion_xyzw`` (ROS, tf2, scipy: scalar last) and ``quaternion_wxyz`` (Eigen's constructor, Kalibr's
    ``q``: scalar first) are the same unit quaternion with ``w >= 0``; ``rpy`` is ``[roll, pitch, yaw]`` in rad
    with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (fixed axes x, then y, then z: URDF's ``<origin rpy>``, tf's
    ``setRPY`` and ``static_transform_publisher``'s yaw-pitch-roll); ``rotvec`` the rotation vector (rad,
    :func:`~fusion_gyrocal.lie.canonical_rotvec`); ``matrix`` the 3x3 rows. Near pitch = +-90 deg (gimbal lock)
    the roll and yaw are one of the equivalent pairs; the quaternion and the matrix are always unique.
    """
    import warnings

    from scipy.spatial.transform import Rotation

    r = Rotation.from_matrix(np.asarray(R, dtype=float))
    q = r.as_quat()
    if q[3] < 0:
        q = -q
    with warnings.catch_warnings():   # gimbal lock: scipy warns and still returns a valid triple
        warnings.simplefilter("ignore", UserWarning)
        rpy = r.as_euler("xyz")
    return {"quaternion_xyzw": q.tolist(), "quaternion_wxyz": [q[3], q[0], q[1], q[2]], "rpy": rpy.tolist(),
            "rotvec": canonical_rotvec(log(r.as_matrix())).tolist(), "matrix": r.as_matrix().tolist()}


def parallel_axes(R) -> np.ndarray:
    """For each axis ``a`` of the rotated gyro, the axis of the reference gyro nearest to (anti)parallel to it:
    ``argmax_b |R[b, a]|`` for ``R`` mapping the rotated gyro's frame into the reference's."""
    return np.argmax(np.abs(np.asarray(R)), axis=0)


def ratio_std(ratio: float, var_num: float, var_den: float, cov: float, num: float, den: float) -> float:
    """1-sigma of ``num / den`` from the (co)variances of ``num`` and ``den`` (first order, on the log):
    NaN where one of them is not finite (an undetermined scale factor, :func:`mark_undetermined`)."""
    v = var_num / num ** 2 + var_den / den ** 2 - 2.0 * cov / (num * den)
    return float(ratio * np.sqrt(max(v, 0.0))) if np.isfinite(v) else float("nan")


def scale_ratios(R_1_2, scale_1, scale_2, covariance) -> tuple[np.ndarray, np.ndarray]:
    """``scale_2[a] / scale_1[p(a)]`` for every axis ``a`` of gyro 2, ``p`` its parallel axis of gyro 1
    (:func:`parallel_axes`), and the 1-sigma of each from a (12, 12) covariance in the order of
    :data:`PARAMETER_NAMES`.

    Gauge-invariant (Theorem 2) for axis-parallel gyros (Lemmas 2-3: each pair of parallel axes is a group of
    linked axes whose ratio the data determine although neither scale factor is), and for every pair whose scale
    factors are all determined. The covariance must be the one in the gauge, before
    :func:`mark_undetermined` hides the ratios' information (else NaN where it did).
    """
    p = parallel_axes(R_1_2)
    s1, s2, C = np.asarray(scale_1, float), np.asarray(scale_2, float), np.asarray(covariance, float)
    r = np.array([s2[a] / s1[p[a]] for a in range(3)])
    sd = np.array([ratio_std(r[a], C[6 + a, 6 + a], C[3 + p[a], 3 + p[a]], C[6 + a, 3 + p[a]], s2[a], s1[p[a]])
                   for a in range(3)])
    return r, sd


def rotation_deviation(R, R_nominal, covariance) -> tuple[np.ndarray, np.ndarray]:
    """``d = Log(R R_nominal^T)``, the rotation taking the nominal mounting to the estimate in the reference
    frame (``R = Exp(d) R_nominal``), and its (3, 3) covariance from the estimate's rotation covariance
    ``covariance`` (``R_true = Exp(dtheta) R``): ``d_true ~ d + J_l(d)^-1 dtheta``."""
    from ..lie import exp_and_right_jacobian

    d = log(np.asarray(R, float) @ np.asarray(R_nominal, float).T)
    _, Jl = exp_and_right_jacobian(-d)   # J_l(d) = J_r(-d)
    Ji = np.linalg.inv(Jl)
    return d, Ji @ np.asarray(covariance, float) @ Ji.T


def rotation_text(R, std_rad=None) -> str:
    """One line for a person: angle (deg) about a unit axis, with the 1-sigma norm when given."""
    v = canonical_rotvec(log(np.asarray(R, float)))
    ang = float(np.linalg.norm(v))
    axis = v / ang if ang > 0 else np.array([0.0, 0.0, 1.0])
    sd = "" if std_rad is None else f" +- {np.degrees(float(np.linalg.norm(std_rad))):.3g}"
    return f"{np.degrees(ang):.4f}{sd} deg about ({axis[0]:.4f}, {axis[1]:.4f}, {axis[2]:.4f})"


def _frozen(name, a, shape, dtype=np.float64):
    arr = np.array(a, dtype=dtype)
    if arr.shape != shape:
        raise InputError(f"{name}: expected shape {shape}, got {arr.shape}")
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class PairCalibration:
    """Calibration of a rigidly mounted gyroscope pair.

    Attributes
    ----------
    R_1_2 : ndarray (3, 3)
        Rotation from gyro 2's frame to gyro 1's frame (``omega_1 = R_1_2 @ omega_2``).
    scale_1, scale_2 : ndarray (3,)
        Scale factors (diagonals of S_1, S_2) in the gauge named by ``gauge``.
    bias : ndarray (3,)
        Combined bias ``b_1 - A b_2`` in rad/s (Eq. 5); the mean over the data where the
        bias was modelled piecewise.
    configuration : str
        ``"general"``, ``"one_axis_pair_parallel"`` or ``"all_axes_parallel"`` (Lemmas 2-4).
    scale_observable : ndarray (2, 3) of bool
        Which scale factors the data determine up to the global scale (Theorem 2).
    covariance : ndarray (12, 12)
        Covariance of ``[dtheta, scale_1, scale_2, bias]`` (see module docstring), in the gauge.
    gauge : str
        How the global scale was fixed.
    snr : ndarray (3,)
        Per-axis SNR, ``sqrt(sum_k omega_1,i(k)^2) / sigma`` over the centred signal of gyro 1 with
        ``sigma^2 = sigma_1^2 + sigma_2^2`` (Eq. 36 split per axis).
    n_samples : int
        Samples used.
    noise_std : ndarray (2,)
        White-noise standard deviation per sample of gyro 1 and gyro 2 (rad/s) used for the
        weights and the covariance.
    noise_source : str
        Where ``noise_std`` came from (``"user"``, ``"residual"``, ...).
    residual_rms : float
        RMS of the residual ``omega_1 - A omega_2 - bias`` per axis (rad/s).
    method : str
        Estimator that produced the result (``"direct"``, ``"ml"``, ...).
    iterations : int
        Iterations of the refinement (0 for the direct solution).
    time_offset_s, time_offset_std_s : float
        Offset added to gyro 2's timestamps, and its standard deviation (0 when given aligned); with a clock
        drift, the offset at the middle of the overlap.
    clock_drift_ppm, clock_drift_std_ppm : float
        Drift of gyro 2's clock against gyro 1's (how fast the offset grows, 1e-6 s per s) and its std, when
        it was estimated and compensated (0 otherwise).
    timestamp_quality : tuple of str
        The timestamp diagnosis of each timestamped stream (rate histogram, jitter, bursts, drops).
    skew_rotation_covariance : ndarray (3, 3)
        Rotation error covariance implied by the stated skew uncertainty (Appendix D, Eq. 40-41);
        already included in ``covariance``'s rotation block.
    bias_segments : int
        Number of independent bias segments (1 for a constant bias).
    rigid : bool or None
        Rigidity verdict: False when a rigid rotation and scale factors leave more than 5% of
        gyro 1's motion energy unexplained (``unexplained_fraction``); None when not tested.
    unexplained_fraction : float
        Residual energy over gyro 1's signal energy (0 for a perfect rigid fit).
    rate_residual_correlation : float
        Spearman correlation of the residual norm with the rate norm (the paper's flex signature,
        Section VI.C; near 0 for a rigid pair limited by white noise). NaN when not computed.
    rejected_fraction : float
        Fraction of samples rejected by flex/outlier gating.
    covariance_basis : str
        What ``covariance`` rests on: the noise model's inverse Fisher information, the block-robust
        sandwich (:mod:`~fusion_gyrocal.core.robust`), or the larger of the two in every direction: the sentence
        of ``covariance_kind``.
    covariance_kind : CovarianceBasis
        Which of those it is (:class:`~fusion_gyrocal.core.robust.CovarianceBasis`).
    lack_of_fit : float
        Chi-square of the residual per degree of freedom against the noise model (1 when the model
        explains the residual; rate-dependent misfit, coloured noise or flex make it larger).
    robust_inflation : float
        Largest ratio of the block-robust variance to the noise model's over all directions (NaN when
        not computed): how much more the estimate scatters than the noise model says.
    cross_axis : ndarray (3, 3)
        What the full linear map (Eq. 17) explains beyond rotation and scale factors, as relative
        cross-axis terms in gyro 1's frame (Appendix D; :func:`~fusion_gyrocal.core.robust.cross_axis`);
        zeros when not computed.
    cross_axis_chi2 : float
        Its chi-square with ``cross_axis_dof`` degrees of freedom (NaN when not computed).
    cross_axis_dof : int
    linear_map : {"rigid", "full", "reference"}
        The sensor model of the estimate: ``"rigid"`` the paper's ``A = S_1 R S_2^-1`` (Eq. 4), ``"full"`` the
        full linear map ``A = (I + K) S_1 R S_2^-1`` with symmetric relative cross-axis terms
        (:mod:`~fusion_gyrocal.core.linear_map`; ``R_1_2`` is the rotation under that convention),
        ``"reference"`` gyro 2's whole intrinsic matrix against gyro 1's known one (``intrinsics_1``).
    cross_axis_terms : ndarray (3,)
        The full map's relative cross-axis terms ``(K_xy, K_yz, K_zx)`` (fractions, gyro 1's axes); zeros for
        ``"rigid"``.
    cross_axis_covariance : ndarray (3, 3)
        Their covariance (zeros for ``"rigid"``).
    intrinsics_2 : ndarray (3, 3)
        For ``"reference"``: gyro 2's intrinsic matrix (upper triangular: scale factors on the diagonal, cross-axis
        terms above, gyro 2's measured rate ``intrinsics_2 @ omega_2``); zeros otherwise.
    intrinsics_2_covariance : ndarray (6, 6)
        Covariance of its upper-triangular entries (in the order xx, xy, xz, yy, yz, zz); zeros otherwise.
    timing_tones_hz : tuple of float
        Beat tones of gyro 2's delay against gyro 1's beyond the constant offset
        (:mod:`~fusion_gyrocal.pipeline.timing`; Hz, cycles per sample without timestamps), empty when the residual
        shows none; gyro 2's samples were moved to the instants they describe before the solve.
    timing_delay_s : float
        Mean of gyro 2's delay beyond the time offset (s; samples without timestamps; a filter's group delay in
        sample-aligned input), 0 when none was found.
    timing_delay_std_s : float
        Standard deviation of that delay (s; samples without timestamps).
    timing_explained : float
        Fraction of the residual's energy it explained.
    scale_ratio_std : ndarray (3,)
        1-sigma of :attr:`scale_ratio` (gauge-invariant, finite also where the scale factors themselves are
        undetermined: computed from the covariance before :func:`mark_undetermined`); NaN when not known.
    nominal_R_1_2 : ndarray (3, 3) or None
        The nominal mounting the user gave (``--nominal``); :attr:`deviation` is the estimate against it.
    provenance : Provenance or None
        What the result was computed from (:class:`~fusion_gyrocal.provenance.Provenance`: inputs, options,
        version, masked and rejected samples).
    noise_model : NoiseModel or None
        The noise model identified from the pair's residual (:func:`~fusion_gyrocal.core.noise.identify_noise`)
        when ``noise_std`` came from it.
    notes : tuple of str
        Human-readable warnings (weak axes, prior-dominated directions, ...).
    """

    R_1_2: np.ndarray
    scale_1: np.ndarray
    scale_2: np.ndarray
    bias: np.ndarray
    configuration: str
    scale_observable: np.ndarray
    covariance: np.ndarray
    gauge: str
    snr: np.ndarray
    n_samples: int
    noise_std: np.ndarray
    noise_source: str = "user"
    residual_rms: float = float("nan")
    method: str = "ml"
    iterations: int = 0
    time_offset_s: float = 0.0
    time_offset_std_s: float = 0.0
    skew_rotation_covariance: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    bias_segments: int = 1
    rigid: bool | None = None
    unexplained_fraction: float = float("nan")
    rate_residual_correlation: float = float("nan")
    rejected_fraction: float = 0.0
    covariance_basis: str = "noise model"
    covariance_kind: CovarianceBasis = CovarianceBasis.MODEL
    lack_of_fit: float = float("nan")
    robust_inflation: float = float("nan")
    cross_axis: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    cross_axis_chi2: float = float("nan")
    cross_axis_dof: int = 0
    linear_map: str = "rigid"
    cross_axis_terms: np.ndarray = field(default_factory=lambda: np.zeros(3))
    cross_axis_covariance: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    intrinsics_2: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    intrinsics_2_covariance: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    timing_tones_hz: tuple = ()
    timing_delay_s: float = 0.0
    timing_delay_std_s: float = 0.0
    timing_explained: float = 0.0
    scale_ratio_std: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    nominal_R_1_2: np.ndarray | None = None
    provenance: Any = None
    clock_drift_ppm: float = 0.0
    clock_drift_std_ppm: float = 0.0
    timestamp_quality: tuple = ()
    noise_model: Any = None
    notes: tuple = ()

    def __post_init__(self):
        for name, shape in _ARRAY_SHAPES.items():
            dtype = bool if name == "scale_observable" else np.float64
            object.__setattr__(self, name, _frozen(name, getattr(self, name), shape, dtype))
        if self.configuration not in CONFIGURATIONS:
            raise InputError(f"configuration: expected one of {CONFIGURATIONS}, got {self.configuration!r}")
        object.__setattr__(self, "notes", tuple(self.notes))
        object.__setattr__(self, "timestamp_quality", tuple(self.timestamp_quality))
        object.__setattr__(self, "timing_tones_hz", tuple(float(f) for f in self.timing_tones_hz))
        object.__setattr__(self, "covariance_kind", CovarianceBasis(self.covariance_kind))
        if np.isnan(self.scale_ratio_std).all():   # not given: from the covariance where it keeps the ratios
            object.__setattr__(self, "scale_ratio_std", _frozen("scale_ratio_std", scale_ratios(
                self.R_1_2, self.scale_1, self.scale_2, self.covariance)[1], (3,)))
        if self.nominal_R_1_2 is not None:
            from ..lie import nearest_rotation

            nom = _frozen("nominal_R_1_2", self.nominal_R_1_2, (3, 3))
            if not np.allclose(nom, nearest_rotation(nom), atol=1e-6):
                raise InputError(f"nominal_R_1_2: expected a rotation matrix, got {nom.tolist()}")
            object.__setattr__(self, "nominal_R_1_2", nom)

    def __repr__(self) -> str:
        """One short line: configuration, rotation, relative scales, bias, time offset, samples (not the arrays)."""
        deg = np.degrees
        ratios = ", ".join(f"{r:.5f}" + (f"+-{e:.1g}" if np.isfinite(e) else "") for r, e in
                           zip(self.scale_ratio, self.scale_ratio_std))
        return (f"PairCalibration({self.configuration}, R_1_2 {rotation_text(self.R_1_2, self.rotation_std_rad)}, "
                f"scale_2/scale_1 [{ratios}], bias [{', '.join(f'{b:.4g}' for b in deg(self.bias))}] deg/s, "
                f"time offset {self.time_offset_s * 1e3:+.4g} ms, {self.n_samples} samples, rigid {self.rigid}, "
                f"{self.linear_map}/{self.method})")

    # ------------------------------------------------------------------ derived
    @property
    def A(self) -> np.ndarray:
        """``S_1 R_1_2 S_2^-1`` (Eq. 4), or ``(I + K) S_1 R_1_2 S_2^-1`` for the full linear map."""
        from .observability import A_of

        if self.linear_map == "reference":
            return (self.scale_1[:, None] * self.R_1_2) @ np.linalg.inv(self.intrinsics_2)
        return A_of(self.R_1_2, self.scale_1, self.scale_2, self.cross_axis_terms if self.linear_map == "full"
                    else None)

    @property
    def rotation_std_rad(self) -> np.ndarray:
        """1-sigma rotation uncertainty per axis of gyro 1's frame (rad)."""
        return np.sqrt(np.diag(self.covariance)[ROT])

    @property
    def repeatable_rotation_covariance(self) -> np.ndarray:
        """(3, 3) the rotation covariance without ``skew_rotation_covariance``: what the data determine, and what
        two sessions of one device differ by (the skew budget is the same in every session, so their difference
        cancels it)."""
        return self.covariance[ROT, ROT] - self.skew_rotation_covariance

    @property
    def scale_std(self) -> np.ndarray:
        """(2, 3) 1-sigma scale-factor uncertainty in the gauge (inf where undetermined)."""
        d = np.diag(self.covariance)
        return np.sqrt(np.stack([d[S1], d[S2]]))

    @property
    def bias_std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance)[BIAS])

    @property
    def rotvec(self) -> np.ndarray:
        """Rotation vector (axis * angle, rad) of ``R_1_2``, canonical at 180 deg (:func:`fusion_gyrocal.lie.canonical_rotvec`)."""
        return canonical_rotvec(log(self.R_1_2))

    @property
    def rotation(self):
        """``R_1_2`` as a :class:`scipy.spatial.transform.Rotation` (``rotation.apply(omega_2)`` is in gyro 1's
        frame)."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_matrix(self.R_1_2)

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        """Unit quaternion of ``R_1_2``, scalar last, ``w >= 0`` (ROS / tf2 / scipy order)."""
        return np.array(rotation_forms(self.R_1_2)["quaternion_xyzw"])

    @property
    def quaternion_wxyz(self) -> np.ndarray:
        """Unit quaternion of ``R_1_2``, scalar first, ``w >= 0`` (Eigen's constructor order)."""
        return np.array(rotation_forms(self.R_1_2)["quaternion_wxyz"])

    @property
    def rpy(self) -> np.ndarray:
        """``[roll, pitch, yaw]`` (rad) of ``R_1_2 = Rz(yaw) Ry(pitch) Rx(roll)`` (URDF / tf convention)."""
        return np.array(rotation_forms(self.R_1_2)["rpy"])

    @property
    def scale_ratio(self) -> np.ndarray:
        """``scale_2[a] / scale_1[p(a)]`` per axis of gyro 2, ``p(a)`` the parallel axis of gyro 1
        (:func:`scale_ratios`): the relative scale factors, gauge-invariant; 1-sigma in :attr:`scale_ratio_std`."""
        p = parallel_axes(self.R_1_2)
        return self.scale_2 / self.scale_1[p]

    @property
    def deviation(self):
        """``(d, covariance)``: the rotation vector (rad, gyro 1's frame) from :attr:`nominal_R_1_2` to the
        estimate, ``R_1_2 = Exp(d) nominal_R_1_2``, and its (3, 3) covariance; None without a nominal."""
        if self.nominal_R_1_2 is None:
            return None
        return rotation_deviation(self.R_1_2, self.nominal_R_1_2, self.covariance[ROT, ROT])

    def compensate(self, omega_2) -> np.ndarray:
        """Predict gyro 1's measurement from gyro 2's: ``A @ omega_2 + bias`` for (N, 3) input."""
        return np.asarray(omega_2) @ self.A.T + self.bias

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary with ``format_version``: strict JSON, every number a number; NaN and +-inf
        (an undetermined scale factor's variance) are ``null``, each named in ``non_finite`` (:func:`strict_json`),
        and the parameters with an infinite variance are listed by name in ``undetermined``."""
        out: dict[str, Any] = {"format_version": FORMAT_VERSION, "units": {"rate": "rad/s", "time": "s"},
                               "convention": "omega_1 = R_1_2 @ omega_2; omega_i_meas = diag(scale_i) omega_i + b_i",
                               "covariance_order": list(PARAMETER_NAMES)}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                v = to_json_list(v)
            elif isinstance(v, float):
                v = to_json_number(v)
            elif isinstance(v, tuple):
                v = list(v)
            elif f.name in ("noise_model", "provenance") and v is not None:
                v = v.to_dict()
            elif isinstance(v, Enum):
                v = v.value
            out[f.name] = v
        out.update(self._derived())
        return strict_json(out)

    def _derived(self) -> dict[str, Any]:
        """The :data:`DERIVED_KEYS` entries: the rotation in every form, the relative scale factors with their
        1-sigma (finite numbers, null where not known) and the deviation from the nominal mounting."""
        def num(x):
            return float(x) if np.isfinite(x) else None

        with np.errstate(invalid="ignore"):   # a negative variance (a hand-made covariance) is no number
            rot_sd = self.rotation_std_rad
        out: dict[str, Any] = {
            "rotation": {"of": "R_1_2: gyro 2's frame into gyro 1's (omega_1 = R_1_2 @ omega_2)",
                         **rotation_forms(self.R_1_2),
                         "std_rad": [num(x) for x in rot_sd]},
            "scale_ratio": {"of": "scale_2[a] / scale_1[axis_of_gyro_1[a]] per axis a of gyro 2",
                            "axis_of_gyro_1": parallel_axes(self.R_1_2).tolist(),
                            "value": [num(x) for x in self.scale_ratio],
                            "std": [num(x) for x in self.scale_ratio_std]},
            "deviation": None,
            "undetermined": [name for name, v in zip(PARAMETER_NAMES, np.diag(self.covariance)) if np.isposinf(v)]}
        dev = self.deviation
        if dev is not None:
            d, C = dev
            out["deviation"] = {"of": "R_1_2 = Exp(rotvec) @ nominal_R_1_2 (rotvec in gyro 1's frame)",
                                "rotvec_rad": d.tolist(), "angle_deg": float(np.degrees(np.linalg.norm(d))),
                                "std_rad": [num(x) for x in np.sqrt(np.clip(np.diag(C), 0.0, None))],
                                "covariance": [[num(x) for x in row] for row in C]}
        return out

    def to_json(self, **kwargs) -> str:
        return json.dumps(self.to_dict(), **kwargs)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "PairCalibration":
        """Inverse of :meth:`to_dict`, for every version of :data:`READABLE_VERSIONS`; a file with the
        ``covariance_basis`` sentence only (1.0-1.2) gets the basis it names
        (:meth:`~fusion_gyrocal.core.robust.CovarianceBasis.from_text`)."""
        version = d.get("format_version")
        if version not in READABLE_VERSIONS:
            raise FormatError(f"calibration: expected format_version {FORMAT_VERSION!r} (or an earlier "
                              f"{', '.join(repr(v) for v in READABLE_VERSIONS[:-1])}), got {version!r}")
        legacy = version == "1.0"
        d = restore_non_finite(d)
        kwargs = {}
        for f in fields(cls):
            if f.name not in d:
                continue
            v = d[f.name]
            if f.name == "noise_model":
                if v is not None:
                    from .noise import NoiseModel
                    v = NoiseModel.from_dict(v)
            elif f.name == "provenance":
                if v is not None:
                    from ..provenance import Provenance
                    v = Provenance.from_dict(v)
            elif f.name == "nominal_R_1_2":
                v = None if v is None else from_json_list(v, np.float64)
            elif f.name in _ARRAY_SHAPES:
                v = from_json_list(v, bool if f.name == "scale_observable" else np.float64, legacy)
            elif f.name == "covariance_kind":
                v = CovarianceBasis.read(v)
            elif f.name != "rigid" and (v is None or isinstance(v, str) and v in NON_FINITE):
                v = float("nan") if v is None else NON_FINITE[v]
            kwargs[f.name] = v
        if "covariance_kind" not in d and "covariance_basis" in d:   # written before the kind was stored
            kwargs["covariance_kind"] = CovarianceBasis.from_text(d["covariance_basis"])
        return cls(**kwargs)


def to_json_number(x: float) -> float:
    """``x`` as a Python float (a non-finite one stays: :func:`strict_json` writes it as ``null``)."""
    return float(x)


def to_json_list(a: np.ndarray) -> list:
    """``a`` as nested lists of Python floats (or bools); non-finite entries are left to :func:`strict_json`."""
    return np.asarray(a).tolist()


def from_json_list(v, dtype, legacy: bool = False):
    if dtype is bool:
        return np.array(v, dtype=bool)
    arr = np.array(v, dtype=object)
    null = arr == None  # noqa: E711
    if legacy:  # format 1.0 wrote every non-finite entry as null; they were the undetermined (infinite) ones
        arr = np.where(null, np.inf, arr)
    elif np.any(null):
        raise FormatError("calibration: expected numbers or 'NaN'/'Infinity'/'-Infinity' in arrays, got null")
    for text, value in NON_FINITE.items():
        arr = np.where(arr == text, value, arr)
    try:
        return arr.astype(np.float64)
    except (TypeError, ValueError):
        raise FormatError(f"calibration: expected numbers in arrays, got {v!r}") from None
