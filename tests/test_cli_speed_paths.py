"""Correctness of what keeps ``gyrocal calibrate`` and fleets fast: the command line's BLAS threads, and the
fleet's batches of devices."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from fusion_gyrocal.evaluate.sim import simulate_pair

ROOT = Path(__file__).resolve().parents[1]


def _run_python(code: str, **env_extra) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    env.update(PYTHONPATH=os.pathsep.join(filter(None, (str(ROOT), os.environ.get("PYTHONPATH")))), **env_extra)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True,
                          cwd=ROOT).stdout.strip()


def test_cli_sets_single_threaded_blas_before_numpy_loads():
    from fusion_gyrocal.cli.app import SINGLE_THREADED_BLAS

    probe = "import os, {first}fusion_gyrocal.cli; print([os.environ.get(n) for n in {names!r}])"
    assert _run_python(probe.format(first="", names=SINGLE_THREADED_BLAS)) == str(["1"] * len(SINGLE_THREADED_BLAS))
    # the environment's own setting wins
    got = _run_python(probe.format(first="", names=SINGLE_THREADED_BLAS), OPENBLAS_NUM_THREADS="2")
    assert got.startswith("['2'")
    # numpy already loaded: nothing is set (it would act on nothing in this process)
    assert _run_python(probe.format(first="numpy, ", names=SINGLE_THREADED_BLAS)) == str(
        [None] * len(SINGLE_THREADED_BLAS))


def test_cli_calibrate_on_csv_pair_writes_offset(tmp_path):
    sim = simulate_pair(rng=7, n=6000)
    t = np.arange(sim.omega_1.shape[0]) / 100.0
    for name, w in (("a.csv", sim.omega_1), ("b.csv", sim.omega_2)):
        np.savetxt(tmp_path / name, np.column_stack([t, w]), delimiter=",", header="t,wx,wy,wz", comments="")
    code = textwrap.dedent(f"""
        from fusion_gyrocal.cli import main
        print(main(["calibrate", {str(tmp_path / 'a.csv')!r}, {str(tmp_path / 'b.csv')!r}, "--output",
                    {str(tmp_path / 'cal.json')!r}]))
    """)
    assert _run_python(code).splitlines()[-1] == "0"
    cal = json.loads((tmp_path / "cal.json").read_text())
    assert abs(cal["time_offset_s"]) < 0.001


def test_fleet_batches_cover_every_device_once_round_robin():
    from fusion_gyrocal.distributed.fleet import TASKS_PER_THREAD, _batches

    for n, threads in ((1, 2), (5, 2), (24, 2), (24, 1), (100, 3), (3, 0)):
        batches = _batches(n, threads)
        assert sorted(i for b in batches for i in b) == list(range(n))
        assert len(batches) == min(n, TASKS_PER_THREAD * max(threads, 1))
        assert max(map(len, batches)) - min(map(len, batches)) <= 1
        assert all(b == sorted(b) and np.all(np.diff(b) == len(batches)) for b in batches if len(b) > 1)


def test_device_rows_in_order_with_errors_recorded(tmp_path):
    pytest.importorskip("pyarrow")
    from fusion_gyrocal.distributed.fleet import COLUMNS, device_row, device_rows

    import pyarrow as pa
    import pyarrow.parquet as pq

    sim = simulate_pair(rng=8, n=3000)
    data = {"t": np.arange(3000) / 100.0}
    for g, w in (("1", sim.omega_1), ("2", sim.omega_2)):
        for a, ax in enumerate("xyz"):
            data[f"w{g}{ax}"] = w[:, a]
    pq.write_table(pa.table({c: data[c] for c in COLUMNS}), tmp_path / "good.parquet")
    paths = [tmp_path / "good.parquet", tmp_path / "missing.parquet"]
    rows = device_rows(paths)
    assert [r["device"] for r in rows] == ["good", "missing"]
    assert rows[0]["ok"] and not rows[1]["ok"] and rows[1]["error_type"] == "FormatError"
    assert rows[0]["calibration_json"] == device_row(paths[0])["calibration_json"]
