"""Header profiles: CSV layouts of common loggers, recognised from their header so no flag is needed.

Each :class:`CsvProfile` names the time column and its unit (when the header names none), the x, y, z rate columns
(rad/s in every layout here; a unit the header names, or ``unit=``, still wins), and where a log interleaves several
IMUs, the instance column (rows are then kept for one instance, ``imu=``). The layouts, as their writers
document or emit them:

* ``uzh-fpv``: the UZH-FPV drone racing dataset's ``imu.txt``, ``# id timestamp ang_vel_x ang_vel_y ang_vel_z
  lin_acc_x lin_acc_y lin_acc_z`` (whitespace, seconds, rad/s);
* ``kalibr``: Kalibr's ``bagcreater`` IMU CSV, ``timestamp,omega_x,omega_y,omega_z,alpha_x,alpha_y,alpha_z``
  (integer nanoseconds, rad/s);
* ``sensor-logger``: the Sensor Logger app's ``Gyroscope.csv``, ``time,seconds_elapsed,z,y,x`` (nanoseconds since
  the epoch, rad/s, the axes in the order z, y, x);
* ``mars-logger``: MARS logger's ``gyro_accel.csv``, ``Timestamp[nanosec],gx[rad/s],gy[rad/s],gz[rad/s],...``;
* ``px4-ulog2csv``: PX4 ``ulog2csv`` exports: ``sensor_combined_<i>.csv`` (``timestamp``, ``gyro_rad[0..2]``) and
  ``sensor_gyro_<i>.csv`` (``timestamp_sample``, ``x``, ``y``, ``z``; microseconds, rad/s);
* ``vectornav``: VectorNav CSV exports, ``TimeStartup`` (ns) with ``UncompGyroX..Z`` (factory-calibrated, no
  on-board bias removal: preferred) or ``GyroX..Z`` (rad/s);
* ``ardupilot``: ArduPilot ``IMU`` messages as CSV (``mavlogdump.py --format csv --types IMU``): ``TimeUS``
  (microseconds since boot), instance ``I``, ``GyrX..Z`` (rad/s).

:func:`match_profile` returns the profile a header matches (None: the generic column rules of
:mod:`fusion_gyrocal.io.csv` apply).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..errors import FormatError, InputError


def _key(name: str) -> str:
    """A header field for matching: lower case, stripped of quotes, '#', spaces and a trailing ``[unit]``
    (array indices such as ``gyro_rad[0]`` are kept)."""
    n = name.strip().strip('"').strip("'").lstrip("#").strip().lower()
    n = re.sub(r"\s*\[(?!\d+\])[^\]]*\]\s*$", "", n)
    return n.replace(" ", "_")


@dataclass(frozen=True)
class CsvProfile:
    """One logger's CSV layout (columns by their matching key, see :func:`_key`)."""

    name: str
    requires: tuple          # keys the header must hold
    time: tuple              # time column keys, first present wins
    gyro: tuple              # (x, y, z) key triples, first complete one wins
    time_unit: str           # when the header names none
    instance: str | None = None
    note: str = ""

    def matches(self, keys: list[str]) -> bool:
        return all(k in keys for k in self.requires) and any(all(c in keys for c in g) for g in self.gyro) \
            and any(t in keys for t in self.time)

    def columns(self, keys: list[str]) -> tuple[int, list[int], int | None]:
        """``(time index, [x, y, z] indices, instance index or None)`` in a header with ``keys``."""
        k_t = next(keys.index(t) for t in self.time if t in keys)
        triple = next(g for g in self.gyro if all(c in keys for c in g))
        k_i = keys.index(self.instance) if self.instance in keys else None
        return k_t, [keys.index(c) for c in triple], k_i


PROFILES = (
    CsvProfile("uzh-fpv", ("id", "timestamp"), ("timestamp",), (("ang_vel_x", "ang_vel_y", "ang_vel_z"),), "s"),
    CsvProfile("kalibr", ("timestamp", "alpha_x"), ("timestamp",), (("omega_x", "omega_y", "omega_z"),), "ns"),
    CsvProfile("sensor-logger", ("seconds_elapsed",), ("time",), (("x", "y", "z"),), "ns"),
    CsvProfile("mars-logger", ("unix_time",), ("timestamp",), (("gx", "gy", "gz"),), "ns"),
    CsvProfile("px4-ulog2csv", ("gyro_integral_dt",), ("timestamp",), (("gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]"),),
               "us"),
    CsvProfile("px4-ulog2csv", ("timestamp_sample", "device_id"), ("timestamp_sample",), (("x", "y", "z"),), "us"),
    CsvProfile("vectornav", (), ("timestartup",), (("uncompgyrox", "uncompgyroy", "uncompgyroz"),
                                                   ("gyrox", "gyroy", "gyroz")), "ns",
               note="GyroX..Z of a VectorNav export have the on-board filter's bias removed; UncompGyro is preferred"),
    CsvProfile("ardupilot", (), ("timeus",), (("gyrx", "gyry", "gyrz"),), "us", instance="i"),
)
"""Every profile, tried in this order."""


def match_profile(header) -> CsvProfile | None:
    """The profile whose columns ``header`` (the header's fields) holds, else None."""
    keys = [_key(h) for h in header]
    return next((p for p in PROFILES if p.matches(keys)), None)


def header_keys(header) -> list[str]:
    """The matching keys of a header's fields (:func:`match_profile`'s spelling)."""
    return [_key(h) for h in header]


def select_instance(instances: np.ndarray, imu, fname: str, column: str) -> np.ndarray:
    """Rows of one IMU instance: ``instances == imu``; with ``imu`` None, every row when one instance is logged.

    Raises
    ------
    InputError
        Several instances and ``imu`` None, or ``imu`` not among them (the message lists them).
    """
    finite = instances[np.isfinite(instances)]
    present = sorted(int(v) for v in np.unique(finite))
    if imu is None:
        if len(present) > 1:
            raise InputError(f"{fname}: interleaves IMU instances {present} (column {column!r}); pass imu= to "
                             "choose one")
        return np.ones(instances.shape, dtype=bool)
    if int(imu) not in present:
        raise InputError(f"{fname}: expected IMU instance {imu} in column {column!r}, got instances {present}")
    keep = instances == int(imu)
    if keep.sum() < 2:
        raise FormatError(f"{fname}: IMU instance {imu} has {int(keep.sum())} row(s), expected at least 2")
    return keep
