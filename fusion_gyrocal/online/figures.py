"""Figures of the online tracker: the history with its 1-sigma bands, and the report's tracking figure."""

from __future__ import annotations

import textwrap

import numpy as np

from ..core.moments import finite_rows
from ..errors import InputError
from ..lie import log
from .config import DriftNoise
from .history import TrackHistory

__all__ = ["plot_history", "track_figure_for_report"]


def plot_history(history: TrackHistory, *, title: str | None = None):
    """Figure of the tracked rotation change, scale factors and bias with 1-sigma bands.

    Rows: rotation of ``R_1_2`` relative to the first estimate (deg, gyro 1's axes), scale
    factors of both gyros (deviation from 1 in %), combined bias (deg/s). Re-seeds are marked
    with vertical lines (solid: accepted, dotted: rejected); the truth is dashed when present.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..extras import require

    Figure = require("matplotlib.figure", "plots", "the tracker's figures").Figure

    deg = 180.0 / np.pi
    fig = Figure(figsize=(9, 8), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    t = history.t
    colors = ("tab:red", "tab:green", "tab:blue")
    if len(history):
        rot = history.rotation_change * deg
        for i in range(3):
            c = colors[i]
            axes[0].plot(t, rot[:, i], color=c, label="xyz"[i])
            axes[0].fill_between(t, rot[:, i] - history.rotation_std[:, i] * deg,
                                 rot[:, i] + history.rotation_std[:, i] * deg, color=c, alpha=0.2)
            for gy, (s, sd, ls) in enumerate(((history.scale_1, history.scale_1_std, "-"),
                                              (history.scale_2, history.scale_2_std, "--"))):
                v = (s[:, i] - 1.0) * 100
                axes[1].plot(t, v, color=c, ls=ls, label=f"scale_{gy + 1}[{'xyz'[i]}]")
                axes[1].fill_between(t, v - sd[:, i] * 100, v + sd[:, i] * 100, color=c, alpha=0.15)
            b = history.bias[:, i] * deg
            axes[2].plot(t, b, color=c, label="xyz"[i])
            axes[2].fill_between(t, b - history.bias_std[:, i] * deg, b + history.bias_std[:, i] * deg,
                                 color=c, alpha=0.2)
        if history.truth_R_1_2 is not None:
            ok = np.isfinite(history.truth_R_1_2).all(axis=(1, 2))
            rt = np.full((len(history), 3), np.nan)
            rt[ok] = log(history.truth_R_1_2[ok] @ history.R_1_2[0].T) * deg
            for i in range(3):
                axes[0].plot(t, rt[:, i], color=colors[i], ls=":", lw=1)
                axes[1].plot(t, (history.truth_scale_1[:, i] - 1) * 100, color=colors[i], ls=":", lw=1)
                axes[1].plot(t, (history.truth_scale_2[:, i] - 1) * 100, color=colors[i], ls=":", lw=1)
                axes[2].plot(t, history.truth_bias[:, i] * deg, color=colors[i], ls=":", lw=1)
    for ev in history.reseeds:
        for ax in axes:
            ax.axvline(ev.t_detected, color="k", ls="-" if ev.accepted else ":", lw=0.8)
    axes[0].set_ylabel("R_1_2 change [deg]")
    axes[1].set_ylabel("scale - 1 [%]")
    axes[2].set_ylabel("bias [deg/s]")
    axes[2].set_xlabel("time [s]")
    axes[0].legend(loc="upper left", fontsize="small", ncol=3)
    axes[1].legend(loc="upper left", fontsize="x-small", ncol=3)
    fig.suptitle(title or f"EKF drift tracking ({history.mode} mode; gauge: {history.gauge})", fontsize="small")
    return fig


def seed_window(omega_1, omega_2, size: int, *, share: float = 0.8) -> tuple[int, int]:
    """``(start, stop)`` of about ``size`` consecutive samples to seed a tracker on: a well-excited stretch.

    The log is cut into quarter-size pieces (:func:`~fusion_gyrocal.core.moments.window_moments`); each
    run of four consecutive pieces is a candidate, scored by the smallest eigenvalue of gyro 1's centred
    scatter over it (the excitation of its weakest direction, Lemma 1). The earliest candidate scoring at
    least ``share`` of the best is returned, so a log that starts at rest is not seeded on the rest. When
    the log is at least twice ``size`` long, only candidates that leave ``size`` samples after them are
    considered: a log whose most violent motion is at its end (the MIMU sessions) is not seeded there
    with nothing left to track.
    """
    from ..core.moments import Moments, window_moments

    n = len(omega_1)
    size = int(min(max(size, 8), n))
    if size >= n:
        return 0, n
    quarter = max(2, size // 4)
    pieces = window_moments(omega_1, omega_2, quarter, with_starts=True)
    if len(pieces) < 4:
        return 0, size
    last = len(pieces) - 3
    if n >= 2 * size:                       # leave at least a seed's length to track
        last = max(1, min(last, sum(1 for st, _ in pieces if st + 4 * quarter <= n - size)))
    scores = [np.linalg.eigvalsh(Moments.merge_all(m for _, m in pieces[i:i + 4]).S11)[0]
              for i in range(last)]
    best = int(np.flatnonzero(np.asarray(scores) >= share * max(scores))[0])
    start = pieces[best][0]
    return start, min(start + 4 * quarter, n)


def track_figure_for_report(run, *, seed_fraction: float = 0.2, rate_hz: float = 100.0,
                            drift: DriftNoise = DriftNoise(), block_size: int | None = None):
    """Drift-tracking figure for ``gyrocal report --track``: seed on a well-excited stretch, track the rest.

    Parameters
    ----------
    run : fusion_gyrocal.pipeline.pipeline.PipelineRun
        Sample-aligned rates the batch solver used (``run.omega_1``, ``run.omega_2``, ``run.t`` on
        gyro 1's clock, ``run.valid``).
    seed_fraction : float
        Fraction of the samples used to seed the tracker: the earliest well-excited stretch of that
        length (:func:`seed_window`); the tracker runs over the samples after it.
    rate_hz : float
        Sample rate assumed when ``run.t`` is None (sample-aligned input without timestamps).
    drift : DriftNoise
        Random-walk densities of the tracker.
    block_size : int, optional
        Samples per fast-mode block (default: about one second).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from .tracker import GyroPairTracker

    w1, w2 = np.asarray(run.omega_1, float), np.asarray(run.omega_2, float)
    n = w1.shape[0]
    t = np.arange(n) / float(rate_hz) if run.t is None else np.asarray(run.t, float)
    keep = finite_rows(w1) & finite_rows(w2)
    if run.valid is not None:
        keep = keep & np.asarray(run.valid, bool)       # never modify the run's arrays
    t, w1, w2 = t[keep], w1[keep], w2[keep]
    if t.size < 20:
        raise InputError(f"run: expected at least 20 valid samples to track, got {t.size}")
    a, b = seed_window(w1, w2, max(int(seed_fraction * t.size), 10))
    tracker = GyroPairTracker.from_samples(t[a:b], w1[a:b], w2[a:b], noise_std=tuple(run.calibration.noise_std),
                                           drift=drift)
    if block_size is None:
        block_size = max(1, int(round(1.0 / float(np.median(np.diff(t))))))
    h = tracker.run(t[b:], w1[b:], w2[b:], block_size=block_size) if b < t.size else tracker.history()
    where = f"{t[a] - t[0]:.0f}-{t[b - 1] - t[0]:.0f} s"
    title = (f"Drift tracking (EKF, seeded on {100 * seed_fraction:.0f} % of the log at {where}; "
             f"{len(h.reseeds)} step alarm(s); gauge: {h.gauge})")
    return plot_history(h, title=textwrap.fill(title, 130))
