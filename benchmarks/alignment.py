"""Monte Carlo of the time-offset estimate (fusion_gyrocal.pipeline.alignment.estimate_time_offset).

Two gyros on their own clocks at 100 Hz and 200 Hz (which one is faster alternates; one
scenario has both at 200 Hz), jittered
sample instants (uniform +-0.25 period, recorded exactly), gyro 2 rotated by a random rotation,
scaled by ~1 % per axis and biased (0.5 deg/s per axis), white noise 0.1 deg/s per sample
(the paper's Section V), human-like motion from ``fusion_gyrocal.evaluate.sim.HumanMotion`` and a true
offset drawn from U(-0.3, 0.3) s.

Printed per scenario: RMS and max offset error, mean reported std, the ratio RMS / mean std
(1 when the reported std is right), the error of two simpler estimators on the same data (the
coarse norm-correlation peak with parabolic interpolation; the same refined by matching spline
norms with a gain and an offset instead of the full rigid model), the time per alignment and
the time of one plain FFT cross-correlation of the two raw norm series.

Then (issue 24) independent clocks: 10-minute pairs at 200 Hz with gyro 2's clock seconds to an hour off and
drifting by 10-200 ppm, the defaults (the whole overlap searched): the drift error (ppm) against its std and
the offset error at the log's middle (ms).

Then (issue 25) the timestamped pipeline against what a user would write by hand, in a fresh process per N
(``benchmarks/scaling.py``'s 200 Hz inputs, gyro 2 35 ms behind): ``run_pipeline(omega_1, omega_2, t_1=...,
t_2=...)`` against ``np.interp`` of gyro 2's three axes at gyro 1's instants (the offset known) plus
``X.T @ X`` of the stacked (N, 6) samples, timed in the same process, and the pipeline's peak memory beyond the
inputs (peak RSS reset through ``/proc/self/clear_refs``) in bytes per sample.

``--where`` adds a diagnostic: the highest RSS a thread reading ``/proc/self/status`` every 2 ms saw during the
pipeline and the library frames running then (the measure above is unchanged; the watch is off without it).

Run: ``python benchmarks/alignment.py [--runs 100] [--seed 1] [--clocks-only | --pipeline-only] [--n 1e7]
[--where]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import minimize_scalar
from scipy.signal import correlate

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))   # benchmarks/scaling.py's inputs
sys.path.insert(1, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))   # this checkout's package

from fusion_gyrocal.pipeline.alignment import _parabolic_peak, estimate_time_offset  # noqa: E402
from fusion_gyrocal.evaluate.sim import simulate_streams  # noqa: E402


def coarse_offset(est) -> float:
    """Peak of the norm correlation with parabolic interpolation (the library's coarse stage alone)."""
    r = np.where(np.isfinite(est.correlation), est.correlation, -np.inf)
    i = int(np.argmax(r))
    return float(est.lags_s[i] + _parabolic_peak(r, i) * (est.lags_s[1] - est.lags_s[0]))


def norm_refined_offset(t1, w1, t2, w2, tau0, h) -> float:
    """Minimise sum_k (|w1(t_k)| - g |w2|(t_k - tau) - c)^2 over tau (g, c by least squares)."""
    n1 = np.linalg.norm(w1, axis=1)
    spl = CubicSpline(t2, np.linalg.norm(w2, axis=1))
    use = (t1 - tau0 - 2 * h > t2[0]) & (t1 - tau0 + 2 * h < t2[-1])
    x, y = t1[use], n1[use]

    def cost(tau):
        z = spl(x - tau)
        X = np.c_[z, np.ones_like(z)]
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        return float(np.sum((y - X @ coef) ** 2))

    return float(minimize_scalar(cost, bounds=(tau0 - 1.5 * h, tau0 + 1.5 * h), method="bounded",
                                 options={"xatol": 1e-9}).x)


def run(scenario: str, runs: int, rng, *, duration: float, rms: float, rates=((100.0, 200.0), (200.0, 100.0))) -> None:
    err, std, err_coarse, err_norm, t_est, t_fft = [], [], [], [], [], []
    for k in range(runs):
        offset = rng.uniform(-0.3, 0.3)
        rate_1, rate_2 = rates[k % len(rates)]
        t1, w1, t2, w2, *_ = simulate_streams(rng, rate_1=rate_1, rate_2=rate_2, duration=duration,
                                              offset=offset, rms=rms)
        t0 = time.perf_counter()
        est = estimate_time_offset(t1, w1, t2, w2)
        t_est.append(time.perf_counter() - t0)
        n1, n2 = np.linalg.norm(w1, axis=1), np.linalg.norm(w2, axis=1)
        t0 = time.perf_counter()
        correlate(n1 - n1.mean(), n2 - n2.mean(), mode="full", method="fft")
        t_fft.append(time.perf_counter() - t0)
        err.append(est.offset_s - offset)
        std.append(est.std_s)
        tau_c = coarse_offset(est)
        err_coarse.append(tau_c - offset)
        err_norm.append(norm_refined_offset(t1, w1, t2, w2, tau_c, est.lags_s[1] - est.lags_s[0]) - offset)
    err, std = np.array(err), np.array(std)
    rms_ms = 1e3 * np.sqrt(np.mean(err**2))
    hz = ", ".join(f"{a:g}/{b:g}" for a, b in rates)
    print(f"\n{scenario}: {runs} runs, {duration:g} s, motion RMS {rms:g} rad/s per axis, gyro 1/2 at {hz} Hz, "
          "jitter +-0.25 period, offsets U(-0.3, 0.3) s")
    print(f"  offset error RMS            {rms_ms:9.5f} ms   (max {1e3 * np.abs(err).max():.5f} ms, "
          f"mean {1e3 * err.mean():+.5f} ms)")
    print(f"  mean reported std           {1e3 * std.mean():9.5f} ms")
    print(f"  RMS / mean std              {rms_ms / (1e3 * std.mean()):9.3f}     "
          f"(RMS of err/std: {np.sqrt(np.mean((err / std) ** 2)):.3f})")
    print(f"  coarse peak only            {1e3 * np.sqrt(np.mean(np.square(err_coarse))):9.5f} ms RMS")
    print(f"  norm-matching refinement    {1e3 * np.sqrt(np.mean(np.square(err_norm))):9.5f} ms RMS "
          f"(max {1e3 * np.abs(err_norm).max():.5f} ms)")
    print(f"  time per alignment          {1e3 * np.mean(t_est):9.2f} ms   "
          f"(plain FFT correlation of the raw norms: {1e3 * np.mean(t_fft):.2f} ms)")


def clocks(seed: int = 0) -> None:
    """Offsets of seconds to an hour and 10-200 ppm of drift recovered with the defaults."""
    from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, HumanMotion, random_rotation
    from fusion_gyrocal.pipeline.alignment import align_streams

    print("\nindependent clocks: 600 s at 200 Hz, offset at the middle tau, drift ppm (defaults: whole overlap)")
    print(f"  {'tau s':>8} {'ppm':>6} {'drift err ppm':>14} {'drift std':>10} {'offset err ms':>14} {'std ms':>8} "
          f"{'time s':>7}")
    rng = np.random.default_rng(seed)
    for tau, ppm in ((2.0, 10.0), (-15.0, 50.0), (300.0, -100.0), (3600.0, 200.0)):
        motion, R = HumanMotion(1.0, rng=rng), random_rotation(rng)
        t1 = np.arange(0, 600.0, 1 / 200.0)
        s = -tau + np.arange(t1.size) / 200.0
        d = 1e-6 * ppm
        w1 = motion(t1) + rng.normal(0, PAPER_NOISE_STD, (t1.size, 3))
        w2 = motion((s + tau - d * 300.0) / (1 - d)) @ R + rng.normal(0, PAPER_NOISE_STD, (s.size, 3))
        t0 = time.perf_counter()
        est = align_streams(t1, w1, s, w2).time_offset
        dt = time.perf_counter() - t0
        print(f"  {tau:8g} {ppm:6g} {est.drift_ppm - ppm:+14.3f} {est.drift_std_ppm:10.3f} "
              f"{1e3 * (float(est.offset_at(300.0)) - tau):+14.5f} {1e3 * est.std_s:8.5f} {dt:7.2f}")


def _rss_watch(interval: float = 0.002):
    """Diagnostic (``--where``): a thread reading VmRSS every ``interval`` s and, at its highest reading, the main
    thread's innermost library frames; call the returned ``stop()`` for ``(rss, frames)``."""
    import threading

    main, best, done = threading.get_ident(), [0, ()], threading.Event()

    def frames():
        f, out = sys._current_frames().get(main), []
        while f is not None and len(out) < 4:
            if "fusion_gyrocal" in f.f_code.co_filename:
                out.append(f"{os.path.basename(f.f_code.co_filename)}:{f.f_code.co_name}:{f.f_lineno}")
            f = f.f_back
        return tuple(reversed(out))

    def watch():
        while not done.is_set():
            with open("/proc/self/status") as fh:
                rss = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("VmRSS:"))
            if rss > best[0]:
                best[:] = [rss, frames()]
            done.wait(interval)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()

    def stop():
        done.set()
        thread.join()
        return best[0], best[1]
    return stop


def pipeline_child(n: int, where: bool = False) -> dict:
    """One process: the reference, the pipeline, the reference again; the pipeline's peak RSS beyond the inputs
    (``where``: also the library frames at the highest RSS a watching thread read)."""
    from pathlib import Path

    from scaling import _hwm, _rss, make_inputs

    from fusion_gyrocal.pipeline.pipeline import run_pipeline

    t1, w1, t2, w2, offset = make_inputs(n)

    def reference():
        t0, c0 = time.perf_counter(), time.process_time()
        s2 = t2 + offset
        X = np.hstack([w1] + [np.interp(t1, s2, w2[:, a])[:, None] for a in range(3)])
        X.T @ X
        return time.perf_counter() - t0, time.process_time() - c0

    refs = [reference()]
    base = _rss()
    Path("/proc/self/clear_refs").write_text("5")
    stop = _rss_watch() if where else None
    t0, c0 = time.perf_counter(), time.process_time()
    run = run_pipeline(w1, w2, t_1=t1, t_2=t2)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    peak = _hwm() - base
    seen = stop() if where else None
    refs.append(reference())
    return {"n": n, "pipeline_s": wall, "pipeline_cpu_s": cpu, "reference_s": [r[0] for r in refs],
            "reference_cpu_s": [r[1] for r in refs], "peak_bytes": peak,
            "offset_err_us": 1e6 * (run.aligned.time_offset_s - offset),
            "where": None if seen is None else [(seen[0] - base) / n, list(seen[1])]}


def pipeline(ns, where: bool = False) -> None:
    import json
    import subprocess
    import sys

    print("\ntimestamped pipeline (run_pipeline with t_1, t_2) against np.interp x 3 + X.T @ X (the offset known), "
          "one process per N")
    print(f"  {'N':>10} {'pipeline s':>11} {'reference s':>16} {'ratio':>7} {'CPU s':>7} {'ref CPU s':>10} "
          f"{'CPU ratio':>9} {'peak B/sample':>14} {'offset err us':>14}")
    for n in ns:
        out = subprocess.run([sys.executable, __file__, "--child", str(int(n))] + (["--where"] if where else []),
                             capture_output=True, text=True)
        if out.returncode:
            print(f"  {int(n):10d} failed: {out.stderr.strip().splitlines()[-1] if out.stderr else out.returncode}")
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        refs, cpus = r["reference_s"], r["reference_cpu_s"]
        print(f"  {r['n']:10d} {r['pipeline_s']:11.2f} {min(refs):7.2f} ({max(refs):5.2f}) "
              f"{r['pipeline_s'] / min(refs):7.2f} {r['pipeline_cpu_s']:7.2f} {min(cpus):10.2f} "
              f"{r['pipeline_cpu_s'] / min(cpus):9.2f} {r['peak_bytes'] / r['n']:14.1f} {r['offset_err_us']:14.3f}")
        if r["where"] is not None:
            print(f"  {'':10} highest RSS a 2 ms watch read: {r['where'][0]:.1f} B/sample, in "
                  + (" > ".join(r["where"][1]) or "no library frame"))
    print("  (ratios to the faster of the two reference runs, wall and CPU time (all threads); the references' "
          "spread shows the machine's load; target <= 4.5, peak <= 60 B/sample)")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--clocks-only", action="store_true")
    parser.add_argument("--pipeline-only", action="store_true")
    parser.add_argument("--n", type=float, nargs="+", default=[1e6, 1e7])
    parser.add_argument("--where", action="store_true",
                        help="diagnostic: also where the pipeline's RSS was highest (a thread reading it every 2 ms)")
    parser.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child is not None:
        import json
        print(json.dumps(pipeline_child(args.child, args.where)))
        return
    if args.clocks_only:
        clocks(args.seed)
        return
    if args.pipeline_only:
        pipeline(args.n, args.where)
        return
    rng = np.random.default_rng(args.seed)
    run("paper's motion", args.runs, rng, duration=60.0, rms=1.0)
    run("slow motion", args.runs, rng, duration=60.0, rms=0.2)
    run("short recording", args.runs, rng, duration=10.0, rms=1.0)
    run("equal rates, slow motion", args.runs, rng, duration=60.0, rms=0.2, rates=((200.0, 200.0),))
    clocks(args.seed)
    pipeline(args.n, args.where)


if __name__ == "__main__":
    main()
