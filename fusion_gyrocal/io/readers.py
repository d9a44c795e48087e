"""File readers: IMU logs in, :class:`ImuStream` (seconds, rad/s, float64) out.

Every reader converts units at this edge (``deg/s`` and raw ``counts`` to rad/s, ``ms``/``us``/``ns``
timestamps to seconds) so nothing downstream ever sees anything but the library's units
(``ARCHITECTURE.md``). Integer timestamps (EuRoC nanoseconds, ROS stamps) are split into whole and
fractional seconds before the conversion, so an epoch-sized nanosecond count keeps the full float64
resolution (about 0.2 us at 1.7e9 s) instead of losing digits in a single ``ns * 1e-9``.
Text files of :data:`PANDAS_MIN_BYTES` or more have their float columns parsed by pandas when it
is installed (about 8x faster); the result is the same as ``np.loadtxt``'s, which reads everything
else and reports every error.

Supported layouts
-----------------
* generic CSV / TSV / whitespace text, with or without a header (:func:`read_csv`);
* the EuRoC / ASL ``mav0/imu0/data.csv`` layout, detected from its header (:func:`read_csv`);
* the Xsens MT Manager text export (:func:`read_xsens`);
* ``.npz`` archives with ``t`` and ``omega`` (or ``gyro``) arrays, and the MIMU4444 array layout
  (``t_s``, ``gyro_counts`` N x M x 3, ``gyro_lsb_per_dps``) (:func:`read_npz`);
* ROS1 / ROS2 bags with ``sensor_msgs/msg/Imu`` (:mod:`fusion_gyrocal.io.bags`);
* :func:`read_imu` picks one of these from the suffix and the content.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

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

#: Text files from this size on are parsed with pandas when it is installed (it is optional: extras
#: "fleet" and "test"). Its C parser reads a one-hour 200 Hz CSV (720k rows, ~55 MB) in about 0.15 s
#: where np.loadtxt takes about 1 s; importing pandas (~0.5 s) pays off from about this size on.
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

    def __post_init__(self):
        name = self.name
        omega = np.array(self.omega, dtype=np.float64)
        if omega.ndim != 2 or omega.shape[1] != 3:
            raise InputError(f"{name}: expected angular rates of shape (N, 3), got {omega.shape}")
        t = np.array(check_timestamps(f"{name}.t", self.t, length=omega.shape[0]), dtype=np.float64)
        dt = np.diff(t)
        valid = np.isfinite(omega).all(axis=1)
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
def _path(path, what: str = "file") -> Path:
    p = Path(path).expanduser()
    if not p.exists():
        raise FormatError(f"{p}: no such {what}")
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


def _head(path: Path, n: int = 64) -> list[str]:
    lines = []
    with open(path, "r", encoding="utf-8", errors="replace", newline=None) as f:
        for line in f:
            lines.append(line.rstrip("\n").rstrip("\r"))
            if len(lines) >= n:
                break
    return lines


def _load_columns(path: Path, *, skiprows: int, delimiter: str | None, usecols: Sequence[int],
                  dtype) -> np.ndarray:
    """``np.loadtxt`` of some columns as ``(N, len(usecols))``; empty fields become NaN (floats)."""
    try:
        with open(path, "r", encoding="utf-8", errors="replace", newline=None) as f:
            return np.loadtxt(f, delimiter=delimiter, skiprows=skiprows, usecols=tuple(usecols),
                              dtype=dtype, ndmin=2, comments="#")
    except ValueError as exc:
        if dtype is np.int64 or "''" not in str(exc):
            raise FormatError(f"{path.name}: expected numeric data in columns {list(usecols)}, {exc}") from None
    # Empty fields (e.g. a packet that lacked gyro data): read them as NaN, flagged later by ImuStream.valid.
    with open(path, "r", encoding="utf-8", errors="replace", newline=None) as f:
        data = np.genfromtxt(f, delimiter=delimiter, skip_header=skiprows, usecols=tuple(usecols),
                             dtype=np.float64, comments="#", filling_values=np.nan, invalid_raise=True)
    return np.atleast_2d(data).reshape(-1, len(usecols))


def _pandas_floats(path: Path, *, skiprows: int, delimiter: str | None, usecols: Sequence[int]) -> np.ndarray | None:
    """What ``_load_columns(..., dtype=np.float64)`` returns, parsed by pandas' C parser; or None.

    None (use ``np.loadtxt``) when pandas is not installed, the file is smaller than
    :data:`PANDAS_MIN_BYTES`, a column is used twice, the delimiter is longer than one character, or
    pandas does not read the file cleanly: any parse error, or any NaN (an empty field, a short row,
    a blank line or an ``NA`` word, which ``np.loadtxt`` each treats in its own way). Both parse
    floats exactly, so a result is the array ``np.loadtxt`` would return.
    """
    if len(set(usecols)) < len(usecols) or (delimiter is not None and len(delimiter) != 1):
        return None
    if path.stat().st_size < PANDAS_MIN_BYTES:
        return None
    try:
        import pandas as pd
    except ImportError:
        return None
    # pandas 3.1 parses every float exactly (and deprecates float_precision); before, only "round_trip" does
    exact = {} if tuple(int(v) for v in re.findall(r"\d+", pd.__version__)[:2]) >= (3, 1) else \
        {"float_precision": "round_trip"}
    try:
        df = pd.read_csv(path, sep=r"\s+" if delimiter is None else delimiter, header=None, skiprows=skiprows,
                         usecols=list(usecols), dtype=np.float64, comment="#", quoting=csv.QUOTE_NONE,
                         skip_blank_lines=False, encoding="utf-8", encoding_errors="replace", **exact)
    except (ValueError, TypeError, OverflowError):  # np.loadtxt then reads the file or says what is wrong
        return None
    x = df[list(usecols)].to_numpy(dtype=np.float64)
    return None if np.isnan(x).any() else x


def _read_columns(path: Path, *, skiprows: int, delimiter: str | None, k_t: int, k_w: Sequence[int],
                  int_time: bool) -> tuple[np.ndarray, np.ndarray]:
    """Time column ``k_t`` ((N,), int64 when ``int_time``, else float64) and rate columns ``k_w`` ((N, 3) float64).

    Floats of big files are parsed by pandas when it is installed and reads them cleanly
    (:func:`_pandas_floats`, one pass for all columns); integers, other files and every error go
    through ``np.loadtxt`` (:func:`_load_columns`), which only takes plain integers as int64
    (pandas would also take ``6.0``).
    """
    kw = dict(skiprows=skiprows, delimiter=delimiter)
    if int_time:
        t = _load_columns(path, usecols=[k_t], dtype=np.int64, **kw)[:, 0]
        w = _pandas_floats(path, usecols=k_w, **kw)
        return t, (w if w is not None else _load_columns(path, usecols=k_w, dtype=np.float64, **kw))
    x = _pandas_floats(path, usecols=[k_t, *k_w], **kw)
    if x is not None:
        return x[:, 0], x[:, 1:]
    return (_load_columns(path, usecols=[k_t], dtype=np.float64, **kw)[:, 0],
            _load_columns(path, usecols=k_w, dtype=np.float64, **kw))


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
    path = _euroc_csv(_path(path, "file or folder"))
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
    if time_unit is None:
        time_unit = (_time_unit_from_header(header[k_t]) if header is not None else None) or ("ns" if is_euroc else "s")
    if time_unit not in TIME_UNITS:
        raise InputError(f"{fname}: expected time_unit in {tuple(TIME_UNITS)}, got {time_unit!r}")
    if unit is None:
        unit = (_rate_unit_from_header(header[k_w[0]]) if header is not None else None) or "rad/s"
    factor = _rate_factor(unit, sensitivity, fname)

    # timestamps: integer ticks keep every digit, decimals go through float64
    first_t = _split(data_lines[0], delim)[k_t].strip() if k_t < len(_split(data_lines[0], delim)) else ""
    integer_time = bool(re.fullmatch(r"[+-]?\d+", first_t))
    t = None
    if integer_time:
        try:
            ticks, w = _read_columns(path, skiprows=skip, delimiter=delim, k_t=k_t, k_w=k_w, int_time=True)
            t = _int_time_to_seconds(ticks, TIME_UNITS[time_unit])
        except FormatError:
            t = None  # some rows are not integers: fall back to float parsing
    if t is None:
        t, w = _read_columns(path, skiprows=skip, delimiter=delim, k_t=k_t, k_w=k_w, int_time=False)
        t = t / 10.0 ** TIME_UNITS[time_unit]
    w = w * factor
    if name is None:
        name = path.parent.name if path.name == "data.csv" else path.stem
    return ImuStream(t, w, name=name, source=str(path), unit_in=unit)


# ----------------------------------------------------------------------------- Xsens
def read_xsens(path, *, unit: str = "rad/s", name: str | None = None) -> ImuStream:
    """Read an Xsens MT Manager text export (``// Sample rate: 120.0Hz`` comments, ``Gyr_X..Z``).

    Timestamps come from the packet counter (``PacketCounter`` or ``Counter``) divided by the
    sample rate stated in the ``// Sample rate:`` comment, so two files recorded on one device
    share one clock. The 16-bit counter wraps at 65536 (at 120 Hz every ~9 min); wrap-arounds are
    undone before the division. Dropped packets therefore leave gaps in ``t``, not shifts.

    Parameters
    ----------
    path : str or Path
    unit : {"rad/s", "deg/s"}
        Unit of the ``Gyr_*`` columns (MT Manager exports rad/s unless configured otherwise).
    name : str, optional
        Stream name (default: the file stem).

    Raises
    ------
    FormatError
        Without a sample-rate comment, a counter column or the ``Gyr_X/Y/Z`` columns.
    """
    path = _path(path)
    lines = _head(path)
    rate = None
    k = 0
    while k < len(lines) and (lines[k].lstrip().startswith("//") or not lines[k].strip()):
        m = re.search(r"sample\s*rate\s*:\s*([0-9.eE+-]+)\s*hz", lines[k], re.IGNORECASE)
        if m:
            rate = float(m.group(1))
        k += 1
    if k >= len(lines):
        raise FormatError(f"{path.name}: expected a header row after the '//' comment lines, got none")
    delim = _sniff_delimiter(lines[k])
    header = [h.strip() for h in _split(lines[k], delim)]
    low = [h.lower() for h in header]
    try:
        k_w = [low.index(c) for c in ("gyr_x", "gyr_y", "gyr_z")]
    except ValueError:
        raise FormatError(f"{path.name}: expected Xsens columns 'Gyr_X', 'Gyr_Y', 'Gyr_Z', got header "
                          f"{[h for h in header if h]}") from None
    k_c = next((low.index(c) for c in ("packetcounter", "counter") if c in low), None)
    if k_c is None:
        raise FormatError(f"{path.name}: expected a 'PacketCounter' or 'Counter' column to time the samples, "
                          f"got header {[h for h in header if h]}")
    if rate is None or not rate > 0:
        raise FormatError(f"{path.name}: expected a '// Sample rate: <rate>Hz' comment line before the header, "
                          "got none (timestamps are derived from the packet counter and the sample rate)")
    factor = _rate_factor(unit, None, path.name)
    counter, w = _read_columns(path, skiprows=k + 1, delimiter=delim, k_t=k_c, k_w=k_w, int_time=True)
    w = w * factor
    modulus = 1 << 16 if counter.max(initial=0) < (1 << 16) else 1 << 32
    steps = np.mod(np.diff(counter), modulus)
    if (steps == 0).any():
        j = int(np.argmax(steps == 0)) + 1
        raise InputError(f"{path.name}: expected a strictly advancing packet counter, got a repeated value "
                         f"{int(counter[j])} at sample {j}")
    ticks = counter[0] + np.concatenate(([0], np.cumsum(steps)))
    t = ticks.astype(np.float64) / rate
    return ImuStream(t, w, name=name or path.stem, source=str(path), rate_hz=rate, unit_in=unit)


def _looks_like_xsens(lines: list[str]) -> bool:
    if any(re.search(r"sample\s*rate\s*:", ln, re.IGNORECASE) for ln in lines if ln.lstrip().startswith("//")):
        return True
    return any("gyr_x" in ln.lower() and ("counter" in ln.lower()) for ln in lines[:20])


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
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise FormatError(f"{path.name}: expected a numpy .npz archive, {exc}") from None
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
    p = _path(path, "file or folder")
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
    lines = _head(p, 32)
    if _looks_like_xsens(lines):
        return "xsens"
    first = next((ln for ln in lines if ln.strip()), "")
    if first.startswith("#") and "w_RS_S_x" in first:
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
        :func:`read_xsens` (``unit``), :func:`read_npz` (``imu``, ``unit``),
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
