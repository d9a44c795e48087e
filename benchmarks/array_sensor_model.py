"""Repeatability of the joint N-gyro calibration on one rigid board, and its honesty with cross-axis terms (issue 20).

1. MIMU board (``../shared/data/mimu_8imu_array``, nine sessions of one soldered PCB): ``calibrate_array`` of all 8
   IMUs per session (sample-aligned: one microcontroller samples every IMU, the read-out's timestamps as ``t``), with
   ``linear_map`` "rigid" (the paper's model) and the defaults (the full linear map per gyro where the data call for
   it), each with ``timing_model`` "off" and "auto" (the default: one delay per chip from all pairs' residuals at a
   first estimate, the beat tone of each chip's sampling clock, compensated and the array solved on the moved
   samples), timed in the same run (the ratio auto / off is printed per linear map). For the 14 pairs of
   ``benchmarks/sensor_model.py`` the pair views (:meth:`ArrayCalibration.pair`) give per pair the RMS
   session-to-session rotation difference and the mean ``z^2`` of the differences against the two sessions'
   repeatable rotation covariances (without ``skew_rotation_covariance``, which the board's constant cross-axis
   terms make the same in every session: 3 dof, 3 is honest). Also: how far the views of pairs without the
   reference move from ``R_ref_i^T R_ref_j`` into the pair's convention, and how far they are from the pair solver
   on the same moments (:func:`fusion_gyrocal.solve`, its own noise and windows; with the timing model the moments
   are those of the moved samples), and per gyro the delays found (tones, std of the delay, residual explained).
   Then the leave-one-session-out check and the site check of ``benchmarks/sensor_model.py`` on the pair views.
2. Simulated arrays: N gyros (general rotations, or an axis-parallel board), every gyro with scale errors of 1 % and
   cross-axis terms of 0.5-2 % (each off-diagonal entry of ``I + C_k`` a random sign times U(0.5, 2) %), white noise,
   sample-aligned, the defaults: the mean ``z^2`` of every ``R_ref_k``'s error against the physical rotation and the
   reported covariance (which carries the cross-axis budget).

    python benchmarks/array_sensor_model.py [--runs 20] [--linear-map rigid auto] [--timing-model off auto]
                                            [--robust-weights auto|off]
                                            [--no-mimu] [--no-sim]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from fusion_gyrocal import solve
from fusion_gyrocal.core.array import calibrate_array
from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, PAPER_RATE_HZ, HumanMotion, general_rotation, shared_data_dir
from fusion_gyrocal.lie import log
from sensor_model import PAIRS, consistency, session_pairs, site_check

DEG = np.pi / 180.0
MDEG = DEG * 1e-3
FLIP = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def mimu(linear_maps, timing_models, keywords: dict) -> None:
    d = shared_data_dir() / "mimu_8imu_array" / "npz"
    if not d.exists():
        print("1. MIMU: ../shared/data not present, skipped")
        return
    from fusion_gyrocal.io import read_npz

    sessions = [read_npz(d / f"exp_{e}.npz") for e in range(1, 10)]
    print("1. MIMU board, 9 sessions, calibrate_array of all 8 IMUs (sample-aligned, the read-out's timestamps), "
          f"pair views of 14 pairs; options {keywords or 'defaults'}")
    seconds, cpu, results = {}, {}, {}
    for lm in linear_maps:        # the timing models interleaved session by session: the same load for each
        for s in sessions:
            for tm in timing_models:
                t0, c0 = time.perf_counter(), time.process_time()
                results.setdefault((lm, tm), []).append(
                    calibrate_array([g.omega for g in s], mask=np.all([g.valid for g in s], axis=0), t=s[0].t,
                                    linear_map=lm, timing_model=tm, **keywords))
                seconds[lm, tm] = seconds.get((lm, tm), 0.0) + time.perf_counter() - t0
                cpu[lm, tm] = cpu.get((lm, tm), 0.0) + time.process_time() - c0
    for lm, tm in ((lm, tm) for lm in linear_maps for tm in timing_models):
        arrays, dt = results[lm, tm], seconds[lm, tm]
        maps = [m for a in arrays for m in a.linear_map if m]
        print(f"\nlinear_map={lm!r}, timing_model={tm!r}: {dt:.1f} s for 9 joint calibrations; gyros with the full "
              f"map {maps.count('full')}/{len(maps)}; largest |K| "
              f"{100 * max(np.abs(a.cross_axis_terms).max() for a in arrays):.2f} %")
        timing_table(arrays)
        print(f"{'pair':>5} {'rms diff mdeg':>14} {'sigma mdeg':>11} {'mean z2':>8} {'max z2':>7} "
              f"{'shift mdeg':>11} {'vs solve mdeg':>14} {'solve sigma':>12}")
        rms_all, z2_all, shifts, gaps, per_pair = [], [], [], [], []
        for i, j in PAIRS:
            views = [a.pair(i - 1, j - 1) for a in arrays]
            per_pair.append(views)
            rms, z2 = session_pairs(views)
            sigma = np.mean([np.sqrt(np.trace(v.repeatable_rotation_covariance) / 3.0) for v in views])
            shift = [np.linalg.norm(log(v.R_1_2 @ (a.R_ref_k[j - 1].T @ a.R_ref_k[i - 1]))) for v, a in
                     zip(views, arrays)]
            pairs = [solve(a.moments.pair(i - 1, j - 1), linear_map=lm) for a in arrays]
            gap = [np.linalg.norm(log(v.R_1_2 @ p.R_1_2.T)) for v, p in zip(views, pairs)]
            psig = np.mean([np.sqrt(np.trace(p.repeatable_rotation_covariance) / 3.0) for p in pairs])
            rms_all.append(rms)
            z2_all.append(z2)
            shifts += shift
            gaps += gap
            print(f"{i}-{j:<3} {rms / MDEG:14.1f} {sigma / MDEG:11.1f} {z2.mean():8.2f} {z2.max():7.1f} "
                  f"{np.mean(shift) / MDEG:11.2f} {np.sqrt(np.mean(np.square(gap))) / MDEG:14.1f} {psig / MDEG:12.1f}")
            sys.stdout.flush()
        rms_all = np.array(rms_all)
        print(f"all {len(PAIRS)} pairs: RMS session-to-session rotation difference "
              f"{np.sqrt(np.mean(rms_all ** 2)) / MDEG:.1f} mdeg ({rms_all.min() / MDEG:.0f}-{rms_all.max() / MDEG:.0f} "
              f"per pair); mean z2 {np.concatenate(z2_all).mean():.2f} (3 dof); the pair convention's shift of the "
              f"views without the reference: mean {np.mean(shifts) / MDEG:.2f}, largest {np.max(shifts) / MDEG:.2f} "
              f"mdeg; view vs the pair solver on the same moments: RMS {np.sqrt(np.mean(np.square(gaps))) / MDEG:.1f} "
              "mdeg")
        consistency(per_pair, PAIRS, arrays)
        site_check(per_pair, PAIRS, lambda k, l: [a.pair(k - 1, l - 1) for a in arrays], d.parent)
    for lm in linear_maps:
        if (lm, "off") in seconds and (lm, "auto") in seconds:
            print(f"\nlinear_map={lm!r}: timing_model 'auto' took {seconds[lm, 'auto']:.1f} s, 'off' "
                  f"{seconds[lm, 'off']:.1f} s for the 9 sessions in this run (interleaved): ratio "
                  f"{seconds[lm, 'auto'] / seconds[lm, 'off']:.2f}; process CPU time {cpu[lm, 'auto']:.1f} vs "
                  f"{cpu[lm, 'off']:.1f} s: ratio {cpu[lm, 'auto'] / cpu[lm, 'off']:.2f}")


def timing_table(arrays) -> None:
    """Per gyro over the sessions: how often a delay was found, its tones, the std and mean of the delay, the
    residual energy it explained."""
    n = arrays[0].n_gyros
    found = [[a for a in arrays if a.timing_explained[g] > 0] for g in range(n)]
    if not any(found):
        print("timing: no delay found in any session")
        return
    print(f"{'gyro':>5} {'sessions':>9} {'tones Hz (first session)':>26} {'delay std ms':>13} {'mean ms':>8} "
          f"{'explained':>10}")
    for g in range(n):
        if g == arrays[0].reference:
            continue
        f = found[g]
        tones = ", ".join(f"{x:.4g}" for x in f[0].timing_tones_hz[g]) if f else ""
        std = np.mean([a.timing_delay_std_s[g] for a in f]) * 1e3 if f else 0.0
        mean = np.mean([a.timing_delay_s[g] for a in f]) * 1e3 if f else 0.0
        expl = np.mean([a.timing_explained[g] for a in f]) if f else 0.0
        print(f"{g + 1:>5} {len(f):>5d}/{len(arrays):<3d} {tones:>26} {std:13.3f} {mean:8.4f} {100 * expl:9.0f}%")


def simulated_array(k: int, n: int, configuration: str) -> dict:
    """One array of ``n`` gyros, each with scale errors and 0.5-2 % cross-axis terms: the rotation errors of every
    ``R_ref_k`` against the physical rotation, their ``z^2`` against the reported covariance."""
    rng = np.random.default_rng([20, 4, k, n, len(configuration)])
    if configuration == "general":
        R = [np.eye(3)] + [general_rotation(rng) for _ in range(n - 1)]
    else:   # a board of top- and bottom-side chips, each a few tenths of a degree off
        from fusion_gyrocal.lie import exp

        R = [np.eye(3)] + [exp(rng.normal(0, 0.3 * DEG, 3)) @ (FLIP if g % 2 else np.eye(3)) for g in range(1, n)]
    t = np.arange(20000) / PAPER_RATE_HZ
    omega = HumanMotion(0.5, rng=rng)(t)
    rates = []
    for g in range(n):
        C = rng.choice([-1.0, 1.0], (3, 3)) * rng.uniform(0.005, 0.02, (3, 3))
        np.fill_diagonal(C, 0.0)
        M = rng.normal(1.0, 0.01, 3)[:, None] * (np.eye(3) + C)
        rates.append((omega @ R[g]) @ M.T + rng.normal(0, 0.005, 3) + rng.normal(0, PAPER_NOISE_STD, omega.shape))
    cal = calibrate_array(rates, rate_hz=PAPER_RATE_HZ)
    err, z2 = [], []
    for g in range(1, n):
        d = log(cal.R_ref_k[g] @ R[g].T)
        err.append(float(np.linalg.norm(d)))
        z2.append(float(d @ np.linalg.solve(cal.covariance[3 * g:3 * g + 3, 3 * g:3 * g + 3], d)))
    sigma = np.sqrt(np.trace(cal.covariance[:3 * n, :3 * n]) / (3 * (n - 1)))
    return {"err": err, "z2": z2, "sigma": float(sigma), "full": sum(m == "full" for m in cal.linear_map)}


def simulations(runs: int) -> None:
    print(f"\n2. Simulated arrays, every gyro with 0.5-2 % cross-axis terms and 1 % scale errors, defaults, {runs} runs "
          "per case: R_ref_k against the physical rotation")
    print(f"{'case':>28} {'rms err mdeg':>13} {'sigma mdeg':>11} {'mean z2':>8} {'median z2':>10} {'full map':>9}")
    for n, configuration in ((3, "general"), (4, "general"), (4, "axis-parallel board"), (8, "axis-parallel board")):
        res = [simulated_array(k, n, configuration) for k in range(runs)]
        err = np.concatenate([r["err"] for r in res])
        z2 = np.concatenate([r["z2"] for r in res])
        print(f"{f'{n} gyros, {configuration}':>28} {np.sqrt(np.mean(err ** 2)) / MDEG:13.1f} "
              f"{np.mean([r['sigma'] for r in res]) / MDEG:11.1f} {z2.mean():8.2f} {np.median(z2):10.2f} "
              f"{sum(r['full'] for r in res):>5d}/{runs * (n - 1)}")
        sys.stdout.flush()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20, help="simulated arrays per case")
    ap.add_argument("--linear-map", nargs="+", default=["rigid", "auto"], help="linear_map values for the MIMU part")
    ap.add_argument("--timing-model", nargs="+", default=["off", "auto"], help="timing_model values for the MIMU part")
    ap.add_argument("--robust-weights", default=None, help="the robust_weights option (default: the library's)")
    ap.add_argument("--no-mimu", action="store_true")
    ap.add_argument("--no-sim", action="store_true")
    a = ap.parse_args(argv)
    if not a.no_mimu:
        mimu(a.linear_map, a.timing_model, {} if a.robust_weights is None else {"robust_weights": a.robust_weights})
    if not a.no_sim:
        simulations(a.runs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
