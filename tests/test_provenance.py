"""Provenance in every result file: inputs as read, options, version, masked and rejected counts; one numbering."""

import json

import numpy as np
import pytest

import fusion_gyrocal
from fusion_gyrocal import FormatError
from fusion_gyrocal.cli import main
from fusion_gyrocal.io import read_imu, read_json
from fusion_gyrocal.provenance import InputRecord, Provenance, provenance_of
from test_cli import _write_pair


def test_provenance_to_dict_from_dict_round_trip():
    p = Provenance("1.2.3", "gyrocal calibrate x", (InputRecord(1, "x.bag", "bag", (("topic", "/imu0"),), "rad/s",
                                                                400.0, 100, 3),), (("gauge", "fixed"),), 90, 4,
                   "2026-01-01T00:00:00+00:00")
    d = json.loads(json.dumps(p.to_dict()))
    assert Provenance.from_dict(d) == p
    assert d["inputs"][0]["reader_options"] == {"topic": "/imu0"} and d["n_masked"] == [3]
    with pytest.raises(FormatError, match="provenance: expected an object with a 'version'"):
        Provenance.from_dict({"inputs": []})


def test_provenance_of_counts_masked_samples_per_gyro():
    t = np.arange(100) / 50.0
    w = np.zeros((100, 3))
    w[[3, 7, 9]] = np.nan
    from fusion_gyrocal.io import ImuStream

    s = ImuStream(t, w, name="a", source="a.csv", unit_in="deg/s")
    p = provenance_of([s, ImuStream(t, np.zeros((100, 3)))], n_used=97)
    assert p.n_masked == (3, 0) and p.inputs[0].unit_in == "deg/s" and p.inputs[0].gyro == 1
    assert p.inputs[1].gyro == 2 and p.version == fusion_gyrocal.__version__


def test_cli_calibrate_json_records_inputs_options_version_and_counts(tmp_path, capsys):
    p1, p2, _, _ = _write_pair(tmp_path, seed=6)
    out = tmp_path / "cal.json"
    assert main(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--method", "direct", "--output", str(out)]) == 0
    printed = capsys.readouterr().out
    d = json.loads(out.read_text())["provenance"]
    assert d["version"] == fusion_gyrocal.__version__ and d["command"].startswith("gyrocal ")
    assert [i["gyro"] for i in d["inputs"]] == [1, 2]
    assert [i["path"] for i in d["inputs"]] == [str(p1), str(p2)]
    assert [i["format"] for i in d["inputs"]] == ["csv", "csv"]
    assert [i["unit_in"] for i in d["inputs"]] == ["rad/s", "deg/s"] and d["inputs"][1]["reader_options"] == {
        "unit": "deg/s"}
    s1, s2 = read_imu(p1), read_imu(p2, unit="deg/s")
    assert [i["n_samples"] for i in d["inputs"]] == [len(s1.t), len(s2.t)]
    assert [i["rate_hz"] for i in d["inputs"]] == [s1.rate_hz, s2.rate_hz]
    assert d["options"] == {"method": "direct"}
    cal = read_json(out)
    assert d["n_used"] == cal.n_samples and cal.provenance.inputs[1].path == str(p2)
    assert isinstance(d["n_rejected"], int) and (d["n_rejected"] == 0) == (cal.rejected_fraction == 0)
    assert "input: gyro 1:" in printed and "input: gyro 2:" in printed and "masked" in printed


def test_cli_calibrate_array_json_and_report_record_inputs(tmp_path, capsys):
    p1, p2, _, _ = _write_pair(tmp_path, seed=7)
    out = tmp_path / "arr.json"
    assert main(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--array", "--output", str(out)]) == 0
    cal = read_json(out)
    assert cal.provenance is not None and [r.gyro for r in cal.provenance.inputs] == [1, 2]
    assert main(["report", str(p1), str(p2), "--unit2", "deg/s", "--out", str(tmp_path / "rep")]) == 0
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## Inputs" in md and f"gyro 2: {p2} (csv, unit deg/s; read in deg/s" in md
    capsys.readouterr()


def test_cli_report_three_gyros_one_page_each_and_an_index(tmp_path, capsys):
    p1, p2, _, _ = _write_pair(tmp_path, seed=8)
    p3 = tmp_path / "c.csv"
    p3.write_text(p1.read_text())   # a copy of gyro 1's file: another recording of the same motion
    arr = np.loadtxt(p3, delimiter=",", skiprows=1)
    arr[:, 1:] += np.random.default_rng(0).normal(0, 1e-3, arr[:, 1:].shape)
    np.savetxt(p3, arr, delimiter=",", header="t,gyro_x,gyro_y,gyro_z", comments="")
    assert main(["report", str(p1), str(p2), str(p3), "--unit", "rad/s,deg/s,rad/s", "--out", str(tmp_path / "r")]) == 0
    index = (tmp_path / "r" / "report.md").read_text()
    assert "(gyro2/report.md)" in index and "(gyro3/report.md)" in index and "## Inputs" in index
    for k in (2, 3):
        assert (tmp_path / "r" / f"gyro{k}" / "residual_vs_rate.png").exists()
    row3 = next(line for line in index.splitlines() if line.startswith("| 3 |"))
    assert float(row3.split("|")[2].split()[0]) < 0.5          # gyro 3 is mounted like gyro 1
    assert main(["report", str(p1), str(p2), str(p3), "--unit", "rad/s,deg/s,rad/s", "--track",
                 "--out", str(tmp_path / "t")]) == 1
    assert "--track: expected two gyros" in capsys.readouterr().err
