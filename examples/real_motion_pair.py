"""Synthesise a second gyro from REAL recorded hand-held motion (BROAD, CC BY 4.0) and calibrate.

The second gyro sees the recorded rates rotated, scaled, biased, delayed by 83.7 ms on its own
clock and sampled with fresh noise, as in the paper's simulations (which used recorded human motion).

    python examples/real_motion_pair.py
"""

import numpy as np

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, load_broad_rates, random_rotation, rotation_error, simulate_pair


def main(trial: str = "06_undisturbed_fast_rotation_A", seed: int = 3) -> dict:
    gyr, fs = load_broad_rates(trial)  # Laidig et al., Data 6(7):72, 2021
    R = random_rotation(seed)
    sim = simulate_pair(gyr, R_1_2=R, scale_1=(1.0, 1.003, 0.998), scale_2=(1.004, 0.996, 1.001), rate_hz=fs,
                        rng=seed)
    t = np.arange(len(gyr)) / fs
    offset = 0.0837
    cal = calibrate_pair(sim.omega_1, sim.omega_2, t_1=t, t_2=t - offset, noise_std=PAPER_NOISE_STD)
    err = rotation_error(cal.R_1_2, R)
    print(f"BROAD trial {trial}: {len(gyr)} samples at {fs:.1f} Hz")
    print(f"rotation error {np.rad2deg(err) * 1e3:.3f} mdeg (1-sigma {np.rad2deg(np.linalg.norm(cal.rotation_std_rad)) * 1e3:.3f})")
    print(f"time offset {cal.time_offset_s * 1e3:.4f} ms (truth {offset * 1e3:.4f} ms, 1-sigma {cal.time_offset_std_s * 1e6:.2f} us)")
    print(f"scale ratios estimated {np.round(np.concatenate([cal.scale_1, cal.scale_2]) / cal.scale_1[0], 5)}")
    print(f"scale ratios true      {np.round(np.concatenate([sim.scale_1, sim.scale_2]) / sim.scale_1[0], 5)}")
    return {"rotation_error": err, "calibration": cal, "offset": offset}


if __name__ == "__main__":
    main()
