"""Readers of the formats users have: a lone ROS 2 storage file, PX4 ULog, logger CSV profiles, IMU instances,
binary files refused by name."""

import struct
import warnings

import numpy as np
import pytest

from fusion_gyrocal.cli import main
from fusion_gyrocal.errors import FormatError, InputError
from fusion_gyrocal.io import ImuStream, detect_format, list_imu_topics, read_imu, write_imu_bag

DEG = np.pi / 180


def _stream(n=300, rate=200.0, seed=0, t0=1.7e9):
    rng = np.random.default_rng(seed)
    t = t0 + np.arange(n) / rate
    return ImuStream(t, rng.normal(scale=0.5, size=(n, 3)))


# ---------------------------------------------------------------------------------------------- lone ROS 2 files
@pytest.mark.parametrize("storage,suffix", [("sqlite3", ".db3"), ("mcap", ".mcap")])
def test_read_imu_lone_ros2_storage_file_without_metadata(tmp_path, storage, suffix):
    pytest.importorskip("rosbags")
    a, b = _stream(seed=1), _stream(seed=2)
    bag = write_imu_bag(tmp_path / "run", {"/imu0": a, "/imu1": b}, version=2, storage=storage)
    files = list(bag.glob(f"*{suffix}"))
    assert len(files) == 1 and (bag / "metadata.yaml").is_file()
    lone = tmp_path / f"shared{suffix}"
    files[0].rename(lone)                  # the file alone, as it is shared, without metadata.yaml
    assert detect_format(lone) == "bag"
    assert list_imu_topics(lone) == ("/imu0", "/imu1")
    s = read_imu(lone, topic="/imu1")
    np.testing.assert_array_equal(s.omega, b.omega)
    np.testing.assert_allclose(s.t, b.t, rtol=0, atol=1e-9)


def test_cli_calibrate_lone_mcap_two_topics(tmp_path, capsys):
    pytest.importorskip("rosbags")
    from fusion_gyrocal.evaluate.sim import simulate_pair
    sim = simulate_pair(rng=3, n=3000)
    t = 100.0 + np.arange(3000) / 100.0
    bag = write_imu_bag(tmp_path / "b", {"/a": ImuStream(t, sim.omega_1), "/b": ImuStream(t, sim.omega_2)},
                        version=2, storage="mcap")
    lone = next(bag.glob("*.mcap")).rename(tmp_path / "alone.mcap")
    out = tmp_path / "cal.json"
    assert main(["calibrate", str(lone), "--topic1", "/a", "--topic2", "/b", "-o", str(out)]) == 0
    from fusion_gyrocal.io import read_json
    cal = read_json(out)
    err = np.degrees(np.linalg.norm(np.linalg.svd(cal.R_1_2 - sim.R_1_2, compute_uv=False)))
    assert err < 0.05


# ---------------------------------------------------------------------------------------------- PX4 ULog
def _ulog_bytes(datasets, start_us=1000):
    """A ULog file written to the documented format (header, 'F' formats, 'A' subscriptions, 'D' data).

    ``datasets``: list of (message name, multi_id, fields [(type, name)], rows (list of tuples)).
    """
    packs = {"uint64_t": "Q", "uint32_t": "I", "float": "f", "uint8_t": "B"}

    def msg(kind, payload):
        return struct.pack("<HB", len(payload), ord(kind)) + payload

    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", start_us))
    out += msg("B", bytes(16) + struct.pack("<3Q", 0, 0, 0))                   # flag bits: nothing incompatible
    formats = {}
    for name, _, fields, _ in datasets:
        formats[name] = fields
    for name, fields in formats.items():
        out += msg("F", (name + ":" + "".join(f"{t} {n};" for t, n in fields)).encode())
    items = []
    for msg_id, (name, multi_id, fields, rows) in enumerate(datasets):
        out += msg("A", struct.pack("<BH", multi_id, msg_id) + name.encode())
        fmt = "<" + "".join(packs[t] for t, _ in fields)
        for row in rows:
            items.append((row[0], msg("D", struct.pack("<H", msg_id) + struct.pack(fmt, *row))))
    for _, m in sorted(items, key=lambda x: x[0]):
        out += m
    return bytes(out)


_GYRO_FIELDS = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("uint32_t", "device_id"),
                ("float", "x"), ("float", "y"), ("float", "z")]
_COMBINED_FIELDS = [("uint64_t", "timestamp"), ("float", "gyro_rad[0]"), ("float", "gyro_rad[1]"),
                    ("float", "gyro_rad[2]"), ("uint32_t", "gyro_integral_dt")]


def _px4_log(tmp_path, rate_hz=400.0, n=400, combined_rate_hz=400.0):
    rng = np.random.default_rng(5)
    w = rng.normal(scale=1.0, size=(2, n, 3)).astype(np.float32)
    step = int(1e6 / rate_hz)
    ds = []
    for inst in (0, 1):
        rows = [(10_000 + k * step + 150, 10_000 + k * step, 1000 + inst, *w[inst, k]) for k in range(n)]
        ds.append(("sensor_gyro", inst, _GYRO_FIELDS, rows))
    cstep = int(1e6 / combined_rate_hz)
    m = int(n * step / cstep)
    ds.append(("sensor_combined", 0, _COMBINED_FIELDS,
               [(10_000 + k * cstep, *w[0, min(k * cstep // step, n - 1)], cstep) for k in range(m)]))
    path = tmp_path / "flight.ulg"
    path.write_bytes(_ulog_bytes(ds))
    return path, w, step


def test_read_ulog_every_gyro_instance_checked_by_pyulog(tmp_path):
    pyulog = pytest.importorskip("pyulog")
    path, w, step = _px4_log(tmp_path)
    ref = pyulog.ULog(str(path))          # the format's own reader takes the hand-built file
    assert sorted((d.name, d.multi_id) for d in ref.data_list) == [("sensor_combined", 0), ("sensor_gyro", 0),
                                                                   ("sensor_gyro", 1)]
    from fusion_gyrocal.io import list_ulog_gyros, read_ulog
    assert list_ulog_gyros(path) == ("sensor_combined/0", "sensor_gyro/0", "sensor_gyro/1")
    assert detect_format(path) == "ulog"
    g1 = read_imu(path, topic="sensor_gyro/1")
    np.testing.assert_array_equal(g1.omega, w[1].astype(np.float64))
    np.testing.assert_allclose(np.diff(g1.t), step * 1e-6, rtol=0, atol=1e-12)
    assert g1.t[0] == pytest.approx(0.010)                      # timestamp_sample, not timestamp (+150 us)
    assert read_ulog(path, imu=0).name == "sensor_gyro/0"
    with pytest.raises(InputError, match="holds 3 gyro streams"):
        read_ulog(path)
    with pytest.raises(InputError, match=r"expected a gyro stream 'sensor_gyro/4'"):
        read_ulog(path, imu=4)


def test_read_ulog_round_trip_through_pyulog_writer(tmp_path):
    pyulog = pytest.importorskip("pyulog")
    path, w, _ = _px4_log(tmp_path)
    again = tmp_path / "again.ulg"
    pyulog.ULog(str(path)).write_ulog(str(again))
    a, b = read_imu(path, topic="sensor_gyro/0"), read_imu(again, topic="sensor_gyro/0")
    np.testing.assert_array_equal(a.omega, b.omega)
    np.testing.assert_array_equal(a.t, b.t)


def test_read_ulog_low_logging_rate_warns_and_notes(tmp_path):
    pytest.importorskip("pyulog")
    path, _, _ = _px4_log(tmp_path, rate_hz=400.0, combined_rate_hz=20.0)
    with pytest.warns(UserWarning, match="logged at 20 Hz, below the 50 Hz"):
        s = read_imu(path, topic="sensor_combined")
    assert any("20 Hz" in n for n in s.notes)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_imu(path, topic="sensor_gyro", imu=1)             # 400 Hz: no warning


def test_cli_calibrate_ulog_two_instances(tmp_path, capsys):
    pytest.importorskip("pyulog")
    from fusion_gyrocal.evaluate.sim import simulate_pair
    sim = simulate_pair(rng=4, n=4000)
    step = 5000                                                # 200 Hz
    rows = [[(k * step + 1, k * step, 7, *sim.omega_1[k]) for k in range(4000)],
            [(k * step + 1, k * step, 8, *sim.omega_2[k]) for k in range(4000)]]
    path = tmp_path / "two.ulg"
    path.write_bytes(_ulog_bytes([("sensor_gyro", i, _GYRO_FIELDS, rows[i]) for i in (0, 1)]))
    out = tmp_path / "cal.json"
    assert main(["calibrate", str(path), "--imu1", "0", "--imu2", "1", "-o", str(out)]) == 0
    from fusion_gyrocal.io import read_json
    cal = read_json(out)
    assert np.degrees(np.linalg.norm(np.linalg.svd(cal.R_1_2 - sim.R_1_2, compute_uv=False))) < 0.05


def test_read_ulog_truncated_file_is_format_error(tmp_path):
    pytest.importorskip("pyulog")
    bad = tmp_path / "cut.ulg"
    bad.write_bytes(b"ULog\x01\x12\x35\x01" + b"\x07")
    with pytest.raises(FormatError, match="cut.ulg"):
        read_imu(bad)


# ---------------------------------------------------------------------------------------------- binary refused
def test_read_imu_refuses_binary_by_name_without_printing_it(tmp_path, capsys):
    mat = tmp_path / "log.csv"
    mat.write_bytes(b"MATLAB 5.0 MAT-file, Platform: GLNXA64, Created on: Mon" + bytes(range(256)) * 40)
    with pytest.raises(FormatError, match=r"log.csv: expected CSV or Xsens text, got a MATLAB .mat file") as e:
        read_imu(mat)
    assert len(str(e.value)) < 300 and "\x00" not in str(e.value) and "Platform" not in str(e.value)
    from fusion_gyrocal.io import read_csv, read_xsens
    for reader in (read_csv, read_xsens):           # the readers themselves refuse it too
        with pytest.raises(FormatError, match="got a MATLAB .mat file") as e:
            reader(mat)
        assert "Platform" not in str(e.value)
    junk = tmp_path / "data.txt"
    junk.write_bytes(b"t,gx,gy,gz\n" + b"\x00\x01\x02" * 100)
    with pytest.raises(FormatError, match="binary file"):
        read_imu(junk)
    assert main(["calibrate", str(mat), str(junk)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "MATLAB" in err and "Platform" not in err


def test_read_imu_ulog_renamed_csv_detected_and_forced_csv_refused(tmp_path):
    pytest.importorskip("pyulog")
    path, w, _ = _px4_log(tmp_path)
    renamed = path.rename(tmp_path / "flight.csv")
    assert detect_format(renamed) == "ulog"
    with pytest.raises(FormatError, match="expected CSV text, got a PX4 ULog file; read it with read_imu"):
        read_imu(renamed, format="csv")
    with pytest.raises(FormatError, match="expected Xsens text, got a PX4 ULog file"):
        read_imu(renamed, format="xsens")


# ---------------------------------------------------------------------------------------------- CSV profiles
def _write(path, header, rows, sep=","):
    with open(path, "w") as f:
        if header is not None:
            f.write(header + "\n")
        for r in rows:
            f.write(sep.join(str(x) for x in r) + "\n")
    return path


def _rates(n=200, seed=0):
    return np.round(np.random.default_rng(seed).normal(size=(n, 3)), 6)


@pytest.mark.parametrize("layout", ["uzh-fpv", "kalibr", "sensor-logger", "mars-logger", "px4-combined",
                                    "px4-gyro", "vectornav"])
def test_read_csv_profile_reads_logger_layout_without_flags(tmp_path, layout):
    w = _rates()
    n = len(w)
    t_s = 1_600_000_000 + np.arange(n) * 0.005
    ns = [1_600_000_000_000_000_000 + k * 5_000_000 for k in range(n)]
    us = [12_000_000 + k * 5000 for k in range(n)]
    if layout == "uzh-fpv":
        p = _write(tmp_path / "imu.txt", "# id timestamp ang_vel_x ang_vel_y ang_vel_z lin_acc_x lin_acc_y lin_acc_z",
                   [(k, f"{t_s[k]:.6f}", *w[k], 0, 0, 9.8) for k in range(n)], sep=" ")
        t_exp = t_s
    elif layout == "kalibr":
        p = _write(tmp_path / "imu0.csv", "timestamp,omega_x,omega_y,omega_z,alpha_x,alpha_y,alpha_z",
                   [(ns[k], *w[k], 0, 0, 9.8) for k in range(n)])
        t_exp = np.array(ns) * 1e-9
    elif layout == "sensor-logger":
        p = _write(tmp_path / "Gyroscope.csv", "time,seconds_elapsed,z,y,x",
                   [(ns[k], k * 0.005, w[k, 2], w[k, 1], w[k, 0]) for k in range(n)])
        t_exp = np.array(ns) * 1e-9
    elif layout == "mars-logger":
        p = _write(tmp_path / "gyro_accel.csv", "Timestamp[nanosec], gx[rad/s], gy[rad/s], gz[rad/s], ax[m/s^2], "
                   "ay[m/s^2], az[m/s^2], Unix time[nanosec]", [(ns[k], *w[k], 0, 0, 9.8, ns[k]) for k in range(n)])
        t_exp = np.array(ns) * 1e-9
    elif layout == "px4-combined":
        p = _write(tmp_path / "log_sensor_combined_0.csv", "timestamp,gyro_rad[0],gyro_rad[1],gyro_rad[2],"
                   "gyro_integral_dt,accelerometer_timestamp_relative,accelerometer_m_s2[0]",
                   [(us[k], *w[k], 5000, 0, 9.8) for k in range(n)])
        t_exp = np.array(us) * 1e-6
    elif layout == "px4-gyro":
        p = _write(tmp_path / "log_sensor_gyro_1.csv", "timestamp,timestamp_sample,device_id,x,y,z,temperature",
                   [(us[k] + 120, us[k], 2490378, *w[k], 41.0) for k in range(n)])
        t_exp = np.array(us) * 1e-6
    else:
        p = _write(tmp_path / "vn.csv", "TimeStartup [ns],GyroX [rad/s],GyroY [rad/s],GyroZ [rad/s],UncompGyroX,"
                   "UncompGyroY,UncompGyroZ", [(ns[k], 9, 9, 9, *w[k]) for k in range(n)])
        t_exp = np.array(ns) * 1e-9
    s = read_imu(p)
    np.testing.assert_array_equal(s.omega, w)
    np.testing.assert_allclose(s.t, t_exp, rtol=0, atol=1e-6)
    assert any("layout" in note for note in s.notes)


def test_read_csv_ardupilot_instances_filtered(tmp_path, capsys):
    w = _rates(n=300)
    rows = []
    for k in range(100):
        for inst in (0, 1, 2):
            rows.append((1.7e9 + k * 0.0025, 5_000_000 + k * 2500, inst, *w[3 * k + inst], 0, 0, -9.8))
    p = _write(tmp_path / "imu.csv", "timestamp,TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ", rows)
    with pytest.raises(InputError, match=r"interleaves IMU instances \[0, 1, 2\] \(column 'I'\); pass imu="):
        read_imu(p)
    s = read_imu(p, imu=2)
    np.testing.assert_array_equal(s.omega, w[2::3])
    np.testing.assert_allclose(s.t, 5.0 + np.arange(100) * 0.0025, rtol=0, atol=1e-9)
    with pytest.raises(InputError, match=r"expected IMU instance 5 .* got instances \[0, 1, 2\]"):
        read_imu(p, imu=5)
    assert main(["calibrate", str(p)]) == 1
    assert "--imu1/--imu2 (npz, .ulg, a CSV with an instance column)" in capsys.readouterr().err
    assert main(["calibrate", str(p), "--imu1", "0", "--imu2", "7"]) == 1
    assert "expected IMU instance 7" in capsys.readouterr().err


def test_read_csv_imu_without_instance_column_is_input_error(tmp_path):
    p = _write(tmp_path / "plain.csv", "t,gx,gy,gz", [(k * 0.01, 0.1, 0.2, 0.3) for k in range(50)])
    with pytest.raises(InputError, match="no instance column"):
        read_imu(p, imu=1)


def test_read_csv_profile_units_named_in_the_header_win(tmp_path):
    w = _rates(n=100)
    ms = [5000 + 5 * k for k in range(100)]
    p = _write(tmp_path / "vn.csv", "TimeStartup [ms],GyroX [deg/s],GyroY [deg/s],GyroZ [deg/s]",
               [(ms[k], *w[k]) for k in range(100)])
    s = read_imu(p)
    np.testing.assert_allclose(s.omega, w * DEG, rtol=1e-15)
    np.testing.assert_allclose(s.t, np.array(ms) * 1e-3, rtol=0, atol=1e-12)
    assert any("vectornav layout" in n and "UncompGyro is preferred" in n for n in s.notes)
