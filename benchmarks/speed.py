"""Throughput of calibrate_pair beside a raw numpy pass over the same data, and its memory.

For N = 1e4 ... 1e7 samples, measured in the same run (best of 3):
* core: ``solve(Moments.from_samples(omega_1, omega_2))`` (the O(N) pass, direct solve, ML
  refinement, covariance);
* default: ``calibrate_pair(omega_1, omega_2)`` (the core plus the flex/outlier checks on a
  subsample and the rate-residual correlation);
* raw: ``X.T @ X`` on the same samples stacked as an (N, 6) array;
the ratios raw_time / our_time (1.0 = as fast as the raw pass) and the peak memory allocated
beyond the inputs by calibrate_pair (tracemalloc).

    python benchmarks/speed.py
"""

from __future__ import annotations

import time
import tracemalloc

import numpy as np

from fusion_gyrocal import Moments, calibrate_pair, solve
from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, random_rotation


def best_of(f, k=3):
    t = []
    for _ in range(k):
        t0 = time.perf_counter()
        f()
        t.append(time.perf_counter() - t0)
    return min(t)


def main():
    rng = np.random.default_rng(0)
    R = random_rotation(rng)
    print(f"{'N':>10} {'core s':>9} {'default s':>10} {'raw X.T@X s':>12} {'core Msamples/s':>16} "
          f"{'raw/core':>9} {'raw/default':>12} {'peak MB':>8}")
    for n in (10**4, 10**5, 10**6, 10**7):
        w1 = rng.standard_normal((n, 3))
        w2 = w1 @ R + rng.normal(0, PAPER_NOISE_STD, (n, 3)) + 0.01
        X = np.hstack([w1, w2])
        core = best_of(lambda: solve(Moments.from_samples(w1, w2), noise_std=PAPER_NOISE_STD))
        ours = best_of(lambda: calibrate_pair(w1, w2, noise_std=PAPER_NOISE_STD))
        raw = best_of(lambda: X.T @ X)
        tracemalloc.start()
        calibrate_pair(w1, w2, noise_std=PAPER_NOISE_STD)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        print(f"{n:10d} {core:9.4f} {ours:10.4f} {raw:12.4f} {n / core / 1e6:16.2f} {raw / core:9.3f} "
              f"{raw / ours:12.3f} {peak:8.2f}")
        del X


if __name__ == "__main__":
    main()
