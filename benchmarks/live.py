"""Live tracking: latency per sample of the live path, and `gyrocal track` on a replayed MIMU session.

1. In process (``LivePair``): the samples of IMU 0 and IMU 2 of a MIMU session (``../shared/data/mimu_8imu_array``,
   62.5 Hz, both IMUs on one clock) pushed one by one in a random interleaving of the two streams; the time of
   every ``push`` is measured (``perf_counter_ns``): median, 99th percentile and maximum per sample, per mode
   (``fast``: blocks of 100 samples, the block's update paid by the sample that completes it; ``sample``: one
   update per sample), after the seed (the seed's batch solve is timed once, apart), and the mean time per aligned
   pair (the time of all calls over the pairs). Timed on a loaded machine, the maximum and the 99th percentile
   include the scheduler's pauses. The final state is compared
   with the batch tracker on the same aligned samples (``GyroPairTracker.run``).
2. ``gyrocal track`` as a process reading standard input, the session written to it as ``tagged`` lines either in
   real time (``--realtime``: each line at its sample time; about 10 minutes per session) or as fast as the pipe
   takes it (default): wall time per sample, and the largest difference of the final state from the batch
   tracker's.

    python benchmarks/live.py [--session 1] [--realtime] [--samples N]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fusion_gyrocal.evaluate.sim import shared_data_dir  # noqa: E402
from fusion_gyrocal.io import read_npz  # noqa: E402
from fusion_gyrocal.online.live import LivePair  # noqa: E402
from fusion_gyrocal.online.tracker import GyroPairTracker  # noqa: E402

SEED_S = 30.0
STATE = ("R_1_2", "scale_1", "scale_2", "bias")


def batch(t, w1, w2, mode):
    k = int(np.argmax(t - t[0] >= SEED_S))
    gap = 5.0 * float(np.median(np.diff(t[:k + 1])))
    bt = GyroPairTracker.from_samples(t[:k + 1], w1[:k + 1], w2[:k + 1], history_max_rows=2000)
    bt.run(t[k + 1:], w1[k + 1:], w2[k + 1:], mode=mode, max_gap_s=gap)
    return bt


def in_process(t, w1, w2, mode, rng):
    live = LivePair(seed_s=SEED_S, mode=mode)
    order = np.repeat([1, 2], len(t))
    rng.shuffle(order)
    i = {1: 0, 2: 0}
    lat = np.empty(order.size, dtype=np.int64)
    seeded_at = None
    for j, g in enumerate(order):
        k = i[g]
        i[g] += 1
        a = time.perf_counter_ns()
        live.push(int(g), t[k], (w1 if g == 1 else w2)[k])
        lat[j] = time.perf_counter_ns() - a
        if seeded_at is None and live.tracker is not None:
            seeded_at = j
    live.close()
    bt = batch(t, w1, w2, mode)
    diff = max(float(np.max(np.abs(getattr(live.tracker, n) - getattr(bt, n)))) for n in STATE)
    return lat, seeded_at, diff


def through_cli(t, w1, w2, realtime: bool):
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "track.jsonl"      # a file, not a pipe: the lines never block the command
        proc = subprocess.Popen([sys.executable, "-m", "fusion_gyrocal.cli", "track", "-", "--format", "tagged",
                                 "--seed-s", str(SEED_S), "--every", "10", "-o", str(out)], cwd=ROOT,
                                stdin=subprocess.PIPE, text=True)
        start = time.perf_counter()
        for k in range(len(t)):
            if realtime:
                wait = (t[k] - t[0]) - (time.perf_counter() - start)
                if wait > 0:
                    time.sleep(wait)
            proc.stdin.write("".join(f"{g},{float(t[k])!r},{float(w[k, 0])!r},{float(w[k, 1])!r},"
                                     f"{float(w[k, 2])!r}\n" for g, w in ((1, w1), (2, w2))))
        proc.stdin.close()
        proc.wait()
        wall = time.perf_counter() - start
        final = json.loads(out.read_text().splitlines()[-1])
    bt = batch(t, w1, w2, "fast")
    diff = max(float(np.max(np.abs(np.asarray(final[n]) - getattr(bt, n)))) for n in STATE)
    return wall, final, diff


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--session", type=int, default=1)
    ap.add_argument("--samples", type=int, help="only the first N samples of the session")
    ap.add_argument("--realtime", action="store_true", help="replay to gyrocal track at the recording's pace")
    args = ap.parse_args()
    p = shared_data_dir() / "mimu_8imu_array" / "npz" / f"exp_{args.session}.npz"
    if not p.exists():
        sys.exit(f"{p} not present (real recordings are only in the project checkout)")
    imus = read_npz(p)
    n = len(imus[0]) if args.samples is None else args.samples
    t, w1, w2 = imus[0].t[:n], imus[0].omega[:n], imus[2].omega[:n]
    print(f"MIMU session {args.session}, IMU 0 (gyro 1) and IMU 2 (gyro 2): {n} samples per gyro, "
          f"{t[-1] - t[0]:.0f} s at {1 / np.median(np.diff(t)):.1f} Hz; seed {SEED_S:g} s\n")
    print("1. LivePair.push, one sample of either gyro per call, random interleaving, after the seed: us per call "
          "(median, 99th percentile, max) and per aligned pair (all calls' time / pairs)", flush=True)
    print(f"{'mode':<8}{'median':>9}{'p99':>9}{'max':>10}{'per pair':>10}{'seed solve ms':>15}{'|live - batch|':>16}",
          flush=True)
    rng = np.random.default_rng(0)
    for mode in ("fast", "sample"):
        lat, seeded_at, diff = in_process(t, w1, w2, mode, rng)
        after = lat[seeded_at + 1:] / 1e3
        pairs = (len(lat) - seeded_at - 1) / 2
        print(f"{mode:<8}{np.median(after):>9.1f}{np.percentile(after, 99):>9.1f}{after.max():>10.0f}"
              f"{after.sum() / pairs:>10.1f}{lat[seeded_at] / 1e6:>15.0f}{diff:>16.1e}", flush=True)
    how = "in real time" if args.realtime else "as fast as the pipe takes it"
    wall, final, diff = through_cli(t, w1, w2, args.realtime)
    print(f"\n2. gyrocal track - (stdin, tagged lines, {how}): {wall:.1f} s wall for {2 * n} lines "
          f"({wall / (2 * n) * 1e6:.0f} us per line, process start included); final n_samples "
          f"{final['n_samples']}, max |final - batch| = {diff:.1e}")


if __name__ == "__main__":
    main()
