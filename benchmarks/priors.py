"""Scale priors on the axis-parallel MIMU board, and the excitation test on one-axis motion (issue 12).

1. MIMU board (../shared/data/mimu_8imu_array, 9 sessions, 62.5 Hz, every pair all axes parallel, Lemma 2):
   IMU 1 against IMUs 2, 3 and 6 through ``calibrate_pair`` with ``scale_prior_std=0.01`` and without.
   Per pair: the range of the six scale factors with the prior, the largest change of a determined ratio
   (``scale_1[i] / scale_2[j]`` of a parallel pair) against the no-prior solution, the prior-held scale std,
   the smallest covariance eigenvalue (relative to the largest) and the exit state (rigid, configuration).
2. One-axis motion with the noise not given: the smallest SNR of a principal direction of the motion that
   gyro 2 explains (what ``check_excitation`` judges) and of gyro 1's noise-corrected scatter with the
   noise estimated from the residual (what it judged before), for simulated human motion at several
   lengths and for the ten BROAD hand-held trials projected on one axis; then whether ``calibrate_pair``,
   ``calibrate_array`` and ``StreamingCalibrator`` raise ``ExcitationError``.
3. Where the test draws the line: one axis of simulated motion (6000 samples) scaled down; the paper's SNR of
   that axis (true noise), the fraction of ``--runs`` realisations that raise ``ExcitationError`` or another
   error, and the rotation error of those that pass.

    python benchmarks/priors.py [--runs 20]
"""

from __future__ import annotations

import argparse

import numpy as np

from fusion_gyrocal import ExcitationError, GyroCalError, Moments, calibrate_pair
from fusion_gyrocal.core.array import calibrate_array
from fusion_gyrocal.core.direct import solve_A
from fusion_gyrocal.core.observability import classify, explained_scatter, signal_scatter
from fusion_gyrocal.core.solve import _residual_noise
from fusion_gyrocal.evaluate.sim import (PAPER_NOISE_STD, HumanMotion, load_broad_rates, random_rotation,
                                         rotation_error, shared_data_dir, simulate_pair)
from fusion_gyrocal.online.stream import StreamingCalibrator

AXIS = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])


def _ratios(cal):
    return np.array([cal.scale_1[i] / cal.scale_2[j] for i, j, _ in classify(cal.R_1_2).parallel_pairs])


def mimu():
    from fusion_gyrocal.io import read_npz

    folder = shared_data_dir() / "mimu_8imu_array" / "npz"
    if not folder.exists():
        print(f"MIMU: {folder} not present, skipped")
        return
    print("1. MIMU board, IMU 1 against IMU k, scale_prior_std=0.01 (no-prior gauge: unit prior on the x axes)")
    print(f"{'exp':>4} {'IMU':>4} {'config':>18} {'rigid':>6} {'scales min..max':>17} {'max|s-1| %':>10} "
          f"{'ratio change %':>14} {'prior std %':>11} {'min eig/max':>12}")
    worst_s, worst_r = 0.0, 0.0
    for e in range(1, 10):
        streams = read_npz(folder / f"exp_{e}.npz")
        for k in (1, 2, 5):
            a, b = streams[0], streams[k]
            free = calibrate_pair(a.omega, b.omega, t_1=a.t, t_2=b.t)
            cal = calibrate_pair(a.omega, b.omega, t_1=a.t, t_2=b.t, scale_prior_std=0.01)
            s = np.concatenate([cal.scale_1, cal.scale_2])
            dr = float(np.max(np.abs(_ratios(cal) / _ratios(free) - 1.0)))
            w = np.linalg.eigvalsh(cal.covariance)
            worst_s, worst_r = max(worst_s, float(np.max(np.abs(s - 1)))), max(worst_r, dr)
            print(f"{e:>4} {k + 1:>4} {cal.configuration:>18} {str(cal.rigid):>6} {s.min():8.4f}..{s.max():.4f} "
                  f"{100 * np.max(np.abs(s - 1)):10.3f} {100 * dr:14.2e} {100 * cal.scale_std.max():11.3f} "
                  f"{w.min() / w.max():12.2e}")
    print(f"   worst over 27 pairs: max |scale - 1| = {100 * worst_s:.3f} %, determined ratio change = "
          f"{100 * worst_r:.2e} %")


def _snrs(w1, w2):
    m = Moments.from_samples(w1, w2)
    noise = _residual_noise(m, solve_A(m)[0])
    sigma = float(np.hypot(*noise))
    old = np.sqrt(np.clip(np.linalg.eigvalsh(signal_scatter(m, noise)[0]), 0, None)) / sigma
    new = np.sqrt(np.clip(np.linalg.eigvalsh(explained_scatter(m)), 0, None)) / sigma
    return old[0], new[0]


def _raises(w1, w2):
    out = []
    for f in (lambda: calibrate_pair(w1, w2), lambda: calibrate_array([w1, w2]), lambda: _stream(w1, w2)):
        try:
            f()
            out.append("passes")
        except ExcitationError:
            out.append("Excitation")
        except Exception as err:  # noqa: BLE001  (the figure is which error, if any)
            out.append(type(err).__name__)
    return out


def _stream(w1, w2):
    cal = StreamingCalibrator()
    cal.update(w1, w2)
    return cal.estimate()


def one_axis():
    print("\n2. One-axis motion, noise not given: smallest direction SNR (old: gyro 1's scatter less N sigma^2 "
          "with the residual noise; new: the scatter gyro 2 explains), and what the three APIs do")
    print(f"{'case':>40} {'N':>7} {'old SNR':>8} {'new SNR':>8} {'pair':>11} {'array':>11} {'stream':>11}")
    rng = np.random.default_rng(0)
    for n in (2000, 6000, 60000):
        motion = HumanMotion(rng=rng)(np.arange(n) / 100.0)[:, 0]
        w = motion[:, None] * AXIS
        R = random_rotation(rng)
        w1 = w + rng.normal(0, PAPER_NOISE_STD, w.shape)
        w2 = w @ R + rng.normal(0, PAPER_NOISE_STD, w.shape)
        old, new = _snrs(w1, w2)
        print(f"{'simulated human motion':>40} {n:>7} {old:8.3g} {new:8.3g} " + " ".join(f"{r:>11}" for r in _raises(w1, w2)))
    if not (shared_data_dir() / "broad_handheld").exists():
        print("   BROAD: not present, skipped")
        return
    for trial in sorted(p.stem for p in (shared_data_dir() / "broad_handheld" / "data_mat").glob("*.mat")):
        gyr, _ = load_broad_rates(trial)
        w = (gyr @ AXIS)[:, None] * AXIS
        R = random_rotation(rng)
        w1 = w + rng.normal(0, 1e-3, w.shape)
        w2 = w @ R + rng.normal(0, 1e-3, w.shape)
        old, new = _snrs(w1, w2)
        print(f"{'BROAD ' + trial:>40} {len(w):>7} {old:8.3g} {new:8.3g} " + " ".join(f"{r:>11}" for r in _raises(w1, w2)))


def threshold(runs):
    print(f"\n3. A weak but real x axis (6000 samples, noise {PAPER_NOISE_STD:.3g} rad/s, noise estimated): "
          f"fraction of {runs} runs that raise")
    print(f"{'x RMS / noise':>14} {'paper SNR of x (median)':>24} {'Excitation':>11} {'other error':>12} "
          f"{'x rotation error deg (median of passes)':>40}")
    for amp in (0.0, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0, 2.0):
        snrs, raised, other, errors = [], 0, 0, []
        for k in range(runs):
            rng = np.random.default_rng([7, k])
            w = HumanMotion(rng=rng)(np.arange(6000) / 100.0)
            w[:, 0] *= amp * PAPER_NOISE_STD / np.sqrt(np.mean(w[:, 0] ** 2))
            sim = simulate_pair(w, rng=rng)
            x = w[:, 0] - w[:, 0].mean()
            snrs.append(np.sqrt(x @ x) / np.hypot(PAPER_NOISE_STD, PAPER_NOISE_STD))
            try:
                cal = calibrate_pair(sim.omega_1, sim.omega_2)
                errors.append(np.rad2deg(rotation_error(cal.R_1_2, sim.R_1_2)))
            except ExcitationError:
                raised += 1
            except GyroCalError:
                other += 1
        med = f"{np.median(errors):.3g}" if errors else "-"
        print(f"{amp:>14.2f} {np.median(snrs):>24.3g} {raised / runs:>11.2f} {other / runs:>12.2f} {med:>40}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=20)
    a = ap.parse_args(argv)
    mimu()
    one_axis()
    threshold(a.runs)


if __name__ == "__main__":
    main()
