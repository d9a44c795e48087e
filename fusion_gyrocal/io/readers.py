"""File readers: IMU logs in, :class:`ImuStream` (seconds, rad/s, float64) out.

Every reader converts units at this edge (``deg/s`` and raw ``counts`` to rad/s, ``ms``/``us``/``ns``
timestamps to seconds) so nothing downstream ever sees anything but the library's units
(``ARCHITECTURE.md``). Integer timestamps (EuRoC nanoseconds, ROS stamps) are split into whole and
fractional seconds before the conversion, so an epoch-sized nanosecond count keeps the full float64
resolution (about 0.2 us at 1.7e9 s) instead of losing digits in a single ``ns * 1e-9``.
Text files of :data:`PANDAS_MIN_BYTES` or more with a one-character delimiter have their float
columns parsed by ``pyarrow.csv`` when it is installed (memory-mapped, multi-threaded, and about 0.07 s
to import against 0.3 s for pandas), else by pandas' C parser when that is installed (both many
times faster than ``np.loadtxt``); the result is the array ``np.loadtxt`` would return, which reads
everything else (and every file either parser does not read cleanly) and reports every error.

Text is read as UTF-8 with or without a byte-order mark. Lines without any number after the last
data row (what spreadsheets leave: empty rows, rows of delimiters, a text line) are dropped and
named in the stream's ``notes``; such lines between data rows are refused. Timestamps whose unit
would give a sample rate outside :data:`PLAUSIBLE_RATE_HZ` while another unit gives one inside
it are refused with the unit they look like (``time_unit=``), never silently misread. Only
regular files are opened (a FIFO would block).

Supported layouts
-----------------
* generic CSV / TSV / whitespace text, with or without a header (:func:`read_csv`);
* the EuRoC / ASL ``mav0/imu0/data.csv`` layout, detected from its header (:func:`read_csv`);
* the Xsens MT Manager text export, every delimiter and time source (:func:`read_xsens`);
* ``.npz`` archives with ``t`` and ``omega`` (or ``gyro``) arrays, and the MIMU4444 array layout
  (``t_s``, ``gyro_counts`` N x M x 3, ``gyro_lsb_per_dps``) (:func:`read_npz`);
* ROS1 / ROS2 bags with ``sensor_msgs/msg/Imu`` (:mod:`fusion_gyrocal.io.bags`);
* :func:`read_imu` picks one of these from the suffix and the content.
"""

from __future__ import annotations

import csv
import io
import re
import warnings
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..core.moments import finite_rows
from ..errors import FormatError, InputError, OptionError
from ..pipeline.streams import UNITS, check_timestamps, to_rad_per_s


#: Rate units understood by the readers (converted with :func:`fusion_gyrocal.pipeline.streams.to_rad_per_s`).
RATE_UNITS = UNITS
#: Time units understood by the readers, as powers of ten of one second.
TIME_UNITS = {"s": 0, "ms": 3, "us": 6, "ns": 9}

# Recognised gyro column triples (normalised names, see _norm) in order of preference.
_GYRO_TRIPLES = (
    ("gyro_x", "gyro_y", "gyro_z"),
    ("gyr_x", "gyr_y", "gyr_z"),
    ("w_rs_s_x", "w_rs_s_y", "w_rs_s_z"),
    ("omega_x", "omega_y", "omega_z"),
    ("angular_velocity_x", "angular_velocity_y", "angular_velocity_z"),
    ("angular_velocity.x", "angular_velocity.y", "angular_velocity.z"),
    ("field.angular_velocity.x", "field.angular_velocity.y", "field.angular_velocity.z"),
    ("gyroscope_x", "gyroscope_y", "gyroscope_z"),
    ("wx", "wy", "wz"),
    ("gx", "gy", "gz"),
)
_TIME_NAMES = ("t", "time", "timestamp", "stamp", "time_s", "t_s", "timestamp_s", "time_ns", "t_ns",
               "timestamp_ns", "time_us", "t_us", "timestamp_us", "time_ms", "t_ms", "timestamp_ms",
               "field.header.stamp", "%time")
_NS_TIME_NAMES = ("field.header.stamp", "%time")  # `rostopic echo -p` CSV: integer nanoseconds

#: Text files from this size on are parsed with pyarrow, else pandas, when installed (both optional:
#: extras "fleet" and "test"). Either reads a one-hour 200 Hz CSV (720k rows, ~55 MB) in 0.05-0.1 s
#: where np.loadtxt takes about 1 s; importing pyarrow.csv (~0.07 s) or pandas (~0.3 s) pays off from
#: about this size on.
PANDAS_MIN_BYTES = 8 << 20


# ----------------------------------------------------------------------------- the stream type
@dataclass(frozen=True)
class ImuStream:
    """One gyroscope's angular-rate stream in library units.

    Attributes
    ----------
    t : ndarray (N,)
        Strictly increasing timestamps in seconds (float64, read-only).
    omega : ndarray (N, 3)
        Angular rate in rad/s in the sensor's own frame (float64, read-only). Rows that could
        not be measured (non-finite, saturated) stay in place and are flagged in ``valid``.
    name : str
        Sensor name (topic, file stem, ``"imu3"``, ...).
    source : str
        Where the data came from (file path, plus topic / IMU index where relevant).
    rate_hz : float
        Median sample rate ``1 / median(diff(t))``; computed when not given.
    unit_in : str
        Rate unit of the file before conversion (``"rad/s"``, ``"deg/s"`` or ``"counts"``).
    valid : ndarray (N,) of bool
        Samples usable for calibration: finite and, where the reader knows the sensor's range,
        not saturated. Always ANDed with finiteness of ``omega``.
    notes : tuple of str
        What the reader did that the numbers alone do not show (trailing junk rows dropped, the
        time source of an Xsens export, a stated rate overridden). Empty when there is nothing to say.

    Raises
    ------
    InputError
        On shapes other than ``t (N,)`` / ``omega (N, 3)``, fewer than 2 samples, non-finite
        timestamps or timestamps that are not strictly increasing.
    """

    t: np.ndarray
    omega: np.ndarray
    name: str = "imu"
    source: str = ""
    rate_hz: float | None = None
    unit_in: str = "rad/s"
    valid: np.ndarray | None = None
    notes: tuple = ()

    def __post_init__(self):
        name = self.name
        omega = np.array(self.omega, dtype=np.float64)
        if omega.ndim != 2 or omega.shape[1] != 3:
            raise InputError(f"{name}: expected angular rates of shape (N, 3), got {omega.shape}")
        t = np.array(check_timestamps(f"{name}.t", self.t, length=omega.shape[0]), dtype=np.float64)
        dt = np.diff(t)
        valid = finite_rows(omega)
        if self.valid is not None:
            given = np.asarray(self.valid)
            if given.shape != valid.shape:
                raise InputError(f"{name}: expected a valid mask of shape {valid.shape}, got {given.shape}")
            valid &= given.astype(bool)
        if self.unit_in not in RATE_UNITS:
            raise InputError(f"{name}: expected unit_in in {RATE_UNITS}, got {self.unit_in!r}")
        rate = float(1.0 / np.median(dt)) if self.rate_hz is None else float(self.rate_hz)
        if not (np.isfinite(rate) and rate > 0):
            raise InputError(f"{name}: expected a positive finite rate_hz, got {self.rate_hz!r}")
        for a in (t, omega, valid):
            a.flags.writeable = False
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "omega", omega)
        object.__setattr__(self, "valid", valid)
        object.__setattr__(self, "rate_hz", rate)
        object.__setattr__(self, "notes", tuple(str(n) for n in self.notes))

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def masked_omega(self) -> np.ndarray:
        """``omega`` with the samples that are not ``valid`` (saturated, non-finite) set to NaN."""
        return np.where(self.valid[:, None], self.omega, np.nan)

    @property
    def duration_s(self) -> float:
        """``t[-1] - t[0]`` in seconds."""
        return float(self.t[-1] - self.t[0])


# ----------------------------------------------------------------------------- helpers
def _path(path, what: str = "file", *, folder: bool = False) -> Path:
    """``path`` as a Path that exists and is a regular file (or a folder when ``folder``).

    FIFOs, sockets and devices are refused before anything opens them (reading a FIFO blocks).
    """
    p = Path(path).expanduser()
    if not p.exists():
        raise FormatError(f"{p}: no such {what}")
    if not (p.is_file() or (folder and p.is_dir())):
        kind = "a folder" if p.is_dir() else "a FIFO" if p.is_fifo() else "a device" if p.is_char_device() or \
            p.is_block_device() else "a socket" if p.is_socket() else "not a regular file"
        raise FormatError(f"{p}: expected a regular {what.replace('file or folder', 'file or a folder')}, got {kind}")
    return p


def _rate_factor(unit: str, sensitivity, where: str) -> float:
    """Factor turning ``unit`` into rad/s (:func:`fusion_gyrocal.pipeline.streams.to_rad_per_s`);
    ``sensitivity`` is LSB per deg/s for raw counts."""
    try:
        return float(to_rad_per_s(np.ones(1), unit, sensitivity)[0])
    except OptionError as exc:
        raise OptionError(f"{where}: {exc}") from None


def _int_time_to_seconds(ticks: np.ndarray, decimals: int) -> np.ndarray:
    """Integer counts of ``10**-decimals`` s to float seconds without losing digits."""
    ticks = np.asarray(ticks, dtype=np.int64)
    if decimals == 0:
        return ticks.astype(np.float64)
    scale = 10 ** decimals
    whole, frac = np.divmod(ticks, scale)
    return whole.astype(np.float64) + frac.astype(np.float64) / scale


#: Sample rates an IMU log can plausibly have; timestamps whose median step gives a rate outside
#: this range in the unit they are read in are refused when another unit gives one inside it.
PLAUSIBLE_RATE_HZ = (1.0, 1e5)
_MAX_TIME_S = 1e10  # about the year 2286 as a Unix time: larger "seconds" are in a finer unit


def _rates_by_unit(raw: np.ndarray) -> tuple[float, dict[str, float], dict[str, float]]:
    """Median positive step of raw timestamps, the rate each time unit gives, and the plausible ones."""
    raw = np.asarray(raw)
    d = np.diff(raw)
    d = d[d > 0]
    if d.size == 0 or not np.isfinite(raw[[0, -1]]).all():
        return float("nan"), {}, {}
    step = float(np.median(d))
    size = float(np.max(np.abs(raw[[0, -1]].astype(np.float64))))
    rates = {u: 10.0 ** dec / step for u, dec in TIME_UNITS.items()}
    lo, hi = PLAUSIBLE_RATE_HZ
    ok = {u: r for u, r in rates.items() if lo <= r <= hi and size / 10.0 ** TIME_UNITS[u] < _MAX_TIME_S}
    return step, rates, ok


def _check_time_unit(raw: np.ndarray, unit: str, how: str, fname: str, column: str) -> None:
    """Refuse timestamps whose unit makes an implausible rate when another unit makes a plausible one.

    ``how`` says where ``unit`` came from (the option, the header, the default), for the message.
    """
    step, rates, ok = _rates_by_unit(raw)
    if not ok or unit in ok:
        return
    likely = min(ok, key=lambda u: abs(np.log10(ok[u] / 200.0)))  # nearest to a typical IMU rate
    raise InputError(f"{fname}: timestamps of column {column!r} read as {unit} ({how}) have a median step of "
                     f"{step:g} {unit} = {rates[unit]:.3g} Hz, expected {PLAUSIBLE_RATE_HZ[0]:g} Hz to "
                     f"{PLAUSIBLE_RATE_HZ[1]:g} Hz; they look like {likely} ({ok[likely]:.4g} Hz): pass "
                     f"time_unit='{likely}' (CLI --time-unit {likely})")


def _norm(name: str) -> str:
    """Normalised column name: lower case, no leading '#'/'%' clutter, units in brackets removed."""
    n = name.strip().strip('"').strip("'").strip()
    n = n.lstrip("#").strip()
    n = re.sub(r"\s*[\[(][^\])]*[\])]\s*$", "", n)  # "timestamp [ns]" -> "timestamp"
    return n.strip().lower().replace(" ", "_")


def _bracket_unit(name: str) -> str | None:
    m = re.search(r"[\[(]([^\])]*)[\])]\s*$", name)
    return m.group(1).strip().lower() if m else None


def _time_unit_from_header(name: str) -> str | None:
    unit = _bracket_unit(name)
    if unit in TIME_UNITS:
        return unit
    if unit in ("sec", "seconds"):
        return "s"
    if unit in ("µs", "usec"):
        return "us"
    n = _norm(name)
    if n in _NS_TIME_NAMES:
        return "ns"
    for u in ("ns", "us", "ms", "s"):
        if n.endswith("_" + u):
            return u
    return None


def _rate_unit_from_header(name: str) -> str | None:
    unit = (_bracket_unit(name) or "").replace(" ", "")
    n = _norm(name)
    if unit in ("rad/s", "rads^-1", "rad/sec", "rad*s^-1") or n.endswith("_rad_s") or n.endswith("_rads"):
        return "rad/s"
    if unit in ("deg/s", "dps", "°/s", "degs^-1", "deg/sec") or n.endswith("_dps") or n.endswith("_deg_s"):
        return "deg/s"
    if unit in ("counts", "lsb", "raw"):
        return "counts"
    return None


def _split(line: str, delimiter: str | None) -> list[str]:
    if delimiter is None:
        return line.split()
    return line.split(delimiter)


def _sniff_delimiter(line: str) -> str | None:
    for d in (",", "\t", ";"):
        if d in line:
            return d
    return None


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


#: Encoding of every text file read: UTF-8, with or without the byte-order mark that Excel on
#: Windows writes ("CSV UTF-8"); undecodable bytes become U+FFFD and then fail as non-numbers.
_ENCODING = "utf-8-sig"


def _check_text(path: Path) -> None:
    """Refuse UTF-16/32 text (Excel's "Unicode Text"), which would read as NUL-riddled garbage."""
    with open(path, "rb") as f:
        start = f.read(4)
    if start[:2] in (b"\xff\xfe", b"\xfe\xff") or start in (b"\x00\x00\xfe\xff",):
        raise FormatError(f"{path.name}: expected UTF-8 text, got UTF-16/32 (a byte-order mark "
                          f"{start[:2].hex(' ')}); save it as 'CSV UTF-8'")


class _Prefix(io.RawIOBase):
    """The first ``end`` bytes of a binary file, as a raw stream (the data rows before a junk trailer)."""

    def __init__(self, f, end: int):
        self._f, self._left = f, end

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:
        if self._left <= 0:
            return 0
        view = memoryview(b)[:self._left]
        n = self._f.readinto(view)
        self._left -= n or 0
        return n or 0

    def close(self) -> None:
        self._f.close()
        super().close()


def _open_text(path: Path, end: int | None = None):
    """``path`` opened as text (:data:`_ENCODING`, universal newlines), cut after ``end`` bytes if given."""
    if end is None:
        return open(path, "r", encoding=_ENCODING, errors="replace", newline=None)
    raw = _Prefix(open(path, "rb", buffering=0), end)
    return io.TextIOWrapper(io.BufferedReader(raw), encoding=_ENCODING, errors="replace", newline=None)


def _head(path: Path, n: int = 64) -> list[str]:
    _check_text(path)
    lines = []
    with _open_text(path) as f:
        for line in f:
            lines.append(line.rstrip("\n").rstrip("\r"))
            if len(lines) >= n:
                break
    return lines


def _data_end(path: Path, delimiter: str | None, first_data_line: int) -> tuple[int | None, list[str]]:
    """Where the data rows end: the byte offset before a trailer of lines without any number.

    Spreadsheets that re-save a CSV leave empty rows, rows of delimiters only (``,,,,``) and text
    lines ("Exported by ...") after the data. Those trailing lines are cut (their text is returned
    for a note); anything without a number *between* data rows stays and is refused by the parser.
    Returns ``(None, [])`` when there is no trailer.
    """
    size = path.stat().st_size
    chunk = 1 << 16
    with open(path, "rb") as f:
        while True:
            start = max(0, size - chunk)
            f.seek(start)
            buf = f.read(size - start)
            lines = buf.split(b"\n")
            if buf.endswith(b"\n"):
                lines.pop()  # the terminator of the last line, not a line
            first = 0 if start == 0 else 1  # the first piece of a chunk may be a partial line
            junk = 0
            for raw in reversed(lines[first:]):
                text = raw.decode("utf-8", "replace").strip().lstrip("\ufeff")
                if any(_is_number(x.strip()) for x in _split(text, delimiter) if x.strip()):
                    break
                junk += 1
            if junk < len(lines) - first or start == 0:
                break
            chunk *= 4  # the whole chunk was junk: look further back
    if junk == 0:
        return None, []
    kept = lines[:len(lines) - junk]
    if start == 0 and len(kept) <= first_data_line:
        return None, []  # nothing but header and junk: let the parser say "no data"
    end = start + sum(len(x) + 1 for x in kept)
    dropped = [x.decode("utf-8", "replace").strip() for x in lines[len(lines) - junk:]]
    return end, dropped


def _dropped_note(dropped: list[str]) -> str:
    shown = next((d for d in dropped if d), "")
    kinds = f", e.g. {shown[:40]!r}" if shown else ""
    return (f"dropped {len(dropped)} trailing line{'s' if len(dropped) != 1 else ''} without numbers "
            f"(empty, delimiters only or text{kinds}) after the last data row")


def _empty_as_nan(field: str) -> float:
    return float(field) if field.strip() else np.nan


def _load_columns(path: Path, *, skiprows: int, delimiter: str | None, usecols: Sequence[int],
                  dtype, end: int | None = None) -> np.ndarray:
    """``np.loadtxt`` of some columns as ``(N, len(usecols))``; empty fields become NaN (floats).

    A delimiter is taken literally (two tabs are an empty field between them, as are two spaces
    with ``delimiter=" "``); only ``delimiter=None`` merges runs of whitespace.
    """
    def load(converters=None):
        with _open_text(path, end) as f:
            return np.loadtxt(f, delimiter=delimiter, skiprows=skiprows, usecols=tuple(usecols), dtype=dtype,
                              ndmin=2, comments="#", converters=converters)

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "input contained no data": said below
            try:
                data = load()
            except ValueError as exc:
                if dtype is np.int64 or "''" not in str(exc):
                    raise
                # Empty fields (e.g. a packet that lacked gyro data): NaN, flagged later by ImuStream.valid.
                data = load(_empty_as_nan)
    except (ValueError, IndexError, OverflowError) as exc:
        raise FormatError(f"{path.name}: expected numeric data in columns {list(usecols)}, {exc}") from None
    if data.shape[0] == 0:
        raise FormatError(f"{path.name}: expected data rows after the header, got none")
    return data


def _data_start(path: Path, skiprows: int) -> int | None:
    """Byte offset of line ``skiprows`` (0-based; after a UTF-8 byte-order mark), or None.

    None when the first MiB does not hold that many lines, or when its lines before that offset
    end in a bare carriage return (the text reader's universal newlines would count them as
    lines where a count of ``\\n`` does not).
    """
    with open(path, "rb") as f:
        head = f.read(1 << 20)
    pos = 3 if head.startswith(b"\xef\xbb\xbf") else 0
    for _ in range(skiprows):
        nl = head.find(b"\n", pos)
        if nl < 0:
            return None
        pos = nl + 1
    return None if b"\r" in head[:pos].replace(b"\r\n", b"") else pos


def _pyarrow_floats(path: Path, *, skiprows: int, delimiter: str, usecols: Sequence[int],
                    end: int | None = None) -> np.ndarray | None:
    """What ``_load_columns(..., dtype=np.float64)`` returns, parsed by ``pyarrow.csv``; or None.

    The file is memory-mapped and only the data rows (after ``skiprows`` lines, before ``end``)
    are parsed, with the delimiter taken literally, no quoting and every field of a used column a
    number. None (another parser reads the file or says what is wrong) when pyarrow is not
    installed, the data hold a ``#`` anywhere (``np.loadtxt`` cuts comments, also in unused
    columns), or pyarrow does not read the rows cleanly: a parse or conversion error (an empty
    field, a blank or short row, a word), or a non-finite value. pyarrow parses floats exactly
    (correctly rounded), so a result is the array ``np.loadtxt`` would return.
    """
    try:
        import pyarrow as pa
        import pyarrow.csv as pacsv
    except ImportError:
        return None
    import mmap

    start = _data_start(path, skiprows)
    stop = path.stat().st_size if end is None else end
    if start is None or stop <= start:
        return None
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        if mm.find(b"#", start, stop) >= 0:
            return None
    names = [f"f{k}" for k in usecols]
    try:
        with pa.memory_map(str(path)) as src:
            src.seek(start)
            table = pacsv.read_csv(
                pa.BufferReader(src.read_buffer(stop - start)),
                read_options=pacsv.ReadOptions(autogenerate_column_names=True),
                parse_options=pacsv.ParseOptions(delimiter=delimiter, quote_char=False, ignore_empty_lines=False),
                convert_options=pacsv.ConvertOptions(column_types=dict.fromkeys(names, pa.float64()),
                                                     include_columns=names, null_values=[],
                                                     strings_can_be_null=False, quoted_strings_can_be_null=False))
    except (pa.ArrowException, ValueError, OSError):   # np.loadtxt then reads the file or says what is wrong
        return None
    x = np.empty((table.num_rows, len(names)))
    for j, name in enumerate(names):   # from the value buffers: (Chunked)Array.to_numpy would import pandas
        row = 0
        for chunk in table.column(name).chunks:
            if chunk.null_count:
                return None
            n = len(chunk)
            x[row:row + n, j] = np.frombuffer(chunk.buffers()[1], dtype=np.float64, count=n, offset=8 * chunk.offset)
            row += n
    return x if x.shape[0] and np.isfinite(x).all() else None


def _pandas_floats(path: Path, *, skiprows: int, delimiter: str | None, usecols: Sequence[int],
                   end: int | None = None) -> np.ndarray | None:
    """What ``_load_columns(..., dtype=np.float64)`` returns, parsed by pandas' C parser; or None.

    None (use ``np.loadtxt``) when pandas is not installed or does not read the file cleanly: any
    parse error, or any NaN (an empty field, a short row, a blank line or an ``NA`` word, which
    ``np.loadtxt`` each treats in its own way). Both parse floats exactly, so a result is the
    array ``np.loadtxt`` would return.
    """
    try:
        import pandas as pd
    except ImportError:
        return None
    # pandas 3.1 parses every float exactly (and deprecates float_precision); before, only "round_trip" does
    exact = {} if tuple(int(v) for v in re.findall(r"\d+", pd.__version__)[:2]) >= (3, 1) else \
        {"float_precision": "round_trip"}
    try:
        with _open_text(path, end) as f:
            df = pd.read_csv(f, sep=r"\s+" if delimiter is None else delimiter, header=None, skiprows=skiprows,
                             usecols=list(usecols), dtype=np.float64, comment="#", quoting=csv.QUOTE_NONE,
                             skip_blank_lines=False, **exact)
    except (ValueError, TypeError, OverflowError, IndexError):  # np.loadtxt then reads the file or says what is wrong
        return None
    x = df[list(usecols)].to_numpy(dtype=np.float64)
    return None if x.shape[0] == 0 or np.isnan(x).any() else x


def _fast_floats(path: Path, *, skiprows: int, delimiter: str | None, usecols: Sequence[int],
                 end: int | None = None) -> np.ndarray | None:
    """Float columns of a big file by pyarrow (:func:`_pyarrow_floats`), else pandas (:func:`_pandas_floats`).

    None (``np.loadtxt`` reads the file) for files smaller than :data:`PANDAS_MIN_BYTES`, a column
    used twice, a delimiter longer than one character, or when neither parser is installed or
    reads the file cleanly. pyarrow needs a delimiter (whitespace runs go to pandas).
    """
    if len(set(usecols)) < len(usecols) or (delimiter is not None and len(delimiter) != 1):
        return None
    if path.stat().st_size < PANDAS_MIN_BYTES:
        return None
    kw = dict(skiprows=skiprows, delimiter=delimiter, usecols=usecols, end=end)
    x = _pyarrow_floats(path, **kw) if delimiter is not None else None
    return x if x is not None else _pandas_floats(path, **kw)


def _read_floats(path: Path, *, skiprows: int, delimiter: str | None, usecols: Sequence[int],
                 end: int | None = None) -> np.ndarray:
    """Columns ``usecols`` as float64 ``(N, k)``: pyarrow or pandas when one reads them cleanly, else ``np.loadtxt``."""
    kw = dict(skiprows=skiprows, delimiter=delimiter, usecols=usecols, end=end)
    x = _fast_floats(path, **kw)
    return x if x is not None else _load_columns(path, dtype=np.float64, **kw)


def _read_columns(path: Path, *, skiprows: int, delimiter: str | None, k_t: int, k_w: Sequence[int],
                  int_time: bool, end: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Time column ``k_t`` ((N,), int64 when ``int_time``, else float64) and rate columns ``k_w`` ((N, 3) float64).

    Floats of big files are parsed by pyarrow or pandas when one is installed and reads them cleanly
    (:func:`_fast_floats`, one pass for all columns); integers, other files and every error go
    through ``np.loadtxt`` (:func:`_load_columns`), which only takes plain integers as int64
    (pandas would also take ``6.0``).
    """
    kw = dict(skiprows=skiprows, delimiter=delimiter, end=end)
    if int_time:
        t = _load_columns(path, usecols=[k_t], dtype=np.int64, **kw)[:, 0]
        return t, _read_floats(path, usecols=k_w, **kw)
    x = _read_floats(path, usecols=[k_t, *k_w], **kw)
    return x[:, 0], x[:, 1:]


# ----------------------------------------------------------------------------- CSV and EuRoC
def _euroc_csv(path: Path) -> Path:
    """Resolve an EuRoC folder (``mav0/imu0`` or ``mav0`` holding one ``imu*``) to its data.csv."""
    if path.is_file():
        return path
    if (path / "data.csv").is_file():
        return path / "data.csv"
    candidates = sorted(p for p in path.glob("imu*/data.csv") if p.is_file())
    if not candidates and (path / "mav0").is_dir():
        candidates = sorted(p for p in (path / "mav0").glob("imu*/data.csv") if p.is_file())
    if len(candidates) == 1:
        return candidates[0]
    if len(candidates) > 1:
        names = [str(c.parent.relative_to(path)) for c in candidates]
        raise InputError(f"{path}: holds several IMU folders {names}; pass the folder of one of them")
    raise FormatError(f"{path}: expected a CSV file, an EuRoC 'imu0' folder with data.csv, or a 'mav0' "
                      f"folder with one imu*/data.csv, got a folder without any")


def _resolve_column(spec, header: list[str] | None, ncols: int, what: str, fname: str) -> int:
    if isinstance(spec, (int, np.integer)):
        k = int(spec)
        if not -ncols <= k < ncols:
            raise InputError(f"{fname}: {what} index {k} is out of range for {ncols} columns")
        return k % ncols
    if header is None:
        raise InputError(f"{fname}: {what} {spec!r} is a name but the file has no header row; pass a column index")
    wanted = _norm(str(spec))
    for k, h in enumerate(header):
        if h.strip() == str(spec) or _norm(h) == wanted:
            return k
    raise FormatError(f"{fname}: expected a column {spec!r} for {what}, got header {header}")


def read_csv(path, *, time_column=None, columns=None, unit: str | None = None, sensitivity=None,
             time_unit: str | None = None, delimiter: str | None = None, name: str | None = None) -> ImuStream:
    """Read a gyro stream from a delimited text file (generic CSV, or EuRoC / ASL ``imu0/data.csv``).

    Parameters
    ----------
    path : str or Path
        The file, or an EuRoC folder: ``mav0/imu0`` (holding ``data.csv``) or ``mav0`` with a single
        ``imu*`` sub-folder.
    time_column : int or str, optional
        Timestamp column (index or header name). Default: a header column named like ``t``,
        ``time``, ``timestamp`` (units in brackets or a ``_ns``/``_us``/``_ms``/``_s`` suffix are
        recognised), else column 0.
    columns : sequence of 3 int or str, optional
        The x, y, z gyro columns. Default: a recognised header triple (``gyro_x..``, ``gyr_x..``,
        EuRoC ``w_RS_S_x..``, ``omega_x..``, ``wx..``, ``gx..``, ROS ``angular_velocity.x..``),
        or columns 1, 2, 3 of a file without header.
    unit : {"rad/s", "deg/s", "counts"}, optional
        Rate unit in the file. Default: from the header (``[rad s^-1]``, ``[deg/s]``, ``_dps``),
        else rad/s.
    sensitivity : float, optional
        LSB per deg/s, required with ``unit="counts"`` (rad/s = counts / sensitivity * pi / 180).
    time_unit : {"s", "ms", "us", "ns"}, optional
        Timestamp unit. Default: from the header (``[ns]``, ``_ns``), ``ns`` for EuRoC, else s.
    delimiter : str, optional
        Field separator. Default: sniffed from the first data row (``,`` tab ``;`` or whitespace).
    name : str, optional
        Stream name. Default: the file stem (the folder name for EuRoC ``data.csv``).

    Returns
    -------
    ImuStream

    Raises
    ------
    FormatError
        When the file has no data rows, non-numeric data, or no recognisable gyro columns.
    InputError
        On inconsistent options (unknown unit, counts without sensitivity, bad column indices)
        or timestamps that are not strictly increasing.
    """
    path = _euroc_csv(_path(path, "file or folder", folder=True))
    fname = path.name if path.name != "data.csv" else f"{path.parent.name}/{path.name}"
    lines = _head(path)
    # Leading blank lines and '//', '%', '#' comment lines are skipped; a '#' line right above the
    # first data row with as many fields is the header (the EuRoC "#timestamp [ns],w_RS_S_x ..." row).
    first, last_hash = 0, None
    while first < len(lines) and (not lines[first].strip() or lines[first].lstrip().startswith(("//", "%", "#"))):
        if lines[first].lstrip().startswith("#"):
            last_hash = first
        first += 1
    if first >= len(lines):
        raise FormatError(f"{fname}: expected a header or data rows, got no data")

    def fields_of(line: str, delim) -> list[str]:
        f = _split(line.strip(), delim)
        return f[:-1] if f and delim is not None and not f[-1].strip() else f  # trailing delimiter

    delim = delimiter if delimiter is not None else _sniff_delimiter(lines[first])
    fields = fields_of(lines[first], delim)
    header = None
    if not all(_is_number(f) for f in fields if f.strip()):
        header, skip = [f.strip() for f in fields], first + 1
        data_lines = [ln for ln in lines[skip:] if ln.strip() and not ln.lstrip().startswith("#")]
        if not data_lines:
            raise FormatError(f"{fname}: expected data rows after the header, got none")
        if delimiter is None and delim is None:
            delim = _sniff_delimiter(data_lines[0])
            header = [f.strip() for f in fields_of(lines[first], delim)]
        ncols = len(fields_of(data_lines[0], delim))
    else:
        skip, ncols = first, len(fields)
        if last_hash == first - 1:
            hfields = fields_of(lines[last_hash].lstrip()[1:], delim)
            if len(hfields) == ncols and not all(_is_number(f) for f in hfields if f.strip()):
                header = [f.strip() for f in hfields]
        data_lines = [lines[first]]
    if header is not None:
        ncols = max(ncols, len(header))
    norm_header = [_norm(h) for h in header] if header is not None else None
    is_euroc = norm_header is not None and "w_rs_s_x" in norm_header

    # time column
    if time_column is None:
        k_t = 0
        if norm_header is not None:
            k_t = next((norm_header.index(c) for c in _TIME_NAMES if c in norm_header), None)
            if k_t is None:
                raise FormatError(f"{fname}: expected a time column named like 't', 'time' or 'timestamp' or "
                                  f"one given by time_column=, got header {header}")
    else:
        k_t = _resolve_column(time_column, header, ncols, "the time column", fname)

    # gyro columns
    if columns is None:
        if norm_header is None:
            if ncols < 4:
                raise FormatError(f"{fname}: expected at least 4 columns (time and x, y, z rates) in a file "
                                  f"without header, got {ncols}")
            k_w = [1, 2, 3]
        else:
            k_w = None
            for triple in _GYRO_TRIPLES:
                if all(c in norm_header for c in triple):
                    k_w = [norm_header.index(c) for c in triple]
                    break
            if k_w is None:
                raise FormatError(f"{fname}: expected a column 'gyro_x' (or gyr_x, w_RS_S_x, omega_x, wx, "
                                  f"angular_velocity.x, ...) or columns given by columns=, got header {header}")
    else:
        columns = list(columns)
        if len(columns) != 3:
            raise InputError(f"{fname}: expected 3 gyro columns (x, y, z), got {len(columns)}: {columns}")
        k_w = [_resolve_column(c, header, ncols, "a gyro column", fname) for c in columns]

    # units
    if time_unit is not None:
        how = "time_unit= given"
    elif header is not None and _time_unit_from_header(header[k_t]):
        time_unit, how = _time_unit_from_header(header[k_t]), f"as the header {header[k_t]!r} says"
    elif is_euroc:
        time_unit, how = "ns", "the EuRoC layout"
    else:
        time_unit, how = "s", "the default"
    if time_unit not in TIME_UNITS:
        raise InputError(f"{fname}: expected time_unit in {tuple(TIME_UNITS)}, got {time_unit!r}")
    if unit is None:
        unit = (_rate_unit_from_header(header[k_w[0]]) if header is not None else None) or "rad/s"
    factor = _rate_factor(unit, sensitivity, fname)

    # junk after the data (spreadsheets): cut, and said in a note
    end, dropped = _data_end(path, delim, skip)
    notes = [_dropped_note(dropped)] if dropped else []

    # timestamps: integer ticks keep every digit, decimals go through float64
    row0 = _split(data_lines[0], delim)
    first_t = row0[k_t].strip() if k_t < len(row0) else ""
    raw = None
    if re.fullmatch(r"[+-]?\d+", first_t):
        try:
            raw, w = _read_columns(path, skiprows=skip, delimiter=delim, k_t=k_t, k_w=k_w, int_time=True, end=end)
        except FormatError:
            raw = None  # some rows are not integers: fall back to float parsing
    if raw is None:
        raw, w = _read_columns(path, skiprows=skip, delimiter=delim, k_t=k_t, k_w=k_w, int_time=False, end=end)
        if not np.isfinite(raw).all():
            j = int(np.argmax(~np.isfinite(raw)))
            raise FormatError(f"{fname}: data row {j + 1} has no timestamp (an empty or non-finite field in the "
                              f"time column); expected a number in every row")
    column = header[k_t] if header is not None else f"#{k_t}"
    _check_time_unit(raw, time_unit, how, fname, column)
    if raw.dtype.kind == "i":
        t = _int_time_to_seconds(raw, TIME_UNITS[time_unit])
    else:
        t = raw / 10.0 ** TIME_UNITS[time_unit]
    w = w * factor
    if name is None:
        name = path.parent.name if path.name == "data.csv" else path.stem
    return ImuStream(t, w, name=name, source=str(path), unit_in=unit, notes=tuple(notes))


# ----------------------------------------------------------------------------- Xsens
#: ``SampleTimeFine``: a 32-bit count of 0.1 ms (10 kHz) ticks that wraps after about 119 h.
XSENS_FINE_TICKS_PER_S = 10_000
_XSENS_RATE = re.compile(r"//\s*(?:update|sample|output)\s*rate\s*:\s*(.*?)\s*$", re.IGNORECASE)
_UTC_FIELDS = ("utc_nano", "utc_year", "utc_month", "utc_day", "utc_hour", "utc_minute", "utc_second")
_UTC_VALID_BIT = 0x04  # UTC_Valid flag: "valid UTC" (0x01 time of week, 0x02 week number)


def _xsens_delimiter(header: str) -> str:
    """MT Manager's export delimiter (tab, semicolon, comma or a single space), from the header row."""
    for d in ("\t", ";", ","):
        if d in header:
            return d
    return " "


def _unwrap_counter(values: np.ndarray, modulus: int, what: str, fname: str) -> np.ndarray:
    """Integer ticks of a wrapping counter, made monotonic (int64). A step of more than half the
    modulus is not a wrap but a step back, and a step of zero a repeated sample: both refused."""
    ticks = values.astype(np.int64)
    steps = np.mod(np.diff(ticks), modulus)
    bad = (steps == 0) | (steps > modulus // 2)
    if bad.any():
        j = int(np.argmax(bad)) + 1
        how = "repeats" if steps[j - 1] == 0 else "steps back"
        raise InputError(f"{fname}: expected a strictly advancing {what}, but it {how} at data row {j + 1} "
                         f"({int(ticks[j - 1])} -> {int(ticks[j])})")
    return ticks[0] + np.concatenate(([0], np.cumsum(steps)))


def _utc_ns(cols: np.ndarray) -> np.ndarray:
    """Integer ns since 1970 of the columns UTC_Nano, _Year, _Month, _Day, _Hour, _Minute, _Second."""
    nano, year, month, day, hour, minute, second = (cols[:, k].astype(np.int64) for k in range(7))
    months = np.array((year - 1970) * 12 + (month - 1), dtype="datetime64[M]")
    days = (months.astype("datetime64[D]") - np.datetime64("1970-01-01", "D")).astype(np.int64) + day - 1
    seconds = days * 86400 + hour * 3600 + minute * 60 + second
    return seconds * 1_000_000_000 + nano


def read_xsens(path, *, unit: str = "rad/s", rate_hz: float | None = None, name: str | None = None) -> ImuStream:
    """Read an Xsens MT Manager text export (``//`` comment lines, a header row, ``Gyr_X/Y/Z``).

    Every variant MT Manager writes is read: tab, comma, semicolon or space delimiter (empty fields
    are kept in place as NaN, also between spaces), with or without a ``// Update Rate: 100.0Hz``
    (MT 4.x) or ``// Sample rate: 120.0Hz`` line (MT Manager 2019 and later state none), with or
    without orientation columns (``Quat_q0..``, ``Mat[1][1]..``, ``Roll/Pitch/Yaw``, ``Euler_X..``).
    Rows whose gyro fields are empty or ``NaN`` stay in place and are flagged in ``valid``.

    The timestamps come from the first time source the file holds in every row:

    1. ``SampleTimeFine``: the device's 10 kHz clock (a 32-bit count; wraps are undone);
    2. the ``UTC_Nano, UTC_Year, ..., UTC_Second`` columns (when ``UTC_Valid`` is present, only
       if every row has its valid-UTC bit 0x04);
    3. ``PacketCounter`` (or ``Counter``), 16-bit, divided by the rate stated in the file or
       ``rate_hz``; wraps at 65536 are undone, so dropped packets leave gaps, not shifts.

    Sources that are present but empty are skipped, and the stream's ``notes`` say which source
    timed it and why others were not used.

    Parameters
    ----------
    path : str or Path
    unit : {"rad/s", "deg/s"}
        Unit of the ``Gyr_*`` columns (MT Manager exports rad/s unless configured otherwise).
    rate_hz : float, optional
        Sample rate for packet-counter timing, for exports that state none (MT Manager 2019 and
        later); overrides a stated rate (with a note). Not used when the file holds
        ``SampleTimeFine`` or UTC time.
    name : str, optional
        Stream name (default: the file stem).

    Raises
    ------
    FormatError
        Without ``Gyr_X/Y/Z`` columns (the message lists the columns found), without any time
        source, with a packet counter but no rate (the message names ``rate_hz``), with an
        unreadable rate line or non-numeric fields.
    InputError
        When the chosen time source repeats or steps back.
    OptionError
        On a ``rate_hz`` that is not a positive finite number.
    """
    path = _path(path)
    fname = path.name
    lines = _head(path, 256)
    rate, k = None, 0
    while k < len(lines) and (lines[k].lstrip().startswith("//") or not lines[k].strip()):
        m = _XSENS_RATE.match(lines[k].strip())
        if m:
            v = re.fullmatch(r"(.*?)\s*hz", m.group(1), re.IGNORECASE)
            try:
                rate = float((v.group(1) if v else m.group(1)).strip())
            except ValueError:
                rate = float("nan")
            if not (np.isfinite(rate) and rate > 0):
                raise FormatError(f"{fname}: expected a positive rate in Hz in the line {lines[k].strip()!r}")
        k += 1
    if k >= len(lines):
        raise FormatError(f"{fname}: expected a header row (PacketCounter, Gyr_X, ...) after the '//' comment "
                          "lines, got none")
    if rate_hz is not None:
        try:
            rate_hz = float(rate_hz)
        except (TypeError, ValueError):
            rate_hz = float("nan")
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise OptionError(f"rate_hz: expected a positive sample rate in Hz, got {rate_hz!r}")
    delim = _xsens_delimiter(lines[k])
    names = [h.strip() for h in lines[k].split(delim)]
    while names and not names[-1]:
        names.pop()  # a trailing delimiter
    low = [h.lower() for h in names]
    found = ", ".join(h for h in names if h)

    def col(*candidates):
        return next((low.index(c) for c in candidates if c in low), None)

    k_w = [col("gyr_x"), col("gyr_y"), col("gyr_z")]
    if None in k_w:
        raise FormatError(f"{fname}: no gyro columns (Gyr_X/Gyr_Y/Gyr_Z); columns found: {found}")
    skip = k + 1
    data_head = [ln for ln in lines[skip:] if ln.strip()]
    if not data_head:
        raise FormatError(f"{fname}: expected data rows after the header row, got none")

    def empty_in_head(cols) -> bool:  # every head row lacks one of these fields
        def lacks(line):
            f = line.split(delim)
            return any(c >= len(f) or not f[c].strip() or f[c].strip().lower() == "nan" for c in cols)
        return all(lacks(ln) for ln in data_head)

    end, dropped = _data_end(path, delim, skip)
    notes = [_dropped_note(dropped)] if dropped else []
    w = _read_floats(path, skiprows=skip, delimiter=delim, usecols=k_w, end=end) * _rate_factor(unit, None, fname)

    sources = []
    if col("sampletimefine") is not None:
        sources.append(("SampleTimeFine", [col("sampletimefine")]))
    utc = [col(c) for c in _UTC_FIELDS]
    if None not in utc:
        sources.append(("UTC", utc + ([col("utc_valid")] if col("utc_valid") is not None else [])))
    k_c = col("packetcounter", "counter")
    if k_c is not None:
        sources.append((names[k_c], [k_c]))
    skipped = []
    for what, cols in sources:
        if empty_in_head(cols):
            skipped.append(f"{what} is empty")
            continue
        x = _read_floats(path, skiprows=skip, delimiter=delim, usecols=cols, end=end)
        missing = ~finite_rows(x)
        if missing.any():
            skipped.append(f"{what} is missing in {int(missing.sum())} of {len(x)} rows")
            continue
        if (x != np.round(x)).any():
            j = int(np.argmax((x != np.round(x)).any(axis=1)))
            raise FormatError(f"{fname}: expected whole numbers in {what}, got {x[j].tolist()} in data row {j + 1}")
        if what == "SampleTimeFine":
            ticks = _unwrap_counter(x[:, 0], 1 << 32, what, fname)
            t, rate_out = _int_time_to_seconds(ticks, 4), None
            notes.append(f"time from SampleTimeFine (the device's {XSENS_FINE_TICKS_PER_S // 1000} kHz clock)")
        elif what == "UTC":
            if x.shape[1] == 8 and ((x[:, 7].astype(np.int64) & _UTC_VALID_BIT) == 0).any():
                skipped.append(f"UTC is not valid (UTC_Valid without bit 0x04) in "
                               f"{int(((x[:, 7].astype(np.int64) & _UTC_VALID_BIT) == 0).sum())} rows")
                continue
            t, rate_out = _int_time_to_seconds(_utc_ns(x[:, :7]), 9), None
            notes.append("time from the UTC columns")
        else:
            r = rate_hz if rate_hz is not None else rate
            if r is None:
                why = "; ".join(skipped + ["no '// Update Rate:' or '// Sample rate:' line"])
                raise FormatError(f"{fname}: no sample rate to time the samples by {what} ({why}); pass rate_hz= "
                                  f"(the update rate set in MT Manager)")
            modulus = 1 << 16 if x.max(initial=0) < (1 << 16) else 1 << 32
            t = _unwrap_counter(x[:, 0], modulus, what, fname).astype(np.float64) / r
            rate_out = r
            given = f"rate_hz={r:g}" if rate_hz is not None else f"the stated {r:g} Hz"
            notes.append(f"time from {what} at {given}")
            if rate_hz is not None and rate is not None and rate_hz != rate:
                notes.append(f"rate_hz={rate_hz:g} overrides the file's stated {rate:g} Hz")
        if skipped:
            notes[-1] += f" ({'; '.join(skipped)})"
        if rate_hz is not None and what in ("SampleTimeFine", "UTC"):
            notes.append(f"rate_hz={rate_hz:g} not used: the file holds {what} time")
        return ImuStream(t, w, name=name or path.stem, source=str(path), rate_hz=rate_out, unit_in=unit,
                         notes=tuple(notes))
    why = "; ".join(skipped) if skipped else "none of these columns"
    raise FormatError(f"{fname}: no time source: expected SampleTimeFine, UTC_* columns or a PacketCounter in "
                      f"every row ({why}); columns found: {found}")


def _looks_like_xsens(lines: list[str]) -> bool:
    """An MT Manager export: its '//' comment lines, or a header naming Xsens' counter or clock columns."""
    comments = [ln for ln in lines if ln.lstrip().startswith("//")]
    if any(re.search(r"(update|sample)\s*rate\s*:|mt manager|xda version|deviceid", ln, re.IGNORECASE)
           for ln in comments):
        return True
    for ln in lines[:64]:
        if ln.lstrip().startswith("//") or not ln.strip():
            continue
        tokens = {x.strip().lower() for x in re.split(r"[\t,; ]", ln)}
        clock = tokens & {"packetcounter", "sampletimefine", "counter"}
        return bool(clock) and any(x.startswith(("gyr_", "acc_", "mag_", "quat_", "mat[")) for x in tokens)
    return False


# ----------------------------------------------------------------------------- npz
def read_npz(path, imu: int | None = None, *, unit: str = "rad/s", name: str | None = None):
    """Read gyro streams from a numpy ``.npz`` archive.

    Two layouts are recognised:

    * generic: ``t`` (N,) in seconds and ``omega`` (or ``gyro``) of shape (N, 3) or (N, M, 3) in
      ``unit``; an optional boolean ``valid`` (N,) (for every IMU) or (N, M) is honoured (as written by
      :func:`fusion_gyrocal.io.write_npz`);
    * the MIMU4444 array layout (``../shared/data/mimu_8imu_array``): ``t_s`` (N,) in seconds,
      ``gyro_counts`` int16 (N, M, 3) and ``gyro_lsb_per_dps``. Samples with any axis at the int16
      limits (the +-1998 deg/s clip) are flagged invalid.

    Parameters
    ----------
    path : str or Path
    imu : int, optional
        0-based index of the IMU along the second axis (``imu=0`` is the MIMU data's "IMU 1").
    unit : {"rad/s", "deg/s"}
        Rate unit of the generic layout (the MIMU layout states its own).
    name : str, optional
        Stream name (default: the file stem, or ``imu<k>`` for multi-IMU files).

    Returns
    -------
    ImuStream
        When ``imu`` is given.
    tuple of ImuStream
        All IMUs in the file (one element for an (N, 3) file) when ``imu`` is None.
    """
    path = _path(path)
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic not in (b"PK\x03\x04", b"PK\x05\x06"):
        got = "an empty file" if not magic else "a .npy array" if magic.startswith(b"\x93NUM") else \
            "a file that is not a zip archive"
        raise FormatError(f"{path.name}: expected a numpy .npz archive (zip), got {got}")
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        why = "an object array (pickled data), which is not read" if "pickle" in str(exc) else \
            " ".join(str(exc).split())
        raise FormatError(f"{path.name}: expected a complete numpy .npz archive of numeric arrays, got {why}") \
            from None
    valid = None
    if {"t_s", "gyro_counts", "gyro_lsb_per_dps"} <= d.keys():
        t = np.asarray(d["t_s"], dtype=np.float64)
        counts = np.asarray(d["gyro_counts"])
        if counts.ndim == 2:
            counts = counts[:, None, :]
        info = np.iinfo(counts.dtype) if counts.dtype.kind in "iu" else None
        w = counts.astype(np.float64) * _rate_factor("counts", float(d["gyro_lsb_per_dps"]), path.name)
        if info is not None:
            valid = ~((counts >= info.max) | (counts <= info.min)).any(axis=-1)
        unit_in = "counts"
    elif "t" in d and ("omega" in d or "gyro" in d):
        t = np.asarray(d["t"], dtype=np.float64)
        w = np.asarray(d["omega"] if "omega" in d else d["gyro"], dtype=np.float64)
        w = w * _rate_factor(unit, None, path.name)
        if w.ndim == 2:
            w = w[:, None, :]
        if "valid" in d:
            valid = np.asarray(d["valid"], dtype=bool)
            if valid.ndim == 1:
                valid = valid[:, None]
        unit_in = unit
    else:
        raise FormatError(f"{path.name}: expected keys 't' and 'omega' (or 'gyro'), or the MIMU layout "
                          f"'t_s', 'gyro_counts', 'gyro_lsb_per_dps', got {sorted(d)}")
    if w.ndim != 3 or w.shape[2] != 3:
        raise FormatError(f"{path.name}: expected gyro data of shape (N, 3) or (N, M, 3), got {w.shape}")
    n_imu = w.shape[1]
    multi = n_imu > 1
    if valid is not None:  # one mask per sample applies to every IMU; (N, M) masks are per IMU
        if valid.shape not in ((w.shape[0], 1), (w.shape[0], n_imu)):
            raise FormatError(f"{path.name}: expected 'valid' of shape ({w.shape[0]},) or ({w.shape[0]}, {n_imu}), "
                              f"got {valid.shape}")
        valid = np.broadcast_to(valid, (w.shape[0], n_imu))

    def stream(k: int) -> ImuStream:
        nm = name or (f"imu{k}" if multi else path.stem)
        src = f"{path}[imu={k}]" if multi else str(path)
        return ImuStream(t, w[:, k], name=nm, source=src, unit_in=unit_in,
                         valid=None if valid is None else valid[:, k])

    if imu is None:
        return tuple(stream(k) for k in range(n_imu))
    k = int(imu)
    if not 0 <= k < n_imu:
        raise InputError(f"{path.name}: expected imu in 0..{n_imu - 1} (0-based), got {imu}")
    return stream(k)


# ----------------------------------------------------------------------------- dispatch
FORMATS = ("auto", "csv", "euroc", "xsens", "npz", "bag")


def detect_format(path) -> str:
    """Guess the layout of ``path``: one of ``"csv"``, ``"euroc"``, ``"xsens"``, ``"npz"``, ``"bag"``."""
    p = _path(path, "file or folder", folder=True)
    if p.is_dir():
        if (p / "metadata.yaml").is_file() or any(p.glob("*.db3")) or any(p.glob("*.mcap")):
            return "bag"
        return "euroc"
    suffix = p.suffix.lower()
    if suffix in (".bag", ".db3", ".mcap"):
        return "bag"
    if suffix == ".npz":
        return "npz"
    with open(p, "rb") as f:
        magic = f.read(13)
    if magic.startswith(b"#ROSBAG V2.0"):
        return "bag"
    if magic.startswith(b"PK"):
        return "npz"
    lines = _head(p, 256)
    if _looks_like_xsens(lines):
        return "xsens"
    first = next((ln for ln in lines if ln.strip()), "")
    if first.startswith("#") and "w_rs_s_x" in first.lower():
        return "euroc"
    return "csv"


def read_imu(path, *, format: str = "auto", **options) -> ImuStream:
    """Read one gyro stream from any supported file, choosing the reader from suffix and content.

    Parameters
    ----------
    path : str or Path
        A CSV/TSV/text file, an EuRoC ``imu0`` folder, an Xsens export, an ``.npz``, a ROS1
        ``.bag`` or a ROS2 bag folder.
    format : {"auto", "csv", "euroc", "xsens", "npz", "bag"}
        Force a reader instead of :func:`detect_format`.
    **options
        Passed to the reader: :func:`read_csv` (``columns``, ``unit``, ``time_unit``, ...),
        :func:`read_xsens` (``unit``, ``rate_hz``), :func:`read_npz` (``imu``, ``unit``),
        :func:`fusion_gyrocal.io.read_bag` (``topic``).

    Raises
    ------
    InputError
        When the file holds several IMUs (npz) or Imu topics (bag) and none was chosen; the
        message lists the choices.
    """
    if format not in FORMATS:
        raise InputError(f"format: expected one of {FORMATS}, got {format!r}")
    fmt = detect_format(path) if format == "auto" else format
    if fmt in ("csv", "euroc"):
        return read_csv(path, **options)
    if fmt == "xsens":
        return read_xsens(path, **options)
    if fmt == "npz":
        imu = options.pop("imu", None)
        if imu is not None:
            return read_npz(path, imu, **options)
        streams = read_npz(path, **options)
        if len(streams) == 1:
            return streams[0]
        raise InputError(f"{Path(path).name}: holds {len(streams)} IMUs; pass imu=0..{len(streams) - 1} "
                         "to choose one")
    from .bags import read_bag
    return read_bag(path, **options)
