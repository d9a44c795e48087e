"""Fleets of devices and huge logs on Dask.

Two uses of one idea (the sufficient statistics are the hinge, see ``ARCHITECTURE.md``):

* :func:`run_fleet` maps the per-device pipeline (:func:`fusion_gyrocal.calibrate_pair`: alignment,
  saturation masks, flex gating, maximum likelihood) over many device recordings on a Dask cluster
  and returns a results table with one row per device; a device that fails gets a row with its
  error message instead of stopping the run, and the devices that shared a worker that died are run
  again alone, so only the device that kills its worker fails. :func:`fleet_cluster` starts a local
  cluster of worker processes set up for it; :func:`write_results` writes the table as Parquet.
* :func:`log_moments` splits one huge log (a Parquet file or dataset) into its row groups, computes
  :meth:`Moments.from_samples` of every row group on the workers and reduces them with a
  ``dask.bag`` tree reduction of :meth:`Moments.merge`; :func:`calibrate_log` then solves from the
  reduced statistics (:func:`fusion_gyrocal.solve`). The result equals the single-process pass to
  rounding (about 1e-12 relative), with memory bounded by one row group per worker.

Device layouts (every path given to :func:`run_fleet` is a device, or a folder of devices):

* ``<device>.parquet``: a Parquet file, or a folder of that name holding ``*.parquet`` part files
  (a Parquet dataset as Dask or Spark write it; parts read in name order): sample-aligned columns ``t`` (s), ``w1x w1y w1z`` (gyro 1,
  rad/s), ``w2x w2y w2z`` (gyro 2, rad/s). Rows with a non-finite rate are missing samples.
* ``<device>/`` holding ``gyro1.<ext>`` and ``gyro2.<ext>``: one recording per gyro in any format
  :func:`fusion_gyrocal.io.read_imu` reads (e.g. CSV with columns ``t,wx,wy,wz`` in s and rad/s),
  each on its own clock; the pipeline aligns them (time offset estimated).

The command line is ``gyrocal fleet`` (:mod:`fusion_gyrocal.cli.fleet`).
"""

from __future__ import annotations

import functools
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from ..core.solve import solve
from ..options import TIMESTAMP_OPTIONS, Options
from ..progress import progress_bar
from ..pipeline.pipeline import calibrate_pair

from ..errors import FormatError, GyroCalError, InputError
from ..core.model import PairCalibration
from ..core.moments import Moments, finite_rows
from ..pipeline.streams import check_timestamps

COLUMNS = ("t", "w1x", "w1y", "w1z", "w2x", "w2y", "w2z")
GYRO_FILES = ("gyro1", "gyro2")
RESULT_COLUMNS = (
    "device", "path", "ok", "error_type", "error", "seconds", "n_samples", "configuration", "rigid",
    "rotvec_x", "rotvec_y", "rotvec_z", "rotation_std_x", "rotation_std_y", "rotation_std_z",
    "scale_1_x", "scale_1_y", "scale_1_z", "scale_2_x", "scale_2_y", "scale_2_z",
    "bias_x", "bias_y", "bias_z", "time_offset_s", "time_offset_std_s", "noise_std_1", "noise_std_2",
    "residual_rms", "rejected_fraction", "gauge", "calibration_json",
)


# ---------------------------------------------------------------------------------------- devices
def _parquet_parts(path: Path) -> list[Path]:
    if path.is_file():
        return [path]
    return sorted(p for p in path.glob("*.parquet") if p.is_file())


def _gyro_hits(path: Path) -> list[list[Path]]:
    """The files of a folder named ``gyro1.*`` and ``gyro2.*`` (or exactly ``gyro1``, ``gyro2``), in name order."""
    children = sorted(path.iterdir())
    return [[p for p in children if p.stem == stem or p.name == stem] for stem in GYRO_FILES]


def _gyro_files(path: Path) -> tuple[Path, Path] | None:
    if not path.is_dir():
        return None
    hits = _gyro_hits(path)
    if not all(hits):
        return None
    return hits[0][0], hits[1][0]


def _is_device(path: Path) -> bool:
    if path.suffix == ".parquet":
        return path.is_file() or (path.is_dir() and bool(_parquet_parts(path)))
    return _gyro_files(path) is not None


def _broken_link(path: Path) -> str | None:
    """Why ``path`` is a symbolic link that leads nowhere (dangling, or a loop), or None."""
    if not path.is_symlink():
        return None
    try:
        path.resolve(strict=True)
    except RuntimeError:                        # Python < 3.13: a loop raises RuntimeError
        return "a symbolic link loop"
    except OSError as exc:
        if getattr(exc, "errno", None) == 40:   # ELOOP
            return "a symbolic link loop"
        return f"a symbolic link to {os.readlink(path)!r}, which does not exist"
    return None


def _looks_like_device(path: Path) -> bool:
    """A child of a folder of devices that is meant as a device: a ``.parquet`` file or folder, a folder, or a
    symbolic link that leads nowhere (its row says so). Hidden entries and other files are not."""
    if path.name.startswith("."):
        return False
    return path.suffix == ".parquet" or path.is_dir() or _broken_link(path) is not None


def find_devices(paths: Iterable) -> list[Path]:
    """Expand device paths and folders of devices into a sorted list of device paths.

    A path that is a device (see the module docstring) is kept; a folder that is not a device
    contributes its children meant as devices: ``.parquet`` files and folders, folders (one missing
    ``gyro1.*`` or ``gyro2.*`` gets a row saying so) and symbolic links that lead nowhere; hidden entries
    and other files are left out. Paths that do not exist are kept (their row will say so): every device
    named gets a row.
    """
    out = []
    for p in paths:
        p = Path(p).expanduser()
        if not p.exists() or _is_device(p):
            out.append(p)
        elif p.is_dir():
            out.extend(sorted(c for c in p.iterdir() if _looks_like_device(c)))
        else:
            out.append(p)    # a file that is no device: its row says what a device is
    if not out:
        raise InputError(f"expected at least one device (a .parquet file, a <name>.parquet dataset folder or a folder "
                         f"with gyro1.* and gyro2.*), found none in {[str(p) for p in paths]}")
    return out


def _not_a_device(path: Path) -> FormatError:
    """The error of a path that is no device, saying what is there and what a device is."""
    broken = _broken_link(path)
    if broken is not None:
        return FormatError(f"{path}: {broken}; expected a device (a .parquet file or folder, or a folder with "
                           f"{GYRO_FILES[0]}.* and {GYRO_FILES[1]}.*)")
    if not path.exists():
        return FormatError(f"{path}: no such device file or folder")
    if path.is_dir() and path.suffix == ".parquet":
        return FormatError(f"{path}: a Parquet dataset folder with no .parquet part files")
    if path.is_dir():
        hits = _gyro_hits(path)
        found = [h[0].name for h in hits if h]
        missing = [f"{stem}.*" for stem, h in zip(GYRO_FILES, hits) if not h]
        return FormatError(f"{path}: a device folder needs {GYRO_FILES[0]}.* and {GYRO_FILES[1]}.*; "
                           f"{'found ' + ', '.join(found) + ', ' if found else ''}missing {' and '.join(missing)}")
    return FormatError(f"{path}: expected a .parquet file, a <name>.parquet folder of .parquet parts or a folder "
                       f"with {GYRO_FILES[0]}.* and {GYRO_FILES[1]}.*")


def _check_columns(names: Sequence[str], where: Path):
    missing = [c for c in COLUMNS if c not in names]
    if missing:
        raise FormatError(f"{where}: expected Parquet columns {list(COLUMNS)}, missing {missing} (got {list(names)})")


def _open_parts(path: Path) -> list:
    """``(part, pyarrow.parquet.ParquetFile)`` of a Parquet file or dataset folder, each checked for :data:`COLUMNS`."""
    import pyarrow.parquet as pq

    parts = _parquet_parts(path)
    if not parts:
        raise FormatError(f"{path}: expected a .parquet file or a folder of .parquet parts, found none")
    opened = []
    for part in parts:
        try:
            pf = pq.ParquetFile(part)
        except Exception as exc:  # noqa: BLE001 - pyarrow raises its own types for damaged files
            raise FormatError(f"{part}: not a readable Parquet file: {exc}") from exc
        _check_columns(pf.schema_arrow.names, part)
        opened.append((part, pf))
    return opened


def _read_parquet_device(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Gyro 1 and gyro 2 rates (N, 3) of a Parquet device, after checking that its ``t`` increases."""
    tables = []
    for part, pf in _open_parts(path):
        try:
            tables.append(pf.read(columns=list(COLUMNS)))
        except Exception as exc:  # noqa: BLE001 - pyarrow raises its own types for damaged files
            raise FormatError(f"{part}: not a readable Parquet file: {exc}") from exc
    cols = {}
    for c in COLUMNS:
        try:
            cols[c] = np.concatenate([np.asarray(t.column(c).to_numpy(zero_copy_only=False), dtype=np.float64)
                                      for t in tables])
        except (ValueError, TypeError):   # strings, lists, ...: say which column
            kinds = sorted({str(t.schema.field(c).type) for t in tables})
            raise FormatError(f"{path}: expected numbers in column {c!r}, got type {', '.join(kinds)}") from None
    check_timestamps(f"{path}: t", cols["t"])
    w1 = np.column_stack([cols["w1x"], cols["w1y"], cols["w1z"]])
    w2 = np.column_stack([cols["w2x"], cols["w2y"], cols["w2z"]])
    return w1, w2


def calibrate_device(path, options: Options | None = None, **keywords) -> PairCalibration:
    """Run the per-device pipeline (:func:`fusion_gyrocal.calibrate_pair`) on one device recording.

    Parameters
    ----------
    path : str or Path
        A device (see the module docstring).
    options : Options, optional
        Passed to :func:`fusion_gyrocal.calibrate_pair`; a Parquet device is sample-aligned, so the
        time-alignment options (:data:`~fusion_gyrocal.options.TIMESTAMP_OPTIONS`) apply to
        gyro1/gyro2 devices only and are reset to their defaults for it.
    **keywords
        Fields of :class:`~fusion_gyrocal.options.Options` (``method``, ``noise_std``, ...).

    Raises
    ------
    FormatError
        Unreadable files, missing columns, or a folder that is no device.
    GyroCalError
        Anything :func:`fusion_gyrocal.calibrate_pair` raises.
    """
    options = Options.of(options, **keywords).require("pair", "calibrate_device")
    path = Path(path).expanduser()
    gyros = _gyro_files(path)
    if gyros is not None:
        from ..io import read_imu

        s1, s2 = read_imu(gyros[0]), read_imu(gyros[1])
        return calibrate_pair(s1.masked_omega, s2.masked_omega, t_1=s1.t, t_2=s2.t, options=options)
    if not _is_device(path):
        raise _not_a_device(path)
    w1, w2 = _read_parquet_device(path)
    finite = finite_rows(w1) & finite_rows(w2)
    aligned = options.replace(**{n: getattr(Options(), n) for n in TIMESTAMP_OPTIONS})
    return calibrate_pair(np.where(finite[:, None], w1, 0.0), np.where(finite[:, None], w2, 0.0),
                          mask=finite, options=aligned)


# ---------------------------------------------------------------------------------------- rows
def _row(name: str, path: str, cal: PairCalibration | None, exc: BaseException | None, seconds: float) -> dict:
    row = {c: None for c in RESULT_COLUMNS}
    row.update(device=name, path=path, ok=cal is not None, seconds=float(seconds))
    for c in RESULT_COLUMNS[6:-2]:
        if c not in ("configuration", "rigid"):
            row[c] = math.nan
    if exc is not None:
        known = isinstance(exc, GyroCalError)
        row["error_type"] = type(exc).__name__
        row["error"] = str(exc) if known else f"unexpected {type(exc).__name__}: {exc}"
        return row
    rv = cal.rotvec   # canonical_rotvec(log(R_1_2)), as every table
    std = cal.rotation_std_rad
    for a, ax in enumerate("xyz"):
        row[f"rotvec_{ax}"] = float(rv[a])
        row[f"rotation_std_{ax}"] = float(std[a])
        row[f"scale_1_{ax}"] = float(cal.scale_1[a])
        row[f"scale_2_{ax}"] = float(cal.scale_2[a])
        row[f"bias_{ax}"] = float(cal.bias[a])
    row.update(n_samples=int(cal.n_samples), configuration=cal.configuration,
               rigid=None if cal.rigid is None else bool(cal.rigid), time_offset_s=float(cal.time_offset_s),
               time_offset_std_s=float(cal.time_offset_std_s), noise_std_1=float(cal.noise_std[0]),
               noise_std_2=float(cal.noise_std[1]), residual_rms=float(cal.residual_rms),
               rejected_fraction=float(cal.rejected_fraction), gauge=cal.gauge, calibration_json=cal.to_json())
    return row


def device_row(path, options: Options | None = None) -> dict:
    """Calibrate one device and return its results-table row; never raises for a failing device.

    A :class:`~fusion_gyrocal.errors.GyroCalError` is recorded with its message in ``error``; any
    other exception too (``error`` starts with "unexpected"), so one bad device cannot stop a fleet.
    """
    path = Path(path)
    t0 = time.perf_counter()
    try:
        cal = calibrate_device(path, options)
        return _row(path.stem, str(path), cal, None, time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - recorded per device by design
        return _row(path.stem, str(path), None, exc, time.perf_counter() - t0)


def _table(rows):
    import pandas as pd

    df = pd.DataFrame(rows, columns=list(RESULT_COLUMNS))
    return df.astype({"ok": bool})


def run_fleet(devices, *, client=None, output=None, chunked: bool = False, split_every: int = 8,
              progress: bool | None = False, options: Options | None = None, **keywords):
    """Calibrate many devices on Dask; one results row per device, errors recorded per device.

    Parameters
    ----------
    devices : path or iterable of paths
        Devices or folders of devices (see the module docstring and :func:`find_devices`).
    client : distributed.Client, optional
        Cluster to run on (a few tasks per worker thread, each a batch of devices: :data:`TASKS_PER_THREAD`);
        devices that shared a worker that died are run again alone. :func:`fleet_cluster` starts a local one set up for this. Default: Dask's
        local threaded scheduler in this process.
    output : path, optional
        Also write the table as Parquet (:func:`write_results`).
    chunked : bool
        Calibrate every device from its Parquet row groups reduced across the workers
        (:func:`log_moments` then :func:`fusion_gyrocal.solve`): for devices whose logs are too big
        for one worker. Parquet devices only; no time alignment or flex gating.
    split_every : int
        Fan-in of the tree reduction (``chunked`` only).
    progress : bool or None
        A progress bar over the devices on stderr (:func:`fusion_gyrocal.progress.progress_bar`; None:
        when stderr is a terminal). One tick per device: no cost to throughput.
    options : Options, optional
        Passed unchanged to :func:`fusion_gyrocal.calibrate_pair` on every device (to
        :func:`fusion_gyrocal.solve` when ``chunked``, which refuses options that do not act on moments).
    **keywords
        Fields of :class:`~fusion_gyrocal.options.Options`, e.g. ``method="direct"``, ``noise_std=1e-3``.

    Returns
    -------
    pandas.DataFrame
        Columns :data:`RESULT_COLUMNS`: ``device``, ``path``, ``ok``, ``error_type``, ``error`` (the
        error message, None when ok), ``seconds`` (wall time of the device's pipeline on its worker;
        with ``chunked``, the shared reduction time split evenly plus the device's solve), the estimate in SI units (rotation vector of
        ``R_1_2`` in rad, scale factors, combined bias in rad/s, time offset in s, ...) and the full
        result as ``calibration_json`` (:meth:`PairCalibration.from_dict` reads it back).

    Raises
    ------
    InputError
        When no device is found.
    OptionError
        For an option the pipeline does not have (or, ``chunked``, one that does not act on moments).
    """
    options = Options.of(options, **keywords).require(*(("moments", "run_fleet(chunked=True)") if chunked
                                                        else ("pair", "run_fleet")))
    paths = find_devices([devices] if isinstance(devices, (str, Path)) else devices)
    if chunked:
        rows = _run_chunked(paths, client, split_every, options)
    else:
        task = functools.partial(device_row, options=options)
        with progress_bar(progress) as bar:
            tick = functools.partial(bar.advance, bar.add_task("devices", total=len(paths)))
            if client is not None:
                rows = _run_on_client(client, options, paths, tick)
            else:
                import dask
                from dask.callbacks import Callback

                with Callback(posttask=lambda *_: tick()):
                    rows = dask.compute(*[dask.delayed(task, pure=False)(str(p)) for p in paths], scheduler="threads")
    df = _table(list(rows))
    if output is not None:
        write_results(df, output)
    return df


#: Tasks per worker thread of a fleet on a cluster: each task calibrates a batch of devices, so the scheduler's
#: per-task cost is paid a few times per thread rather than once per device, and a few batches per thread still
#: even out devices of unequal size.
TASKS_PER_THREAD = 4


def device_rows(paths: Sequence, options: Options | None = None) -> list[dict]:
    """:func:`device_row` of each of ``paths`` in turn (one task of :func:`run_fleet` on a cluster)."""
    return [device_row(p, options) for p in paths]


def _batches(n: int, threads: int) -> list[list[int]]:
    """Device indices ``0..n-1`` dealt round-robin into ``min(n, TASKS_PER_THREAD x threads)`` batches (neighbours in
    a folder, often alike in size, land in different batches)."""
    k = max(1, min(n, TASKS_PER_THREAD * max(int(threads), 1)))
    return [list(range(j, n, k)) for j in range(k)]


def _run_on_client(client, options, paths, tick) -> list:
    """The rows of :func:`device_row` over ``paths`` on a distributed client, in batches of devices (:func:`_batches`,
    one task each, :func:`device_rows`); ``tick`` once per device.

    A worker that dies (out of memory, killed) takes the batches queued on it down with the one that killed it
    (``KilledWorker``). Each device of those is run again alone, one after the other: the healthy ones get their
    results, and only the device that kills its worker again fails, with a row that says so.
    """
    from distributed import KilledWorker, as_completed

    batches = _batches(len(paths), sum(client.nthreads().values()))
    futures = [client.submit(device_rows, [str(paths[i]) for i in b], options, pure=False, retries=0)
               for b in batches]
    size = {f.key: len(b) for f, b in zip(futures, batches)}
    for future in as_completed(futures):
        for _ in range(size[future.key]):
            tick()
    rows, lost = [None] * len(paths), []
    for batch, future in zip(batches, futures):
        try:
            for i, row in zip(batch, future.result()):
                rows[i] = row
        except KilledWorker:
            lost.extend(batch)
        except Exception as exc:  # noqa: BLE001 - recorded for this batch's devices only
            for i in batch:
                rows[i] = _row(paths[i].stem, str(paths[i]), None, exc, math.nan)
    task = functools.partial(device_row, options=options)
    for i in sorted(lost):
        path = paths[i]
        t0 = time.perf_counter()
        try:
            rows[i] = client.submit(task, str(path), pure=False, retries=0).result()
        except Exception as exc:  # noqa: BLE001 - KilledWorker again: this device kills its worker
            rows[i] = _row(path.stem, str(path), None, exc, time.perf_counter() - t0)
            if isinstance(exc, KilledWorker):
                rows[i]["error"] = (f"the Dask worker running this device died (out of memory, or killed), also "
                                    f"when the device ran alone: {' '.join(str(exc).split())}")
    return rows


_DISTRIBUTED_TRIM = 65536     # distributed's MALLOC_TRIM_THRESHOLD_ for its workers (its nanny.pre-spawn-environ)
#: glibc's malloc thresholds in :func:`fleet_cluster`'s workers (bytes): the ceiling its adaptive rule reaches in a
#: long-running process (mmap 32 MiB on 64-bit, trim twice that), fixed from the worker's start.
WORKER_MALLOC = {"MALLOC_MMAP_THRESHOLD_": 32 << 20, "MALLOC_TRIM_THRESHOLD_": 64 << 20}


def fleet_cluster(workers: int = 2, threads_per_worker: int = 1, **kwargs):
    """A local Dask cluster of worker processes set up for :func:`run_fleet`.

    Each worker is a process (the pipeline holds the GIL between numpy calls, so threads in one process
    would queue) started with glibc's malloc thresholds at :data:`WORKER_MALLOC`. A task runs in a thread of the
    worker, whose malloc arena otherwise hands every device's pages back to the system and maps them afresh for
    the next (measured, 24 devices of 60000 samples: ~112k page faults per pass, ~440 MB, and ~15 % more CPU time
    than the same loop in a main thread; ~10 faults with these thresholds); distributed's own
    ``MALLOC_TRIM_THRESHOLD_=65536`` is worse (each device ~1.75x slower). The
    scheduler does not retry a task whose worker died (``allowed-failures`` 0): :func:`run_fleet` runs each
    device that shared the dead worker again alone, so one device that exhausts memory cannot kill worker
    after worker. The workers' statistical profiler (a thread sampling every task's stack each 10 ms, for the
    dashboard) is off: it takes CPU time from the devices. The event loops' tick, a timer that measures their
    responsiveness for the dashboard, runs every second instead of every 20 ms (each wake-up takes the GIL
    from the task; measured: devices ~7 % faster, an idle cluster of two workers 0.10 -> 0.04 of a core; a
    loop stalled for over 3 s is still reported). (Each nanny also writes its variables, these
    thresholds and distributed's ``OMP_NUM_THREADS=1`` and the like, into this process's environment, where they
    would reach the processes it starts later and override the next cluster's settings: distributed's
    ``MALLOC_TRIM_THRESHOLD_`` value is removed from it before the start, and the environment is put back
    after it; a value the user set there wins, as in distributed.)

    Parameters
    ----------
    workers : int
        Worker processes (one per core is the usual choice).
    threads_per_worker : int
        Threads per worker process.
    **kwargs
        Passed to :class:`distributed.LocalCluster` (e.g. ``memory_limit``).

    Returns
    -------
    distributed.LocalCluster
        Use as a context manager, with ``distributed.Client(cluster)``.
    """
    import dask
    from distributed import LocalCluster

    settings = {**{f"distributed.nanny.pre-spawn-environ.{k}": v for k, v in WORKER_MALLOC.items()},
                "distributed.scheduler.allowed-failures": 0,
                "distributed.worker.profile.enabled": False,
                "distributed.admin.tick.interval": "1s"}
    kwargs = {"host": "127.0.0.1", "dashboard_address": None, **kwargs}
    if os.environ.get("MALLOC_TRIM_THRESHOLD_") == str(_DISTRIBUTED_TRIM):   # left by a default cluster's nanny
        del os.environ["MALLOC_TRIM_THRESHOLD_"]
    with dask.config.set(settings):
        # what each nanny writes into os.environ: its pre-spawn variables, and a fixed PYTHONHASHSEED where unset
        written = [*dask.config.get("distributed.nanny.pre-spawn-environ"), "PYTHONHASHSEED"]
        before = {k: os.environ.get(k) for k in written}
        try:
            return LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker, processes=True, **kwargs)
        finally:   # put this process's environment back
            for k, v in before.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v


def write_results(df, path) -> Path:
    """Write a results table (:func:`run_fleet`) to ``path`` as Parquet, atomically."""
    import io as _io

    from ..io.writers import atomic_write

    buf = _io.BytesIO()
    try:
        df.to_parquet(buf, engine="pyarrow", index=False)
    except Exception as exc:  # noqa: BLE001 - pyarrow's own error types
        raise FormatError(f"{path}: could not encode the results table as Parquet: {exc}") from exc
    return atomic_write(path, buf.getvalue())


# ---------------------------------------------------------------------------------------- huge logs
@dataclass(frozen=True)
class _Failed:
    """A failed chunk: carried through the reduction so one device's error stays in its row."""

    error_type: str
    message: str

    def error(self) -> GyroCalError:
        """The error to raise for the device: a FormatError stays one, anything else becomes an InputError."""
        return (FormatError if self.error_type == "FormatError" else InputError)(self.message)


def row_groups(path) -> list[tuple[str, int]]:
    """The ``(file, row_group)`` chunks of a Parquet log (file or dataset folder), in order."""
    path = Path(path).expanduser()
    if not path.exists():
        raise FormatError(f"{path}: no such Parquet file or folder")
    return [(str(part), i) for part, pf in _open_parts(path) for i in range(pf.num_row_groups)]


def chunk_moments(file: str, row_group: int) -> Moments:
    """:meth:`Moments.from_samples` of one row group (rows with a non-finite rate are missing samples)."""
    import pyarrow.parquet as pq

    try:
        table = pq.ParquetFile(file).read_row_group(row_group, columns=list(COLUMNS[1:]))
    except Exception as exc:  # noqa: BLE001
        raise FormatError(f"{file}: row group {row_group}: could not read: {exc}") from exc
    x = np.column_stack([np.asarray(table.column(c).to_numpy(zero_copy_only=False), dtype=np.float64)
                         for c in COLUMNS[1:]])
    finite = finite_rows(x)
    if not finite.all():
        x[~finite] = 0.0
        return Moments.from_samples(x[:, :3], x[:, 3:], mask=finite)
    return Moments.from_samples(x[:, :3], x[:, 3:])


def _safe_chunk(task) -> Moments | _Failed:
    try:
        return chunk_moments(*task)
    except Exception as exc:  # noqa: BLE001 - carried to the device's row
        return _Failed(type(exc).__name__, str(exc) if isinstance(exc, GyroCalError)
                       else f"unexpected {type(exc).__name__}: {exc}")


def _merge(parts) -> Moments | _Failed:
    """Merge moments; the first failure wins (the reduction of a device with a bad chunk fails)."""
    out = Moments.empty()
    for p in parts:
        if isinstance(p, _Failed):
            return p
        out = out.merge(p)
    return out


def _reduction(tasks, split_every):
    import dask.bag as db

    return (db.from_sequence(tasks, npartitions=max(1, len(tasks)))
            .map(_safe_chunk)
            .reduction(_merge, _merge, split_every=split_every))


def _compute(items, client):
    if client is not None:
        return client.gather(client.compute(list(items)))
    import dask

    return list(dask.compute(*items, scheduler="threads"))


def log_moments(path, *, client=None, split_every: int = 8) -> Moments:
    """Statistics of a huge Parquet log, reduced across Dask workers (one task per row group).

    Parameters
    ----------
    path : str or Path
        A Parquet file or dataset folder with the columns :data:`COLUMNS` (sample-aligned).
    client : distributed.Client, optional
        Cluster to run on; default: Dask's local threaded scheduler.
    split_every : int
        Fan-in of the ``dask.bag`` tree reduction of :meth:`Moments.merge`.

    Returns
    -------
    Moments
        Equal to ``Moments.from_samples`` of the whole log to rounding (~1e-12 relative).
    """
    tasks = row_groups(path)
    (m,) = _compute([_reduction(tasks, split_every)], client)
    if isinstance(m, _Failed):
        raise m.error()
    return m


def calibrate_log(path, *, client=None, split_every: int = 8, options: Options | None = None,
                  **keywords) -> PairCalibration:
    """Calibrate a pair from a huge Parquet log: :func:`log_moments` across workers, then :func:`fusion_gyrocal.solve`
    with ``options`` (solve options only; keywords are fields of :class:`~fusion_gyrocal.options.Options`)."""
    options = Options.of(options, **keywords).require("moments", "calibrate_log")
    return solve(log_moments(path, client=client, split_every=split_every), options)


def _run_chunked(paths, client, split_every, options):
    items, rows, pending = [], [None] * len(paths), []
    for i, p in enumerate(paths):
        try:
            items.append(_reduction(row_groups(p), split_every))
            pending.append(i)
        except Exception as exc:  # noqa: BLE001 - recorded per device
            rows[i] = _row(p.stem, str(p), None, exc, 0.0)
    t0 = time.perf_counter()
    results = _compute(items, client) if items else []
    per_device = (time.perf_counter() - t0) / max(len(items), 1)
    for i, m in zip(pending, results):
        p = paths[i]
        t1 = time.perf_counter()
        try:
            if isinstance(m, _Failed):
                raise m.error()
            cal = solve(m, options)
            rows[i] = _row(p.stem, str(p), cal, None, per_device + time.perf_counter() - t1)
        except Exception as exc:  # noqa: BLE001 - recorded per device
            rows[i] = _row(p.stem, str(p), None, exc, per_device + time.perf_counter() - t1)
    return rows
