"""End-to-end time of ``gyrocal calibrate`` on a one-hour, 200 Hz CSV pair.

Writes two CSV files (t, gyro_x, gyro_y, gyro_z; gyro 2 in deg/s on a clock 37.1 ms behind),
then measures in one run:
* the whole command (``gyrocal calibrate a.csv b.csv --unit2 deg/s``, in-process),
* its parts: reading both files, alignment (offset estimate + resampling), solving (moments,
  ML, flex checks),
* beside the time pandas and pyarrow need just to read the same two files,
and the ratios to the pandas read (the whole command; alignment + solving, this library's pipeline;
reading, its readers). Every row is the best of 3.

    python benchmarks/end_to_end.py [--minutes 60] [--dir /tmp/gyrocal_e2e]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np
from _timing import best_of  # noqa: E402  (benchmarks/ is the script's folder)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # this checkout's package, in-process and in the subprocesses (not an installed one)


def make_files(d: Path, minutes: float, rate=200.0, seed=0):
    from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, HumanMotion, random_rotation

    rng = np.random.default_rng(seed)
    motion, R = HumanMotion(0.6, rng=rng), random_rotation(rng)
    t = np.arange(0, minutes * 60.0, 1.0 / rate)
    w1 = motion(t) + rng.normal(0, PAPER_NOISE_STD, (t.size, 3)) + 0.004
    w2 = np.rad2deg(motion(t + 0.0371) @ R + rng.normal(0, PAPER_NOISE_STD, (t.size, 3)) - 0.002)
    d.mkdir(parents=True, exist_ok=True)
    for name, w in (("a.csv", w1), ("b.csv", w2)):
        np.savetxt(d / name, np.column_stack([t, w]), delimiter=",", fmt="%.9f",
                   header="t,gyro_x,gyro_y,gyro_z", comments="")
    return d / "a.csv", d / "b.csv", t.size


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--dir", default="/tmp/gyrocal_e2e")
    a = ap.parse_args(argv)
    p1, p2, n = make_files(Path(a.dir), a.minutes)
    print(f"{n} samples per file ({a.minutes:g} min at 200 Hz), {p1.stat().st_size / 2**20:.1f} MB per CSV")

    from fusion_gyrocal.pipeline.pipeline import run_pipeline
    from fusion_gyrocal.cli import main as cli
    from fusion_gyrocal.io import read_imu
    from fusion_gyrocal.pipeline.alignment import align_streams
    from fusion_gyrocal.pipeline.streams import valid_mask

    t_read, (s1, s2) = best_of(lambda: (read_imu(p1), read_imu(p2, unit="deg/s")))
    t_align, pair = best_of(lambda: align_streams(s1.t, s1.omega, s2.t, s2.omega, valid_1=valid_mask(s1.omega),
                                                valid_2=valid_mask(s2.omega)))
    w1 = np.where(pair.valid[:, None], pair.omega_1, 0.0)
    w2 = np.where(pair.valid[:, None], pair.omega_2, 0.0)
    t_solve, run = best_of(lambda: run_pipeline(w1, w2, mask=pair.valid))
    t_cli, code = best_of(lambda: cli(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--output",
                                     str(Path(a.dir) / "cal.json")]))
    rows = [("gyrocal calibrate (whole command)", t_cli), ("  reading both files (fusion_gyrocal.io)", t_read),
            ("  alignment (offset + resampling)", t_align), ("  solving (moments, ML, flex checks)", t_solve)]
    try:
        import pandas as pd
        t_pd, _ = best_of(lambda: (pd.read_csv(p1), pd.read_csv(p2)))
        rows.append(("pandas.read_csv of both files", t_pd))
    except ImportError:
        pass
    try:
        import pyarrow.csv as pacsv
        t_pa, _ = best_of(lambda: (pacsv.read_csv(p1), pacsv.read_csv(p2)))
        rows.append(("pyarrow.csv.read_csv of both files", t_pa))
    except ImportError:
        pass
    print(f"exit code {code}; offset {run.calibration.time_offset_s if pair.time_offset is None else pair.time_offset_s:.6f} s"
          " (best of 3 for every row)")
    for name, t in rows:
        print(f"{name:<45} {t:8.3f} s")
    # as a user sees it: whole processes (interpreter start and imports included), as in issue 14
    import subprocess

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (str(ROOT), os.environ.get("PYTHONPATH"))))}

    def process(args):
        return best_of(lambda: subprocess.run([sys.executable, *args], check=True, capture_output=True, env=env))[0]

    p_cli = process(["-m", "fusion_gyrocal.cli", "calibrate", str(p1), str(p2), "--unit2", "deg/s", "--output",
                     str(Path(a.dir) / "cal.json")])
    p_pd = process(["-c", f"import pandas as pd; pd.read_csv({str(p1)!r}); pd.read_csv({str(p2)!r})"])
    print(f"{'process: gyrocal calibrate a.csv b.csv':<45} {p_cli:8.3f} s")
    print(f"{'process: python, import pandas, read both':<45} {p_pd:8.3f} s")
    print(f"process ratio                                 {p_cli / p_pd:8.2f} x (target <= 2, issue 25)")
    t_ref = dict(rows).get("pandas.read_csv of both files")
    if t_ref:
        print(f"whole command / pandas read                   {t_cli / t_ref:8.2f} x (target <= 2, issue 25)")
        print(f"(alignment + solving) / pandas read           {(t_align + t_solve) / t_ref:8.2f} x  (the pipeline)")
        print(f"reading (fusion_gyrocal.io) / pandas read     {t_read / t_ref:8.2f} x  (the readers' part)")


if __name__ == "__main__":
    main()
