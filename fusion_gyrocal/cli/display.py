"""What ``calibrate`` and ``demo`` print: the console, the per-axis table of a pair and the table of N gyros.

Rotations are printed as canonical rotation vectors (:func:`fusion_gyrocal.lie.canonical_rotvec`).
"""

from __future__ import annotations


MODELS = {"rigid": "rotation + scale factors (Eq. 4)",
          "full": "full linear map, symmetric cross-axis convention (R_1_2 repeatable; the skew budget is in its +-)",
          "reference": "gyro 2's intrinsic matrix against gyro 1's given one"}
"""The sensor model of a pair's result (``PairCalibration.linear_map``), as the summary names it."""


def console(stderr: bool = False):
    """A rich console, 110 columns wide unless the terminal is a wide one; on stderr when ``stderr`` (the
    result itself goes to standard output)."""
    from rich.console import Console

    c = Console(stderr=stderr)
    return c if c.is_terminal and c.width >= 100 else Console(width=110, stderr=stderr)


def summary_table(cal, truth=None):
    """Per-axis table: estimate +- 1-sigma (and the truth when known)."""
    import numpy as np
    from rich.table import Table

    from ..core.model import parallel_axes
    from ..lie import canonical_rotvec

    t = Table(title=f"gyro pair calibration: {cal.configuration}, method {cal.method}, {cal.n_samples} samples, "
                    f"rigid {cal.rigid}")
    t.add_column("quantity")
    for axis in "xyz":
        t.add_column(axis, justify="right")

    def cells(v, sd, fmt):
        return [f"{fmt(a)} +- {fmt(b)}" if np.isfinite(b) else f"{fmt(a)} (ratio only)" for a, b in zip(v, sd)]

    deg = np.rad2deg
    rows = [("R_1_2 rotvec (deg)", deg(cal.rotvec), deg(cal.rotation_std_rad), "{:.4f}", "rotvec", deg),
            ("scale_1", cal.scale_1, cal.scale_std[0], "{:.6f}", "scale_1", None),
            ("scale_2", cal.scale_2, cal.scale_std[1], "{:.6f}", "scale_2", None),
            ("bias b1 - A b2 (deg/s)", deg(cal.bias), deg(cal.bias_std), "{:.4f}", "bias", deg)]
    for name, v, sd, f, key, conv in rows:
        t.add_row(name, *cells(v, sd, f.format))
        if truth is not None:
            tv = canonical_rotvec(truth[key]) if key == "rotvec" else truth[key]
            tv = tv if conv is None else conv(tv)
            t.add_row("  truth", *[f.format(x) for x in tv], style="dim")
    if cal.linear_map == "full":      # the full linear map's symmetric relative cross-axis terms
        sd = np.sqrt(np.clip(np.diag(cal.cross_axis_covariance), 0.0, None))
        t.add_row("cross-axis K xy, yz, zx (%)", *[f"{100 * v:.3f} +- {100 * e:.3f}"
                                                   for v, e in zip(cal.cross_axis_terms, sd)])
    elif cal.linear_map == "reference":   # gyro 2's intrinsic matrix, row by row
        from ..core.linear_map import UPPER

        sd = np.zeros((3, 3))
        for p, (a, b) in enumerate(UPPER):
            sd[a, b] = np.sqrt(max(cal.intrinsics_2_covariance[p, p], 0.0))
        for a in range(3):
            t.add_row(f"intrinsics_2 row {'xyz'[a]}", *[f"{cal.intrinsics_2[a, b]:.5f} +- {sd[a, b]:.5f}" if b >= a
                                                         else "0" for b in range(3)])
    p = parallel_axes(cal.R_1_2)
    t.add_row("scale_2 / scale_1 (gyro 1 axis " + ",".join("xyz"[b] for b in p) + ")",
              *[f"{r:.6f} +- {e:.6f}" if np.isfinite(e) else f"{r:.6f}" for r, e in zip(cal.scale_ratio,
                                                                                         cal.scale_ratio_std)])
    t.add_row("roll, pitch, yaw (deg)", *[f"{v:.4f}" for v in deg(cal.rpy)])
    if cal.deviation is not None:
        d, C = cal.deviation
        t.add_row("deviation from nominal (deg)", *[f"{v:.4f} +- {e:.4f}" for v, e in
                                                    zip(deg(d), deg(np.sqrt(np.clip(np.diag(C), 0, None))))])
    t.add_row("per-axis SNR", *[f"{x:.0f}" for x in cal.snr])
    t.caption = (f"time offset {cal.time_offset_s * 1e3:+.4f} +- {cal.time_offset_std_s * 1e3:.4f} ms"
                 + (f" (truth {truth['time_offset_s'] * 1e3:+.4f} ms)" if truth is not None else "")
                 + (f", clock drift {cal.clock_drift_ppm:+.3f} +- {cal.clock_drift_std_ppm:.3f} ppm (offset at the "
                    "overlap's middle)" if getattr(cal, "clock_drift_ppm", 0.0) else "")
                 + "".join(f"; timestamps {q.split(':')[0]} regular" if q.endswith("; regular")
                           else f"; timestamps {q}" for q in getattr(cal, "timestamp_quality", ()))
                 + f"; gauge: {cal.gauge}; unexplained {100 * cal.unexplained_fraction:.3g}%, "
                   f"rejected {100 * cal.rejected_fraction:.2f}%; model: {MODELS[cal.linear_map]}"
                 + (f"; gyro 2's delay beyond the offset: std {cal.timing_delay_std_s * 1e3:.3g} ms, tones "
                    f"{', '.join(f'{f:.4g}' for f in cal.timing_tones_hz) or 'none'}" if cal.timing_explained > 0
                    else ""))
    return t


def array_table(cal):
    """One row per gyro of a joint calibration: rotation into gyro 1's frame, scales, bias, time offset, noise."""
    import numpy as np
    from rich.table import Table

    from ..lie import canonical_rotvec, log

    configs = sorted({c for row in cal.configurations for c in row if c})
    t = Table(title=f"joint calibration of {cal.n_gyros} gyros (reference gyro {cal.reference + 1}): "
                    f"{', '.join(configs)}, {cal.n_samples} samples")
    for col in ("gyro", "R_ref_k rotvec (deg)", "+- (deg, norm)", "scale x, y, z", "bias vs ref (deg/s)",
                "time offset (ms)", "noise (deg/s)"):
        t.add_column(col, justify="left" if col == "gyro" else "right")
    deg = np.rad2deg
    rot_sd = deg(cal.rotation_std_rad)
    for k in range(cal.n_gyros):
        rv = deg(canonical_rotvec(log(cal.R_ref_k[k])))
        scales = ", ".join(f"{s:.5f}" if ok else f"({s:.5f})" for s, ok in zip(cal.scale[k], cal.scale_observable[k]))
        off = cal.time_offset_s[k] * 1e3
        off_text = f"{off:+.3f} +- {cal.time_offset_std_s[k] * 1e3:.3f}" if cal.time_offset_std_s[k] > 0 else f"{off:+.3f}"
        t.add_row(f"{k + 1}", ", ".join(f"{v:.4f}" for v in rv), f"{np.linalg.norm(rot_sd[k]):.4f}", scales,
                  ", ".join(f"{v:.4f}" for v in deg(cal.bias[k])), f"{off_text} ({cal.time_offset_source[k]})",
                  f"{deg(cal.noise_std[k]):.4f}")
    t.caption = (f"gauge: {cal.gauge}; scale factors in parentheses: only ratios within a group of linked axes are "
                 f"determined ({len(cal.scale_groups)} group(s)); noise: {cal.noise_source}")
    return t


def rotation_lines(cal) -> list[str]:
    """Every gyro's rotation into gyro 1's frame as ROS and VIO consumers read it: the unit quaternion (x, y, z, w
    and w-first), roll-pitch-yaw and the matrix rows; the relative scale factors with their 1-sigma; the deviation
    from the nominal mounting (``--nominal``) with its 1-sigma."""
    import numpy as np

    from ..core.array_result import ArrayCalibration
    from ..core.model import parallel_axes, rotation_forms

    def fmt(v, p=6):
        return ", ".join(f"{x:.{p}f}" for x in v)

    if isinstance(cal, ArrayCalibration):
        items = [k for k in range(cal.n_gyros) if k != cal.reference]
        Rs = {k: cal.R_ref_k[k] for k in items}
        rel, sd = cal.relative_scales()
        scales = {k: (rel[k], sd[k]) for k in items}
        devs = {k: cal.deviation(k) for k in items}
        ref = cal.reference
    else:
        items, ref = [1], 0
        Rs = {1: cal.R_1_2}
        scales = {1: (cal.scale_ratio, cal.scale_ratio_std)}
        devs = {1: cal.deviation}
    lines = [f"rotations R_1_k (gyro k's frame into gyro {ref + 1}'s, v_{ref + 1} = R v_k; the tf transform with "
             f"parent gyro {ref + 1}, child gyro k):"]
    for k in items:
        f = rotation_forms(Rs[k])
        r, e = scales[k]
        p = parallel_axes(Rs[k])
        lines.append(f"  gyro {k + 1}: quaternion xyzw [{fmt(f['quaternion_xyzw'], 9)}] (wxyz "
                     f"[{fmt(f['quaternion_wxyz'], 9)}]); roll pitch yaw [{fmt(np.degrees(f['rpy']), 4)}] deg; "
                     "matrix [" + "; ".join(fmt(row) for row in f["matrix"]) + "]")
        lines.append(f"    scale / gyro {ref + 1}'s on axes " + ",".join("xyz"[b] for b in p) + ": "
                     + ", ".join(f"{a:.6f} +- {b:.2g}" if np.isfinite(b) else f"{a:.6f}" for a, b in zip(r, e)))
        if devs[k] is not None:
            d, C = devs[k]
            sd_d = np.degrees(np.sqrt(np.clip(np.diag(C), 0.0, None)))
            lines.append(f"    deviation from nominal: {np.degrees(np.linalg.norm(d)):.4f} deg, rotation vector "
                         f"[{fmt(np.degrees(d), 4)}] +- [{fmt(sd_d, 4)}] deg (gyro {ref + 1}'s axes)")
    return lines


def provenance_lines(prov) -> list[str]:
    """What the result was computed from (:meth:`~fusion_gyrocal.provenance.Provenance.lines`), prefixed
    ``input:``; nothing without a provenance."""
    return [] if prov is None else [f"input: {line}" for line in prov.lines()]
