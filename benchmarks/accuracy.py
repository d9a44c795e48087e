"""Monte Carlo accuracy of calibrate_pair against the Cramer-Rao bound, SNR scaled 0.5/1/2/4.

The paper's protocol (100 Hz, noise 0.1 deg/s per gyro, bias random walk 57.3 micro-deg/s per
step, 60 s of human-like motion); the SNR is scaled through the rate norm. For each SNR and
estimator: RMSE of the rotation error ||Log(R_hat R^T)|| (Eq. 37) and of the scale error (Eq. 38),
and their ratio to the bound (inverse Fisher information at the truth, bias profiled out).

    python benchmarks/accuracy.py [--runs 100]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.core.observability import cramer_rao_bound
from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, general_rotation, rotation_error, scale_error, simulate_pair


def run(runs: int, snr_factors=(0.5, 1.0, 2.0, 4.0), n=6000, rms=0.5, seed=0):
    rows = []
    for f in snr_factors:
        err = {m: ([], []) for m in ("direct", "ml")}
        bound_r, bound_s, snr, times = [], [], [], {m: 0.0 for m in err}
        for k in range(runs):
            rng = np.random.default_rng([seed, k, int(f * 100)])
            R = general_rotation(rng)
            s1, s2 = rng.normal(1.0, 0.01, 3), rng.normal(1.0, 0.01, 3)
            sim = simulate_pair(n=n, rms=rms * f, R_1_2=R, scale_1=s1, scale_2=s2, rng=rng)
            b = cramer_rao_bound(R, s1, s2, sim.noise_std, (sim.omega_true_1 @ R) @ sim.S_2.T)
            bound_r.append(b.rotation_rmse**2)
            bound_s.append(b.scale_rmse**2)
            for m in err:
                t0 = time.perf_counter()
                cal = calibrate_pair(sim.omega_1, sim.omega_2, method=m, noise_std=PAPER_NOISE_STD)
                times[m] += time.perf_counter() - t0
                err[m][0].append(rotation_error(cal.R_1_2, R) ** 2)
                err[m][1].append(scale_error(cal.scale_1, cal.scale_2, s1, s2) ** 2)
            snr.append(np.sqrt((cal.snr**2).sum()))
        br, bs = np.sqrt(np.mean(bound_r)), np.sqrt(np.mean(bound_s))
        for m, (er, es) in err.items():
            rr, rs = np.sqrt(np.mean(er)), np.sqrt(np.mean(es))
            rows.append((f, np.mean(snr), m, rr, br, rr / br, rs, bs, rs / bs, 1e3 * times[m] / runs))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=100)
    args = ap.parse_args(argv)
    rows = run(args.runs)
    print(f"Monte Carlo runs per row: {args.runs}; noise {np.rad2deg(PAPER_NOISE_STD):.2f} deg/s per gyro, 100 Hz, 60 s")
    hdr = (f"{'SNRx':>5} {'SNR':>9} {'method':>7} {'rot RMSE mdeg':>14} {'bound':>9} {'ratio':>6} "
           f"{'scale RMSE %':>13} {'bound':>9} {'ratio':>6} {'ms/solve':>9}")
    print(hdr)
    for f, snr, m, rr, br, qr, rs, bs, qs, ms in rows:
        print(f"{f:5.1f} {snr:9.0f} {m:>7} {np.rad2deg(rr) * 1e3:14.3f} {np.rad2deg(br) * 1e3:9.3f} {qr:6.3f} "
              f"{rs * 100:13.5f} {bs * 100:9.5f} {qs:6.3f} {ms:9.2f}")
    for m in ("direct", "ml"):
        sel = [r for r in rows if r[2] == m]
        x = np.log([r[1] for r in sel])
        print(f"log-log slope vs SNR ({m}): rotation {np.polyfit(x, np.log([r[3] for r in sel]), 1)[0]:.3f}, "
              f"scales {np.polyfit(x, np.log([r[6] for r in sel]), 1)[0]:.3f}")


if __name__ == "__main__":
    main()
