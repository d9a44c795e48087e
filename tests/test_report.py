"""The report's files: every figure and the summary written atomically; an unwritable folder is one FormatError."""

import os

import pytest

from fusion_gyrocal import FormatError
from fusion_gyrocal.cli import main
from fusion_gyrocal.evaluate.sim import simulate_pair
from fusion_gyrocal.io.report import write_figure, write_report
from fusion_gyrocal.pipeline.pipeline import run_pipeline

NAMES = ("residual_vs_rate.png", "snr_accumulation.png", "alignment.png", "rejected_stretches.png", "report.md")


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
