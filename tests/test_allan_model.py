"""The Allan model's tone and bounded terms, the measured scatter of its points, and the model on real logs (the
moving pair's residual on BROAD and the MIMU board; ``gyrocal noise`` on the MIMU static poses)."""

import numpy as np
import pytest
from scipy.signal import lfilter

from fusion_gyrocal.core.allan import (BOUNDED, TONE, WHITE, allan_deviation, allan_points, bounded_shape, edf_table,
                                       fit_allan, tone_shape)
from _shared import data_folder

RATE = 100.0


def _narrowband(rng, n, freq_hz, rho, rate=RATE):
    """Unit-variance noise whose autocovariance is ``rho^k cos(2 pi freq_hz k / rate)``: the real part of a
    complex AR(1) driven by circular white noise."""
    z = rho * np.exp(2j * np.pi * freq_hz / rate)
    e = rng.standard_normal((n, 3)) + 1j * rng.standard_normal((n, 3))
    x = lfilter([1.0], [1.0, -z], e, axis=0).real
    return x / np.sqrt((1.0 / (1.0 - rho ** 2)))


def test_tone_shape_matches_simulated_narrowband_noise():
    rng = np.random.default_rng(0)
    y = _narrowband(rng, 400_000, 16.0, 0.9)
    taus, adev, sub_n, sub_m = allan_deviation(y, RATE)
    avar = (adev ** 2).mean(axis=1)
    shape = tone_shape(taus, 1.0 / RATE, 16.0, 0.9)
    rel_sd = np.sqrt(2.0 / edf_table(sub_n, sub_m)[:, 0])
    z = (avar - shape) / (shape * rel_sd)
    assert np.all(np.abs(z[:10]) < 4.0), z


def test_bounded_shape_matches_differentiated_gauss_markov_angle():
    rng = np.random.default_rng(1)
    n, tb = 400_000, 0.08                      # angle error: AR(1) of time constant tb, the rate its difference
    rho = np.exp(-1.0 / (RATE * tb))
    sigma_x = 1e-3
    angle = lfilter([np.sqrt(1 - rho ** 2) * sigma_x], [1.0, -rho], rng.standard_normal((n + 1, 3)), axis=0)
    y = np.diff(angle, axis=0) * RATE
    taus, adev, sub_n, sub_m = allan_deviation(y, RATE)
    avar = (adev ** 2).mean(axis=1)
    h_sq = 2.0 * sigma_x ** 2 / tb                                   # its white level at short taus
    rel_sd = np.sqrt(2.0 / edf_table(sub_n, sub_m)[:, 0])
    z = (avar - h_sq * bounded_shape(taus, tb)) / (h_sq * bounded_shape(taus, tb) * rel_sd)
    assert np.all(np.abs(z[:10]) < 4.0), z


def test_allan_points_scatter_is_absent_for_stationary_noise():
    y = np.random.default_rng(2).standard_normal((60_000, 3))
    p = allan_points(y, RATE)
    assert p.scatter.shape == (p.taus.size, 4)
    assert np.count_nonzero(np.isfinite(p.scatter)) <= 2        # three-sigma excesses only, by chance
    np.testing.assert_allclose(p.adev, allan_deviation(y, RATE)[1])


def test_allan_points_scatter_of_bursty_noise_matches_monte_carlo():
    # white noise whose level follows random bursts (as a moving pair's residual follows the motion): the spread
    # of the Allan variance over realisations is far above the stationary estimator's and the batch means see it
    rng = np.random.default_rng(3)
    avars, scatters = [], []
    for _ in range(40):
        env = np.repeat(rng.uniform(0.0, 1.0, 60) ** 3, 1000)[:, None]
        p = allan_points(rng.standard_normal((60_000, 3)) * env, RATE)
        avars.append((p.adev ** 2).mean(axis=1))
        scatters.append(p.scatter[:, 3])
    avars, scatters = np.array(avars), np.array(scatters)
    mc = avars.var(axis=0, ddof=1) / avars.mean(axis=0) ** 2
    measured = np.nanmean(scatters, axis=0)
    for i in range(6):                                          # taus with many batches
        assert np.all(np.isfinite(scatters[:, i]))
        assert 0.5 < measured[i] / mc[i] < 2.0, (i, measured[i], mc[i])
        assert mc[i] > 20 * 2.0 / edf_table(p.sub_n, p.sub_m)[i, 0]    # far above the stationary variance


def test_fit_allan_tone_gives_the_variance_per_sample():
    # white noise plus a narrow band at 12 Hz with twice its variance: the model keeps the tone, passes through
    # the points, and its variance per sample is the samples' (its Allan variance at one sample is not)
    rng = np.random.default_rng(4)
    y = 0.01 * rng.standard_normal((120_000, 3)) + 0.01 * np.sqrt(2.0) * _narrowband(rng, 120_000, 12.0, 0.9)
    taus, adev, sub_n, sub_m = allan_deviation(y, RATE)
    avar = (adev ** 2).mean(axis=1)
    fit = fit_allan(taus, avar, edf_table(sub_n, sub_m), extra=True)
    assert fit.coef[TONE] > 0 and fit.coef[WHITE] > 0 and fit.fits and fit.first == 0
    assert abs(fit.tone[0] - 12.0) <= 2.0
    assert fit.sample_variance() == pytest.approx(y.var(axis=0).mean(), rel=0.05)
    assert abs(avar[0] / y.var(axis=0).mean() - 1.0) > 0.3
    plain = fit_allan(taus, avar, edf_table(sub_n, sub_m))            # without the extra terms: no tone
    assert plain.coef[TONE] == 0 and plain.coef[BOUNDED] == 0


def test_fit_allan_white_noise_gets_no_tone_or_bounded_term():
    for seed in range(3):
        y = np.random.default_rng(10 + seed).normal(0.0, 0.01, (60_000, 3))
        p = allan_points(y, RATE)
        fit = fit_allan(p.taus, (p.adev ** 2).mean(axis=1), edf_table(p.sub_n, p.sub_m), scatter=p.scatter[:, 3],
                        extra=True)
        assert fit.coef[TONE] == 0 and fit.coef[BOUNDED] == 0 and fit.fits
        assert fit.coef[WHITE] == pytest.approx(1e-4 / RATE, rel=0.05)


# --------------------------------------------------------------------------------- real logs


@pytest.mark.shared_data
def test_static_noise_mimu_every_axis_of_one_session_within_10_percent_of_direct():
    from fusion_gyrocal.core.static_noise import rest_stretches, static_noise
    from fusion_gyrocal.io import read_npz

    p = data_folder("mimu_8imu_array") / "npz" / "exp_1.npz"
    ratios = []
    for imu in range(8):
        s = read_npz(p, imu=imu)
        r = static_noise(s.omega, s.rate_hz, valid=s.valid, stretches=rest_stretches(s.omega, s.rate_hz,
                                                                                   valid=s.valid))
        x = np.concatenate([s.omega[a:b] - s.omega[a:b].mean(axis=0) for a, b in r.stretches])
        ratios.append(r.white / (x.std(axis=0) / np.sqrt(s.rate_hz)))
    ratios = np.array(ratios)
    print("white / direct per IMU (x, y, z):", np.round(ratios, 3).tolist())
    # IMU 2's z axis carries a 9-11 Hz tone of about twice its white variance (it read 1.94x before the tone term)
    np.testing.assert_array_less(np.abs(ratios - 1.0), 0.10)


@pytest.mark.shared_data
def test_residual_allan_model_passes_through_its_points_on_broad_and_mimu():
    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.evaluate.sim import load_broad_pair
    from fusion_gyrocal.io import read_npz

    # BROAD trial 07: the IMU against the motion-capture rate (the model was 3.1x off its points before the
    # measured scatter and the bounded term)
    data_folder("broad_handheld")
    gyr, moc, _, fs = load_broad_pair("07_undisturbed_fast_rotation_B")
    t = np.arange(len(gyr)) / fs
    nm = calibrate_pair(gyr, moc, t_1=t, t_2=t).noise_model
    assert nm.fits, nm.sources["noise"]
    # MIMU session 5, IMU 1 against IMU 2 (1.27x beyond the points' scatter with white and walk alone)
    streams = read_npz(data_folder("mimu_8imu_array") / "npz" / "exp_5.npz")
    nm = calibrate_pair(streams[0].omega, streams[1].omega, t_1=streams[0].t, t_2=streams[1].t).noise_model
    assert nm.fits, nm.sources["noise"]
    # session 7, IMU 1 against IMU 4: 2.2x off before; closer now but not yet within FIT_FACTOR (the residual's
    # short taus carry a structure the tone and bounded terms describe only in part)
    streams = read_npz(data_folder("mimu_8imu_array") / "npz" / "exp_7.npz")
    nm = calibrate_pair(streams[0].omega, streams[3].omega, t_1=streams[0].t, t_2=streams[3].t).noise_model
    assert nm.adev_worst < 1.6, nm.sources["noise"]
