"""N timestamped gyro streams to one joint calibration: :func:`calibrate_streams`.

The N-gyro counterpart of :func:`~fusion_gyrocal.calibrate_pair` on timestamped input: every gyro's
saturated and non-finite samples are masked (:func:`~fusion_gyrocal.pipeline.streams.valid_mask`,
``saturation_limit``), the streams are put on gyro 1's clock and one grid
(:func:`~fusion_gyrocal.pipeline.alignment.align_to_reference`: streams on one clock as they are,
otherwise each gyro's offset estimated or ``time_offset_s``, resampled onto gyro 1's timestamps or a
``rate_hz`` grid), ``max_rate`` drops samples as in the pair pipeline
(:func:`~fusion_gyrocal.pipeline.selection.informative_mask`), and the kept samples are calibrated
jointly (:func:`~fusion_gyrocal.core.array.calibrate_array`, gyro 1 the reference, on the grid's instants: every
gyro's delay beyond its offset, from its pair's residual with gyro 1, is compensated there, ``timing_model``).

Unlike the pair pipeline there is no flex gate (Eq. 42 is per pair) and no check of the rates' unit
(``max_plausible_rate``): neither applies here, and setting them is refused.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.array import calibrate_array
from ..core.array_result import ArrayCalibration
from ..errors import InputError
from ..options import Options, applying_to
from .alignment import align_to_reference
from .selection import informative_mask
from .streams import grid_rate


def calibrate_streams(ts, omegas, options: Options | None = None, **keywords) -> ArrayCalibration:
    """Jointly calibrate N gyros from their own timestamped streams (gyro 1, ``ts[0]``, the reference).

    Parameters
    ----------
    ts : sequence of N array_like (M_k,)
        Each gyro's timestamps (s), strictly increasing.
    omegas : sequence of N array_like (M_k, 3)
        Each gyro's measured rates (rad/s; NaN where not measured).
    options : Options, optional
        :class:`~fusion_gyrocal.options.Options` (``gyros`` is set to N); an option set away from its default
        that does not apply to N timestamped streams (``applies_to`` without ``"streams"``) is refused. Those
        of :func:`~fusion_gyrocal.core.array.calibrate_array`, and the ones that align and mask:

        ``time_offset_s``
            Known offset (s) added to every other gyro's timestamps; default: estimated per gyro.
        ``max_offset_s``
            Search range (s) of the offset estimates.
        ``rate_hz``
            Resample every gyro onto a uniform grid at this rate (Hz); default: gyro 1's timestamps.
        ``saturation_limit``
            Sensor range (rad/s) for masking clipped samples, one value or one per gyro (N).
        ``max_rate``
            Drop samples where any gyro's rate norm exceeds this (rad/s).
    **keywords
        Fields of :class:`~fusion_gyrocal.options.Options`, applied on top of ``options``
        (``noise_std=[s_1, ..., s_N]``, ``time_offset_s=0.0``, ...).

    Returns
    -------
    ArrayCalibration
        With every gyro's ``time_offset_s``, its std and where it came from.

    Raises
    ------
    InputError
        ``ts`` and ``omegas`` of different lengths, fewer than 2 gyros, bad samples.
    OptionError
        An option value it does not accept, or one that does not apply to N streams.
    TimeAlignmentError
        An offset cannot be estimated, or the gyros have no common span.

    Examples
    --------
    >>> import numpy as np
    >>> from fusion_gyrocal import calibrate_streams
    >>> from fusion_gyrocal.evaluate.sim import HumanMotion, random_rotation
    >>> rng = np.random.default_rng(1)
    >>> t = np.arange(6000) / 100.0
    >>> omega = HumanMotion(rng=rng)(t)
    >>> R = [np.eye(3)] + [random_rotation(rng) for _ in range(2)]
    >>> omegas = [omega @ Rk + rng.normal(0, 1e-3, omega.shape) for Rk in R]
    >>> cal = calibrate_streams([t, t, t], omegas, noise_std=1e-3)
    >>> bool(np.allclose(cal.R_ref_k, R, atol=2e-3)), cal.time_offset_source
    (True, ('reference', 'one clock', 'one clock'))
    """
    ts, omegas = list(ts), list(omegas)
    if len(ts) != len(omegas):
        raise InputError(f"ts and omegas: expected one timestamp array per gyro, got {len(ts)} and {len(omegas)}")
    if len(ts) < 2:
        raise InputError(f"omegas: expected at least 2 gyros, got {len(ts)}")
    n = len(ts)
    o = Options.of(options, gyros=n, **keywords).require("streams", "calibrate_streams")
    aligned = align_to_reference(ts, omegas, time_offset_s=o.time_offset_s, max_offset_s=o.max_offset_s,
                                 rate_hz=o.rate_hz, saturation_limit=o.saturation_limit)
    mask = aligned.valid
    if o.max_rate is not None:   # the pair pipeline's rule, for every gyro against gyro 1
        w = aligned.omegas
        for k in range(1, n):
            mask = mask & informative_mask(w[:, 0], w[:, k], None, 1.0, min_rate=0.0, max_rate=o.max_rate)
    # what aligned and masked the samples is done: the joint solve gets the rest
    joint = o.replace(**{name: getattr(Options(gyros=n), name) for name in applying_to("streams")
                         if name not in applying_to("array")})
    resampling = _resampling(ts, aligned, o.rate_hz is not None)
    cal = calibrate_array(aligned.omegas, joint, mask=mask, rate_hz=grid_rate(aligned.t), t=aligned.t,
                          resampling=resampling)
    density = np.asarray(cal.noise_std, float) / np.sqrt(np.asarray(resampling.variance) * resampling.rates_hz)
    return dataclasses.replace(cal, time_offset_s=aligned.time_offset_s, time_offset_std_s=aligned.time_offset_std_s,
                               time_offset_source=aligned.time_offset_source, notes=cal.notes + aligned.notes,
                               rates_hz=np.asarray(resampling.rates_hz), noise_density=density)


def _resampling(ts, aligned, resampled_reference: bool) -> "Resampling":
    """How every gyro's stream reached the grid (:class:`~fusion_gyrocal.core.noise.Resampling`, one entry per gyro):
    its own rate (Hz) and what the interpolation did to its white noise
    (:func:`~fusion_gyrocal.pipeline.resample.noise_factors` at the instants of its own clock it was sampled at, as
    the pair pipeline measures it). A gyro's white-noise density is then ``noise_std[k] / sqrt(variance_k f_k)``.
    The reference keeps its samples unless a ``rate_hz`` grid resampled it too, and recordings on one clock keep
    theirs (``"one clock"``)."""
    from ..core.noise import Resampling
    from .resample import noise_factors
    from .streams import _nominal_period

    grid = np.asarray(aligned.t, dtype=np.float64)
    drift = np.zeros(len(ts)) if aligned.clock_drift_ppm is None else 1e-6 * np.asarray(aligned.clock_drift_ppm)
    mid = 0.5 * (grid[0] + grid[-1])
    rates, factors = [], []
    for k, t in enumerate(ts):
        t = np.asarray(t, dtype=np.float64)
        rates.append(1.0 / _nominal_period(t))
        own = (k > 0 or resampled_reference) and aligned.time_offset_source[k] != "one clock"
        factors.append(noise_factors(t, grid - aligned.time_offset_s[k] - drift[k] * (grid - mid)) if own
                       else (1.0, 1.0, 1.0, 1))
    variance, diff3, density, white_from = zip(*factors)
    return Resampling(tuple(rates), tuple(variance), tuple(diff3), tuple(density), max(white_from))
