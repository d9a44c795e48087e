"""N gyros at the command line: the options the joint solver takes, and N recordings on one time grid.

``gyrocal calibrate`` calibrates more than two gyros (or two with ``--array``) jointly with
:func:`fusion_gyrocal.core.array.calibrate_array`. Recordings on one clock (identical timestamps, e.g. a
multi-IMU npz) are sample-aligned as they are. Otherwise every gyro k is aligned to gyro 1 (the
reference) with :func:`~fusion_gyrocal.pipeline.alignment.align_streams` (its offset estimated, or
``--offset`` for every gyro), and all gyros are resampled
(:func:`~fusion_gyrocal.pipeline.resample.resample`) onto gyro 1's timestamps (or a ``--rate`` grid)
over the span every gyro covers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ARRAY_OPTIONS = ("noise_std", "gauge", "parallel_tol_deg", "min_snr", "time_offset_s", "max_offset_s", "rate_hz",
                 "saturation_limit", "bias_window", "max_rate", "flex_rejection", "noise_model", "covariance")
"""The options (of :class:`~fusion_gyrocal.options.Options`) the joint calibration applies; others are refused.
``flex_rejection`` is accepted because the joint solver has no flex gate (``--no-flex-rejection`` changes nothing)."""

_PER_GYRO = ("noise_std", "saturation_limit")  # one value, or one per gyro (N of them)


@dataclass(frozen=True)
class ArraySettings:
    """What the joint calibration of N gyros takes from the command line."""

    options: object          # Options (the per-gyro values reset)
    noise_std: np.ndarray | None
    saturation_limit: list


def array_settings(args, n: int, rate_hz: float) -> ArraySettings:
    """The checked settings of the flags for ``n`` gyros.

    Raises
    ------
    OptionError
        A value an option does not accept, the wrong number of per-gyro values, or an option the joint
        calibration cannot apply (named by its flag).
    """
    import argparse

    from ..errors import OptionError
    from ..options import FLAGS, Options, options_from_args

    per_gyro = {}
    plain = argparse.Namespace(**vars(args))
    for name in _PER_GYRO:
        values = getattr(args, f"option_{name}", None)
        setattr(plain, f"option_{name}", None)
        if values is not None:
            if len(values) not in (1, n):
                raise OptionError(f"{FLAGS[name]}: expected one value or one per gyro ({n}), got {len(values)} values")
            per_gyro[name] = [getattr(Options.of(**{name: v}), name)[0] for v in values]
    o = options_from_args(plain, rate_hz=rate_hz)
    refused = sorted(set(o.to_dict()) - set(ARRAY_OPTIONS))
    if refused:
        flags = ", ".join(FLAGS.get(name, name) for name in refused)
        raise OptionError(f"{flags}: not available for the joint calibration of {n} gyros; expected only "
                          f"{', '.join(FLAGS[k] for k in ARRAY_OPTIONS if k in FLAGS)} (two gyros without --array "
                          "take every option)")
    noise = per_gyro.get("noise_std")
    limits = per_gyro.get("saturation_limit", [None])
    return ArraySettings(o, None if noise is None else np.broadcast_to(noise, (n,)).copy(),
                         list(limits) * n if len(limits) == 1 else list(limits))


def calibrate_streams(streams, args):
    """The joint calibration of ``streams`` with the flags of ``args``: ``(ArrayCalibration, notes)``."""
    import dataclasses

    from ..core.array import calibrate_array
    from ..pipeline.alignment import align_to_reference
    from ..pipeline.streams import grid_rate

    n = len(streams)
    settings = array_settings(args, n, streams[0].rate_hz)
    o = settings.options
    aligned = align_to_reference([st.t for st in streams], [st.masked_omega for st in streams],
                                 time_offset_s=o.time_offset_s, max_offset_s=o.max_offset_s, rate_hz=o.rate_hz,
                                 saturation_limit=settings.saturation_limit)
    mask = aligned.valid
    if o.max_rate is not None:
        mask = mask & (np.linalg.norm(aligned.omegas, axis=2) <= o.max_rate).all(axis=1)
    cal = calibrate_array(aligned.omegas, mask=mask, noise_std=settings.noise_std, gauge=o.gauge,
                          bias_window=o.bias_window, parallel_tol_deg=o.parallel_tol_deg, min_snr=o.min_snr,
                          rate_hz=grid_rate(aligned.t), noise_model=o.noise_model, covariance=o.covariance)
    cal = dataclasses.replace(cal, time_offset_s=aligned.time_offset_s, time_offset_std_s=aligned.time_offset_std_s,
                              time_offset_source=aligned.time_offset_source)
    notes = ["joint calibration: no flex/outlier gate (Eq. 42 is per pair); calibrate a suspect gyro against gyro 1 "
             "as a pair to see its rigidity figures"]
    return cal, notes
