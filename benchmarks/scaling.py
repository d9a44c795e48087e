"""Time and memory of the timestamped pipeline against N (1e6 ... 5e7 samples per gyro).

``run_pipeline(omega_1, omega_2, t_1=..., t_2=...)`` on two 200 Hz streams (gyro 2 rotated, scaled,
biased, 35 ms behind, the paper's noise), each N in a fresh process. Printed per N:
wall time, time per sample (flat when the time is linear in N), peak memory beyond the inputs
(peak RSS after the inputs exist, reset through ``/proc/self/clear_refs``; tracemalloc's peak
when that is unavailable) in bytes per sample, the aligned output's size (57 bytes per sample)
and the offset error against its reported std.

    python benchmarks/scaling.py [--n 1e6 5e6 1e7 5e7]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

RATE = 200.0
SHIFT = 7          # gyro 2 runs SHIFT samples (35 ms) behind gyro 1


def _rss() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


def _hwm() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return 0


def make_inputs(n: int, seed: int = 0):
    """Two 200 Hz streams of smooth random (non-periodic) motion, generated in chunks."""
    from scipy.signal import lfilter

    from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, random_rotation

    rng = np.random.default_rng(seed)
    R = random_rotation(rng)
    t1 = np.empty(n)
    t2 = np.empty(n)
    w1 = np.empty((n, 3))
    w2 = np.empty((n, 3))
    b, a = [0.02], [1.0, -0.98]                       # first-order low-pass: a few Hz of motion
    zi = np.zeros((1, 3))
    chunk = 1 << 20
    prev = np.zeros((SHIFT, 3))
    for lo in range(0, n, chunk):
        hi = min(lo + chunk, n)
        x, zi = lfilter(b, a, rng.normal(0.0, 6.0, (hi - lo, 3)), axis=0, zi=zi)
        k = np.arange(lo, hi)
        t1[lo:hi] = k / RATE
        t2[lo:hi] = k / RATE                          # gyro 2's own clock
        w1[lo:hi] = x + rng.normal(0, PAPER_NOISE_STD, x.shape) + 0.004
        delayed = np.vstack([prev, x])[: hi - lo]     # gyro 2 sees the motion SHIFT samples later
        w2[lo:hi] = (delayed @ R) * 1.01 + rng.normal(0, PAPER_NOISE_STD, x.shape) - 0.002
        prev = x[-SHIFT:]
    offset = -SHIFT / RATE                             # added to t_2 puts it on gyro 1's clock
    return t1, w1, t2, w2, offset


def child(n: int) -> dict:
    from fusion_gyrocal.pipeline.pipeline import run_pipeline

    t1, w1, t2, w2, offset = make_inputs(n)
    base = _rss()
    reset = True
    try:
        Path("/proc/self/clear_refs").write_text("5")  # reset the peak RSS (VmHWM)
    except OSError:
        reset = False
    if not reset:
        import tracemalloc
        tracemalloc.start()
    t0 = time.perf_counter()
    run = run_pipeline(w1, w2, t_1=t1, t_2=t2)
    wall = time.perf_counter() - t0
    if reset:
        peak = _hwm() - base
    else:
        import tracemalloc
        peak = tracemalloc.get_traced_memory()[1]
    tof = run.aligned.time_offset
    return {"n": n, "wall_s": wall, "peak_bytes": peak, "how": "peak RSS" if reset else "tracemalloc",
            "offset_err_s": tof.offset_s - offset, "offset_std_s": tof.std_s}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=float, nargs="+", default=[1e6, 5e6, 1e7, 5e7])
    p.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.child is not None:
        print(json.dumps(child(a.child)))
        return
    print(f"{'N':>10} {'time s':>8} {'us/sample':>10} {'peak MiB':>9} {'bytes/sample':>13} {'offset err us':>14} "
          f"{'std us':>7}  (aligned output: 57 bytes/sample; inputs 64 bytes/sample)")
    for n in (int(x) for x in a.n):
        out = subprocess.run([sys.executable, __file__, "--child", str(n)], capture_output=True, text=True)
        if out.returncode:
            print(f"{n:10d} failed: {out.stderr.strip().splitlines()[-1] if out.stderr else out.returncode}")
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"{n:10d} {r['wall_s']:8.2f} {1e6 * r['wall_s'] / n:10.3f} {r['peak_bytes'] / 2**20:9.1f} "
              f"{r['peak_bytes'] / n:13.1f} {1e6 * r['offset_err_s']:14.3f} {1e6 * r['offset_std_s']:7.3f}  "
              f"({r['how']})")


if __name__ == "__main__":
    main()
