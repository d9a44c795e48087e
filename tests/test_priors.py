"""Excitation judged on the motion gyro 2 explains, and scale priors that hold only what the data leave free."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion_gyrocal import ExcitationError, Moments, calibrate_pair, solve
from fusion_gyrocal.core.array import calibrate_array
from fusion_gyrocal.core.observability import (PRIOR_GAUGE, check_excitation, classify, cramer_rao_bound,
                                               explained_scatter)
from fusion_gyrocal.evaluate.scenarios import make_scenario
from fusion_gyrocal.evaluate.sim import (PAPER_NOISE_STD, HumanMotion, load_broad_rates, random_rotation,
                                         shared_data_dir, simulate_pair)
from fusion_gyrocal.online.stream import StreamingCalibrator

DATA = shared_data_dir()
BROAD = DATA / "broad_handheld" / "data_mat" / "06_undisturbed_fast_rotation_A.mat"
MIMU = DATA / "mimu_8imu_array" / "npz"
#: The MIMU board's nominal bottom-side rotation (180 deg about (1, -1, 0) / sqrt 2; SOURCE.md).
FLIP = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def _one_axis_pair(rng, axis, n=6000, noise=PAPER_NOISE_STD, motion=None):
    """Gyro 1 turns about ``axis`` only; gyro 2 = R^T omega + noise (no noise level handed to the solver)."""
    rng = np.random.default_rng(rng)
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    if motion is None:
        motion = HumanMotion(rng=rng)(np.arange(n) / 100.0)[:, 0]
    w = motion[:, None] * axis[None, :]
    R = random_rotation(rng)
    return w + rng.normal(0, noise, w.shape), w @ R + rng.normal(0, noise, w.shape)


def _stream(w1, w2):
    cal = StreamingCalibrator()
    for start in range(0, len(w1), 2000):
        cal.update(w1[start:start + 2000], w2[start:start + 2000])
    return cal.estimate()


API = {"calibrate_pair": lambda w1, w2: calibrate_pair(w1, w2),
       "calibrate_array": lambda w1, w2: calibrate_array([w1, w2]),
       "StreamingCalibrator": _stream}


# ---------------------------------------------------------------------------------------- excitation
@pytest.mark.parametrize("api", API)
@pytest.mark.parametrize("n", [2000, 40000])
def test_check_excitation_one_axis_motion_noise_not_given_raises(api, n):
    w1, w2 = _one_axis_pair(11, [0.3, -0.5, 0.8], n=n)
    with pytest.raises(ExcitationError, match=r"SNR.*Rotate the device about its x and y"):
        API[api](w1, w2)


@pytest.mark.skipif(not BROAD.exists(), reason=f"{BROAD} not present (set FUSION_GYROCAL_DATA to the shared data)")
@pytest.mark.parametrize("api", API)
def test_check_excitation_one_axis_real_handheld_motion_raises(api):
    gyr, _ = load_broad_rates()
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    w1, w2 = _one_axis_pair(12, axis, motion=gyr @ axis, noise=1e-3)
    with pytest.raises(ExcitationError, match="too little motion"):
        API[api](w1, w2)


def test_check_excitation_noise_only_direction_stays_near_chi2_whatever_the_length():
    # along a direction gyro 1 does not turn, what gyro 2 explains is ~ sigma_1^2 chi2(3), for any N
    for n, seed in ((2000, 1), (200000, 2)):
        w1, w2 = _one_axis_pair(seed, [0.0, 0.0, 1.0], n=n, motion=np.random.default_rng(seed).standard_normal(n))
        m = Moments.from_samples(w1, w2)
        E = explained_scatter(m)
        assert E[:2, :2].trace() / PAPER_NOISE_STD**2 < 40.0     # chi2(6) beyond 40: p ~ 3e-7
        assert E[2, 2] > 0.99 * m.S11[2, 2]


@pytest.mark.parametrize("name", ["nominal", "weak_axis", "slow_motion", "near_parallel", "drifting_bias"])
def test_check_excitation_well_excited_scenarios_pass_with_estimated_noise(name):
    d = make_scenario(name, rng=5).data
    cal = calibrate_pair(d.omega_1, d.omega_2)
    assert cal.rigid


def test_check_excitation_weak_but_real_axis_passes_and_noise_only_axis_raises():
    rng = np.random.default_rng(6)
    w = HumanMotion(rng=rng)(np.arange(6000) / 100.0)
    w[:, 0] *= 3e-3                        # x rate ~ 3 mrad/s RMS against 1.7 mrad/s noise: real, weak
    sim = simulate_pair(w, rng=rng)
    m = Moments.from_samples(sim.omega_1, sim.omega_2)
    check_excitation(m, (PAPER_NOISE_STD, PAPER_NOISE_STD))
    w[:, 0] = 0.0
    sim = simulate_pair(w, rng=rng)
    with pytest.raises(ExcitationError, match="mostly x"):
        check_excitation(Moments.from_samples(sim.omega_1, sim.omega_2), (PAPER_NOISE_STD, PAPER_NOISE_STD))


# ---------------------------------------------------------------------------------------- scale priors
def _all_parallel_sim(rng=3):
    R = Rotation.from_rotvec([0.001, -0.002, 0.003]).as_matrix() @ FLIP
    return simulate_pair(rng=rng, R_1_2=R, scale_1=[1.01, 0.99, 1.02], scale_2=[0.98, 1.00, 1.01])


def _determined_ratios(cal):
    """``scale_1[i] / scale_2[j]`` of every parallel axis pair (what Lemma 2 leaves determined)."""
    conf = classify(cal.R_1_2)
    return np.array([cal.scale_1[i] / cal.scale_2[j] for i, j, _ in conf.parallel_pairs])


@pytest.mark.parametrize("std", [0.01, 1.0, 100.0])
def test_solve_scale_prior_keeps_determined_ratios_and_holds_the_rest(std):
    sim = _all_parallel_sim()
    free = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD, scale_prior_std=std)
    assert cal.configuration == "all_axes_parallel" and not cal.scale_observable.any()
    np.testing.assert_allclose(_determined_ratios(cal), _determined_ratios(free), rtol=1e-12)
    np.testing.assert_allclose(cal.R_1_2, free.R_1_2, atol=1e-12)
    # each pair's common factor sits at the prior's maximum: sum (s - 1) s = 0 over the pair
    groups = classify(cal.R_1_2).groups
    np.testing.assert_allclose(PRIOR_GAUGE.condition(groups, [cal.scale_1, cal.scale_2]), 0.0, atol=1e-12)
    # the prior alone sets their spread: two N(1, std^2) draws of one common factor
    np.testing.assert_allclose(cal.scale_std, std / np.sqrt(2.0) * np.stack([cal.scale_1, cal.scale_2]), rtol=0.01)
    assert np.linalg.eigvalsh(cal.covariance).min() >= -1e-12 * np.abs(cal.covariance).max()
    assert "prior" in cal.gauge and any("from the scale prior" in n for n in cal.notes)


@pytest.mark.parametrize("std", [1.0, 100.0])
def test_solve_scale_prior_covariance_is_psd_on_one_parallel_pair(std):
    R = Rotation.from_rotvec([0.0, 0.0, 0.7]).as_matrix()     # z axes parallel (Lemma 3)
    sim = simulate_pair(rng=4, R_1_2=R, scale_1=[1.01, 0.99, 1.02], scale_2=[0.98, 1.00, 1.01])
    m = Moments.from_samples(sim.omega_1, sim.omega_2)
    free = solve(m, noise_std=PAPER_NOISE_STD)
    cal = solve(m, noise_std=PAPER_NOISE_STD, scale_prior_std=std)
    assert cal.configuration == "one_axis_pair_parallel"
    s_free, s = np.concatenate([free.scale_1, free.scale_2]), np.concatenate([cal.scale_1, cal.scale_2])
    rest = [0, 1, 3, 4]                                        # the general group: ratios from the data
    np.testing.assert_allclose(s[rest] / s[0], s_free[rest] / s_free[0], rtol=1e-12)
    assert s[2] / s[5] == pytest.approx(s_free[2] / s_free[5], rel=1e-12)
    assert np.linalg.eigvalsh(cal.covariance).min() >= -1e-12 * np.abs(cal.covariance).max()
    assert np.all(np.abs(s - 1.0) < 0.03)


def test_cramer_rao_bound_scale_prior_is_psd_and_prior_sized_on_parallel_pairs():
    sim = _all_parallel_sim()
    R, s1, s2 = sim.R_1_2, np.array([1.01, 0.99, 1.02]), np.array([0.98, 1.00, 1.01])
    bound = cramer_rao_bound(R, s1, s2, (PAPER_NOISE_STD,) * 2, sim.omega_true_1 @ R, scale_prior_std=1.0)
    assert np.linalg.eigvalsh(bound.covariance).min() >= -1e-12
    # log-scale of gyro 1's x: the common factor of the pair (x ~ y), prior information (s1_x^2 + s2_y^2) / std^2
    assert np.sqrt(bound.covariance[3, 3]) == pytest.approx(1.0 / np.sqrt(s1[0] ** 2 + s2[1] ** 2), rel=1e-3)


@pytest.mark.skipif(not (MIMU / "exp_1.npz").exists(),
                    reason=f"{MIMU}/exp_1.npz not present (set FUSION_GYROCAL_DATA to the shared data)")
@pytest.mark.parametrize("imu", [1, 2, 5])  # IMU 2 (flipped), 3 (same side), 6 (flipped) against IMU 1
def test_calibrate_pair_scale_prior_on_mimu_board_stays_near_one(imu):
    from fusion_gyrocal.io import read_npz

    streams = read_npz(MIMU / "exp_1.npz")
    a, b = streams[0], streams[imu]
    free = calibrate_pair(a.omega, b.omega, t_1=a.t, t_2=b.t)
    cal = calibrate_pair(a.omega, b.omega, t_1=a.t, t_2=b.t, scale_prior_std=0.01)
    assert cal.configuration == "all_axes_parallel"
    assert np.all(np.abs(np.concatenate([cal.scale_1, cal.scale_2]) - 1.0) < 0.05)
    np.testing.assert_allclose(_determined_ratios(cal), _determined_ratios(free), rtol=0.005)
    assert np.isfinite(cal.scale_std).all() and not cal.scale_observable.any()
