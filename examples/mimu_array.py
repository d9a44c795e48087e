"""Joint calibration of the 8-IMU MIMU4444 array (../shared/data/mimu_8imu_array).

All eight gyros are axis-parallel (top side: identity, bottom side: a 180 degree flip), the paper's
fully degenerate case (Lemma 2): only the rotations and the per-axis scale ratios
``scale_1[i] / scale_k[perm(i)]`` are determined. For every session this script calibrates the
whole array jointly (:func:`fusion_gyrocal.core.array.calibrate_array`) and every gyro against IMU 1
pairwise (:func:`fusion_gyrocal.solve` on the same moments), both with the defaults: the sensor model the data
call for, here the full linear map with every gyro's relative cross-axis terms (they are 0.1-2 % on this board),
and prints

* each gyro's deviation from its nominal rotation (degrees),
* the per-axis ratios, their mean over axes, and the "gain" table of SOURCE.md,
* the largest cross-axis term of every gyro against IMU 1 (%),
* the spread of both estimates over the sessions. With the full map on this axis-parallel board every gyro's map
  to the reference has as many parameters as entries, so the joint estimate is the pairwise one up to the weights
  (the rotations' spread agrees to a few percent); with ``linear_map="rigid"`` the joint one is the steadier.

Run: ``python examples/mimu_array.py [--sessions 1 2 ...]``.
"""

from __future__ import annotations

import argparse
import re
import sys
import time

import numpy as np
from scipy.spatial.transform import Rotation

from fusion_gyrocal import solve
from fusion_gyrocal.io import read_npz
from fusion_gyrocal.core.array import calibrate_array
from fusion_gyrocal.evaluate.sim import DEG, shared_data_dir

C_BOTTOM = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # SOURCE.md, bottom-side IMUs


def source_gains(folder) -> np.ndarray:
    """Gain means of IMU 2..8 from the consensus table of SOURCE.md (gain = ||omega_1|| / ||R omega_k||)."""
    text = (folder / "SOURCE.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\|\s*(\d)\s*\|\s*[CI]\s*\|.*\|\s*([0-9.]+)\s*±\s*[0-9.]+\s*\|\s*$", text, flags=re.M)
    gains = {int(k): float(g) for k, g in rows}
    if sorted(gains) != list(range(2, 9)):
        raise ValueError(f"SOURCE.md: expected gain rows for IMU 2..8, got IMU {sorted(gains)}")
    return np.array([gains[k] for k in range(2, 9)])


def summarise(R, s_ref, s_k, nominal):
    dev = Rotation.from_matrix(nominal.T @ R).as_rotvec() / DEG
    ratio = s_ref / s_k[np.argmax(np.abs(R), axis=1)]  # Lemma 2: scale_1[i] / scale_k[perm(i)]
    return dev, ratio


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, nargs="+", default=list(range(1, 10)))
    args = parser.parse_args(argv)
    folder = shared_data_dir() / "mimu_8imu_array"
    if not folder.exists():
        print(f"{folder} not found (real recordings are only in the project checkout)")
        return {}
    gains = source_gains(folder)
    res = {"joint": ([], []), "pairwise": ([], [])}
    for e in args.sessions:
        streams = read_npz(folder / "npz" / f"exp_{e}.npz")  # 8 IMUs, rad/s; clipped samples flagged invalid
        rates = np.stack([s.omega for s in streams], axis=1)
        mask = np.all([s.valid for s in streams], axis=0)
        t0 = time.perf_counter()
        cal = calibrate_array(rates, mask=mask)
        dt = time.perf_counter() - t0
        print(f"\nsession {e}: {cal.n_samples} of {len(mask)} samples unsaturated, joint solve {dt:.2f} s, "
              f"{cal.iterations} iterations, noise per gyro (deg/s) {np.round(cal.noise_std / DEG, 2).tolist()}")
        print("  IMU  joint dev from nominal (deg)   per-axis ratio (x, y, z)        mean     SOURCE gain  "
              "max |K| %  | pairwise mean")
        for name in res:
            res[name][0].append([])
            res[name][1].append([])
        for k in range(1, 8):
            nominal = C_BOTTOM if k % 2 == 1 else np.eye(3)
            dj, rj = summarise(cal.R_ref_k[k], cal.scale[0], cal.scale[k], nominal)
            pc = solve(cal.moments.pair(0, k))
            dp, rp = summarise(pc.R_1_2, pc.scale_1, pc.scale_2, nominal)
            for name, d, r in (("joint", dj, rj), ("pairwise", dp, rp)):
                res[name][0][-1].append(d)
                res[name][1][-1].append(r)
            print(f"  {k + 1}    {np.array2string(dj, precision=3, sign=' '):28s} "
                  f"{np.array2string(rj, precision=4):30s} {rj.mean():.4f}   {gains[k - 1]:.4f}       "
                  f"{100 * np.abs(cal.cross_axis_terms[k]).max():9.2f}  | {rp.mean():.4f}")
    out = {name: (np.array(d), np.array(r)) for name, (d, r) in res.items()}
    dev_j, rat_j = out["joint"]
    dev_p, rat_p = out["pairwise"]
    mean_j = rat_j.mean(axis=2)
    print(f"\nover {len(args.sessions)} session(s):")
    print(f"  largest rotation deviation from nominal: joint {np.linalg.norm(dev_j, axis=2).max():.3f} deg, "
          f"pairwise {np.linalg.norm(dev_p, axis=2).max():.3f} deg")
    print(f"  ratio mean over axes vs SOURCE gain: per session worst {100 * np.abs(mean_j / gains - 1).max():.3f} %, "
          f"session average worst {100 * np.abs(mean_j.mean(0) / gains - 1).max():.3f} %")
    if len(args.sessions) > 1:
        print(f"  spread over sessions (mean std): rotation joint {dev_j.std(0).mean():.5f} deg vs pairwise "
              f"{dev_p.std(0).mean():.5f} deg; ratios joint {rat_j.std(0).mean():.6f} vs pairwise "
              f"{rat_p.std(0).mean():.6f}")
    return out


if __name__ == "__main__":
    main(sys.argv[1:])
