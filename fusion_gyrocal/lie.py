"""SO(3), the one place: hat, Exp, Log, the right Jacobian, the nearest rotation, canonical rotation vectors.

Every function takes stacks (``(..., 3)`` vectors, ``(..., 3, 3)`` matrices), except :func:`exp3` (one
rotation vector as three floats, the trackers' per-sample path). Rotation errors follow
the library's convention ``R_true = Exp(dtheta) @ R_estimate`` (``dtheta`` in the left frame).

Examples
--------
>>> import numpy as np
>>> v = np.array([0.1, -0.2, 0.3])
>>> np.allclose(log(exp(v)), v)
True
>>> np.allclose(exp(np.array([0.0, 0.0, np.pi / 2])) @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
True
"""

from __future__ import annotations

import math

import numpy as np


def skew(v) -> np.ndarray:
    """``[v x]``: the matrix of the cross product with ``v``; (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _coefficients(theta):
    """``sin(t)/t``, ``(1-cos t)/t^2``, ``(t-sin t)/t^3`` of ``t = |theta|`` (Taylor series near 0)."""
    t2 = np.einsum("...i,...i->...", theta, theta)
    t = np.sqrt(t2)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(ts) / ts)
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(ts)) / ts**2)
    c = np.where(small, 1.0 / 6.0 - t2 / 120.0, (ts - np.sin(ts)) / ts**3)
    return a, b, c


def exp(theta) -> np.ndarray:
    """``Exp(theta)``: Rodrigues' formula; (..., 3) rad -> (..., 3, 3)."""
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (3,):
        return exp_and_right_jacobian(theta)[0]
    return exp3(*theta.tolist())


def exp3(x: float, y: float, z: float) -> np.ndarray:
    """:func:`exp` of one rotation vector ``(x, y, z)`` given as floats (the trackers' per-sample path:
    scalar arithmetic, no array conversion); (3, 3)."""
    t2 = x * x + y * y + z * z
    if t2 < 1e-8:
        a, b = 1.0 - t2 / 6.0, 0.5 - t2 / 24.0
    else:
        t = math.sqrt(t2)
        a, b = math.sin(t) / t, (1.0 - math.cos(t)) / t2
    xx, yy, zz, xy, yz, zx = x * x, y * y, z * z, x * y, y * z, z * x
    return np.array([1.0 - b * (yy + zz), b * xy - a * z, b * zx + a * y,          # a flat list: converts faster
                     b * xy + a * z, 1.0 - b * (xx + zz), b * yz - a * x,
                     b * zx - a * y, b * yz + a * x, 1.0 - b * (xx + yy)]).reshape(3, 3)


def exp_and_right_jacobian(theta) -> tuple[np.ndarray, np.ndarray]:
    """``Exp(theta)`` and the right Jacobian ``J_r(theta)``, with ``Exp(t + d) ~ Exp(t) Exp(J_r(t) d)``."""
    theta = np.asarray(theta, dtype=float)
    a, b, c = _coefficients(theta)
    K = skew(theta)
    K2 = K @ K
    eye = np.eye(3)
    R = eye + a[..., None, None] * K + b[..., None, None] * K2
    Jr = eye - b[..., None, None] * K + c[..., None, None] * K2
    return R, Jr


def log(R) -> np.ndarray:
    """``Log(R)``: the rotation vector (rad) of rotation matrices; (..., 3, 3) -> (..., 3), angle in [0, pi].

    Below 60 degrees the axial vector's arcsine is exact and cheap; larger angles go through the unit
    quaternion (scipy's ``Rotation``, imported only then), accurate up to and at pi.
    """
    R = np.asarray(R, dtype=float)
    if R.shape == (3, 3):     # one matrix (the trackers' per-sample path): scalar arithmetic
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()
        if r00 + r11 + r22 > 2.0:   # cos > 0.5
            v = (0.5 * (r21 - r12), 0.5 * (r02 - r20), 0.5 * (r10 - r01))
            s = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
            f = 1.0 if s < 1e-12 else math.asin(min(s, 1.0)) / s
            return np.array([f * v[0], f * v[1], f * v[2]])
    v = 0.5 * np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    cos = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    s = np.linalg.norm(v, axis=-1)
    out = v * np.where(s < 1e-12, 1.0, np.arcsin(np.clip(s, 0.0, 1.0)) / np.where(s < 1e-12, 1.0, s))[..., None]
    large = cos <= 0.5
    if np.any(large):
        from scipy.spatial.transform import Rotation

        out[large] = Rotation.from_matrix(R[large].reshape(-1, 3, 3)).as_rotvec()
    return out


HALF_TURN_BAND = np.deg2rad(1.0)
"""Half-width (rad) of the band about a half turn in which :func:`canonical_rotvec` fixes the axis's sign."""


def canonical_rotvec(v, band: float = HALF_TURN_BAND) -> np.ndarray:
    """The same rotations as ``v`` (..., 3) with a unique representative that does not flip near a half turn.

    Below ``pi - band`` it is ``Log(Exp(v))``. Within ``band`` of a half turn the axis is the one whose first
    component larger than 0.1 in magnitude is positive, the angle then in (pi - band, pi + band): estimates of
    one half-turn mounting scattered about 180 deg read as nearby vectors instead of opposite ones.
    """
    v = log(exp(v))
    n = np.linalg.norm(v, axis=-1)
    near = n > np.pi - band
    if np.any(near):
        ang = n[near]
        u = v[near] / ang[:, None]
        first = np.argmax(np.abs(u) > 0.1, axis=-1)
        flip = u[np.arange(len(u)), first] < 0
        v[near] = np.where(flip[:, None], -u, u) * np.where(flip, 2.0 * np.pi - ang, ang)[:, None]
    return v


def nearest_rotation(M) -> np.ndarray:
    """Nearest rotation matrix to ``M`` in the Frobenius norm (Horn et al., used after Eq. 31)."""
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones(np.shape(M)[:-2] + (3,))
    D[..., 2] = d
    return (U * D[..., None, :]) @ Vt
