"""End-to-end time of ``gyrocal calibrate`` on a one-hour, 200 Hz CSV pair.

Writes two CSV files (t, gyro_x, gyro_y, gyro_z; gyro 2 in deg/s on a clock 37.1 ms behind),
then measures in one run:

* as a user sees it (the comparison of issue 25's target): the whole ``gyrocal calibrate a.csv b.csv --unit2
  deg/s`` process beside ``python -c "import pandas; read both files"``, interpreter start and imports included,
  over interleaved rounds after a warm-up; wall time and the children's CPU time (user + system: on a shared
  machine the wall time also counts other processes' turns), with the ratio's spread over the rounds, and the
  command's imports (one ``-X importtime`` run: their sum, scipy's part);
* in this process (imports done): the whole command, its parts (reading both files, alignment: offset estimate
  + resampling, and of that the checks and resampling alone with the offset given; solving: moments, ML, flex
  checks) beside the time pandas and pyarrow need just to read the
  same two files, and the ratios to the pandas read. Every in-process row is the best of 3.

    python benchmarks/end_to_end.py [--minutes 60] [--dir /tmp/gyrocal_e2e] [--rounds 5]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
from _timing import best_of, installed_like_env  # noqa: E402  (benchmarks/ is the script's folder)

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


def wall_and_cpu(f, k: int = 3):
    """``(best wall s, best CPU s of this process, the last result)`` of ``k`` calls of ``f``."""
    wall, cpu, out = float("inf"), float("inf"), None
    for _ in range(k):
        t0, c0 = time.perf_counter(), time.process_time()
        out = f()
        wall, cpu = min(wall, time.perf_counter() - t0), min(cpu, time.process_time() - c0)
    return wall, cpu, out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--dir", default="/tmp/gyrocal_e2e")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds of the two processes")
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
    t_given, _ = best_of(lambda: align_streams(s1.t, s1.omega, s2.t, s2.omega, valid_1=valid_mask(s1.omega),
                                               valid_2=valid_mask(s2.omega), time_offset_s=pair.time_offset_s))
    w1 = np.where(pair.valid[:, None], pair.omega_1, 0.0)
    w2 = np.where(pair.valid[:, None], pair.omega_2, 0.0)
    t_solve, run = best_of(lambda: run_pipeline(w1, w2, mask=pair.valid))
    t_cli, c_cli, code = wall_and_cpu(lambda: cli(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--output",
                                                  str(Path(a.dir) / "cal.json")]))
    cpu = {"cli": c_cli}
    rows = [("gyrocal calibrate (whole command)", t_cli), ("  reading both files (fusion_gyrocal.io)", t_read),
            ("  alignment (offset + resampling)", t_align),
            ("    of which checks + resampling (offset given)", t_given),
            ("  solving (moments, ML, flex checks)", t_solve)]
    try:
        import pandas as pd
        t_pd, cpu["pandas.read_csv of both files"], _ = wall_and_cpu(lambda: (pd.read_csv(p1), pd.read_csv(p2)))
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
    # as a user sees it: whole processes (interpreter start and imports included), as in issue 14. The package's
    # bytecode is cached as an installed package's is (pip compiles it; Python caches it on first import): this
    # checkout runs with its own bytecode cache in a temporary folder, filled by a warm-up run, also where the
    # environment sets PYTHONDONTWRITEBYTECODE. Rounds interleave the two commands so both see the same load.
    import resource
    import subprocess

    env = installed_like_env(ROOT)
    cache = env["PYTHONPYCACHEPREFIX"]

    def process(args):
        """(wall s, CPU s of the child: user + system) of one run."""
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, *args], check=True, capture_output=True, env=env)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)

    cli_args = ["-m", "fusion_gyrocal.cli", "calibrate", str(p1), str(p2), "--unit2", "deg/s", "--output",
                str(Path(a.dir) / "cal.json")]
    pd_args = ["-c", f"import pandas as pd; pd.read_csv({str(p1)!r}); pd.read_csv({str(p2)!r})"]
    process(cli_args), process(pd_args)                 # warm-up: bytecode cache, file cache
    runs = [(process(cli_args), process(pd_args)) for _ in range(a.rounds)]
    (cw, cc), (pw, pc) = [(min(r[i][0] for r in runs), min(r[i][1] for r in runs)) for i in (0, 1)]
    wall_ratios = sorted(c[0] / p[0] for c, p in runs)
    cpu_ratios = sorted(c[1] / p[1] for c, p in runs)
    print(f"\nprocesses ({a.rounds} interleaved rounds after a warm-up; best wall and best CPU of each; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)")
    print(f"{'process: gyrocal calibrate a.csv b.csv':<45} {cw:8.3f} s wall {cc:8.3f} s CPU")
    print(f"{'process: python, import pandas, read both':<45} {pw:8.3f} s wall {pc:8.3f} s CPU")
    print(f"process ratio, wall                           {cw / pw:8.2f} x (target <= 2, issue 25; per round "
          f"{wall_ratios[0]:.2f}-{wall_ratios[-1]:.2f}, median {float(np.median(wall_ratios)):.2f})")
    print(f"process ratio, CPU time                       {cc / pc:8.2f} x (per round {cpu_ratios[0]:.2f}-"
          f"{cpu_ratios[-1]:.2f}, median {float(np.median(cpu_ratios)):.2f})")
    # where the command's process spends its imports: one more run with -X importtime (its own overhead
    # included), the top-level imports summed, scipy's named apart (it loads with the first spline and the noise fit)
    trace = subprocess.run([sys.executable, "-X", "importtime", *cli_args], check=True, capture_output=True,
                           env=env, text=True).stderr
    top = {}
    for line in trace.splitlines():
        parts = line.split("|")
        if line.startswith("import time:") and len(parts) == 3 and parts[1].strip().isdigit() \
                and not parts[2].startswith("  "):
            top[parts[2].strip()] = 1e-6 * int(parts[1])
    scipy_s = sum(v for k, v in top.items() if k.split(".")[0] == "scipy")
    print(f"{'process: imports (one -X importtime run)':<45} {sum(top.values()):8.3f} s, of which scipy "
          f"{scipy_s:.3f} s ({', '.join(f'{k} {v:.3f}' for k, v in top.items() if k.split('.')[0] == 'scipy')})")
    shutil.rmtree(cache, ignore_errors=True)
    t_ref = dict(rows).get("pandas.read_csv of both files")
    if t_ref:
        print("\nin this process (imports done):")
        print(f"whole command / pandas read                   {t_cli / t_ref:8.2f} x")
        print(f"(alignment + solving) / pandas read           {(t_align + t_solve) / t_ref:8.2f} x  (the pipeline)")
        print(f"reading (fusion_gyrocal.io) / pandas read     {t_read / t_ref:8.2f} x  (the readers' part)")
        c_ref = cpu.get("pandas.read_csv of both files")
        if c_ref:
            print(f"whole command / pandas read, CPU time         {cpu['cli'] / c_ref:8.2f} x")


if __name__ == "__main__":
    main()
