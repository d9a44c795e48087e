import json

import numpy as np
import pytest

pd = pytest.importorskip("pandas")
pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")
distributed = pytest.importorskip("distributed")

from fusion_gyrocal import FormatError, InputError, Moments, OptionError, PairCalibration, solve  # noqa: E402
from fusion_gyrocal.cli.fleet import fleet_main  # noqa: E402
from fusion_gyrocal.distributed.fleet import (RESULT_COLUMNS, calibrate_log, find_devices, log_moments,  # noqa: E402
                                  row_groups, run_fleet)
from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, rotation_error, simulate_pair  # noqa: E402


def _write_parquet(path, sim, *, row_group_size=1000, t0=0.0):
    t = t0 + np.arange(sim.omega_1.shape[0]) / 100.0
    data = {"t": t}
    for g, w in (("1", sim.omega_1), ("2", sim.omega_2)):
        for a, ax in enumerate("xyz"):
            data[f"w{g}{ax}"] = w[:, a]
    pq.write_table(pa.table(data), path, row_group_size=row_group_size)


def _write_csv_device(folder, sim):
    folder.mkdir()
    t = np.arange(sim.omega_1.shape[0]) / 100.0
    for name, w in (("gyro1.csv", sim.omega_1), ("gyro2.csv", sim.omega_2)):
        np.savetxt(folder / name, np.column_stack([t, w]), delimiter=",", header="t,wx,wy,wz", comments="",
                   fmt="%.10g")


@pytest.fixture(scope="module")
def client():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as c:
        yield c


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    """Five devices: two Parquet, one gyro1/gyro2 CSV folder, one with a missing column, one not rigid."""
    root = tmp_path_factory.mktemp("fleet")
    truth = {}
    for i, name in enumerate(("dev_a", "dev_b")):
        sim = simulate_pair(rng=10 + i, n=4000)
        _write_parquet(root / f"{name}.parquet", sim)
        truth[name] = sim
    sim = simulate_pair(rng=12, n=4000)
    _write_csv_device(root / "dev_c", sim)
    truth["dev_c"] = sim
    pq.write_table(pa.table({"t": np.arange(10.0), "w1x": np.zeros(10)}), root / "dev_d.parquet")
    a, b = simulate_pair(rng=13, n=4000), simulate_pair(rng=14, n=4000)  # two unrelated motions
    _write_parquet(root / "dev_e.parquet", type(a)(**{**a.__dict__, "omega_2": b.omega_2}))
    return root, truth


def test_run_fleet_one_row_per_device_with_errors_recorded(client, fleet_dir):
    root, truth = fleet_dir
    df = run_fleet(root, client=client, noise_std=PAPER_NOISE_STD)
    assert list(df.columns) == list(RESULT_COLUMNS)
    assert df["device"].tolist() == ["dev_a", "dev_b", "dev_c", "dev_d", "dev_e"]
    assert df["ok"].tolist() == [True, True, True, False, False]
    assert df.loc[3, "error_type"] == "FormatError" and "missing ['w1y'" in df.loc[3, "error"]
    assert df.loc[4, "error_type"] == "NotRigidError" and "not rigid" in df.loc[4, "error"]
    assert df.loc[:2, "error"].isna().all()
    for _, row in df[df["ok"]].iterrows():
        cal = PairCalibration.from_dict(json.loads(row["calibration_json"]))
        sim = truth[row["device"]]
        assert rotation_error(cal.R_1_2, sim.R_1_2) < 5 * np.linalg.norm(cal.rotation_std_rad)
        np.testing.assert_allclose([row["rotvec_x"], row["rotvec_y"], row["rotvec_z"]], cal.rotvec, atol=1e-12)


def test_run_fleet_without_client_matches_cluster(client, fleet_dir):
    root, _ = fleet_dir
    on_cluster = run_fleet([root / "dev_a.parquet", root / "dev_c"], client=client)
    local = run_fleet([root / "dev_a.parquet", root / "dev_c"])
    cols = ["rotvec_x", "rotvec_y", "rotvec_z", "scale_2_x", "bias_z", "time_offset_s"]
    np.testing.assert_allclose(local[cols].to_numpy(float), on_cluster[cols].to_numpy(float), rtol=1e-12, atol=1e-15)


def test_run_fleet_writes_parquet_results_table(fleet_dir, tmp_path):
    root, _ = fleet_dir
    out = tmp_path / "results.parquet"
    df = run_fleet([root / "dev_b.parquet", root / "dev_d.parquet"], output=out)
    back = pd.read_parquet(out)
    assert back["device"].tolist() == ["dev_b", "dev_d"] and back["ok"].tolist() == [True, False]
    np.testing.assert_array_equal(back["scale_2_y"].to_numpy(), df["scale_2_y"].to_numpy())
    assert back.loc[1, "error"] == df.loc[1, "error"]


def test_run_fleet_csv_device_estimates_time_offset(fleet_dir):
    root, truth = fleet_dir
    df = run_fleet([root / "dev_c"])
    assert df.loc[0, "ok"] and abs(df.loc[0, "time_offset_s"]) < 5 * df.loc[0, "time_offset_std_s"]  # truth: 0


def test_run_fleet_missing_device_is_a_row_not_a_crash(fleet_dir):
    root, _ = fleet_dir
    df = run_fleet([root / "dev_a.parquet", root / "no_such_device"])
    assert df["ok"].tolist() == [True, False]
    assert df.loc[1, "error_type"] == "FormatError" and "no such device" in df.loc[1, "error"]


def test_run_fleet_unknown_option_raises_option_error(fleet_dir):
    with pytest.raises(OptionError, match="no_such_option"):
        run_fleet(fleet_dir[0], no_such_option=1)


def test_find_devices_in_empty_folder_raises_input_error(tmp_path):
    with pytest.raises(InputError, match="at least one device"):
        find_devices([tmp_path])


@pytest.fixture(scope="module")
def huge_log(tmp_path_factory):
    """A Parquet dataset of two part files, 30 row groups, with a few missing (NaN) samples."""
    folder = tmp_path_factory.mktemp("huge") / "log.parquet"
    folder.mkdir()
    sim = simulate_pair(rng=20, n=30000)
    w1 = sim.omega_1.copy()
    w1[[5, 17000, 29999], 1] = np.nan
    sim = type(sim)(**{**sim.__dict__, "omega_1": w1})
    half = type(sim)(**{**sim.__dict__, "omega_1": w1[:12000], "omega_2": sim.omega_2[:12000]})
    rest = type(sim)(**{**sim.__dict__, "omega_1": w1[12000:], "omega_2": sim.omega_2[12000:]})
    _write_parquet(folder / "part-000.parquet", half, row_group_size=1000)
    _write_parquet(folder / "part-001.parquet", rest, row_group_size=1000, t0=120.0)
    keep = np.isfinite(w1).all(axis=1)
    return folder, np.where(keep[:, None], w1, 0.0), sim.omega_2, keep


def test_log_moments_on_cluster_matches_single_process(client, huge_log):
    folder, w1, w2, keep = huge_log
    assert len(row_groups(folder)) == 30
    m = log_moments(folder, client=client, split_every=4)
    ref = Moments.from_samples(w1, w2, mask=keep)
    assert m.count == ref.count == 29997
    np.testing.assert_allclose(m.mean, ref.mean, rtol=1e-12, atol=1e-12 * np.abs(ref.mean).max())
    np.testing.assert_allclose(m.scatter, ref.scatter, rtol=1e-12, atol=1e-12 * np.abs(ref.scatter).max())


def test_calibrate_log_matches_in_process_solve(client, huge_log):
    folder, w1, w2, keep = huge_log
    cal = calibrate_log(folder, client=client, noise_std=PAPER_NOISE_STD)
    ref = solve(Moments.from_samples(w1, w2, mask=keep), noise_std=PAPER_NOISE_STD)
    assert rotation_error(cal.R_1_2, ref.R_1_2) < 1e-10
    np.testing.assert_allclose(cal.scale_2, ref.scale_2, rtol=1e-10)


def test_run_fleet_chunked_matches_log_moments_and_records_errors(client, huge_log, fleet_dir):
    folder, w1, w2, keep = huge_log
    df = run_fleet([folder, fleet_dir[0] / "dev_d.parquet"], client=client, chunked=True, noise_std=PAPER_NOISE_STD)
    assert df["ok"].tolist() == [True, False] and df.loc[1, "error_type"] == "FormatError"
    ref = solve(Moments.from_samples(w1, w2, mask=keep), noise_std=PAPER_NOISE_STD)
    assert df.loc[0, "n_samples"] == 29997
    np.testing.assert_allclose(df.loc[0, ["scale_2_x", "scale_2_y", "scale_2_z"]].to_numpy(float), ref.scale_2,
                               rtol=1e-10)


def test_log_moments_damaged_row_group_raises_format_error(tmp_path):
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"PAR1 this is not parquet")
    with pytest.raises(FormatError, match="not a readable Parquet file"):
        log_moments(bad)


def test_fleet_main_writes_table_and_flags_failures_in_exit_code(fleet_dir, tmp_path, capsys):
    root, _ = fleet_dir
    out = tmp_path / "cli.parquet"
    code = fleet_main([str(root / "dev_a.parquet"), str(root / "dev_d.parquet"), "-o", str(out), "--workers", "0"])
    assert code == 4
    assert pd.read_parquet(out)["ok"].tolist() == [True, False]
    assert "1 failed" in capsys.readouterr().out
    assert fleet_main([str(root / "dev_a.parquet"), "-o", str(out), "--workers", "0"]) == 0


def test_gyrocal_cli_has_fleet_subcommand(fleet_dir, tmp_path):
    from fusion_gyrocal.cli import main

    out = tmp_path / "via_cli.parquet"
    assert main(["fleet", str(fleet_dir[0] / "dev_b.parquet"), "-o", str(out), "--workers", "0",
                 "--method", "direct"]) == 0
    assert pd.read_parquet(out)["ok"].tolist() == [True]


def test_run_fleet_parquet_device_with_backward_time_step_is_an_input_error_row(tmp_path):
    sim = simulate_pair(rng=15, n=500)
    _write_parquet(tmp_path / "dev.parquet", sim)
    table = pq.read_table(tmp_path / "dev.parquet")
    t = table.column("t").to_numpy().copy()
    t[300] = t[298]
    pq.write_table(table.set_column(0, "t", pa.array(t)), tmp_path / "dev.parquet")
    df = run_fleet([tmp_path / "dev.parquet"])
    assert df.loc[0, "error_type"] == "InputError"
    assert "dev.parquet: t: expected strictly increasing timestamps, got a step of -0.01 s at sample 300" \
        in df.loc[0, "error"]


def test_fleet_main_chunked_refuses_pipeline_options_before_starting_workers(fleet_dir, tmp_path, capsys):
    out = tmp_path / "never.parquet"
    code = fleet_main([str(fleet_dir[0] / "dev_a.parquet"), "--chunked", "--no-flex-rejection", "-o", str(out)])
    assert code == 1 and not out.exists()
    err = capsys.readouterr().err
    assert err.startswith("gyrocal: error: --chunked: works from moments only and cannot apply "
                          "['flex_rejection']") and err.count("\n") == 1


def test_fleet_main_has_no_bias_window_flag(capsys):
    with pytest.raises(SystemExit):
        fleet_main(["dev.parquet", "--bias-window", "2"])
    assert "unrecognized arguments: --bias-window" in capsys.readouterr().err


class _KillOn(distributed.WorkerPlugin):
    """In every (re)started worker: the device named ``stem`` kills its worker process after ``delay`` s (as an
    out-of-memory kill would), once the worker has other devices queued."""

    def __init__(self, stem, delay):
        self.stem, self.delay = stem, delay

    def setup(self, worker):
        import os
        import time
        from pathlib import Path

        import fusion_gyrocal.distributed.fleet as fleet

        original, stem, delay = fleet.calibrate_device, self.stem, self.delay

        def calibrate_device(path, options=None, **keywords):
            if Path(path).stem == stem:
                time.sleep(delay)
                os._exit(1)
            return original(path, options, **keywords)

        fleet.calibrate_device = calibrate_device


def test_run_fleet_dead_worker_fails_only_its_device(tmp_path):
    from fusion_gyrocal.distributed.fleet import fleet_cluster

    names = [f"dev_{i}" for i in range(6)]
    for i, name in enumerate(names):
        _write_parquet(tmp_path / f"{name}.parquet", simulate_pair(rng=40 + i, n=2000))
    with fleet_cluster(2) as cluster, distributed.Client(cluster) as c:
        c.register_plugin(_KillOn("dev_2", 1.0))
        df = run_fleet(tmp_path, client=c, noise_std=PAPER_NOISE_STD).set_index("device")
    assert sorted(df.index) == names
    assert df.loc["dev_2", "ok"] == False and df.loc["dev_2", "error_type"] == "KilledWorker"  # noqa: E712
    assert "worker running this device died" in df.loc["dev_2", "error"] and "alone" in df.loc["dev_2", "error"]
    healthy = df.drop("dev_2")
    assert healthy["ok"].all(), healthy[["error_type", "error"]]
    assert np.isfinite(healthy["rotvec_x"].to_numpy(float)).all()


def _worker_page_faults(paths):
    """Minor page faults of the task's thread over a second pass of :func:`device_rows` on ``paths``."""
    import resource

    from fusion_gyrocal.distributed.fleet import device_rows

    device_rows(paths)
    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    device_rows(paths)
    return resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before


def test_fleet_cluster_workers_reuse_memory_from_device_to_device(tmp_path, monkeypatch):
    import os

    from fusion_gyrocal.distributed.fleet import WORKER_MALLOC, fleet_cluster

    paths = []
    for k in range(3):
        paths.append(str(tmp_path / f"dev_{k}.parquet"))
        _write_parquet(paths[-1], simulate_pair(rng=60 + k, n=20_000))
    for k in ("MALLOC_MMAP_THRESHOLD_", "OMP_NUM_THREADS", "PYTHONHASHSEED"):   # (a worker restarted by an
        monkeypatch.delenv(k, raising=False)                                     # earlier test's nanny writes them)
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")     # what a default cluster's nanny leaves in this process
    with fleet_cluster(1) as cluster, distributed.Client(cluster) as c:
        env = c.run(lambda: tuple(os.environ.get(k) for k in (*WORKER_MALLOC, "OMP_NUM_THREADS")))
        faults = c.submit(_worker_page_faults, paths, pure=False).result()
    assert list(env.values()) == [(*map(str, WORKER_MALLOC.values()), "1")]
    assert all(k not in os.environ for k in (*WORKER_MALLOC, "OMP_NUM_THREADS", "PYTHONHASHSEED"))   # put back
    # 3 devices touch ~40 MB a pass: mapped afresh (a thread's arena with glibc's adaptive thresholds, or
    # distributed's trim threshold) that is ~10^4 faults; reused, a few dozen
    assert faults < 1000, faults


def test_run_fleet_folder_entries_that_are_no_device_get_error_rows(tmp_path):
    import os

    _write_parquet(tmp_path / "dev_a.parquet", simulate_pair(rng=50, n=2000))
    half = tmp_path / "half"
    half.mkdir()
    (half / "gyro1.csv").write_text("t,wx,wy,wz\n0,0,0,0\n")
    (tmp_path / "empty.parquet").mkdir()
    os.symlink(tmp_path / "nowhere.parquet", tmp_path / "gone.parquet")
    os.symlink(tmp_path / "loop", tmp_path / "loop")
    (tmp_path / "notes.txt").write_text("not a device")
    (tmp_path / ".cache").mkdir()
    df = run_fleet(tmp_path).set_index("device")
    assert sorted(df.index) == ["dev_a", "empty", "gone", "half", "loop"]
    assert df.loc["dev_a", "ok"] and not df.drop("dev_a")["ok"].any()
    assert (df.drop("dev_a")["error_type"] == "FormatError").all()
    assert "missing gyro2.*" in df.loc["half", "error"] and "found gyro1.csv" in df.loc["half", "error"]
    assert "symbolic link to" in df.loc["gone", "error"] and "does not exist" in df.loc["gone", "error"]
    assert "symbolic link loop" in df.loc["loop", "error"]
    assert "no .parquet part files" in df.loc["empty", "error"]


def test_fleet_main_folder_with_half_device_exits_4(tmp_path, capsys):
    _write_parquet(tmp_path / "dev_a.parquet", simulate_pair(rng=51, n=2000))
    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "gyro2.csv").write_text("t,wx,wy,wz\n0,0,0,0\n")
    code = fleet_main([str(tmp_path), "-o", str(tmp_path / "out.parquet"), "--workers", "0"])
    out = capsys.readouterr().out
    assert code == 4 and "half: FAILED (FormatError)" in out and "missing gyro1.*" in out


def test_run_fleet_poisoned_timestamp_fails_only_its_device(tmp_path):
    import tracemalloc
    for i, name in enumerate(("dev_a", "dev_b", "dev_c")):
        _write_parquet(tmp_path / f"{name}.parquet", simulate_pair(rng=30 + i, n=3000))
    table = pq.read_table(tmp_path / "dev_b.parquet")
    t = table.column("t").to_numpy().copy()
    t[1500:] += 1e6                       # one corrupted timestamp shifts the rest of the log by 11.6 days
    pq.write_table(table.set_column(0, "t", pa.array(t)), tmp_path / "dev_b.parquet")
    tracemalloc.start()
    try:
        df = run_fleet(tmp_path).set_index("device")   # Dask's local threaded scheduler
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert sorted(df.index) == ["dev_a", "dev_b", "dev_c"]
    assert df.loc["dev_b", "error_type"] == "InputError"
    assert "at sample 1500" in df.loc["dev_b", "error"] and "corrupt timestamp?" in df.loc["dev_b", "error"]
    for name in ("dev_a", "dev_c"):
        assert df.loc[name, "ok"] and np.isfinite(df.loc[name, "rotvec_x"])
    assert peak < 200e6


def test_run_fleet_progress_bar_ticks_once_per_device(fleet_dir, monkeypatch):
    import fusion_gyrocal.distributed.fleet as fleet_module

    ticks = []

    class Bar:     # stands for the rich bar: counts the ticks
        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def add_task(self, description, total):
            ticks.append(("total", total))
            return 0

        def advance(self, task, advance=1):
            ticks.append("tick")

    monkeypatch.setattr(fleet_module, "progress_bar", lambda enabled: Bar())
    df = run_fleet(fleet_dir[0], progress=True)
    assert ticks[0] == ("total", len(df)) and ticks.count("tick") == len(df)
