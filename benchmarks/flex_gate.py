"""The flex gate (pipeline/flex.py): flex removed, a rigid board's rate-dependent misfit kept.

1. Smooth flex (``sim.bend_with_rate``: the mounting bends from 0 at 2.5 rad/s to 1 deg at 5 rad/s, capped;
   200 s at 100 Hz, 1 rad/s RMS per axis, random general rotation, scales 1 +- 1 %), ``--runs`` Monte Carlo runs
   of ``calibrate_pair`` with the defaults: rotation RMSE of the same runs without flex, with flex and the gate,
   with flex and no gate, as ratios to the Cramer-Rao bound of the rigid pair; failures (error > 5x the bound or
   an exception); the fraction rejected against the fraction bent; mean z^2 (the rotation error's Mahalanobis
   distance against the reported rotation covariance: 3 = honest).
2. The same rigid runs with a rate-dependent scale error of gyro 2 (0.2 % per rad/s of |omega|): fraction rejected,
   RMSE against the runs without it.
3. Named scenarios nominal, weak_axis, slow_motion (evaluate/scenarios.py) with the defaults: RMSE / bound.
4. MIMU board (../shared/data/mimu_8imu_array, sessions 1-9, timestamps from the reader), IMU 1 vs IMUs 2, 3, 6:
   fraction of samples the gate rejects. Before this gate (commit b04bfa5) the gate proposed to remove 16.5-32.6 %
   of the samples of these 27 pairs (every moving sample: a rate cut near 0.03 rad/s, 0.0 % of the motion energy
   kept), which ``min_kept_energy`` vetoed, so 0 % was rejected with a note "model error or flex everywhere".

    python benchmarks/flex_gate.py [--runs 24] [--workers 2]
"""

from __future__ import annotations

import argparse
import re
import zlib
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.core.observability import cramer_rao_bound
from fusion_gyrocal.errors import GyroCalError
from fusion_gyrocal.evaluate.sim import (DEG, bend_with_rate, general_rotation, rotation_error, shared_data_dir,
                                         simulate_pair)
from fusion_gyrocal.lie import log

N = 20000


def _errors(cal, R):
    d = log(R @ cal.R_1_2.T)                        # R_true = Exp(dtheta) R_hat
    P = np.asarray(cal.covariance)[:3, :3]
    return rotation_error(cal.R_1_2, R), float(d @ np.linalg.solve(P, d)), cal.rejected_fraction


def run(k):
    rng = np.random.default_rng([zlib.crc32(b"flex_gate"), k])
    R = general_rotation(rng)
    s1, s2 = rng.normal(1.0, 0.01, 3), rng.normal(1.0, 0.01, 3)
    sim = simulate_pair(n=N, rms=1.0, R_1_2=R, scale_1=s1, scale_2=s2, rng=rng)
    flexed, angle = bend_with_rate(sim, rng=rng)
    w2_true = sim.omega_true_1 @ R @ sim.S_2.T
    misfit = sim.omega_2 + 0.002 * np.linalg.norm(w2_true, axis=1)[:, None] * w2_true
    out = {"bound": cramer_rao_bound(R, s1, s2, sim.noise_std, w2_true).rotation_rmse, "bent": float(np.mean(angle > 0))}
    for name, w2, kw in (("rigid", sim.omega_2, {}), ("flex gated", flexed.omega_2, {}),
                         ("flex kept", flexed.omega_2, {"flex_rejection": False}), ("scale misfit", misfit, {})):
        try:
            out[name] = _errors(calibrate_pair(sim.omega_1, w2, **kw), R)
        except GyroCalError as exc:
            out[name] = (np.nan, np.nan, np.nan, type(exc).__name__)
    return out


def scenario_run(args):
    from fusion_gyrocal.evaluate.scenarios import make_scenario, scenario_bound

    name, k = args
    sc = make_scenario(name, rng=[zlib.crc32(name.encode()), k])
    cal = calibrate_pair(sc.data.omega_1, sc.data.omega_2)
    return rotation_error(cal.R_1_2, sc.data.R_1_2), scenario_bound(sc).rotation, cal.rejected_fraction


def simulated(runs, workers):
    with ProcessPoolExecutor(workers) as pool:
        res = list(pool.map(run, range(runs)))
    bound = np.sqrt(np.mean([r["bound"] ** 2 for r in res]))
    print(f"1-2. {runs} runs, {N} samples at 100 Hz, 1 rad/s RMS per axis, defaults; bound (rigid) "
          f"{bound / DEG * 1e3:.3f} mdeg; bent samples {100 * np.mean([r['bent'] for r in res]):.1f}% on average")
    print(f"{'case':>14} {'RMSE mdeg':>10} {'/bound':>7} {'/rigid':>7} {'fail':>5} {'mean z^2':>9} {'rejected %':>16}")
    rigid = None
    for name in ("rigid", "flex gated", "flex kept", "scale misfit"):
        e = np.array([r[name][:3] for r in res], dtype=float)
        b = np.array([r["bound"] for r in res])
        ok = np.isfinite(e[:, 0])
        rmse = np.sqrt(np.mean(e[ok, 0] ** 2))
        rigid = rmse if rigid is None else rigid
        fail = int((~ok).sum() + np.sum(e[ok, 0] > 5 * b[ok]))
        rej = e[ok, 2]
        print(f"{name:>14} {rmse / DEG * 1e3:10.3f} {rmse / bound:7.2f} {rmse / rigid:7.2f} {fail:>5} "
              f"{np.mean(e[ok, 1]):9.2f} {100 * rej.mean():7.2f} (max {100 * rej.max():5.2f})")


def scenarios(runs, workers):
    print(f"\n3. named scenarios with the defaults, {runs} runs each: rotation RMSE / Cramer-Rao bound")
    with ProcessPoolExecutor(workers) as pool:
        for name in ("nominal", "weak_axis", "slow_motion"):
            r = np.array(list(pool.map(scenario_run, [(name, k) for k in range(runs)])))
            print(f"{name:>12} RMSE/bound {np.sqrt(np.mean(r[:, 0] ** 2)) / np.sqrt(np.mean(r[:, 1] ** 2)):.3f}, "
                  f"rejected {100 * r[:, 2].mean():.2f}% (max {100 * r[:, 2].max():.2f}%)")


def mimu():
    d = shared_data_dir() / "mimu_8imu_array" / "npz"
    if not d.exists():
        print("\n4. MIMU: ../shared/data not present, skipped")
        return
    from fusion_gyrocal.io import read_npz

    print("\n4. MIMU board, IMU 1 vs IMU k, timestamps from the reader: fraction rejected by the gate "
          "(before this gate: 0 % rejected after the energy veto of a proposed 16.5-32.6 %)")
    print(f"{'sess':>4} {'IMU 2':>7} {'IMU 3':>7} {'IMU 6':>7}   share of the excess along the rate (flex < 15 %)")
    fr = []
    for e in range(1, 10):
        s = read_npz(d / f"exp_{e}.npz")
        row, shares = [], []
        for k in (1, 2, 5):
            cal = calibrate_pair(s[0].omega, s[k].omega, t_1=s[0].t, t_2=s[k].t)
            row.append(cal.rejected_fraction)
            share = [m.group(1) for n in cal.notes for m in [re.search(r"(\d+)% of its excess along the rate", n)] if m]
            shares.append(f"{share[0]:>3}%" if share else "   -")
        fr += row
        print(f"{e:>4} " + " ".join(f"{100 * x:6.2f}%" for x in row) + "   " + " ".join(shares))
    print(f"rejected over the 27 pairs: mean {100 * np.mean(fr):.2f}%, max {100 * np.max(fr):.2f}%")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=24)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    simulated(a.runs, a.workers)
    scenarios(a.runs, a.workers)
    mimu()


if __name__ == "__main__":
    main()
