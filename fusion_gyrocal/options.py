"""One frozen options object for every estimator and the command line: :class:`Options`.

Every option is declared once below, with its default, its check, its documentation, its
command-line flag and what it applies to (``applies_to``, a set of :data:`CONSUMERS`):

``"pair"``
    Two gyros from samples: :func:`~fusion_gyrocal.calibrate_pair`,
    :func:`~fusion_gyrocal.pipeline.pipeline.run_pipeline`, the fleet's devices (every option but ``gyros``).
``"moments"``
    A solve from moments only (:func:`~fusion_gyrocal.core.solve.solve`, the streaming calibrator, chunked
    fleet reductions): the options that act on the moments.
``"array"``
    :func:`~fusion_gyrocal.core.array.calibrate_array`: N sample-aligned gyros, jointly.
``"streams"``
    :func:`~fusion_gyrocal.pipeline.array.calibrate_streams`: N timestamped gyros (the array's options and
    those that align and mask recordings).
``"graph"``
    :func:`~fusion_gyrocal.graph.calibrate_pair_graph`.
``"recordings"``
    What aligns and masks a recording pair before estimators that take their own settings (``gyrocal compare``).

Each consumer calls :meth:`Options.require`: an option set away from its default that the consumer
does not apply is refused (:class:`~fusion_gyrocal.errors.OptionError` naming it and what the consumer
takes), never ignored. Per-gyro options (``noise_std``, ``saturation_limit``, ``skew_std``,
``bias_walk_std``) take one value for every gyro or one per gyro; ``gyros`` (default 2) says how
many gyros that is (:meth:`Options.for_gyros`).

Examples
--------
>>> from fusion_gyrocal.options import Options
>>> opts = Options(noise_std=1.7e-3, method="direct")
>>> opts.noise_std, opts.method
((0.0017, 0.0017), 'direct')
>>> opts.replace(method="ml").method
'ml'
>>> Options(method="fast")
Traceback (most recent call last):
...
fusion_gyrocal.errors.OptionError: method: expected one of ('ml', 'direct'), got 'fast'
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field

import numpy as np

from .errors import OptionError

METHODS = ("ml", "direct")
GAUGES = ("unit_prior", "fixed")
COVARIANCES = ("auto", "model", "robust")
NOISE_MODELS = ("identify", "residual")
LINEAR_MAPS = ("auto", "rigid", "full")
TIMING_MODELS = ("auto", "off")
ROBUST_WEIGHTS = ("auto", "off")


# ------------------------------------------------------------------------------------------ checks
def _finite(name, v):
    if isinstance(v, (bool, np.bool_)):   # True is no noise level, duration or rate (float(True) == 1.0)
        raise OptionError(f"{name}: expected a number, got {v!r}")
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise OptionError(f"{name}: expected a number, got {v!r}") from None
    if not math.isfinite(x):
        raise OptionError(f"{name}: expected a finite number, got {v!r}")
    return x


def _positive(name, v):
    x = _finite(name, v)
    if x <= 0:
        raise OptionError(f"{name}: expected a positive number, got {v!r}")
    return x


def _non_negative(name, v):
    x = _finite(name, v)
    if x < 0:
        raise OptionError(f"{name}: expected a number >= 0, got {v!r}")
    return x


def _optional(check):
    def optional(name, v, *gyros):
        return None if v is None else check(name, v, *gyros)
    optional.per_gyro = getattr(check, "per_gyro", False)
    return optional


def _per_gyro(check):
    """One value for every gyro or one per gyro (``gyros`` of them), normalised to a tuple of ``gyros``."""
    def per_gyro(name, v, gyros=2):
        a = np.asarray(v, dtype=object).ravel() if not np.isscalar(v) else np.array([v], dtype=object)
        if a.size not in (1, gyros):
            raise OptionError(f"{name}: expected one value or one per gyro ({gyros}), got {a.size} values: {v!r}")
        vals = tuple(check(name, x) for x in a)
        return vals * gyros if len(vals) == 1 else vals
    per_gyro.per_gyro = True
    return per_gyro


def _angle_below_90(name, v):
    x = _finite(name, v)
    if not 0.0 < x < 90.0:
        raise OptionError(f"{name}: expected an angle in (0, 90) deg, got {v!r}")
    return x


def _choice(choices):
    def choice(name, v):
        if not isinstance(v, str) or v not in choices:
            raise OptionError(f"{name}: expected one of {choices}, got {v!r}")
        return v
    return choice


def _gauge(name, v):
    from .core.gauge import Gauge

    if isinstance(v, Gauge) or (isinstance(v, str) and v in GAUGES):
        return v
    raise OptionError(f"{name}: expected one of {GAUGES} or a Gauge, got {v!r}")


def _flex(name, v):
    if (isinstance(v, str) and v == "auto") or v is True or v is False:
        return v
    raise OptionError(f"{name}: expected 'auto', True or False, got {v!r}")


def _int_at_least(low):
    def check(name, v):
        x = None if isinstance(v, bool) else _finite(name, v)
        if x is None or not x.is_integer() or x < low:
            raise OptionError(f"{name}: expected an integer >= {low}, got {v!r}")
        return int(x)
    return check


def _fraction(name, v):
    x = _finite(name, v)
    if not 0.0 <= x <= 1.0:
        raise OptionError(f"{name}: expected a fraction in [0, 1], got {v!r}")
    return x


def _intrinsics(name, v):
    if v is None:
        return None
    try:
        S = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        S = None
    if S is None or S.shape != (3, 3) or not np.all(np.isfinite(S)) or np.any(np.tril(S, -1) != 0) or np.any(np.diag(S) <= 0):
        raise OptionError(f"{name}: expected an upper-triangular (3, 3) intrinsic matrix with a positive diagonal, "
                          f"got {v if S is None else S.tolist()!r}")
    return tuple(map(tuple, S.tolist()))


def _window_samples(seconds, context) -> int:
    """``--bias-window`` (s) to samples at the recording's rate; refuses what is not a window of >= 2 samples."""
    x = _positive("bias_window (--bias-window, s)", seconds)
    rate = context.get("rate_hz")
    if rate is None:
        raise OptionError("bias_window: --bias-window is in seconds and needs the sample rate; expected --rate "
                          "or a recording, got neither")
    n = int(round(x * rate))
    if n < 2:
        raise OptionError(f"bias_window: expected a window of at least 2 samples ({2 / rate:.3g} s at {rate:g} Hz), "
                          f"got --bias-window {seconds!r} s ({n} sample(s))")
    return n


# ------------------------------------------------------------------------------------------ declaration
CONSUMERS = {
    "pair": "calibrates two gyros from samples",
    "moments": "works from moments only",
    "array": "calibrates N sample-aligned gyros jointly",
    "streams": "calibrates N timestamped gyros jointly",
    "graph": "calibrates a pair with the factor graph",
    "recordings": "aligns and masks a recording pair only",
}
"""What takes options (the values of ``applies_to``), and what each does (for messages)."""

_SOLVE = frozenset({"pair", "moments"})                    # act on the moments
_JOINT = frozenset({"array", "streams"})                   # the joint calibration of N gyros
_RECORDING = frozenset({"pair", "streams", "recordings"})  # align and mask recordings


def _option(default, check, applies_to, doc, flag=None, **cli):
    """Declare one option: default, check (returns the normalised value), what it applies to (a set of
    :data:`CONSUMERS`), documentation, CLI flag.

    ``cli`` holds the argparse keywords of the flag; ``cli["to_option"]``, when given, maps the parsed
    flag value to the option value (``context`` gives the recording's sample rate).
    """
    unknown = sorted(set(applies_to) - set(CONSUMERS))
    if unknown:
        raise OptionError(f"applies_to: expected some of {sorted(CONSUMERS)}, got {unknown}")
    return field(default=default, metadata=dict(check=check, applies_to=frozenset(applies_to), doc=doc, flag=flag,
                                                cli=cli))


class FrozenOptions:
    """Building and changing a frozen options dataclass: :meth:`of` and :meth:`replace`, unknown names refused.

    Shared by :class:`Options` and the tracker's :class:`~fusion_gyrocal.online.config.TrackerConfig`;
    ``KIND`` (class attribute) names the options in messages and ``ARGUMENT`` the parameter that passes them.
    """

    KIND = "option"
    ARGUMENT = "options"

    @classmethod
    def of(cls, options=None, **changes):
        """``options`` (default: the defaults) with ``changes`` applied (each a field name, checked again)."""
        names = [f.name for f in dataclasses.fields(cls) if f.init]
        unknown = sorted(set(changes) - set(names))
        if unknown:
            raise OptionError(f"unknown {cls.KIND}(s) {unknown}; expected some of {sorted(names)}")
        if options is None:
            return cls(**changes)
        if not isinstance(options, cls):
            raise OptionError(f"{cls.ARGUMENT}: expected {cls.__name__}, got {type(options).__name__}")
        return dataclasses.replace(options, **changes) if changes else options

    def replace(self, **changes):
        """A copy with ``changes`` applied (checked again)."""
        return type(self).of(self, **changes)


@dataclass(frozen=True)
class Options(FrozenOptions):
    # --- the solve (moments -> calibration)
    method: str = _option(
        "ml", _choice(METHODS), _SOLVE,
        "Estimator. ``'direct'``: the paper's closed form (Eq. 17, Lemmas 2-4, Eq. 32-34), covariance by "
        "first-order propagation. ``'ml'`` (default): the direct solution refined to the maximum-likelihood "
        "estimate of the errors-in-variables model (Appendix C generalised); covariance = inverse Fisher "
        "information (Appendix B generalised).",
        "--method", choices=METHODS, help="estimator (default ml)")
    noise_std: tuple | None = _option(
        None, _optional(_per_gyro(_positive)), _SOLVE | _JOINT | {"graph"},
        "White-noise std per sample (rad/s), one value or one per gyro. Default: estimated from the "
        "least-squares residual, split between the gyros by their third differences.",
        "--noise-std", type=float, nargs="+", metavar="RAD_S",
        help="white-noise std per sample (rad/s), one value or one per gyro; default: from residuals")
    gauge: object = _option(
        "unit_prior", _gauge, _SOLVE | _JOINT | {"graph"},
        "How the global scale is fixed (Theorem 2): ``'unit_prior'`` (the paper's unit prior on both x axes, "
        "Eq. 32-34), ``'fixed'`` (``scale_1[0] == 1``) or a :class:`~fusion_gyrocal.core.gauge.Gauge`. Ignored "
        "when ``scale_prior_std`` is given.",
        "--gauge", choices=GAUGES, help="global-scale gauge: unit prior on both x axes (paper) or scale_1[0] = 1")
    scale_prior_std: float | None = _option(
        None, _optional(_positive), _SOLVE,
        "Gaussian prior N(1, std^2) on every scale factor (``method='ml'`` only); directions the data do not "
        "fix then take the prior and the covariance says so.",
        "--scale-prior", type=float, metavar="STD", help="Gaussian prior N(1, STD^2) on the scale factors")
    parallel_tol_deg: float = _option(
        5.0, _angle_below_90, _SOLVE | _JOINT | {"graph"},
        "Axes closer than this to parallel (deg) are treated as parallel (Lemmas 2-3).",
        "--parallel-tol", type=float, metavar="DEG",
        help="axes closer than this to parallel are treated as parallel (default 5 deg)")
    intrinsics_1: tuple | None = _option(
        None, _intrinsics, _SOLVE,
        "Manufacturer intrinsic matrix of gyro 1 (upper triangular, (3, 3)); its skew part is compensated "
        "before the solve (Appendix D).")
    intrinsics_2: tuple | None = _option(
        None, _intrinsics, _SOLVE, "As ``intrinsics_1``, for gyro 2.")
    skew_std: tuple = _option(
        0.0, _per_gyro(_non_negative), _SOLVE,
        "Std of the remaining skew error of each gyro; its rotation error (Appendix D, Eq. 40-41) is "
        "reported in ``skew_rotation_covariance`` and added to the covariance.",
        "--skew-std", type=float, nargs="+", metavar="STD",
        help="remaining skew uncertainty for the error budget, one value or one per gyro")
    linear_map: str = _option(
        "auto", _choice(LINEAR_MAPS), _SOLVE | _JOINT,
        "The sensor model (:mod:`~fusion_gyrocal.core.linear_map`). ``'auto'`` (default): the full linear map "
        "(rotation, scale factors and the symmetric relative cross-axis terms) when it fits significantly better "
        "than rotation + scale factors (the cross-axis chi-square, p < 0.001) or when the data determine every "
        "cross-axis term (all axes parallel), else the paper's model; "
        "``'rigid'``: the paper's model ``A = S_1 R S_2^-1`` (Eq. 4) always; ``'full'``: the full map always. "
        "``method='ml'`` only (the direct solution is the paper's).",
        "--linear-map", choices=LINEAR_MAPS,
        help="sensor model: auto (cross-axis terms when the data show them, default), rigid (paper), full")
    cross_axis_std: float = _option(
        0.015, _positive, _SOLVE | _JOINT,
        "Std of each gyro's cross-axis sensitivity (a fraction; MEMS datasheets give 1-2 %): the prior of the "
        "full linear map's relative cross-axis terms where the data do not determine them (the rotation's "
        "uncertainty from their antisymmetric part, which no data see, is as large as the symmetric part: "
        ":func:`~fusion_gyrocal.core.linear_map.cross_axis_budget`, in ``skew_rotation_covariance``).",
        "--cross-axis-std", type=float, metavar="FRACTION",
        help="std of each gyro's cross-axis sensitivity for the full map (default 0.015)")
    covariance: str = _option(
        "auto", _choice(COVARIANCES), _SOLVE | _JOINT,
        "Which covariance is reported (``'ml'`` solves of :func:`~fusion_gyrocal.calibrate_pair`). ``'auto'`` "
        "(default): in every direction the larger of the noise model's (inverse Fisher information) and the "
        "block-robust sandwich from per-window scores (:mod:`~fusion_gyrocal.core.robust`), which covers "
        "coloured noise and model error; ``'model'``: the noise model's alone; ``'robust'``: the sandwich alone.",
        "--covariance", choices=COVARIANCES,
        help="reported covariance: auto (larger of noise model and block-robust), model, robust")
    min_snr: float = _option(
        10.0, _positive, _SOLVE | _JOINT,
        "Smallest SNR of any principal motion direction accepted (Lemma 1).",
        "--min-snr", type=float, help="smallest accepted SNR of any motion direction (default 10)")
    max_unexplained: float = _option(
        0.05, _fraction, _SOLVE,
        "Rigidity test: the pair is not rigid when the least-squares fit leaves more than this fraction of "
        "gyro 1's motion energy unexplained.")
    on_not_rigid: str = _option(
        "raise", _choice(("raise", "flag")), _SOLVE,
        "``'raise'``: :class:`~fusion_gyrocal.errors.NotRigidError`; ``'flag'``: return the result with "
        "``rigid=False``.",
        "--allow-not-rigid", action="store_true", to_option=lambda v, context: "flag" if v else "raise",
        help="report a non-rigid pair (flagged) instead of failing with exit code 3")
    target_snr: float = _option(
        4e3, _positive, _SOLVE,
        "Per-axis SNR the data should reach (Section VI accumulates to 4e3); a note names the axes below it.")
    # --- the pipeline (samples -> moments)
    time_offset_s: float | None = _option(
        None, _optional(_finite), _RECORDING,
        "Known time offset (s), ADDED to gyro 2's timestamps (N gyros: to every other gyro's) to put them on "
        "gyro 1's clock; default: estimated (timestamped input only).",
        "--offset", type=float, help="known time offset (s) added to gyro 2's timestamps; default: estimated")
    max_offset_s: float | None = _option(
        None, _optional(_positive), _RECORDING,
        "Search range (s) of the time-offset estimate; default: every offset that leaves half the shorter "
        "recording overlapping (independent clocks may differ by hours).",
        "--max-offset", type=float, help="offset search range in s (default: the whole overlap)")
    rate_hz: float | None = _option(
        None, _optional(_positive), _RECORDING,
        "Resample both streams onto a uniform grid at this rate (Hz); default: gyro 1's timestamps.",
        "--rate", type=float, help="resample both onto a uniform grid at this rate (Hz)")
    saturation_limit: tuple | None = _option(
        None, _optional(_per_gyro(_positive)), _RECORDING,
        "Sensor range (rad/s) of each gyro for masking clipped samples; default: detect samples sitting flat "
        "at the extreme values.",
        "--saturation-limit", type=float, nargs="+", metavar="RAD_S",
        help="sensor range (rad/s) for masking clipped samples, one value or one per gyro")
    bias_window: int | None = _option(
        None, _optional(_int_at_least(2)), {"pair"} | _JOINT,
        "Model the bias as piecewise constant over windows of this many samples (drifting biases). The "
        "command-line flag is in seconds, converted with the recording's sample rate (``--rate`` when given).",
        "--bias-window", type=float, metavar="SECONDS", to_option=lambda v, context: _window_samples(v, context),
        help="piecewise-constant bias over windows of this length in s (drifting biases)")
    bias_walk_std: tuple | None = _option(
        None, _optional(_per_gyro(_positive)), {"pair"},
        "Bias random-walk step std per sample (rad/s) of each gyro: the exact drifting-bias likelihood "
        "(Kalman innovations filter). Needs ``noise_std``.",
        "--bias-walk", type=float, nargs="+", metavar="RAD_S",
        help="bias random-walk step std per sample (rad/s), one value or one per gyro: the exact drifting-bias "
             "model (needs --noise-std)")
    noise_model: str = _option(
        "identify", _choice(NOISE_MODELS), {"pair"} | _JOINT,
        "Where the noise comes from when ``noise_std`` is not given. ``'identify'`` (default): white noise, bias "
        "random walk and rate-dependent misfit identified from the pair's own residual "
        "(:func:`~fusion_gyrocal.core.noise.identify_noise`), the bias model (constant or random walk) chosen "
        "from it; ``'residual'``: the least-squares residual's variance as white noise, constant bias.",
        "--noise-model", choices=NOISE_MODELS,
        help="noise when --noise-std is not given: identify (Allan fit of the residual, default) or residual")
    timing_model: str = _option(
        "auto", _choice(TIMING_MODELS), {"pair"} | _JOINT,
        "Inter-sensor timing beyond the constant offset (:mod:`~fusion_gyrocal.pipeline.timing`). ``'auto'`` "
        "(default): the delay of gyro 2's samples that follows the beat of each chip's sampling clock against the "
        "read-out, found in the residual along the rate's derivative, compensated when it explains far more than "
        "noise would, and the pair calibrated again (for N gyros: every gyro's delay against the reference, from "
        "its pair's residual, and the array calibrated again); ``'off'``: one constant offset only.",
        "--timing-model", choices=TIMING_MODELS,
        help="delay beyond the constant offset: auto (beat tones of the chips' clocks, default) or off")
    robust_weights: str = _option(
        "off", _choice(ROBUST_WEIGHTS), {"pair"} | _JOINT,
        "Per-sample weights against a heavy-tailed residual (:func:`~fusion_gyrocal.core.weights."
        "residual_weights`). ``'auto'``: after the timing step, when the residual's largest 1 % of samples carry "
        "more than a tenth of its energy, each sample is weighted by the white noise's variance over its residual's "
        "local variance (impacts, transients faster than the read-out, spikes after clipping weigh little), the "
        "pair (N gyros: each sample at its smallest weight over the gyros' pairs with the reference) is calibrated "
        "again on the weighted moments and the result kept when its rotation is better determined (constant bias, "
        "identified or given noise). ``'off'`` (default): every sample weighs 1, and a residual that heavy-tailed "
        "gets a note saying what the weights would do (:func:`~fusion_gyrocal.core.weights.hint`). On the MIMU board "
        "(benchmarks/sensor_model.py) the weighted rotations repeat to 17.5 mdeg RMS over nine sessions (25.7 "
        "unweighted) and to 8.9 mdeg, mean z^2 5.85, without exp_6 (7.4 mdeg, z^2 4.39 without exp_7 too); the "
        "chips that share a site repeat to 5.6-6.7 mdeg, z^2 3.7-5.0, over all nine; calibrate_array of all 8 IMUs "
        "22.2 mdeg, mean z^2 3.61 (25.4 / 4.66 unweighted). Not the default: in exp_6 one site of the board turned "
        "by ~49 mdeg against chip 1 (both of its chips alike, their own pair unmoved), which the weighted "
        "covariance (~3.6x narrower in sigma) resolves: over all nine sessions mean z^2 26.4 (up to 52 for the "
        "pairs with that site), where the board is taken as rigid. Within a session the weighted covariance covers "
        "about as the unweighted one does (a session's halves: mean z^2 5.06 weighted, 4.69 unweighted; batch "
        "means of the scores over 4-24 segments leave it unchanged). In benchmarks/honesty.py's simulated cases the weights were "
        "kept in 2 of 200 runs (both of the beat case; 20 per case).",
        "--robust-weights", choices=ROBUST_WEIGHTS,
        help="per-sample weights from the residual's local variance: auto or off (default)")
    flex_rejection: object = _option(
        "auto", _flex, {"pair"} | _JOINT,
        "The paper's flex rejection (Section VI.C, Eq. 42): ``'auto'`` gates when more than 1% of the samples "
        "exceed the 3-sigma gate; True always; False never.",
        "--no-flex-rejection", action="store_true", to_option=lambda v, context: False if v else "auto",
        help="keep every sample (no flex/outlier gate)")
    flex_margin: int = _option(
        2, _int_at_least(0), {"pair"}, "Samples removed on each side of a gated outlier.")
    min_kept_energy: float = _option(
        0.05, _fraction, {"pair"},
        "Flex rejection applies only when the kept samples retain at least this fraction of gyro 1's motion "
        "energy; otherwise the rate-dependent residual is pervasive and a note says so.")
    max_rate: float | None = _option(
        None, _optional(_positive), _RECORDING,
        "Drop samples where either gyro's rate norm exceeds this (rad/s): a known flex or saturation limit.",
        "--max-rate", type=float, metavar="RAD_S",
        help="drop samples faster than this rate norm (a known flex or saturation limit)")
    max_plausible_rate: float = _option(
        100.0, _positive, {"pair"},
        "Rates above this (rad/s; 100 = 5730 deg/s, beyond any MEMS gyro's range) at the 99th percentile of both "
        "streams are refused as being in another unit (deg/s, raw counts); raise it for a gyro with a wider range.",
        "--max-plausible-rate", type=float, metavar="RAD_S",
        help="refuse rates above this (rad/s) as being in another unit (default 100 rad/s)")
    # --- N gyros
    gyros: int = _option(
        2, _int_at_least(2), _JOINT,
        "Number of gyros the per-gyro options (``noise_std``, ``saturation_limit``, ``skew_std``, "
        "``bias_walk_std``) are given for: each takes one value for every gyro or ``gyros`` values. The joint "
        "calibration of N gyros sets it to N (:meth:`for_gyros`); build ``Options(gyros=N, noise_std=[...])`` "
        "to give N values yourself.")

    def __post_init__(self):
        gyros = _GYROS_FIELD.metadata["check"]("gyros", self.gyros)
        object.__setattr__(self, "gyros", gyros)
        for f in dataclasses.fields(self):
            check = f.metadata["check"]
            extra = (gyros,) if getattr(check, "per_gyro", False) else ()
            object.__setattr__(self, f.name, check(f.name, getattr(self, f.name), *extra))
        if self.bias_walk_std is not None and self.noise_std is None:
            raise OptionError("bias_walk_std: the drifting-bias filter needs noise_std too (rad/s per sample)")
        if self.bias_walk_std is not None and self.bias_window is not None:
            raise OptionError("bias_window and bias_walk_std: expected one bias model, got both")
        if self.scale_prior_std is not None and self.method != "ml":
            raise OptionError("scale_prior_std: expected method='ml' (the direct solution has no prior)")

    @classmethod
    def of(cls, options=None, **changes):
        """``options`` (default: the defaults) with ``changes`` applied (each a field name, checked again).

        ``gyros`` among the changes is applied first (:meth:`for_gyros`), so that the per-gyro values among
        them are checked against it: ``Options.of(options, gyros=3, noise_std=[a, b, c])``.
        """
        if "gyros" in changes:
            options = super().of(options).for_gyros(changes.pop("gyros"))
        return super().of(options, **changes)

    def refused(self, consumer: str) -> list:
        """The options set away from their default that do not apply to ``consumer`` (sorted names)."""
        accepted = applying_to(consumer)
        return sorted(n for n in self.to_dict() if n not in accepted)

    def require(self, consumer: str, who: str | None = None) -> "Options":
        """Refuse what ``consumer`` (one of :data:`CONSUMERS`) would not apply; return ``self``.

        Every estimator that takes an :class:`Options` calls this: an option set away from its default
        that does not apply to it raises rather than being ignored.

        Parameters
        ----------
        consumer : str
            A key of :data:`CONSUMERS` (matched against each option's ``applies_to``).
        who : str, optional
            The caller as named in the message (default ``consumer``).

        Raises
        ------
        OptionError
            Naming the refused options and every option ``consumer`` takes.
        """
        refused = self.refused(consumer)
        if refused:
            raise OptionError(f"{who or consumer}: {CONSUMERS[consumer]} and cannot apply {refused}; expected only "
                              f"its options ({sorted(applying_to(consumer))})")
        return self

    def for_gyros(self, n: int) -> "Options":
        """The same options for ``n`` gyros (``gyros=n``).

        Per-gyro options left at their default follow; one given for another number of gyros is refused
        (build the options with ``gyros=n``, or give the per-gyro values as keywords to the estimator,
        which sets ``gyros`` first).
        """
        n = _GYROS_FIELD.metadata["check"]("gyros", n)
        if n == self.gyros:
            return self
        given = [name for name in PER_GYRO if getattr(self, name) != _defaults(self.gyros)[name]]
        if given:
            raise OptionError(f"{', '.join(given)}: given for {self.gyros} gyros, expected values for {n} gyros "
                              f"(Options(gyros={n}, ...) or the values as keywords)")
        return dataclasses.replace(self, gyros=n, **{name: _FIELDS[name].default for name in PER_GYRO})

    def to_dict(self) -> dict:
        """The non-default options as plain values (for logs and JSON)."""
        defaults = dict(_defaults(self.gyros), gyros=_GYROS_FIELD.default)
        return {n: getattr(self, n) for n in NAMES if getattr(self, n) != defaults[n]}


_FIELDS = {f.name: f for f in dataclasses.fields(Options)}
_GYROS_FIELD = _FIELDS["gyros"]
NAMES = tuple(_FIELDS)
#: Options that act on timestamps (time alignment and resampling): refused for sample-aligned input.
TIMESTAMP_OPTIONS = ("time_offset_s", "max_offset_s", "rate_hz")
#: Options with one value per gyro (``gyros`` of them).
PER_GYRO = tuple(n for n, f in _FIELDS.items() if getattr(f.metadata["check"], "per_gyro", False))
APPLIES_TO = {n: f.metadata["applies_to"] for n, f in _FIELDS.items()}
"""What each option applies to (option name -> set of :data:`CONSUMERS`)."""


def applying_to(consumer: str) -> tuple:
    """The options that apply to ``consumer`` (a key of :data:`CONSUMERS`), in declaration order."""
    if consumer not in CONSUMERS:
        raise OptionError(f"consumer: expected one of {sorted(CONSUMERS)}, got {consumer!r}")
    return tuple(n for n in NAMES if consumer in APPLIES_TO[n])


@functools.lru_cache(maxsize=None)
def _defaults(gyros: int) -> dict:
    """The default value of every option for ``gyros`` gyros (per-gyro defaults are tuples of that length)."""
    o = Options(gyros=gyros)
    return {n: getattr(o, n) for n in NAMES}


def _numpydoc() -> str:
    lines = ["Options of every estimator and the command line (frozen; change with :meth:`replace`).", "",
             "Every field is checked and normalised on construction (a bad value raises",
             ":class:`~fusion_gyrocal.errors.OptionError`); per-gyro values become a tuple of ``gyros`` (two by",
             "default).", "",
             "Parameters", "----------"]
    for f in dataclasses.fields(Options):
        flag = f" Command line: ``{f.metadata['flag']}``." if f.metadata["flag"] else ""
        where = ", ".join(c for c in CONSUMERS if c in f.metadata["applies_to"])
        lines += [f"{f.name} : default {f.default!r}", f"    (applies to: {where}) {f.metadata['doc']}{flag}"]
    return "\n".join(lines)


Options.__doc__ = _numpydoc()


# ------------------------------------------------------------------------------------------ command line
FLAGS = {f.name: f.metadata["flag"] for f in dataclasses.fields(Options) if f.metadata["flag"] is not None}
"""The command-line flag of every option that has one (option name -> flag)."""


def add_option_arguments(parser, *, consumer: str | None = None, exclude=(), names=None):
    """Add the command-line flag of every option to ``parser``, in one argument group; returns the group.

    Parameters
    ----------
    parser : argparse.ArgumentParser
    consumer : str, optional
        Only the options that apply to this consumer (a key of :data:`CONSUMERS`).
    exclude : iterable of str
        Option names left out.
    names : iterable of str, optional
        Only these options (each must have a flag).

    The value of a flag is stored under ``option_<name>``; :func:`options_from_args` reads it back.
    """
    if consumer is not None:
        names = tuple(n for n in (FLAGS if names is None else names) if n in applying_to(consumer))
    if names is not None:
        names = tuple(names)
        unknown = sorted(set(names) - set(FLAGS))
        if unknown:
            raise OptionError(f"unknown option(s) or option(s) without a flag {unknown}; expected some of {sorted(FLAGS)}")
    group = parser.add_argument_group("calibration options", "fusion_gyrocal.options.Options (one flag per option)")
    for f in dataclasses.fields(Options):
        flag = f.metadata["flag"]
        if flag is None or f.name in exclude or (names is not None and f.name not in names):
            continue
        kw = {k: v for k, v in f.metadata["cli"].items() if k != "to_option"}
        if kw.get("action") != "store_true":
            kw.setdefault("default", None)
            if "choices" not in kw:
                kw.setdefault("metavar", flag.lstrip("-").upper().replace("-", "_"))
        group.add_argument(flag, dest=f"option_{f.name}", **kw)
    return group


def options_from_args(args, *, rate_hz: float | None = None, **keywords) -> Options:
    """The :class:`Options` of parsed command-line flags (added by :func:`add_option_arguments`).

    A flag left out keeps the option's default; a bad value raises
    :class:`~fusion_gyrocal.errors.OptionError` naming the option.

    Parameters
    ----------
    args : argparse.Namespace
    rate_hz : float, optional
        Sample rate of the recording (gyro 1's), for flags given in seconds (``--bias-window``). The
        resampling rate ``--rate`` takes precedence when given: the samples are then on its grid.
    **keywords
        Further options set by the command itself (they win over the flags).
    """
    parsed = {f: getattr(args, f"option_{f}") for f in FLAGS if hasattr(args, f"option_{f}")}
    rate = parsed.get("rate_hz")
    context = {"rate_hz": rate_hz if rate is None else _positive("rate_hz", rate)}
    values = {}
    for name, v in parsed.items():
        convert = _FIELDS[name].metadata["cli"].get("to_option")
        if convert is not None and v is not None:
            v = convert(v, context)
        if v is None or (isinstance(v, list) and not v):
            continue
        values[name] = v
    values.update(keywords)
    return Options.of(**values)
