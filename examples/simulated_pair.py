"""Calibrate a simulated gyro pair (the paper's protocol) and compare with the truth.

    python examples/simulated_pair.py
"""

import numpy as np

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, random_rotation, rotation_error, scale_error, simulate_pair


def main(seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    R = random_rotation(rng)
    sim = simulate_pair(n=6000, R_1_2=R, scale_1=(1.01, 0.99, 1.02), scale_2=(0.98, 1.0, 1.03), rng=rng)
    out = {}
    for method in ("direct", "ml"):
        cal = calibrate_pair(sim.omega_1, sim.omega_2, method=method, noise_std=PAPER_NOISE_STD)
        rot = rotation_error(cal.R_1_2, R)
        sc = scale_error(cal.scale_1, cal.scale_2, sim.scale_1, sim.scale_2)
        print(f"{method:>6}: rotation error {np.rad2deg(rot) * 1e3:7.3f} mdeg "
              f"(1-sigma {np.rad2deg(np.linalg.norm(cal.rotation_std_rad)) * 1e3:.3f}), scale error {100 * sc:.4f} %, "
              f"configuration {cal.configuration}, iterations {cal.iterations}")
        out[method] = (rot, sc, cal)
    return out


if __name__ == "__main__":
    main()
