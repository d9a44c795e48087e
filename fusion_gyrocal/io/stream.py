"""The stream every reader returns, :class:`ImuStream`, and what every reader shares.

:class:`ImuStream` holds one gyro in the library's units (seconds, rad/s, float64). Beside it: the
check of an input path (:func:`input_path`: only regular files are opened, a FIFO would block), the
factor of a rate unit to rad/s (:func:`rate_factor`, from the table in :mod:`fusion_gyrocal.units`)
and integer timestamps to float seconds without losing digits (:func:`int_time_to_seconds`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.moments import finite_rows
from ..errors import FormatError, InputError, OptionError
from ..pipeline.streams import (_checked_timestamps, _known, _trusted, median_step, remember_timestamps,
                                to_rad_per_s)
from ..units import RATE_UNITS


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
        ``t`` and ``omega`` are copies of what was given, except float64 arrays that are already
        read-only and own their data (what a reader hands over, :func:`hand_over`; another stream's
        arrays): those are kept as they are. What the check of ``t`` found (its diagnosis, its median
        step) is kept for the alignment (:func:`~fusion_gyrocal.pipeline.streams.remember_timestamps`).
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
    notes : tuple of str
        What the reader did that the numbers alone do not show (trailing junk rows dropped, the
        time source of an Xsens export, a stated rate overridden). Empty when there is nothing to say.

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
    notes: tuple = ()

    def __post_init__(self):
        name = self.name
        omega = self.omega if _trusted(self.omega) else np.array(self.omega, dtype=np.float64)
        if omega.ndim != 2 or omega.shape[1] != 3:
            raise InputError(f"{name}: expected angular rates of shape (N, 3), got {omega.shape}")
        t, known = self.t, _known(self.t)
        if known is not None and t.shape[0] == omega.shape[0]:   # a stream's (dataclasses.replace): checked then
            quality, median = known.quality, known.median_step
        else:
            t, step, quality = _checked_timestamps(f"{name}.t", t, length=omega.shape[0])
            if not _trusted(t):
                t = np.array(t, dtype=np.float64)
            median = median_step(step, quality)
        valid = finite_rows(omega)
        if self.valid is not None:
            given = np.asarray(self.valid)
            if given.shape != valid.shape:
                raise InputError(f"{name}: expected a valid mask of shape {valid.shape}, got {given.shape}")
            valid &= given.astype(bool)
        if self.unit_in not in RATE_UNITS:
            raise InputError(f"{name}: expected unit_in in {RATE_UNITS}, got {self.unit_in!r}")
        rate = float(1.0 / median) if self.rate_hz is None else float(self.rate_hz)
        if not (np.isfinite(rate) and rate > 0):
            raise InputError(f"{name}: expected a positive finite rate_hz, got {self.rate_hz!r}")
        for a in (t, omega, valid):
            a.flags.writeable = False
        remember_timestamps(t, median, quality)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "omega", omega)
        object.__setattr__(self, "valid", valid)
        object.__setattr__(self, "rate_hz", rate)
        object.__setattr__(self, "notes", tuple(str(n) for n in self.notes))

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


# ----------------------------------------------------------------------------- what every reader shares
def hand_over(arr: np.ndarray) -> np.ndarray:
    """``arr`` (an array the reader made and keeps no reference to) made read-only: :class:`ImuStream` then keeps
    it instead of copying it. C-contiguous float64 first (a copy only where it is not)."""
    out = np.ascontiguousarray(arr, dtype=np.float64)
    if out.base is not None:
        out = out.copy()
    out.flags.writeable = False
    return out


def input_path(path, what: str = "file", *, folder: bool = False) -> Path:
    """``path`` as a Path that exists and is a regular file (or a folder when ``folder``).

    FIFOs, sockets and devices are refused before anything opens them (reading a FIFO blocks).
    """
    p = Path(path).expanduser()
    if not p.exists():
        raise FormatError(f"{p}: no such {what}")
    if not (p.is_file() or (folder and p.is_dir())):
        kind = "a folder" if p.is_dir() else "a FIFO" if p.is_fifo() else "a device" if p.is_char_device() or \
            p.is_block_device() else "a socket" if p.is_socket() else "not a regular file"
        raise FormatError(f"{p}: expected a regular {what.replace('file or folder', 'file or a folder')}, got {kind}")
    if not os.access(p, os.R_OK | (os.X_OK if p.is_dir() else 0)):
        raise FormatError(f"{p}: expected a {what} we may read, got one "
                          "without read permission (could not read: permission denied)")
    return p


def rate_factor(unit: str, sensitivity, where: str) -> float:
    """Factor turning ``unit`` into rad/s (:func:`fusion_gyrocal.pipeline.streams.to_rad_per_s`);
    ``sensitivity`` is LSB per deg/s for raw counts."""
    try:
        return float(to_rad_per_s(np.ones(1), unit, sensitivity)[0])
    except OptionError as exc:
        raise OptionError(f"{where}: {exc}") from None


def int_time_to_seconds(ticks: np.ndarray, decimals: int) -> np.ndarray:
    """Integer counts of ``10**-decimals`` s to float seconds without losing digits."""
    ticks = np.asarray(ticks, dtype=np.int64)
    if decimals == 0:
        return ticks.astype(np.float64)
    scale = 10 ** decimals
    whole, frac = np.divmod(ticks, scale)
    return whole.astype(np.float64) + frac.astype(np.float64) / scale
