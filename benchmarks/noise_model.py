"""The noise model identified from the moving pair itself (core/noise.py): figures against the truth.

1. Simulated cases (100 Hz, 600 s, the paper's 0.1 deg/s noise): white only, a bias walk 100x the paper's,
   coloured AR(1) noise (rho 0.9), a rate-dependent scale error of gyro 2 (0.2 % per rad/s). Identified
   white std per gyro and bias walk against the truth, and the time per call against Moments.from_samples.
2. MIMU board (../shared/data/mimu_8imu_array, 9 sessions, 62.5 Hz): IMU 1 against IMUs 2..8, the identified
   white noise per gyro against the std of each IMU over its first 20 s (at rest).
3. The drifting-bias case: rotation and scale RMSE over ``--runs`` Monte Carlo runs of ``calibrate_pair``
   with the identified model passed explicitly, with the defaults (which identify it), and with the true
   model, as ratios to the constant-bias Cramer-Rao bound (as benchmarks/beyond_paper.py).
4. Real logs through ``calibrate_pair`` with its defaults (timestamps given), the white noise it identified
   (``cal.noise_model``) against a direct estimate from the same log's static stretches (the median over 1 s
   windows of the per-axis std, at rest): BROAD (../shared/data/broad_handheld, the IMU against the rate
   differentiated from motion capture, rest = not ``movement``) and the MIMU board's static poses (IMU 1
   against IMUs 2, 4, 7; the static windows found from each IMU's own variance). Also how far the fitted
   Allan model is from the residual's points: ``ratio``, the largest ratio of model to point Allan deviation (or
   its inverse) over the fitted taus, and ``worst``, the same beyond each point's 2-sigma scatter (the stationary
   estimator's, or the one measured from batch means where larger); ``fits`` says whether it passes through them.
5. ``gyrocal noise`` (core/static_noise.py) on the MIMU static poses (9 sessions x 8 IMUs x 3 axes) and on the
   BROAD rest stretches: the white noise per sample against the direct estimate from the same stretches (the
   pooled per-sample std about each stretch's mean), per axis.

    python benchmarks/noise_model.py [--runs 30] [--workers 2] [--only real|static]
"""

from __future__ import annotations

import argparse
import zlib
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from _timing import best_of  # noqa: E402  (benchmarks/ is the script's folder)
from scipy.signal import lfilter

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.core.allan import FIT_FACTOR
from fusion_gyrocal.core.direct import solve_A
from fusion_gyrocal.core.moments import Moments, random_walk_gain
from fusion_gyrocal.core.noise import identify_noise
from fusion_gyrocal.core.observability import cramer_rao_bound
from fusion_gyrocal.evaluate.sim import (DEG, PAPER_BIAS_WALK_STD, PAPER_NOISE_STD, general_rotation, load_broad_pair,
                                         rotation_error, scale_error, shared_data_dir, simulate_pair)

RATE = 100.0


def _identify(w1, w2, rate, mask=None):
    t_mom, mom = best_of(lambda: Moments.from_samples(w1, w2, mask=mask))
    A, b = solve_A(mom)
    t_id, nm = best_of(lambda: identify_noise(w1, w2, A, b, rate_hz=rate, mask=mask))
    return nm, t_id, t_mom


def simulated_cases():
    print("1. simulated, 600 s at 100 Hz (noise in deg/s per sample, walk in micro-deg/s per step)")
    print(f"{'case':>22} {'kind':>40} {'bias':>12} {'noise 1':>16} {'noise 2':>16} {'truth':>8} "
          f"{'walk/gyro':>10} {'truth':>7} {'ms/call':>8} {'Moments ms':>10}")
    n = 60000
    for case in ("white", "drifting_bias_100x", "ar1_rho0.9", "scale_0.2%_per_rad/s"):
        rng = np.random.default_rng(zlib.crc32(case.encode()))
        walk = 100 * PAPER_BIAS_WALK_STD if case.startswith("drifting") else 0.0
        sim = simulate_pair(n=n, bias_walk_std=walk, noise_std=1e-12 if case.startswith("ar1") else PAPER_NOISE_STD,
                            rng=rng)
        w1, w2 = sim.omega_1, sim.omega_2
        truth = f"{PAPER_NOISE_STD / DEG:.4f}"
        if case.startswith("ar1"):
            rho = 0.9
            w1, w2 = (w + lfilter([np.sqrt(1 - rho**2) * PAPER_NOISE_STD], [1.0, -rho], rng.standard_normal((n, 3)),
                                  axis=0) for w in (w1, w2))
            truth = f"{PAPER_NOISE_STD / DEG:.3f}/{PAPER_NOISE_STD * np.sqrt((1 + rho) / (1 - rho)) / DEG:.3f}"
        if case.startswith("scale"):
            w2_true = sim.omega_true_1 @ sim.R_1_2
            w2 = w2 + 0.002 * np.linalg.norm(w2_true, axis=1)[:, None] * w2_true
        nm, t_id, t_mom = _identify(w1, w2, RATE)
        q = "-" if nm.bias_walk_std is None else f"{nm.bias_walk_std[0] / DEG * 1e6:.0f}"
        noise = [f"{s / DEG:.4f}+-{u / DEG:.4f}" for s, u in zip(nm.noise_std, nm.noise_std_uncertainty)]
        print(f"{case:>22} {nm.kind:>40} {nm.bias_model:>12} {noise[0]:>16} {noise[1]:>16} {truth:>8} {q:>10} "
              f"{walk / DEG * 1e6:7.0f} {1e3 * t_id:8.1f} {1e3 * t_mom:10.2f}")
        if case.startswith("ar1"):
            print(f"{'':>22} (AR(1) truth: per-sample std / low-frequency equivalent white std "
                  "sigma sqrt((1+rho)/(1-rho)); the motion band sees the latter)")
        if case.startswith("scale"):
            print(f"{'':>22} misfit share {100 * nm.misfit_share:.0f}%, gain error a = {nm.misfit_gain[0]:+.4f}, "
                  f"b = {nm.misfit_gain[1]:+.4f} per rad/s (truth b = -0.002 on gyro 1's side)")
    sim = simulate_pair(n=1_000_000, bias_walk_std=100 * PAPER_BIAS_WALK_STD, rng=1)
    _, t_id, t_mom = _identify(sim.omega_1, sim.omega_2, RATE)
    print(f"{'1e6 samples (walk)':>22} time per call {1e3 * t_id:.0f} ms, Moments.from_samples {1e3 * t_mom:.0f} ms")


def mimu():
    d = shared_data_dir() / "mimu_8imu_array" / "npz"
    if not d.exists():
        print("2. MIMU: ../shared/data not present, skipped")
        return
    from fusion_gyrocal.io import read_npz

    rate = 62.5
    rest = slice(0, int(20 * rate))
    print("\n2. MIMU board, IMU 1 vs IMU k: identified white noise per gyro (deg/s per sample) vs the std of each IMU "
          "over its first 20 s at rest; resid = the least-squares residual's std (what noise_model='residual' reports)")
    print(f"{'sess':>4} {'k':>2} {'kind':>40} {'bias':>9} {'id IMU1':>8} {'rest 1':>7} {'id IMUk':>8} {'rest k':>7} "
          f"{'resid':>7} {'ms/call':>8} {'Mom ms':>7}")
    ratios = []
    for e in range(1, 10):
        streams = read_npz(d / f"exp_{e}.npz")
        g1 = streams[0]
        for k in range(1, 8):
            gk = streams[k]
            mask = g1.valid & gk.valid
            nm, t_id, t_mom = _identify(g1.omega, gk.omega, rate, mask=mask)
            st = [float(np.mean(g.omega[rest].std(axis=0, ddof=1))) for g in (g1, gk)]
            A, b = solve_A(Moments.from_samples(g1.omega, gk.omega, mask=mask))
            resid = float((g1.omega[mask] - gk.omega[mask] @ A.T - b).std(axis=0).mean())
            ratios.append([nm.noise_std[0] / st[0], nm.noise_std[1] / st[1]])
            print(f"{e:>4} {k + 1:>2} {nm.kind:>40} {nm.bias_model:>9} {nm.noise_std[0] / DEG:8.4f} {st[0] / DEG:7.4f} "
                  f"{nm.noise_std[1] / DEG:8.4f} {st[1] / DEG:7.4f} {resid / DEG:7.3f} {1e3 * t_id:8.1f} "
                  f"{1e3 * t_mom:7.2f}")
    r = np.array(ratios)
    print(f"identified / at-rest std over the 63 pairs: IMU 1 {r[:, 0].mean():.3f} (range {r[:, 0].min():.3f}-"
          f"{r[:, 0].max():.3f}), IMU k {r[:, 1].mean():.3f} (range {r[:, 1].min():.3f}-{r[:, 1].max():.3f})")


def drifting_run(k):
    rng = np.random.default_rng([zlib.crc32(b"drifting_bias"), k])
    R = general_rotation(rng)
    s1, s2 = rng.normal(1.0, 0.01, 3), rng.normal(1.0, 0.01, 3)
    walk = 100 * PAPER_BIAS_WALK_STD
    sim = simulate_pair(n=60000, rms=0.5, R_1_2=R, scale_1=s1, scale_2=s2, bias_walk_std=walk, rng=rng)
    x2 = (sim.omega_true_1 @ R) @ np.diag(s2)
    bound = cramer_rao_bound(R, s1, s2, sim.noise_std, x2)
    # the random-walk model's own bound: the same bound on the innovations (what the exact likelihood sees: the
    # motion through the steady-state filter's high-pass, the noise scaled to the innovations' variance)
    gain, scale = random_walk_gain(walk, sim.noise_std)
    xf = lfilter([1.0, -1.0], [1.0, -(1.0 - gain)], x2 - x2[0], axis=0)[int(5 / gain):]
    rw = cramer_rao_bound(R, s1, s2, tuple(np.asarray(sim.noise_std, float) * scale), xf)
    A, b = solve_A(Moments.from_samples(sim.omega_1, sim.omega_2))
    nm = identify_noise(sim.omega_1, sim.omega_2, A, b, rate_hz=RATE)
    out = {"bound": (bound.rotation_rmse, bound.scale_rmse), "rw_bound": (rw.rotation_rmse, rw.scale_rmse),
           "model": nm.bias_model, "noise": nm.noise_std, "walk": nm.bias_walk_std}
    for name, kw in (("identified", nm.calibrate_keywords), ("defaults", {}),
                     ("true model", {"noise_std": PAPER_NOISE_STD, "bias_walk_std": walk})):
        cal = calibrate_pair(sim.omega_1, sim.omega_2, flex_rejection=False, **kw)
        out[name] = (rotation_error(cal.R_1_2, R), scale_error(cal.scale_1, cal.scale_2, s1, s2))
    return out


def drifting(runs, workers):
    print(f"\n3. drifting bias (walk 100x the paper's, 600 s at 100 Hz, rms 0.5 rad/s), {runs} runs: RMSE / constant-bias "
          "Cramer-Rao bound (flex_rejection=False)")
    with ProcessPoolExecutor(workers) as pool:
        res = list(pool.map(drifting_run, range(runs)))
    br = np.sqrt(np.mean([r["bound"][0] ** 2 for r in res]))
    bs = np.sqrt(np.mean([r["bound"][1] ** 2 for r in res]))
    chosen = sum(r["model"] == "random walk" for r in res)
    walks = np.array([r["walk"][0] for r in res if r["walk"] is not None])
    print(f"identified: random walk chosen in {chosen}/{runs} runs, walk per gyro {np.mean(walks) / DEG * 1e6:.1f} "
          f"+- {np.std(walks) / DEG * 1e6:.1f} micro-deg/s (truth {100 * PAPER_BIAS_WALK_STD / DEG * 1e6:.1f}), noise "
          f"{np.mean([r['noise'][0] for r in res]) / DEG:.4f} deg/s (truth {PAPER_NOISE_STD / DEG:.4f})")
    print(f"{'model':>12} {'rot RMSE mdeg':>14} {'rot/bound':>10} {'scale RMSE %':>13} {'scale/bound':>12}")
    rr = np.sqrt(np.mean([r["rw_bound"][0] ** 2 for r in res]))
    rs = np.sqrt(np.mean([r["rw_bound"][1] ** 2 for r in res]))
    for name in ("identified", "defaults", "true model"):
        er = np.sqrt(np.mean([r[name][0] ** 2 for r in res]))
        es = np.sqrt(np.mean([r[name][1] ** 2 for r in res]))
        print(f"{name:>12} {np.rad2deg(er) * 1e3:14.3f} {er / br:10.2f} {100 * es:13.5f} {es / bs:12.2f}   "
              f"/ random-walk bound: {er / rr:.2f} rot, {es / rs:.2f} scale")
    print(f"the random-walk model's own bound is {rr / br:.2f}x (rotation) and {rs / bs:.2f}x (scales) the constant-bias "
          "one: the motion below the filter's corner (K / (2 pi dt)) carries no information once the bias walks")


def static_std(omega: np.ndarray, still: np.ndarray, window: int) -> float:
    """Median over the ``window``-sample windows wholly inside ``still`` of the per-axis std, averaged over axes."""
    k = len(omega) // window
    x = omega[:k * window].reshape(k, window, 3)
    inside = still[:k * window].reshape(k, window).all(axis=1)
    return float(np.median(x[inside].std(axis=1, ddof=1).mean(axis=1)))


def model_ratio(nm) -> float:
    """The largest ratio of the residual's fitted Allan model to its points (or the inverse) over the fitted taus."""
    taus = np.asarray(nm.taus)
    sel = (taus >= nm.fit_taus[0] * (1 - 1e-9)) & (taus <= nm.fit_taus[1] * (1 + 1e-9))
    pts = np.sqrt((np.asarray(nm.adev) ** 2).mean(axis=1))[sel]
    mod = np.asarray(nm.adev_fit)[sel]
    return float(np.max(np.maximum(mod / pts, pts / mod)))


def _real_row(name, cal, static, fits):
    nm = cal.noise_model
    ratio = [nm.noise_std[i] / static[i] for i in (0, 1)]
    used = "still" if nm.sources.get("noise", "").startswith("USED: each gyro's own") else "residual"
    fits.append((model_ratio(nm), nm.adev_worst, nm.fits))
    print(f"{name:>34} {nm.noise_std[0] / DEG:8.4f} {static[0] / DEG:7.4f} {ratio[0]:6.2f} {nm.noise_std[1] / DEG:8.4f} "
          f"{static[1] / DEG:7.4f} {ratio[1]:6.2f} {used:>8} {fits[-1][0]:6.2f} {nm.adev_worst:6.2f} "
          f"{'yes' if nm.fits else 'NO':>4} {cal.lack_of_fit:8.3g}")
    return ratio


def _fit_summary(name, fits):
    f = np.array(fits, float)
    print(f"{name} residual Allan model vs points: ratio up to {f[:, 0].max():.2f}, beyond the points' 2-sigma up to "
          f"{f[:, 1].max():.2f}; passes through them (within {FIT_FACTOR:g}x beyond) in {int(f[:, 2].sum())}/{len(f)}")


def real_logs():
    from fusion_gyrocal.io import read_npz

    print("\n4. real logs, calibrate_pair defaults: identified white noise per sample (deg/s) vs the static stretches' "
          "std; used = where the white level came from; model = largest ratio Allan model / points, worst = the "
          "same beyond their 2-sigma scatter, fits = within 1.2x of that; lof = residual chi2/dof")
    head = (f"{'log':>34} {'id 1':>8} {'stat 1':>7} {'ratio':>6} {'id 2':>8} {'stat 2':>7} {'ratio':>6} {'used':>8} "
            f"{'model':>6} {'worst':>6} {'fits':>4} {'lof':>8}")
    broad = shared_data_dir() / "broad_handheld" / "data_mat"
    if broad.exists():
        print("BROAD: gyro 1 = the IMU, gyro 2 = the motion-capture rate (differentiated orientation: not white; "
              "its 'static' figure is the per-sample std)")
        print(head)
        ratios, fits = [], []
        for f in sorted(broad.glob("*.mat")):
            gyr, moc, rest, fs = load_broad_pair(f.stem)
            t = np.arange(len(gyr)) / fs
            cal = calibrate_pair(gyr, moc, t_1=t, t_2=t)
            static = (static_std(gyr, rest, int(fs)), static_std(np.nan_to_num(moc), rest & np.isfinite(moc).all(1),
                                                                  int(fs)))
            ratios.append(_real_row(f.stem[:34], cal, static, fits)[0])
        r = np.array(ratios)
        print(f"BROAD IMU identified / static: {r.min():.2f}-{r.max():.2f} (mean {r.mean():.2f}); within 1.5x in "
              f"{np.sum((r < 1.5) & (r > 1 / 1.5))}/{r.size}")
        _fit_summary("BROAD", fits)
    d = shared_data_dir() / "mimu_8imu_array" / "npz"
    if d.exists():
        print("MIMU static poses: IMU 1 vs IMU k")
        print(head)
        ratios, fits = [], []
        for e in range(1, 10):
            streams = read_npz(d / f"exp_{e}.npz")
            for k in (1, 3, 6):
                g1, gk = streams[0], streams[k]
                cal = calibrate_pair(g1.omega, gk.omega, t_1=g1.t, t_2=gk.t)
                static = []
                for g in (g1, gk):   # each IMU's static poses: its quietest 1 s windows (within 2x of the median
                    w = 62                                                           # of the quietest tenth)
                    k_ = len(g.omega) // w
                    s = g.omega[:k_ * w].reshape(k_, w, 3).std(axis=1, ddof=1).mean(axis=1)
                    still = np.repeat(s <= 2.0 * np.quantile(s, 0.1), w)
                    static.append(static_std(g.omega, np.r_[still, np.zeros(len(g.omega) - still.size, bool)], w))
                ratios.append(_real_row(f"exp_{e} IMU 1 vs {k + 1}", cal, static, fits))
        r = np.array(ratios)
        print(f"MIMU identified / static: IMU 1 {r[:, 0].min():.2f}-{r[:, 0].max():.2f}, IMU k {r[:, 1].min():.2f}-"
              f"{r[:, 1].max():.2f}; within 1.5x in {np.sum((r < 1.5) & (r > 1 / 1.5))}/{r.size}")
        _fit_summary("MIMU", fits)


def direct_white(omega, stretches, rate_hz):
    """The direct estimate of the white noise density from rest stretches: the per-sample std about each stretch's
    own mean, pooled, over sqrt(rate) (rad/s/sqrt(Hz), per axis)."""
    x = np.concatenate([omega[a:b] - omega[a:b].mean(axis=0) for a, b in stretches])
    return x.std(axis=0) / np.sqrt(rate_hz)


def static_logs():
    from scipy.io import loadmat

    from fusion_gyrocal.core.static_noise import rest_stretches, static_noise
    from fusion_gyrocal.io import read_npz

    print("\n5. gyrocal noise (static_noise) vs the direct estimate from the same rest stretches, per axis: "
          "white / direct")
    d = shared_data_dir() / "mimu_8imu_array" / "npz"
    if d.exists():
        rows = []
        for e in range(1, 10):
            line = []
            for imu in range(8):
                s = read_npz(d / f"exp_{e}.npz", imu=imu)
                r = static_noise(s.omega, s.rate_hz, valid=s.valid,
                                 stretches=rest_stretches(s.omega, s.rate_hz, valid=s.valid))
                q = r.white / direct_white(s.omega, r.stretches, s.rate_hz)
                rows.append(q)
                line.append("/".join(f"{v:.2f}" for v in q))
            print(f"MIMU exp_{e} IMU 1..8 (x/y/z): " + " ".join(line))
        q = np.concatenate(rows)
        print(f"MIMU static poses: white / direct {q.min():.3f}-{q.max():.3f}; within 10 % in "
              f"{int(np.sum(np.abs(q - 1) <= 0.10))}/{q.size} axes")
    broad = shared_data_dir() / "broad_handheld" / "data_mat"
    if broad.exists():
        rows = []
        for f in sorted(broad.glob("*.mat")):
            m = loadmat(f, squeeze_me=True)
            g, fs = np.asarray(m["imu_gyr"], float), float(m["sampling_rate"])
            r = static_noise(g, fs)
            q = r.white / direct_white(g, r.stretches, fs)
            rows.append(q)
            print(f"{f.stem[:34]:>34}: {len(r.stretches)} stretch(es), {r.n_samples / fs:.0f} s, white / direct "
                  + "/".join(f"{v:.3f}" for v in q))
        q = np.concatenate(rows)
        print(f"BROAD rest stretches: white / direct {q.min():.3f}-{q.max():.3f}; within 10 % in "
              f"{int(np.sum(np.abs(q - 1) <= 0.10))}/{q.size} axes")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", choices=("all", "real", "static"), default="all",
                    help="real: only section 4, static: only section 5")
    a = ap.parse_args(argv)
    if a.only == "all":
        simulated_cases()
        mimu()
        drifting(a.runs, a.workers)
    if a.only in ("all", "real"):
        real_logs()
    if a.only in ("all", "static"):
        static_logs()


if __name__ == "__main__":
    main()
