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
    out.add_argument("--openvins", metavar="FILE",
                     help="write an OpenVINS kalibr_imu_chain.yaml (every gyro); '-' is standard output")
    out.add_argument("--ros", metavar="FOLDER",
                     help="write into FOLDER (created) the mounting for ROS: tf2 static transforms "
                          "(static_transforms.launch for ROS 1, static_transforms.launch.xml for ROS 2, "
                          "static_transforms.yaml) and URDF fixed joints (imu_joints.urdf); parent = gyro 1")
    out.add_argument("--frames", metavar="NAMES",
                     help="frame (link) names of every gyro for --ros, comma-separated, gyro 1 first "
                          "(default gyro1,gyro2,...)")
    out.add_argument("--noise", metavar="FILE",
                     help="measured noise figures for the Kalibr/OpenVINS files: a Kalibr imu.yaml or "
                          "allan_variance_ros output (for every IMU), an IMU chain (one per IMU), or one file per "
                          "gyro comma-separated (gyro 1 first); e.g. from gyrocal noise")
    p.add_argument("--nominal", metavar="ROTATION",
                   help="the nominal mounting R_1_k of every gyro (or one per gyro 2..N separated by ';'): "
                        "'identity', '180 deg about (1,-1,0)', 9 matrix entries row by row, 'rpy R,P,Y deg' or "
                        "'xyzw X,Y,Z,W'; the deviation from it is printed and written with its uncertainty")
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


def _noise_figures(spec: str, n: int):
    """The :class:`~fusion_gyrocal.io.writers.ImuNoise` of ``--noise``: one file for every IMU (or a chain, one
    per IMU), or one file per gyro."""
    from ..errors import OptionError
    from ..io.writers import read_imu_noise

    files = [f.strip() for f in spec.split(",") if f.strip()]
    figures = [read_imu_noise(f) for f in files]
    if len(files) == 1:
        got = figures[0]
        if len(got) == 1:
            return got[0]
        if len(got) != n:
            raise OptionError(f"--noise: expected one IMU's figures or a chain of {n} (imu0..imu{n - 1}), got a chain "
                              f"of {len(got)} in {files[0]}")
        return list(got)
    if len(files) != n:
        raise OptionError(f"--noise: expected one file or one per gyro ({n}), got {len(files)}")
    bad = [f for f, g in zip(files, figures) if len(g) != 1]
    if bad:
        raise OptionError(f"--noise: expected one IMU's figures per file, got chains in {bad}")
    return [g[0] for g in figures]


def _frames(args, n: int):
    """``--frames`` checked for ``n`` gyros (None: the defaults)."""
    if not args.frames:
        return None
    from ..io.ros import check_frames

    return check_frames([f.strip() for f in args.frames.split(",")], n)


def command_provenance(sources, streams, options, *, n_used: int, n_rejected: int = 0):
    """The :class:`~fusion_gyrocal.provenance.Provenance` of a command's run: every gyro's file, format, reader
    keywords, units and masked samples as read, the options, the command line and the version."""
    from ..io import detect_format
    from ..provenance import command_line, provenance_of
    from .recording import _for_reader

    return provenance_of(streams, options, paths=[s.path for s in sources],
                         formats=[detect_format(s.path) for s in sources],
                         reader_options=[_for_reader(s.options, s.path) for s in sources],
                         command=command_line(), n_used=n_used, n_rejected=n_rejected)


def run(args) -> int:
    """Calibrate; exit code 0 (a pair flagged not rigid with ``--allow-not-rigid`` too, with a warning)."""
    from ..io.writers import (STDOUT, output_group, write_json, write_kalibr_imu_chain, write_kalibr_imu_configs,
                              write_openvins_imu_chain)
    from ..io.report import uncertainty_basis
    from ..progress import progress_bar
    from .display import array_table, console as make_console, summary_table

    import dataclasses

    import numpy as np

    from .display import provenance_lines, rotation_lines

    kalibr = _kalibr_folder(args.kalibr) if args.kalibr else None
    if args.output == STDOUT and args.openvins == STDOUT:
        from ..errors import OptionError
        raise OptionError("--output and --openvins: expected at most one of them on standard output ('-'), got both")
    console = make_console(stderr=STDOUT in (args.output, args.openvins))   # "-o -": the result alone on stdout
    sources = gyro_sources(args)
    n = len(sources)
    joint = n > 2 or args.array
    frames = _frames(args, n)
    noise = _noise_figures(args.noise, n) if args.noise else None   # read before the long work: fail early
    nominal = None
    if args.nominal:
        from ..io.ros import parse_nominals

        nominal = parse_nominals(args.nominal, n)
    with progress_bar() as progress:
        task = progress.add_task("reading", total=len(sources) + 1)
        streams = read_sources(sources, lambda: progress.advance(task))
        progress.update(task, description="aligning and solving")
        if joint:
            from .array import calibrate_recordings

            from .array import array_options

            cal, notes = calibrate_recordings(streams, args)
            prov = command_provenance(sources, streams, array_options(args, n, streams[0].rate_hz),
                                      n_used=cal.n_samples)
            cal = dataclasses.replace(cal, provenance=prov, nominal_R_ref_k=nominal)
        else:
            from ..options import options_from_args
            from ..pipeline.pipeline import run_pipeline

            s1, s2 = streams
            options = options_from_args(args, rate_hz=s1.rate_hz)
            run_ = run_pipeline(*(s.masked_omega if not s.valid.all() else s.omega for s in (s1, s2)), t_1=s1.t,
                                t_2=s2.t, options=options)   # masked_omega copies: only where a sample is masked
            rejected = 0 if run_.valid is None or run_.used is None else int(np.sum(run_.valid & ~run_.used))
            prov = command_provenance(sources, streams, options, n_used=run_.calibration.n_samples,
                                      n_rejected=rejected)
            cal = dataclasses.replace(run_.calibration, provenance=prov,
                                      nominal_R_1_2=None if nominal is None else nominal[1])
            notes = []
        progress.advance(task)
    console.print(array_table(cal) if joint else summary_table(cal))
    for line in rotation_lines(cal):
        console.print(line)
    console.print(uncertainty_basis(cal))
    for line in provenance_lines(cal.provenance):
        console.print(line)
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
            wrote += write_kalibr_imu_configs(cal, kalibr, topics=topics, update_rate=rates, noise=noise)
            wrote.append(write_kalibr_imu_chain(cal, kalibr / "imu_chain.yaml", topics=topics, update_rate=rates,
                                                noise=noise))
        if args.openvins:
            wrote.append(write_openvins_imu_chain(cal, args.openvins, topics=topics, update_rate=rates, noise=noise))
        if args.ros:
            from ..io.ros import write_ros_frames

            wrote += write_ros_frames(cal, args.ros, frames=frames)
    for p in wrote:
        console.print(f"wrote {'standard output' if str(p) == STDOUT else p}")
    return EXIT_OK
