"""Delimited text files (generic CSV / TSV / whitespace, and the EuRoC / ASL layout): :func:`read_csv`.

Columns are found by header name (or given by index or name), units are read from the header
(``[ns]``, ``[deg/s]``, ``_dps``, ...; the spellings are those of :mod:`fusion_gyrocal.units`; a label
that looks like a unit but is none of them is refused, naming it) or given, and converted at this edge: rates to rad/s, timestamps to seconds. Integer timestamps
(EuRoC nanoseconds) are split into whole and fractional seconds before the conversion, so an
epoch-sized nanosecond count keeps the full float64 resolution (about 0.2 us at 1.7e9 s) instead of
losing digits in a single ``ns * 1e-9``. Timestamps whose unit would give a sample rate outside
:data:`PLAUSIBLE_RATE_HZ` while another unit gives one inside it are refused with the unit they
look like (``time_unit=``), never silently misread. The text itself is read by
:mod:`fusion_gyrocal.io.text`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from ..pipeline.streams import _checked_timestamps, median_step, remember_timestamps
from ..units import RATE_UNIT_HINTS, RATE_UNIT_LABELS, RATE_UNITS, TIME_UNIT_LABELS, TIME_UNITS
from .stream import ImuStream, hand_over, input_path, int_time_to_seconds, rate_factor
from .binary import check_text_file
from .profiles import header_keys, match_profile, select_instance
from .text import data_end, dropped_note, head_lines, is_number, read_columns, sniff_delimiter, split_fields

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
# Column-name suffixes naming a rate unit (``gyro_x_dps``), by unit.
_RATE_SUFFIXES = (("rad/s", ("_rad_s", "_rads")), ("deg/s", ("_dps", "_deg_s")), ("mrad/s", ("_mrad_s", "_mrads")),
                  ("mdeg/s", ("_mdps", "_mdeg_s")))


#: Sample rates an IMU log can plausibly have; timestamps whose median step gives a rate outside
#: this range in the unit they are read in are refused when another unit gives one inside it.
PLAUSIBLE_RATE_HZ = (1.0, 1e5)
_MAX_TIME_S = 1e10  # about the year 2286 as a Unix time: larger "seconds" are in a finer unit


def _rates_by_unit(raw: np.ndarray, step: float | None = None) -> tuple[float, dict[str, float], dict[str, float]]:
    """Median positive step of raw timestamps, the rate each time unit gives, and the plausible ones.

    ``step``: that median when already known (of timestamps checked to increase strictly)."""
    raw = np.asarray(raw)
    if step is None:
        d = np.diff(raw)
        if not (d.size and d.min() > 0):   # all positive (the usual case): no copy
            d = d[d > 0]
        if d.size == 0 or not np.isfinite(raw[[0, -1]]).all():
            return float("nan"), {}, {}
        step = float(np.median(d))
    size = float(np.max(np.abs(raw[[0, -1]].astype(np.float64))))
    rates = {u: 10.0 ** dec / step for u, dec in TIME_UNITS.items()}
    lo, hi = PLAUSIBLE_RATE_HZ
    ok = {u: r for u, r in rates.items() if lo <= r <= hi and size / 10.0 ** TIME_UNITS[u] < _MAX_TIME_S}
    return step, rates, ok


def _check_time_unit(raw: np.ndarray, unit: str, how: str, fname: str, column: str,
                     step: float | None = None) -> None:
    """Refuse timestamps whose unit makes an implausible rate when another unit makes a plausible one.

    ``how`` says where ``unit`` came from (the option, the header, the default), for the message; ``step``: their
    median positive step when already known.
    """
    step, rates, ok = _rates_by_unit(raw, step)
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


def _time_unit_from_header(name: str, fname: str = "") -> str | None:
    """The time unit a header names: in brackets (``[ns]``), by a ``rostopic`` name, or by a ``_ms``-like suffix.

    A bracketed label that is no time unit this reader knows (``[min]``, ``[ticks]``) is refused, naming it.
    """
    unit = _bracket_unit(name)
    if unit in TIME_UNIT_LABELS:
        return TIME_UNIT_LABELS[unit]
    if unit:
        raise FormatError(f"{fname}: the time column {name.strip()!r} names the unit {unit!r}, expected one of "
                          f"{sorted(TIME_UNIT_LABELS)}; pass time_unit= (CLI --time-unit) with the unit in "
                          f"{tuple(TIME_UNITS)}")
    n = _norm(name)
    if n in _NS_TIME_NAMES:
        return "ns"
    for u in ("ns", "us", "ms", "s"):
        if n.endswith("_" + u):
            return u
    return None


def _rate_unit_from_header(name: str, fname: str = "") -> str | None:
    """The rate unit a header names: in brackets (``[rad s^-1]``, ``[deg/s]``, ``[mdps]``) or by a suffix (``_dps``).

    A bracketed label that looks like a rate unit (:data:`~fusion_gyrocal.units.RATE_UNIT_HINTS`) but is none
    this reader knows (``[rpm]``, ``[urad/s]``) is refused, naming it: never read as rad/s.
    """
    n = _norm(name)
    label = (_bracket_unit(name) or "").replace(" ", "")
    if label and label not in RATE_UNIT_LABELS and any(h in label for h in RATE_UNIT_HINTS):
        raise FormatError(f"{fname}: the gyro column {name.strip()!r} names the unit {label!r}, expected one of "
                          f"{sorted(RATE_UNIT_LABELS)}; convert the rates or pass unit= (CLI --unit) with one of "
                          f"{RATE_UNITS}")
    named = {RATE_UNIT_LABELS.get(label), next((u for u, ends in _RATE_SUFFIXES if n.endswith(ends)), None)}
    return next((u for u in RATE_UNITS if u in named), None)


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
             time_unit: str | None = None, delimiter: str | None = None, name: str | None = None,
             imu: int | None = None) -> ImuStream:
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
    unit : {"rad/s", "deg/s", "counts", "mrad/s", "mdeg/s"}, optional
        Rate unit in the file. Default: from the header (``[rad s^-1]``, ``[deg/s]``, ``[°/s]``, ``[mdps]``,
        ``_dps``; a bracketed label that looks like a rate unit this reader does not know is refused,
        naming it), else rad/s with a note saying that it was assumed.
    sensitivity : float, optional
        LSB per deg/s, required with ``unit="counts"`` (rad/s = counts / sensitivity * pi / 180).
    time_unit : {"s", "ms", "us", "ns"}, optional
        Timestamp unit. Default: from the header (``[ns]``, ``_ns``, ``rostopic echo -p`` columns; another
        bracketed label is refused), ``ns`` for EuRoC, else s.
    delimiter : str, optional
        Field separator. Default: sniffed from the first data row (``,`` tab ``;`` or whitespace).
    name : str, optional
        Stream name. Default: the file stem (the folder name for EuRoC ``data.csv``).
    imu : int, optional
        The IMU instance to keep in a log that interleaves several (an instance column, e.g. ArduPilot's ``I``).

    The headers of common loggers (UZH-FPV, Kalibr, Sensor Logger, MARS logger, PX4 ``ulog2csv``, VectorNav,
    ArduPilot) set the columns and units not given (:mod:`fusion_gyrocal.io.profiles`).

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
    path = _euroc_csv(input_path(path, "file or folder", folder=True))
    check_text_file(path, "CSV")             # a binary file is refused by name, before any parsing
    fname = path.name if path.name != "data.csv" else f"{path.parent.name}/{path.name}"
    layout = _layout(path, fname, delimiter)
    profile = match_profile(layout.header) if layout.header is not None else None
    k_inst = None
    if profile is not None:                  # a known logger's layout fills what was not given
        p_t, p_w, k_inst = profile.columns(header_keys(layout.header))
        time_column = p_t if time_column is None else time_column
        columns = p_w if columns is None else columns
        if time_unit is None and not _time_unit_from_header(layout.header[p_t]):
            time_unit = profile.time_unit    # a unit the header names wins; the rate unit is read as usual
    k_t = _time_column(time_column, layout, fname)
    k_w = _gyro_columns(columns, layout, fname)
    time_unit, how, unit = _units(layout, k_t, k_w, time_unit, unit, fname)
    notes = []
    if unit is None:   # said, so that a log in another unit is not silently read as rad/s
        unit = "rad/s"
        notes.append("rates read as rad/s: neither the header nor unit= names their unit (pass unit=, CLI --unit, "
                     "if they are in deg/s or another unit)")
    factor = rate_factor(unit, sensitivity, fname)

    # junk after the data (spreadsheets): cut, and said in a note
    end, dropped = data_end(path, layout.delim, layout.skip)
    notes += [dropped_note(dropped)] if dropped else []

    raw, w = _read_rows(path, layout, k_t, k_w, end, fname)
    if profile is not None:
        notes.append(f"read as the {profile.name} layout" + (f" ({profile.note})" if profile.note else ""))
    if imu is not None and k_inst is None:
        raise InputError(f"{fname}: imu={imu} picks an IMU instance, but the file has no instance column "
                         f"(header {layout.header})")
    if k_inst is not None:
        inst, _ = read_columns(path, skiprows=layout.skip, delimiter=layout.delim, k_t=k_inst, k_w=k_w,
                               int_time=False, end=end)
        keep = select_instance(inst, imu, fname, layout.header[k_inst])
        if not keep.all():
            raw, w = raw[keep], w[keep]
            notes.append(f"IMU instance {imu}: {int(keep.sum())} of {keep.size} rows")
    column = layout.header[k_t] if layout.header is not None else f"#{k_t}"
    if name is None:
        name = path.parent.name if path.name == "data.csv" else path.stem
    if raw.dtype.kind == "f" and not TIME_UNITS[time_unit]:   # seconds as parsed: one look at the steps
        t = hand_over(raw)
        _checked_seconds(t, f"{name}.t", time_unit, how, fname, column)
    else:
        _check_time_unit(raw, time_unit, how, fname, column)
        t = hand_over(int_time_to_seconds(raw, TIME_UNITS[time_unit]) if raw.dtype.kind == "i"
                      else raw / 10.0 ** TIME_UNITS[time_unit])
    if factor != 1.0:        # rad/s in place: the parsed array is this reader's own (unless a parser froze it)
        w = np.multiply(w, factor, out=w if w.flags.writeable else None)
    del raw                  # the arrays are handed over (ImuStream keeps them instead of a copy)
    return ImuStream(t, hand_over(w), name=name, source=str(path), unit_in=unit, notes=tuple(notes))


def _checked_seconds(t: np.ndarray, name_t: str, unit: str, how: str, fname: str, column: str) -> None:
    """:func:`_check_time_unit` and :class:`ImuStream`'s check of timestamps read as seconds, on one look at
    their steps: their median step, which the first reads, is the diagnosis's period unless they are bursty.

    The refusals and their order are those of the two checks made one after the other; what the stream's
    check found is remembered for it (:func:`~fusion_gyrocal.pipeline.streams.remember_timestamps`).
    """
    try:
        _, step, quality = _checked_timestamps(name_t, t)
    except InputError:
        _check_time_unit(t, unit, how, fname, column)   # its refusal, naming the unit they look like, first
        raise
    median = median_step(step, quality)
    _check_time_unit(t, unit, how, fname, column, step=median)   # all steps positive: the median positive step
    remember_timestamps(t, median, quality)


# ----------------------------------------------------------------------------- the steps of read_csv
@dataclass(frozen=True)
class _Layout:
    """Where a text file's header and data are: what :func:`_layout` finds in its first lines."""

    header: list[str] | None   # the header's fields (stripped), None without a header row
    delim: str | None          # the field separator (None: runs of whitespace)
    skip: int                  # lines before the first data row
    ncols: int                 # columns of the first data row, or of the header when that has more
    first_row: str             # the first data row

    @property
    def norm_header(self) -> list[str] | None:
        return [_norm(h) for h in self.header] if self.header is not None else None

    @property
    def is_euroc(self) -> bool:
        return self.header is not None and "w_rs_s_x" in self.norm_header


def _fields_of(line: str, delim: str | None) -> list[str]:
    f = split_fields(line.strip(), delim)
    return f[:-1] if f and delim is not None and not f[-1].strip() else f  # trailing delimiter


def _layout(path: Path, fname: str, delimiter: str | None) -> _Layout:
    """The header row (if any), the delimiter (``delimiter`` or sniffed) and where the data start."""
    lines = head_lines(path)
    # Leading blank lines and '//', '%', '#' comment lines are skipped; a '#' line right above the
    # first data row with as many fields is the header (the EuRoC "#timestamp [ns],w_RS_S_x ..." row). The
    # `rostopic echo -p` header starts with '%time': it is the header, not a comment.
    first, last_hash = 0, None
    while first < len(lines) and (not lines[first].strip() or lines[first].lstrip().startswith(("//", "%", "#"))) \
            and not lines[first].lstrip().lower().startswith("%time"):
        if lines[first].lstrip().startswith("#"):
            last_hash = first
        first += 1
    if first >= len(lines):
        raise FormatError(f"{fname}: expected a header or data rows, got no data")

    delim = delimiter if delimiter is not None else sniff_delimiter(lines[first])
    fields = _fields_of(lines[first], delim)
    header = None
    if not all(is_number(f) for f in fields if f.strip()):
        header, skip = [f.strip() for f in fields], first + 1
        data_lines = [ln for ln in lines[skip:] if ln.strip() and not ln.lstrip().startswith("#")]
        if not data_lines:
            raise FormatError(f"{fname}: expected data rows after the header, got none")
        if delimiter is None and delim is None:
            delim = sniff_delimiter(data_lines[0])
            header = [f.strip() for f in _fields_of(lines[first], delim)]
        ncols = len(_fields_of(data_lines[0], delim))
    else:
        skip, ncols = first, len(fields)
        if last_hash == first - 1:
            hfields = _fields_of(lines[last_hash].lstrip()[1:], delim)
            if len(hfields) == ncols and not all(is_number(f) for f in hfields if f.strip()):
                header = [f.strip() for f in hfields]
        data_lines = [lines[first]]
    if header is not None:
        ncols = max(ncols, len(header))
    return _Layout(header, delim, skip, ncols, data_lines[0])


def _time_column(time_column, layout: _Layout, fname: str) -> int:
    """The timestamp column: ``time_column``, else a header column named like a time, else column 0."""
    if time_column is not None:
        return _resolve_column(time_column, layout.header, layout.ncols, "the time column", fname)
    norm_header = layout.norm_header
    if norm_header is None:
        return 0
    k_t = next((norm_header.index(c) for c in _TIME_NAMES if c in norm_header), None)
    if k_t is None:
        raise FormatError(f"{fname}: expected a time column named like 't', 'time' or 'timestamp' or "
                          f"one given by time_column=, got header {layout.header}")
    return k_t


def _gyro_columns(columns, layout: _Layout, fname: str) -> list[int]:
    """The x, y, z rate columns: ``columns``, else a recognised header triple, else columns 1, 2, 3."""
    header, norm_header, ncols = layout.header, layout.norm_header, layout.ncols
    if columns is not None:
        columns = list(columns)
        if len(columns) != 3:
            raise InputError(f"{fname}: expected 3 gyro columns (x, y, z), got {len(columns)}: {columns}")
        return [_resolve_column(c, header, ncols, "a gyro column", fname) for c in columns]
    if norm_header is None:
        if ncols < 4:
            raise FormatError(f"{fname}: expected at least 4 columns (time and x, y, z rates) in a file "
                              f"without header, got {ncols}")
        return [1, 2, 3]
    for triple in _GYRO_TRIPLES:
        if all(c in norm_header for c in triple):
            return [norm_header.index(c) for c in triple]
    raise FormatError(f"{fname}: expected a column 'gyro_x' (or gyr_x, w_RS_S_x, omega_x, wx, "
                      f"angular_velocity.x, ...) or columns given by columns=, got header {header}")


def _units(layout: _Layout, k_t: int, k_w: list[int], time_unit: str | None, unit: str | None,
           fname: str) -> tuple[str, str, str]:
    """``(time_unit, how, unit)``: the units given, else from the header, else the layout's defaults.

    ``how`` says where the time unit came from (for the message of :func:`_check_time_unit`).
    """
    header = layout.header
    from_header = _time_unit_from_header(header[k_t], fname) if header is not None and time_unit is None else None
    if time_unit is not None:
        how = "time_unit= given"
    elif from_header:
        time_unit, how = from_header, f"as the header {header[k_t]!r} says"
    elif layout.is_euroc:
        time_unit, how = "ns", "the EuRoC layout"
    else:
        time_unit, how = "s", "the default"
    if time_unit not in TIME_UNITS:
        raise InputError(f"{fname}: expected time_unit in {tuple(TIME_UNITS)}, got {time_unit!r}")
    if unit is None and header is not None:
        named = {_rate_unit_from_header(header[k], fname) for k in k_w} - {None}   # often only x names it
        if len(named) > 1:
            raise FormatError(f"{fname}: the gyro columns {[header[k] for k in k_w]} name different units "
                              f"{sorted(str(u) for u in named)}; expected one unit (or pass unit=, CLI --unit)")
        unit = named.pop() if named else None
    return time_unit, how, unit


def _read_rows(path: Path, layout: _Layout, k_t: int, k_w: list[int], end: int | None,
               fname: str) -> tuple[np.ndarray, np.ndarray]:
    """Raw timestamps (int64 when the time column holds integer ticks: every digit kept, else float64)
    and the rates in the file's unit."""
    row0 = split_fields(layout.first_row, layout.delim)
    first_t = row0[k_t].strip() if k_t < len(row0) else ""
    kw = dict(skiprows=layout.skip, delimiter=layout.delim, k_t=k_t, k_w=k_w, end=end)
    if re.fullmatch(r"[+-]?\d+", first_t):
        try:
            return read_columns(path, int_time=True, **kw)
        except FormatError:
            pass  # some rows are not integers: fall back to float parsing
    raw, w = read_columns(path, int_time=False, **kw)
    if not np.isfinite(raw).all():
        j = int(np.argmax(~np.isfinite(raw)))
        raise FormatError(f"{fname}: data row {j + 1} has no timestamp (an empty or non-finite field in the "
                          f"time column); expected a number in every row")
    return raw, w
