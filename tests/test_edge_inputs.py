"""Edges of the API: wrong shapes and types, implausible units, glitches and corrupt timestamps.

Each case must end in one :class:`InputError` (or the honest verdict) that says what was expected
and what arrived, never a numpy error, a warning cascade or an unbounded allocation.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.core.moments import Moments
from fusion_gyrocal.errors import InputError, NotRigidError
from fusion_gyrocal.evaluate.sim import shared_data_dir, simulate_pair


@pytest.fixture(scope="module")
def sim():
    return simulate_pair(rng=0)


def _one_line(exc) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


# ------------------------------------------------------------------------------------------ shapes and types
def test_calibrate_pair_one_dimensional_rates_raise():
    with pytest.raises(InputError, match=r"omega_1: expected shape \(N, 3\), got \(10,\) \(float64") as exc:
        calibrate_pair(np.ones(10), np.ones(10))
    _one_line(exc)


def test_calibrate_pair_none_rates_raise(sim):
    with pytest.raises(InputError, match=r"omega_1: expected a numeric \(N, 3\) array of rad/s, got None"):
        calibrate_pair(None, sim.omega_2)
    with pytest.raises(InputError, match=r"omega_2: .*got None"):
        calibrate_pair(sim.omega_1, None)


def test_calibrate_pair_ragged_lists_raise(sim):
    with pytest.raises(InputError, match=r"omega_1: expected a numeric \(N, 3\) array of rad/s, got a ragged list"):
        calibrate_pair([[1.0, 2.0, 3.0], [1.0, 2.0]], sim.omega_2)


def test_calibrate_pair_huge_values_raise_without_warnings(sim):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow RuntimeWarning on the way
        with pytest.raises(InputError, match=r"omega_1: expected angular rates in rad/s.*values up to 3.26e\+160") as e:
            calibrate_pair(sim.omega_1 * 1e160, sim.omega_2 * 1e160)
    _one_line(e)


def test_moments_from_samples_huge_values_raise(sim):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match=r"omega_2: expected angular rates in rad/s, got values up to 3\.\d+e\+160 rad/s"):
            Moments.from_samples(sim.omega_1, sim.omega_2 * 1e160)


def test_check_samples_overflowing_moments_raise():
    from fusion_gyrocal.core.observability import check_samples
    m = Moments(100, np.zeros(6), np.diag([np.inf, 1, 1, 1, 1, 1]))
    with pytest.raises(InputError, match="omega_1: expected angular rates in rad/s, got moments that overflow"):
        check_samples(m)


# ------------------------------------------------------------------------------------------ units
def test_calibrate_pair_deg_per_s_as_rad_per_s_raise(sim):
    deg1, deg2 = np.rad2deg(sim.omega_1), np.rad2deg(sim.omega_2)
    with pytest.raises(InputError, match=r"look like deg/s: pass unit deg/s \(--unit1/--unit2\)") as exc:
        calibrate_pair(deg1, deg2)
    assert "omega_1 and omega_2" in _one_line(exc)


def test_calibrate_pair_counts_as_rad_per_s_raise(sim):
    counts = 131.0 * np.rad2deg(sim.omega_1), 131.0 * np.rad2deg(sim.omega_2)  # a +-250 deg/s gyro
    with pytest.raises(InputError, match=r"look like raw counts: pass unit counts"):
        calibrate_pair(*counts)


def test_calibrate_pair_fast_plausible_rates_accepted(sim):
    # 30 rad/s (1700 deg/s) is fast but within a MEMS gyro's range: no unit error
    k = 30.0 / np.quantile(np.linalg.norm(sim.omega_1, axis=1), 0.99)
    cal = calibrate_pair(sim.omega_1 * k, sim.omega_2 * k, noise_std=sim.noise_std)
    assert cal.rigid


# ------------------------------------------------------------------------------------------ glitches
def test_calibrate_pair_one_glitch_is_masked_before_the_rigidity_test(sim):
    clean = calibrate_pair(sim.omega_1, sim.omega_2)
    w1 = np.array(sim.omega_1)
    w1[3000] = [1000.0, 0.0, 0.0]      # one comms glitch in 6000 samples
    cal = calibrate_pair(w1, sim.omega_2)
    assert cal.rigid
    assert any("1 gross outlier sample(s)" in n for n in cal.notes)
    np.testing.assert_allclose(cal.R_1_2, clean.R_1_2, atol=1e-4)


def test_calibrate_pair_glitch_in_both_gyros_is_masked(sim):
    w1, w2 = np.array(sim.omega_1), np.array(sim.omega_2)
    w1[100] = [0.0, 800.0, 0.0]
    w2[4000] = [0.0, 0.0, -900.0]
    cal = calibrate_pair(w1, w2)
    assert cal.rigid and any("2 gross outlier sample(s)" in n for n in cal.notes)


def test_calibrate_pair_not_rigid_still_raises_with_glitch(sim):
    rng = np.random.default_rng(3)
    other = simulate_pair(rng=7).omega_2           # an unrelated motion: no rigid pair
    w1 = np.array(sim.omega_1)
    w1[10] = [1000.0, 0.0, 0.0]
    with pytest.raises(NotRigidError):
        calibrate_pair(w1, other[: len(w1)] + 0 * rng.normal(size=(len(w1), 3)))


@pytest.mark.skipif(not shared_data_dir().exists(), reason="../shared/data not present (real recordings are only "
                                                           "in the project checkout)")
def test_calibrate_pair_walking_legs_still_not_rigid():
    from fusion_gyrocal.io.readers import read_imu
    d = shared_data_dir() / "xsens_walking_nonrigid"
    a, b = read_imu(d / "walking_xsens_upperLeg.txt"), read_imu(d / "walking_xsens_lowerLeg.txt")
    with pytest.raises(NotRigidError):
        calibrate_pair(a.omega, b.omega)
    with pytest.raises(NotRigidError):
        calibrate_pair(a.omega, b.omega, t_1=a.t, t_2=b.t, time_offset_s=0.0)


# ------------------------------------------------------------------------------------------ timestamps
def test_calibrate_pair_millisecond_timestamps_raise(sim):
    t_ms = sim.t * 1000.0
    with pytest.raises(InputError, match=r"t_1: .*0\.1 Hz if seconds\); they look like ms: pass t_1/t_2 in seconds "
                                         r"\(the CLI's --time-unit1/--time-unit2 ms\)") as exc:
        calibrate_pair(sim.omega_1, sim.omega_2, t_1=t_ms, t_2=t_ms)
    _one_line(exc)


def test_calibrate_pair_integer_nanosecond_timestamps_raise(sim):
    t_ns = np.round(sim.t * 1e9).astype(np.int64)
    with pytest.raises(InputError, match="they look like ns"):
        calibrate_pair(sim.omega_1, sim.omega_2, t_1=t_ns, t_2=t_ns)


def test_check_timestamps_implausible_rate_raise():
    from fusion_gyrocal.pipeline.streams import check_timestamps
    with pytest.raises(InputError, match=r"1e\+06 Hz if seconds"):
        check_timestamps("t", np.arange(100) * 1e-6)
    np.testing.assert_array_equal(check_timestamps("t", np.arange(100) * 1e-5), np.arange(100) * 1e-5)


def test_calibrate_pair_corrupt_timestamp_raise_in_bounded_memory(sim):
    import tracemalloc
    t2 = np.array(sim.t)
    t2[3000:] += 1e6                      # one corrupted timestamp: every later sample shifted by 11.6 days
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match=r"t_2: .* at sample 3000 .*corrupt timestamp\?") as exc:
            calibrate_pair(sim.omega_1, sim.omega_2, t_1=sim.t, t_2=t2)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    _one_line(exc)
    assert peak < 20 * sim.omega_1.nbytes


def test_check_timestamps_real_gap_accepted():
    from fusion_gyrocal.pipeline.streams import check_timestamps
    t = np.arange(10_000) * 0.01
    t[5000:] += 30.0                      # a 30 s dropout in a 100 s log: a gap, not corruption
    assert check_timestamps("t", t).shape == (10_000,)


def test_calibrate_pair_max_plausible_rate_option_moves_the_limit():
    from fusion_gyrocal.evaluate.sim import simulate_pair
    sim = simulate_pair(rng=3, n=4000)
    w1, w2 = 200.0 * sim.omega_1, 200.0 * sim.omega_2          # a very fast (or wrongly scaled) pair
    with pytest.raises(InputError, match="at most 100 rad/s"):
        calibrate_pair(w1, w2)
    cal = calibrate_pair(w1, w2, max_plausible_rate=1e4)       # a gyro with a wider range: accepted
    assert cal.configuration == "general"


def test_calibrate_pair_constant_timestamped_input_says_why_nothing_is_left():
    t = np.arange(2000) / 100.0
    w = np.full((2000, 3), 0.3)
    with pytest.raises(InputError, match=r"omega_1: .*2000 of which 0 are non-finite and 2000 flagged saturated"):
        calibrate_pair(w, w, t_1=t, t_2=t)
