"""``gyrocal noise``: the static Allan analysis against simulated noise of known figures and against a direct
estimate on real rest stretches (MIMU static poses, BROAD breaks)."""

import json

import numpy as np
import pytest

from fusion_gyrocal import ExcitationError
from fusion_gyrocal.cli import main
from fusion_gyrocal.core.static_noise import rest_stretches, static_noise
from _shared import data_folder
from fusion_gyrocal.io.writers import ImuNoise, read_imu_noise
from test_writers import kalibr_imu_parameters


def _direct(omega, stretches, rate_hz):
    """The direct estimate of the white noise density: the per-sample std of every stretch about its own mean,
    pooled, over sqrt(rate)."""
    x = np.concatenate([omega[a:b] - omega[a:b].mean(axis=0) for a, b in stretches])
    return x.std(axis=0) / np.sqrt(rate_hz)


# --------------------------------------------------------------------------------- simulated
def test_static_noise_recovers_simulated_white_noise_and_random_walk():
    rng = np.random.default_rng(0)
    fs, n = 200.0, 400_000                          # 2000 s at rest
    N = np.array([2e-4, 3e-4, 4e-4])                # rad/s/sqrt(Hz)
    K = np.array([2e-5, 2e-5, 2e-5])                # rad/s^2/sqrt(Hz)
    omega = rng.normal(0, 1, (n, 3)) * N * np.sqrt(fs) + np.cumsum(rng.normal(0, 1, (n, 3)) * K / np.sqrt(fs), axis=0)
    r = static_noise(omega, fs, stretches=[(0, n)])
    assert np.all(np.abs(r.white - N) < 4 * r.white_std + 0.01 * N)
    assert np.all(r.white_std < 0.05 * N) and np.all(r.white_std > 0)
    assert np.all(r.random_walk > 0) and np.all(np.abs(r.random_walk - K) < 4 * r.random_walk_std)


def test_static_noise_comb_of_tones_takes_white_noise_from_the_spread():
    # a chip with a comb of tones below the Allan fit's tone band (as MIMU IMU 7 x: 1.5-30 Hz at 62.5 Hz): the
    # white noise a filter must take per sample is the samples' whole short-term spread, tones included
    # (the comb read off that axis's spectrum; the tones carry 84 % of the variance; the fit alone gave 0.85x)
    rng = np.random.default_rng(0)
    fs, n = 62.5, 20 * 1400
    t = np.arange(n) / fs
    sigma = 2.5e-3                                                 # rad/s per sample
    comb = ((1.46, 2.5e-3), (4.4, 1.8e-3), (5.1, 1.8e-3), (9.5, 2.8e-3), (11.7, 2.0e-3), (21.2, 1.8e-3),
            (23.4, 3.4e-3), (27.8, 2.9e-3), (30.0, 4.2e-3))
    tones = sum(a * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f, a in comb)
    omega = rng.normal(0, sigma, (n, 3))
    omega[:, 0] += tones
    r = static_noise(omega, fs, stretches=[(k * 1400, (k + 1) * 1400) for k in range(20)])
    truth = np.sqrt(sigma ** 2 + np.array([np.var(tones), 0.0, 0.0])) / np.sqrt(fs)
    np.testing.assert_array_less(np.abs(r.white / truth - 1), 0.05)
    assert r.white_from == ("spread", "fit", "fit")                # white noise alone: the fit describes it
    assert np.all(r.white_std > 0) and r.white_std[0] < 0.05 * r.white[0]
    assert r.to_dict()["white_from"] == list(r.white_from)


def test_short_term_spread_is_the_white_variance_and_ignores_a_drift():
    from fusion_gyrocal.core.static_noise import short_term_spread

    rng = np.random.default_rng(5)
    fs, n = 100.0, 60_000
    omega = rng.normal(0, 0.01, (n, 3)) + np.linspace(0, 0.5, n)[:, None]      # a drift 50x the noise over the log
    v, sd = short_term_spread(omega, [(0, n // 2), (n // 2, n)], fs)
    assert np.all(np.abs(v / 1e-4 - 1) < 4 * sd / 1e-4) and np.all(sd / 1e-4 < 0.02)
    assert short_term_spread(omega, [(0, 5)], fs) == (None, None)


def test_rest_stretches_find_the_rest_between_motions():
    rng = np.random.default_rng(1)
    fs = 100.0
    t = np.arange(0, 120, 1 / fs)
    omega = rng.normal(0, 0.002, (t.size, 3))
    moving = ((t > 30) & (t < 40)) | ((t > 80) & (t < 90))
    omega[moving] += np.sin(2 * np.pi * 0.7 * t[moving])[:, None] * [1.0, -0.5, 0.3]
    got = [(a / fs, b / fs) for a, b in rest_stretches(omega, fs)]
    assert len(got) == 3
    for (a, b), (lo, hi) in zip(got, ((0, 30), (40, 80), (90, 120))):
        assert lo <= a <= lo + 2.01 and hi - 2.01 <= b <= hi     # each rest, trimmed by at most a window per end
    with pytest.raises(ExcitationError, match="no rest stretch"):
        static_noise(omega, fs, stretches=[])


def test_cli_noise_writes_kalibr_yaml_plot_and_json(tmp_path, capsys):
    rng = np.random.default_rng(2)
    fs, n = 100.0, 60_000
    t = np.arange(n) / fs
    w = rng.normal(0, 3e-4 * np.sqrt(fs), (n, 3))
    csv = tmp_path / "static.csv"
    np.savetxt(csv, np.column_stack([t, np.rad2deg(w)]), delimiter=",", header="t,gx,gy,gz", comments="")
    code = main(["noise", str(csv), "--unit", "deg/s", "--whole", "--kalibr", str(tmp_path / "imu.yaml"),
                 "--plot", str(tmp_path / "allan.png"), "-o", str(tmp_path / "noise.json"), "--rostopic", "/imu/data"])
    out = capsys.readouterr().out
    assert code == 0 and "white N" in out and "input: gyro 1:" in out
    k = kalibr_imu_parameters(tmp_path / "imu.yaml")           # what Kalibr's reader takes
    assert k["rostopic"] == "/imu/data" and k["update_rate"] == pytest.approx(fs)
    assert k["gyroscope_noise_density"] == pytest.approx(3e-4, rel=0.03)
    noise, = read_imu_noise(tmp_path / "imu.yaml")            # and what gyrocal calibrate --noise reads back
    assert isinstance(noise, ImuNoise) and noise.gyroscope_noise_density == k["gyroscope_noise_density"]
    assert (tmp_path / "imu.yaml").read_text().count("PLACEHOLDER, not measured (gyro data only)") == 2
    d = json.loads((tmp_path / "noise.json").read_text())
    assert d["kind"] == "static_noise" and d["provenance"]["inputs"][0]["unit_in"] == "deg/s"
    assert d["n_samples"] == n and len(d["white"]) == 3
    assert (tmp_path / "allan.png").read_bytes().startswith(b"\x89PNG")


def test_cli_noise_bad_window_is_one_line_error(tmp_path, capsys):
    csv = tmp_path / "s.csv"
    np.savetxt(csv, np.column_stack([np.arange(1000) / 100.0, np.zeros((1000, 3))]), delimiter=",",
               header="t,gx,gy,gz", comments="")
    assert main(["noise", str(csv), "--start", "50"]) == 1
    assert "--start/--end: expected a range holding samples" in capsys.readouterr().err


# --------------------------------------------------------------------------------- real rest stretches


@pytest.mark.shared_data
def test_cli_noise_mimu_static_poses_white_noise_within_10_percent_of_direct(tmp_path, capsys):
    from fusion_gyrocal.io import read_npz

    p = data_folder("mimu_8imu_array") / "npz" / "exp_1.npz"
    for imu in range(8):
        out = tmp_path / f"n{imu}.json"
        assert main(["noise", str(p), "--imu", str(imu), "-o", str(out)]) == 0
        d = json.loads(out.read_text())
        s = read_npz(p, imu=imu)
        assert len(d["stretches"]) >= 20        # the 20 static poses (masked samples may split one)
        direct = _direct(s.omega, d["stretches"], s.rate_hz)
        white = np.array(d["white"])
        # where the fit is the white-noise term alone from the shortest tau on, the per-sample spread is that noise
        only_white = (np.array(d["fit_from"]) == 0) & (np.array(d["bias_instability"]) == 0) & \
            (np.array(d["random_walk"]) == 0)
        assert only_white.sum() >= 2
        np.testing.assert_array_less(np.abs(white / direct - 1)[only_white], 0.10)
    capsys.readouterr()


def test_cli_noise_mimu_tones_every_axis_within_10_percent_of_direct(tmp_path, capsys):
    from fusion_gyrocal.io import read_npz

    p = data_folder("mimu_8imu_array") / "npz" / "exp_2.npz"
    out = tmp_path / "n6.json"
    assert main(["noise", str(p), "--imu", "6", "-o", str(out)]) == 0    # IMU 7: x carries tones of 1.5-30 Hz
    assert "its white noise is the samples' own spread" in capsys.readouterr().out
    d = json.loads(out.read_text())
    s = read_npz(p, imu=6)
    direct = _direct(s.omega, d["stretches"], s.rate_hz)
    assert d["white_from"][0] == "spread"
    np.testing.assert_array_less(np.abs(np.array(d["white"]) / direct - 1), 0.10)


@pytest.mark.shared_data
def test_cli_noise_broad_rest_stretches_white_noise_within_10_percent_of_direct(tmp_path, capsys):
    from scipy.io import loadmat

    folder = data_folder("broad_handheld") / "data_mat"
    for name in ("04_undisturbed_slow_rotation_with_breaks_A", "08_undisturbed_fast_rotation_with_breaks_A"):
        m = loadmat(folder / f"{name}.mat", squeeze_me=True)
        g, fs = np.asarray(m["imu_gyr"], float), float(m["sampling_rate"])
        csv = tmp_path / f"{name}.csv"
        np.savetxt(csv, np.column_stack([np.arange(len(g)) / fs, g]), delimiter=",", header="t,gx,gy,gz",
                   comments="")
        out = tmp_path / f"{name}.json"
        assert main(["noise", str(csv), "-o", str(out)]) == 0
        d = json.loads(out.read_text())
        assert len(d["stretches"]) >= 4 and d["n_samples"] / fs > 40     # the breaks (and the rest at the start)
        direct = _direct(g, d["stretches"], fs)
        np.testing.assert_array_less(np.abs(np.array(d["white"]) / direct - 1), 0.10)
    capsys.readouterr()
