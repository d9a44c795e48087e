"""Configuration of the online tracker: one frozen :class:`TrackerConfig` (and its noise types).

Everything that configures a :class:`~fusion_gyrocal.online.tracker.GyroPairTracker` lives in one
frozen object, checked once on construction. A tracker never caches a value that its configuration
could change behind its back: to change the configuration, build a new tracker
(:meth:`~fusion_gyrocal.online.tracker.GyroPairTracker.reconfigured` continues from the current state).

Examples
--------
>>> from fusion_gyrocal.online.config import DriftNoise, TrackerConfig
>>> cfg = TrackerConfig(drift=DriftNoise.constant(), cusum_threshold=40.0)
>>> cfg.replace(gate_probability=0.99).gate_probability
0.99
>>> cfg.gauge.describe()
'unit prior on scale_1[0], scale_2[0] (Eq. 32-34)'
>>> cfg.drift = DriftNoise()
Traceback (most recent call last):
...
dataclasses.FrozenInstanceError: cannot assign to field 'drift'
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.stats import chi2

from ..core.gauge import Gauge
from ..errors import OptionError
from ..options import FrozenOptions

HISTORY_MAX_ROWS = 1 << 16
"""Default bound on the rows of a tracker's history (:attr:`TrackerConfig.history_max_rows`)."""


def _check_densities(obj, what: str) -> None:
    for name in ("rotation", "log_scale", "bias"):
        v = getattr(obj, name)
        if not (isinstance(v, (int, float, np.floating, np.integer)) and np.isfinite(v) and v >= 0):
            raise OptionError(f"{type(obj).__name__}.{name}: expected a finite {what} >= 0, got {v!r}")


@dataclass(frozen=True)
class DriftNoise:
    """Random-walk densities of the tracked parameters (physical units).

    Attributes
    ----------
    rotation : float
        Rotation random walk, rad/sqrt(s) per axis (default 3e-5, about 0.1 deg/sqrt(h)).
    log_scale : float
        Relative scale-factor random walk, 1/sqrt(s) per scale factor (default 1e-4, about
        0.6 %/sqrt(h)).
    bias : float
        Combined-bias random walk, rad/s/sqrt(s) per axis (default 1.41e-5: the paper's bias
        walk, 57.3 micro-deg/s per 10 ms step for each gyro, Section V).
    """

    rotation: float = 3e-5
    log_scale: float = 1e-4
    bias: float = 1.41e-5

    def __post_init__(self):
        _check_densities(self, "density")

    @classmethod
    def constant(cls) -> "DriftNoise":
        """No drift: the filter becomes a recursive least-squares estimator of constant parameters."""
        return cls(0.0, 0.0, 0.0)


@dataclass(frozen=True)
class StepPrior:
    """1-sigma size of a step change (a shock), added to the covariance when one is detected.

    Attributes
    ----------
    rotation : float
        rad per axis (default 1 deg).
    log_scale : float
        Relative scale-factor change (default 0.01).
    bias : float
        rad/s per axis (default 0.5 deg/s).
    """

    rotation: float = np.pi / 180.0
    log_scale: float = 0.01
    bias: float = 0.5 * np.pi / 180.0

    def __post_init__(self):
        _check_densities(self, "std")


@dataclass(frozen=True)
class TrackerConfig(FrozenOptions):
    """Everything that configures a :class:`~fusion_gyrocal.online.tracker.GyroPairTracker` (frozen).

    Attributes
    ----------
    drift : DriftNoise
        Random-walk densities of the tracked parameters (the process noise, ``Q = q^2 dt``).
    step_prior : StepPrior
        Covariance added at a step alarm so the filter follows a step at once (and says so in its
        bands) while the confirming batch window fills.
    gauge : Gauge
        Gauge of the scale group that holds its members (``"unit_prior"``, ``"fixed"`` or a
        :class:`~fusion_gyrocal.core.gauge.Gauge`; a string is parsed). Give the seed's gauge.
    scale_prior_std : float
        Prior 1-sigma (relative) of the common factor of each parallel axis pair in a degenerate
        configuration; also replaces the seed's infinite scale variances.
    gate_probability : float
        Per-sample chi-square(3) acceptance probability of the innovation gate.
    gate_neighbours : int
        Samples removed on each side of a gated sample inside a block; the ones after a gated
        sample are removed in the next block too (a sample already folded is never revisited).
    cusum_drift, cusum_threshold : float
        CUSUM on ``min(d^2, gate) / 3 - 1``: allowance per sample and alarm level.
    reseed_window_s : float
        Data after the estimated onset used for the re-seeding batch solve.
    reseed_max_s : float
        Give up re-seeding (the motion never excited all axes enough) after this long.
    reseed_probability : float
        Chi-square quantile for accepting a re-seed: the difference between the batch solve and the
        filter at the alarm in the rotation and the scale factors (the extrinsic part; a step of the
        combined bias alone is absorbed by the filter, not re-seeded).
    reseed_min_spread : float
        A re-seed window must excite every direction: the smallest eigenvalue of the scatter of gyro 1
        that gyro 2 explains (:func:`fusion_gyrocal.core.observability.explained_scatter`) over the
        largest, at least this. A window dominated by one axis (a turn between two poses) leaves the
        rotation about that axis to a few degrees of off-axis motion and to the misfit; the tracker then
        waits for more data after the onset (up to ``reseed_max_s``) and otherwise keeps its estimate.
    buffer_samples : int
        Capacity of the ring buffer of recent samples (re-seed windows and replays).
    reseed_solver : callable ``(omega_1, omega_2) -> PairCalibration`` or None
        Batch solver for re-seeding; default :func:`fusion_gyrocal.calibrate_pair` with the
        tracker's noise and gauge (and its flex rejection).
    block_size : int
        Samples per block of :meth:`~fusion_gyrocal.online.tracker.GyroPairTracker.run` in the fast
        mode when the call does not give one.
    noise_memory : int
        Samples per rate bin over which the tracker adapts its measurement noise to the innovations
        (:class:`~fusion_gyrocal.online.adapt.NoiseScale`: a factor of the modelled covariance per
        ``|omega|`` bin, >= 1 except where the seed window did not reach, so that the normalised innovations
        the CUSUM screens stay near 1 and the covariance covers the model error). 0: no adaptation (the
        modelled noise as it is).
    history_max_rows : int or None
        Bound on the rows of the tracker's history (264 bytes each; default :data:`HISTORY_MAX_ROWS`,
        65536 rows, 17 MiB). When reached, every other row is dropped and then only every 2nd (4th, ...)
        update is recorded: memory stays flat over any run, the rows evenly spread over it. None: the full
        history, one row per update, unbounded (what a run with a truth needs when it makes more updates
        than the bound; :meth:`~fusion_gyrocal.online.tracker.GyroPairTracker.run` says so).
    gate : float
        Derived: the chi-square(3) quantile of ``gate_probability`` (not a constructor argument).
    """

    KIND = "tracker option"
    ARGUMENT = "config"

    drift: DriftNoise = DriftNoise()
    step_prior: StepPrior = StepPrior()
    gauge: Gauge = Gauge.unit_prior()
    scale_prior_std: float = 0.01
    gate_probability: float = 0.999
    gate_neighbours: int = 1
    cusum_drift: float = 0.5
    cusum_threshold: float = 25.0
    reseed_window_s: float = 10.0
    reseed_max_s: float = 60.0
    reseed_probability: float = 0.999
    reseed_min_spread: float = 0.1
    buffer_samples: int = 1 << 15
    reseed_solver: Callable | None = None
    block_size: int = 100
    noise_memory: int = 2000
    history_max_rows: int | None = HISTORY_MAX_ROWS
    gate: float = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if not isinstance(self.drift, DriftNoise):
            raise OptionError(f"drift: expected a DriftNoise, got {type(self.drift).__name__}")
        if not isinstance(self.step_prior, StepPrior):
            raise OptionError(f"step_prior: expected a StepPrior, got {type(self.step_prior).__name__}")
        object.__setattr__(self, "gauge", Gauge.parse(self.gauge))
        if not 0 <= self.reseed_min_spread <= 1:
            raise OptionError(f"reseed_min_spread: expected a value in [0, 1], got {self.reseed_min_spread!r}")
        for name in ("gate_probability", "reseed_probability"):
            if not 0 < getattr(self, name) < 1:
                raise OptionError(f"{name}: expected a value in (0, 1), got {getattr(self, name)!r}")
        for name in ("scale_prior_std", "cusum_threshold"):
            if not getattr(self, name) > 0:
                raise OptionError(f"{name}: expected > 0, got {getattr(self, name)!r}")
        if not np.isfinite(self.cusum_drift):
            raise OptionError(f"cusum_drift: expected a finite allowance, got {self.cusum_drift!r}")
        if not (self.reseed_window_s > 0 and self.reseed_max_s >= self.reseed_window_s):
            raise OptionError(f"reseed_window_s, reseed_max_s: expected 0 < window <= max, got "
                              f"{self.reseed_window_s}, {self.reseed_max_s}")
        for name, low in (("gate_neighbours", 0), ("buffer_samples", 1), ("block_size", 1), ("noise_memory", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise OptionError(f"{name}: expected an integer >= {low}, got {v!r}")
            object.__setattr__(self, name, int(v))
        v = self.history_max_rows
        if v is not None:
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 2:
                raise OptionError(f"history_max_rows: expected an integer >= 2 or None, got {v!r}")
            object.__setattr__(self, "history_max_rows", int(v))
        if self.reseed_solver is not None and not callable(self.reseed_solver):
            raise OptionError(f"reseed_solver: expected a callable or None, got {type(self.reseed_solver).__name__}")
        for name in ("scale_prior_std", "gate_probability", "cusum_drift", "cusum_threshold", "reseed_window_s",
                     "reseed_max_s", "reseed_probability", "reseed_min_spread"):
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "gate", float(chi2.ppf(self.gate_probability, 3)))


