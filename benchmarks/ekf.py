"""EKF drift tracker against the closed-form batch estimate on the same data, and its throughput.

1. Accuracy (constant parameters, the paper's noise, human-like motion at 100 Hz, general
   configurations): the tracker is seeded by ``calibrate_pair`` on the first 10 s and tracks the
   rest with ``DriftNoise.constant()``; its final estimate is compared with the closed-form batch
   estimate (``method="direct"``) and the default ML batch estimate over ALL the data. Printed:
   RMSE of the rotation (Eq. 37) and scale (Eq. 38) errors and the ratios EKF / batch, per mode.
2. Throughput: samples per second of ``run`` in each mode (per-sample, fast with several block
   sizes; a block of one sample takes the per-sample path) on one core: BLAS/OpenMP pinned to one thread, timed by this process's CPU time (robust
   to other load on the machine) and by the wall clock (best of 3).
3. Drift: a 0.5 % scale ramp over 10 minutes with a 0.5 deg rotation step half way; fraction of
   estimate components inside the 2-sigma bands, step detection delay, mean NEES.
4. Real board (``../shared/data/mimu_8imu_array``, skipped when absent): IMU 1 against IMUs 2, 3 and 6
   of one rigid PCB, sessions 1-9 (62.5 Hz, 20 static poses then ~100 s of violent rotation; clipped
   samples dropped). The tracker is seeded on the first 120 s (``from_samples``: identified noise) and
   tracks the rest in the fast mode (1 s blocks; measurement noise adapted per rate bin, ``online/adapt.py``).
   Printed per session: step alarms (every one false on a rigid board), accepted re-seeds,
   the final rotation minus the batch ``calibrate_pair`` over the whole session with its timestamps (mdeg), the tracker's
   reported rotation sigma (sqrt of the trace of its rotation covariance), the batch's, and
   ``z = |diff| / sqrt(sigma_ekf^2 + sigma_batch^2)``; "open" marks an alarm still open at the end (the
   covariance then carries the step prior: a small z there says nothing; the z of the state at the alarm,
   which a rejected alarm returns to, is printed below the table). Then the honesty of the final
   covariances on one soldered PCB: the session-to-session rotation differences of each IMU (36 pairs)
   against the reported covariances, mean ``z^2 = d^T (P_a + P_b)^-1 d`` (3 = honest), for the tracker and
   the batch (``benchmarks/honesty.py`` section 2 measures the batch the same way).

    python benchmarks/ekf.py [--runs 40] [--sample-runs 8] [--mimu-only]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")       # one core (set before numpy is imported)

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from fusion_gyrocal import calibrate_pair  # noqa: E402
from fusion_gyrocal.evaluate.sim import simulate_drifting_pair  # noqa: E402
from fusion_gyrocal.online.tracker import DriftNoise, GyroPairTracker  # noqa: E402
from fusion_gyrocal.evaluate.sim import DEG, PAPER_NOISE_STD, general_rotation, rotation_error, scale_error  # noqa: E402

RATE = 100.0


def pair(rng, duration_s, R=None, s2_ramp=0.0, step=None):
    t = np.arange(0.0, duration_s, 1.0 / RATE)
    R0 = general_rotation(rng, 15.0) if R is None else R
    s1, s2 = 1 + rng.normal(0, 0.01, 3), 1 + rng.normal(0, 0.01, 3)
    S2 = np.tile(s2, (t.size, 1))
    S2[:, 1] *= 1 + s2_ramp * t / t[-1]
    Rt = np.tile(R0, (t.size, 1, 1))
    if step is not None:
        Rt[t >= step[0]] = Rotation.from_rotvec(step[1]).as_matrix() @ R0
    w1, w2, truth = simulate_drifting_pair(t, Rt, s1, S2, bias_1=rng.normal(0, 0.5 * DEG, 3),
                                           bias_2=rng.normal(0, 0.5 * DEG, 3), noise_std=PAPER_NOISE_STD, rng=rng)
    return t, w1, w2, truth, R0, s1, s2


def accuracy(runs, modes, duration_s=60.0, seed_s=10.0):
    rng = np.random.default_rng(0)
    k = int(seed_s * RATE)
    err = {}
    for _ in range(runs):
        t, w1, w2, _, R, s1, s2 = pair(rng, duration_s)
        cals = {"batch direct": calibrate_pair(w1, w2, method="direct"), "batch ml": calibrate_pair(w1, w2)}
        for mode in modes:
            tr = GyroPairTracker.from_samples(t[:k], w1[:k], w2[:k], drift=DriftNoise.constant())
            tr.run(t[k:], w1[k:], w2[k:], mode=mode)
            cals[f"ekf {mode}"] = tr.calibration
        for name, c in cals.items():
            e = err.setdefault(name, ([], []))
            e[0].append(rotation_error(c.R_1_2, R))
            e[1].append(scale_error(c.scale_1, c.scale_2, s1, s2))
    return {name: (np.sqrt(np.mean(np.square(r))), np.sqrt(np.mean(np.square(s)))) for name, (r, s) in err.items()}


def throughput(mode, block_size, duration_s, reps=3):
    rng = np.random.default_rng(1)
    t, w1, w2, *_ = pair(rng, duration_s + 10.0)
    k = int(10 * RATE)
    cpu, wall = [], []
    for _ in range(reps):
        tr = GyroPairTracker.from_samples(t[:k], w1[:k], w2[:k])
        c0, w0 = time.process_time(), time.perf_counter()
        tr.run(t[k:], w1[k:], w2[k:], mode=mode, block_size=block_size)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    n = t.size - k
    return n / min(cpu), n / min(wall)


def drift_and_step(runs):
    rng = np.random.default_rng(2)
    fractions, delays, nees, reseeds = [], [], [], []
    for _ in range(runs):
        axis = rng.normal(size=3)
        step = (300.0, 0.5 * DEG * axis / np.linalg.norm(axis))
        t, w1, w2, truth, *_ = pair(rng, 600.0, s2_ramp=0.005, step=step)
        k = int(30 * RATE)
        tr = GyroPairTracker.from_samples(t[:k], w1[:k], w2[:k])
        h = tr.run(t[k:], w1[k:], w2[k:], truth=truth[k:])
        fractions.append(np.mean(np.abs(h.normalised_error) <= 2.0, axis=0))
        accepted = [ev for ev in h.reseeds if ev.accepted]
        reseeds.append(len(accepted))
        if accepted:
            delays.append(accepted[0].t_detected - step[0])
        nees.append(np.nanmean(h.nees))
    return np.array(fractions), np.array(delays), np.array(nees), reseeds, h.nees_dof


def history_memory(n=20000):
    """Bytes a sample the tracker keeps (tracemalloc growth over n per-sample updates after a warm-up)."""
    import tracemalloc

    rng = np.random.default_rng(3)
    t, w1, w2, *_ = pair(rng, (2 * n + 1000) / RATE + 1.0)
    k = 1000
    out = {}
    for max_rows in (None, 10_000):
        tracemalloc.start()                   # from the start: buffers freed later are subtracted
        tr = GyroPairTracker.from_samples(t[:k], w1[:k], w2[:k], history_max_rows=max_rows)
        tr.run(t[k:k + n], w1[k:k + n], w2[k:k + n], mode="sample")      # warm-up (and fill the bound)
        before = tracemalloc.get_traced_memory()[0]
        tr.run(t[k + n:k + 2 * n], w1[k + n:k + 2 * n], w2[k + n:k + 2 * n], mode="sample")
        grown = tracemalloc.get_traced_memory()[0] - before
        tracemalloc.stop()
        out[max_rows] = grown / n
    return out


def _z_at_alarm(tr, batch) -> tuple[float, float, float]:
    """``(t_detected, diff_mdeg, z)`` of the filter's state at its open alarm (the state it returns to if no step is
    confirmed; :attr:`GyroPairTracker.state_at_alarm`) against the batch."""
    from fusion_gyrocal.lie import log

    R0, P0 = tr.state_at_alarm[0], tr.state_at_alarm[4]
    d = np.linalg.norm(log(R0 @ batch.R_1_2.T))
    se = np.sqrt(np.trace(P0[:3, :3]))
    sb = np.sqrt(np.trace(batch.repeatable_rotation_covariance))
    return tr.open_alarm[0], d / DEG * 1e3, d / np.hypot(se, sb)


def mimu(sessions=range(1, 10), imus=(2, 3, 6), seed_s=120.0):
    """Rows ``(session, imu, alarms, accepted, diff_mdeg, sigma_ekf_mdeg, sigma_batch_mdeg, z, misfit, open, fit)``
    with ``fit = (R_ekf, P_ekf, R_batch, P_batch)`` (rotation and its 3x3 covariance)."""
    from fusion_gyrocal.evaluate.sim import shared_data_dir
    from fusion_gyrocal.io import read_npz
    from fusion_gyrocal.lie import log

    root = shared_data_dir() / "mimu_8imu_array" / "npz"
    rows = []
    for s in sessions:
        path = root / f"exp_{s}.npz"
        if not path.exists():
            continue
        ref = read_npz(path, imu=0)
        for k in imus:
            other = read_npz(path, imu=k - 1)
            keep = np.asarray(ref.valid, bool) & np.asarray(other.valid, bool)
            t, w1, w2 = ref.t[keep], ref.omega[keep], other.omega[keep]
            batch = calibrate_pair(w1, w2, t_1=t, t_2=t, time_offset_s=0.0)   # one clock: no offset to estimate
            n0 = int(np.searchsorted(t, t[0] + seed_s))
            tr = GyroPairTracker.from_samples(t[:n0], w1[:n0], w2[:n0])
            rate = 1.0 / float(np.median(np.diff(t)))
            h = tr.run(t[n0:], w1[n0:], w2[n0:], block_size=int(round(rate)))
            d = log(tr.R_1_2 @ batch.R_1_2.T)
            se = np.sqrt(np.trace(tr.error_covariance[:3, :3]))
            rep = batch.repeatable_rotation_covariance   # without the skew
            sb = np.sqrt(np.trace(rep))                       # budget: constant, the tracker's seed drops it too
            rows.append((s, k, len(h.reseeds), sum(ev.accepted for ev in h.reseeds), np.linalg.norm(d) / DEG * 1e3,
                         se / DEG * 1e3, sb / DEG * 1e3, np.linalg.norm(d) / np.hypot(se, sb),
                         tr.misfit_gain != (0.0, 0.0), None if tr.open_alarm is None else _z_at_alarm(tr, batch),
                         (tr.R_1_2, tr.error_covariance[:3, :3], batch.R_1_2, rep)))
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=40, help="Monte Carlo runs for the fast-mode accuracy")
    p.add_argument("--sample-runs", type=int, default=8, help="runs that also use the (slow) per-sample mode")
    p.add_argument("--drift-runs", type=int, default=10)
    p.add_argument("--throughput-only", action="store_true", help="only section 2 (rates and history memory)")
    p.add_argument("--mimu-only", action="store_true", help="only section 4 (the real board)")
    args = p.parse_args(argv)
    if args.mimu_only:
        return print_mimu()

    if not args.throughput_only:
        print("1. Accuracy with constant parameters (60 s at 100 Hz, seed on 10 s, paper noise, general configuration)")
        for runs, modes in ((args.runs, ("fast",)), (args.sample_runs, ("fast", "sample"))):
            rm = accuracy(runs, modes)
            print(f"   {runs} runs:")
            print(f"   {'estimator':>14} {'rot RMSE deg':>13} {'scale RMSE %':>13} {'rot / direct':>13} "
                  f"{'scale / direct':>15} {'rot / ml':>9} {'scale / ml':>11}")
            d, m = rm["batch direct"], rm["batch ml"]
            for name, (r, s) in rm.items():
                print(f"   {name:>14} {r / DEG:13.5f} {100 * s:13.5f} {r / d[0]:13.3f} {s / d[1]:15.3f} "
                      f"{r / m[0]:9.3f} {s / m[1]:11.3f}")

    print("\n2. Throughput on one core (samples/s of tracker.run, best of 7 runs per sample, of 3 in blocks; one BLAS thread)")
    print(f"   {'mode':>7} {'block':>6} {'CPU-time samples/s':>19} {'wall samples/s':>15} {'x real time @200 Hz':>20}")
    for mode, block, dur in (("sample", 1, 30.0), ("fast", 1, 30.0), ("fast", 50, 300.0), ("fast", 100, 300.0), ("fast", 200, 300.0),
                             ("fast", 500, 300.0)):
        cpu, wall = throughput(mode, block, dur, reps=7 if block == 1 else 3)   # short runs: best of more
        print(f"   {mode:>7} {block:6d} {cpu:19.0f} {wall:15.0f} {cpu / 200.0:20.1f}")

    print("\n   history kept per sample (tracemalloc growth over 20k per-sample updates after 20k; the unbounded rows"
          " grow by doubling,\n   264 to 528 bytes a row), extrapolated to 1e7 samples:")
    for max_rows, per in history_memory().items():
        name = "history_max_rows=None (one row per update)" if max_rows is None else f"history_max_rows={max_rows}"
        print(f"   {name:44} {per:8.1f} bytes/sample -> {per * 1e7 / 2**20:9.1f} MiB over 1e7 samples")

    if args.throughput_only:
        return
    print(f"\n3. Drift 0.5 %/10 min on scale_2[y] + 0.5 deg rotation step at 300 s ({args.drift_runs} runs, fast mode)")
    fr, delays, nees, reseeds, dof = drift_and_step(args.drift_runs)
    print(f"   fraction of estimates inside 2 sigma: pooled {fr.mean():.3f}, worst component in any run {fr.min():.3f}")
    print(f"   accepted re-seeds per run: {reseeds}; detection delay after the step: "
          f"median {np.median(delays):.3f} s, max {np.max(delays):.3f} s")
    print(f"   mean NEES per run: {np.round(nees, 2).tolist()} ({dof} dof; below dof = conservative for smooth ramps)")
    print_mimu()


def print_mimu():
    rows = mimu()
    print("\n4. Real board (MIMU4444, IMU 1 vs k; seed on the first 120 s, identified noise; fast mode, 1 s blocks)")
    if not rows:
        print("   ../shared/data/mimu_8imu_array not present: skipped")
        return
    print(f"   {'session':>7} {'IMU':>4} {'alarms':>7} {'re-seeds':>9} {'EKF-batch mdeg':>15} {'sigma EKF':>10} "
          f"{'sigma batch':>12} {'z':>6} {'misfit':>7} {'open':>5}")
    for s, k, n_alarm, n_acc, diff, se, sb, z, mis, op, _ in rows:
        print(f"   {s:7d} {k:4d} {n_alarm:7d} {n_acc:9d} {diff:15.1f} {se:10.1f} {sb:12.1f} {z:6.2f} {str(mis):>7} "
              f"{'' if op is None else 'open':>5}")
    acc = np.array([r[3] for r in rows])
    z = np.array([r[7] for r in rows])
    alarms = np.array([r[2] for r in rows])
    print(f"   sessions with <= 1 re-seed: {np.sum(acc <= 1)} of {len(rows)}; |z| <= 3: {np.sum(z <= 3)} of {len(rows)}")
    print(f"   step alarms (all rigid: false): {alarms.sum()} in all, at most {alarms.max()} a session; "
          f"<= 1 alarm: {np.sum(alarms <= 1)} of {len(rows)}; open at the end: {sum(r[9] is not None for r in rows)}")
    for r in rows:
        if r[9] is not None:
            print(f"   session {r[0]} IMU {r[1]}: alarm open since t = {r[9][0]:.1f} s; the state at the alarm is "
                  f"{r[9][1]:.1f} mdeg from the batch, z {r[9][2]:.2f}")
    print("   session-to-session rotation differences against the final covariances (mean z^2 over session pairs, "
          "3 = honest):")
    import itertools

    from fusion_gyrocal.lie import log

    for k in sorted({r[1] for r in rows}):
        fits = [r[10] for r in rows if r[1] == k and r[9] is None]
        z2 = {"EKF": [], "batch": []}
        for a, b in itertools.combinations(fits, 2):
            for name, i in (("EKF", 0), ("batch", 2)):
                d = log(a[i] @ b[i].T)
                z2[name].append(float(d @ np.linalg.solve(a[i + 1] + b[i + 1], d)))
        print(f"   IMU {k}: {len(fits)} sessions (none with an alarm open), {len(z2['EKF'])} pairs: mean z^2 EKF "
              f"{np.mean(z2['EKF']):.2f}, batch {np.mean(z2['batch']):.2f}")


if __name__ == "__main__":
    main()
