"""Throughput of the Dask fleet run and of the distributed huge-log reduction on this machine.

Prints measured figures (nothing is hard-coded):

1. ``run_fleet`` over generated Parquet devices against the serial loop in this process
   (``device_row`` of each device in turn): on ``fleet_cluster`` (what ``gyrocal fleet`` starts) with 1 and
   with 2 worker processes (one thread each), on a ``LocalCluster`` with distributed's defaults, and on
   Dask's threaded scheduler in this process: seconds, devices/s and each as a ratio to the serial loop,
   over ``--rounds`` interleaved rounds (each cluster started for its turn and closed after it, so no idle
   cluster takes CPU time from the one measured; a warm-up run pays the workers' imports; targets:
   2 workers <= 0.65x, 1 worker <= 1.15x).
2. One huge Parquet log: the in-process pass (read the whole file, ``Moments.from_samples``)
   versus ``log_moments`` (one task per row group, ``dask.bag`` tree reduction of
   ``Moments.merge``) on 1 and 2 workers: samples/s, and the largest relative difference of the
   reduced statistics from the in-process ones.

Run: ``python benchmarks/fleet.py [--devices 24 --device-samples 60000 --log-samples 6000000] [--fleet-only]``.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # this checkout's package, here and in the workers (not an installed one)
os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, (str(ROOT), os.environ.get("PYTHONPATH"))))

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from _timing import best_of  # noqa: E402  (benchmarks/ is the script's folder)
import pyarrow as pa  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402
from distributed import Client, LocalCluster  # noqa: E402

from fusion_gyrocal import Moments  # noqa: E402
from fusion_gyrocal.distributed.fleet import (COLUMNS, device_row, find_devices, fleet_cluster, log_moments,  # noqa: E402
                                              run_fleet)
from fusion_gyrocal.evaluate.sim import simulate_pair  # noqa: E402


def write_log(path: Path, n: int, *, seed: int, row_group_size: int, base: int = 200_000) -> None:
    """A sample-aligned Parquet log of ``n`` rows: a simulated pair of ``base`` samples, repeated with fresh noise."""
    rng = np.random.default_rng(seed)
    sim = simulate_pair(rng=rng, n=min(base, n))
    writer = pq.ParquetWriter(path, pa.schema([(c, pa.float64()) for c in COLUMNS]))
    try:
        for start in range(0, n, sim.omega_1.shape[0]):
            m = min(sim.omega_1.shape[0], n - start)
            noise = rng.normal(0.0, 1e-4, (m, 6))
            data = {"t": (start + np.arange(m)) / 100.0}
            for g, w in (("1", sim.omega_1[:m]), ("2", sim.omega_2[:m])):
                for a, ax in enumerate("xyz"):
                    data[f"w{g}{ax}"] = w[:, a] + noise[:, 3 * (g == "2") + a]
            writer.write_table(pa.table(data), row_group_size=row_group_size)
    finally:
        writer.close()


def bench_fleet(root: Path, n_devices: int, n_samples: int, repeat: int, rounds: int) -> None:
    for i in range(n_devices):
        write_log(root / f"device_{i:03d}.parquet", n_samples, seed=i, row_group_size=n_samples, base=n_samples)
    paths = find_devices([root])
    total = n_devices * n_samples
    print(f"\n1. fleet: {n_devices} Parquet devices x {n_samples} samples (calibrate_pair per device, defaults); "
          f"best of {repeat} per round after a warm-up run, {rounds} interleaved rounds")

    def serial():
        return pd.DataFrame([device_row(p) for p in paths])

    local = functools.partial(LocalCluster, n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                              dashboard_address=None)
    # label: (the cluster's factory or None for an in-process engine, the run without a client)
    engines = {"serial loop, this process": (None, serial),
               "threaded scheduler, this process": (None, lambda: run_fleet(root)),
               "fleet_cluster, 1 worker process": (lambda: fleet_cluster(1), None),
               "fleet_cluster, 2 worker processes": (lambda: fleet_cluster(2), None),
               "LocalCluster defaults, 2 workers": (local, None)}
    times = {k: [] for k in engines}
    checks, where = {}, set()
    for _ in range(rounds):
        for label, (make, run) in engines.items():
            # one cluster at a time: idle schedulers, nannies and workers of the others would take ~10 % of a
            # core each (their event loops' ticks, memory monitors) from the one measured
            with contextlib.ExitStack() as stack:
                if make is not None:
                    client = stack.enter_context(Client(stack.enter_context(make())))
                    run = functools.partial(run_fleet, root, client=client)
                    where |= set(client.run(lambda: __import__("fusion_gyrocal").__file__).values())
                run()  # warm-up: imports in this process or in every worker, file cache
                dt, df = best_of(run, repeat)
            times[label].append(dt)
            checks[label] = (int(df["ok"].sum()), len(df), float(df["seconds"].sum()))
    print(f"   package in this process: {__import__('fusion_gyrocal').__file__}; in the workers: {sorted(where)}")
    ref = times["serial loop, this process"]
    print(f"   {'engine':36s} {'seconds':>8s} {'devices/s':>10s} {'Msamples/s':>11s} {'/ serial':>9s} "
          f"{'rounds':>13s} {'sum of task s':>14s}  rows ok")
    for label, ts in times.items():
        ratios = [t / r for t, r in zip(ts, ref)]
        ok, n, task_s = checks[label]
        dt = min(ts)
        print(f"   {label:36s} {dt:8.2f} {n_devices / dt:10.2f} {total / dt / 1e6:11.3f} {np.median(ratios):9.2f} "
              f"{min(ratios):6.2f}-{max(ratios):<6.2f} {task_s:14.2f}  {ok}/{n}")
    print("   (/ serial: the median over the rounds of the engine's best time over the serial loop's in the same round)")


def bench_log(root: Path, n: int, row_group_size: int, repeat: int) -> None:
    path = root / "huge.parquet"
    write_log(path, n, seed=99, row_group_size=row_group_size)
    size_mb = path.stat().st_size / 1e6
    n_groups = pq.ParquetFile(path).num_row_groups
    print(f"\n2. huge log: {n} samples, {n_groups} row groups, {size_mb:.0f} MB on disk; best of {repeat}")

    def read_rates():
        table = pq.read_table(path, columns=list(COLUMNS[1:]))
        return np.column_stack([table.column(c).to_numpy() for c in COLUMNS[1:]])

    def in_process():
        x = read_rates()
        return Moments.from_samples(x[:, :3], x[:, 3:])

    x = read_rates()
    dt_mem = best_of(lambda: Moments.from_samples(x[:, :3], x[:, 3:]), 3)[0]
    del x
    dt_ref, ref = best_of(in_process, repeat)
    print(f"   {'engine':46s} {'seconds':>8s} {'Msamples/s':>11s} {'max rel diff':>13s}")
    print(f"   {'in-process pass over arrays already in memory':46s} {dt_mem:8.2f} {n / dt_mem / 1e6:11.2f} {'-':>13s}")
    print(f"   {'in-process: read whole file + one pass':46s} {dt_ref:8.2f} {n / dt_ref / 1e6:11.2f} {'(reference)':>13s}")

    def rel(m):
        return max(float(np.max(np.abs(m.scatter - ref.scatter)) / np.max(np.abs(ref.scatter))),
                   float(np.max(np.abs(m.mean - ref.mean)) / np.max(np.abs(ref.mean))), abs(m.count - ref.count))

    dt, m = best_of(lambda: log_moments(path), repeat)
    print(f"   {'dask threaded scheduler, this process':46s} {dt:8.2f} {n / dt / 1e6:11.2f} {rel(m):13.2e}")
    for workers in (1, 2):
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None) as cluster, Client(cluster) as client:
            log_moments(path, client=client)  # warm-up (imports, file cache)
            dt, m = best_of(lambda: log_moments(path, client=client), repeat)
            print(f"   {f'LocalCluster, {workers} worker process(es)':46s} {dt:8.2f} {n / dt / 1e6:11.2f} "
                  f"{rel(m):13.2e}")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--devices", type=int, default=24)
    p.add_argument("--device-samples", type=int, default=60_000)
    p.add_argument("--log-samples", type=int, default=6_000_000)
    p.add_argument("--row-group", type=int, default=250_000)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--rounds", type=int, default=3, help="interleaved rounds of the fleet engines")
    p.add_argument("--fleet-only", action="store_true")
    args = p.parse_args(argv)
    print(f"machine: {os.cpu_count()} CPU(s); load average at start {os.getloadavg()[0]:.1f} "
          "(other processes share the CPUs: figures are only comparable at low load)")
    root = Path(tempfile.mkdtemp(prefix="gyrocal_fleet_bench_"))
    try:
        (root / "fleet").mkdir()
        bench_fleet(root / "fleet", args.devices, args.device_samples, args.repeat, args.rounds)
        if not args.fleet_only:
            bench_log(root, args.log_samples, args.row_group, args.repeat)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    print(f"\nload average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    import logging

    logging.getLogger("distributed").setLevel(logging.WARNING)
    main()
