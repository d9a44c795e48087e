"""Figures a person can read: residual versus rate norm, SNR accumulation, alignment, rejections, the
residual's Allan deviation with the identified noise model; and the one line saying what the uncertainty
rests on (:func:`uncertainty_basis`, also printed by ``gyrocal calibrate``).

Every function returns a :class:`matplotlib.figure.Figure` (Agg backend, no display needed);
:func:`write_report` saves them as PNG files beside a short Markdown summary, each file written
atomically (:func:`fusion_gyrocal.io.writers.atomic_write`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..pipeline.pipeline import PipelineRun
from ..core.model import PairCalibration
from ..core.robust import CovarianceBasis


def _figure(nrows=1, ncols=1, **kw):
    from ..extras import require

    matplotlib = require("matplotlib", "plots", "the report's figures")
    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    fig = Figure(figsize=kw.pop("figsize", (8, 4.5)), layout="constrained")
    axes = fig.subplots(nrows, ncols, **kw)
    return fig, axes


def residual_vs_rate(run: PipelineRun, max_points: int = 20000):
    """Residual norm against gyro 1's rate norm (the paper's Fig. 6): flat for a rigid pair."""
    cal = run.calibration
    valid = np.ones(len(run.omega_1), bool) if run.valid is None else run.valid
    used = valid if run.used is None else run.used
    idx = np.flatnonzero(valid)
    idx = idx[:: max(1, idx.size // max_points)]
    rate = np.linalg.norm(run.omega_1[idx], axis=1)
    res = np.linalg.norm(run.omega_1[idx] - cal.compensate(run.omega_2[idx]), axis=1)
    fig, ax = _figure()
    kept = used[idx]
    ax.scatter(np.rad2deg(rate[kept]), np.rad2deg(res[kept]), s=2, alpha=0.4, label="used")
    if (~kept).any():
        ax.scatter(np.rad2deg(rate[~kept]), np.rad2deg(res[~kept]), s=4, color="tab:red", alpha=0.6,
                   label=f"rejected ({100 * cal.rejected_fraction:.1f}% of samples)")
    ax.set_xlabel("rate norm of gyro 1 (deg/s)")
    ax.set_ylabel("residual norm (deg/s)")
    ax.set_yscale("log")
    ax.set_title(f"Residual vs rate (Spearman rho = {cal.rate_residual_correlation:.2f}; "
                 f"{'rigid' if cal.rigid else 'NOT RIGID'})")
    ax.legend(loc="upper left")
    return fig


def snr_accumulation(run: PipelineRun, target_snr: float = 4e3):
    """Per-axis SNR of gyro 1 as samples accumulate (Eq. 36 per axis), with the paper's target."""
    from ..pipeline.selection import excitation_report

    cal = run.calibration
    sigma = float(np.hypot(*cal.noise_std))
    used = run.used if run.used is not None else None
    rep = excitation_report(run.omega_1, sigma, valid=used, target_snr=target_snr)
    x = np.arange(len(run.omega_1)) if run.t is None else run.t - run.t[0]
    fig, ax = _figure()
    for i, name in enumerate("xyz"):
        ax.plot(x, rep.cumulative_snr[:, i], label=f"axis {name}: {rep.snr[i]:.3g}")
    ax.axhline(target_snr, color="k", ls="--", lw=1, label=f"target {target_snr:g} (paper, Section VI)")
    ax.set_yscale("log")
    ax.set_xlabel("time (s)" if run.t is not None else "sample")
    ax.set_ylabel("per-axis SNR")
    ax.set_title("Excitation: SNR accumulation per axis")
    ax.legend()
    return fig


def alignment_curve(run: PipelineRun):
    """Correlation of the rate norms against the trial time offset (None for aligned input)."""
    if run.aligned is None or run.aligned.time_offset is None:
        return None
    off = run.aligned.time_offset
    fig, ax = _figure()
    ax.plot(off.lags_s * 1e3, off.correlation)
    ax.axvline(off.offset_s * 1e3, color="tab:red", ls="--",
               label=f"offset {off.offset_s * 1e3:+.3f} ms +- {off.std_s * 1e3:.3f} ms")
    ax.set_xlabel("offset added to gyro 2's timestamps (ms)")
    ax.set_ylabel("correlation of rate norms")
    ax.set_title("Time alignment")
    ax.legend()
    return fig


def rejected_stretches(run: PipelineRun):
    """Gyro 1's rate norm over time with the rejected and masked stretches shaded."""
    cal = run.calibration
    x = np.arange(len(run.omega_1)) if run.t is None else run.t - run.t[0]
    valid = np.ones(len(x), bool) if run.valid is None else run.valid
    used = valid if run.used is None else run.used
    fig, ax = _figure()
    ax.plot(x, np.rad2deg(np.linalg.norm(run.omega_1, axis=1)), lw=0.6, color="tab:blue")
    for m, color, label in ((~valid, "0.6", "masked (saturated / gap)"), (valid & ~used, "tab:red", "rejected (flex)")):
        if m.any():
            ax.fill_between(x, 0, 1, where=m, color=color, alpha=0.3, transform=ax.get_xaxis_transform(), label=label)
    ax.set_xlabel("time (s)" if run.t is not None else "sample")
    ax.set_ylabel("rate norm of gyro 1 (deg/s)")
    ax.set_title(f"Samples used: {cal.n_samples}; rejected {100 * cal.rejected_fraction:.1f}%")
    if (~used).any():
        ax.legend()
    return fig


def allan_deviation(run: PipelineRun):
    """The residual's overlapping Allan deviation per axis with the identified noise model (None without one).

    The curves are :attr:`NoiseModel.adev <fusion_gyrocal.core.noise.NoiseModel>` (per axis) and the fit
    ``adev_fit`` (white, bias instability, random walk, quantisation and filtered terms,
    :func:`~fusion_gyrocal.core.allan.fit_allan`), over the range of taus the fit used (shaded), with the model's
    white-noise line (slope -1/2, ``N`` from ``residual_noise_std``), its quantisation line (slope -1, ``Q``) and
    its random-walk line (slope +1/2, ``K`` the rest of the fit at the longest tau) where the fit has those terms.
    """
    from ..core.allan import FLICKER

    nm = run.calibration.noise_model
    if nm is None:
        return None
    deg = np.rad2deg(1.0)
    taus = np.asarray(nm.taus, float)
    fit = np.asarray(nm.adev_fit, float)
    n_sq = nm.residual_noise_std ** 2 / nm.rate_hz                 # N^2: the white term of the fit
    b_sq = nm.bias_instability ** 2
    k_sq = max(3.0 * (fit[-1] ** 2 - n_sq / taus[-1] - FLICKER * b_sq) / taus[-1], 0.0)
    if k_sq < 1e-6 * fit[-1] ** 2 / taus[-1]:   # rounding of the other terms, no walk in the fit
        k_sq = 0.0
    per_sample = run.t is None   # sample-aligned input: the model is per sample, tau in samples
    unit = "samples" if per_sample else "s"
    fig, ax = _figure(figsize=(8, 5))
    for i, (name, colour) in enumerate(zip("xyz", ("tab:blue", "tab:orange", "tab:green"))):
        ax.loglog(taus, nm.adev[:, i] * deg, "o", ms=4, color=colour, alpha=0.8, label=f"residual, axis {name}")
    lo, hi = nm.fit_taus
    ax.axvspan(lo, hi, color="0.85", alpha=0.5, lw=0, label=f"fit range {lo:.3g}-{hi:.3g} {unit}")
    for edge in (lo, hi):
        ax.axvline(edge, color="0.5", lw=0.8)
    ax.loglog(taus, fit * deg, "k-", lw=2, label="fitted model (axes pooled)")
    grid = np.geomspace(taus[0], taus[-1], 64)
    n_text = (f"{np.sqrt(n_sq) * deg:.3g} deg/s per sample" if per_sample else
              f"{np.sqrt(n_sq) * deg * 60:.3g} deg/sqrt(h)")
    ax.loglog(grid, np.sqrt(n_sq / grid) * deg, "--", color="tab:purple", lw=1.5,
              label=f"white noise N = {n_text} (slope -1/2)")
    if k_sq > 0:
        k_text = (f"{np.sqrt(k_sq) * deg:.3g} deg/s per sample^1.5" if per_sample else
                  f"{np.sqrt(k_sq) * deg * 3600 ** 1.5:.3g} deg/h/sqrt(h)")
        ax.loglog(grid, np.sqrt(k_sq * grid / 3.0) * deg, ":", color="tab:red", lw=2,
                  label=f"bias random walk K = {k_text} (slope +1/2)")
    q = nm.quantisation
    if q > 0:   # slope -1: quantisation, or a rate differentiated from a noisy angle
        q_text = f"{q * deg:.3g} deg" if not per_sample else f"{q * deg:.3g} deg-samples"
        ax.loglog(grid, np.sqrt(3.0) * q / grid * deg, "-.", color="tab:olive", lw=1.5,
                  label=f"quantisation / angle noise Q = {q_text} (slope -1)")
    if b_sq > 0:
        b_text = f"{np.sqrt(b_sq) * deg:.3g} deg/s" if per_sample else f"{np.sqrt(b_sq) * deg * 3600:.3g} deg/h"
        ax.axhline(np.sqrt(FLICKER * b_sq) * deg, color="tab:brown", ls="-.", lw=1,
                   label=f"bias instability B = {b_text}")
    shown = np.concatenate([nm.adev.ravel(), fit])
    shown = shown[np.isfinite(shown) & (shown > 0)] * deg
    if shown.size:
        ax.set_ylim(shown.min() / 2.0, shown.max() * 2.0)
    ax.set_xlabel(f"averaging time tau ({unit})")
    ax.set_ylabel("Allan deviation of the residual (deg/s)")
    walk = "no random-walk term in the fit" if k_sq == 0 else "random-walk term in the fit"
    where = "samples kept (quiet windows)" if nm.is_misfit else "valid samples"
    ax.set_title(f"Allan deviation of the pair's residual: {nm.kind}\n"
                 f"on the {where}; {walk}; bias model {nm.bias_model}", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    return fig


def static_allan_figure(noise, title: str = ""):
    """The pooled Allan deviation of a gyro at rest per axis (:class:`~fusion_gyrocal.core.static_noise.StaticNoise`)
    with each axis's fitted model and its white-noise line (slope -1/2)."""
    deg = np.rad2deg(1.0)
    fig, ax = _figure(figsize=(8, 5))
    for a, (name, colour) in enumerate(zip("xyz", ("tab:blue", "tab:orange", "tab:green"))):
        ax.loglog(noise.taus, noise.adev[:, a] * deg, "o", ms=4, color=colour, label=f"axis {name}")
        ax.loglog(noise.taus, noise.adev_fit[:, a] * deg, "-", color=colour, lw=1.5,
                  label=f"fit {name}: N {noise.white[a] * deg * 60:.3g} deg/sqrt(h), "
                        f"B {noise.bias_instability[a] * deg * 3600:.3g} deg/h, "
                        f"K {noise.random_walk[a] * deg * 3600 ** 1.5:.3g} deg/h/sqrt(h)")
        ax.loglog(noise.taus, noise.white[a] / np.sqrt(noise.taus) * deg, ":", color=colour, lw=1)
    ax.set_xlabel("averaging time tau (s)")
    ax.set_ylabel("Allan deviation (deg/s)")
    ax.set_title(title or f"Allan deviation at rest: {noise.n_samples} samples in {len(noise.stretches)} stretch(es)",
                 fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    return fig


def uncertainty_basis(cal) -> str:
    """One line saying what the reported uncertainty rests on: the noise (where it came from) and the
    covariance (noise model, block-robust, inflated), with the residual's chi-square per degree of freedom.

    ``cal`` is a :class:`PairCalibration` or an :class:`~fusion_gyrocal.core.array.ArrayCalibration`.
    """
    deg = np.rad2deg(1.0)
    white = "/".join(f"{v * deg:.3g}" for v in np.atleast_1d(cal.noise_std))
    pair = isinstance(cal, PairCalibration)
    nm = cal.noise_model if pair else None
    if nm is not None:
        bias = "bias random walk" if nm.bias_walk_std is not None else "bias constant"
        kind = "rate-dependent misfit" if nm.is_misfit else nm.kind
        noise = f"noise model identified from the residual (white {white} deg/s, {bias}; residual is {kind})"
    elif cal.noise_source == "user":
        noise = f"the given noise (white {white} deg/s)"
    elif cal.noise_source.startswith("identified"):
        noise = f"noise identified for every gyro from its pair with the reference (white {white} deg/s)"
    else:
        noise = f"noise from the {cal.noise_source}, its spread taken as white noise (white {white} deg/s)"
    if cal.bias_segments > 1:
        noise += f", bias piecewise constant over {cal.bias_segments} segments"
    lack = cal.lack_of_fit if pair else float("nan")
    chi = f"residual chi2/dof {lack:.3g}" if np.isfinite(lack) else "no residual chi2"
    worst = (f"std x{np.sqrt(cal.robust_inflation):.3g} in the worst direction"
             if np.isfinite(cal.robust_inflation) else "")
    kind = cal.covariance_kind
    if kind is CovarianceBasis.RAISED:
        cov = f"raised to the block-robust covariance where larger ({worst}; {chi})"
    elif kind is CovarianceBasis.ROBUST:
        cov = f"block-robust covariance as asked ({worst} against the noise model; {chi})"
    elif kind is CovarianceBasis.CHECKED:
        cov = f"covariance from the noise model; the block-robust check agrees ({worst}; {chi})"
    elif kind is CovarianceBasis.INFLATED:
        cov = "covariance from the noise model inflated by the residual's chi2/dof (see the note)"
    else:
        cov = f"covariance from the {cal.covariance_basis} alone, no block-robust check ({chi})"
    return f"uncertainty: {noise}, {cov}"


def sensor_model_lines(cal: PairCalibration) -> list[str]:
    """What the sensor model of ``cal`` found (``linear_map``, cross-axis terms, gyro 2's intrinsics, timing), a
    line each, with the rotation's repeatable 1-sigma beside its skew budget."""
    rep = np.sqrt(np.clip(np.diag(cal.repeatable_rotation_covariance), 0.0, None))
    budget = np.sqrt(np.clip(np.diag(cal.skew_rotation_covariance), 0.0, None))
    lines = [f"model: {cal.linear_map}; rotation 1-sigma {np.array2string(np.rad2deg(rep) * 1e3, precision=2)} mdeg "
             f"repeatable, skew budget {np.array2string(np.rad2deg(budget) * 1e3, precision=1)} mdeg"]
    if cal.linear_map == "full":
        sd = np.sqrt(np.clip(np.diag(cal.cross_axis_covariance), 0.0, None))
        lines.append("cross-axis terms (xy, yz, zx): " + ", ".join(
            f"{100 * v:.3f} +- {100 * e:.3f} %" for v, e in zip(cal.cross_axis_terms, sd)))
    elif cal.linear_map == "reference":
        lines.append(f"gyro 2's intrinsic matrix: {np.array2string(cal.intrinsics_2, precision=5)}")
    if cal.timing_explained > 0:
        tones = ", ".join(f"{f:.4g}" for f in cal.timing_tones_hz) or "none (a constant delay)"
        lines.append(f"timing: beat tones {tones}; delay {cal.timing_delay_s * 1e3:+.3g} ms, std "
                     f"{cal.timing_delay_std_s * 1e3:.3g} ms; {100 * cal.timing_explained:.0f}% of the residual's energy")
    return lines


def summary_markdown(cal: PairCalibration) -> str:
    """A short human-readable summary of a calibration."""
    rv = np.rad2deg(cal.rotvec)
    rs = np.rad2deg(cal.rotation_std_rad) * 1e3
    lines = [
        "# Gyroscope pair calibration", "",
        f"- configuration: **{cal.configuration}**; rigid: **{cal.rigid}**; method: {cal.method}",
        f"- R_1_2 rotation vector: {np.array2string(rv, precision=4)} deg "
        f"(1-sigma {np.array2string(rs, precision=2)} mdeg)",
        f"- scale_1: {np.array2string(cal.scale_1, precision=6)}; scale_2: {np.array2string(cal.scale_2, precision=6)}",
        f"- scale observable: {cal.scale_observable.tolist()}; gauge: {cal.gauge}",
        f"- bias: {np.array2string(np.rad2deg(cal.bias), precision=4)} deg/s",
        f"- time offset: {cal.time_offset_s * 1e3:+.4f} ms +- {cal.time_offset_std_s * 1e3:.4f} ms",
        f"- per-axis SNR: {np.array2string(cal.snr, precision=0)}; samples: {cal.n_samples}; "
        f"rejected: {100 * cal.rejected_fraction:.2f}%",
        f"- noise std: {np.array2string(np.rad2deg(cal.noise_std), precision=4)} deg/s ({cal.noise_source})",
        f"- {uncertainty_basis(cal)}; covariance basis: {cal.covariance_basis}",
    ]
    lines += ["", "## Sensor model", ""] + [f"- {line}" for line in sensor_model_lines(cal)]
    if cal.deviation is not None:
        d, C = cal.deviation
        lines.append(f"- deviation from the nominal mounting: {np.degrees(np.linalg.norm(d)):.4f} deg, rotation vector "
                     f"{np.array2string(np.degrees(d), precision=4)} +- "
                     f"{np.array2string(np.degrees(np.sqrt(np.clip(np.diag(C), 0, None))), precision=4)} deg")
    lines.append("- scale_2 / scale_1 on the parallel axes: " + ", ".join(
        f"{r:.6f} +- {e:.2g}" if np.isfinite(e) else f"{r:.6f}" for r, e in zip(cal.scale_ratio, cal.scale_ratio_std)))
    q = cal.quaternion_xyzw
    lines.append(f"- R_1_2 quaternion x, y, z, w: {', '.join(f'{v:.9f}' for v in q)}; roll, pitch, yaw "
                 f"{np.array2string(np.degrees(cal.rpy), precision=4)} deg")
    lines += [""] + [f"- note: {n}" for n in cal.notes]
    if cal.provenance is not None:
        lines += ["", "## Inputs", ""] + [f"- {line}" for line in cal.provenance.lines()]
    if cal.noise_model is not None:
        lines += ["", "## Noise model (identified from the residual)", ""]
        lines += [f"- {line}" for line in cal.noise_model.describe().splitlines()]
    return "\n".join(lines) + "\n"


def write_figure(fig, path, **savefig) -> Path:
    """Write ``fig`` to ``path`` atomically, in the format of its suffix (PNG without one).

    The figure is rendered in memory and written with :func:`~fusion_gyrocal.io.writers.atomic_write`
    (temp file in the same folder, then ``os.replace``): a reader never sees half a figure.
    ``savefig`` are keywords of :meth:`matplotlib.figure.Figure.savefig` (``dpi``, ``bbox_inches``).

    Raises
    ------
    FormatError
        The folder does not exist or cannot be written (the message names the file and the cause).
    """
    import io

    from .writers import atomic_write

    path = Path(path).expanduser()
    buf = io.BytesIO()
    fig.savefig(buf, format=path.suffix.lstrip(".").lower() or "png", **savefig)
    return atomic_write(path, buf.getvalue())


def write_report(run: PipelineRun, out_dir, *, extra_figures=None) -> list[Path]:
    """Write the summary (``report.md``) and every figure as PNG into ``out_dir`` (created).

    Every file is written atomically (:func:`~fusion_gyrocal.io.writers.atomic_write`): a figure or
    summary being replaced is never seen half-written.

    Raises
    ------
    FormatError
        ``out_dir`` cannot be created or written ("cannot write the report to OUT: Permission
        denied"); the files already in it are left as they were.
    """
    from ..errors import FormatError
    from .writers import atomic_write, os_reason

    out = Path(out_dir).expanduser()
    figs = {"residual_vs_rate": residual_vs_rate(run), "snr_accumulation": snr_accumulation(run),
            "alignment": alignment_curve(run), "rejected_stretches": rejected_stretches(run),
            "allan_deviation": allan_deviation(run)}
    figs.update(extra_figures or {})
    paths = []
    md = summary_markdown(run.calibration)
    if out.exists() and not out.is_dir():
        raise FormatError(f"cannot write the report to {out}: it is a file, expected a folder (--out)")
    try:
        out.mkdir(parents=True, exist_ok=True)
        for name, fig in figs.items():
            if fig is None:
                continue
            paths.append(write_figure(fig, out / f"{name}.png", dpi=110))
            md += f"\n![{name}]({name}.png)\n"
        paths.append(atomic_write(out / "report.md", md))
    except (OSError, FormatError) as exc:
        cause = exc if isinstance(exc, OSError) else exc.__cause__
        why = os_reason(cause) if isinstance(cause, OSError) else str(exc)
        raise FormatError(f"cannot write the report to {out}: {why}") from exc
    return paths


def write_array_report(runs, out_dir, *, provenance=None) -> list[Path]:
    """The report of N gyros: one page per gyro against the reference, and an index.

    ``runs`` maps each gyro's number (from 2; gyro 1 is the reference) to the :class:`PipelineRun` of its pair with
    gyro 1. Every page is :func:`write_report` in ``out_dir/gyro<k>/``; ``out_dir/report.md`` lists each gyro's
    rotation, relative scale factors, time offset, rigidity and noise with a link to its page, and the inputs
    (``provenance``: :class:`~fusion_gyrocal.provenance.Provenance`). Every file is written atomically.

    Raises
    ------
    FormatError
        ``out_dir`` cannot be created or written.
    """
    from ..core.model import rotation_text
    from ..errors import FormatError
    from .writers import atomic_write

    out = Path(out_dir).expanduser()
    if out.exists() and not out.is_dir():
        raise FormatError(f"cannot write the report to {out}: it is a file, expected a folder (--out)")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FormatError(f"cannot write the report to {out}: {exc.strerror or exc}") from exc
    paths = []
    lines = [f"# Calibration of {len(runs) + 1} gyros, each against gyro 1 (the reference)", "",
             "| gyro | R_1_k | scale_k / scale_1 (parallel axes) | time offset (ms) | rigid | rejected | page |",
             "|---|---|---|---|---|---|---|"]
    for k, run in sorted(runs.items()):
        paths += write_report(run, out / f"gyro{k}")
        cal = run.calibration
        ratios = ", ".join(f"{r:.5f} +- {e:.2g}" if np.isfinite(e) else f"{r:.5f}"
                           for r, e in zip(cal.scale_ratio, cal.scale_ratio_std))
        lines.append(f"| {k} | {rotation_text(cal.R_1_2, cal.rotation_std_rad)} | {ratios} | "
                     f"{cal.time_offset_s * 1e3:+.4f} +- {cal.time_offset_std_s * 1e3:.4f} | {cal.rigid} | "
                     f"{100 * cal.rejected_fraction:.2f}% | [gyro {k}](gyro{k}/report.md) |")
    if provenance is not None:
        lines += ["", "## Inputs", ""] + [f"- {line}" for line in provenance.lines()]
    paths.append(atomic_write(out / "report.md", "\n".join(lines) + "\n"))
    return paths
