"""Named simulated scenarios for comparing estimators, with their truth and their bound.

Every scenario follows the paper's simulation protocol (Section V, :func:`fusion_gyrocal.evaluate.sim.simulate_pair`:
100 Hz, white noise 0.1 deg/s per gyro, bias random walk 57.3 micro-deg/s per step, 60 s of human-like
motion from :class:`fusion_gyrocal.evaluate.sim.HumanMotion`) and changes one thing:

=================  ===================================================================================
name               what changes
=================  ===================================================================================
``nominal``        nothing (0.5 rad/s RMS per axis, random well-conditioned ``R_1_2``, scales 1 +- 1 %)
``snr_x<f>``       SNR (Eq. 36) scaled by ``f`` through the rate norm; ``snr_x<f>_noise`` through the
                   noise (``sigma / f``), ``snr_x<f>_samples`` through the sample count (``N f^2``)
``weak_axis``      x rates 10x smaller, y and z amplified so that the total SNR stays the same
``skew``           upper-triangular intrinsics with skew ~ N(0, 2.357e-4^2) (Appendix D)
``flex``           bursts of fast motion during which the mounting bends by up to 1 deg
``slow_motion``    unequal, slow rates (0.03 / 0.06 / 0.12 rad/s RMS): noise in the regressor matters
``drifting_bias``  bias random walk 100x the paper's
``near_parallel``  gyro 2's z axis 10 deg from gyro 1's z axis (close to Lemma 3's singular case)
=================  ===================================================================================

The SNR of each scenario is set exactly (the motion is rescaled so that ``sum ||omega_1||^2`` hits
its target), so that Monte Carlo runs at one SNR point share one abscissa.
:func:`make_scenario` also takes ``snr_factor`` / ``snr_via`` to scale the SNR of any scenario
(``make_scenario("weak_axis", snr_factor=2)``).

:func:`scenario_bound` gives the Cramer-Rao bound of a realisation in the paper's metrics
(Eq. 37-38), from the true signal (:func:`fusion_gyrocal.core.observability.cramer_rao_bound`), plus the
rotation error that Appendix D predicts from the realised skew.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import InputError
from ..core.observability import cramer_rao_bound
from .sim import (DEG, PAPER_BIAS_WALK_STD, PAPER_NOISE_STD, PAPER_RATE_HZ, PAPER_SKEW_STD, HumanMotion,
                  SimulatedPair, general_rotation, simulate_pair)

__all__ = ["Scenario", "ScenarioBound", "SCENARIOS", "SNR_FACTORS", "SNR_VIA", "make_scenario", "describe_scenario",
           "scenario_bound", "list_scenarios"]

NOMINAL_N = 6000                 # 60 s at the paper's 100 Hz
NOMINAL_RMS = 0.5                # rad/s per axis (about 29 deg/s, hand-held motion)
SCALE_STD = 0.01                 # true scale factors ~ N(1, 1 %^2)
MIN_PARALLEL_ANGLE_DEG = 20.0    # nominal R_1_2: no axis pair closer than this to (anti)parallel
FLEX_MAX_BEND_DEG = 1.0
NEAR_PARALLEL_DEG = 10.0

SNR_FACTORS = (0.5, 1.0, 2.0, 4.0)
SNR_VIA = ("rate", "noise", "samples")

#: Base scenario names and a one-line description of each.
SCENARIOS = {
    "nominal": "the paper's protocol: 60 s at 100 Hz, 0.5 rad/s RMS per axis, noise 0.1 deg/s, scales 1 +- 1 %",
    "weak_axis": "x rates 10x smaller, y/z amplified so the total SNR is unchanged",
    "skew": "skewed intrinsics, off-diagonals ~ N(0, 2.357e-4^2) (Appendix D)",
    "flex": "bursts of fast motion during which the mounting bends by up to 1 deg",
    "slow_motion": "slow, unequal rates (0.03 / 0.06 / 0.12 rad/s RMS): noise in the regressor matters",
    "drifting_bias": "bias random walk 100x the paper's",
    "near_parallel": "gyro 2's z axis 10 deg from gyro 1's z axis",
}

_SNR_NAME = re.compile(r"^snr_x(?P<f>[0-9]*\.?[0-9]+)(?:_(?P<via>rate|noise|samples))?$")


@dataclass(frozen=True)
class Scenario:
    """One simulated realisation of a named scenario.

    Attributes
    ----------
    name : str
        Scenario name as given to :func:`make_scenario` (e.g. ``"snr_x2_noise"``).
    description : str
        What the scenario changes with respect to the paper's protocol.
    data : SimulatedPair
        Measurements and truth (``R_1_2`` is the rigid, unflexed rotation).
    snr_factor : float
        Factor applied to the base scenario's SNR.
    snr_via : str
        How the SNR was scaled: ``"rate"``, ``"noise"`` or ``"samples"``.
    skew_std : float
        Standard deviation of the simulated skew (0 without skew).
    flex_angle : ndarray (N,) or None
        Bending angle (rad) of the mounting at each sample (``flex`` only).
    """

    name: str
    description: str
    data: SimulatedPair = field(repr=False)
    snr_factor: float = 1.0
    snr_via: str = "rate"
    skew_std: float = 0.0
    flex_angle: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        if self.flex_angle is not None:
            angle = np.array(self.flex_angle, dtype=np.float64)
            angle.flags.writeable = False
            object.__setattr__(self, "flex_angle", angle)

    @property
    def omega_1(self) -> np.ndarray:
        return self.data.omega_1

    @property
    def omega_2(self) -> np.ndarray:
        return self.data.omega_2

    @property
    def noise_std(self) -> tuple:
        """White-noise standard deviation per sample of gyro 1 and gyro 2 (rad/s)."""
        return self.data.noise_std

    @property
    def n_samples(self) -> int:
        return int(self.data.omega_1.shape[0])

    @property
    def signal_2(self) -> np.ndarray:
        """Noise-free gyro-2 signal ``S_2 omega_2`` (N, 3) of the rigid model (rad/s)."""
        d = self.data
        return (d.omega_true_1 @ d.R_1_2) @ d.S_2.T

    @property
    def snr(self) -> float:
        """``sqrt(sum_k ||omega_1(k)||^2) / sigma`` with ``sigma^2 = sigma_1^2 + sigma_2^2`` (Eq. 36)."""
        s1, s2 = self.noise_std
        return float(np.sqrt(np.sum(self.data.omega_true_1**2)) / np.hypot(s1, s2))


@dataclass(frozen=True)
class ScenarioBound:
    """What the best unbiased estimator can reach on one realisation, in the paper's metrics.

    Attributes
    ----------
    rotation : float
        Cramer-Rao bound on the RMSE of ``||Log(R_hat R^T)||`` (rad, Eq. 37).
    scale : float
        Cramer-Rao bound on the RMSE of the paper's scale error (Eq. 38, a fraction).
    rotation_skew : float
        ``||(w_1 - C w_2) / 2||``: the rotation error Appendix D predicts from the realised skew
        (rad; 0 without skew). It is a bias, not noise, so it adds to the bound in quadrature.
    """

    rotation: float
    scale: float
    rotation_skew: float = 0.0

    @property
    def rotation_expected(self) -> float:
        """``sqrt(rotation^2 + rotation_skew^2)``: expected rotation RMSE including skew (rad)."""
        return float(np.hypot(self.rotation, self.rotation_skew))


def list_scenarios() -> tuple[str, ...]:
    """Every scenario name :func:`make_scenario` accepts without parameters."""
    snr = tuple(f"snr_x{f:g}" + ("" if via == "rate" else f"_{via}") for via in SNR_VIA for f in SNR_FACTORS)
    return tuple(SCENARIOS) + snr


def _near_parallel_rotation(rng, angle_deg: float = NEAR_PARALLEL_DEG) -> np.ndarray:
    """``Rz(a) Exp(angle * u) Rz(b)`` with ``u`` horizontal: gyro 2's z axis ``angle_deg`` from gyro 1's,
    the other axes at least 20 deg from parallel."""
    from scipy.spatial.transform import Rotation

    cos_max = np.cos(np.deg2rad(MIN_PARALLEL_ANGLE_DEG))
    while True:
        a, b, phi = rng.uniform(0, 2 * np.pi, 3)
        tilt = Rotation.from_rotvec(np.deg2rad(angle_deg) * np.array([np.cos(phi), np.sin(phi), 0.0]))
        R = (Rotation.from_rotvec([0, 0, a]) * tilt * Rotation.from_rotvec([0, 0, b])).as_matrix()
        if np.abs(R[:2, :2]).max() < cos_max:
            return R


def _motion(rng, n: int, rms, total_rms: float) -> np.ndarray:
    """Human-like motion with per-axis RMS shape ``rms``, rescaled so that the mean squared rate norm
    is exactly ``3 * total_rms^2`` (fixes the SNR of Eq. 36)."""
    w = HumanMotion(rms, rng=rng)(np.arange(n) / PAPER_RATE_HZ)
    return w * np.sqrt(3.0 * total_rms**2 * n / np.sum(w**2))


def _flex_bursts(rng, w: np.ndarray, n_bursts: int = 6, burst_s: float = 1.5, gain: float = 4.0):
    """Add bursts of fast motion (rates up to ``gain`` x; up to ``n_bursts``, fewer in short data)
    and the bending angle they cause.

    The bend grows with the rate norm above the pre-burst 99th percentile and reaches
    ``FLEX_MAX_BEND_DEG`` at the fastest sample (quasi-static bending: the bending rate itself is
    not added to gyro 2, which is what the residual-versus-rate-norm figure of the paper shows).
    """
    n = w.shape[0]
    L = int(burst_s * PAPER_RATE_HZ)
    slots = np.arange(L, n - 2 * L, 2 * L)  # bursts never overlap and leave rigid data around them
    if slots.size == 0:
        raise InputError(f"flex: expected at least {4 * L} samples (room for one {burst_s:g} s burst), got {n}")
    starts = np.sort(rng.choice(slots, size=min(n_bursts, slots.size), replace=False))
    env = np.zeros(n)
    for s in starts:
        env[s:s + L] = np.maximum(env[s:s + L], np.hanning(L))
    threshold = np.quantile(np.linalg.norm(w, axis=1), 0.99)
    w = w * (1.0 + (gain - 1.0) * env)[:, None]
    norm = np.linalg.norm(w, axis=1)
    excess = np.clip(norm - threshold, 0.0, None) * (env > 0)
    angle = FLEX_MAX_BEND_DEG * DEG * excess / excess.max()
    return w, angle


def _parse(name: str) -> tuple[str, float, str]:
    if name in SCENARIOS:
        return name, 1.0, "rate"
    m = _SNR_NAME.match(name)
    if m is None:
        raise InputError(f"scenario: expected one of {', '.join(list_scenarios())} "
                         f"(or snr_x<factor>[_rate|_noise|_samples]), got {name!r}")
    return "nominal", float(m.group("f")), m.group("via") or "rate"


def _resolve(name: str, snr_factor, snr_via, n: int) -> tuple[str, float, str, int]:
    """Base scenario, SNR factor, SNR route and sample count of ``name`` with the overrides (checked)."""
    base, factor, via = _parse(name)
    if snr_factor is not None:
        factor *= float(snr_factor)
    if snr_via is not None:
        via = snr_via
    if via not in SNR_VIA:
        raise InputError(f"snr_via: expected one of {SNR_VIA}, got {via!r}")
    if not (np.isfinite(factor) and factor > 0):
        raise InputError(f"snr_factor: expected a positive factor, got {factor!r}")
    n_s = int(round(n * factor**2)) if via == "samples" else int(n)
    if n_s < 10:
        raise InputError(f"snr_factor {factor:g} through the sample count leaves {n_s} samples; expected >= 10")
    return base, factor, via, n_s


def describe_scenario(name: str = "nominal", *, snr_factor: float | None = None, snr_via: str | None = None,
                      n: int = NOMINAL_N) -> str:
    """The ``description`` of :func:`make_scenario` with the same arguments, checked the same way,
    without simulating anything."""
    base, factor, via, _ = _resolve(name, snr_factor, snr_via, n)
    desc = SCENARIOS[base]
    if factor != 1.0:
        desc += f"; SNR x{factor:g} through the {'rate norm' if via == 'rate' else via}"
    return desc


def make_scenario(name: str = "nominal", *, rng=None, snr_factor: float | None = None,
                  snr_via: str | None = None, n: int = NOMINAL_N) -> Scenario:
    """Simulate one realisation of a named scenario.

    Parameters
    ----------
    name : str
        One of :data:`SCENARIOS` or ``snr_x<factor>[_rate|_noise|_samples]`` (the paper's SNR sweep of
        the nominal scenario, Section V: factors 0.5, 1, 2 and 4).
    rng : numpy.random.Generator, int or sequence of int, optional
        Seed of the realisation (truth, motion, bias and noise).
    snr_factor : float, optional
        Scale the scenario's SNR by this factor (multiplies a factor given in the name).
    snr_via : {"rate", "noise", "samples"}, optional
        How to scale the SNR: the rate norm, the noise standard deviation (``sigma / f``) or the
        sample count (``N f^2``, Eq. 36). Default: from the name, else ``"rate"``.
    n : int
        Samples of the base scenario at 100 Hz (before scaling through the sample count).

    Returns
    -------
    Scenario

    Raises
    ------
    InputError
        Unknown name, non-positive factor or unknown ``snr_via``.

    Examples
    --------
    >>> from fusion_gyrocal.evaluate.scenarios import make_scenario
    >>> sc = make_scenario("snr_x2_noise", rng=0)
    >>> round(sc.snr / make_scenario("nominal", rng=0).snr, 6)
    2.0
    """
    base, factor, via, n_s = _resolve(name, snr_factor, snr_via, n)
    rng = np.random.default_rng(rng)
    rate_f = factor if via == "rate" else 1.0
    noise = PAPER_NOISE_STD / (factor if via == "noise" else 1.0)

    R = _near_parallel_rotation(rng) if base == "near_parallel" else general_rotation(rng, MIN_PARALLEL_ANGLE_DEG)
    s1, s2 = rng.normal(1.0, SCALE_STD, 3), rng.normal(1.0, SCALE_STD, 3)
    rms_shape = {"weak_axis": (0.1, 1.0, 1.0), "slow_motion": (0.03, 0.06, 0.12)}.get(base, 1.0)
    total = {"slow_motion": float(np.sqrt((0.03**2 + 0.06**2 + 0.12**2) / 3))}.get(base, NOMINAL_RMS)
    w = _motion(rng, n_s, rms_shape, total * rate_f)
    angle = None
    if base == "flex":
        w, angle = _flex_bursts(rng, w)
    skew = PAPER_SKEW_STD if base == "skew" else 0.0
    walk = PAPER_BIAS_WALK_STD * (100.0 if base == "drifting_bias" else 1.0)
    data = simulate_pair(w, R_1_2=R, scale_1=s1, scale_2=s2, noise_std=noise, bias_walk_std=walk, skew_std=skew,
                         rng=rng)
    if angle is not None:
        data = _bend(data, rng, angle)
    desc = describe_scenario(name, snr_factor=snr_factor, snr_via=snr_via, n=n)
    return Scenario(name, desc, data, factor, via, skew, angle)


def _bend(data: SimulatedPair, rng, angle: np.ndarray) -> SimulatedPair:
    """Replace gyro 2's signal by that of a mounting bent by ``angle`` (rad) about a random axis:
    ``R_1_2(k) = Exp(angle_k u) R_1_2``, ``omega_2(k) = R_1_2(k)^T omega_1(k)``."""
    from scipy.spatial.transform import Rotation

    u = rng.standard_normal(3)
    u /= np.linalg.norm(u)
    R_k = Rotation.from_rotvec(angle[:, None] * u) * Rotation.from_matrix(data.R_1_2)
    w2_rigid = data.omega_true_1 @ data.R_1_2
    w2_bent = R_k.inv().apply(data.omega_true_1)
    omega_2 = data.omega_2 + (w2_bent - w2_rigid) @ data.S_2.T
    return replace(data, omega_2=omega_2)


def scenario_bound(scenario: Scenario) -> ScenarioBound:
    """Cramer-Rao bound of one realisation in the paper's metrics (Eq. 37-38).

    The Fisher information (Appendix B, generalised to the scale factors, bias profiled out) is
    evaluated at the truth with the true, noise-free signal scatter of gyro 2
    (:func:`fusion_gyrocal.core.observability.cramer_rao_bound`):

    * rotation: ``sqrt(tr P_rot)``, the expected RMSE of ``||Log(R_hat R^T)||`` since
      ``Log(R_hat R^T) = dtheta`` to first order;
    * scales: with ``l`` the six log scale factors, the paper's error vector
      ``e_k = s_hat_k / s_hat_1x - s_k / s_1x = (s_k / s_1x)(dl_k - dl_1x)`` to first order, so
      ``E||e||^2 = tr(J P J^T)`` with ``J`` that linear map; ``e`` is invariant to the global scale
      (Theorem 2), so any gauge of ``P`` gives the same number; RMSE ``= sqrt(E||e||^2 / 5)``.

    For the ``skew`` scenario the rotation error predicted by Appendix D from the realised skew,
    ``theta ~ (w_1 - C w_2) / 2`` with ``w_i = [-U_i(2,3), U_i(1,3), -U_i(1,2)]`` and
    ``U_i = S_i^-1 (S_i - diag S_i)``, is returned as ``rotation_skew``. The bound of ``flex`` and
    ``drifting_bias`` is that of the rigid, constant-bias model: what the data would allow without
    the defect.
    """
    d = scenario.data
    b = cramer_rao_bound(d.R_1_2, d.scale_1, d.scale_2, d.noise_std, scenario.signal_2)
    w = []
    for S in (d.S_1, d.S_2):
        U = np.linalg.solve(S, S - np.diag(np.diag(S)))
        w.append(np.array([-U[1, 2], U[0, 2], -U[0, 1]]))
    theta_skew = 0.5 * (w[0] - d.R_1_2 @ w[1])
    return ScenarioBound(b.rotation_rmse, b.scale_rmse, float(np.linalg.norm(theta_skew)))
