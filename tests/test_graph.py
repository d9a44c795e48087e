
import gtsam
import numpy as np
from _examples import load_example
import pytest
from gtsam.utils.numerical_derivative import numericalDerivative11
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from fusion_gyrocal import ConfigurationError, InputError, Moments, calibrate_pair, solve
from fusion_gyrocal.graph import (GLOBAL_SCALE_GAUGE, GyroPairGraph, RotationIncrements, calibrate_pair_graph,
                                  gyro_pair_factor, preintegrate_rotations, rotation_increment_factor)
from fusion_gyrocal.graph import solver as graph_solver
from fusion_gyrocal.core.moments import window_moments
from fusion_gyrocal.evaluate.sim import DEG, HumanMotion, random_rotation, rotation_error, scale_error, simulate_pair

S1 = np.array([1.01, 0.99, 1.02])
S2 = np.array([0.98, 1.03, 1.00])
NOISE = (0.1 * DEG, 0.15 * DEG)   # unequal, so the weight's dependence on A matters
KR, KL, KB, KG = 1, 2, 3, 4



def _example():
    """The example script as a module (its simulator and ``run``/``main`` are exercised here)."""
    return load_example("graph_global_scale")


def _values(pairs):
    v = gtsam.Values()
    for key, value in pairs:
        v.insert(key, value)
    return v


def _normalised_difference(a, b):
    """Differences of a from b in units of b's standard deviations: [dtheta, scale_1, scale_2, bias].

    Undetermined parameters (infinite sd) count as 0; gauge-fixed ones (zero sd) as 0 when equal, inf if not.
    """
    sd = np.sqrt(np.diag(b.covariance))
    dtheta = Rotation.from_matrix(a.R_1_2 @ b.R_1_2.T).as_rotvec()
    diff = np.concatenate([dtheta, a.scale_1 - b.scale_1, a.scale_2 - b.scale_2, a.bias - b.bias])
    out = np.zeros(12)
    ok = np.isfinite(sd) & (sd > 0)
    out[ok] = diff[ok] / sd[ok]
    out[(sd == 0) & (np.abs(diff) > 1e-12)] = np.inf
    return out


# ---------------------------------------------------------------------------------------------- pair factor
def test_gyro_pair_factor_jacobians_match_numerical():
    rng = np.random.default_rng(0)
    sim = simulate_pair(n=400, scale_1=S1, scale_2=S2, rng=rng)
    f = gyro_pair_factor(Moments.from_samples(sim.omega_1, sim.omega_2), NOISE, rotation_key=KR, log_scale_key=KL,
                         bias_key=KB)
    R0, l0, b0 = gtsam.Rot3(random_rotation(rng)), rng.normal(0, 0.05, 6), rng.normal(0, 0.01, 3)

    def err(R=R0, l=l0, b=b0):
        return f.unwhitenedError(_values([(KR, R), (KL, l), (KB, b)]))

    analytic, _ = f.linearize(_values([(KR, R0), (KL, l0), (KB, b0)])).jacobian()
    numeric = np.hstack([numericalDerivative11(lambda R: err(R=R), R0), numericalDerivative11(lambda l: err(l=l), l0),
                         numericalDerivative11(lambda b: err(b=b), b0)])
    assert analytic.shape == (21, 12)
    assert np.abs(analytic - numeric).max() <= 1e-7 * np.abs(numeric).max()


def test_gyro_pair_factor_error_equals_per_sample_likelihood():
    rng = np.random.default_rng(1)
    sim = simulate_pair(n=700, scale_1=S1, scale_2=S2, rng=rng)
    f = gyro_pair_factor(Moments.from_samples(sim.omega_1, sim.omega_2), NOISE, rotation_key=KR, log_scale_key=KL,
                         bias_key=KB)
    R, l, b = random_rotation(rng), rng.normal(0, 0.05, 6), rng.normal(0, 0.01, 3)
    A = (np.exp(l[:3])[:, None] * R) / np.exp(l[3:])[None, :]
    W = np.linalg.inv(NOISE[0] ** 2 * np.eye(3) + NOISE[1] ** 2 * A @ A.T)
    r = sim.omega_1 - sim.omega_2 @ A.T - b
    expected = 0.5 * np.einsum("ki,ij,kj->", r, W, r)
    assert f.error(_values([(KR, gtsam.Rot3(R)), (KL, l), (KB, b)])) == pytest.approx(expected, rel=1e-9)


def test_gyro_pair_factor_windows_sharing_a_bias_sum_to_one_factor():
    rng = np.random.default_rng(2)
    sim = simulate_pair(n=3000, scale_1=S1, scale_2=S2, rng=rng)
    v = _values([(KR, gtsam.Rot3(random_rotation(rng))), (KL, rng.normal(0, 0.02, 6)), (KB, rng.normal(0, 0.01, 3))])
    parts = window_moments(sim.omega_1, sim.omega_2, 250)
    windowed = sum(gyro_pair_factor(m, NOISE, rotation_key=KR, log_scale_key=KL, bias_key=KB).error(v) for m in parts)
    whole = gyro_pair_factor(Moments.merge_all(parts), NOISE, rotation_key=KR, log_scale_key=KL, bias_key=KB).error(v)
    assert windowed == pytest.approx(whole, rel=1e-9)


# ---------------------------------------------------------------------------------------------- rotation increments
def _camera_setup(seed, n=600, sigma=1e-3):
    rng = np.random.default_rng(seed)
    motion = HumanMotion(1.0, rng=rng)
    t = np.arange(n) / 100.0
    inc = _example().simulate_camera_increments(motion, t, np.arange(0, n, 10), sigma, rng)
    return rng, motion(t), inc


def test_preintegrate_rotations_matches_integrated_truth():
    # noise-free gyro and camera: only the discretisation remains; 1e-4 rad is a tenth of the 1 mrad camera noise
    rng, w, inc = _camera_setup(3, sigma=1e-12)
    s1, b1 = np.array([1.02, 0.97, 1.01]), np.array([0.01, -0.02, 0.005])
    pre = preintegrate_rotations(w * s1 + b1, 100.0, inc, scale_1=s1, bias_1=b1)
    err = Rotation.from_matrix(np.einsum("kji,kjl->kil", inc.in_gyro_frame(), pre.delta_R)).magnitude()
    assert err.max() < 1e-4


def test_preintegrate_rotations_jacobians_match_relinearized():
    rng, w, inc = _camera_setup(4)
    s1 = np.array([1.02, 0.97, 1.01])
    pre = preintegrate_rotations(w * s1, 100.0, inc, scale_1=s1, bias_1=np.zeros(3))
    h = 1e-6
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        for J, moved in ((pre.J_scale, pre.relinearized(np.log(s1) + e, np.zeros(3))),
                         (pre.J_bias, pre.relinearized(np.log(s1), e))):
            num = Rotation.from_matrix(np.einsum("kji,kjl->kil", pre.delta_R, moved.delta_R)).as_rotvec() / h
            # first-order Jacobian; the finite difference carries O(h * angle) curvature
            assert np.abs(num - J[:, :, j]).max() < 1e-3 * np.abs(J[:, :, j]).max()


def test_rotation_increment_factor_jacobians_match_numerical():
    rng, w, inc = _camera_setup(5)
    pre = preintegrate_rotations(w, 100.0, inc)
    f = rotation_increment_factor(pre, 7, inc.in_gyro_frame()[7], 1e-3, global_scale_key=KG, log_scale_key=KL,
                                  bias_1_key=KB)
    g0, l0, c0 = np.array([0.01]), rng.normal(0, 0.02, 6), rng.normal(0, 0.01, 3)

    def err(g=g0, l=l0, c=c0):
        return f.unwhitenedError(_values([(KG, g), (KL, l), (KB, c)]))

    analytic, _ = f.linearize(_values([(KG, g0), (KL, l0), (KB, c0)])).jacobian()
    analytic = analytic * 1e-3   # undo the whitening by sigma
    numeric = np.hstack([numericalDerivative11(lambda g: err(g=g), g0), numericalDerivative11(lambda l: err(l=l), l0),
                         numericalDerivative11(lambda c: err(c=c), c0)])
    assert analytic.shape == (3, 10)
    assert np.abs(analytic - numeric).max() <= 1e-7 * np.abs(numeric).max()


def test_rotation_increments_in_gyro_frame_undoes_camera_mounting():
    rng = np.random.default_rng(6)
    R_w_1 = Rotation.random(4, random_state=rng).as_matrix()       # gyro 1 orientations at 4 keyframes
    R_cam_1 = random_rotation(rng)                                  # gyro 1 frame -> camera frame
    R_w_c = R_w_1 @ R_cam_1.T
    inc = RotationIncrements.from_orientations([0, 10, 20, 30], R_w_c, 1e-3, R_cam_1)
    expected = np.einsum("kji,kjl->kil", R_w_1[:-1], R_w_1[1:])
    np.testing.assert_allclose(inc.in_gyro_frame(), expected, atol=1e-12)


def test_rotation_increments_stop_before_start_raises():
    with pytest.raises(InputError, match="stop > start"):
        RotationIncrements([0, 10], [10, 10], np.broadcast_to(np.eye(3), (2, 3, 3)), 1e-3)


# ---------------------------------------------------------------------------------------------- graph vs batch
@pytest.fixture(scope="module")
def constant_bias_case():
    sim = simulate_pair(n=6000, scale_1=S1, scale_2=S2, noise_std=NOISE, bias_walk_std=0.0, rng=10)
    return sim, calibrate_pair(sim.omega_1, sim.omega_2, noise_std=NOISE)


def test_calibrate_pair_graph_constant_bias_agrees_with_batch_ml(constant_bias_case):
    sim, ml = constant_bias_case
    gr = calibrate_pair_graph(sim.omega_1, sim.omega_2, noise_std=NOISE, window=500)
    assert gr.bias_segments == 1 and gr.gauge == ml.gauge
    assert np.abs(_normalised_difference(gr, ml)).max() <= 0.1


def test_calibrate_pair_graph_covariance_matches_batch_ml(constant_bias_case):
    sim, ml = constant_bias_case
    gr = calibrate_pair_graph(sim.omega_1, sim.omega_2, noise_std=NOISE, window=500)
    np.testing.assert_allclose(np.diag(gr.covariance), np.diag(ml.covariance), rtol=1e-2)


def test_calibrate_pair_graph_independent_window_biases_agree_with_batch_bias_window():
    sim = simulate_pair(n=6000, scale_1=S1, scale_2=S2, noise_std=NOISE, bias_walk_std=2e-3 * DEG, rng=30)
    ml = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=NOISE, bias_window=500)      # pooled moments
    gr = calibrate_pair_graph(sim.omega_1, sim.omega_2, noise_std=NOISE, window=500, bias_walk_std=np.inf)
    assert gr.bias_segments == ml.bias_segments == 12
    assert np.abs(_normalised_difference(gr, ml)).max() <= 0.1
    np.testing.assert_allclose(np.diag(gr.covariance), np.diag(ml.covariance), rtol=1e-2)


def test_gyro_pair_graph_isam2_matches_batch_lm(constant_bias_case):
    sim, _ = constant_bias_case
    parts = window_moments(sim.omega_1, sim.omega_2, 500)
    seed = solve(Moments.merge_all(parts), noise_std=NOISE, method="direct")
    lm_graph, isam_graph = GyroPairGraph(seed), GyroPairGraph(seed)
    estimates = []
    for m in parts:
        lm_graph.add_window(m)
        isam_graph.add_window(m)
        estimates.append(isam_graph.update())
    lm, isam = lm_graph.solve(), isam_graph.result()
    assert isam.method == "graph_isam2" and len(estimates) == len(parts)
    assert np.abs(_normalised_difference(isam, lm)).max() <= 0.01
    np.testing.assert_allclose(np.diag(isam.covariance), np.diag(lm.covariance), rtol=1e-3)


def test_calibrate_pair_graph_fixed_gauge_agrees_with_batch_ml(constant_bias_case):
    sim, _ = constant_bias_case
    ml = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=NOISE, gauge="fixed")
    gr = calibrate_pair_graph(sim.omega_1, sim.omega_2, noise_std=NOISE, window=1000, gauge="fixed")
    assert gr.scale_1[0] == pytest.approx(1.0, abs=1e-12)
    assert gr.covariance[3, 3] < 1e-6 * gr.covariance[4, 4]
    assert np.abs(_normalised_difference(gr, ml)).max() <= 0.1


def test_calibrate_pair_graph_one_axis_parallel_agrees_with_batch_ml():
    R = Rotation.from_euler("z", 30, degrees=True).as_matrix()          # z axes parallel (Lemma 3)
    sim = simulate_pair(n=6000, R_1_2=R, scale_1=S1, scale_2=S2, noise_std=NOISE, bias_walk_std=0.0, rng=11)
    ml = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=NOISE)
    gr = calibrate_pair_graph(sim.omega_1, sim.omega_2, noise_std=NOISE, window=1000)
    assert gr.configuration == ml.configuration == "one_axis_pair_parallel"
    np.testing.assert_array_equal(gr.scale_observable, ml.scale_observable)
    assert np.isinf(gr.scale_std[~gr.scale_observable]).all()
    assert np.abs(_normalised_difference(gr, ml)).max() <= 0.1


def test_calibrate_pair_graph_one_axis_parallel_fixed_gauge_agrees_with_batch_ml():
    # the seed's gauge-fixed scale_1[0] has a std of ~1e-14 from rounding: not a scale std for the gauge prior
    R = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    for seed in (0, 1):          # seeds whose gauge-fixed std is not exactly zero
        sim = simulate_pair(n=6000, R_1_2=R, scale_1=S1, scale_2=S2, rng=seed)
        ml = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=sim.noise_std, gauge="fixed")
        gr = calibrate_pair_graph(sim.omega_1, sim.omega_2, noise_std=sim.noise_std, window=1000, gauge="fixed")
        assert gr.configuration == ml.configuration == "one_axis_pair_parallel" and gr.gauge == ml.gauge
        assert gr.scale_1[0] == pytest.approx(1.0, abs=1e-12)
        assert np.abs(_normalised_difference(gr, ml)).max() <= 0.1
        np.testing.assert_allclose(gr.scale_std[gr.scale_std > 0], ml.scale_std[ml.scale_std > 0], rtol=1e-2)


def test_calibrate_pair_graph_drifting_bias_beats_constant_bias_batch():
    walk = 2e-3 * DEG        # per-step bias random walk of each gyro (35x the paper's)
    err_batch, err_graph, nees = [], [], []
    for seed in range(5):
        sim = simulate_pair(n=12000, scale_1=S1, scale_2=S2, bias_walk_std=walk, rms=0.5, rng=seed)
        ml = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=sim.noise_std)
        gr = calibrate_pair_graph(sim.omega_1, sim.omega_2, noise_std=sim.noise_std, window=200,
                                  bias_walk_std=np.sqrt(2.0) * walk)
        err_batch.append([rotation_error(ml.R_1_2, sim.R_1_2), scale_error(ml.scale_1, ml.scale_2, S1, S2)])
        err_graph.append([rotation_error(gr.R_1_2, sim.R_1_2), scale_error(gr.scale_1, gr.scale_2, S1, S2)])
        dtheta = Rotation.from_matrix(sim.R_1_2 @ gr.R_1_2.T).as_rotvec()
        nees.append(dtheta @ np.linalg.solve(gr.covariance[:3, :3], dtheta))
    rms_batch = np.sqrt(np.mean(np.square(err_batch), axis=0))
    rms_graph = np.sqrt(np.mean(np.square(err_graph), axis=0))
    assert gr.bias_segments == 60
    assert np.all(rms_graph < 0.8 * rms_batch), (rms_graph, rms_batch)
    # and the windowed graph's rotation covariance is honest: chi2(15) / 5, two-sided 99.8 %
    assert chi2.ppf(0.001, 15) / 5 < np.mean(nees) < chi2.ppf(0.999, 15) / 5


def test_gyro_pair_graph_sparse_covariance_matches_marginals(monkeypatch):
    sim = simulate_pair(n=8000, scale_1=S1, scale_2=S2, bias_walk_std=1e-3 * DEG, rng=12)
    kw = dict(noise_std=sim.noise_std, window=400, bias_walk_std=1.4e-3 * DEG)
    dense = calibrate_pair_graph(sim.omega_1, sim.omega_2, **kw)
    monkeypatch.setattr(graph_solver, "MARGINALS_MAX_SEGMENTS", 0)
    sparse = calibrate_pair_graph(sim.omega_1, sim.omega_2, **kw)
    assert dense.bias_segments == 20
    atol = 1e-12 * np.abs(dense.covariance).max()
    np.testing.assert_allclose(sparse.covariance, dense.covariance, rtol=1e-8, atol=atol)


def test_gyro_pair_graph_factor_count_is_per_window_not_per_sample():
    sim = simulate_pair(n=100_000, scale_1=S1, scale_2=S2, bias_walk_std=0.0, rng=13)
    parts = window_moments(sim.omega_1, sim.omega_2, 1000)
    seed = solve(Moments.merge_all(parts), noise_std=sim.noise_std, method="direct")
    windowed, constant = GyroPairGraph(seed, bias_walk_std=1e-6), GyroPairGraph(seed)
    for m in parts:
        windowed.add_window(m)
        constant.add_window(m)
    assert constant.n_windows == windowed.n_windows == 100
    assert windowed.graph.size() == 100 + 99 + 1   # a pair factor per window, random walks, the gauge prior
    assert constant.graph.size() == 1 + 1          # one pair factor of the merged moments, the gauge prior


def test_mean_walk_variance_matches_simulation():
    rng = np.random.default_rng(14)
    n_a, n_b = 30, 50
    walk = np.cumsum(rng.standard_normal((20000, n_a + n_b)), axis=1)
    diff = walk[:, n_a:].mean(axis=1) - walk[:, :n_a].mean(axis=1)
    # 20000 draws: the variance estimate has a relative std of 1 %
    assert np.var(diff) == pytest.approx(graph_solver._mean_walk_variance(n_a, n_b), rel=0.05)


# ---------------------------------------------------------------------------------------------- global scale
def test_gyro_pair_graph_camera_global_scale_error_consistent_with_covariance():
    run = _example().run
    z = []
    for seed in range(20):
        err, std = run(seconds=20.0, seed=seed, pair_only=False).global_scale_error()
        z.append(err / std)                                          # global (mean log-) scale error / sigma
    assert chi2.ppf(0.001, 20) / 20 < np.mean(np.square(z)) < chi2.ppf(0.999, 20) / 20


def test_example_graph_global_scale_recovers_absolute_scale(capsys):
    demo = _example().main(["--seconds", "60", "--seed", "1"])
    assert "global scale" in capsys.readouterr().out
    cal = demo.with_camera
    err = np.concatenate([cal.scale_1 - demo.scale_1, cal.scale_2 - demo.scale_2])
    std = cal.scale_std.reshape(-1)
    assert cal.gauge == GLOBAL_SCALE_GAUGE and cal.scale_observable.all()
    assert np.all(std < 1e-3) and np.all(np.abs(err) < 4.0 * std)
    # the pair alone, in its gauge, is off by the unobservable common factor (truth drawn with 2 % spread)
    truth = np.concatenate([demo.scale_1, demo.scale_2])
    pair = np.concatenate([demo.pair_only.scale_1, demo.pair_only.scale_2]) / truth
    assert np.ptp(pair) < 1e-3


def _camera_pair(seed, n=3000, bias_walk_std=None):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    motion = HumanMotion(1.0, rng=rng)
    s1, s2 = rng.normal(1.0, 0.02, 3), rng.normal(1.0, 0.02, 3)
    kw = {} if bias_walk_std is None else {"bias_walk_std": bias_walk_std}
    sim = simulate_pair(motion(t), scale_1=s1, scale_2=s2, rng=rng, **kw)
    inc = _example().simulate_camera_increments(motion, t, np.arange(0, n, 10), 1e-3, rng)
    return sim, inc


def test_calibrate_pair_graph_isam2_with_rotation_increments_matches_lm():
    sim, inc = _camera_pair(20)
    kw = dict(noise_std=sim.noise_std, window=500, rotation_increments=inc, rate_hz=100.0)
    lm = calibrate_pair_graph(sim.omega_1, sim.omega_2, **kw)
    isam = calibrate_pair_graph(sim.omega_1, sim.omega_2, solver="isam2", **kw)
    assert isam.gauge == lm.gauge == GLOBAL_SCALE_GAUGE
    # iSAM2 keeps the first preintegration point, LM re-preintegrates at its solution
    assert np.abs(_normalised_difference(isam, lm)).max() <= 0.02


def test_calibrate_pair_graph_drifting_biases_with_rotation_increments_recover_absolute_scale():
    walk = 2e-3 * DEG
    sim, inc = _camera_pair(21, n=6000, bias_walk_std=walk)
    cal = calibrate_pair_graph(sim.omega_1, sim.omega_2, noise_std=sim.noise_std, window=500,
                               bias_walk_std=np.sqrt(2.0) * walk, rotation_increments=inc, rate_hz=100.0)
    err = np.concatenate([cal.scale_1 - sim.scale_1, cal.scale_2 - sim.scale_2])
    assert cal.bias_segments == 12 and "12 windows" in " ".join(cal.notes)
    assert np.all(np.abs(err) < 4.0 * cal.scale_std.reshape(-1))


@pytest.fixture(scope="module")
def tilted_general_case():
    """Samples and a seed solved at 1 deg whose z axes are 3 deg from parallel: 'general' at 1 deg, not at 5 deg."""
    R = Rotation.from_euler("z", 30, degrees=True).as_matrix() @ Rotation.from_euler("x", 3, degrees=True).as_matrix()
    sim = simulate_pair(n=3000, R_1_2=R, scale_1=S1, scale_2=S2, rng=22)
    seed = solve(Moments.from_samples(sim.omega_1, sim.omega_2), noise_std=sim.noise_std, method="direct",
                 parallel_tol_deg=1.0)
    assert seed.configuration == "general"
    return sim, seed


def test_gyro_pair_graph_seed_configuration_mismatch_raises(tilted_general_case):
    _, seed = tilted_general_case
    with pytest.raises(ConfigurationError, match="parallel_tol_deg"):
        GyroPairGraph(seed, parallel_tol_deg=5.0)     # at 5 deg the 3 deg tilt counts as parallel
    assert GyroPairGraph(seed, parallel_tol_deg=1.0).configuration.name == "general"


def test_gyro_pair_graph_default_keeps_seed_configuration(tilted_general_case):
    sim, seed = tilted_general_case
    graph = GyroPairGraph(seed)                        # no tolerance: the seed's class, not classify's at 5 deg
    assert graph.configuration.name == "general" and len(graph.configuration.groups) == 1
    for m in window_moments(sim.omega_1, sim.omega_2, 1000):
        graph.add_window(m)
    cal = graph.solve()
    assert cal.configuration == "general" and cal.scale_observable.all() and np.isfinite(cal.scale_std).all()


def test_gyro_pair_graph_global_scale_without_increments_raises(constant_bias_case):
    sim, ml = constant_bias_case
    g = GyroPairGraph(ml, global_scale=True)
    g.add_window(Moments.from_samples(sim.omega_1, sim.omega_2))
    with pytest.raises(ConfigurationError, match="rotation increments"):
        g.solve()


def test_gyro_pair_graph_add_rotation_increments_without_global_scale_raises(constant_bias_case):
    sim, ml = constant_bias_case
    inc = RotationIncrements([0], [10], np.eye(3)[None], 1e-3)
    with pytest.raises(ConfigurationError, match="global_scale=True"):
        GyroPairGraph(ml).add_rotation_increments(sim.omega_1, 100.0, inc)


def test_gyro_pair_graph_add_window_rejects_pooled_moments(constant_bias_case):
    sim, ml = constant_bias_case
    pooled = Moments.pool_all(window_moments(sim.omega_1, sim.omega_2, 1000))
    with pytest.raises(InputError, match="one bias segment"):
        GyroPairGraph(ml).add_window(pooled)


def test_calibrate_pair_graph_options_and_keywords_agree(constant_bias_case):
    from fusion_gyrocal import Options

    sim, _ = constant_bias_case
    a = calibrate_pair_graph(sim.omega_1, sim.omega_2, Options(noise_std=NOISE, gauge="fixed"), window=1000)
    b = calibrate_pair_graph(sim.omega_1, sim.omega_2, noise_std=NOISE, gauge="fixed", window=1000)
    np.testing.assert_array_equal(a.R_1_2, b.R_1_2)
    np.testing.assert_array_equal(a.covariance, b.covariance)


@pytest.mark.parametrize("keywords, refused", [({"method": "direct"}, "method"), ({"bias_window": 100}, "bias_window"),
                                               ({"time_offset_s": 0.01}, "time_offset_s")])
def test_calibrate_pair_graph_refuses_an_option_it_does_not_apply(keywords, refused):
    from fusion_gyrocal import OptionError

    sim = simulate_pair(n=600, rng=11)
    with pytest.raises(OptionError, match=rf"^calibrate_pair_graph: .* cannot apply \['{refused}'\]"):
        calibrate_pair_graph(sim.omega_1, sim.omega_2, window=100, **keywords)


def test_calibrate_pair_graph_full_map_seed_holds_cross_axis_terms():
    """A full-map seed (a pair with cross-axis terms) is solved with its terms held: the graph's rotation is the
    batch's (same convention, within its repeatable sigma), its A the full map, its bias in gyro 1's frame."""
    from fusion_gyrocal.core.observability import cross_matrix
    from fusion_gyrocal.lie import log

    sim = simulate_pair(rng=3, n=20000, R_1_2=random_rotation(np.random.default_rng(3)))
    k = np.array([0.012, -0.008, 0.015])
    w1 = sim.omega_1 @ (np.eye(3) + cross_matrix(k)).T
    batch = calibrate_pair(w1, sim.omega_2, noise_std=sim.noise_std)
    assert batch.linear_map == "full"
    cal = calibrate_pair_graph(w1, sim.omega_2, noise_std=sim.noise_std, window=1000, seed=batch)
    assert cal.linear_map == "full" and np.array_equal(cal.cross_axis_terms, batch.cross_axis_terms)
    err = log(cal.R_1_2 @ batch.R_1_2.T)
    rep = batch.covariance[:3, :3] - batch.skew_rotation_covariance
    assert err @ np.linalg.solve(rep, err) < 1.0, err            # the same estimate, not just within the bars
    assert np.allclose(cal.A, batch.A, atol=5e-5)
    assert np.allclose(cal.bias, batch.bias, atol=3.0 * np.sqrt(np.diag(batch.covariance)[9:]).max())
    rigid = calibrate_pair_graph(w1, sim.omega_2, noise_std=sim.noise_std, window=1000)
    assert rigid.linear_map == "rigid" and not np.allclose(rigid.A, batch.A, atol=5e-5)
