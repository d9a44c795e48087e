"""``gyrocal calibrate``: recordings of two or more gyros in, calibration out (table, JSON, Kalibr, OpenVINS).

Two gyros go through the pair pipeline (:func:`~fusion_gyrocal.pipeline.pipeline.run_pipeline`: time
offset, flex gate, rigidity verdict, every option). Below the table one line says what the uncertainty rests
on (:func:`~fusion_gyrocal.io.report.uncertainty_basis`); the Kalibr and OpenVINS files carry the gyro noise
identified from the pair's residual, with where it came from. More than two, or two with ``--array``, are calibrated
jointly (:func:`~fusion_gyrocal.pipeline.array.calibrate_streams`, see :mod:`fusion_gyrocal.cli.array`).
"""

from __future__ import annotations

import argparse
import sys

from ..options import add_option_arguments
from .app import EXAMPLES, EXIT_OK
from .recording import add_recording_args, gyro_sources, read_sources


DESCRIPTION = ("Two gyros go through the pair pipeline (time offset, flex gate, rigidity verdict, every option). "
               "More than two, or two with --array, are calibrated jointly (one maximum likelihood over all gyros, "
               "gyro 1 the reference; each gyro's clock aligned to gyro 1's unless they share one).")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``calibrate`` (every option's flag, see :mod:`fusion_gyrocal.options`)."""
    p = subparsers.add_parser("calibrate", help="recordings of two or more gyros in, calibration out",
                              description=DESCRIPTION, epilog=EXAMPLES,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    add_recording_args(p, many=True)
    out = p.add_argument_group("outputs")
    out.add_argument("--output", "-o", help="write the full result as JSON (every gyro); '-' is standard output")
    out.add_argument("--kalibr", metavar="FOLDER",
                     help="write Kalibr files into FOLDER (created): imu0.yaml, imu1.yaml, ... (what "
                          "kalibr_calibrate_imu_camera --imu reads) and imu_chain.yaml (Kalibr's result layout)")
    out.add_argument("--openvins", metavar="FILE", help="write an OpenVINS kalibr_imu_chain.yaml (every gyro); '-' is standard output")
    p.add_argument("--array", action="store_true",
                   help="calibrate two gyros with the joint N-gyro solver too (default: the pair pipeline)")
    add_option_arguments(p)
    p.set_defaults(func=run)
    return p


def _kalibr_folder(path: str):
    from pathlib import Path

    from ..errors import OptionError

    p = Path(path)
    if path == "-":
        raise OptionError("--kalibr: expected a folder (imu0.yaml, imu1.yaml, ... are written into it), got '-' "
                          "(standard output takes one file: --output - or --openvins -)")
    if p.suffix.lower() in (".yaml", ".yml"):
        raise OptionError(f"--kalibr: expected a folder (Kalibr reads one file per IMU: imu0.yaml, imu1.yaml, ... "
                          f"are written into it), got the file name {path!r}")
    return p


def _topics(args, sources) -> list[str]:
    return [s.options.get("topic") or f"/imu{k}" for k, s in enumerate(sources)]


def run(args) -> int:
    """Calibrate; exit code 0 (a pair flagged not rigid with ``--allow-not-rigid`` too, with a warning)."""
    from ..io.writers import (STDOUT, output_group, write_json, write_kalibr_imu_chain, write_kalibr_imu_configs,
                              write_openvins_imu_chain)
    from ..io.report import uncertainty_basis
    from ..progress import progress_bar
    from .display import array_table, console as make_console, summary_table

    kalibr = _kalibr_folder(args.kalibr) if args.kalibr else None
    if args.output == STDOUT and args.openvins == STDOUT:
        from ..errors import OptionError
        raise OptionError("--output and --openvins: expected at most one of them on standard output ('-'), got both")
    console = make_console(stderr=STDOUT in (args.output, args.openvins))   # "-o -": the result alone on stdout
    sources = gyro_sources(args)
    joint = len(sources) > 2 or args.array
    with progress_bar() as progress:
        task = progress.add_task("reading", total=len(sources) + 1)
        streams = read_sources(sources, lambda: progress.advance(task))
        progress.update(task, description="aligning and solving")
        if joint:
            from .array import calibrate_recordings

            cal, notes = calibrate_recordings(streams, args)
        else:
            from ..options import options_from_args
            from ..pipeline.pipeline import run_pipeline

            s1, s2 = streams
            options = options_from_args(args, rate_hz=s1.rate_hz)
            cal = run_pipeline(s1.masked_omega, s2.masked_omega, t_1=s1.t, t_2=s2.t, options=options).calibration
            notes = []
        progress.advance(task)
    console.print(array_table(cal) if joint else summary_table(cal))
    console.print(uncertainty_basis(cal))
    for note in tuple(cal.notes) + tuple(notes):
        console.print(f"note: {note}")
    for source, stream in zip(sources, streams):   # what each reader dropped or chose
        for note in stream.notes:
            console.print(f"note ({source.describe()}): {note}")
    if not joint and cal.rigid is False:
        print(f"gyrocal: warning: NOT RIGID ({100 * cal.unexplained_fraction:.1f}% of gyro 1's motion unexplained): "
              "the result is flagged (--allow-not-rigid), not a calibration; every file written says so",
              file=sys.stderr)
    topics = _topics(args, sources)
    rates = [s.rate_hz for s in streams]
    wrote = []
    with output_group():   # this run's files are replaced together or not at all
        if args.output:
            wrote.append(write_json(cal, args.output))
        if kalibr is not None:
            wrote += write_kalibr_imu_configs(cal, kalibr, topics=topics, update_rate=rates)
            wrote.append(write_kalibr_imu_chain(cal, kalibr / "imu_chain.yaml", topics=topics, update_rate=rates))
        if args.openvins:
            wrote.append(write_openvins_imu_chain(cal, args.openvins, topics=topics, update_rate=rates))
    for p in wrote:
        console.print(f"wrote {'standard output' if str(p) == STDOUT else p}")
    return EXIT_OK
