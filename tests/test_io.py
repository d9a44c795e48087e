"""Tests for fusion_gyrocal.io: readers, writers, bags, atomicity, YAML exports."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from fusion_gyrocal.errors import FormatError, InputError, OptionError
from fusion_gyrocal.io import (ImuStream, detect_format, list_imu_topics, read_bag, read_csv, read_imu,
                               read_json, read_npz, read_xsens, write_csv, write_imu_bag, write_json,
                               write_kalibr_imu_chain, write_npz, write_openvins_imu_chain)
from fusion_gyrocal.io import text as text_mod
from fusion_gyrocal.io import writers as writers_mod
from fusion_gyrocal.core.model import PairCalibration
from fusion_gyrocal.evaluate.sim import DEG, shared_data_dir
from fusion_gyrocal.units import RATE_FACTORS, RATE_UNIT_LABELS

DATA = shared_data_dir()
NO_DATA = "../shared/data not present (real recordings are only in the project checkout)"


def _stream(rng, n=500, rate=100.0, t0=12.5, name="imu"):
    t = t0 + np.arange(n) / rate + rng.uniform(0, 1e-4, n)  # a little jitter
    return ImuStream(t, rng.normal(0.0, 1.0, (n, 3)), name=name)


def _cal(rng, **over):
    cov = np.diag(rng.uniform(1e-8, 1e-6, 12))
    cov[8, 8] = np.inf  # an undetermined scale
    kw = dict(R_1_2=Rotation.from_rotvec(rng.normal(0, 0.5, 3)).as_matrix(),
              scale_1=[1.0, 1.003, 0.997], scale_2=[1.01, 0.99, 1.002], bias=rng.normal(0, 0.01, 3),
              configuration="general", scale_observable=[[True, True, True], [True, True, False]],
              covariance=cov, gauge="scale_1[0] == 1", snr=[500.0, 600.0, 700.0], n_samples=6000,
              noise_std=[0.1 * DEG, 0.2 * DEG], residual_rms=float("nan"), time_offset_s=-0.0123,
              time_offset_std_s=1e-4, notes=("weak z axis",), rigid=None)
    kw.update(over)
    return PairCalibration(**kw)


def _leftovers(folder: Path, keep: set[str]) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name not in keep)


# ----------------------------------------------------------------------------- ImuStream
def test_imustream_copies_and_freezes_input():
    rng = np.random.default_rng(1)
    t, w = np.arange(10) / 50.0, rng.normal(size=(10, 3))
    s = ImuStream(t, w, name="a")
    w[0, 0] = 99.0
    assert s.omega[0, 0] != 99.0
    assert not s.omega.flags.writeable and not s.t.flags.writeable
    assert s.rate_hz == pytest.approx(50.0)


def test_imustream_rejects_backward_step_with_index():
    t = np.array([0.0, 0.01, 0.02, 0.01, 0.04])
    with pytest.raises(InputError, match=r"strictly increasing.*step of -0\.01 s at sample 3"):
        ImuStream(t, np.zeros((5, 3)), name="g2")


def test_imustream_valid_flags_nonfinite_rows():
    w = np.ones((4, 3))
    w[2, 1] = np.nan
    s = ImuStream(np.arange(4.0), w, valid=[True, False, True, True])
    assert s.valid.tolist() == [True, False, False, True]


# ----------------------------------------------------------------------------- CSV
def test_read_csv_roundtrip_write_csv(tmp_path):
    s = _stream(np.random.default_rng(2))
    p = write_csv(s, tmp_path / "imu.csv")
    r = read_csv(p)
    np.testing.assert_array_equal(r.t, s.t)
    np.testing.assert_array_equal(r.omega, s.omega)
    assert r.name == "imu" and r.unit_in == "rad/s"


def test_read_csv_header_units_are_converted(tmp_path):
    rng = np.random.default_rng(3)
    t_ms = np.arange(200) * 10.0
    w_deg = rng.normal(0, 50, (200, 3))
    p = tmp_path / "log.csv"
    np.savetxt(p, np.column_stack([t_ms, w_deg]), delimiter=",", fmt="%.17g",
               header="time_ms,gx [deg/s],gy [deg/s],gz [deg/s]", comments="")
    r = read_csv(p)
    np.testing.assert_allclose(r.t, t_ms / 1000.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(r.omega, w_deg * DEG, rtol=1e-15)
    assert r.unit_in == "deg/s" and r.rate_hz == pytest.approx(100.0)


def test_read_csv_counts_without_header_and_explicit_columns(tmp_path):
    rng = np.random.default_rng(4)
    counts = rng.integers(-30000, 30000, (100, 3))
    p = tmp_path / "raw.txt"
    # layout: z y x time (whitespace separated, no header)
    np.savetxt(p, np.column_stack([counts[:, ::-1], np.arange(100) * 4000]), fmt="%d")
    r = read_csv(p, time_column=3, columns=(2, 1, 0), unit="counts", sensitivity=16.4, time_unit="us")
    np.testing.assert_allclose(r.omega, counts / 16.4 * DEG, rtol=1e-15)
    np.testing.assert_allclose(r.t, np.arange(100) * 4e-3, atol=1e-15)
    assert r.unit_in == "counts"


@pytest.mark.parametrize("label, unit", sorted(RATE_UNIT_LABELS.items()))
def test_read_csv_header_rate_unit_spellings_of_the_unit_table(tmp_path, label, unit):
    p = tmp_path / "log.csv"
    p.write_text(f"t,gx [{label}],gy,gz\n0,1,2,3\n0.01,4,5,6\n")
    sensitivity = 2.0 if unit == "counts" else None
    r = read_csv(p, sensitivity=sensitivity)
    assert r.unit_in == unit
    np.testing.assert_array_equal(r.omega[0], np.array([1.0, 2.0, 3.0]) * (RATE_FACTORS[unit] / (sensitivity or 1.0)))


def test_units_table_is_the_one_of_readers_conversion_and_cli():
    from fusion_gyrocal import units
    from fusion_gyrocal.cli import recording
    from fusion_gyrocal.io import readers
    from fusion_gyrocal.pipeline.streams import to_rad_per_s

    assert readers.RATE_UNITS is recording.RATE_UNITS is units.RATE_UNITS == tuple(units.RATE_FACTORS)
    assert readers.TIME_UNITS is recording.TIME_UNITS is units.TIME_UNITS
    for unit, factor in units.RATE_FACTORS.items():
        sensitivity = 4.0 if unit == "counts" else None
        assert to_rad_per_s([3.0], unit, sensitivity)[0] == 3.0 * (factor / (sensitivity or 1.0))
    assert set(units.RATE_UNIT_LABELS.values()) == set(units.RATE_UNITS)
    assert set(units.TIME_UNIT_LABELS.values()) == set(units.TIME_UNITS)


def test_read_csv_counts_without_sensitivity_raises(tmp_path):
    p = tmp_path / "raw.csv"
    p.write_text("t,gyro_x,gyro_y,gyro_z\n0,1,2,3\n1,1,2,3\n")
    with pytest.raises(OptionError, match="raw.csv: .*sensitivity"):
        read_csv(p, unit="counts")


def test_read_csv_euroc_folder_and_file(tmp_path):
    rng = np.random.default_rng(5)
    n = 400
    t_ns = 1403636579758555392 + np.arange(n, dtype=np.int64) * 5_000_000 + rng.integers(0, 1000, n)
    w = rng.normal(0, 1, (n, 3))
    acc = rng.normal(0, 9.8, (n, 3))
    folder = tmp_path / "mav0" / "imu0"
    folder.mkdir(parents=True)
    header = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
    rows = [f"{t_ns[k]}," + ",".join(f"{v:.17g}" for v in (*w[k], *acc[k])) for k in range(n)]
    (folder / "data.csv").write_text(header + "\n" + "\n".join(rows) + "\n")
    expected_t = (t_ns // 10**9).astype(float) + (t_ns % 10**9) * 1e-9
    for target in (folder, folder / "data.csv", tmp_path / "mav0"):
        r = read_csv(target)
        np.testing.assert_array_equal(r.omega, w)
        np.testing.assert_allclose(r.t, expected_t, rtol=0, atol=1e-6)  # float64 at 1.4e9 s: ~0.2 us
        assert r.name == "imu0"
    # relative timing keeps nanoseconds (no digits lost to one big ns * 1e-9)
    np.testing.assert_allclose(np.diff(r.t), np.diff(t_ns) * 1e-9, rtol=0, atol=5e-7)
    assert detect_format(folder / "data.csv") == "euroc"


def test_read_csv_missing_gyro_columns_message(tmp_path):
    p = tmp_path / "imu.csv"
    p.write_text("t,a,b\n0,1,2\n1,3,4\n")
    with pytest.raises(FormatError, match=r"imu\.csv: expected a column 'gyro_x'.*got header \['t', 'a', 'b'\]"):
        read_csv(p)


def test_read_csv_missing_time_column_message(tmp_path):
    p = tmp_path / "imu.csv"
    p.write_text("counter,gyro_x,gyro_y,gyro_z\n0,1,2,3\n1,3,4,5\n")
    with pytest.raises(FormatError, match=r"expected a time column.*time_column="):
        read_csv(p)


def test_read_csv_non_numeric_row_message(tmp_path):
    p = tmp_path / "imu.csv"
    p.write_text("t,gyro_x,gyro_y,gyro_z\n0,1,2,3\n0.01,1,oops,3\n")
    with pytest.raises(FormatError, match=r"imu\.csv: expected numeric data"):
        read_csv(p)


def test_read_csv_backward_time_message(tmp_path):
    p = tmp_path / "imu.csv"
    p.write_text("t,gyro_x,gyro_y,gyro_z\n0,1,2,3\n0.02,1,2,3\n0.01,1,2,3\n")
    with pytest.raises(InputError, match=r"strictly increasing.*sample 2"):
        read_csv(p)


def test_read_csv_empty_file_message(tmp_path):
    p = tmp_path / "empty.csv"
    p.write_text("\n\n")
    with pytest.raises(FormatError, match="empty.csv: expected a header or data rows"):
        read_csv(p)


def _read_both_ways(monkeypatch, read, path):
    """``read(path)`` through np.loadtxt only and through pandas (size threshold 0): (result or error) x 2."""
    out = []
    for threshold in (float("inf"), 0):
        monkeypatch.setattr(text_mod, "PANDAS_MIN_BYTES", threshold)
        try:
            out.append(read(path))
        except (FormatError, InputError) as exc:
            out.append(f"{type(exc).__name__}: {exc}")
    return out


def test_read_csv_pandas_reads_big_files_exactly_in_one_pass(tmp_path, monkeypatch):
    pytest.importorskip("pandas")
    s = _stream(np.random.default_rng(60), n=3000)
    p = write_csv(s, tmp_path / "imu.csv")
    monkeypatch.setattr(text_mod, "PANDAS_MIN_BYTES", 0)
    loadtxt = text_mod._load_columns
    monkeypatch.setattr(text_mod, "_load_columns", None)  # float columns must not reach np.loadtxt
    r = read_csv(p)
    np.testing.assert_array_equal(r.t, s.t)
    np.testing.assert_array_equal(r.omega, s.omega)
    monkeypatch.setattr(text_mod, "_load_columns", loadtxt)
    ref, fast = _read_both_ways(monkeypatch, read_csv, p)
    np.testing.assert_array_equal(fast.omega, ref.omega)


def test_read_csv_pandas_and_loadtxt_agree_on_integer_time_and_xsens(tmp_path, monkeypatch):
    pytest.importorskip("pandas")
    rng = np.random.default_rng(61)
    t_ns = 1403636579758555392 + np.arange(50, dtype=np.int64) * 5_000_000
    p = tmp_path / "data.csv"
    p.write_text("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1]\n"
                 + "".join(f"{t_ns[k]}," + ",".join(f"{v:.17g}" for v in rng.normal(size=3)) + "\n" for k in range(50)))
    ref, fast = _read_both_ways(monkeypatch, read_csv, p)
    np.testing.assert_array_equal(fast.t, ref.t)
    np.testing.assert_array_equal(fast.omega, ref.omega)
    x = tmp_path / "x.txt"
    x.write_text(_xsens_text(np.arange(1, 41), rng.normal(size=(40, 3))))
    ref, fast = _read_both_ways(monkeypatch, read_xsens, x)
    np.testing.assert_array_equal(fast.t, ref.t)
    np.testing.assert_array_equal(fast.omega, ref.omega)
    x.write_text(_xsens_text(["1", "2.5", "3"], np.zeros((3, 3))))  # a counter must count whole packets
    assert _read_both_ways(monkeypatch, read_xsens, x) == [
        "FormatError: x.txt: expected whole numbers in PacketCounter, got [2.5] in data row 2"] * 2
    x.write_text(_xsens_text(["1", "2.0", "3"], np.zeros((3, 3))))  # 2.0 is packet 2 both ways
    ref, fast = _read_both_ways(monkeypatch, read_xsens, x)
    np.testing.assert_array_equal(fast.t, [0.01, 0.02, 0.03])
    np.testing.assert_array_equal(fast.t, ref.t)


_LAYOUTS = {  # name: (file bytes of a header and rows, delimiter or None for whitespace runs)
    "csv, BOM, CRLF": (lambda rows: ("\ufefft,gyro_x,gyro_y,gyro_z\r\n"
                                     + "".join(",".join(r) + "\r\n" for r in rows)).encode(), ","),
    "tsv, extra text column": (lambda rows: ("time\tgyr_x\tgyr_y\tgyr_z\tnote\n"
                                             + "".join("\t".join(r) + "\tok\n" for r in rows)).encode(), "\t"),
    "semicolons, spreadsheet trailer": (lambda rows: ("t;wx;wy;wz\n" + "".join(";".join(r) + "\n" for r in rows)
                                                      + ";;;\n\nsaved by a spreadsheet\n").encode(), ";"),
    "whitespace runs": (lambda rows: ("t gyro_x gyro_y gyro_z\n"
                                      + "".join("  ".join(r) + "\n" for r in rows)).encode(), None),
}


@pytest.mark.parametrize("parser", ["pyarrow", "pandas", "loadtxt"])
@pytest.mark.parametrize("layout", sorted(_LAYOUTS))
def test_read_csv_fast_parsers_and_loadtxt_give_identical_arrays(tmp_path, monkeypatch, parser, layout):
    """Each fast parser alone (the others made unavailable) reads what np.loadtxt reads, bit for bit."""
    if parser != "loadtxt":
        pytest.importorskip(parser)
    rng = np.random.default_rng(62)
    t = 1.7e9 + np.arange(400) / 200.0 + rng.uniform(0, 1e-4, 400)
    w = rng.normal(0, 2.0, (400, 3)) * 10.0 ** rng.integers(-6, 3, (400, 3))
    rows = [[repr(float(t[k]))] + [f"{v:.25g}" if k % 3 else repr(float(v)) for v in w[k]] for k in range(400)]
    build, _ = _LAYOUTS[layout]
    p = tmp_path / "imu.csv"
    p.write_bytes(build(rows))
    monkeypatch.setattr(text_mod, "PANDAS_MIN_BYTES", float("inf"))
    ref = read_csv(p)
    for other in {"pyarrow", "pandas"} - {parser}:   # an import that fails, as when not installed
        monkeypatch.setitem(sys.modules, other, None)
        monkeypatch.setitem(sys.modules, f"{other}.csv", None)
    used = []

    def spy(name):
        fn = getattr(text_mod, name)

        def wrapped(*args, **kwargs):
            x = fn(*args, **kwargs)
            used.append(name if x is not None else None)
            return x
        monkeypatch.setattr(text_mod, name, wrapped)

    spy("_pyarrow_floats")
    spy("_pandas_floats")
    monkeypatch.setattr(text_mod, "PANDAS_MIN_BYTES", 0)
    fast = read_csv(p)
    expected = "loadtxt" if parser == "loadtxt" or (parser == "pyarrow" and _LAYOUTS[layout][1] is None) else parser
    assert [u for u in used if u] == ([] if expected == "loadtxt" else [f"_{expected}_floats"])
    np.testing.assert_array_equal(ref.t, t)
    np.testing.assert_array_equal(ref.omega, w)
    for name in ("t", "omega", "valid"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(ref, name), err_msg=name)
    assert fast.notes == ref.notes


@pytest.mark.parametrize("rows", [
    "0,1,,3\n0.01,4,5,6\n0.02,7,8,9\n",      # empty field: NaN, flagged invalid
    "0,1,2,3\n0.01,4,5\n0.02,7,8,9\n",       # short row: an error
    "0,1,2,3\n\n0.01,4,5,6\n0.02,7,8,9\n",   # blank line: skipped
    "0,1,2,3\n   \n0.01,4,5,6\n",            # whitespace-only line: an error
    "0,1,NA,3\n0.01,4,5,6\n0.02,7,8,9\n",    # 'NA': an error
    "0,1,nan,3\n0.01,4,5,6\n0.02,7,8,9\n",   # 'nan': NaN
    '0,1,"2",3\n0.01,4,5,6\n',              # quotes: an error
    "0,1,2,3 # note\n# comment\n0.01,4,5,6\n",
])
def test_read_csv_pandas_defers_to_loadtxt_on_unclean_rows(tmp_path, monkeypatch, rows):
    pytest.importorskip("pandas")
    p = tmp_path / "imu.csv"
    p.write_text("t,gyro_x,gyro_y,gyro_z\n" + rows)
    ref, fast = _read_both_ways(monkeypatch, read_csv, p)
    if isinstance(ref, str):
        assert fast == ref
    else:
        for name in ("t", "omega", "valid"):
            np.testing.assert_array_equal(getattr(fast, name), getattr(ref, name), err_msg=name)


# ----------------------------------------------------------------------------- Xsens
def test_read_xsens_real_file_counter_timing():
    if not DATA.is_dir():
        pytest.skip(NO_DATA)
    folder = DATA / "xsens_walking_nonrigid"
    up = read_xsens(folder / "walking_xsens_upperLeg.txt")
    low = read_imu(folder / "walking_xsens_lowerLeg.txt")
    raw = np.genfromtxt(folder / "walking_xsens_upperLeg.txt", skip_header=5, delimiter="\t")[:, :13]
    assert len(up) == 3511 and up.rate_hz == 120.0
    np.testing.assert_allclose(up.t, raw[:, 0] / 120.0, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(up.omega, raw[:, 4:7])
    np.testing.assert_array_equal(up.t, low.t)  # one counter, one clock
    peak = max(np.abs(up.omega).max(), np.abs(low.omega).max())
    assert 4.0 < peak < 8.0  # rad/s: SOURCE.md reports a peak of about 5.5 rad/s while walking


def _xsens_text(counter, gyro, rate="100.0"):
    lines = ["// Start Time: 0", f"// Sample rate: {rate}Hz", "// Scenario: 5.9",
             "PacketCounter\tAcc_X\tAcc_Y\tAcc_Z\tGyr_X\tGyr_Y\tGyr_Z\t"]
    for c, g in zip(counter, gyro):
        lines.append(f"{c}\t0.1\t0.2\t9.8\t" + "\t".join(f"{v:.17g}" for v in g) + "\t")
    return "\r\n".join(lines) + "\r\n"


def test_read_xsens_counter_wraparound(tmp_path):
    rng = np.random.default_rng(6)
    counter = (65530 + np.arange(12)) % 65536
    counter = np.delete(counter, 8)  # one dropped packet after the wrap
    g = rng.normal(size=(counter.size, 3))
    p = tmp_path / "wrap.txt"
    p.write_text(_xsens_text(counter, g))
    s = read_xsens(p)
    expected = (65530 + np.delete(np.arange(12), 8)) / 100.0
    np.testing.assert_allclose(s.t, expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(s.omega, g)
    assert detect_format(p) == "xsens"


def test_read_xsens_missing_rate_message(tmp_path):
    p = tmp_path / "norate.txt"
    p.write_text(_xsens_text([1, 2, 3], np.zeros((3, 3))).replace("// Sample rate: 100.0Hz", "// nothing"))
    with pytest.raises(FormatError, match=r"norate\.txt: no sample rate to time the samples by PacketCounter "
                                          r"\(no '// Update Rate:' or '// Sample rate:' line\); pass rate_hz="):
        read_xsens(p)
    np.testing.assert_array_equal(read_xsens(p, rate_hz=50.0).t, [0.02, 0.04, 0.06])


# ----------------------------------------------------------------------------- npz
def test_read_npz_roundtrip_write_npz(tmp_path):
    rng = np.random.default_rng(7)
    w = rng.normal(size=(300, 3))
    s = ImuStream(np.arange(300) / 200.0, w, name="x", valid=rng.random(300) > 0.1)
    r = read_npz(write_npz(s, tmp_path / "x.npz"), imu=0)
    np.testing.assert_array_equal(r.t, s.t)
    np.testing.assert_array_equal(r.omega, s.omega)
    np.testing.assert_array_equal(r.valid, s.valid)


def test_read_npz_multi_imu_index_and_error(tmp_path):
    rng = np.random.default_rng(8)
    gyro = rng.normal(size=(50, 3, 3))
    p = tmp_path / "array.npz"
    np.savez(p, t=np.arange(50) / 10.0, gyro=gyro)
    streams = read_npz(p)
    assert len(streams) == 3
    np.testing.assert_array_equal(read_npz(p, imu=2).omega, gyro[:, 2])
    with pytest.raises(InputError, match=r"imu in 0\.\.2"):
        read_npz(p, imu=3)
    with pytest.raises(InputError, match=r"holds 3 IMUs; pass imu=0\.\.2"):
        read_imu(p)


def test_read_npz_unknown_keys_message(tmp_path):
    p = tmp_path / "bad.npz"
    np.savez(p, time=np.arange(3.0), rates=np.zeros((3, 3)))
    with pytest.raises(FormatError, match=r"bad\.npz: expected keys 't' and 'omega'.*got \['rates', 'time'\]"):
        read_npz(p)


def test_read_npz_mimu_real_file_converts_counts_and_masks_clipping():
    if not DATA.is_dir():
        pytest.skip(NO_DATA)
    p = DATA / "mimu_8imu_array" / "npz" / "exp_1.npz"
    streams = read_npz(p)
    assert len(streams) == 8
    with np.load(p) as z:
        counts, t = z["gyro_counts"], z["t_s"]
    s2 = read_npz(p, imu=1)
    np.testing.assert_allclose(s2.omega, counts[:, 1] / 16.4 * DEG, rtol=1e-15)
    np.testing.assert_array_equal(s2.t, t)
    assert s2.rate_hz == pytest.approx(62.5)
    clipped = (np.abs(counts[:, 1].astype(int)) >= 32767).any(axis=1)
    np.testing.assert_array_equal(s2.valid, ~clipped)
    assert 0.005 < clipped.mean() < 0.05  # SOURCE.md: 2-3.5% of samples clip on some IMU


# ----------------------------------------------------------------------------- bags
@pytest.mark.parametrize("version", [1, 2])
def test_write_imu_bag_roundtrip(tmp_path, version):
    rng = np.random.default_rng(10 + version)
    a = _stream(rng, n=400, t0=1.7e9, name="a")
    b = ImuStream(a.t + 0.0037, rng.normal(size=(400, 3)), name="b")
    path = tmp_path / ("pair.bag" if version == 1 else "pair_bag")
    write_imu_bag(path, {"/imu0": a, "/imu1": b}, version=version)
    assert list_imu_topics(path) == ("/imu0", "/imu1")
    for topic, s in (("/imu0", a), ("/imu1", b)):
        r = read_bag(path, topic)
        np.testing.assert_array_equal(r.omega, s.omega)
        np.testing.assert_allclose(r.t, s.t, rtol=0, atol=1e-6)  # ns stamps, float64 at 1.7e9 s
        assert r.name == topic
    assert _leftovers(tmp_path, {path.name}) == []


def test_read_bag_several_topics_asks_for_one(tmp_path):
    rng = np.random.default_rng(12)
    path = tmp_path / "two.bag"
    write_imu_bag(path, {"/left/imu": _stream(rng), "/right/imu": _stream(rng)})
    with pytest.raises(InputError, match=r"several Imu topics \['/left/imu', '/right/imu'\]; pass topic="):
        read_bag(path)
    with pytest.raises(InputError, match=r"several Imu topics"):
        read_imu(path)
    assert read_imu(path, topic="/right/imu").name == "/right/imu"


def test_list_imu_topics_skips_other_message_types(tmp_path):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    rng = np.random.default_rng(13)
    path = tmp_path / "mixed"
    write_imu_bag(path, {"/imu": _stream(rng)}, version=2)
    # a second bag that also carries a non-Imu topic, written with rosbags directly
    store = get_typestore(Stores.ROS2_HUMBLE)
    String = store.types["std_msgs/msg/String"]
    mixed = tmp_path / "mixed2"
    with Writer(mixed, version=9) as w:
        c = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        w.write(c, 1, store.serialize_cdr(String(data="hi"), "std_msgs/msg/String"))
    assert list_imu_topics(path) == ("/imu",)
    assert list_imu_topics(mixed) == ()
    with pytest.raises(FormatError, match=r"expected a sensor_msgs/msg/Imu topic, got none.*/chatter"):
        read_bag(mixed)


def test_write_imu_bag_refuses_existing_path(tmp_path):
    rng = np.random.default_rng(14)
    path = tmp_path / "x.bag"
    write_imu_bag(path, {"/imu": _stream(rng)})
    before = path.read_bytes()
    with pytest.raises(FormatError, match="exists already; pass overwrite=True"):
        write_imu_bag(path, {"/imu": _stream(rng)})
    assert path.read_bytes() == before


def test_write_imu_bag_failure_keeps_old_bag(tmp_path, monkeypatch):
    from rosbags.typesys.store import Typestore

    rng = np.random.default_rng(15)
    path = tmp_path / "x.bag"
    old = _stream(rng, name="old")
    write_imu_bag(path, {"/imu": old})
    before = path.read_bytes()
    calls = {"n": 0}
    real = Typestore.serialize_ros1

    def failing(self, msg, typename):
        calls["n"] += 1
        if calls["n"] > 100:
            raise RuntimeError("simulated crash mid-write")
        return real(self, msg, typename)

    monkeypatch.setattr(Typestore, "serialize_ros1", failing)
    with pytest.raises(RuntimeError, match="simulated crash"):
        write_imu_bag(path, {"/imu": _stream(rng, n=1000)}, overwrite=True)
    assert calls["n"] > 100
    assert path.read_bytes() == before
    assert _leftovers(tmp_path, {"x.bag"}) == []
    np.testing.assert_array_equal(read_bag(path).omega, old.omega)


def _raw_ros1_imu_bag(path, stamps_ns, recv_ns, omega):
    """A ROS1 Imu bag written message by message with rosbags (header stamps chosen freely)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    with Writer(path) as w:
        c = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store)
        for k, (st, rc, om) in enumerate(zip(stamps_ns, recv_ns, omega)):
            msg = T["sensor_msgs/msg/Imu"](
                header=T["std_msgs/msg/Header"](seq=k, stamp=T["builtin_interfaces/msg/Time"](
                    sec=int(st // 10**9), nanosec=int(st % 10**9)), frame_id="imu"),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.zeros(9),
                angular_velocity=T["geometry_msgs/msg/Vector3"](x=om[0], y=om[1], z=om[2]),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                linear_acceleration_covariance=np.zeros(9))
            w.write(c, int(rc), store.serialize_ros1(msg, "sensor_msgs/msg/Imu"))


def test_read_bag_sorts_by_header_stamp(tmp_path):
    rng = np.random.default_rng(16)
    stamps = 5 * 10**9 + np.arange(20, dtype=np.int64) * 10_000_000
    perm = rng.permutation(20)  # received (and stored) out of stamp order
    omega = rng.normal(size=(20, 3))
    _raw_ros1_imu_bag(tmp_path / "j.bag", stamps[perm], 6 * 10**9 + np.arange(20) * 10**6, omega[perm])
    r = read_bag(tmp_path / "j.bag")
    np.testing.assert_allclose(r.t, stamps * 1e-9, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(r.omega, omega)


def test_read_bag_zero_header_stamps_fall_back_to_receive_time(tmp_path):
    rng = np.random.default_rng(17)
    recv = 7 * 10**9 + np.arange(30, dtype=np.int64) * 5_000_000
    _raw_ros1_imu_bag(tmp_path / "z.bag", np.zeros(30, dtype=np.int64), recv, rng.normal(size=(30, 3)))
    r = read_bag(tmp_path / "z.bag")
    np.testing.assert_allclose(r.t, recv * 1e-9, rtol=0, atol=1e-12)
    assert r.rate_hz == pytest.approx(200.0)


def test_read_bag_rejects_non_bag(tmp_path):
    p = tmp_path / "notes.bag"
    p.write_text("not a bag")
    with pytest.raises(FormatError, match=r"notes\.bag: could not read the bag"):
        read_bag(p)


# ----------------------------------------------------------------------------- JSON
def test_write_json_roundtrip(tmp_path):
    cal = _cal(np.random.default_rng(20))
    r = read_json(write_json(cal, tmp_path / "cal.json"))
    for name in ("R_1_2", "scale_1", "scale_2", "bias", "scale_observable", "covariance", "snr", "noise_std",
                 "skew_rotation_covariance"):
        np.testing.assert_array_equal(getattr(r, name), getattr(cal, name), err_msg=name)
    assert np.isinf(r.covariance[8, 8]) and np.isnan(r.residual_rms)
    for name in ("configuration", "gauge", "n_samples", "time_offset_s", "time_offset_std_s", "notes", "rigid",
                 "method", "bias_segments"):
        assert getattr(r, name) == getattr(cal, name), name
    def refuse(token):
        raise AssertionError(f"non-standard JSON literal {token}")
    json.loads((tmp_path / "cal.json").read_text(), parse_constant=refuse)  # strict JSON: no NaN/Infinity literals


def test_read_json_wrong_version_message(tmp_path):
    p = tmp_path / "cal.json"
    write_json(_cal(np.random.default_rng(21)), p)
    d = json.loads(p.read_text())
    d["format_version"] = "0.1"
    p.write_text(json.dumps(d))
    with pytest.raises(FormatError, match=r"cal\.json: .*expected format_version '1\.5' \(or an earlier '1\.0', '1\.1', '1\.2', '1\.3', '1\.4'\), "
                                         r"got '0\.1'"):
        read_json(p)


def test_read_json_syntax_error_message(tmp_path):
    p = tmp_path / "cal.json"
    p.write_text('{"format_version": "1.0",\n  "R_1_2": [1, 2,\n')
    with pytest.raises(FormatError, match=r"cal\.json: expected JSON, got a syntax error at line \d+"):
        read_json(p)


def test_write_json_failure_mid_write_keeps_old_file(tmp_path, monkeypatch):
    rng = np.random.default_rng(22)
    p = tmp_path / "cal.json"
    write_json(_cal(rng), p)
    before = p.read_bytes()

    def broken_fsync(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(writers_mod.os, "fsync", broken_fsync)
    with pytest.raises(FormatError, match="No space left on device"):
        write_json(_cal(rng, gauge="other"), p)
    assert p.read_bytes() == before
    assert _leftovers(tmp_path, {"cal.json"}) == []


def test_write_json_keeps_file_mode(tmp_path):
    p = tmp_path / "cal.json"
    cal = _cal(np.random.default_rng(23))
    write_json(cal, p)
    os.chmod(p, 0o640)
    write_json(cal, p)
    assert (os.stat(p).st_mode & 0o777) == 0o640


# ----------------------------------------------------------------------------- YAML exports
def test_write_kalibr_imu_chain_matrices_parse_back(tmp_path):
    cal = _cal(np.random.default_rng(30))
    p = write_kalibr_imu_chain(cal, tmp_path / "imu.yaml", topics=("/a", "/b"), update_rate=(100.0, 200.0))
    y = yaml.safe_load(p.read_text())
    T0, T1 = np.array(y["imu0"]["T_i_b"]), np.array(y["imu1"]["T_i_b"])
    np.testing.assert_array_equal(T0, np.eye(4))
    np.testing.assert_array_equal(T1[:3, :3], cal.R_1_2.T)
    np.testing.assert_array_equal(T1[:3, 3], np.zeros(3))
    np.testing.assert_array_equal(T1[3], [0, 0, 0, 1])
    g = np.exp(np.mean(np.log(cal.scale_1)))   # relative to imu0: a general mounting divided by imu0's geometric mean
    np.testing.assert_allclose(np.array(y["imu0"]["gyroscopes"]["M"]), np.diag(cal.scale_1 / g), rtol=1e-15)
    # an undetermined scale factor (scale_2 z here) is not written as measured: 1 in its place
    np.testing.assert_allclose(np.array(y["imu1"]["gyroscopes"]["M"]),
                               np.diag(np.where(cal.scale_observable[1], cal.scale_2 / g, 1.0)), rtol=1e-15)
    np.testing.assert_array_equal(np.array(y["imu1"]["gyroscopes"]["C_gyro_i"]), np.eye(3))
    np.testing.assert_array_equal(np.array(y["imu1"]["gyroscopes"]["A"]), np.zeros((3, 3)))
    assert y["imu0"]["time_offset"] == 0.0 and y["imu1"]["time_offset"] == cal.time_offset_s
    assert (y["imu0"]["rostopic"], y["imu1"]["rostopic"]) == ("/a", "/b")
    assert (y["imu0"]["update_rate"], y["imu1"]["update_rate"]) == (100.0, 200.0)
    assert y["imu1"]["model"] == "scale-misalignment" and y["imu1"]["translation_estimated"] is False
    assert "TRANSLATION IS NOT ESTIMATED" in p.read_text()


def test_write_kalibr_imu_chain_reproduces_A(tmp_path):
    """Kalibr's gyro models M_i C_i_b chained from imu1 to imu0 give A = S_1 R_1_2 S_2^-1 (Eq. 4)."""
    cal = _cal(np.random.default_rng(31), scale_observable=[[True] * 3] * 2)   # every scale determined
    y = yaml.safe_load(write_kalibr_imu_chain(cal, tmp_path / "imu.yaml").read_text())
    M0, M1 = np.array(y["imu0"]["gyroscopes"]["M"]), np.array(y["imu1"]["gyroscopes"]["M"])
    C0, C1 = np.array(y["imu0"]["T_i_b"])[:3, :3], np.array(y["imu1"]["T_i_b"])[:3, :3]
    A = (M0 @ C0) @ np.linalg.inv(M1 @ C1)  # omega_0 = M0 C0 w_b, omega_1 = M1 C1 w_b
    np.testing.assert_allclose(A, cal.A, rtol=0, atol=1e-14)


def test_write_kalibr_imu_chain_rejects_nonfinite_scale(tmp_path):
    cal = _cal(np.random.default_rng(33), scale_2=[1.0, np.nan, 1.0])
    with pytest.raises(FormatError, match=r"cal\.scale_2: Kalibr/OpenVINS files need finite values"):
        write_kalibr_imu_chain(cal, tmp_path / "imu.yaml")
    assert list(tmp_path.iterdir()) == []


def test_write_openvins_imu_chain_parses_back(tmp_path):
    cal = _cal(np.random.default_rng(34))
    p = write_openvins_imu_chain(cal, tmp_path / "kalibr_imu_chain.yaml", update_rate=400.0)
    text = p.read_text()
    assert text.splitlines()[0] == "%YAML:1.0"
    y = yaml.safe_load(text.split("\n", 1)[1])
    g = np.exp(np.mean(np.log(cal.scale_1)))   # relative to imu0: a general mounting divided by imu0's geometric mean
    for i, scale in enumerate((cal.scale_1, cal.scale_2)):
        imu = y[f"imu{i}"]
        np.testing.assert_allclose(np.array(imu["Tw"]), np.diag(np.where(cal.scale_observable[i], scale / g, 1.0)),
                                   rtol=1e-15)
        np.testing.assert_array_equal(np.array(imu["R_IMUtoGYRO"]), np.eye(3))
        np.testing.assert_array_equal(np.array(imu["Ta"]), np.eye(3))
        np.testing.assert_array_equal(np.array(imu["R_IMUtoACC"]), np.eye(3))
        np.testing.assert_array_equal(np.array(imu["Tg"]), np.zeros((3, 3)))
        assert imu["model"] == "kalibr" and imu["update_rate"] == 400.0
        for key in ("accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
                    "gyroscope_random_walk", "rostopic", "time_offset", "T_i_b"):
            assert key in imu, key
    np.testing.assert_array_equal(np.array(y["imu1"]["T_i_b"])[:3, :3], cal.R_1_2.T)
    assert y["imu1"]["time_offset"] == cal.time_offset_s


def test_write_openvins_imu_chain_tiny_values_stay_floats(tmp_path):
    """YAML 1.1 reads '1e-05' as a string; the writer must emit '1.0e-05'."""
    cal = _cal(np.random.default_rng(35), scale_1=[1.0, 1e-5 + 1.0, 1.0], time_offset_s=1e-5)
    y = yaml.safe_load(write_openvins_imu_chain(cal, tmp_path / "c.yaml").read_text().split("\n", 1)[1])
    assert isinstance(y["imu1"]["time_offset"], float) and y["imu1"]["time_offset"] == 1e-5
    assert all(isinstance(v, float) for row in y["imu0"]["Tw"] for v in row)


def test_kalibr_T_i_b_maps_gyro1_rates_to_gyro2(tmp_path):
    """Noise-free rigid pair: T_i_b of imu1 applied to gyro 1's true rate gives gyro 2's true rate."""
    from fusion_gyrocal.evaluate.sim import simulate_pair
    sim = simulate_pair(n=200, noise_std=0.0, bias_walk_std=0.0, bias_1=np.zeros(3), bias_2=np.zeros(3), rng=36)
    cal = _cal(np.random.default_rng(36), R_1_2=sim.R_1_2, scale_1=np.ones(3), scale_2=np.ones(3))
    y = yaml.safe_load(write_kalibr_imu_chain(cal, tmp_path / "imu.yaml").read_text())
    R_i_b = np.array(y["imu1"]["T_i_b"])[:3, :3]
    np.testing.assert_allclose(sim.omega_true_1 @ R_i_b.T, sim.omega_2, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- dispatch
def test_read_imu_dispatches_on_suffix_and_content(tmp_path):
    rng = np.random.default_rng(40)
    s = _stream(rng, n=100)
    write_csv(s, tmp_path / "a.csv")
    write_npz(s, tmp_path / "b.npz")
    write_imu_bag(tmp_path / "c.bag", {"/imu": s})
    write_imu_bag(tmp_path / "d", {"/imu": s}, version=2)
    (tmp_path / "e.log").write_bytes((tmp_path / "a.csv").read_bytes())
    for name, fmt in (("a.csv", "csv"), ("b.npz", "npz"), ("c.bag", "bag"), ("d", "bag"), ("e.log", "csv")):
        assert detect_format(tmp_path / name) == fmt
        np.testing.assert_allclose(read_imu(tmp_path / name).omega, s.omega, rtol=0, atol=0)
    with pytest.raises(InputError, match="format: expected one of"):
        read_imu(tmp_path / "a.csv", format="matlab")


def test_read_imu_missing_file_message(tmp_path):
    with pytest.raises(FormatError, match="nope.csv: no such file"):
        read_imu(tmp_path / "nope.csv")


# ----------------------------------------------------------------------------- end to end
def test_read_bag_feeds_calibrate_pair_with_time_offset(tmp_path):
    """Two Imu topics on different clocks -> bag -> read -> calibrate -> Kalibr time_offset."""
    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, rotation_error, simulate_pair

    sim = simulate_pair(n=6000, rng=50)
    offset = 0.0234  # added to gyro 2's stamps puts them on gyro 1's clock
    write_imu_bag(tmp_path / "pair", {"/imu0": ImuStream(100.0 + sim.t, sim.omega_1),
                                      "/imu1": ImuStream(100.0 + sim.t - offset, sim.omega_2)}, version=2)
    g1, g2 = read_bag(tmp_path / "pair", "/imu0"), read_bag(tmp_path / "pair", "/imu1")
    cal = calibrate_pair(g1.omega, g2.omega, t_1=g1.t, t_2=g2.t, noise_std=PAPER_NOISE_STD)
    assert abs(cal.time_offset_s - offset) < 5 * cal.time_offset_std_s + 1e-9  # + ns rounding of the stamps
    assert rotation_error(cal.R_1_2, sim.R_1_2) < 5 * np.linalg.norm(cal.rotation_std_rad)
    y = yaml.safe_load(write_kalibr_imu_chain(cal, tmp_path / "imu.yaml").read_text())
    assert y["imu1"]["time_offset"] == cal.time_offset_s
    np.testing.assert_array_equal(read_json(write_json(cal, tmp_path / "cal.json")).R_1_2, cal.R_1_2)


def test_read_npz_one_valid_mask_applies_to_every_imu(tmp_path):
    t = np.arange(50) / 100.0
    w = np.random.default_rng(0).standard_normal((50, 3, 3))
    valid = np.ones(50, bool)
    valid[7] = False
    np.savez(tmp_path / "multi.npz", t=t, omega=w, valid=valid)
    s = read_npz(tmp_path / "multi.npz", 2)
    assert not s.valid[7] and s.valid.sum() == 49
    np.savez(tmp_path / "bad.npz", t=t, omega=w, valid=np.ones((50, 2), bool))
    with pytest.raises(FormatError, match=r"expected 'valid' of shape \(50,\) or \(50, 3\)"):
        read_npz(tmp_path / "bad.npz", 0)


def test_read_json_not_utf8_or_not_a_regular_file_is_format_error(tmp_path):
    p = tmp_path / "cal.json"
    p.write_bytes(b'{"format_version": "1.1", "gauge": "\xff\xfe"}')
    with pytest.raises(FormatError, match=r"cal\.json: expected UTF-8 JSON, got undecodable bytes at offset"):
        read_json(p)
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    with pytest.raises(FormatError, match="a FIFO"):
        read_json(fifo)       # refused before opening (opening a FIFO would block)
