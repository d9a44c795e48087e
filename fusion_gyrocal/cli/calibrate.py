"""``gyrocal calibrate``: two recordings in, calibration out (table, JSON, Kalibr, OpenVINS)."""

from __future__ import annotations

import argparse
import sys

from ..options import add_option_arguments
from .app import EXAMPLES, EXIT_NOT_RIGID, EXIT_OK
from .recording import add_recording_args, read_recording


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``calibrate`` (every option's flag, see :mod:`fusion_gyrocal.options`)."""
    p = subparsers.add_parser("calibrate", help="two recordings in, calibration out", epilog=EXAMPLES,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    add_recording_args(p)
    p.add_argument("--output", "-o", help="write the full result as JSON")
    p.add_argument("--kalibr", help="write a Kalibr-style imu.yaml")
    p.add_argument("--openvins", help="write an OpenVINS kalibr_imu_chain.yaml")
    add_option_arguments(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    """Calibrate the pair; exit code 0, or 3 when it is flagged not rigid (``--allow-not-rigid``)."""
    from rich.progress import Progress

    from ..io import write_json, write_kalibr_imu_yaml, write_openvins_imu_chain
    from ..pipeline.pipeline import run_pipeline
    from .display import console as make_console, summary_table

    console = make_console()
    with Progress(transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task("reading", total=3)
        s1, s2, options = read_recording(args, lambda: progress.advance(task))
        progress.update(task, description="aligning and solving")
        run_ = run_pipeline(s1.masked_omega, s2.masked_omega, t_1=s1.t, t_2=s2.t, options=options)
        progress.advance(task)
    cal = run_.calibration
    console.print(summary_table(cal))
    for n in cal.notes:
        console.print(f"note: {n}")
    topics = (args.topic1 or "/imu0", args.topic2 or "/imu1")
    rates = (s1.rate_hz, s2.rate_hz)
    if args.output:
        console.print(f"wrote {write_json(cal, args.output)}")
    if args.kalibr:
        console.print(f"wrote {write_kalibr_imu_yaml(cal, args.kalibr, topics=topics, update_rate=rates)}")
    if args.openvins:
        console.print(f"wrote {write_openvins_imu_chain(cal, args.openvins, topics=topics, update_rate=rates)}")
    return EXIT_OK if cal.rigid else EXIT_NOT_RIGID
