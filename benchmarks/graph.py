"""GTSAM graph versus the closed-form batch solver on identical data, and iSAM2 update cost.

1. For N = 1e3 ... 1e6 samples of the paper's protocol (100 Hz, 0.1 deg/s noise): both solvers
   read the same window moments (one constant bias, so the graph merges them into one pair factor).
   Printed: the number of windows, the time of the moment pass, the time per solve from the moments
   (batch: direct + ML refinement + covariance; graph: direct seed + factor construction +
   Levenberg-Marquardt + Marginals), best of 3, and the largest difference between the two
   estimates over all 12 parameters in units of the batch standard deviation.
0. End to end at N = 1e4 and 1e6 (issue 25): ``calibrate_pair_graph(omega_1, omega_2, noise_std=...)`` (window
   moments, direct seed, LM, Marginals; 1000-sample windows) against the closed form
   ``calibrate_pair(omega_1, omega_2, noise_std=...)`` on the same data, as the ratio of the best times of each
   round over ``--rounds`` interleaved rounds (target at 1e6: <= 5x).
2. iSAM2 fed one second of 100 Hz data at a time (one window per second): wall time per
   ``update()`` (median, 95th percentile, max) over the run, with one constant bias (the merged
   pair factor replaced at each update) and with a bias random walk (one new pair factor and bias
   variable per second), and the final ``result()`` time.

    python benchmarks/graph.py [--max-n 1000000] [--seconds 600] [--end-to-end-only]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _timing import best_of  # noqa: E402  (benchmarks/ is the script's folder)
from scipy.spatial.transform import Rotation

from fusion_gyrocal import Moments, calibrate_pair, solve
from fusion_gyrocal.graph import GyroPairGraph, calibrate_pair_graph
from fusion_gyrocal.core.moments import window_moments
from fusion_gyrocal.evaluate.sim import PAPER_BIAS_WALK_STD, simulate_pair


def graph_solve(parts, noise):
    seed = solve(Moments.merge_all(parts), noise_std=noise, method="direct")
    g = GyroPairGraph(seed)
    for m in parts:
        g.add_window(m)
    return g.solve()


def max_sigma_difference(a, b) -> float:
    sd = np.sqrt(np.diag(b.covariance))
    dtheta = Rotation.from_matrix(a.R_1_2 @ b.R_1_2.T).as_rotvec()
    diff = np.concatenate([dtheta, a.scale_1 - b.scale_1, a.scale_2 - b.scale_2, a.bias - b.bias])
    ok = np.isfinite(sd) & (sd > 0)
    return float(np.max(np.abs(diff[ok] / sd[ok])))


def end_to_end(rounds: int = 3):
    print("graph end to end against the closed form, calibrate_pair_graph / calibrate_pair (noise given), "
          f"best of 3 per round, {rounds} interleaved rounds")
    for n in (10**4, 10**6):
        sim = simulate_pair(n=n, rng=1)
        w1, w2, noise = sim.omega_1, sim.omega_2, sim.noise_std
        ratios, tg, tc = [], [], []
        for _ in range(rounds):
            tg.append(best_of(lambda: calibrate_pair_graph(w1, w2, noise_std=noise))[0])
            tc.append(best_of(lambda: calibrate_pair(w1, w2, noise_std=noise))[0])
            ratios.append(tg[-1] / tc[-1])
        print(f"  N = {n:8d}: graph {min(tg):.4f} s, closed form {min(tc):.4f} s, graph / closed form median "
              f"{np.median(ratios):.2f}x (rounds {min(ratios):.2f}-{max(ratios):.2f})")


def batch_versus_graph(max_n: int):
    print("graph (LM) versus closed-form batch (direct + ML) on the same window moments, one constant bias")
    print(f"{'N':>9} {'windows':>8} {'moments s':>10} {'batch s':>9} {'graph s':>9} {'graph/batch':>11} "
          f"{'max |diff|/sigma':>17} {'LM iters':>8}")
    n = 1000
    while n <= max_n:
        sim = simulate_pair(n=n, rng=n)
        noise = sim.noise_std
        window = max(100, n // 200)                      # at most 200 windows whatever N
        t_mom, parts = best_of(lambda: window_moments(sim.omega_1, sim.omega_2, window), k=1)
        total = Moments.merge_all(parts)
        t_batch, batch = best_of(lambda: solve(total, noise_std=noise, method="ml"))
        t_graph, gr = best_of(lambda: graph_solve(parts, noise))
        print(f"{n:9d} {len(parts):8d} {t_mom:10.4f} {t_batch:9.4f} {t_graph:9.4f} {t_graph / t_batch:11.1f} "
              f"{max_sigma_difference(gr, batch):17.2e} {gr.iterations:8d}")
        n *= 10


def isam2_streaming(seconds: int, rate_hz: float = 100.0):
    print(f"\niSAM2 fed 1 s of {rate_hz:g} Hz data per update ({seconds} s in all)")
    print(f"{'bias model':>22} {'median ms':>10} {'p95 ms':>8} {'max ms':>8} {'last 60 s median ms':>20} "
          f"{'result() s':>11} {'real-time factor':>17}")
    n = int(seconds * rate_hz)
    walk = 20 * PAPER_BIAS_WALK_STD
    sim = simulate_pair(n=n, bias_walk_std=walk, rng=7)
    window = int(rate_hz)
    parts = window_moments(sim.omega_1, sim.omega_2, window)
    seed = solve(Moments.merge_all(parts[:10]), noise_std=sim.noise_std, method="direct")  # first 10 s
    for label, bias_walk in (("constant", None), ("random walk per second", np.sqrt(2.0) * walk)):
        g = GyroPairGraph(seed, bias_walk_std=bias_walk)
        times = []
        for m in parts:
            g.add_window(m)
            t0 = time.perf_counter()
            g.update()
            times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        g.result()
        t_res = time.perf_counter() - t0
        ms = 1e3 * np.asarray(times)
        tail = ms[-int(min(60, len(ms))):]
        print(f"{label:>22} {np.median(ms):10.2f} {np.percentile(ms, 95):8.2f} {ms.max():8.2f} "
              f"{np.median(tail):20.2f} {t_res:11.3f} {1.0 / (np.median(ms) / 1e3):17.0f}x")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-n", type=int, default=10**6)
    ap.add_argument("--seconds", type=int, default=600)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--end-to-end-only", action="store_true")
    args = ap.parse_args(argv)
    end_to_end(args.rounds)
    if args.end_to_end_only:
        return
    batch_versus_graph(args.max_n)
    isam2_streaming(args.seconds)


if __name__ == "__main__":
    main()
