"""Calibrate a gyroscope pair from its moments: :func:`solve`.

Pipeline: moments -> direct least squares for A (Eq. 17) -> configuration class (Lemmas 2-4)
-> decomposition -> gauge (Theorem 2, Eq. 32-34) -> maximum-likelihood refinement (Appendix C
generalised, default) -> the sensor model the data call for (the full linear map or gyro 2's intrinsics,
:mod:`~fusion_gyrocal.core.linear_map`) -> covariance from the Fisher information (Appendix B generalised),
checked block-robustly (:mod:`~fusion_gyrocal.core.robust`) -> skew budget (Appendix D).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import InputError, NotRigidError, OptionError
from ..lie import log, nearest_rotation
from ..options import Options
from .direct import decompose, solve_A
from .gauge import Gauge, constrained_inverse
from .linear_map import (UPPER, choose_full_map, cross_axis_budget, decompose_reference, prior_information,
                         reference_derivatives, reference_map, refine_full, refine_reference)
from .model import BIAS, ROT, PairCalibration, mark_undetermined, scale_ratios
from .moments import Moments, WindowStats, noise_pair
from .noise import check_residual_dof
from .observability import (PRIOR_GAUGE, A_of, check_excitation, check_samples, classify, dA_dp, information_of_A,
                            parallel_tilt_bias, per_axis_snr, prior_held_covariance, residual_weight, signal_scatter)
from .refine import residual_scatter, refine_ml
from .robust import (MIN_ROBUST_WINDOWS, CovarianceBasis, bias_variance, cross_axis, effective_windows, larger,
                     reported_covariance, sandwich, score_variance, scores_of_A)


def _residual_noise(moments: Moments, A, ratio: float = 1.0) -> tuple[float, float]:
    """Noise per gyro from the least-squares residual, split in the ratio ``sigma_1 / sigma_2``."""
    check_residual_dof(3.0 * (moments.dof - 3.0))   # before any noise is estimated from the residual
    M = residual_scatter(A, moments.scatter)
    dof = max(moments.dof - 3.0, 1.0)
    total = float(np.trace(M)) / (3.0 * dof)
    floor = 1e-24 * float(np.trace(moments.S11)) / (3.0 * dof)  # noise-free input: keep weights finite
    s2 = max(total, floor) / (1.0 + ratio**2)
    return float(np.sqrt(s2) * ratio), float(np.sqrt(s2))


def _skew_compensation(intrinsics):
    """``U^-1`` for an upper-triangular intrinsic matrix ``S = U D`` (U unit upper triangular; checked by
    :class:`~fusion_gyrocal.options.Options`)."""
    if intrinsics is None:
        return np.eye(3)
    S = np.asarray(intrinsics, dtype=float)
    U = S / np.diag(S)[None, :]
    return np.linalg.inv(U)


#: Largest plausible ratio of the two gyros' rate magnitudes (scale factors of real gyros differ by percent).
MAX_GAIN_RATIO = 1.5


def _check_plausible_A(A, moments: Moments | None = None, noise=None) -> None:
    """Refuse an ``A`` no rigid pair of gyros in the same unit gives: a mirrored frame or a unit mismatch.

    ``A = S_1 R S_2^-1`` (Eq. 4) has ``det(A) > 0`` and singular values near 1 for any real pair; a
    negative determinant is a left-handed frame (an axis sign-inverted or two axes swapped), and a
    common gain far from 1 is one gyro in other units (57.3 for deg/s read as rad/s). Least squares
    attenuates ``A`` where gyro 2's noise is comparable to its motion (Eq. 17 ignores the noise in the
    regressor); with ``moments`` and ``noise`` the gain is judged on ``A S22 (S22 - dof sigma_2^2 I)^-1``.
    """
    if moments is not None and noise is not None:   # undo the attenuation (check_excitation bounds it)
        A = A @ moments.S22 @ np.linalg.inv(moments.S22 - moments.dof * noise[1] ** 2 * np.eye(3))
    gain = float(np.prod(np.linalg.svd(A, compute_uv=False)) ** (1.0 / 3.0))   # |det A|^(1/3)
    if np.linalg.det(A) < 0:
        raise InputError("gyro 2's axes form a left-handed frame relative to gyro 1's (det(A) < 0, no rotation "
                         "maps one onto the other): one axis is sign-inverted or two axes are swapped (wiring, "
                         "driver or export error); fix gyro 2's axis mapping (negate or swap its columns)")
    if not 1.0 / MAX_GAIN_RATIO <= gain <= MAX_GAIN_RATIO:
        hint = ""
        for name, factor in (("deg/s", np.rad2deg(1.0)), ("rad/s", np.deg2rad(1.0))):
            if abs(np.log(gain / factor)) < np.log(1.15):
                hint = (f" (x{gain:.4g}: gyro 1 in {name}, gyro 2 in {'rad/s' if name == 'deg/s' else 'deg/s'}?"
                        " pass the unit of each gyro, --unit1/--unit2)")
        raise InputError(f"gyro 1's rates are {gain:.4g} times gyro 2's (expected near 1 for two gyros in the same "
                         f"unit: scale factors differ by percent){hint}; check the units (rad/s, deg/s, raw counts "
                         "with their sensitivity) of both recordings")


def _transform(moments: Moments, windows: WindowStats | None, T1, T2):
    """The moments and window statistics of ``[T1 omega_1; T2 omega_2]``."""
    T = np.zeros((6, 6))
    T[:3, :3], T[3:, 3:] = T1, T2
    moments = Moments(moments.count, T @ moments.mean, T @ moments.scatter @ T.T, moments.segments)
    if windows is not None:
        windows = dataclasses.replace(windows, mean=windows.mean @ T.T, scatter=T @ windows.scatter @ T.T)
    return moments, windows


def solve(moments: Moments, options: Options | None = None, *, noise_ratio: float | None = None,
          windows: WindowStats | None = None, noise_model=None, noise=None, **keywords) -> PairCalibration:
    """Calibrate a pair from its sufficient statistics.

    Pipeline: direct least squares for A (Eq. 17) -> rigidity test -> excitation test (Lemma 1) ->
    configuration class and decomposition (Lemmas 2-4) -> gauge (Theorem 2, Eq. 32-34) ->
    maximum-likelihood refinement (``method="ml"``) -> sensor model (``linear_map``, ``intrinsics_1``) ->
    covariance (Appendix B generalised) -> skew error budget (Appendix D, Eq. 40-41).

    Parameters
    ----------
    moments : Moments
        Statistics of sample-aligned ``[omega_1; omega_2]`` (pooled per segment for a
        piecewise-constant bias).
    options : Options, optional
        The solve options (:class:`~fusion_gyrocal.options.Options`; its pipeline options play no part
        here). Default: ``Options()``.
    noise_ratio : float, optional
        ``sigma_1 / sigma_2`` used to split the residual variance when ``noise_std`` is not given
        (only the sum ``sigma_1^2 + sigma_2^2`` is observable from the residual); default 1.
        :func:`~fusion_gyrocal.calibrate_pair` estimates it from each stream's third differences.
    windows : WindowStats, optional
        Per-window statistics of the same samples (:func:`~fusion_gyrocal.core.moments.window_stats`):
        with them the covariance is also computed block-robustly (:mod:`~fusion_gyrocal.core.robust`)
        and ``options.covariance`` chooses what is reported. Without them the Fisher covariance is
        reported, inflated by the residual's chi-square per degree of freedom when a user's
        ``noise_std`` explains less than the residual.
    noise_model : NoiseModel, optional
        The identified noise model behind ``noise`` (:func:`~fusion_gyrocal.core.noise.identify_noise`), carried
        into the result.
    noise : float or (float, float), optional
        The white noise per sample (rad/s) the moments are weighed with when the caller derived it (identified:
        ``noise_model``'s, or that of a random-walk bias's innovations); default ``options.noise_std``, the user's.
    **keywords
        Fields of :class:`~fusion_gyrocal.options.Options` (``method``, ``noise_std``, ``gauge``, ...),
        applied on top of ``options``.

    Returns
    -------
    PairCalibration

    Raises
    ------
    OptionError
        An option value it does not accept.
    ExcitationError
        Motion that does not determine every parameter (Lemma 1).
    NotRigidError
        The pair is not rigid and ``on_not_rigid="raise"``.
    """
    o = Options.of(options, **keywords)
    gauge = Gauge.parse(o.gauge)
    if o.intrinsics_1 is not None or o.intrinsics_2 is not None:
        moments, windows = _transform(moments, windows, _skew_compensation(o.intrinsics_1),
                                      _skew_compensation(o.intrinsics_2))
    noise = noise_pair(noise) if noise is not None else None if o.noise_std is None else noise_pair(o.noise_std)
    user_noise = noise is not None and noise_model is None
    check_samples(moments)
    A_ls, _ = solve_A(moments)
    unexplained = float(np.trace(residual_scatter(A_ls, moments.scatter)) / np.trace(moments.S11))
    rigid = unexplained <= o.max_unexplained
    if not rigid and o.on_not_rigid == "raise":
        raise NotRigidError(
            f"not rigid: a single rotation and scale factors leave {100 * unexplained:.1f}% of gyro 1's motion "
            f"unexplained (a rigid pair leaves <= {100 * o.max_unexplained:g}%); the gyros move relative to each "
            "other, the streams are misaligned in time, or they are not the same device")
    noise, noise_source = _noise_of(moments, A_ls, noise, noise_ratio, noise_model)
    if rigid:
        check_excitation(moments, noise, min_snr=o.min_snr)
        _check_plausible_A(A_ls, moments, noise)
    fit = _fit(moments, windows, A_ls, noise, rigid, gauge, o)
    A, D = fit.map()
    bias = moments.mean_1 - A @ moments.mean_2
    W, M = residual_weight(A, noise), residual_scatter(A, moments.scatter)
    # lack of fit: the residual's chi-square per degree of freedom against the stated noise
    lack_of_fit = float(np.trace(W @ M)) / max(3.0 * moments.dof - fit.n_free, 1.0)
    P, F = _model_covariance(moments, fit, A_ls, A, D, noise, gauge, o)
    P, Sigma_r, inflation, basis_kind, basis, more = _reported_covariance(
        moments, windows, fit, P, F, A, D, bias, noise, user_noise, gauge, o, lack_of_fit, np.linalg.inv(W))
    notes = fit.notes + ([] if rigid else [f"NOT RIGID: {100 * unexplained:.1f}% of the motion is unexplained; do "
                                           "not use this estimate"]) + more
    cov = parameter_covariance(P, fit.jacobian(len(P)), D, moments, Sigma_r)
    ratio_sd = scale_ratios(fit.R, fit.s1, fit.s2, cov)[1]   # gauge-invariant: kept before the marking hides it
    if o.scale_prior_std is None:
        mark_undetermined(cov, fit.observable)
    budget = (cross_axis_budget(fit.k, P[9:, 9:], o.cross_axis_std if fit.shown else None)
              if fit.model == "full" else 0.0)   # the antisymmetric cross-axis part no data see, per axis
    sk = np.asarray(o.skew_std, dtype=float)
    skew_cov = (0.25 * (sk[0] ** 2 + sk[1] ** 2) + budget) * np.eye(3)   # Appendix D: theta ~ (w_1 - C w_2) / 2
    cov[ROT, ROT] += skew_cov
    tilt = parallel_tilt_bias(A_ls, fit.R, fit.s1, fit.s2, fit.config, np.diag(cov[ROT, ROT])) \
        if fit.model == "rigid" and fit.rigid else np.zeros(3)
    cov[ROT, ROT] += np.diag(tilt ** 2)      # the gauge's scale ratios times the tilt (all axes parallel)
    snr = per_axis_snr(moments, noise)
    notes += _notes(fit, P, snr, budget, o) + _tilt_note(tilt, cov[ROT, ROT])
    return PairCalibration(
        R_1_2=fit.R, scale_1=fit.s1, scale_2=fit.s2, bias=bias, configuration=fit.config.name,
        scale_observable=fit.observable, covariance=cov, gauge=_gauge_text(fit, gauge, o), snr=snr,
        n_samples=int(moments.count), noise_std=np.array(noise), noise_source=noise_source,
        residual_rms=float(np.sqrt(max(np.trace(M), 0.0) / (3.0 * max(moments.dof, 1.0)))), method=o.method,
        iterations=fit.iterations, skew_rotation_covariance=skew_cov, bias_segments=moments.segments,
        rigid=rigid, unexplained_fraction=unexplained, covariance_basis=basis, covariance_kind=basis_kind,
        lack_of_fit=lack_of_fit, robust_inflation=inflation, cross_axis=fit.E, cross_axis_chi2=fit.chi2,
        cross_axis_dof=fit.dof, linear_map=fit.model, cross_axis_terms=np.zeros(3) if fit.k is None else fit.k,
        cross_axis_covariance=P[9:, 9:] if fit.model == "full" else np.zeros((3, 3)),
        intrinsics_2=np.zeros((3, 3)) if fit.S2 is None else fit.S2,
        intrinsics_2_covariance=P[3:, 3:] if fit.model == "reference" else np.zeros((6, 6)), noise_model=noise_model,
        scale_ratio_std=ratio_sd,
        notes=tuple(notes))


@dataclasses.dataclass
class _Fit:
    """The estimate in the parameters of its sensor model (``model``: "rigid", "full" or "reference")."""

    R: np.ndarray
    s1: np.ndarray
    s2: np.ndarray
    config: object
    model: str = "rigid"
    k: np.ndarray | None = None          # "full": the cross-axis terms
    S2: np.ndarray | None = None         # "reference": gyro 2's intrinsic matrix
    iterations: int = 0
    notes: list = dataclasses.field(default_factory=list)
    E: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((3, 3)))
    chi2: float = float("nan")
    dof: int = 0
    shown: bool = False                  # the data show cross-axis terms (their chi-square, p < 0.001)
    rigid: bool = True                   # False: the nearest rotation with unit scales, never refined

    def map(self):
        """``(A, dA/dp)`` of the model."""
        if self.model == "reference":
            return reference_map(self.R, self.S2, self.s1), reference_derivatives(self.R, self.S2, self.s1)
        return A_of(self.R, self.s1, self.s2, self.k), dA_dp(self.R, self.s1, self.s2, self.k)

    @property
    def n_free(self) -> float:
        """Parameters fitted beyond the bias (the residual's degrees of freedom lost to them)."""
        return {"rigid": 8.0, "full": 11.0, "reference": 9.0}[self.model]

    @property
    def observable(self) -> np.ndarray:
        return np.ones((2, 3), bool) if self.model == "reference" else self.config.scale_observable

    def jacobian(self, n: int) -> np.ndarray:
        """(9, n): ``[dtheta, scale_1, scale_2]`` from the model's ``n`` parameters."""
        J = np.zeros((9, n))
        J[:3, :3] = np.eye(3)
        if self.model == "reference":    # scale_1 known; scale_2 the diagonal of S_2 (UPPER 0, 3, 5)
            J[6, 3], J[7, 6], J[8, 8] = 1.0, 1.0, 1.0
        else:                            # log scale factors
            J[3:9, 3:9] = np.diag(np.concatenate([self.s1, self.s2]))
        return J


def _noise_of(moments, A_ls, noise, noise_ratio, noise_model):
    """The noise per gyro and where it came from (the residual's, split by ``noise_ratio``, when not given)."""
    if noise is None:
        ratio = 1.0 if noise_ratio is None or not np.isfinite(noise_ratio) else float(noise_ratio)
        return _residual_noise(moments, A_ls, ratio), ("residual (split equally between the gyros)"
                                                      if noise_ratio is None else
                                                      f"residual, split {ratio:.3g}:1 by the third differences of "
                                                      "each stream")
    if noise_model is not None:
        return noise, f"identified from the pair's residual ({noise_model.kind}, bias {noise_model.bias_model})"
    return noise, "user"


def _fit(moments, windows, A_ls, noise, rigid: bool, gauge, o: Options) -> _Fit:
    """Decomposition (Lemmas 2-4), gauge (Theorem 2), maximum likelihood, then the sensor model the data call for
    (:mod:`~fusion_gyrocal.core.linear_map`)."""
    # classify from the polar factor of A (scales ~1), then again from the decomposed rotation
    config = classify(nearest_rotation(A_ls), o.parallel_tol_deg)
    if rigid:
        R, s1, s2 = decompose(A_ls, config)
        config = classify(R, o.parallel_tol_deg)
        R, s1, s2 = decompose(A_ls, config)
    else:  # no rigid model fits: report the nearest rotation with unit scales, flagged, never refined
        R, s1, s2 = nearest_rotation(A_ls), np.ones(3), np.ones(3)
    s1, s2 = gauge.apply(config.groups, np.stack([s1, s2]))
    fit = _Fit(R, s1, s2, config, rigid=rigid)

    def constraints(a, b):
        return gauge.constraints(config.groups, [a, b], 3)

    def regauge(a, b):
        return tuple(gauge.apply(config.groups, [a, b]))

    if o.method == "ml" and rigid:
        ref = refine_ml(moments, R, s1, s2, noise, constraints=constraints, regauge=regauge)
        fit.R, fit.s1, fit.s2, fit.iterations = ref.R, ref.s1, ref.s2, ref.iterations
        if not ref.converged:
            fit.notes.append(f"maximum-likelihood refinement stopped after {ref.iterations} iterations without "
                             "converging")
    if rigid and o.method == "ml" and o.intrinsics_1 is not None and o.intrinsics_2 is None:
        fit.model, fit.s1 = "reference", np.diag(np.asarray(o.intrinsics_1, dtype=float)).copy()
        fit.R, fit.S2, it, converged = refine_reference(moments, *decompose_reference(A_ls, fit.s1), fit.s1, noise)
        fit.s2, fit.iterations = np.diag(fit.S2).copy(), fit.iterations + it
        fit.config = classify(fit.R, o.parallel_tol_deg)
        if not converged:
            fit.notes.append(f"the refinement of gyro 2's intrinsics stopped after {it} iterations without converging")
        return fit
    if rigid:
        fit.E, fit.chi2, fit.dof = cross_axis(A_ls, fit.R, fit.s1, fit.s2, moments, noise, windows,
                                              n_null=len(config.groups))
    full, fit.shown = choose_full_map(o.linear_map, o.method, fit.chi2, fit.dof)
    if full and rigid:
        fm = refine_full(moments, fit.R, fit.s1, fit.s2, noise, o.cross_axis_std, constraints=constraints,
                         regauge=regauge)
        fit.model, fit.R, fit.s1, fit.s2, fit.k = "full", fm.R, fm.s1, fm.s2, fm.k
        fit.iterations += fm.iterations
        if not fm.converged:
            fit.notes.append(f"the full linear map's refinement stopped after {fm.iterations} iterations without "
                             "converging")
    if o.scale_prior_std is not None:
        # the prior holds only what the data leave free, one common factor per group of linked scale factors;
        # its maximum there is the group's unit convention, so the determined ratios stay the data's
        fit.s1, fit.s2 = PRIOR_GAUGE.apply(config.groups, np.stack([fit.s1, fit.s2]))
    return fit


def _model_covariance(moments, fit: _Fit, A_ls, A, D, noise, gauge, o: Options):
    """``(P, F)``: the noise model's covariance of the fit's parameters and their information (with the
    cross-axis prior of the full map)."""
    _, Xi_c = signal_scatter(moments, noise)
    F = information_of_A(A, D, noise, Xi_c)
    if fit.model == "full":
        F = F + prior_information(o.cross_axis_std)
    if fit.model == "reference":
        return constrained_inverse(F, np.zeros((0, 9))), F
    if o.method == "ml":
        return _ml_covariance(F, fit.s1, fit.s2, fit.config, gauge, o.scale_prior_std), F
    return _direct_covariance(moments, A_ls, noise, fit.config, gauge), F


def _reported_covariance(moments, windows, fit: _Fit, P, F, A, D, bias, noise, user_noise, gauge, o: Options,
                         lack_of_fit, Sigma_residual):
    """The covariance reported (:func:`~fusion_gyrocal.core.robust.reported_covariance`) and that of the mean
    residual (the bias estimate's own noise): ``(P, Sigma_r, inflation, kind, basis, notes)``."""
    Sigma_r = Sigma_residual / moments.count      # under the noise model
    basis = "noise model (inverse Fisher information, Appendix B)" if o.method == "ml" else \
        "noise model (first-order propagation of Cov(A))"
    robust = None
    if fit.rigid and o.method == "ml" and windows is not None:
        def robust():
            V = score_variance(scores_of_A(A, D, noise, windows), windows)
            if fit.model == "full":   # the cross-axis prior's part of the scores' variance (the model's)
                V = V + 4.0 * prior_information(o.cross_axis_std)
            # the data's part in the gauge the covariance is expressed in; a prior's part (what the data leave
            # free) is the model's and stays
            held = PRIOR_GAUGE if o.scale_prior_std is not None else gauge
            C = (np.zeros((0, 9)) if fit.model == "reference" else
                 _padded(held.constraints(fit.config.groups, [fit.s1, fit.s2], 3), len(F)))
            return P + sandwich(F, V, C) - constrained_inverse(F, C)
    P, inflation, kind, basis, notes = reported_covariance(
        P, robust, windows, o.covariance, basis, lack_of_fit, user_noise=user_noise, what="flex, skew, time offset")
    if kind in (CovarianceBasis.CHECKED, CovarianceBasis.RAISED, CovarianceBasis.ROBUST):
        if not windows.pooled and moments.segments == 1:
            Sigma_b = bias_variance(A, bias, windows)
            Sigma_r = Sigma_b if o.covariance == "robust" else larger(Sigma_r, Sigma_b, effective_windows(windows))[0]
    elif o.covariance == "robust":
        raise OptionError("covariance='robust': expected per-window statistics (windows=...) of an 'ml' solve of a "
                          f"rigid pair with at least {MIN_ROBUST_WINDOWS} windows; calibrate_pair computes them")
    elif kind is CovarianceBasis.INFLATED:
        Sigma_r = Sigma_r * lack_of_fit
    return P, Sigma_r, inflation, kind, basis, notes


def _notes(fit: _Fit, P, snr, budget: float, o: Options) -> list:
    """The notes on the sensor model (``budget``: the full map's skew variance per axis), the per-axis SNR and the
    configuration."""
    notes = []
    if fit.model == "full":
        notes.append(_full_map_note(fit.k, P[9:, 9:], fit.chi2, fit.dof, budget,
                                    o.cross_axis_std if fit.shown else None))
    elif fit.shown:
        off = np.abs(fit.E - np.diag(np.diag(fit.E))).max()
        notes.append(f"the full linear map fits significantly better than rotation + scale factors (chi2 "
                     f"{fit.chi2:.3g} for {fit.dof} dof, p < 0.001): relative cross-axis terms up to {off:.2g} "
                     f"remain (cross_axis). Skew errors of that size that the data cannot see move the rotation by "
                     f"about {np.rad2deg(off / 2) * 1e3:.3g} mdeg (Appendix D, Eq. 40): use linear_map='auto' or "
                     "'full', compensate the intrinsics (intrinsics_1/2) or pass skew_std to budget for it")
    elif fit.model == "reference":
        notes.append(_reference_note(fit.S2, P[3:, 3:]))
    weak = [f"{'xyz'[i]} ({snr[i]:.3g})" for i in range(3) if snr[i] < o.target_snr]
    if weak:
        notes.append(f"per-axis SNR below the target {o.target_snr:g} (the paper accumulates to 4e3) on axis "
                     f"{', '.join(weak)}: rotate more about those axes of gyro 1, or record longer")
    if fit.config.name != "general":
        pairs = ", ".join(f"gyro 1 {'xyz'[i]} ~ gyro 2 {'xyz'[j]} ({ang:.2f} deg)"
                          for i, j, ang in fit.config.parallel_pairs)
        held = ("; their common factor comes from the scale prior (scale_observable False)"
                if o.scale_prior_std is not None else "")
        notes.append(f"{fit.config.name}: {pairs}; only the ratio of those scale factors is determined (Lemma "
                     f"{'2' if fit.config.name == 'all_axes_parallel' else '3'}){held}")
    return notes


def _tilt_note(tilt, rotation_cov) -> list:
    """The note on :func:`~fusion_gyrocal.core.observability.parallel_tilt_bias` when it matters (a tenth of the
    rotation's std or more)."""
    if not np.any(tilt ** 2 >= 0.01 * np.diag(rotation_cov)):
        return []
    return [f"all axes parallel with the paper's model (linear_map='rigid'): the axes' undetermined scale ratios "
            f"bias the tilt by up to {np.rad2deg(tilt.max()) * 1e3:.3g} mdeg per axis, budgeted in the covariance "
            "(linear_map='auto' fits the symmetric cross-axis part instead)"]


def _gauge_text(fit: _Fit, gauge, o: Options) -> str:
    if fit.model == "reference":
        return "absolute: gyro 1's intrinsic matrix is given (intrinsics_1)"
    if o.scale_prior_std is not None:
        return (f"Gaussian prior N(1, {o.scale_prior_std:g}^2) on the scale factors, acting only on what the data "
                "leave free: the global scale and the common factor of each parallel axis pair (ratios from the data)")
    return gauge.describe()


def _reference_note(S2, cov):
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    off = ", ".join(f"{'xyz'[a]}{'xyz'[b]} {100 * S2[a, b] / S2[b, b]:.3g} +- {100 * sd[p] / S2[b, b]:.2g} %"
                    for p, (a, b) in enumerate(UPPER) if a != b)
    return ("gyro 2's intrinsic matrix from gyro 1's (the result's intrinsics_2; upper triangular, gyro 2's x axis and xy "
            f"plane define its frame): scale factors {', '.join(f'{v:.5g}' for v in np.diag(S2))}, cross-axis {off}")


def _padded(C, n):
    """Gauge constraints on ``[dtheta, log s]`` (k, 9) extended by zeros to ``n`` parameters (the full map's ``k``)."""
    return np.hstack([C, np.zeros((len(C), n - C.shape[1]))]) if n > C.shape[1] else C


def _full_map_note(k, cov_k, chi2, dof, budget: float, budget_prior):
    sd = np.sqrt(np.clip(np.diag(cov_k), 0.0, None))
    terms = ", ".join(f"{n} {100 * v:.3g} +- {100 * e:.2g} %" for n, v, e in zip(("xy", "yz", "zx"), k, sd))
    pooled = "" if budget_prior is None else f", pooled with cross_axis_std {budget_prior:g}"
    return (f"full linear map (cross-axis chi2 {chi2:.3g} for {dof} dof): symmetric relative cross-axis terms "
            f"{terms}; R_1_2 is the rotation under the symmetric convention, repeatable from session to session. "
            f"The chip-to-chip rotation differs from it by the antisymmetric part, which no data see: budgeted at "
            f"{np.rad2deg(np.sqrt(budget)):.3g} deg per axis, as large as the "
            f"symmetric part{pooled} (skew_rotation_covariance, included in the covariance)")


def _ml_covariance(F, s1, s2, config, gauge, scale_prior_std):
    if scale_prior_std is not None:
        return prior_held_covariance(F, config.groups, s1, s2, scale_prior_std)
    return constrained_inverse(F, _padded(gauge.constraints(config.groups, [s1, s2], 3), len(F)))


def _direct_covariance(moments, A_ls, noise, config, gauge):
    """First-order propagation of Cov(vec A) through the decomposition and gauge (numerical Jacobian)."""
    W_inv = np.linalg.inv(residual_weight(A_ls, noise))
    cov_A = np.kron(W_inv, np.linalg.inv(moments.S22))  # row-major vec(A)

    def params(A):
        R, s1, s2 = decompose(A, config)
        s1, s2 = gauge.apply(config.groups, [s1, s2])
        return R, np.log(s1), np.log(s2)

    R0, l10, l20 = params(A_ls)
    J = np.zeros((9, 9))
    h = 1e-7
    for k in range(9):
        dA = np.zeros(9)
        dA[k] = h
        R, l1, l2 = params(A_ls + dA.reshape(3, 3))
        J[:3, k] = log(R @ R0.T) / h
        J[3:6, k] = (l1 - l10) / h
        J[6:, k] = (l2 - l20) / h
    return J @ cov_A @ J.T


def pair_covariance(P9, R, s1, s2, A, moments, Sigma_r):
    """:func:`parameter_covariance` of the paper's model, from the covariance of ``[dtheta, log s_1, log s_2]``."""
    J = np.diag(np.concatenate([np.ones(3), s1, s2]))
    return parameter_covariance(P9, J, dA_dp(R, s1, s2), moments, Sigma_r)


def parameter_covariance(P, J, D, moments, Sigma_r):
    """12x12 covariance of ``[dtheta, scale_1, scale_2, bias]`` from the covariance ``P`` of the model's parameters
    (``J`` (9, p): the derivatives of ``[dtheta, scale_1, scale_2]`` w.r.t. them; ``D`` (p, 3, 3): those of A) and
    the covariance ``Sigma_r`` of the mean residual (the bias estimate's own noise)."""
    G = np.einsum("pij,j->ip", D, moments.mean_2)  # d(A m_2)/dp, so db = -G dp
    cov = np.zeros((12, 12))
    cov[:9, :9] = J @ P @ J.T
    cov[BIAS, BIAS] = Sigma_r + G @ P @ G.T
    cov[BIAS, :9] = -G @ P @ J.T
    cov[:9, BIAS] = cov[BIAS, :9].T
    return cov
