import argparse
import json
import subprocess
import sys

import numpy as np
import pytest

from fusion_gyrocal import ExcitationError, InputError, NotRigidError, OptionError
from fusion_gyrocal.cli import main
from fusion_gyrocal.cli.app import EXIT_MEANINGS
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
                 "--kalibr", str(tmp_path / "kalibr"), "--openvins", str(tmp_path / "chain.yaml")])
    assert code == 0
    d = json.loads(out.read_text())
    assert np.allclose(np.array(d["R_1_2"]), R, atol=1e-3)
    assert abs(d["time_offset_s"] - offset) < 1e-4
    assert sorted(p.name for p in (tmp_path / "kalibr").iterdir()) == ["imu0.yaml", "imu1.yaml", "imu_chain.yaml"]
    assert (tmp_path / "chain.yaml").read_text().startswith("%YAML:1.0")
    assert "general" in capsys.readouterr().out


def test_cli_calibrate_kalibr_file_name_refused_naming_the_flag(tmp_path, capsys):
    p1, p2, _, _ = _write_pair(tmp_path)
    assert main(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--kalibr", str(tmp_path / "imu.yaml")]) == 1
    assert capsys.readouterr().err.startswith("gyrocal: error: --kalibr: expected a folder")
    assert not (tmp_path / "imu.yaml").exists()


def test_cli_known_error_is_one_line_exit_1(tmp_path, capsys):
    code = main(["calibrate", str(tmp_path / "missing.csv"), str(tmp_path / "missing2.csv")])
    err = capsys.readouterr().err
    assert code == 1
    assert err.startswith("gyrocal: error:") and err.count("\n") == 1 and "Traceback" not in err


def test_cli_bad_csv_reports_expected_columns(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n3,4\n")
    (tmp_path / "bad2.csv").write_text("a,b\n1,2\n3,4\n")
    code = main(["calibrate", str(bad), str(tmp_path / "bad2.csv")])
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


@pytest.mark.parametrize("argv", [["--skew-std", "nan"], ["--skew-std", "-0.1"], ["--noise-std", "1", "2", "3"],
                                  ["--bias-window", "-5"], ["--parallel-tol", "95"]])
def test_cli_bad_option_is_one_line_exit_1_naming_it(tmp_path, capsys, argv):
    p1, p2, _, _ = _write_pair(tmp_path, seed=4)
    code = main(["calibrate", str(p1), str(p2), "--unit2", "deg/s", *argv])
    err = capsys.readouterr().err
    name = {"--skew-std": "skew_std", "--noise-std": "noise_std", "--bias-window": "bias_window",
            "--parallel-tol": "parallel_tol_deg"}[argv[0]]
    assert code == 1 and err.startswith(f"gyrocal: error: {name}") and err.count("\n") == 1


def _raise(exc):
    def run(args):
        raise exc
    return run


@pytest.mark.parametrize("exc, code, line", [
    (ExcitationError("too little motion"), 1, "gyrocal: error: too little motion\n"),
    (OptionError("min_snr: expected a positive number, got 0"), 1,
     "gyrocal: error: min_snr: expected a positive number, got 0 (command line: min_snr is --min-snr)\n"),
    (NotRigidError("the pair is not rigid"), 3, "gyrocal: the pair is not rigid\n"),
    (PermissionError("denied"), 1, "gyrocal: error: denied\n"),
    (KeyboardInterrupt(), 130, "gyrocal: interrupted\n"),
    (RuntimeError("boom\nsecond line"), 70,
     "gyrocal: internal error: RuntimeError: boom second line (rerun with --debug for the traceback)\n"),
])
def test_main_maps_errors_to_documented_exit_codes(monkeypatch, capsys, exc, code, line):
    monkeypatch.setattr("fusion_gyrocal.cli.demo.run", _raise(exc))
    assert main(["demo"]) == code
    assert capsys.readouterr().err == line


def test_main_debug_reraises_unexpected_errors_only(monkeypatch, capsys):
    monkeypatch.setattr("fusion_gyrocal.cli.demo.run", _raise(RuntimeError("boom")))
    with pytest.raises(RuntimeError, match="boom"):
        main(["--debug", "demo"])
    monkeypatch.setattr("fusion_gyrocal.cli.demo.run", _raise(InputError("bad")))
    assert main(["--debug", "demo"]) == 1 and capsys.readouterr().err == "gyrocal: error: bad\n"


def test_standalone_entry_points_use_the_same_map(monkeypatch, capsys):
    from fusion_gyrocal.cli.compare import add_compare_parser, compare_main
    from fusion_gyrocal.cli.fleet import fleet_main

    for exc, code in ((NotRigidError("nr"), 3), (InputError("in"), 1), (ValueError("v"), 70)):
        monkeypatch.setattr("fusion_gyrocal.cli.fleet.run", _raise(exc))
        assert fleet_main(["some_device"]) == code
        monkeypatch.setattr("fusion_gyrocal.cli.compare.run", _raise(exc))
        parser = argparse.ArgumentParser(prog="gyrocal")
        add_compare_parser(parser.add_subparsers(dest="command"))
        assert compare_main(parser.parse_args(["compare"])) == code
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 2 and err[0].startswith("gyrocal: ") and err[1].startswith("gyrocal compare: ")


def test_main_help_lists_every_exit_code(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    for code, meaning in EXIT_MEANINGS:
        assert f"{code} {' '.join(meaning.split())}" in out


def test_cli_compare_alignment_flags_without_recordings_exit_1(capsys):
    assert main(["compare", "--offset", "0", "--no-progress"]) == 1
    assert capsys.readouterr().err == ("gyrocal: error: --offset: expected recordings (gyro1 [gyro2]) to align and "
                                       "mask; a simulated scenario has none\n")
    assert main(["compare", "--saturation-limit", "30", "--no-progress"]) == 1
    assert capsys.readouterr().err.startswith("gyrocal: error: --saturation-limit: expected recordings")


def test_cli_same_json_as_calibrate_pair_with_the_same_options(tmp_path):
    p1, p2, _, _ = _write_pair(tmp_path, seed=5)
    out = tmp_path / "c.json"
    assert main(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--method", "direct", "--noise-std", "0.0017",
                 "--bias-window", "5", "--output", str(out)]) == 0
    from fusion_gyrocal.io import read_imu
    from fusion_gyrocal.pipeline.pipeline import run_pipeline

    s1, s2 = read_imu(p1), read_imu(p2, unit="deg/s")
    cal = run_pipeline(s1.masked_omega, s2.masked_omega, t_1=s1.t, t_2=s2.t, method="direct", noise_std=0.0017,
                       bias_window=int(round(5 * s1.rate_hz))).calibration
    got = json.loads(out.read_text())
    prov = got.pop("provenance")   # the command records what it read; the library call has no provenance
    assert [i["path"] for i in prov["inputs"]] == [str(p1), str(p2)] and prov["options"]["method"] == "direct"
    assert got == {k: v for k, v in json.loads(cal.to_json()).items() if k != "provenance"}


def test_main_xsens_without_rate_needs_sample_rate_flag(tmp_path, capsys):
    folder = shared_data_dir() / "xsens_mt_exports" if shared_data_dir() else None
    if folder is None or not folder.is_dir():
        pytest.skip("../shared/data/xsens_mt_exports is absent (a user's own clone)")
    f = folder / "MT_01200454_000-000_00B40DE4.txt"       # MT Manager 2019.2: no rate line, PacketCounter only
    g = tmp_path / f.name
    g.write_bytes(f.read_bytes())
    assert main(["calibrate", str(f), str(g), "--sample-rate1", "-3"]) == 1
    assert "--sample-rate1: expected a positive sample rate in Hz" in capsys.readouterr().err
    assert main(["calibrate", str(f), str(g)]) == 1
    assert "rate_hz" in capsys.readouterr().err      # the reader names what the file lacks


def test_main_report_track_log_starting_at_rest_tracks_a_rigid_pair(tmp_path, capsys):
    rng = np.random.default_rng(0)
    motion, R = HumanMotion(0.8, rng=rng), random_rotation(rng)
    t = np.arange(0, 60, 0.01)
    w = motion(t)
    w[t < 15] = 0.0                                   # the first quarter at rest
    for name, x in (("a.csv", w + 0.01), ("b.csv", w @ R - 0.02)):
        x = x + rng.normal(0, PAPER_NOISE_STD, x.shape)
        np.savetxt(tmp_path / name, np.column_stack([t, x]), delimiter=",", header="t,gx,gy,gz", comments="")
    assert main(["report", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--offset", "0",
                 "--out", str(tmp_path / "rep"), "--track"]) == 0
    assert "skipped" not in capsys.readouterr().err
    assert (tmp_path / "rep" / "drift_tracking.png").stat().st_size > 10_000


def test_main_reader_flag_a_format_does_not_take_is_refused(tmp_path, capsys):
    from fusion_gyrocal.evaluate.sim import simulate_pair
    from fusion_gyrocal.io import ImuStream, write_csv, write_npz

    sim = simulate_pair(rng=5, n=2000)
    write_csv(ImuStream(sim.t, sim.omega_1), tmp_path / "a.csv")
    write_npz(ImuStream(sim.t, sim.omega_2), tmp_path / "b.npz")
    assert main(["calibrate", str(tmp_path / "a.csv"), str(tmp_path / "b.npz"), "--time-unit2", "ms"]) == 1
    err = capsys.readouterr().err
    assert "--time-unit1/--time-unit2 or --time-unit: not used when reading b.npz (npz" in err


# ------------------------------------------------------------------------------- noise model and uncertainty basis
def test_cli_calibrate_prints_one_uncertainty_line_two_rates_each_gyro_density_exported(tmp_path, capsys):
    import yaml

    p1, p2, _, _ = _write_pair(tmp_path, seed=3)
    out = tmp_path / "cal.json"
    assert main(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--output", str(out),
                 "--kalibr", str(tmp_path / "k")]) == 0
    text = " ".join(capsys.readouterr().out.split())   # the console wraps long lines
    assert text.count("uncertainty: ") == 1
    assert "uncertainty: noise model identified from the residual (white " in text
    assert "residual chi2/dof" in text
    nm = json.loads(out.read_text())["noise_model"]
    assert nm["rate_hz"] == pytest.approx(200.0) and nm["sources"]["split"].startswith("third differences")
    assert nm["rates_hz"] == pytest.approx([200.0, 100.0])
    for i, rate in enumerate((200.0, 100.0)):
        text = (tmp_path / "k" / f"imu{i}.yaml").read_text()
        y = yaml.safe_load(text)
        # gyro 2 (100 Hz) is interpolated onto gyro 1's 200 Hz grid, no stretch at rest: each sensor's own density
        # (the simulated PAPER_NOISE_STD per own sample), referred back from the grid (Resampling)
        assert abs(y["gyroscope_noise_density"] / (PAPER_NOISE_STD / np.sqrt(rate)) - 1) < 0.15
        assert "identified" in text and f"per sample at its {rate:.6g} Hz" in text


def test_cli_calibrate_noise_model_residual_exports_placeholders(tmp_path, capsys):
    p1, p2, _, _ = _write_pair(tmp_path, seed=4)
    assert main(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--noise-model", "residual",
                 "--openvins", str(tmp_path / "ov.yaml")]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "uncertainty: noise from the residual" in text and "its spread taken as white noise" in text
    chain = (tmp_path / "ov.yaml").read_text()
    assert "IDENTIFIED" not in chain and chain.count("PLACEHOLDER, not measured\n") == 8


def test_cli_report_writes_allan_deviation_and_noise_model(tmp_path, capsys):
    p1, p2, _, _ = _write_pair(tmp_path, seed=5)
    assert main(["report", str(p1), str(p2), "--unit2", "deg/s", "--out", str(tmp_path / "rep")]) == 0
    assert f"wrote {tmp_path / 'rep' / 'allan_deviation.png'}" in capsys.readouterr().out
    assert (tmp_path / "rep" / "allan_deviation.png").read_bytes().startswith(b"\x89PNG")
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "![allan_deviation](allan_deviation.png)" in md and "- uncertainty: noise model identified" in md
    assert "## Noise model (identified from the residual)" in md


def test_cli_calibrate_mimu_exports_noise_density_near_static_poses(tmp_path, capsys):
    """MIMU session 1, IMU 0 against IMU 2: the residual is a rate-dependent misfit (~5.6 deg/s), yet the written
    gyroscope_noise_density is each sensor's, within 3x of its static poses (first 20 s, SOURCE.md)."""
    import yaml

    from fusion_gyrocal.io import read_npz

    p = shared_data_dir() / "mimu_8imu_array" / "npz" / "exp_1.npz"
    if not p.exists():
        pytest.skip("../shared/data not present (real recordings are only in the project checkout)")
    assert main(["calibrate", str(p), str(p), "--imu1", "0", "--imu2", "2", "--kalibr", str(tmp_path / "k"),
                 "--openvins", str(tmp_path / "ov.yaml")]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "residual is rate-dependent misfit), raised to the block-robust covariance" in text
    streams = read_npz(p)
    rate = 62.5
    chain = yaml.safe_load((tmp_path / "ov.yaml").read_text().split("\n", 1)[1])
    for i, k in enumerate((0, 2)):
        static = float(np.mean(streams[k].omega[: int(20 * rate)].std(axis=0, ddof=1))) / np.sqrt(rate)
        y = yaml.safe_load((tmp_path / "k" / f"imu{i}.yaml").read_text())
        for got in (y["gyroscope_noise_density"], chain[f"imu{i}"]["gyroscope_noise_density"]):
            print(f"MIMU exp_1 IMU {k}: written {got:.4g}, static {static:.4g} rad/s/sqrt(Hz), ratio {got / static:.3f}")
            assert 1 / 3 < got / static < 3
        assert y["accelerometer_noise_density"] == 2.0e-3   # placeholder: gyro-only


def test_cli_calibrate_array_prints_its_uncertainty_line(tmp_path, capsys):
    rng = np.random.default_rng(11)
    t = np.arange(0, 30, 0.01)
    motion = HumanMotion(0.8, rng=rng)(t)
    paths = []
    for k in range(3):
        R = np.eye(3) if k == 0 else random_rotation(rng)
        w = motion @ R + rng.normal(0, PAPER_NOISE_STD, motion.shape)
        paths.append(tmp_path / f"g{k}.csv")
        np.savetxt(paths[-1], np.column_stack([t, w]), delimiter=",", header="t,gyro_x,gyro_y,gyro_z", comments="")
    assert main(["calibrate", *map(str, paths)]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert text.count("uncertainty: ") == 1
    assert "uncertainty: noise identified for every gyro from its pair with the reference (white " in text
    assert "the block-robust check agrees" in text or "raised to the block-robust covariance" in text
