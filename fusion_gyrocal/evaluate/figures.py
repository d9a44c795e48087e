"""The paper's figures from the comparison: RMSE versus SNR with the bound, residual versus rate norm.

:func:`plot_rmse_vs_snr` draws :class:`~fusion_gyrocal.evaluate.tables.SnrSweep` results on log-log
axes beside the Cramer-Rao bound (the paper's Fig. rmse_rotation / rmse_scale);
:func:`plot_residual_vs_rate` draws the residual norm against the rate norm (Fig. residual_gyro).
Each estimator's colour and marker are those of its :class:`~fusion_gyrocal.evaluate.registry.Estimator`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.moments import Moments
from ..core.observability import A_of
from ..errors import InputError
from .registry import REGISTRY, Estimator, run_estimator
from .scenarios import Scenario
from .tables import SnrSweep

__all__ = ["plot_rmse_vs_snr", "plot_residual_vs_rate"]

_LINESTYLES = ("-", "--", ":", "-.")


def _style(name: str):
    """The registry entry of ``name`` (its colour and marker); an unknown name draws in matplotlib's defaults."""
    return REGISTRY.get(name) or Estimator(name, "", None)


def _save(fig, path):
    """Write ``fig`` to ``path`` (folder created) atomically, when a path is given; returns ``fig``."""
    if path is not None:
        from ..errors import FormatError
        from ..io.report import write_figure
        from ..io.writers import os_reason

        folder = Path(path).expanduser().parent
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise FormatError(f"{path}: cannot create the folder {folder}: {os_reason(exc)}") from exc
        write_figure(fig, path, dpi=130, bbox_inches="tight")
    return fig


def plot_rmse_vs_snr(sweeps, path=None, *, metrics=("rotation", "scale"), estimators=None, title=None):
    """The paper's RMSE versus SNR on log-log axes (Fig. rmse_rotation / rmse_scale), with the bound.

    Parameters
    ----------
    sweeps : SnrSweep or sequence of SnrSweep
        One line style per sweep (e.g. nominal and weak axis, or rate / noise / samples), one colour
        per estimator; the Cramer-Rao bound of each sweep in black. The legend gives the fitted
        log-log slopes (one per sweep, in line-style order).
    path : str or Path, optional
        Write the figure there (PNG, SVG, PDF from the suffix).
    metrics : sequence of {"rotation", "scale"}
        One panel each: rotation RMSE in mdeg, scale RMSE in %.
    estimators : sequence of str, optional
        Subset of the sweeps' estimators to draw.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..extras import require

    matplotlib = require("matplotlib", "plots", "the comparison figures")
    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    sweeps = [sweeps] if isinstance(sweeps, SnrSweep) else list(sweeps)
    many = len(sweeps) > 1
    outside = many and len(metrics) == 1  # legend right of a single panel; inside (lower left) otherwise
    fig, axes = plt.subplots(1, len(metrics), figsize=((6.2 + 2.8 * outside) * len(metrics), 5.0), squeeze=False)
    unit = {"rotation": (np.rad2deg(1.0) * 1e3, "rotation RMSE [mdeg]  (Eq. 37)"),
            "scale": (100.0, "scale-factor RMSE [%]  (Eq. 38)")}
    names = sweeps[0].estimators if estimators is None else tuple(estimators)
    for ax, metric in zip(axes[0], metrics):
        k, ylabel = unit[metric]
        slopes = [{s.estimator: getattr(s, metric) for s in sw.slopes()} for sw in sweeps]
        for name in names:
            drawn = []
            for j, sw in enumerate(sweeps):
                y = sw.rmse(name, metric) if name in sw.estimators else np.full(len(sw.factors), np.nan)
                if np.isfinite(y).any():
                    ax.plot(sw.snr, y * k, _LINESTYLES[j % len(_LINESTYLES)], color=_style(name).colour,
                            marker=_style(name).marker, ms=6, mfc="none",
                            label="_" if drawn else name)
                    drawn.append(f"{slopes[j][name]:.2f}")
            if drawn:  # one legend entry per estimator, with its slope in every sweep
                ax.get_lines()[-len(drawn)].set_label(f"{name}: slope {' / '.join(drawn)}")
        bound_slopes = []
        skew = False
        for j, sw in enumerate(sweeps):
            b = sw.bound(metric)
            bound_slopes.append(f"{np.polyfit(np.log(sw.snr), np.log(b), 1)[0]:.2f}")
            skew |= metric == "rotation" and any(r.bound.rotation_skew > 0 for c in sw.comparisons for r in c.records)
            ax.plot(sw.snr, b * k, _LINESTYLES[j % len(_LINESTYLES)], color="black", lw=2.2, alpha=0.6,
                    label="_" if j else "")
        what = "Cramer-Rao bound" + (" (+ Appendix D skew error)" if skew else "")
        ax.get_lines()[-len(sweeps)].set_label(f"{what}: slope {' / '.join(bound_slopes)}")
        if many:  # line styles: one proxy entry per sweep
            for j, sw in enumerate(sweeps):
                ax.plot([], [], _LINESTYLES[j % len(_LINESTYLES)], color="gray",
                        label=f"{_LINESTYLES[j % len(_LINESTYLES)]}  {sw.scenario}, SNR via {sw.via}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        plain = FuncFormatter(lambda v, _: f"{v:g}")
        minor = FuncFormatter(lambda v, _: f"{v:g}" if f"{v:.1e}"[0] in "25" else "")  # label 2x and 5x
        ax.yaxis.set_major_formatter(plain)
        ax.yaxis.set_minor_formatter(minor)
        ax.xaxis.set_major_formatter(plain)
        ax.xaxis.set_minor_formatter(minor)
        ax.set_xlabel("SNR  (Eq. 36)")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
        if many:
            where = dict(loc="upper left", bbox_to_anchor=(1.01, 1.0)) if outside else dict(loc="lower left")
            ax.legend(fontsize=7.5 if outside else 7, title="slopes: " + " / ".join(
                _LINESTYLES[j % len(_LINESTYLES)] for j in range(len(sweeps))), title_fontsize=7.5, **where)
        else:
            ax.legend(fontsize=8, loc="best")
    runs = len(sweeps[0].comparisons[0].records)
    fig.suptitle(title or f"RMSE versus SNR, {runs} Monte Carlo runs per point", fontsize=11)
    fig.tight_layout()
    return _save(fig, path)


def plot_residual_vs_rate(scenarios, path=None, *, estimator: str = "direct", max_points: int = 4000, rng=0):
    """Residual norm versus rate norm (the paper's Fig. residual_gyro), one panel per scenario.

    The residual is Eq. (residual), ``r(k) = w1(k) - A_hat w2(k)`` of the centred rates with the
    estimator's ``A_hat = S1 C S2^-1`` from all the data; rigid pairs give residuals that look like
    noise at every rate, a flexing pair residuals that grow with the rate norm. A binned median is
    drawn over the scatter (at most ``max_points`` points per panel).
    """
    from ..extras import require

    matplotlib = require("matplotlib", "plots", "the comparison figures")
    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    scenarios = [scenarios] if isinstance(scenarios, Scenario) else list(scenarios)
    fig, axes = plt.subplots(1, len(scenarios), figsize=(5.2 * len(scenarios), 4.2), squeeze=False, sharey=True)
    gen = np.random.default_rng(rng)
    for ax, sc in zip(axes[0], scenarios):
        est = run_estimator(estimator, sc.omega_1, sc.omega_2)
        if not est.ok:
            raise InputError(f"{estimator} failed on {sc.name}: {est.error}")
        A = A_of(est.R_1_2, est.scale_1, est.scale_2) if est.has_scales else est.R_1_2
        m = Moments.from_samples(sc.omega_1, sc.omega_2)
        r = (sc.omega_1 - m.mean_1) - (sc.omega_2 - m.mean_2) @ A.T
        rn = np.rad2deg(np.linalg.norm(r, axis=1))
        wn = np.rad2deg(np.linalg.norm(sc.omega_1, axis=1))
        pick = gen.choice(rn.size, size=min(max_points, rn.size), replace=False)
        flexed = sc.flex_angle is not None
        colour = np.where(sc.flex_angle[pick] > 0, "tab:red", "tab:blue") if flexed else "tab:blue"
        ax.scatter(wn[pick], rn[pick], s=3, c=colour, alpha=0.4, linewidths=0)
        edges = np.quantile(wn, np.linspace(0, 1, 21))
        idx = np.clip(np.searchsorted(edges, wn, side="right") - 1, 0, 19)
        med = [np.median(rn[idx == i]) if np.any(idx == i) else np.nan for i in range(20)]
        ax.plot(0.5 * (edges[1:] + edges[:-1]), med, "k-", lw=2, label="binned median")
        sig = np.rad2deg(np.sqrt(3 * (sc.noise_std[0] ** 2 + sc.noise_std[1] ** 2)))
        ax.axhline(sig, color="gray", ls="--", label="noise level sqrt(3 (s1^2+s2^2))")
        ax.set_yscale("log")
        ax.set_xlabel("rate norm ||omega_1|| [deg/s]")
        ax.set_title(f"{sc.name}" + (" (red: mounting bent)" if flexed else " (rigid)"), fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    axes[0][0].set_ylabel(f"residual norm ||r(k)|| [deg/s]  ({estimator})")
    fig.tight_layout()
    return _save(fig, path)
