"""Binary files at the edge of the text readers: recognised by their first bytes and refused by name.

The text readers (CSV, Xsens) and the choice of reader call :func:`check_text_file` before any parser reads a file:
a file that starts like a known binary layout (MATLAB ``.mat``, HDF5, ``.npy``, PX4 ULog, MCAP, SQLite, an archive,
an image, an executable) or holds a NUL byte in its first 4 kB is a :class:`~fusion_gyrocal.errors.FormatError`
naming what it is and what to do, never quoting its bytes. UTF-16/32 text (a byte-order mark) is left to the text
reader, which refuses it with the fix.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import FormatError

HEAD_BYTES = 4096
"""Bytes read from the start of a file to tell binary from text."""

ULOG_MAGIC = b"ULog\x01\x12\x35"
"""The first 7 bytes of every PX4 ULog file (then the format version and the start time, in us)."""

# Known binary layouts by their first bytes (what the file is, what to do with it).
_BINARY_MAGIC = (
    (ULOG_MAGIC, "a PX4 ULog file", "read it with read_imu / read_ulog (format 'ulog' or 'auto')"),
    (b"MATLAB 5.0 MAT-file", "a MATLAB .mat file (v5-v7.2)", "export the gyro columns to CSV, or load it with "
     "scipy.io.loadmat and pass the arrays to calibrate_pair"),
    (b"\x89HDF\r\n\x1a\n", "an HDF5 file (e.g. MATLAB .mat v7.3)", "export the gyro columns to CSV, or load it "
     "with h5py and pass the arrays to calibrate_pair"),
    (b"\x93NUMPY", "a NumPy .npy array", "save t and omega together with numpy.savez (an .npz)"),
    (b"\x7fELF", "an executable", "pass the recording instead"),
    (b"\x1f\x8b", "a gzip archive", "decompress it first"),
    (b"\x89PNG", "a PNG image", "pass the recording instead"),
    (b"%PDF", "a PDF document", "pass the recording instead"),
    (b"\x89MCAP", "an MCAP file without the '.mcap' suffix", "rename it to '.mcap'"),
    (b"SQLite format 3\x00", "an SQLite database (a ROS2 .db3?)", "rename it to '.db3' if it is a ROS2 bag"),
)


def refuse_binary(path: Path, head: bytes, fmt: str) -> None:
    """Raise a :class:`FormatError` naming what ``path`` is when its first bytes ``head`` are binary.

    ``fmt`` is the format the file was about to be read as. Recognised layouts are named with what to do;
    any other file with a NUL byte in ``head`` is refused as binary. The message never quotes the bytes.
    """
    if head[:2] in (b"\xff\xfe", b"\xfe\xff") or head[:4] == b"\x00\x00\xfe\xff":
        return   # UTF-16/32 text: the text reader refuses it with the fix (save as 'CSV UTF-8')
    what, advice = next(((w, a) for magic, w, a in _BINARY_MAGIC if head.startswith(magic)), (None, None))
    if what is None and b"\x00" in head:
        what, advice = "a binary file (NUL bytes in its first block)", "pass a text export or a supported format"
    if what is not None:
        raise FormatError(f"{path.name}: expected {fmt} text, got {what}; {advice}")


def check_text_file(path, fmt: str) -> None:
    """Refuse ``path`` before ``fmt`` text parsing when its first :data:`HEAD_BYTES` bytes are binary
    (:func:`refuse_binary`)."""
    p = Path(path)
    with open(p, "rb") as f:
        head = f.read(HEAD_BYTES)
    refuse_binary(p, head, fmt)
