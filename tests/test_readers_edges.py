"""Readers at the edge of real files: byte-order marks, spreadsheet junk rows, timestamp units,
ROS2 storage files given directly, and broken inputs that must be one-line FormatErrors."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

from fusion_gyrocal.errors import FormatError, GyroCalError, InputError
from fusion_gyrocal.io import ImuStream, detect_format, read_bag, read_csv, read_imu, write_csv, write_imu_bag
from fusion_gyrocal.io import text as text_mod

EUROC_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
T0_NS = 1403636579758555392


def _euroc_rows(n=20, seed=0):
    g = np.random.default_rng(seed).normal(size=(n, 3))
    rows = [f"{T0_NS + k * 5_000_000}," + ",".join(f"{v:.17g}" for v in g[k]) + ",9.81,0,0" for k in range(n)]
    return rows, g


# ----------------------------------------------------------------------------- encodings
def test_read_csv_utf8_bom_header_is_read(tmp_path):
    p = tmp_path / "excel.csv"
    p.write_bytes("\ufefft,gyro_x,gyro_y,gyro_z\r\n0,1,2,3\r\n0.01,4,5,6\r\n0.02,7,8,9\r\n".encode())
    s = read_csv(p)
    np.testing.assert_array_equal(s.t, [0, 0.01, 0.02])
    np.testing.assert_array_equal(s.omega[:, 0], [1, 4, 7])
    q = tmp_path / "nohead.csv"
    q.write_bytes("\ufeff0,1,2,3\n0.01,4,5,6\n".encode())
    np.testing.assert_array_equal(read_imu(q).omega[1], [4, 5, 6])


def test_read_csv_utf16_is_refused_with_the_fix(tmp_path):
    p = tmp_path / "unicode.txt"
    p.write_bytes("t\tgyro_x\tgyro_y\tgyro_z\n0\t1\t2\t3\n".encode("utf-16"))
    with pytest.raises(FormatError, match=r"unicode\.txt: expected UTF-8 text, got UTF-16/32 .* 'CSV UTF-8'"):
        read_imu(p)


# ----------------------------------------------------------------------------- spreadsheet junk
@pytest.mark.parametrize("trailer, n_junk", [("\n\n", 2), (",,,,,,\n,,,,,,\n", 2),
                                             (",,,,,,\n\n,,,,,,\nsaved by a spreadsheet\n", 4),
                                             ("\n ,, ,,,,\r\nEnd of file", 3)])
def test_read_csv_euroc_trailing_junk_is_dropped_with_a_note(tmp_path, monkeypatch, trailer, n_junk):
    rows, g = _euroc_rows()
    p = tmp_path / "data.csv"
    p.write_text(EUROC_HEADER + "\n" + "\n".join(rows) + "\n" + trailer)
    for threshold in (float("inf"), 0):  # np.loadtxt and pandas
        monkeypatch.setattr(text_mod, "PANDAS_MIN_BYTES", threshold)
        s = read_csv(p)
        assert len(s) == 20
        np.testing.assert_array_equal(s.omega, g)
        assert np.abs(np.diff(s.t) - 0.005).max() < 3e-7  # float64 spacing at 1.4e9 s is 2.4e-7
        assert len(s.notes) == 1 and s.notes[0].startswith(f"dropped {n_junk} trailing lines without numbers")


@pytest.mark.parametrize("middle, message", [
    (",,,,,,", r"data\.csv: data row 11 has no timestamp"),
    ("saved by a spreadsheet", r"data\.csv: expected numeric data in columns .*'saved by a spreadsheet'"),
])
def test_read_csv_junk_between_data_rows_is_refused(tmp_path, middle, message):
    rows, _ = _euroc_rows()
    p = tmp_path / "data.csv"
    p.write_text(EUROC_HEADER + "\n" + "\n".join(rows[:10] + [middle] + rows[10:]) + "\n")
    with pytest.raises(FormatError, match=message):
        read_csv(p)


def test_read_csv_blank_lines_between_rows_are_skipped(tmp_path):
    rows, g = _euroc_rows()
    p = tmp_path / "data.csv"
    p.write_text(EUROC_HEADER + "\n" + "\n".join(rows[:10] + [""] + rows[10:]) + "\n")
    s = read_csv(p)
    np.testing.assert_array_equal(s.omega, g)
    assert s.notes == ()


# ----------------------------------------------------------------------------- timestamp units
def _csv(path, header, times):
    path.write_text(header + "\n" + "".join(f"{t},{0.1},{0.2},{0.3}\n" for t in times))
    return path


def test_read_csv_integer_ns_under_plain_timestamp_is_refused_naming_ns(tmp_path):
    ns = [T0_NS + k * 5_000_000 for k in range(10)]
    p = _csv(tmp_path / "ns.csv", "timestamp,gyro_x,gyro_y,gyro_z", ns)
    with pytest.raises(InputError, match=r"ns\.csv: timestamps of column 'timestamp' read as s \(the default\) "
                                         r"have a median step of 5e\+06 s = 2e-07 Hz, .* they look like ns "
                                         r"\(200 Hz\): pass time_unit='ns' \(CLI --time-unit ns\)"):
        read_csv(p)
    s = read_csv(p, time_unit="ns")  # integers keep every digit
    whole, frac = divmod(T0_NS, 10**9)
    assert s.t[0] == whole + frac / 1e9
    assert np.abs(np.diff(s.t) - 0.005).max() < 3e-7  # float64 spacing at 1.4e9 s is 2.4e-7


def test_read_csv_milliseconds_read_as_seconds_are_refused(tmp_path):
    p = _csv(tmp_path / "ms.csv", "time,gyro_x,gyro_y,gyro_z", [1000.0 + 5 * k for k in range(10)])
    with pytest.raises(InputError, match=r"they look like ms \(200 Hz\): pass time_unit='ms'"):
        read_csv(p)
    np.testing.assert_allclose(np.diff(read_csv(p, time_unit="ms").t), 0.005, rtol=0, atol=1e-12)


def test_read_csv_header_unit_contradicted_by_values_is_refused(tmp_path):
    p = _csv(tmp_path / "hdr.csv", "timestamp [ns],gyro_x,gyro_y,gyro_z", [12.0 + 0.01 * k for k in range(10)])
    with pytest.raises(InputError, match=r"read as ns \(as the header 'timestamp \[ns\]' says\) .* they look "
                                         r"like s \(100 Hz\)"):
        read_csv(p)
    with pytest.raises(InputError, match=r"read as ms \(time_unit= given\)"):
        read_csv(p, time_unit="ms")
    assert read_csv(p, time_unit="s").rate_hz == pytest.approx(100.0)


def test_read_csv_plausible_seconds_read_without_notes(tmp_path):
    s = ImuStream(1.7e9 + np.arange(50) / 400.0, np.zeros((50, 3)))
    p = write_csv(s, tmp_path / "epoch.csv")
    r = read_csv(p)
    assert r.rate_hz == pytest.approx(400.0, rel=1e-3) and r.notes == ()


# ----------------------------------------------------------------------------- ROS2 storage files
def test_read_bag_ros2_storage_file_given_directly(tmp_path):
    s = ImuStream(100.0 + np.arange(30) / 100.0, np.random.default_rng(1).normal(size=(30, 3)))
    folder = write_imu_bag(tmp_path / "bag2", {"/imu": s}, version=2)
    db3 = next(folder.glob("*.db3"))
    assert detect_format(db3) == "bag"
    np.testing.assert_array_equal(read_imu(db3).omega, read_imu(folder).omega)
    lone = tmp_path / "lone"
    lone.mkdir()
    shutil.copy(db3, lone / db3.name)
    # without metadata.yaml the storage file is read on its own (issue 24: no 'ros2 bag reindex' needed)
    np.testing.assert_array_equal(read_bag(lone / db3.name).omega, read_imu(folder).omega)


# ----------------------------------------------------------------------------- broken inputs
def _broken_inputs(tmp_path):
    np.savez(tmp_path / "ok.npz", t=np.arange(10.0), omega=np.zeros((10, 3)))
    ok = (tmp_path / "ok.npz").read_bytes()
    (tmp_path / "empty.npz").write_bytes(b"")
    (tmp_path / "truncated.npz").write_bytes(ok[:len(ok) // 2])
    (tmp_path / "random.npz").write_bytes(np.random.default_rng(0).bytes(300))
    np.save(tmp_path / "array.npy", np.zeros(3))
    os.replace(tmp_path / "array.npy", tmp_path / "array.npz")
    np.savez(tmp_path / "objects.npz", t=np.array([object()], dtype=object))
    (tmp_path / "short.csv").write_text("t,gyro_x,gyro_y,gyro_z\n0,1,2,3\n0.01,1,2\n0.02,1,2,3\n")
    (tmp_path / "stray.db3").write_bytes(b"not sqlite")
    (tmp_path / "norows.txt").write_text("// Update Rate: 100.0Hz\nPacketCounter\tGyr_X\tGyr_Y\tGyr_Z\n")
    (tmp_path / "badrate.txt").write_text("// Update Rate: 1eHz\nPacketCounter\tGyr_X\tGyr_Y\tGyr_Z\n1\t0\t0\t0\n")
    return {
        "empty.npz": r"empty\.npz: expected a numpy \.npz archive \(zip\), got an empty file",
        "truncated.npz": r"truncated\.npz: expected a complete numpy \.npz archive",
        "random.npz": r"random\.npz: expected a numpy \.npz archive \(zip\), got a file that is not a zip archive",
        "array.npz": r"array\.npz: expected a numpy \.npz archive \(zip\), got a \.npy array",
        "objects.npz": r"objects\.npz: expected a complete numpy \.npz archive of numeric arrays, got an object array",
        "short.csv": r"short\.csv: expected numeric data in columns \[0, 1, 2, 3\], .*row 2",
        "stray.db3": r"stray\.db3: could not read the bag: .*file is not a database",   # read alone (issue 24)
        "norows.txt": r"norows\.txt: expected data rows after the header row, got none",
        "badrate.txt": r"badrate\.txt: expected a positive rate in Hz in the line '// Update Rate: 1eHz'",
    }


def test_read_imu_broken_files_are_one_line_format_errors(tmp_path):
    for fname, message in _broken_inputs(tmp_path).items():
        with pytest.raises(FormatError, match=message) as err:
            read_imu(tmp_path / fname)
        assert "\n" not in str(err.value), fname


def test_read_imu_fifo_is_refused_before_opening(tmp_path):
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this platform")
    fifo = tmp_path / "gyro.csv"
    os.mkfifo(fifo)  # opening it for reading would block until a writer comes
    for call in (lambda: read_imu(fifo), lambda: read_csv(fifo), lambda: detect_format(fifo),
                 lambda: read_imu(fifo, format="xsens"), lambda: read_imu(fifo, format="npz"),
                 lambda: read_bag(fifo)):
        with pytest.raises(FormatError, match=r"gyro\.csv: expected a .*, got a FIFO"):
            call()


def test_read_imu_errors_stay_inside_gyrocal_error(tmp_path):
    (tmp_path / "x.mcap").write_bytes(b"\x89MCAP0\r\n")
    (tmp_path / "metadata.yaml").write_text("not: [a bag")
    with pytest.raises(GyroCalError, match=r"could not read the bag"):
        read_imu(tmp_path / "x.mcap")
