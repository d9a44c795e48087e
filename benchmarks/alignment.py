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

Run: ``python benchmarks/alignment.py [--runs 100] [--seed 1]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import minimize_scalar
from scipy.signal import correlate

from fusion_gyrocal.pipeline.alignment import _parabolic_peak, estimate_time_offset
from fusion_gyrocal.evaluate.sim import simulate_streams


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


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    run("paper's motion", args.runs, rng, duration=60.0, rms=1.0)
    run("slow motion", args.runs, rng, duration=60.0, rms=0.2)
    run("short recording", args.runs, rng, duration=10.0, rms=1.0)
    run("equal rates, slow motion", args.runs, rng, duration=60.0, rms=0.2, rates=((200.0, 200.0),))


if __name__ == "__main__":
    main()
