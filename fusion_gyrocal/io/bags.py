"""ROS1 / ROS2 bags: read ``sensor_msgs/msg/Imu`` angular rates, and write IMU bags.

Everything goes through the pure-Python ``rosbags`` package (no ROS installation needed):
``rosbags.highlevel.AnyReader`` for reading both generations, ``rosbags.rosbag1.Writer`` and
``rosbags.rosbag2.Writer`` with the ``ROS1_NOETIC`` / ``ROS2_HUMBLE`` type stores for writing.
``rosbags`` is imported lazily, so importing :mod:`fusion_gyrocal.io` stays light (and works without it:
extra ``[ros]``).

Timestamps are the messages' ``header.stamp`` (the sensor's clock), not the bag's receive time;
a topic whose header stamps are all zero (some drivers never fill them) falls back to the receive
time. ROS time is ``(sec, nanosec)``; it is converted to float seconds through whole and
fractional parts, so no digits are lost on epoch-sized stamps.
"""

from __future__ import annotations

import os
import shutil
import uuid
from pathlib import Path
from typing import Mapping

import numpy as np

from ..errors import FormatError, GyroCalError, InputError
from .stream import ImuStream, int_time_to_seconds
from .writers import fsync_dir

IMU_MSGTYPE = "sensor_msgs/msg/Imu"
_IMU_TYPES = (IMU_MSGTYPE, "sensor_msgs/Imu")


def _bag_path(path) -> tuple[Path, int]:
    """The path AnyReader wants and the bag generation (1 or 2).

    A ROS2 storage file (``.db3`` / ``.mcap``) given directly is read through its folder when that
    folder holds the bag's ``metadata.yaml`` (the bag may span several storage files), else on its own:
    ``rosbags`` reads a lone storage file's topics and types from the file itself (the common case
    when one file of a bag is shared).
    """
    p = Path(path).expanduser()
    if not p.exists():
        raise FormatError(f"{p}: no such bag file or folder")
    if p.is_dir():
        return p, 2
    if not p.is_file():
        raise FormatError(f"{p}: expected a bag file or folder, got {'a FIFO' if p.is_fifo() else 'a special file'}")
    if p.suffix.lower() in (".db3", ".mcap"):
        if (p.parent / "metadata.yaml").is_file():
            return p.parent, 2
        return p, 2
    if p.suffix.lower() == ".bag":
        return p, 1
    raise FormatError(f"{p}: expected a ROS1 '.bag' file, a ROS2 bag folder or a ROS2 storage file "
                      f"('.db3' / '.mcap'), got a file with suffix {p.suffix!r}")


def _open_reader(path):
    """``(path, AnyReader)``; every error of opening the bag is a :class:`FormatError`."""
    from ..extras import require

    AnyReader = require("rosbags.highlevel", "ros", "reading ROS bags").AnyReader
    from rosbags.typesys import Stores, get_typestore

    p, version = _bag_path(path)
    store = get_typestore(Stores.ROS2_HUMBLE if version == 2 else Stores.ROS1_NOETIC)
    try:
        return p, AnyReader([p], default_typestore=store)
    except _reader_errors() as exc:
        raise FormatError(f"{p}: could not read the bag: {' '.join(str(exc).split())}") from None


def _imu_topics(reader) -> dict[str, list]:
    topics: dict[str, list] = {}
    for c in reader.connections:
        if c.msgtype in _IMU_TYPES:
            topics.setdefault(c.topic, []).append(c)
    return topics


def _reader_errors():
    import sqlite3

    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error
    return (AnyReaderError, Reader1Error, Reader2Error, sqlite3.Error, OSError, ValueError, KeyError, EOFError)


def list_imu_topics(path) -> tuple[str, ...]:
    """Topics carrying ``sensor_msgs/msg/Imu`` in a ROS1 ``.bag``, a ROS2 bag folder or storage file, sorted."""
    p, reader = _open_reader(path)
    try:
        with reader:
            return tuple(sorted(_imu_topics(reader)))
    except GyroCalError:
        raise
    except _reader_errors() as exc:
        raise FormatError(f"{p}: could not read the bag: {exc}") from None


def read_bag(path, topic: str | None = None, *, name: str | None = None) -> ImuStream:
    """Read the angular velocity of one ``sensor_msgs/msg/Imu`` topic from a ROS1 or ROS2 bag.

    Parameters
    ----------
    path : str or Path
        ROS1 ``.bag`` file, ROS2 bag folder, or a ROS2 storage file (``.db3`` / ``.mcap``): read through
        its folder when that holds the bag's ``metadata.yaml``, else on its own (no ``ros2 bag reindex``
        needed).
    topic : str, optional
        The Imu topic. May be omitted when the bag holds exactly one Imu topic.
    name : str, optional
        Stream name (default: the topic).

    Returns
    -------
    ImuStream
        ``t`` from ``header.stamp`` (s), ``omega`` from ``angular_velocity`` (rad/s, REP 103),
        sorted by stamp if the bag stored the messages out of order.

    Raises
    ------
    InputError
        When ``topic`` is None and several Imu topics exist (the message lists them), or when the
        named topic is absent / not an Imu topic.
    FormatError
        When the file is not a readable bag or holds no Imu messages.
    """
    p, reader = _open_reader(path)
    try:
        with reader:
            topics = _imu_topics(reader)
            if topic is None:
                if len(topics) != 1:
                    if not topics:
                        others = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
                        raise FormatError(f"{p}: expected a sensor_msgs/msg/Imu topic, got none (topics: {others})")
                    raise InputError(f"{p}: holds several Imu topics {sorted(topics)}; pass topic= to choose one")
                topic = next(iter(topics))
            elif topic not in topics:
                raise InputError(f"{p}: expected an Imu topic {topic!r}, got Imu topics {sorted(topics)}")
            conns = topics[topic]
            n = sum(c.msgcount for c in conns)
            stamp_ns = np.empty(n, dtype=np.int64)
            recv_ns = np.empty(n, dtype=np.int64)
            omega = np.empty((n, 3))
            k = 0
            for conn, recv, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                st, av = msg.header.stamp, msg.angular_velocity
                if k == n:  # msgcount was stale: grow
                    stamp_ns = np.resize(stamp_ns, 2 * n + 1)
                    recv_ns = np.resize(recv_ns, 2 * n + 1)
                    omega = np.resize(omega, (2 * n + 1, 3))
                    n = 2 * n + 1
                stamp_ns[k] = int(st.sec) * 1_000_000_000 + int(st.nanosec)
                recv_ns[k] = recv
                omega[k] = (av.x, av.y, av.z)
                k += 1
    except GyroCalError:
        raise
    except _reader_errors() as exc:
        raise FormatError(f"{p}: could not read the bag: {exc}") from None
    if k == 0:
        raise FormatError(f"{p}: topic {topic!r} holds no messages")
    stamp_ns, recv_ns, omega = stamp_ns[:k], recv_ns[:k], omega[:k]
    if not stamp_ns.any():
        stamp_ns = recv_ns  # header stamps never filled in: use the receive time
    order = np.argsort(stamp_ns, kind="stable")
    if (np.diff(order) != 1).any():
        stamp_ns, omega = stamp_ns[order], omega[order]
    t = int_time_to_seconds(stamp_ns, 9)
    return ImuStream(t, omega, name=name or topic, source=f"{p}:{topic}", unit_in="rad/s")


# ----------------------------------------------------------------------------- writing
def _stamp(t: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray]:
    """float seconds -> (sec, nanosec) int64, rounding to the nearest nanosecond."""
    if (t < 0).any():
        k = int(np.argmax(t < 0))
        raise InputError(f"{where}: expected non-negative timestamps for ROS time, got {t[k]} s at sample {k}")
    sec = np.floor(t)
    nsec = np.rint((t - sec) * 1e9).astype(np.int64)
    sec = sec.astype(np.int64)
    carry = nsec >= 1_000_000_000
    sec[carry] += 1
    nsec[carry] -= 1_000_000_000
    return sec, nsec


def write_imu_bag(path, streams: Mapping[str, ImuStream], *, version: int = 1,
                  frame_ids: Mapping[str, str] | None = None, overwrite: bool = False,
                  storage: str = "sqlite3") -> Path:
    """Write gyro streams as ``sensor_msgs/msg/Imu`` messages into a ROS1 or ROS2 bag.

    Only the angular velocity is known: ``orientation_covariance[0]`` and
    ``linear_acceleration_covariance[0]`` are set to -1 ("not provided", as ``sensor_msgs/Imu``
    specifies), the angular-velocity covariance to zeros ("unknown"). ``header.stamp`` and the bag
    record time are both ``t`` rounded to the nanosecond. Messages of all topics are written in
    time order. Invalid samples (``stream.valid`` False) are written as they are.

    The bag is first written under a temporary name in the same folder and renamed into place
    when complete, so an interrupted write never leaves a half bag under ``path``.

    Parameters
    ----------
    path : str or Path
        ROS1: the ``.bag`` file (suffix ``.bag`` required so readers recognise it).
        ROS2: the bag folder to create (rosbag2 format version 9, storage per ``storage``).
    streams : mapping of topic -> ImuStream
    version : {1, 2}
        ROS generation.
    frame_ids : mapping of topic -> str, optional
        ``header.frame_id`` per topic (default: the topic without slashes).
    overwrite : bool
        Replace an existing bag at ``path`` (refused by default, like ``rosbag record``).
    storage : {"sqlite3", "mcap"}
        ROS2 storage file format (``<name>.db3`` or ``<name>.mcap`` in the folder); ROS1 ignores it.

    Returns
    -------
    Path
        The written bag.
    """
    from ..extras import require

    require("rosbags", "ros", "writing ROS bags")
    from rosbags.typesys import Stores, get_typestore

    path = Path(path).expanduser()
    if version not in (1, 2):
        raise InputError(f"version: expected 1 (ROS1 .bag) or 2 (ROS2 folder), got {version!r}")
    if version == 1 and path.suffix != ".bag":
        raise InputError(f"{path}: a ROS1 bag needs the suffix '.bag', got {path.suffix!r}")
    if storage not in ("sqlite3", "mcap"):
        raise InputError(f"storage: expected 'sqlite3' or 'mcap', got {storage!r}")
    if not streams:
        raise InputError("streams: expected at least one topic -> ImuStream, got none")
    for topic, s in streams.items():
        if not isinstance(topic, str) or not topic:
            raise InputError(f"streams: expected non-empty topic names, got {topic!r}")
        if not isinstance(s, ImuStream):
            raise InputError(f"streams[{topic!r}]: expected an ImuStream, got {type(s).__name__}")
    if path.exists() and not overwrite:
        raise FormatError(f"{path}: exists already; pass overwrite=True to replace it")
    if not path.parent.is_dir():
        raise FormatError(f"{path}: folder {path.parent} does not exist")

    store = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
    T = store.types
    Imu, Header, Time = T[IMU_MSGTYPE], T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Quaternion, Vector3 = T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Vector3"]
    serialize = store.serialize_ros1 if version == 1 else store.serialize_cdr
    not_provided = np.zeros(9)
    not_provided[0] = -1.0
    unknown = np.zeros(9)
    no_orientation = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    no_acceleration = Vector3(x=0.0, y=0.0, z=0.0)

    topics = list(streams)
    stamps = [_stamp(streams[tp].t, tp) for tp in topics]
    ns = np.concatenate([s * 1_000_000_000 + n for s, n in stamps])
    which = np.concatenate([np.full(len(streams[tp]), i) for i, tp in enumerate(topics)])
    index = np.concatenate([np.arange(len(streams[tp])) for tp in topics])
    order = np.argsort(ns, kind="stable")

    # Write into a private temporary folder next to ``path`` (same file system), then rename the
    # finished bag into place: the bag keeps its final name inside (ROS2 metadata lists the
    # storage file by name) and an interrupted write leaves nothing under ``path``.
    tmpdir = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    tmp = tmpdir / path.name
    try:
        tmpdir.mkdir()
        if version == 1:
            from rosbags.rosbag1 import Writer
            writer = Writer(tmp)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            writer = Writer(tmp, version=9, storage_plugin=plugin)
        with writer:
            conns = [writer.add_connection(tp, IMU_MSGTYPE, typestore=store) for tp in topics]
            frames = [(frame_ids or {}).get(tp, tp.strip("/").replace("/", "_") or "imu") for tp in topics]
            for j in order:
                i, k = int(which[j]), int(index[j])
                sec, nsec = stamps[i][0][k], stamps[i][1][k]
                w = streams[topics[i]].omega[k]
                hdr_kw = {"seq": k} if version == 1 else {}
                msg = Imu(header=Header(stamp=Time(sec=int(sec), nanosec=int(nsec)), frame_id=frames[i], **hdr_kw),
                          orientation=no_orientation, orientation_covariance=not_provided,
                          angular_velocity=Vector3(x=float(w[0]), y=float(w[1]), z=float(w[2])),
                          angular_velocity_covariance=unknown,
                          linear_acceleration=no_acceleration, linear_acceleration_covariance=not_provided)
                writer.write(conns[i], int(ns[j]), serialize(msg, IMU_MSGTYPE))
        _fsync_tree(tmp)
        old = tmpdir / (path.name + ".old")
        if path.exists():  # overwrite=True: move the old bag aside, put the new one in, drop the old
            os.replace(path, old)
        try:
            os.replace(tmp, path)
        except OSError:
            if old.exists():
                os.replace(old, path)  # put the old bag back
            raise
        fsync_dir(path.parent)
    except BaseException as exc:
        import sqlite3

        from rosbags.rosbag1 import WriterError as W1
        from rosbags.rosbag2 import WriterError as W2
        if isinstance(exc, (OSError, W1, W2, sqlite3.Error)):   # sqlite3: a ROS2 bag on a full disk
            raise FormatError(f"{path}: could not write the bag: {exc}") from exc
        raise
    finally:
        _remove(tmpdir)
    return path


def _remove(p: Path) -> None:
    try:
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()
    except OSError:
        pass


def _fsync_tree(p: Path) -> None:
    files = [p] if p.is_file() else [f for f in p.rglob("*") if f.is_file()]
    for f in files:
        fd = os.open(f, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    if p.is_dir():
        fsync_dir(p)
