"""Xsens MT Manager text exports: the real files of several MT Manager versions, and synthetic files
of the variants the real ones do not cover (semicolon and space delimiters, UTC and Euler columns,
counter and clock wraps), written with the real files' header structure."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from fusion_gyrocal.errors import FormatError, InputError, OptionError
from fusion_gyrocal.evaluate.sim import shared_data_dir
from fusion_gyrocal.io import detect_format, read_imu, read_xsens
from fusion_gyrocal.io import text as text_mod

EXPORTS = shared_data_dir() / "xsens_mt_exports"
NO_EXPORTS = "shared/data/xsens_mt_exports not present (real recordings are only in the project checkout)"

# The comment block of an MT Manager 2022.2 export (as in the real files), and of an MT 4.x one.
MT2022_HEADER = [
    "// General information: ",
    "//  MT Manager version: 2022.2.0 ",
    "//  XDA version: 2022.2.0 build 7381 rev 124627 built on 2023-07-19",
    "// Device information: ",
    "//  DeviceId: 00B42D4B",
    "//  ProductCode: MTW2-3A7G6",
    "//  Firmware Version: 4.4.0",
    "//  Hardware Version: 1.1.0",
    "// Device settings: ",
    "//  Filter Profile: human(46.1)",
    "//  Option Flags: Orientation Smoother Disabled, Position/Velocity Smoother Disabled, Continuous Zero "
    "Rotation Update Disabled, AHS Disabled, ICC Disabled",
    "// Coordinate system: ENU",
]
MT4_HEADER = ["// Start Time: Unknown", "// Update Rate: 100.0Hz", "// Filter Profile: human (46.1)",
              "// Firmware Version: 4.4.0"]


def _export(path, comments, columns, rows, delim="\t"):
    """Write an export: comment lines, the header row, one row per dict (missing keys are empty fields)."""
    lines = list(comments) + [delim.join(columns)]
    lines += [delim.join(str(r.get(c, "")) for c in columns) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def _independent_gyro(path):
    """Gyr_X/Y/Z of an export parsed without the library: '//' lines skipped, fields split on the
    header's delimiter one by one, empty or 'NaN' fields NaN."""
    lines = [ln.rstrip("\r\n") for ln in path.read_text().splitlines()]
    body = [ln for ln in lines if not ln.startswith("//")]
    delim = "\t" if "\t" in body[0] else "," if "," in body[0] else ";" if ";" in body[0] else " "
    head = body[0].split(delim)
    k = [head.index(c) for c in ("Gyr_X", "Gyr_Y", "Gyr_Z")]
    rows = [ln.split(delim) for ln in body[1:] if ln.strip()]
    counter = np.array([int(r[head.index("PacketCounter")]) for r in rows])
    gyro = np.array([[float(r[j]) if r[j].strip() else np.nan for j in k] for r in rows])
    return counter, gyro


# ----------------------------------------------------------------------------- the real exports
REAL = {  # file: (rows, rate stated in the file or None)
    "MT2022_ACC_GYRO_ROT_ALL_TAB_NAN_00B42D4B.txt": (5, None),
    "MT2022_ACC_GYRO_ROT_MAT_COMMA_00B42D4B.txt": (5, None),
    "MT46_01-000_00B42D4D.txt": (5, 100.0),
    "MT_01200454_000-000_00B40DE4.txt": (4, None),
    "test1_00B421E6.txt": (3, 100.0),
}


@pytest.mark.parametrize("fname", sorted(REAL))
def test_read_xsens_real_exports_match_an_independent_parse(fname):
    if not EXPORTS.is_dir():
        pytest.skip(NO_EXPORTS)
    path = EXPORTS / fname
    rows, stated = REAL[fname]
    counter, gyro = _independent_gyro(path)
    assert detect_format(path) == "xsens"
    if stated is None:  # MT Manager 2019/2022: no rate line, SampleTimeFine empty: the rate must be given
        with pytest.raises(FormatError, match=rf"{fname}: no sample rate .* pass rate_hz="):
            read_imu(path)
    s = read_imu(path, rate_hz=100.0) if stated is None else read_imu(path)
    assert len(s) == rows == len(gyro)
    np.testing.assert_array_equal(s.omega, gyro)  # every row, in place
    np.testing.assert_allclose(s.t, counter / 100.0, rtol=0, atol=1e-12)
    assert s.rate_hz == 100.0 and s.valid.all()
    assert s.notes[0].startswith("time from PacketCounter")


def test_read_xsens_real_export_without_gyro_names_the_missing_columns():
    if not EXPORTS.is_dir():
        pytest.skip(NO_EXPORTS)
    path = EXPORTS / "MT2022_ACC_00B42D4B.txt"
    assert detect_format(path) == "xsens"
    with pytest.raises(FormatError, match=r"MT2022_ACC_00B42D4B\.txt: no gyro columns \(Gyr_X/Gyr_Y/Gyr_Z\); "
                                          r"columns found: PacketCounter, SampleTimeFine, .*Acc_Z$"):
        read_imu(path)


# ----------------------------------------------------------------------------- synthetic variants
def test_read_xsens_semicolon_sampletimefine_wrap_and_euler(tmp_path):
    rng = np.random.default_rng(1)
    n = 12
    fine = (2**32 - 500 + 100 * np.arange(n)) % 2**32  # 10 kHz ticks at 100 Hz, wrapping after row 4
    fine = np.delete(fine, 7)  # a dropped sample leaves a gap
    g = rng.normal(size=(n - 1, 3))
    cols = ["PacketCounter", "SampleTimeFine", "Acc_X", "Acc_Y", "Acc_Z", "Gyr_X", "Gyr_Y", "Gyr_Z",
            "Roll", "Pitch", "Yaw"]
    rows = [dict(PacketCounter=f"{k:05d}", SampleTimeFine=int(fine[k]), Acc_X=0.1, Acc_Y=0.2, Acc_Z=9.8,
                 Gyr_X=f"{g[k, 0]:.17g}", Gyr_Y=f"{g[k, 1]:.17g}", Gyr_Z=f"{g[k, 2]:.17g}", Roll=1.0, Pitch=2.0, Yaw=3.0)
            for k in range(n - 1)]
    p = _export(tmp_path / "semi.txt", MT2022_HEADER, cols, rows, delim=";")
    assert detect_format(p) == "xsens"
    s = read_xsens(p)
    ticks = 2**32 - 500 + 100 * np.delete(np.arange(n), 7)
    np.testing.assert_allclose(s.t, ticks / 1e4, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(s.omega, g)
    assert s.notes == ("time from SampleTimeFine (the device's 10 kHz clock)",)


def test_read_xsens_space_delimited_keeps_empty_fields_in_place(tmp_path):
    rng = np.random.default_rng(2)
    n = 8
    g = rng.normal(size=(n, 3))
    cols = ["PacketCounter", "SampleTimeFine", "Year", "Month", "Day", "Second", "Acc_X", "Acc_Y", "Acc_Z",
            "Gyr_X", "Gyr_Y", "Gyr_Z", "Mat[1][1]", "Mat[2][1]", "Mat[3][1]", "Mat[1][2]", "Mat[2][2]",
            "Mat[3][2]", "Mat[1][3]", "Mat[2][3]", "Mat[3][3]"]
    rows = []
    for k in range(n):
        r = dict(PacketCounter=f"{100 + k:05d}", SampleTimeFine=1000 + 100 * k, Acc_Y=0.2, Acc_Z=9.8,
                 Gyr_X=f"{g[k, 0]:.17g}", Gyr_Y=f"{g[k, 1]:.17g}", Gyr_Z=f"{g[k, 2]:.17g}")
        r.update({c: 0.5 + j for j, c in enumerate(cols[12:])})
        if k != 2:
            r["Acc_X"] = 0.1  # row 2 lacks Acc_X: one more empty field before the gyro
        rows.append(r)
    del rows[5]["Gyr_Y"]  # a packet without its gyro y: NaN in place, masked, not dropped
    g[5, 1] = np.nan
    p = _export(tmp_path / "space.txt", MT2022_HEADER, cols, rows, delim=" ")
    assert "  " in p.read_text()  # consecutive delimiters really are in the file
    s = read_imu(p)
    assert len(s) == n
    np.testing.assert_array_equal(s.omega, g)
    np.testing.assert_array_equal(s.valid, np.arange(n) != 5)
    np.testing.assert_allclose(s.t, (1000 + 100 * np.arange(n)) / 1e4, rtol=0, atol=1e-12)


def _utc_row(when: dt.datetime, valid=7):
    return dict(UTC_Nano=when.microsecond * 1000, UTC_Year=when.year, UTC_Month=when.month, UTC_Day=when.day,
                UTC_Hour=when.hour, UTC_Minute=when.minute, UTC_Second=when.second, UTC_Valid=valid)


UTC_COLUMNS = ["PacketCounter", "SampleTimeFine", "UTC_Nano", "UTC_Year", "UTC_Month", "UTC_Day", "UTC_Hour",
               "UTC_Minute", "UTC_Second", "UTC_Valid", "Acc_X", "Acc_Y", "Acc_Z", "Gyr_X", "Gyr_Y", "Gyr_Z",
               "Quat_q0", "Quat_q1", "Quat_q2", "Quat_q3"]


def test_read_xsens_utc_columns_across_new_year(tmp_path):
    rng = np.random.default_rng(3)
    t0 = dt.datetime(2023, 12, 31, 23, 59, 59, 970000, tzinfo=dt.timezone.utc)
    when = [t0 + dt.timedelta(milliseconds=10 * k) for k in range(8)]
    g = rng.normal(size=(8, 3))
    rows = [dict(PacketCounter=k, **_utc_row(w), Gyr_X=f"{g[k, 0]:.17g}", Gyr_Y=f"{g[k, 1]:.17g}", Gyr_Z=f"{g[k, 2]:.17g}",
                 Quat_q0=1, Quat_q1=0, Quat_q2=0, Quat_q3=0) for k, w in enumerate(when)]
    p = _export(tmp_path / "utc.txt", MT2022_HEADER, UTC_COLUMNS, rows)  # SampleTimeFine empty
    s = read_xsens(p)
    np.testing.assert_array_equal(s.t, [w.timestamp() for w in when])
    np.testing.assert_array_equal(s.omega, g)
    assert s.notes == ("time from the UTC columns (SampleTimeFine is empty)",)


def test_read_xsens_invalid_utc_falls_back_to_the_counter(tmp_path):
    t0 = dt.datetime(2024, 5, 1, 12, 0, 0, tzinfo=dt.timezone.utc)
    rows = [dict(PacketCounter=65534 + k - (65536 if 65534 + k > 65535 else 0), **_utc_row(
        t0 + dt.timedelta(milliseconds=10 * k), valid=0 if k == 3 else 7), Gyr_X=0.1, Gyr_Y=0.2, Gyr_Z=0.3)
        for k in range(6)]
    p = _export(tmp_path / "badutc.txt", MT4_HEADER, UTC_COLUMNS, rows)
    s = read_xsens(p)
    np.testing.assert_allclose(s.t, (65534 + np.arange(6)) / 100.0, rtol=0, atol=1e-12)  # the wrap is undone
    assert s.notes == ("time from PacketCounter at the stated 100 Hz (SampleTimeFine is empty; UTC is not valid "
                       "(UTC_Valid without bit 0x04) in 1 rows)",)


def test_read_xsens_partial_sampletimefine_is_not_mixed_with_the_counter(tmp_path):
    cols = ["PacketCounter", "SampleTimeFine", "Gyr_X", "Gyr_Y", "Gyr_Z"]
    rows = [dict(PacketCounter=k, SampleTimeFine=100 * k if k != 2 else "", Gyr_X=1, Gyr_Y=2, Gyr_Z=3)
            for k in range(5)]
    p = _export(tmp_path / "partial.txt", MT4_HEADER, cols, rows, delim=",")
    s = read_xsens(p)
    np.testing.assert_allclose(s.t, np.arange(5) / 100.0, rtol=0, atol=1e-12)
    assert "SampleTimeFine is missing in 1 of 5 rows" in s.notes[0]


def test_read_xsens_rate_hz_option_and_its_checks(tmp_path):
    cols = ["PacketCounter", "Acc_X", "Acc_Y", "Acc_Z", "Gyr_X", "Gyr_Y", "Gyr_Z"]
    rows = [dict(PacketCounter=k, Acc_X=0, Acc_Y=0, Acc_Z=9.8, Gyr_X=k, Gyr_Y=0, Gyr_Z=0) for k in range(4)]
    p = _export(tmp_path / "norate.txt", MT2022_HEADER, cols, rows)
    with pytest.raises(FormatError, match=r"norate\.txt: no sample rate to time the samples by PacketCounter "
                                          r"\(no '// Update Rate:' or '// Sample rate:' line\); pass rate_hz="):
        read_xsens(p)
    assert read_imu(p, rate_hz=40.0).t[-1] == 3 / 40.0
    with pytest.raises(OptionError, match="rate_hz: expected a positive sample rate in Hz, got -1.0"):
        read_xsens(p, rate_hz=-1)
    q = _export(tmp_path / "stated.txt", MT4_HEADER, cols, rows)
    s = read_xsens(q, rate_hz=50.0)
    assert s.rate_hz == 50.0 and "rate_hz=50 overrides the file's stated 100 Hz" in s.notes


def test_read_xsens_clock_stepping_back_is_refused(tmp_path):
    cols = ["PacketCounter", "SampleTimeFine", "Gyr_X", "Gyr_Y", "Gyr_Z"]
    fine = [1000, 1100, 1200, 1150, 1300]
    rows = [dict(PacketCounter=k, SampleTimeFine=f, Gyr_X=0, Gyr_Y=0, Gyr_Z=0) for k, f in enumerate(fine)]
    p = _export(tmp_path / "back.txt", MT2022_HEADER, cols, rows)
    with pytest.raises(InputError, match=r"back\.txt: expected a strictly advancing SampleTimeFine, but it steps "
                                         r"back at data row 4 \(1200 -> 1150\)"):
        read_xsens(p)


@pytest.mark.parametrize("text, message", [
    ("// Update Rate: 1eHz\nPacketCounter\tGyr_X\tGyr_Y\tGyr_Z\n1\t0\t0\t0\n",
     r"bad\.txt: expected a positive rate in Hz in the line '// Update Rate: 1eHz'"),
    ("// Update Rate: 100.0Hz\nPacketCounter\tGyr_X\tGyr_Y\tGyr_Z\n",
     r"bad\.txt: expected data rows after the header row, got none"),
    ("// Update Rate: 100.0Hz\n",
     r"bad\.txt: expected a header row \(PacketCounter, Gyr_X, \.\.\.\) after the '//' comment lines, got none"),
    ("// Update Rate: 100.0Hz\nGyr_X\tGyr_Y\tGyr_Z\n0\t0\t0\n0\t0\t0\n",
     r"bad\.txt: no time source: expected SampleTimeFine, UTC_\* columns or a PacketCounter in every row "
     r"\(none of these columns\); columns found: Gyr_X, Gyr_Y, Gyr_Z"),
])
def test_read_xsens_broken_headers_are_one_line_format_errors(tmp_path, text, message):
    p = tmp_path / "bad.txt"
    p.write_text(text)
    with pytest.raises(FormatError, match=message) as err:
        read_xsens(p)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("delim", ["\t", ",", ";", " "])
def test_read_xsens_pandas_and_loadtxt_agree_on_every_delimiter(tmp_path, monkeypatch, delim):
    pytest.importorskip("pandas")
    rng = np.random.default_rng(4)
    g = rng.normal(size=(30, 3))
    cols = ["PacketCounter", "SampleTimeFine", "Acc_X", "Acc_Y", "Acc_Z", "Gyr_X", "Gyr_Y", "Gyr_Z"]
    rows = [dict(PacketCounter=k, SampleTimeFine=10_000 + 100 * k, Acc_X=0.1, Acc_Y=0.2, Acc_Z=9.8,
                 Gyr_X=f"{g[k, 0]:.17g}", Gyr_Y=f"{g[k, 1]:.17g}", Gyr_Z=f"{g[k, 2]:.17g}") for k in range(30)]
    del rows[7]["Gyr_Z"]
    g[7, 2] = np.nan
    p = _export(tmp_path / "x.txt", MT2022_HEADER, cols, rows, delim=delim)
    out = []
    for threshold in (float("inf"), 0):
        monkeypatch.setattr(text_mod, "PANDAS_MIN_BYTES", threshold)
        out.append(read_xsens(p))
    for s in out:
        np.testing.assert_array_equal(s.omega, g)
        np.testing.assert_array_equal(s.t, out[0].t)
