"""The ``gyrocal`` application: the parser of every command and ONE error-to-exit-code map.

Every command lives in its own module of this package (:data:`COMMANDS`) with ``add_parser(subparsers)``
(which sets ``func``) and ``run(args) -> int``. Commands raise; :func:`run_command` turns what they
raise into one line on stderr and an exit code by :data:`ERROR_EXIT_CODES`, for ``gyrocal`` and for the
standalone entry points (:func:`fusion_gyrocal.cli.fleet.fleet_main`,
:func:`fusion_gyrocal.cli.compare.compare_main`) alike.

Stderr carries one line per error: the message of what a command raised is folded into one line
(:func:`one_line`), an exception without a message is named by its type, and the warnings a command's
numerics emit (numpy's floating-point ``RuntimeWarning``) are captured by :func:`run_command` instead of
reaching stderr as a file:line pair (``--debug`` prints them, one line each); other warnings are printed
as one ``PROG: warning: ...`` line each.

Imports stay light here: a command imports what it needs when it runs.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys
import textwrap
import warnings
from typing import NamedTuple

#: Environment variables set to ``"1"`` for a ``gyrocal`` process (unless the environment sets them, or numpy is
#: already loaded in this process, where they would act on nothing): the library's BLAS calls are skinny products
#: ((N, 3) by (3, 3), (7, 8192) by (8192, 6)) that a multi-threaded OpenBLAS runs several times slower in CPU time
#: (measured 40x for (129427, 3) by (3, 3) on a busy 2-core machine, where its threads spin waiting for a core);
#: long passes run on threads of their own (``Moments.from_samples``). This module is the first the command line
#: imports, so they are set before numpy loads.
SINGLE_THREADED_BLAS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
if "numpy" not in sys.modules:
    for _name in SINGLE_THREADED_BLAS:
        os.environ.setdefault(_name, "1")

from ..errors import GyroCalError, NotRigidError  # noqa: E402

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2  # argparse's own exit for a bad command line
EXIT_NOT_RIGID = 3
EXIT_SOME_FAILED = 4
EXIT_CHANGED = 5
EXIT_INTERNAL = 70
EXIT_INTERRUPTED = 130
EXIT_PIPE_CLOSED = 141   # 128 + SIGPIPE: what a shell reports for a writer whose reader went away

EXIT_MEANINGS = (
    (EXIT_OK, "calibrated"),
    (EXIT_ERROR, "a known error (one line on stderr says what was expected and what arrived)"),
    (EXIT_USAGE, "a bad command line (usage)"),
    (EXIT_NOT_RIGID, "the gyros are not rigid (--allow-not-rigid: a flagged result and exit 0, pairs only)"),
    (EXIT_SOME_FAILED, "(fleet) some devices failed"),
    (EXIT_CHANGED, "(sessions) the device changed between sessions"),
    (EXIT_INTERNAL, "an unexpected error (--debug shows the traceback)"),
    (EXIT_INTERRUPTED, "interrupted"),
    (EXIT_PIPE_CLOSED, "the reader of the output closed it (| head): no message"),
)


class ExitRule(NamedTuple):
    """One row of the map: what is caught, the exit code, the stderr line, and whether ``--debug`` re-raises."""

    errors: type | tuple
    code: int
    message: str
    debug_raises: bool = False


ERROR_EXIT_CODES = (
    ExitRule(NotRigidError, EXIT_NOT_RIGID, "{prog}: {exc}"),
    ExitRule(GyroCalError, EXIT_ERROR, "{prog}: error: {exc}"),
    ExitRule(KeyboardInterrupt, EXIT_INTERRUPTED, "{prog}: interrupted"),
    ExitRule(BrokenPipeError, EXIT_PIPE_CLOSED, ""),
    ExitRule(MemoryError, EXIT_ERROR, "{prog}: error: out of memory ({what}): the recording is too large for this "
             "machine or its timestamps are corrupt (a huge span or gap makes a huge time grid)", debug_raises=True),
    ExitRule(OSError, EXIT_ERROR, "{prog}: error: {exc}", debug_raises=True),
    ExitRule(Exception, EXIT_INTERNAL,
             "{prog}: internal error: {what} (rerun with --debug for the traceback)", debug_raises=True),
)
"""The error -> exit-code map of every command; the first row whose ``errors`` match wins.

A row's ``message`` may use ``{prog}``, ``{exc}`` (the error's message, or its type when it has none),
``{kind}`` (its type) and ``{what}`` (``kind: message``, or the type alone); an empty one prints nothing (a closed
pipe: the reader wanted no more, as ``head`` does).
"""

_CARETS = re.compile(r"^\s*\^+\s*(\(line: \d+\))?\s*$")   # a parser's marker line under a quoted snippet


def one_line(text: str) -> str:
    """``text`` as one line: lines joined by a space, runs of blanks collapsed, a parser's caret lines
    (YAML's ``^`` under the quoted source line) dropped."""
    return " ".join(" ".join(line.split()) for line in str(text).splitlines()
                    if line.strip() and not _CARETS.match(line))

COMMANDS = ("calibrate", "report", "noise", "demo", "compare", "fleet", "track", "sessions")
"""The command modules of this package, in the order ``gyrocal --help`` lists them."""

EXAMPLES = """examples:
  gyrocal demo
  gyrocal calibrate imu_a.csv imu_b.csv --output cal.json --kalibr kalibr/
  gyrocal calibrate run.bag --topic1 /imu0 --topic2 /imu1 --openvins kalibr_imu_chain.yaml
  gyrocal calibrate mav0/imu0 other/data.csv --unit2 deg/s --time-unit2 ms --noise-std 0.0017
  gyrocal calibrate exp_1.npz --imu1 0 --imu2 3 --method direct
  gyrocal calibrate exp_1.npz --output array.json --openvins kalibr_imu_chain.yaml   (all IMUs, jointly)
  gyrocal calibrate a.csv b.csv c.csv --time-unit ms,s,s --kalibr kalibr/            (N recordings, jointly)
  gyrocal report imu_a.csv imu_b.csv --out report/
  gyrocal calibrate exp_1.npz --nominal "180 deg about (1,-1,0)" --ros ros/ --noise imu.yaml --openvins chain.yaml
  gyrocal noise static.csv --kalibr imu.yaml --plot allan.png          (Allan analysis of a static recording)
  gyrocal track pair.csv --seed cal.json --follow                                    (live drift, JSON lines)
  gyrocal sessions monday.json tuesday.json wednesday.json         (did the device change? exit 5 if it did)

""" + textwrap.fill("exit codes: " + "; ".join(f"{code} {meaning}" for code, meaning in EXIT_MEANINGS),
                    width=118, break_on_hyphens=False) + "\n"


def flag_hint(message: str) -> str:
    """``message`` with the command-line flags of the API keywords it names appended.

    The library names its options and reader keywords (``max_offset_s``, ``pass topic=``); at the command
    line the user needs the flag (``--max-offset``, ``--topic1/--topic2 or --topics``). Options are
    recognised at the start of the message (``name: expected ...``) or, for names with an underscore,
    anywhere; reader keywords in their ``name=`` form.
    """
    import re

    from ..options import FLAGS
    from .recording import READER_FLAGS

    reader = [f"{key}= is {flags}" for key, flags in READER_FLAGS.items() if re.search(rf"\b{key}=", message)]
    hints = [f"{name} is {flag}" for name, flag in FLAGS.items()
             if (re.match(rf"{name}\b", message) or ("_" in name and re.search(rf"\b{name}\b", message)))
             and not (name in READER_FLAGS and re.search(rf"\b{name}=", message))]   # "rate_hz=": the reader's
    hints += reader
    return f"{message} (command line: {'; '.join(hints)})" if hints else message


def _stdout_to_devnull() -> None:
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.stdout.fileno())
        os.close(null)
    except (OSError, ValueError, AttributeError):   # no file descriptor behind stdout (captured): nothing to do
        pass


def run_command(func, args, *, prog: str = "gyrocal", debug: bool | None = None) -> int:
    """Run ``func(args)`` and map what it raises to one stderr line and an exit code (:data:`ERROR_EXIT_CODES`).

    Parameters
    ----------
    func : callable
        A command's ``run(args) -> int`` (None counts as 0).
    args : argparse.Namespace
    prog : str
        Prefix of the stderr line.
    debug : bool, optional
        Re-raise unexpected errors (their traceback); default ``args.debug`` when present.
    """
    if debug is None:
        debug = bool(getattr(args, "debug", False))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            return int(func(args) or 0)
        except BaseException as exc:  # noqa: BLE001 - mapped by the table; SystemExit and the like pass through
            rule = next((r for r in ERROR_EXIT_CODES if isinstance(exc, r.errors)), None)
            if rule is None or (debug and rule.debug_raises):
                raise
            if isinstance(exc, BrokenPipeError):   # what is still buffered for the closed pipe goes nowhere, so
                _stdout_to_devnull()               # the interpreter's last flush does not fail again at exit
            if not rule.message:
                return rule.code
            message = one_line(exc)
            kind = type(exc).__name__
            text = flag_hint(message) if isinstance(exc, GyroCalError) else message
            line = rule.message.format(prog=prog, exc=text or kind, kind=kind,
                                       what=f"{kind}: {text}" if text else kind)
            print(one_line(line), file=sys.stderr)
            return rule.code
        finally:
            _report_warnings(caught, prog, debug)


def _report_warnings(caught, prog: str, debug: bool) -> None:
    """One stderr line per distinct warning a command emitted; numerical ``RuntimeWarning`` only with
    ``--debug`` (the command's result or error already says what went wrong with the data)."""
    seen = set()
    for w in caught:
        numeric = issubclass(w.category, RuntimeWarning)
        line = f"{prog}: {'debug: ' if numeric else ''}warning: {one_line(w.message)} ({w.category.__name__})"
        if (debug or not numeric) and line not in seen:
            seen.add(line)
            print(line, file=sys.stderr)


def command_modules(names=COMMANDS):
    """The command modules of ``names`` (imported now; each imports its heavy dependencies only when it runs)."""
    return [importlib.import_module(f".{name}", __package__) for name in names]


def build_parser(argv=None) -> argparse.ArgumentParser:
    """The ``gyrocal`` parser: ``--debug`` and one sub-command per module of :data:`COMMANDS`.

    When ``argv`` names a command, only that command's module is imported and its parser built (the
    others' imports are not paid for on every run); otherwise (``--help``, a wrong name) all of them.
    """
    parser = argparse.ArgumentParser(
        prog="gyrocal", description="Calibrate rigidly mounted gyroscopes from their angular rates alone: "
        "rotation, scale factors (up to one global scale), biases and time offset.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--debug", action="store_true", help="show tracebacks of unexpected errors")
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"gyrocal (fusion_gyrocal) {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    chosen = next((a for a in (argv or ()) if not a.startswith("-")), None)
    for module in command_modules((chosen,) if chosen in COMMANDS else COMMANDS):
        module.add_parser(sub)
    return parser


def main(argv=None) -> int:
    """``gyrocal [--debug] COMMAND ...``: parse, run the command, return its exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    return run_command(args.func, args, prog=parser.prog)
