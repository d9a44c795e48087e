"""File readers: IMU logs in, :class:`ImuStream` (seconds, rad/s, float64) out; the entry points.

Every reader converts units at this edge (``deg/s`` and raw ``counts`` to rad/s, ``ms``/``us``/``ns``
timestamps to seconds, with the units of :mod:`fusion_gyrocal.units`) so nothing downstream ever
sees anything but the library's units (``ARCHITECTURE.md``). Every failure to read a file is a
:class:`~fusion_gyrocal.errors.FormatError` naming the file. Only regular files are opened (a FIFO
would block).

This module picks the reader (:func:`detect_format`, :func:`read_imu`) and gathers the readers'
public names; each format has its own module:

* generic CSV / TSV / whitespace text, with or without a header, and the EuRoC / ASL
  ``mav0/imu0/data.csv`` layout, detected from its header (:func:`read_csv`,
  :mod:`fusion_gyrocal.io.csv`), the text parsed by :mod:`fusion_gyrocal.io.text`;
* the Xsens MT Manager text export, every delimiter and time source (:func:`read_xsens`,
  :mod:`fusion_gyrocal.io.xsens`);
* ``.npz`` archives with ``t`` and ``omega`` (or ``gyro``) arrays, and the MIMU4444 array layout
  (``t_s``, ``gyro_counts`` N x M x 3, ``gyro_lsb_per_dps``) (:func:`read_npz`, :mod:`fusion_gyrocal.io.npz`);
* ROS1 / ROS2 bags with ``sensor_msgs/msg/Imu``, a ROS2 ``.db3`` / ``.mcap`` storage file on its own too
  (:mod:`fusion_gyrocal.io.bags`, loaded on first use);
* PX4 ULog ``.ulg`` flight logs, every gyro instance (:mod:`fusion_gyrocal.io.ulog`, loaded on first use);
* :class:`ImuStream` and what every reader shares: :mod:`fusion_gyrocal.io.stream`.

Binary files that are none of these (a ``.mat``, an executable, a ``.ulg`` given as CSV, anything with NUL bytes
in its first block) are refused by name before any parser sees them (:mod:`fusion_gyrocal.io.binary`); no byte of
them is ever printed.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import FormatError, InputError
from ..units import RATE_UNITS, TIME_UNITS
from .csv import PLAUSIBLE_RATE_HZ, read_csv
from .npz import read_npz
from .stream import ImuStream, input_path
from .text import PANDAS_MIN_BYTES, head_lines
from .binary import HEAD_BYTES, ULOG_MAGIC, refuse_binary
from .xsens import XSENS_FINE_TICKS_PER_S, looks_like_xsens, read_xsens

__all__ = ["ImuStream", "FORMATS", "detect_format", "read_imu", "read_csv", "read_xsens", "read_npz",
           "RATE_UNITS", "TIME_UNITS", "PLAUSIBLE_RATE_HZ", "PANDAS_MIN_BYTES", "XSENS_FINE_TICKS_PER_S"]

FORMATS = ("auto", "csv", "euroc", "xsens", "npz", "bag", "ulog")

def detect_format(path) -> str:
    """Guess the layout of ``path``: ``"csv"``, ``"euroc"``, ``"xsens"``, ``"npz"``, ``"bag"`` or ``"ulog"``.

    Raises
    ------
    FormatError
        For a binary file of no supported format (:mod:`~fusion_gyrocal.io.binary`), before any parser reads it.
    """
    p = input_path(path, "file or folder", folder=True)
    if p.is_dir():
        if (p / "metadata.yaml").is_file() or any(p.glob("*.db3")) or any(p.glob("*.mcap")):
            return "bag"
        return "euroc"
    suffix = p.suffix.lower()
    if suffix in (".bag", ".db3", ".mcap"):
        return "bag"
    if suffix == ".npz":
        return "npz"
    if suffix == ".ulg":
        return "ulog"
    with open(p, "rb") as f:
        head = f.read(HEAD_BYTES)
    if head.startswith(b"#ROSBAG V2.0"):
        return "bag"
    if head.startswith(b"PK"):
        return "npz"
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    refuse_binary(p, head, "CSV or Xsens")
    lines = head_lines(p, 256)
    if looks_like_xsens(lines):
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
        ``.bag``, a ROS2 bag folder or ``.db3`` / ``.mcap`` storage file, or a PX4 ``.ulg``.
    format : {"auto", "csv", "euroc", "xsens", "npz", "bag", "ulog"}
        Force a reader instead of :func:`detect_format`.
    **options
        Passed to the reader: :func:`read_csv` (``columns``, ``unit``, ``time_unit``, ...),
        :func:`read_xsens` (``unit``, ``rate_hz``), :func:`read_npz` (``imu``, ``unit``),
        :func:`fusion_gyrocal.io.read_bag` (``topic``), :func:`fusion_gyrocal.io.read_ulog` (``topic``, ``imu``).

    Raises
    ------
    InputError
        When the file holds several IMUs (npz) or Imu topics (bag) and none was chosen; the
        message lists the choices.
    """
    if format not in FORMATS:
        raise InputError(f"format: expected one of {FORMATS}, got {format!r}")
    try:
        return _read(path, format, options)
    except OSError as exc:   # EIO, a file that vanished or became unreadable while read: a FormatError naming it
        raise FormatError(f"{path}: expected a readable file, got an error reading it (could not read: "
                          f"{exc.strerror or exc})") from exc
    except RecursionError:
        raise FormatError(f"{path}: expected an IMU log, got data nested too deeply to read") from None


def _read(path, format: str, options: dict) -> ImuStream:
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
    if fmt == "ulog":
        from .ulog import read_ulog
        return read_ulog(path, **options)
    from .bags import read_bag
    return read_bag(path, **options)
