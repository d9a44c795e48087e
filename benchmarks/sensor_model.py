"""Repeatability on one rigid board: the sensor model against the MIMU sessions (issue 20).

The MIMU board (``../shared/data/mimu_8imu_array``) is one soldered PCB recorded in nine sessions: the rotation
between two of its IMUs is the same in every session, so the session-to-session differences of an estimate are
its real error (twice over), and the covariance it reports must explain them.

For 14 pairs (IMU 1 against 2..8 and the neighbouring pairs 2-4, 3-5, 3-7, 5-7, 2-6, 4-8, 6-8), with timestamps
and the defaults (or ``--linear-map``), this prints per pair the RMS session-to-session rotation difference
(``sqrt(mean |Log(R_a R_b^T)|^2)`` over the 36 session pairs), the mean reported 1-sigma (per axis, without the skew budget
``skew_rotation_covariance``: the board's constant cross-axis, which the difference of two sessions cancels), the mean
``z^2`` of the differences against the sum of the two sessions' rotation covariances (3 dof: 3 is honest), the
residual's chi2/dof, the robust inflation, how many sessions used the full linear map and its largest
cross-axis term, and the mean z^2 per axis of the session-to-session differences of the relative scale factors
(``scale_ratio``) against their reported 1-sigma.

Then the library's change test (:func:`fusion_gyrocal.compare_sessions`) per pair: per session, how far its rotation
sits from the information-weighted mean of the consistent others in units of its repeatable covariance plus the
mean's (``z^2``, 3 dof), the median over the pairs and the pairs where the test says the session changed (beyond the
chi-square point of a 1 % false-alarm rate over the nine sessions). A session changed in more than half of the pairs
is flagged (a board that changed in that session, not noise), and the target figures are printed again without the
flagged sessions. The library keeps every session and tests each pair; the flagging over pairs is the benchmark's,
the decision the reader's. Last, per site of two co-located chips (top and bottom of the board at one x, y): both
chips' deviations from chip 1 in the sessions that stand out, and the co-located pair's own change-test z^2; two
different chips that moved alike while their own pair stayed put are a site of the board that moved (a bend), not an
estimate that erred.

With ``--halves``, each MIMU session's first half against its second (a truth within a session, which a bend of the
board between sessions cannot touch): the RMS rotation difference, the mean and median z^2 against the halves'
repeatable covariances (3 dof) and the relative scale factors' mean z^2 per axis (1 is honest). With ``--broad``,
BROAD's undisturbed trials split into halves, one half against the other (a truth within a trial).

    python benchmarks/sensor_model.py [--linear-map auto|rigid|full] [--robust-weights auto|off] [--pairs 1-2,2-4]
                                      [--halves] [--broad] [--no-mimu] [--sim N]
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time

import numpy as np

from fusion_gyrocal import calibrate_pair, compare_sessions
from fusion_gyrocal.evaluate.sim import shared_data_dir
from fusion_gyrocal.lie import log

DEG = np.pi / 180.0
PAIRS = ((1, 2), (1, 3), (1, 4), (1, 5), (1, 6), (1, 7), (1, 8),
         (2, 4), (3, 5), (3, 7), (5, 7), (2, 6), (4, 8), (6, 8))


def session_pairs(cals):
    """RMS rotation difference (rad) and the z^2 of each session pair against the repeatable rotation covariances."""
    z2, d2 = [], []
    for a, b in itertools.combinations(cals, 2):
        diff = log(a.R_1_2 @ b.R_1_2.T)
        z2.append(float(diff @ np.linalg.solve(a.repeatable_rotation_covariance + b.repeatable_rotation_covariance,
                                                      diff)))
        d2.append(float(diff @ diff))
    return float(np.sqrt(np.mean(d2))), np.array(z2)


def scale_pairs(cals) -> float:
    """Mean z^2 per axis of the session-to-session differences of the relative scale factors
    (``scale_ratio``, gauge-invariant) against their reported 1-sigma (1 is honest)."""
    z2 = [((a.scale_ratio - b.scale_ratio) ** 2 / (a.scale_ratio_std ** 2 + b.scale_ratio_std ** 2)).mean()
          for a, b in itertools.combinations(cals, 2)]
    return float(np.mean(z2))


def session_test(cals):
    """The library's change test of one pair's sessions (:func:`fusion_gyrocal.compare_sessions`): each session
    against the consistent others' mean, in units of the repeatable covariances."""
    return compare_sessions(cals, [f"exp_{e + 1}" for e in range(len(cals))])


def summary(per_pair, sessions) -> str:
    """The target figures over the pairs for the sessions ``sessions`` (indices into each pair's calibrations)."""
    rms, z2 = zip(*(session_pairs([cals[e] for e in sessions]) for cals in per_pair))
    rms = np.array(rms)
    return (f"RMS session-to-session rotation difference {np.sqrt(np.mean(rms ** 2)) / DEG * 1e3:.1f} mdeg "
            f"({rms.min() / DEG * 1e3:.0f}-{rms.max() / DEG * 1e3:.0f} per pair); mean z2 "
            f"{np.concatenate(z2).mean():.2f} (3 dof)")


def consistency(per_pair, pairs, arrays=None) -> None:
    """Print the change test per session (the library's, per pair; with ``arrays``, also the arrays' joint test)
    and the target figures with and without the flagged sessions: those the joint test finds changed (arrays), else
    those changed in more than half of the pairs."""
    tests = [session_test(cals) for cals in per_pair]
    z2 = np.array([t.z2 for t in tests])          # (pairs, sessions)
    changed = np.array([t.changed for t in tests])
    n = z2.shape[1]
    print(f"\nchange test (compare_sessions): each session against the consistent others' mean, z2 (3 dof) in units "
          f"of their covariances; changed beyond {tests[0].limit:.1f} (false alarms 1 % over the {n} sessions); "
          + ("flagged when changed in more than half of the pairs" if arrays is None else
             "flagged when the arrays' joint test finds the session changed"))
    joint = None if arrays is None else compare_sessions(arrays, [f"exp_{e + 1}" for e in range(len(arrays))])
    print(f"{'session':>8} {'median z2':>10} {'max z2':>8} {'pairs changed':>14}  worst pairs"
          + ("" if joint is None else f"   array jointly ({joint.dof} dof, changed beyond {joint.limit:.1f})"))
    flagged = []
    for e in range(n):
        worst = np.argsort(z2[:, e])[::-1][:3]
        print(f"{'exp_' + str(e + 1):>8} {np.median(z2[:, e]):10.1f} {z2[:, e].max():8.1f} "
              f"{int(changed[:, e].sum()):>7d}/{len(pairs):<6d}  "
              + ", ".join(f"{pairs[k][0]}-{pairs[k][1]} ({z2[k, e]:.0f})" for k in worst)
              + ("" if joint is None else f"   z2 {joint.z2[e]:.1f}{' CHANGED' if joint.changed[e] else ''}"))
        if (changed[:, e].sum() > len(pairs) / 2) if joint is None else joint.changed[e]:
            flagged.append(e)
    everything = list(range(n))
    print(f"all {n} sessions: {summary(per_pair, everything)}")
    if joint is not None:
        print(f"array jointly: the consistent sessions' spread is {joint.spread:.2f} per dof ({joint.spread_dof} dof)")
    if flagged:
        names = ", ".join(f"exp_{e + 1}" for e in flagged)
        print(f"without {names} ({'changed in more than half of the pairs' if joint is None else 'changed jointly'}): "
              f"{summary(per_pair, [e for e in everything if e not in flagged])}")
    else:
        print("no session flagged")


def sites(folder) -> list[tuple[int, int]]:
    """Chips (1-based) that share one site of the board: same x and y in ``IMU_positions.csv`` (top and bottom side)."""
    rows = [line.split(",") for line in (folder / "IMU_positions.csv").read_text().splitlines()[1:]]
    xy = np.array([[float(v) for v in r[1:]] for r in rows[:2]]).T          # (chips, 2)
    return [(a + 1, b + 1) for a, b in itertools.combinations(range(len(xy)), 2) if np.allclose(xy[a], xy[b])]


def site_check(per_pair, pairs, co_located, folder) -> None:
    """Did a changed session's chips move, or did the estimate err? Per site of two co-located chips k, l (top and
    bottom of the board, different chips with different axes), each chip's deviation from its consistent sessions'
    mean against reference chip 1 (:func:`fusion_gyrocal.compare_sessions`, rotation vector in chip 1's frame) beside
    the change test's z^2 of the pair k-l itself: a site that moved as a whole shows the same deviation on both chips
    and a small z^2 of k-l (a deformation of the board between the sites; noise or a chip's own sensor model would
    not move two chips alike). ``co_located(k, l)``: the pair k-l's calibrations, one per session."""
    print("\nsites (co-located chips, IMU_positions.csv): each chip's deviation from its consistent sessions' mean "
          "against chip 1 (mdeg, about chip 1's x, y, z) and the change test's z2 of the co-located pair itself")
    given = dict(zip(pairs, per_pair))
    for k, l in sites(folder):
        if (1, k) not in given or (1, l) not in given:
            continue
        own = co_located(k, l)
        test = session_test(own)
        dk_all, dl_all = (session_test(given[(1, m)]).deviation[:, 0] / DEG * 1e3 for m in (k, l))
        for e in range(len(own)):
            dk, dl = dk_all[e], dl_all[e]
            if max(np.abs(dk).max(), np.abs(dl).max()) < 15.0 and not test.changed[e]:
                continue
            print(f"  site {k}/{l} exp_{e + 1}: chip {k} [{dk[0]:6.1f} {dk[1]:6.1f} {dk[2]:6.1f}], chip {l} "
                  f"[{dl[0]:6.1f} {dl[1]:6.1f} {dl[2]:6.1f}]; pair {k}-{l} z2 {test.z2[e]:.1f}")
        print(f"  site {k}/{l}: pair {k}-{l} over all sessions: {summary([own], list(range(len(own))))}")


def session_halves(sessions, pairs, keywords) -> None:
    """Each session's first half against its second, per pair: a truth within one session (the board cannot
    bend between the halves of one recording unless it bent during it)."""
    print(f"\nMIMU, each session's first half against its second, {len(pairs)} pairs, options {keywords or 'defaults'}")
    d2, z2, scale = [], [], []
    for i, j in pairs:
        per_pair = []
        for s in sessions:
            a, b = s[i - 1], s[j - 1]
            h = len(a.t) // 2
            cals = [calibrate_pair(a.omega[u:v], b.omega[u:v], t_1=a.t[u:v], t_2=b.t[u:v], **keywords)
                    for u, v in ((0, h), (h, len(a.t)))]
            rms, z = session_pairs(cals)
            d2.append(rms ** 2)
            z2.append(z[0])
            per_pair.append(z[0])
            scale.append(scale_pairs(cals))
        print(f"  {i}-{j}: mean z2 {np.mean(per_pair):.2f}")
        sys.stdout.flush()
    print(f"halves: RMS rotation difference {np.sqrt(np.mean(d2)) / DEG * 1e3:.1f} mdeg, mean z2 {np.mean(z2):.2f} "
          f"(median {np.median(z2):.2f}; 3 dof); relative scale factors mean z2 per axis {np.mean(scale):.2f} (1)")


def broad_halves(keywords) -> None:
    """BROAD's ten undisturbed trials (the IMU against the rate from motion capture), each split into halves: the
    rotation of one half against the other's, in units of their repeatable covariances (a truth within one trial:
    the trials themselves disagree by far more than any covariance, ~390 mdeg). The streams go in with their
    sample times, the motion capture's without its gaps, so that its lag is estimated (~6 ms; sample-aligned, the
    halves differ 2.3x more)."""
    from fusion_gyrocal.evaluate.sim import load_broad_pair

    folder = shared_data_dir() / "broad_handheld" / "data_mat"
    if not folder.exists():
        print("BROAD: ../shared/data not present, nothing to measure")
        return
    print(f"\nBROAD, each undisturbed trial's first half against its second, options {keywords or 'defaults'}")
    z2, d2 = [], []
    for f in sorted(folder.glob("*undisturbed*.mat")):
        p = load_broad_pair(f.stem)
        n, t, seen = len(p.gyr), np.arange(len(p.gyr)) / p.rate_hz, np.isfinite(p.mocap).all(axis=1)
        cals = [calibrate_pair(p.gyr[a:b], p.mocap[a:b][seen[a:b]], t_1=t[a:b], t_2=t[a:b][seen[a:b]], **keywords)
                for a, b in ((0, n // 2), (n // 2, n))]   # timestamps: the motion capture lags ~6 ms, estimated
        rms, z = session_pairs(cals)
        z2.append(z[0])
        d2.append(rms ** 2)
        sigma = np.mean([np.sqrt(np.trace(c.repeatable_rotation_covariance) / 3.0) for c in cals])
        print(f"{f.stem[:34]:>34}: difference {rms / DEG * 1e3:6.1f} mdeg, 1-sigma {sigma / DEG * 1e3:5.1f}, "
              f"z2 {z[0]:6.2f}")
    print(f"BROAD halves: RMS difference {np.sqrt(np.mean(d2)) / DEG * 1e3:.1f} mdeg, mean z2 {np.mean(z2):.2f} (3 dof)")


def cross_axis_case(k: int, configuration: str, delay_s: float = 0.0, cross: bool = True) -> dict:
    """One simulated pair whose gyros both have cross-axis terms of 0.5-2 % (each off-diagonal entry of
    ``U_i = I + K_i`` a random sign times U(0.5, 2) %): gyro i measures ``S_i U_i omega_i + b_i + n_i``; gyro 2
    ``delay_s`` late (a filter's group delay), sample-aligned. The rotation error is against the physical rotation."""
    from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, PAPER_RATE_HZ, HumanMotion, general_rotation

    rng = np.random.default_rng([20, k, len(configuration)])
    R = general_rotation(rng) if configuration == "general" else np.array([[0., -1, 0], [-1, 0, 0], [0, 0, -1]])
    s1, s2 = rng.normal(1.0, 0.01, 3), rng.normal(1.0, 0.01, 3)
    noise = PAPER_NOISE_STD
    t = np.arange(20000) / PAPER_RATE_HZ
    motion = HumanMotion(0.5, rng=rng)
    w_true = (motion(t), motion(t - delay_s) @ R)              # each gyro's true rate in its own frame
    out = []
    for w, s in zip(w_true, (s1, s2)):
        K = rng.choice([-1.0, 1.0], (3, 3)) * rng.uniform(0.005, 0.02, (3, 3)) * cross
        np.fill_diagonal(K, 0.0)
        M = s[:, None] * (np.eye(3) + K)
        out.append(w @ M.T + rng.normal(0, 0.005, 3) + rng.normal(0, noise, w.shape))
    cal = calibrate_pair(*out)
    d = log(cal.R_1_2 @ R.T)
    return {"err": float(np.linalg.norm(d)), "z2": float(d @ np.linalg.solve(cal.covariance[:3, :3], d)),
            "full": cal.linear_map == "full", "sigma": float(np.sqrt(np.trace(cal.covariance[:3, :3]) / 3))}


def reference_case(k: int) -> dict:
    """Gyro 1 with a known intrinsic matrix (``intrinsics_1``), gyro 2 with scale factors and cross-axis terms of
    0.5-2 %: gyro 2's intrinsic matrix and the rotation against their truth and the Cramer-Rao bound."""
    from fusion_gyrocal.core.linear_map import UPPER, reference_derivatives, reference_map
    from fusion_gyrocal.core.observability import information_of_A
    from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, general_rotation, simulate_pair

    rng = np.random.default_rng([21, k])
    R, noise = general_rotation(rng), PAPER_NOISE_STD
    S = [np.diag(rng.normal(1.0, 0.01, 3)) + np.triu(rng.choice([-1.0, 1.0], (3, 3)) * rng.uniform(0.005, 0.02, (3, 3)), 1)
         for _ in range(2)]
    sim = simulate_pair(n=20000, rms=0.5, R_1_2=R, noise_std=1e-12, bias_walk_std=0.0, rng=rng)
    w_true = (sim.omega_true_1, sim.omega_true_1 @ R)
    w1, w2 = (w @ M.T + rng.normal(0, 0.005, 3) + rng.normal(0, noise, w.shape) for w, M in zip(w_true, S))
    # the truth in the solver's terms: gyro 1's skew compensated, so A = D_1 R S_2^-1
    s1 = np.diag(S[0])
    F = information_of_A(reference_map(R, S[1], s1), reference_derivatives(R, S[1], s1), (noise, noise),
                         np.cov((w_true[1] @ S[1].T).T, bias=True) * len(w2))
    bound = np.sqrt(np.trace(np.linalg.inv(F)[:3, :3]))
    cal = calibrate_pair(w1, w2, intrinsics_1=S[0])
    d = log(cal.R_1_2 @ R.T)
    sd = np.sqrt(np.diag(cal.intrinsics_2_covariance))
    z = np.array([(cal.intrinsics_2[a, b] - S[1][a, b]) / sd[p] for p, (a, b) in enumerate(UPPER)])
    return {"err": float(np.linalg.norm(d)), "bound": float(bound), "z": z,
            "z2": float(d @ np.linalg.solve(cal.covariance[:3, :3], d))}


def simulations(runs: int) -> None:
    print(f"\nGyro 1's intrinsics known (intrinsics_1), gyro 2 with 0.5-2 % cross-axis terms, {runs} runs: gyro 2's "
          "intrinsic matrix and the rotation")
    res = [reference_case(k) for k in range(runs)]
    z = np.array([r["z"] for r in res])
    print(f"  rotation RMSE / bound {np.sqrt(np.mean([r['err'] ** 2 for r in res]) / np.mean([r['bound'] ** 2 for r in res])):.3f}; "
          f"mean z2 {np.mean([r['z2'] for r in res]):.2f} (3 dof); intrinsics_2 entries within 2 sigma "
          f"{100 * np.mean(np.abs(z) < 2):.1f} % (95.4 % expected), mean z^2 per entry {np.mean(z ** 2):.2f}")
    print(f"\nSimulated pairs with cross-axis terms of 0.5-2 % on both gyros (and gyro 2 2 ms late), sample-aligned, "
          f"defaults, {runs} runs per case: rotation error against the physical rotation")
    print(f"{'configuration':>42} {'rms err mdeg':>13} {'sigma mdeg':>11} {'mean z2':>8} {'full map':>9}")
    for configuration, delay, cross in (("general", 0.0, True), ("all_axes_parallel", 0.0, True),
                                        ("general", 0.002, True), ("all_axes_parallel", 0.002, True),
                                        ("general", 0.002, False)):
        res = [cross_axis_case(k, configuration, delay, cross) for k in range(runs)]
        name = configuration + (f" +{delay * 1e3:g} ms" if delay else "") + ("" if cross else ", no cross-axis")
        print(f"{name:>42} {np.sqrt(np.mean([r['err'] ** 2 for r in res])) / DEG * 1e3:13.1f} "
              f"{np.mean([r['sigma'] for r in res]) / DEG * 1e3:11.1f} {np.mean([r['z2'] for r in res]):8.2f} "
              f"{sum(r['full'] for r in res):>5d}/{runs}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--linear-map", default=None, help="the linear_map option (default: the library's default)")
    ap.add_argument("--robust-weights", default=None, help="the robust_weights option (default: the library's)")
    ap.add_argument("--pairs", default=None, help="comma-separated i-j pairs (1-based), default the 14 of issue 20")
    ap.add_argument("--sim", type=int, default=0, help="also simulate this many cross-axis pairs per configuration")
    ap.add_argument("--no-mimu", action="store_true")
    ap.add_argument("--broad", action="store_true", help="also the BROAD within-trial halves")
    ap.add_argument("--halves", action="store_true", help="also each MIMU session's halves, one against the other")
    a = ap.parse_args(argv)
    if a.sim:
        simulations(a.sim)
    keywords = {k: v for k, v in (("linear_map", a.linear_map), ("robust_weights", a.robust_weights)) if v is not None}
    if a.broad:
        broad_halves(keywords)
    if a.no_mimu:
        return 0
    d = shared_data_dir() / "mimu_8imu_array" / "npz"
    if not d.exists():
        print("MIMU: ../shared/data not present, nothing to measure")
        return 0
    from fusion_gyrocal.io import read_npz

    pairs = PAIRS if a.pairs is None else tuple(tuple(int(v) for v in p.split("-")) for p in a.pairs.split(","))
    sessions = [read_npz(d / f"exp_{e}.npz") for e in range(1, 10)]
    if a.halves:
        session_halves(sessions, pairs, keywords)
    print(f"MIMU board, 9 sessions, {len(pairs)} pairs, timestamps given, options {keywords or 'defaults'}")
    print(f"{'pair':>5} {'rms diff mdeg':>14} {'sigma mdeg':>11} {'mean z2':>8} {'max z2':>7} {'chi2/dof':>9} "
          f"{'inflation':>10} {'full':>6} {'max |K| %':>10} {'scale z2':>9}")
    rms_all, z2_all, scale_z2, per_pair, t0 = [], [], [], [], time.perf_counter()
    for i, j in pairs:
        cals = [calibrate_pair(s[i - 1].omega, s[j - 1].omega, t_1=s[i - 1].t, t_2=s[j - 1].t, **keywords)
                for s in sessions]
        per_pair.append(cals)
        rms, z2 = session_pairs(cals)
        sigma = np.mean([np.sqrt(np.trace(c.repeatable_rotation_covariance) / 3.0) for c in cals])
        n_full = sum(getattr(c, "linear_map", "rigid") == "full" for c in cals)
        model = f"{n_full}/9"
        K = max(float(np.abs(getattr(c, "cross_axis_terms", np.zeros(3))).max()) for c in cals)
        rms_all.append(rms)
        z2_all.append(z2)
        scale_z2.append(scale_pairs(cals))
        print(f"{i}-{j:<3} {rms / DEG * 1e3:14.1f} {sigma / DEG * 1e3:11.1f} {z2.mean():8.2f} {z2.max():7.1f} "
              f"{np.mean([c.lack_of_fit for c in cals]):9.3g} {np.mean([c.robust_inflation for c in cals]):10.3g} "
              f"{model:>6} {100 * K:10.2f} {scale_z2[-1]:9.2f}")
        sys.stdout.flush()
    rms_all = np.array(rms_all)
    print(f"all {len(pairs)} pairs: RMS session-to-session rotation difference "
          f"{np.sqrt(np.mean(rms_all ** 2)) / DEG * 1e3:.1f} mdeg ({rms_all.min() / DEG * 1e3:.0f}-"
          f"{rms_all.max() / DEG * 1e3:.0f} per pair); mean z2 {np.concatenate(z2_all).mean():.2f} (3 dof); "
          f"{time.perf_counter() - t0:.1f} s")
    print(f"relative scale factors (scale_2 / scale_1 on parallel axes), session to session: mean z2 per axis "
          f"{np.mean(scale_z2):.2f} ({min(scale_z2):.2f}-{max(scale_z2):.2f} per pair; 1 is honest)")
    if len(sessions) >= 3:
        consistency(per_pair, pairs)
        site_check(per_pair, pairs, lambda k, l: [calibrate_pair(s[k - 1].omega, s[l - 1].omega, t_1=s[k - 1].t,
                                                                 t_2=s[l - 1].t, **keywords) for s in sessions], d.parent)
    return 0


if __name__ == "__main__":
    sys.exit(main())
