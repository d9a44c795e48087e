"""The timing model (:mod:`fusion_gyrocal.pipeline.timing`) on a simulated pair whose chips each sample on their own
clock: per-chip sawtooth delays (a 1 kHz internal clock read at 62.5 Hz beats against the read-out), known here."""

import numpy as np
import pytest

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.evaluate.sim import HumanMotion, general_rotation
from fusion_gyrocal.lie import log

RATE_HZ = 62.5
CHIP_PERIOD_S = 1e-3                    # the chips' internal sample period: each sawtooth spans it
TONES_HZ = (0.35, 2.5)                  # gyro 1's and gyro 2's beat against the read-out
NOISE = np.deg2rad(0.25)                # rad/s per sample


def chip_delay(t, tone_hz, phase):
    """A chip's delay against the read-out: the age of its latest internal sample, a sawtooth over one period."""
    return CHIP_PERIOD_S * np.mod(tone_hz * t + phase, 1.0)


def simulated_pair(seed: int):
    rng = np.random.default_rng([42, seed])
    R = general_rotation(rng)
    t = np.arange(20000) / RATE_HZ
    motion = HumanMotion(3.0, max_freq_hz=4.0, rng=rng)
    d1, d2 = (chip_delay(t, f, rng.uniform()) for f in TONES_HZ)
    w1 = motion(t - d1) + rng.normal(0, NOISE, (len(t), 3)) + rng.normal(0, 0.01, 3)
    w2 = motion(t - d2) @ R + rng.normal(0, NOISE, (len(t), 3)) + rng.normal(0, 0.01, 3)
    return t, w1, w2, R, d2 - d1


def rotation_z2(cal, R):
    d = log(cal.R_1_2 @ R.T)
    return float(d @ np.linalg.solve(cal.covariance[:3, :3], d)), float(np.linalg.norm(d))


@pytest.fixture(scope="module")
def runs():
    out = []
    for seed in range(2):
        t, w1, w2, R, relative = simulated_pair(seed)
        out.append((calibrate_pair(w1, w2, t_1=t, t_2=t), calibrate_pair(w1, w2, t_1=t, t_2=t, timing_model="off"),
                    R, relative))
    return out


def test_estimate_timing_recovers_per_chip_tones(runs):
    for cal, _, _, relative in runs:
        assert len(cal.timing_tones_hz) == 2
        assert np.allclose(sorted(cal.timing_tones_hz), TONES_HZ, atol=0.01)
        # the relative delay's variation: two independent sawtooths over 1 ms, std 1 ms / sqrt(6)
        assert cal.timing_delay_std_s == pytest.approx(relative.std(), rel=0.25)
        assert cal.timing_explained > 0.3


def test_timing_model_rotation_error_honest(runs):
    z2 = []
    for cal, off, R, _ in runs:
        z, err = rotation_z2(cal, R)
        z_off, err_off = rotation_z2(off, R)
        assert err < err_off          # the delay modelled: closer to the truth than without it
        z2.append(z)
    assert max(z2) < 16.3             # chi2_3's 99.9 % point: the reported covariance covers the error


def _beat_pair(seed: int, delay_s):
    """100 Hz, 60 s of human motion; gyro 2's samples describe the instants ``t + delay_s(t)``; R the rotation."""
    rng = np.random.default_rng([7, seed])
    R = general_rotation(rng)
    t = np.arange(6000) / 100.0
    motion = HumanMotion(1.0, rng=rng)
    w1 = motion(t) + rng.normal(0, 1.7e-3, (len(t), 3))
    w2 = motion(t + delay_s(t)) @ R + rng.normal(0, 1.7e-3, (len(t), 3))
    return t, w1, w2, R


def test_estimate_timing_fits_a_sawtooth_delay_as_one():
    from fusion_gyrocal.pipeline.timing import estimate_timing

    for seed in range(2):
        phase = 0.25 + 0.5 * seed
        late = lambda t: 8e-3 * np.mod(1.7 * t + phase, 1.0)      # noqa: E731  a chip's clock beating, 8 ms
        t, w1, w2, R = _beat_pair(seed, late)
        model = estimate_timing(t, w1, w2, R, np.zeros(3))
        assert len(model.tones_hz) == 1 and abs(model.tones_hz[0] - 1.7) < 1e-3
        assert len(model.phases) == 1 and np.isfinite(model.phases[0])      # a sawtooth, not its harmonics
        delay = model.delay(t)
        assert np.corrcoef(delay, -late(t))[0, 1] > 0.99
        assert delay.std() == pytest.approx(8e-3 / np.sqrt(12.0), rel=0.05)
        assert model.explained > 0.95
        harmonics = estimate_timing(t, w1, w2, R, np.zeros(3), sawtooth=False)
        assert harmonics.phases == () and harmonics.explained < model.explained


def test_estimate_timing_high_pass_keeps_the_delay_amplitude():
    """The residual is high-passed over a second (a drifting bias is slow); the delay's columns are too, so a
    delay at 1.3 Hz keeps its amplitude (15 % less when only the residual was high-passed)."""
    from fusion_gyrocal.pipeline.timing import estimate_timing

    late = lambda t: 3e-3 * np.sin(2 * np.pi * 1.3 * t)            # noqa: E731
    t, w1, w2, R = _beat_pair(5, late)
    model = estimate_timing(t, w1, w2, R, np.zeros(3), sawtooth=False)
    assert len(model.tones_hz) == 1 and abs(model.tones_hz[0] - 1.3) < 1e-3
    assert model.delay(t).std() == pytest.approx(3e-3 / np.sqrt(2.0), rel=0.03)
