"""The gyro-pair factor graph: build it from a seed, solve it (LM or iSAM2), read its covariance.

:class:`GyroPairGraph` puts the factors of :mod:`fusion_gyrocal.graph.factors` into one graph,
solved in batch (Levenberg-Marquardt) or incrementally (iSAM2), with covariances from
``gtsam.Marginals`` (or a sparse solve of the same information for many bias segments), and
returns the result as a :class:`~fusion_gyrocal.core.model.PairCalibration`.
:func:`calibrate_pair_graph` does it all from two rate streams.

Variables (keys in :class:`GraphKeys`)
--------------------------------------
* ``R_1_2`` as a ``gtsam.Rot3`` (right-perturbed by GTSAM: ``R.retract(d) = R Exp(d)``);
* the six log scale factors ``[log scale_1, log scale_2]`` as one 6-vector;
* one combined bias ``b = b_1 - A b_2`` (Eq. 5) per window, 3-vectors, tied by random-walk
  ``BetweenFactorVector`` factors (or one bias shared by all windows: the paper's constant bias,
  and then the windows' moments are merged into a single pair factor, exactly their sum);
* optionally one global log-scale ``g`` (1-vector), absolute scales ``= exp(g) * exp(log scale)``,
  and gyro 1's own bias ``b_1`` (3-vectors, one per call of
  :meth:`GyroPairGraph.add_rotation_increments`) for the rotation-increment factors.

The pair factor constrains only ``b``; the camera factor needs ``b_1``, which is therefore a
separate variable. Each increment's noise is its own ``sigma_rad`` plus gyro 1's white noise
integrated over the interval, independent between increments (visual odometry between consecutive
keyframes; increments formed from noisy absolute orientations are anti-correlated, and the
covariance is then conservative); its correlation with the pair factors through gyro 1's noise is
neglected. A batch solve re-preintegrates the increments at its solution.

Covariance order and conventions follow :mod:`fusion_gyrocal.core.model`: ``[dtheta, scale_1,
scale_2, bias]`` with ``R_true = Exp(dtheta) R_1_2``; GTSAM's right perturbation ``d`` maps to
``dtheta = R_1_2 d``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.gauge import Gauge, null_directions, oblique_projector
from ..core.linear_map import hold_cross_axis, restore_cross_axis
from ..core.model import BIAS, ROT, PairCalibration, mark_undetermined
from ..core.moments import Moments, as_rate_pair, noise_pair, window_moments
from ..core.observability import A_of, per_axis_snr, seed_configuration
from ..core.solve import solve
from ..errors import ConfigurationError, InputError, OptionError
from ..options import Options
from .factors import gtsam, WindowStatistics, gauge_factor, gyro_pair_factor, rotation_increment_factor
from .preintegration import (PreintegratedRotations, RotationIncrements, fit_global_scale_and_bias,
                             preintegrate_rotations)

__all__ = ["GraphKeys", "GraphEstimate", "GyroPairGraph", "calibrate_pair_graph", "GLOBAL_SCALE_GAUGE"]

GAUGE_PRIOR_RATIO = 1e-2        # gauge-prior std relative to the seed's smallest scale std (see GyroPairGraph notes)
GAUGE_FIXED_STD_RATIO = 1e-6    # seed scale stds below this times the largest are gauge-fixed, not measured
GLOBAL_SCALE_GAUGE = "global scale estimated from rotation increments"
MARGINALS_MAX_SEGMENTS = 64     # above: bias-mean covariance by a sparse solve of the same information


# ---------------------------------------------------------------------------------------------- keys
@dataclass(frozen=True)
class GraphKeys:
    """GTSAM keys of the calibration variables (change them to embed in a larger graph).

    Attributes
    ----------
    rotation : int
        ``gtsam.Rot3`` ``R_1_2``.
    log_scale : int
        6-vector ``[log scale_1, log scale_2]``.
    global_scale : int
        1-vector ``g`` (only with ``global_scale=True``).
    bias_symbol, bias_1_symbol : str
        Symbol characters of the per-window combined bias and of gyro 1's bias.
    """

    rotation: int = gtsam.symbol("r", 0)
    log_scale: int = gtsam.symbol("s", 0)
    global_scale: int = gtsam.symbol("g", 0)
    bias_symbol: str = "b"
    bias_1_symbol: str = "c"

    def bias(self, index: int) -> int:
        """Key of the combined bias of bias segment ``index``."""
        return gtsam.symbol(self.bias_symbol, index)

    def bias_1(self, index: int) -> int:
        """Key of gyro 1's bias of rotation-increment segment ``index``."""
        return gtsam.symbol(self.bias_1_symbol, index)


# ---------------------------------------------------------------------------------------------- graph
@dataclass(frozen=True)
class GraphEstimate:
    """Current point estimate (no covariance), cheap to read after each iSAM2 update.

    ``scale_1``/``scale_2`` are in the graph's gauge, or absolute with the global-scale variable;
    ``bias`` is the latest window's.
    """

    R_1_2: np.ndarray
    scale_1: np.ndarray
    scale_2: np.ndarray
    bias: np.ndarray


@dataclass
class _CameraSegment:
    increments: RotationIncrements
    preintegrated: PreintegratedRotations
    measured: np.ndarray          # (K, 3, 3) in gyro 1's frame
    sigma: np.ndarray             # (K,) residual std
    key: int


class GyroPairGraph:
    """Factor graph of one gyro pair, fully set up from a seed calibration.

    Parameters
    ----------
    seed : PairCalibration
        Initial values (typically the direct solution, ``solve(moments, method="direct")``) and its
        configuration class (Lemmas 2-4); its ``noise_std`` is used unless ``noise_std`` is given.
    noise_std : (float, float), optional
        White-noise standard deviation per sample of gyro 1 and gyro 2 (rad/s).
    bias_walk_std : float, optional
        ``None`` (default): one combined bias shared by all windows (the paper's constant bias).
        A float > 0: one bias per window with a random-walk factor between consecutive windows;
        the value is the per-sample random-walk step of the *combined* bias ``b_1 - A b_2`` (rad/s;
        ``sqrt(2) q`` for two gyros whose biases each walk by ``q``). ``numpy.inf``: independent
        window biases (no between factors).
    gauge : str or Gauge
        How the result states the global scale (``"unit_prior"``, ``"fixed"`` or a
        :class:`~fusion_gyrocal.core.gauge.Gauge`); ignored with ``global_scale=True``.
    global_scale : bool
        Add the global log-scale variable ``g`` (absolute scales ``= exp(g) * relative``), to be fixed
        by :meth:`add_rotation_increments`.
    bias_1_walk_std : float, optional
        Per-sample random-walk step of gyro 1's bias ``b_1`` between consecutive
        :meth:`add_rotation_increments` segments (``None``: one ``b_1`` for all of them).
    keys : GraphKeys, optional
    isam2_params : gtsam.ISAM2Params, optional
        Default: ``relinearizeThreshold`` 1e-3, ``relinearizeSkip`` 1.
    parallel_tol_deg : float, optional
        ``None`` (default): keep the seed's configuration class (Lemmas 2-4) as its solver decided it.
        A float: axes closer than this to parallel are treated as parallel (as in
        :func:`fusion_gyrocal.solve`), and the class must be the seed's
        (:func:`~fusion_gyrocal.core.observability.seed_configuration`).

    Notes
    -----
    The gauge (Theorem 2) enters as one tight prior per linked group of scale factors on the
    same nonlinear condition the batch refinement imposes (:meth:`Gauge.apply`), so graph and
    batch solve the same constrained problem -- also near a parallel-axis configuration, where
    the group levels are not exactly free. With ``global_scale`` only the level of scale_1[0]'s
    group is held (``g`` carries the common factor) and the rotation increments fix the rest.
    The priors' std is ``GAUGE_PRIOR_RATIO`` (1e-2) times the seed's smallest scale std: along an
    exact null direction of the data the prior's strength changes neither the estimate (it sits
    on the condition) nor the covariance once projected onto the gauge (:func:`_project_gauge`),
    while far tighter priors make GTSAM's Cholesky report an indeterminate system.
    """

    def __init__(self, seed: PairCalibration, *, noise_std=None, bias_walk_std: float | None = None,
                 gauge="unit_prior", global_scale: bool = False, bias_1_walk_std: float | None = None,
                 keys: GraphKeys | None = None, isam2_params: gtsam.ISAM2Params | None = None,
                 parallel_tol_deg: float | None = None):
        if not isinstance(seed, PairCalibration):
            raise InputError(f"seed: expected a PairCalibration, got {type(seed).__name__}")
        self.seed = seed
        self.noise_std = np.array(noise_pair(seed.noise_std if noise_std is None else noise_std))
        self._noise_source = seed.noise_source if noise_std is None else "user"
        for name, v in (("bias_walk_std", bias_walk_std), ("bias_1_walk_std", bias_1_walk_std)):
            if v is not None and not v > 0:
                raise InputError(f"{name}: expected None, a positive float or inf, got {v}")
        self.bias_walk_std = bias_walk_std
        self.bias_1_walk_std = bias_1_walk_std
        self.gauge = Gauge.parse(gauge)
        self.global_scale = bool(global_scale)
        self.keys = keys or GraphKeys()
        self.configuration = seed_configuration(seed.R_1_2, seed.configuration, parallel_tol_deg)
        self._isam_params = isam2_params
        self._isam: gtsam.ISAM2 | None = None

        self._fixed_factors: list = []       # priors and between factors (never rebuilt)
        self._pairs: list = []               # (WindowStatistics, bias key, factor), see _pair
        self._merged_stale = False           # constant bias: windows merged since the pair factor was built
        self._camera: list[_CameraSegment] = []
        self._camera_factors: list = []
        self._bias_keys: list[int] = []
        self._bias_counts: list[float] = []
        self._window_steps: list[float] = []
        self._n_windows = 0
        self._pair_dirty = False             # constant bias: the merged pair factor changed since the last update
        self._pair_index: int | None = None  # its index inside iSAM2
        self._all_moments = Moments.empty()  # see _moments
        self._unmerged: list = []            # constant bias: window moments not yet merged into _all_moments
        self._pending = gtsam.NonlinearFactorGraph()
        self._pending_values = gtsam.Values()
        self._initial = gtsam.Values()

        k = self.keys
        groups = self.configuration.groups
        # gauge-prior std: 1e-2 of the seed's smallest scale std (see the class notes)
        # (a scale the seed's gauge fixes has a std of zero up to rounding, ~1e-14: not a scale std)
        seed_std = np.sqrt(np.diag(seed.covariance)[3:9]) / np.concatenate([seed.scale_1, seed.scale_2])
        seed_std = seed_std[np.isfinite(seed_std)]
        seed_std = seed_std[seed_std > GAUGE_FIXED_STD_RATIO * seed_std.max(initial=0.0)]
        sigma = GAUGE_PRIOR_RATIO * (float(seed_std.min()) if seed_std.size else 1e-6)
        s1, s2 = (seed.scale_1, seed.scale_2) if self.global_scale else self.gauge.apply(groups, [seed.scale_1,
                                                                                          seed.scale_2])
        self._insert(k.rotation, gtsam.Rot3(seed.R_1_2))
        self._insert(k.log_scale, np.log(np.concatenate([s1, s2])))
        if self.global_scale:
            self._insert(k.global_scale, np.zeros(1))
            # g and the relative log-scales overlap in one direction: hold the level of scale_1[0]'s group
            groups = tuple(g for g in groups if (0, 0) in g)
            self._add_fixed(gauge_factor(Gauge.known_scale(1, 0, float(s1[0])), groups[0], sigma,
                                         log_scale_key=k.log_scale))
        else:
            for group in groups:   # the same nonlinear gauge conditions as the batch refinement
                self._add_fixed(gauge_factor(self.gauge, group, sigma, log_scale_key=k.log_scale))

    # ------------------------------------------------------------------ construction helpers
    def _insert(self, key, value):
        self._initial.insert(key, value)
        self._pending_values.insert(key, value)

    def _add_fixed(self, factor):
        self._fixed_factors.append(factor)
        self._pending.add(factor)

    # ------------------------------------------------------------------ public building
    @property
    def n_windows(self) -> int:
        """Windows added so far."""
        return self._n_windows

    def add_window(self, moments: Moments, *, steps: int | None = None) -> int:
        """Add one window's moments; returns the index of its bias segment.

        With a bias per window the window becomes one gyro-pair factor (plus a random-walk factor
        to the previous bias). With one constant bias the windows' moments are merged and the
        graph holds a single pair factor built from them (exactly the sum of the windows' factors).

        Parameters
        ----------
        moments : Moments
            Statistics of the window (one bias segment, ``segments == 1``).
        steps : int, optional
            Sample steps the window spans, for the random-walk sigma (default: ``moments.count``).
        """
        if not isinstance(moments, Moments):
            raise InputError(f"moments: expected a Moments, got {type(moments).__name__}")
        if moments.segments > 1:
            raise InputError(f"moments: expected one bias segment per window, got {moments.segments}; "
                             "add the windows one by one")
        if moments.count < 2:
            raise InputError(f"window moments: expected at least 2 samples, got {moments.count:g}")
        k = self.keys
        new_segment = self.bias_walk_std is not None or not self._bias_keys
        if new_segment:
            seg = len(self._bias_keys)
            key = k.bias(seg)
            self._insert(key, moments.mean_1 - self.seed.A @ moments.mean_2)   # Eq. (12) at the seed's A
            if seg > 0 and self.bias_walk_std is not None and np.isfinite(self.bias_walk_std):
                n_a = self._window_steps[-1]
                n_b = float(moments.count if steps is None else steps)
                sigma = self.bias_walk_std * np.sqrt(_mean_walk_variance(n_a, n_b))
                self._add_fixed(gtsam.BetweenFactorVector(self._bias_keys[-1], key, np.zeros(3),
                                                          gtsam.noiseModel.Isotropic.Sigma(3, sigma)))
            self._bias_keys.append(key)
            self._bias_counts.append(0.0)
            self._window_steps.append(float(moments.count if steps is None else steps))
        key = self._bias_keys[-1]
        self._bias_counts[-1] += moments.count
        self._n_windows += 1
        if self.bias_walk_std is None:
            # one shared bias: the merged moments give exactly the sum of the windows' costs, so the
            # graph keeps ONE pair factor, replaced as windows arrive (iSAM2 removes the old one); it is
            # built from the merged moments when the graph is next read (:attr:`_pair`)
            self._unmerged.append(moments)
            self._merged_stale = True
            self._pair_dirty = True
        else:
            stats = WindowStatistics.from_moments(moments)
            factor = gyro_pair_factor(stats, self.noise_std, rotation_key=k.rotation, log_scale_key=k.log_scale,
                                      bias_key=key)
            self._pairs.append((stats, key, factor))
            self._pending.add(factor)
            self._all_moments = self._all_moments.pool(moments)
        return len(self._bias_keys) - 1

    @property
    def _moments(self) -> Moments:
        """The moments of every window added: merged (one constant bias) or pooled (a bias per window)."""
        if self._unmerged:
            self._all_moments = Moments.merge_all([self._all_moments, *self._unmerged])
            self._unmerged = []
        return self._all_moments

    @property
    def _pair(self) -> list:
        """The pair factors as ``(WindowStatistics, bias key, factor)``: one per window with a bias per window;
        with one constant bias, the single factor of the merged moments (built here once per change)."""
        if self._merged_stale:
            stats = WindowStatistics.from_moments(self._moments)
            factor = gyro_pair_factor(stats, self.noise_std, rotation_key=self.keys.rotation,
                                      log_scale_key=self.keys.log_scale, bias_key=self._bias_keys[0])
            self._pairs = [(stats, self._bias_keys[0], factor)]
            self._merged_stale = False
        return self._pairs

    def add_rotation_increments(self, omega_1, rate_hz: float, increments: RotationIncrements) -> int:
        """Add external rotation increments (e.g. camera keyframes) that fix the global scale.

        With ``bias_1_walk_std`` set, each call adds one gyro-1 bias variable ``b_1`` shared by its
        increments, tied to the previous call's by a random walk; otherwise every call shares one
        ``b_1``. Returns the index of the ``b_1`` segment used.

        Parameters
        ----------
        omega_1 : array_like (N, 3)
            Gyro 1's measured rates (rad/s) that ``increments`` index into, uniform at ``rate_hz``.
        rate_hz : float
        increments : RotationIncrements

        Raises
        ------
        ConfigurationError
            If the graph was built without ``global_scale=True``.
        """
        if not self.global_scale:
            raise ConfigurationError("rotation increments fix the global scale: build the graph with "
                                     "global_scale=True (got global_scale=False)")
        if len(increments) == 0:
            raise InputError("rotation increments: expected at least one increment, got 0")
        k = self.keys
        measured = increments.in_gyro_frame()
        # residual std: the increment's own plus gyro 1's white noise integrated over the interval
        duration = (increments.stop - increments.start) / float(rate_hz)
        sigma = np.sqrt(increments.sigma_rad**2 + (self.noise_std[0] / self.seed.scale_1.min())**2
                        * duration / float(rate_hz))
        # linearization point: the current estimate; for the first increments a Gauss-Newton fit of
        # (g, b_1) alone, so that the first-order preintegration starts close to the solution
        l_rel = self._current_vector(k.log_scale)[:3]
        g0 = float(self._current_vector(k.global_scale)[0])
        b0 = self._current_vector(self._camera[-1].key) if self._camera else np.zeros(3)
        if not self._camera and not (self._isam is not None and self._isam.valueExists(k.global_scale)):
            g0, b0 = fit_global_scale_and_bias(omega_1, rate_hz, increments, measured, sigma, l_rel, g0, b0)
            self._initial.update(k.global_scale, np.array([g0]))
            self._pending_values.update(k.global_scale, np.array([g0]))
        if not self._camera or self.bias_1_walk_std is not None:
            seg = len({c.key for c in self._camera})
            key = k.bias_1(seg)
            self._insert(key, b0)
            if self._camera and np.isfinite(self.bias_1_walk_std):
                n_a = float(self._camera[-1].preintegrated.steps.sum())
                n_b = float((increments.stop - increments.start).sum())
                sd = self.bias_1_walk_std * np.sqrt(_mean_walk_variance(n_a, n_b))
                self._add_fixed(gtsam.BetweenFactorVector(self._camera[-1].key, key, np.zeros(3),
                                                          gtsam.noiseModel.Isotropic.Sigma(3, sd)))
        else:
            seg, key = 0, self._camera[0].key
        pre = preintegrate_rotations(omega_1, rate_hz, increments, scale_1=np.exp(g0 + l_rel), bias_1=b0)
        cam = _CameraSegment(increments, pre, measured, sigma, key)
        self._camera.append(cam)
        for f in self._camera_segment_factors(cam):
            self._camera_factors.append(f)
            self._pending.add(f)
        return seg

    def _current_vector(self, key) -> np.ndarray:
        if self._isam is not None and self._isam.valueExists(key):
            return np.asarray(self._isam.calculateEstimateVector(key))
        return np.asarray(self._initial.atVector(key))

    def _camera_segment_factors(self, cam: _CameraSegment):
        k = self.keys
        return [rotation_increment_factor(cam.preintegrated, i, cam.measured[i], cam.sigma[i],
                                          global_scale_key=k.global_scale, log_scale_key=k.log_scale,
                                          bias_1_key=cam.key)
                for i in range(len(cam.increments))]

    # ------------------------------------------------------------------ graphs
    @property
    def graph(self) -> gtsam.NonlinearFactorGraph:
        """All factors added so far (a new graph; the factors are shared)."""
        g = gtsam.NonlinearFactorGraph()
        for f in self._fixed_factors:
            g.add(f)
        for _, _, f in self._pair:
            g.add(f)
        for f in self._camera_factors:
            g.add(f)
        return g

    @property
    def initial_values(self) -> gtsam.Values:
        """Initial values of every variable added so far (a copy)."""
        return gtsam.Values(self._initial)

    # ------------------------------------------------------------------ solving
    def _check_ready(self):
        if not self._pair:
            raise InputError("graph: expected at least one window (add_window) before solving, got none")
        if self.global_scale and not self._camera:
            raise ConfigurationError("global_scale=True needs rotation increments (add_rotation_increments) to "
                                     "fix the global scale; none were added")

    def _repreintegrate(self, values):
        g = values.atVector(self.keys.global_scale)[0]
        ls1 = g + values.atVector(self.keys.log_scale)[:3]
        moved = 0.0
        self._camera_factors = []
        for i, cam in enumerate(self._camera):
            b1 = values.atVector(cam.key)
            pre = cam.preintegrated
            moved = max(moved, float(np.max(np.abs(ls1 - pre.log_scale_1))),
                        float(np.max(np.abs(b1 - pre.bias_1)) * pre.duration.max()))
            cam = _CameraSegment(cam.increments, pre.relinearized(ls1, b1), cam.measured, cam.sigma, cam.key)
            self._camera[i] = cam
            self._camera_factors.extend(self._camera_segment_factors(cam))
        return moved

    def solve(self, *, max_iterations: int = 100, relative_tol: float = 1e-10, passes: int = 3) -> PairCalibration:
        """Batch Levenberg-Marquardt over every factor added so far; covariance from ``gtsam.Marginals``.

        With rotation increments, these are re-preintegrated at the solution and, if the
        linearization point moved, the graph is solved again from there (up to ``passes`` solves).
        """
        self._check_ready()
        values = self.initial_values
        iterations = 0
        for _ in range(passes):
            params = gtsam.LevenbergMarquardtParams()
            params.setMaxIterations(max_iterations)
            params.setRelativeErrorTol(relative_tol)
            params.setAbsoluteErrorTol(0.0)
            opt = gtsam.LevenbergMarquardtOptimizer(self.graph, values, params)
            values = opt.optimize()
            iterations += opt.iterations()
            if not self._camera or self._repreintegrate(values) < 1e-7:
                break
        return self._result(values, lambda: gtsam.Marginals(self.graph, values), "graph_lm", iterations)

    def update(self) -> GraphEstimate:
        """Push the factors and variables added since the last call into iSAM2; return the estimate.

        Rotation increments keep their first preintegration point (first-order corrections in
        ``log scale_1`` and ``b_1``, as in IMU preintegration); :meth:`result` gives the covariance.
        """
        self._check_ready()
        if self._isam is None:
            params = self._isam_params
            if params is None:
                params = gtsam.ISAM2Params()
                params.setRelinearizeThreshold(1e-3)
                params.relinearizeSkip = 1
            self._isam = gtsam.ISAM2(params)
        remove = []
        if self._pair_dirty:
            self._pending.add(self._pair[0][2])
            if self._pair_index is not None:
                remove = [self._pair_index]
        res = self._isam.update(self._pending, self._pending_values, remove)
        if self._pair_dirty:
            self._pair_index = int(res.getNewFactorsIndices()[-1])
            self._pair_dirty = False
        self._pending = gtsam.NonlinearFactorGraph()
        self._pending_values = gtsam.Values()
        k = self.keys
        R = self._isam.calculateEstimateRot3(k.rotation).matrix()
        l = self._isam.calculateEstimateVector(k.log_scale)
        if self.global_scale:
            l = l + self._isam.calculateEstimateVector(k.global_scale)[0]
        b = self._isam.calculateEstimateVector(self._bias_keys[-1])
        return GraphEstimate(R, np.exp(l[:3]), np.exp(l[3:]), b)

    def result(self) -> PairCalibration:
        """The iSAM2 estimate of everything pushed by :meth:`update`, with its joint marginal covariance."""
        if self._isam is None:
            raise InputError("graph: call update() before result() (no iSAM2 estimate yet)")
        if self._pending.size() or self._pending_values.size() or self._pair_dirty:
            self.update()
        values = self._isam.calculateEstimate()
        return self._result(values, lambda: self._isam, "graph_isam2", 0)

    # ------------------------------------------------------------------ result
    def _result(self, values, marginals, method: str, iterations: int) -> PairCalibration:
        k = self.keys
        R = values.atRot3(k.rotation).matrix()
        l = values.atVector(k.log_scale).copy()
        n_b = len(self._bias_keys)
        x_keys = [k.rotation, k.log_scale] + ([k.global_scale] if self.global_scale else [])
        weights = np.asarray(self._bias_counts) / np.sum(self._bias_counts)
        P = _joint_covariance(self, values, marginals, x_keys, weights)
        g = values.atVector(k.global_scale)[0] if self.global_scale else None
        s1, s2, C, gauge, scale_observable = _pair_covariance(P, R, l, g, self.gauge, self.configuration)
        bias_values = np.array([values.atVector(b) for b in self._bias_keys])
        bias = weights @ bias_values
        A = A_of(R, s1, s2)
        ssr = sum(stats.cost(A, values.atVector(b)) for stats, b, _ in self._pair)
        n = self._moments.count
        notes = []
        if self.global_scale:
            notes.append(f"gyro 1 bias b_1 estimated for the rotation increments "
                         f"({len({c.key for c in self._camera})} segment(s))")
        if self.bias_walk_std is not None:
            notes.append(f"combined bias modelled per window ({n_b} windows); 'bias' is their count-weighted mean")
        return PairCalibration(
            R_1_2=R, scale_1=s1, scale_2=s2, bias=bias, configuration=self.configuration.name,
            scale_observable=scale_observable, covariance=C, gauge=gauge,
            snr=per_axis_snr(self._moments, self.noise_std), n_samples=int(round(n)), noise_std=self.noise_std,
            noise_source=self._noise_source, residual_rms=float(np.sqrt(ssr / (3.0 * max(n - n_b, 1.0)))),
            method=method,
            iterations=int(iterations), time_offset_s=self.seed.time_offset_s,
            time_offset_std_s=self.seed.time_offset_std_s, bias_segments=n_b, notes=tuple(notes))


def _joint_covariance(gg: GyroPairGraph, values, marginals, x_keys, weights) -> np.ndarray:
    """Covariance of ``[x_keys..., sum_i weights_i b_i]`` (tangent spaces of the keys) of the graph ``gg``.

    Up to :data:`MARGINALS_MAX_SEGMENTS` bias segments: ``jointMarginalCovariance`` over every key
    of what ``marginals()`` returns (``gtsam.Marginals`` or iSAM2; built only then). Beyond, that
    dense joint marginal grows cubically, so the same Gauss-Newton information ``J^T J`` of the
    graph linearised at ``values`` is factorised sparsely and solved for the few columns needed.
    """
    nb = len(gg._bias_keys)
    dx = 10 if gg.global_scale else 9
    if nb <= MARGINALS_MAX_SEGMENTS:
        try:
            P = np.asarray(marginals().jointMarginalCovariance(x_keys + gg._bias_keys).fullMatrix())
        except RuntimeError as exc:
            if "Indeterminate linear system" not in str(exc):
                raise
            raise ConfigurationError(
                "graph: the covariance is undetermined (gtsam: indeterminate linear system); the graph's "
                "linearisation leaves a direction free on this data (seen on axis-parallel boards, Lemmas 2-3): "
                "use calibrate_pair, which reports undetermined scale factors as ratios") from None
        T = np.zeros((dx + 3, dx + 3 * nb))
        T[:dx, :dx] = np.eye(dx)
        T[dx:, dx:] = np.kron(weights[None, :], np.eye(3))
        return T @ P @ T.T
    return _sparse_covariance(gg.graph, values, _key_dims(gg), x_keys, gg._bias_keys, weights)


def _key_dims(gg: GyroPairGraph) -> dict:
    """The tangent dimension of every key of the graph ``gg``."""
    k = gg.keys
    dims = {k.rotation: 3, k.log_scale: 6, k.global_scale: 1}
    dims.update({b: 3 for b in gg._bias_keys})
    dims.update({c.key: 3 for c in gg._camera})
    return dims


def _pair_covariance(P, R, l, g, gauge, configuration):
    """``(s1, s2, covariance, gauge text, scale_observable)`` of the pair result from the graph's covariance ``P`` of
    ``[d_right (3), dl (6), (dg), d mean bias]`` at ``R`` and log scales ``l`` (``g``: the global log-scale, None
    without that variable)."""
    d = 9 if g is None else 10
    # linear map from [d_right (3), dl (6), (dg), d mean bias] to [dtheta, dlog s1, dlog s2, d mean bias]
    T = np.zeros((12, d + 3))
    T[ROT, :3] = R                                         # dtheta = R d (left vs right perturbation)
    T[3:9, 3:9] = np.eye(6)
    if g is not None:
        T[3:9, 9] = 1.0                                    # absolute log-scale = g + l
        l = l + g
    T[BIAS, d:] = np.eye(3)
    C = T @ P @ T.T
    C = 0.5 * (C + C.T)
    s1, s2 = np.exp(l[:3]), np.exp(l[3:])
    scale_observable = np.ones((2, 3), bool)
    if g is not None:
        text = GLOBAL_SCALE_GAUGE
    else:
        groups = configuration.groups
        s1, s2 = gauge.apply(groups, [s1, s2])
        C = _project_gauge(C, gauge, groups, s1, s2)
        text = gauge.describe()
        scale_observable = configuration.scale_observable
    J = np.eye(12)                                         # log-scale -> scale
    J[3:9, 3:9] = np.diag(np.concatenate([s1, s2]))
    return s1, s2, mark_undetermined(J @ C @ J.T, scale_observable), text, scale_observable


def _sparse_covariance(graph, values, dims: dict, x_keys, bias_keys, weights) -> np.ndarray:
    """``E^T (J^T J)^-1 E`` from the graph's whitened Jacobian at ``values`` (sparse LU).

    ``E`` selects the ``x_keys`` columns and forms ``sum_i weights_i b_i``; same linearisation as
    ``gtsam.Marginals`` (Gauss-Newton information), without the dense joint over every bias.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import splu

    offsets, col = {}, 0
    for key in list(x_keys) + list(bias_keys) + [key for key in dims if key not in x_keys and key not in bias_keys]:
        if values.exists(key) and key not in offsets:
            offsets[key] = col
            col += dims[key]
    lin = graph.linearize(values)
    rows, cols, vals, row0 = [], [], [], 0
    for i in range(lin.size()):
        f = lin.at(i)
        A, _ = f.jacobian()
        c0 = 0
        for key in f.keys():
            block = A[:, c0:c0 + dims[key]]
            r, c = np.nonzero(block)
            rows.append(r + row0)
            cols.append(c + offsets[key])
            vals.append(block[r, c])
            c0 += dims[key]
        row0 += A.shape[0]
    J = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(row0, col)).tocsc()
    H = (J.T @ J).tocsc()
    dx = sum(dims[key] for key in x_keys)
    E = np.zeros((col, dx + 3))
    E[:dx, :dx] = np.eye(dx)
    for w, key in zip(weights, bias_keys):
        E[offsets[key]:offsets[key] + 3, dx:] = w * np.eye(3)
    Y = splu(H).solve(E)
    P = E.T @ Y
    return 0.5 * (P + P.T)


def _mean_walk_variance(n_a: float, n_b: float) -> float:
    """Variance (in random-walk steps) of the difference of a walk's means over two adjacent windows.

    For windows of ``n_a`` and ``n_b`` steps: ``(n_a-1)(2n_a-1)/(6 n_a) + (n_b+1)(2n_b+1)/(6 n_b)``,
    i.e. ``(2n^2 + 1)/(3n)`` for equal windows (about 2/3 of the point-to-point ``n``).
    """
    n_a, n_b = max(float(n_a), 1.0), max(float(n_b), 1.0)
    return (n_a - 1.0) * (2.0 * n_a - 1.0) / (6.0 * n_a) + (n_b + 1.0) * (2.0 * n_b + 1.0) / (6.0 * n_b)


def _project_gauge(C, gauge: Gauge, groups, s1, s2) -> np.ndarray:
    """Move a covariance of ``[dtheta, dlog s1, dlog s2, db]`` onto the gauge's constraint surface.

    Shifting the log-scales of a linked group by a common amount leaves ``A`` (hence every factor)
    unchanged, so the oblique projection along those null directions onto the linearised gauge
    conditions (:func:`~fusion_gyrocal.core.gauge.oblique_projector`) re-expresses the covariance in
    the gauge without changing anything the data determine.
    """
    G = np.zeros((len(groups), 12))
    G[:, :9] = gauge.constraints(groups, [s1, s2], 3)
    N = np.zeros((12, len(groups)))
    N[3:9] = null_directions(groups, 2)
    T = oblique_projector(N, G)
    out = T @ C @ T.T
    return 0.5 * (out + out.T)


def calibrate_pair_graph(omega_1, omega_2, options: Options | None = None, *, window: int = 1000,
                         bias_walk_std: float | None = None, rotation_increments: RotationIncrements | None = None,
                         rate_hz: float | None = None, solver: str = "lm", seed: PairCalibration | None = None,
                         mask=None, **keywords) -> PairCalibration:
    """Calibrate a sample-aligned gyro pair with the factor graph (windows of ``window`` samples).

    Parameters
    ----------
    omega_1, omega_2 : array_like (N, 3)
        Measured rates (rad/s) at the same instants.
    options : Options, optional
        :class:`~fusion_gyrocal.options.Options`; an option that does not apply to the graph (``applies_to``
        without ``"graph"``) set away from its default is refused. The ones used:

        ``noise_std``
            Per-sample white noise of gyro 1 and 2 (rad/s); default: the seed's.
        ``gauge``
            Gauge of the relative scale factors (ignored when ``rotation_increments`` fix the global scale).
        ``parallel_tol_deg``
            Near-parallel tolerance of the configuration class (Lemmas 2-3), as in :func:`fusion_gyrocal.solve`;
            left at its default: the solver's for the direct seed, the seed's own class for a given ``seed``.
    window : int
        Samples per window factor (and per bias segment when ``bias_walk_std`` is set).
    bias_walk_std : float, optional
        The graph's own bias model, see :class:`GyroPairGraph` (``None``: one constant bias; ``inf``: free
        segments). Not the option of the same name (a random walk per gyro for the pair pipeline's filter),
        which the graph refuses.
    rotation_increments : RotationIncrements, optional
        External orientation increments on gyro 1's sample grid; adds the global-scale variable.
    rate_hz : float, optional
        Sample rate, required with ``rotation_increments``.
    solver : {"lm", "isam2"}
        Batch Levenberg-Marquardt, or iSAM2 updated window by window.
    seed : PairCalibration, optional
        Initial values; default the direct solution ``solve(moments, method="direct")``. A seed with the full
        linear map (``linear_map="full"``, e.g. ``calibrate_pair``'s on a board with cross-axis terms) has its
        cross-axis terms held fixed (:func:`~fusion_gyrocal.core.linear_map.hold_cross_axis`) and the result is
        in the same full map and rotation convention.
    mask : array_like of bool (N,), optional
        Samples to use.
    **keywords
        Fields of :class:`~fusion_gyrocal.options.Options` (``noise_std``, ``gauge``, ``parallel_tol_deg``),
        applied on top of ``options``.

    Returns
    -------
    PairCalibration
        ``method`` ``"graph_lm"`` or ``"graph_isam2"``; ``bias`` the count-weighted mean of the window
        biases; covariance from the graph's marginals in the order of :mod:`fusion_gyrocal.core.model`.

    Examples
    --------
    >>> from fusion_gyrocal.graph import calibrate_pair_graph
    >>> from fusion_gyrocal.evaluate.sim import simulate_pair
    >>> sim = simulate_pair(rng=0)
    >>> cal = calibrate_pair_graph(sim.omega_1, sim.omega_2, noise_std=sim.noise_std, window=500)
    >>> cal.method, cal.bias_segments
    ('graph_lm', 1)
    """
    o = Options.of(options, **keywords).require("graph", "calibrate_pair_graph")
    noise_std, gauge = o.noise_std, o.gauge
    parallel_tol_deg = o.parallel_tol_deg if "parallel_tol_deg" in o.to_dict() else None
    if solver not in ("lm", "isam2"):
        raise OptionError(f"solver: expected 'lm' or 'isam2', got {solver!r}")
    if rotation_increments is not None and rate_hz is None:
        raise ConfigurationError("rotation_increments need rate_hz (the sample rate of omega_1), got None")
    w1, w2, mask = as_rate_pair(omega_1, omega_2, mask)
    held = seed
    if seed is not None:      # a full-map seed: its cross-axis terms held, gyro 1 through (I + K)^-1
        seed, unmix = hold_cross_axis(seed)
        if unmix is not None:
            w1 = w1 @ unmix.T
    windows = window_moments(w1, w2, window, mask=mask, with_starts=True)
    if not windows:
        raise InputError(f"expected at least one window of >= 2 samples, got {w1.shape[0]} samples")
    if seed is None:
        parts = [m for _, m in windows]
        total = Moments.pool_all(parts) if bias_walk_std is not None else Moments.merge_all(parts)
        seed = solve(total, o, method="direct")
    glob = rotation_increments is not None
    g = GyroPairGraph(seed, noise_std=noise_std, bias_walk_std=bias_walk_std, gauge=gauge, global_scale=glob,
                      parallel_tol_deg=parallel_tol_deg,
                      bias_1_walk_std=(bias_walk_std / np.sqrt(2.0) if bias_walk_std is not None else None))
    for start, m in windows:
        g.add_window(m)
        if glob:
            sel = (rotation_increments.start >= start) & (rotation_increments.start < start + window)
            if sel.any():
                g.add_rotation_increments(w1, rate_hz, rotation_increments.subset(sel))
        if solver == "isam2" and (not glob or g._camera):
            g.update()
    result = g.result() if solver == "isam2" else g.solve()
    return result if held is None else restore_cross_axis(result, held)
