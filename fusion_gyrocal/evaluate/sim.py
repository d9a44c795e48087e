"""The paper's simulation protocol and its error metrics (Section V).

* :class:`HumanMotion`: smooth, band-limited, human-like angular velocity that can be
  evaluated at any instant (so streams at different rates and clocks can be drawn from it).
* :func:`simulate_pair`: gyro 1 and gyro 2 measurements from a true rate history following
  Eq. (1): ``omega_i_meas = S_i omega_i + b_i + n_i`` with white noise (0.1 deg/s), a bias
  random walk (57.3 micro-deg/s per step, Eq. 35) and optional skew (upper-triangular
  ``S_i`` with off-diagonals drawn from N(0, 2.357e-4^2)).
* :func:`load_broad_rates`: real hand-held gyro motion from the BROAD dataset to drive the
  simulation with recorded motion (as the paper did with its own human motion); :func:`load_broad_pair`: a BROAD
  trial's IMU against the rate differentiated from its motion capture, a real pair.
* :func:`rotation_error` and :func:`scale_error`: the paper's two error metrics (Eq. 37-38).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..core.moments import as_rates

if TYPE_CHECKING:
    from ..online.history import PairTruth

DEG = np.pi / 180.0
PAPER_RATE_HZ = 100.0
PAPER_NOISE_STD = 0.1 * DEG            # rad/s per sample
PAPER_BIAS_WALK_STD = 57.3e-6 * DEG    # rad/s per step
PAPER_SKEW_STD = 2.357e-4


class HumanMotion:
    """Band-limited human-like angular velocity, a random sum of sinusoids per axis.

    Parameters
    ----------
    rms : float or array_like (3,)
        Target RMS rate per axis (rad/s).
    max_freq_hz : float
        Highest frequency component (hand-held motion stays below ~3 Hz).
    n_components : int
        Sinusoids per axis.
    rng : numpy.random.Generator or int, optional
    """

    def __init__(self, rms=1.0, *, max_freq_hz: float = 2.5, n_components: int = 24, rng=None):
        rng = np.random.default_rng(rng)
        self.freq = rng.uniform(0.05, max_freq_hz, size=(3, n_components))
        self.phase = rng.uniform(0, 2 * np.pi, size=(3, n_components))
        amp = 1.0 / np.sqrt(self.freq)
        amp /= np.sqrt(0.5 * (amp**2).sum(axis=1, keepdims=True))  # unit RMS per axis
        self.amp = amp * np.broadcast_to(np.asarray(rms, dtype=float), (3,))[:, None]

    def __call__(self, t) -> np.ndarray:
        """Angular velocity (N, 3) in rad/s at times ``t`` (s), in gyro 1's frame."""
        t = np.asarray(t, dtype=float)
        out = np.empty((t.size, 3))
        for i in range(3):
            out[:, i] = np.sin(np.outer(t, 2 * np.pi * self.freq[i]) + self.phase[i]) @ self.amp[i]
        return out


@dataclass(frozen=True)
class SimulatedPair:
    """Simulated measurements with their ground truth.

    ``omega_1``/``omega_2`` are the measurements; ``R_1_2``, ``scale_1``, ``scale_2`` the truth;
    ``S_1``/``S_2`` the full (possibly skewed, upper-triangular) intrinsic matrices;
    ``bias_1``/``bias_2`` the (N, 3) bias histories; ``omega_true_1`` gyro 1's true rate.
    """

    t: np.ndarray
    omega_1: np.ndarray
    omega_2: np.ndarray
    omega_true_1: np.ndarray
    R_1_2: np.ndarray
    scale_1: np.ndarray
    scale_2: np.ndarray
    S_1: np.ndarray
    S_2: np.ndarray
    bias_1: np.ndarray
    bias_2: np.ndarray
    noise_std: tuple

    @property
    def A(self) -> np.ndarray:
        return self.S_1 @ self.R_1_2 @ np.linalg.inv(self.S_2)

    @property
    def bias(self) -> np.ndarray:
        """Mean combined bias ``b_1 - A b_2`` over the run (Eq. 5)."""
        return self.bias_1.mean(axis=0) - self.A @ self.bias_2.mean(axis=0)


def random_rotation(rng=None, *, angle_deg: float | None = None) -> np.ndarray:
    """A random rotation matrix (uniform, or with the given angle about a random axis)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(rng)
    if angle_deg is None:
        return Rotation.random(random_state=rng).as_matrix()
    axis = rng.standard_normal(3)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle_deg * DEG).as_matrix()


def general_rotation(rng=None, min_angle_deg: float = 20.0) -> np.ndarray:
    """A uniformly random rotation redrawn until no axis of one frame is within ``min_angle_deg`` of
    (anti)parallel to an axis of the other: the general configuration of Lemma 4."""
    rng = np.random.default_rng(rng)
    cos_max = np.cos(np.deg2rad(min_angle_deg))
    while True:
        R = random_rotation(rng)
        if np.abs(R).max() < cos_max:
            return R


def simulate_pair(omega_true_1=None, *, n: int = 6000, rate_hz: float = PAPER_RATE_HZ, R_1_2=None,
                  scale_1=(1.0, 1.0, 1.0), scale_2=(1.0, 1.0, 1.0), noise_std=PAPER_NOISE_STD,
                  bias_walk_std: float = PAPER_BIAS_WALK_STD, bias_1=None, bias_2=None,
                  skew_std: float = 0.0, rms=1.0, flex_deg: float = 0.0, flex_quantile: float = 0.9,
                  rng=None) -> SimulatedPair:
    """Simulate a rigid gyro pair following the paper's protocol (Section V).

    Parameters
    ----------
    omega_true_1 : array_like (N, 3), optional
        True angular velocity in gyro 1's frame (rad/s). Default: :class:`HumanMotion` with
        ``rms`` sampled at ``rate_hz`` for ``n`` samples.
    R_1_2 : array_like (3, 3), optional
        True rotation (the paper's C, Eq. 2). Default: a random rotation.
    scale_1, scale_2 : array_like (3,)
        True scale factors (diagonals of S_i, Eq. 9).
    noise_std : float or (float, float)
        White noise standard deviation per sample (rad/s) for gyro 1 and 2.
    bias_walk_std : float
        Bias random-walk step standard deviation (rad/s per step, Eq. 35).
    bias_1, bias_2 : array_like (3,), optional
        Initial biases (rad/s). Default: drawn from N(0, (0.5 deg/s)^2).
    skew_std : float
        Standard deviation of the upper off-diagonal skew terms of S_i (the paper: 2.357e-4).
    flex_deg : float
        Device flex: above the ``flex_quantile`` of the rate norm the extrinsic bends by up to
        ``flex_deg`` degrees (Section VI.C); 0 for a rigid pair.
    rng : numpy.random.Generator or int, optional
    """
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(rng)
    if omega_true_1 is None:
        t = np.arange(n) / rate_hz
        omega_true_1 = HumanMotion(rms, rng=rng)(t)
    else:
        omega_true_1 = np.asarray(omega_true_1, dtype=float)
        n = omega_true_1.shape[0]
        t = np.arange(n) / rate_hz
    R = random_rotation(rng) if R_1_2 is None else np.asarray(R_1_2, dtype=float)
    s1, s2 = np.asarray(scale_1, float), np.asarray(scale_2, float)
    S = []
    for s in (s1, s2):
        Si = np.diag(s)
        if skew_std > 0:
            iu = np.triu_indices(3, 1)
            Si[iu] = rng.normal(0.0, skew_std, size=3)
        S.append(Si)
    sig = np.broadcast_to(np.asarray(noise_std, float), (2,))
    biases = []
    for b0 in (bias_1, bias_2):
        b0 = rng.normal(0, 0.5 * DEG, 3) if b0 is None else np.asarray(b0, float)
        walk = np.cumsum(rng.normal(0, bias_walk_std, (n, 3)), axis=0) if bias_walk_std > 0 else 0.0
        biases.append(b0 + walk)
    omega_true_2 = omega_true_1 @ R  # R^T omega_1, row-wise
    if flex_deg:
        # device flex (Section VI.C): above the rate quantile the extrinsic bends by up to flex_deg about a
        # fixed axis, smoothly with the excess rate, with onset/settle over a few samples
        speed = np.linalg.norm(omega_true_1, axis=1)
        thr = np.quantile(speed, flex_quantile)
        amount = np.clip((speed - thr) / max(speed.max() - thr, 1e-12), 0.0, 1.0) ** 0.5
        amount = np.convolve(amount, np.ones(5) / 5, mode="same")
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        bend = Rotation.from_rotvec(np.outer(amount * flex_deg * DEG, axis)).as_matrix()  # R(t) = Exp(bend) R
        omega_true_2 = np.einsum("nji,nj->ni", bend @ R, omega_true_1)
    w1 = omega_true_1 @ S[0].T + biases[0] + rng.normal(0, sig[0], (n, 3))
    w2 = omega_true_2 @ S[1].T + biases[1] + rng.normal(0, sig[1], (n, 3))
    return SimulatedPair(t, w1, w2, omega_true_1, R, s1, s2, S[0], S[1],
                         np.broadcast_to(biases[0], (n, 3)), np.broadcast_to(biases[1], (n, 3)),
                         (float(sig[0]), float(sig[1])))


class SimulatedStreams(NamedTuple):
    """Two gyro streams on their own clocks (unpacks as ``t_1, omega_1, t_2, omega_2, R_1_2, motion``)."""

    t_1: np.ndarray
    omega_1: np.ndarray
    t_2: np.ndarray
    omega_2: np.ndarray
    R_1_2: np.ndarray
    motion: HumanMotion


def simulate_streams(rng=None, *, rate_1: float = 100.0, rate_2: float = 200.0, duration: float = 60.0,
                     offset: float = 0.1, jitter: float = 0.25, noise=PAPER_NOISE_STD, rms=1.0,
                     scale_std: float = 0.01, bias_std: float = 0.5 * DEG) -> SimulatedStreams:
    """Two gyros sampled on their own clocks from one continuous :class:`HumanMotion`.

    Gyro 2's sample at its own time ``s`` happened at ``s + offset`` on gyro 1's clock (the
    library's sign of ``time_offset_s``). Sample instants are jittered by up to ``jitter``
    periods (uniform) and recorded exactly; gyro 2 is rotated by a random rotation and scaled by
    ``1 + N(0, scale_std^2)`` per axis; both carry a bias ``N(0, bias_std^2)`` and white noise.
    """
    rng = np.random.default_rng(rng)
    motion = HumanMotion(rms, rng=rng)
    R = random_rotation(rng)
    s2 = 1.0 + scale_std * rng.standard_normal(3)
    b1, b2 = rng.normal(0.0, bias_std, 3), rng.normal(0.0, bias_std, 3)
    n1, n2 = int(duration * rate_1), int(duration * rate_2)
    t1 = (np.arange(n1) + rng.uniform(-jitter, jitter, n1)) / rate_1
    t2 = rng.uniform(0.0, 1.0) / rate_2 - offset + (np.arange(n2) + rng.uniform(-jitter, jitter, n2)) / rate_2
    w1 = motion(t1) + b1 + rng.normal(0.0, noise, (n1, 3))
    w2 = (motion(t2 + offset) @ R) * s2 + b2 + rng.normal(0.0, noise, (n2, 3))
    return SimulatedStreams(t1, w1, t2, w2, R, motion)


def rotation_error(R_hat, R_true) -> float:
    """``||Log(R_hat R_true^T)||`` in rad (Eq. 37)."""
    from scipy.spatial.transform import Rotation

    return float(np.linalg.norm(Rotation.from_matrix(np.asarray(R_hat) @ np.asarray(R_true).T).as_rotvec()))


def scale_error(scale_1_hat, scale_2_hat, scale_1, scale_2) -> float:
    """The paper's scale error (Eq. 38): both gyros' scales normalised by gyro 1's x scale,
    difference norm divided by sqrt(5)."""
    est = np.concatenate([scale_1_hat, scale_2_hat]) / scale_1_hat[0]
    tru = np.concatenate([scale_1, scale_2]) / scale_1[0]
    return float(np.linalg.norm(est - tru) / np.sqrt(5.0))


def shared_data_dir() -> Path:
    """Where the real recordings live: ``$FUSION_GYROCAL_DATA``, else ``../shared/data`` beside the
    repository (found from the working directory or from a source checkout of the package).

    The folder may not exist (a user's own clone); callers check ``.exists()``.
    """
    import os

    env = os.environ.get("FUSION_GYROCAL_DATA")
    if env:
        return Path(env)
    here = Path(__file__).resolve()
    candidates = [Path.cwd().resolve().parent / "shared" / "data", Path.cwd().resolve() / "shared" / "data",
                  here.parents[2] / "shared" / "data"]
    return next((c for c in candidates if c.exists()), candidates[-1])


def load_broad_rates(trial: str = "06_undisturbed_fast_rotation_A", *, data_dir=None,
                     movement_only: bool = True) -> tuple[np.ndarray, float]:
    """Recorded hand-held gyro rates (rad/s) and the sample rate (Hz) from BROAD (CC BY 4.0).

    Laidig et al., "BROAD - A Benchmark for Robust Inertial Orientation Estimation", Data 6(7):72, 2021.
    """
    from scipy.io import loadmat

    root = Path(data_dir) if data_dir is not None else shared_data_dir()
    path = root / "broad_handheld" / "data_mat" / f"{trial}.mat"
    if not path.exists():
        from ..errors import FormatError
        raise FormatError(f"BROAD trial not found: expected {path}")
    d = loadmat(path, squeeze_me=True)
    gyr = np.asarray(d["imu_gyr"], dtype=float)
    if movement_only:
        gyr = gyr[np.asarray(d["movement"], dtype=bool)]
    return gyr, float(d["sampling_rate"])


class BroadPair(NamedTuple):
    """A BROAD trial as a gyro pair (:func:`load_broad_pair`)."""

    gyr: np.ndarray        #: (N, 3) the IMU's gyro (rad/s)
    mocap: np.ndarray      #: (N, 3) body rate differentiated from motion capture (rad/s; NaN where missing)
    rest: np.ndarray       #: (N,) bool, the trial's rest stretches (not ``movement``)
    rate_hz: float


def load_broad_pair(trial: str, *, data_dir=None) -> BroadPair:
    """A BROAD trial's IMU gyro against the body rate differentiated from its motion-capture orientation
    (``log(q_k^-1 q_{k+1}) rate``, NaN where either quaternion is missing), on the same samples: a real pair whose
    second gyro is not white (Laidig et al., Data 6(7):72, 2021; CC BY 4.0)."""
    from scipy.io import loadmat
    from scipy.spatial.transform import Rotation

    root = Path(data_dir) if data_dir is not None else shared_data_dir()
    path = root / "broad_handheld" / "data_mat" / f"{trial}.mat"
    if not path.exists():
        from ..errors import FormatError
        raise FormatError(f"BROAD trial not found: expected {path}")
    d = loadmat(path, squeeze_me=True)
    fs, quat = float(d["sampling_rate"]), np.asarray(d["opt_quat"], dtype=float)
    ok = np.isfinite(quat).all(axis=1)
    R = Rotation.from_quat(np.where(ok[:, None], quat, [1.0, 0.0, 0.0, 0.0])[:, [1, 2, 3, 0]])
    mocap = np.full((len(quat), 3), np.nan)
    mocap[:-1] = (R[:-1].inv() * R[1:]).as_rotvec() * fs
    mocap[:-1][~(ok[:-1] & ok[1:])] = np.nan
    return BroadPair(np.asarray(d["imu_gyr"], dtype=float), mocap, ~np.asarray(d["movement"], dtype=bool), fs)


def simulate_drifting_pair(t, R_1_2, scale_1, scale_2, *, bias_1=None, bias_2=None, noise_std=0.1 * np.pi / 180,
                           omega_true_1=None, rms=1.0, rng=None) -> tuple[np.ndarray, np.ndarray, PairTruth]:
    """Simulate a pair whose calibration changes over time (the paper's Eq. 1 per sample).

    Parameters
    ----------
    t : array_like (N,)
        Sample times (s).
    R_1_2 : array_like (3, 3) or (N, 3, 3)
        True rotation per sample.
    scale_1, scale_2 : array_like (3,) or (N, 3)
        True scale factors per sample.
    bias_1, bias_2 : array_like (3,) or (N, 3), optional
        True biases per sample (rad/s); default zero.
    noise_std : float or (float, float)
        White noise per sample (rad/s).
    omega_true_1 : array_like (N, 3), optional
        True rate in gyro 1's frame (rad/s), e.g. recorded motion from
        :func:`fusion_gyrocal.evaluate.sim.load_broad_rates`. Default: :class:`fusion_gyrocal.evaluate.sim.HumanMotion`.
    rms : float
        RMS rate of the default human-like motion (rad/s per axis).
    rng : numpy.random.Generator or int, optional

    Returns
    -------
    omega_1, omega_2 : ndarray (N, 3)
    truth : PairTruth
    """
    from ..evaluate.sim import HumanMotion

    rng = np.random.default_rng(rng)
    t = np.asarray(t, dtype=float)
    n = t.shape[0]
    R = np.broadcast_to(np.asarray(R_1_2, float), (n, 3, 3))
    s1 = np.broadcast_to(np.asarray(scale_1, float), (n, 3))
    s2 = np.broadcast_to(np.asarray(scale_2, float), (n, 3))
    b1 = np.broadcast_to(np.zeros(3) if bias_1 is None else np.asarray(bias_1, float), (n, 3))
    b2 = np.broadcast_to(np.zeros(3) if bias_2 is None else np.asarray(bias_2, float), (n, 3))
    sig = np.broadcast_to(np.asarray(noise_std, float), (2,))
    if omega_true_1 is None:
        w_true_1 = HumanMotion(rms, rng=rng)(t)
    else:
        w_true_1 = as_rates("omega_true_1", omega_true_1, length=n).astype(float)
    w_true_2 = np.einsum("kji,kj->ki", R, w_true_1)          # R^T omega_1
    w1 = s1 * w_true_1 + b1 + rng.normal(0, sig[0], (n, 3))
    w2 = s2 * w_true_2 + b2 + rng.normal(0, sig[1], (n, 3))
    A = (s1[:, :, None] * R) / s2[:, None, :]
    bias = b1 - np.einsum("kij,kj->ki", A, b2)
    from ..online.history import PairTruth

    return w1, w2, PairTruth(R, s1, s2, bias)


def bend_with_rate(sim: SimulatedPair, *, start: float = 2.5, full: float = 5.0, max_deg: float = 1.0, axis=None,
                   rng=None) -> tuple[SimulatedPair, np.ndarray]:
    """Make gyro 2 of a simulated pair see a mounting that bends smoothly with the rate (device flex).

    The bending angle grows with gyro 1's true rate norm ``|omega|`` as a smoothstep: 0 up to
    ``start`` rad/s, ``max_deg`` degrees from ``full`` rad/s on (capped: a mounting bent to its stop),
    ``angle = max_deg (3 x^2 - 2 x^3)`` with ``x = (|omega| - start) / (full - start)`` in between. The
    mounting is ``R_1_2(k) = Exp(angle_k u) R_1_2`` about a fixed unit axis ``u`` in gyro 1's frame and
    gyro 2 measures ``S_2 R_1_2(k)^T omega_1(k)`` plus its bias and noise (quasi-static bending: the
    bending rate itself is not added). The residual of the rigid model is then
    ``(Exp(angle u) - I) R_1_2 omega_2 ~ angle u x omega_1``: perpendicular to the rate and zero below
    ``start``. Use enough fast motion (``simulate_pair(rms=...)``) for samples above ``start``.

    Parameters
    ----------
    sim : SimulatedPair
        A rigid simulation (:func:`simulate_pair`); its ``R_1_2`` stays the truth (the unbent mounting).
    start, full : float
        Rate norms (rad/s) where the bend starts and where it reaches ``max_deg`` (``0 <= start < full``).
    max_deg : float
        Largest bending angle (degrees).
    axis : array_like (3,), optional
        Bending axis in gyro 1's frame (normalised). Default: a random direction drawn from ``rng``.
    rng : numpy.random.Generator or int, optional

    Returns
    -------
    (SimulatedPair, ndarray (N,))
        The pair with gyro 2 bent, and the bending angle (rad) of each sample.

    Raises
    ------
    InputError
        ``start``/``full`` not ``0 <= start < full``, or a zero or non-finite axis.
    """
    from scipy.spatial.transform import Rotation

    from dataclasses import replace

    from ..errors import InputError

    if not (np.isfinite(start) and np.isfinite(full) and 0.0 <= start < full):
        raise InputError(f"start, full: expected rate norms 0 <= start < full (rad/s), got {start!r}, {full!r}")
    if axis is None:
        axis = np.random.default_rng(rng).standard_normal(3)
    u = np.asarray(axis, dtype=float).reshape(-1)
    if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) == 0.0:
        raise InputError(f"axis: expected a finite non-zero 3-vector, got {axis!r}")
    u = u / np.linalg.norm(u)
    x = np.clip((np.linalg.norm(sim.omega_true_1, axis=1) - start) / (full - start), 0.0, 1.0)
    angle = max_deg * DEG * x * x * (3.0 - 2.0 * x)
    R_k = Rotation.from_rotvec(angle[:, None] * u) * Rotation.from_matrix(sim.R_1_2)
    bent = R_k.inv().apply(sim.omega_true_1) - sim.omega_true_1 @ sim.R_1_2   # R_1_2(k)^T omega_1 - R^T omega_1
    return replace(sim, omega_2=sim.omega_2 + bent @ sim.S_2.T), angle
