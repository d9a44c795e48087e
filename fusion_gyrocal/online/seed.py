"""Seeding the tracker: the batch solve of a window and the filter started from a calibration.

A tracker starts (and re-starts, on a confirmed step) from a :class:`~fusion_gyrocal.core.model.PairCalibration`:
its estimate and covariance become the :class:`~.ekf.ErrorStateEKF`'s nominal state and error covariance in the
scale hold (:class:`~.hold.ScaleHold`). :func:`batch` solves a window (the seed, a re-seed window) with
:func:`fusion_gyrocal.calibrate_pair`; :func:`seed_from_samples` is the seed of
:meth:`~.tracker.GyroPairTracker.from_samples` (the noise identified on the window).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.model import S1, S2, PairCalibration
from ..core.moments import as_rates, noise_pair
from ..core.observability import seed_configuration
from ..errors import InputError
from ..pipeline.streams import check_timestamps
from .ekf import ErrorStateEKF, inflation, misfit_coefficients
from .hold import DIM, ScaleHold


def batch(w1, w2, noise_std, gauge, misfit=None, linear_map: str = "rigid") -> PairCalibration:
    """Batch calibration of a window (:func:`fusion_gyrocal.calibrate_pair`, which applies the paper's
    flex rejection, Section VI.C, when the residuals call for it).

    With a rate-dependent misfit (``misfit``: :func:`~.ekf.misfit_coefficients`, None for white noise) the
    white ``noise_std`` is raised to the window's effective level (:func:`effective_noise`), so that the
    batch covariance says what the window's fast samples are worth.
    """
    from ..pipeline.pipeline import calibrate_pair

    if misfit is not None and noise_std is not None:
        noise_std = effective_noise(noise_std, w1, inflation(misfit, w1))
    return calibrate_pair(w1, w2, noise_std=noise_std, gauge=gauge, linear_map=linear_map)


def effective_noise(noise_std, w1, g) -> tuple[float, float]:
    """White per-sample noise ``noise_std`` scaled to the level of equal weights that carries the same
    information as the samples' covariances ``g_k R``: the rate-weighted harmonic mean
    ``sigma_eff^2 = sigma^2 sum |omega_k|^2 / sum (|omega_k|^2 / g_k)`` (the rotation's information is
    ``sum omega omega^T / (g_k sigma^2)``; Eq. 12-17 weigh every sample alike)."""
    if g is None:
        return noise_std
    sq = np.einsum("ka,ka->k", w1, w1)
    k = float(np.sqrt(sq.sum() / max(float((sq / g).sum()), 1e-300))) if sq.sum() > 0 else 1.0
    n = np.broadcast_to(np.asarray(noise_std, dtype=float), (2,))
    return float(n[0] * k), float(n[1] * k)


def misfit_gain(noise_model) -> tuple[float, float]:
    """``(a, b)`` of a :class:`~fusion_gyrocal.core.noise.NoiseModel`'s misfit when it flags one (its residual is
    not white noise), else ``(0, 0)``: an insignificant fit is noise of the fit, not a model."""
    if noise_model is None or noise_model.is_white or not noise_model.is_misfit:
        return 0.0, 0.0
    a, b = noise_model.misfit_gain
    return float(a), float(b)


def model_error(cal: PairCalibration) -> float:
    """Variance factor of the model error a re-seed batch covariance is raised by: the seed's
    ``robust_inflation`` (block-robust over model covariance in its worst direction,
    :mod:`fusion_gyrocal.core.robust`), 1 when it has none. A re-seed window is too short for a sandwich
    of its own (:data:`fusion_gyrocal.core.solve.MIN_ROBUST_WINDOWS`); the pair's misfit is the same."""
    k = float(cal.robust_inflation)
    return k if np.isfinite(k) and k > 1.0 else 1.0


def log_covariance(cal: PairCalibration, prior_std: float) -> np.ndarray:
    """``cal``'s covariance in ``[dtheta, log s1, log s2, b]``; undetermined scale factors get the prior."""
    cov = np.array(cal.covariance, dtype=float)
    bad = ~np.isfinite(cov).all(axis=1)
    cov[bad, :], cov[:, bad] = 0.0, 0.0
    J = np.ones(DIM)
    J[S1], J[S2] = 1.0 / np.asarray(cal.scale_1), 1.0 / np.asarray(cal.scale_2)
    P = cov * np.outer(J, J)
    P[bad, bad] = prior_std**2
    return P


def seed_noise(calibration: PairCalibration, noise_model):
    """``(noise_model, noise_std, misfit)`` of a tracker seeded by ``calibration`` with ``noise_model`` (a
    :class:`~fusion_gyrocal.core.noise.NoiseModel`, None, or ``"seed"``: the calibration's own): the model, the white
    noise per sample of each gyro (the model's when it flags a misfit, else the calibration's) and the misfit's
    gains (:func:`misfit_gain`)."""
    from ..core.noise import NoiseModel

    if isinstance(noise_model, str) and noise_model == "seed":
        noise_model = calibration.noise_model if isinstance(calibration.noise_model, NoiseModel) else None
    if noise_model is not None and not isinstance(noise_model, NoiseModel):
        raise InputError(f"noise_model: expected a NoiseModel (fusion_gyrocal.core.noise.identify_noise), None "
                         f"or 'seed', got {noise_model!r}")
    misfit = misfit_gain(noise_model)
    noise = np.asarray(calibration.noise_std if misfit == (0.0, 0.0) else noise_model.noise_std, dtype=float)
    what = "calibration.noise_std" if misfit == (0.0, 0.0) else "noise_model.noise_std"
    if not (np.isfinite(noise).all() and (noise > 0).all()):
        raise InputError(f"{what}: expected two positive rad/s values, got {noise}")
    return noise_model, (float(noise[0]), float(noise[1])), misfit


def seed_filter(cal: PairCalibration, t: float, config, noise_std, misfit, *, span_s: float = 0.0,
                previous: ScaleHold | None = None):
    """``(configuration, filter)``: the seed's :class:`~fusion_gyrocal.core.observability.Configuration` and the
    :class:`~.ekf.ErrorStateEKF` started from ``cal`` at time ``t`` (construction, re-seed), its covariance grown
    by the drift over a third of ``span_s`` (the seed estimates the average over its window); ``previous``: the
    hold before a re-seed (groups held before keep their held value)."""
    configuration = seed_configuration(np.asarray(cal.R_1_2, dtype=float), cal.configuration)
    hold = ScaleHold(configuration, config.gauge, config.scale_prior_std, cal.scale_1, cal.scale_2, previous=previous)
    f = ErrorStateEKF(hold, config.drift, config.step_prior, noise_std, cal.R_1_2, cal.scale_1, cal.scale_2, cal.bias,
                      log_covariance(cal, config.scale_prior_std), t, inflate_s=span_s / 3.0, misfit=misfit)
    return configuration, f


def seed_from_samples(t, omega_1, omega_2, noise_std, noise_model, config):
    """``(calibration, noise_model, t, w1, w2)``: the seed of :meth:`~.tracker.GyroPairTracker.from_samples` and its
    checked window.

    The batch solve applies the paper's flex rejection and ``config.gauge``; ``noise_std`` (rad/s per sample, one
    value or one per gyro, None: the residual estimate). The noise is then identified on the window
    (:func:`fusion_gyrocal.core.noise.identify_noise` at the sample rate of ``t``, unless ``noise_model`` is given;
    a window shorter than 16 s leaves it white). When it flags a rate-dependent misfit the seed is solved again with
    the window's effective noise (:func:`effective_noise`), the caller's white level (``noise_std``) replacing the
    model's if given.
    """
    from ..core.noise import identify_noise

    t = check_timestamps("t", t)
    w1 = as_rates("omega_1", omega_1, length=t.shape[0])
    w2 = as_rates("omega_2", omega_2, length=t.shape[0])
    cal = batch(w1, w2, noise_std, config.gauge, linear_map="auto")
    if noise_model is None:
        try:
            noise_model = identify_noise(w1, w2, cal.A, cal.bias, rate_hz=1.0 / float(np.median(np.diff(t))))
        except InputError:           # too short a window for the noise identification: white noise
            noise_model = None
    misfit = misfit_gain(noise_model)
    if misfit != (0.0, 0.0):
        if noise_std is not None:    # the caller's white level, the model's misfit
            noise_model = dataclasses.replace(noise_model, noise_std=noise_pair(noise_std))
        cal = batch(w1, w2, noise_model.noise_std, config.gauge,
                    misfit=misfit_coefficients(noise_model.noise_std, cal.A, misfit), linear_map="auto")
    return cal, noise_model, t, np.asarray(w1, dtype=float), np.asarray(w2, dtype=float)
