import json
import subprocess
import sys

import numpy as np
import pytest

from fusion_gyrocal.cli.main import main
from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, HumanMotion, random_rotation, shared_data_dir


def _write_pair(tmp_path, seed=0, offset=0.031):
    rng = np.random.default_rng(seed)
    motion, R = HumanMotion(0.8, rng=rng), random_rotation(rng)
    t1 = np.arange(0, 30, 0.005)
    t2 = np.arange(0, 30, 0.01)
    w1 = motion(t1) + rng.normal(0, PAPER_NOISE_STD, (t1.size, 3))
    w2 = np.rad2deg(motion(t2 + offset) @ R + rng.normal(0, PAPER_NOISE_STD, (t2.size, 3)))
    p1, p2 = tmp_path / "a.csv", tmp_path / "b.csv"
    np.savetxt(p1, np.column_stack([t1, w1]), delimiter=",", header="t,gyro_x,gyro_y,gyro_z", comments="")
    np.savetxt(p2, np.column_stack([t2, w2]), delimiter=",", header="t,gyro_x,gyro_y,gyro_z", comments="")
    return p1, p2, R, offset


def test_cli_calibrate_writes_json_kalibr_openvins(tmp_path, capsys):
    p1, p2, R, offset = _write_pair(tmp_path)
    out = tmp_path / "cal.json"
    code = main(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--output", str(out),
                 "--kalibr", str(tmp_path / "imu.yaml"), "--openvins", str(tmp_path / "chain.yaml")])
    assert code == 0
    d = json.loads(out.read_text())
    assert np.allclose(np.array(d["R_1_2"]), R, atol=1e-3)
    assert abs(d["time_offset_s"] - offset) < 1e-4
    assert (tmp_path / "imu.yaml").exists() and (tmp_path / "chain.yaml").read_text().startswith("%YAML:1.0")
    assert "general" in capsys.readouterr().out


def test_cli_known_error_is_one_line_exit_1(tmp_path, capsys):
    code = main(["calibrate", str(tmp_path / "missing.csv"), str(tmp_path / "missing2.csv")])
    err = capsys.readouterr().err
    assert code == 1
    assert err.startswith("gyrocal: error:") and err.count("\n") == 1 and "Traceback" not in err


def test_cli_bad_csv_reports_expected_columns(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n3,4\n")
    code = main(["calibrate", str(bad), str(bad)])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err and "bad.csv" in err


@pytest.mark.skipif(not shared_data_dir().exists(), reason="../shared/data not present (real recordings are only "
                                                           "in the project checkout)")
def test_cli_not_rigid_exits_3(capsys):
    d = shared_data_dir() / "xsens_walking_nonrigid"
    code = main(["calibrate", str(d / "walking_xsens_upperLeg.txt"), str(d / "walking_xsens_lowerLeg.txt"),
                 "--offset", "0"])
    assert code == 3
    assert "not rigid" in capsys.readouterr().err


def test_cli_report_writes_figures(tmp_path):
    p1, p2, _, _ = _write_pair(tmp_path, seed=1)
    code = main(["report", str(p1), str(p2), "--unit2", "deg/s", "--out", str(tmp_path / "rep")])
    assert code == 0
    pngs = sorted(p.name for p in (tmp_path / "rep").glob("*.png"))
    assert {"alignment.png", "residual_vs_rate.png", "snr_accumulation.png", "rejected_stretches.png"} <= set(pngs)
    assert all((tmp_path / "rep" / p).stat().st_size > 10000 for p in pngs)
    assert "configuration" in (tmp_path / "rep" / "report.md").read_text()


def test_cli_report_track_adds_drift_plot(tmp_path):
    p1, p2, _, _ = _write_pair(tmp_path, seed=2)
    code = main(["report", str(p1), str(p2), "--unit2", "deg/s", "--out", str(tmp_path / "rep"), "--track"])
    assert code == 0
    assert (tmp_path / "rep" / "drift_tracking.png").stat().st_size > 10000


def test_cli_demo_prints_estimate_beside_truth():
    r = subprocess.run([sys.executable, "-m", "fusion_gyrocal.cli", "demo"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert "truth" in r.stdout and "rotation error" in r.stdout


def test_cli_help_shows_examples():
    r = subprocess.run([sys.executable, "-m", "fusion_gyrocal.cli", "calibrate", "--help"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0 and "examples:" in r.stdout and "gyrocal calibrate" in r.stdout


def test_cli_bias_walk_needs_noise_std(tmp_path, capsys):
    p1, p2, _, _ = _write_pair(tmp_path, seed=3)
    assert main(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--bias-walk", "1e-5"]) == 1
    assert "needs noise_std" in capsys.readouterr().err
    code = main(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--bias-walk", "1e-5", "--noise-std", "0.0017",
                 "--output", str(tmp_path / "c.json")])
    assert code == 0 and json.loads((tmp_path / "c.json").read_text())["rigid"] is True
