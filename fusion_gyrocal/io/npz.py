"""Numpy ``.npz`` archives: :func:`read_npz` (the generic ``t`` / ``omega`` layout and the MIMU array layout)."""

from __future__ import annotations

import zipfile
import zlib

import numpy as np

from ..errors import FormatError, InputError, OptionError
from .stream import ImuStream, input_path, rate_factor

#: Arrays of an archive may take at most this many times its size (plus :data:`EXPANSION_SLACK_BYTES`).
MAX_EXPANSION = 50
EXPANSION_SLACK_BYTES = 64 << 20


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
    path = input_path(path)
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic not in (b"PK\x03\x04", b"PK\x05\x06"):
        got = "an empty file" if not magic else "a .npy array" if magic.startswith(b"\x93NUM") else \
            "a file that is not a zip archive"
        raise FormatError(f"{path.name}: expected a numpy .npz archive (zip), got {got}")
    try:
        _check_sizes(path)
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error, NotImplementedError,
            RuntimeError) as exc:
        why = "an object array (pickled data), which is not read" if "pickle" in str(exc) else \
            " ".join(str(exc).split())
        raise FormatError(f"{path.name}: expected a complete numpy .npz archive of numeric arrays, got {why}") \
            from None
    bad = sorted(k for k, v in d.items() if v.dtype.kind not in "biuf")
    if bad:
        raise FormatError(f"{path.name}: expected numeric arrays, got {', '.join(f'{k!r} of dtype {d[k].dtype}' for k in bad)}")
    try:
        return _streams(path, d, imu, unit, name)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, (InputError, OptionError)):
            raise
        raise FormatError(f"{path.name}: expected the arrays of a gyro log, {' '.join(str(exc).split())}") from None


def _check_sizes(path) -> None:
    """Refuse an archive whose arrays would take more memory than such a file can hold, before decompressing.

    Every ``.npy`` member's header (shape and dtype) is read first: its bytes must match what the archive
    declares, and all members together may take at most :data:`MAX_EXPANSION` times the file's size (plus
    :data:`EXPANSION_SLACK_BYTES`): gyro logs compress a few times at most, a "zip bomb" a thousand times.
    """
    limit = EXPANSION_SLACK_BYTES + MAX_EXPANSION * path.stat().st_size
    total = 0
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            with zf.open(info) as f:
                version = np.lib.format.read_magic(f)
                shape, _, dtype = (np.lib.format.read_array_header_1_0(f) if version == (1, 0)
                                   else np.lib.format.read_array_header_2_0(f))
                header = f.tell()
            nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
            if not dtype.hasobject and nbytes != info.file_size - header:
                raise ValueError(f"member {info.filename!r} whose header says {shape} {dtype} ({nbytes} bytes) but "
                                 f"which holds {info.file_size - header} bytes")
            total += nbytes
            if total > limit:
                raise ValueError(f"arrays of {total} bytes or more from a file of {path.stat().st_size} bytes "
                                 f"(at most {MAX_EXPANSION}x the file's size plus {EXPANSION_SLACK_BYTES >> 20} MiB "
                                 "are read)")


def _streams(path, d: dict, imu, unit: str, name):
    """The streams of the arrays ``d`` of ``path`` (the layouts of :func:`read_npz`)."""
    valid = None
    if {"t_s", "gyro_counts", "gyro_lsb_per_dps"} <= d.keys():
        t = np.asarray(d["t_s"], dtype=np.float64)
        counts = np.asarray(d["gyro_counts"])
        if counts.ndim == 2:
            counts = counts[:, None, :]
        info = np.iinfo(counts.dtype) if counts.dtype.kind in "iu" else None
        w = counts.astype(np.float64) * rate_factor("counts", float(d["gyro_lsb_per_dps"]), path.name)
        if info is not None:
            valid = ~((counts >= info.max) | (counts <= info.min)).any(axis=-1)
        unit_in = "counts"
    elif "t" in d and ("omega" in d or "gyro" in d):
        t = np.asarray(d["t"], dtype=np.float64)
        w = np.asarray(d["omega"] if "omega" in d else d["gyro"], dtype=np.float64)
        w = w * rate_factor(unit, None, path.name)
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
    k = int(imu) if isinstance(imu, (int, np.integer)) and not isinstance(imu, bool) else -1
    if not 0 <= k < n_imu:
        raise InputError(f"{path.name}: expected imu in 0..{n_imu - 1} (0-based), got {imu!r}")
    return stream(k)
