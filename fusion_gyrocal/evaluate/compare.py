"""Every estimator side by side on the same data: tables, Monte Carlo, SNR sweeps and figures.

Estimators (:data:`ESTIMATORS`)
-------------------------------
``direct``
    The paper's direct solution: least squares for A (Eq. 17), decomposition (Lemmas 2-4),
    unit-scale prior (Eq. 32-34), with the paper's residual-based flex rejection where it finds
    outliers: ``calibrate_pair(method="direct")``.
``default``
    What :func:`fusion_gyrocal.calibrate_pair` does by default (maximum likelihood from the
    direct solution, same flex rejection).
``appendix_c``
    The paper's iterative Gauss-Newton solver of Appendix C (:func:`solve_appendix_c`), started from
    the direct solution as in the paper's comparison ("a properly initialized iterative solver").
``appendix_c_identity``
    The same solver started from identity (``C = I``, unit scales): how an iterative solver
    without the direct solution fares (not in the default set).
``rotation_only``
    What rotation-only tools do: Kabsch / Wahba alignment of the bias-removed rates
    (:func:`rotation_only`, :meth:`scipy.spatial.transform.Rotation.align_vectors`); no scale factors.
``graph``
    The GTSAM factor graph (:func:`fusion_gyrocal.graph.pair.calibrate_pair_graph`, windows of 1000
    samples, Levenberg-Marquardt).
``ekf``
    The final estimate of the online tracker (:class:`fusion_gyrocal.online.tracker.GyroPairTracker`)
    seeded from the first 20 % of the data and run over the rest, with the simulations' model:
    constant extrinsics and scale factors and the paper's bias random walk (a tracker that expects
    drift forgets old data and cannot match a batch estimate on constant parameters).

``graph`` and ``ekf`` are imported lazily; when their module is missing their rows say
"not available" instead of failing the comparison.

Outputs
-------
:func:`compare` runs every estimator on one recording, one :class:`~fusion_gyrocal.evaluate.scenarios.Scenario`
or ``runs`` Monte Carlo realisations of a named scenario (:mod:`fusion_gyrocal.evaluate.scenarios`), spread
over the machine's cores with a progress bar, and returns a :class:`Comparison`: per estimator the
estimate, the errors against the truth (the paper's metrics, Eq. 37-38), their ratio to the
Cramer-Rao bound (:func:`fusion_gyrocal.evaluate.scenarios.scenario_bound`) and the time per solve, as a
terminal table (:meth:`Comparison.print`), Markdown (:meth:`Comparison.to_markdown`) and CSV
(:meth:`Comparison.to_csv`). :func:`snr_sweep` repeats this over the paper's SNR factors and fits the
log-log slope of RMSE versus SNR (:meth:`SnrSweep.slopes`); :func:`plot_rmse_vs_snr` and
:func:`plot_residual_vs_rate` draw the paper's figures. ``gyrocal compare`` is the same from the
command line (:func:`add_compare_parser`, :func:`compare_main`).

Equations are cited by number as elsewhere in the library and, for Appendix C, by the LaTeX label
of the paper's source (``residual``, ``Gamma``, ``residual_linear``, ``eq:Jk``, ``eq:obj_iter_cost_2``,
``Jk_iterative``), since the appendix's numbering is not printed in the source.
"""

from __future__ import annotations

import csv
import io
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import GyroCalError, InputError
from ..core.moments import Moments, as_rates
from ..core.observability import A_of
from ..lie import skew
from .scenarios import SNR_FACTORS, Scenario, ScenarioBound, describe_scenario, make_scenario, scenario_bound
from .sim import rotation_error, scale_error

__all__ = [
    "ESTIMATORS", "DEFAULT_ESTIMATORS", "Estimate", "AppendixCResult", "RunRecord", "Row", "Comparison", "Slope",
    "SnrSweep", "solve_appendix_c", "rotation_only", "run_estimator", "estimator_available", "compare",
    "snr_sweep", "plot_rmse_vs_snr", "plot_residual_vs_rate",
]

#: Every estimator name and what it is.
ESTIMATORS = {
    "direct": "paper's direct solution (Eq. 17, Lemmas 2-4, Eq. 32-34) with its flex rejection",
    "default": "calibrate_pair() default: maximum likelihood from the direct solution, flex rejection",
    "appendix_c": "paper's iterative Gauss-Newton (Appendix C) from the direct solution",
    "appendix_c_identity": "paper's iterative Gauss-Newton (Appendix C) from identity",
    "rotation_only": "Kabsch alignment of bias-removed rates (rotation-only tools); no scales",
    "graph": "GTSAM factor graph, windows of 1000 samples, Levenberg-Marquardt",
    "ekf": "online EKF tracker (constant extrinsics and scales, the paper's bias walk) seeded on the first "
           "20 % of the data, final estimate",
}
#: Estimators run when none are named.
DEFAULT_ESTIMATORS = ("direct", "default", "appendix_c", "rotation_only", "graph", "ekf")

_CAUGHT = (GyroCalError, np.linalg.LinAlgError, ValueError, RuntimeError)  # an estimator failing, not a bug here


# ============================================================================================ results
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
        Name (a key of :data:`ESTIMATORS`).
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


@dataclass(frozen=True)
class AppendixCResult:
    """Result of :func:`solve_appendix_c`.

    ``scale_1[0]`` keeps its initial value (the paper fixes ``1s_x`` to remove the global scale).
    ``converged`` is False when ``max_iter`` was reached before the step fell below ``tol``.
    """

    R_1_2: np.ndarray
    scale_1: np.ndarray
    scale_2: np.ndarray
    bias: np.ndarray
    iterations: int
    converged: bool


# ============================================================================================ Appendix C
_GAMMA_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _appendix_c_basis() -> np.ndarray:
    """Matrices ``B_p`` (9, 3, 3) with ``J(k) x = (sum_p x_p B_p) omega(k)``.

    From Eq. (residual_linear) and (eq:Jk): ``J(k) x = [omega x] theta + Omega(k) gamma
    = (Gamma - [theta x]) omega``; gamma = (g11, g12, g13, g22, g23, g33) fills the symmetric
    ``Gamma`` (Eq. Gamma).
    """
    B = np.zeros((9, 3, 3))
    B[:3] = -skew(np.eye(3))                    # -[e_m x]:  [omega x] e_m = -[e_m x] omega
    for p, (i, j) in enumerate(_GAMMA_INDEX):
        B[3 + p, i, j] = B[3 + p, j, i] = 1.0
    return B


_B = _appendix_c_basis()


def _phi(C) -> np.ndarray:
    """``Phi`` (6, 6) of Appendix C: ``gamma = Phi [1s~; 2s~]`` from ``Gamma = S~1' - C S~2' C^T``."""
    Phi = np.zeros((6, 6))
    for row, (i, j) in enumerate(_GAMMA_INDEX):
        if i == j:
            Phi[row, i] = 1.0
        Phi[row, 3:] = -C[i] * C[j]
    return Phi


def solve_appendix_c(moments: Moments, R_1_2=None, scale_1=None, scale_2=None, *, max_iter: int = 10,
                     tol: float = 1e-10) -> AppendixCResult:
    """The paper's iterative (Gauss-Newton) solver of Appendix C, from the sufficient statistics.

    Each iteration compensates the rates with the current scales, ``omega_i' = S_i_hat^-1 omega_i``,
    forms the centred residual ``r(k) = omega_1'(k) - C_hat omega_2'(k)`` (Eq. residual,
    equ:residual) and the Jacobian ``J(k) = [[omega(k) x], Omega(k)]`` of (eq:Jk, Jk_iterative) with
    the true rate ``omega(k)`` replaced by the compensated measurement ``omega_1'(k)`` (as the
    appendix says, "J can be computed using the measurements"), solves the linear least squares
    (eq:obj_iter_cost_2) for ``x = [theta~, gamma]`` and recovers the scale errors from
    ``Phi s~ = gamma`` with ``1s~_x = 0`` (the global scale is not observable, Theorem 2). The
    update is ``C <- (I - [theta~ x]) C_hat`` (applied as ``Exp(-theta~) C_hat``) and
    ``S_i <- S_i_hat (I + S~_i')``.

    Both ``sum_k J^T J`` and ``sum_k J^T r`` are quadratic in the centred samples, so the whole
    iteration runs on the centred scatter of the moments: ``sum_k (B_p w)^T (B_q w) =
    tr(B_p^T B_q S11')`` and ``sum_k (B_p w)^T r = tr(B_p^T (S11' - C S12'^T))``.

    Parameters
    ----------
    moments : Moments
        Statistics of the sample-aligned pair (the bias is profiled out by the centring).
    R_1_2, scale_1, scale_2 : array_like, optional
        Initial estimate; default identity and unit scales.
    max_iter : int
        Iteration limit ("typically the algorithm converges in fewer than 5 iterations").
    tol : float
        Stop when the largest applied correction (rad or relative scale) is below this.

    Notes
    -----
    In a degenerate configuration (Lemmas 2-3) ``Phi`` loses further rank; the remaining
    undetermined combinations of scale errors are then set by the minimum-norm least-squares
    solution, i.e. left at their initial values, which is the paper's "fix more elements".
    """
    C = np.eye(3) if R_1_2 is None else np.array(R_1_2, dtype=float)
    s1 = np.ones(3) if scale_1 is None else np.array(scale_1, dtype=float)
    s2 = np.ones(3) if scale_2 is None else np.array(scale_2, dtype=float)
    Sc = moments.scatter
    converged = False
    it = 0
    for it in range(1, int(max_iter) + 1):
        d1, d2 = 1.0 / s1, 1.0 / s2
        S11 = Sc[:3, :3] * np.outer(d1, d1)
        S12 = Sc[:3, 3:] * np.outer(d1, d2)
        BS = _B @ S11                                  # B_q S11'
        H = np.einsum("pij,qij->pq", _B, BS)           # tr(B_p^T B_q S11')
        g = np.einsum("pij,ij->p", _B, S11 - C @ S12.T)
        x = np.linalg.solve(H, g)
        theta, gamma = x[:3], x[3:]
        Phi = _phi(C)
        s_err = np.zeros(6)
        s_err[1:] = np.linalg.lstsq(Phi[:, 1:], gamma, rcond=1e-8)[0]   # 1s~_x = 0
        C = Rotation.from_rotvec(-theta).as_matrix() @ C
        s1, s2 = s1 * (1.0 + s_err[:3]), s2 * (1.0 + s_err[3:])
        if max(np.abs(theta).max(), np.abs(s_err).max()) < tol:
            converged = True
            break
    bias = moments.mean_1 - A_of(C, s1, s2) @ moments.mean_2
    return AppendixCResult(C, s1, s2, bias, it, converged)


# ============================================================================================ rotation only
def rotation_only(omega_1, omega_2) -> tuple[np.ndarray, np.ndarray]:
    """Rotation-only baseline: Kabsch (Wahba) alignment of the bias-removed rates.

    Minimises ``sum_k ||w1(k) - R w2(k)||^2`` over rotations ``R`` with ``w_i`` the rates minus
    their mean (the mean removes constant biases), using
    :meth:`scipy.spatial.transform.Rotation.align_vectors`. Scale factors are not modelled
    (taken as 1), which is what rotation-only extrinsic tools do.

    Returns
    -------
    R_1_2 : ndarray (3, 3)
        ``omega_1 ~ R_1_2 @ omega_2``.
    bias : ndarray (3,)
        ``mean_1 - R_1_2 mean_2``.
    """
    w1 = as_rates("omega_1", omega_1)
    w2 = as_rates("omega_2", omega_2, length=w1.shape[0])
    m = Moments.from_samples(w1, w2)
    rot, _ = Rotation.align_vectors(w1 - m.mean_1, w2 - m.mean_2)
    R = rot.as_matrix()
    return R, m.mean_1 - R @ m.mean_2


# ============================================================================================ running estimators
def estimator_available(name: str) -> str:
    """``""`` when ``name`` can run here, else the reason it cannot (e.g. a missing module)."""
    if name not in ESTIMATORS:
        raise InputError(f"estimator: expected one of {', '.join(ESTIMATORS)}, got {name!r}")
    module = {"graph": "fusion_gyrocal.graph.pair", "ekf": "fusion_gyrocal.online.tracker"}.get(name)
    if module is None:  # only these estimators have a module of their own (optional dependencies)
        return ""
    try:
        __import__(module)
    except ImportError as exc:
        return f"not available: {module} cannot be imported ({exc})"
    return ""


def _from_calibration(name, cal, seconds) -> Estimate:
    return Estimate(name, cal.R_1_2, cal.scale_1, cal.scale_2, cal.bias, seconds, int(cal.iterations))


def _run(name, w1, w2, rate_hz):
    from ..core.solve import solve
    from ..pipeline.pipeline import calibrate_pair

    if name == "direct":
        return calibrate_pair(w1, w2, method="direct")
    if name == "default":
        return calibrate_pair(w1, w2)
    if name in ("appendix_c", "appendix_c_identity"):
        m = Moments.from_samples(w1, w2)
        init = (None, None, None)
        if name == "appendix_c":
            d = solve(m, method="direct")
            init = (d.R_1_2, d.scale_1, d.scale_2)
        return solve_appendix_c(m, *init)
    if name == "rotation_only":
        R, b = rotation_only(w1, w2)
        return AppendixCResult(R, np.full(3, np.nan), np.full(3, np.nan), b, 0, True)
    if name == "graph":
        from ..graph.pair import calibrate_pair_graph
        return calibrate_pair_graph(w1, w2)
    if name == "ekf":
        from ..online.tracker import DriftNoise, GyroPairTracker
        n = w1.shape[0]
        k = max(int(0.2 * n), min(n, 200))
        t = np.arange(n) / rate_hz
        # the model of the simulations: constant extrinsics and scales, the paper's bias random walk
        drift = DriftNoise(rotation=0.0, log_scale=0.0, bias=DriftNoise().bias)
        tracker = GyroPairTracker.from_samples(t[:k], w1[:k], w2[:k], drift=drift)
        if k < n:
            tracker.run(t[k:], w1[k:], w2[k:])
        return tracker.calibration
    raise InputError(f"estimator: expected one of {', '.join(ESTIMATORS)}, got {name!r}")


_WARM: set = set()  # estimators already run once in this process


def run_estimator(name: str, omega_1, omega_2, *, rate_hz: float = 100.0) -> Estimate:
    """Run one estimator on sample-aligned rates and time it.

    Parameters
    ----------
    name : str
        A key of :data:`ESTIMATORS`.
    omega_1, omega_2 : array_like (N, 3)
        Sample-aligned measured rates (rad/s).
    rate_hz : float
        Sample rate (only the EKF uses time).

    Returns
    -------
    Estimate
        ``seconds`` is the wall time of the solve; the first call of each estimator in a process
        is run once untimed before (one-time costs such as lazy imports are not a solve).
        ``error`` is set (and the estimates are NaN) when the estimator raised a known failure
        (:class:`~fusion_gyrocal.errors.GyroCalError`, a singular matrix, a solver error) or is not
        available.
    """
    reason = estimator_available(name)
    if reason:
        return Estimate.failed(name, float("nan"), reason)
    w1 = as_rates("omega_1", omega_1)
    w2 = as_rates("omega_2", omega_2, length=w1.shape[0])
    if name not in _WARM:
        # the first call in a process pays one-time costs (lazy imports): run it once untimed
        _WARM.add(name)
        try:
            _run(name, w1, w2, float(rate_hz))
        except _CAUGHT:
            pass
    t0 = time.perf_counter()
    try:
        out = _run(name, w1, w2, float(rate_hz))
    except _CAUGHT as exc:
        return Estimate.failed(name, time.perf_counter() - t0, f"{type(exc).__name__}: {exc}")
    seconds = time.perf_counter() - t0
    if isinstance(out, AppendixCResult):
        return Estimate(name, out.R_1_2, out.scale_1, out.scale_2, out.bias, seconds, out.iterations)
    return _from_calibration(name, out, seconds)


# ============================================================================================ Monte Carlo
@dataclass(frozen=True)
class RunRecord:
    """Every estimator on one data set (one Monte Carlo run).

    Attributes
    ----------
    seed : tuple of int
        Seed of the realisation (``make_scenario(name, rng=list(seed))`` reproduces it); ``()``
        for a recording.
    snr : float
        SNR of the realisation (Eq. 36), NaN without truth.
    bound : ScenarioBound or None
        Cramer-Rao bound of the realisation (None without truth).
    estimates : tuple of Estimate
        One per estimator, in the comparison's order.
    rotation_error, scale_error : ndarray (n_estimators,)
        The paper's errors (Eq. 37-38) against the truth (rad, fraction); NaN without truth, for a
        failed estimator, or (scales) for an estimator without scale factors.
    """

    seed: tuple
    snr: float
    bound: ScenarioBound | None
    estimates: tuple
    rotation_error: np.ndarray
    scale_error: np.ndarray


def _evaluate(scenario: Scenario | None, omega_1, omega_2, estimators, seed=(), rate_hz: float = 100.0) -> RunRecord:
    """Every estimator on one data set; errors against the truth of ``scenario`` (NaN without one)."""
    estimates = tuple(run_estimator(name, omega_1, omega_2, rate_hz=rate_hz) for name in estimators)
    rot, sca = np.full(len(estimates), np.nan), np.full(len(estimates), np.nan)
    if scenario is None:
        return RunRecord(tuple(seed), float("nan"), None, estimates, rot, sca)
    d = scenario.data
    for i, e in enumerate(estimates):
        if e.ok:
            rot[i] = rotation_error(e.R_1_2, d.R_1_2)
            if e.has_scales:
                sca[i] = scale_error(e.scale_1, e.scale_2, d.scale_1, d.scale_2)
    return RunRecord(tuple(seed), scenario.snr, scenario_bound(scenario), estimates, rot, sca)


def _task(spec, seed, estimators) -> RunRecord:
    """One Monte Carlo run: simulate ``spec = (name, snr_factor, snr_via)`` with ``seed``, run all."""
    name, factor, via = spec
    sc = make_scenario(name, rng=list(seed), snr_factor=factor, snr_via=via)
    return _evaluate(sc, sc.omega_1, sc.omega_2, estimators, seed)


def _progress(enabled: bool):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                    disable=not enabled, transient=True)


def _monte_carlo(specs, runs: int, estimators, seed: int, workers: int | None, progress: bool,
                 paired: bool = True):
    """``runs`` realisations of every spec. ``paired``: run ``i`` of every spec uses the seed
    ``(seed, i)`` (common random numbers: the same truth and motion at every SNR point); else
    spec ``s`` uses ``(seed, s + 1, i)`` (independent realisations)."""
    if runs < 1:
        raise InputError(f"runs: expected >= 1, got {runs}")
    tasks = [(s, i, (int(seed), i) if paired else (int(seed), s + 1, i)) for s in range(len(specs))
             for i in range(runs)]
    out = [[None] * runs for _ in specs]
    workers = (os.cpu_count() or 1) if workers is None else int(workers)
    with _progress(progress) as bar:
        job = bar.add_task(f"{len(specs)} x {runs} runs, {len(estimators)} estimators", total=len(tasks))
        if workers <= 1 or len(tasks) == 1:
            for s, j, sd in tasks:
                out[s][j] = _task(specs[s], sd, estimators)
                bar.advance(job)
        else:
            import multiprocessing as mp
            saved = {k: os.environ.get(k) for k in _THREAD_VARS}
            os.environ.update({k: "1" for k in _THREAD_VARS})  # one BLAS thread per worker process
            try:
                with ProcessPoolExecutor(min(workers, len(tasks)), mp_context=mp.get_context("spawn")) as pool:
                    futures = {pool.submit(_task, specs[s], sd, estimators): (s, j) for s, j, sd in tasks}
                    for fut in as_completed(futures):
                        s, j = futures[fut]
                        out[s][j] = fut.result()
                        bar.advance(job)
            finally:
                for k, v in saved.items():
                    if v is None:
                        os.environ.pop(k, None)
                    else:
                        os.environ[k] = v
    return out


_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


# ============================================================================================ table
@dataclass(frozen=True)
class Row:
    """One estimator's line of a :class:`Comparison` table.

    Errors are RMSE over the successful runs (rad for rotation, fraction for scales, Eq. 37-38);
    bounds are the root mean square of the per-run Cramer-Rao bounds over the same runs (rotation:
    including the skew prediction of Appendix D); ``seconds`` is the median time per solve.
    The estimate columns are those of the first run.
    """

    estimator: str
    description: str
    note: str
    runs: int
    failures: int
    rotvec_deg: np.ndarray
    scale_1: np.ndarray
    scale_2: np.ndarray
    rotation_rmse: float
    rotation_bound: float
    scale_rmse: float
    scale_bound: float
    seconds: float

    @property
    def rotation_ratio(self) -> float:
        return self.rotation_rmse / self.rotation_bound

    @property
    def scale_ratio(self) -> float:
        return self.scale_rmse / self.scale_bound


def _first_line(text: str, width: int = 160) -> str:
    line = text.strip().splitlines()[0] if text.strip() else ""
    return line if len(line) <= width else line[:width - 3] + "..."


def _rms(x) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def _row(k: int, name: str, records) -> Row:
    ests = [r.estimates[k] for r in records]
    ok = [e.ok for e in ests]
    first = ests[0]
    failures = len(ests) - int(np.sum(ok))
    note = "" if failures == 0 else _first_line(next(e.error for e in ests if not e.ok))
    rot = np.array([r.rotation_error[k] for r in records])
    sca = np.array([r.scale_error[k] for r in records])
    has_truth = records[0].bound is not None
    rb = np.array([r.bound.rotation_expected if has_truth else np.nan for r in records])
    sb = np.array([r.bound.scale if has_truth else np.nan for r in records])
    r_sel, s_sel = np.isfinite(rot), np.isfinite(sca)
    nan = float("nan")
    secs = np.array([e.seconds for e in ests if e.ok])
    return Row(
        estimator=name, description=ESTIMATORS[name], note=note, runs=int(np.sum(ok)), failures=failures,
        rotvec_deg=np.rad2deg(Rotation.from_matrix(first.R_1_2).as_rotvec()) if first.ok else np.full(3, nan),
        scale_1=first.scale_1, scale_2=first.scale_2,
        rotation_rmse=_rms(rot[r_sel]) if r_sel.any() else nan,
        rotation_bound=_rms(rb[r_sel]) if r_sel.any() else nan,
        scale_rmse=_rms(sca[s_sel]) if s_sel.any() else nan,
        scale_bound=_rms(sb[s_sel]) if s_sel.any() else nan,
        seconds=float(np.median(secs)) if secs.size else nan)


_CSV_COLUMNS = ("estimator", "runs", "failures", "rotvec_x_deg", "rotvec_y_deg", "rotvec_z_deg",
                "scale_1_x", "scale_1_y", "scale_1_z", "scale_2_x", "scale_2_y", "scale_2_z",
                "rotation_rmse_rad", "rotation_bound_rad", "rotation_ratio", "scale_rmse", "scale_bound",
                "scale_ratio", "seconds_per_solve", "note")


@dataclass(frozen=True)
class Comparison:
    """Every estimator on the same data: one recording or the Monte Carlo runs of a scenario.

    Attributes
    ----------
    source : str
        Scenario name, or ``"recording"``.
    description : str
        What the data are.
    estimators : tuple of str
        Estimator names, in row order.
    records : tuple of RunRecord
        Per-run results (one for a recording).
    """

    source: str
    description: str
    estimators: tuple
    records: tuple = field(repr=False)

    @property
    def has_truth(self) -> bool:
        return self.records[0].bound is not None

    @property
    def snr(self) -> float:
        """Mean SNR (Eq. 36) over the runs (NaN for a recording)."""
        return float(np.mean([r.snr for r in self.records]))

    @cached_property
    def rows(self) -> tuple:
        """One :class:`Row` per estimator."""
        return tuple(_row(k, name, self.records) for k, name in enumerate(self.estimators))

    def bound(self, metric: str) -> float:
        """Root-mean-square Cramer-Rao bound over all runs: ``"rotation"`` (rad, with the skew
        prediction of Appendix D) or ``"scale"`` (fraction); NaN without truth."""
        if not self.has_truth:
            return float("nan")
        if metric == "rotation":
            return _rms([r.bound.rotation_expected for r in self.records])
        return _rms([r.bound.scale for r in self.records])

    def row(self, estimator: str) -> Row:
        for r in self.rows:
            if r.estimator == estimator:
                return r
        raise InputError(f"estimator: expected one of {self.estimators}, got {estimator!r}")

    # ---------------------------------------------------------------- formats
    def _title(self) -> str:
        runs = len(self.records)
        head = f"{self.source}: {self.description}"
        if self.has_truth:
            head += f" | {runs} run{'s' if runs > 1 else ''}, SNR {self.snr:.4g}"
        return head

    @property
    def _show_estimates(self) -> bool:
        return len(self.records) == 1 or not self.has_truth

    def _tables(self) -> list[tuple[str, list[str], list[list[str]]]]:
        """``(caption, headers, rows)`` of the estimate table and the accuracy table (human units)."""
        def f(x, fmt):
            return "-" if not np.isfinite(x) else format(x, fmt)

        def vec(v, fmt):
            return "-" if not np.isfinite(v).all() else " ".join(format(x, fmt) for x in v)

        rows = self.rows
        out = []
        if self._show_estimates:
            what = "estimates" if len(self.records) == 1 else "estimates of run 1"
            out.append((what, ["estimator", "rotvec R_1_2 [deg]", "scale_1", "scale_2", "ms / solve"],
                        [[r.estimator, vec(r.rotvec_deg, ".4f"), vec(r.scale_1, ".5f"), vec(r.scale_2, ".5f"),
                          f(r.seconds * 1e3, ".3g")] for r in rows]))
        if self.has_truth:
            err = "error" if len(self.records) == 1 else "RMSE"
            out.append(("errors against the truth (Eq. 37-38) and their ratio to the Cramer-Rao bound",
                        ["estimator", f"rot {err} [mdeg]", "rot / bound", f"scale {err} [%]", "scale / bound",
                         "ms / solve", "failed"],
                        [[r.estimator, f(np.rad2deg(r.rotation_rmse) * 1e3, ".4g"), f(r.rotation_ratio, ".3f"),
                          f(r.scale_rmse * 100, ".4g"), f(r.scale_ratio, ".3f"), f(r.seconds * 1e3, ".3g"),
                          f"{r.failures}/{r.runs + r.failures}" if r.failures else "0"] for r in rows]))
        return out

    def _footer(self) -> list[str]:
        lines = []
        if self.has_truth:
            rb, sb = self.bound("rotation"), self.bound("scale")
            lines.append(f"Cramer-Rao bound (at the truth, true signal): rotation {np.rad2deg(rb) * 1e3:.4g} mdeg, "
                         f"scales {sb * 100:.4g} %")
        lines += [f"{r.estimator}: {r.note}" for r in self.rows if r.note]
        return lines

    def to_markdown(self) -> str:
        """The tables as GitHub Markdown (title, estimate and/or accuracy table, bound and notes)."""
        lines = [f"**{self._title()}**"]
        for caption, headers, rows in self._tables():
            lines += ["", f"*{caption}*", "", "| " + " | ".join(headers) + " |",
                      "|" + "|".join("---" if i == 0 else "---:" for i in range(len(headers))) + "|"]
            lines += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |" for row in rows]
        foot = self._footer()
        if foot:
            lines += [""] + [f"- {x}" for x in foot]
        return "\n".join(lines) + "\n"

    def to_csv(self) -> str:
        """The table as CSV in library units (rad, fraction, seconds), one line per estimator."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(_CSV_COLUMNS)
        for r in self.rows:
            w.writerow([r.estimator, r.runs, r.failures, *(repr(float(v)) for v in r.rotvec_deg),
                        *(repr(float(v)) for v in np.concatenate([r.scale_1, r.scale_2])),
                        *(repr(float(v)) for v in (r.rotation_rmse, r.rotation_bound, r.rotation_ratio,
                                                   r.scale_rmse, r.scale_bound, r.scale_ratio, r.seconds)),
                        r.note])
        return buf.getvalue()

    def rich_tables(self) -> list:
        """The tables as :class:`rich.table.Table` objects."""
        from rich.markup import escape
        from rich.table import Table
        out = []
        for k, (caption, headers, rows) in enumerate(self._tables()):
            t = Table(title=escape(self._title()) if k == 0 else None, caption=escape(caption))
            for i, h in enumerate(headers):
                t.add_column(escape(h), justify="left" if i == 0 else "right", no_wrap=i > 0)
            for row in rows:
                t.add_row(*(escape(c) for c in row))
            out.append(t)
        return out

    def print(self, console=None) -> None:
        """Print the tables, the bound and the notes to the terminal (``rich``)."""
        import sys

        from rich.console import Console
        if console is None:
            console = Console(width=None if sys.stdout.isatty() else 160)
        for t in self.rich_tables():
            console.print(t)
        for line in self._footer():
            console.print(line, highlight=False, markup=False)


def _estimator_list(estimators) -> tuple:
    names = DEFAULT_ESTIMATORS if estimators is None else tuple(estimators)
    for n in names:
        if n not in ESTIMATORS:
            raise InputError(f"estimator: expected names from {', '.join(ESTIMATORS)}, got {n!r}")
    if not names:
        raise InputError("estimators: expected at least one estimator, got none")
    return names


def compare(source="nominal", *, estimators=None, runs: int = 1, seed: int = 0, snr_factor: float = 1.0,
            snr_via: str | None = None, workers: int | None = None, progress: bool = True,
            rate_hz: float = 100.0) -> Comparison:
    """Run every estimator on the same data and tabulate estimates, errors, bounds and times.

    Parameters
    ----------
    source : str, Scenario or (omega_1, omega_2)
        A scenario name (:func:`fusion_gyrocal.evaluate.scenarios.list_scenarios`; ``runs`` realisations
        are simulated), one :class:`~fusion_gyrocal.evaluate.scenarios.Scenario` realisation, or a recording
        as two sample-aligned ``(N, 3)`` rate arrays (rad/s; no truth, so no errors).
    estimators : sequence of str, optional
        Keys of :data:`ESTIMATORS`; default :data:`DEFAULT_ESTIMATORS`.
    runs : int
        Monte Carlo realisations of a named scenario (run ``i`` uses ``rng=[seed, i]``).
    seed : int
        Base seed.
    snr_factor, snr_via
        Scale the scenario's SNR (see :func:`fusion_gyrocal.evaluate.scenarios.make_scenario`).
    workers : int, optional
        Processes for the Monte Carlo runs (default: all cores; 1 runs in this process).
    progress : bool
        Show a progress bar.
    rate_hz : float
        Sample rate of a recording (used by the EKF only).

    Returns
    -------
    Comparison

    Examples
    --------
    >>> from fusion_gyrocal.evaluate.compare import compare
    >>> c = compare("nominal", estimators=["direct", "default"], runs=2, workers=1, progress=False)
    >>> [r.estimator for r in c.rows]
    ['direct', 'default']
    >>> bool(c.row("default").rotation_ratio < 3)
    True
    """
    names = _estimator_list(estimators)
    if isinstance(source, str):
        description = describe_scenario(source, snr_factor=snr_factor, snr_via=snr_via)  # checks the name first
        records = _monte_carlo([(source, snr_factor, snr_via)], int(runs), names, seed, workers, progress)[0]
        return Comparison(source, description, names, tuple(records))
    if isinstance(source, Scenario):
        rec = _evaluate(source, source.omega_1, source.omega_2, names)
        return Comparison(source.name, source.description, names, (rec,))
    try:
        omega_1, omega_2 = source
    except (TypeError, ValueError):
        raise InputError("source: expected a scenario name, a Scenario or a pair (omega_1, omega_2), got "
                         f"{type(source).__name__}") from None
    w1 = as_rates("omega_1", omega_1)
    w2 = as_rates("omega_2", omega_2, length=w1.shape[0])
    rec = _evaluate(None, w1, w2, names, rate_hz=rate_hz)
    return Comparison("recording", f"{w1.shape[0]} sample-aligned samples", names, (rec,))


# ============================================================================================ SNR sweep
@dataclass(frozen=True)
class Slope:
    """Fitted log-log slope of RMSE versus SNR for one estimator (NaN where not defined)."""

    estimator: str
    rotation: float
    scale: float


@dataclass(frozen=True)
class SnrSweep:
    """A scenario at several SNR factors (the paper's Section V sweep).

    Attributes
    ----------
    scenario : str
        Base scenario name.
    via : str
        How the SNR was scaled (``"rate"``, ``"noise"``, ``"samples"``).
    factors : tuple of float
    comparisons : tuple of Comparison
        One per factor.
    """

    scenario: str
    via: str
    factors: tuple
    comparisons: tuple = field(repr=False)

    @property
    def estimators(self) -> tuple:
        return self.comparisons[0].estimators

    @property
    def snr(self) -> np.ndarray:
        return np.array([c.snr for c in self.comparisons])

    def rmse(self, estimator: str, metric: str) -> np.ndarray:
        """RMSE per SNR point of ``metric`` (``"rotation"``, rad, or ``"scale"``, fraction)."""
        attr = {"rotation": "rotation_rmse", "scale": "scale_rmse"}[metric]
        return np.array([getattr(c.row(estimator), attr) for c in self.comparisons])

    def bound(self, metric: str) -> np.ndarray:
        """Root-mean-square Cramer-Rao bound per SNR point (all runs, :meth:`Comparison.bound`)."""
        return np.array([c.bound(metric) for c in self.comparisons])

    def slopes(self) -> tuple:
        """Least-squares slope of ``log RMSE`` against ``log SNR`` per estimator (-1 is the paper's finding)."""
        x = np.log(self.snr)
        out = []
        for name in self.estimators:
            s = []
            for metric in ("rotation", "scale"):
                y = np.log(self.rmse(name, metric))
                ok = np.isfinite(y)
                s.append(float(np.polyfit(x[ok], y[ok], 1)[0]) if ok.sum() >= 2 else float("nan"))
            out.append(Slope(name, *s))
        return tuple(out)

    def bound_slopes(self) -> tuple[float, float]:
        x = np.log(self.snr)
        return tuple(float(np.polyfit(x, np.log(self.bound(m)), 1)[0]) for m in ("rotation", "scale"))


def snr_sweep(scenario: str = "nominal", *, factors=SNR_FACTORS, via: str = "rate", runs: int = 100,
              estimators=None, seed: int = 0, workers: int | None = None, progress: bool = True,
              paired: bool = True) -> SnrSweep:
    """Monte Carlo of ``scenario`` at each SNR factor (all points in one process pool).

    With ``paired`` (default) run ``i`` of every factor uses the seed ``(seed, i)``: the same truth,
    motion and noise draws at every SNR (common random numbers), so the fitted slopes are not
    blurred by realisation-to-realisation spread; through the rate norm or the noise the error of a
    linear estimator then scales exactly with 1 / SNR. ``paired=False`` draws independent
    realisations per factor (seed ``(seed, k + 1, i)`` for factor ``k``): the stricter test of the
    slope. See :func:`compare` for the other parameters.
    """
    names = _estimator_list(estimators)
    factors = tuple(float(f) for f in factors)
    descriptions = [describe_scenario(scenario, snr_factor=f, snr_via=via) for f in factors]  # checks first
    recs = _monte_carlo([(scenario, f, via) for f in factors], int(runs), names, seed, workers, progress, paired)
    comps = tuple(Comparison(scenario if f == 1 else f"{scenario} (SNR x{f:g} via {via})", desc, names, tuple(records))
                  for f, desc, records in zip(factors, descriptions, recs))
    return SnrSweep(scenario, via, factors, comps)


# ============================================================================================ figures
_COLOURS = {"direct": "tab:blue", "default": "tab:orange", "appendix_c": "tab:green",
            "appendix_c_identity": "tab:olive", "rotation_only": "tab:red", "graph": "tab:purple",
            "ekf": "tab:brown"}
_MARKERS = {"direct": "o", "default": "s", "appendix_c": "^", "appendix_c_identity": "v", "rotation_only": "x",
            "graph": "D", "ekf": "P"}
_LINESTYLES = ("-", "--", ":", "-.")


def _save(fig, path):
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=130, bbox_inches="tight")
    return fig


def plot_rmse_vs_snr(sweeps, path=None, *, metrics=("rotation", "scale"), estimators=None, title=None):
    """The paper's RMSE versus SNR on log-log axes (Fig. rmse_rotation / rmse_scale), with the bound.

    Parameters
    ----------
    sweeps : SnrSweep or sequence of SnrSweep
        One line style per sweep (e.g. nominal and weak axis, or rate / noise / samples), one colour
        per estimator; the Cramer-Rao bound of each sweep in black. The legend gives the fitted
        log-log slopes (one per sweep, in line-style order).
    path : str or Path, optional
        Write the figure there (PNG, SVG, PDF from the suffix).
    metrics : sequence of {"rotation", "scale"}
        One panel each: rotation RMSE in mdeg, scale RMSE in %.
    estimators : sequence of str, optional
        Subset of the sweeps' estimators to draw.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib
    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    sweeps = [sweeps] if isinstance(sweeps, SnrSweep) else list(sweeps)
    many = len(sweeps) > 1
    outside = many and len(metrics) == 1  # legend right of a single panel; inside (lower left) otherwise
    fig, axes = plt.subplots(1, len(metrics), figsize=((6.2 + 2.8 * outside) * len(metrics), 5.0), squeeze=False)
    unit = {"rotation": (np.rad2deg(1.0) * 1e3, "rotation RMSE [mdeg]  (Eq. 37)"),
            "scale": (100.0, "scale-factor RMSE [%]  (Eq. 38)")}
    names = sweeps[0].estimators if estimators is None else tuple(estimators)
    for ax, metric in zip(axes[0], metrics):
        k, ylabel = unit[metric]
        slopes = [{s.estimator: getattr(s, metric) for s in sw.slopes()} for sw in sweeps]
        for name in names:
            drawn = []
            for j, sw in enumerate(sweeps):
                y = sw.rmse(name, metric) if name in sw.estimators else np.full(len(sw.factors), np.nan)
                if np.isfinite(y).any():
                    ax.plot(sw.snr, y * k, _LINESTYLES[j % len(_LINESTYLES)], color=_COLOURS.get(name),
                            marker=_MARKERS.get(name), ms=6, mfc="none",
                            label="_" if drawn else name)
                    drawn.append(f"{slopes[j][name]:.2f}")
            if drawn:  # one legend entry per estimator, with its slope in every sweep
                ax.get_lines()[-len(drawn)].set_label(f"{name}: slope {' / '.join(drawn)}")
        bound_slopes = []
        skew = False
        for j, sw in enumerate(sweeps):
            b = sw.bound(metric)
            bound_slopes.append(f"{np.polyfit(np.log(sw.snr), np.log(b), 1)[0]:.2f}")
            skew |= metric == "rotation" and any(r.bound.rotation_skew > 0 for c in sw.comparisons for r in c.records)
            ax.plot(sw.snr, b * k, _LINESTYLES[j % len(_LINESTYLES)], color="black", lw=2.2, alpha=0.6,
                    label="_" if j else "")
        what = "Cramer-Rao bound" + (" (+ Appendix D skew error)" if skew else "")
        ax.get_lines()[-len(sweeps)].set_label(f"{what}: slope {' / '.join(bound_slopes)}")
        if many:  # line styles: one proxy entry per sweep
            for j, sw in enumerate(sweeps):
                ax.plot([], [], _LINESTYLES[j % len(_LINESTYLES)], color="gray",
                        label=f"{_LINESTYLES[j % len(_LINESTYLES)]}  {sw.scenario}, SNR via {sw.via}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        plain = FuncFormatter(lambda v, _: f"{v:g}")
        minor = FuncFormatter(lambda v, _: f"{v:g}" if f"{v:.1e}"[0] in "25" else "")  # label 2x and 5x
        ax.yaxis.set_major_formatter(plain)
        ax.yaxis.set_minor_formatter(minor)
        ax.xaxis.set_major_formatter(plain)
        ax.xaxis.set_minor_formatter(minor)
        ax.set_xlabel("SNR  (Eq. 36)")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
        if many:
            where = dict(loc="upper left", bbox_to_anchor=(1.01, 1.0)) if outside else dict(loc="lower left")
            ax.legend(fontsize=7.5 if outside else 7, title="slopes: " + " / ".join(
                _LINESTYLES[j % len(_LINESTYLES)] for j in range(len(sweeps))), title_fontsize=7.5, **where)
        else:
            ax.legend(fontsize=8, loc="best")
    runs = len(sweeps[0].comparisons[0].records)
    fig.suptitle(title or f"RMSE versus SNR, {runs} Monte Carlo runs per point", fontsize=11)
    fig.tight_layout()
    return _save(fig, path)


def plot_residual_vs_rate(scenarios, path=None, *, estimator: str = "direct", max_points: int = 4000, rng=0):
    """Residual norm versus rate norm (the paper's Fig. residual_gyro), one panel per scenario.

    The residual is Eq. (residual), ``r(k) = w1(k) - A_hat w2(k)`` of the centred rates with the
    estimator's ``A_hat = S1 C S2^-1`` from all the data; rigid pairs give residuals that look like
    noise at every rate, a flexing pair residuals that grow with the rate norm. A binned median is
    drawn over the scatter (at most ``max_points`` points per panel).
    """
    import matplotlib
    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    scenarios = [scenarios] if isinstance(scenarios, Scenario) else list(scenarios)
    fig, axes = plt.subplots(1, len(scenarios), figsize=(5.2 * len(scenarios), 4.2), squeeze=False, sharey=True)
    gen = np.random.default_rng(rng)
    for ax, sc in zip(axes[0], scenarios):
        est = run_estimator(estimator, sc.omega_1, sc.omega_2)
        if not est.ok:
            raise InputError(f"{estimator} failed on {sc.name}: {est.error}")
        A = A_of(est.R_1_2, est.scale_1, est.scale_2) if est.has_scales else est.R_1_2
        m = Moments.from_samples(sc.omega_1, sc.omega_2)
        r = (sc.omega_1 - m.mean_1) - (sc.omega_2 - m.mean_2) @ A.T
        rn = np.rad2deg(np.linalg.norm(r, axis=1))
        wn = np.rad2deg(np.linalg.norm(sc.omega_1, axis=1))
        pick = gen.choice(rn.size, size=min(max_points, rn.size), replace=False)
        flexed = sc.flex_angle is not None
        colour = np.where(sc.flex_angle[pick] > 0, "tab:red", "tab:blue") if flexed else "tab:blue"
        ax.scatter(wn[pick], rn[pick], s=3, c=colour, alpha=0.4, linewidths=0)
        edges = np.quantile(wn, np.linspace(0, 1, 21))
        idx = np.clip(np.searchsorted(edges, wn, side="right") - 1, 0, 19)
        med = [np.median(rn[idx == i]) if np.any(idx == i) else np.nan for i in range(20)]
        ax.plot(0.5 * (edges[1:] + edges[:-1]), med, "k-", lw=2, label="binned median")
        sig = np.rad2deg(np.sqrt(3 * (sc.noise_std[0] ** 2 + sc.noise_std[1] ** 2)))
        ax.axhline(sig, color="gray", ls="--", label="noise level sqrt(3 (s1^2+s2^2))")
        ax.set_yscale("log")
        ax.set_xlabel("rate norm ||omega_1|| [deg/s]")
        ax.set_title(f"{sc.name}" + (" (red: mounting bent)" if flexed else " (rigid)"), fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    axes[0][0].set_ylabel(f"residual norm ||r(k)|| [deg/s]  ({estimator})")
    fig.tight_layout()
    return _save(fig, path)
