"""The pipeline from raw rate streams to a calibration: :func:`calibrate_pair` and :func:`run_pipeline`.

Streams with timestamps are checked, masked, time-aligned and resampled
(:mod:`~fusion_gyrocal.pipeline.alignment`); the moments of the kept samples are solved
(:func:`~fusion_gyrocal.core.solve.solve`); flex and outliers are gated
(:mod:`~fusion_gyrocal.pipeline.flex`, Eq. 42) and the pair is solved again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.direct import solve_A
from ..core.model import PairCalibration
from ..core.moments import Moments, as_rate_pair, window_samples
from ..core.noise import difference_noise_std
from ..core.solve import solve
from ..core.weights import TAIL_SHARE, WEIGHT_SPAN, hint, residual_tail_share, residual_weights, tail_samples
from ..errors import InputError, NotRigidError, OptionError
from ..options import TIMESTAMP_OPTIONS, Options
from .bias import BiasModel
from .flex import GLITCH_FACTOR, gate, gross_outliers, subsample_rate_norms
from ..units import check_unit_evidence
from .streams import grid_rate

PLAUSIBILITY_QUANTILE = 0.99  # of the rate norm: isolated glitches do not decide the unit
MAX_GLITCH_FRACTION = 0.01   # more "outliers" than this are the motion itself, not glitches


def calibrate_pair(omega_1, omega_2, *, t_1=None, t_2=None, mask=None, options: Options | None = None,
                   **keywords) -> PairCalibration:
    """Calibrate two rigidly mounted gyroscopes from their angular rates.

    Parameters
    ----------
    omega_1, omega_2 : array_like, shape (N, 3) and (M, 3)
        Measured angular rates (rad/s) of gyro 1 (the reference) and gyro 2, float32 or
        float64. Without timestamps they must be sample-aligned (N == M, same instants).
    t_1, t_2 : array_like (N,) and (M,), optional
        Timestamps (s) of each stream on its own clock. When given, saturated and non-finite
        samples are masked, the time offset is estimated by correlating the rate norms and
        refined below one sample (unless ``time_offset_s`` is given), and gyro 2 is resampled
        onto gyro 1's timestamps (or a ``rate_hz`` grid) with cubic splines that never cross
        a gap (see :mod:`fusion_gyrocal.pipeline.alignment`); a much faster gyro 1 is low-pass filtered onto a
        grid at gyro 2's rate instead (:func:`slow_grid`).
    mask : array_like of bool (N,), optional
        Samples to use (sample-aligned input only).
    options : Options, optional
        Every option of the solver and the pipeline (:class:`~fusion_gyrocal.options.Options`: method,
        noise model, gauge, priors, time alignment, bias model, flex gate, ...). Default: ``Options()``.
    **keywords
        Fields of :class:`~fusion_gyrocal.options.Options`, applied on top of ``options``
        (e.g. ``noise_std=1.7e-3``, ``gauge="fixed"``, ``bias_walk_std=1e-5``).

    Returns
    -------
    PairCalibration

    Raises
    ------
    OptionError
        An unknown option or a value it does not accept.
    InputError
        Wrong shapes or lengths, non-finite values, fewer than 4 samples, constant input, bad
        timestamps (unsorted, duplicate, non-finite).
    ExcitationError
        Motion that does not determine all parameters (Lemma 1); the message names the weak
        axes, their SNR and the motion to add.
    NotRigidError
        The gyros do not move as one rigid body (unless ``on_not_rigid="flag"``).
    TimeAlignmentError
        The time offset cannot be determined from the data.

    Examples
    --------
    >>> from fusion_gyrocal import calibrate_pair
    >>> from fusion_gyrocal.evaluate.sim import simulate_pair
    >>> sim = simulate_pair(rng=0)
    >>> cal = calibrate_pair(sim.omega_1, sim.omega_2)
    >>> cal.configuration
    'general'
    """
    return run_pipeline(omega_1, omega_2, t_1=t_1, t_2=t_2, mask=mask, options=options, **keywords).calibration


@dataclass(frozen=True)
class PipelineRun:
    """Everything :func:`calibrate_pair` saw and decided, for reports and plots.

    ``omega_1``/``omega_2`` are the sample-aligned rates the solver used (for timestamped input the
    aligned rates, NaN where ``valid`` is False: no copy of a long record is made), ``t`` their
    times on gyro 1's clock (None for sample-aligned input), ``used`` the samples kept after masking
    and flex rejection, and ``aligned`` the :class:`~fusion_gyrocal.pipeline.alignment.AlignedPair`
    (None for sample-aligned input).
    """

    calibration: PairCalibration
    t: np.ndarray | None
    omega_1: np.ndarray
    omega_2: np.ndarray
    valid: np.ndarray | None
    used: np.ndarray | None
    aligned: object | None


def prepare_samples(omega_1, omega_2, *, t_1=None, t_2=None, mask=None, options: Options | None = None):
    """The sample-aligned rates and the mask the solver starts from (before the flex gate).

    With timestamps: saturated and non-finite samples masked (:func:`~fusion_gyrocal.pipeline.streams.valid_mask`,
    ``saturation_limit``), the pair aligned and resampled (:func:`~fusion_gyrocal.pipeline.alignment.align_streams`).
    Without: the timestamp options refused, clipped samples masked (``saturation_limit``, else samples flat at
    an axis's extreme). Then ``max_rate``
    (:func:`~fusion_gyrocal.pipeline.selection.informative_mask`). One place for :func:`run_pipeline` and for
    everything that must use the same samples (``gyrocal compare`` on recordings).

    Returns
    -------
    (omega_1, omega_2, mask, aligned, notes)
        The rates (NaN where not valid with timestamps), the mask of usable samples (None: all), the
        :class:`~fusion_gyrocal.pipeline.alignment.AlignedPair` (None for sample-aligned input) and what the
        preparation masked, in words (the clipped samples of sample-aligned input).
    """
    return _prepare(omega_1, omega_2, t_1=t_1, t_2=t_2, mask=mask, options=options, moments=False)[:5]


def _prepare(omega_1, omega_2, *, t_1=None, t_2=None, mask=None, options: Options | None = None,
             moments: bool = True, grid_options: Options | None = None):
    """:func:`prepare_samples` and, last, the moments of every prepared sample when the clipping test of
    sample-aligned input read them in its pass (:func:`~fusion_gyrocal.core.moments.moments_with_extremes`;
    ``moments``: the caller solves on them) and nothing was masked (else None). ``grid_options``: the caller's
    :func:`slow_grid` of ``options`` when already known."""
    o = slow_grid(t_1, t_2, Options.of(options)) if grid_options is None else grid_options
    pair, base = None, None
    if (t_1 is None) != (t_2 is None):
        raise InputError("t_1 and t_2: expected both timestamps or neither (sample-aligned input)")
    if t_1 is None or _same_instants(t_1, t_2):
        from ..core.array import check_distinct
        check_distinct(("omega_1", "omega_2"), (omega_1, omega_2))
    if t_1 is not None:
        from .alignment import align_streams
        from .streams import valid_mask
        if mask is not None:
            raise InputError("mask: only for sample-aligned input; with timestamps, saturated and non-finite "
                             "samples are masked automatically")
        lim = (None, None) if o.saturation_limit is None else o.saturation_limit
        valid = [valid_mask(w, limit=v) for w, v in ((omega_1, lim[0]), (omega_2, lim[1]))]
        for name, w, ok in (("omega_1", omega_1, valid[0]), ("omega_2", omega_2, valid[1])):
            if ok.sum() < 8:   # say why nothing is left: the masks, not "0 valid samples"
                finite = int(np.isfinite(np.asarray(w, dtype=float)).all(axis=1).sum())
                raise InputError(f"{name}: expected samples to calibrate, got {len(ok)} of which {len(ok) - finite} are "
                                 f"non-finite and {finite - int(ok.sum())} flagged saturated (sitting flat at the "
                                 "extreme values: constant input or clipping? pass saturation_limit with the sensor "
                                 "range)")
        pair = align_streams(t_1, omega_1, t_2, omega_2, time_offset_s=o.time_offset_s, max_offset_s=o.max_offset_s,
                             rate_hz=o.rate_hz, valid_1=valid[0], valid_2=valid[1])
        w1, w2 = pair.omega_1, pair.omega_2     # NaN where not valid: every step below reads them through mask
        mask = pair.valid
        notes = () if o.rate_hz == Options.of(options).rate_hz else (
            f"gyro 1 ({_mean_rate(t_1):.5g} Hz) was low-pass filtered onto a grid at gyro 2's rate ({o.rate_hz:.5g} "
            "Hz): interpolated onto gyro 1's instants, gyro 2's noise would be correlated over many of them"
            + ("" if o.noise_std is None else "; gyro 1's noise_std referred to that grid (x sqrt(f_2 / f_1))"),)
    else:
        timing = sorted(set(o.to_dict()) & set(TIMESTAMP_OPTIONS))
        if timing:
            raise OptionError(f"{', '.join(timing)}: act on timestamps; expected t_1 and t_2 with them, got "
                              "sample-aligned input")
        w1, w2, mask = as_rate_pair(omega_1, omega_2, mask)
        base = _moments_first(w1, w2, mask, o) if moments else None
        mask, notes = _unclipped(w1, w2, mask, o.saturation_limit, None if base is None else base[1:])
    check_rate_units(w1, w2, mask, limit=o.max_plausible_rate)
    if o.max_rate is not None:
        from .selection import informative_mask
        keep = informative_mask(w1, w2, mask, 1.0, min_rate=0.0, max_rate=o.max_rate)
        mask = keep if mask is None else (mask & keep)
    return w1, w2, mask, pair, notes, (base[0] if pair is None and base is not None and mask is None else None)


def _moments_first(w1, w2, mask, o: Options):
    """``(moments, extremes_1, extremes_2)`` of sample-aligned input read in one pass
    (:func:`~fusion_gyrocal.core.moments.moments_with_extremes`) where the run would take the moments of every
    sample anyway (no mask, no ``saturation_limit`` or ``max_rate``, a constant bias or an identified noise) and
    the clipping test needs the extremes; None otherwise, or when the pass refuses the samples (the checks that
    follow say why, in their order)."""
    from ..core.moments import moments_with_extremes
    from ..errors import GyroCalError

    identify = o.noise_std is None and o.noise_model == "identify"
    constant = o.bias_walk_std is None and o.bias_window is None
    if mask is not None or o.saturation_limit is not None or o.max_rate is not None or not (identify or constant):
        return None
    try:
        return moments_with_extremes(w1, w2)
    except GyroCalError:
        return None


def check_rate_units(w1, w2, mask=None, *, limit: float = 100.0) -> None:
    """Refuse rates no gyro measures in rad/s: the 99th percentile of both streams' rate norms above
    ``limit`` (the option ``max_plausible_rate``; on a bounded subsample, so a few glitches do not decide).

    One stream alone beyond the limit is a unit mismatch between the gyros, which the solver refuses
    naming both units (:func:`~fusion_gyrocal.core.solve.solve`); values whose squares overflow
    float64 are refused here for either stream.

    Raises
    ------
    InputError
        Naming the rate level and the unit the values look like (deg/s, or counts).
    """
    if len(w1) == 0:
        raise InputError("omega_1 and omega_2: expected at least 4 samples (Lemma 1), got 0")
    levels = []
    norms = subsample_rate_norms(w1, w2, mask)
    for name, flag, n, w in zip(("omega_1", "omega_2"), ("--unit1", "--unit2"), norms, (w1, w2)):
        if n.size == 0:
            return
        with np.errstate(invalid="ignore"):
            level = float(np.quantile(n, PLAUSIBILITY_QUANTILE))
        if not np.isfinite(level):
            raise InputError(f"{name}: expected angular rates in rad/s (at most {limit:g} rad/s), got "
                             f"values up to {float(np.max(np.abs(w))):.3g} (their squares overflow float64); convert "
                             f"them to rad/s ({flag})")
        levels.append(level)
    if min(levels) > limit:
        looks = ("deg/s: pass unit deg/s" if max(levels) * np.pi / 180.0 <= limit
                 else "raw counts: pass unit counts with the sensitivity (LSB per deg/s)")
        raise InputError(f"omega_1 and omega_2: expected rates in rad/s (at most {limit:g} rad/s, above "
                         f"any MEMS gyro's range), got rate norms of {levels[0]:.4g} and {levels[1]:.4g} at the 99th "
                         f"percentile; they look like {looks} (--unit1/--unit2)")
    check_unit_evidence(w1, w2, mask, limit)


def run_pipeline(omega_1, omega_2, *, t_1=None, t_2=None, mask=None, options: Options | None = None,
                 **keywords) -> PipelineRun:
    """:func:`calibrate_pair` returning its intermediate products too (same parameters)."""
    given = Options.of(options, **keywords).require("pair", "calibrate_pair")
    o = slow_grid(t_1, t_2, given)
    w1, w2, mask, pair, notes, base = _prepare(omega_1, omega_2, t_1=t_1, t_2=t_2, mask=mask, options=given,
                                               grid_options=o)
    resampling = _resampling(t_1, t_2, pair, o)
    run = _calibrate(w1, w2, mask, pair, resampling, o, base)
    carried = {}
    if o.timing_model == "auto" and run.calibration.rigid:
        run, carried = _with_timing(run, mask, pair, resampling, o)
    if run.calibration.rigid:
        run = _with_weights(run, pair, resampling, o, carried)
    if notes:
        run = _replace(run, calibration=_replace(run.calibration, notes=run.calibration.notes + notes))
    return run


#: Options counted per sample of the grid: given, the grid stays gyro 1's timestamps (:func:`slow_grid`)
PER_SAMPLE_OPTIONS = ("bias_window", "bias_walk_std")


def _same_instants(t_1, t_2) -> bool:
    """Identical timestamps (False for any that are not numbers: the alignment refuses those)."""
    try:
        return bool(np.array_equal(np.asarray(t_1, dtype=np.float64), np.asarray(t_2, dtype=np.float64)))
    except (TypeError, ValueError):
        return False


def _mean_rate(t) -> float:
    """Mean sample rate (Hz) of timestamps ``t`` over their finite span (NaN without one)."""
    t = np.asarray(t, dtype=np.float64).ravel()
    finite = np.isfinite(t)
    t = t if finite.all() else t[finite]
    return float((t.size - 1) / (t[-1] - t[0])) if t.size >= 2 and t[-1] > t[0] else float("nan")


def slow_grid(t_1, t_2, o: Options) -> Options:
    """``o`` with ``rate_hz`` at gyro 2's mean rate when gyro 1 samples
    :data:`~fusion_gyrocal.pipeline.resample.DECIMATE_RATIO` or more times faster; ``o`` otherwise.

    On gyro 1's own instants a much slower gyro 2 is interpolated: its noise is correlated over
    ``f_1 / f_2`` grid samples, which a white-noise model per sample cannot describe (the covariance came out
    ~7x too small at 10 kHz against 100 Hz). On a grid at gyro 2's rate, gyro 2 is resampled at about its own
    rate (its noise stays white) and gyro 1 is low-pass filtered onto it
    (:func:`~fusion_gyrocal.pipeline.resample._antialiased`): its noise averages down, the motion both can see
    passes unchanged, and the pair is solved on ``f_2 / f_1`` of the samples. A given ``noise_std`` (per sample of
    each gyro) is referred to that grid: gyro 1's becomes ``sigma_1 sqrt(f_2 / f_1)``, the white noise per grid
    sample with the low-frequency density the filter keeps. Left as it is with ``rate_hz`` given, for
    sample-aligned input, and with options counted per grid sample (:data:`PER_SAMPLE_OPTIONS`): their meaning
    would change with the grid.
    """
    from .resample import DECIMATE_RATIO

    if t_1 is None or t_2 is None or o.rate_hz is not None or any(getattr(o, k) is not None
                                                                  for k in PER_SAMPLE_OPTIONS):
        return o
    try:
        f1, f2 = _mean_rate(t_1), _mean_rate(t_2)
    except (TypeError, ValueError):
        return o           # the alignment refuses such timestamps, naming them
    if not (np.isfinite(f1) and np.isfinite(f2) and f1 >= DECIMATE_RATIO * f2):
        return o
    if o.noise_std is None:
        return o.replace(rate_hz=f2)
    from ..core.moments import noise_pair
    s1, s2 = noise_pair(o.noise_std)
    return o.replace(rate_hz=f2, noise_std=(s1 * float(np.sqrt(f2 / f1)), s2))


def _unclipped(w1, w2, mask, limits, extremes=None):
    """``(mask, notes)``: sample-aligned input without its clipped samples
    (:func:`~fusion_gyrocal.pipeline.streams.saturation_mask`: at or beyond ``limits``, the sensor ranges, when
    given; else flat at an axis's extreme value, as on reading a recording), and what was masked. Input flat on
    more than half its samples is constant, not clipped: left to the solver's message. ``extremes``: each
    stream's column extremes when known."""
    from .streams import saturation_mask

    lim = (None, None) if limits is None else limits
    ext = (None, None) if extremes is None else extremes
    if limits is None and extremes is not None and not any(e[2].any() or e[3].any() for e in extremes):
        return mask, ()            # no extreme value repeats: nothing sits flat at one
    clipped = saturation_mask(w1, lim[0], extremes=ext[0]) | saturation_mask(w2, lim[1], extremes=ext[1])
    if mask is not None:
        clipped &= mask
    n = int(np.count_nonzero(clipped))
    if n == 0 or (limits is None and n > 0.5 * (len(clipped) if mask is None else np.count_nonzero(mask))):
        return mask, ()
    said = "reach saturation_limit (the sensor range) and were masked" if limits is not None else (
        "sit flat at an axis's extreme value (clipped at the sensor range?) and were masked (saturation_limit "
        "names the range; mask= to decide yourself)")
    return (~clipped if mask is None else (mask & ~clipped)), (f"{n} sample(s) {said}",)


def _with_timing(run: PipelineRun, mask, pair, resampling, o: Options) -> tuple[PipelineRun, dict]:
    """The run again on gyro 2's samples moved to the instants they describe, when the residual shows a delay
    that follows beat tones (:mod:`~fusion_gyrocal.pipeline.timing`); the run as it is otherwise. Also the fields
    (and the note, ``notes``) the step added to the calibration, for a later step that solves again."""
    from .timing import estimate_timing

    # on the samples before the flex gate: the gate rejects where the delay's residual is largest, a mask that
    # follows the beat and would put sidebands (one tone plus or minus another) into the search
    model = estimate_timing(run.t, run.omega_1, run.omega_2, run.calibration.A, run.calibration.bias, run.valid)
    if not model.significant:
        return run, {}
    t = run.t if run.t is not None else np.arange(len(run.omega_1), dtype=float)
    again = _calibrate(run.omega_1, model.compensate(t, run.omega_2), mask, pair, resampling, o)
    if not again.calibration.rigid or again.calibration.residual_rms >= run.calibration.residual_rms:
        return run, {}                # the compensation did not explain the residual better: kept as it was
    delay = model.delay(t if again.used is None else t[again.used])
    unit = ("Hz", "ms", 1e3) if run.t is not None else ("cycles/sample", "samples", 1.0)
    tones = ", ".join(f"{f:.4g}" for f in model.tones_hz)
    shape = (f"follows beat tone(s) at {tones} {unit[0]} (each chip's sampling clock against the read-out), std "
             f"{delay.std() * unit[2]:.3g} {unit[1]}, mean" if tones else "is constant (a filter's group delay?):")
    note = (f"inter-sensor timing: gyro 2's delay against gyro 1 {shape} {delay.mean() * unit[2]:.3g} {unit[1]}; "
            f"{100 * model.explained:.0f}% of the residual's energy; gyro 2's samples were moved to the instants they "
            "describe and the pair calibrated again: residual RMS per axis "
            f"{np.rad2deg(run.calibration.residual_rms):.4g} -> "
            f"{np.rad2deg(again.calibration.residual_rms):.4g} deg/s (timing_model='off': no delay beyond the time "
            "offset)")
    carried = dict(timing_tones_hz=model.tones_hz, timing_delay_s=float(delay.mean()),
                   timing_delay_std_s=float(delay.std()), timing_explained=model.explained, notes=(note,))
    return _carry(again, carried), carried


def _carry(run: PipelineRun, fields: dict) -> PipelineRun:
    """``run`` with the fields a step of :func:`run_pipeline` added to its calibration (``notes`` appended)."""
    if not fields:
        return run
    more = dict(fields, notes=run.calibration.notes + tuple(fields.get("notes", ())))
    return _replace(run, calibration=_replace(run.calibration, **more))


def _with_weights(run: PipelineRun, pair, resampling, o: Options, carried: dict) -> PipelineRun:
    """The run again with each sample weighted by the inverse of its residual's local variance
    (:func:`~fusion_gyrocal.core.weights.residual_weights`, at the run's estimate) when the residual is heavy-tailed
    (:func:`~fusion_gyrocal.core.weights.tail_share` above :data:`~fusion_gyrocal.core.weights.TAIL_SHARE`), kept
    when its rotation is better determined (``robust_weights``); ``carried``: the fields earlier steps added to the
    calibration. Only for a constant bias and a white noise identified or given. With ``robust_weights`` off, a
    heavy-tailed residual gets a note saying what the weights would do (:func:`~fusion_gyrocal.core.weights.hint`)."""
    cal = run.calibration
    if cal.bias_segments != 1 or cal.noise_model is not None and cal.noise_model.bias_walk_std is not None \
            or o.bias_walk_std is not None or o.bias_window is not None:
        return run                    # weighted moments are those of a constant bias
    if cal.noise_model is None and o.noise_std is None:
        return run                    # no white noise to weigh against (the residual's own variance is the noise)
    use = run.valid                   # the samples before the flex gate, which the weighted run gates again
    share = residual_tail_share(run.omega_1, run.omega_2, cal.A, cal.bias, use, tail_samples(o.robust_weights))
    if share < TAIL_SHARE:
        return run                    # a residual without a heavy tail: every sample weighs the same
    if o.robust_weights == "off":     # what the weights would do, in a note
        return _replace(run, calibration=_replace(cal, notes=cal.notes + (hint(share),)))
    weights = residual_weights(run.omega_1, run.omega_2, cal.A, cal.bias, cal.noise_std, use)
    n_used = float(np.count_nonzero(weights > 0))
    effective = float(weights.sum())
    noise = (cal.noise_model, tuple(cal.noise_std), None)
    again = _calibrate(run.omega_1, run.omega_2, use, pair, resampling, o, weights=weights, noise=noise)
    if not again.calibration.rigid:
        return run
    before, after = _rotation_sd(cal), _rotation_sd(again.calibration)
    if not after < before:
        return run                    # the weighted estimate is not better determined: kept as it was
    note = (f"robust weights: the largest 1% of the residual carried {100 * share:.0f}% of its energy (impacts, "
            "transients faster than the read-out, spikes; 4.5% for Gaussian noise): each sample weighted by the white "
            f"noise's variance over its residual's local variance ({WEIGHT_SPAN} samples), "
            f"{100 * effective / n_used:.0f}% effective samples (n_samples counts the weights); rotation 1-sigma "
            f"{np.rad2deg(before) * 1e3:.3g} -> {np.rad2deg(after) * 1e3:.3g} mdeg, residual RMS per axis "
            f"{np.rad2deg(cal.residual_rms):.4g} -> {np.rad2deg(again.calibration.residual_rms):.4g} deg/s weighted "
            "(robust_weights='off': every sample weighs 1)")
    more = dict(carried, notes=tuple(carried.get("notes", ())) + (note,))
    return _carry(again, more)


def _rotation_sd(cal: PairCalibration) -> float:
    """RMS 1-sigma of the rotation per axis (rad) without the skew budget (what the data determine)."""
    return float(np.sqrt(max(np.trace(cal.repeatable_rotation_covariance), 0.0) / 3.0))


def _calibrate(w1, w2, mask, pair, resampling, o: Options, base: Moments | None = None,
               weights=None, noise: tuple | None = None) -> PipelineRun:
    """The calibration of prepared samples: the noise model, the bias model, the solve, the flex gate. ``base``:
    the moments of the samples ``mask`` when already taken; ``weights``: a weight per sample
    (:func:`~fusion_gyrocal.core.weights.residual_weights`) the moments are taken with; ``noise``:
    ``(noise_model, noise_std, noise_ratio)`` of an earlier calibration of the same samples, used instead of
    identifying them again."""
    t_grid = None if pair is None else pair.t
    offset = 0.0 if pair is None else pair.time_offset_s
    offset_std = pair.time_offset.std_s if pair is not None and pair.time_offset is not None else 0.0
    rate_hz = None if t_grid is None else grid_rate(t_grid)
    window = window_samples(rate_hz)   # about 1 s
    noise_model, noise_ratio = None, None
    noise_std = o.noise_std       # the white noise the run uses; base: the moments of every usable sample
    if noise is not None:
        noise_model, noise_std, noise_ratio = noise
    elif noise_std is None and o.noise_model == "identify":
        base = Moments.from_samples(w1, w2, mask=mask) if base is None else base
        noise_model = _identify(w1, w2, mask, rate_hz, base, resampling)
        if noise_model is not None:
            noise_std = noise_model.noise_std
    if noise_std is None:  # split the residual variance by each stream's high-frequency noise
        d1, d2 = (difference_noise_std(w, mask) for w in (w1, w2))  # a bounded subsample of the log
        noise_ratio = d1 / d2 if d1 > 0 and d2 > 0 else None
    bias = BiasModel.of(o, noise_std, noise_model)
    solve_noise = bias.solve_noise(noise_std)
    base_mask = mask

    def solve_on(use):
        """The pair solved on the samples ``use`` with the run's bias model and noise, and its moments."""
        m, windows = bias.moments(w1, w2, use, window, base if use is base_mask and weights is None else None,
                                  weights=weights)
        return solve(m, o, noise=solve_noise, noise_ratio=noise_ratio, windows=windows, noise_model=noise_model), m

    valid_in = mask

    def first_solve(use):
        try:
            return (*solve_on(use), None)
        except NotRigidError as exc:
            return None, None, exc

    cal, mom, not_rigid = first_solve(mask)
    if not_rigid is not None or not cal.rigid:  # a few comms glitches must not make the log "not rigid"
        glitch = gross_outliers(w1, w2, mask)
        n_glitch = int(np.count_nonzero(glitch))
        n_all = len(w1) if mask is None else int(np.count_nonzero(mask))
        if 0 < n_glitch <= MAX_GLITCH_FRACTION * n_all:
            mask = ~glitch if mask is None else (mask & ~glitch)
            valid_in = mask
            cal, mom, not_rigid = first_solve(mask)
            if cal is not None and cal.rigid:
                cal = _replace(cal, notes=cal.notes + (
                    f"{n_glitch} gross outlier sample(s) (rate norm over {GLITCH_FACTOR:g}x the log's 99th "
                    "percentile: comms glitches?) masked before the rigidity test",))
        if not_rigid is not None:
            raise not_rigid
    rejected = 0.0
    corr = float("nan")
    if o.flex_rejection is not False and cal.rigid:
        cal, mask, rejected, corr = gate(w1, w2, mask, cal, mom, bias, lambda use: solve_on(use)[0], o)
    cal = _replace(cal, time_offset_s=offset, time_offset_std_s=offset_std, rejected_fraction=rejected,
                   rate_residual_correlation=corr, **({} if pair is None else pair.calibration_fields(cal.notes)))
    return PipelineRun(cal, t_grid, np.asarray(w1), np.asarray(w2), valid_in, mask, pair)


def _identify(w1, w2, mask, rate_hz, moments: Moments, resampling=None):
    """The noise model identified from the pair's residual (None when the log is too short for it; without a
    sample rate it is identified per sample, :func:`~fusion_gyrocal.core.noise.identify_noise`)."""
    from ..core.noise import identify_noise
    from ..errors import GyroCalError

    try:   # too short, too little motion, constant input...: the solve says why, with the residual noise
        A, b = solve_A(moments)
        return identify_noise(w1, w2, A, b, rate_hz=rate_hz, mask=mask, resampling=resampling)
    except GyroCalError:
        return None


def _resampling(t_1, t_2, pair, options: Options):
    """How the aligned streams reached the grid (:class:`~fusion_gyrocal.core.noise.Resampling`): each gyro's own
    rate and what the spline interpolation did to its white noise (gyro 1 keeps its samples unless ``rate_hz``
    resamples both); None for sample-aligned input."""
    if pair is None:
        return None
    from ..core.noise import Resampling
    from .resample import noise_factors
    from .streams import _nominal_period

    t1, t2 = (np.asarray(t, dtype=np.float64) for t in (t_1, t_2))
    f1 = noise_factors(t1, pair.t) if options.rate_hz is not None else (1.0, 1.0, 1.0, 1)
    f2 = noise_factors(t2, pair.t - pair.time_offset_s)
    return Resampling((1.0 / _nominal_period(t1), 1.0 / _nominal_period(t2)), (f1[0], f2[0]), (f1[1], f2[1]),
                      (f1[2], f2[2]), max(f1[3], f2[3]))


def _replace(obj, **changes):
    """``obj`` (a frozen :class:`PairCalibration` or :class:`PipelineRun`) with ``changes``."""
    import dataclasses
    return dataclasses.replace(obj, **changes)
