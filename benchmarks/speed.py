"""Throughput of calibrate_pair beside a raw numpy pass over the same data, and its memory.

For N = 1e4 ... 1e7 samples, measured in the same run (best of 3):
* core: ``solve(Moments.from_samples(omega_1, omega_2))`` (the O(N) pass, direct solve, ML
  refinement, covariance);
* default: ``calibrate_pair(omega_1, omega_2)`` (the core plus the flex/outlier checks on a
  subsample and the rate-residual correlation);
* raw: ``X.T @ X`` on the same samples stacked as an (N, 6) array;
the ratios raw_time / our_time (1.0 = as fast as the raw pass) and the peak memory allocated
beyond the inputs by calibrate_pair (tracemalloc).

Then the target row, what users do: two separate (5e6, 3) arrays (``calibrate_pair(omega_1, omega_2)``,
the default pipeline: the noise model identified from the data, the block-robust covariance, the flex checks) against
``X.T @ X`` of the same data stacked as (N, 6), best of 5, with each part (the moments pass, the
noise split, the moments pass with the clipping test's extremes the default takes) and the peak memory beyond the
inputs (target: >= 0.5x, <= 64 MiB).

Then the drifting-bias row (issue 25): a 1e6-sample log whose bias walks at 100x the paper's rate; the default
``calibrate_pair(omega_1, omega_2)`` (which identifies the walk and solves on the Kalman innovations) against the
same call with the noise given (``noise_std``: no identification, one constant bias), as the ratio of the two best
times of each round, over ``--rounds`` interleaved rounds (target: <= 2.5x).

Then the start-up row: ``gyrocal --help`` (``python -m fusion_gyrocal.cli --help``) against
``python -c "import numpy"``, each a fresh interpreter, interleaved, median of ``--starts`` runs (target: <= 1.5x).

    python benchmarks/speed.py [--target-only] [--drift-only] [--startup-only]
"""

from __future__ import annotations

import shutil
import statistics
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import argparse
import os

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # this checkout's package (not an installed one)

import numpy as np  # noqa: E402
from _timing import best_of, installed_like_env  # noqa: E402  (benchmarks/ is the script's folder)

from fusion_gyrocal import Moments, calibrate_pair, solve
from fusion_gyrocal.evaluate.sim import PAPER_BIAS_WALK_STD, PAPER_NOISE_STD, random_rotation, simulate_pair
from fusion_gyrocal.core.direct import solve_A
from fusion_gyrocal.core.moments import moments_with_extremes, random_walk_bias_moments, window_stats
from fusion_gyrocal.core.noise import difference_noise_std, identify_noise


def target(n=5_000_000, k=5):
    """calibrate_pair on two separate (n, 3) arrays against X.T @ X of the stacked (n, 6) data."""
    rng = np.random.default_rng(1)
    R = random_rotation(rng)
    w1 = rng.standard_normal((n, 3))
    w2 = w1 @ R * 1.01 + rng.normal(0, PAPER_NOISE_STD, (n, 3)) + 0.01
    X = np.hstack([w1, w2])
    raw = best_of(lambda: X.T @ X, k)[0]
    cal = best_of(lambda: calibrate_pair(w1, w2), k)[0]
    cal_known = best_of(lambda: calibrate_pair(w1, w2, noise_std=PAPER_NOISE_STD), k)[0]
    mom = best_of(lambda: Moments.from_samples(w1, w2), k)[0]
    mom_ext = best_of(lambda: moments_with_extremes(w1, w2), k)[0]
    noise = best_of(lambda: (difference_noise_std(w1), difference_noise_std(w2)), k)[0]
    A, b = solve_A(Moments.from_samples(w1, w2))
    ident = best_of(lambda: identify_noise(w1, w2, A, b, rate_hz=1.0, window_s=100.0), k)[0]
    windows = best_of(lambda: window_stats(w1, w2, 100), k)[0]
    X = None  # free it before measuring memory
    tracemalloc.start()
    calibrate_pair(w1, w2)
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    print(f"\ntwo separate ({n}, 3) arrays, best of {k}; raw = X.T @ X of the stacked ({n}, 6) data: {raw:.4f} s")
    print(f"  {'':44} {'s':>8} {'raw/ours':>9}")
    for name, tt in (("calibrate_pair(omega_1, omega_2)", cal),
                     ("calibrate_pair(..., noise_std=known)", cal_known),
                     ("  Moments.from_samples(omega_1, omega_2)", mom),
                     ("  moments_with_extremes (the default's pass)", mom_ext),
                     ("  noise split (difference_noise_std x 2)", noise),
                     ("  identify_noise (stretches of the log)", ident),
                     ("  window_stats (robust covariance)", windows)):
        print(f"  {name:44} {tt:8.4f} {raw / tt:9.3f}")
    print(f"  the rest of the default (calibrate_pair less its pass): {cal - mom_ext:.4f} s; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"  peak memory beyond the inputs (calibrate_pair): {peak:.1f} MiB (target <= 64)")


def drift(n=1_000_000, rounds=5, k=3):
    """Default calibrate_pair on a drifting-bias log against the same call with the noise given."""
    sim = simulate_pair(n=n, bias_walk_std=100 * PAPER_BIAS_WALK_STD, rng=1)
    w1, w2 = sim.omega_1, sim.omega_2
    default = calibrate_pair(w1, w2)
    ratios, t_def, t_known = [], [], []
    for _ in range(rounds):
        td = best_of(lambda: calibrate_pair(w1, w2), k)[0]
        tk = best_of(lambda: calibrate_pair(w1, w2, noise_std=PAPER_NOISE_STD), k)[0]
        ratios.append(td / tk)
        t_def.append(td)
        t_known.append(tk)
    walk, noise = default.noise_model.bias_walk_std, default.noise_model.noise_std
    # the filter's own time, at the identified walk (or, where the identification kept a constant bias, the walk
    # the log was simulated with)
    walk = 100 * PAPER_BIAS_WALK_STD if walk is None else walk
    t_rw = best_of(lambda: random_walk_bias_moments(w1, w2, walk, noise, window=100), k)[0]
    t_mom = best_of(lambda: Moments.from_samples(w1, w2), k)[0]
    A, b = solve_A(Moments.from_samples(w1, w2))
    t_id = best_of(lambda: identify_noise(w1, w2, A, b, rate_hz=1.0, window_s=100.0), k)[0]
    print(f"\ndrifting bias ({n} samples, walk 100x the paper's; identified: {default.noise_model.bias_model}), "
          f"best of {k} per round, {rounds} rounds; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"  calibrate_pair(omega_1, omega_2) (default)      {min(t_def):8.4f} s (rounds {min(t_def):.3f}-{max(t_def):.3f})")
    print(f"  calibrate_pair(..., noise_std=known)            {min(t_known):8.4f} s (rounds {min(t_known):.3f}-"
          f"{max(t_known):.3f})")
    print(f"    identify_noise (the default's extra step)     {t_id:8.4f} s")
    print(f"    random_walk_bias_moments(..., window=100)     {t_rw:8.4f} s; Moments.from_samples {t_mom:.4f} s")
    print(f"  default / noise given: median {np.median(ratios):.2f}x (rounds {min(ratios):.2f}-{max(ratios):.2f}; "
          "target <= 2.5x)")


def startup(runs=15):
    """``gyrocal --help`` against ``import numpy``, fresh interpreters, interleaved, after a warm-up round (the
    package's bytecode cached as an installed package's is: :func:`_timing.installed_like_env`)."""
    root = str(Path(__file__).resolve().parent.parent)     # this checkout's package, its bytecode cached as an
    env = installed_like_env(root)                          # installed package's is
    cmds = {"import numpy": [sys.executable, "-c", "import numpy"],
            "gyrocal --help": [sys.executable, "-m", "fusion_gyrocal.cli", "--help"]}
    times = {k: [] for k in cmds}
    for r in range(runs + 1):                               # the first round fills the bytecode cache
        for name, cmd in cmds.items():
            t0 = time.perf_counter()
            subprocess.run(cmd, cwd=root, check=True, stdout=subprocess.DEVNULL, env=env)
            if r:
                times[name].append(time.perf_counter() - t0)
    shutil.rmtree(env["PYTHONPYCACHEPREFIX"], ignore_errors=True)
    med = {k: statistics.median(v) for k, v in times.items()}
    ratios = [h / n for h, n in zip(times["gyrocal --help"], times["import numpy"])]
    print(f"\nstart-up, fresh interpreters, median of {runs} interleaved runs")
    for k, v in med.items():
        print(f"  {k:16} {v:8.3f} s (runs {min(times[k]):.3f}-{max(times[k]):.3f})")
    print(f"  gyrocal --help / import numpy: {med['gyrocal --help'] / med['import numpy']:.2f}x of the medians "
          f"(per-pair ratios {min(ratios):.2f}-{max(ratios):.2f}; target <= 1.5x)")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--target-only", action="store_true")
    p.add_argument("--drift-only", action="store_true")
    p.add_argument("--startup-only", action="store_true")
    p.add_argument("--starts", type=int, default=15, help="interpreter starts of each kind in the start-up row")
    p.add_argument("--rounds", type=int, default=5, help="interleaved rounds of the drifting-bias row")
    p.add_argument("--n", type=int, default=5_000_000, help="samples of the target row (default 5e6)")
    a = p.parse_args(argv)
    if a.startup_only:
        startup(a.starts)
        return
    if a.drift_only:
        drift(rounds=a.rounds)
        return
    if a.target_only:
        target(a.n)
        return
    rng = np.random.default_rng(0)
    R = random_rotation(rng)
    print(f"{'N':>10} {'core s':>9} {'default s':>10} {'raw X.T@X s':>12} {'core Msamples/s':>16} "
          f"{'raw/core':>9} {'raw/default':>12} {'peak MB':>8}")
    for n in (10**4, 10**5, 10**6, 10**7):
        w1 = rng.standard_normal((n, 3))
        w2 = w1 @ R + rng.normal(0, PAPER_NOISE_STD, (n, 3)) + 0.01
        X = np.hstack([w1, w2])
        core = best_of(lambda: solve(Moments.from_samples(w1, w2), noise_std=PAPER_NOISE_STD))[0]
        ours = best_of(lambda: calibrate_pair(w1, w2, noise_std=PAPER_NOISE_STD))[0]
        raw = best_of(lambda: X.T @ X)[0]
        tracemalloc.start()
        calibrate_pair(w1, w2, noise_std=PAPER_NOISE_STD)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        print(f"{n:10d} {core:9.4f} {ours:10.4f} {raw:12.4f} {n / core / 1e6:16.2f} {raw / core:9.3f} "
              f"{raw / ours:12.3f} {peak:8.2f}")
        X = None
    target(a.n)
    drift(rounds=a.rounds)
    startup(a.starts)


if __name__ == "__main__":
    main()
