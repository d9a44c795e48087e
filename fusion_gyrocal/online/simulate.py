"""Simulation of a gyro pair whose calibration drifts (per-sample truth for the tracker's tests and benchmarks)."""

from __future__ import annotations

import numpy as np

from ..core.moments import as_rates
from .history import PairTruth

__all__ = ["simulate_drifting_pair"]


def simulate_drifting_pair(t, R_1_2, scale_1, scale_2, *, bias_1=None, bias_2=None, noise_std=0.1 * np.pi / 180,
                           omega_true_1=None, rms=1.0, rng=None) -> tuple[np.ndarray, np.ndarray, PairTruth]:
    """Simulate a pair whose calibration changes over time (the paper's Eq. 1 per sample).

    Parameters
    ----------
    t : array_like (N,)
        Sample times (s).
    R_1_2 : array_like (3, 3) or (N, 3, 3)
        True rotation per sample.
    scale_1, scale_2 : array_like (3,) or (N, 3)
        True scale factors per sample.
    bias_1, bias_2 : array_like (3,) or (N, 3), optional
        True biases per sample (rad/s); default zero.
    noise_std : float or (float, float)
        White noise per sample (rad/s).
    omega_true_1 : array_like (N, 3), optional
        True rate in gyro 1's frame (rad/s), e.g. recorded motion from
        :func:`fusion_gyrocal.evaluate.sim.load_broad_rates`. Default: :class:`fusion_gyrocal.evaluate.sim.HumanMotion`.
    rms : float
        RMS rate of the default human-like motion (rad/s per axis).
    rng : numpy.random.Generator or int, optional

    Returns
    -------
    omega_1, omega_2 : ndarray (N, 3)
    truth : PairTruth
    """
    from ..evaluate.sim import HumanMotion

    rng = np.random.default_rng(rng)
    t = np.asarray(t, dtype=float)
    n = t.shape[0]
    R = np.broadcast_to(np.asarray(R_1_2, float), (n, 3, 3))
    s1 = np.broadcast_to(np.asarray(scale_1, float), (n, 3))
    s2 = np.broadcast_to(np.asarray(scale_2, float), (n, 3))
    b1 = np.broadcast_to(np.zeros(3) if bias_1 is None else np.asarray(bias_1, float), (n, 3))
    b2 = np.broadcast_to(np.zeros(3) if bias_2 is None else np.asarray(bias_2, float), (n, 3))
    sig = np.broadcast_to(np.asarray(noise_std, float), (2,))
    if omega_true_1 is None:
        w_true_1 = HumanMotion(rms, rng=rng)(t)
    else:
        w_true_1 = as_rates("omega_true_1", omega_true_1, length=n).astype(float)
    w_true_2 = np.einsum("kji,kj->ki", R, w_true_1)          # R^T omega_1
    w1 = s1 * w_true_1 + b1 + rng.normal(0, sig[0], (n, 3))
    w2 = s2 * w_true_2 + b2 + rng.normal(0, sig[1], (n, 3))
    A = (s1[:, :, None] * R) / s2[:, None, :]
    bias = b1 - np.einsum("kij,kj->ki", A, b2)
    return w1, w2, PairTruth(R, s1, s2, bias)
