"""``gyrocal demo``: calibrate a built-in simulated pair and print it beside the truth."""

from __future__ import annotations

import argparse

from .app import EXIT_OK


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``demo``."""
    p = subparsers.add_parser("demo", help="calibrate a built-in simulated pair and print it beside the truth")
    p.add_argument("--seed", type=int, default=7)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    """60 s of simulated hand-held motion, two clocks and rates; the estimate beside the truth."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from ..evaluate.sim import PAPER_NOISE_STD, HumanMotion, random_rotation
    from ..pipeline.pipeline import run_pipeline
    from ..io.report import uncertainty_basis
    from .display import console as make_console, summary_table

    rng = np.random.default_rng(args.seed)
    motion = HumanMotion(0.8, rng=rng)
    R = random_rotation(rng)
    s1, s2 = np.array([1.004, 0.997, 1.002]), np.array([0.995, 1.006, 1.001])
    b1, b2 = np.deg2rad([0.4, -0.2, 0.1]), np.deg2rad([-0.3, 0.5, 0.2])
    offset = 0.0473  # gyro 2's clock runs 47.3 ms behind gyro 1's
    t1 = np.arange(0, 60, 1 / 200.0)                                           # gyro 1: 200 Hz
    t2 = np.arange(0.013, 60, 1 / 100.0) + rng.normal(0, 2e-4, 5999)[: len(np.arange(0.013, 60, 1 / 100.0))]
    t2.sort()
    w1 = motion(t1) * s1 + b1 + rng.normal(0, PAPER_NOISE_STD, (t1.size, 3))
    w2 = (motion(t2 + offset) @ R) * s2 + b2 + rng.normal(0, PAPER_NOISE_STD, (t2.size, 3))
    cal = run_pipeline(w1, w2, t_1=t1, t_2=t2, noise_std=PAPER_NOISE_STD).calibration
    lam = s1[0] / s2[0]  # the unit-prior gauge (Eq. 34) applied to the truth, for a like-for-like comparison
    c = (lam + 1) / (lam**2 + 1) / s2[0]
    A = (s1[:, None] * R) / s2[None, :]
    truth = {"rotvec": Rotation.from_matrix(R).as_rotvec(), "scale_1": s1 * c, "scale_2": s2 * c,
             "bias": b1 - A @ b2, "time_offset_s": offset}
    console = make_console()
    console.print("Demo: a simulated gyro pair (60 s of hand-held motion, gyro 1 at 200 Hz, gyro 2 at 100 Hz with "
                  "timestamp jitter, 47.3 ms clock offset, noise 0.1 deg/s per sample)")
    console.print(summary_table(cal, truth))
    console.print(uncertainty_basis(cal))
    err = np.rad2deg(np.linalg.norm(Rotation.from_matrix(cal.R_1_2 @ R.T).as_rotvec())) * 1e3
    console.print(f"rotation error {err:.2f} mdeg (1-sigma {np.rad2deg(np.linalg.norm(cal.rotation_std_rad)) * 1e3:.2f}"
                  f" mdeg); time offset error {(cal.time_offset_s - offset) * 1e6:+.1f} us")
    return EXIT_OK
