"""Readers and writers at the library's edge (units are converted here and nowhere else).

Readers return :class:`ImuStream` (``t`` in s, ``omega`` in rad/s, float64, ``notes`` saying what
the reader dropped or chose): :func:`read_imu` (any format, picked from suffix and content),
:func:`read_csv` (generic and EuRoC / ASL ``imu0/data.csv``), :func:`read_xsens` (MT Manager exports of
every version and delimiter; ``rate_hz`` for exports that state none), :func:`read_npz` (generic and
the MIMU array layout), :func:`read_bag` / :func:`list_imu_topics` (ROS1 and ROS2, a lone ``.db3`` / ``.mcap``
too, via ``rosbags``), :func:`read_ulog` / :func:`list_ulog_gyros` (PX4 ULog, via ``pyulog``).
Every failure to read a file is a :class:`~fusion_gyrocal.errors.FormatError` naming the file.
One module per format (:mod:`~fusion_gyrocal.io.csv`, :mod:`~fusion_gyrocal.io.xsens`,
:mod:`~fusion_gyrocal.io.npz`, :mod:`~fusion_gyrocal.io.bags`), the text parsing they share in
:mod:`~fusion_gyrocal.io.text`, the stream type in :mod:`~fusion_gyrocal.io.stream`, the choice of
reader in :mod:`~fusion_gyrocal.io.readers`.

Writers are atomic (temp file, fsync, ``os.replace``): :func:`write_json` / :func:`read_json` for
:class:`~fusion_gyrocal.core.model.PairCalibration` and :class:`~fusion_gyrocal.core.array.ArrayCalibration`,
:func:`write_kalibr_imu_configs` (one Kalibr IMU configuration per gyro, what ``kalibr_calibrate_imu_camera
--imu`` reads), :func:`write_kalibr_imu_chain`, :func:`write_openvins_imu_chain`, and for streams
:func:`write_csv`, :func:`write_npz`, :func:`write_imu_bag`.
"""

from .csv import read_csv
from .npz import read_npz
from .readers import detect_format, read_imu
from .stream import ImuStream
from .writers import (ImuNoise, read_json, write_csv, write_json, write_kalibr_imu_chain, write_kalibr_imu_configs,
                      write_npz, write_openvins_imu_chain)
from .xsens import read_xsens

__all__ = [
    "ImuStream", "ImuNoise",
    "read_imu", "detect_format", "read_csv", "read_xsens", "read_npz", "read_bag", "list_imu_topics",
    "read_ulog", "list_ulog_gyros",
    "write_json", "read_json", "write_kalibr_imu_configs", "write_kalibr_imu_chain", "write_openvins_imu_chain",
    "write_csv", "write_npz", "write_imu_bag",
]

_BAGS = ("list_imu_topics", "read_bag", "write_imu_bag")   # rosbags loads on first use of a bag
_ULOG = ("read_ulog", "list_ulog_gyros")                   # pyulog loads on first use of a ULog file


def __getattr__(name):
    if name in _BAGS:
        from . import bags

        return getattr(bags, name)
    if name in _ULOG:
        from . import ulog

        return getattr(ulog, name)
    raise AttributeError(f"module 'fusion_gyrocal.io' has no attribute {name!r}")
