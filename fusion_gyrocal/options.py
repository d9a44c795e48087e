"""One frozen options object for the solver and the pipeline: :class:`Options`.

Every option is declared once below, with its default, its check, its documentation and its
command-line flag. :func:`~fusion_gyrocal.core.solve.solve`, :func:`~fusion_gyrocal.calibrate_pair`,
:func:`~fusion_gyrocal.pipeline.pipeline.run_pipeline`, the command line, the fleet, the streaming
calibrator and ``compare`` take an :class:`Options` (or its fields as keywords) and pass it on
unchanged.

Options of ``stage="solve"`` act on the moments (:func:`~fusion_gyrocal.core.solve.solve`); those of
``stage="pipeline"`` act on samples (time alignment, masks, bias model, flex gate). Consumers that
only solve from moments (the streaming calibrator, chunked fleet reductions) refuse pipeline options
that differ from their default instead of ignoring them.

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
import math
from dataclasses import dataclass, field

import numpy as np

from .errors import OptionError

METHODS = ("ml", "direct")
GAUGES = ("unit_prior", "fixed")
COVARIANCES = ("auto", "model", "robust")
NOISE_MODELS = ("identify", "residual")
LINEAR_MAPS = ("auto", "rigid", "full")


# ------------------------------------------------------------------------------------------ checks
def _finite(name, v):
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
    return lambda name, v: None if v is None else check(name, v)


def _per_gyro(check):
    """One value for both gyros or one per gyro, normalised to a tuple of two."""
    def per_gyro(name, v):
        a = np.asarray(v, dtype=object).ravel() if not np.isscalar(v) else np.array([v], dtype=object)
        if a.size not in (1, 2):
            raise OptionError(f"{name}: expected one value or one per gyro (2), got {a.size} values: {v!r}")
        vals = tuple(check(name, x) for x in a)
        return vals * 2 if len(vals) == 1 else vals
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
def _option(default, check, stage, doc, flag=None, **cli):
    """Declare one option: default, check (returns the normalised value), stage, documentation, CLI flag.

    ``cli`` holds the argparse keywords of the flag; ``cli["to_option"]``, when given, maps the parsed
    flag value to the option value (``context`` gives the recording's sample rate).
    """
    return field(default=default, metadata=dict(check=check, stage=stage, doc=doc, flag=flag, cli=cli))


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
        "ml", _choice(METHODS), "solve",
        "Estimator. ``'direct'``: the paper's closed form (Eq. 17, Lemmas 2-4, Eq. 32-34), covariance by "
        "first-order propagation. ``'ml'`` (default): the direct solution refined to the maximum-likelihood "
        "estimate of the errors-in-variables model (Appendix C generalised); covariance = inverse Fisher "
        "information (Appendix B generalised).",
        "--method", choices=METHODS, help="estimator (default ml)")
    noise_std: tuple | None = _option(
        None, _optional(_per_gyro(_positive)), "solve",
        "White-noise std per sample (rad/s), one value or one per gyro. Default: estimated from the "
        "least-squares residual, split between the gyros by their third differences.",
        "--noise-std", type=float, nargs="+", metavar="RAD_S",
        help="white-noise std per sample (rad/s), one value or one per gyro; default: from residuals")
    gauge: object = _option(
        "unit_prior", _gauge, "solve",
        "How the global scale is fixed (Theorem 2): ``'unit_prior'`` (the paper's unit prior on both x axes, "
        "Eq. 32-34), ``'fixed'`` (``scale_1[0] == 1``) or a :class:`~fusion_gyrocal.core.gauge.Gauge`. Ignored "
        "when ``scale_prior_std`` is given.",
        "--gauge", choices=GAUGES, help="global-scale gauge: unit prior on both x axes (paper) or scale_1[0] = 1")
    scale_prior_std: float | None = _option(
        None, _optional(_positive), "solve",
        "Gaussian prior N(1, std^2) on every scale factor (``method='ml'`` only); directions the data do not "
        "fix then take the prior and the covariance says so.",
        "--scale-prior", type=float, metavar="STD", help="Gaussian prior N(1, STD^2) on the scale factors")
    parallel_tol_deg: float = _option(
        5.0, _angle_below_90, "solve",
        "Axes closer than this to parallel (deg) are treated as parallel (Lemmas 2-3).",
        "--parallel-tol", type=float, metavar="DEG",
        help="axes closer than this to parallel are treated as parallel (default 5 deg)")
    intrinsics_1: tuple | None = _option(
        None, _intrinsics, "solve",
        "Manufacturer intrinsic matrix of gyro 1 (upper triangular, (3, 3)); its skew part is compensated "
        "before the solve (Appendix D).")
    intrinsics_2: tuple | None = _option(
        None, _intrinsics, "solve", "As ``intrinsics_1``, for gyro 2.")
    skew_std: tuple = _option(
        0.0, _per_gyro(_non_negative), "solve",
        "Std of the remaining skew error of each gyro; its rotation error (Appendix D, Eq. 40-41) is "
        "reported in ``skew_rotation_covariance`` and added to the covariance.",
        "--skew-std", type=float, nargs="+", metavar="STD",
        help="remaining skew uncertainty for the error budget, one value or one per gyro")
    linear_map: str = _option(
        "auto", _choice(LINEAR_MAPS), "solve",
        "The sensor model (:mod:`~fusion_gyrocal.core.linear_map`). ``'auto'`` (default): the full linear map "
        "(rotation, scale factors and the symmetric relative cross-axis terms) when it fits significantly better "
        "than rotation + scale factors (the cross-axis chi-square, p < 0.001) or when the data determine every "
        "cross-axis term (all axes parallel), else the paper's model; "
        "``'rigid'``: the paper's model ``A = S_1 R S_2^-1`` (Eq. 4) always; ``'full'``: the full map always. "
        "``method='ml'`` only (the direct solution is the paper's).",
        "--linear-map", choices=LINEAR_MAPS,
        help="sensor model: auto (cross-axis terms when the data show them, default), rigid (paper), full")
    cross_axis_std: float = _option(
        0.015, _positive, "solve",
        "Std of each gyro's cross-axis sensitivity (a fraction; MEMS datasheets give 1-2 %): the prior of the "
        "full linear map's relative cross-axis terms where the data do not determine them (the rotation's "
        "uncertainty from their antisymmetric part, which no data see, is as large as the symmetric part: "
        ":func:`~fusion_gyrocal.core.linear_map.cross_axis_budget`, in ``skew_rotation_covariance``).",
        "--cross-axis-std", type=float, metavar="FRACTION",
        help="std of each gyro's cross-axis sensitivity for the full map (default 0.015)")
    covariance: str = _option(
        "auto", _choice(COVARIANCES), "solve",
        "Which covariance is reported (``'ml'`` solves of :func:`~fusion_gyrocal.calibrate_pair`). ``'auto'`` "
        "(default): in every direction the larger of the noise model's (inverse Fisher information) and the "
        "block-robust sandwich from per-window scores (:mod:`~fusion_gyrocal.core.robust`), which covers "
        "coloured noise and model error; ``'model'``: the noise model's alone; ``'robust'``: the sandwich alone.",
        "--covariance", choices=COVARIANCES,
        help="reported covariance: auto (larger of noise model and block-robust), model, robust")
    min_snr: float = _option(
        10.0, _positive, "solve",
        "Smallest SNR of any principal motion direction accepted (Lemma 1).",
        "--min-snr", type=float, help="smallest accepted SNR of any motion direction (default 10)")
    max_unexplained: float = _option(
        0.05, _fraction, "solve",
        "Rigidity test: the pair is not rigid when the least-squares fit leaves more than this fraction of "
        "gyro 1's motion energy unexplained.")
    on_not_rigid: str = _option(
        "raise", _choice(("raise", "flag")), "solve",
        "``'raise'``: :class:`~fusion_gyrocal.errors.NotRigidError`; ``'flag'``: return the result with "
        "``rigid=False``.",
        "--allow-not-rigid", action="store_true", to_option=lambda v, context: "flag" if v else "raise",
        help="report a non-rigid pair (flagged) instead of failing with exit code 3")
    target_snr: float = _option(
        4e3, _positive, "solve",
        "Per-axis SNR the data should reach (Section VI accumulates to 4e3); a note names the axes below it.")
    # --- the pipeline (samples -> moments)
    time_offset_s: float | None = _option(
        None, _optional(_finite), "pipeline",
        "Known time offset (s), ADDED to gyro 2's timestamps to put them on gyro 1's clock; default: "
        "estimated (timestamped input only).",
        "--offset", type=float, help="known time offset (s) added to gyro 2's timestamps; default: estimated")
    max_offset_s: float = _option(
        1.0, _positive, "pipeline", "Search range (s) of the time-offset estimate.",
        "--max-offset", type=float, help="offset search range in s (default 1.0)")
    rate_hz: float | None = _option(
        None, _optional(_positive), "pipeline",
        "Resample both streams onto a uniform grid at this rate (Hz); default: gyro 1's timestamps.",
        "--rate", type=float, help="resample both onto a uniform grid at this rate (Hz)")
    saturation_limit: tuple | None = _option(
        None, _optional(_per_gyro(_positive)), "pipeline",
        "Sensor range (rad/s) of each gyro for masking clipped samples; default: detect samples sitting flat "
        "at the extreme values.",
        "--saturation-limit", type=float, nargs="+", metavar="RAD_S",
        help="sensor range (rad/s) for masking clipped samples, one value or one per gyro")
    bias_window: int | None = _option(
        None, _optional(_int_at_least(2)), "pipeline",
        "Model the bias as piecewise constant over windows of this many samples (drifting biases). The "
        "command-line flag is in seconds, converted with the recording's sample rate (``--rate`` when given).",
        "--bias-window", type=float, metavar="SECONDS", to_option=lambda v, context: _window_samples(v, context),
        help="piecewise-constant bias over windows of this length in s (drifting biases)")
    bias_walk_std: tuple | None = _option(
        None, _optional(_per_gyro(_positive)), "pipeline",
        "Bias random-walk step std per sample (rad/s) of each gyro: the exact drifting-bias likelihood "
        "(Kalman innovations filter). Needs ``noise_std``.",
        "--bias-walk", type=float, nargs="+", metavar="RAD_S",
        help="bias random-walk step std per sample (rad/s), one value or one per gyro: the exact drifting-bias "
             "model (needs --noise-std)")
    noise_model: str = _option(
        "identify", _choice(NOISE_MODELS), "pipeline",
        "Where the noise comes from when ``noise_std`` is not given. ``'identify'`` (default): white noise, bias "
        "random walk and rate-dependent misfit identified from the pair's own residual "
        "(:func:`~fusion_gyrocal.core.noise.identify_noise`), the bias model (constant or random walk) chosen "
        "from it; ``'residual'``: the least-squares residual's variance as white noise, constant bias.",
        "--noise-model", choices=NOISE_MODELS,
        help="noise when --noise-std is not given: identify (Allan fit of the residual, default) or residual")
    flex_rejection: object = _option(
        "auto", _flex, "pipeline",
        "The paper's flex rejection (Section VI.C, Eq. 42): ``'auto'`` gates when more than 1% of the samples "
        "exceed the 3-sigma gate; True always; False never.",
        "--no-flex-rejection", action="store_true", to_option=lambda v, context: False if v else "auto",
        help="keep every sample (no flex/outlier gate)")
    flex_margin: int = _option(
        2, _int_at_least(0), "pipeline", "Samples removed on each side of a gated outlier.")
    min_kept_energy: float = _option(
        0.05, _fraction, "pipeline",
        "Flex rejection applies only when the kept samples retain at least this fraction of gyro 1's motion "
        "energy; otherwise the rate-dependent residual is pervasive and a note says so.")
    max_rate: float | None = _option(
        None, _optional(_positive), "pipeline",
        "Drop samples where either gyro's rate norm exceeds this (rad/s): a known flex or saturation limit.",
        "--max-rate", type=float, metavar="RAD_S",
        help="drop samples faster than this rate norm (a known flex or saturation limit)")
    max_plausible_rate: float = _option(
        100.0, _positive, "pipeline",
        "Rates above this (rad/s; 100 = 5730 deg/s, beyond any MEMS gyro's range) at the 99th percentile of both "
        "streams are refused as being in another unit (deg/s, raw counts); raise it for a gyro with a wider range.",
        "--max-plausible-rate", type=float, metavar="RAD_S",
        help="refuse rates above this (rad/s) as being in another unit (default 100 rad/s)")

    def __post_init__(self):
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, f.metadata["check"](f.name, getattr(self, f.name)))
        if self.bias_walk_std is not None and self.noise_std is None:
            raise OptionError("bias_walk_std: the drifting-bias filter needs noise_std too (rad/s per sample)")
        if self.bias_walk_std is not None and self.bias_window is not None:
            raise OptionError("bias_window and bias_walk_std: expected one bias model, got both")
        if self.scale_prior_std is not None and self.method != "ml":
            raise OptionError("scale_prior_std: expected method='ml' (the direct solution has no prior)")

    def require_stage(self, stage: str, consumer: str) -> "Options":
        """Refuse options of another stage that differ from their default (``consumer`` would ignore them)."""
        set_elsewhere = [f.name for f in dataclasses.fields(self)
                         if f.metadata["stage"] != stage and getattr(self, f.name) != _DEFAULTS[f.name]]
        if set_elsewhere:
            raise OptionError(f"{consumer}: works from moments only and cannot apply {sorted(set_elsewhere)}; "
                              f"expected only {stage} options ({sorted(n for n in NAMES if STAGES[n] == stage)})")
        return self

    def to_dict(self) -> dict:
        """The non-default options as plain values (for logs and JSON)."""
        return {n: getattr(self, n) for n in NAMES if getattr(self, n) != _DEFAULTS[n]}


NAMES = tuple(f.name for f in dataclasses.fields(Options))
#: Options that act on timestamps (time alignment and resampling): refused for sample-aligned input.
TIMESTAMP_OPTIONS = ("time_offset_s", "max_offset_s", "rate_hz")
STAGES = {f.name: f.metadata["stage"] for f in dataclasses.fields(Options)}
_DEFAULTS = {n: getattr(Options(), n) for n in NAMES}


def _numpydoc() -> str:
    lines = ["Options of the solver and the pipeline (frozen; change with :meth:`replace`).", "",
             "Every field is checked and normalised on construction (a bad value raises",
             ":class:`~fusion_gyrocal.errors.OptionError`); per-gyro values become a tuple of two.", "",
             "Parameters", "----------"]
    for f in dataclasses.fields(Options):
        flag = f" Command line: ``{f.metadata['flag']}``." if f.metadata["flag"] else ""
        lines += [f"{f.name} : default {f.default!r}", f"    ({f.metadata['stage']}) {f.metadata['doc']}{flag}"]
    return "\n".join(lines)


Options.__doc__ = _numpydoc()


# ------------------------------------------------------------------------------------------ command line
FLAGS = {f.name: f.metadata["flag"] for f in dataclasses.fields(Options) if f.metadata["flag"] is not None}
"""The command-line flag of every option that has one (option name -> flag)."""


def add_option_arguments(parser, *, stage: str | None = None, exclude=(), names=None):
    """Add the command-line flag of every option to ``parser``, in one argument group; returns the group.

    Parameters
    ----------
    parser : argparse.ArgumentParser
    stage : {"solve", "pipeline"}, optional
        Only the options of this stage.
    exclude : iterable of str
        Option names left out.
    names : iterable of str, optional
        Only these options (each must have a flag).

    The value of a flag is stored under ``option_<name>``; :func:`options_from_args` reads it back.
    """
    if names is not None:
        names = tuple(names)
        unknown = sorted(set(names) - set(FLAGS))
        if unknown:
            raise OptionError(f"unknown option(s) or option(s) without a flag {unknown}; expected some of {sorted(FLAGS)}")
    group = parser.add_argument_group("calibration options", "fusion_gyrocal.options.Options (one flag per option)")
    for f in dataclasses.fields(Options):
        flag = f.metadata["flag"]
        if (flag is None or f.name in exclude or (stage is not None and f.metadata["stage"] != stage)
                or (names is not None and f.name not in names)):
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


_FIELDS = {f.name: f for f in dataclasses.fields(Options)}
