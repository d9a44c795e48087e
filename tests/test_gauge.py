"""The one gauge mechanism (Theorem 2, Eq. 32-34) for pairs and arrays."""

import numpy as np
import pytest

from fusion_gyrocal import ConfigurationError, OptionError
from fusion_gyrocal.core.gauge import Gauge, constrained_inverse, null_directions, null_space, oblique_projector
from fusion_gyrocal.core.observability import classify, seed_configuration

EVERY = (tuple((g, a) for g in (0, 1) for a in range(3)),)


def test_gauge_apply_unit_prior_closed_form():
    s = np.array([[1.2, 1.0, 0.9], [1.1, 1.3, 0.8]])
    out = Gauge.unit_prior().apply(EVERY, s)
    c = (1.2 + 1.1) / (1.2**2 + 1.1**2)     # argmin_c (c 1.2 - 1)^2 + (c 1.1 - 1)^2, Eq. (32)-(34)
    np.testing.assert_allclose(out, c * s)


def test_gauge_apply_known_scale_and_other_groups_follow_unit_convention():
    groups = (((0, 0), (1, 1)), ((0, 1), (1, 0)), ((0, 2), (1, 2)))      # all axes parallel
    s = np.array([[2.0, 3.0, 4.0], [1.0, 2.0, 5.0]])
    out = Gauge.known_scale(2, 1, 0.5).apply(groups, s)
    assert out[1, 1] == 0.5 and out[0, 0] / out[1, 1] == pytest.approx(2.0 / 2.0)
    # groups without a gauge member: their members as close to 1 as their ratio allows
    for group in groups[1:]:
        r = np.array([out[g, a] for g, a in group])
        raw = np.array([s[g, a] for g, a in group])
        np.testing.assert_allclose(r, raw * raw.sum() / (raw**2).sum())


def test_gauge_constraints_are_the_derivative_of_the_condition():
    rng = np.random.default_rng(0)
    s = rng.uniform(0.8, 1.2, (2, 3))
    g = Gauge.unit_prior()
    row = g.constraints(EVERY, s, leading=3)
    assert row.shape == (1, 9) and np.all(row[:, :3] == 0)

    def h(log_s):
        x = np.exp(log_s).reshape(2, 3)
        return (x[0, 0] - 1) * x[0, 0] + (x[1, 0] - 1) * x[1, 0]
    eps = 1e-7
    num = [(h(np.log(s).ravel() + eps * e) - h(np.log(s).ravel() - eps * e)) / (2 * eps) for e in np.eye(6)]
    np.testing.assert_allclose(row[0, 3:], num, rtol=1e-6, atol=1e-9)


def test_gauge_parse_strings_for_arrays_and_refuses_others():
    assert Gauge.parse("unit_prior", n_gyros=4).members == ((0, 0), (1, 0), (2, 0), (3, 0))
    assert Gauge.parse("fixed", n_gyros=4, reference=2) == Gauge(((2, 0),), 1.0)
    for bad in ("none", 3, None):
        with pytest.raises(OptionError, match="gauge"):
            Gauge.parse(bad)
    with pytest.raises(OptionError, match="members"):
        Gauge.parse(Gauge(((5, 0),), 1.0), n_gyros=2)


def test_oblique_projector_keeps_the_condition_and_moves_along_null_directions():
    groups = (((0, 0), (1, 1)), ((0, 1), (1, 0), (0, 2), (1, 2)))
    s = np.array([[1.1, 0.9, 1.05], [0.97, 1.02, 1.0]])
    N = null_directions(groups, 2)
    G = Gauge.unit_prior(axis=0).constraints(groups, s)
    T = oblique_projector(N, G)
    np.testing.assert_allclose(G @ T, 0.0, atol=1e-14)          # projected directions satisfy the gauge
    np.testing.assert_allclose(T @ N, 0.0, atol=1e-14)          # null directions are removed
    np.testing.assert_allclose(T @ T, T, atol=1e-14)


def test_constrained_inverse_matches_bordered_system():
    rng = np.random.default_rng(1)
    J = rng.normal(size=(20, 5))
    F = J.T @ J
    C = rng.normal(size=(2, 5))
    P = constrained_inverse(F, C)
    K = np.block([[F, C.T], [C, np.zeros((2, 2))]])
    np.testing.assert_allclose(P, np.linalg.inv(K)[:5, :5], atol=1e-10)


def test_seed_configuration_keeps_class_or_checks_tolerance():
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("zx", [30, 3], degrees=True).as_matrix()   # x axes 3 deg from parallel
    assert classify(R, 5.0).name == "one_axis_pair_parallel" and classify(R, 1.0).name == "general"
    assert seed_configuration(R, "general").name == "general"
    one = seed_configuration(R, "one_axis_pair_parallel")
    assert one.groups == classify(R, 5.0).groups
    with pytest.raises(ConfigurationError, match="parallel_tol_deg"):
        seed_configuration(R, "general", parallel_tol_deg=5.0)
    with pytest.raises(ConfigurationError, match="configuration"):
        seed_configuration(R, "diagonal")


def test_gauge_condition_holds_after_apply_and_constraints_are_its_derivative():
    groups = (((0, 0), (1, 1)), ((0, 1), (1, 0), (0, 2), (1, 2)))
    s = np.array([[1.1, 0.9, 1.05], [0.97, 1.02, 1.0]])
    for gauge in (Gauge.unit_prior(), Gauge.known_scale(2, 1, 0.8)):
        np.testing.assert_allclose(gauge.condition(groups, gauge.apply(groups, s)), 0.0, atol=1e-15)
        eps, log_s = 1e-7, np.log(s).ravel()
        num = np.column_stack([(gauge.condition(groups, np.exp(log_s + eps * e).reshape(2, 3))
                                - gauge.condition(groups, np.exp(log_s - eps * e).reshape(2, 3))) / (2 * eps)
                               for e in np.eye(6)])
        np.testing.assert_allclose(gauge.constraints(groups, s), num, rtol=1e-6, atol=1e-9)


def test_null_space_orthonormal_basis_of_the_kernel_with_numerical_rank():
    rng = np.random.default_rng(2)
    M = rng.normal(size=(3, 9))
    M[2] = M[0] - 2.0 * M[1] + 1e-17   # rank 2: the dependent row is dropped at the numerical rank
    Z = null_space(M)
    assert Z.shape == (9, 7)
    np.testing.assert_allclose(Z.T @ Z, np.eye(7), atol=1e-14)
    np.testing.assert_allclose(M @ Z, 0.0, atol=1e-14)
    assert null_space(np.eye(4)).shape == (4, 0)
