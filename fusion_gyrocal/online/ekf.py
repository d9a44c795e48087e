"""The tracker's filter: filterpy's EKF on a 12-d error state, folded into the nominal calibration.

Measurement (Eq. 4-9 of the paper, one sample)::

    z_k = omega_1_meas(k) = A(x) omega_2_meas(k) + b + n(k),
    A(x) = diag(s_1) Exp(dtheta) R_ref diag(1 / s_2),   s_i = s_i,ref * exp(delta_i),
    Cov n(k) = g_k (sigma_1^2 I + sigma_2^2 A A^T)     (gyro 2's noise enters through A)

``g_k`` is 1 for white noise. A pair whose residual grows with the rate (a rate-dependent scale or
cross-axis error, the misfit ``(a + b |omega|) omega`` of :func:`fusion_gyrocal.core.noise.identify_noise`)
gets the misfit's variance per axis on top of the white one, as a factor of the white covariance (the
two are nearly isotropic: ``A`` is a rotation up to scale factors near 1)::

    g_k = 1 + (a + b |omega_1(k)|)^2 |omega_1(k)|^2 / (3 sigma^2),   sigma^2 = tr(R_white) / 3

and a block's samples still fold into one update through their (weighted) moments. The gate, the CUSUM
and the noise adaptation (:meth:`ErrorStateEKF.innovations`) see the
same covariance ``g_k R`` the update uses: the misfit is identified from the residual's mean square
(:func:`fusion_gyrocal.core.noise.identify_noise`), not from its direction, and a covariance screened in
one shape but folded in another would let the adapted factor (:class:`~.adapt.NoiseScale`) that fits the
first weigh the samples wrongly in the second. On the MIMU board about half of the fast residual lies
across the rate, ~4000 times the white noise per axis: the factor fitted to ``R + (a + b |omega|)^2 omega
omega^T`` (``~3000``) made the fast samples ~1e7 times too light in the isotropic update (Issue 12).

Errors in variables: ``H_k`` is evaluated at the measured ``omega_2``, whose white noise is also in the
residual; both update paths remove the resulting pull of ``A`` towards zero (:meth:`ErrorStateEKF.update_block`,
:meth:`ErrorStateEKF.update_one`), so the per-sample and the block modes agree at rest.

Error state (12): ``[dtheta (3, rad, gyro 1 frame), delta_1 (3), delta_2 (3) log-scales, db (3, rad/s)]``.
After every update the error is folded into the nominal estimate (``R <- Exp(dtheta) R``,
``s <- s exp(delta)``, ``b <- b + db``) and reset to zero (multiplicative EKF). Process noise, step
priors and every correction are projected off the directions the :class:`~.hold.ScaleHold` holds.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.model import BIAS, ROT
from ..core.moments import Moments
from ..extras import require

_kalman = require("filterpy.kalman", "track", "the online tracker (GyroPairTracker, gyrocal track)")
ExtendedKalmanFilter, kalman_update = _kalman.ExtendedKalmanFilter, _kalman.update
from ..core.observability import A_of
from ..errors import InputError
from ..lie import exp3
from .hold import DIM, LOG, ScaleHold

REFRESH = 50      # folds between re-linearisations of the gauge projector and the measurement noise
                  # (they change at second order only: the scale factors move by < 1e-3 between them)
_ZERO_X = np.zeros((DIM, 1))
_ZERO_X.flags.writeable = False    # the error state after every fold (read-only: never modified in place)
_ROT_DIAG, _BIAS_DIAG = (np.arange(3), np.arange(3)), (np.arange(9, 12), np.arange(9, 12))
_I3 = np.eye(3)
_I3.flags.writeable = False


# flat indices in G (4, 3, 12) of :func:`_generators`' entries: per G_m (m < 3) and row, the two off-diagonal
# entries of -diag(s1) skew(u_m), diag(s1 u_m) and -A e_m in column 6 + m; then G_3's bias block
_G_ENTRIES = np.array([36 * m + 12 * i + c for m in range(3) for i in range(3)
                       for c in ((1, 2, 3 + i, 6 + m), (0, 2, 3 + i, 6 + m), (0, 1, 3 + i, 6 + m))[i]]
                      + [108 + 12 * i + 9 + i for i in range(3)])


def _generators(R, s1, s2, A) -> np.ndarray:
    """The measurement Jacobian ``dh/dx`` (3, 12) at zero error at the unit rates minus at zero, and at zero (the
    generators ``G`` of :meth:`ErrorStateEKF.generators`), entry by entry from the Jacobian's structure: with
    ``u_m = R diag(1/s2) e_m``, ``G_m = [-diag(s1) skew(u_m), diag(s1 u_m), -A e_m e_m^T, 0]`` and
    ``G_3 = [0, 0, 0, I]``."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()
    a0, a1, a2 = s1.tolist()
    v0, v1, v2 = (1.0 / s2).tolist()
    (A00, A01, A02), (A10, A11, A12), (A20, A21, A22) = A.tolist()
    vals = []
    for (u0, u1, u2), (c0, c1, c2) in (((r00 * v0, r10 * v0, r20 * v0), (A00, A10, A20)),     # u_m, A e_m
                                       ((r01 * v1, r11 * v1, r21 * v1), (A01, A11, A21)),
                                       ((r02 * v2, r12 * v2, r22 * v2), (A02, A12, A22))):
        vals += (a0 * u2, -a0 * u1, a0 * u0, -c0,          # row 0: -s1_0 skew(u)[0, 1:], s1_0 u_0, -A[0, m]
                 -a1 * u2, a1 * u0, a1 * u1, -c1,
                 a2 * u1, -a2 * u0, a2 * u2, -c2)
    G = np.zeros((4, 3, DIM))
    G.reshape(-1)[_G_ENTRIES] = vals + [1.0, 1.0, 1.0]
    return G


def misfit_coefficients(noise_std, A, misfit) -> tuple[float, float, float] | None:
    """``(a, b, 1 / (3 sigma^2))`` of the measurement covariance's factor :func:`inflation` for white noise
    ``noise_std`` (per gyro), ``A`` and the misfit gains ``(a, b)``; None when the misfit is zero."""
    a, b = float(misfit[0]), float(misfit[1])
    if a == b == 0.0:
        return None
    return a, b, 1.0 / (noise_std[0] ** 2 * 3.0 + noise_std[1] ** 2 * float(np.sum(np.square(A))))


def covariance_factors(g, lam):
    """The measurement covariance's factors (B,) of a block, ``max(lambda_j g_k, 1)`` (never below the white
    noise), from the misfit's :func:`inflation` ``g`` (None: white) and the adapted ``lam``
    (:meth:`~.adapt.NoiseScale.factors`), and ``held``: ``max(lambda_j g_k, 1) / (lambda_j g_k)`` (None when no
    sample is held; the argument of :meth:`~.adapt.NoiseScale.learn`)."""
    if g is None:
        return lam, None              # white noise: lam >= 1
    g = g * lam
    if g.min() >= 1.0:
        return g, None
    gs = np.maximum(g, 1.0)
    return gs, gs / g


def inflation(coefficients, w1) -> np.ndarray | None:
    """Per-sample factor ``g_k = 1 + (a + b |omega|)^2 |omega|^2 / (3 sigma^2)`` of the white measurement
    covariance for gyro-1 rates ``w1`` (B, 3) (the module docstring); None for white noise
    (``coefficients`` None: every factor 1)."""
    if coefficients is None:
        return None
    a, b, c = coefficients
    sq = np.einsum("ka,ka->k", w1, w1)
    m = a + b * np.sqrt(sq)
    return 1.0 + c * (m * m) * sq


def _quadratic_3(S, x: float, y: float, z: float) -> float:
    """``r^T S^-1 r`` of ``r = (x, y, z)`` for a symmetric positive 3x3 ``S`` in scalar arithmetic (LDL^T;
    NaN if not positive)."""
    (a, b, c), (_, d, e), (_, _, f) = S.tolist()
    if not a > 0:
        return float("nan")
    l1, l2 = b / a, c / a                       # S = L D L^T, L unit lower triangular
    d2 = d - b * l1
    if not d2 > 0:
        return float("nan")
    l3 = (e - c * l1) / d2
    d3 = f - c * l2 - d2 * l3 * l3
    if not d3 > 0:
        return float("nan")
    y1 = y - l1 * x                             # forward substitution L v = r
    z1 = z - l2 * x - l3 * y1
    return x * x / a + y1 * y1 / d2 + z1 * z1 / d3


# flat indices in a (3, 12) Jacobian of the entries that depend on the sample: per row, -diag(s1) skew(u)
# (two off-diagonal entries), diag(s1 u) (one) and -A diag(omega_2) (three); the rest is constant
_H1_VARYING = np.array([1, 2, 3, 6, 7, 8, 12, 14, 16, 18, 19, 20, 24, 25, 29, 30, 31, 32])


def _one_sample_jacobian() -> np.ndarray:
    """A (3, 12) Jacobian buffer with the constant entries in place: zeros and the bias block (``d/d b = I``)."""
    H = np.zeros((3, DIM))
    H[:, 9:12] = np.eye(3)
    return H


def _projected_cov(std, TT) -> np.ndarray:
    """Independent per-parameter std (DriftNoise, StepPrior) as an error covariance off the held directions."""
    C = np.zeros((DIM, DIM))
    C[_ROT_DIAG] = std.rotation**2                  # (std^2 I on the diagonal blocks)
    C[LOG, LOG] = std.log_scale**2 * TT
    C[_BIAS_DIAG] = std.bias**2
    return C


def _bias_cov(step_prior) -> np.ndarray:
    """The bias part of a :class:`~.config.StepPrior` as an error covariance."""
    C = np.zeros((DIM, DIM))
    C[BIAS, BIAS] = step_prior.bias**2 * np.eye(3)
    return C


class ErrorStateEKF:
    """filterpy's :class:`~filterpy.kalman.ExtendedKalmanFilter` on the error state plus the nominal estimate.

    Ready once constructed: nominal estimate in the hold, error state zero, covariance projected,
    process noise, step prior and measurement noise linearised at the estimate.

    Parameters
    ----------
    hold : ScaleHold
    drift : DriftNoise
        Process noise densities (``Q = q^2 dt``).
    step_prior : StepPrior
        Covariance added by :meth:`open_step`.
    noise_std : (float, float)
        White noise per sample of each gyro (rad/s).
    R, s1, s2, b : the nominal estimate (``R_1_2``, scale factors, combined bias).
    P : ndarray (12, 12)
        Error covariance (projected here).
    t : float
        Time of the estimate (s).
    inflate_s : float
        The covariance is grown by the random walk over this many seconds (a seed that estimated an
        average over a window is inflated to its end).
    misfit : (float, float)
        Gains ``(a, b)`` of the rate-dependent misfit ``(a + b |omega|) omega`` (``NoiseModel.misfit_gain``):
        each sample's measurement covariance is the white one times :meth:`inflation`. ``(0, 0)``: white.
    """

    __slots__ = ("kf", "hold", "R", "s1", "s2", "b", "t", "noise_std", "misfit", "drift", "step_prior",
                 "_T", "_Pi", "_q", "_shock", "_bias_shock", "_G", "_folds", "_H1", "_held", "_mis", "_eiv", "score",
                 "_R_rows", "_gR", "_Qdt", "_H1f", "_H1b", "_eiv_g", "_s12")

    def __init__(self, hold: ScaleHold, drift, step_prior, noise_std, R, s1, s2, b, P, t: float,
                 inflate_s: float = 0.0, misfit=(0.0, 0.0)):
        self.kf = ExtendedKalmanFilter(dim_x=DIM, dim_z=3)
        self.kf.F = np.eye(DIM)
        self.kf.Q = np.zeros((DIM, DIM))
        self.hold, self.drift, self.step_prior = hold, drift, step_prior
        self.noise_std = (float(noise_std[0]), float(noise_std[1]))
        self.misfit = (float(misfit[0]), float(misfit[1]))
        self.R, self.b = np.array(R, dtype=float), np.array(b, dtype=float)
        self.s1, self.s2 = hold.express(s1, s2)
        self._s12 = np.concatenate((self.s1, self.s2))     # [s1; s2] (the fold scales both at once)
        self.t = float(t)
        self._H1 = _one_sample_jacobian()
        self._H1f = self._H1.reshape(-1)           # its flat view (:meth:`innovations` writes through it)
        self._H1b = self._H1[None]                 # as a block of one
        self._bias_shock = _bias_cov(step_prior)  # fixed with the step prior
        self.score = (0.0, 0)
        self._held = hold.held_cov if hold.held_cov.any() else None    # fixed with the hold; None: nothing to add
        self.relinearise()
        P = self.project(P)
        if inflate_s > 0:
            P = P + self.process_noise(inflate_s)
        self.kf.x = np.zeros((DIM, 1))
        self.kf.P = 0.5 * (P + P.T)

    def copy(self, *, drift=None, step_prior=None) -> "ErrorStateEKF":
        """An independent copy (same state and linearisation), with other noise densities if given."""
        new = object.__new__(ErrorStateEKF)
        new.kf = ExtendedKalmanFilter(dim_x=DIM, dim_z=3)
        new.kf.F, new.kf.Q, new.kf.R = np.eye(DIM), self.kf.Q.copy(), self.kf.R.copy()
        new.kf.x, new.kf.P = self.kf.x.copy(), self.kf.P.copy()
        new.hold, new.noise_std, new.misfit, new._mis = self.hold, self.noise_std, self.misfit, self._mis
        new.drift = self.drift if drift is None else drift
        new.step_prior = self.step_prior if step_prior is None else step_prior
        new.R, new.s1, new.s2, new.b, new.t = self.R, self.s1, self.s2, self.b, self.t   # never modified in place
        new._s12 = self._s12
        new._T, new._Pi, new._G, new._folds, new._held = self._T, self._Pi, self._G, self._folds, self._held
        new._H1 = _one_sample_jacobian()
        new._H1f = new._H1.reshape(-1)
        new._H1b = new._H1[None]
        new.score = self.score
        TT = self._T @ self._T.T
        new._q, new._shock = _projected_cov(new.drift, TT), None
        new._Qdt = None
        new._bias_shock, new._eiv = _bias_cov(new.step_prior), self._eiv
        new._R_rows, new._gR, new._eiv_g = self._R_rows, None, None
        return new

    # ------------------------------------------------------------------ linearisation
    @property
    def A(self) -> np.ndarray:
        return A_of(self.R, self.s1, self.s2)

    def relinearise(self) -> None:
        """Gauge projector, process noise, step prior and measurement noise at the current estimate."""
        T = self.hold.projector(self.s1, self.s2)
        Pi = np.eye(DIM)
        Pi[LOG, LOG] = T
        self._T, self._Pi = T, Pi
        TT = T @ T.T
        self._q = _projected_cov(self.drift, TT)          # process noise per second
        self._Qdt = None                                  # (dt, Q) of the last prediction (:meth:`predict_to`)
        self._shock = None                                # the step prior, when a step is suspected (open_step)
        A = self.A                                 # once for everything below
        self.kf.R = self.noise_std[0] ** 2 * _I3 + self.noise_std[1] ** 2 * np.dot(A, A.T)
        self._R_rows = self.kf.R.tolist()          # its entries as floats (the per-sample misfit term)
        self._gR = None                            # (g, R, g R) of the last white sample (:meth:`update_one`)
        self._mis = misfit_coefficients(self.noise_std, A, self.misfit)    # None for white noise
        self._G = _generators(self.R, self.s1, self.s2, A)
        self._eiv = self.eiv_correction(1.0, A)
        self._eiv_g = None                         # (g, eiv / g) of the last sample with g != 1 (update_one)
        self._folds = 0

    def project(self, P) -> np.ndarray:
        """``P`` moved off the held directions, which get the hold's covariance."""
        P = np.dot(np.dot(self._Pi, P), self._Pi.T)     # a new array: updated in place below
        if self._held is not None:
            P += self._held
        P = P + P.T                                     # (a new array: cheaper than buffering the overlap of +=)
        P *= 0.5
        return P

    def process_noise(self, dt: float) -> np.ndarray:
        """Random-walk process noise over ``dt`` seconds, projected off the held directions."""
        return self._q * max(dt, 0.0)

    def linearise(self, w1, w2) -> tuple[np.ndarray, np.ndarray]:
        """Jacobians ``H`` (B, 3, 12) and residuals ``r = omega_1 - A omega_2 - b`` (B, 3) of a block.

        ``H_k = sum_m y_k[m] G[m]`` for ``y_k = [omega_2(k); 1]`` (``H`` is affine in ``omega_2``) with the
        :meth:`generators` ``G``.
        """
        G = self.generators()
        H = (w2 @ G[:3].reshape(3, 3 * DIM)).reshape(w2.shape[0], 3, DIM) + G[3]
        return H, w1 - w2 @ self.A.T - self.b

    def generators(self) -> np.ndarray:
        """``G`` (4, 3, 12) with ``H(omega_2) = sum_m omega_2[m] G[m] + G[3]``, once per estimate."""
        if self._G is None:
            self._G = _generators(self.R, self.s1, self.s2, self.A)
        return self._G

    def inflation(self, w1) -> np.ndarray | None:
        """Per-sample factor ``g_k >= 1`` of the white measurement covariance for gyro-1 rates ``w1`` (B, 3)
        at the current estimate (:func:`inflation`); None when the noise is white (every factor 1)."""
        return inflation(self._mis, w1)

    def eiv_correction(self, n: float, A=None) -> np.ndarray:
        """``n sigma_2^2 sum_m G_m^T W A e_m`` (12,): the expectation of ``-sum_k H_k^T W r_k`` over ``n``
        (weighted) samples that gyro 2's white noise causes, being in the Jacobian ``H_k`` (evaluated at the
        measured ``omega_2``) as well as in the residual ``r_k`` (:meth:`update_block`); ``A``: :attr:`A`
        when the caller has it."""
        WA = np.dot(np.linalg.inv(self.kf.R), self.A if A is None else A)
        return n * self.noise_std[1] ** 2 * np.dot(WA.T.ravel(), self.generators()[:3].reshape(3 * 3, DIM))

    def innovation_d2(self, H, r, g=None) -> np.ndarray:
        """Per-sample ``r_k^T (H_k P H_k^T + g_k R)^-1 r_k`` with ``g_k`` (B,) the factor of the measurement
        covariance the update uses (:meth:`inflation` times the adapted factor of :class:`~.adapt.NoiseScale`;
        None: 1)."""
        S = (H @ self.kf.P) @ np.swapaxes(H, 1, 2)
        if g is not None:
            S += self.kf.R * g[:, None, None]          # one (B, 3, 3) temporary
        else:
            S += self.kf.R
        return np.einsum("ka,ka->k", r, np.linalg.solve(S, r[:, :, None])[:, :, 0])

    # ------------------------------------------------------------------ filter steps
    def predict_to(self, t: float) -> None:
        """Predict to time ``t`` (covariance grows by the random walk over ``t - self.t``)."""
        dt = t - self.t
        if not (math.isfinite(t) and dt >= 0):
            raise InputError(f"t: expected finite, non-decreasing times, got {t!r} after {self.t!r} "
                             f"(a step of {dt:.6g} s)")
        if dt > 0:
            # filterpy's predict with F = I and the error state at zero (reset by every fold) is exactly
            # P + Q: done directly, without its per-call copies of the prior (the per-sample hot path)
            Q = self._Qdt
            if Q is None or Q[0] != dt:        # a steady sample rate: the same Q = process_noise(dt) again
                Q = self._Qdt = (dt, self._q * dt)
            self.kf.Q = Q = Q[1]               # never modified in place (a new P below)
            self.kf.P = self.kf.P + Q
            self.t = float(t)

    def innovations(self, w1, w2, lam=None) -> tuple:
        """A block's ``(H, r, d2, g, held)`` at the current estimate: Jacobians (B, 3, 12) and residuals (B, 3)
        (:meth:`linearise`), ``d2`` the B floats ``r_k^T S_k^-1 r_k`` (:meth:`innovation_d2`), ``g`` the factors
        of the measurement covariance the update uses (B,) (:meth:`inflation` times the adapted factors ``lam``
        (B,) of :class:`~.adapt.NoiseScale`, never below 1: :func:`covariance_factors`; None: every factor 1) and
        ``held`` (:func:`covariance_factors`).

        A block of one sample (the per-sample mode) is computed in scalar arithmetic with a reused Jacobian
        buffer (numpy's per-call cost on one sample is several times the arithmetic); the same values.
        """
        if len(w1) == 1:
            return self._innovations_one(w1, w2[0], 1.0 if lam is None else lam[0])
        H, r = self.linearise(w1, w2)
        g, held = self.inflation(w1), None
        if lam is not None:
            g, held = covariance_factors(g, lam)
        return H, r, self.innovation_d2(H, r, g).tolist(), g, held

    def _innovations_one(self, w1, w2, lam: float) -> tuple:
        """:meth:`innovations` of a block of one sample (``w1`` (1, 3), ``w2`` (3,)) with the adapted factor ``lam``
        (scalar arithmetic)."""
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self.R.tolist()
        a0, a1, a2 = self.s1.tolist()
        c0, c1, c2 = self.s2.tolist()
        b0, b1, b2 = self.b.tolist()
        x0, x1, x2 = w2.tolist()
        v0, v1, v2 = x0 / c0, x1 / c1, x2 / c2                  # R diag(1/s2) omega_2
        u0, u1, u2 = r00 * v0 + r01 * v1 + r02 * v2, r10 * v0 + r11 * v1 + r12 * v2, r20 * v0 + r21 * v1 + r22 * v2
        A00, A01, A02 = a0 * r00 / c0, a0 * r01 / c1, a0 * r02 / c2     # A = diag(s1) R diag(1/s2)
        A10, A11, A12 = a1 * r10 / c0, a1 * r11 / c1, a1 * r12 / c2
        A20, A21, A22 = a2 * r20 / c0, a2 * r21 / c1, a2 * r22 / c2
        H = self._H1                               # its varying entries, written through the flat view
        self._H1f[_H1_VARYING] = (a0 * u2, -a0 * u1, a0 * u0, A00 * -x0, A01 * -x1, A02 * -x2,   # row 0
                                      -a1 * u2, a1 * u0, a1 * u1, A10 * -x0, A11 * -x1, A12 * -x2,   # row 1
                                      a2 * u1, -a2 * u0, a2 * u2, A20 * -x0, A21 * -x1, A22 * -x2)   # row 2
        (y0, y1, y2), = w1.tolist()
        # A omega_2 through numpy's product, as in :meth:`linearise` (BLAS fuses the multiply-adds)
        d0, d1, d2 = np.dot(np.array((A00, A01, A02, A10, A11, A12, A20, A21, A22)).reshape(3, 3), w2).tolist()
        e0, e1, e2 = y0 - d0 - b0, y1 - d1 - b1, y2 - d2 - b2        # omega_1 - A omega_2 - b
        S = np.dot(np.dot(H, self.kf.P), H.T)     # np.dot: less call overhead than @ on tiny arrays
        if self._mis is None:
            g = lam
        else:
            a, b, c = self._mis
            sq = y0 * y0 + y1 * y1 + y2 * y2
            m = a + b * math.sqrt(sq)
            g = (1.0 + c * (m * m) * sq) * lam
        gs = g if g > 1.0 else 1.0                 # the covariance is never below the white noise
        if gs == 1.0:
            S += self.kf.R
        else:
            R = self.kf.R
            gR = gs * R
            S += gR
            self._gR = (gs, R, gR)                 # the update's measurement covariance (update_one)
        return (self._H1b, np.array((e0, e1, e2))[None], (_quadratic_3(S, e0, e1, e2),), (gs,),
                None if g >= 1.0 else (1.0 / g,))

    def update_one(self, H, r, g: float = 1.0) -> None:
        """One sample's update through filterpy's Kalman update (Joseph form), then the fold; ``g`` is the
        sample's :meth:`inflation`.

        The errors-in-variables pull is removed as in :meth:`update_block`: the information form of the
        update is ``x = P_post (H^T W r / g + c / g)`` with ``c`` the one-sample :meth:`eiv_correction`, so
        ``P_post c / g`` is added to filterpy's state (``c`` is re-linearised with the measurement noise,
        every ``REFRESH`` folds).
        """
        R = self.kf.R
        if g != 1.0:
            c = self._gR               # g R of this sample when innovations made it (white noise)
            R = c[2] if c is not None and c[0] == g and c[1] is R else g * R
        x, P = kalman_update(self.kf.x, self.kf.P, r[:, None], R, H)
        self.kf.P = P
        if g == 1.0:
            c = self._eiv
        else:
            c = self._eiv_g
            if c is None or c[0] != g:
                c = self._eiv_g = (g, self._eiv / g)
            c = c[1]
        self._fold(x[:, 0] + np.dot(P, c), project=self._held is not None)   # filterpy's x (12, 1), flat

    def update_block(self, w1, w2, keep, g=None) -> float:
        """ONE update from the samples ``keep`` of a block through their moments, then the fold.

        With ``Y = sum_k y_k y_k^T / g_k`` of ``y_k = [omega_1; omega_2; 1]`` (from count, mean and centred
        scatter, weighted by ``1 / g_k`` when the covariance of sample ``k`` is ``g_k R``, :meth:`inflation`),
        ``Lambda = sum_mn Y_mn G_m^T W G_n`` and ``eta = sum_m G_m^T W L Y[:, m]`` where
        ``r_k = L y_k``, ``L = [I, -A, -b]``, ``W = R^-1``: exactly the stacked update of the block's
        samples. It is applied through filterpy as a whitened 12-d pseudo-measurement
        (``H_p^T H_p = Lambda``, ``H_p^T z_p = eta``, ``R = I``).

        Errors in variables: ``H_k`` is evaluated at the measured ``omega_2``, whose white noise also enters
        ``r_k``; ``E[H_k^T W r_k]`` then holds ``-sigma_2^2 sum_m G_m^T W A e_m`` per sample, a pull of ``A``
        towards zero that dominates at rest (the measured ``omega_2`` is gyro 2's bias plus noise). It is
        removed from ``eta`` (the update is the stacked one plus ``P_post`` times that correction,
        :meth:`eiv_correction`); the per-sample path (:meth:`update_one`) removes the same.

        Returns
        -------
        float
            The block's innovation statistic ``r^T S^-1 r`` (chi-square with 3 n dof).
        """
        A, b, P, G = self.A, self.b, self.kf.P, self.generators()
        B = w1.shape[0]
        if g is None:
            m = Moments.from_samples(w1, w2, mask=None if keep.all() else keep, chunk_size=B)
            n, mu1, mu2, scatter = m.count, m.mean_1, m.mean_2, m.scatter
        else:                                                # weights 1 / g_k: weighted count, mean, scatter
            v = np.where(keep, 1.0 / g, 0.0)
            y = np.hstack([w1, w2])
            n = float(v.sum())
            mu = (v @ y) / n
            yc = y - mu
            scatter = (yc * v[:, None]).T @ yc
            mu1, mu2 = mu[:3], mu[3:]
        W = np.linalg.inv(self.kf.R)
        rbar = mu1 - A @ mu2 - b                             # mean residual L ybar
        Lc = np.hstack([np.eye(3), -A])                      # centred part of L
        Yp = np.empty((4, 4))                                # Y restricted to the regressors [omega_2; 1] of H
        Yp[:3, :3] = scatter[3:, 3:] + n * np.outer(mu2, mu2)
        Yp[:3, 3] = Yp[3, :3] = n * mu2
        Yp[3, 3] = n
        Gf = G.reshape(12, DIM)
        Lam = Gf.T @ np.kron(Yp, W) @ Gf
        LY = np.empty((3, 4))                                # L Y[:, m'] for m' over [omega_2; 1]
        LY[:, :3] = Lc @ scatter[:, 3:] + n * np.outer(rbar, mu2)
        LY[:, 3] = n * rbar
        eta = np.einsum("mai,am->i", G, W @ LY)
        # errors in variables: gyro 2's white noise n_2 is in H_k as well as in r_k, so E[H_k^T W r_k] holds
        # -sigma_2^2 sum_m G_m^T W A e_m, which shrinks A towards zero wherever the motion is below the noise
        # (at rest: tens of % in a minute on a real board); that expectation is removed
        eta += self.eiv_correction(n)
        rWr = float(np.trace(W @ (Lc @ scatter @ Lc.T)) + n * rbar @ W @ rbar)
        # block innovation statistic (Woodbury): r^T S^-1 r = rWr - eta^T P (I + Lam P)^-1 eta
        stat = rWr - float(eta @ P @ np.linalg.solve(np.eye(DIM) + Lam @ P, eta))
        lam, V = np.linalg.eigh(0.5 * (Lam + Lam.T))
        ok = lam > 1e-12 * max(lam.max(), 1e-300)
        sq = np.sqrt(np.where(ok, lam, 0.0))
        Hp = sq[:, None] * V.T
        zp = np.where(ok, (V.T @ eta) / np.where(ok, sq, 1.0), 0.0)
        # the block's score test: Cov zp = I + Hp P Hp^T under the model (independent samples)
        self.score = (float(zp @ np.linalg.solve(np.eye(DIM) + Hp @ P @ Hp.T, zp)), int(ok.sum()))
        self.kf.update(zp[:, None], HJacobian=lambda x: Hp, Hx=lambda x: Hp @ x, R=np.eye(DIM))
        self.fold()
        return stat

    def fold(self) -> None:
        """Fold the error state into the nominal estimate and reset it (multiplicative EKF).

        The correction is projected off the held directions (exact for the linear conditions of
        a fixed scale and of the pairs' log-means). Every ``REFRESH`` folds the nonlinear gauge is
        re-imposed and everything linearised is re-linearised at the new estimate.
        """
        self._fold(self.kf.x[:, 0])

    def _fold(self, x, project: bool = True) -> None:
        """:meth:`fold` of the error state ``x`` (12,) (the per-sample path passes its own, flat).

        ``project=False`` (the per-sample path, no hold covariance) skips the projection of ``P``
        between re-linearisations: a Kalman update keeps ``P`` in the projector's range (its gain
        ``P H^T S^-1`` lies there, and so does the projected process noise), so that projection only
        removed rounding; it is done at every re-linearisation instead (results equal to ~1e-15).
        """
        e = np.exp(np.dot(self._T, x[LOG]))      # never move a held direction
        t0, t1, t2 = x[ROT].tolist()
        self.R = np.dot(exp3(t0, t1, t2), self.R)
        self._s12 = s = self._s12 * e             # s1 and s2: views of it
        self.s1, self.s2 = s[:3], s[3:]
        self.b = self.b + x[BIAS]
        self.kf.x = _ZERO_X            # filterpy's updates return a new state: sharing the zero is safe
        if project:
            self.kf.P = self.project(self.kf.P)
        self._G = None
        self._folds += 1
        if self._folds >= REFRESH:
            self.s1, self.s2 = self.hold.express(self.s1, self.s2)
            self._s12 = np.concatenate((self.s1, self.s2))
            self.relinearise()
            if not project:
                self.kf.P = self.project(self.kf.P)      # with the new projector

    def open_step(self, bias_only: bool = False) -> None:
        """Add the step prior to the covariance (a step change is suspected); ``bias_only``: its bias part
        alone (a step of the combined bias, e.g. a gravity-dependent bias after a change of pose)."""
        if bias_only:
            shock = self._bias_shock
        else:
            if self._shock is None:
                self._shock = _projected_cov(self.step_prior, self._T @ self._T.T)
            shock = self._shock
        self.kf.P = self.project(self.kf.P + shock)

    # ------------------------------------------------------------------ state
    def state(self) -> tuple:
        """``(R, s1, s2, b, P, t)`` (copies) for :meth:`restore`."""
        return self.R.copy(), self.s1.copy(), self.s2.copy(), self.b.copy(), self.kf.P.copy(), self.t

    def restore(self, state: tuple) -> None:
        """Return to a :meth:`state` (error zero, everything re-linearised there)."""
        R, s1, s2, b, P, t = state
        self.R, self.s1, self.s2, self.b = R, s1, s2, b
        self._s12 = np.concatenate((s1, s2))
        self.kf.x = np.zeros((DIM, 1))
        self.kf.P = P
        self.t = t
        self.relinearise()
