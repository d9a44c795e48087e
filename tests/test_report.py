"""The report's files: every figure and the summary written atomically; an unwritable folder is one FormatError."""

import os

import pytest

from fusion_gyrocal import FormatError
from fusion_gyrocal.cli import main
from fusion_gyrocal.evaluate.sim import simulate_pair
from fusion_gyrocal.io.report import write_figure, write_report
from fusion_gyrocal.pipeline.pipeline import run_pipeline

NAMES = ("residual_vs_rate.png", "snr_accumulation.png", "alignment.png", "rejected_stretches.png",
         "allan_deviation.png", "report.md")


@pytest.fixture(scope="module")
def run():
    sim = simulate_pair(rng=4, n=2000)
    return run_pipeline(sim.omega_1, sim.omega_2, t_1=sim.t, t_2=sim.t)


def test_write_report_writes_every_file_through_a_temp_file_and_replace(run, tmp_path, monkeypatch):
    replaced = []
    real = os.replace

    def spy(src, dst):
        replaced.append((os.path.dirname(src), os.path.basename(src), os.path.basename(dst)))
        return real(src, dst)

    monkeypatch.setattr(os, "replace", spy)
    paths = write_report(run, tmp_path / "rep")
    assert sorted(p.name for p in paths) == sorted(NAMES)
    assert sorted(d for _, _, d in replaced) == sorted(NAMES)
    # each from a hidden temp file in the report's own folder (a rename, never a copy across file systems)
    assert all(folder == str(tmp_path / "rep") and src.startswith(f".{dst}.") for folder, src, dst in replaced)
    png = (tmp_path / "rep" / "residual_vs_rate.png").read_bytes()
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and len(png) > 10_000
    assert sorted(os.listdir(tmp_path / "rep")) == sorted(NAMES)   # no temp file left


def test_write_report_failed_write_keeps_the_old_files_and_names_the_folder(run, tmp_path, monkeypatch):
    out = tmp_path / "rep"
    write_report(run, out)
    before = {n: (out / n).read_bytes() for n in NAMES}
    calls = []
    real = os.replace

    def refuse_second(src, dst):
        calls.append(dst)
        if len(calls) == 2:
            raise PermissionError(13, "Permission denied")
        return real(src, dst)

    monkeypatch.setattr(os, "replace", refuse_second)
    with pytest.raises(FormatError, match=f"^cannot write the report to {out}: Permission denied$"):
        write_report(run, out)
    assert (out / os.path.basename(calls[1])).read_bytes() == before[os.path.basename(calls[1])]
    assert sorted(os.listdir(out)) == sorted(NAMES)   # the temp file of the refused write is removed


def test_write_report_out_is_a_file_raises_format_error(run, tmp_path):
    f = tmp_path / "taken"
    f.write_text("x")
    with pytest.raises(FormatError, match="cannot write the report to .*taken: it is a file, expected a folder"):
        write_report(run, f)


def test_write_report_folder_that_cannot_be_created_raises_format_error(run, tmp_path, monkeypatch):
    from pathlib import Path

    def refuse(self, *a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(Path, "mkdir", refuse)
    with pytest.raises(FormatError, match=r"^cannot write the report to .*new: Permission denied$"):
        write_report(run, tmp_path / "new")


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root writes into read-only folders")
def test_write_report_read_only_folder_raises_format_error(run, tmp_path):
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o555)
    try:
        with pytest.raises(FormatError, match=f"^cannot write the report to {out}: Permission denied$"):
            write_report(run, out)
    finally:
        out.chmod(0o755)


def test_write_figure_format_from_suffix(tmp_path):
    from matplotlib.figure import Figure

    fig = Figure()
    fig.subplots().plot([0, 1], [1, 0])
    assert write_figure(fig, tmp_path / "f.svg").read_bytes().lstrip().startswith(b"<?xml")
    assert write_figure(fig, tmp_path / "f.png").read_bytes().startswith(b"\x89PNG")
    with pytest.raises(FormatError, match="does not exist"):
        write_figure(fig, tmp_path / "missing" / "f.png")


def test_cli_report_unwritable_out_is_one_line_exit_1(tmp_path, capsys):
    from fusion_gyrocal.io import ImuStream, write_csv

    sim = simulate_pair(rng=5, n=2000)
    write_csv(ImuStream(sim.t, sim.omega_1), tmp_path / "a.csv")
    write_csv(ImuStream(sim.t, sim.omega_2), tmp_path / "b.csv")
    (tmp_path / "taken").write_text("x")
    assert main(["report", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--out", str(tmp_path / "taken")]) == 1
    out = capsys.readouterr()
    assert out.err == (f"gyrocal: error: cannot write the report to {tmp_path / 'taken'}: it is a file, expected a "
                       "folder (--out)\n")


# ------------------------------------------------------------------------------- noise model and uncertainty basis
def test_allan_deviation_draws_the_residual_fit_range_and_model_lines():
    import numpy as np

    from fusion_gyrocal.evaluate.sim import PAPER_BIAS_WALK_STD
    from fusion_gyrocal.io.report import allan_deviation

    sim = simulate_pair(rng=6, n=30000, bias_walk_std=100 * PAPER_BIAS_WALK_STD)
    run_ = run_pipeline(sim.omega_1, sim.omega_2, t_1=sim.t, t_2=sim.t)
    nm = run_.calibration.noise_model
    assert nm.bias_model == "random walk"
    ax = allan_deviation(run_).axes[0]
    assert ax.get_xscale() == ax.get_yscale() == "log"
    assert nm.kind in ax.get_title()
    lines = {line.get_label(): line for line in ax.get_lines()}
    # the residual per axis and the fitted model, in deg/s against tau
    for i, name in enumerate("xyz"):
        np.testing.assert_allclose(lines[f"residual, axis {name}"].get_ydata(), np.rad2deg(nm.adev[:, i]))
    np.testing.assert_allclose(lines["fitted model (axes pooled)"].get_ydata(), np.rad2deg(nm.adev_fit))
    white = next(v for k, v in lines.items() if k.startswith("white noise"))
    walk = next(v for k, v in lines.items() if k.startswith("bias random walk"))
    x, y = white.get_xdata(), white.get_ydata()
    assert np.allclose(np.diff(np.log(y)) / np.diff(np.log(x)), -0.5)
    # the white line is the fit's white term: N = residual_noise_std / sqrt(rate)
    assert y[0] == pytest.approx(np.rad2deg(nm.residual_noise_std / np.sqrt(nm.rate_hz * x[0])), rel=1e-9)
    x, y = walk.get_xdata(), walk.get_ydata()
    assert np.allclose(np.diff(np.log(y)) / np.diff(np.log(x)), 0.5)
    # white + walk (no flicker here) add up to the fitted model at the longest tau
    assert nm.bias_instability == 0.0
    assert np.hypot(white.get_ydata()[-1], walk.get_ydata()[-1]) == pytest.approx(np.rad2deg(nm.adev_fit[-1]), rel=1e-6)
    span = [p for p in ax.patches if p.get_label().startswith("fit range")]
    assert len(span) == 1 and f"{nm.fit_taus[0]:.3g}-{nm.fit_taus[1]:.3g} s" in span[0].get_label()


def test_allan_deviation_none_without_noise_model():
    from fusion_gyrocal.io.report import allan_deviation

    sim = simulate_pair(rng=7, n=2000)
    assert allan_deviation(run_pipeline(sim.omega_1, sim.omega_2, noise_std=0.002)) is None


def test_summary_markdown_lists_the_noise_model_and_the_uncertainty_basis(run):
    from fusion_gyrocal.io.report import summary_markdown, uncertainty_basis

    md = summary_markdown(run.calibration)
    for line in run.calibration.noise_model.describe().splitlines():
        assert f"- {line}" in md
    assert f"- {uncertainty_basis(run.calibration)}" in md
    assert "## Noise model (identified from the residual)" in md


def test_uncertainty_basis_names_noise_source_and_covariance():
    import dataclasses

    from fusion_gyrocal.core.noise import NoiseKind
    from fusion_gyrocal.core.robust import CovarianceBasis
    from fusion_gyrocal.io.report import uncertainty_basis

    sim = simulate_pair(rng=8, n=6000)
    cal = run_pipeline(sim.omega_1, sim.omega_2, t_1=sim.t, t_2=sim.t).calibration
    line = uncertainty_basis(cal)
    assert line.startswith("uncertainty: noise model identified from the residual (white ")
    assert "bias constant; residual is white noise" in line and "\n" not in line
    assert f"residual chi2/dof {cal.lack_of_fit:.3g}" in line
    # a misfit raised to the block-robust covariance: the worst direction's std ratio is named
    bad = dataclasses.replace(cal, robust_inflation=39.69, lack_of_fit=210.0,
                              noise_model=dataclasses.replace(cal.noise_model, noise_kind=NoiseKind.RATE_MISFIT),
                              covariance_basis="noise model raised to the block-robust sandwich (9 windows of 9 "
                                               "samples) where that is significantly larger",
                              covariance_kind=CovarianceBasis.RAISED)
    assert uncertainty_basis(bad).endswith("residual is rate-dependent misfit), raised to the block-robust covariance "
                                           "where larger (std x6.3 in the worst direction; residual chi2/dof 210)")
    user = run_pipeline(sim.omega_1, sim.omega_2, noise_std=0.002, covariance="model").calibration
    assert uncertainty_basis(user).startswith("uncertainty: the given noise (white 0.115/0.115 deg/s)")
    assert "no block-robust check" in uncertainty_basis(user)
    res = run_pipeline(sim.omega_1, sim.omega_2, noise_model="residual").calibration
    assert "its spread taken as white noise" in uncertainty_basis(res)
