"""identify_noise: white noise, bias walk and model error identified from a moving rigid pair."""

import numpy as np
import pytest

from fusion_gyrocal.core.direct import solve_A
from fusion_gyrocal.core.moments import Moments
from fusion_gyrocal.core.noise import NoiseModel, identify_noise
from fusion_gyrocal.errors import InputError, OptionError
from fusion_gyrocal.evaluate.sim import (DEG, PAPER_BIAS_WALK_STD, PAPER_NOISE_STD, HumanMotion, shared_data_dir,
                                         simulate_pair)

RATE = 100.0


def _identify(w1, w2, mask=None, rate=RATE):
    A, b = solve_A(Moments.from_samples(w1, w2, mask=mask))
    return identify_noise(w1, w2, A, b, rate_hz=rate, mask=mask)


def _normalised_errors(walk_factor, seeds, n=60000):
    z_noise, z_walk, models = [], [], []
    for seed in seeds:
        sim = simulate_pair(n=n, bias_walk_std=walk_factor * PAPER_BIAS_WALK_STD, rng=seed)
        nm = _identify(sim.omega_1, sim.omega_2)
        # residual n_1 - A n_2 and walk b_1 - A b_2 (A is a rotation here): the sums are what is observed
        z_noise.append((nm.residual_noise_std - np.sqrt(2.0) * PAPER_NOISE_STD) / nm.residual_noise_std_uncertainty)
        if walk_factor:
            z_walk.append((nm.residual_walk_std - np.sqrt(2.0) * walk_factor * PAPER_BIAS_WALK_STD)
                          / nm.residual_walk_std_uncertainty)
        models.append(nm)
    return np.array(z_noise), np.array(z_walk), models


def test_identify_noise_white_within_its_uncertainty_and_constant_bias():
    z, _, models = _normalised_errors(0.0, range(10))
    assert np.mean(np.abs(z) < 3.0) >= 0.9, z
    assert np.all(np.abs(z) < 5.0), z
    for nm in models:
        assert nm.bias_model == "constant" and nm.bias_walk_std is None
        assert nm.kind == "white noise" and nm.is_white
        assert np.allclose(nm.noise_std, PAPER_NOISE_STD, rtol=0.03)
        assert nm.calibrate_keywords == {"noise_std": nm.noise_std}


def test_identify_noise_drifting_bias_chooses_random_walk_near_the_truth():
    z_noise, z_walk, models = _normalised_errors(100.0, range(10))
    assert np.mean(np.abs(z_noise) < 3.0) >= 0.8, z_noise
    assert np.mean(np.abs(z_walk) < 3.0) >= 0.8, z_walk
    for nm in models:
        assert nm.bias_model == "random walk" and nm.kind == "white noise + bias random walk"
        # per gyro, as calibrate_pair takes it: the equal split of the observed sum
        assert np.allclose(nm.bias_walk_std, 100 * PAPER_BIAS_WALK_STD, rtol=0.1)
        assert set(nm.calibrate_keywords) == {"noise_std", "bias_walk_std"}
        assert np.allclose(nm.random_walk, np.array(nm.bias_walk_std) * np.sqrt(RATE))


def test_identify_noise_paper_walk_is_too_slow_to_matter():
    sim = simulate_pair(n=6000, rng=3)  # the paper's walk, 60 s
    assert _identify(sim.omega_1, sim.omega_2).bias_model == "constant"


def test_identify_noise_static_start_splits_unequal_gyros():
    for seed in range(3):
        rng = np.random.default_rng(seed)
        truth = HumanMotion(1.0, rng=rng)(np.arange(12000) / RATE)
        truth[:2000] = 0.0  # 20 s at rest first
        sim = simulate_pair(truth, noise_std=(0.05 * DEG, 0.15 * DEG), bias_walk_std=0.0, rng=rng)
        nm = _identify(sim.omega_1, sim.omega_2)
        z = (np.array(nm.noise_std) - np.array(sim.noise_std)) / np.array(nm.noise_std_uncertainty)
        assert np.all(np.abs(z) < 4.0), z
        assert np.allclose(nm.noise_std, sim.noise_std, rtol=0.06)
        assert nm.sources["split"].startswith("steady stretches") and "0.0-20.0 s" in nm.sources["split"]


def test_identify_noise_without_rest_splits_by_third_differences():
    sim = simulate_pair(n=20000, noise_std=(0.05 * DEG, 0.15 * DEG), bias_walk_std=0.0, rng=4)
    nm = _identify(sim.omega_1, sim.omega_2)
    assert nm.sources["split"].startswith("third differences")
    assert nm.noise_std[0] < 0.6 * nm.noise_std[1]


def test_identify_noise_rate_dependent_scale_error_is_model_error_not_noise():
    for seed in range(3):
        sim = simulate_pair(n=60000, bias_walk_std=0.0, rng=seed)
        w2_true = sim.omega_true_1 @ sim.R_1_2
        w2 = sim.omega_2 + 0.002 * np.linalg.norm(w2_true, axis=1)[:, None] * w2_true  # 0.2 % per rad/s
        plain = _identify(sim.omega_1, sim.omega_2)
        nm = _identify(sim.omega_1, w2)
        assert nm.kind == "not white noise: rate-dependent misfit" and not nm.is_white
        assert "NOT white noise" in nm.notes[0]
        assert nm.misfit_share > 0.1 and plain.misfit_share < 0.05
        assert 0.001 < abs(nm.misfit_gain[1]) < 0.004  # the rate-dependent scale error, per rad/s
        # the white noise stays the sensor's (the residual's RMS is larger)
        z = (nm.residual_noise_std - np.sqrt(2.0) * PAPER_NOISE_STD) / nm.residual_noise_std_uncertainty
        assert abs(z) < 4.0, z
        r = sim.omega_1 - w2 @ solve_A(Moments.from_samples(sim.omega_1, w2))[0].T
        assert r.std(axis=0).mean() > 1.1 * nm.residual_noise_std


def test_identify_noise_coloured_noise_is_flagged():
    from scipy.signal import lfilter

    rng = np.random.default_rng(5)
    sim = simulate_pair(n=30000, noise_std=1e-12, bias_walk_std=0.0, rng=rng)
    rho = 0.9
    ar = [lfilter([np.sqrt(1 - rho**2) * PAPER_NOISE_STD], [1.0, -rho], rng.standard_normal((30000, 3)), axis=0)
          for _ in range(2)]
    nm = _identify(sim.omega_1 + ar[0], sim.omega_2 + ar[1])
    assert nm.kind == "coloured noise" and not nm.is_white
    # recognised as low-pass filtered white noise (the Allan fit's filtered term), time constant -1 / ln(rho) samples
    truth_tc = -1.0 / np.log(rho) / RATE
    assert truth_tc / 2.5 < nm.filter_time_s < 2.5 * truth_tc, nm.filter_time_s
    # the white level the motion sees is above the per-sample std of the AR(1) noise
    assert np.all(np.array(nm.noise_std) > 1.5 * PAPER_NOISE_STD)


def test_identify_noise_mask_and_allan_curve():
    sim = simulate_pair(n=20000, bias_walk_std=0.0, rng=6)
    w1 = sim.omega_1.copy()
    w1[5000:5100] = np.nan  # a dropout
    mask = np.ones(20000, bool)
    mask[12000:12500] = False
    nm = _identify(w1, sim.omega_2, mask=mask & np.isfinite(w1).all(axis=1))
    assert isinstance(nm, NoiseModel)
    assert nm.adev.shape == (nm.taus.size, 3) and nm.adev_fit.shape == nm.taus.shape
    assert np.allclose(nm.noise_std, PAPER_NOISE_STD, rtol=0.05)
    # white noise: the Allan deviation at the shortest tau is the per-sample std of the residual
    assert nm.adev[0].mean() == pytest.approx(np.sqrt(2.0) * PAPER_NOISE_STD, rel=0.05)
    assert np.allclose(nm.noise_density, np.array(nm.noise_std) / np.sqrt(RATE))


def test_identify_noise_rejects_bad_input():
    sim = simulate_pair(n=2000, rng=7)
    A, b = np.eye(3), np.zeros(3)
    with pytest.raises(OptionError, match="rate_hz"):
        identify_noise(sim.omega_1, sim.omega_2, A, b, rate_hz=0.0)
    with pytest.raises(InputError, match="at least 16 windows"):
        identify_noise(sim.omega_1[:500], sim.omega_2[:500], A, b, rate_hz=RATE)
    with pytest.raises(InputError, match="mask"):
        identify_noise(sim.omega_1, sim.omega_2, A, b, rate_hz=RATE, mask=np.ones(5, bool))


# ------------------------------------------------------------------------------------------- real data
def test_identify_noise_mimu_white_noise_matches_static_poses_or_is_flagged():
    """IMU 1 against IMU 2 (sessions 1, 9), every IMU (session 4) and the pairs whose clipped violent phase once
    hid the misfit (session 3, IMUs 4 and 7)."""
    d = shared_data_dir() / "mimu_8imu_array" / "npz"
    if not d.exists():
        pytest.skip("../shared/data not present (real recordings are only in the project checkout)")
    from fusion_gyrocal.io import read_npz

    rate = 62.5
    for e, k in [(1, 1), (9, 1)] + [(4, k) for k in range(1, 8)] + [(3, 3), (3, 6)]:
        streams = read_npz(d / f"exp_{e}.npz")
        g1, g2 = streams[0], streams[k]
        mask = g1.valid & g2.valid
        nm = _identify(g1.omega, g2.omega, mask=mask, rate=rate)
        # independent: each IMU's std over the first 20 s (at rest, SOURCE.md), per axis, averaged
        rest = slice(0, int(20 * rate))
        static = [float(np.mean(g.omega[rest].std(axis=0, ddof=1))) for g in (g1, g2)]
        r = g1.omega[mask] - g2.omega[mask] @ solve_A(Moments.from_samples(g1.omega, g2.omega, mask=mask))[0].T
        assert r.std(axis=0).mean() > 10 * np.hypot(*static)  # the residual is mostly not noise
        within = all(1 / 3 < nm.noise_std[i] / static[i] < 3 for i in (0, 1))
        assert within or nm.kind == "not white noise: rate-dependent misfit"
        assert within, (nm.noise_std, static)
        assert nm.kind == "not white noise: rate-dependent misfit"


def test_identify_noise_allan_deviation_equals_allantools_oadev():
    allantools = pytest.importorskip("allantools")
    from fusion_gyrocal.core.allan import allan_deviation
    rng = np.random.default_rng(11)
    y = rng.standard_normal((20000, 3)) + np.cumsum(rng.standard_normal((20000, 3)), axis=0) * 1e-3
    taus, adev, _, _ = allan_deviation(y, RATE)
    phase = np.concatenate([np.zeros((1, 3)), np.cumsum(y - y.mean(axis=0), axis=0)]) / RATE
    for i in (0, 3, 7, taus.size - 1):
        m = int(round(taus[i] * RATE))
        b = max(1, m // 4)
        for a in range(3):
            ref = allantools.oadev(np.ascontiguousarray(phase[::b, a]), rate=RATE / b, data_type="phase",
                                   taus=np.array([taus[i]]))[1][0]
            assert adev[i, a] == pytest.approx(ref, rel=1e-12)


def test_identify_noise_degrees_of_freedom_near_greenhall():
    allantools = pytest.importorskip("allantools")
    from fusion_gyrocal.core.allan import edf
    for N, m in ((20001, 1), (5001, 2), (5001, 16), (2501, 128)):
        for alpha in (0, -1, -2):
            ref = allantools.edf_greenhall(alpha=alpha, d=2, m=m, N=N, overlapping=True)
            assert edf(alpha, float(m), float(N)) == pytest.approx(ref, rel=0.3 if m == 1 else 0.2)


def test_identify_noise_long_log_on_stretches_keeps_the_walk():
    from fusion_gyrocal.core.noise import MAX_IDENTIFY_SAMPLES
    n = 4 * MAX_IDENTIFY_SAMPLES + 5
    walk = 100 * PAPER_BIAS_WALK_STD
    sim = simulate_pair(n=n, bias_walk_std=walk, rng=12)
    nm = _identify(sim.omega_1, sim.omega_2)
    assert "stretches spread over the" in nm.sources["noise"] and nm.rate_hz == RATE
    np.testing.assert_allclose(nm.noise_std, PAPER_NOISE_STD, rtol=0.1)
    assert nm.bias_model == "random walk"
    assert 0.5 * walk < nm.bias_walk_std[0] < 2.0 * walk


def test_identify_noise_two_rate_pair_each_sensors_own_density():
    # gyro 1 at 100 Hz, gyro 2 at 300 Hz spline-resampled onto gyro 1's grid (a fractional offset): the grid's
    # noise of gyro 2 is aliased (3x sparser: below resample.DECIMATE_RATIO, no anti-alias filter) and its
    # per-sample level is not the sensor's; referred back through the Resampling, both densities are the
    # sensors' own; without it gyro 2's is ~1.7x too large
    from fusion_gyrocal.evaluate.sim import general_rotation
    from fusion_gyrocal.pipeline.pipeline import run_pipeline

    rng = np.random.default_rng(3)
    motion = HumanMotion(0.8, rng=rng)
    R = general_rotation(rng, 15.0)
    sigma, rates = (0.002, 0.006), (100.0, 300.0)
    t1, t2 = np.arange(0, 150.0, 1 / rates[0]), np.arange(0.0031, 150.0, 1 / rates[1])
    w1 = motion(t1) + rng.normal(0, sigma[0], (t1.size, 3))
    w2 = motion(t2 + 0.0213) @ R + rng.normal(0, sigma[1], (t2.size, 3))
    run = run_pipeline(w1, w2, t_1=t1, t_2=t2)
    nm = run.calibration.noise_model
    truth = np.array(sigma) / np.sqrt(rates)
    assert nm.sensor_rates == pytest.approx(rates, rel=1e-6)
    np.testing.assert_allclose(nm.noise_density, truth, rtol=0.1)
    A, b = solve_A(Moments.from_samples(run.omega_1, run.omega_2, mask=run.valid))
    grid_only = identify_noise(run.omega_1, run.omega_2, A, b, rate_hz=rates[0], mask=run.valid)
    assert grid_only.noise_density[1] / truth[1] > 1.5


def test_noise_factors_decimation_aliases_and_interpolation_smooths():
    from fusion_gyrocal.pipeline.resample import noise_factors

    t = np.arange(100_000) / 200.0
    variance, diff3, density, white_from = noise_factors(t, np.arange(40_000) / 100.0 + 0.1)   # every other sample
    assert variance == pytest.approx(1.0, abs=0.02) and diff3 == pytest.approx(1.0, abs=0.02)
    assert density == pytest.approx(2.0, rel=0.05) and white_from == 1                    # aliased: twice the density
    variance, diff3, density, white_from = noise_factors(np.arange(50_000) / 100.0, np.arange(80_000) / 200.0 + 0.1)
    assert variance < 0.95 and diff3 < 0.1 and density == pytest.approx(1.0, rel=0.05) and white_from > 4


# ------------------------------------------------------------------------------------------- the kind as a type
def _kinds():
    """One identified model of every kind but coloured (white, white + walk, misfit), from seeded simulations."""
    sim = simulate_pair(n=20000, bias_walk_std=0.0, rng=11)
    walk = simulate_pair(n=60000, bias_walk_std=100 * PAPER_BIAS_WALK_STD, rng=0)
    w2_true = sim.omega_true_1 @ sim.R_1_2
    w2 = sim.omega_2 + 0.002 * np.linalg.norm(w2_true, axis=1)[:, None] * w2_true
    return [_identify(sim.omega_1, sim.omega_2), _identify(walk.omega_1, walk.omega_2), _identify(sim.omega_1, w2)]


def test_noise_model_from_dict_legacy_text_only_keeps_the_kind():
    import dataclasses
    import json

    from fusion_gyrocal.core.noise import NoiseKind

    models = _kinds()
    assert [nm.noise_kind for nm in models] == [NoiseKind.WHITE, NoiseKind.WHITE_WALK, NoiseKind.RATE_MISFIT]
    for nm in models + [dataclasses.replace(models[0], noise_kind=NoiseKind.COLOURED)]:
        d = json.loads(json.dumps(nm.to_dict(), allow_nan=False))
        assert d["kind"] == nm.kind and d["noise_kind"] == nm.noise_kind.value
        legacy = {k: v for k, v in d.items() if k != "noise_kind"}   # format 1.0-1.2: the sentence only
        for back in (NoiseModel.from_dict(d), NoiseModel.from_dict(legacy)):
            assert back.noise_kind is nm.noise_kind and back.kind == nm.kind
            assert (back.is_white, back.is_misfit) == (nm.is_white, nm.is_misfit)
            assert back.to_dict() == d


def test_noise_model_from_dict_unknown_kind_text_is_a_format_error():
    from fusion_gyrocal.errors import FormatError

    d = {k: v for k, v in _kinds()[0].to_dict().items() if k != "noise_kind"}
    d["kind"] = "pink noise"
    with pytest.raises(FormatError, match="noise_model"):
        NoiseModel.from_dict(d)


def test_noise_kind_reworded_text_changes_no_decision(monkeypatch):
    """The sentences are only rendered: rewording them changes no test of the kind, no report wording that
    depends on it, and files written before (the old sentences) still load."""
    import dataclasses

    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.core import noise
    from fusion_gyrocal.core.noise import NoiseKind
    from fusion_gyrocal.io.report import uncertainty_basis

    models = _kinds()
    before = [(nm.is_white, nm.is_misfit, nm.to_dict()) for nm in models]
    sim = simulate_pair(n=6000, rng=3)
    misfit_cal = dataclasses.replace(calibrate_pair(sim.omega_1, sim.omega_2), noise_model=models[2])
    line = uncertainty_basis(misfit_cal)
    monkeypatch.setattr(noise, "_KIND_TEXT", {k: f"reworded {k.value}" for k in NoiseKind})
    for nm, (white, misfit, d) in zip(models, before):
        assert nm.kind == f"reworded {nm.noise_kind.value}"
        assert (nm.is_white, nm.is_misfit) == (white, misfit)
        assert NoiseModel.from_dict({k: v for k, v in d.items() if k != "noise_kind"}).noise_kind is nm.noise_kind
    assert uncertainty_basis(misfit_cal) == line    # "residual is rate-dependent misfit": from the kind


def test_identify_noise_long_drifting_log_finds_the_walk():
    """A log longer than MAX_IDENTIFY_SAMPLES whose bias walks at 100x the paper's rate (0.1 rad/s over the log): it is
    identified on stretches, with A fitted on them with a bias each (a constant-bias A absorbs the drift and leaves
    the motion in the residual, 20-30x the noise) and no Allan difference across two stretches (the walk jumps
    between them). Before: a constant bias (walk 2.3 sigma, the model 2.5x off its points)."""
    walk = 100 * PAPER_BIAS_WALK_STD
    sim = simulate_pair(n=1_000_000, bias_walk_std=walk, rng=1)
    A, b = solve_A(Moments.from_samples(sim.omega_1, sim.omega_2))
    nm = identify_noise(sim.omega_1, sim.omega_2, A, b, rate_hz=100.0)
    assert nm.bias_model == "random walk"
    assert nm.bias_walk_std[0] == pytest.approx(walk, rel=0.2)          # measured 1.03x
    assert nm.noise_std[0] == pytest.approx(PAPER_NOISE_STD, rel=0.1)   # measured 0.99x
    assert nm.adev_worst < 1.2                                          # the model passes through its points
