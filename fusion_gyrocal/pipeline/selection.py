"""Sample selection (Section III, remark after Eq. 8) and per-axis SNR accumulation (Eq. 36 per axis;
Section VI accumulates to an SNR of 4e3 per axis)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.moments import as_rates, finite_rows, noise_pair, row_norms
from ..errors import OptionError
from .streams import _and_valid, _freeze

PAPER_TARGET_SNR = 4e3         # Section VI: accumulate until this SNR per axis


# ---------------------------------------------------------------------------------------------- selection
def informative_mask(omega_1, omega_2, valid, noise_std, *, min_rate: float | None = None,
                     max_rate: float | None = None) -> np.ndarray:
    """Samples whose rate is well above the noise and below a flex / saturation limit.

    The paper (remark after Eq. 8) recommends samples with a large rate norm (high SNR) but
    not the fastest motion, where the device may flex (Section VI.C). A sample is kept when it
    is valid and the rate norm of BOTH gyros is in ``[min_rate, max_rate]``.

    Parameters
    ----------
    omega_1, omega_2 : array_like, shape (N, 3)
        Sample-aligned rates (rad/s), e.g. from :func:`align_streams`.
    valid : array_like of bool, shape (N,) or None
        Usable samples (None: all finite samples).
    noise_std : float or (float, float)
        White-noise std per sample and axis of each gyro (rad/s).
    min_rate : float, optional
        Smallest rate norm kept (default ``10 * max(noise_std)``). The measured norm contains the
        bias; raise ``min_rate`` above the bias norm when biases are large.
    max_rate : float, optional
        Largest rate norm kept (default: no limit), e.g. below the sensor range or where
        the device starts to flex.

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    w1 = as_rates("omega_1", omega_1)
    w2 = as_rates("omega_2", omega_2, length=w1.shape[0])
    s1, s2 = noise_pair(noise_std)
    lo = 10.0 * max(s1, s2) if min_rate is None else float(min_rate)
    hi = np.inf if max_rate is None else float(max_rate)
    if not (lo >= 0 and hi > lo):
        raise OptionError(f"min_rate/max_rate: expected 0 <= min_rate < max_rate, got {lo!r} and {hi!r}")
    keep = _and_valid(finite_rows(w1) & finite_rows(w2), valid, "valid")
    with np.errstate(invalid="ignore"):
        n1, n2 = row_norms(w1), row_norms(w2)
        keep &= (n1 >= lo) & (n2 >= lo) & (n1 <= hi) & (n2 <= hi)
    return keep


@dataclass(frozen=True)
class ExcitationReport:
    """Per-axis accumulation of the signal-to-noise ratio (Eq. 36 per axis).

    Attributes
    ----------
    snr : ndarray, shape (3,)
        Final per-axis SNR ``sqrt(sum_k (omega_k - mean)^2 - (n - 1) sigma^2) / sigma`` over all used samples.
    cumulative_snr : ndarray, shape (N, 3)
        The same after each sample (running mean; constant across unused samples).
    target_snr : float
        The target per axis (the paper: 4e3).
    reached : ndarray of bool, shape (3,)
        Whether each axis reached the target.
    reached_at : ndarray of int, shape (3,)
        Sample index at which each axis first reached the target (-1: never).
    n_used : int
        Samples used (valid ones).
    """

    snr: np.ndarray
    cumulative_snr: np.ndarray = field(repr=False)
    target_snr: float
    reached: np.ndarray
    reached_at: np.ndarray
    n_used: int

    def __post_init__(self):
        _freeze(self, ("snr", "cumulative_snr", "reached", "reached_at"))

    @property
    def all_reached(self) -> bool:
        return bool(self.reached.all())

    @property
    def samples_needed(self) -> int | None:
        """Index of the sample at which every axis had reached the target (None if some never did)."""
        return int(self.reached_at.max()) if self.all_reached else None


def excitation_report(omega, noise_std: float, *, valid=None, target_snr: float = PAPER_TARGET_SNR) -> ExcitationReport:
    """Accumulate the per-axis SNR of one gyro's rates and find when it reaches a target.

    The paper's SNR (Eq. 36) is ``sqrt(sum_k |omega_k|^2) / sigma`` of the true rate; here it is
    taken per axis over the *centred* signal (the bias is unknown, and only the motion about
    the mean informs A, Eq. 16), with the expected noise contribution removed:
    ``SNR_i(k) = sqrt(max(C_ii(k) - (n(k) - 1) sigma^2, 0)) / sigma`` where ``C(k)`` is the centred
    scatter of the first ``k + 1`` samples (running mean) and ``n(k)`` their count. Section VI
    accumulates samples until every axis reaches 4e3.

    Parameters
    ----------
    omega : array_like, shape (N, 3)
        Rates (rad/s) of one gyro.
    noise_std : float
        White-noise std per sample and axis (rad/s).
    valid : array_like of bool, shape (N,), optional
        Samples to use (non-finite samples are always skipped).
    target_snr : float
        Target per axis.

    Returns
    -------
    ExcitationReport
    """
    w = as_rates("omega", omega)
    sig = float(noise_std)
    if not (np.isfinite(sig) and sig > 0):
        raise OptionError(f"noise_std: expected a positive rad/s per sample, got {noise_std!r}")
    if not (np.isfinite(target_snr) and target_snr > 0):
        raise OptionError(f"target_snr: expected a positive value, got {target_snr!r}")
    keep = _and_valid(finite_rows(w), valid, "valid")
    n = w.shape[0]
    cum = np.zeros((n, 3))
    if keep.any():
        # shifted by the mean: the running sums stay O(spread), not O(bias)
        x = np.where(keep[:, None], w - w[keep].mean(axis=0), 0.0)
        cnt = np.cumsum(keep).astype(float)[:, None]
        s = np.cumsum(x, axis=0)
        q = np.cumsum(x * x, axis=0)
        scat = q - s * s / np.maximum(cnt, 1.0)  # 0 before the first used sample (s = q = 0 there)
        cum = np.sqrt(np.clip(scat - np.maximum(cnt - 1.0, 0.0) * sig**2, 0.0, None)) / sig
    snr = cum[-1].copy() if n else np.zeros(3)
    reached = snr >= target_snr
    at = np.array([int(np.argmax(cum[:, a] >= target_snr)) if reached[a] else -1 for a in range(3)])
    return ExcitationReport(snr, cum, float(target_snr), reached, at, int(keep.sum()))
