"""The recordings of ``calibrate``, ``report`` and ``compare``: their arguments, their reading, their options.

A command names its recordings as positional arguments: one file per gyro (gyro 1 = the reference
first), or one file holding several gyros (a multi-IMU ``.npz``: every IMU unless ``--imus`` or
``--imu1``/``--imu2`` pick some; a bag: ``--topics`` or ``--topic1``/``--topic2``). How to read each
gyro is given per gyro (``--unit2 deg/s``, ``--time-unit1 ms``) or for all at once, one value for
every gyro or a comma-separated value per gyro (``--unit deg/s``, ``--time-unit ms,s,s``); a per-gyro
flag wins over the list.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

from ..options import TIMESTAMP_OPTIONS, add_option_arguments, applying_to, options_from_args
from ..units import RATE_UNITS, TIME_UNITS

ALIGNMENT_OPTIONS = TIMESTAMP_OPTIONS
"""The options that act on reading and aligning recordings (``--offset``, ``--max-offset``, ``--rate``)."""

RECORDING_OPTIONS = applying_to("recordings")
"""Every option that acts on recordings before a solve (``applies_to`` ``"recordings"``): what ``compare`` takes
for its recording pair (the alignment options and the masks ``--saturation-limit``, ``--max-rate``)."""

READER_OPTIONS = {"csv": {"columns", "unit", "sensitivity", "time_column", "time_unit", "imu"},
                  "euroc": {"columns", "unit", "sensitivity", "time_column", "time_unit"},
                  "xsens": {"unit", "rate_hz"}, "npz": {"imu", "unit"}, "bag": {"topic"}, "ulog": {"topic", "imu"}}
"""The keywords of :func:`fusion_gyrocal.io.read_imu` that each detected format accepts."""

# reader keyword -> (per-gyro flag stem, flag for every gyro, separator of its per-gyro list)
_READER_FLAGS = {
    "topic": ("--topic", "--topics", ","),
    "imu": ("--imu", "--imus", ","),
    "unit": ("--unit", "--unit", ","),
    "sensitivity": ("--sensitivity", "--sensitivity", ","),
    "columns": ("--columns", "--columns", ";"),
    "time_column": ("--time-column", "--time-column", ","),
    "time_unit": ("--time-unit", "--time-unit", ","),
    "rate_hz": ("--sample-rate", "--sample-rate", ","),
}

READER_FLAGS = {key: f"{stem}1/{stem}2 or {every}" for key, (stem, every, _) in _READER_FLAGS.items()}
"""The command-line flags of each reader keyword (for messages)."""


def add_recording_args(p: argparse.ArgumentParser, *, optional: bool = False, many: bool = False) -> None:
    """Arguments naming the recordings and how to read them (calibrate, report, compare).

    Parameters
    ----------
    p : argparse.ArgumentParser
    optional : bool
        Recordings may be omitted (``compare`` simulates instead).
    many : bool
        The command takes N gyros (``calibrate``); otherwise one pair.

    The alignment flags (``--offset``, ``--max-offset``, ``--rate``) are options
    (:data:`ALIGNMENT_OPTIONS`), added with the others by :func:`fusion_gyrocal.options.add_option_arguments`.
    """
    kinds = ("CSV, EuRoC imu0 folder or data.csv, Xsens export, .npz, ROS1 .bag, ROS2 bag folder or .db3/.mcap, "
             "PX4 .ulg")
    if many:
        what = ("recordings of gyro 1 (the reference), gyro 2, ...: one per gyro, or one file holding several "
                "(an npz: all its IMUs unless --imus/--imu1/--imu2 pick; a bag: --topics or --topic1/--topic2); "
                + kinds)
    else:
        what = ("recording of gyro 1 (the reference) and of gyro 2 (omit it when the first holds both: a bag with "
                "--topic1/--topic2, an npz with --imu1/--imu2); " + kinds)
    p.add_argument("recordings", nargs="*" if optional else "+", metavar="RECORDING",
                   help=what + ("; omit to simulate --scenario" if optional else ""))
    g = p.add_argument_group("reading the recordings", "per gyro (FLAG1, FLAG2) or for every gyro (one value, or "
                             "one per gyro separated by commas; --columns by ';'); a per-gyro flag wins")
    for k in ("1", "2"):
        g.add_argument(f"--topic{k}", help=f"sensor_msgs/Imu topic of gyro {k} in a bag, or its gyro in a PX4 .ulg "
                                           "(sensor_gyro/1, sensor_combined/0)")
        g.add_argument(f"--imu{k}", type=int, help=f"IMU index (from 0) of gyro {k} in a multi-IMU npz, a PX4 .ulg "
                                                   "or a CSV log with an instance column (ArduPilot)")
        g.add_argument(f"--unit{k}", choices=RATE_UNITS, help=f"rate unit of gyro {k} (CSV, Xsens, npz)")
        g.add_argument(f"--sensitivity{k}", type=float, help=f"LSB per deg/s of gyro {k} with --unit{k} counts")
        g.add_argument(f"--columns{k}", help=f"comma-separated rate columns of gyro {k} in a CSV (names or indices)")
        g.add_argument(f"--time-column{k}", help=f"timestamp column of gyro {k}'s CSV (name or index)")
        g.add_argument(f"--time-unit{k}", choices=TIME_UNITS, help=f"timestamp unit of gyro {k}'s CSV")
        g.add_argument(f"--sample-rate{k}", metavar="HZ",
                       help=f"sample rate of gyro {k}'s Xsens export when the file states none (MT Manager 2019+)")
    if many:
        g.add_argument("--topics", help="Imu topics of every gyro in a bag, comma-separated (gyro 1 first)")
        g.add_argument("--imus", help="IMU indices (from 0) of every gyro, comma-separated (gyro 1 first); "
                                      "default with one multi-IMU npz: all of them")
    g.add_argument("--unit", help=f"rate unit of every gyro ({', '.join(RATE_UNITS)}), or one per gyro")
    g.add_argument("--sensitivity", help="LSB per deg/s with unit counts, or one per gyro")
    g.add_argument("--columns", help="rate columns of every CSV (comma-separated), or one set per gyro separated by ';'")
    g.add_argument("--time-column", help="timestamp column in CSV files (name or index), or one per gyro")
    g.add_argument("--time-unit", help=f"timestamp unit in CSV files ({', '.join(TIME_UNITS)}), or one per gyro")
    g.add_argument("--sample-rate", metavar="HZ", help="sample rate (Hz) of Xsens exports that state none, or one "
                                                        "per gyro")


def add_alignment_args(p: argparse.ArgumentParser) -> None:
    """Only the flags of the options that align and mask recordings (:data:`RECORDING_OPTIONS`), for commands
    that read a pair but run their own estimators."""
    add_option_arguments(p, names=RECORDING_OPTIONS)


# ---------------------------------------------------------------------------------------------- values
def _column(c: str):
    c = c.strip()
    return int(c) if c.lstrip("-").isdigit() else c


def _convert(key: str, text: str, flag: str):
    """One gyro's value of a reader flag, checked (OptionError names the flag)."""
    from ..errors import OptionError

    text = text.strip()
    if key == "columns":
        return [_column(c) for c in text.split(",")]
    if key == "time_column":
        return _column(text)
    if key == "unit" and text not in RATE_UNITS:
        raise OptionError(f"{flag}: expected one of {RATE_UNITS}, got {text!r}")
    if key == "time_unit" and text not in TIME_UNITS:
        raise OptionError(f"{flag}: expected one of {tuple(TIME_UNITS)}, got {text!r}")
    if key in ("imu", "sensitivity", "rate_hz"):
        try:
            value = int(text) if key == "imu" else float(text)
        except ValueError:
            raise OptionError(f"{flag}: expected {'an integer' if key == 'imu' else 'a number'}, got {text!r}") from None
        if key == "rate_hz" and not (math.isfinite(value) and value > 0):
            raise OptionError(f"{flag}: expected a positive sample rate in Hz, got {text!r}")
        return value
    return text


def _lists(args) -> dict:
    """The flags for every gyro, split into one value per gyro (or one for all)."""
    out = {}
    for key, (_, every, sep) in _READER_FLAGS.items():
        raw = getattr(args, every.lstrip("-").replace("-", "_"), None)
        if raw is not None:
            out[key] = [_convert(key, part, every) for part in str(raw).split(sep)]
    return out


def _per_gyro(args, k: int) -> dict:
    """The per-gyro flags given for gyro ``k`` (0-based; only gyros 1 and 2 have them)."""
    if k > 1:
        return {}
    out = {}
    for key, (stem, _, _) in _READER_FLAGS.items():
        v = getattr(args, f"{stem.lstrip('-').replace('-', '_')}{k + 1}", None)
        if v is not None:
            out[key] = _convert(key, v, f"{stem}{k + 1}") if isinstance(v, str) else v
    return out


def _for_gyro(lists: dict, args, k: int, n: int) -> dict:
    """The reader keywords of gyro ``k`` of ``n``: its per-gyro flags over the lists."""
    from ..errors import OptionError

    opts = {}
    for key, values in lists.items():
        if len(values) == 1:
            opts[key] = values[0]
        elif len(values) == n:
            opts[key] = values[k]
        else:
            raise OptionError(f"{_READER_FLAGS[key][1]}: expected one value or one per gyro ({n}), got "
                              f"{len(values)}")
    opts.update(_per_gyro(args, k))
    return opts


def _for_reader(opts: dict, path) -> dict:
    """Keep only the keywords that the reader of ``path``'s detected format accepts."""
    from ..io import detect_format

    allowed = READER_OPTIONS.get(detect_format(path), set(opts))
    return {k: v for k, v in opts.items() if k in allowed}


@dataclass(frozen=True)
class GyroSource:
    """Where one gyro's stream comes from: the file and the reader keywords."""

    path: str
    options: dict

    def key(self):
        """What identifies the sensor: the file, and the IMU, topic or columns inside it."""
        o = self.options
        cols = tuple(o["columns"]) if o.get("columns") is not None else None
        return (str(Path(self.path).expanduser().resolve()), o.get("imu"), o.get("topic"), cols)

    def describe(self) -> str:
        extra = [f"{k} {self.options[k]}" for k in ("imu", "topic", "columns") if self.options.get(k) is not None]
        return Path(self.path).name + (f" ({', '.join(extra)})" if extra else "")


def gyro_sources(args) -> list[GyroSource]:
    """The gyros the recording arguments name, gyro 1 (the reference) first.

    Raises
    ------
    InputError
        No second gyro, or the same sensor named twice (a gyro calibrated against itself).
    OptionError
        A list flag with neither one value nor one per gyro, or a bad value.
    """
    from ..errors import InputError
    from ..io import detect_format

    paths = list(args.recordings)
    lists = _lists(args)
    if len(paths) >= 2:
        n = len(paths)
    else:
        picked = [key for key in ("imu", "topic") if key in lists]
        pair = [f for f in ("imu1", "imu2", "topic1", "topic2") if getattr(args, f, None) is not None]
        if picked:
            n = len(lists[picked[0]])
        elif pair:
            n = 2
        elif detect_format(paths[0]) == "npz":
            from ..io import read_npz

            n = len(read_npz(paths[0], **_for_reader(_for_gyro(lists, args, 0, 1), paths[0])))
            lists = dict(lists, imu=list(range(n)))
        else:
            n = 1
        if n < 2:
            raise InputError(f"{Path(paths[0]).name}: expected a second gyro: a second recording, or --topic1/--topic2 "
                             "(bag, .ulg) or --imu1/--imu2 (npz, .ulg, a CSV with an instance column) to take both gyros from one file")
        paths = paths * n
    sources = [GyroSource(p, _for_gyro(lists, args, k, n)) for k, p in enumerate(paths)]
    seen = {}
    for k, s in enumerate(sources):
        j = seen.setdefault(s.key(), k)
        if j != k:
            raise InputError(f"gyro {j + 1} and gyro {k + 1} are the same sensor ({s.describe()}): a gyro calibrated "
                             "against itself; expected different recordings, IMUs (--imu1/--imu2, --imus) or topics "
                             "(--topic1/--topic2, --topics)")
    return sources


def read_sources(sources, progress=None) -> list:
    """Read every gyro's :class:`~fusion_gyrocal.io.ImuStream` (``progress()`` after each)."""
    from ..io import read_imu

    from ..errors import OptionError
    from ..io import detect_format

    streams = []
    for s in sources:
        opts = _for_reader(s.options, s.path)
        unused = sorted(set(s.options) - set(opts))
        if unused:   # a flag the format has no use for is refused, never ignored
            raise OptionError(f"{', '.join(READER_FLAGS[k] for k in unused)}: not used when reading "
                              f"{Path(s.path).name} ({detect_format(s.path)}: it takes "
                              f"{', '.join(sorted(READER_FLAGS[k] for k in READER_OPTIONS[detect_format(s.path)]))})")
        streams.append(read_imu(s.path, **opts))
        if progress:
            progress()
    return streams


def read_streams(args, progress=None):
    """Read the two gyro streams of a pair command (``report``, ``compare``)."""
    from ..errors import InputError

    sources = gyro_sources(args)
    if len(sources) != 2:
        raise InputError(f"expected the recordings of two gyros, got {len(sources)} "
                         "(gyrocal calibrate takes N gyros jointly); pick two with --imu1/--imu2 or --topic1/--topic2")
    return tuple(read_sources(sources, progress))


def read_recording(args, progress=None):
    """``(stream_1, stream_2, options)``: the pair and the :class:`~fusion_gyrocal.options.Options` of the
    flags, ``--bias-window`` converted at gyro 1's rate (or ``--rate``'s)."""
    s1, s2 = read_streams(args, progress)
    return s1, s2, options_from_args(args, rate_hz=s1.rate_hz)


def aligned_samples(s1, s2, options):
    """The sample-aligned rates of a recording pair with the masks of ``calibrate``: ``(omega_1, omega_2)``.

    The samples :func:`~fusion_gyrocal.pipeline.pipeline.run_pipeline` starts from (before its flex gate),
    by the same function (:func:`~fusion_gyrocal.pipeline.pipeline.prepare_samples`); only the valid ones.
    """
    from ..pipeline.pipeline import prepare_samples

    w1, w2, keep, _, _ = prepare_samples(s1.masked_omega, s2.masked_omega, t_1=s1.t, t_2=s2.t, options=options)
    return w1[keep], w2[keep]
