import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion_gyrocal import (ExcitationError, Gauge, InputError, OptionError, PairCalibration,
                            calibrate_pair)
from fusion_gyrocal.core.model import ROT
from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, DEG, rotation_error, simulate_pair

S1 = np.array([1.01, 0.99, 1.02])
S2 = np.array([0.98, 1.00, 1.03])


def _ratios(scale_1, scale_2):
    s = np.concatenate([scale_1, scale_2])
    return s / s[0]


@pytest.mark.parametrize("method", ["direct", "ml"])
def test_calibrate_pair_noise_free_recovers_every_parameter(method):
    sim = simulate_pair(rng=1, scale_1=S1, scale_2=S2, noise_std=1e-13, bias_walk_std=0.0)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, method=method)
    assert rotation_error(cal.R_1_2, sim.R_1_2) < 1e-9
    np.testing.assert_allclose(_ratios(cal.scale_1, cal.scale_2), _ratios(S1, S2), atol=1e-9)
    np.testing.assert_allclose(cal.bias, sim.bias, atol=1e-9)
    np.testing.assert_allclose(cal.A, sim.A, atol=1e-9)
    assert cal.configuration == "general" and cal.scale_observable.all()


@pytest.mark.parametrize("method", ["direct", "ml"])
def test_calibrate_pair_noisy_error_within_reported_sigma(method):
    # NEES over a few runs: each parameter's error is within a few sigma of the reported covariance.
    nees = []
    for seed in range(20):
        sim = simulate_pair(rng=seed, scale_1=S1, scale_2=S2, n=3000)
        cal = calibrate_pair(sim.omega_1, sim.omega_2, method=method, noise_std=PAPER_NOISE_STD, gauge="fixed")
        dtheta = Rotation.from_matrix(sim.R_1_2 @ cal.R_1_2.T).as_rotvec()
        ds = np.concatenate([cal.scale_1, cal.scale_2]) - np.concatenate([S1, S2]) / S1[0]
        err = np.concatenate([dtheta, ds[1:]])
        P = cal.covariance[:9, :9][np.ix_([0, 1, 2, 4, 5, 6, 7, 8], [0, 1, 2, 4, 5, 6, 7, 8])]
        nees.append(err @ np.linalg.solve(P, err))
    # mean NEES of 8-dof errors over 20 runs: 95% interval of chi2(160)/20 is about [6.3, 9.9]
    assert 5.5 < np.mean(nees) < 11.0, np.mean(nees)


def _signed_permutations():
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product([1, -1], repeat=3):
            P = np.zeros((3, 3))
            P[range(3), perm] = signs
            if np.linalg.det(P) > 0:
                yield P, perm


@pytest.mark.parametrize("P, perm", list(_signed_permutations()))
def test_calibrate_pair_all_axes_parallel_every_signed_permutation(P, perm):
    sim = simulate_pair(rng=7, R_1_2=P, scale_1=S1, scale_2=S2, n=2000)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD)
    assert cal.configuration == "all_axes_parallel"
    assert not cal.scale_observable.any()
    assert rotation_error(cal.R_1_2, P) < 0.05 * DEG
    ratio = cal.scale_1 / cal.scale_2[list(perm)]
    np.testing.assert_allclose(ratio, S1 / S2[list(perm)], atol=5e-4)
    assert np.isinf(cal.scale_std).all() and np.isfinite(cal.rotation_std_rad).all()


def _one_pair_rotation(i, j, sign, angle_deg=40.0):
    for P, perm in _signed_permutations():
        if perm[i] == j and P[i, j] == sign:
            e = np.zeros(3)
            e[i] = 1.0
            return Rotation.from_rotvec(e * angle_deg * DEG).as_matrix() @ P
    raise AssertionError


@pytest.mark.parametrize("i, j, sign", [(i, j, s) for i in range(3) for j in range(3) for s in (1, -1)])
def test_calibrate_pair_one_axis_pair_parallel_every_pair(i, j, sign):
    R = _one_pair_rotation(i, j, sign)
    sim = simulate_pair(rng=10 + 3 * i + j, R_1_2=R, scale_1=S1, scale_2=S2, n=3000)
    for method in ("direct", "ml"):
        cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD, method=method)
        assert cal.configuration == "one_axis_pair_parallel"
        expected = np.ones((2, 3), bool)
        expected[0, i] = expected[1, j] = False
        np.testing.assert_array_equal(cal.scale_observable, expected)
        assert rotation_error(cal.R_1_2, R) < 0.05 * DEG
        assert abs(cal.scale_1[i] / cal.scale_2[j] - S1[i] / S2[j]) < 5e-4
        rest = [(g, a) for g in range(2) for a in range(3) if expected[g, a]]
        est = np.array([(cal.scale_1, cal.scale_2)[g][a] for g, a in rest])
        tru = np.array([(S1, S2)[g][a] for g, a in rest])
        np.testing.assert_allclose(est / est[0], tru / tru[0], atol=2e-3)


def test_calibrate_pair_near_parallel_board_is_not_general():
    # a real board whose gyro 2 is tilted 2 degrees from axis-parallel: ill-conditioned, not general
    R = Rotation.from_rotvec(np.deg2rad([1.2, -1.0, 1.2])).as_matrix()
    sim = simulate_pair(rng=3, R_1_2=R, scale_1=S1, scale_2=S2)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD)
    assert cal.configuration == "all_axes_parallel"
    assert not cal.scale_observable.any()
    assert np.isinf(cal.scale_std).all()
    assert np.isfinite(cal.scale_1).all() and np.isfinite(cal.scale_2).all()
    assert rotation_error(cal.R_1_2, R) < 0.05 * DEG  # the tilt itself is still measured


def test_calibrate_pair_gauge_fixed_sets_scale_1_x():
    sim = simulate_pair(rng=4, scale_1=S1, scale_2=S2)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, gauge="fixed", noise_std=PAPER_NOISE_STD)
    assert cal.scale_1[0] == pytest.approx(1.0, abs=1e-12)
    assert cal.covariance[3, 3] == pytest.approx(0.0, abs=1e-15)
    assert "scale_1[0] == 1" in cal.gauge


def test_calibrate_pair_gauge_unit_prior_matches_paper_closed_form():
    sim = simulate_pair(rng=5, scale_1=S1, scale_2=S2)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, method="direct", noise_std=PAPER_NOISE_STD)
    lam = cal.scale_1[0] / cal.scale_2[0]
    assert cal.scale_1[0] == pytest.approx(lam * (lam + 1) / (lam**2 + 1), rel=1e-12)  # Eq. (32)
    assert cal.scale_2[0] == pytest.approx((lam + 1) / (lam**2 + 1), rel=1e-12)
    assert "unit prior" in cal.gauge


def test_calibrate_pair_known_scale_gauge():
    sim = simulate_pair(rng=6, scale_1=S1, scale_2=S2)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, gauge=Gauge.known_scale(2, 1, S2[1]), noise_std=PAPER_NOISE_STD)
    np.testing.assert_allclose(np.concatenate([cal.scale_1, cal.scale_2]), np.concatenate([S1, S2]), atol=1e-3)


def test_calibrate_pair_scale_prior_fixes_degenerate_directions():
    R = _one_pair_rotation(2, 2, 1)
    sim = simulate_pair(rng=8, R_1_2=R, scale_1=S1, scale_2=S2)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD, scale_prior_std=0.02)
    assert np.isfinite(cal.scale_std).all()
    # the prior-held direction is reported with about the prior's uncertainty, not a confident one
    assert cal.scale_std[0, 2] > 0.005 and cal.scale_std[0, 0] < 0.02
    assert "prior" in cal.gauge


def test_calibrate_pair_one_axis_motion_raises_with_weak_axes():
    rng = np.random.default_rng(0)
    w = np.zeros((2000, 3))
    w[:, 2] = rng.standard_normal(2000)
    w1 = w + rng.normal(0, PAPER_NOISE_STD, w.shape)
    w2 = w + rng.normal(0, PAPER_NOISE_STD, w.shape)
    with pytest.raises(ExcitationError, match=r"mostly [xy].*SNR.*Rotate the device about its x and y"):
        calibrate_pair(w1, w2, noise_std=PAPER_NOISE_STD)


@pytest.mark.parametrize("w1, w2, msg", [
    (np.zeros((3, 3)), np.zeros((3, 3)), "at least 4 samples"),
    (np.ones((50, 3)), np.ones((50, 3)), "constant input"),
    (np.zeros((50, 3)), np.zeros((49, 3)), "expected 50 samples"),
    (np.zeros((50, 4)), np.zeros((50, 4)), r"expected shape \(N, 3\)"),
])
def test_calibrate_pair_bad_input_raises(w1, w2, msg):
    with pytest.raises(InputError, match=msg):
        calibrate_pair(w1, w2)


def test_calibrate_pair_nan_raises_with_index():
    sim = simulate_pair(rng=0, n=1000)
    w1 = sim.omega_1.copy()
    w1[17, 0] = np.nan
    with pytest.raises(InputError, match="sample 17"):
        calibrate_pair(w1, sim.omega_2)


def test_calibrate_pair_does_not_mutate_input():
    sim = simulate_pair(rng=0, n=1000)
    w1, w2 = sim.omega_1.copy(), sim.omega_2.copy()
    calibrate_pair(sim.omega_1, sim.omega_2)
    np.testing.assert_array_equal(w1, sim.omega_1)
    np.testing.assert_array_equal(w2, sim.omega_2)


def test_calibrate_pair_identifies_noise_from_residual_by_default():
    sim = simulate_pair(rng=2, scale_1=S1, scale_2=S2, bias_walk_std=0.0)
    cal = calibrate_pair(sim.omega_1, sim.omega_2)
    np.testing.assert_allclose(cal.noise_std, PAPER_NOISE_STD, rtol=0.05)
    assert cal.noise_source.startswith("identified") and cal.noise_model.kind == "white noise"
    assert cal.noise_model.bias_model == "constant"


def test_calibrate_pair_noise_model_residual_keeps_the_least_squares_residual():
    sim = simulate_pair(rng=2, scale_1=S1, scale_2=S2, bias_walk_std=0.0)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_model="residual")
    np.testing.assert_allclose(cal.noise_std, PAPER_NOISE_STD, rtol=0.05)
    assert cal.noise_source.startswith("residual") and cal.noise_model is None


def test_calibrate_pair_snr_follows_paper_definition():
    sim = simulate_pair(rng=2, noise_std=PAPER_NOISE_STD, bias_walk_std=0.0)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD)
    w = sim.omega_true_1 - sim.omega_true_1.mean(0)
    expected = np.sqrt((w**2).sum(0)) / (np.sqrt(2) * PAPER_NOISE_STD)
    np.testing.assert_allclose(cal.snr, expected, rtol=0.01)


def test_calibrate_pair_bias_window_follows_drifting_bias():
    # a bias random walk 100x the paper's: windowed bias beats the constant-bias model
    sim = simulate_pair(rng=3, n=20000, scale_1=S1, scale_2=S2, bias_walk_std=100 * 57.3e-6 * DEG)
    const = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD)
    windowed = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD, bias_window=100)
    assert windowed.bias_segments == 200
    assert rotation_error(windowed.R_1_2, sim.R_1_2) < 0.5 * rotation_error(const.R_1_2, sim.R_1_2)


def test_calibrate_pair_skew_compensation_and_budget():
    # the paper's model (Appendix D's budget is for rotation + scale factors; the full map has its own, test_linear_map)
    sim = simulate_pair(rng=9, scale_1=S1, scale_2=S2, skew_std=2e-3, n=20000, bias_walk_std=0.0)
    raw = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD, linear_map="rigid")
    comp = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD, intrinsics_1=sim.S_1,
                          intrinsics_2=sim.S_2)
    assert rotation_error(comp.R_1_2, sim.R_1_2) < 0.3 * rotation_error(raw.R_1_2, sim.R_1_2)
    budget = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD, skew_std=2.357e-4, linear_map="rigid")
    np.testing.assert_allclose(np.diag(budget.skew_rotation_covariance), 0.25 * 2 * 2.357e-4**2)
    assert np.all(np.diag(budget.covariance)[ROT] > np.diag(raw.covariance)[ROT])


def test_calibrate_pair_rejects_unknown_method_and_gauge_with_one_error_class():
    sim = simulate_pair(rng=0, n=500)
    with pytest.raises(OptionError, match="method"):
        calibrate_pair(sim.omega_1, sim.omega_2, method="magic")
    with pytest.raises(OptionError, match="gauge"):
        calibrate_pair(sim.omega_1, sim.omega_2, gauge="none")
    with pytest.raises(OptionError, match="no_such_option"):
        calibrate_pair(sim.omega_1, sim.omega_2, no_such_option=1)


def test_pair_calibration_to_dict_round_trip_is_json():
    import json

    sim = simulate_pair(rng=0, R_1_2=np.eye(3))
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD)
    text = json.dumps(cal.to_dict(), allow_nan=False)  # strict JSON even with undetermined (inf) entries
    back = PairCalibration.from_dict(json.loads(text))
    np.testing.assert_array_equal(back.R_1_2, cal.R_1_2)
    np.testing.assert_array_equal(back.covariance, cal.covariance)
    assert back.configuration == cal.configuration and back.gauge == cal.gauge
    assert cal.to_dict()["format_version"] == "1.5"


def _strict_json(text):
    import json

    def refuse(token):
        raise AssertionError(f"non-standard JSON literal {token}")
    return json.loads(text, parse_constant=refuse)


def test_pair_calibration_to_dict_keeps_nan_and_inf_apart():
    import dataclasses
    import json

    sim = simulate_pair(rng=0, n=2000)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD)
    cov = cal.covariance.copy()
    cov[0, 0], cov[1, 1], cov[2, 2] = np.nan, np.inf, -np.inf
    cal = dataclasses.replace(cal, covariance=cov, residual_rms=float("inf"), time_offset_std_s=float("nan"),
                              rate_residual_correlation=float("-inf"))
    back = PairCalibration.from_dict(_strict_json(json.dumps(cal.to_dict(), allow_nan=False)))
    assert np.isnan(back.covariance[0, 0])
    assert back.covariance[1, 1] == np.inf and back.covariance[2, 2] == -np.inf
    assert back.residual_rms == np.inf and np.isnan(back.time_offset_std_s)
    assert back.rate_residual_correlation == -np.inf
    np.testing.assert_array_equal(back.covariance[3:, 3:], cal.covariance[3:, 3:])


def test_pair_calibration_from_dict_reads_format_1_0_nulls():
    sim = simulate_pair(rng=0, R_1_2=np.eye(3))
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD)
    d = cal.to_dict()
    d["format_version"] = "1.0"   # version 1.0 wrote every non-finite number as null
    del d["non_finite"]           # it wrote nulls only: the undetermined variances (the covariance's are null)
    d["residual_rms"] = None
    back = PairCalibration.from_dict(d)
    np.testing.assert_array_equal(back.covariance, cal.covariance)
    assert np.isinf(back.covariance[3, 3]) and np.isnan(back.residual_rms)


def test_pair_calibration_is_frozen():
    sim = simulate_pair(rng=0, n=500)
    cal = calibrate_pair(sim.omega_1, sim.omega_2)
    with pytest.raises(Exception):
        cal.R_1_2 = np.eye(3)
    with pytest.raises(ValueError):
        cal.R_1_2[0, 0] = 2.0


def test_calibrate_pair_max_rate_drops_fast_samples():
    sim = simulate_pair(rng=1, n=3000)
    fast = (np.linalg.norm(sim.omega_1, axis=1) > 2.0) | (np.linalg.norm(sim.omega_2, axis=1) > 2.0)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD, max_rate=2.0, flex_rejection=False)
    assert cal.n_samples == 3000 - fast.sum() and fast.any()


def test_calibrate_pair_notes_axes_below_target_snr():
    sim = simulate_pair(rng=1, n=300, rms=(0.05, 1.0, 1.0))
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD)
    assert cal.snr[0] < 4e3 < cal.snr[1]
    assert any("below the target 4000" in n and "axis x" in n for n in cal.notes)


def test_calibrate_pair_bias_walk_model_is_efficient_under_drift():
    # bias random walk 100x the paper's over 10 minutes: the innovations-filter model follows it and its
    # reported covariance matches the errors (rotation NEES ~ chi2(3)), the constant-bias model does not
    from scipy.stats import chi2

    walk = 100 * 57.3e-6 * DEG
    R = Rotation.from_rotvec([0.4, -0.9, 0.6]).as_matrix()
    runs = 12
    nees, err_walk, err_const = [], [], []
    for seed in range(runs):
        sim = simulate_pair(rng=seed, n=60000, rms=0.5, R_1_2=R, scale_1=S1, scale_2=S2, bias_walk_std=walk)
        cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD, bias_walk_std=walk)
        const = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD, flex_rejection=False)
        d = Rotation.from_matrix(R @ cal.R_1_2.T).as_rotvec()
        nees.append(d @ np.linalg.solve(cal.covariance[ROT, ROT], d))
        err_walk.append(rotation_error(cal.R_1_2, R))
        err_const.append(rotation_error(const.R_1_2, R))
    # The filtered regressor noise is not white, so the Fisher covariance of this model is approximate:
    # measured mean NEES 3.64 over 40 runs (chi2(3) mean 3). Bound it at twice the 99% interval.
    lo, hi = chi2.ppf([0.005, 0.995], 3 * runs) / runs
    assert lo < np.mean(nees) < 2 * hi, (lo, np.mean(nees), hi)
    assert np.sqrt(np.mean(np.square(err_walk))) < 0.3 * np.sqrt(np.mean(np.square(err_const)))


def test_calibrate_pair_mirrored_or_swapped_axis_names_the_cause():
    sim = simulate_pair(rng=11, n=3000)
    for w2 in (sim.omega_2 * [1.0, -1.0, 1.0], sim.omega_2[:, [1, 0, 2]]):
        with pytest.raises(InputError, match="left-handed frame"):
            calibrate_pair(sim.omega_1, w2)


def test_calibrate_pair_unit_mismatch_names_the_units():
    sim = simulate_pair(rng=12, n=3000)
    with pytest.raises(InputError, match=r"gyro 1 in rad/s, gyro 2 in deg/s\?.*--unit1/--unit2"):
        calibrate_pair(sim.omega_1, np.rad2deg(sim.omega_2))
    with pytest.raises(InputError, match="gyro 1 in deg/s, gyro 2 in rad/s"):
        calibrate_pair(np.rad2deg(sim.omega_1), sim.omega_2)


def test_calibrate_pair_motion_below_gyro_2_noise_raises_excitation_error():
    # the x axis moves at 0.6 of the noise per sample: its explained SNR passes Lemma 1's test, but least squares
    # attenuate A there and the Fisher covariance under-states the error (mean z^2 80 before this check)
    from fusion_gyrocal.core.moments import Moments
    from fusion_gyrocal.core.observability import check_excitation
    sim = simulate_pair(n=20000, rms=np.array([0.6 * PAPER_NOISE_STD, 0.5, 0.5]), rng=3)
    m = Moments.from_samples(sim.omega_1, sim.omega_2)
    with pytest.raises(ExcitationError, match=r"the motion's power is 0\.[0-9]+x its noise's per sample"):
        check_excitation(m, (PAPER_NOISE_STD, PAPER_NOISE_STD), min_snr=10.0)
    with pytest.raises(ExcitationError, match="too little motion"):
        calibrate_pair(sim.omega_1, sim.omega_2)
