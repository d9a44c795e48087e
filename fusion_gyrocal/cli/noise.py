"""``gyrocal noise``: the noise of one gyro at rest, what imu_utils and allan_variance_ros are installed for.

One recording (any format ``calibrate`` reads) of a gyro lying still, or with still stretches between motions
(found by :func:`~fusion_gyrocal.core.static_noise.rest_stretches`, or given with ``--start``/``--end`` or
``--whole``), gives per axis the white noise, bias instability and random walk with their uncertainty
(:func:`~fusion_gyrocal.core.static_noise.static_noise`), an Allan-deviation plot and a Kalibr ``imu.yaml``
(:func:`~fusion_gyrocal.io.writers.write_kalibr_noise`) that ``gyrocal calibrate --noise`` and Kalibr read.
"""

from __future__ import annotations

import argparse

from ..units import RATE_UNITS, TIME_UNITS
from .app import EXIT_OK

STATIC_NOISE_KIND = "static_noise"
STATIC_NOISE_FORMAT_VERSION = "1.0"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``noise``."""
    p = subparsers.add_parser(
        "noise", help="white noise, bias instability and random walk of one gyro at rest (Allan variance)",
        description="Allan analysis of a static recording (or of the still stretches of a longer one): per-axis "
                    "white noise N, bias instability B and random walk K with their uncertainty, an Allan plot and "
                    "a Kalibr imu.yaml.", epilog="example: gyrocal noise static.csv --kalibr imu.yaml --plot allan.png")
    p.add_argument("recording", metavar="RECORDING",
                   help="CSV, EuRoC imu0 folder or data.csv, Xsens export, .npz (--imu), ROS1 .bag or ROS2 bag "
                        "folder (--topic)")
    g = p.add_argument_group("reading the recording")
    g.add_argument("--topic", help="sensor_msgs/Imu topic in a bag")
    g.add_argument("--imu", type=int, help="IMU index (from 0) in a multi-IMU npz")
    g.add_argument("--unit", choices=RATE_UNITS, help="rate unit (CSV, Xsens, npz)")
    g.add_argument("--sensitivity", type=float, help="LSB per deg/s with --unit counts")
    g.add_argument("--columns", help="comma-separated rate columns of a CSV (names or indices)")
    g.add_argument("--time-column", help="timestamp column of a CSV (name or index)")
    g.add_argument("--time-unit", choices=TIME_UNITS, help="timestamp unit of a CSV")
    g.add_argument("--sample-rate", metavar="HZ", help="sample rate of an Xsens export that states none")
    s = p.add_argument_group("which samples")
    s.add_argument("--whole", action="store_true", help="use the whole recording as one stretch at rest "
                                                        "(default: find the still stretches)")
    s.add_argument("--start", type=float, metavar="S", help="use only the samples from S seconds after the first")
    s.add_argument("--end", type=float, metavar="S", help="use only the samples up to S seconds after the first")
    out = p.add_argument_group("outputs")
    out.add_argument("--kalibr", metavar="FILE", help="write a Kalibr imu.yaml (gyrocal calibrate --noise reads it)")
    out.add_argument("--plot", metavar="FILE", help="write the Allan-deviation plot (PNG)")
    out.add_argument("--output", "-o", metavar="FILE", help="write every figure as JSON (with the provenance)")
    out.add_argument("--rostopic", help="rostopic written in the imu.yaml (default --topic, else /imu0)")
    p.set_defaults(func=run)
    return p


def _reader_options(args) -> dict:
    from .recording import _convert

    opts = {}
    for key, flag in (("topic", "--topic"), ("imu", "--imu"), ("unit", "--unit"), ("sensitivity", "--sensitivity"),
                      ("columns", "--columns"), ("time_column", "--time-column"), ("time_unit", "--time-unit"),
                      ("rate_hz", "--sample-rate")):
        v = getattr(args, "sample_rate" if key == "rate_hz" else key, None)
        if v is not None:
            opts[key] = _convert(key, v, flag) if isinstance(v, str) else v
    return opts


def _window(args, t):
    """The sample range of ``--start``/``--end`` (seconds after the first sample)."""
    import numpy as np

    from ..errors import OptionError

    rel = t - t[0]
    a = 0 if args.start is None else int(np.searchsorted(rel, args.start))
    b = len(t) if args.end is None else int(np.searchsorted(rel, args.end, side="right"))
    if b - a < 16:
        raise OptionError(f"--start/--end: expected a range holding samples, got {b - a} samples between "
                          f"{args.start} and {args.end} s (the recording spans {rel[-1]:.6g} s)")
    return a, b


def run(args) -> int:
    """Analyse, print the per-axis table and write what was asked."""
    import json

    import numpy as np

    from rich.table import Table

    from ..core.static_noise import rest_stretches, static_noise
    from ..io import detect_format
    from ..io.writers import atomic_write, output_group, write_kalibr_noise
    from ..provenance import command_line, provenance_of
    from .display import console as make_console
    from .recording import GyroSource, read_sources

    console = make_console()
    source = GyroSource(args.recording, _reader_options(args))
    stream = read_sources([source])[0]
    a, b = _window(args, stream.t)
    omega, valid = stream.omega[a:b], stream.valid[a:b]
    if args.whole:
        stretches = [(0, b - a)]
    else:
        stretches = rest_stretches(omega, stream.rate_hz, valid=valid)
    noise = static_noise(omega, stream.rate_hz, valid=valid, stretches=stretches)
    prov = provenance_of([stream], paths=[args.recording], formats=[detect_format(args.recording)],
                         reader_options=[dict(source.options)], command=command_line(), n_used=noise.n_samples)
    deg = np.rad2deg(1.0)

    t = Table(title=f"gyro at rest: {noise.n_samples} samples in {len(noise.stretches)} stretch(es) of "
                    f"{(b - a) / stream.rate_hz:.6g} s, {stream.rate_hz:.6g} Hz")
    t.add_column("axis")
    for col in ("white N (rad/s/sqrt(Hz))", "N (deg/sqrt(h))", "per sample (deg/s)", "bias instability (deg/h)",
                "random walk K (rad/s^2/sqrt(Hz))"):
        t.add_column(col, justify="right")
    for i, name in enumerate("xyz"):
        t.add_row(name, f"{noise.white[i]:.4g} +- {noise.white_std[i]:.2g}",
                  f"{noise.white[i] * deg * 60:.4g} +- {noise.white_std[i] * deg * 60:.2g}",
                  f"{noise.white_per_sample[i] * deg:.4g}",
                  f"{noise.bias_instability[i] * deg * 3600:.3g} +- {noise.bias_instability_std[i] * deg * 3600:.2g}",
                  f"{noise.random_walk[i]:.3g} +- {noise.random_walk_std[i]:.2g}" if noise.random_walk[i] > 0
                  else f"none up to tau {noise.taus[-1]:.3g} s")
    console.print(t)
    for i, name in enumerate("xyz"):
        if noise.white_from[i] == "spread":
            why = (f"the shortest {noise.fit_from[i]} tau(s) are off every term of the Allan fit (tones, coloured "
                   "noise) and were left out of it" if noise.fit_from[i] > 0 else
                   "the Allan fit's short-term terms claimed more variance per sample than the samples hold")
            console.print(f"note: axis {name}: {why}; its white noise is the samples' own spread about their "
                          "means over 1 s blocks (short_term_spread)")
        elif noise.fit_from[i] > 0:
            console.print(f"note: axis {name}: the shortest {noise.fit_from[i]} tau(s) are off the standard terms "
                          "(coloured noise) and were left out of the fit; its white noise is that of the longer taus")
    for line in prov.lines():
        console.print(f"input: {line}")
    for note in stream.notes:
        console.print(f"note ({source.describe()}): {note}")
    wrote = []
    with output_group():   # this run's files are replaced together or not at all
        if args.kalibr:
            topic = args.rostopic or args.topic or "/imu0"
            wrote.append(write_kalibr_noise(noise, args.kalibr, rostopic=topic, provenance=prov))
        if args.plot:
            from ..io.report import static_allan_figure, write_figure

            wrote.append(write_figure(static_allan_figure(noise), args.plot, dpi=110))
        if args.output:
            d = {"kind": STATIC_NOISE_KIND, "format_version": STATIC_NOISE_FORMAT_VERSION, **noise.to_dict(),
                 "window_samples": [int(a), int(b)], "provenance": prov.to_dict()}
            wrote.append(atomic_write(args.output, json.dumps(d, indent=2, allow_nan=False) + chr(10)))
    for p in wrote:
        console.print(f"wrote {p}")
    return EXIT_OK
