"""``gyrocal report``: the calibration of recordings as plots a person can read (PNG + Markdown).

Two gyros: one page (:func:`~fusion_gyrocal.io.report.write_report`). More: one page per gyro against gyro 1 (each
pair through the pair pipeline, flex gate and rigidity verdict included) and an index
(:func:`~fusion_gyrocal.io.report.write_array_report`).
"""

from __future__ import annotations

import argparse
import sys

from ..options import add_option_arguments
from .app import EXAMPLES, EXIT_OK
from .recording import add_recording_args, gyro_sources, read_sources


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``report`` (every option's flag, see :mod:`fusion_gyrocal.options`)."""
    p = subparsers.add_parser("report", help="plots a person can read (PNG + Markdown); N gyros: a page per gyro",
                              epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_recording_args(p, many=True)
    p.add_argument("--out", default="gyrocal_report", help="output folder (default gyrocal_report)")
    p.add_argument("--track", action="store_true", help="also track drift with the EKF and plot it")
    add_option_arguments(p, consumer="pair")
    p.set_defaults(func=run)
    return p


def _with_provenance(run_, sources, streams, options):
    """``run_`` with its calibration carrying the provenance of the pair it was computed from."""
    import dataclasses

    import numpy as np

    from .calibrate import command_provenance

    rejected = 0 if run_.valid is None or run_.used is None else int(np.sum(run_.valid & ~run_.used))
    prov = command_provenance(sources, streams, options, n_used=run_.calibration.n_samples, n_rejected=rejected)
    return dataclasses.replace(run_, calibration=dataclasses.replace(run_.calibration, provenance=prov))


def _run_many(args, sources, streams) -> int:
    """N gyros: every gyro against gyro 1 through the pair pipeline, a page each and an index."""
    from ..io.report import write_array_report
    from ..io.writers import output_group
    from ..options import options_from_args
    from ..pipeline.pipeline import run_pipeline
    from ..progress import progress_bar
    from .calibrate import command_provenance

    if args.track:
        from ..errors import OptionError

        raise OptionError(f"--track: expected two gyros (the drift of one pair), got {len(sources)}")
    options = options_from_args(args, rate_hz=streams[0].rate_hz)
    s1 = streams[0]
    runs = {}
    with progress_bar() as bar:
        stage = bar.add_task("solving each gyro against gyro 1", total=len(streams) - 1)
        for k in range(1, len(streams)):
            sk = streams[k]
            run_ = run_pipeline(s1.masked_omega, sk.masked_omega, t_1=s1.t, t_2=sk.t, options=options)
            runs[k + 1] = _with_provenance(run_, [sources[0], sources[k]], [s1, sk], options)
            bar.advance(stage)
        prov = command_provenance(sources, streams, options, n_used=min(r.calibration.n_samples for r in runs.values()))
        with output_group():   # the report's files replaced together or not at all
            paths = write_array_report(runs, args.out, provenance=prov)
    for p in paths:
        print(f"wrote {p}")
    return EXIT_OK


def run(args) -> int:
    """Calibrate the pair (or every gyro against gyro 1) and write the report; a failing drift tracking only skips
    its plot."""
    from ..errors import GyroCalError
    from ..io.report import write_report
    from ..io.writers import output_group
    from ..options import options_from_args
    from ..pipeline.pipeline import run_pipeline

    from ..progress import progress_bar

    sources = gyro_sources(args)
    if len(sources) > 2:
        return _run_many(args, sources, read_sources(sources))
    with progress_bar() as bar:   # one tick per stage
        stage = bar.add_task("reading", total=4 if args.track else 3)
        s1, s2 = read_sources(sources)
        options = options_from_args(args, rate_hz=s1.rate_hz)
        bar.update(stage, advance=1, description="aligning and solving")
        run_ = run_pipeline(s1.masked_omega, s2.masked_omega, t_1=s1.t, t_2=s2.t, options=options)
        run_ = _with_provenance(run_, sources, [s1, s2], options)
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
