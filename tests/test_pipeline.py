"""calibrate_pair on recordings: real data (../shared/data), flex, non-rigid pairs, timestamps."""

import numpy as np
import pytest

from fusion_gyrocal import NotRigidError, OptionError, calibrate_pair
from fusion_gyrocal.evaluate.sim import (PAPER_NOISE_STD, DEG, HumanMotion, random_rotation, rotation_error, shared_data_dir,
                                simulate_pair)

DATA = shared_data_dir()
needs_data = pytest.mark.skipif(not DATA.exists(), reason="../shared/data not present (real recordings are only in "
                                                          "the project checkout)")
# MIMU4444 board, SOURCE.md: bottom-side IMUs (2, 4, 6, 8) are rotated by C, top-side ones are not.
C_BOTTOM = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
MIMU_GAIN = {2: 1.0025, 3: 1.0014, 4: 1.0001, 5: 0.9976, 6: 1.0059, 7: 1.0014, 8: 1.0069}  # SOURCE.md check fit


@pytest.fixture(scope="module")
def mimu_results():
    from fusion_gyrocal.io import read_npz

    out = {}
    for e in range(1, 10):
        streams = read_npz(DATA / "mimu_8imu_array" / "npz" / f"exp_{e}.npz")
        ref = streams[0]
        for k in range(1, 8):
            cal = calibrate_pair(ref.omega, streams[k].omega, mask=ref.valid & streams[k].valid)
            out.setdefault(k + 1, []).append(cal)
    return out


@needs_data
def test_calibrate_pair_mimu_board_is_all_axes_parallel_near_nominal(mimu_results):
    for imu, cals in mimu_results.items():
        nominal = C_BOTTOM if imu % 2 == 0 else np.eye(3)
        for cal in cals:
            assert cal.configuration == "all_axes_parallel"
            assert not cal.scale_observable.any()
            assert rotation_error(cal.R_1_2, nominal) < 0.5 * DEG


def _ratios(cal):
    perm = np.argmax(np.abs(cal.R_1_2), axis=1)
    return cal.scale_1 / cal.scale_2[perm]


@needs_data
def test_calibrate_pair_mimu_scale_ratios_repeat_across_sessions(mimu_results):
    for imu, cals in mimu_results.items():
        r = np.array([_ratios(c) for c in cals])
        assert np.all(r.std(axis=0) / r.mean(axis=0) < 0.002), (imu, r.std(axis=0))


@needs_data
def test_calibrate_pair_mimu_mean_ratio_matches_source_gain(mimu_results):
    for imu, cals in mimu_results.items():
        mean_ratio = np.mean([_ratios(c) for c in cals])
        assert abs(mean_ratio / MIMU_GAIN[imu] - 1.0) < 0.003, (imu, mean_ratio)


@needs_data
def test_calibrate_pair_walking_legs_not_rigid():
    from fusion_gyrocal.io import read_imu

    d = DATA / "xsens_walking_nonrigid"
    thigh, shank = read_imu(d / "walking_xsens_upperLeg.txt"), read_imu(d / "walking_xsens_lowerLeg.txt")
    with pytest.raises(NotRigidError, match="not rigid"):
        calibrate_pair(thigh.omega, shank.omega)
    flagged = calibrate_pair(thigh.omega, shank.omega, on_not_rigid="flag")
    assert flagged.rigid is False and flagged.unexplained_fraction > 0.5
    assert any("NOT RIGID" in n for n in flagged.notes)


@needs_data
def test_calibrate_pair_broad_motion_with_offset_and_clock():
    from fusion_gyrocal.evaluate.sim import load_broad_rates

    gyr, fs = load_broad_rates("02_undisturbed_slow_rotation_B")
    R = random_rotation(11)
    sim = simulate_pair(gyr, R_1_2=R, scale_1=(1.01, 0.99, 1.0), scale_2=(1.0, 1.02, 0.98), rate_hz=fs, rng=1)
    t1 = np.arange(len(gyr)) / fs
    cal = calibrate_pair(sim.omega_1, sim.omega_2, t_1=t1, t_2=t1 - 0.2117, noise_std=PAPER_NOISE_STD)
    assert abs(cal.time_offset_s - 0.2117) < 5 * cal.time_offset_std_s + 1e-6
    assert rotation_error(cal.R_1_2, R) < 5 * np.linalg.norm(cal.rotation_std_rad)


@pytest.mark.parametrize("rate_2", [100.0, 200.0])
def test_calibrate_pair_different_rates_and_jitter(rate_2):
    rng = np.random.default_rng(int(rate_2))
    motion, R = HumanMotion(0.8, rng=rng), random_rotation(rng)
    t1 = np.arange(0, 40, 0.01)
    t2 = np.sort(np.arange(0, 40, 1 / rate_2) + rng.normal(0, 1e-4, int(40 * rate_2)))
    offset = -0.173
    w1 = motion(t1) + rng.normal(0, PAPER_NOISE_STD, (t1.size, 3))
    w2 = motion(t2 + offset) @ R + 0.01 + rng.normal(0, PAPER_NOISE_STD, (t2.size, 3))
    cal = calibrate_pair(w1, w2, t_1=t1, t_2=t2, noise_std=PAPER_NOISE_STD)
    assert abs(cal.time_offset_s - offset) < 1e-4
    assert rotation_error(cal.R_1_2, R) < 0.02 * DEG


def test_calibrate_pair_flex_rejection_recovers_rigid_accuracy():
    # bursts where the extrinsic bends by up to 1 degree at the fastest 10% of the motion (Section VI.C)
    R = random_rotation(5)
    err = np.zeros((6, 3))
    for seed in range(6):
        rigid = simulate_pair(n=20000, R_1_2=R, rng=seed)
        flex = simulate_pair(n=20000, R_1_2=R, rng=seed, flex_deg=1.0)
        err[seed] = [rotation_error(calibrate_pair(s.omega_1, s.omega_2, noise_std=PAPER_NOISE_STD,
                                                   flex_rejection=f).R_1_2, R)
                     for s, f in ((rigid, "auto"), (flex, False), (flex, "auto"))]
    rmse = np.sqrt((err**2).mean(axis=0))
    assert rmse[1] > 20 * rmse[0]          # flex ruins the calibration without rejection
    assert rmse[2] <= 1.5 * rmse[0], rmse  # and the rejection brings it back to the rigid accuracy


def test_calibrate_pair_flex_reports_rejections_and_flat_residual():
    sim = simulate_pair(n=20000, R_1_2=random_rotation(2), rng=3, flex_deg=1.0)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD)
    assert 0.05 < cal.rejected_fraction < 0.3
    assert abs(cal.rate_residual_correlation) < 0.1 and cal.rigid


def test_calibrate_pair_timestamps_errors_are_specific():
    from fusion_gyrocal import InputError

    sim = simulate_pair(n=500, rng=0)
    t = np.arange(500) / 100.0
    bad = t.copy()
    bad[100:200] = bad[100:200][::-1]    # a reversed stretch (one repeated stamp is repaired: tests/test_clocks.py)
    with pytest.raises(InputError, match="t_2"):
        calibrate_pair(sim.omega_1, sim.omega_2, t_1=t, t_2=bad)
    with pytest.raises(InputError, match="both timestamps or neither"):
        calibrate_pair(sim.omega_1, sim.omega_2, t_1=t)


def test_calibrate_pair_flex_bursts_of_fast_motion_are_rejected():
    # bursts at 4x the usual rates that bend the mounting by up to 1 degree carry most of the motion energy;
    # rejecting them must not be vetoed as "removing the excitation"
    from fusion_gyrocal.evaluate.scenarios import make_scenario

    err = []
    for seed in range(5):
        d = make_scenario("flex", rng=seed).data
        cal = calibrate_pair(d.omega_1, d.omega_2, noise_std=PAPER_NOISE_STD)
        raw = calibrate_pair(d.omega_1, d.omega_2, noise_std=PAPER_NOISE_STD, flex_rejection=False)
        err.append((rotation_error(cal.R_1_2, d.R_1_2), rotation_error(raw.R_1_2, d.R_1_2), cal.rejected_fraction))
    err = np.array(err)
    assert np.sqrt((err[:, 0] ** 2).mean()) < 0.1 * np.sqrt((err[:, 1] ** 2).mean())
    assert np.all(err[:, 2] > 0.02)


def test_calibrate_pair_refuses_timestamp_options_without_timestamps():
    sim = simulate_pair(rng=5, n=2000)
    for kw in ({"time_offset_s": 0.01}, {"max_offset_s": 2.0}, {"rate_hz": 100.0}):
        with pytest.raises(OptionError, match="act on timestamps"):
            calibrate_pair(sim.omega_1, sim.omega_2, **kw)


def test_calibrate_pair_saturation_limit_masks_sample_aligned_input():
    sim = simulate_pair(rng=5, n=4000)
    w1 = sim.omega_1.copy()
    limit = float(np.quantile(np.abs(w1).max(axis=1), 0.9))
    clipped = np.abs(w1) >= limit
    w1 = np.clip(w1, -limit, limit)                          # gyro 1 clips at its range
    cal = calibrate_pair(w1, sim.omega_2, saturation_limit=(limit, 1e3))
    assert cal.n_samples == 4000 - int(clipped.any(axis=1).sum())
    ref = calibrate_pair(sim.omega_1, sim.omega_2, mask=~clipped.any(axis=1))
    np.testing.assert_allclose(cal.R_1_2, ref.R_1_2, atol=1e-12)


def test_bias_model_of_options_and_identified_noise():
    from fusion_gyrocal.core.moments import Moments, random_walk_gain, window_moments
    from fusion_gyrocal.options import Options
    from fusion_gyrocal.pipeline.bias import BiasKind, BiasModel

    class Identified:   # what BiasModel.of reads of a NoiseModel
        bias_walk_std = (1e-5, 1e-5)

    noise = (2e-3, 3e-3)
    constant = BiasModel.of(Options(), noise)
    assert constant.kind is BiasKind.CONSTANT and constant.gate_window is None and constant.solve_noise(noise) == noise
    walk = BiasModel.of(Options(), noise, Identified())
    gain, scale = random_walk_gain(Identified.bias_walk_std, noise)
    assert walk == BiasModel(BiasKind.RANDOM_WALK, Identified.bias_walk_std, noise)
    assert walk.gate_window == max(20, int(round(1.0 / gain)))
    assert walk.solve_noise(noise) == tuple(np.asarray(noise) * scale) and walk.solve_noise(None) is None
    user = BiasModel.of(Options(noise_std=1e-3, bias_walk_std=2e-5), (1e-3, 1e-3), Identified())
    assert user.walk_std == (2e-5, 2e-5)                 # the user's walk wins over the identified one
    piecewise = BiasModel.of(Options(bias_window=500), noise, Identified())
    assert piecewise == BiasModel(BiasKind.PIECEWISE, window=500) and piecewise.gate_window == 500
    sim = simulate_pair(n=4000, rng=2)
    m, windows = piecewise.moments(sim.omega_1, sim.omega_2, None)
    assert windows is None and m.segments == Moments.pool_all(window_moments(sim.omega_1, sim.omega_2, 500)).segments
    assert piecewise.moments(sim.omega_1, sim.omega_2, None, window=100)[1].pooled


def test_solve_noise_argument_weighs_like_the_option_and_leaves_options_alone():
    from fusion_gyrocal.core.moments import Moments
    from fusion_gyrocal.core.solve import solve
    from fusion_gyrocal.options import Options

    sim = simulate_pair(n=6000, rng=5)
    m = Moments.from_samples(sim.omega_1, sim.omega_2)
    o = Options()
    given = solve(m, o, noise=(2e-3, 3e-3))
    option = solve(m, o, noise_std=(2e-3, 3e-3))
    assert o.noise_std is None
    np.testing.assert_array_equal(given.covariance, option.covariance)
    np.testing.assert_array_equal(given.noise_std, option.noise_std)
    assert given.noise_source == option.noise_source == "user"


def test_flex_imports_nothing_from_the_pipeline_module():
    import ast
    import inspect

    from fusion_gyrocal.pipeline import flex

    tree = ast.parse(inspect.getsource(flex))
    modules = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert "pipeline" not in modules and not any(m and m.endswith("pipeline.pipeline") for m in modules)
