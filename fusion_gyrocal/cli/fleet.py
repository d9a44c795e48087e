"""``gyrocal fleet``: many devices on Dask, one results row per device."""

from __future__ import annotations

import argparse
import sys

from ..distributed.fleet import run_fleet
from ..errors import GyroCalError


EXIT_SOME_FAILED = 4


def add_fleet_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``fleet`` subcommand to a ``gyrocal`` subparsers object (sets ``func``)."""
    p = subparsers.add_parser(
        "fleet", help="calibrate many devices on Dask, one Parquet row per device",
        description="Calibrate every device (a .parquet file or dataset with columns t,w1x,w1y,w1z,w2x,w2y,w2z in "
                    "s and rad/s, or a folder with gyro1.* and gyro2.* recordings) on a Dask cluster and write a "
                    "results table with one row per device. A failing device gets a row with its error. Exit code "
                    f"0 when every device was calibrated, {EXIT_SOME_FAILED} when some failed (the table is still "
                    "written).")
    p.add_argument("devices", nargs="+", help="device paths, or folders holding devices")
    p.add_argument("--output", "-o", default="fleet_results.parquet", help="results table (Parquet)")
    p.add_argument("--workers", type=int, default=2,
                   help="local Dask worker processes (0: threads in this process); ignored with --scheduler")
    p.add_argument("--threads-per-worker", type=int, default=1)
    p.add_argument("--scheduler", help="address of a running Dask scheduler (e.g. tcp://10.0.0.5:8786)")
    p.add_argument("--chunked", action="store_true",
                   help="huge Parquet logs: reduce each device's row-group statistics across the workers, then solve")
    p.add_argument("--method", choices=("ml", "direct"), default="ml")
    p.add_argument("--noise-std", type=float, nargs="+", metavar="RAD_S",
                   help="white-noise std per sample (rad/s), one value or one per gyro")
    p.add_argument("--gauge", choices=("unit_prior", "fixed"), default="unit_prior")
    p.add_argument("--max-offset", type=float, help="time-offset search range in s (gyro1/gyro2 devices)")
    p.add_argument("--no-flex-rejection", action="store_true", help="keep every sample (no flex/outlier gate)")
    p.set_defaults(func=cmd_fleet)
    return p


def _cli_options(args) -> dict:
    opts = {"method": args.method, "gauge": args.gauge}
    if args.noise_std:
        opts["noise_std"] = args.noise_std if len(args.noise_std) > 1 else args.noise_std[0]
    if not args.chunked:
        if args.max_offset is not None:
            opts["max_offset_s"] = args.max_offset
        if args.no_flex_rejection:
            opts["flex_rejection"] = False
    return opts


def cmd_fleet(args) -> int:
    """Run ``gyrocal fleet`` from parsed arguments; returns the exit code."""
    options = _cli_options(args)
    cluster = client = None
    try:
        if args.scheduler or args.workers > 0:
            from distributed import Client, LocalCluster

            if args.scheduler:
                client = Client(args.scheduler)
            else:
                cluster = LocalCluster(n_workers=args.workers, threads_per_worker=args.threads_per_worker,
                                       processes=True, host="127.0.0.1", dashboard_address=None)
                client = Client(cluster)
        df = run_fleet(args.devices, client=client, output=args.output, chunked=args.chunked, **options)
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    failed = df[~df["ok"]]
    for _, r in df.iterrows():
        status = "ok" if r["ok"] else f"FAILED ({r['error_type']}): {r['error']}"
        print(f"{r['device']}: {status}")
    print(f"{len(df)} device(s), {len(failed)} failed; table written to {args.output}")
    return 0 if failed.empty else EXIT_SOME_FAILED


def fleet_main(argv=None) -> int:
    """Standalone entry point: ``python -m fusion_gyrocal.cli.fleet DEVICES... -o results.parquet``."""
    parser = argparse.ArgumentParser(prog="gyrocal")
    sub = parser.add_subparsers(dest="command", required=True)
    add_fleet_parser(sub)
    args = parser.parse_args(["fleet", *(sys.argv[1:] if argv is None else argv)])
    try:
        return cmd_fleet(args)
    except GyroCalError as exc:
        print(f"gyrocal: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(fleet_main())
