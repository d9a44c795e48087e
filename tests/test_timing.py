"""Inter-sensor timing beyond one constant offset (pipeline/timing.py)."""

import numpy as np

from fusion_gyrocal import calibrate_pair
from fusion_gyrocal.evaluate.sim import HumanMotion, general_rotation
from fusion_gyrocal.lie import log
from fusion_gyrocal.pipeline.timing import estimate_timing

RATE = 100.0


def _pair(rng, beat_hz=None, n=60000, noise=1e-3, span_s=0.004):
    """Gyro 2 samples ``delay(t)`` late, a sawtooth of ``span_s`` at ``beat_hz`` (its clock against the read-out)."""
    t = np.arange(n) / RATE
    R = general_rotation(rng)
    motion = HumanMotion(1.0, rng=rng)
    delay = np.zeros(n) if beat_hz is None else span_s * ((beat_hz * t + 0.3) % 1.0)
    w1 = motion(t) + rng.normal(0, noise, (n, 3))
    w2 = motion(t - delay) @ R + rng.normal(0, noise, (n, 3))
    return t, w1, w2, R


def test_estimate_timing_finds_the_beat_tone_of_a_sawtooth_delay():
    rng = np.random.default_rng(1)
    t, w1, w2, R = _pair(rng, beat_hz=2.3)
    A = R.T.T                                     # omega_1 = R omega_2
    model = estimate_timing(t, w1, w2, A, np.zeros(3))
    assert model.significant
    assert abs(model.tones_hz[0] - 2.3) < 1.0 / (t[-1] - t[0])
    assert model.explained > 0.5
    assert abs(model.delay_std - 0.004 / np.sqrt(12)) < 0.3 * 0.004 / np.sqrt(12)   # a sawtooth's std


def test_estimate_timing_finds_nothing_in_white_noise():
    for seed in range(5):
        t, w1, w2, R = _pair(np.random.default_rng(10 + seed))
        assert not estimate_timing(t, w1, w2, R, np.zeros(3)).significant


def test_calibrate_pair_timing_model_compensates_the_delay():
    t, w1, w2, R = _pair(np.random.default_rng(2), beat_hz=1.7, span_s=0.008)
    off = calibrate_pair(w1, w2, t_1=t, t_2=t, timing_model="off")
    on = calibrate_pair(w1, w2, t_1=t, t_2=t)
    assert on.timing_tones_hz and abs(on.timing_tones_hz[0] - 1.7) < 0.01
    assert on.residual_rms < 0.5 * off.residual_rms
    err_on, err_off = (np.linalg.norm(log(c.R_1_2 @ R.T)) for c in (on, off))
    assert err_on <= err_off
    assert any(n.startswith("inter-sensor timing") for n in on.notes)
    assert off.timing_tones_hz == () and not any(n.startswith("inter-sensor timing") for n in off.notes)
    import json

    from fusion_gyrocal.core.model import PairCalibration
    back = PairCalibration.from_dict(json.loads(json.dumps(on.to_dict())))
    assert back.timing_tones_hz == on.timing_tones_hz and back.timing_delay_std_s == on.timing_delay_std_s


def test_calibrate_pair_timing_model_compensates_a_constant_group_delay_without_timestamps():
    rng = np.random.default_rng(3)
    t, R = np.arange(60000) / RATE, general_rotation(rng)
    motion = HumanMotion(1.0, rng=rng)
    w1 = motion(t) + rng.normal(0, 1e-3, (t.size, 3))
    w2 = motion(t - 0.002) @ R + rng.normal(0, 1e-3, (t.size, 3))        # gyro 2 2 ms late (a filter's group delay)
    on = calibrate_pair(w1, w2)
    off = calibrate_pair(w1, w2, timing_model="off")
    assert on.timing_tones_hz == () and abs(on.timing_delay_s - 0.2) < 0.02       # samples at 100 Hz
    err_on, err_off = (np.linalg.norm(log(c.R_1_2 @ R.T)) for c in (on, off))
    assert err_on < 0.5 * err_off


def test_estimate_timing_finds_the_tone_across_gaps_in_the_log():
    t, w1, w2, R = _pair(np.random.default_rng(7), beat_hz=2.3)
    keep = np.ones(t.size, bool)
    keep[20000:20700] = keep[41000:41013] = False                       # dropped samples (clipped, say)
    model = estimate_timing(t[keep], w1[keep], w2[keep], R, np.zeros(3))
    assert model.significant and abs(model.tones_hz[0] - 2.3) < 1.0 / (t[-1] - t[0])
