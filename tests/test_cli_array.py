"""``gyrocal calibrate`` with N gyros, per-file reading flags, refusals and the not-rigid exit, through ``cli.app.main``."""

import json

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from fusion_gyrocal.cli import main
from fusion_gyrocal.core.array import ArrayCalibration
from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, HumanMotion, random_rotation, shared_data_dir
from fusion_gyrocal.io import read_json

C_BOTTOM = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # MIMU SOURCE.md, bottom-side IMUs


def _write_gyros(tmp_path, seed, offsets, rates, time_scale=None, duration=30.0):
    """One CSV per gyro: gyro k's sample at its own time t is the motion at t + offsets[k] on gyro 1's clock."""
    rng = np.random.default_rng(seed)
    motion = HumanMotion(0.8, rng=rng)
    R = [np.eye(3)] + [random_rotation(rng) for _ in offsets[1:]]
    time_scale = time_scale or [1.0] * len(offsets)
    paths = []
    for k, (off, rate, ts) in enumerate(zip(offsets, rates, time_scale)):
        t = np.arange(0, duration, 1 / rate)
        w = motion(t + off) @ R[k] + rng.normal(0, PAPER_NOISE_STD, (t.size, 3))
        p = tmp_path / f"g{k}.csv"
        np.savetxt(p, np.column_stack([t * ts, w]), delimiter=",", header="t,gx,gy,gz", comments="")
        paths.append(str(p))
    return paths, R


def _deg(R_a, R_b):
    return np.degrees(np.linalg.norm(Rotation.from_matrix(R_a @ R_b.T).as_rotvec()))


def test_cli_calibrate_three_csv_joint_with_per_file_time_units(tmp_path, capsys):
    offsets = [0.0, 0.031, -0.052]
    paths, R = _write_gyros(tmp_path, 1, offsets, [200.0, 100.0, 150.0], time_scale=[1.0, 1.0, 1e3])
    out = tmp_path / "array.json"
    code = main(["calibrate", *paths, "--time-unit", "s,s,ms", "--output", str(out), "--kalibr", str(tmp_path / "k"),
                 "--openvins", str(tmp_path / "ov.yaml")])
    assert code == 0
    cal = read_json(out)
    assert isinstance(cal, ArrayCalibration) and cal.n_gyros == 3
    for k in range(3):
        assert _deg(cal.R_ref_k[k], R[k]) < 0.02
    np.testing.assert_allclose(cal.time_offset_s, offsets, atol=1e-4)
    assert cal.time_offset_source == ("reference", "estimated", "estimated")
    assert np.all(cal.time_offset_std_s[1:] > 0)
    assert sorted(p.name for p in (tmp_path / "k").iterdir()) == ["imu0.yaml", "imu1.yaml", "imu2.yaml",
                                                                   "imu_chain.yaml"]
    chain = yaml.safe_load((tmp_path / "ov.yaml").read_text().split("\n", 1)[1])
    assert [chain[f"imu{k}"]["time_offset"] for k in range(3)] == cal.time_offset_s.tolist()
    assert "joint calibration of 3 gyros" in capsys.readouterr().out


def test_cli_calibrate_time_unit_per_gyro_flags(tmp_path):
    paths, R = _write_gyros(tmp_path, 2, [0.0, 0.02], [200.0, 100.0], time_scale=[1e3, 1.0])
    out = tmp_path / "c.json"
    assert main(["calibrate", *paths, "--time-unit1", "ms", "--time-unit2", "s", "--output", str(out)]) == 0
    d = json.loads(out.read_text())
    assert abs(d["time_offset_s"] - 0.02) < 1e-4 and _deg(np.array(d["R_1_2"]), R[1]) < 0.02


def test_cli_calibrate_array_flag_two_gyros_joint(tmp_path):
    paths, R = _write_gyros(tmp_path, 3, [0.0, 0.0], [200.0, 100.0])
    out = tmp_path / "c.json"
    assert main(["calibrate", *paths, "--array", "--output", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["kind"] == "array_calibration" and d["time_offset_source"] == ["reference", "estimated"]


@pytest.mark.parametrize("argv, message", [
    (["--time-unit", "ms,s"], "gyrocal: error: --time-unit: expected one value or one per gyro (3), got 2"),
    (["--method", "direct"], "gyrocal: error: --method: not available for the joint calibration of 3 gyros"),
    (["--allow-not-rigid"], "gyrocal: error: --allow-not-rigid: not available for the joint calibration of 3 gyros"),
    (["--noise-std", "0.001", "0.002"], "gyrocal: error: --noise-std: expected one value or one per gyro (3), got 2"),
    (["--unit", "furlongs"], "gyrocal: error: --unit: expected one of ('rad/s', 'deg/s', 'counts', 'mrad/s', 'mdeg/s'), got 'furlongs'"),
])
def test_cli_calibrate_three_gyros_bad_flags_name_the_flag(tmp_path, capsys, argv, message):
    paths, _ = _write_gyros(tmp_path, 4, [0.0, 0.0, 0.0], [100.0] * 3, duration=5.0)
    assert main(["calibrate", *paths, *argv]) == 1
    err = capsys.readouterr().err
    assert err.startswith(message) and err.count("\n") == 1


def _two_imu_npz(tmp_path):
    rng = np.random.default_rng(5)
    t = np.arange(0, 20, 0.01)
    omega = HumanMotion(0.8, rng=rng)(t)
    R = random_rotation(rng)
    w = np.stack([omega, omega @ R], axis=1) + rng.normal(0, PAPER_NOISE_STD, (t.size, 2, 3))
    p = tmp_path / "two.npz"
    np.savez(p, t=t, omega=w)
    return p, R


def test_cli_calibrate_same_imu_twice_refused(tmp_path, capsys):
    p, _ = _two_imu_npz(tmp_path)
    assert main(["calibrate", str(p), "--imu1", "0", "--imu2", "0"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("gyrocal: error: gyro 1 and gyro 2 are the same sensor (two.npz (imu 0))")
    assert main(["calibrate", str(tmp_path / "two.npz"), str(p), "--imus", "1"]) == 1
    assert "a gyro calibrated against itself" in capsys.readouterr().err


def test_cli_calibrate_one_npz_takes_every_imu(tmp_path):
    p, R = _two_imu_npz(tmp_path)
    out = tmp_path / "c.json"
    assert main(["calibrate", str(p), "--output", str(out)]) == 0  # two IMUs: the pair pipeline
    d = json.loads(out.read_text())
    assert "kind" not in d and _deg(np.array(d["R_1_2"]), R) < 0.02 and d["time_offset_s"] == pytest.approx(0, abs=1e-4)


def test_cli_calibrate_allow_not_rigid_exits_0_with_warning_in_files(tmp_path, capsys):
    rng = np.random.default_rng(6)
    t = np.arange(0, 30, 0.01)
    motion = HumanMotion(0.8, rng=rng)
    w1 = motion(t)
    bend = Rotation.from_rotvec(np.outer(np.sin(2 * np.pi * t / 7.0), [0.0, 0.0, 1.2])).as_matrix()
    w2 = np.einsum("nij,nj->ni", bend, motion(t)) + rng.normal(0, 0.2, (t.size, 3))  # a hinge between them
    paths = []
    for k, w in enumerate((w1, w2)):
        paths.append(tmp_path / f"n{k}.csv")
        np.savetxt(paths[-1], np.column_stack([t, w]), delimiter=",", header="t,gx,gy,gz", comments="")
    base = ["calibrate", str(paths[0]), str(paths[1]), "--offset", "0"]
    assert main(base) == 3
    assert "not rigid" in capsys.readouterr().err
    code = main(base + ["--allow-not-rigid", "--output", str(tmp_path / "c.json"), "--kalibr", str(tmp_path / "k"),
                        "--openvins", str(tmp_path / "ov.yaml")])
    assert code == 0
    assert "gyrocal: warning: NOT RIGID" in capsys.readouterr().err
    assert json.loads((tmp_path / "c.json").read_text())["rigid"] is False
    for f in [*(tmp_path / "k").iterdir(), tmp_path / "ov.yaml"]:
        assert "# WARNING: NOT RIGID" in f.read_text(), f.name


def test_cli_error_naming_an_api_keyword_names_the_flag(tmp_path, capsys):
    paths, _ = _write_gyros(tmp_path, 7, [0.0, 0.6], [100.0, 100.0], duration=20.0)
    assert main(["calibrate", *paths, "--max-offset", "0.2"]) == 1
    err = capsys.readouterr().err
    assert "max_offset_s" in err and "(command line: max_offset_s is --max-offset)" in err


# ------------------------------------------------------------------------------------------- real data
def _mimu_npz():
    p = shared_data_dir() / "mimu_8imu_array" / "npz" / "exp_1.npz"
    if not p.exists():
        pytest.skip("../shared/data not present (real recordings are only in the project checkout)")
    return p


def test_cli_calibrate_mimu_npz_all_eight_imus(tmp_path):
    p = _mimu_npz()
    out = tmp_path / "mimu.json"
    code = main(["calibrate", str(p), "--output", str(out), "--openvins", str(tmp_path / "ov.yaml"),
                 "--kalibr", str(tmp_path / "k")])
    assert code == 0
    cal = read_json(out)
    assert cal.n_gyros == 8 and cal.time_offset_source[1:] == ("one clock",) * 7
    for k in range(1, 8):
        nominal = C_BOTTOM if k % 2 == 1 else np.eye(3)
        assert _deg(cal.R_ref_k[k], nominal) < 0.5
    assert not cal.scale_observable.any()  # axis-parallel array (Lemma 2): only ratios to the reference's axes
    chain = yaml.safe_load((tmp_path / "ov.yaml").read_text().split("\n", 1)[1])
    assert np.array_equal(chain["imu0"]["Tw"], np.eye(3))   # OpenVINS does not rescale the reference gyro
    rel, _ = cal.relative_scales()
    for k in range(1, 8):   # the others carry their ratio to the reference's parallel axis
        np.testing.assert_allclose(np.diag(chain[f"imu{k}"]["Tw"]), rel[k], rtol=1e-15)
    assert len(list((tmp_path / "k").iterdir())) == 9


def test_cli_calibrate_mimu_npz_imus_subset(tmp_path):
    p = _mimu_npz()
    out = tmp_path / "sub.json"
    assert main(["calibrate", str(p), "--imus", "0,3,5", "--output", str(out)]) == 0
    cal = read_json(out)
    assert cal.n_gyros == 3
    for k, imu in ((1, 3), (2, 5)):
        assert _deg(cal.R_ref_k[k], C_BOTTOM if imu % 2 == 1 else np.eye(3)) < 0.5
