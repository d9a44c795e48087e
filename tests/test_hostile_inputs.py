"""Issue 22, one test per class of hostile input: special output paths, unit labels and encodings, deg/s read as
rad/s, too few samples, allocations sized by options or file headers, ``rostopic echo -p`` CSVs, foreign
exceptions, smaller silent answers and kill safety of the outputs."""

import contextlib
import io
import json
import os
import socket
import stat
import subprocess
import sys
import threading
import tracemalloc
import zipfile

import numpy as np
import pytest

from fusion_gyrocal import calibrate_array, calibrate_pair
from fusion_gyrocal.core.moments import Moments
from fusion_gyrocal.errors import ExcitationError, FormatError, GyroCalError, InputError, OptionError
from fusion_gyrocal.evaluate.sim import simulate_pair, simulate_streams
from fusion_gyrocal.io import ImuStream, read_imu, read_npz
from fusion_gyrocal.io.writers import (atomic_write, output_group, read_json, recover_outputs, write_json)

DEG = np.pi / 180


def _csv(path, t, w, label="", encoding="utf-8", time_name="t"):
    head = ",".join([time_name] + [f"gyro_{a}{label}" for a in "xyz"])
    rows = "\n".join(f"{a:.6f},{float(x)!r},{float(y)!r},{float(z)!r}" for a, (x, y, z) in zip(t, w))
    path.write_bytes((head + "\n" + rows + "\n").encode(encoding))
    return path


def _pair_files(tmp_path, scale=1.0, label="", encoding="utf-8", rms=1.0, seed=1, n=3000):
    sim = simulate_pair(n=n, rms=rms, rng=seed)
    a = _csv(tmp_path / "g1.csv", sim.t, sim.omega_1 * scale, label, encoding)
    b = _csv(tmp_path / "g2.csv", sim.t, sim.omega_2 * scale, label, encoding)
    return sim, a, b


def _cli(*argv):
    from fusion_gyrocal.cli.app import main
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


# ----------------------------------------------------------------------------- 1: output paths
def test_atomic_write_character_device_written_in_place(tmp_path):
    node = tmp_path / "null"
    try:
        os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, 3))   # a /dev/null of our own (root only)
    except OSError:
        pytest.skip("mknod needs root")
    atomic_write(node, "data")
    assert stat.S_ISCHR(os.stat(node).st_mode)


def test_atomic_write_fifo_written_in_place(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(open(fifo, "rb").read()), daemon=True)
    reader.start()
    atomic_write(fifo, "through the pipe")
    reader.join(10)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert got == [b"through the pipe"]


def test_atomic_write_symlink_kept_and_target_replaced(tmp_path):
    target = tmp_path / "real.txt"
    target.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(target)
    atomic_write(link, "new")
    assert link.is_symlink() and target.read_text() == "new"


@pytest.mark.parametrize("kind", ["folder", "socket"])
def test_atomic_write_refuses_what_is_no_file(tmp_path, kind):
    p = tmp_path / kind
    if kind == "folder":
        p.mkdir()
    else:
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(p))
        s.close()
    with pytest.raises(FormatError, match=f"expected .*got a {kind}"):
        atomic_write(p, "x")
    assert not stat.S_ISREG(os.lstat(p).st_mode)


def test_atomic_write_dash_is_standard_output(tmp_path, capsysbinary, monkeypatch):
    monkeypatch.chdir(tmp_path)
    atomic_write("-", "to stdout\n")
    assert capsysbinary.readouterr().out == b"to stdout\n"
    assert not (tmp_path / "-").exists()


def test_cli_calibrate_output_dash_prints_json_alone(tmp_path, monkeypatch):
    _, a, b = _pair_files(tmp_path, label=" [rad/s]")
    monkeypatch.chdir(tmp_path)
    code, out, err = _cli("calibrate", a, b, "-o", "-")
    assert code == 0, err
    assert "R_1_2" in json.loads(out)
    assert not (tmp_path / "-").exists()


# ----------------------------------------------------------------------------- 2: unit labels, encodings
@pytest.mark.parametrize("label, encoding, factor, unit", [
    (" [mdps]", "utf-8", 1e3 / DEG, "mdeg/s"),
    (" [mrad/s]", "utf-8", 1e3, "mrad/s"),
    (" [°/s]", "cp1252", 1 / DEG, "deg/s"),
    (" (°/s)", "latin-1", 1 / DEG, "deg/s"),
    (" [º/s]", "utf-8", 1 / DEG, "deg/s"),
])
def test_read_csv_unit_labels_and_encodings_converted(tmp_path, label, encoding, factor, unit):
    t = np.arange(50) / 100.0
    w = np.random.default_rng(0).normal(0, 0.3, (50, 3))
    s = read_imu(_csv(tmp_path / "g.csv", t, w * factor, label, encoding))
    assert s.unit_in == unit
    np.testing.assert_allclose(s.omega, w, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("label, where", [(" [rpm]", "gyro"), (" [urad/s]", "gyro"), (" [deg/h]", "gyro"),
                                          ("", "time")])
def test_read_csv_unknown_unit_label_refused_naming_it(tmp_path, label, where):
    t = np.arange(50) / 100.0
    w = np.zeros((50, 3))
    if where == "time":
        p = _csv(tmp_path / "g.csv", t, w, time_name="time [min]")
        match = "'min'"
    else:
        p = _csv(tmp_path / "g.csv", t, w, label)
        match = repr(label.strip(" []"))
    with pytest.raises(FormatError, match=match):
        read_imu(p)


def test_read_csv_assumed_unit_said_in_a_note(tmp_path):
    t = np.arange(50) / 100.0
    s = read_imu(_csv(tmp_path / "g.csv", t, np.zeros((50, 3))))
    assert any("read as rad/s" in n for n in s.notes)
    s = read_imu(_csv(tmp_path / "h.csv", t, np.zeros((50, 3)), " [rad/s]"))
    assert not any("read as rad/s" in n for n in s.notes)


# ----------------------------------------------------------------------------- 3: deg/s read as rad/s
@pytest.mark.parametrize("rms", [0.03, 0.2, 0.5])
def test_calibrate_pair_deg_per_s_with_slow_motion_refused(rms):
    sim = simulate_pair(n=6000, rms=rms, rng=2)
    with pytest.raises(InputError, match="look like deg/s.*white noise per sample"):
        calibrate_pair(sim.omega_1 / DEG, sim.omega_2 / DEG)


@pytest.mark.parametrize("rms", [0.03, 0.5])
def test_calibrate_pair_rad_per_s_with_slow_motion_accepted(rms):
    sim = simulate_pair(n=6000, rms=rms, rng=2)
    cal = calibrate_pair(sim.omega_1, sim.omega_2)
    np.testing.assert_allclose(cal.bias, sim.bias, atol=2e-3)


def test_calibrate_pair_deg_per_s_static_bias_is_a_sign():
    """Static stretches: a rate at rest of 0.5 "rad/s" (a 0.5 deg/s offset read as rad/s) with moderate noise."""
    from fusion_gyrocal.units import rate_unit_evidence
    rng = np.random.default_rng(5)
    w = np.zeros((4000, 3)) + 0.5 / np.sqrt(3) + rng.normal(0, 0.04, (4000, 3))
    figures, signs = rate_unit_evidence((w, w))
    assert "bias" in signs and figures["bias"] == pytest.approx(0.5, rel=0.05)
    assert "bias" not in rate_unit_evidence((w * DEG, w * DEG))[1]


def test_calibrate_pair_deg_per_s_on_one_gyro_left_to_the_mismatch_check():
    sim = simulate_pair(n=6000, rms=1.0, rng=3)
    with pytest.raises(GyroCalError, match="gyro 1 in rad/s, gyro 2 in deg/s"):
        calibrate_pair(sim.omega_1, sim.omega_2 / DEG)


def test_calibrate_pair_one_sign_warns_what_was_assumed():
    sim = simulate_pair(n=6000, rms=1.0, noise_std=0.06, rng=3)    # a very noisy gyro, in rad/s
    with pytest.warns(UserWarning, match="taken as rad/s although some signs say deg/s"):
        calibrate_pair(sim.omega_1, sim.omega_2, noise_std=0.06)


# ----------------------------------------------------------------------------- 6: too few samples
@pytest.mark.parametrize("n", [0, 3, 4, 5, 8, 13])
@pytest.mark.parametrize("noise", [0.0, 1e-3])
def test_calibrate_pair_too_few_samples_refused(n, noise):
    sim = simulate_pair(n=max(n, 1), noise_std=noise, rng=4)
    with pytest.raises(GyroCalError, match="expected"):
        calibrate_pair(sim.omega_1[:n], sim.omega_2[:n])


def test_calibrate_pair_residual_dof_counted_before_noise():
    sim = simulate_pair(n=10, noise_std=0.0, bias_walk_std=0.0, rng=4)
    with pytest.raises(InputError, match="degrees of freedom"):
        calibrate_pair(sim.omega_1, sim.omega_2)


# ----------------------------------------------------------------------------- 8: memory by option or file
@pytest.fixture(scope="module")
def streams():
    return simulate_streams(5, duration=20)


def test_calibrate_pair_huge_max_offset_bounded_by_data(streams):
    s = streams
    cal = calibrate_pair(s.omega_1, s.omega_2, t_1=s.t_1, t_2=s.t_2, max_offset_s=1e7)
    assert cal.time_offset_s == pytest.approx(0.1, abs=2e-3)


@pytest.mark.parametrize("rate", [1e6, 1e300])
def test_calibrate_pair_rate_beyond_the_data_refused(streams, rate):
    s = streams
    with pytest.raises(OptionError, match="rate_hz: expected at most"):
        calibrate_pair(s.omega_1, s.omega_2, t_1=s.t_1, t_2=s.t_2, rate_hz=rate)


def test_calibrate_pair_huge_bias_window_bounded_by_data():
    sim = simulate_pair(n=3000, rng=6)
    tracemalloc.start()
    cal = calibrate_pair(sim.omega_1, sim.omega_2, bias_window=10 ** 12)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 200e6
    np.testing.assert_allclose(cal.bias, sim.bias, atol=2e-3)


def _npz_claiming(path, shape):
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w") as z:
        for key in ("t", "omega"):
            z.writestr(f"{key}.npy", buf.getvalue() + bytes(32))
    return path


def _npz_of_zeros(path, n):
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for key, shape in (("t", (n,)), ("omega", (n, 3))):
            with z.open(f"{key}.npy", "w") as f:
                np.lib.format.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": shape})
                for _ in range(int(np.prod(shape)) * 8 >> 20):
                    f.write(bytes(1 << 20))
    return path


@pytest.mark.parametrize("make, match", [
    (lambda p: _npz_claiming(p, (1 << 28,)), "header says"),
    (lambda p: _npz_of_zeros(p, 1 << 22), "at most 50x the file's size"),   # 128 MiB of zeros in ~0.1 MB
])
def test_read_npz_sizes_checked_before_decompressing(tmp_path, make, match):
    p = make(tmp_path / "bad.npz")
    tracemalloc.start()
    with pytest.raises(FormatError, match=match):
        read_npz(p)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 20e6


def test_read_csv_huge_line_refused_before_splitting(tmp_path):
    p = tmp_path / "long.csv"
    p.write_text("t,gyro_x,gyro_y,gyro_z\n0,1,2,3\n" + ",".join(["1.0"] * 1_500_000) + "\n")   # a 6 MB line
    tracemalloc.start()
    with pytest.raises(FormatError, match="longer than"):
        read_imu(p)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 20e6


# ----------------------------------------------------------------------------- 9: rostopic echo -p
def _rostopic(path, sim, w):
    stamp0 = 1_700_000_000_000_000_000
    head = ("%time,field.header.seq,field.header.stamp,field.header.frame_id,field.angular_velocity.x,"
            "field.angular_velocity.y,field.angular_velocity.z")
    rows = [f"{stamp0 + int(round(t * 1e9)) + 150000},{i},{stamp0 + int(round(t * 1e9))},imu_link,{float(x)!r},"
            f"{float(y)!r},{float(z)!r}"
            for i, (t, (x, y, z)) in enumerate(zip(sim.t, w))]
    path.write_text(head + "\n" + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("options", [{}, {"time_unit": "ns"}])
def test_read_csv_rostopic_echo_header_read(tmp_path, options):
    sim = simulate_pair(n=500, rng=7)
    s = read_imu(_rostopic(tmp_path / "imu.csv", sim, sim.omega_1), **options)
    np.testing.assert_array_equal(s.omega, sim.omega_1)
    np.testing.assert_allclose(s.t - s.t[0], sim.t, atol=1e-6)


# ----------------------------------------------------------------------------- 10: foreign exceptions
def _sim(n=300, seed=9):
    return simulate_pair(n=n, rng=seed)


def _deep_json(tmp_path):
    p = tmp_path / "deep.json"
    p.write_text('{"format_version": 1, "R_1_2": ' + "[" * 100000 + "]" * 100000 + "}")
    return read_json(p)


def _strings_npz(tmp_path):
    np.savez(tmp_path / "s.npz", t=np.array(["a", "b", "c"]), omega=np.array([["x"] * 3] * 3))
    return read_npz(tmp_path / "s.npz")


def _two_sensitivities(tmp_path):
    np.savez(tmp_path / "m.npz", t_s=np.arange(10) / 100.0, gyro_counts=np.zeros((10, 2, 3), np.int16),
             gyro_lsb_per_dps=np.array([16.4, 16.4]))
    return read_npz(tmp_path / "m.npz")


def _string_parquet(tmp_path):
    pd = pytest.importorskip("pandas")
    pytest.importorskip("pyarrow")
    from fusion_gyrocal.distributed.fleet import calibrate_device
    p = tmp_path / "dev.parquet"
    pd.DataFrame({"t": np.arange(100) / 100.0, **{c: ["x"] * 100 for c in ("w1x", "w1y", "w1z", "w2x", "w2y", "w2z")}}
                 ).to_parquet(p)
    return calibrate_device(p)


def _full_disk_bag(tmp_path):
    import sqlite3

    from rosbags.rosbag2 import storage_sqlite3

    from fusion_gyrocal.io.bags import write_imu_bag

    def full(self, *args, **kw):
        raise sqlite3.OperationalError("database or disk is full")
    sim = _sim()
    real = storage_sqlite3.Sqlite3Writer.write
    storage_sqlite3.Sqlite3Writer.write = full
    try:
        return write_imu_bag(tmp_path / "bag", {"/imu0": ImuStream(sim.t, sim.omega_1)}, version=2)
    finally:
        storage_sqlite3.Sqlite3Writer.write = real


def _unreadable(tmp_path, monkeypatch):
    sim = _sim()
    p = _csv(tmp_path / "g.csv", sim.t, sim.omega_1)
    monkeypatch.setattr(os, "access", lambda path, mode: str(path) != str(p))   # what chmod 000 does to non-root
    return read_imu(p)


def _vanishing(tmp_path, monkeypatch):
    """An OSError while reading (EIO, a file removed under us) is a FormatError naming the file."""
    import fusion_gyrocal.io.readers as readers
    sim = _sim()
    p = _csv(tmp_path / "g.csv", sim.t, sim.omega_1)

    def broken(*args, **kw):
        raise OSError(5, "Input/output error")
    monkeypatch.setattr(readers, "read_csv", broken)
    return read_imu(p)


@pytest.mark.parametrize("make, error, match", [
    (_unreadable, FormatError, "could not read: permission denied"),
    (_vanishing, FormatError, "could not read: Input/output error"),
    (lambda tmp, mp: Moments.from_samples(_sim().omega_1, _sim().omega_2, chunk_size=0), OptionError, "chunk_size"),
    (lambda tmp, mp: calibrate_array([_sim(2000).omega_1, _sim(2000).omega_2, _sim(2000, 10).omega_2], reference=1.5),
     OptionError, "reference: expected a gyro index"),
    (lambda tmp, mp: _deep_json(tmp), FormatError, "nested too deeply|expected"),
    (lambda tmp, mp: _strings_npz(tmp), FormatError, "expected numeric arrays"),
    (lambda tmp, mp: _two_sensitivities(tmp), FormatError, "expected the arrays of a gyro log"),
    (lambda tmp, mp: _string_parquet(tmp), FormatError, "expected numbers in column"),
    (lambda tmp, mp: _full_disk_bag(tmp), FormatError, "disk is full"),
    (lambda tmp, mp: calibrate_pair(_sim().omega_1, _sim().omega_2, noise_std=True), OptionError, "noise_std"),
])
def test_hostile_input_raises_gyrocal_error(tmp_path, monkeypatch, make, error, match):
    with pytest.raises(error, match=match):
        make(tmp_path, monkeypatch)


@pytest.mark.parametrize("argv", [["calibrate", "{a}", "{b}", "--rate", "1e300"],
                                  ["compare", "--seed", "-1", "--runs", "1", "--estimators", "direct",
                                   "--workers", "1", "--no-progress"]])
def test_cli_hostile_option_exit_1_with_one_line(tmp_path, argv):
    s = simulate_streams(5, duration=10)
    a = _csv(tmp_path / "a.csv", s.t_1, s.omega_1)
    b = _csv(tmp_path / "b.csv", s.t_2, s.omega_2)
    code, out, err = _cli(*[x.format(a=a, b=b) for x in argv])
    assert code == 1
    assert "expected" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


# ----------------------------------------------------------------------------- 11: smaller silent ones
def test_read_json_not_a_rotation_refused(tmp_path):
    sim = simulate_pair(n=3000, rng=11)
    p = write_json(calibrate_pair(sim.omega_1, sim.omega_2), tmp_path / "c.json")
    d = json.loads(p.read_text())
    d["R_1_2"] = (2 * np.eye(3)).tolist()
    p.write_text(json.dumps(d))
    with pytest.raises(FormatError, match="R_1_2 to be a rotation"):
        read_json(p)


def test_compare_rotation_only_one_axis_motion_flagged():
    from fusion_gyrocal.evaluate.compare import compare
    rng = np.random.default_rng(12)
    w = np.zeros((6000, 3))
    w[:, 2] = np.sin(np.arange(6000) / 20.0)
    R = simulate_pair(n=10, rng=12).R_1_2
    c = compare((w + rng.normal(0, 1e-3, w.shape), w @ R + rng.normal(0, 1e-3, w.shape)),
                estimators=["rotation_only"], progress=False)
    assert c.rows[0].failures == 1 and "motion about at least two directions" in c.rows[0].note


def test_rotation_only_two_axis_motion_still_solved():
    from fusion_gyrocal.evaluate.baselines import rotation_only
    sim = simulate_pair(n=3000, rng=12)
    R, _ = rotation_only(sim.omega_1, sim.omega_2)
    assert np.degrees(np.linalg.norm(np.linalg.svd(R - sim.R_1_2, compute_uv=False))) < 3.0


# ----------------------------------------------------------------------------- 13: kill safety
def test_output_group_exception_leaves_every_old_file(tmp_path):
    (tmp_path / "a").write_text("old a")
    (tmp_path / "b").write_text("old b")
    with pytest.raises(RuntimeError):
        with output_group():
            atomic_write(tmp_path / "a", "new a")
            raise RuntimeError("the run failed after one file")
    assert (tmp_path / "a").read_text() == "old a"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b"]


def _die_on_second_rename(folders, files):
    """A child process writing ``files`` in one group that dies (SIGKILL-like ``os._exit``) on its second rename."""
    code = f"""
import os
from fusion_gyrocal.io import writers
calls = []
real = os.replace
def dying(src, dst, *a, **k):
    calls.append(dst)
    if len(calls) == 2:
        os._exit(9)
    return real(src, dst, *a, **k)
os.replace = dying
with writers.output_group():
    for path in {[str(f) for f in files]!r}:
        writers.atomic_write(path, "new")
"""
    return subprocess.run([sys.executable, "-c", code], cwd=os.getcwd()).returncode


def test_output_group_killed_mid_commit_finished_by_next_run(tmp_path):
    sub = tmp_path / "kalibr"
    sub.mkdir()
    files = [tmp_path / "cal.json", sub / "imu0.yaml", sub / "imu1.yaml"]
    for f in files:
        f.write_text("old")
    assert _die_on_second_rename([tmp_path, sub], files) == 9
    assert sorted(f.read_text() for f in files) == ["new", "old", "old"]      # a mix, behind a journal
    atomic_write(sub / "other", "x")                                           # the next run into one folder
    assert [f.read_text() for f in files] == ["new", "new", "new"]
    assert not [p for p in (*tmp_path.iterdir(), *sub.iterdir()) if p.name.startswith(".")]


def test_recover_outputs_undoes_an_incomplete_journal_and_cleans_dead_temps(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    pid = dead.pid
    (tmp_path / "a").write_text("old")
    tmp = tmp_path / f".a.gyrocal-{pid}-xyz.tmp"
    tmp.write_text("new")
    orphan = tmp_path / f".b.gyrocal-{pid}-abc.tmp"
    orphan.write_text("half")
    journal = tmp_path / f".gyrocal-commit-{pid}-1234.json"
    journal.write_text(json.dumps({"renames": [[str(tmp), str(tmp_path / "a")]],
                                   "journals": [str(journal), str(tmp_path / "missing" / "copy.json")]}))
    recover_outputs(tmp_path)
    assert (tmp_path / "a").read_text() == "old"           # a copy of the journal is missing: rolled back
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a"]


def test_recover_outputs_leaves_live_writers_alone(tmp_path):
    live = tmp_path / f".a.gyrocal-{os.getpid()}-xyz.tmp"
    live.write_text("being written")
    recover_outputs(tmp_path)
    assert live.exists()


def test_calibrate_pair_vibration_like_rates_not_taken_for_deg_s():
    """Rates with no smooth motion at the sample rate (aliased vibration: third differences as large as the rates)
    in rad/s are a warning, not a refusal: the noise sign alone says nothing about the unit."""
    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.evaluate.sim import random_rotation
    from fusion_gyrocal.lie import log

    rng = np.random.default_rng(1)
    R = random_rotation(rng)
    w1 = rng.standard_normal((20000, 3))
    w2 = w1 @ R + rng.normal(0.0, 1.7e-3, w1.shape) + 0.01
    with pytest.warns(UserWarning, match="some signs say deg/s"):
        cal = calibrate_pair(w1, w2)
    assert np.linalg.norm(log(cal.R_1_2 @ R.T)) < 1e-3


def test_calibrate_pair_clipped_sample_aligned_input_is_masked_and_said():
    """Sample-aligned input clipped at a sensor range (9 % of gyro 2's samples flat at +-range) gives the rotation
    of the unclipped samples, with a note, not an 80 mdeg error passed as rigid."""
    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.evaluate.sim import simulate_pair
    from fusion_gyrocal.lie import log

    sim = simulate_pair(rng=4, n=20000)
    lim = np.quantile(np.abs(sim.omega_2), 0.97)
    cal = calibrate_pair(sim.omega_1, np.clip(sim.omega_2, -lim, lim))
    e = log(cal.R_1_2 @ sim.R_1_2.T)
    assert e @ np.linalg.solve(cal.covariance[:3, :3], e) < 16.3        # chi2_3 at 0.999
    assert any("sit flat at an axis's extreme" in n for n in cal.notes)
