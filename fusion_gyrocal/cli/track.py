"""``gyrocal track``: follow a gyro pair's calibration live and print the tracked state and alarms as JSON lines.

The source is text lines (:class:`~fusion_gyrocal.online.live.LineReader`: ``pair``, ``tagged`` or ``ros2 topic
echo --csv`` rows) from a file (``--follow``: keep reading while it grows), standard input (``-``), a UDP socket
(``udp://HOST:PORT``: each datagram one or more lines) or a ZeroMQ SUB socket (``zmq+tcp://HOST:PORT``, when
``pyzmq`` is installed). Samples go through :class:`~fusion_gyrocal.online.live.LivePair` (aligner, tracker,
streaming calibrator). Output, one JSON object per line: ``{"type": "seeded" | "seed_failed" | "alarm" | "reseed",
...}`` when they happen, ``{"type": "state", ...}`` every ``--every`` seconds of stream time, and
``{"type": "final", ...}`` at the end of the source.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from .app import EXIT_OK

IDLE_POLL_S = 0.05   # how often a followed file is polled for new lines


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``track``."""
    p = subparsers.add_parser(
        "track", help="track drift live from a stream (file, stdin, UDP, ZeroMQ); JSON lines out",
        description=__doc__.split("\n\n")[0].replace("``", "'"),
        epilog="examples:\n  gyrocal track pair.csv --seed cal.json\n"
               "  (ros2 topic echo --csv /imu0 & ros2 topic echo --csv /imu1) | gyrocal track - --format ros2 "
               "--names imu0_link,imu1_link\n  gyrocal track udp://0.0.0.0:9870 --format tagged --idle-timeout 10 "
               "-o track.jsonl\n", formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("source", help="a file, '-' (standard input), udp://HOST:PORT or zmq+tcp://HOST:PORT")
    p.add_argument("--format", default="auto", choices=("auto", "pair", "tagged", "ros2"),
                   help="line layout: pair 't,w1x,w1y,w1z,w2x,w2y,w2z'; tagged 'gyro,t,wx,wy,wz'; ros2 'ros2 "
                        "topic echo --csv' Imu rows (default: from the first data line)")
    p.add_argument("--names", help="tags (tagged) or frame ids (ros2) of gyro 1 and gyro 2, comma-separated")
    p.add_argument("--time-unit", default="s", choices=("s", "ms", "us", "ns"), help="timestamp unit (pair, tagged)")
    p.add_argument("--seed", metavar="CAL.json", help="start from this calibration (gyrocal calibrate -o); "
                                                      "default: seed from the stream's first --seed-s seconds")
    p.add_argument("--seed-s", type=float, default=30.0, help="seconds of the stream that seed the tracker (30)")
    p.add_argument("--mode", default="fast", choices=("fast", "sample"), help="tracker updates per block or per "
                                                                            "sample (fast)")
    p.add_argument("--block-size", type=int, help="samples per block in the fast mode (tracker default 100)")
    p.add_argument("--max-gap", type=float, metavar="S", help="a larger step between samples is a gap (default "
                                                               "5 median intervals of the seed)")
    p.add_argument("--window", type=float, default=60.0, metavar="S", help="streaming calibrator window (60 s)")
    p.add_argument("--every", type=float, default=1.0, metavar="S", help="a state line every S seconds of stream "
                                                                         "time (0: after every update)")
    p.add_argument("--follow", action="store_true", help="keep reading a file as it grows (until --idle-timeout)")
    p.add_argument("--idle-timeout", type=float, default=5.0, metavar="S",
                   help="end after S seconds without data (--follow, udp, zmq; default 5)")
    p.add_argument("-o", "--output", help="write the JSON lines to this file instead of standard output")
    p.set_defaults(func=run)
    return p


# ---------------------------------------------------------------------------------------------- sources
def _file_lines(path, follow: bool, idle_s: float):
    from ..io.stream import input_path

    with open(input_path(path), "r", encoding="utf-8-sig") as f:
        idle_since = time.monotonic()
        partial = ""
        while True:
            line = f.readline()
            if line.endswith("\n"):
                yield partial + line
                partial = ""
                idle_since = time.monotonic()
                continue
            partial += line                  # a line still being written
            if not follow or time.monotonic() - idle_since > idle_s:
                if partial.strip():
                    yield partial
                return
            time.sleep(IDLE_POLL_S)


def _udp_lines(address: str, idle_s: float):
    import socket

    from ..errors import InputError

    host, _, port = address.rpartition(":")
    if not port.isdigit():
        raise InputError(f"udp://{address}: expected udp://HOST:PORT, got no port number")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host or "0.0.0.0", int(port)))
        sock.settimeout(idle_s)
        while True:
            try:
                data = sock.recv(65536)
            except socket.timeout:
                return
            yield from data.decode("utf-8", errors="replace").splitlines()
    finally:
        sock.close()


def _zmq_lines(address: str, idle_s: float):
    from ..errors import OptionError

    try:
        import zmq
    except ImportError:
        raise OptionError(f"{address}: a ZeroMQ source needs pyzmq (pip install pyzmq); use udp:// or stdin "
                          "otherwise") from None
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.SUB)
    try:
        sock.connect(address)
        sock.setsockopt(zmq.SUBSCRIBE, b"")
        while sock.poll(int(idle_s * 1000)):
            yield from sock.recv().decode("utf-8", errors="replace").splitlines()
    finally:
        sock.close(0)


def source_lines(source: str, *, follow: bool = False, idle_s: float = 5.0):
    """The text lines of ``source`` (a file, ``-``, ``udp://HOST:PORT``, ``zmq+tcp://HOST:PORT``) as they come."""
    if source == "-":
        return iter(sys.stdin.readline, "")
    if source.startswith("udp://"):
        return _udp_lines(source[len("udp://"):], idle_s)
    if source.startswith("zmq+"):
        return _zmq_lines(source[len("zmq+"):], idle_s)
    return _file_lines(source, follow, idle_s)


# ---------------------------------------------------------------------------------------------- run
def run(args) -> int:
    """Read the source to its end, printing the events and states as JSON lines."""
    from ..errors import OptionError
    from ..online.live import LineReader, LivePair
    from ..units import TIME_UNITS

    for name in ("seed_s", "window", "idle_timeout"):
        v = getattr(args, name)
        if not v > 0:
            raise OptionError(f"--{name.replace('_', '-')}: expected a positive number of seconds, got {v}")
    if args.every < 0:
        raise OptionError(f"--every: expected seconds >= 0, got {args.every}")
    names = None if args.names is None else [n.strip() for n in args.names.split(",")]
    reader = LineReader(args.format, names=names, time_scale=10.0 ** -TIME_UNITS[args.time_unit])
    tracker = None
    if args.seed:
        from ..io import read_json
        from ..online.tracker import GyroPairTracker

        tracker = GyroPairTracker(read_json(args.seed), history_max_rows=2000)
    live = LivePair(tracker=tracker, seed_s=args.seed_s, window_s=args.window, mode=args.mode,
                    block_size=args.block_size, max_gap_s=args.max_gap)
    out = open(args.output, "w", encoding="utf-8") if args.output else sys.stdout
    try:
        def emit(obj):
            out.write(json.dumps(obj, allow_nan=False) + "\n")
            out.flush()

        next_t, last_n = None, 0
        for line in source_lines(args.source, follow=args.follow, idle_s=args.idle_timeout):
            for gyro, t, w in reader.samples(line):
                for event in live.push(gyro, t, w):
                    emit(event)
                tr = live.tracker
                if tr is not None and tr.n_samples > last_n and (next_t is None or tr.t >= next_t):
                    emit(live.state())
                    next_t, last_n = tr.t + args.every, tr.n_samples
        for event in live.close():
            emit(event)
        emit({**live.state(), "type": "final", "lines": reader.line_no, "lines_skipped": reader.skipped})
    finally:
        if out is not sys.stdout:
            out.close()
    return EXIT_OK
