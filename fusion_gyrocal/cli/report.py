"""``gyrocal report``: the calibration of a recording pair as plots a person can read (PNG + Markdown)."""

from __future__ import annotations

import argparse
import sys

from ..options import add_option_arguments
from .app import EXAMPLES, EXIT_OK
from .recording import add_recording_args, read_recording


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``report`` (every option's flag, see :mod:`fusion_gyrocal.options`)."""
    p = subparsers.add_parser("report", help="plots a person can read (PNG + Markdown)", epilog=EXAMPLES,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    add_recording_args(p)
    p.add_argument("--out", default="gyrocal_report", help="output folder (default gyrocal_report)")
    p.add_argument("--track", action="store_true", help="also track drift with the EKF and plot it")
    add_option_arguments(p, consumer="pair")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    """Calibrate the pair and write the report; a failing drift tracking only skips its plot."""
    from ..errors import GyroCalError
    from ..io.report import write_report
    from ..io.writers import output_group
    from ..pipeline.pipeline import run_pipeline

    from ..progress import progress_bar

    with progress_bar() as bar:   # one tick per stage
        stage = bar.add_task("reading", total=4 if args.track else 3)
        s1, s2, options = read_recording(args)
        bar.update(stage, advance=1, description="aligning and solving")
        run_ = run_pipeline(s1.masked_omega, s2.masked_omega, t_1=s1.t, t_2=s2.t, options=options)
        extra = {}
        if args.track:
            from ..online.tracker import track_figure_for_report  # drift tracking plot

            bar.update(stage, advance=1, description="tracking drift (EKF)")
            try:
                extra["drift_tracking"] = track_figure_for_report(run_)
            except GyroCalError as e:  # the rest of the report is still worth writing
                print(f"gyrocal: drift tracking skipped: {e}", file=sys.stderr)
        bar.update(stage, advance=1, description="drawing the figures")
        with output_group():   # the report's files replaced together or not at all
            paths = write_report(run_, args.out, extra_figures=extra)
    for p in paths:
        print(f"wrote {p}")
    return EXIT_OK
