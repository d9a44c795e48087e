"""N gyros at the command line: the flags of the joint calibration, checked against what it applies.

``gyrocal calibrate`` calibrates more than two gyros (or two with ``--array``) jointly with
:func:`fusion_gyrocal.pipeline.array.calibrate_streams` (alignment to gyro 1, masks, the joint solve).
This module only turns the flags into :class:`~fusion_gyrocal.options.Options` for N gyros and refuses,
by flag, an option the joint calibration does not apply (``applies_to`` without ``"streams"``).
"""

from __future__ import annotations


def array_options(args, n: int, rate_hz: float):
    """The :class:`~fusion_gyrocal.options.Options` of the flags for ``n`` gyros (``gyros=n``).

    Raises
    ------
    OptionError
        A value an option does not accept, the wrong number of per-gyro values, or an option the joint
        calibration cannot apply (named by its flag).
    """
    from ..errors import OptionError
    from ..options import FLAGS, PER_GYRO, applying_to, options_from_args

    for name in PER_GYRO:   # named by the flag (options_from_args names the option)
        values = getattr(args, f"option_{name}", None)
        if values is not None and len(values) not in (1, n):
            raise OptionError(f"{FLAGS[name]}: expected one value or one per gyro ({n}), got {len(values)} values")
    o = options_from_args(args, rate_hz=rate_hz, gyros=n)
    refused = o.refused("streams")
    if refused:
        flags = ", ".join(FLAGS.get(name, name) for name in refused)
        raise OptionError(f"{flags}: not available for the joint calibration of {n} gyros; expected only "
                          f"{', '.join(FLAGS[k] for k in applying_to('streams') if k in FLAGS)} (two gyros without "
                          "--array take every option)")
    return o


def calibrate_recordings(streams, args):
    """The joint calibration of the read ``streams`` with the flags of ``args``: ``(ArrayCalibration, notes)``."""
    from ..pipeline.array import calibrate_streams

    o = array_options(args, len(streams), streams[0].rate_hz)
    cal = calibrate_streams([st.t for st in streams], [st.masked_omega for st in streams], o)
    notes = ["joint calibration: no flex/outlier gate (Eq. 42 is per pair); calibrate a suspect gyro against gyro 1 "
             "as a pair to see its rigidity figures", timing_line(cal, o.timing_model)]
    return cal, notes


def timing_line(cal, timing_model: str) -> str:
    """One line on every gyro's delay against the reference beyond its time offset
    (:attr:`~fusion_gyrocal.core.array_result.ArrayCalibration.timing_delay_s`): std, mean and beat tones where one
    was compensated, what was not found otherwise."""
    ref = cal.reference + 1
    if timing_model == "off":
        return f"timing: --timing-model off, no delay beyond each gyro's time offset against gyro {ref} modelled"
    found = [k for k in range(cal.n_gyros) if cal.timing_explained[k] > 0]
    if not found:
        return f"timing: no delay beyond the time offsets against gyro {ref} found in any gyro's residual"
    parts = [(f"gyro {k + 1} std {cal.timing_delay_std_s[k] * 1e3:.3g} ms, mean {cal.timing_delay_s[k] * 1e3:+.3g} ms, "
              f"tones {', '.join(f'{f:.4g}' for f in cal.timing_tones_hz[k])} Hz" if cal.timing_tones_hz[k]
              else f"gyro {k + 1} constant {cal.timing_delay_s[k] * 1e3:+.3g} ms")
             + f" ({100 * cal.timing_explained[k]:.0f}% of its residual)" for k in found]
    rest = [k + 1 for k in range(cal.n_gyros) if k not in found and k != cal.reference]
    return (f"timing: delays against gyro {ref} beyond the time offsets, compensated: " + "; ".join(parts)
            + (f"; none found for gyro(s) {', '.join(map(str, rest))}" if rest else ""))
