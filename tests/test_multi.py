import itertools
from pathlib import Path

import numpy as np
from _examples import load_example
import pytest
from _shared import data_folder
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from fusion_gyrocal import (ConfigurationError, ExcitationError, InputError, Moments, NotRigidError, OptionError,
                            Options, calibrate_streams, solve)
from fusion_gyrocal.core.array import (ArrayCalibration, ArrayMoments, _retract, calibrate_array, joint_cost,
                                  joint_gradient, solve_array)
from fusion_gyrocal.core.refine import ml_cost
from fusion_gyrocal.evaluate.sim import DEG, PAPER_NOISE_STD, HumanMotion, random_rotation, rotation_error

SCALES = np.array([[1.01, 0.99, 1.02], [0.98, 1.00, 1.03], [1.00, 1.02, 0.97], [0.99, 1.01, 1.00]])


def _simulate(rng, R, scales, noise, n=4000, biases=None):
    """Rates of N rigid gyros: y_k = S_k R_k^T omega + b_k + n_k (the module's model)."""
    rng = np.random.default_rng(rng)
    omega = HumanMotion(1.0, rng=rng)(np.arange(n) / 100.0)
    noise = np.broadcast_to(np.asarray(noise, float), (len(R),))
    if biases is None:
        biases = rng.normal(0.0, 0.5 * DEG, (len(R), 3))
    return np.stack([(omega @ Rk) * sk + bk + rng.normal(0.0, sg, omega.shape)
                     for Rk, sk, bk, sg in zip(R, scales, biases, noise)], axis=1), biases


def _rotations(rng, n):
    rng = np.random.default_rng(rng)
    return [np.eye(3)] + [random_rotation(rng) for _ in range(n - 1)]


def _signed_permutation(perm, signs):
    P = np.zeros((3, 3))
    P[range(3), perm] = signs
    return P


def test_calibrate_array_noise_free_recovers_every_parameter():
    R = _rotations(1, 4)
    w, b = _simulate(2, R, SCALES, 1e-12)
    cal = calibrate_array(w)
    assert isinstance(cal, ArrayCalibration) and cal.n_gyros == 4
    for k in range(4):
        assert rotation_error(cal.R_ref_k[k], R[k]) < 1e-9
    np.testing.assert_allclose(cal.scale / cal.scale[0, 0], SCALES / SCALES[0, 0], atol=1e-9)
    for k in range(1, 4):
        A = np.diag(SCALES[0]) @ R[k] @ np.diag(1.0 / SCALES[k])
        np.testing.assert_allclose(cal.bias[k], b[0] - A @ b[k], atol=1e-9)
    assert cal.scale_observable.all() and len(cal.scale_groups) == 1


def test_calibrate_array_noisy_error_within_reported_sigma():
    # NEES of the 6 rotation and 8 scale-ratio errors (gauge "fixed") over 12 runs against chi2(14 * 12) / 12
    nees = []
    for seed in range(12):
        R = _rotations(100 + seed, 3)
        w, _ = _simulate(seed, R, SCALES[:3], PAPER_NOISE_STD, n=3000)
        cal = calibrate_array(w, noise_std=PAPER_NOISE_STD, gauge="fixed")
        dtheta = np.concatenate([Rotation.from_matrix(R[k] @ cal.R_ref_k[k].T).as_rotvec() for k in (1, 2)])
        ds = (cal.scale - SCALES[:3] / SCALES[0, 0]).ravel()[1:]
        err = np.concatenate([dtheta, ds])
        idx = np.r_[3:9, 10:18]  # dtheta_1, dtheta_2, every scale except the fixed scale[0][0]
        nees.append(err @ np.linalg.solve(cal.covariance[np.ix_(idx, idx)], err))
    lo, hi = chi2.ppf([0.005, 0.995], 14 * 12) / 12
    assert lo < np.mean(nees) < hi, np.mean(nees)


def test_calibrate_array_bias_error_within_reported_sigma():
    # NEES of the combined biases b_0 - A_0k b_k of gyros 1 and 2 (6 dof) over 12 runs
    nees = []
    for seed in range(12):
        R = _rotations(300 + seed, 3)
        w, b = _simulate(40 + seed, R, SCALES[:3], PAPER_NOISE_STD, n=3000)
        cal = calibrate_array(w, noise_std=PAPER_NOISE_STD)
        truth = [b[0] - np.diag(SCALES[0]) @ R[k] @ np.diag(1.0 / SCALES[k]) @ b[k] for k in (1, 2)]
        err = np.concatenate([cal.bias[k] - truth[k - 1] for k in (1, 2)])
        idx = np.r_[18 + 3:18 + 9]
        nees.append(err @ np.linalg.solve(cal.covariance[np.ix_(idx, idx)], err))
    lo, hi = chi2.ppf([0.005, 0.995], 6 * 12) / 12
    assert lo < np.mean(nees) < hi, np.mean(nees)


def test_calibrate_array_names_the_gyro_that_fails():
    R = _rotations(34, 3)
    w, _ = _simulate(35, R, SCALES[:3], PAPER_NOISE_STD)
    w = w.copy()
    w[:, 2] = _simulate(36, R, SCALES[:3], PAPER_NOISE_STD)[0][:, 2]  # gyro 3 rides on another device
    with pytest.raises(NotRigidError, match="gyro 3 against the reference gyro 1"):
        calibrate_array(w)
    still = w.copy()
    still[:, 1] = still[0, 1]  # gyro 2 reports a constant rate
    with pytest.raises((ExcitationError, InputError), match="gyro 2 against"):
        calibrate_array(still)


def test_calibrate_array_loops_close_exactly():
    R = _rotations(3, 4)
    w, _ = _simulate(4, R, SCALES, PAPER_NOISE_STD)
    cal = calibrate_array(w)
    for i, j, k in itertools.permutations(range(4), 3):
        loop = cal.pair(i, j).R_1_2 @ cal.pair(j, k).R_1_2 @ cal.pair(k, i).R_1_2
        assert rotation_error(loop, np.eye(3)) < 1e-12


def test_calibrate_array_general_gyro_links_scales_of_a_parallel_pair():
    # gyros 0 and 1 are axis-parallel (the pair alone gives only per-axis ratios, Lemma 2); gyro 2 is in a
    # general orientation to both, so jointly every scale factor is determined up to the one global scale
    P = _signed_permutation([1, 0, 2], [-1, -1, -1])
    R = [np.eye(3), P, random_rotation(32)]
    w, _ = _simulate(33, R, SCALES[:3], PAPER_NOISE_STD, n=6000)
    cal = calibrate_array(w, noise_std=PAPER_NOISE_STD, gauge="fixed")
    assert cal.configurations[0][1] == "all_axes_parallel" and cal.configurations[0][2] == "general"
    assert len(cal.scale_groups) == 1 and cal.scale_observable.all()
    std = np.sqrt(np.diag(cal.covariance)[9:18]).reshape(3, 3)
    err = cal.scale - SCALES[:3] / SCALES[0, 0]
    assert np.all(np.abs(err) <= 5 * std + 1e-15)
    assert std[1].max() < 2e-3  # gyro 1's scale factors, unobservable from the pair (0, 1) alone
    assert not solve(cal.moments.pair(0, 1)).scale_observable.any()


def test_joint_cost_two_gyros_equals_pair_ml_cost():
    R = _rotations(5, 2)
    w, _ = _simulate(6, R, SCALES[:2], PAPER_NOISE_STD)
    am = ArrayMoments.from_samples(w)
    noise = (0.1 * DEG, 0.2 * DEG)
    Rp = random_rotation(7, angle_deg=2.0) @ R[1]
    s1, s2 = SCALES[0] * 1.01, SCALES[1] * 0.98
    joint = joint_cost(np.stack([np.eye(3), Rp]), np.stack([s1, s2]), am.scatter, noise)
    assert joint == pytest.approx(ml_cost(Rp, s1, s2, am.pair(0, 1), noise), rel=1e-12)


def test_joint_gradient_matches_numerical_derivative():
    rng = np.random.default_rng(8)
    R = np.stack(_rotations(9, 3))
    w, _ = _simulate(10, R, SCALES[:3], 0.01, n=2000)
    Sc = ArrayMoments.from_samples(w).scatter
    noise = np.array([0.01, 0.02, 0.015])
    Rp, sp = _retract(R, SCALES[:3], rng.normal(0.0, 0.05, 18))
    g = joint_gradient(Rp, sp, Sc, noise)
    num = np.empty(18)
    h = 1e-6
    for p in range(18):
        d = np.zeros(18)
        d[p] = h
        num[p] = (joint_cost(*_retract(Rp, sp, d), Sc, noise) - joint_cost(*_retract(Rp, sp, -d), Sc, noise)) / (2 * h)
    np.testing.assert_allclose(g, num, atol=1e-6 * np.abs(g).max())


def test_solve_array_two_gyros_matches_pair_solve():
    R = _rotations(11, 2)
    w, _ = _simulate(12, R, SCALES[:2], PAPER_NOISE_STD)
    am = ArrayMoments.from_samples(w)
    noise = (PAPER_NOISE_STD, 2 * PAPER_NOISE_STD)
    view = solve_array(am, noise_std=noise).pair(0, 1)
    ref = solve(am.pair(0, 1), noise_std=noise)
    assert rotation_error(view.R_1_2, ref.R_1_2) < 1e-9
    np.testing.assert_allclose(view.scale_1, ref.scale_1, rtol=1e-9)
    np.testing.assert_allclose(view.scale_2, ref.scale_2, rtol=1e-9)
    np.testing.assert_allclose(view.bias, ref.bias, atol=1e-12)
    # same information up to the signal scatter, estimated from both gyros here and from gyro 2 alone in solve()
    np.testing.assert_allclose(view.covariance, ref.covariance, rtol=1e-2, atol=1e-2 * np.abs(ref.covariance).max())


def test_array_moments_merge_equals_one_pass_and_stacked_scatter():
    R = _rotations(13, 3)
    w, _ = _simulate(14, R, SCALES[:3], PAPER_NOISE_STD, n=3001)
    whole = ArrayMoments.from_samples(w)
    halves = ArrayMoments.from_samples(w[:1234]) + ArrayMoments.from_samples(w[1234:])
    x = w.reshape(w.shape[0], 9)
    xc = x - x.mean(axis=0)
    np.testing.assert_allclose(whole.scatter, xc.T @ xc, rtol=1e-12, atol=1e-12 * np.abs(xc.T @ xc).max())
    np.testing.assert_allclose(halves.scatter, whole.scatter, rtol=1e-12, atol=1e-12 * np.abs(whole.scatter).max())
    np.testing.assert_allclose(whole.mean, x.mean(axis=0), rtol=1e-13, atol=1e-15)
    sw = whole.pair(2, 0)
    assert isinstance(sw, Moments)
    np.testing.assert_allclose(sw.S12, whole.scatter[6:9, 0:3])


def test_calibrate_array_all_axes_parallel_recovers_per_axis_ratios():
    P1 = _signed_permutation([1, 0, 2], [-1, -1, -1])  # the MIMU bottom-side layout
    P2 = _signed_permutation([2, 0, 1], [1, 1, 1])
    R = [np.eye(3), P1, P2]
    w, _ = _simulate(15, R, SCALES[:3], PAPER_NOISE_STD)
    cal = calibrate_array(w, noise_std=PAPER_NOISE_STD)
    assert len(cal.scale_groups) == 3 and not cal.scale_observable.any()
    assert cal.configurations[0][1] == cal.configurations[1][2] == "all_axes_parallel"
    for k, Rk in ((1, P1), (2, P2)):
        assert rotation_error(cal.R_ref_k[k], Rk) < 5 * np.sqrt(np.sum(cal.rotation_std_rad[k] ** 2))
        perm = np.argmax(np.abs(Rk), axis=1)
        for a in range(3):
            r, std = cal.scale_ratio(0, a, k, perm[a])
            assert abs(r - SCALES[0, a] / SCALES[k, perm[a]]) < 5 * std
            assert 0 < std < 1e-3
    view = cal.pair(0, 1)
    assert view.configuration == "all_axes_parallel" and np.isinf(np.diag(view.covariance)[3:9]).all()


def test_scale_ratio_across_groups_raises_configuration_error():
    R = [np.eye(3), _signed_permutation([1, 0, 2], [-1, -1, -1])]
    w, _ = _simulate(16, R, SCALES[:2], PAPER_NOISE_STD)
    cal = calibrate_array(w)
    with pytest.raises(ConfigurationError, match="different groups"):
        cal.scale_ratio(0, 0, 1, 0)  # x of gyro 0 is linked to y of gyro 1, not x


def test_calibrate_array_one_axis_parallel_links_rest_of_the_scales():
    # gyro 1 shares only its z axis with gyro 0: one group of four and one ratio-only pair
    Rz = Rotation.from_euler("z", 40, degrees=True).as_matrix()
    w, _ = _simulate(17, [np.eye(3), Rz], SCALES[:2], PAPER_NOISE_STD)
    cal = calibrate_array(w)
    assert cal.configurations[0][1] == "one_axis_pair_parallel"
    assert cal.scale_observable.tolist() == [[True, True, False], [True, True, False]]


def test_calibrate_array_reference_choice_changes_only_the_frame():
    R = _rotations(18, 3)
    w, _ = _simulate(19, R, SCALES[:3], PAPER_NOISE_STD)
    c0 = calibrate_array(w, noise_std=PAPER_NOISE_STD)
    c1 = calibrate_array(w, noise_std=PAPER_NOISE_STD, reference=1)
    assert c1.reference == 1 and rotation_error(c1.R_ref_k[1], np.eye(3)) == 0.0
    for k in range(3):
        assert rotation_error(c1.R_ref_k[k], c0.R_ref_k[1].T @ c0.R_ref_k[k]) < 1e-9
    np.testing.assert_allclose(c1.scale / c1.scale[0, 0], c0.scale / c0.scale[0, 0], rtol=1e-8)


def test_calibrate_array_fixed_gauge_holds():
    R = _rotations(20, 3)
    w, _ = _simulate(21, R, SCALES[:3], PAPER_NOISE_STD)
    cal = calibrate_array(w, gauge="fixed", reference=2)
    assert cal.scale[2, 0] == pytest.approx(1.0, abs=1e-14)
    assert "scale[2][0] == 1" in cal.gauge
    assert cal.covariance[9 + 6, 9 + 6] == pytest.approx(0.0, abs=1e-20)  # scale block starts at 3N = 9
    assert cal.covariance[9 + 7, 9 + 7] > 0.0


def test_calibrate_array_estimates_each_gyro_noise():
    # three-cornered hat: with four gyros every gyro's noise is observable
    noise = np.array([0.05, 0.1, 0.2, 0.15]) * DEG
    R = _rotations(22, 4)
    w, _ = _simulate(23, R, SCALES, noise, n=20000)
    cal = calibrate_array(w)
    # std of a noise estimate from ~3 * 20000 residuals is well below 1%; allow 3%
    np.testing.assert_allclose(cal.noise_std, noise, rtol=0.03)


def test_calibrate_array_piecewise_bias_window():
    R = _rotations(24, 3)
    w, b = _simulate(25, R, SCALES[:3], PAPER_NOISE_STD, n=6000)
    w = w.copy()
    w[3000:, 1] += 2.0 * DEG  # gyro 1's bias jumps half way
    const = calibrate_array(w, noise_std=PAPER_NOISE_STD)
    windowed = calibrate_array(w, noise_std=PAPER_NOISE_STD, bias_window=500)
    assert windowed.bias_segments == 12
    err_c, err_w = rotation_error(const.R_ref_k[1], R[1]), rotation_error(windowed.R_ref_k[1], R[1])
    assert err_w < 5 * np.linalg.norm(windowed.rotation_std_rad[1]) < err_c


def test_calibrate_array_does_not_modify_input():
    R = _rotations(26, 3)
    w, _ = _simulate(27, R, SCALES[:3], PAPER_NOISE_STD)
    before = w.copy()
    calibrate_array(w, mask=np.ones(w.shape[0], bool))
    np.testing.assert_array_equal(w, before)


@pytest.mark.parametrize("omegas, match", [
    (np.zeros((100, 3)), "expected shape"),
    (np.zeros((100, 1, 3)), "at least 2 gyros"),
    ([np.zeros((100, 3)), np.zeros((99, 3))], "expected 100 samples"),
    (np.zeros((100, 3, 2)), "expected shape"),
])
def test_calibrate_array_bad_shapes_raise_input_error(omegas, match):
    with pytest.raises(InputError, match=match):
        calibrate_array(omegas)


def test_calibrate_array_non_finite_sample_names_gyro_and_sample():
    R = _rotations(28, 3)
    w, _ = _simulate(29, R, SCALES[:3], PAPER_NOISE_STD, n=500)
    w = w.copy()
    w[123, 2, 1] = np.nan
    with pytest.raises(InputError, match="gyro 3: .*sample 123"):
        calibrate_array(w)
    mask = np.ones(500, bool)
    mask[123] = False
    assert calibrate_array(w, mask=mask).n_samples == 499


@pytest.mark.parametrize("kwargs, exc", [
    ({"reference": 3}, OptionError), ({"reference": -1}, OptionError), ({"gauge": "nope"}, OptionError),
    ({"noise_std": [1e-3, 1e-3]}, OptionError), ({"noise_std": -1.0}, OptionError),
])
def test_calibrate_array_bad_options_raise(kwargs, exc):
    R = _rotations(30, 3)
    w, _ = _simulate(31, R, SCALES[:3], PAPER_NOISE_STD, n=500)
    with pytest.raises(exc):
        calibrate_array(w, **kwargs)


# ------------------------------------------------------------------------------------------- real data


def _example():
    """The example script as a module: its session loop and SOURCE.md reader are what the tests check."""
    return load_example("mimu_array")


def _mimu_dir() -> Path:
    return data_folder("mimu_8imu_array")


@pytest.fixture(scope="module")
def mimu_runs():
    """Joint and pairwise estimates for the 9 sessions (the example's loop over the recordings read with
    ``fusion_gyrocal.io.read_npz``, clipped samples masked): rotation deviation from nominal in deg (9, 7, 3)
    and per-axis ratios ``scale_0[i] / scale_k[perm(i)]`` (9, 7, 3)."""
    _mimu_dir()
    return _example().main([])


def test_calibrate_array_mimu_rotations_within_half_degree_of_nominal(mimu_runs):
    dev, _ = mimu_runs["joint"]
    assert dev.shape == (9, 7, 3)
    assert np.linalg.norm(dev, axis=2).max() < 0.5


def test_calibrate_array_mimu_ratio_means_match_source_gains(mimu_runs):
    # SOURCE.md's gain ||omega_1|| / ||R omega_k|| is scale_1 / scale_k (the ratio itself, not its inverse).
    _, ratios = mimu_runs["joint"]
    gains = _example().source_gains(_mimu_dir())
    per_session = ratios.mean(axis=2)  # (9, 7): mean over axes
    assert np.abs(per_session.mean(axis=0) / gains - 1.0).max() < 0.003
    # single sessions scatter about the consensus (its own session std reaches 0.15 %): within 0.5 %
    assert np.abs(per_session / gains - 1.0).max() < 0.005


def test_calibrate_array_mimu_joint_as_consistent_as_pairwise(mimu_runs):
    # the full linear map (the default here) gives every gyro's map to the reference as many parameters as entries on
    # this axis-parallel board: the joint estimate is the pairwise one up to the weights
    dev_j, rat_j = mimu_runs["joint"]
    dev_p, rat_p = mimu_runs["pairwise"]
    assert dev_j.std(axis=0).mean() <= 1.02 * dev_p.std(axis=0).mean()
    assert rat_j.std(axis=0).mean() <= 1.02 * rat_p.std(axis=0).mean()


def test_example_mimu_array_runs_and_reports_both_estimates(capsys):
    _mimu_dir()
    out = _example().main(["--sessions", "3"])
    dev, ratios = out["joint"]
    assert dev.shape == (1, 7, 3) and ratios.shape == (1, 7, 3)
    assert np.linalg.norm(dev, axis=2).max() < 0.5
    assert "session 3:" in capsys.readouterr().out


# ------------------------------------------------------------------------------------------- serialisation
def test_array_calibration_json_roundtrip_keeps_nan_and_inf_apart(tmp_path):
    import dataclasses
    import json

    from fusion_gyrocal.io import read_json, write_json

    R = _rotations(60, 3)
    w, _ = _simulate(61, R, SCALES[:3], PAPER_NOISE_STD)
    cal = calibrate_array(w)
    rms = np.array([np.inf, np.nan, cal.residual_rms[2]])
    cal = dataclasses.replace(cal, residual_rms=rms, time_offset_s=np.array([0.0, 0.031, -0.052]),
                              time_offset_std_s=np.array([0.0, 4e-6, 5e-6]),
                              time_offset_source=("reference", "estimated", "given"))
    p = write_json(cal, tmp_path / "array.json")
    d = json.loads(p.read_text())
    assert d["kind"] == "array_calibration" and d["format_version"] == "1.3"
    assert d["residual_rms"][:2] == [None, None]   # strict JSON: numbers or null, each null named by kind
    assert "/residual_rms/0" in d["non_finite"]["inf"] and "/residual_rms/1" in d["non_finite"]["nan"]
    back = read_json(p)
    assert isinstance(back, ArrayCalibration)
    assert np.isposinf(back.residual_rms[0]) and np.isnan(back.residual_rms[1])
    for name in ("R_ref_k", "scale", "bias", "scale_observable", "covariance", "noise_std", "time_offset_s",
                 "time_offset_std_s"):
        np.testing.assert_array_equal(getattr(back, name), getattr(cal, name))
    assert back.scale_groups == cal.scale_groups and back.configurations == cal.configurations
    assert back.time_offset_source == ("reference", "estimated", "given") and back.notes == cal.notes
    # the moments travel too: the pair view of the loaded result equals the original's
    a, b = cal.pair(1, 2), back.pair(1, 2)
    np.testing.assert_array_equal(a.A, b.A)
    assert b.time_offset_s == pytest.approx(-0.083, abs=1e-15)


def test_array_calibration_from_dict_wrong_version_or_kind_raises_format_error():
    from fusion_gyrocal import FormatError

    R = _rotations(62, 3)
    w, _ = _simulate(63, R, SCALES[:3], PAPER_NOISE_STD)
    d = calibrate_array(w).to_dict()
    with pytest.raises(FormatError, match=r"expected format_version '1.3' \(or an earlier '1.0', '1.1', '1.2'\), got '0.9'"):
        ArrayCalibration.from_dict({**d, "format_version": "0.9"})
    with pytest.raises(FormatError, match="expected kind 'array_calibration'"):
        ArrayCalibration.from_dict({k: v for k, v in d.items() if k != "kind"})
    with pytest.raises(FormatError, match=r"expected the fields \['scale'\]"):
        ArrayCalibration.from_dict({k: v for k, v in d.items() if k != "scale"})


# ------------------------------------------------------------------------------------------- timestamped streams
def _streams(seed, offsets, rates, duration=30.0):
    """Gyro k's own timestamps and rates: its sample at its time t is the motion at t + offsets[k] (gyro 1's clock)."""
    rng = np.random.default_rng(seed)
    motion = HumanMotion(0.8, rng=rng)
    R = _rotations(rng, len(offsets))
    ts, ws = [], []
    for k, (off, rate) in enumerate(zip(offsets, rates)):
        t = 5.0 + np.arange(0, duration, 1 / rate)
        ts.append(t)
        ws.append(motion(t + off) @ R[k] * SCALES[k] + rng.normal(0, PAPER_NOISE_STD, (t.size, 3)))
    return ts, ws, R


def test_calibrate_streams_offsets_and_rates_recover_the_truth():
    offsets = [0.0, 0.031, -0.052]
    ts, ws, R = _streams(40, offsets, [200.0, 100.0, 150.0])
    cal = calibrate_streams(ts, ws)
    assert cal.n_gyros == 3 and cal.time_offset_source == ("reference", "estimated", "estimated")
    np.testing.assert_allclose(cal.time_offset_s, offsets, atol=1e-3)
    for k in (1, 2):
        assert rotation_error(cal.R_ref_k[k], R[k]) < 0.05 * DEG
    np.testing.assert_allclose(cal.scale / cal.scale[0, 0], SCALES[:3] / SCALES[0, 0], atol=2e-3)


def test_calibrate_streams_options_and_keywords_agree_with_given_offsets():
    ts, ws, _ = _streams(41, [0.0, 0.02, 0.02], [100.0, 125.0, 100.0], duration=20.0)
    keywords = dict(time_offset_s=0.02, noise_std=[PAPER_NOISE_STD] * 3, max_rate=3.0, saturation_limit=30.0)
    a = calibrate_streams(ts, ws, **keywords)
    b = calibrate_streams(ts, ws, Options(gyros=3, **keywords))
    np.testing.assert_array_equal(a.R_ref_k, b.R_ref_k)
    assert a.time_offset_source == ("reference", "given", "given")
    np.testing.assert_allclose(a.time_offset_s, [0.0, 0.02, 0.02])


@pytest.mark.parametrize("keywords, match", [
    ({"method": "direct"}, r"^calibrate_streams: calibrates N timestamped gyros jointly and cannot apply \['method'\]"),
    ({"max_plausible_rate": 200.0}, r"cannot apply \['max_plausible_rate'\]; expected only its options"),
    ({"noise_std": [1e-3, 1e-3]}, r"^noise_std: expected one value or one per gyro \(3\), got 2 values"),
])
def test_calibrate_streams_refused_option_raises_option_error(keywords, match):
    ts, ws, _ = _streams(42, [0.0, 0.0, 0.0], [100.0] * 3, duration=5.0)
    with pytest.raises(OptionError, match=match):
        calibrate_streams(ts, ws, **keywords)


def test_calibrate_array_refuses_an_option_it_does_not_apply():
    R = _rotations(43, 3)
    w, _ = _simulate(44, R, SCALES[:3], PAPER_NOISE_STD, n=500)
    with pytest.raises(OptionError, match=r"^calibrate_array: .* cannot apply \['rate_hz', 'time_offset_s'\]"):
        calibrate_array(w, Options(time_offset_s=0.1, rate_hz=50.0))
    with pytest.raises(OptionError, match=r"^noise_std: given for 2 gyros, expected values for 3 gyros"):
        calibrate_array(w, Options(noise_std=1e-3))
    a = calibrate_array(w, Options(gyros=3, noise_std=PAPER_NOISE_STD, gauge="fixed"))
    b = calibrate_array(w, noise_std=PAPER_NOISE_STD, gauge="fixed")
    np.testing.assert_array_equal(a.R_ref_k, b.R_ref_k)
