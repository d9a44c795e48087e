"""The block-robust (sandwich) covariance and the identified noise model in the result (core/robust.py)."""

import itertools
import json

import numpy as np
import pytest

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.core.model import PairCalibration
from fusion_gyrocal.core.moments import Moments, window_stats
from fusion_gyrocal.core.refine import ml_gradient
from fusion_gyrocal.core.robust import larger, significant_ratio, window_scores
from fusion_gyrocal.evaluate.sim import DEG, PAPER_NOISE_STD, general_rotation, shared_data_dir, simulate_pair
from fusion_gyrocal.lie import exp, log

DATA = shared_data_dir()
needs_data = pytest.mark.skipif(not DATA.exists(), reason="../shared/data not present (real recordings are only in "
                                "the development checkout's ../shared/data)")


def _rate_scale_pair(rng, n=20000, per_rad_s=0.02):
    """A rigid pair whose gyro 2 has a scale error growing with the rate (``per_rad_s`` per rad/s of |omega|)."""
    R = general_rotation(rng)
    sim = simulate_pair(n=n, rms=0.8, R_1_2=R, bias_walk_std=0.0, rng=rng)
    w2_true = sim.omega_true_1 @ R
    return sim, R, sim.omega_2 + per_rad_s * np.linalg.norm(w2_true, axis=1)[:, None] * w2_true


def test_window_scores_sum_to_the_gradient_of_the_whole_log():
    sim = simulate_pair(n=6000, rng=0)
    stats = window_stats(sim.omega_1, sim.omega_2, 100)
    R = exp(np.array([0.01, -0.02, 0.03])) @ sim.R_1_2
    s1, s2, noise = np.array([1.01, 0.99, 1.0]), np.array([1.0, 1.02, 0.98]), (0.002, 0.003)
    g = window_scores(R, s1, s2, noise, stats)
    whole = ml_gradient(R, s1, s2, Moments.from_samples(sim.omega_1, sim.omega_2), noise)
    np.testing.assert_allclose(g.sum(axis=0), whole, rtol=1e-9, atol=1e-9 * np.abs(whole).max())


def test_window_stats_subsample_runs_stand_for_the_whole_log():
    sim = simulate_pair(n=40000, rng=1)
    stats = window_stats(sim.omega_1, sim.omega_2, 10, max_windows=512)
    assert stats.n_windows == 512 and len(np.unique(stats.run)) == 32
    assert stats.weight == pytest.approx(4000 / 512)
    full = window_stats(sim.omega_1, sim.omega_2, 10, max_windows=4000)
    assert full.n_windows == 4000 and full.weight == 1.0


def test_significant_ratio_is_exceeded_by_one_percent_of_white_logs():
    rng = np.random.default_rng(2)
    p, n, trials = 8, 60, 4000
    z = rng.standard_normal((trials, n, p))
    z -= z.mean(axis=1, keepdims=True)
    top = np.linalg.eigvalsh(np.einsum("tni,tnj->tij", z, z) / n)[:, -1]
    rate = float(np.mean(top > significant_ratio(p, n)))
    assert 0.002 <= rate <= 0.03


def test_larger_keeps_the_model_unless_the_robust_one_is_significantly_larger():
    rng = np.random.default_rng(3)
    B = rng.standard_normal((4, 4))
    P = B @ B.T + np.eye(4)
    same, ratio = larger(P, 1.2 * P, n_effective=100.0)
    assert same is P and ratio == pytest.approx(1.2)
    u = np.linalg.cholesky(P)[:, 0]
    raised, ratio = larger(P, P + 9.0 * np.outer(u, u), n_effective=100.0)
    w = np.linalg.solve(P, u)
    assert w @ raised @ w == pytest.approx(w @ (P + 9.0 * np.outer(u, u)) @ w)
    assert np.all(np.linalg.eigvalsh(raised - P) >= -1e-9) and ratio > 5.0


def test_calibrate_pair_covariance_auto_is_the_noise_model_on_white_noise():
    sim = simulate_pair(n=20000, rng=4, bias_walk_std=0.0)
    auto = calibrate_pair(sim.omega_1, sim.omega_2)
    model = calibrate_pair(sim.omega_1, sim.omega_2, covariance="model")
    robust = calibrate_pair(sim.omega_1, sim.omega_2, covariance="robust")
    np.testing.assert_array_equal(auto.covariance, model.covariance)
    assert auto.covariance_basis.startswith("noise model (inverse Fisher") and "not significantly" in auto.covariance_basis
    assert 0.9 <= auto.lack_of_fit <= 1.1 and auto.robust_inflation < significant_ratio(8, 200 / 1.78)
    ratio = np.trace(robust.covariance[:3, :3]) / np.trace(model.covariance[:3, :3])
    assert 0.7 <= ratio <= 1.4                       # the sandwich is the Fisher covariance when the model holds
    assert robust.covariance_basis.startswith("block-robust")


def test_calibrate_pair_covariance_raised_for_a_rate_dependent_misfit():
    rng = np.random.default_rng(5)
    sim, R, w2 = _rate_scale_pair(rng)
    cal = calibrate_pair(sim.omega_1, w2)
    model = calibrate_pair(sim.omega_1, w2, covariance="model")
    assert cal.covariance_basis.startswith("noise model raised") and cal.robust_inflation > 3.0
    assert cal.lack_of_fit > 2.0
    assert np.trace(cal.covariance[:3, :3]) > 2.0 * np.trace(model.covariance[:3, :3])
    assert any("scatters" in n for n in cal.notes)


def test_calibrate_pair_covariance_robust_without_windows_raises():
    from fusion_gyrocal.core.solve import solve
    from fusion_gyrocal.errors import OptionError
    sim = simulate_pair(n=3000, rng=6)
    with pytest.raises(OptionError, match="covariance='robust': expected per-window statistics"):
        solve(Moments.from_samples(sim.omega_1, sim.omega_2), covariance="robust", noise_std=PAPER_NOISE_STD)


def test_pair_calibration_round_trip_keeps_noise_model_and_basis():
    sim = simulate_pair(n=6000, rng=7)
    cal = calibrate_pair(sim.omega_1, sim.omega_2)
    back = PairCalibration.from_dict(json.loads(json.dumps(cal.to_dict(), allow_nan=False)))
    assert back.covariance_basis == cal.covariance_basis and back.lack_of_fit == cal.lack_of_fit
    assert back.noise_model.kind == cal.noise_model.kind and back.noise_model.sources == cal.noise_model.sources
    np.testing.assert_array_equal(back.noise_model.adev, cal.noise_model.adev)
    assert back.noise_model.noise_std == cal.noise_model.noise_std


@needs_data
def test_calibrate_pair_mimu_sessions_spread_is_covered_by_the_covariance():
    """Nine sessions of one soldered PCB: the session-to-session rotation differences are the truth the
    reported covariances must explain (mean z^2 over the 36 session pairs near 3, not 100s). The board's cross-axis
    terms are the same in every session, so the difference of two sessions cancels the skew budget
    (``skew_rotation_covariance``): the repeatable part of the covariance is what explains it."""
    from fusion_gyrocal.io import read_npz
    cals = []
    for e in range(1, 10):
        s = read_npz(DATA / "mimu_8imu_array" / "npz" / f"exp_{e}.npz")
        cals.append(calibrate_pair(s[0].omega, s[2].omega, t_1=s[0].t, t_2=s[2].t))
    repeatable = [c.covariance[:3, :3] - c.skew_rotation_covariance for c in cals]
    z2, d2 = [], []
    for (a, Pa), (b, Pb) in itertools.combinations(zip(cals, repeatable), 2):
        d = log(a.R_1_2 @ b.R_1_2.T)
        z2.append(d @ np.linalg.solve(Pa + Pb, d))
        d2.append(d @ d)
    spread = np.sqrt(np.mean(d2) / 6.0)
    sigma = np.mean([np.sqrt(np.trace(P) / 3.0) for P in repeatable])
    assert 0.75 <= np.mean(z2) <= 6.0
    assert sigma <= 3.0 * spread
    rest = [c.noise_model for c in cals]
    assert all(nm is not None and 0.05 * DEG < nm.noise_std[0] < 0.5 * DEG for nm in rest)  # static poses: 0.146 deg/s


def test_calibrate_pair_cross_axis_flags_skew_the_rigid_model_cannot_absorb():
    clean = [calibrate_pair(*(lambda s: (s.omega_1, s.omega_2))(simulate_pair(n=6000, rng=k)), noise_std=PAPER_NOISE_STD)
             for k in range(8)]
    assert all(c.cross_axis_dof == 1 for c in clean)
    assert np.mean([c.cross_axis_chi2 for c in clean]) < 3.0       # chi2(1): mean 1
    assert not any("full linear map" in n for c in clean for n in c.notes)
    sim = simulate_pair(n=6000, rng=1, skew_std=2e-3)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD, linear_map="rigid")
    assert cal.cross_axis_chi2 > 100.0 and np.abs(cal.cross_axis).max() > 2e-4
    assert any("full linear map fits significantly better" in n for n in cal.notes)
    auto = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=PAPER_NOISE_STD)   # the default models what it sees
    assert auto.linear_map == "full" and any(n.startswith("full linear map (cross-axis chi2") for n in auto.notes)


def test_calibrate_array_identifies_each_gyros_noise():
    from fusion_gyrocal.core.array import calibrate_array
    from fusion_gyrocal.evaluate.sim import HumanMotion, random_rotation
    rng = np.random.default_rng(13)
    motion = HumanMotion(0.8, rng=rng)(np.arange(30000) / 100.0)
    sigma = np.array([0.1, 0.2, 0.15]) * DEG
    Rs = [np.eye(3), random_rotation(rng), random_rotation(rng)]
    omegas = [motion @ R + rng.normal(0.0, s, motion.shape) for R, s in zip(Rs, sigma)]
    cal = calibrate_array(omegas, rate_hz=100.0)
    assert cal.noise_source.startswith("identified")
    np.testing.assert_allclose(cal.noise_std, sigma, rtol=0.1)
    assert "not significantly larger" in cal.covariance_basis


@needs_data
def test_calibrate_array_mimu_sessions_spread_is_covered_by_the_covariance():
    from fusion_gyrocal.core.array import calibrate_array
    from fusion_gyrocal.io import read_npz
    cals = []
    for e in range(1, 10):
        s = read_npz(DATA / "mimu_8imu_array" / "npz" / f"exp_{e}.npz")
        mask = np.all([g.valid for g in s], axis=0)
        # the paper's model: its robust covariance (the full map's is in tests/test_array_linear_map.py)
        cals.append(calibrate_array([g.omega for g in s[:4]], mask=mask, rate_hz=62.5, linear_map="rigid"))
    for k in (1, 2, 3):
        z2 = []
        for a, b in itertools.combinations(cals, 2):
            pa, pb = a.pair(0, k), b.pair(0, k)
            d = log(pa.R_1_2 @ pb.R_1_2.T)
            z2.append(d @ np.linalg.solve(pa.covariance[:3, :3] + pb.covariance[:3, :3], d))
        assert 0.75 <= np.mean(z2) <= 6.0, (k, np.mean(z2))
    assert all(0.05 * DEG < c.noise_std[0] < 0.5 * DEG for c in cals)          # static poses: 0.146 deg/s


def test_streaming_calibrator_sliding_window_bins_give_the_robust_covariance():
    from fusion_gyrocal.online.stream import StreamingCalibrator
    sim, _, w2 = _rate_scale_pair(np.random.default_rng(5))
    bases = []
    for second in (w2, sim.omega_2):
        sc = StreamingCalibrator(window_s=200.0, rate_hz=100.0)
        for a in range(0, 20000, 1000):
            sc.update(sim.omega_1[a:a + 1000], second[a:a + 1000])
        bases.append(sc.estimate().covariance_basis)
    assert bases[0].startswith("noise model raised") and "32 windows" in bases[0]
    assert "not significantly larger" in bases[1]


def test_covariance_basis_from_text_reads_back_every_text_choose_and_inflated_write():
    from fusion_gyrocal.core.moments import WindowStats
    from fusion_gyrocal.core.robust import CovarianceBasis, choose, inflated

    def basis_kind(text):
        return CovarianceBasis.from_text(text)

    rng = np.random.default_rng(4)
    W = 200
    stats = WindowStats(np.full(W, 100.0), np.zeros((W, 6)), np.zeros((W, 6, 6)), np.zeros(W, int), 100)
    P = np.eye(3)
    model = "noise model (inverse Fisher information, Appendix B)"
    assert basis_kind(choose(P, 0.5 * P, stats, "robust", model, 1.0)[3]) == "robust"
    assert basis_kind(choose(P, 50.0 * P, stats, "auto", model, 1.0)[3]) == "raised"
    small = P + 0.01 * np.diag(rng.random(3))
    assert basis_kind(choose(P, small, stats, "auto", model, 1.0)[3]) == "checked"
    assert basis_kind(inflated(P, 2.5, model, "flex")[2]) == "inflated"
    assert basis_kind(model) == "model"


def test_pair_calibration_from_dict_legacy_basis_text_keeps_the_kind():
    from fusion_gyrocal.core.robust import CovarianceBasis

    sim = simulate_pair(n=6000, rng=7)
    for options, kind in (({}, CovarianceBasis.CHECKED), ({"covariance": "robust"}, CovarianceBasis.ROBUST),
                          ({"covariance": "model"}, CovarianceBasis.MODEL),
                          ({"covariance": "model", "noise_std": 0.3 * PAPER_NOISE_STD}, CovarianceBasis.INFLATED)):
        cal = calibrate_pair(sim.omega_1, sim.omega_2, **options)
        assert cal.covariance_kind is kind
        d = json.loads(json.dumps(cal.to_dict(), allow_nan=False))
        assert d["covariance_kind"] == kind.value and d["covariance_basis"] == cal.covariance_basis
        for version in ("1.1", "1.2"):   # written before the kind was stored: the sentence only
            legacy = {k: v for k, v in d.items() if k != "covariance_kind"} | {"format_version": version}
            assert PairCalibration.from_dict(legacy).covariance_kind is kind
        assert PairCalibration.from_dict(d).covariance_kind is kind


def test_array_calibration_from_dict_legacy_basis_text_keeps_the_kind():
    from fusion_gyrocal.core.array import ArrayCalibration, calibrate_array
    from fusion_gyrocal.core.robust import CovarianceBasis
    from fusion_gyrocal.evaluate.sim import HumanMotion, random_rotation

    rng = np.random.default_rng(0)
    omega = HumanMotion(rng=rng)(np.arange(8000) / 100.0)
    omegas = [omega @ R + rng.normal(0, 1e-3, omega.shape) for R in [np.eye(3), random_rotation(rng)]]
    cal = calibrate_array(omegas, rate_hz=100.0, noise_std=3e-4)
    assert cal.covariance_kind is CovarianceBasis.RAISED and cal.pair(0, 1).covariance_kind is CovarianceBasis.RAISED
    d = json.loads(json.dumps(cal.to_dict(), allow_nan=False))
    legacy = {k: v for k, v in d.items() if k != "covariance_kind"}
    for back in (ArrayCalibration.from_dict(d), ArrayCalibration.from_dict(legacy)):
        assert back.covariance_kind is CovarianceBasis.RAISED and back.covariance_basis == cal.covariance_basis


def test_covariance_basis_reworded_text_changes_no_report_decision():
    import dataclasses

    from fusion_gyrocal.core.robust import CovarianceBasis
    from fusion_gyrocal.io.report import uncertainty_basis

    sim = simulate_pair(n=6000, rng=7)
    cal = calibrate_pair(sim.omega_1, sim.omega_2)
    for kind, says in ((CovarianceBasis.RAISED, "raised to the block-robust covariance where larger"),
                       (CovarianceBasis.ROBUST, "block-robust covariance as asked"),
                       (CovarianceBasis.CHECKED, "the block-robust check agrees"),
                       (CovarianceBasis.INFLATED, "inflated by the residual's chi2/dof (see the note)")):
        reworded = dataclasses.replace(cal, covariance_kind=kind, covariance_basis="a reworded sentence")
        assert says in uncertainty_basis(reworded)
    assert CovarianceBasis.MODEL.describe("noise model (x)", "3 windows", 2.0) == "noise model (x)"


def test_pair_calibration_from_dict_unknown_covariance_kind_is_a_format_error():
    from fusion_gyrocal.errors import FormatError

    sim = simulate_pair(n=6000, rng=7)
    d = calibrate_pair(sim.omega_1, sim.omega_2).to_dict() | {"covariance_kind": "guessed"}
    with pytest.raises(FormatError, match="covariance_kind"):
        PairCalibration.from_dict(d)
