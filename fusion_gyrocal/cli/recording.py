"""The recording pair of ``calibrate``, ``report`` and ``compare``: its arguments, its reading, its options."""

from __future__ import annotations

import argparse

from ..options import add_option_arguments, options_from_args

ALIGNMENT_OPTIONS = ("time_offset_s", "max_offset_s", "rate_hz")
"""The options that act on reading and aligning a pair (``--offset``, ``--max-offset``, ``--rate``)."""

READER_OPTIONS = {"csv": {"columns", "unit", "sensitivity", "time_column", "time_unit"},
                  "euroc": {"columns", "unit", "sensitivity", "time_column", "time_unit"},
                  "xsens": {"unit"}, "npz": {"imu", "unit"}, "bag": {"topic"}}
"""The keywords of :func:`fusion_gyrocal.io.read_imu` that each detected format accepts."""


def add_recording_args(p: argparse.ArgumentParser, *, optional: bool = False) -> None:
    """Arguments naming a recording pair and how to read it (calibrate, report, compare).

    The alignment flags (``--offset``, ``--max-offset``, ``--rate``) are options
    (:data:`ALIGNMENT_OPTIONS`), added with the others by :func:`fusion_gyrocal.options.add_option_arguments`.
    """
    p.add_argument("gyro1", nargs="?" if optional else None,
                   help="recording of gyro 1 (the reference): CSV, EuRoC imu0 folder or data.csv, Xsens export, "
                        ".npz, ROS1 .bag or ROS2 bag folder" + ("; omit to simulate --scenario" if optional else ""))
    p.add_argument("gyro2", nargs="?", help="recording of gyro 2 (omit when gyro1 holds both, e.g. a bag with "
                                            "--topic1/--topic2 or an npz with --imu1/--imu2)")
    for k in ("1", "2"):
        p.add_argument(f"--topic{k}", help=f"sensor_msgs/Imu topic of gyro {k} in a bag")
        p.add_argument(f"--imu{k}", type=int, help=f"IMU index (from 0) of gyro {k} in a multi-IMU npz")
        p.add_argument(f"--unit{k}", choices=("rad/s", "deg/s", "counts"), help=f"rate unit of gyro {k} (CSV)")
        p.add_argument(f"--sensitivity{k}", type=float, help=f"LSB per deg/s of gyro {k} with --unit{k} counts")
        p.add_argument(f"--columns{k}", help=f"comma-separated rate columns of gyro {k} in a CSV (names or indices)")
    p.add_argument("--time-column", help="timestamp column in CSV files (name or index)")
    p.add_argument("--time-unit", choices=("s", "ms", "us", "ns"), help="timestamp unit in CSV files")


def add_alignment_args(p: argparse.ArgumentParser) -> None:
    """Only the alignment options' flags (for commands that read a pair but run their own estimators)."""
    add_option_arguments(p, names=ALIGNMENT_OPTIONS)


def reader_options(args, k: str) -> dict:
    """The :func:`fusion_gyrocal.io.read_imu` keywords given for gyro ``k`` ("1" or "2")."""
    opts = {key: getattr(args, f"{key}{k}") for key in ("topic", "imu", "unit", "sensitivity")}
    opts = {key: v for key, v in opts.items() if v is not None}
    cols = getattr(args, f"columns{k}")
    if cols:
        opts["columns"] = [int(c) if c.strip().lstrip("-").isdigit() else c.strip() for c in cols.split(",")]
    if args.time_column is not None:
        opts["time_column"] = int(args.time_column) if args.time_column.isdigit() else args.time_column
    if args.time_unit is not None:
        opts["time_unit"] = args.time_unit
    return opts


def _for_reader(opts: dict, path) -> dict:
    """Keep only the keywords that the reader of ``path``'s detected format accepts."""
    from ..io import detect_format

    allowed = READER_OPTIONS.get(detect_format(path), set(opts))
    return {k: v for k, v in opts.items() if k in allowed}


def read_streams(args, progress=None):
    """Read the two gyro streams named by :func:`add_recording_args` arguments (``progress()`` after each)."""
    from ..errors import InputError
    from ..io import read_imu

    path2 = args.gyro2 or args.gyro1
    if args.gyro2 is None and args.topic2 is None and args.imu2 is None:
        raise InputError("gyro2: expected a second recording, or --topic1/--topic2 (bag) or --imu1/--imu2 (npz) "
                         "to take both gyros from one file")
    s1 = read_imu(args.gyro1, **_for_reader(reader_options(args, "1"), args.gyro1))
    if progress:
        progress()
    s2 = read_imu(path2, **_for_reader(reader_options(args, "2"), path2))
    if progress:
        progress()
    return s1, s2


def read_recording(args, progress=None):
    """``(stream_1, stream_2, options)``: the pair and the :class:`~fusion_gyrocal.options.Options` of the
    flags, ``--bias-window`` converted at gyro 1's rate (or ``--rate``'s)."""
    s1, s2 = read_streams(args, progress)
    return s1, s2, options_from_args(args, rate_hz=s1.rate_hz)
