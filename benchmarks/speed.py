"""Throughput of calibrate_pair beside a raw numpy pass over the same data, and its memory.

For N = 1e4 ... 1e7 samples: the time of ``calibrate_pair(omega_1, omega_2)`` (moments, direct
solve, ML refinement, covariance) against ``X.T @ X`` on the same samples stacked as an
(N, 6) array, measured in the same run (best of 3); the ratio raw_time / our_time (1.0 = as
fast as the raw pass), and the peak memory allocated beyond the inputs (tracemalloc).

    python benchmarks/speed.py
"""

from __future__ import annotations

import time
import tracemalloc

import numpy as np

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.sim import PAPER_NOISE_STD, random_rotation


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
    print(f"{'N':>10} {'ours s':>9} {'raw X.T@X s':>12} {'Msamples/s':>11} {'ratio raw/ours':>15} {'peak MB':>8} "
          f"{'us/sample':>10}")
    for n in (10**4, 10**5, 10**6, 10**7):
        w1 = rng.standard_normal((n, 3))
        w2 = w1 @ R + rng.normal(0, PAPER_NOISE_STD, (n, 3)) + 0.01
        X = np.hstack([w1, w2])
        ours = best_of(lambda: calibrate_pair(w1, w2, noise_std=PAPER_NOISE_STD))
        raw = best_of(lambda: X.T @ X)
        tracemalloc.start()
        calibrate_pair(w1, w2, noise_std=PAPER_NOISE_STD)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        print(f"{n:10d} {ours:9.4f} {raw:12.4f} {n / ours / 1e6:11.2f} {raw / ours:15.3f} {peak:8.2f} "
              f"{1e6 * ours / n:10.4f}")
        del X


if __name__ == "__main__":
    main()
