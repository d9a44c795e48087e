"""The tracker's history is bounded by default (TrackerConfig.history_max_rows), full on request, and a run
that needs one row per update (a truth) says when the bound stands in the way."""

import numpy as np
import pytest

from fusion_gyrocal import OptionError
from fusion_gyrocal.evaluate.sim import DEG, general_rotation, simulate_drifting_pair
from fusion_gyrocal.online.config import HISTORY_MAX_ROWS
from fusion_gyrocal.online.history import HistoryRecorder
from fusion_gyrocal.online.tracker import GyroPairTracker, TrackerConfig


def _pair(seed, seconds=15.0, rate=100.0):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate)
    n = t.size
    R = general_rotation(rng, 15.0)
    s1, s2 = 1 + rng.normal(0, 0.01, 3), 1 + rng.normal(0, 0.01, 3)
    w1, w2, truth = simulate_drifting_pair(t, np.tile(R, (n, 1, 1)), s1, np.tile(s2, (n, 1)),
                                           bias_1=rng.normal(0, 0.01, 3), bias_2=rng.normal(0, 0.01, 3),
                                           noise_std=0.1 * DEG, rng=rng)
    return t, w1, w2, truth


def _fill(recorder, rows):
    R, s, P = np.eye(3), np.ones(3), np.eye(12)
    for k in range(rows):
        recorder.add(float(k), R, s, s, s, P, 1.0, 1, "sample")


def test_TrackerConfig_history_max_rows_default_is_bounded():
    assert TrackerConfig().history_max_rows == HISTORY_MAX_ROWS == 65536
    rec = HistoryRecorder(TrackerConfig().history_max_rows)
    _fill(rec, HISTORY_MAX_ROWS + 5000)
    h = rec.build(reseeds=(), n_samples=0, n_rejected=0, gauge="", nees_dof=0)
    assert HISTORY_MAX_ROWS // 2 <= len(h) <= HISTORY_MAX_ROWS
    assert np.all(np.diff(h.t) == 2.0)          # every other update, spread over the whole run
    assert h.t[0] == 0.0 and h.t[-1] >= HISTORY_MAX_ROWS


def test_TrackerConfig_history_max_rows_none_keeps_every_row():
    rec = HistoryRecorder(TrackerConfig(history_max_rows=None).history_max_rows)
    _fill(rec, HISTORY_MAX_ROWS + 5000)
    assert len(rec) == HISTORY_MAX_ROWS + 5000


def test_run_truth_within_default_bound_has_truth_columns():
    t, w1, w2, truth = _pair(1)
    tr = GyroPairTracker.from_samples(t[:1000], w1[:1000], w2[:1000])   # the default, bounded history
    h = tr.run(t[1000:], w1[1000:], w2[1000:], truth=truth[1000:])
    assert h.nees is not None and np.isfinite(h.nees[-5:]).all() and h.truth_R_1_2 is not None


def test_run_truth_beyond_bound_raises_option_error_naming_full_history():
    t, w1, w2, truth = _pair(2)
    tr = GyroPairTracker.from_samples(t[:1000], w1[:1000], w2[:1000], history_max_rows=4)
    with pytest.raises(OptionError, match=r"history_max_rows=4 .*5 update\(s\).*history_max_rows=None"):
        tr.run(t[1000:], w1[1000:], w2[1000:], truth=truth[1000:])      # 5 blocks of 100 samples
    full = GyroPairTracker.from_samples(t[:1000], w1[:1000], w2[:1000], history_max_rows=None)
    h = full.run(t[1000:], w1[1000:], w2[1000:], truth=truth[1000:])
    assert len(h) == 5 and np.isfinite(h.nees).all()


def test_run_truth_after_thinned_history_raises_option_error():
    t, w1, w2, truth = _pair(3)
    tr = GyroPairTracker.from_samples(t[:1000], w1[:1000], w2[:1000], history_max_rows=2)
    tr.run(t[1000:1300], w1[1000:1300], w2[1000:1300])                 # 3 updates: thinned to every 2nd
    with pytest.raises(OptionError, match="already thinned"):
        tr.run(t[1300:1400], w1[1300:1400], w2[1300:1400], truth=truth[1300:1400])
