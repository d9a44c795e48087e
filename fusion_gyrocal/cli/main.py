"""The ``gyrocal`` command: calibrate, report, demo (and compare, fleet where available).

Known errors (every :class:`~fusion_gyrocal.errors.GyroCalError`) print one line and exit 1;
a pair that is not rigid exits 3; anything unexpected prints one line (``--debug`` for the
traceback) and exits 70. Heavy imports happen inside the subcommands.
"""

from __future__ import annotations

import argparse
import sys

EXAMPLES = """examples:
  gyrocal demo
  gyrocal calibrate imu_a.csv imu_b.csv --output cal.json --kalibr imu.yaml
  gyrocal calibrate run.bag --topic1 /imu0 --topic2 /imu1 --openvins kalibr_imu_chain.yaml
  gyrocal calibrate mav0/imu0 other/data.csv --unit2 deg/s --noise-std 0.0017
  gyrocal calibrate exp_1.npz --imu1 0 --imu2 3 --method direct
  gyrocal report imu_a.csv imu_b.csv --out report/

exit codes: 0 calibrated; 1 a known error (one line on stderr says what was expected and what arrived);
3 the pair is not rigid; 4 (fleet) some devices failed; 70 an unexpected error (--debug shows the traceback)
"""

EXIT_ERROR, EXIT_NOT_RIGID, EXIT_INTERNAL = 1, 3, 70


def add_recording_args(p: argparse.ArgumentParser, *, optional: bool = False) -> None:
    """Arguments naming a recording pair and how to read and align it (shared by calibrate, report, compare)."""
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
    p.add_argument("--offset", type=float, help="known time offset (s) added to gyro 2's timestamps; "
                                                "default: estimated")
    p.add_argument("--max-offset", type=float, default=1.0, help="offset search range in s (default 1.0)")
    p.add_argument("--rate", type=float, help="resample both onto a uniform grid at this rate (Hz)")


def _add_calibrate_args(p: argparse.ArgumentParser) -> None:
    """Recording arguments plus the estimator options of calibrate and report."""
    add_recording_args(p)
    p.add_argument("--method", choices=("ml", "direct"), default="ml", help="estimator (default ml)")
    p.add_argument("--noise-std", type=float, nargs="+", metavar="RAD_S",
                   help="white-noise std per sample (rad/s), one value or one per gyro; default: from residuals")
    p.add_argument("--gauge", choices=("unit_prior", "fixed"), default="unit_prior",
                   help="global-scale gauge: unit prior on both x axes (paper) or scale_1[0] = 1")
    p.add_argument("--scale-prior", type=float, metavar="STD", help="Gaussian prior N(1, STD^2) on the scale factors")
    p.add_argument("--bias-window", type=float, metavar="SECONDS",
                   help="piecewise-constant bias over windows of this length (drifting biases)")
    p.add_argument("--bias-walk", type=float, nargs="+", metavar="RAD_S",
                   help="bias random-walk step std per sample (rad/s), one value or one per gyro: the exact "
                        "drifting-bias model (needs --noise-std)")
    p.add_argument("--no-flex-rejection", action="store_true", help="keep every sample (no flex/outlier gate)")
    p.add_argument("--max-rate", type=float, metavar="RAD_S",
                   help="drop samples faster than this rate norm (a known flex or saturation limit)")
    p.add_argument("--skew-std", type=float, default=0.0, help="remaining skew uncertainty for the error budget")
    p.add_argument("--allow-not-rigid", action="store_true",
                   help="report a non-rigid pair (flagged) instead of failing with exit code 3")


def _stream_options(args, k: str) -> dict:
    opts = {}
    for name, key in (("topic", "topic"), ("imu", "imu"), ("unit", "unit"), ("sensitivity", "sensitivity")):
        v = getattr(args, f"{name}{k}")
        if v is not None:
            opts[key] = v
    cols = getattr(args, f"columns{k}")
    if cols:
        opts["columns"] = [int(c) if c.strip().lstrip("-").isdigit() else c.strip() for c in cols.split(",")]
    if args.time_column is not None:
        opts["time_column"] = int(args.time_column) if args.time_column.isdigit() else args.time_column
    if args.time_unit is not None:
        opts["time_unit"] = args.time_unit
    return opts


def read_streams(args, progress=None):
    """Read the two gyro streams named by :func:`add_recording_args` arguments."""
    from ..errors import InputError
    from ..io import read_imu

    path2 = args.gyro2 or args.gyro1
    if args.gyro2 is None and args.topic2 is None and args.imu2 is None:
        raise InputError("gyro2: expected a second recording, or --topic1/--topic2 (bag) or --imu1/--imu2 (npz) "
                         "to take both gyros from one file")
    s1 = read_imu(args.gyro1, **_pick(_stream_options(args, "1"), args.gyro1))
    if progress:
        progress()
    s2 = read_imu(path2, **_pick(_stream_options(args, "2"), path2))
    if progress:
        progress()
    return s1, s2


def _pick(opts: dict, path) -> dict:
    """Keep only the options that the detected reader accepts."""
    from ..io import detect_format

    fmt = detect_format(path)
    allowed = {"csv": {"columns", "unit", "sensitivity", "time_column", "time_unit"},
               "euroc": {"columns", "unit", "sensitivity", "time_column", "time_unit"},
               "xsens": {"unit"}, "npz": {"imu", "unit"}, "bag": {"topic"}}.get(fmt, set(opts))
    return {k: v for k, v in opts.items() if k in allowed}


def _pipeline(args, s1, s2):
    import numpy as np

    from ..pipeline.pipeline import run_pipeline

    window = None
    if args.bias_window:
        window = max(2, int(round(args.bias_window * (args.rate or s1.rate_hz))))
    noise = None if not args.noise_std else (args.noise_std if len(args.noise_std) > 1 else args.noise_std[0])
    return run_pipeline(s1.masked_omega, s2.masked_omega, t_1=s1.t, t_2=s2.t, time_offset_s=args.offset, max_offset_s=args.max_offset,
                        rate_hz=args.rate, method=args.method, noise_std=noise, gauge=args.gauge,
                        scale_prior_std=args.scale_prior, bias_window=window,
                        bias_walk_std=None if not args.bias_walk else np.asarray(args.bias_walk, float),
                        flex_rejection=False if args.no_flex_rejection else "auto", skew_std=args.skew_std,
                        max_rate=args.max_rate,
                        on_not_rigid="flag" if args.allow_not_rigid else "raise")


def _summary_table(cal, truth=None):
    """Per-axis table: estimate +- 1-sigma (and the truth when known)."""
    import numpy as np
    from rich.table import Table

    t = Table(title=f"gyro pair calibration: {cal.configuration}, method {cal.method}, {cal.n_samples} samples, "
                    f"rigid {cal.rigid}")
    t.add_column("quantity")
    for axis in "xyz":
        t.add_column(axis, justify="right")

    def cells(v, sd, fmt):
        return [f"{fmt(a)} +- {fmt(b)}" if np.isfinite(b) else f"{fmt(a)} (ratio only)" for a, b in zip(v, sd)]

    deg = np.rad2deg
    rows = [("R_1_2 rotvec (deg)", deg(cal.rotvec), deg(cal.rotation_std_rad), "{:.4f}", "rotvec", deg),
            ("scale_1", cal.scale_1, cal.scale_std[0], "{:.6f}", "scale_1", None),
            ("scale_2", cal.scale_2, cal.scale_std[1], "{:.6f}", "scale_2", None),
            ("bias b1 - A b2 (deg/s)", deg(cal.bias), deg(cal.bias_std), "{:.4f}", "bias", deg)]
    for name, v, sd, f, key, conv in rows:
        t.add_row(name, *cells(v, sd, f.format))
        if truth is not None:
            tv = truth[key] if conv is None else conv(truth[key])
            t.add_row("  truth", *[f.format(x) for x in tv], style="dim")
    t.add_row("per-axis SNR", *[f"{x:.0f}" for x in cal.snr])
    extra = (f"time offset {cal.time_offset_s * 1e3:+.4f} +- {cal.time_offset_std_s * 1e3:.4f} ms"
             + (f" (truth {truth['time_offset_s'] * 1e3:+.4f} ms)" if truth is not None else "")
             + f"; gauge: {cal.gauge}; unexplained {100 * cal.unexplained_fraction:.3g}%, "
               f"rejected {100 * cal.rejected_fraction:.2f}%")
    t.caption = extra
    return t


def _console():
    from rich.console import Console

    c = Console()
    return c if c.is_terminal and c.width >= 100 else Console(width=110)


def cmd_calibrate(args) -> int:
    from rich.progress import Progress

    from ..io import write_json, write_kalibr_imu_yaml, write_openvins_imu_chain

    console = _console()
    with Progress(transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task("reading", total=3)
        s1, s2 = read_streams(args, lambda: progress.advance(task))
        progress.update(task, description="aligning and solving")
        run = _pipeline(args, s1, s2)
        progress.advance(task)
    cal = run.calibration
    console.print(_summary_table(cal))
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
    return 0 if cal.rigid else EXIT_NOT_RIGID


def cmd_report(args) -> int:
    from ..io.report import write_report

    s1, s2 = read_streams(args)
    run = _pipeline(args, s1, s2)
    extra = {}
    if args.track:
        from ..online.tracker import track_figure_for_report  # drift tracking plot
        from ..errors import GyroCalError
        try:
            extra["drift_tracking"] = track_figure_for_report(run)
        except GyroCalError as e:  # the rest of the report is still worth writing
            print(f"gyrocal: drift tracking skipped: {e}", file=sys.stderr)
    for p in write_report(run, args.out, extra_figures=extra):
        print(f"wrote {p}")
    return 0


def cmd_demo(args) -> int:
    import numpy as np

    from ..pipeline.pipeline import run_pipeline
    from ..evaluate.sim import PAPER_NOISE_STD, HumanMotion, random_rotation

    rng = np.random.default_rng(args.seed)
    motion = HumanMotion(0.8, rng=rng)
    R = random_rotation(rng)
    s1, s2 = np.array([1.004, 0.997, 1.002]), np.array([0.995, 1.006, 1.001])
    b1, b2 = np.deg2rad([0.4, -0.2, 0.1]), np.deg2rad([-0.3, 0.5, 0.2])
    offset = 0.0473  # gyro 2's clock runs 47.3 ms behind gyro 1's
    t1 = np.arange(0, 60, 1 / 200.0)                                           # gyro 1: 200 Hz
    t2 = np.arange(0.013, 60, 1 / 100.0) + rng.normal(0, 2e-4, 5999)[: len(np.arange(0.013, 60, 1 / 100.0))]
    t2.sort()
    w1 = motion(t1) * s1 + b1 + rng.normal(0, PAPER_NOISE_STD, (t1.size, 3))
    w2 = (motion(t2 + offset) @ R) * s2 + b2 + rng.normal(0, PAPER_NOISE_STD, (t2.size, 3))
    run = run_pipeline(w1, w2, t_1=t1, t_2=t2, noise_std=PAPER_NOISE_STD)
    cal = run.calibration
    lam = s1[0] / s2[0]  # the unit-prior gauge (Eq. 34) applied to the truth, for a like-for-like comparison
    c = (lam + 1) / (lam**2 + 1) / s2[0]
    A = (s1[:, None] * R) / s2[None, :]
    truth = {"rotvec": __import__("scipy.spatial.transform", fromlist=["Rotation"]).Rotation.from_matrix(R).as_rotvec(),
             "scale_1": s1 * c, "scale_2": s2 * c, "bias": b1 - A @ b2, "time_offset_s": offset}
    console = _console()
    console.print("Demo: a simulated gyro pair (60 s of hand-held motion, gyro 1 at 200 Hz, gyro 2 at 100 Hz with "
                  "timestamp jitter, 47.3 ms clock offset, noise 0.1 deg/s per sample)")
    console.print(_summary_table(cal, truth))
    err = np.rad2deg(np.linalg.norm(__import__("scipy.spatial.transform", fromlist=["Rotation"]).Rotation
                                    .from_matrix(cal.R_1_2 @ R.T).as_rotvec())) * 1e3
    console.print(f"rotation error {err:.2f} mdeg (1-sigma {np.rad2deg(np.linalg.norm(cal.rotation_std_rad)) * 1e3:.2f}"
                  f" mdeg); time offset error {(cal.time_offset_s - offset) * 1e6:+.1f} us")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gyrocal", description="Calibrate rigidly mounted gyroscopes from their angular rates alone: "
        "rotation, scale factors (up to one global scale), biases and time offset.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--debug", action="store_true", help="show tracebacks of unexpected errors")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("calibrate", help="two recordings in, calibration out", epilog=EXAMPLES,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_calibrate_args(p)
    p.add_argument("--output", "-o", help="write the full result as JSON")
    p.add_argument("--kalibr", help="write a Kalibr-style imu.yaml")
    p.add_argument("--openvins", help="write an OpenVINS kalibr_imu_chain.yaml")
    p.set_defaults(func=cmd_calibrate)
    p = sub.add_parser("report", help="plots a person can read (PNG + Markdown)", epilog=EXAMPLES,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_calibrate_args(p)
    p.add_argument("--out", default="gyrocal_report", help="output folder (default gyrocal_report)")
    p.add_argument("--track", action="store_true", help="also track drift with the EKF and plot it")
    p.set_defaults(func=cmd_report)
    p = sub.add_parser("demo", help="calibrate a built-in simulated pair and print it beside the truth")
    p.add_argument("--seed", type=int, default=7)
    p.set_defaults(func=cmd_demo)
    for mod, adder in (("compare", "add_compare_parser"), ("fleet", "add_fleet_parser")):
        try:
            m = __import__(f"fusion_gyrocal.cli.{mod}", fromlist=[adder])
            getattr(m, adder)(sub)
        except (ImportError, AttributeError):
            pass
    return parser


def main(argv=None) -> int:
    from ..errors import GyroCalError, NotRigidError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except NotRigidError as e:
        print(f"gyrocal: {e}", file=sys.stderr)
        return EXIT_NOT_RIGID
    except GyroCalError as e:
        print(f"gyrocal: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("gyrocal: interrupted", file=sys.stderr)
        return 130
    except (OSError, MemoryError) as e:
        if args.debug:
            raise
        print(f"gyrocal: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    except Exception as e:  # noqa: BLE001 - the CLI never shows a traceback unless asked
        if args.debug:
            raise
        print(f"gyrocal: internal error: {type(e).__name__}: {e} (rerun with --debug for the traceback)",
              file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
