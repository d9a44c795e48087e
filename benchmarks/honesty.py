"""Does the covariance we report cover the error we make? With the defaults: no noise given.

1. Monte Carlo (``--runs`` each, 100 Hz, the paper's noise 0.1 deg/s per gyro unless said otherwise),
   ``calibrate_pair(omega_1, omega_2)`` with nothing but the rates:
     nominal        the paper's protocol, 60 s, 0.5 rad/s RMS per axis
     weak_axis      x rates 10x smaller, y/z amplified at the same total SNR
     slow_motion    0.02 rad/s RMS: gyro 2's noise in the regressor matters
     coloured       AR(1) noise, rho 0.9 at the output rate, the same per-sample variance (a digital low-pass)
     drifting_bias  10 min, bias random walk 100x the paper's (ratio to the CONSTANT-bias bound)
     rate_scale     gyro 2's scale error grows with the rate: 0.2 % per rad/s of |omega|
     flex_smooth    the mounting bends with the rate above 2.5 rad/s, up to 1 deg at 5 rad/s (200 s, 1 rad/s RMS;
                    benchmarks/flex_gate.py compares it with the same runs without flex)
     impacts        heavy-tailed noise: each gyro on its own has bursts of 10 samples at 10x its noise std
                    starting at 0.5 % of the samples (shocks, vibration a chip rectifies); the bound is the white
                    noise's without the bursts
     jitter         gyro 2 sampled late by a random delay per sample, uniform in [0, 2] ms (a chip's sampling
                    instant wandering against the read-out: a residual of the rate's derivative times the delay,
                    largest where the motion turns fast), 1 rad/s RMS
     beat           gyro 2 sampled late by a sawtooth of 8 ms at 1.7 Hz (a chip's clock beating against the
                    read-out, the MIMU board's timing: the timing model fits the tone as one sawtooth; fitted by
                    three harmonics, the sawtooth's jumps stayed in the residual as a heavy tail), 1 rad/s RMS
   ``--robust-weights auto`` runs every case with the per-sample weights (``robust_weights``, off by default) to
   see whether the covariance still covers the error with them.
   Printed: rotation and scale RMSE / Cramer-Rao bound of the white-noise model (for coloured noise, of
   white noise with the same per-sample variance), the mean z^2 of the rotation error against the
   reported rotation covariance (3 = honest; [0.75, 6] accepted), failed runs, the covariance basis.
2. MIMU board (../shared/data/mimu_8imu_array, nine sessions of one rigid PCB): IMU 1 against IMU 2..8,
   the session-to-session rotation differences against the reported covariances: mean z^2 over the 36
   session pairs (3 = honest), the per-axis spread against the reported 1-sigma, the identified white
   noise against each IMU's first 20 s at rest; then the same for the joint calibration of all 8 IMUs.

    python benchmarks/honesty.py [--runs 50] [--workers 2] [--cases nominal,coloured] [--no-mimu]
                                 [--robust-weights auto|off]
"""

from __future__ import annotations

import argparse
import itertools
import zlib
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from scipy.signal import lfilter

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.core.observability import cramer_rao_bound
from fusion_gyrocal.errors import GyroCalError
from fusion_gyrocal.evaluate.sim import (DEG, PAPER_BIAS_WALK_STD, PAPER_NOISE_STD, PAPER_RATE_HZ, HumanMotion,
                                         general_rotation, rotation_error, scale_error, shared_data_dir, simulate_pair)
from fusion_gyrocal.lie import log

CASES = ("nominal", "weak_axis", "slow_motion", "coloured", "drifting_bias", "rate_scale", "flex_smooth", "impacts",
         "jitter", "beat")
JITTER_S = 2e-3   # the jitter case: gyro 2's sampling delay is uniform in [0, JITTER_S]
BEAT_S, BEAT_HZ = 8e-3, 1.7   # the beat case: gyro 2's sampling delay a sawtooth of BEAT_S at BEAT_HZ
BURST, BURST_GAIN, BURST_RATE = 1, 8.0, 0.01  # the impacts case: samples per burst, noise gain, starts per sample
RHO = 0.9


def _bursts(n: int, noise: float, rng) -> np.ndarray:
    """(n, 3) extra noise of one gyro: bursts of :data:`BURST` samples at :data:`BURST_GAIN` times ``noise`` (the
    burst's variance beyond the white noise's) starting at a :data:`BURST_RATE` share of the samples."""
    on = np.zeros(n, bool)
    for a in np.flatnonzero(rng.random(n) < BURST_RATE):
        on[a:a + BURST] = True
    return np.where(on[:, None], rng.normal(0.0, noise * np.sqrt(BURST_GAIN ** 2 - 1.0), (n, 3)), 0.0)


def case(name: str, k: int, keywords=None) -> dict:
    rng = np.random.default_rng([zlib.crc32(name.encode()), k])
    R = general_rotation(rng)
    s1, s2 = rng.normal(1.0, 0.01, 3), rng.normal(1.0, 0.01, 3)
    n, rms, walk, noise = 6000, 0.5, PAPER_BIAS_WALK_STD, PAPER_NOISE_STD
    if name == "weak_axis":
        rms = np.array([0.1, np.sqrt(2.99 / 2), np.sqrt(2.99 / 2)]) * 0.5
    elif name == "slow_motion":
        rms = 0.02
    elif name == "drifting_bias":
        n, walk = 60000, 100 * PAPER_BIAS_WALK_STD
    elif name == "flex_smooth":
        n, rms = 20000, 1.0
    elif name in ("jitter", "beat"):
        rms = 1.0
    motion, t = HumanMotion(rms, rng=rng), np.arange(n) / PAPER_RATE_HZ
    sim = simulate_pair(motion(t), R_1_2=R, scale_1=s1, scale_2=s2, bias_walk_std=walk,
                        noise_std=1e-12 if name == "coloured" else noise, rng=rng)
    w1, w2 = sim.omega_1, sim.omega_2
    w2_true = sim.omega_true_1 @ R                       # gyro 2's true rate (its own frame)
    if name == "coloured":
        w1, w2 = (w + lfilter([np.sqrt(1 - RHO**2) * noise], [1.0, -RHO], rng.standard_normal((n, 3)), axis=0)
                  for w in (w1, w2))
    elif name == "rate_scale":
        w2 = w2 + (0.002 * np.linalg.norm(w2_true, axis=1)[:, None] * w2_true) * s2
    elif name == "flex_smooth":
        from fusion_gyrocal.evaluate.sim import bend_with_rate
        w2 = bend_with_rate(sim, rng=rng)[0].omega_2
    elif name == "jitter":   # gyro 2's true rate at its late instants instead of the nominal ones
        w2 = w2 + (motion(t + rng.uniform(0.0, JITTER_S, n)) - sim.omega_true_1) @ R * s2
    elif name == "beat":     # ... at instants late by a sawtooth: its clock beating against the read-out
        w2 = w2 + (motion(t + BEAT_S * ((BEAT_HZ * t + rng.random()) % 1.0)) - sim.omega_true_1) @ R * s2
    elif name == "impacts":
        w1, w2 = w1 + _bursts(n, noise, rng), w2 + _bursts(n, noise, rng)
    bound = cramer_rao_bound(R, s1, s2, (noise, noise), w2_true * s2)
    out = {"bound": (bound.rotation_rmse, bound.scale_rmse), "fail": None}
    try:
        cal = calibrate_pair(w1, w2, **(keywords or {}))
    except GyroCalError as exc:
        out["fail"] = f"{type(exc).__name__}: {exc}"[:120]
        return out
    d = log(cal.R_1_2 @ R.T)
    P = cal.covariance[:3, :3]
    out.update(rot=rotation_error(cal.R_1_2, R), scale=scale_error(cal.scale_1, cal.scale_2, s1, s2),
               z2=float(d @ np.linalg.solve(P, d)), basis=cal.covariance_basis.split(" (")[0],
               inflation=cal.robust_inflation, kind=cal.noise_model.kind if cal.noise_model else cal.noise_source,
               rejected=cal.rejected_fraction, weighted=any(n.startswith("robust weights") for n in cal.notes))
    return out


def _run(args):
    return case(*args)


def simulations(runs: int, workers: int, names, keywords=None) -> None:
    print(f"1. {runs} Monte Carlo runs per case, calibrate_pair(omega_1, omega_2) with "
          f"{keywords or 'the defaults'}; RMSE / Cramer-Rao bound; z^2 = rotation error against the reported "
          "covariance (3 = honest); weighted = runs the per-sample weights were kept in")
    print(f"{'case':>14} {'rot/bound':>10} {'scale/bound':>12} {'mean z2':>8} {'median z2':>10} {'failed':>7} "
          f"{'rejected':>9} {'robust used':>12} {'weighted':>9} {'noise identified as (most runs)':>40}")
    with ProcessPoolExecutor(workers) as pool:
        for name in names:
            res = list(pool.map(_run, [(name, k, keywords) for k in range(runs)], chunksize=2))
            ok = [r for r in res if r["fail"] is None]
            if not ok:
                print(f"{name:>14} every run failed: {res[0]['fail']}")
                continue
            br = np.sqrt(np.mean([r["bound"][0] ** 2 for r in ok]))
            bs = np.sqrt(np.mean([r["bound"][1] ** 2 for r in ok]))
            er = np.sqrt(np.mean([r["rot"] ** 2 for r in ok]))
            es = np.sqrt(np.mean([r["scale"] ** 2 for r in ok]))
            z2 = np.array([r["z2"] for r in ok])
            robust = sum(r["basis"].startswith("noise model raised") for r in ok)
            kinds = [r["kind"] for r in ok]
            kind = max(set(kinds), key=kinds.count)
            rej = np.mean([r["rejected"] for r in ok])
            print(f"{name:>14} {er / br:10.3f} {es / bs:12.3f} {z2.mean():8.2f} {np.median(z2):10.2f} "
                  f"{len(res) - len(ok):7d} {100 * rej:8.1f}% {robust:>7d}/{len(ok):<4d} "
                  f"{sum(r['weighted'] for r in ok):>5d}/{len(ok):<3d} {kind:>40}")
            for r in res:
                if r["fail"] is not None:
                    print(f"{'':>14} failed: {r['fail']}")
                    break


def mimu() -> None:
    d = shared_data_dir() / "mimu_8imu_array" / "npz"
    if not d.exists():
        print("\n2. MIMU: ../shared/data not present, skipped")
        return
    from fusion_gyrocal.io import read_npz

    sessions = [read_npz(d / f"exp_{e}.npz") for e in range(1, 10)]
    rest = slice(0, int(20 * 62.5))
    print("\n2. MIMU board, 9 sessions of one PCB, IMU 1 vs IMU k, defaults with timestamps: session-to-session "
          "rotation differences against the reported covariances")
    print(f"{'k':>2} {'mean z2':>8} {'max z2':>7} {'spread mdeg':>12} {'sigma mdeg':>11} {'sigma/spread':>13} "
          f"{'lack of fit':>12} {'inflation':>10} {'noise 1 / rest':>15} {'noise k / rest':>15} {'kind':>40}")
    all_z2 = []
    for k in range(1, 8):
        cals, ratios = [], []
        for s in sessions:
            cal = calibrate_pair(s[0].omega, s[k].omega, t_1=s[0].t, t_2=s[k].t)
            cals.append(cal)
            at_rest = [float(np.mean(g.omega[rest].std(axis=0, ddof=1))) for g in (s[0], s[k])]
            ratios.append([cal.noise_std[0] / at_rest[0], cal.noise_std[1] / at_rest[1]])
        # the board's cross-axis terms are the same in every session: a difference cancels the skew budget
        rep = [c.repeatable_rotation_covariance for c in cals]
        z2, d2 = [], []
        for (a, Pa), (b, Pb) in itertools.combinations(zip(cals, rep), 2):
            diff = log(a.R_1_2 @ b.R_1_2.T)
            z2.append(float(diff @ np.linalg.solve(Pa + Pb, diff)))
            d2.append(float(diff @ diff))
        spread = np.sqrt(np.mean(d2) / 6.0)              # per-axis std of one session
        sigma = np.mean([np.sqrt(np.trace(P) / 3.0) for P in rep])
        r = np.array(ratios)
        kinds = [c.noise_model.kind if c.noise_model else c.noise_source for c in cals]
        all_z2 += z2
        print(f"{k + 1:>2} {np.mean(z2):8.2f} {np.max(z2):7.1f} {spread / DEG * 1e3:12.1f} {sigma / DEG * 1e3:11.1f} "
              f"{sigma / spread:13.2f} {np.mean([c.lack_of_fit for c in cals]):12.3g} "
              f"{np.mean([c.robust_inflation for c in cals]):10.3g} {r[:, 0].mean():15.2f} {r[:, 1].mean():15.2f} "
              f"{max(set(kinds), key=kinds.count):>40}")
    print(f"all 7 IMUs x 36 session pairs: mean z2 {np.mean(all_z2):.2f} (3 = honest)")
    from fusion_gyrocal.core.array import calibrate_array

    arrays = [calibrate_array([g.omega for g in s], mask=np.all([g.valid for g in s], axis=0), rate_hz=62.5)
              for s in sessions]
    z2_k = []
    for k in range(1, 8):
        z2 = []
        for a, b in itertools.combinations(arrays, 2):
            pa, pb = a.pair(0, k), b.pair(0, k)
            diff = log(pa.R_1_2 @ pb.R_1_2.T)
            rep = [p.repeatable_rotation_covariance for p in (pa, pb)]   # the board's constant
            z2.append(float(diff @ np.linalg.solve(rep[0] + rep[1], diff)))                 # skew cancels
        z2_k.append(np.mean(z2))
    print(f"calibrate_array, all 8 IMUs jointly (defaults): mean z2 per IMU {', '.join(f'{z:.2f}' for z in z2_k)}; "
          f"all {np.mean(z2_k):.2f}; identified white noise {', '.join(f'{v / DEG:.3f}' for v in arrays[0].noise_std)} "
          "deg/s (session 1)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--no-mimu", action="store_true")
    ap.add_argument("--robust-weights", default=None, help="the robust_weights option (default: the library's)")
    a = ap.parse_args(argv)
    names = [c for c in a.cases.split(",") if c]
    unknown = sorted(set(names) - set(CASES))
    if unknown:
        ap.error(f"unknown case(s) {unknown}; expected some of {', '.join(CASES)}")
    simulations(a.runs, a.workers, names, None if a.robust_weights is None else {"robust_weights": a.robust_weights})
    if not a.no_mimu:
        mimu()


if __name__ == "__main__":
    main()
