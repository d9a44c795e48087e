"""``gyrocal compare``: every estimator on the same data, errors against the truth and the bound."""

from __future__ import annotations

import csv
import io

from ..errors import InputError
from ..evaluate.registry import DEFAULT_ESTIMATORS, ESTIMATORS
from ..evaluate.scenarios import SNR_FACTORS
from ..options import FLAGS
from .app import EXIT_OK, run_command
from .recording import RECORDING_OPTIONS, add_alignment_args, add_recording_args, aligned_samples, read_recording


def add_parser(subparsers):
    """Add ``compare`` to an :mod:`argparse` sub-command set (sets ``func``); returns the sub-parser."""
    import argparse

    from ..evaluate.scenarios import SCENARIOS, SNR_VIA

    p = subparsers.add_parser(
        "compare", help="run every estimator on the same data and tabulate errors, bounds and times",
        description="Run every estimator (" + ", ".join(ESTIMATORS) + ") on a recording pair or on Monte "
                    "Carlo runs of a simulated scenario; print a table (errors against the truth, error / "
                    "Cramer-Rao bound, time per solve) and optionally write Markdown, CSV and a figure.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    add_recording_args(p, optional=True)
    p.add_argument("--scenario", default="nominal",
                   help="simulated scenario (without recordings): " + ", ".join(SCENARIOS)
                        + ", or snr_x<f>[_rate|_noise|_samples]")
    p.add_argument("--estimators", default=",".join(DEFAULT_ESTIMATORS), help="comma-separated estimator names")
    p.add_argument("--runs", type=int, default=1, help="Monte Carlo runs of the scenario")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--snr-factor", type=float, default=1.0, help="scale the scenario's SNR")
    p.add_argument("--snr-via", choices=SNR_VIA, default=None, help="how to scale the SNR")
    p.add_argument("--sweep", action="store_true",
                   help="sweep the SNR over the paper's factors " + "/".join(f"{f:g}" for f in SNR_FACTORS)
                        + " and print the log-log slopes")
    p.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    p.add_argument("--markdown", metavar="PATH", help="write the table(s) as Markdown")
    p.add_argument("--csv", metavar="PATH", help="write the table(s) as CSV")
    p.add_argument("--figure", metavar="PATH", help="with --sweep: write the RMSE-versus-SNR figure")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_alignment_args(p)  # recordings only (aligned and masked as calibrate does); the estimators run with
    # their own settings
    p.set_defaults(func=run)
    return p


add_compare_parser = add_parser  # the name fusion_gyrocal.evaluate.compare's documentation and tests use


def load_recording(args):
    """Read, align and mask the recording pair as ``calibrate`` does: ``(omega_1, omega_2, rate_hz)`` of the
    valid aligned samples (:func:`~fusion_gyrocal.cli.recording.aligned_samples`: the streams' validity, the
    saturated and non-finite samples, ``--saturation-limit``, ``--max-rate``)."""
    s1, s2, o = read_recording(args)
    w1, w2 = aligned_samples(s1, s2, o)
    return w1, w2, float(o.rate_hz or s1.rate_hz)


def run(args) -> int:
    """Run ``gyrocal compare`` from parsed arguments (raises; :func:`compare_main` maps errors to exit codes)."""
    from rich.console import Console

    from ..evaluate.compare import compare, plot_rmse_vs_snr, snr_sweep
    from ..io.writers import atomic_write, output_group

    console = Console(highlight=False)
    names = tuple(n.strip() for n in args.estimators.split(",") if n.strip())
    progress = not args.no_progress
    if args.recordings:
        w1, w2, rate = load_recording(args)
        tables = [compare((w1, w2), estimators=names, rate_hz=rate, progress=progress)]
        sweep = None
    else:
        given = [FLAGS[n] for n in RECORDING_OPTIONS if getattr(args, f"option_{n}", None) is not None]
        if given:
            raise InputError(f"{'/'.join(given)}: expected recordings (gyro1 [gyro2]) to align and mask; a "
                             f"simulated scenario has none")
        if args.sweep:
            sweep = snr_sweep(args.scenario, via=args.snr_via or "rate", runs=args.runs, estimators=names,
                              seed=args.seed, workers=args.workers, progress=progress)
            tables = list(sweep.comparisons)
        else:
            sweep = None
            tables = [compare(args.scenario, estimators=names, runs=args.runs, seed=args.seed,
                              snr_factor=args.snr_factor, snr_via=args.snr_via, workers=args.workers,
                              progress=progress)]
    for t in tables:
        t.print()
    if sweep is not None:
        console.print("log-log slope of RMSE versus SNR (paper: -1):")
        for s in sweep.slopes():
            console.print(f"  {s.estimator:>20}: rotation {s.rotation:+.3f}, scales {s.scale:+.3f}")
        br, bs = sweep.bound_slopes()
        console.print(f"  {'Cramer-Rao bound':>20}: rotation {br:+.3f}, scales {bs:+.3f}")
    with output_group():   # replaced together or not at all
        if args.markdown:
            atomic_write(args.markdown, "\n".join(t.to_markdown() for t in tables))
        if args.csv:
            atomic_write(args.csv, tables[0].to_csv() if len(tables) == 1 else _sweep_csv(tables))
    if args.figure:
        if sweep is None:
            raise InputError("--figure: expected --sweep (the figure is RMSE versus SNR)")
        plot_rmse_vs_snr(sweep, args.figure)
    return EXIT_OK


def compare_main(args) -> int:
    """``gyrocal compare`` from parsed arguments through the command line's error map; returns the exit code."""
    return run_command(run, args, prog="gyrocal compare")


def _sweep_csv(tables) -> str:
    """Several tables in one CSV with a leading ``source`` and ``snr`` column."""
    out = []
    for i, t in enumerate(tables):
        lines = t.to_csv().splitlines()
        if i == 0:
            out.append("source,snr," + lines[0])
        out += [f"{_csv_field(t.source)},{t.snr!r}," + line for line in lines[1:]]
    return "\n".join(out) + "\n"


def _csv_field(s: str) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="").writerow([s])
    return buf.getvalue()
