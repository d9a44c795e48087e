"""The one SO(3) module: Exp, Log, right Jacobian, canonical rotation vectors, nearest rotation."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion_gyrocal import lie


@pytest.fixture
def rotvecs():
    rng = np.random.default_rng(3)
    v = rng.normal(size=(200, 3))
    angles = np.concatenate([np.geomspace(1e-9, 1e-3, 50), rng.uniform(1e-3, np.pi - 1e-6, 150)])
    return v / np.linalg.norm(v, axis=1, keepdims=True) * angles[:, None]


def test_exp_matches_scipy(rotvecs):
    np.testing.assert_allclose(lie.exp(rotvecs), Rotation.from_rotvec(rotvecs).as_matrix(), atol=1e-14)


def test_log_inverts_exp_small_and_large_angles(rotvecs):
    np.testing.assert_allclose(lie.log(lie.exp(rotvecs)), rotvecs, atol=1e-12, rtol=1e-9)


def test_log_single_matrix_shape():
    assert lie.log(np.eye(3)).shape == (3,)
    np.testing.assert_array_equal(lie.log(np.eye(3)), np.zeros(3))


def test_exp_and_right_jacobian_first_order():
    rng = np.random.default_rng(4)
    for _ in range(20):
        t, d = rng.normal(size=3), 1e-7 * rng.normal(size=3)
        R, Jr = lie.exp_and_right_jacobian(t)
        lhs = lie.exp(t + d)
        rhs = R @ lie.exp(Jr @ d)
        assert np.abs(lhs - rhs).max() < 1e-12


def test_canonical_rotvec_unique_at_pi():
    axis = np.array([0.0, -1.0, 0.0])
    a, b = lie.canonical_rotvec(np.pi * axis), lie.canonical_rotvec(-np.pi * axis)
    np.testing.assert_allclose(a, b, atol=1e-12)
    np.testing.assert_allclose(np.abs(a), [0.0, np.pi, 0.0], atol=1e-12)
    assert a[1] > 0
    # away from pi the vector is left as it is (up to round-off)
    v = np.array([0.3, -2.0, 0.1])
    np.testing.assert_allclose(lie.canonical_rotvec(v), v, atol=1e-12)


def test_nearest_rotation_projects_and_keeps_rotations():
    rng = np.random.default_rng(5)
    R = Rotation.random(10, random_state=6).as_matrix()
    np.testing.assert_allclose(lie.nearest_rotation(R), R, atol=1e-12)
    noisy = R + 1e-3 * rng.normal(size=R.shape)
    P = lie.nearest_rotation(noisy)
    np.testing.assert_allclose(P @ np.swapaxes(P, 1, 2), np.broadcast_to(np.eye(3), P.shape), atol=1e-12)
    assert np.all(np.linalg.det(P) > 0)


def test_canonical_rotvec_does_not_flip_across_a_half_turn():
    u = np.array([0.707, -0.708, 0.003]) / np.linalg.norm([0.707, -0.708, 0.003])
    below, above = lie.exp(np.deg2rad(179.997) * u), lie.exp(np.deg2rad(180.003) * u)
    assert np.linalg.norm(lie.log(below) - lie.log(above)) > 6.0          # Log itself jumps across pi
    a, b = lie.canonical_rotvec(lie.log(below)), lie.canonical_rotvec(lie.log(above))
    assert np.linalg.norm(a - b) < np.deg2rad(0.01)
    np.testing.assert_allclose(lie.exp(b), above, atol=1e-12)
    v = np.deg2rad(170.0) * u
    np.testing.assert_allclose(lie.canonical_rotvec(-v), -v, atol=1e-12)


def test_log_matches_scipy_near_and_at_a_half_turn():
    # large angles go through the unit quaternion: accurate up to and at a half turn, the rotation vectors scipy gives
    rng = np.random.default_rng(8)
    axes = rng.normal(size=(300, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(np.pi / 3, np.pi, 200), np.pi - np.geomspace(1e-12, 1e-3, 99), [np.pi]])
    R = Rotation.from_rotvec(axes * angles[:, None]).as_matrix()
    v = lie.log(R)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), angles, atol=1e-12)
    np.testing.assert_allclose(lie.exp(v), R, atol=1e-14)
    below = angles < np.pi - 1e-6     # away from the half turn the vector is unique
    np.testing.assert_allclose(v[below], Rotation.from_matrix(R[below]).as_rotvec(), atol=1e-13)
