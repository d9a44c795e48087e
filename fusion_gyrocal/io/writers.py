"""File writers: calibration results (JSON, Kalibr / OpenVINS YAML) and gyro streams (CSV, npz).

Every writer is atomic: the bytes go to a temporary file in the destination folder, are flushed
and fsync'ed, and only then renamed over the destination with :func:`os.replace`. A crash or an
exception mid-write leaves the previous file untouched and no half-written file behind.

Frame and time conventions of the YAML exports (``ARCHITECTURE.md``)
--------------------------------------------------------------------
* gyro 1 is the body / reference frame ``b``: ``imu0`` has ``T_i_b = I``;
* gyro 2 is ``imu1`` with ``T_i_b = [R_2_1 | 0]``, ``R_2_1 = R_1_2^T`` mapping body (gyro 1)
  vectors into gyro 2's frame. The translation is NOT estimated (gyro-only calibration): it is
  written as zeros and flagged by a comment and ``translation_estimated: false``;
* ``time_offset`` of ``imu1`` is :attr:`PairCalibration.time_offset_s`, the seconds ADDED to gyro
  2's timestamps to put them on gyro 1's clock. Kalibr uses the same sign (it evaluates imu N at
  ``t_N + time_offset`` on the reference clock), so the value is written unchanged;
* the measurement model ``omega_i_meas = S_i R_i_b omega_b + b_i`` (Eq. 1) is Kalibr's
  ``scale-misalignment`` gyro model ``omega = M C_gyro_i C_i_b omega_b + b`` with ``M = S_i``
  (diagonal: no misalignment is estimated), ``C_gyro_i = I`` and ``A = 0`` (no g-sensitivity), and
  OpenVINS' ``omega_m = Tw R_IMUtoGYRO omega_I + Tg a + b`` with ``Tw = S_i``,
  ``R_IMUtoGYRO = I``, ``Tg = 0``;
* scale factors are known only up to one global factor (Theorem 2): the files carry the values in
  the calibration's gauge, named in a comment.
"""

from __future__ import annotations

import io
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from ..core.model import PairCalibration
from .readers import ImuStream

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
def _umask() -> int:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    return 0o022


def _fsync_dir(d: Path) -> None:
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


def atomic_write(path, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` atomically (temp file in the same folder, fsync, ``os.replace``).

    The file keeps the permissions of the file it replaces (new files get ``0o666 & ~umask``).

    Raises
    ------
    FormatError
        When the folder does not exist or the write fails (the old file is left as it was).
    """
    path = Path(path).expanduser()
    if isinstance(data, str):
        data = data.encode("utf-8")
    folder = path.parent
    if not folder.is_dir():
        raise FormatError(f"{path}: folder {folder} does not exist")
    try:
        mode = (os.stat(path).st_mode & 0o7777) if path.exists() else (0o666 & ~_umask())
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    except OSError as exc:
        raise FormatError(f"{path}: could not write: {exc}") from exc
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise FormatError(f"{path}: could not write: {exc}") from exc
        raise
    _fsync_dir(folder)
    return path


# ----------------------------------------------------------------------------- JSON
def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_json(cal: PairCalibration, path) -> Path:
    """Write the full calibration (``cal.to_dict()``, with ``format_version``) as JSON, atomically.

    Non-finite numbers are written as the strings ``"NaN"``, ``"Infinity"``, ``"-Infinity"``
    (``PairCalibration.to_dict``); the file is strict JSON (no NaN / Infinity literals).
    """
    if not isinstance(cal, PairCalibration):
        raise InputError(f"cal: expected a PairCalibration, got {type(cal).__name__}")
    text = json.dumps(cal.to_dict(), indent=2, allow_nan=False, default=_json_default) + "\n"
    return atomic_write(path, text)


def read_json(path) -> PairCalibration:
    """Read a calibration written by :func:`write_json`.

    Raises
    ------
    FormatError
        When the file is not JSON, has another ``format_version`` or lacks required fields.
    """
    p = Path(path).expanduser()
    try:
        with open(p, "r", encoding="utf-8") as f:
            d = json.load(f)
    except FileNotFoundError:
        raise FormatError(f"{p}: no such file") from None
    except json.JSONDecodeError as exc:
        raise FormatError(f"{p.name}: expected JSON, got a syntax error at line {exc.lineno} column {exc.colno}: "
                          f"{exc.msg}") from None
    if not isinstance(d, dict):
        raise FormatError(f"{p.name}: expected a JSON object, got {type(d).__name__}")
    try:
        return PairCalibration.from_dict(d)
    except FormatError as exc:
        raise FormatError(f"{p.name}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise FormatError(f"{p.name}: expected a calibration written by write_json, {exc}") from None


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


def _pair(value, name: str, conv) -> tuple:
    if isinstance(value, (tuple, list)):
        if len(value) != 2:
            raise InputError(f"{name}: expected one value or a pair (imu0, imu1), got {len(value)} values")
        return conv(value[0]), conv(value[1])
    v = conv(value)
    return v, v


def _noise_for(cal: PairCalibration, noise, rates) -> tuple[list[dict], list[list[str]]]:
    """Per-IMU noise dicts and, per IMU, the names of fields that are placeholders."""
    out, flags = [], []
    given = _pair(noise, "noise", lambda v: v) if noise is not None else (None, None)
    for i in range(2):
        g = given[i]
        if g is not None:
            if not isinstance(g, ImuNoise):
                raise InputError(f"noise: expected ImuNoise or a pair of them, got {type(g).__name__}")
            out.append({k: getattr(g, k) for k in _PLACEHOLDER})
            flags.append([])
            continue
        d = dict(_PLACEHOLDER)
        placeholders = [k for k in _PLACEHOLDER if k != "gyroscope_noise_density"]
        sigma = float(cal.noise_std[i])
        if np.isfinite(sigma) and sigma > 0:
            d["gyroscope_noise_density"] = sigma / np.sqrt(rates[i])  # discrete std = density * sqrt(rate)
        else:
            placeholders.insert(0, "gyroscope_noise_density")
        out.append(d)
        flags.append(placeholders)
    return out, flags


def _check_cal(cal: PairCalibration) -> None:
    if not isinstance(cal, PairCalibration):
        raise InputError(f"cal: expected a PairCalibration, got {type(cal).__name__}")
    for nm in ("R_1_2", "scale_1", "scale_2"):
        v = getattr(cal, nm)
        if not np.isfinite(v).all():
            raise FormatError(f"cal.{nm}: Kalibr/OpenVINS files need finite values, got {v.tolist()}")
    if not np.isfinite(cal.time_offset_s):
        raise FormatError(f"cal.time_offset_s: expected a finite time offset, got {cal.time_offset_s}")


def _header_lines(cal: PairCalibration, what: str, topics, flags) -> list[str]:
    axes = "xyz"
    unobs = [f"scale_{g + 1}_{axes[a]}" for g in range(2) for a in range(3) if not cal.scale_observable[g, a]]
    lines = [
        f"# {what} written by fusion_gyrocal from a gyro-pair calibration ({cal.method}, {cal.n_samples} samples).",
        f"# imu0 = gyro 1 ({topics[0]}), the body/reference frame: T_i_b = identity.",
        f"# imu1 = gyro 2 ({topics[1]}): T_i_b = [R_2_1 | t], R_2_1 = R_1_2^T maps body (gyro 1) vectors into imu1.",
        "# TRANSLATION IS NOT ESTIMATED (gyro-only calibration): t = 0 is a placeholder (translation_estimated: false).",
        "# time_offset [s] is ADDED to this IMU's timestamps to put them on imu0's clock.",
        f"# Scale factors are relative (Theorem 2): gauge = {cal.gauge}; configuration = {cal.configuration}.",
    ]
    if unobs:
        lines.append(f"# Not determined by the data (gauge/prior values only): {', '.join(unobs)}.")
    rot_std_deg = np.degrees(cal.rotation_std_rad)
    if np.isfinite(rot_std_deg).all():
        lines.append("# 1-sigma rotation uncertainty (deg, gyro-1 axes): "
                     + ", ".join(f"{v:.3g}" for v in rot_std_deg) + ".")
    for i, f in enumerate(flags):
        if f:
            lines.append(f"# imu{i}: {', '.join(f)} = PLACEHOLDER values (not estimated; replace with Allan-variance figures).")
    return lines


def _imu_block(i: int, T_i_b: np.ndarray, noise: dict, flags: list[str], topic: str, rate: float,
               time_offset: float, model: str) -> list[str]:
    lines = [f"imu{i}:"]
    lines += _matrix("T_i_b", T_i_b, "  ")
    units = {"accelerometer_noise_density": "m/s^2/sqrt(Hz)", "accelerometer_random_walk": "m/s^3/sqrt(Hz)",
             "gyroscope_noise_density": "rad/s/sqrt(Hz)", "gyroscope_random_walk": "rad/s^2/sqrt(Hz)"}
    for k in ("accelerometer_noise_density", "accelerometer_random_walk",
              "gyroscope_noise_density", "gyroscope_random_walk"):
        note = "  # PLACEHOLDER, not estimated" if k in flags else ""
        lines.append(f"  {k}: {_yf(noise[k])}  # [{units[k]}]{note}")
    lines += [f"  model: {model}",
              f"  rostopic: {topic}",
              f"  time_offset: {_yf(time_offset)}",
              f"  update_rate: {_yf(rate)}"]
    return lines


def _common(cal, topics, update_rate, noise):
    _check_cal(cal)
    topics = tuple(topics)
    if len(topics) != 2 or not all(isinstance(t, str) and t for t in topics):
        raise InputError(f"topics: expected two topic names (imu0, imu1), got {topics!r}")

    def rate_conv(v):
        v = float(v)
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"update_rate: expected a positive rate in Hz, got {v!r}")
        return v

    rates = _pair(update_rate, "update_rate", rate_conv)
    noises, flags = _noise_for(cal, noise, rates)
    T0 = np.eye(4)
    T1 = np.eye(4)
    T1[:3, :3] = cal.R_1_2.T  # R_2_1: body (gyro 1) -> imu1 (gyro 2)
    return topics, rates, noises, flags, (T0, T1), (0.0, float(cal.time_offset_s))


def _validate_yaml(text: str, path) -> None:
    import yaml
    try:
        yaml.safe_load(text)
    except yaml.YAMLError as exc:  # a bug here, never the user's: refuse to write a broken file
        raise FormatError(f"{path}: generated YAML does not parse: {exc}") from None


def write_kalibr_imu_yaml(cal: PairCalibration, path, *, topics=("/imu0", "/imu1"), update_rate=200.0,
                          noise=None) -> Path:
    """Write a Kalibr multi-IMU ``imu.yaml`` (``imu0`` = gyro 1, ``imu1`` = gyro 2), atomically.

    The keys per IMU are those of Kalibr's ``ImuParameters`` / ``IccScaledMisalignedImu`` results:
    ``T_i_b`` (4x4), ``accelerometer_noise_density``, ``accelerometer_random_walk``,
    ``gyroscope_noise_density``, ``gyroscope_random_walk``, ``model: scale-misalignment``,
    ``rostopic``, ``time_offset``, ``update_rate`` and the intrinsics ``gyroscopes: {M, A, C_gyro_i}``
    and ``accelerometers: {M}``. With Kalibr's gyro model ``omega = M C_gyro_i C_i_b omega_b + A a + b``,
    ``M = diag(scale_i)`` (Eq. 1), ``C_gyro_i = I``, ``A = 0``; the accelerometer ``M = I`` is not
    estimated. See the module docstring for frames, sign of ``time_offset`` and the gauge.

    Parameters
    ----------
    cal : PairCalibration
    path : str or Path
    topics : (str, str)
        ``rostopic`` of imu0 and imu1.
    update_rate : float or (float, float)
        IMU rates in Hz. Also used to turn ``cal.noise_std`` (per sample) into a noise density
        (``std / sqrt(rate)``) when ``noise`` is not given, so pass the real sensor rates.
    noise : ImuNoise or (ImuNoise, ImuNoise), optional
        Noise figures. When omitted, the gyro noise density comes from ``cal.noise_std`` and the
        other three figures are placeholders, flagged as such in the file.

    Returns
    -------
    Path
    """
    topics, rates, noises, flags, Ts, offsets = _common(cal, topics, update_rate, noise)
    lines = _header_lines(cal, "Kalibr IMU configuration", topics, flags)
    for i, scale in enumerate((cal.scale_1, cal.scale_2)):
        lines.append("")
        lines += _imu_block(i, Ts[i], noises[i], flags[i], topics[i], rates[i], offsets[i], "scale-misalignment")
        lines.append("  gyroscopes:")
        lines += _matrix("M", np.diag(scale), "    ")
        lines += _matrix("A", np.zeros((3, 3)), "    ")
        lines += _matrix("C_gyro_i", np.eye(3), "    ")
        lines.append("  accelerometers:  # not estimated (gyro-only calibration)")
        lines += _matrix("M", np.eye(3), "    ")
        lines.append("  translation_estimated: false")
    text = "\n".join(lines) + "\n"
    _validate_yaml(text, path)
    return atomic_write(path, text)


def write_openvins_imu_chain(cal: PairCalibration, path, *, topics=("/imu0", "/imu1"), update_rate=200.0,
                             noise=None) -> Path:
    """Write an OpenVINS ``kalibr_imu_chain.yaml`` (``imu0`` = gyro 1, ``imu1`` = gyro 2), atomically.

    The first line is the ``%YAML:1.0`` directive OpenCV's ``cv::FileStorage`` needs; the rest is
    plain YAML (PyYAML reads it once that line is dropped). Keys per IMU follow OpenVINS'
    ``config/*/kalibr_imu_chain.yaml`` and ``VioManagerOptions::print_and_load_state``: ``T_i_b``,
    the four noise figures, ``rostopic``, ``time_offset``, ``update_rate``, ``model: calibrated``
    (the intrinsics are fixed, not refined online), ``Tw``, ``R_IMUtoGYRO``, ``Ta``, ``R_IMUtoACC``,
    ``Tg``. With OpenVINS' model ``omega_m = Tw R_IMUtoGYRO omega_I + Tg a + b``:
    ``Tw = diag(scale_i)``, ``R_IMUtoGYRO = I``, ``Tg = 0``; ``Ta = R_IMUtoACC = I`` (accelerometer not
    estimated). OpenVINS itself reads only ``imu0``; ``imu1`` documents gyro 2 in the same terms.

    Parameters are those of :func:`write_kalibr_imu_yaml`.
    """
    topics, rates, noises, flags, Ts, offsets = _common(cal, topics, update_rate, noise)
    lines = ["%YAML:1.0"] + _header_lines(cal, "OpenVINS kalibr_imu_chain", topics, flags)
    for i, scale in enumerate((cal.scale_1, cal.scale_2)):
        lines.append("")
        lines += _imu_block(i, Ts[i], noises[i], flags[i], topics[i], rates[i], offsets[i], "calibrated")
        lines += _matrix("Tw", np.diag(scale), "  ")
        lines += _matrix("R_IMUtoGYRO", np.eye(3), "  ")
        lines += _matrix("Ta", np.eye(3), "  ")
        lines += _matrix("R_IMUtoACC", np.eye(3), "  ")
        lines += _matrix("Tg", np.zeros((3, 3)), "  ")
        lines.append("  translation_estimated: false")
    text = "\n".join(lines) + "\n"
    _validate_yaml(text.split("\n", 1)[1], path)
    return atomic_write(path, text)
