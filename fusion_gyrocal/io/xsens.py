"""Xsens MT Manager text exports: :func:`read_xsens`, and :func:`looks_like_xsens` for telling them apart.

Every variant MT Manager writes is read (tab, comma, semicolon or space delimiter; with or without a
stated rate; with or without orientation columns); the timestamps come from the device's
``SampleTimeFine`` clock, the UTC columns or the packet counter, whichever the file holds in every
row, with the counters' wraps undone. The text itself is read by :mod:`fusion_gyrocal.io.text`.
"""

from __future__ import annotations

import re

import numpy as np

from ..core.moments import finite_rows
from ..errors import FormatError, InputError, OptionError
from .binary import check_text_file
from .stream import ImuStream, input_path, int_time_to_seconds, rate_factor
from .text import data_end, dropped_note, head_lines, read_floats

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
    path = input_path(path)
    check_text_file(path, "Xsens")           # a binary file is refused by name, before any parsing
    fname = path.name
    lines = head_lines(path, 256)
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

    end, dropped = data_end(path, delim, skip)
    notes = [dropped_note(dropped)] if dropped else []
    w = read_floats(path, skiprows=skip, delimiter=delim, usecols=k_w, end=end) * rate_factor(unit, None, fname)

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
        x = read_floats(path, skiprows=skip, delimiter=delim, usecols=cols, end=end)
        missing = ~finite_rows(x)
        if missing.any():
            skipped.append(f"{what} is missing in {int(missing.sum())} of {len(x)} rows")
            continue
        if (x != np.round(x)).any():
            j = int(np.argmax((x != np.round(x)).any(axis=1)))
            raise FormatError(f"{fname}: expected whole numbers in {what}, got {x[j].tolist()} in data row {j + 1}")
        if what == "SampleTimeFine":
            ticks = _unwrap_counter(x[:, 0], 1 << 32, what, fname)
            t, rate_out = int_time_to_seconds(ticks, 4), None
            notes.append(f"time from SampleTimeFine (the device's {XSENS_FINE_TICKS_PER_S // 1000} kHz clock)")
        elif what == "UTC":
            if x.shape[1] == 8 and ((x[:, 7].astype(np.int64) & _UTC_VALID_BIT) == 0).any():
                skipped.append(f"UTC is not valid (UTC_Valid without bit 0x04) in "
                               f"{int(((x[:, 7].astype(np.int64) & _UTC_VALID_BIT) == 0).sum())} rows")
                continue
            t, rate_out = int_time_to_seconds(_utc_ns(x[:, :7]), 9), None
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


def looks_like_xsens(lines: list[str]) -> bool:
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
