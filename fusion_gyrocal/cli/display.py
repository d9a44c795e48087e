"""What ``calibrate`` and ``demo`` print: the console and the per-axis summary table."""

from __future__ import annotations


def console():
    """A rich console, 110 columns wide unless the terminal is a wide one."""
    from rich.console import Console

    c = Console()
    return c if c.is_terminal and c.width >= 100 else Console(width=110)


def summary_table(cal, truth=None):
    """Per-axis table: estimate +- 1-sigma (and the truth when known)."""
    import numpy as np
    from rich.table import Table

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
            tv = truth[key] if conv is None else conv(truth[key])
            t.add_row("  truth", *[f.format(x) for x in tv], style="dim")
    t.add_row("per-axis SNR", *[f"{x:.0f}" for x in cal.snr])
    t.caption = (f"time offset {cal.time_offset_s * 1e3:+.4f} +- {cal.time_offset_std_s * 1e3:.4f} ms"
                 + (f" (truth {truth['time_offset_s'] * 1e3:+.4f} ms)" if truth is not None else "")
                 + f"; gauge: {cal.gauge}; unexplained {100 * cal.unexplained_fraction:.3g}%, "
                   f"rejected {100 * cal.rejected_fraction:.2f}%")
    return t
