"""File writers: calibration results (JSON, Kalibr / OpenVINS YAML) and gyro streams (CSV, npz).

Every writer is atomic: the bytes go to a temporary file in the destination folder, are flushed
and fsync'ed, and only then renamed over the destination with :func:`os.replace`. A crash or an
exception mid-write leaves the previous file untouched and no half-written file behind.

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
* scale factors are known only up to one global factor (Theorem 2): the files carry the values in
  the calibration's gauge, named in a comment; scale factors the data do not determine at all
  (axis-parallel gyros, Lemmas 2-3) are written as 1 and named in a comment;
* noise figures: figures passed as :class:`ImuNoise` are written as given. Otherwise, when a pair's
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

import io
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.array import ARRAY_KIND, ArrayCalibration
from ..core.model import PairCalibration
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


def atomic_write(path, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` atomically (temp file in the same folder, fsync, ``os.replace``).

    The one mechanism for every file the library writes, text (``str``, UTF-8) and binary (``bytes``,
    e.g. a PNG rendered in memory) alike: a reader never sees a half-written file. The file keeps the
    permissions of the file it replaces (new files get ``0o666 & ~umask``).

    Raises
    ------
    FormatError
        When the folder does not exist or the write fails (the old file is left as it was); the message
        names the file and the cause (``"cal.json: could not write: Permission denied"``).
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
        raise FormatError(f"{path}: could not write: {os_reason(exc)}") from exc
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
            raise FormatError(f"{path}: could not write: {os_reason(exc)}") from exc
        raise
    fsync_dir(folder)
    return path


# ----------------------------------------------------------------------------- JSON
def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_json(cal, path) -> Path:
    """Write the full calibration (``cal.to_dict()``, with ``format_version``) as JSON, atomically.

    ``cal`` is a :class:`PairCalibration` or an :class:`~fusion_gyrocal.core.array.ArrayCalibration`
    (every gyro; its dict carries ``kind: "array_calibration"``). Non-finite numbers are written as
    the strings ``"NaN"``, ``"Infinity"``, ``"-Infinity"``; the file is strict JSON (no NaN / Infinity
    literals).
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
    if not isinstance(d, dict):
        raise FormatError(f"{p.name}: expected a JSON object, got {type(d).__name__}")
    try:
        if d.get("kind") == ARRAY_KIND:
            return ArrayCalibration.from_dict(d)
        return PairCalibration.from_dict(d)
    except FormatError as exc:
        raise FormatError(f"{p.name}: {exc}") from None
    except (TypeError, ValueError, KeyError) as exc:
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


def _chain_of(cal) -> _Chain:
    """The :class:`_Chain` of a :class:`PairCalibration` or an :class:`ArrayCalibration` (finite values checked)."""
    if isinstance(cal, PairCalibration):
        for nm in ("R_1_2", "scale_1", "scale_2"):
            _finite(f"cal.{nm}", getattr(cal, nm))
        if not np.isfinite(cal.time_offset_s):
            raise FormatError(f"cal.time_offset_s: expected a finite time offset, got {cal.time_offset_s}")
        rot_std = np.degrees(cal.rotation_std_rad)
        src = "estimated" if cal.time_offset_std_s > 0 else "given or sample-aligned"
        imus = (_ChainImu(0, np.eye(3), cal.scale_1, cal.scale_observable[0], 0.0, "reference", np.zeros(3)),
                _ChainImu(1, cal.R_1_2, cal.scale_2, cal.scale_observable[1], float(cal.time_offset_s), src, rot_std))
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
        imus = tuple(_ChainImu(k, cal.R_ref_k[k], cal.scale[k], cal.scale_observable[k],
                               float(cal.time_offset_s[k] - cal.time_offset_s[ref]), cal.time_offset_source[k],
                               rot_std[k]) for k in order)
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
    unobs = [f"imu{i} {'xyz'[a]}" for i, imu in enumerate(chain.imus) for a in range(3) if not imu.observable[a]]
    if unobs:
        lines.append(f"# Scale factors the data do not determine are written as 1 (not estimated): {', '.join(unobs)}.")
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


def _determined(imu: _ChainImu) -> np.ndarray:
    """Diagonal scale matrix: the scale factors the data determine, 1 where they do not."""
    return np.diag(np.where(imu.observable, imu.scale, 1.0))


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
        lines.append(f"# Scale factors (relative, gauge {chain.gauge}): "
                     + ", ".join(f"{'xyz'[a]} {imu.scale[a]:.6f}" if imu.observable[a] else f"{'xyz'[a]} undetermined"
                                 for a in range(3)) + ".")
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
