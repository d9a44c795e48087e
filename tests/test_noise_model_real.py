"""The noise model's extra Allan terms (quantisation, filtered noise), the still stretches, and real sensors."""

import numpy as np
import pytest
from _shared import data_folder
from scipy.signal import lfilter

from fusion_gyrocal.core.allan import (FILTERED, FLICKER_TERM, QUANTISATION, WALK, WHITE, allan_deviation, edf_table,
                                       fit_allan)
from fusion_gyrocal.core.direct import solve_A
from fusion_gyrocal.core.moments import Moments
from fusion_gyrocal.core.noise import identify_noise
from fusion_gyrocal.evaluate.sim import DEG, HumanMotion, simulate_pair

RATE = 100.0


def _fit(y, rate=RATE, max_tc=None):
    taus, adev, sub_n, sub_m = allan_deviation(y, rate)
    return fit_allan(taus, (adev ** 2).mean(axis=1), edf_table(sub_n, sub_m), 0, max_tc)


def _identify(w1, w2, mask=None, rate=RATE):
    A, b = solve_A(Moments.from_samples(w1, w2, mask=mask))
    return identify_noise(w1, w2, A, b, rate_hz=rate, mask=mask)


def test_fit_allan_recovers_white_quantisation_and_walk():
    # at 1 kHz: rate = white rate noise + differenced white angle noise (quantisation, slope -1, dominant below
    # 75 ms) + a random-walk bias (dominant above 3.5 s); each term within 4 sigma and its stated tolerance
    rate, n, sigma, q_angle, k_step = 1000.0, 2 ** 18, 0.01, 5e-5, 5e-6
    for seed in range(3):
        rng = np.random.default_rng(seed)
        angle = rng.normal(0.0, q_angle, (n + 1, 3))
        y = (rng.normal(0.0, sigma, (n, 3)) + np.diff(angle, axis=0) * rate
             + np.cumsum(rng.normal(0.0, k_step, (n, 3)), axis=0))
        fit = _fit(y, rate)
        sd = np.sqrt(np.diag(fit.cov))
        truth = {WHITE: sigma ** 2 / rate, QUANTISATION: q_angle ** 2, WALK: k_step ** 2 * rate}
        for term, value in truth.items():
            assert fit.coef[term] > 0, (term, fit.coef)
            assert abs(fit.coef[term] - value) < 4.0 * sd[term], (term, fit.coef[term], value, sd[term])
            assert fit.coef[term] == pytest.approx(value, rel=0.5 if term == WALK else 0.05)
        assert fit.coef[FILTERED] == 0 and fit.tc == 0 and fit.fits


def test_fit_allan_white_noise_gets_no_other_term():
    for seed in range(5):
        fit = _fit(np.random.default_rng(seed).normal(0.0, 0.01, (60000, 3)))
        assert fit.coef[WHITE] == pytest.approx(1e-4 / RATE, rel=0.05)
        assert fit.coef[QUANTISATION] == fit.coef[FILTERED] == fit.coef[WALK] == fit.coef[FLICKER_TERM] == 0
        assert fit.first == 0 and fit.fits


def test_fit_allan_recognises_filtered_noise():
    # first-order low-pass filtered white noise (AR(1), rho 0.8): flat Allan deviation below its time constant,
    # white above it with the low-frequency density sigma^2 (1 + rho) / (1 - rho) / rate
    sigma, rho = 0.01, 0.8
    y = lfilter([np.sqrt(1 - rho ** 2) * sigma], [1.0, -rho], np.random.default_rng(3).standard_normal((120000, 3)),
                axis=0)
    fit = _fit(y)
    tc = -1.0 / np.log(rho) / RATE
    assert fit.coef[FILTERED] > 0 and tc / 2.5 < fit.tc < 2.5 * tc and fit.first == 0, (fit.coef, fit.tc)
    level = fit.coef[WHITE] + fit.coef[FILTERED]
    assert level == pytest.approx(sigma ** 2 * (1 + rho) / (1 - rho) / RATE, rel=0.15)
    assert fit.fits


def test_identify_noise_differentiated_noise_and_still_start():
    # gyro 2 like a motion-capture rate: the motion plus a differentiated noisy angle (slope -1, a per-sample std
    # 6x gyro 1's white noise) plus a little white; 20 s at rest first. Gyro 1's white noise comes from its still
    # stretch, the residual's fit carries the slope -1 term, and gyro 2's white level is far below its per-sample std
    rng = np.random.default_rng(8)
    n, s1, s2, q = 15000, 0.1 * DEG, 0.05 * DEG, 0.6 * DEG / RATE / np.sqrt(2.0)
    truth = HumanMotion(1.0, rng=rng)(np.arange(n) / RATE)
    truth[:2000] = 0.0
    w1 = truth + rng.normal(0.0, s1, (n, 3))
    w2 = truth + rng.normal(0.0, s2, (n, 3)) + np.diff(rng.normal(0.0, q, (n + 1, 3)), axis=0) * RATE
    nm = _identify(w1, w2)
    assert nm.still_noise_std is not None and "USED: each gyro's own white level" in nm.sources["noise"]
    assert nm.noise_std[0] == pytest.approx(s1, rel=0.1)
    assert nm.quantisation == pytest.approx(q, rel=0.3)
    per_sample_2 = np.hypot(s2, np.sqrt(2.0) * q * RATE)
    assert nm.noise_std[1] < 0.5 * per_sample_2
    assert "still stretches" in nm.describe()


def test_identify_noise_never_above_the_residual():
    # a still start with 3x the noise of the moving part (a shaking table): the still stretch's level would imply a
    # residual 3x wider than the residual itself; it is capped at the residual's spread and says so
    rng = np.random.default_rng(9)
    n, sigma = 12000, 0.05 * DEG
    truth = HumanMotion(1.0, rng=rng)(np.arange(n) / RATE)
    truth[:2000] = 0.0
    scale = np.where(np.arange(n) < 2000, 3.0, 1.0)[:, None]
    sim = simulate_pair(truth, noise_std=(1e-12, 1e-12), bias_walk_std=0.0, rng=rng)
    w1 = sim.omega_1 + scale * rng.normal(0.0, sigma, (n, 3))
    w2 = sim.omega_2 + scale * rng.normal(0.0, sigma, (n, 3))
    nm = _identify(w1, w2)
    A, b = solve_A(Moments.from_samples(w1, w2))
    r = w1 - w2 @ A.T - b
    implied = nm.noise_std[0] ** 2 + nm.noise_std[1] ** 2 * np.sum(A * A) / 3.0
    assert "CAPPED" in nm.sources["noise"]
    assert implied <= 1.5 ** 2 * np.mean(r.var(axis=0)) * 1.001


# ------------------------------------------------------------------------------------------- real data
def _static_std(omega, still, window):
    k = len(omega) // window
    x = omega[:k * window].reshape(k, window, 3)
    inside = still[:k * window].reshape(k, window).all(axis=1)
    return float(np.median(x[inside].std(axis=1, ddof=1).mean(axis=1)))


def test_identify_noise_broad_imu_white_noise_within_1p5x_of_its_rest():
    """BROAD: the IMU against the rate differentiated from motion capture (calibrate_pair's defaults); the IMU's
    identified white noise against its std at rest (not ``movement``)."""
    d = data_folder("broad_handheld/data_mat")
    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.evaluate.sim import load_broad_pair

    for trial in ("01_undisturbed_slow_rotation_A", "04_undisturbed_slow_rotation_with_breaks_A",
                  "06_undisturbed_fast_rotation_A"):
        gyr, moc, rest, fs = load_broad_pair(trial)
        t = np.arange(len(gyr)) / fs
        nm = calibrate_pair(gyr, moc, t_1=t, t_2=t).noise_model
        static = _static_std(gyr, rest, int(fs))
        assert 1 / 1.5 < nm.noise_std[0] / static < 1.5, (trial, nm.noise_std[0] / DEG, static / DEG)
        assert nm.still_noise_std is not None


def test_identify_noise_mimu_static_poses_within_1p5x():
    d = data_folder("mimu_8imu_array/npz")
    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.io import read_npz

    for e, k in ((1, 1), (5, 3), (9, 6)):
        streams = read_npz(d / f"exp_{e}.npz")
        g1, gk = streams[0], streams[k]
        nm = calibrate_pair(g1.omega, gk.omega, t_1=g1.t, t_2=gk.t).noise_model
        for i, g in enumerate((g1, gk)):   # each IMU's static poses: its quietest 1 s windows
            w = 62
            s = g.omega[:len(g.omega) // w * w].reshape(-1, w, 3).std(axis=1, ddof=1).mean(axis=1)
            still = np.repeat(s <= 2.0 * np.quantile(s, 0.1), w)
            static = _static_std(g.omega, np.r_[still, np.zeros(len(g.omega) - still.size, bool)], w)
            assert 1 / 1.5 < nm.noise_std[i] / static < 1.5, (e, k, i, nm.noise_std[i] / static)


def test_write_kalibr_imu_chain_noise_model_that_misses_its_points_is_flagged(tmp_path):
    import dataclasses
    import re

    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.io.writers import write_kalibr_imu_chain

    sim = simulate_pair(n=20000, rng=0)
    t = np.arange(20000) / RATE
    cal = calibrate_pair(sim.omega_1, sim.omega_2, t_1=t, t_2=t)
    assert cal.noise_model.fits
    for worst, flagged in ((cal.noise_model.adev_worst, False), (1.6, True)):
        c = dataclasses.replace(cal, noise_model=dataclasses.replace(cal.noise_model, adev_worst=worst))
        write_kalibr_imu_chain(c, tmp_path / "chain.yaml")
        lines = [ln for ln in (tmp_path / "chain.yaml").read_text().splitlines()
                 if ln.lstrip().startswith("gyroscope_noise_density")]
        assert len(lines) == 2
        for ln in lines:
            value, sd = float(ln.split(":")[1].split("#")[0]), float(re.search(r"\+- ([0-9.eE+-]+)", ln).group(1))
            assert ("UNCERTAIN" in ln) is flagged
            if flagged:   # the uncertainty covers how far the model is off its points
                assert sd >= 0.55 * value   # 0.6 x the value, written to two digits
