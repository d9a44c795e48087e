"""Delimited text at the edge: reading the head of a file, cutting a spreadsheet's trailer, parsing float columns.

Text is read as UTF-8 with or without a byte-order mark (UTF-16/32 is refused); a header that is not
UTF-8 is read as Windows-1252 (Excel's default on Western systems, so ``°/s`` is the degree sign). Lines
longer than :data:`MAX_LINE_BYTES` are refused before any parser splits them. Lines without any
number after the last data row (what spreadsheets leave: empty rows, rows of delimiters, a text
line) are cut by :func:`data_end` and named by :func:`dropped_note`; such lines between data rows
are refused by the parser. Files of :data:`PANDAS_MIN_BYTES` or more with a one-character delimiter
have their float columns parsed by ``pyarrow.csv`` when it is installed (memory-mapped,
multi-threaded, and about 0.07 s to import against 0.3 s for pandas), else by pandas' C parser when
that is installed (both many times faster than ``np.loadtxt``); the result is the array
``np.loadtxt`` would return, which reads everything else (and every file either parser does not
read cleanly) and reports every error (:func:`read_floats`, :func:`read_columns`).
"""

from __future__ import annotations

import csv
import io
import re
import warnings
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import FormatError

#: Text files from this size on are parsed with pyarrow, else pandas, when installed (both optional:
#: extras "fleet" and "test"). Either reads a one-hour 200 Hz CSV (720k rows, ~55 MB) in 0.05-0.1 s
#: where np.loadtxt takes about 1 s; importing pyarrow.csv (~0.07 s) or pandas (~0.3 s) pays off from
#: about this size on.
PANDAS_MIN_BYTES = 8 << 20


def split_fields(line: str, delimiter: str | None) -> list[str]:
    """The fields of ``line``: split at ``delimiter`` taken literally, or at runs of whitespace when None."""
    if delimiter is None:
        return line.split()
    return line.split(delimiter)


def sniff_delimiter(line: str) -> str | None:
    """The first of ``,`` tab ``;`` that ``line`` holds, else None (whitespace runs)."""
    for d in (",", "\t", ";"):
        if d in line:
            return d
    return None


def is_number(s: str) -> bool:
    """Whether ``float(s)`` reads ``s``."""
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


#: Longest line (bytes) of a text table: an IMU log's row is some hundred bytes; longer lines are refused before
#: anything splits them into fields (a 50 MB line would otherwise cost gigabytes).
MAX_LINE_BYTES = 1 << 20
#: Encoding of a header that is not UTF-8: Windows-1252 (Excel's "CSV" on Western systems, a superset of the
#: printable Latin-1), so ``°/s`` in such a file is the degree sign.
FALLBACK_ENCODING = "cp1252"


def decode_header(raw: bytes) -> tuple[str, str]:
    """``(text, encoding)``: ``raw`` as UTF-8 (a byte-order mark dropped), else as :data:`FALLBACK_ENCODING`."""
    try:
        return raw.decode(_ENCODING), "utf-8"
    except UnicodeDecodeError:
        return raw.decode(FALLBACK_ENCODING, errors="replace"), FALLBACK_ENCODING


def head_lines(path: Path, n: int = 64) -> list[str]:
    """The first ``n`` lines of a text file, without their line ends (UTF-16/32 refused).

    The lines are decoded as UTF-8, or as Windows-1252 when they are not UTF-8 (:func:`decode_header`); a line
    longer than :data:`MAX_LINE_BYTES` is refused (:class:`FormatError`).
    """
    _check_text(path)
    raw = []
    with open(path, "rb") as f:
        while len(raw) < n:
            line = f.readline(MAX_LINE_BYTES + 1)
            if not line:
                break
            if len(line) > MAX_LINE_BYTES and b"\r" not in line:
                raise FormatError(f"{path.name}: expected rows of a text table, got line {len(raw) + 1} longer than "
                                  f"{MAX_LINE_BYTES} bytes")
            raw.append(line)
    text, _ = decode_header(b"".join(raw))
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    return lines[:n]


def check_line_lengths(path: Path, end: int | None = None) -> None:
    """Refuse a file with a line longer than twice :data:`MAX_LINE_BYTES` before a parser splits it into fields.

    Such a line holds a whole aligned block of :data:`MAX_LINE_BYTES` without a line end; each block is
    searched from its start (memory-mapped; the search stops at the first line end, so a few bytes per block
    are read).
    """
    size = path.stat().st_size if end is None else end
    if size <= 2 * MAX_LINE_BYTES:
        return
    import mmap

    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        for lo in range(0, size - MAX_LINE_BYTES + 1, MAX_LINE_BYTES):
            hi = lo + MAX_LINE_BYTES
            if mm.find(b"\n", lo, hi) < 0 and mm.find(b"\r", lo, hi) < 0:
                raise FormatError(f"{path.name}: expected rows of a text table, got a line longer than "
                                  f"{MAX_LINE_BYTES} bytes (at byte {lo})")


def data_end(path: Path, delimiter: str | None, first_data_line: int) -> tuple[int | None, list[str]]:
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
                if any(is_number(x.strip()) for x in split_fields(text, delimiter) if x.strip()):
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


def dropped_note(dropped: list[str]) -> str:
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
                    end: int | None = None, split: bool = False):
    """What ``_load_columns(..., dtype=np.float64)`` returns, parsed by ``pyarrow.csv``; or None.

    The file is memory-mapped and only the data rows (after ``skiprows`` lines, before ``end``)
    are parsed, with the delimiter taken literally, no quoting and every field of a used column a
    number. None (another parser reads the file or says what is wrong) when pyarrow is not
    installed, the data hold a ``#`` anywhere (``np.loadtxt`` cuts comments, also in unused
    columns), or pyarrow does not read the rows cleanly: a parse or conversion error (an empty
    field, a blank or short row, a word), or a non-finite value. pyarrow parses floats exactly
    (correctly rounded), so a result is the array ``np.loadtxt`` would return. The data are searched
    for a ``#`` only when the first data row has columns that are not used: pyarrow refuses a row
    with another number of fields and a number holding a ``#``, so where every column is used a
    ``#`` cannot pass. ``split``: ``(first column (N,), the others (N, k - 1))``, each C-contiguous.
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
        eol = mm.find(b"\n", start, stop)
        first = mm[start:stop if eol < 0 else eol]
        every_column = set(usecols) == set(range(first.count(delimiter.encode()) + 1))
        if not every_column and mm.find(b"#", start, stop) >= 0:
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
    n = table.num_rows
    if split:
        first_col, rest = np.empty(n), np.empty((n, len(names) - 1))
        targets = [first_col] + [rest[:, j] for j in range(len(names) - 1)]
    else:
        x = np.empty((n, len(names)))
        targets = [x[:, j] for j in range(len(names))]
    for name, out in zip(names, targets):   # from the value buffers: (Chunked)Array.to_numpy would import pandas
        row = 0
        for chunk in table.column(name).chunks:
            if chunk.null_count:
                return None
            m = len(chunk)
            out[row:row + m] = np.frombuffer(chunk.buffers()[1], dtype=np.float64, count=m, offset=8 * chunk.offset)
            row += m
    if not n or not all(np.isfinite(out).all() for out in ((first_col, rest) if split else (x,))):
        return None
    return (first_col, rest) if split else x


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
                 end: int | None = None, split: bool = False):
    """Float columns of a big file by pyarrow (:func:`_pyarrow_floats`), else pandas (:func:`_pandas_floats`).

    None (``np.loadtxt`` reads the file) for files smaller than :data:`PANDAS_MIN_BYTES`, a column
    used twice, a delimiter longer than one character, or when neither parser is installed or
    reads the file cleanly. pyarrow needs a delimiter (whitespace runs go to pandas). ``split``: pyarrow's
    columns as :func:`_pyarrow_floats` splits them (pandas': as one array).
    """
    if len(set(usecols)) < len(usecols) or (delimiter is not None and len(delimiter) != 1):
        return None
    if path.stat().st_size < PANDAS_MIN_BYTES:
        return None
    kw = dict(skiprows=skiprows, delimiter=delimiter, usecols=usecols, end=end)
    x = _pyarrow_floats(path, **kw, split=split) if delimiter is not None else None
    return x if x is not None else _pandas_floats(path, **kw)


def read_floats(path: Path, *, skiprows: int, delimiter: str | None, usecols: Sequence[int],
                end: int | None = None) -> np.ndarray:
    """Columns ``usecols`` as float64 ``(N, k)``: pyarrow or pandas when one reads them cleanly, else ``np.loadtxt``."""
    kw = dict(skiprows=skiprows, delimiter=delimiter, usecols=usecols, end=end)
    x = _fast_floats(path, **kw)
    return x if x is not None else _load_columns(path, dtype=np.float64, **kw)


def read_columns(path: Path, *, skiprows: int, delimiter: str | None, k_t: int, k_w: Sequence[int],
                 int_time: bool, end: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Time column ``k_t`` ((N,), int64 when ``int_time``, else float64) and rate columns ``k_w`` ((N, 3) float64).

    Floats of big files are parsed by pyarrow or pandas when one is installed and reads them cleanly
    (:func:`_fast_floats`, one pass for all columns); integers, other files and every error go
    through ``np.loadtxt`` (:func:`_load_columns`), which only takes plain integers as int64
    (pandas would also take ``6.0``).
    """
    check_line_lengths(path, end)
    kw = dict(skiprows=skiprows, delimiter=delimiter, end=end)
    if int_time:
        t = _load_columns(path, usecols=[k_t], dtype=np.int64, **kw)[:, 0]
        return t, read_floats(path, usecols=k_w, **kw)
    x = _fast_floats(path, usecols=[k_t, *k_w], split=True, **kw)
    if isinstance(x, tuple):
        return x
    x = x if x is not None else _load_columns(path, usecols=[k_t, *k_w], dtype=np.float64, **kw)
    return x[:, 0], x[:, 1:]
