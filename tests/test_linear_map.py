"""The full linear map (core/linear_map.py): rotation, scale factors and symmetric relative cross-axis terms."""

import numpy as np
import pytest

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.core.linear_map import cross_axis_budget
from fusion_gyrocal.core.model import PairCalibration
from fusion_gyrocal.core.observability import A_of, cross_matrix, dA_dp
from fusion_gyrocal.evaluate.sim import general_rotation, simulate_pair
from fusion_gyrocal.lie import exp, log

FLIP = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])   # 180 deg about (1, -1, 0): all axes parallel
NOISE = 2e-3


def _pair(rng, R, k=(0.0, 0.0, 0.0), n=20000, scale_1=(1.002, 0.997, 1.004), scale_2=(0.995, 1.003, 1.001)):
    """A pair whose map is ``(I + K) S_1 R S_2^-1`` exactly (the model's convention), white noise."""
    sim = simulate_pair(n=n, rms=0.5, R_1_2=R, noise_std=1e-12, bias_walk_std=0.0, rng=rng)
    w2_true = sim.omega_true_1 @ R                                   # gyro 2's rate in its own frame
    s1, s2 = np.asarray(scale_1), np.asarray(scale_2)
    A = A_of(R, s1, s2, np.asarray(k, float))
    w2 = w2_true * s2 + rng.normal(0.0, NOISE, w2_true.shape)
    w1 = (w2_true * s2) @ A.T + rng.normal(0.0, NOISE, w2_true.shape)
    return w1, w2


def test_dA_dp_cross_axis_terms_match_numerical_derivatives():
    rng = np.random.default_rng(3)
    R, s1, s2, k = general_rotation(rng), rng.uniform(0.98, 1.02, 3), rng.uniform(0.98, 1.02, 3), rng.normal(0, 0.01, 3)
    D = dA_dp(R, s1, s2, k)
    h = 1e-7
    for p in range(12):
        d = np.zeros(12)
        d[p] = h
        A_plus = A_of(exp(d[:3]) @ R, s1 * np.exp(d[3:6]), s2 * np.exp(d[6:9]), k + d[9:])
        np.testing.assert_allclose((A_plus - A_of(R, s1, s2, k)) / h, D[p], atol=1e-6)


def test_calibrate_pair_full_map_recovers_cross_axis_terms_all_axes_parallel():
    k = np.array([0.008, -0.012, 0.005])
    w1, w2 = _pair(np.random.default_rng(11), FLIP, k)
    cal = calibrate_pair(w1, w2)
    assert cal.linear_map == "full"
    sd = np.sqrt(np.diag(cal.cross_axis_covariance))
    assert np.all(np.abs(cal.cross_axis_terms - k) < 4 * sd)
    assert np.all(sd < 1e-3)                                          # determined by the data, not the prior
    d = log(cal.R_1_2 @ FLIP.T)
    repeatable = cal.covariance[:3, :3] - cal.skew_rotation_covariance
    assert float(d @ np.linalg.solve(repeatable, d)) < 16.27            # 99.9 % of chi2(3)
    rigid = calibrate_pair(w1, w2, linear_map="rigid")
    assert np.linalg.norm(log(rigid.R_1_2 @ FLIP.T)) > 5 * np.linalg.norm(d)   # the leak the full map removes


def test_calibrate_pair_auto_all_axes_parallel_without_cross_axis_budgets_only_their_noise():
    w1, w2 = _pair(np.random.default_rng(16), FLIP)
    cal = calibrate_pair(w1, w2)
    assert cal.linear_map == "full"                                     # the data determine every term
    budget = cross_axis_budget(cal.cross_axis_terms, cal.cross_axis_covariance, None)
    np.testing.assert_allclose(np.diag(cal.skew_rotation_covariance), budget)
    assert np.sqrt(budget) < 5 * np.sqrt(np.max(np.diag(cal.cross_axis_covariance)))
    d = log(cal.R_1_2 @ FLIP.T)
    assert float(d @ np.linalg.solve(cal.covariance[:3, :3], d)) < 16.27


def test_calibrate_pair_auto_keeps_the_paper_model_without_cross_axis():
    R = general_rotation(np.random.default_rng(5))
    w1, w2 = _pair(np.random.default_rng(12), R)
    cal = calibrate_pair(w1, w2)
    assert cal.linear_map == "rigid"
    assert np.all(cal.cross_axis_terms == 0.0) and np.all(cal.skew_rotation_covariance == 0.0)


def test_calibrate_pair_full_map_budget_covers_the_unseen_antisymmetric_part():
    k = np.array([0.01, 0.0, -0.01])
    w1, w2 = _pair(np.random.default_rng(13), FLIP, k)
    cal = calibrate_pair(w1, w2, linear_map="full")
    assert cal.cross_axis_chi2 > 100.0                                  # shown by the data: pooled with the prior
    budget = cross_axis_budget(cal.cross_axis_terms, cal.cross_axis_covariance, 0.015)
    np.testing.assert_allclose(np.diag(cal.skew_rotation_covariance), budget)
    assert budget == pytest.approx((3 * 0.015**2 + np.sum(k**2)) / 6, rel=0.1)   # the data's k pooled with the prior
    assert any("full linear map" in note for note in cal.notes)


def test_calibrate_pair_full_map_compensate_and_json_round_trip():
    k = np.array([0.006, 0.004, -0.009])
    w1, w2 = _pair(np.random.default_rng(14), FLIP, k, n=8000)
    cal = calibrate_pair(w1, w2, linear_map="full")
    np.testing.assert_allclose(cal.A, A_of(cal.R_1_2, cal.scale_1, cal.scale_2, cal.cross_axis_terms))
    rms_full = np.sqrt(np.mean((w1 - cal.compensate(w2)) ** 2))
    assert rms_full < 1.2 * np.sqrt(2) * NOISE                        # the map explains all but the noise
    back = PairCalibration.from_dict(cal.to_dict())
    assert back.linear_map == "full"
    np.testing.assert_array_equal(back.cross_axis_terms, cal.cross_axis_terms)
    np.testing.assert_array_equal(back.A, cal.A)


def test_calibrate_pair_linear_map_rejects_unknown_value():
    from fusion_gyrocal.errors import OptionError

    w1, w2 = _pair(np.random.default_rng(15), FLIP, n=2000)
    with pytest.raises(OptionError, match="linear_map"):
        calibrate_pair(w1, w2, linear_map="affine")


def test_cross_matrix_is_symmetric_with_zero_diagonal():
    K = cross_matrix([1.0, 2.0, 3.0])
    np.testing.assert_array_equal(K, K.T)
    np.testing.assert_array_equal(np.diag(K), 0.0)
    assert (K[0, 1], K[1, 2], K[2, 0]) == (1.0, 2.0, 3.0)


def test_calibrate_pair_reference_recovers_gyro_2_intrinsics():
    """Gyro 1's intrinsic matrix known: gyro 2's scale factors and cross-axis terms (upper triangular) and the
    rotation follow from A, in absolute scale."""
    from fusion_gyrocal.core.linear_map import UPPER

    rng = np.random.default_rng(21)
    R = general_rotation(rng)
    S1 = np.array([[1.01, 0.004, -0.006], [0.0, 0.99, 0.003], [0.0, 0.0, 1.005]])
    S2 = np.array([[0.98, 0.012, -0.015], [0.0, 1.02, 0.008], [0.0, 0.0, 0.995]])
    sim = simulate_pair(n=20000, rms=0.5, R_1_2=R, noise_std=1e-12, bias_walk_std=0.0, rng=rng)
    w1 = sim.omega_true_1 @ S1.T + rng.normal(0, NOISE, (20000, 3)) + 0.01
    w2 = (sim.omega_true_1 @ R) @ S2.T + rng.normal(0, NOISE, (20000, 3)) - 0.02
    cal = calibrate_pair(w1, w2, intrinsics_1=S1)
    assert cal.linear_map == "reference" and cal.scale_observable.all()
    np.testing.assert_array_equal(cal.scale_1, np.diag(S1))
    sd = np.sqrt(np.diag(cal.intrinsics_2_covariance))
    z = [(cal.intrinsics_2[a, b] - S2[a, b]) / sd[p] for p, (a, b) in enumerate(UPPER)]
    assert np.all(np.abs(z) < 4.0) and np.all(sd < 2e-4)
    d = log(cal.R_1_2 @ R.T)
    assert float(d @ np.linalg.solve(cal.covariance[:3, :3], d)) < 16.27
    np.testing.assert_allclose(cal.scale_2, np.diag(cal.intrinsics_2))
    assert any("gyro 2's intrinsic matrix" in note for note in cal.notes)


def test_calibrate_pair_intrinsics_transform_the_window_statistics_too():
    """With both intrinsics given the block-robust check sees the same compensated samples as the solve: no
    spurious inflation on white noise."""
    rng = np.random.default_rng(22)
    R = general_rotation(rng)
    S = [np.array([[1.0, 0.01, 0.0], [0.0, 1.0, -0.01], [0.0, 0.0, 1.0]]),
         np.array([[1.0, -0.008, 0.012], [0.0, 1.0, 0.005], [0.0, 0.0, 1.0]])]
    sim = simulate_pair(n=20000, rms=0.5, R_1_2=R, noise_std=1e-12, bias_walk_std=0.0, rng=rng)
    w = [wt @ M.T + rng.normal(0, NOISE, wt.shape) for wt, M in zip((sim.omega_true_1, sim.omega_true_1 @ R), S)]
    cal = calibrate_pair(*w, intrinsics_1=S[0], intrinsics_2=S[1], noise_std=NOISE)
    assert cal.robust_inflation < 3.0
    assert "not significantly larger" in cal.covariance_basis
