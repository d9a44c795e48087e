"""Per-sample weights against a heavy-tailed residual: impacts, transients faster than the read-out, spikes.

Real MEMS residuals are heavy-tailed (on the MIMU board the largest 1 % of samples carry more than half of the
residual's energy after the sensor and timing models): a few samples of large variance dominate the moments' cost
(Eq. 12-17) and move the estimate. :func:`tail_share` tells such a residual from Gaussian noise, and
:func:`residual_weights` weighs each sample by the white noise's variance over its residual's local variance, the
likelihood of heteroscedastic samples; the moments take the weights as they are
(:meth:`~fusion_gyrocal.core.moments.Moments.from_samples`, ``weights=``). The pair pipeline
(:mod:`~fusion_gyrocal.pipeline.pipeline`) and :func:`~fusion_gyrocal.core.array.calibrate_array` use them under
``robust_weights``; with the weights off, :func:`hint` is the note of a residual heavy-tailed enough for them.
"""

from __future__ import annotations

import numpy as np

from .moments import row_sumsq, rows_times


#: Samples (centred on each) over which the local residual variance of :func:`residual_weights` is averaged.
WEIGHT_SPAN = 5


def residual_weights(w1, w2, A, bias, noise_std, mask=None, span: int = WEIGHT_SPAN) -> np.ndarray:
    """A weight per sample: the white noise's variance over the residual's local variance, at most 1.

    The residual ``r_k = omega_1(k) - A omega_2(k) - b`` of sample ``k`` has the local variance ``v_k``, the mean
    of ``|r_j|^2 / 3`` over the used samples ``j`` among the ``span`` centred on ``k``, floored at the white
    noise's variance per axis ``v_0 = tr(sigma_1^2 I + sigma_2^2 A A^T) / 3`` (``noise_std``: the identified
    noise). ``w_k = v_0 / max(v_k, v_0)``: samples where the residual is the noise keep weight 1; an impact,
    a transient faster than the read-out, a spike after clipping (the heavy tail of real MEMS residuals) weigh
    as little as their variance is large. With them the moments' cost (Eq. 12-17) is the likelihood of
    heteroscedastic samples. 0 where ``mask`` is False or a rate is not finite.
    """
    s1, s2 = (float(v) for v in np.broadcast_to(np.asarray(noise_std, float), (2,)))
    v0 = (3.0 * s1 ** 2 + s2 ** 2 * float(np.trace(A @ A.T))) / 3.0
    rr, ok = _residual_energy(w1, w2, A, bias, mask)
    kernel = np.ones(int(span))
    total = np.convolve(np.where(ok, rr, 0.0), kernel, "same")
    n = np.convolve(ok.astype(float), kernel, "same")
    local = total / np.maximum(n, 1.0)
    return np.where(ok, v0 / np.maximum(local, v0), 0.0)


_ENERGY_ROWS = 65536     # rows per block of _residual_energy: no (N, 3) temporary for a long log
TAIL_SAMPLES = 200_000  # at most this many samples (evenly strided) decide whether the residual is heavy-tailed
HINT_SAMPLES = 20_000   # ... whether it is worth a note (:func:`hint`: weights off; 15 ms at 5e6 samples with 200k)


def _residual_energy(w1, w2, A, bias, mask=None, stride: int = 1):
    """``(|r_k|^2 / 3, ok)``: the residual energy per axis of every ``stride``-th sample and where it is used
    and finite, a block of rows at a time."""
    n = len(w1)
    rr = np.empty(-(-n // stride))
    block = _ENERGY_ROWS * stride
    with np.errstate(invalid="ignore", over="ignore"):
        for a in range(0, n, block):
            r = np.asarray(w1[a:a + block:stride], float) - rows_times(w2[a:a + block:stride], A.T) - bias
            rr[a // stride:a // stride + len(r)] = row_sumsq(r) / 3.0
    ok = np.isfinite(rr)
    if mask is not None:
        ok &= np.asarray(mask, bool)[::stride]
    return rr, ok


#: Share of the residual's energy in its largest 1 % of samples above which the residual is heavy-tailed: about
#: 4.5 % for Gaussian noise (the top 1 % of a chi-square with 3 dof, divided by 3), 54-57 % on the MIMU board
#: (pair 1-2).
TAIL_SHARE = 0.10


def tail_share(rr: np.ndarray) -> float:
    """Share of the total of ``rr`` (residual energies) carried by its largest 1 % of values."""
    n = rr.size
    k = max(1, n // 100)
    total = float(rr.sum())
    return float(np.partition(rr, n - k)[n - k:].sum()) / total if total > 0 else 0.0


def tail_samples(robust_weights: str) -> int:
    """Samples the heavy-tail check reads under ``robust_weights``: :data:`TAIL_SAMPLES` where the weights may be
    taken, :data:`HINT_SAMPLES` where the check only decides a note (:func:`hint`)."""
    return TAIL_SAMPLES if robust_weights == "auto" else HINT_SAMPLES


def residual_tail_share(w1, w2, A, bias, mask=None, samples: int = TAIL_SAMPLES) -> float:
    """:func:`tail_share` of the pair's residual energies ``|omega_1 - A omega_2 - b|^2`` over the used samples (at
    most ``samples``, evenly strided); 0 when none is used."""
    rr, ok = _residual_energy(w1, w2, A, bias, mask, max(1, len(w1) // samples))
    return tail_share(rr[ok]) if ok.any() else 0.0


def hint(share: float) -> str:
    """The note of a calibration whose residual is heavy-tailed (``share``: :func:`tail_share`, at least
    :data:`TAIL_SHARE`) while ``robust_weights`` is off: what the weights would do, and what they did on a real
    board."""
    return (f"the residual is heavy-tailed: its largest 1% of samples carry {100 * share:.0f}% of its energy (4.5% "
            "for Gaussian noise; impacts, transients faster than the read-out, spikes near full scale). "
            "robust_weights='auto' (--robust-weights auto) weighs each sample by its residual's local variance: on "
            "the MIMU board the weighted rotations repeat to 8.9 mdeg RMS against 21.0 over the sessions where the "
            "board stayed put, and their narrower covariance shows when it did not (compare_sessions)")
