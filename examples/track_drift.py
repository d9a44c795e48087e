"""Track a gyro pair's calibration online while it drifts and then takes a shock.

A simulated pair (human-like motion, the paper's 0.1 deg/s noise) whose gyro 2 y-axis scale
factor drifts by +0.5 % over the run (temperature) and whose mounting rotation jumps by 0.5 deg
half way (a shock). The tracker is seeded with ``calibrate_pair`` on the first 30 s and then
follows the drift in the fast (block) mode; the shock is detected, the covariance opened, and
the filter re-seeded from a batch solve over the window after it.

Run::

    python examples/track_drift.py --out drift.png
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial.transform import Rotation

from fusion_gyrocal.evaluate.sim import simulate_drifting_pair
from fusion_gyrocal.online.tracker import GyroPairTracker, plot_history
from fusion_gyrocal.evaluate.sim import DEG, PAPER_NOISE_STD, general_rotation


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=600.0, help="seconds of data (default 600)")
    p.add_argument("--rate", type=float, default=100.0, help="sample rate in Hz (default 100)")
    p.add_argument("--drift", type=float, default=0.005, help="relative drift of scale_2[y] over the run")
    p.add_argument("--step-deg", type=float, default=0.5, help="rotation step (deg)")
    p.add_argument("--step-at", type=float, default=300.0, help="time of the step (s)")
    p.add_argument("--seed-s", type=float, default=30.0, help="seconds used to seed the tracker")
    p.add_argument("--mode", choices=("fast", "sample"), default="fast")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--out", help="write the tracking figure here (PNG, PDF, ...)")
    args = p.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    t = np.arange(0.0, args.duration, 1.0 / args.rate)
    n = t.size
    R0 = general_rotation(rng, 15.0)                            # keep away from parallel axes (Lemma 4)
    s1, s2 = 1 + rng.normal(0, 0.01, 3), 1 + rng.normal(0, 0.01, 3)
    S2 = np.tile(s2, (n, 1))
    S2[:, 1] *= 1.0 + args.drift * t / t[-1]                   # temperature drift of one scale factor
    axis = rng.normal(size=3)
    R = np.tile(R0, (n, 1, 1))
    R[t >= args.step_at] = Rotation.from_rotvec(axis / np.linalg.norm(axis) * args.step_deg * DEG).as_matrix() @ R0
    w1, w2, truth = simulate_drifting_pair(t, R, s1, S2, bias_1=rng.normal(0, 0.5 * DEG, 3),
                                           bias_2=rng.normal(0, 0.5 * DEG, 3), noise_std=PAPER_NOISE_STD, rng=rng)

    k = int(args.seed_s * args.rate)
    tracker = GyroPairTracker.from_samples(t[:k], w1[:k], w2[:k])         # seeded by calibrate_pair
    h = tracker.run(t[k:], w1[k:], w2[k:], mode=args.mode, block_size=int(args.rate), truth=truth[k:])

    print(f"tracked {h.n_samples} samples in {len(h)} {h.mode}-mode updates; gauge: {h.gauge}")
    print(f"gated samples: {h.n_rejected}")
    for ev in h.reseeds:
        what = "re-seeded" if ev.accepted else "kept the filter"
        print(f"step alarm at t = {ev.t_detected:.2f} s (onset {ev.t_onset:.2f} s): {what} "
              f"(chi-square {ev.statistic:.1f} vs {ev.threshold:.1f})")
    within = 100 * np.mean(np.abs(h.normalised_error) <= 2)
    print(f"estimates within 2 sigma of the truth: {within:.1f} % of all components and updates; "
          f"mean NEES {np.nanmean(h.nees):.2f} ({h.nees_dof} dof)")
    drift_est = h.scale_2[-1, 1] / h.scale_2[0, 1] - 1
    drift_true = h.truth_scale_2[-1, 1] / h.truth_scale_2[0, 1] - 1
    print(f"scale_2[y] drift: estimated {100 * drift_est:+.3f} %, true {100 * drift_true:+.3f} % "
          f"(1-sigma {100 * h.scale_2_std[-1, 1]:.3f} %)")
    if args.out:
        fig = plot_history(h)
        fig.savefig(args.out, dpi=110)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
