import numpy as np
import pytest

from fusion_gyrocal import InputError, Moments, OptionError, solve
from fusion_gyrocal.evaluate.sim import DEG, PAPER_NOISE_STD, HumanMotion, random_rotation, rotation_error, simulate_pair
from fusion_gyrocal.online.stream import StreamingCalibrator

RATE = 100.0


def _feed(cal, w1, w2, chunk, t=None):
    for a in range(0, w1.shape[0], chunk):
        cal.update(w1[a:a + chunk], w2[a:a + chunk], t=None if t is None else t[a:a + chunk])


def _switching_pair(rng, n_each=6000):
    """Rates whose rotation changes half way (e.g. a remounted gyro): R_a for n_each samples, then R_b."""
    rng = np.random.default_rng(rng)
    R_a = random_rotation(rng)
    R_b = random_rotation(rng, angle_deg=5.0) @ R_a
    omega = HumanMotion(1.0, rng=rng)(np.arange(2 * n_each) / RATE)
    w2 = np.concatenate([omega[:n_each] @ R_a, omega[n_each:] @ R_b])
    w1 = omega + rng.normal(0, PAPER_NOISE_STD, omega.shape)
    w2 = w2 + rng.normal(0, PAPER_NOISE_STD, omega.shape)
    return w1, w2, R_a, R_b


def test_streaming_calibrator_without_forgetting_equals_batch_solve():
    sim = simulate_pair(rng=1, n=5000)
    cal = StreamingCalibrator(noise_std=PAPER_NOISE_STD)
    _feed(cal, sim.omega_1, sim.omega_2, 337)
    batch = solve(Moments.from_samples(sim.omega_1, sim.omega_2), noise_std=PAPER_NOISE_STD)
    est = cal.estimate()
    assert cal.samples_seen == 5000 and cal.effective_samples == 5000
    assert rotation_error(est.R_1_2, batch.R_1_2) < 1e-10
    np.testing.assert_allclose(est.scale_2, batch.scale_2, rtol=1e-10)
    P = batch.covariance[:9, :9]
    np.testing.assert_allclose(est.covariance[:9, :9], P, rtol=1e-8, atol=1e-8 * np.abs(P).max())


def test_streaming_calibrator_sliding_window_follows_a_change():
    w1, w2, R_a, R_b = _switching_pair(2)
    cal = StreamingCalibrator(window_s=40.0, rate_hz=RATE, noise_std=PAPER_NOISE_STD)
    _feed(cal, w1[:6000], w2[:6000], 250)
    before = cal.estimate()
    _feed(cal, w1[6000:], w2[6000:], 250)  # 60 s after the change: the 40 s window holds only R_b
    after = cal.estimate()
    assert rotation_error(before.R_1_2, R_a) < 5 * np.linalg.norm(before.rotation_std_rad)
    assert rotation_error(after.R_1_2, R_b) < 5 * np.linalg.norm(after.rotation_std_rad)
    assert 4000 <= after.n_samples <= 4000 + 4000 / cal.n_bins + 250


def test_streaming_calibrator_forgetting_follows_a_change():
    w1, w2, R_a, R_b = _switching_pair(3)
    lam = 1.0 - 1.0 / 1000.0  # memory ~ 1000 samples; after 6000 more, the old part weighs e^-6
    cal = StreamingCalibrator(forgetting=lam, noise_std=PAPER_NOISE_STD)
    _feed(cal, w1, w2, 200)
    est = cal.estimate()
    assert cal.effective_samples == pytest.approx(1000.0, rel=0.15)
    assert rotation_error(est.R_1_2, R_b) < 0.05 * DEG
    grow = StreamingCalibrator(noise_std=PAPER_NOISE_STD)
    _feed(grow, w1, w2, 200)
    assert rotation_error(grow.estimate().R_1_2, R_b) > 1.0 * DEG  # without forgetting it averages both


def test_streaming_calibrator_memory_is_bounded_in_the_log_length():
    rng = np.random.default_rng(4)
    cal = StreamingCalibrator(window_s=10.0, rate_hz=RATE, n_bins=8)
    chunk = rng.normal(0, 1, (50, 3))
    for _ in range(2000):  # 1000 s of data in 50-sample chunks
        cal.update(chunk, chunk)
    assert len(cal._bins) <= cal.n_bins + 1
    assert cal.samples_seen == 100000 and cal.effective_samples <= 10.0 * RATE * (1 + 1 / 8) + 50


def test_streaming_calibrator_window_with_timestamps_equals_window_of_samples():
    sim = simulate_pair(rng=5, n=8000)
    t = 100.0 + np.arange(8000) / RATE
    cal = StreamingCalibrator(window_s=20.0, n_bins=20, noise_std=PAPER_NOISE_STD)
    _feed(cal, sim.omega_1, sim.omega_2, 300, t=t)
    # bins are 1 s wide and aligned to whole seconds; the window holds bins 159..179 (t >= 159 s)
    start = int(np.searchsorted(t, 159.0))
    ref = Moments.from_samples(sim.omega_1[start:], sim.omega_2[start:])
    m = cal.moments
    assert m.count == ref.count
    np.testing.assert_allclose(m.scatter, ref.scatter, rtol=1e-10, atol=1e-10 * np.abs(ref.scatter).max())


def test_streaming_calibrator_estimate_before_data_raises_input_error():
    cal = StreamingCalibrator()
    with pytest.raises(InputError, match="no estimate yet"):
        cal.estimate()


def test_streaming_calibrator_estimate_is_cached_until_update():
    sim = simulate_pair(rng=6, n=2000)
    cal = StreamingCalibrator()
    cal.update(sim.omega_1[:1000], sim.omega_2[:1000])
    first = cal.estimate()
    assert cal.estimate() is first
    cal.update(sim.omega_1[1000:], sim.omega_2[1000:])
    assert cal.estimate() is not first and cal.estimate().n_samples == 2000


def test_streaming_calibrator_mask_drops_samples():
    sim = simulate_pair(rng=7, n=3000)
    mask = np.ones(3000, bool)
    mask[::3] = False
    cal = StreamingCalibrator()
    for a in range(0, 3000, 1000):
        cal.update(sim.omega_1[a:a + 1000], sim.omega_2[a:a + 1000], mask=mask[a:a + 1000])
    assert cal.effective_samples == mask.sum()


def test_streaming_calibrator_non_finite_sample_is_located_in_the_stream():
    sim = simulate_pair(rng=8, n=2000)
    w1 = sim.omega_1.copy()
    w1[1500, 0] = np.nan
    cal = StreamingCalibrator()
    cal.update(w1[:1000], sim.omega_2[:1000])
    with pytest.raises(InputError, match="chunk starting at sample 1000.*sample 500"):
        cal.update(w1[1000:], sim.omega_2[1000:])
    assert cal.samples_seen == 1000  # the failed chunk left the state unchanged


def test_streaming_calibrator_timestamps_must_increase_across_chunks():
    cal = StreamingCalibrator(window_s=5.0)
    w = np.random.default_rng(9).normal(0, 1, (10, 3))
    cal.update(w, w, t=np.arange(10) * 0.01)
    with pytest.raises(InputError, match="strictly increasing.*sample 10"):
        cal.update(w, w, t=np.arange(10) * 0.01)


def test_streaming_calibrator_window_without_clock_raises():
    cal = StreamingCalibrator(window_s=5.0)
    w = np.zeros((10, 3))
    with pytest.raises(InputError, match="rate_hz"):
        cal.update(w, w)


@pytest.mark.parametrize("kwargs", [
    {"forgetting": 0.99, "window_s": 10.0}, {"forgetting": 1.5}, {"forgetting": 0.0}, {"window_s": -1.0},
    {"rate_hz": 0.0}, {"n_bins": 1}, {"no_such_option": 1}, {"moments": None},
])
def test_streaming_calibrator_bad_configuration_raises(kwargs):
    with pytest.raises(OptionError):
        StreamingCalibrator(**kwargs)


def test_streaming_calibrator_passes_solve_options():
    sim = simulate_pair(rng=10, n=2000, rms=0.05)
    cal = StreamingCalibrator(noise_std=PAPER_NOISE_STD, min_snr=1e6)
    cal.update(sim.omega_1, sim.omega_2)
    from fusion_gyrocal import ExcitationError
    with pytest.raises(ExcitationError):
        cal.estimate()


def test_streaming_calibrator_does_not_modify_input():
    sim = simulate_pair(rng=11, n=1000)
    w1, w2 = sim.omega_1.copy(), sim.omega_2.copy()
    cal = StreamingCalibrator(window_s=2.0, rate_hz=RATE)
    cal.update(w1, w2)
    np.testing.assert_array_equal(w1, sim.omega_1)
    np.testing.assert_array_equal(w2, sim.omega_2)
