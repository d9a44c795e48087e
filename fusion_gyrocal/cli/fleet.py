"""``gyrocal fleet``: many devices on Dask, one results row per device.

The options' flags are those of ``calibrate`` (:func:`fusion_gyrocal.options.add_option_arguments`)
except ``--bias-window``: it is given in seconds, and the devices of a fleet each have their own
sample rate, so no one window in samples fits them all (use ``--bias-walk``, or
:func:`fusion_gyrocal.distributed.fleet.run_fleet` with ``bias_window`` in samples). The alignment
options (``--offset``, ``--max-offset``, ``--rate``, ``--saturation-limit``) act on gyro1/gyro2
devices only: Parquet devices are sample-aligned. With ``--chunked`` only the solve options apply;
a pipeline option is refused (exit 1), not ignored.
"""

from __future__ import annotations

import argparse
import sys

from ..options import add_option_arguments, options_from_args
from .app import EXIT_OK, EXIT_SOME_FAILED, main

FLEET_EXCLUDED_OPTIONS = ("bias_window",)
"""Options without a fleet flag (a window in seconds has no one length in samples across devices)."""


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``fleet`` subcommand to a ``gyrocal`` subparsers object (sets ``func``)."""
    p = subparsers.add_parser(
        "fleet", help="calibrate many devices on Dask, one Parquet row per device",
        description="Calibrate every device (a .parquet file or dataset with columns t,w1x,w1y,w1z,w2x,w2y,w2z in "
                    "s and rad/s, or a folder with gyro1.* and gyro2.* recordings) on a Dask cluster and write a "
                    "results table with one row per device. A failing device gets a row with its error. Exit code "
                    f"0 when every device was calibrated, {EXIT_SOME_FAILED} when some failed (the table is still "
                    "written). The options apply to every device; --offset, --max-offset, --rate and "
                    "--saturation-limit only to gyro1/gyro2 devices (Parquet devices are sample-aligned); "
                    "--bias-window is not offered (seconds have no one length in samples across devices of "
                    "different rates); with --chunked only solve options apply.")
    p.add_argument("devices", nargs="+", help="device paths, or folders holding devices")
    p.add_argument("--output", "-o", default="fleet_results.parquet", help="results table (Parquet)")
    p.add_argument("--workers", type=int, default=2,
                   help="local Dask worker processes (0: threads in this process); ignored with --scheduler")
    p.add_argument("--threads-per-worker", type=int, default=1)
    p.add_argument("--scheduler", help="address of a running Dask scheduler (e.g. tcp://10.0.0.5:8786)")
    p.add_argument("--chunked", action="store_true",
                   help="huge Parquet logs: reduce each device's row-group statistics across the workers, then solve")
    add_option_arguments(p, consumer="pair", exclude=FLEET_EXCLUDED_OPTIONS)
    p.set_defaults(func=run)
    return p



def run(args) -> int:
    """Run ``gyrocal fleet`` from parsed arguments; 0, or 4 when some devices failed (the table is written)."""
    from ..distributed.fleet import run_fleet

    options = options_from_args(args)
    if args.chunked:  # refused before a cluster starts (run_fleet applies the same rule)
        options.require("moments", "--chunked")
    cluster = client = None
    try:
        if args.scheduler or args.workers > 0:
            import dask
            from distributed import Client

            from ..distributed.fleet import fleet_cluster

            # a device that kills its worker (out of memory) fails alone: not re-run on every other worker in turn
            dask.config.set({"distributed.scheduler.allowed-failures": 0})
            if args.scheduler:
                client = Client(args.scheduler)
            else:
                cluster = fleet_cluster(args.workers, args.threads_per_worker)
                client = Client(cluster)
        df = run_fleet(args.devices, client=client, output=args.output, chunked=args.chunked, progress=None,
                       options=options)
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
    return EXIT_OK if failed.empty else EXIT_SOME_FAILED


def fleet_main(argv=None) -> int:
    """Standalone entry point: ``python -m fusion_gyrocal.cli.fleet DEVICES... -o results.parquet``
    (``gyrocal fleet`` through the same parser and error map)."""
    return main(["fleet", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(fleet_main())
