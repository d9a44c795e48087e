import argparse
import csv
import dataclasses
import io
import sys

import numpy as np
from _examples import load_example
import pytest
from scipy.spatial.transform import Rotation

from fusion_gyrocal import ConvergenceError, InputError, OptionError, calibrate_pair
from fusion_gyrocal.cli.compare import add_compare_parser, compare_main
from fusion_gyrocal.evaluate import registry
from fusion_gyrocal.evaluate.baselines import rotation_only, solve_appendix_c
from fusion_gyrocal.evaluate.compare import compare, plot_rmse_vs_snr, snr_sweep
from fusion_gyrocal.evaluate.registry import DEFAULT_ESTIMATORS, ESTIMATORS, REGISTRY, Estimator, run_estimator
from fusion_gyrocal.lie import exp
from fusion_gyrocal.options import Options
from fusion_gyrocal.core.moments import Moments
from fusion_gyrocal.core.observability import cramer_rao_bound
from fusion_gyrocal.evaluate.scenarios import SCENARIOS, describe_scenario, list_scenarios, make_scenario, scenario_bound
from fusion_gyrocal.evaluate.sim import (PAPER_NOISE_STD, PAPER_SKEW_STD, random_rotation, rotation_error, scale_error,
                                simulate_pair)

S1 = np.array([1.01, 0.99, 1.02])
S2 = np.array([0.98, 1.00, 1.03])


def _kabsch(w1, w2):
    """Independent Kabsch: SVD of the centred cross-covariance (Arun et al.)."""
    a, b = w1 - w1.mean(axis=0), w2 - w2.mean(axis=0)
    U, _, Vt = np.linalg.svd(a.T @ b)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


# ------------------------------------------------------------------------------------------ compare: table
def test_compare_table_matches_direct_computation():
    seed, runs = 3, 5
    c = compare("nominal", estimators=["direct", "rotation_only"], runs=runs, seed=seed, workers=1, progress=False)
    rot = {"direct": [], "rotation_only": []}
    sca, rb, sb, snr = [], [], [], []
    for i in range(runs):
        sc = make_scenario("nominal", rng=[seed, i])
        d = sc.data
        cal = calibrate_pair(sc.omega_1, sc.omega_2, method="direct")
        rot["direct"].append(rotation_error(cal.R_1_2, d.R_1_2))
        sca.append(scale_error(cal.scale_1, cal.scale_2, d.scale_1, d.scale_2))
        rot["rotation_only"].append(rotation_error(_kabsch(sc.omega_1, sc.omega_2), d.R_1_2))
        signal_2 = (d.omega_true_1 @ d.R_1_2) @ d.S_2.T
        b = cramer_rao_bound(d.R_1_2, d.scale_1, d.scale_2, d.noise_std, signal_2)
        rb.append(b.rotation_rmse)
        sb.append(b.scale_rmse)
        snr.append(np.sqrt(np.sum(d.omega_true_1**2)) / np.hypot(*d.noise_std))

    def rms(x):
        return np.sqrt(np.mean(np.square(x)))

    direct, kabsch = c.row("direct"), c.row("rotation_only")
    assert direct.runs == runs and direct.failures == 0
    np.testing.assert_allclose(direct.rotation_rmse, rms(rot["direct"]), rtol=1e-9)
    np.testing.assert_allclose(direct.scale_rmse, rms(sca), rtol=1e-9)
    np.testing.assert_allclose(direct.rotation_ratio, rms(rot["direct"]) / rms(rb), rtol=1e-9)
    np.testing.assert_allclose(direct.scale_ratio, rms(sca) / rms(sb), rtol=1e-9)
    np.testing.assert_allclose(kabsch.rotation_rmse, rms(rot["rotation_only"]), rtol=1e-6)
    assert np.isnan(kabsch.scale_rmse)
    np.testing.assert_allclose(c.snr, np.mean(snr), rtol=1e-12)
    # the CSV carries the same numbers (library units) ...
    table = {r["estimator"]: r for r in csv.DictReader(io.StringIO(c.to_csv()))}
    assert float(table["direct"]["rotation_rmse_rad"]) == direct.rotation_rmse
    assert float(table["direct"]["scale_ratio"]) == direct.scale_ratio
    # ... and the Markdown their human-unit rendering
    md = c.to_markdown()
    assert f"| direct | {np.rad2deg(rms(rot['direct'])) * 1e3:.4g} | {rms(rot['direct']) / rms(rb):.3f} |" in md


def test_compare_estimate_columns_are_first_run_estimate():
    c = compare("nominal", estimators=["direct"], runs=1, seed=5, workers=1, progress=False)
    sc = make_scenario("nominal", rng=[5, 0])
    cal = calibrate_pair(sc.omega_1, sc.omega_2, method="direct")
    row = c.row("direct")
    np.testing.assert_allclose(row.rotvec_deg, np.rad2deg(Rotation.from_matrix(cal.R_1_2).as_rotvec()), atol=1e-12)
    np.testing.assert_allclose(row.scale_1, cal.scale_1, rtol=1e-12)
    assert "rotvec R_1_2 [deg]" in c.to_markdown()


def test_compare_process_pool_matches_serial():
    kw = dict(estimators=["direct", "appendix_c"], runs=2, seed=11, progress=False)
    serial, pooled = compare("weak_axis", workers=1, **kw), compare("weak_axis", workers=2, **kw)
    for a, b in zip(serial.records, pooled.records):
        np.testing.assert_array_equal(a.rotation_error, b.rotation_error)
        np.testing.assert_array_equal(a.scale_error, b.scale_error)


def test_compare_recording_has_estimates_but_no_errors():
    sim = simulate_pair(rng=2, scale_1=S1, scale_2=S2)
    c = compare((sim.omega_1, sim.omega_2), estimators=["direct"], progress=False)
    row = c.row("direct")
    cal = calibrate_pair(sim.omega_1, sim.omega_2, method="direct")
    assert not c.has_truth and np.isnan(row.rotation_rmse) and np.isnan(row.rotation_ratio)
    np.testing.assert_allclose(row.scale_2, cal.scale_2, rtol=1e-12)
    assert "errors against the truth" not in c.to_markdown()


def test_compare_unavailable_module_row_says_not_available(monkeypatch):
    monkeypatch.setitem(sys.modules, "fusion_gyrocal.online.tracker", None)  # import now raises ImportError
    c = compare("nominal", estimators=["direct", "ekf"], runs=1, workers=1, progress=False)
    ekf, direct = c.row("ekf"), c.row("direct")
    assert ekf.failures == 1 and ekf.note.startswith("not available: fusion_gyrocal.online.tracker")
    assert direct.failures == 0 and np.isfinite(direct.rotation_rmse)
    assert "ekf: not available" in c.to_markdown()


@pytest.mark.parametrize("run", [lambda: compare("nominal", runs=0, progress=False),
                                 lambda: snr_sweep("nominal", runs=0, progress=False)])
def test_compare_and_sweep_reject_zero_runs(run):
    with pytest.raises(InputError, match="runs: expected >= 1, got 0"):
        run()


def test_compare_unknown_estimator_raises_input_error():
    with pytest.raises(InputError, match="expected names from direct"):
        compare("nominal", estimators=["kalibr"], progress=False)


# ------------------------------------------------------------------------------------------ estimators
def test_solve_appendix_c_noise_free_converges_from_identity():
    R = random_rotation(4, angle_deg=40.0)
    sim = simulate_pair(rng=1, R_1_2=R, scale_1=S1, scale_2=S2, noise_std=1e-13, bias_walk_std=0.0)
    res = solve_appendix_c(Moments.from_samples(sim.omega_1, sim.omega_2))
    assert 1 <= res.iterations <= 10
    assert rotation_error(res.R_1_2, R) < 1e-10
    assert scale_error(res.scale_1, res.scale_2, S1, S2) < 1e-10
    np.testing.assert_allclose(res.bias, sim.bias, atol=1e-10)


def test_solve_appendix_c_keeps_scale_1_x_fixed():
    sim = simulate_pair(rng=6, scale_1=S1, scale_2=S2)
    res = solve_appendix_c(Moments.from_samples(sim.omega_1, sim.omega_2), sim.R_1_2, [1.05, 1, 1], [1, 1, 1])
    assert res.scale_1[0] == 1.05


def test_solve_appendix_c_indistinguishable_from_direct():
    # the paper's finding (Section V): direct and iterative solutions agree far inside the noise
    sc = make_scenario("nominal", rng=8)
    b = scenario_bound(sc)
    direct = run_estimator("direct", sc.omega_1, sc.omega_2)
    iterative = run_estimator("appendix_c", sc.omega_1, sc.omega_2)
    assert rotation_error(direct.R_1_2, iterative.R_1_2) < 0.1 * b.rotation
    # both attenuate the scales by noise in the regressor (direct: gyro 2's, Appendix C: gyro 1's in its
    # Jacobian), in opposite directions: the gap is about (sigma_1^2 + sigma_2^2) / (mean square rate per axis)
    attenuation = np.sum(np.square(sc.noise_std)) / np.mean(sc.data.omega_true_1**2)
    assert scale_error(iterative.scale_1, iterative.scale_2, direct.scale_1, direct.scale_2) < 2 * attenuation
    assert 2 * attenuation < 0.5 * b.scale  # ... which is well inside the noise at the paper's SNR


def test_rotation_only_matches_independent_kabsch():
    sim = simulate_pair(rng=9, scale_1=S1, scale_2=S2)
    R, bias = rotation_only(sim.omega_1, sim.omega_2)
    assert rotation_error(R, _kabsch(sim.omega_1, sim.omega_2)) < 1e-10
    np.testing.assert_allclose(bias, sim.omega_1.mean(axis=0) - R @ sim.omega_2.mean(axis=0), atol=1e-12)


def test_run_estimator_reports_failure_instead_of_raising():
    w = np.zeros((100, 3))  # constant input: the calibration must refuse
    est = run_estimator("direct", w, w)
    assert not est.ok and "InputError" in est.error and np.isnan(est.R_1_2).all()


def test_solve_appendix_c_divergence_raises_convergence_error():
    # from identity on a weak-axis realisation the Gauss-Newton iteration runs away (scales change sign)
    sc = make_scenario("weak_axis", rng=[4, 1])
    with pytest.raises(ConvergenceError, match="diverged at iteration"):
        solve_appendix_c(Moments.from_samples(sc.omega_1, sc.omega_2))
    est = run_estimator("appendix_c_identity", sc.omega_1, sc.omega_2)
    assert not est.ok and est.error.startswith("ConvergenceError: appendix C: the Gauss-Newton iteration diverged")


def test_solve_appendix_c_scales_leaving_positive_raise_convergence_error():
    # from identity on this nominal realisation the iteration ran away to scales of -2e13 and was returned
    sc = make_scenario("nominal", rng=[0, 1])
    with pytest.raises(ConvergenceError, match=r"diverged at iteration \d+ \(a scale factor left \(0, inf\)"):
        solve_appendix_c(Moments.from_samples(sc.omega_1, sc.omega_2))


def test_solve_appendix_c_no_convergence_within_max_iter_raises():
    sc = make_scenario("nominal", rng=[0, 7])   # converges from identity, but not in 2 iterations
    m = Moments.from_samples(sc.omega_1, sc.omega_2)
    with pytest.raises(ConvergenceError, match=r"no convergence in 2 iterations \(last step [0-9.e+-]+, expected "
                                               r"below 1e-10"):
        solve_appendix_c(m, max_iter=2)
    assert solve_appendix_c(m).iterations <= 10


@pytest.mark.parametrize("R, s1, s2, bias, what", [
    (np.eye(3), [1.0, -3.257123e6, 1.0], np.ones(3), np.zeros(3), "scale factors outside (0, inf)"),
    (np.eye(3), np.ones(3), [1.0, np.inf, 1.0], np.zeros(3), "scale factors outside (0, inf)"),
    (np.eye(3), [1.0, np.nan, 1.0], np.ones(3), np.zeros(3), "scale factors outside (0, inf)"),
    (np.diag([1.0, 1.0, -1.0]), np.ones(3), np.ones(3), np.zeros(3), "not a rotation"),
    (2 * np.eye(3), np.ones(3), np.ones(3), np.zeros(3), "not a rotation"),
    (np.full((3, 3), np.nan), np.ones(3), np.ones(3), np.zeros(3), "a non-finite R_1_2"),
    (np.eye(3), np.ones(3), np.ones(3), [0.0, np.nan, 0.0], "a non-finite bias"),
])
def test_run_estimator_non_physical_estimate_is_a_failed_row(monkeypatch, R, s1, s2, bias, what):
    # whatever an estimator returns is checked in one place: a diverged scale of -3.26e6 is no success
    def run(w1, w2, rate_hz, options):
        return R, np.asarray(s1, float), np.asarray(s2, float), np.asarray(bias, float), 10

    monkeypatch.setitem(REGISTRY, "appendix_c", _with_run("appendix_c", run))
    sc = make_scenario("nominal", rng=0, n=600)
    est = run_estimator("appendix_c", sc.omega_1, sc.omega_2)
    assert not est.ok and np.isnan(est.R_1_2).all() and np.isnan(est.scale_2).all()
    assert est.error.startswith("ConvergenceError: appendix_c: expected a physical estimate, got ") and what in est.error
    c = compare("nominal", estimators=["appendix_c", "rotation_only"], runs=1, workers=1, progress=False)
    assert c.row("appendix_c").failures == 1 and what in c.row("appendix_c").note
    assert c.row("rotation_only").failures == 0   # no scales (NaN) is not a failure


def _with_run(name, run):
    return dataclasses.replace(REGISTRY[name], run=run)


@pytest.mark.parametrize("exc", [ValueError("a bug"), np.linalg.LinAlgError("Singular matrix"), RuntimeError("x")])
def test_run_estimator_non_gyrocal_error_propagates(monkeypatch, exc):
    def run(w1, w2, rate_hz, options):
        raise exc

    monkeypatch.setitem(REGISTRY, "direct", _with_run("direct", run))
    sc = make_scenario("nominal", rng=0, n=600)
    with pytest.raises(type(exc), match=str(exc)):
        run_estimator("direct", sc.omega_1, sc.omega_2)
    with pytest.raises(type(exc), match=str(exc)):
        compare("nominal", estimators=["direct"], runs=1, workers=1, progress=False)


def test_run_estimator_gyrocal_error_is_a_failed_row(monkeypatch):
    def run(w1, w2, rate_hz, options):
        raise OptionError("noise_std: expected > 0")  # a GyroCalError (and a ValueError): a failure, not a bug

    monkeypatch.setitem(REGISTRY, "direct", _with_run("direct", run))
    c = compare("nominal", estimators=["direct", "rotation_only"], runs=1, workers=1, progress=False)
    assert c.row("direct").failures == 1 and c.row("direct").note == "OptionError: noise_std: expected > 0"
    assert c.row("rotation_only").failures == 0


def test_registry_one_entry_adds_an_estimator(monkeypatch):
    # adding an estimator is adding one entry: it runs, is named in the rows and draws in its colour
    def run(w1, w2, rate_hz, options):
        return np.eye(3), np.ones(3), np.ones(3), np.zeros(3), 0

    monkeypatch.setitem(REGISTRY, "identity", Estimator("identity", "assumes identity", run, colour="k", marker="*"))
    c = compare("nominal", estimators=["identity"], runs=1, seed=2, workers=1, progress=False)
    sc = make_scenario("nominal", rng=[2, 0])
    row = c.row("identity")
    assert row.description == "assumes identity" and row.failures == 0
    np.testing.assert_allclose(row.rotation_rmse, rotation_error(np.eye(3), sc.data.R_1_2), rtol=1e-12)
    assert ESTIMATORS == {n: e.description for n, e in registry.REGISTRY.items() if n != "identity"}
    assert DEFAULT_ESTIMATORS == ("direct", "default", "appendix_c", "rotation_only", "graph", "ekf")


def test_compare_rotvec_is_canonical_at_180_deg(monkeypatch):
    # a half turn about -x - y: Log may return either sign; the table shows the canonical one
    axis = -np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    R = exp(np.pi * axis)

    def run(w1, w2, rate_hz, options):
        return R, np.ones(3), np.ones(3), np.zeros(3), 0

    monkeypatch.setitem(REGISTRY, "half_turn", Estimator("half_turn", "half turn", run))
    sim = simulate_pair(rng=1, n=600)
    row = compare((sim.omega_1, sim.omega_2), estimators=["half_turn"], progress=False).row("half_turn")
    np.testing.assert_allclose(row.rotvec_deg, -180.0 * axis, atol=1e-6)


def test_compare_options_reach_the_estimators():
    sim = simulate_pair(rng=2, scale_1=S1, scale_2=S2)
    noise = (1e-3, 4e-3)  # an unequal split changes the maximum-likelihood weights
    c = compare((sim.omega_1, sim.omega_2), estimators=["direct", "default"], progress=False, noise_std=noise)
    by_options = compare((sim.omega_1, sim.omega_2), estimators=["direct", "default"], progress=False,
                         options=Options(noise_std=noise, method="direct"))  # the method is each estimator's
    plain = compare((sim.omega_1, sim.omega_2), estimators=["default"], progress=False)
    ml = calibrate_pair(sim.omega_1, sim.omega_2, noise_std=noise)
    np.testing.assert_allclose(c.row("default").scale_2, ml.scale_2, rtol=1e-12)
    np.testing.assert_allclose(by_options.row("default").scale_2, ml.scale_2, rtol=1e-12)
    assert np.abs(plain.row("default").scale_2 - ml.scale_2).max() > 1e-7
    direct = calibrate_pair(sim.omega_1, sim.omega_2, method="direct", noise_std=noise)
    np.testing.assert_allclose(by_options.row("direct").scale_2, direct.scale_2, rtol=1e-12)
    with pytest.raises(OptionError, match="unknown option"):
        compare((sim.omega_1, sim.omega_2), estimators=["direct"], progress=False, noise=1e-3)


# ------------------------------------------------------------------------------------------ scenarios
@pytest.mark.parametrize("via", ["rate", "noise", "samples"])
def test_make_scenario_snr_factor_scales_snr(via):
    base = make_scenario("nominal", rng=1)
    for f in (0.5, 2.0, 4.0):
        sc = make_scenario(f"snr_x{f:g}_{via}", rng=1)
        np.testing.assert_allclose(sc.snr, f * base.snr, rtol=1e-12)
    assert make_scenario("snr_x4_samples", rng=1).n_samples == 16 * base.n_samples


def test_make_scenario_weak_axis_keeps_snr_and_weakens_x():
    nominal, weak = make_scenario("nominal", rng=2), make_scenario("weak_axis", rng=2)
    np.testing.assert_allclose(weak.snr, nominal.snr, rtol=1e-12)
    rms = np.sqrt(np.mean(weak.data.omega_true_1**2, axis=0))
    assert 0.05 < rms[0] / rms[1] < 0.2 and 0.05 < rms[0] / rms[2] < 0.2


def test_make_scenario_flex_bends_only_during_bursts():
    sc = make_scenario("flex", rng=4)
    d = sc.data
    rigid = (d.omega_true_1 @ d.R_1_2) @ d.S_2.T + d.bias_2
    dev = np.linalg.norm(sc.omega_2 - rigid, axis=1)
    sigma = PAPER_NOISE_STD
    bent = sc.flex_angle > 0
    np.testing.assert_allclose(np.rad2deg(sc.flex_angle.max()), 1.0, rtol=1e-12)
    assert 0 < bent.mean() < 0.2
    assert dev[~bent].max() < 6 * sigma                     # noise only (chi(3) tail) where rigid
    assert dev[np.argmax(sc.flex_angle)] > 50 * sigma       # 1 deg of a fast rate where bent


def test_make_scenario_unknown_name_lists_choices():
    with pytest.raises(InputError, match="expected one of nominal, weak_axis"):
        make_scenario("nominl")


def test_describe_scenario_is_make_scenario_description_and_checks_the_same():
    for name, kw in (("nominal", {}), ("snr_x2_noise", {}), ("weak_axis", dict(snr_factor=0.5, snr_via="samples"))):
        assert describe_scenario(name, **kw) == make_scenario(name, rng=0, **kw).description
    with pytest.raises(InputError, match="leaves 5 samples"):
        describe_scenario("nominal", snr_factor=0.03, snr_via="samples")


def test_list_scenarios_every_name_builds():
    for name in list_scenarios():
        sc = make_scenario(name, rng=0, n=600)
        assert sc.omega_1.shape == sc.omega_2.shape and np.isfinite(sc.omega_2).all()
    assert set(SCENARIOS) <= set(list_scenarios())


def test_scenario_bound_matches_sampled_errors():
    # draw calibration errors from the bound's covariance and push them through the paper's metrics
    sc = make_scenario("near_parallel", rng=3)
    d = sc.data
    b = scenario_bound(sc)
    P = cramer_rao_bound(d.R_1_2, d.scale_1, d.scale_2, d.noise_std, sc.signal_2).covariance
    rng = np.random.default_rng(0)
    M = 4000
    x = rng.multivariate_normal(np.zeros(9), P, size=M, method="eigh")
    rot = [rotation_error(Rotation.from_rotvec(v[:3]).as_matrix() @ d.R_1_2, d.R_1_2) for v in x]
    sca = [scale_error(d.scale_1 * np.exp(v[3:6]), d.scale_2 * np.exp(v[6:]), d.scale_1, d.scale_2) for v in x]
    # mean of M squared errors: relative std <= sqrt(2 / M) (one chi-square dof, the worst case)
    tol = 4 * np.sqrt(2.0 / M)
    np.testing.assert_allclose(np.sqrt(np.mean(np.square(rot))), b.rotation, rtol=tol)
    np.testing.assert_allclose(np.sqrt(np.mean(np.square(sca))), b.scale, rtol=tol)


def test_scenario_bound_skew_prediction_matches_estimate():
    # noise made negligible: the remaining rotation error is Appendix D's (w_1 - C w_2) / 2
    for seed in range(3):
        sc = make_scenario("skew", rng=seed, snr_factor=1000, snr_via="noise")
        b = scenario_bound(sc)
        est = run_estimator("direct", sc.omega_1, sc.omega_2)
        err = rotation_error(est.R_1_2, sc.data.R_1_2)
        # first order in the skew, with S_i = I assumed: the 1 % scale spread leaves a few % of it
        assert abs(err - b.rotation_skew) < 0.03 * np.sqrt(1.5) * PAPER_SKEW_STD + 10 * b.rotation
        assert b.rotation_expected >= b.rotation_skew


# ------------------------------------------------------------------------------------------ sweeps, figures, CLI
def test_snr_sweep_slopes_are_log_log_fits():
    sw = snr_sweep("nominal", factors=(1.0, 4.0), runs=3, estimators=["direct"], workers=1, progress=False)
    r = sw.rmse("direct", "rotation")
    expected = np.log(r[1] / r[0]) / np.log(sw.snr[1] / sw.snr[0])
    assert sw.slopes()[0].rotation == pytest.approx(expected, rel=1e-9)
    # the SNR goes through the rate norm on the same realisations: the error scales exactly as 1 / SNR
    assert sw.slopes()[0].rotation == pytest.approx(-1.0, abs=0.02)


def test_plot_rmse_vs_snr_draws_each_estimator_and_the_bound(tmp_path):
    sw = snr_sweep("nominal", factors=(1.0, 2.0), runs=2, estimators=["direct", "rotation_only"], workers=1,
                   progress=False)
    fig = plot_rmse_vs_snr(sw, tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 10_000
    rot_ax, scale_ax = fig.axes
    labels = [line.get_label() for line in rot_ax.get_lines()]
    assert labels[0].startswith("direct: slope") and labels[-1].startswith("Cramer-Rao bound")
    np.testing.assert_allclose(rot_ax.get_lines()[0].get_ydata(), np.rad2deg(sw.rmse("direct", "rotation")) * 1e3)
    assert not any(lab.startswith("rotation_only") for lab in (ln.get_label() for ln in scale_ax.get_lines()))


def _cli(argv):
    parser = argparse.ArgumentParser(prog="gyrocal")
    add_compare_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(argv)


def test_compare_main_writes_markdown_and_csv(tmp_path):
    md, table = tmp_path / "t.md", tmp_path / "t.csv"
    args = _cli(["compare", "--scenario", "skew", "--runs", "2", "--estimators", "direct,default", "--workers", "1",
                 "--no-progress", "--markdown", str(md), "--csv", str(table)])
    assert args.func(args) == 0
    rows = list(csv.DictReader(table.open()))
    assert [r["estimator"] for r in rows] == ["direct", "default"]
    assert all(float(r["rotation_ratio"]) > 0 for r in rows)
    assert md.read_text().startswith("**skew:")


def test_compare_main_recording_files_match_calibrate_pair(tmp_path):
    from fusion_gyrocal.io import ImuStream, write_csv

    sim = simulate_pair(rng=12, scale_1=S1, scale_2=S2, n=3000)
    write_csv(ImuStream(sim.t, sim.omega_1), tmp_path / "a.csv")
    write_csv(ImuStream(sim.t, sim.omega_2), tmp_path / "b.csv")
    table = tmp_path / "t.csv"
    args = _cli(["compare", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--offset", "0", "--estimators",
                 "direct", "--no-progress", "--csv", str(table)])
    assert args.func(args) == 0
    row = next(csv.DictReader(table.open()))
    cal = calibrate_pair(sim.omega_1, sim.omega_2, method="direct")
    got = np.array([float(row[f"rotvec_{a}_deg"]) for a in "xyz"])
    np.testing.assert_allclose(got, np.rad2deg(Rotation.from_matrix(cal.R_1_2).as_rotvec()), atol=1e-9)
    assert row["rotation_rmse_rad"] == "nan"  # no truth for a recording


def test_compare_main_sweep_writes_figure_and_slopes(tmp_path, capsys):
    fig = tmp_path / "sweep.png"
    args = _cli(["compare", "--scenario", "nominal", "--sweep", "--runs", "2", "--estimators", "direct",
                 "--workers", "1", "--no-progress", "--figure", str(fig), "--csv", str(tmp_path / "s.csv")])
    assert args.func(args) == 0
    assert fig.stat().st_size > 10_000
    rows = list(csv.DictReader((tmp_path / "s.csv").open()))
    assert len(rows) == 4 and float(rows[3]["snr"]) == pytest.approx(8 * float(rows[0]["snr"]), rel=1e-12)
    assert "direct: rotation -1.000" in capsys.readouterr().out


def test_compare_main_unknown_scenario_exits_1(capsys):
    args = _cli(["compare", "--scenario", "nope", "--no-progress"])
    assert compare_main(args) == 1
    assert "gyrocal compare: error: scenario: expected one of" in capsys.readouterr().err


def test_compare_main_output_in_missing_folder_exits_1(tmp_path, capsys):
    args = _cli(["compare", "--estimators", "direct", "--workers", "1", "--no-progress",
                 "--csv", str(tmp_path / "missing" / "t.csv")])
    assert compare_main(args) == 1
    err = capsys.readouterr().err
    assert err.startswith("gyrocal compare: error:") and "does not exist" in err


def test_example_compare_estimators_runs(capsys):
    mc, rec = load_example("compare_estimators").main(["--runs", "2", "--workers", "1"])
    # the batch estimators reach the bound on the nominal scenario; a recording has estimates, no errors
    assert mc.row("default").rotation_ratio < 3 and mc.row("direct").scale_ratio < 3
    assert not rec.has_truth and np.isfinite(rec.row("appendix_c").rotvec_deg).all()
    assert "rot / bound" in capsys.readouterr().out
