"""Independent clocks: offsets of seconds to hours, clock drift, and timestamps as loggers write them (bursty USB
packets, one corrupt stamp, rate glitches), through :func:`align_streams`, :func:`calibrate_pair` and
:func:`calibrate_array`."""

import numpy as np
import pytest

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.errors import InputError, TimeAlignmentError
from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, HumanMotion, random_rotation
from fusion_gyrocal.pipeline.alignment import align_streams, estimate_time_offset
from fusion_gyrocal.pipeline.streams import timestamp_quality


def _clocks(seed, *, duration=600.0, rate=200.0, tau_mid=5.0, ppm=100.0, rate_2=None):
    """Gyro 1 on the true clock; gyro 2 stamps an event at true time t with ``t - offset(t)``,
    ``offset(t) = tau_mid + ppm 1e-6 (t - duration / 2)`` (the library's sign: added to gyro 2's stamps)."""
    rng = np.random.default_rng(seed)
    motion, R = HumanMotion(1.0, rng=rng), random_rotation(rng)
    t1 = np.arange(0, duration, 1 / rate)
    mid, d = 0.5 * duration, 1e-6 * ppm
    s = -tau_mid + np.arange(int(duration * (rate_2 or rate))) / (rate_2 or rate)
    true_2 = (s + tau_mid - d * mid) / (1 - d)
    w1 = motion(t1) + rng.normal(0, PAPER_NOISE_STD, (t1.size, 3))
    w2 = motion(true_2) @ R * 1.01 + rng.normal(0, PAPER_NOISE_STD, (s.size, 3)) + 0.01
    return t1, w1, s, w2, mid, R


@pytest.mark.parametrize("tau_mid, ppm", [(4.0, 10.0), (-37.5, -60.0), (3600.0, 200.0)])
def test_align_streams_independent_clocks_recover_offset_and_drift(tau_mid, ppm):
    t1, w1, t2, w2, mid, _ = _clocks(1, tau_mid=tau_mid, ppm=ppm)
    pair = align_streams(t1, w1, t2, w2)          # no max_offset_s: the whole overlap is searched
    est = pair.time_offset
    assert est.drift_compensated and pair.clock_drift_ppm == est.drift_ppm
    assert abs(est.drift_ppm - ppm) <= 2.0                           # issue 24: drift within 2 ppm
    assert abs(float(est.offset_at(mid)) - tau_mid) <= 1e-4          # offset within 0.1 ms at the middle
    assert abs(est.drift_ppm - ppm) <= 5 * est.drift_std_ppm
    assert any("clock drift" in n for n in pair.notes)
    # the compensated alignment leaves gyro 2 on gyro 1's clock all along: the rigid residual stays white
    v = pair.valid
    A, *_ = np.linalg.lstsq(np.c_[pair.omega_2[v], np.ones(v.sum())], pair.omega_1[v], rcond=None)
    resid = pair.omega_1[v] - np.c_[pair.omega_2[v], np.ones(v.sum())] @ A
    assert resid.std() < 2.0 * PAPER_NOISE_STD


def test_estimate_time_offset_without_drift_keeps_one_offset():
    t1, w1, t2, w2, _, _ = _clocks(2, duration=300.0, tau_mid=0.3, ppm=0.0)
    est = estimate_time_offset(t1, w1, t2, w2)
    assert not est.drift_compensated and abs(est.drift_ppm) <= 4 * est.drift_std_ppm + 1e-9
    assert abs(est.offset_s - 0.3) <= 5 * est.std_s


def test_estimate_time_offset_max_offset_still_bounds_the_search():
    t1, w1, t2, w2, _, _ = _clocks(3, duration=120.0, tau_mid=40.0, ppm=0.0)
    with pytest.raises(TimeAlignmentError, match="max_offset_s=1"):
        estimate_time_offset(t1, w1, t2, w2, max_offset_s=1.0)
    assert estimate_time_offset(t1, w1, t2, w2).offset_s == pytest.approx(40.0, abs=1e-4)


def test_calibrate_pair_independent_clocks_by_default():
    t1, w1, t2, w2, mid, R = _clocks(4, duration=300.0, tau_mid=1800.0, ppm=80.0, rate_2=100.0)
    cal = calibrate_pair(w1, w2, t_1=t1, t_2=t2)
    assert cal.clock_drift_ppm == pytest.approx(80.0, abs=2.0)
    assert cal.time_offset_s == pytest.approx(1800.0, abs=1e-4)
    err = np.rad2deg(np.linalg.norm(Rotation_log(cal.R_1_2.T @ R)))
    assert err < 0.05


def Rotation_log(R):
    from fusion_gyrocal.lie import log
    return log(R)


# ------------------------------------------------------------------------------------------ timestamp quality
def _bursty(t, packet=4, rng=None):
    """Host arrival stamps of samples delivered ``packet`` at a time: each packet stamped when its last sample is
    taken plus a latency of 0.2-2 ms, the samples inside a packet microseconds apart."""
    rng = np.random.default_rng(rng)
    n = t.size // packet * packet
    last = t[packet - 1:n:packet] + rng.uniform(2e-4, 2e-3, n // packet)
    return (last[:, None] + 1e-6 * np.arange(packet)[None, :]).ravel(), n


def test_timestamp_quality_names_bursts_jitter_and_drops():
    t = np.arange(2000) / 200.0
    q = timestamp_quality("t_1", t)
    assert q.rate_hz == pytest.approx(200.0) and not q.bursty and q.drops == 0 and q.jitter < 1e-6
    assert q.step_histogram[3] == 1999 and "regular" in q.summary()
    dropped = np.delete(t, [100, 500, 501, 502])
    q = timestamp_quality("t_1", dropped)
    assert (q.drops, q.missing) == (2, 4) and q.longest_gap_s == pytest.approx(0.02)
    jittery = t + np.random.default_rng(0).uniform(-0.1, 0.1, t.size) / 200.0
    assert 0.05 < timestamp_quality("t_1", jittery).jitter < 0.12     # uniform +-0.1 period: steps' sd 0.082
    tb, _ = _bursty(t, rng=1)
    q = timestamp_quality("t_2", tb)
    assert q.bursty and q.rate_hz == pytest.approx(200.0, rel=0.01) and "BURSTY" in q.summary()


def test_calibrate_pair_bursty_usb_timestamps_are_regularised():
    t1, w1, t2, w2, _, R = _clocks(5, duration=120.0, tau_mid=0.02, ppm=0.0)
    tb, n = _bursty(t2, rng=2)
    cal = calibrate_pair(w1, w2[:n], t_1=t1, t_2=tb)
    assert any("bursty timestamps" in note for note in cal.notes)
    assert np.rad2deg(np.linalg.norm(Rotation_log(cal.R_1_2.T @ R))) < 0.05
    assert any("BURSTY" in s for s in cal.timestamp_quality)


def test_align_streams_refusal_names_the_timestamp_diagnosis():
    t1, w1, t2, w2, _, _ = _clocks(6, duration=60.0, tau_mid=0.1, ppm=0.0)
    w2 = np.random.default_rng(0).normal(0, 1, w2.shape)          # not the same body: no correlation
    with pytest.raises(TimeAlignmentError, match=r"weak correlation.*Timestamps: t_1: 12000 timestamps, 200 Hz"):
        align_streams(t1, w1, t2, w2)


# ------------------------------------------------------------------------------------------ glitches (issue 22.12)
@pytest.mark.parametrize("glitch", ["forward", "backward", "repeated"])
def test_calibrate_pair_one_corrupt_timestamp_is_masked(glitch):
    t1, w1, t2, w2, _, R = _clocks(7, duration=60.0, tau_mid=0.05, ppm=0.0)
    t2 = t2.copy()
    t2[3000] = {"forward": t2[3000] + 7.3, "backward": t2[3000] - 1.1, "repeated": t2[2999]}[glitch]
    cal = calibrate_pair(w1, w2, t_1=t1, t_2=t2)
    assert any("out-of-place timestamp" in n and "sample 3000" in n for n in cal.notes)
    assert cal.time_offset_s == pytest.approx(0.05, abs=5 * cal.time_offset_std_s + 1e-6)


def test_calibrate_pair_many_backward_steps_still_refused_with_diagnosis():
    t1, w1, t2, w2, _, _ = _clocks(8, duration=20.0, tau_mid=0.05, ppm=0.0)
    t2 = t2.copy()
    t2[100:400] = t2[100:400][::-1]
    with pytest.raises(InputError, match=r"t_2: expected strictly increasing .*step\(s\) backwards or repeated"):
        calibrate_pair(w1, w2, t_1=t1, t_2=t2)


def test_calibrate_array_one_rate_glitch_is_masked():
    from fusion_gyrocal.pipeline.array import calibrate_streams

    t1, w1, t2, w2, _, _ = _clocks(9, duration=60.0, tau_mid=0.07, ppm=0.0)
    w2 = w2.copy()
    w2[4000] = [300.0, -250.0, 400.0]       # a comms glitch, 300x the motion
    pair = align_streams(t1, w1, t2, w2)
    assert pair.time_offset_s == pytest.approx(0.07, abs=5 * pair.time_offset.std_s + 1e-6)
    assert any("rate glitch" in n for n in pair.notes)
    cal = calibrate_streams([t1, t2], [w1, w2])
    assert cal.time_offset_s[1] == pytest.approx(0.07, abs=1e-4)


def test_align_streams_gyro_1_is_a_read_only_view_not_a_copy():
    t1, w1, t2, w2, _, _ = _clocks(10, duration=30.0, tau_mid=0.02, ppm=0.0)
    pair = align_streams(t1, w1, t2, w2)
    assert np.shares_memory(pair.omega_1, w1) and np.shares_memory(pair.t, t1)
    assert not pair.omega_1.flags.writeable and w1.flags.writeable and t1.flags.writeable
    resampled = align_streams(t1, w1, t2, w2, rate_hz=150.0)      # a grid of its own: owned arrays
    assert not np.shares_memory(resampled.omega_1, w1)
