"""The time-offset refinement's faster paths give what the plain ones give (issue 25).

The bracketed (Brent) search runs on a thinned set of the refinement instants and Newton steps on all of them
finish; one linearisation of the misfit serves the whole record's std and every drift stretch's; a Newton step
keeps the instants and the curvature; the excited windows reach the splines as spans. Each is checked against
the path it replaces, and the estimate against the simulated truth.
"""

from __future__ import annotations

import numpy as np
import pytest

import fusion_gyrocal.pipeline.alignment as al
from fusion_gyrocal.evaluate.sim import simulate_streams
from fusion_gyrocal.pipeline.streams import DEFAULT_GAP_PERIODS, _nominal_period


def _full_search(spl2, x1, y1, tau0, h):
    """The refinement before the thinned search: Brent on every instant, the std at its minimum."""
    tau = al._refine(spl2, x1, y1, tau0, h)[0]
    lin = al._linearise(spl2, x1, y1, tau, h)
    return tau, lin, lin.std_step()[0]


def _setup(seed=3, duration=300.0, rates=(200.0, 200.0), offset=0.0371):
    """Gyro 2's splines, the refinement instants and gyro 1's rates there, the grid step, the true offset."""
    t1, w1, t2, w2, _, _ = simulate_streams(seed, rate_1=rates[0], rate_2=rates[1], duration=duration, offset=offset)
    ok1, ok2 = np.ones(t1.size, dtype=bool), np.ones(t2.size, dtype=bool)
    p1, p2 = _nominal_period(t1), _nominal_period(t2)
    h = min(p1, p2)
    spl2, x1, y1 = al._instants(t1, w1, ok1, t2, w2, ok2, h * al._EVAL_STEP, h, DEFAULT_GAP_PERIODS * p1,
                                DEFAULT_GAP_PERIODS * p2, al.MAX_EVAL, [offset])
    return spl2, x1, y1, h, offset


def test_estimate_time_offset_thinned_search_matches_the_full_search_against_the_truth(monkeypatch):
    # 300 s records (~97k instants: the bracketed search on every 5th block): the offset within the search's own
    # tolerance of the full search's and a fiftieth of its std, the std the same, the error to the truth no larger
    errors, stds = [], []
    for seed in range(6):
        rates = ((100.0, 200.0), (200.0, 100.0), (200.0, 200.0))[seed % 3]
        truth = 0.0123 * seed - 0.03
        t1, w1, t2, w2, _, _ = simulate_streams(100 + seed, rate_1=rates[0], rate_2=rates[1], duration=300.0,
                                                offset=truth, rms=(1.0, 0.2)[seed % 2])
        new = al.estimate_time_offset(t1, w1, t2, w2)
        with monkeypatch.context() as m:
            m.setattr(al, "_polish", _full_search)
            m.setattr(al, "_COARSE_EVAL", 1 << 40)
            old = al.estimate_time_offset(t1, w1, t2, w2)
        assert new.n_samples > 4 * al._COARSE_EVAL                  # the thinned search ran
        assert abs(new.offset_s - old.offset_s) <= al._tolerance(old.offset_s, 0.005)
        assert abs(new.offset_s - old.offset_s) <= 0.02 * old.std_s
        assert new.std_s == pytest.approx(old.std_s, rel=1e-3)
        errors.append((new.offset_s - truth, old.offset_s - truth))
        stds.append(old.std_s)
    rms_new, rms_old = np.sqrt(np.mean(np.square(errors), axis=0))
    assert rms_new <= rms_old + 0.02 * np.mean(stds)
    assert np.mean([(e[0] / s) ** 2 for e, s in zip(errors, stds)]) <= 4.0   # the std still covers the error


def test_polish_falls_back_to_the_bracketed_search_when_newton_does_not_settle(monkeypatch):
    spl2, x1, y1, h, truth = _setup()
    monkeypatch.setattr(al, "_NEWTON_STEPS", 0)
    tau, lin, std = al._polish(spl2, x1, y1, truth + 0.3 * h, h)
    assert tau == al._refine(spl2, x1, y1, truth + 0.3 * h, h)[0]
    assert lin.tau == tau and std == lin.std_step()[0]


def test_polish_reaches_the_minimum_from_a_fifth_of_a_step_away():
    spl2, x1, y1, h, truth = _setup()
    tau_full = al._refine(spl2, x1, y1, truth, h)[0]
    tau, lin, std = al._polish(spl2, x1, y1, tau_full + 0.2 * h, h)
    assert abs(tau - tau_full) <= al._tolerance(tau_full, h)
    assert abs(lin.std_step()[1]) <= al._tolerance(tau, h)          # the step left at the last linearisation
    assert abs(tau - truth) <= 5 * std


def test_linearised_within_equals_the_stretch_own_linearisation():
    # a drift stretch's first Newton step and std from the whole record's evaluation: the same numbers as
    # linearising the stretch's instants on their own
    spl2, x1, y1, h, truth = _setup(duration=120.0)
    lin = al._linearise(spl2, x1, y1, truth, h)
    a, b = x1[0] + 30.0, x1[0] + 60.0
    j0, j1 = np.searchsorted(x1, [a, b])
    own = al._offset_std(spl2, x1[j0:j1], y1[j0:j1], truth, h, newton=True)
    np.testing.assert_allclose(lin.within(a, b).std_step()[:2], own, rtol=1e-12, atol=0.0)


def test_linearised_moved_equals_a_fresh_linearisation():
    spl2, x1, y1, h, truth = _setup(duration=120.0)
    lin = al._linearise(spl2, x1, y1, truth, h)
    std0, step0, curv0 = lin.std_step()
    tau = truth + 3.0 * std0                                        # where the thinned search may leave it
    assert abs(tau - truth) <= lin.delta
    moved = lin.moved(spl2, tau, curv0)
    fresh = al._linearise(spl2, x1, y1, tau, h)
    (s_m, d_m, c_m), (s_f, d_f, c_f) = moved.std_step(), fresh.std_step()
    assert c_m == curv0 and c_f == pytest.approx(curv0, rel=1e-4)  # the curvature kept; a fresh one barely moves
    assert s_m == pytest.approx(s_f, rel=1e-4)
    assert abs(d_m - d_f) <= 1e-3 * s_f
    assert abs((tau + d_m) - (truth + step0)) <= 1e-3 * std0       # both steps land on the same minimum
    stretch = moved.within(x1[0] + 30.0, x1[0] + 60.0)              # a stretch's own curvature, about tau_mid
    assert stretch.half_curv is None and stretch.tau_mid == truth
    assert stretch.std_step()[0] == pytest.approx(fresh.within(x1[0] + 30.0, x1[0] + 60.0).std_step()[0],
                                                  rel=1e-3)


def test_near_of_window_spans_equals_near_of_every_instant():
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.004, 0.006, 20000))
    w = rng.normal(size=(t.size, 3))
    ok = rng.random(t.size) > 0.01
    he = 0.005 * al._EVAL_STEP
    windows = [(10.0, 10.25), (10.25, 10.5), (30.0, 30.25), (30.6, 30.85), (80.0, 80.25)]
    idx = [np.arange(np.ceil(a / he), np.ceil(b / he)).astype(np.int64) for a, b in windows]
    x = np.concatenate(idx) * he
    first, last = np.array([i[0] for i in idx]) * he, np.array([i[-1] for i in idx]) * he
    for got, want in zip(al._near(t, w, ok, first, last), al._near(t, w, ok, x, x)):
        np.testing.assert_array_equal(got, want)


def test_ranges_concatenates_the_ranges():
    starts = np.array([3, 10, 11, 40, 41])
    stops = np.array([7, 11, 15, 41, 60])
    np.testing.assert_array_equal(al._ranges(starts, stops),
                                  np.concatenate([np.arange(a, b) for a, b in zip(starts, stops)]))


def _search(spl, x):
    """The interval of each instant by the plain search, as :meth:`_RunSplines.locate` first found it."""
    return np.clip(np.searchsorted(spl.knots, x, side="right") - 1, 0, spl.knots.size - 2)


def test_locate_from_a_hint_equals_the_search():
    # runs split by gaps and masked samples; instants shifted by a fraction of a step, by several steps, beyond the
    # steps a hint may take, and outside the knots' span: the intervals are the search's in every case
    from fusion_gyrocal.pipeline.resample import _LOCATE_STEPS, _RunSplines

    rng = np.random.default_rng(11)
    t = np.cumsum(rng.uniform(0.004, 0.006, 5000))
    t[2000:] += 0.5                                               # a gap
    ok = rng.random(t.size) > 0.02
    spl = _RunSplines(t, rng.normal(size=(t.size, 3)), ok, 0.0125)
    x = np.sort(rng.uniform(t[0] - 0.1, t[-1] + 0.1, 30000))
    x = np.r_[spl.knots[:50], x, spl.knots[-50:], np.nextafter(spl.knots[100:150], -np.inf)]
    hint = spl.locate(x)
    np.testing.assert_array_equal(hint, _search(spl, x))
    for shift in (0.0, 0.00125, -0.00125, 0.011, -0.017, 0.005 * (2 * _LOCATE_STEPS + 3)):
        np.testing.assert_array_equal(spl.locate(x + shift, hint), _search(spl, x + shift))
    np.testing.assert_array_equal(spl.locate(x, np.zeros(x.size, dtype=np.intp)), hint)   # a poor hint: searched


def test_runs_of_an_all_valid_stream_equal_the_masked_path():
    from fusion_gyrocal.pipeline.resample import _runs

    def masked_path(t, valid, gap):            # the runs as found for a masked stream (the index array gathered)
        idx = np.flatnonzero(valid)
        if idx.size < 2:
            return np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp)
        cut = np.flatnonzero((np.diff(idx) > 1) | (np.diff(t[idx]) > gap)) + 1
        a, b = np.r_[0, cut], np.r_[cut, idx.size]
        long = b - a >= 2
        return idx[a[long]], idx[b[long] - 1] + 1

    rng = np.random.default_rng(12)
    t = np.cumsum(rng.uniform(0.004, 0.006, 3000))
    for k in (5, 7, 9, 10, 1500, 2998):
        t[k:] += 1.0                          # gaps: runs of 5, 2, 2, 1 (dropped), 1490, 1498 and 2 samples
    every = np.ones(t.size, dtype=bool)
    for n in (0, 1, 2, 3, 8, 11, t.size):
        got, want = _runs(t[:n], every[:n], 0.0125), masked_path(t[:n], every[:n], 0.0125)
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)
            assert g.dtype == w.dtype


def test_rate_glitches_skip_equals_the_full_pass():
    from fusion_gyrocal.core.moments import row_norms, row_sumsq
    from fusion_gyrocal.pipeline.flex import GLITCH_FACTOR

    rng = np.random.default_rng(13)
    for kind in range(4):
        w = rng.normal(size=(200000, 3))
        ok = rng.random(w.shape[0]) > 0.01
        if kind == 1:
            w[[10, 5000]] *= 30.0                                 # glitches: the full pass finds them
        elif kind == 2:
            w[77, 2] = np.nan                                     # a NaN: no skipping
        elif kind == 3:
            w[123] = (25.0, 0.0, 0.0)                             # too large a rate to skip the pass, below the
                                                                  # level (10x the 99th percentile, ~34)
        lim2 = (GLITCH_FACTOR * float(np.quantile(row_norms(w[::3][ok[::3]]), 0.99))) ** 2
        with np.errstate(invalid="ignore"):
            want = (row_sumsq(w) > lim2) & ok
        np.testing.assert_array_equal(al._rate_glitches(w, ok), want)
