"""The estimators that :func:`~fusion_gyrocal.evaluate.compare.compare` runs side by side: one entry each.

Every estimator is one :class:`Estimator` in :data:`REGISTRY`: its name, what it is, the function that
runs it on sample-aligned rates, the optional module it needs and its colour and marker in the
figures. Adding an estimator is adding one entry; :data:`ESTIMATORS` (name -> description) and
:data:`DEFAULT_ESTIMATORS` derive from the registry.

Estimators
----------
``direct``
    The paper's direct solution: least squares for A (Eq. 17), decomposition (Lemmas 2-4),
    unit-scale prior (Eq. 32-34), with the paper's residual-based flex rejection where it finds
    outliers: ``calibrate_pair(method="direct")``.
``default``
    What :func:`fusion_gyrocal.calibrate_pair` does by default (maximum likelihood from the
    direct solution, same flex rejection).
``appendix_c``
    The paper's iterative Gauss-Newton solver of Appendix C
    (:func:`~fusion_gyrocal.evaluate.baselines.solve_appendix_c`), started from the direct solution
    as in the paper's comparison ("a properly initialized iterative solver").
``appendix_c_identity``
    The same solver started from identity (``C = I``, unit scales): how an iterative solver
    without the direct solution fares (not in the default set).
``rotation_only``
    What rotation-only tools do: Kabsch / Wahba alignment of the bias-removed rates
    (:func:`~fusion_gyrocal.evaluate.baselines.rotation_only`); no scale factors.
``graph``
    The GTSAM factor graph (:func:`fusion_gyrocal.graph.calibrate_pair_graph`, windows of 1000
    samples, Levenberg-Marquardt).
``ekf``
    The final estimate of the online tracker (:class:`fusion_gyrocal.online.tracker.GyroPairTracker`)
    seeded from the first 20 % of the data and run over the rest, with the simulations' model:
    constant extrinsics and scale factors and the paper's bias random walk (a tracker that expects
    drift forgets old data and cannot match a batch estimate on constant parameters).

``graph`` and ``ekf`` are imported lazily; when their module is missing their rows say
"not available" instead of failing the comparison.

Options
-------
Every run function takes the comparison's :class:`~fusion_gyrocal.options.Options`: ``direct`` and
``default`` give it unchanged to :func:`~fusion_gyrocal.calibrate_pair` with the method each is
(``"direct"``, ``"ml"``); the graph takes ``noise_std``, ``gauge`` and ``parallel_tol_deg``; the EKF
``noise_std`` and ``gauge`` for its seed; ``appendix_c`` (the paper's solver with its own gauge,
``1s_x`` fixed) and ``rotation_only`` take none.

Failures
--------
An estimator fails (its row says so) with a :class:`~fusion_gyrocal.errors.GyroCalError`, the
library's errors raised on purpose, when its module is not available, or when what it returns is not
physical (:func:`check_estimate`, applied to every estimator in :func:`run_estimator`: a rotation
that is not one, scale factors outside (0, inf), a non-finite bias). Anything else (a ``ValueError``,
a singular matrix) is a bug and propagates.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..core.moments import Moments, as_rates
from ..errors import ConvergenceError, GyroCalError, InputError
from ..options import Options
from .baselines import rotation_only, solve_appendix_c

__all__ = ["Estimator", "Estimate", "REGISTRY", "ESTIMATORS", "DEFAULT_ESTIMATORS", "estimator", "estimator_names",
           "estimator_available", "check_estimate", "run_estimator"]


# ============================================================================================ the run functions
# Each takes sample-aligned rates (N, 3), the sample rate (Hz) and the Options, and returns
# (R_1_2, scale_1, scale_2, bias, iterations); scales NaN where the estimator has none.
def _fields(cal) -> tuple:
    return cal.R_1_2, cal.scale_1, cal.scale_2, cal.bias, int(cal.iterations)


def _run_direct(w1, w2, rate_hz, options):
    from ..pipeline.pipeline import calibrate_pair
    return _fields(calibrate_pair(w1, w2, options=options.replace(method="direct")))


def _run_default(w1, w2, rate_hz, options):
    from ..pipeline.pipeline import calibrate_pair
    return _fields(calibrate_pair(w1, w2, options=options.replace(method="ml")))


def _appendix_c(w1, w2, from_direct: bool):
    from ..core.solve import solve
    m = Moments.from_samples(w1, w2)
    init = (None, None, None)
    if from_direct:
        d = solve(m, method="direct")
        init = (d.R_1_2, d.scale_1, d.scale_2)
    return _fields(solve_appendix_c(m, *init))


def _run_appendix_c(w1, w2, rate_hz, options):
    return _appendix_c(w1, w2, from_direct=True)


def _run_appendix_c_identity(w1, w2, rate_hz, options):
    return _appendix_c(w1, w2, from_direct=False)


def _run_rotation_only(w1, w2, rate_hz, options):
    R, b = rotation_only(w1, w2)
    return R, np.full(3, np.nan), np.full(3, np.nan), b, 0


def _run_graph(w1, w2, rate_hz, options):
    from ..graph import calibrate_pair_graph
    return _fields(calibrate_pair_graph(w1, w2, noise_std=options.noise_std, gauge=options.gauge,
                                        parallel_tol_deg=options.parallel_tol_deg))


def _run_ekf(w1, w2, rate_hz, options):
    from ..online.tracker import DriftNoise, GyroPairTracker
    n = w1.shape[0]
    k = max(int(0.2 * n), min(n, 200))
    t = np.arange(n) / rate_hz
    # the model of the simulations: constant extrinsics and scales, the paper's bias random walk
    drift = DriftNoise(rotation=0.0, log_scale=0.0, bias=DriftNoise().bias)
    tracker = GyroPairTracker.from_samples(t[:k], w1[:k], w2[:k], drift=drift, noise_std=options.noise_std,
                                           gauge=options.gauge)
    if k < n:
        tracker.run(t[k:], w1[k:], w2[k:])
    return _fields(tracker.calibration)


# ============================================================================================ the registry
@dataclass(frozen=True)
class Estimator:
    """One estimator of the comparison.

    Attributes
    ----------
    name : str
        Row name.
    description : str
        What it is (one line).
    run : callable
        ``run(omega_1, omega_2, rate_hz, options) -> (R_1_2, scale_1, scale_2, bias, iterations)`` on
        sample-aligned rates (rad/s); scales NaN when it has none. Raises a
        :class:`~fusion_gyrocal.errors.GyroCalError` when it fails.
    module : str, optional
        Module it needs (an optional dependency); without it the estimator is "not available".
    colour, marker : str
        Its line colour and marker in the figures (matplotlib).
    default : bool
        Run when no estimators are named.
    """

    name: str
    description: str
    run: Callable
    module: str | None = None
    colour: str | None = None
    marker: str | None = None
    default: bool = True


#: Every estimator, in row order: name -> :class:`Estimator`.
REGISTRY = {e.name: e for e in (
    Estimator("direct", "paper's direct solution (Eq. 17, Lemmas 2-4, Eq. 32-34) with its flex rejection",
              _run_direct, colour="tab:blue", marker="o"),
    Estimator("default", "calibrate_pair() default: maximum likelihood from the direct solution, flex rejection",
              _run_default, colour="tab:orange", marker="s"),
    Estimator("appendix_c", "paper's iterative Gauss-Newton (Appendix C) from the direct solution",
              _run_appendix_c, colour="tab:green", marker="^"),
    Estimator("appendix_c_identity", "paper's iterative Gauss-Newton (Appendix C) from identity",
              _run_appendix_c_identity, colour="tab:olive", marker="v", default=False),
    Estimator("rotation_only", "Kabsch alignment of bias-removed rates (rotation-only tools); no scales",
              _run_rotation_only, colour="tab:red", marker="x"),
    Estimator("graph", "GTSAM factor graph, windows of 1000 samples, Levenberg-Marquardt",
              _run_graph, module="fusion_gyrocal.graph", colour="tab:purple", marker="D"),
    Estimator("ekf", "online EKF tracker (constant extrinsics and scales, the paper's bias walk) seeded on the "
                     "first 20 % of the data, final estimate",
              _run_ekf, module="fusion_gyrocal.online.tracker", colour="tab:brown", marker="P"),
)}
#: Every estimator name and what it is.
ESTIMATORS = {name: e.description for name, e in REGISTRY.items()}
#: Estimators run when none are named.
DEFAULT_ESTIMATORS = tuple(name for name, e in REGISTRY.items() if e.default)


def estimator(name: str) -> Estimator:
    """The registry entry of ``name`` (:class:`~fusion_gyrocal.errors.InputError` for an unknown name)."""
    try:
        return REGISTRY[name]
    except (KeyError, TypeError):
        raise InputError(f"estimator: expected one of {', '.join(REGISTRY)}, got {name!r}") from None


def estimator_names(estimators=None) -> tuple:
    """The names to run: ``estimators`` checked against the registry, default :data:`DEFAULT_ESTIMATORS`."""
    names = tuple(n for n, e in REGISTRY.items() if e.default) if estimators is None else tuple(estimators)
    for n in names:
        if n not in REGISTRY:
            raise InputError(f"estimator: expected names from {', '.join(REGISTRY)}, got {n!r}")
    if not names:
        raise InputError("estimators: expected at least one estimator, got none")
    return names


def estimator_available(name: str) -> str:
    """``""`` when ``name`` can run here, else the reason it cannot (e.g. a missing module)."""
    module = estimator(name).module
    if module is None:  # no optional dependency
        return ""
    try:
        __import__(module)
    except ImportError as exc:
        return f"not available: {module} cannot be imported ({exc})"
    return ""


# ============================================================================================ running one
def _ro(a, shape):
    arr = np.array(a, dtype=np.float64).reshape(shape)
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class Estimate:
    """One estimator's result on one data set.

    Attributes
    ----------
    estimator : str
        Name (a key of :data:`REGISTRY`).
    R_1_2 : ndarray (3, 3)
        Estimated rotation (``omega_1 = R_1_2 @ omega_2``); NaN when the estimator failed.
    scale_1, scale_2 : ndarray (3,)
        Estimated scale factors in the estimator's gauge; NaN when not estimated.
    bias : ndarray (3,)
        Combined bias ``b_1 - A b_2`` (rad/s, Eq. 5).
    seconds : float
        Wall time of the solve, from the samples (including the estimator's own pass over them).
    iterations : int
        Iterations, where the estimator iterates.
    error : str
        Why the estimator failed ("" when it did not).
    """

    estimator: str
    R_1_2: np.ndarray
    scale_1: np.ndarray
    scale_2: np.ndarray
    bias: np.ndarray
    seconds: float
    iterations: int = 0
    error: str = ""

    def __post_init__(self):
        for name, shape in (("R_1_2", (3, 3)), ("scale_1", (3,)), ("scale_2", (3,)), ("bias", (3,))):
            object.__setattr__(self, name, _ro(getattr(self, name), shape))

    @property
    def ok(self) -> bool:
        return not self.error

    @property
    def has_scales(self) -> bool:
        return bool(np.isfinite(self.scale_1).all() and np.isfinite(self.scale_2).all())

    @classmethod
    def failed(cls, estimator: str, seconds: float, error: str) -> "Estimate":
        nan = np.full(3, np.nan)
        return cls(estimator, np.full((3, 3), np.nan), nan, nan, nan, seconds, 0, error)


_ROTATION_TOL = 1e-6   # |R^T R - I| and |det R - 1| of an estimate that is a rotation


def check_estimate(name: str, R_1_2, scale_1, scale_2, bias) -> None:
    """Refuse an estimate that is not physical (one check for every estimator of :data:`REGISTRY`).

    Parameters
    ----------
    name : str
        The estimator (for the message).
    R_1_2 : array_like (3, 3)
        Must be a rotation: finite, orthonormal and right-handed (within 1e-6).
    scale_1, scale_2 : array_like (3,)
        Must be finite and positive, or all NaN (an estimator without scale factors).
    bias : array_like (3,)
        Must be finite.

    Raises
    ------
    ConvergenceError
        Naming what is wrong and the values (e.g. a scale factor of -3.3e6 from a diverged iteration).
    """
    R = np.asarray(R_1_2, dtype=float).reshape(3, 3)
    s = np.concatenate([np.asarray(scale_1, dtype=float).ravel(), np.asarray(scale_2, dtype=float).ravel()])
    b = np.asarray(bias, dtype=float).ravel()
    problem = ""
    if not np.isfinite(R).all():
        problem = "a non-finite R_1_2"
    else:
        off = max(float(np.abs(R.T @ R - np.eye(3)).max()), abs(float(np.linalg.det(R)) - 1.0))
        if off > _ROTATION_TOL:
            problem = (f"an R_1_2 that is not a rotation (|R^T R - I| or |det R - 1| = {off:.3g}, "
                       f"det {np.linalg.det(R):+.3g})")
    if not problem and not np.isnan(s).all() and not (np.isfinite(s).all() and (s > 0).all()):
        problem = (f"scale factors outside (0, inf): scale_1 {np.array2string(s[:3], precision=4)}, "
                   f"scale_2 {np.array2string(s[3:], precision=4)}")
    if not problem and not np.isfinite(b).all():
        problem = f"a non-finite bias {np.array2string(b, precision=4)}"
    if problem:
        raise ConvergenceError(f"{name}: expected a physical estimate, got {problem}")


_WARM: set = set()  # estimators already run once in this process


def run_estimator(name: str, omega_1, omega_2, *, rate_hz: float = 100.0, options: Options | None = None,
                  **keywords) -> Estimate:
    """Run one estimator on sample-aligned rates and time it.

    Parameters
    ----------
    name : str
        A key of :data:`REGISTRY`.
    omega_1, omega_2 : array_like (N, 3)
        Sample-aligned measured rates (rad/s).
    rate_hz : float
        Sample rate (only the EKF uses time).
    options : Options, optional
        Options of the solver and the pipeline, given to the estimators that take them (see the
        module's notes); ``keywords`` are its fields.

    Returns
    -------
    Estimate
        ``seconds`` is the wall time of the solve; the first call of each estimator in a process
        is run once untimed before (one-time costs such as lazy imports are not a solve).
        ``error`` is set (and the estimates are NaN) when the estimator raised a
        :class:`~fusion_gyrocal.errors.GyroCalError`, returned an estimate that is not physical
        (:func:`check_estimate`) or is not available. Any other exception is a bug and propagates.
    """
    entry = estimator(name)
    options = Options.of(options, **keywords)
    reason = estimator_available(name)
    if reason:
        return Estimate.failed(name, float("nan"), reason)
    w1 = as_rates("omega_1", omega_1)
    w2 = as_rates("omega_2", omega_2, length=w1.shape[0])
    rate_hz = float(rate_hz)
    if name not in _WARM:
        # the first call in a process pays one-time costs (lazy imports): run it once untimed
        _WARM.add(name)
        try:
            entry.run(w1, w2, rate_hz, options)
        except GyroCalError:
            pass  # the timed run below fails the same way and reports it
    t0 = time.perf_counter()
    try:
        R, s1, s2, bias, iterations = entry.run(w1, w2, rate_hz, options)
        check_estimate(name, R, s1, s2, bias)
    except GyroCalError as exc:
        return Estimate.failed(name, time.perf_counter() - t0, f"{type(exc).__name__}: {exc}")
    return Estimate(name, R, s1, s2, bias, time.perf_counter() - t0, iterations)
