"""``gyrocal sessions``: did the device change between calibrations? (:func:`~fusion_gyrocal.core.sessions.
compare_sessions` on the result files ``gyrocal calibrate --output`` wrote).

Exit 0 when every session is consistent with the others, :data:`~fusion_gyrocal.cli.app.EXIT_CHANGED` when one
changed beyond its covariance (a script can act on it: recalibrate, alert), 1 on an error.
"""

from __future__ import annotations

import argparse

from .app import EXIT_CHANGED, EXIT_OK


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``sessions``."""
    p = subparsers.add_parser(
        "sessions", help="did the device change between calibrations? (result files of gyrocal calibrate)",
        description="Test calibrations of one device from different sessions against one another: each session's "
                    "rotation(s) against the others' mean in units of their covariances (pairs: R_1_2; arrays: "
                    "every gyro's rotation to the reference, jointly). A session beyond the chi-square point "
                    "changed; exit code 5 says so. For arrays, a changed session also says which gyros turned "
                    "together and by how much, against the gyros that stayed.",
        epilog="example: gyrocal sessions monday.json tuesday.json wednesday.json")
    p.add_argument("results", nargs="+", metavar="RESULT", help="JSON results of gyrocal calibrate --output (two "
                                                                 "or more, all pairs or all arrays of the same gyros)")
    p.add_argument("--alpha", type=float, default=0.01,
                   help="false-alarm rate of the test over all sessions (default 0.01)")
    p.add_argument("--output", "-o", metavar="FILE", help="write the comparison as JSON")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    """Read the results, compare them, print the table (and write the JSON); exit :data:`EXIT_CHANGED` where a
    session changed."""
    from pathlib import Path

    from ..core.sessions import compare_sessions
    from ..io.writers import read_json

    cals = [read_json(f) for f in args.results]
    names = [Path(f).stem for f in args.results]
    if len(set(names)) < len(names):
        names = list(args.results)
    result = compare_sessions(cals, names, alpha=args.alpha)
    print(result.summary())
    if args.output:
        import json

        from ..io.writers import atomic_write

        text = json.dumps(result.to_dict(), indent=2, allow_nan=False) + "\n"
        print(f"wrote {atomic_write(args.output, text)}")
    return EXIT_CHANGED if result.changed.any() else EXIT_OK
