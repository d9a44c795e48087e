"""PX4 ULog (``.ulg``) flight logs: every gyro instance, read through ``pyulog``.

A ULog file holds one data set per logged uORB topic and instance (``multi_id``). Gyro rates appear in:

* ``sensor_gyro`` (one instance per physical gyro, ``multi_id`` 0, 1, 2, ...): fields ``x``, ``y``, ``z``
  in rad/s, the sensor's own sample time in ``timestamp_sample`` (us), the publication time in ``timestamp``;
* ``sensor_combined``: the primary gyro after PX4's voting, ``gyro_rad[0..2]`` in rad/s at ``timestamp`` (us).

Each gyro is named ``"<topic>/<instance>"`` (``"sensor_gyro/1"``, ``"sensor_combined/0"``). PX4's default logging
profile writes these topics at reduced rates; a stream logged below :data:`MIN_CALIBRATION_RATE_HZ` carries a note
(and a :class:`UserWarning`) saying so, since the motion a calibration needs is then aliased. ``pyulog`` is imported
on first use (extra ``[ros]``: ``pip install "fusion_gyrocal[ros]"``).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from .stream import ImuStream, input_path, int_time_to_seconds

#: Topics holding gyro rates, and their x, y, z fields (rad/s), in order of preference.
GYRO_TOPICS = {"sensor_gyro": ("x", "y", "z"),
               "sensor_combined": ("gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]")}

#: Below this logging rate a ULog gyro stream is flagged: hand-held or vehicle motion has content up to
#: 10-20 Hz, which such a rate aliases (PX4's default profile logs ``sensor_combined`` near 100 Hz and
#: ``sensor_gyro`` only in its high-rate profiles).
MIN_CALIBRATION_RATE_HZ = 50.0


def _load(path: Path):
    """``pyulog.ULog`` of the gyro topics of ``path``; a FormatError when the file is not a readable ULog."""
    from ..extras import require

    ULog = require("pyulog", "ros", "reading PX4 ULog files").ULog
    try:
        return ULog(str(path), message_name_filter_list=list(GYRO_TOPICS))
    except Exception as exc:   # pyulog raises ULogException, struct.error, ValueError, IndexError...
        raise FormatError(f"{path.name}: could not read the ULog file: {' '.join(str(exc).split())[:200]}") from None


def _gyro_sets(ulog) -> dict[str, object]:
    """``{"<topic>/<instance>": data set}`` of every gyro data set with samples, sorted by name."""
    sets = {}
    for d in ulog.data_list:
        fields = GYRO_TOPICS.get(d.name)
        if fields and all(f in d.data for f in fields) and len(d.data["timestamp"]) > 0:
            sets[f"{d.name}/{d.multi_id}"] = d
    return dict(sorted(sets.items()))


def list_ulog_gyros(path) -> tuple[str, ...]:
    """Every gyro stream of a ULog file, as ``"<topic>/<instance>"`` names (``"sensor_gyro/0"``, ...)."""
    p = input_path(path)
    return tuple(_gyro_sets(_load(p)))


def read_ulog(path, topic: str | None = None, *, imu: int | None = None, name: str | None = None) -> ImuStream:
    """Read one gyro of a PX4 ULog file.

    Parameters
    ----------
    path : str or Path
        The ``.ulg`` file.
    topic : str, optional
        ``"sensor_gyro/1"``, or a topic name (``"sensor_gyro"``) with ``imu`` giving the instance. Default:
        the only gyro stream, else ``sensor_gyro`` instance ``imu``.
    imu : int, optional
        The instance (uORB ``multi_id``, from 0) of ``topic`` (default topic ``sensor_gyro``).
    name : str, optional
        Stream name (default: the gyro's ``"<topic>/<instance>"``).

    Returns
    -------
    ImuStream
        ``t`` from ``timestamp_sample`` where logged (the sensor's sample time), else ``timestamp`` (us -> s);
        ``omega`` in rad/s. A note says when the logging rate is below :data:`MIN_CALIBRATION_RATE_HZ`.

    Raises
    ------
    InputError
        Several gyros and none chosen, or the chosen one absent (the message lists those present).
    FormatError
        Not a ULog file, or no gyro topic logged.
    """
    p = input_path(path)
    sets = _gyro_sets(_load(p))
    if not sets:
        raise FormatError(f"{p.name}: expected a gyro topic ({', '.join(GYRO_TOPICS)}) in the ULog file, got none "
                          "logged (PX4 logs sensor_gyro with SDLOG_PROFILE 'high rate' or 'debug')")
    if topic is not None and "/" in topic:
        key = topic
    elif topic is not None or imu is not None:
        key = f"{topic or 'sensor_gyro'}/{0 if imu is None else int(imu)}"
    elif len(sets) == 1:
        key = next(iter(sets))
    else:
        raise InputError(f"{p.name}: holds {len(sets)} gyro streams {list(sets)}; pass topic= (CLI --topic1/--topic2) "
                         "to choose one")
    if key not in sets:
        raise InputError(f"{p.name}: expected a gyro stream {key!r}, got {list(sets)}")
    d = sets[key]
    ts = d.data["timestamp_sample"] if "timestamp_sample" in d.data else d.data["timestamp"]
    ticks = np.asarray(ts, dtype=np.int64)
    omega = np.column_stack([np.asarray(d.data[f], dtype=np.float64) for f in GYRO_TOPICS[d.name]])
    order = np.argsort(ticks, kind="stable")
    ticks, omega = ticks[order], omega[order]
    keep = np.concatenate([[True], np.diff(ticks) > 0])   # a repeated sample time: the first sample only
    notes = []
    if not keep.all():
        notes.append(f"{int((~keep).sum())} sample(s) with a repeated timestamp dropped")
        ticks, omega = ticks[keep], omega[keep]
    if ticks.size < 2:
        raise FormatError(f"{p.name}: gyro stream {key!r} holds {ticks.size} sample(s), expected at least 2")
    t = int_time_to_seconds(ticks, 6)
    rate = float(1.0 / np.median(np.diff(t)))
    if rate < MIN_CALIBRATION_RATE_HZ:
        msg = (f"{p.name}: {key} is logged at {rate:.3g} Hz, below the {MIN_CALIBRATION_RATE_HZ:g} Hz a calibration "
               "needs (motion is aliased); log it at full rate (PX4: SDLOG_PROFILE high rate)")
        warnings.warn(msg, UserWarning, stacklevel=2)
        notes.append(msg)
    return ImuStream(t, omega, name=name or key, source=f"{p}:{key}", unit_in="rad/s", notes=tuple(notes))
