"""Reproduce the paper's simulation figures (Section V) for every estimator, with the Cramer-Rao bound.

Monte Carlo sweeps of :mod:`fusion_gyrocal.evaluate.scenarios` over the paper's SNR factors 0.5 / 1 / 2 / 4:

1. ``nominal``, SNR through the rate norm (the paper's Fig. rmse_rotation / rmse_scale);
2. ``nominal``, SNR through the noise and through the sample count (the paper: "by appropriately
   scaling the velocities' norms, noise sigma, or data sample size");
3. ``weak_axis`` (x rates 10x smaller at the same SNR; Fig. rmse_rotation_weak_axis);
4. ``skew`` (skew 2.357e-4; the rotation error levels off at Appendix D's prediction);

and one realisation of ``nominal`` and ``flex`` for the residual-versus-rate-norm figure
(Fig. residual_gyro). For every sweep it prints, per estimator and SNR point, the RMSE (Eq. 37-38),
its ratio to the bound and the fitted log-log slope of RMSE versus SNR (the paper finds -1), and it
writes the figures to ``docs/figures/``:

    python benchmarks/paper_figures.py                # 100 runs per point, all cores
    python benchmarks/paper_figures.py --runs 20      # quicker look

Every SNR point draws its own, independent realisations (``snr_sweep(..., paired=False)``), so the
fitted slopes are a real test, not a consequence of scaling one noise draw (``--paired`` reuses the
realisations across points for smoother curves). The EKF runs on the rate-norm and weak-axis sweeps
only (its solve is 10x slower than the batch solvers', seconds on 96 000 samples), so the whole run
stays within 15 min on 2 cores (measured: 2 min idle, 7 min on a shared machine).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from fusion_gyrocal.evaluate.compare import snr_sweep
from fusion_gyrocal.evaluate.figures import plot_residual_vs_rate, plot_rmse_vs_snr
from fusion_gyrocal.evaluate.registry import DEFAULT_ESTIMATORS, estimator_available
from fusion_gyrocal.evaluate.scenarios import SNR_FACTORS, make_scenario

FIGURES = Path(__file__).resolve().parents[1] / "docs" / "figures"
PAPER = ("direct", "default", "appendix_c")   # the estimators the paper's finding is about
SLOPE_TOL = 0.1


def _summary(sw, t_s: float) -> None:
    print(f"\n=== {sw.scenario}, SNR through the {sw.via}: {len(sw.comparisons[0].records)} runs per point, "
          f"{t_s:.0f} s ===")
    snr = sw.snr
    print("SNR:" + "".join(f"{s:>12.4g}" for s in snr))
    for metric, unit, k in (("rotation", "mdeg", np.rad2deg(1.0) * 1e3), ("scale", "%", 100.0)):
        b = sw.bound(metric)
        print(f"  {metric} RMSE [{unit}] (ratio to the bound)")
        print(f"    {'Cramer-Rao bound':>20}" + "".join(f"{v * k:>12.4g}" for v in b))
        for name in sw.estimators:
            r = sw.rmse(name, metric)
            if not np.isfinite(r).any():
                continue
            print(f"    {name:>20}" + "".join(f"{v * k:>12.4g}" for v in r)
                  + "   (" + " ".join(f"{q:.2f}" for q in r / b) + ")")
    i1 = int(np.argmin(np.abs(np.array(sw.factors) - 1.0)))
    print("  log-log slope of RMSE versus SNR (paper: -1), median ms per solve at SNR x"
          f"{sw.factors[i1]:g}:")
    br, bs = sw.bound_slopes()
    print(f"    {'Cramer-Rao bound':>20}  rotation {br:+.3f}  scales {bs:+.3f}")
    for s in sw.slopes():
        row = sw.comparisons[i1].row(s.estimator)
        fails = sum(c.row(s.estimator).failures for c in sw.comparisons)
        verdict = ""
        if s.estimator in PAPER and sw.scenario == "nominal":
            ok = abs(s.rotation + 1) <= SLOPE_TOL and abs(s.scale + 1) <= SLOPE_TOL
            verdict = f"  slope -1 +- {SLOPE_TOL}: {'yes' if ok else 'NO'}"
        sc = f"{s.scale:+.3f}" if np.isfinite(s.scale) else "   -  "
        note = f"  failed {fails}x: {row.note}" if fails else ""
        print(f"    {s.estimator:>20}  rotation {s.rotation:+.3f}  scales {sc}  {row.seconds * 1e3:8.2f} ms"
              f"{verdict}{note}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=100, help="Monte Carlo runs per SNR point")
    ap.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=FIGURES, help="figure directory")
    ap.add_argument("--paired", action="store_true", help="same realisations at every SNR point")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)

    missing = {n: why for n in DEFAULT_ESTIMATORS if (why := estimator_available(n))}
    for n, why in missing.items():
        print(f"{n}: {why}")
    everyone = tuple(n for n in DEFAULT_ESTIMATORS if n not in missing)
    no_ekf = tuple(n for n in everyone if n != "ekf")
    plan = [("nominal", "rate", everyone), ("nominal", "noise", no_ekf), ("nominal", "samples", no_ekf),
            ("weak_axis", "rate", everyone), ("skew", "rate", PAPER)]
    t_all = time.perf_counter()
    sweeps = {}
    for scenario, via, names in plan:
        t0 = time.perf_counter()
        sw = snr_sweep(scenario, factors=SNR_FACTORS, via=via, runs=args.runs, estimators=names, seed=args.seed,
                       workers=args.workers, progress=not args.no_progress, paired=args.paired)
        sweeps[(scenario, via)] = sw
        _summary(sw, time.perf_counter() - t0)

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    nominal = sweeps[("nominal", "rate")]
    plot_rmse_vs_snr(nominal, out / "rmse_vs_snr.png",
                     title=f"RMSE versus SNR (SNR through the rate norm), {args.runs} runs per point")
    plot_rmse_vs_snr([sweeps[("nominal", "noise")], sweeps[("nominal", "samples")]],
                     out / "rmse_vs_snr_noise_samples.png", estimators=PAPER,
                     title="RMSE versus SNR with the SNR scaled through the noise (solid) "
                           f"and the sample count (dashed), {args.runs} runs per point")
    plot_rmse_vs_snr([nominal, sweeps[("weak_axis", "rate")]], out / "weak_axis.png", metrics=("rotation",),
                     estimators=tuple(n for n in everyone if n != "rotation_only"),
                     title="Rotation RMSE: nominal motion (solid) and x rates 10x smaller at the same SNR (dashed)")
    plot_rmse_vs_snr([nominal, sweeps[("skew", "rate")]], out / "skew.png", metrics=("rotation",), estimators=PAPER,
                     title="Rotation RMSE without (solid) and with (dashed) skew 2.357e-4")
    plot_residual_vs_rate([make_scenario("nominal", rng=[args.seed, 0]), make_scenario("flex", rng=[args.seed, 0])],
                          out / "residual_vs_rate_norm.png")
    print(f"\nfigures written to {out}: rmse_vs_snr.png, rmse_vs_snr_noise_samples.png, weak_axis.png, skew.png, "
          f"residual_vs_rate_norm.png")
    print(f"total {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    main()
