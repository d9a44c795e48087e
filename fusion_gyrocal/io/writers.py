"""File writers: calibration results (JSON, Kalibr / OpenVINS YAML) and gyro streams (CSV, npz).

Every writer is atomic: the bytes go to a temporary file in the destination folder, are flushed
and fsync'ed, and only then renamed over the destination with :func:`os.replace`. A crash or an
exception mid-write leaves the previous file untouched and no half-written file behind. The files of
one run written inside :func:`output_group` are replaced together or not at all (a commit journal; a
run killed mid-commit is finished, and its temp files cleaned, by the next write into the folder:
:func:`recover_outputs`). A character device (``/dev/null``) or a FIFO is written in place, never
replaced by a regular file; ``"-"`` is standard output.

Which file for which consumer
-----------------------------
* :func:`write_kalibr_imu_configs`: one ``imu<k>.yaml`` per gyro, what Kalibr reads
  (``kalibr_calibrate_imu_camera --imu imu0.yaml imu1.yaml ...``, its ``ImuParameters``);
* :func:`write_kalibr_imu_chain`: every gyro in Kalibr's multi-IMU RESULT layout (``imu0``, ``imu1``,
  ... with ``T_i_b``, ``time_offset``, intrinsics), which tools built on Kalibr results read;
* :func:`write_openvins_imu_chain`: OpenVINS' ``kalibr_imu_chain.yaml`` (OpenCV ``%YAML:1.0``).

Frame and time conventions of the YAML exports (``ARCHITECTURE.md``)
--------------------------------------------------------------------
* the reference gyro (gyro 1) is the body frame ``b``: ``imu0`` has ``T_i_b = I``;
* every other gyro k is ``imu<i>`` with ``T_i_b = [R_k_b | 0]``, ``R_k_b = R_b_k^T`` (for a pair,
  ``R_2_1 = R_1_2^T``) mapping body vectors into gyro k's frame. The translation is NOT estimated
  (gyro-only calibration): it is written as zeros and flagged by a comment and
  ``translation_estimated: false``;
* ``time_offset`` is the seconds ADDED to the IMU's timestamps to put them on imu0's clock
  (:attr:`PairCalibration.time_offset_s`). Kalibr uses the same sign (it evaluates imu N at
  ``t_N + time_offset`` on the reference clock), so the value is written unchanged;
* the measurement model ``omega_i_meas = S_i R_i_b omega_b + b_i`` (Eq. 1) is Kalibr's
  ``scale-misalignment`` gyro model ``omega = M C_gyro_i C_i_b omega_b + b`` with ``M = S_i``
  (diagonal: no misalignment is estimated), ``C_gyro_i = I`` and ``A = 0`` (no g-sensitivity), and
  OpenVINS' ``omega_m = Tw R_IMUtoGYRO omega_I + Tg a + b`` with ``Tw = S_i``,
  ``R_IMUtoGYRO = I``, ``Tg = 0``;
* scale factors are known only up to one common factor per group of linked axes (Theorem 2, Lemmas 2-3): the
  files carry them RELATIVE TO THE REFERENCE IMU (imu0), every scale factor of a group divided by imu0's in
  that group, so imu0's ``M`` / ``Tw`` is exactly the identity wherever a group holds one of its axes (every
  axis-parallel board) and OpenVINS does not rescale the reference gyro; where a group holds several of imu0's
  axes (a general mounting: the data fix their ratios) it is divided by their geometric mean. Each IMU's
  relative scale factors and their 1-sigma are in a comment;
* noise figures: figures passed as :class:`ImuNoise` are written as given (:func:`read_imu_noise` reads them
  from a Kalibr ``imu.yaml``, an ``allan_variance_ros`` output or an IMU chain). Otherwise an array's
  per-gyro white noise (:attr:`ArrayCalibration.noise_density`, identified by the joint solve and referred to each
  gyro's own rate; per sample ``noise_std`` at each IMU's ``update_rate`` without timestamps) is each IMU's
  ``gyroscope_noise_density``; and when a pair's
  calibration carries the noise model identified from its own residual
  (:attr:`PairCalibration.noise_model`, :func:`~fusion_gyrocal.core.noise.identify_noise`), each gyro's
  white noise density (``noise_density``, rad/s/sqrt(Hz)) is its ``gyroscope_noise_density`` and the bias
  random walk ``K`` (rad/s^2/sqrt(Hz)) its ``gyroscope_random_walk``, each with a comment saying where it
  came from and its standard uncertainty. When the residual is a rate-dependent misfit rather than noise
  the density is still the sensor's (from the quiet windows, the model's ``sources``), never the
  residual's spread. What nothing measured (the accelerometer figures of a gyro-only calibration, a walk
  the Allan fit did not find, every figure of a calibration without a noise model) is a placeholder
  marked ``PLACEHOLDER`` with how to measure it (never 0, which Kalibr rejects);
* a pair flagged not rigid gets a WARNING comment at the top of every file;
* topic names are written double-quoted, so ``#`` and ``:`` in them stay text.
"""

from __future__ import annotations

import contextlib
import contextvars
import io
import json
import os
import re
import secrets
import stat
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.array_result import ARRAY_KIND, ArrayCalibration   # the result types only: not the joint solver
from ..core.model import PairCalibration, parallel_axes
from ..errors import FormatError, InputError
from ..lie import canonical_rotvec, log
from .stream import ImuStream, input_path

# Placeholder noise figures (the ADIS16448 values of OpenVINS' EuRoC kalibr_imu_chain.yaml), written
# only where nothing better is known, and always flagged as placeholders in the file.
_PLACEHOLDER = {
    "accelerometer_noise_density": 2.0e-3,   # m/s^2/sqrt(Hz)
    "accelerometer_random_walk": 3.0e-3,     # m/s^3/sqrt(Hz)
    "gyroscope_noise_density": 1.6968e-4,    # rad/s/sqrt(Hz)
    "gyroscope_random_walk": 1.9393e-5,      # rad/s^2/sqrt(Hz)
}


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time IMU noise figures in Kalibr's units (from an Allan-variance analysis).

    Attributes
    ----------
    gyroscope_noise_density : float
        Gyro white noise, rad/s/sqrt(Hz) (= per-sample std / sqrt(rate)).
    gyroscope_random_walk : float
        Gyro bias diffusion, rad/s^2/sqrt(Hz).
    accelerometer_noise_density : float
        Accelerometer white noise, m/s^2/sqrt(Hz).
    accelerometer_random_walk : float
        Accelerometer bias diffusion, m/s^3/sqrt(Hz).
    """

    gyroscope_noise_density: float
    gyroscope_random_walk: float
    accelerometer_noise_density: float
    accelerometer_random_walk: float

    def __post_init__(self):
        for k in ("gyroscope_noise_density", "gyroscope_random_walk",
                  "accelerometer_noise_density", "accelerometer_random_walk"):
            v = float(getattr(self, k))
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"ImuNoise.{k}: expected a positive finite value (Kalibr rejects 0), got {v!r}")
            object.__setattr__(self, k, v)


# ----------------------------------------------------------------------------- atomic writes
#: The output path that means standard output (the string ``"-"``; ``Path("-")`` is a file named ``-``).
STDOUT = "-"
#: Temp files are ``.<name>.gyrocal-<pid>-<random>.tmp`` beside their destination; commit journals of a
#: group of outputs (:func:`output_group`) ``.gyrocal-commit-<pid>-<random>.json``.
_TMP = re.compile(r"^\..+\.gyrocal-(\d+)-[^.]+\.tmp$")
_JOURNAL = re.compile(r"^\.gyrocal-commit-(\d+)-[^.]+\.json$")
_GROUP: contextvars.ContextVar = contextvars.ContextVar("fusion_gyrocal_output_group", default=None)


def _umask() -> int:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    return 0o022


def fsync_dir(d: Path) -> None:
    """Flush folder ``d``'s entries to disk (a rename into it survives a crash); errors are ignored."""
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def os_reason(exc: OSError) -> str:
    """The cause of an :class:`OSError` in words (``"Permission denied"``), without errno and path."""
    return exc.strerror or str(exc) or type(exc).__name__


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True   # exists, owned by someone else
    return True


def _unlink(p) -> None:
    try:
        os.unlink(p)
    except OSError:
        pass


def recover_outputs(folder) -> None:
    """Finish or undo what a killed writer left in ``folder``: the next run's first step.

    A commit journal of a dead process (:func:`output_group`) whose copies all exist is rolled forward (its
    remaining temp files renamed over their destinations: the group is replaced as a whole); one whose copies
    do not all exist was being written when the process died, before any rename, and is rolled back (its temp
    files deleted). Then the temp files of dead processes that no journal names are deleted. Errors are ignored
    (a folder we may not write is left as it is).
    """
    folder = Path(folder)
    try:
        names = os.listdir(folder)
    except OSError:
        return
    named = set()
    for name in names:
        m = _JOURNAL.match(name)
        if not m or _alive(int(m.group(1))):
            continue
        try:
            with open(folder / name, encoding="utf-8") as f:
                journal = json.load(f)
            renames, copies = journal["renames"], journal["journals"]
        except (OSError, ValueError, KeyError, TypeError):
            _unlink(folder / name)
            continue
        complete = all(os.path.exists(c) for c in copies)
        for tmp, dest in renames:
            named.add(os.path.abspath(tmp))
            if os.path.exists(tmp):
                try:
                    os.replace(tmp, dest) if complete else os.unlink(tmp)
                except OSError:
                    pass
        for d in {os.path.dirname(dest) for _, dest in renames}:
            fsync_dir(Path(d))
        for c in copies:
            _unlink(c)
    for name in names:
        m = _TMP.match(name)
        if m and not _alive(int(m.group(1))) and os.path.abspath(folder / name) not in named:
            _unlink(folder / name)


def _target(path) -> tuple[Path | None, str]:
    """Where ``path`` writes and how: ``(None, "stdout")``, ``(p, "direct")`` for a character device or a FIFO
    (written in place: a rename would replace the device node), else ``(p, "atomic")`` with symbolic links
    resolved (the file they point at is replaced, the link kept). Folders, block devices and sockets are refused."""
    if isinstance(path, str) and path == STDOUT:
        return None, "stdout"
    p = Path(path).expanduser()
    try:
        st = os.stat(p)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise FormatError(f"{p}: could not write: {os_reason(exc)}") from exc
    if st is None:
        if p.is_symlink():   # a dangling link: write the file it names
            p = Path(os.path.realpath(p))
        return p, "atomic"
    if stat.S_ISCHR(st.st_mode) or stat.S_ISFIFO(st.st_mode):
        return p, "direct"
    if stat.S_ISDIR(st.st_mode):
        raise FormatError(f"{p}: expected a file to write, got a folder")
    if not stat.S_ISREG(st.st_mode):
        kind = "a block device" if stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode) else \
            "not a regular file"
        raise FormatError(f"{p}: expected a regular file, a character device or a FIFO to write, got {kind}")
    return (Path(os.path.realpath(p)) if p.is_symlink() else p), "atomic"


def _write_direct(path: Path | None, data: bytes) -> None:
    """``data`` to standard output (``path`` None) or into a character device / FIFO, in place."""
    if path is None:
        out = getattr(sys.stdout, "buffer", None)
        if out is None:
            sys.stdout.write(data.decode("utf-8"))
        else:
            out.write(data)
        sys.stdout.flush()
        return
    try:
        with open(path, "wb") as f:
            f.write(data)
    except OSError as exc:
        raise FormatError(f"{path}: could not write: {os_reason(exc)}") from exc


def _stage(path: Path, data: bytes) -> str:
    """``data`` in a fsync'ed temp file beside ``path`` with the permissions of the file it will replace."""
    folder = path.parent
    if not folder.is_dir():
        raise FormatError(f"{path}: folder {folder} does not exist")
    recover_outputs(folder)
    try:
        mode = (os.stat(path).st_mode & 0o7777) if path.exists() else (0o666 & ~_umask())
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.gyrocal-{os.getpid()}-", suffix=".tmp", dir=folder)
    except OSError as exc:
        raise FormatError(f"{path}: could not write: {os_reason(exc)}") from exc
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)
    except BaseException as exc:
        _unlink(tmp)
        if isinstance(exc, OSError):
            raise FormatError(f"{path}: could not write: {os_reason(exc)}") from exc
        raise
    return tmp


def atomic_write(path, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` atomically (temp file in the same folder, fsync, ``os.replace``).

    The one mechanism for every file the library writes, text (``str``, UTF-8) and binary (``bytes``,
    e.g. a PNG rendered in memory) alike: a reader never sees a half-written file. The file keeps the
    permissions of the file it replaces (new files get ``0o666 & ~umask``); a symbolic link is kept and
    the file it points at replaced. A character device (``/dev/null``) or a FIFO is written in place,
    never replaced; the string ``"-"`` (:data:`STDOUT`) writes to standard output. Inside
    :func:`output_group` the file is replaced together with the group's other files. What a killed
    writer left in the folder is finished or undone first (:func:`recover_outputs`).

    Raises
    ------
    FormatError
        When the folder does not exist, the path is a folder, a block device or a socket, or the write
        fails (the old file is left as it was); the message names the file and the cause
        (``"cal.json: could not write: Permission denied"``).
    """
    target, how = _target(path)
    shown = Path(STDOUT) if target is None else Path(path).expanduser()   # what the caller named
    if isinstance(data, str):
        data = data.encode("utf-8")
    group = _GROUP.get()
    if how != "atomic":
        if group is not None:
            group.append((None, target, data))
        else:
            _write_direct(target, data)
        return shown
    tmp = _stage(target, data)
    if group is not None:
        group.append((tmp, target, None))
        return shown
    try:
        os.replace(tmp, target)
    except OSError as exc:
        _unlink(tmp)
        raise FormatError(f"{target}: could not write: {os_reason(exc)}") from exc
    fsync_dir(target.parent)
    return shown


@contextlib.contextmanager
def output_group():
    """Every file :func:`atomic_write` writes inside the block is replaced together, or none is.

    The files are staged (temp files, fsync'ed) while the block runs; when it ends without an exception a
    commit journal naming every rename is written into each folder involved, the renames are made and the
    journals deleted. An exception in the block deletes the staged files and leaves every old file as it was;
    a process killed during the renames leaves the journals, and the next write into one of those folders
    finishes the renames (:func:`recover_outputs`). Standard output and devices are written at the commit.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> with output_group():
    ...     _ = atomic_write(d / "a.txt", "new a"), atomic_write(d / "b.txt", "new b")
    >>> sorted(p.name for p in d.iterdir())
    ['a.txt', 'b.txt']
    """
    staged: list = []
    token = _GROUP.set(staged)
    try:
        yield staged
    except BaseException:
        for tmp, _, _ in staged:
            if tmp is not None:
                _unlink(tmp)
        raise
    finally:
        _GROUP.reset(token)
    _commit(staged)


def _commit(staged: list) -> None:
    """The renames of an :func:`output_group`, behind a journal when there are several."""
    files = [(tmp, dest) for tmp, dest, _ in staged if tmp is not None]
    folders = sorted({str(dest.parent) for _, dest in files})
    copies = []
    try:
        if len(files) > 1:
            tag = f"{os.getpid()}-{secrets.token_hex(4)}"
            copies = [os.path.join(f, f".gyrocal-commit-{tag}.json") for f in folders]
            text = json.dumps({"renames": [[os.path.abspath(t), str(d)] for t, d in files], "journals": copies})
            for c in copies:
                with open(c, "w", encoding="utf-8") as f:
                    f.write(text)
                    f.flush()
                    os.fsync(f.fileno())
            for f in folders:
                fsync_dir(Path(f))
        for tmp, dest in files:
            os.replace(tmp, dest)
    except OSError as exc:
        for tmp, _ in files:
            _unlink(tmp)
        for c in copies:
            _unlink(c)
        raise FormatError(f"{files[0][1]}: could not write: {os_reason(exc)}") from exc
    for f in folders:
        fsync_dir(Path(f))
    for c in copies:
        _unlink(c)
    for tmp, target, data in staged:
        if tmp is None:
            _write_direct(target, data)


# ----------------------------------------------------------------------------- JSON
def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_json(cal, path) -> Path:
    """Write the full calibration (``cal.to_dict()``, with ``format_version``) as JSON, atomically.

    ``cal`` is a :class:`PairCalibration` or an :class:`~fusion_gyrocal.core.array.ArrayCalibration`
    (every gyro; its dict carries ``kind: "array_calibration"``). The file is strict JSON with every number a
    number: a non-finite one (an undetermined scale factor's infinite variance) is ``null``, and the top-level
    ``non_finite`` names each such entry by its JSON Pointer under its kind (``inf``, ``-inf``, ``nan``;
    :func:`~fusion_gyrocal.core.model.strict_json`), which :func:`read_json` puts back.
    """
    if not isinstance(cal, (PairCalibration, ArrayCalibration)):
        raise InputError(f"cal: expected a PairCalibration or an ArrayCalibration, got {type(cal).__name__}")
    text = json.dumps(cal.to_dict(), indent=2, allow_nan=False, default=_json_default) + "\n"
    return atomic_write(path, text)


def read_json(path):
    """Read a calibration written by :func:`write_json`: a :class:`PairCalibration`, or an
    :class:`~fusion_gyrocal.core.array.ArrayCalibration` when the file's ``kind`` says so.

    Raises
    ------
    FormatError
        When the file is not JSON, has another ``format_version`` or lacks required fields.
    """
    p = input_path(path)   # exists and is a regular file (a FIFO would block)
    try:
        with open(p, "r", encoding="utf-8") as f:
            d = json.load(f)
    except UnicodeDecodeError as exc:
        raise FormatError(f"{p.name}: expected UTF-8 JSON, got undecodable bytes at offset {exc.start}") from None
    except json.JSONDecodeError as exc:
        raise FormatError(f"{p.name}: expected JSON, got a syntax error at line {exc.lineno} column {exc.colno}: "
                          f"{exc.msg}") from None
    except RecursionError:
        raise FormatError(f"{p.name}: expected a calibration written by write_json, got JSON nested too deeply to "
                          "read") from None
    if not isinstance(d, dict):
        raise FormatError(f"{p.name}: expected a JSON object, got {type(d).__name__}")
    try:
        cal = ArrayCalibration.from_dict(d) if d.get("kind") == ARRAY_KIND else PairCalibration.from_dict(d)
    except FormatError as exc:
        raise FormatError(f"{p.name}: {exc}") from None
    except (TypeError, ValueError, KeyError, AttributeError, IndexError, RecursionError) as exc:
        raise FormatError(f"{p.name}: expected a calibration written by write_json, {exc}") from None
    rotations = [("R_1_2", cal.R_1_2)] if isinstance(cal, PairCalibration) else \
        [(f"R_ref_k[{k}]", R) for k, R in enumerate(cal.R_ref_k)]
    for name, R in rotations:
        R = np.asarray(R, dtype=float)
        if R.shape != (3, 3) or not np.isfinite(R).all() or np.abs(R.T @ R - np.eye(3)).max() > _ROTATION_TOL \
                or abs(np.linalg.det(R) - 1.0) > _ROTATION_TOL:
            raise FormatError(f"{p.name}: expected {name} to be a rotation (orthonormal, det +1, within "
                              f"{_ROTATION_TOL:g}), got {np.round(R, 6).tolist()}")
    return cal


#: How far a rotation read from JSON may be from orthonormal (the file's 17 digits give ~1e-15).
_ROTATION_TOL = 1e-6


# ----------------------------------------------------------------------------- streams
def write_csv(stream: ImuStream, path, *, delimiter: str = ",") -> Path:
    """Write a stream as text: header ``t [s],gyro_x [rad/s],gyro_y [rad/s],gyro_z [rad/s]``.

    Values are written with 17 significant digits, so :func:`fusion_gyrocal.io.read_csv` reads
    back the same float64 numbers. ``stream.valid`` is not stored (non-finite rows stay NaN).
    """
    if not isinstance(stream, ImuStream):
        raise InputError(f"stream: expected an ImuStream, got {type(stream).__name__}")
    buf = io.StringIO()
    names = ["t [s]", "gyro_x [rad/s]", "gyro_y [rad/s]", "gyro_z [rad/s]"]
    np.savetxt(buf, np.column_stack([stream.t, stream.omega]), fmt="%.17g", delimiter=delimiter,
               header=delimiter.join(names), comments="")
    return atomic_write(path, buf.getvalue())


def write_npz(stream: ImuStream, path) -> Path:
    """Write a stream as ``.npz`` with keys ``t`` (s), ``omega`` (rad/s) and ``valid``."""
    if not isinstance(stream, ImuStream):
        raise InputError(f"stream: expected an ImuStream, got {type(stream).__name__}")
    buf = io.BytesIO()
    np.savez(buf, t=stream.t, omega=stream.omega, valid=stream.valid)
    return atomic_write(path, buf.getvalue())


# ----------------------------------------------------------------------------- YAML helpers
def _yf(x) -> str:
    """A float as YAML 1.1 / OpenCV both read back exactly (always with a '.', signed exponent)."""
    x = float(x)
    if not np.isfinite(x):
        raise FormatError(f"expected finite numbers for a Kalibr/OpenVINS file, got {x}")
    s = repr(x)
    if "e" in s or "E" in s:
        mant, exp = s.lower().split("e")
        if "." not in mant:
            mant += ".0"
        sign = "-" if exp.startswith("-") else "+"
        s = f"{mant}e{sign}{exp.lstrip('+-')}"
    elif "." not in s:
        s += ".0"
    return s


def _matrix(key: str, m: np.ndarray, indent: str) -> list[str]:
    out = [f"{indent}{key}:"]
    for row in np.asarray(m, dtype=float):
        out.append(f"{indent}  - [" + ", ".join(_yf(v) for v in row) + "]")
    return out


# ----------------------------------------------------------------------------- IMU chains (Kalibr, OpenVINS)
_NOISE_UNITS = {"accelerometer_noise_density": "m/s^2/sqrt(Hz)", "accelerometer_random_walk": "m/s^3/sqrt(Hz)",
                "gyroscope_noise_density": "rad/s/sqrt(Hz)", "gyroscope_random_walk": "rad/s^2/sqrt(Hz)"}
_GYRO_KEYS = ("gyroscope_noise_density", "gyroscope_random_walk")
_NOT_MEASURED = "PLACEHOLDER, not measured"
_PLACEHOLDER_HOWTO = ("# PLACEHOLDER noise figures (marked below, with why): nothing in this calibration measured them. "
                      "Measure them with an\n# Allan-variance analysis of a long static recording of this IMU (white "
                      "noise at tau = 1 s, random walk from the +1/2 slope)\n# and replace them before estimating with "
                      "them.")


@dataclass(frozen=True)
class _Figure:
    """One noise figure of an export and what its line's comment says about it."""

    value: float
    note: str = ""             # after the unit; "" for figures the caller gave (ImuNoise)
    placeholder: bool = False
    from_model: bool = False   # made from the calibration's noise model (its header says where from)


@dataclass(frozen=True)
class _ChainImu:
    """One IMU of an export: its rotation into the body frame (the reference gyro), scales, clock."""

    gyro: int
    R_b_i: np.ndarray
    scale: np.ndarray
    observable: np.ndarray
    time_offset: float
    time_offset_source: str
    rotation_std_deg: np.ndarray
    rel_scale: np.ndarray = None       # scale factors relative to imu0's (see the module docstring)
    rel_scale_std: np.ndarray = None   # their 1-sigma (NaN where the divisor is no single axis of imu0)


@dataclass(frozen=True)
class _Chain:
    """What every YAML export needs of a calibration (pair or array), the reference first."""

    imus: tuple
    what: str
    gauge: str
    configuration: str
    warning: tuple
    identified: tuple = ()     # per IMU: {gyro key: _Figure} identified from the data, or None
    noise_header: tuple = ()   # comment lines saying where the identified figures came from


def _finite(name: str, v) -> None:
    if not np.isfinite(v).all():
        raise FormatError(f"{name}: Kalibr/OpenVINS files need finite values, got {np.asarray(v).tolist()}")


def _relative_scales(scale, groups, ref: int, ratio_sd) -> tuple[np.ndarray, np.ndarray]:
    """Scale factors ``(N, 3)`` relative to the reference gyro's, per group of linked axes (``(gyro, axis)``
    tuples): divided by the reference's scale factor in the group, or the geometric mean of its several. The
    1-sigma is ``ratio_sd(gyro, axis, ref_axis)`` where one axis of the reference divides (0 for that axis itself),
    NaN elsewhere."""
    scale = np.asarray(scale, float)
    rel, sd = scale.copy(), np.full(scale.shape, np.nan)
    for group in groups:
        refs = [a for g, a in group if g == ref]
        if not refs:
            continue
        div = float(np.exp(np.mean(np.log(scale[ref, refs]))))
        for g, a in group:
            rel[g, a] = scale[g, a] / div
            if len(refs) == 1:
                sd[g, a] = 0.0 if (g, a) == (ref, refs[0]) else ratio_sd(g, a, refs[0])
    return rel, sd


def _chain_of(cal) -> _Chain:
    """The :class:`_Chain` of a :class:`PairCalibration` or an :class:`ArrayCalibration` (finite values checked)."""
    if isinstance(cal, PairCalibration):
        for nm in ("R_1_2", "scale_1", "scale_2"):
            _finite(f"cal.{nm}", getattr(cal, nm))
        if not np.isfinite(cal.time_offset_s):
            raise FormatError(f"cal.time_offset_s: expected a finite time offset, got {cal.time_offset_s}")
        from ..core.observability import seed_configuration

        rot_std = np.degrees(cal.rotation_std_rad)
        src = "estimated" if cal.time_offset_std_s > 0 else "given or sample-aligned"
        p = parallel_axes(cal.R_1_2)
        rel, rel_sd = _relative_scales(
            np.stack([cal.scale_1, cal.scale_2]), seed_configuration(cal.R_1_2, cal.configuration).groups, 0,
            lambda g, a, b: float(cal.scale_ratio_std[a]) if g == 1 and p[a] == b else float("nan"))
        imus = (_ChainImu(0, np.eye(3), cal.scale_1, cal.scale_observable[0], 0.0, "reference", np.zeros(3),
                          rel[0], rel_sd[0]),
                _ChainImu(1, cal.R_1_2, cal.scale_2, cal.scale_observable[1], float(cal.time_offset_s), src, rot_std,
                          rel[1], rel_sd[1]))
        warning = ()
        if cal.rigid is False:
            warning = (f"WARNING: NOT RIGID. A single rotation and scale factors leave "
                       f"{100 * cal.unexplained_fraction:.1f}% of gyro 1's motion unexplained: the gyros move "
                       "relative to each other.",
                       "WARNING: the values below are NOT a calibration (nearest rotation, unit scales); do not use "
                       "them for estimation.")
        what = f"a gyro-pair calibration ({cal.method}, {cal.n_samples} samples)"
        return _Chain(imus, what, cal.gauge, cal.configuration, warning)
    if isinstance(cal, ArrayCalibration):
        _finite("cal.R_ref_k", cal.R_ref_k)
        _finite("cal.scale", cal.scale)
        _finite("cal.time_offset_s", cal.time_offset_s)
        ref = cal.reference
        order = [ref] + [k for k in range(cal.n_gyros) if k != ref]
        rot_std = np.degrees(cal.rotation_std_rad)
        rel, rel_sd = _relative_scales(cal.scale, cal.scale_groups, ref,
                                       lambda g, a, b: cal.scale_ratio(g, a, ref, b)[1])
        imus = tuple(_ChainImu(k, cal.R_ref_k[k], cal.scale[k], cal.scale_observable[k],
                               float(cal.time_offset_s[k] - cal.time_offset_s[ref]), cal.time_offset_source[k],
                               rot_std[k], rel[k], rel_sd[k]) for k in order)
        configs = sorted({c for row in cal.configurations for c in row if c})
        what = f"a joint calibration of {cal.n_gyros} gyros (ml_array, {cal.n_samples} samples)"
        return _Chain(imus, what, cal.gauge, "pairs: " + ", ".join(configs), ())
    raise InputError(f"cal: expected a PairCalibration or an ArrayCalibration, got {type(cal).__name__}")


def _wrapped(text: str) -> list[str]:
    """A long comment as YAML comment lines (``#`` first, continuation lines indented)."""
    import textwrap

    return textwrap.wrap(text, width=118, initial_indent="# ", subsequent_indent="#   ", break_on_hyphens=False)


def _identified(cal: PairCalibration, rates) -> tuple[tuple, tuple]:
    """The gyro noise figures of a pair's identified noise model (:attr:`PairCalibration.noise_model`).

    Per gyro: ``gyroscope_noise_density`` = the model's white ``noise_density`` (rad/s/sqrt(Hz)), and
    ``gyroscope_random_walk`` = its bias random walk ``K`` (``random_walk``, rad/s^2/sqrt(Hz)); for a
    constant-bias model with a walk term in the residual's Allan fit, that term per gyro (the residual sees
    ``b_1 - A b_2``: its step variance split equally, ``q_r^2 / (1 + |A|_F^2 / 3)`` each, as
    :func:`~fusion_gyrocal.core.noise.identify_noise` splits a random-walk bias); no figure where the
    fit has no walk term or a number is not finite and positive. A model identified per sample (input
    without timestamps: ``rate_known`` False) is converted with the IMU's ``rates``. Returns the per-gyro figures
    and the header's comment lines, or ``((None, None), ())`` without a noise model.
    """
    nm = cal.noise_model
    if nm is None:
        return (None, None), ()
    per_sample = not nm.rate_known
    fs = [float(r) for r in rates] if per_sample else list(nm.sensor_rates)    # each IMU's own rate
    fq = fs if per_sample else [float(nm.rate_hz)] * 2                        # the rate of the walk's steps
    misfit = nm.is_misfit
    if nm.bias_walk_std is not None:
        q = nm.bias_walk_std
        share = [qi / nm.residual_walk_std if nm.residual_walk_std > 0 else np.nan for qi in q]
        q_sd = [nm.residual_walk_std_uncertainty * f for f in share]
        walk_how = "the identified random-walk bias model's K"
    elif nm.residual_walk_std > 0:
        each = 1.0 / np.sqrt(1.0 + float(np.sum(cal.A * cal.A)) / 3.0)
        q = (nm.residual_walk_std * each,) * 2
        q_sd = (nm.residual_walk_std_uncertainty * each,) * 2
        walk_how = ("the walk term K of the residual's Allan fit, split equally between the gyros (the calibration "
                    "itself keeps a constant bias)")
    else:
        q = q_sd = None
    # the sensors' own densities (identified on the grid, referred back to each sensor: NoiseModel.noise_density)
    density = [nm.noise_std[i] / np.sqrt(fs[i]) for i in (0, 1)] if per_sample else list(nm.noise_density)
    density_sd = [density[i] * nm.noise_std_uncertainty[i] / nm.noise_std[i] if nm.noise_std[i] > 0 else np.nan
                  for i in (0, 1)]
    still = nm.still_noise_std is not None and np.allclose(nm.noise_std, nm.still_noise_std, rtol=1e-9)
    if not nm.fits and not still:   # the Allan model misses its points: the uncertainty covers how far
        density_sd = [float(np.hypot(sd, d * (nm.adev_worst - 1.0))) for sd, d in zip(density_sd, density)]
    walk = None if q is None else [q[i] * np.sqrt(fq[i]) for i in (0, 1)]
    walk_sd = None if q is None else [q_sd[i] * np.sqrt(fq[i]) for i in (0, 1)]

    def good(v) -> bool:
        return v is not None and bool(np.isfinite(v)) and v > 0

    def pm(sd) -> str:
        return f", +- {sd:.2g}" if good(sd) else ", uncertainty not available"

    per_gyro = []
    for i in (0, 1):
        figs = {}
        if good(density[i]):
            how = ("the gyro's own still stretches in the log" if still else
                   "the sensor's white noise (the residual is a misfit)" if misfit else "white noise of the pair's residual")
            if not nm.fits and not still:
                how += f"; UNCERTAIN: its Allan model is up to {nm.adev_worst:.2f}x off the points"
            figs["gyroscope_noise_density"] = _Figure(density[i], "identified: " + how + pm(density_sd[i]),
                                                      from_model=True)
        if walk is not None and good(walk[i]):
            figs["gyroscope_random_walk"] = _Figure(walk[i], "identified: bias random walk of the pair's residual"
                                                    + pm(walk_sd[i]), from_model=True)
        else:
            figs["gyroscope_random_walk"] = _Figure(
                _PLACEHOLDER["gyroscope_random_walk"],
                f"{_NOT_MEASURED} (no random-walk term in the residual's Allan deviation up to "
                f"tau = {nm.fit_taus[1]:.3g} s)", True, True)
        per_gyro.append(figs or None)
    deg = 180.0 / np.pi
    lines = _wrapped(
        f"Gyroscope noise IDENTIFIED by fusion_gyrocal from the moving pair's own residual (overlapping "
        f"Allan deviation fitted with white noise, bias instability, random walk, quantisation and filtered noise, "
        f"IEEE Std 952; each gyro's own still stretches where the log has them), not from a separate static test: "
        f"residual {nm.kind}; bias model {nm.bias_model}; Allan model within {nm.adev_worst:.2f}x of its points.")
    for i in (0, 1):
        own = density[i] * np.sqrt(fs[i])
        lines.append(f"#   imu{i}: white {own * deg:.4g} +- {own * deg * density_sd[i] / density[i]:.2g} deg/s "
                     f"per sample at its {fs[i]:.6g} Hz = gyroscope_noise_density {density[i]:.4g} "
                     f"+- {density_sd[i]:.2g} rad/s/sqrt(Hz)")
    if per_sample:
        lines += _wrapped("  The calibration had no timestamps: the model is per sample, converted to densities with "
                          "each IMU's update_rate.")
    if walk is not None:
        lines += _wrapped(f"  gyroscope_random_walk: {walk_how}.")
    for key, text in nm.sources.items():
        lines += _wrapped(f"  {key}: {text}")
    if misfit:
        lines += _wrapped(
            f"The residual is NOT white noise but a rate-dependent misfit ({100 * nm.misfit_share:.0f}% of its "
            f"variance explained by the rate; residual rms {cal.residual_rms * deg:.3g} deg/s): "
            "gyroscope_noise_density is the sensors' white noise, from the windows where the misfit is negligible, "
            "never the residual's spread.")
    elif not nm.is_white:
        for note in nm.notes:
            lines += _wrapped(note)
    return tuple(per_gyro), tuple(lines)


def _identified_array(cal: ArrayCalibration, rates) -> tuple[tuple, tuple]:
    """The gyro white-noise densities the joint solve identified, for every IMU in chain order (the reference first):
    each gyro's own density (:attr:`ArrayCalibration.noise_density`: its noise per grid sample referred back to its
    native rate through what the resampling did to it); for input without timestamps (per-sample figures)
    ``noise_std[k] / sqrt(rate)`` with each IMU's own ``rates`` entry. Nothing when the noise was the user's. The
    random walk stays a placeholder (the joint solve does not identify one)."""
    if cal.noise_source == "user":
        return (None,) * cal.n_gyros, ()
    ref = cal.reference
    order = [ref] + [k for k in range(cal.n_gyros) if k != ref]
    per_sample = cal.noise_density is None
    own = [float(r) for r in rates] if per_sample else [float(cal.rates_hz[k]) for k in order]
    density = [float(cal.noise_std[k]) / np.sqrt(f) for k, f in zip(order, own)] if per_sample else \
        [float(cal.noise_density[k]) for k in order]
    per = []
    for k, d in zip(order, density):
        if not (np.isfinite(d) and d > 0):
            per.append(None)
            continue
        per.append({"gyroscope_noise_density": _Figure(
            d, f"identified: gyro {k + 1}'s white noise in the joint solve, uncertainty not available", from_model=True),
            "gyroscope_random_walk": _Figure(_PLACEHOLDER["gyroscope_random_walk"],
                                             f"{_NOT_MEASURED} (the joint solve identifies white noise only)", True,
                                             True)})
    how = ("per sample (input without timestamps), at each IMU's update_rate: gyroscope_noise_density = noise_std / "
           "sqrt(update_rate)" if per_sample else
           "per sample on imu0's grid, referred back to each IMU's own rate through what resampling did to its noise "
           "(noise_std^2 = v f N^2, v the share of white variance kept on the grid)")
    lines = _wrapped(f"Gyroscope white noise IDENTIFIED by fusion_gyrocal's joint solve of {cal.n_gyros} gyros "
                     f"({cal.noise_source}), {how}; a static Allan analysis (gyrocal noise) measures it better.")
    for i, (k, f, d) in enumerate(zip(order, own, density)):
        lines.append(f"#   imu{i} = gyro {k + 1}: white {np.degrees(cal.noise_std[k]):.4g} deg/s per grid sample; "
                     f"own rate {f:.6g} Hz: gyroscope_noise_density {d:.4g} rad/s/sqrt(Hz)")
    return tuple(per), tuple(lines)


def read_imu_noise(path) -> tuple[ImuNoise, ...]:
    """Measured noise figures from a YAML file: a Kalibr IMU configuration / ``allan_variance_ros`` output (the
    four figures at the top level: one :class:`ImuNoise`), or an IMU chain (``imu0``, ``imu1``, ... each with
    them: one per IMU; an OpenCV ``%YAML:1.0`` first line is skipped).

    Keys, in Kalibr's units: ``gyroscope_noise_density`` (rad/s/sqrt(Hz)), ``gyroscope_random_walk``
    (rad/s^2/sqrt(Hz)), ``accelerometer_noise_density`` (m/s^2/sqrt(Hz)), ``accelerometer_random_walk``
    (m/s^3/sqrt(Hz)); each must be positive (Kalibr rejects 0).

    Raises
    ------
    FormatError
        Not YAML, or a key missing or not a positive number (the message names the file and the key).
    """
    import yaml

    p = input_path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise FormatError(f"{p.name}: expected a UTF-8 YAML file, got undecodable bytes") from None
    if text.startswith("%YAML:1.0"):   # OpenCV's directive, which PyYAML does not take
        text = text.split("\n", 1)[1] if "\n" in text else ""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise FormatError(f"{p.name}: expected YAML, got {exc}") from None
    if not isinstance(data, dict):
        raise FormatError(f"{p.name}: expected a mapping of noise figures, got {type(data).__name__}")
    blocks = [data[k] for k in sorted((k for k in data if str(k).startswith("imu") and str(k)[3:].isdigit()),
                                      key=lambda k: int(str(k)[3:]))] or [data]
    out = []
    for i, block in enumerate(blocks):
        where = f"{p.name}" + (f" imu{i}" if len(blocks) > 1 or block is not data else "")
        if not isinstance(block, dict):
            raise FormatError(f"{where}: expected a mapping of noise figures, got {type(block).__name__}")
        missing = [k for k in _PLACEHOLDER if k not in block]
        if missing:
            raise FormatError(f"{where}: expected the Kalibr noise keys {list(_PLACEHOLDER)}, missing {missing}")
        try:
            out.append(ImuNoise(**{k: float(block[k]) for k in _PLACEHOLDER}))
        except (TypeError, ValueError, InputError) as exc:
            raise FormatError(f"{where}: {exc}") from None
    return tuple(out)


def write_kalibr_noise(noise, path, *, rostopic: str = "/imu0", provenance=None) -> Path:
    """Write a static noise analysis (:class:`~fusion_gyrocal.core.static_noise.StaticNoise`) as a Kalibr
    ``imu.yaml`` (what ``kalibr_calibrate_imu_camera --imu`` reads, and what imu_utils / allan_variance_ros users
    write by hand), atomically.

    ``gyroscope_noise_density`` is the mean of the three axes' white noise ``N`` and ``gyroscope_random_walk`` the
    mean of their ``K`` where the Allan fit kept a walk term (each axis with its 1-sigma in a comment); a walk no
    axis showed, and the accelerometer figures (gyro data only), are marked placeholders. ``update_rate`` is the
    recording's rate. The header names the recording (``provenance``) and the rest stretches used.
    """
    _topics([rostopic], 1)
    deg = 180.0 / np.pi
    figs = {k: _Figure(v, f"{_NOT_MEASURED} (gyro data only)", True) for k, v in _PLACEHOLDER.items()}
    figs["gyroscope_noise_density"] = _Figure(float(np.mean(noise.white)), "mean of the axes' white noise N, "
                                              "static Allan analysis")
    walk = [k for k in noise.random_walk if k > 0]
    if walk:
        figs["gyroscope_random_walk"] = _Figure(float(np.mean(walk)), f"mean of the {len(walk)} axes' random walk K "
                                                "with a walk term in the Allan fit")
    else:
        figs["gyroscope_random_walk"] = _Figure(
            _PLACEHOLDER["gyroscope_random_walk"], f"{_NOT_MEASURED} (no random-walk term up to tau = "
            f"{noise.taus[-1]:.3g} s: record longer at rest)", True)
    lines = [f"# Kalibr IMU configuration written by fusion_gyrocal (gyrocal noise): static Allan analysis of "
             f"{noise.n_samples} samples at rest in {len(noise.stretches)} stretch(es), {noise.rate_hz:.6g} Hz."]
    if provenance is not None:
        lines += [f"# {line}" for line in provenance.lines()]
    for a, name in enumerate("xyz"):
        lines.append(f"#   axis {name}: white N {noise.white[a]:.4g} +- {noise.white_std[a]:.2g} rad/s/sqrt(Hz) "
                     f"({noise.white[a] * deg * 60:.4g} deg/sqrt(h)); bias instability B {noise.bias_instability[a]:.3g}"
                     f" +- {noise.bias_instability_std[a]:.2g} rad/s; random walk K {noise.random_walk[a]:.3g} +- "
                     f"{noise.random_walk_std[a]:.2g} rad/s^2/sqrt(Hz)")
    if any(f.placeholder for f in figs.values()):
        lines.append(_PLACEHOLDER_HOWTO)
    lines += [f"rostopic: {_quoted(rostopic)}", f"update_rate: {_yf(noise.rate_hz)}  # [Hz]"]
    lines += _noise_lines(figs, "")
    text = "\n".join(lines) + "\n"
    _check_yaml(text, path, [rostopic])
    return atomic_write(path, text)


def _per_imu(value, n: int, name: str) -> list:
    """One value for every IMU, or a sequence of ``n``."""
    if isinstance(value, (tuple, list)):
        if len(value) != n:
            raise InputError(f"{name}: expected one value or one per IMU ({n}), got {len(value)} values")
        return list(value)
    return [value] * n


def _rates(update_rate, n: int) -> list[float]:
    out = []
    for v in _per_imu(update_rate, n, "update_rate"):
        v = float(v)
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"update_rate: expected a positive rate in Hz, got {v!r}")
        out.append(v)
    return out


def _topics(topics, n: int) -> list[str]:
    topics = [f"/imu{k}" for k in range(n)] if topics is None else list(topics)
    if len(topics) != n:
        raise InputError(f"topics: expected {n} topic names (imu0..imu{n - 1}), got {len(topics)}: {topics!r}")
    for t in topics:
        if not isinstance(t, str) or not t or any(c in t for c in '"\\') or not t.isprintable():
            raise InputError(f"topics: expected non-empty printable names without '\"' or '\\', got {t!r}")
    return topics


def _noises(noise, chain: _Chain) -> list[dict]:
    """Per IMU, every noise figure (a :class:`_Figure` per key): a given :class:`ImuNoise` as given; else the
    gyro figures identified from the data (:func:`_identified`) and placeholders for the rest."""
    n = len(chain.imus)
    identified = chain.identified or (None,) * n
    out = []
    for g, found in zip(_per_imu(noise, n, "noise"), identified):
        if g is not None and not isinstance(g, ImuNoise):
            raise InputError(f"noise: expected ImuNoise, None or one per IMU, got {type(g).__name__}")
        if g is not None:
            out.append({k: _Figure(getattr(g, k)) for k in _PLACEHOLDER})
            continue
        why = f"{_NOT_MEASURED} (gyro-only calibration)" if found else _NOT_MEASURED
        figs = {k: _Figure(v, why, True) for k, v in _PLACEHOLDER.items()}
        figs.update(found or {})
        out.append(figs)
    return out


def _any_placeholder(noises) -> bool:
    return any(f.placeholder for figs in noises for f in figs.values())


def _identified_used(noises) -> bool:
    return any(f.from_model for figs in noises for f in figs.values())


def _quoted(s: str) -> str:
    """A YAML double-quoted scalar (PyYAML and OpenCV read it back unchanged; ``#`` and ``:`` stay text)."""
    return f'"{s}"'


def _header(chain: _Chain, what: str, topics, noises) -> list[str]:
    lines = [f"# {w}" for w in chain.warning]
    lines += [f"# {what} written by fusion_gyrocal from {chain.what}."]
    for i, (imu, topic) in enumerate(zip(chain.imus, topics)):
        role = "the body/reference frame: T_i_b = identity" if i == 0 else "T_i_b = [R_i_b | t], R_i_b maps body " \
            "(imu0) vectors into this IMU's frame"
        lines.append(f"# imu{i} = gyro {imu.gyro + 1} ({topic}), {role}.")
    lines += [
        "# TRANSLATION IS NOT ESTIMATED (gyro-only calibration): t = 0 is a placeholder (translation_estimated: false).",
        "# time_offset [s] is ADDED to this IMU's timestamps to put them on imu0's clock.",
        f"# Scale factors are relative (Theorem 2): gauge = {chain.gauge}; configuration = {chain.configuration}.",
    ]
    lines += _wrapped("M / Tw hold the scale factors RELATIVE TO imu0 (per group of linked axes divided by imu0's, "
                      "the geometric mean of imu0's where a group holds several of its axes): imu0's are exactly 1 "
                      "wherever one of its axes fixes a group.")
    for i, imu in enumerate(chain.imus):
        lines.append(f"# imu{i}: relative scale factors {_scale_text(imu)}.")
    unknown = [f"imu{i} {'xyz'[a]}" for i, imu in enumerate(chain.imus) for a in range(3) if not _known(imu)[a]]
    if unknown:
        lines.append(f"# Scale factors the data do not determine are written as 1 (not estimated): {', '.join(unknown)}.")
    for i, imu in enumerate(chain.imus[1:], start=1):
        if np.isfinite(imu.rotation_std_deg).all():
            lines.append(f"# imu{i}: 1-sigma rotation uncertainty (deg, body axes) "
                         + ", ".join(f"{v:.3g}" for v in imu.rotation_std_deg)
                         + f"; time offset {imu.time_offset_source}.")
    if _identified_used(noises):
        lines += list(chain.noise_header)
    if _any_placeholder(noises):
        lines.append(_PLACEHOLDER_HOWTO)
    return lines


def _noise_lines(noise: dict, indent: str) -> list[str]:
    return [f"{indent}{k}: {_yf(noise[k].value)}  # [{_NOISE_UNITS[k]}]" + (f"  {noise[k].note}" if noise[k].note else "")
            for k in _PLACEHOLDER]


def _known(imu: _ChainImu) -> np.ndarray:
    """Which relative scale factors the data determine: the scale factor itself, or its ratio to one axis of imu0."""
    return np.asarray(imu.observable, bool) | np.isfinite(imu.rel_scale_std)


def _determined(imu: _ChainImu) -> np.ndarray:
    """Diagonal scale matrix: the scale factors relative to imu0's (:func:`_relative_scales`), 1 where the data
    determine neither the scale factor nor its ratio to imu0's."""
    return np.diag(np.where(_known(imu), imu.rel_scale, 1.0))


def _scale_text(imu: _ChainImu) -> str:
    known = _known(imu)
    return ", ".join((f"{'xyz'[a]} {imu.rel_scale[a]:.6f}" + (f" +- {imu.rel_scale_std[a]:.2g}"
                                                            if np.isfinite(imu.rel_scale_std[a]) else ""))
                     if known[a] else f"{'xyz'[a]} undetermined" for a in range(3))


def _chain_block(i: int, imu: _ChainImu, noise, topic: str, rate: float, model: str) -> list[str]:
    T = np.eye(4)
    T[:3, :3] = imu.R_b_i.T  # R_i_b: body (reference gyro) -> this IMU
    lines = [f"imu{i}:"]
    lines += _matrix("T_i_b", T, "  ")
    lines += _noise_lines(noise, "  ")
    lines += [f"  model: {model}",
              f"  rostopic: {_quoted(topic)}",
              f"  time_offset: {_yf(imu.time_offset)}",
              f"  update_rate: {_yf(rate)}"]
    return lines


def _check_yaml(text: str, path, topics) -> None:
    """Refuse to write a file that does not read back (a bug here, never the user's)."""
    import yaml
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise FormatError(f"{path}: generated YAML does not parse: {exc}") from None
    got = [data[f"imu{i}"]["rostopic"] for i in range(len(topics))] if "imu0" in data else [data["rostopic"]]
    if got != list(topics):
        raise FormatError(f"{path}: generated YAML reads back topics {got}, expected {list(topics)}")


def _prepare(cal, topics, update_rate, noise):
    import dataclasses

    chain = _chain_of(cal)
    n = len(chain.imus)
    rates = _rates(update_rate, n)
    if isinstance(cal, PairCalibration):
        identified, header = _identified(cal, rates)
        chain = dataclasses.replace(chain, identified=identified, noise_header=header)
    else:
        identified, header = _identified_array(cal, rates)
        chain = dataclasses.replace(chain, identified=identified, noise_header=header)
    return chain, _topics(topics, n), rates, _noises(noise, chain)


def write_kalibr_imu_configs(cal, folder, *, topics=None, update_rate=200.0, noise=None) -> tuple[Path, ...]:
    """Write one Kalibr IMU configuration per gyro, ``folder/imu0.yaml`` ... (``imu0`` = the reference gyro).

    These are the files ``kalibr_calibrate_imu_camera --imu imu0.yaml imu1.yaml ...`` reads with its
    ``ImuParameters``: top-level ``rostopic`` (a string), ``update_rate`` (Hz, > 0),
    ``accelerometer_noise_density``, ``accelerometer_random_walk``, ``gyroscope_noise_density`` and
    ``gyroscope_random_walk`` (all > 0). Kalibr estimates rotations, time offsets and intrinsics
    itself; fusion_gyrocal's estimates of them are in comments (and in :func:`write_kalibr_imu_chain`).
    Without ``noise`` the gyro figures are those a pair's calibration identified from its residual
    (:attr:`PairCalibration.noise_model`, with where they came from in comments); what nothing measured
    (the accelerometer figures, and every figure without a noise model) is a marked placeholder.

    Parameters
    ----------
    cal : PairCalibration or ArrayCalibration
    folder : str or Path
        Created when missing (its parent must exist).
    topics : sequence of str, optional
        ``rostopic`` of every IMU in gyro order with the reference first (default ``/imu0``, ``/imu1``, ...).
    update_rate : float or sequence of float
        IMU rates in Hz.
    noise : ImuNoise or sequence of (ImuNoise or None), optional
        Measured noise figures, written as given; None (for every IMU or one of them) writes the
        identified gyro figures where the calibration carries a noise model, placeholders elsewhere.

    Returns
    -------
    tuple of Path
    """
    chain, topics, rates, noises = _prepare(cal, topics, update_rate, noise)
    folder = Path(folder).expanduser()
    try:
        folder.mkdir(exist_ok=True)
    except OSError as exc:
        raise FormatError(f"{folder}: could not create the folder: {exc}") from None
    paths = []
    for i, imu in enumerate(chain.imus):
        path = folder / f"imu{i}.yaml"
        lines = [f"# {w}" for w in chain.warning]
        lines += [f"# Kalibr IMU configuration (kalibr_calibrate_imu_camera --imu ...) of imu{i} = gyro {imu.gyro + 1}, "
                  f"written by fusion_gyrocal from {chain.what}."]
        if i:
            rv = np.degrees(canonical_rotvec(log(imu.R_b_i)))
            lines.append(f"# fusion_gyrocal's estimate against imu0 (Kalibr estimates its own): R_b_i rotation vector "
                         f"[deg] {', '.join(f'{v:.4f}' for v in rv)}; time offset "
                         f"{imu.time_offset:+.6g} s ({imu.time_offset_source}).")
        lines.append(f"# Scale factors relative to imu0 (Kalibr estimates its own): {_scale_text(imu)}.")
        if _identified_used(noises[i:i + 1]):
            lines += list(chain.noise_header)
        if _any_placeholder(noises[i:i + 1]):
            lines.append(_PLACEHOLDER_HOWTO)
        lines += [f"rostopic: {_quoted(topics[i])}", f"update_rate: {_yf(rates[i])}  # [Hz]"]
        lines += _noise_lines(noises[i], "")
        text = "\n".join(lines) + "\n"
        _check_yaml(text, path, [topics[i]])
        paths.append(path)
        atomic_write(path, text)
    return tuple(paths)


def write_kalibr_imu_chain(cal, path, *, topics=None, update_rate=200.0, noise=None) -> Path:
    """Write the IMU chain in Kalibr's multi-IMU result layout (``imu0``, ``imu1``, ...), atomically.

    This is the layout Kalibr writes after a multi-IMU calibration and that tools reading Kalibr
    results take (OpenVINS, maplab's exporter); Kalibr itself reads :func:`write_kalibr_imu_configs`.
    Per IMU: ``T_i_b`` (4x4, body = the reference gyro, translation NOT estimated: zeros and
    ``translation_estimated: false``), the four noise figures (``noise``, else the identified gyro
    figures, else placeholders), ``model: scale-misalignment``, ``rostopic`` (quoted), ``time_offset``, ``update_rate``,
    ``gyroscopes: {M, A, C_gyro_i}`` and ``accelerometers: {M}``. With Kalibr's gyro model
    ``omega = M C_gyro_i C_i_b omega_b + A a + b``, ``M = diag(scale)`` (Eq. 1) for the scale factors
    the data determine (1 elsewhere, named in a comment), ``C_gyro_i = I``, ``A = 0``; the
    accelerometer ``M = I`` is not estimated. Parameters as :func:`write_kalibr_imu_configs`.
    """
    chain, topics, rates, noises = _prepare(cal, topics, update_rate, noise)
    lines = _header(chain, "Kalibr IMU chain (result layout)", topics, noises)
    for i, imu in enumerate(chain.imus):
        lines.append("")
        lines += _chain_block(i, imu, noises[i], topics[i], rates[i], "scale-misalignment")
        lines.append("  gyroscopes:")
        lines += _matrix("M", _determined(imu), "    ")
        lines += _matrix("A", np.zeros((3, 3)), "    ")
        lines += _matrix("C_gyro_i", np.eye(3), "    ")
        lines.append("  accelerometers:  # not estimated (gyro-only calibration)")
        lines += _matrix("M", np.eye(3), "    ")
        lines.append("  translation_estimated: false")
    text = "\n".join(lines) + "\n"
    _check_yaml(text, path, topics)
    return atomic_write(path, text)


def write_openvins_imu_chain(cal, path, *, topics=None, update_rate=200.0, noise=None) -> Path:
    """Write an OpenVINS ``kalibr_imu_chain.yaml`` for every gyro (``imu0`` = the reference), atomically.

    The first line is the ``%YAML:1.0`` directive OpenCV's ``cv::FileStorage`` (OpenVINS'
    ``YamlParser``) needs; the rest is plain YAML. Keys per IMU follow OpenVINS'
    ``config/*/kalibr_imu_chain.yaml``: ``T_i_b``, the four noise figures (``noise``, else the
    identified gyro figures, else placeholders), ``rostopic`` (quoted), ``time_offset``, ``update_rate``, ``model: kalibr`` (OpenVINS
    exits on ``calibrated`` when it is asked to refine the intrinsics), ``Tw``, ``R_IMUtoGYRO``,
    ``Ta``, ``R_IMUtoACC``, ``Tg``. With OpenVINS' model ``omega_m = Tw R_IMUtoGYRO omega_I + Tg a + b``:
    ``Tw = diag(scale)`` for the scale factors the data determine and 1 where they do not (a comment
    names them), ``R_IMUtoGYRO = I``, ``Tg = 0``, ``Ta = R_IMUtoACC = I`` (accelerometer not
    estimated). OpenVINS reads ``imu0`` only; the others document the rest of the array in the same
    terms. Parameters as :func:`write_kalibr_imu_configs`.
    """
    chain, topics, rates, noises = _prepare(cal, topics, update_rate, noise)
    lines = ["%YAML:1.0"] + _header(chain, "OpenVINS kalibr_imu_chain", topics, noises)
    for i, imu in enumerate(chain.imus):
        lines.append("")
        lines += _chain_block(i, imu, noises[i], topics[i], rates[i], "kalibr")
        lines += _matrix("Tw", _determined(imu), "  ")
        lines += _matrix("R_IMUtoGYRO", np.eye(3), "  ")
        lines += _matrix("Ta", np.eye(3), "  ")
        lines += _matrix("R_IMUtoACC", np.eye(3), "  ")
        lines += _matrix("Tg", np.zeros((3, 3)), "  ")
        lines.append("  translation_estimated: false")
    text = "\n".join(lines) + "\n"
    _check_yaml(text.split("\n", 1)[1], path, topics)
    return atomic_write(path, text)
