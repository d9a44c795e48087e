"""What reading a recording computes once and hands on (issue 25) gives what computing it again gives.

Equivalence tests only: the arrays a reader hands over, the remembered timestamp diagnosis and median step, the
pyarrow columns read without a '#' scan, and the pipeline on a stream's own arrays. Speed is measured by
``benchmarks/end_to_end.py``, never asserted here.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fusion_gyrocal.errors import InputError
from fusion_gyrocal.io import ImuStream, read_csv
from fusion_gyrocal.io import text as text_mod
from fusion_gyrocal.pipeline import streams
from fusion_gyrocal.pipeline.pipeline import run_pipeline


def _write(path, t, w, header="t,gyro_x,gyro_y,gyro_z", fmt="%.9f"):
    np.savetxt(path, np.column_stack([t, w]), delimiter=",", fmt=fmt, header=header, comments="")
    return path


def _rates(rng, n):
    return rng.normal(0.0, 0.5, (n, 3))


def test_read_csv_hands_over_read_only_arrays_equal_to_a_copy(tmp_path):
    rng = np.random.default_rng(0)
    t = 3.0 + np.arange(400) / 200.0 + rng.uniform(0, 1e-5, 400)
    s = read_csv(_write(tmp_path / "a.csv", t, _rates(rng, 400)), unit="deg/s")
    again = ImuStream(s.t.copy(), s.omega.copy(), name=s.name)        # writeable input: copied and checked
    for a, b in ((s.t, again.t), (s.omega, again.omega), (s.valid, again.valid)):
        np.testing.assert_array_equal(a, b)
        assert not a.flags.writeable and a.base is None and a.flags.c_contiguous
    assert s.rate_hz == again.rate_hz == float(1.0 / np.median(np.diff(s.t)))


def test_imustream_copies_writeable_input_and_keeps_read_only_owned_arrays():
    t, w = np.arange(20) / 50.0, np.ones((20, 3))
    s = ImuStream(t, w)
    assert not np.shares_memory(s.t, t) and not np.shares_memory(s.omega, w)
    t.flags.writeable = w.flags.writeable = False
    kept = ImuStream(t, w)
    assert kept.t is t and kept.omega is w
    whole = np.arange(40.0) / 50.0
    whole.flags.writeable = False
    view = whole[::2]
    assert not np.shares_memory(ImuStream(view, np.ones((20, 3))).t, view)   # a view: copied


def test_remembered_timestamps_give_the_diagnosis_and_period_of_a_fresh_check():
    rng = np.random.default_rng(1)
    t = 100.0 + np.arange(5000) / 400.0 + rng.normal(0, 2e-5, 5000)
    t[2000:] += 0.05                                                     # a drop
    s = ImuStream(t, _rates(rng, 5000), name="g")
    fresh = s.t.copy()                                                   # writeable: not remembered
    assert streams._known(fresh) is None and streams._known(s.t) is not None
    assert streams._nominal_period(s.t) == streams._nominal_period(fresh) == float(np.median(np.diff(fresh)))
    got, want = (streams.timed_stream("t_1", x, "omega_1", s.omega, None) for x in (s.t, fresh))
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[2], want[2])
    assert got[3] == want[3] and got[3].name == "t_1" and got[4] == want[4]
    assert streams.check_timestamps("x", s.t, length=5000) is s.t


def test_remembered_bursty_timestamps_are_regularised_as_a_fresh_check_does():
    n, rng = 4000, np.random.default_rng(2)
    t = np.repeat(np.arange(n // 4) * 0.02, 4) + np.tile([0.0, 1e-5, 2e-5, 3e-5], n // 4) + 10.0
    s = ImuStream(t, _rates(rng, n))
    assert streams._known(s.t).quality.bursty
    assert s.rate_hz == float(1.0 / np.median(np.diff(t)))
    got, want = (streams.timed_stream("t_2", x, "omega_2", s.omega, None) for x in (s.t, s.t.copy()))
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_equal(dataclasses.astuple(got[3]), dataclasses.astuple(want[3]))   # jitter: NaN in both
    assert got[4] == want[4] and "bursty timestamps" in got[4][0]


def test_timestamps_made_writeable_again_are_checked_again():
    s = ImuStream(np.arange(50) / 100.0, np.zeros((50, 3)))
    s.t.flags.writeable = True
    s.t[10] = s.t[9]                                                     # a duplicate now
    with pytest.raises(InputError, match="duplicate timestamp"):
        streams.check_timestamps("t", s.t)
    with pytest.raises(InputError, match="t_1: expected strictly increasing timestamps, got a duplicate"):
        streams.timed_stream("t_1", s.t, "omega_1", s.omega, None)
    assert streams._nominal_period(s.t) == float(np.median(np.diff(s.t)))


def test_replaced_stream_keeps_its_checked_arrays():
    s = ImuStream(np.arange(30) / 10.0, np.ones((30, 3)), name="a")
    r = dataclasses.replace(s, name="b")
    assert r.t is s.t and r.omega is s.omega and r.rate_hz == s.rate_hz and r.name == "b"


@pytest.mark.parametrize("rows", ["ms_read_as_s", "ms_backwards", "duplicate", "one_row", "corrupt_jump"])
def test_read_csv_seconds_refusals_as_the_two_checks_in_turn(tmp_path, rows):
    """Float seconds are checked in one look at their steps: the time-unit refusal still comes first."""
    rng = np.random.default_rng(3)
    n = 1 if rows == "one_row" else 300
    t = np.arange(n) * (5.0 if rows.startswith("ms") else 0.005)
    if rows == "ms_backwards":
        t[100] = t[98]
    if rows == "duplicate":
        t[7] = t[6]
    if rows == "corrupt_jump":
        t[150:] += 1e6
    p = _write(tmp_path / "x.csv", t, _rates(rng, n))
    expected = {"ms_read_as_s": r"read as s \(the default\) have a median step of 5 s = 0.2 Hz.*look like ms",
                "ms_backwards": r"read as s \(the default\).*look like ms",
                "duplicate": r"x\.t: expected strictly increasing timestamps, got a duplicate timestamp "
                             r"(np\.float64\()?0\.03\)? s at samples 6 and 7",
                "one_row": r"x\.t: expected at least 2 timestamps, got 1",
                "corrupt_jump": r"x\.t: expected timestamps without huge jumps"}[rows]
    with pytest.raises(InputError, match=expected):
        read_csv(p)


@pytest.mark.parametrize("layout", ["all_columns", "comment_row", "hash_in_unused_column", "hash_in_used_column"])
def test_pyarrow_columns_without_the_hash_scan_equal_loadtxt(tmp_path, monkeypatch, layout):
    pytest.importorskip("pyarrow")
    monkeypatch.setattr(text_mod, "PANDAS_MIN_BYTES", 0)
    rng = np.random.default_rng(4)
    x = np.column_stack([np.arange(50) / 100.0, _rates(rng, 50)])
    lines = [",".join(f"{v:.9f}" for v in row) for row in x]
    extra = layout == "hash_in_unused_column"
    if extra:
        lines = [ln + (",#note" if k == 20 else ",ok") for k, ln in enumerate(lines)]
    if layout == "comment_row":
        lines.insert(20, "# a comment")
    if layout == "hash_in_used_column":
        lines[20] += " # a comment"
    p = tmp_path / "c.csv"
    p.write_text("t,gyro_x,gyro_y,gyro_z" + (",label" if extra else "") + "\n" + "\n".join(lines) + "\n")
    kw = dict(skiprows=1, delimiter=",", usecols=[0, 1, 2, 3])
    ref = text_mod._load_columns(p, dtype=np.float64, **kw)
    whole, split = text_mod._pyarrow_floats(p, **kw), text_mod._pyarrow_floats(p, **kw, split=True)
    if layout == "all_columns":
        np.testing.assert_array_equal(whole, ref)
        np.testing.assert_array_equal(split[0], ref[:, 0])
        np.testing.assert_array_equal(split[1], ref[:, 1:])
        assert split[0].flags.c_contiguous and split[1].flags.c_contiguous
    else:
        assert whole is None and split is None          # loadtxt (or pandas) reads the comment
    s = read_csv(p)
    np.testing.assert_array_equal(s.t, ref[:, 0])
    np.testing.assert_array_equal(s.omega, ref[:, 1:])


def test_run_pipeline_on_a_streams_own_arrays_equals_on_copies(tmp_path):
    from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, HumanMotion, random_rotation

    rng = np.random.default_rng(5)
    motion, R = HumanMotion(0.6, rng=rng), random_rotation(rng)
    t = np.arange(0, 60.0, 1 / 200.0)
    w1 = motion(t) + rng.normal(0, PAPER_NOISE_STD, (t.size, 3))
    w2 = motion(t + 0.0123) @ R + rng.normal(0, PAPER_NOISE_STD, (t.size, 3))
    s1, s2 = (read_csv(_write(tmp_path / f"{k}.csv", t, w)) for k, w in (("a", w1), ("b", w2)))
    own = run_pipeline(s1.omega, s2.omega, t_1=s1.t, t_2=s2.t).calibration
    copies = run_pipeline(s1.masked_omega, s2.masked_omega, t_1=s1.t.copy(), t_2=s2.t.copy()).calibration
    for f in ("R_1_2", "scale_1", "scale_2", "bias", "covariance", "time_offset_s", "time_offset_std_s"):
        np.testing.assert_array_equal(getattr(own, f), getattr(copies, f))
    assert own.timestamp_quality == copies.timestamp_quality and own.notes == copies.notes


def test_timestamp_quality_histogram_counts_the_bins_of_a_sorted_search():
    rng = np.random.default_rng(6)
    for _ in range(50):
        n = int(rng.integers(2, 2000))
        step = rng.choice([0.01, 0.0025, 0.0075, 0.0125, 0.015, 0.025, 0.0, -0.01, 1.0], n)
        step = step + rng.normal(0, rng.choice([0.0, 1e-4, 3e-3]), n)
        q = streams._quality("t", step, n + 1)
        if not np.isfinite(q.period_s):
            continue
        pos = step[step > 0]
        edges = np.array(streams._STEP_BINS[1:-1]) * q.period_s
        want = np.bincount(np.searchsorted(edges, pos, side="right"), minlength=len(streams._STEP_BINS) - 1)
        assert q.step_histogram == (step.size - pos.size, *(int(c) for c in want))
