"""Inter-sensor timing in the joint calibration of N gyros (calibrate_array's timing model, issue 20)."""

import json

import numpy as np
import pytest

from fusion_gyrocal.core.array import calibrate_array
from fusion_gyrocal.core.array_result import ARRAY_FORMAT_VERSION, ArrayCalibration
from fusion_gyrocal.errors import InputError
from fusion_gyrocal.evaluate.sim import HumanMotion, general_rotation
from fusion_gyrocal.lie import log

RATE = 100.0
CONSTANT_S = 0.002                  # gyro 1: a filter's group delay
SAW_S, SAW_HZ = 0.008, 1.7          # gyro 2: a sawtooth of 8 ms at 1.7 Hz (its clock against the read-out)


def _array(seed, delays=True, n=30000, noise=1e-3):
    """Four gyros at 100 Hz sampled at one read-out: gyro 0 the reference, gyro 1 ``CONSTANT_S`` late, gyro 2 late
    by a sawtooth, gyro 3 on time (all on time without ``delays``)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    motion = HumanMotion(1.0, rng=rng)
    R = [np.eye(3)] + [general_rotation(rng) for _ in range(3)]
    late = [np.zeros(n), np.full(n, CONSTANT_S), SAW_S * ((SAW_HZ * t + 0.3) % 1.0), np.zeros(n)]
    if not delays:
        late = [np.zeros(n)] * 4
    return t, [motion(t - late[g]) @ R[g] + rng.normal(0, noise, (n, 3)) for g in range(4)], R


def _z2(cal, R, g):
    d = log(cal.R_ref_k[g] @ R[g].T)
    return float(d @ np.linalg.solve(cal.covariance[3 * g:3 * g + 3, 3 * g:3 * g + 3], d))


def _error(cal, R, g):
    return float(np.linalg.norm(log(cal.R_ref_k[g] @ R[g].T)))


@pytest.fixture(scope="module")
def delayed():
    """Three seeds of the delayed array: ``[(t, rates, R, cal)]``."""
    out = []
    for seed in range(3):
        t, w, R = _array(seed)
        out.append((t, w, R, calibrate_array(w, t=t)))
    return out


def test_calibrate_array_timing_recovers_a_constant_delay(delayed):
    for _, _, _, cal in delayed:
        assert cal.timing_tones_hz[1] == ()
        assert abs(cal.timing_delay_s[1] - CONSTANT_S) < 0.05 * CONSTANT_S
        assert cal.timing_delay_std_s[1] < 1e-6
        assert cal.timing_explained[1] > 0.5


def test_calibrate_array_timing_recovers_a_sawtooth_tone(delayed):
    for t, _, _, cal in delayed:
        tones = cal.timing_tones_hz[2]
        assert tones and abs(tones[0] - SAW_HZ) < 1.0 / (t[-1] - t[0])
        assert abs(cal.timing_delay_s[2] - SAW_S / 2) < 0.1 * SAW_S / 2            # the sawtooth's mean
        saw_std = SAW_S / np.sqrt(12)
        assert abs(cal.timing_delay_std_s[2] - saw_std) < 0.3 * saw_std             # 3 harmonics of its shape
        assert cal.timing_explained[2] > 0.5


def test_calibrate_array_timing_leaves_an_undelayed_gyro_alone(delayed):
    for _, _, _, cal in delayed:
        assert cal.timing_tones_hz[0] == cal.timing_tones_hz[3] == ()
        assert cal.timing_explained[0] == cal.timing_explained[3] == 0.0
        assert cal.timing_delay_s[0] == cal.timing_delay_s[3] == 0.0
        note = [n for n in cal.notes if n.startswith("inter-sensor timing")]
        assert len(note) == 1 and "gyro 2 constant" in note[0] and "gyro 3 beat tone(s) at 1.7" in note[0]
        assert "gyro 4 " not in note[0].split("were moved")[0]


def test_calibrate_array_timing_rotation_errors_are_honest(delayed):
    z2 = [_z2(cal, R, g) for _, _, R, cal in delayed for g in (1, 2, 3)]
    assert 0.75 <= np.mean(z2) <= 6.0, z2
    assert max(z2) < 16.3, z2                                                      # chi2_3's 99.9 % point


def test_calibrate_array_timing_is_closer_than_without(delayed):
    t, w, R, on = delayed[0]
    off = calibrate_array(w, t=t, timing_model="off")
    assert off.timing_explained.max() == 0.0 and not any(n.startswith("inter-sensor") for n in off.notes)
    for g in (1, 2):
        assert _error(on, R, g) < 0.5 * _error(off, R, g)
        assert on.residual_rms[g] < off.residual_rms[g]


def test_calibrate_array_timing_finds_none_without_delays():
    t, w, R = _array(5, delays=False)
    on = calibrate_array(w, t=t)
    off = calibrate_array(w, t=t, timing_model="off")
    assert on.timing_tones_hz == ((),) * 4
    assert np.all(on.timing_explained == 0) and np.all(on.timing_delay_s == 0) and np.all(on.timing_delay_std_s == 0)
    assert not any(n.startswith("inter-sensor timing") for n in on.notes)
    np.testing.assert_array_equal(on.R_ref_k, off.R_ref_k)


def test_calibrate_array_timing_in_samples_without_a_time_base(delayed):
    _, w, _, cal = delayed[0]
    plain = calibrate_array(w)                                          # no t, no rate_hz: the sample index
    assert abs(plain.timing_delay_s[1] - CONSTANT_S * RATE) < 0.1 * CONSTANT_S * RATE
    assert plain.timing_tones_hz[2] and abs(plain.timing_tones_hz[2][0] - SAW_HZ / RATE) < 1.0 / len(w[0])
    timed = calibrate_array(w, rate_hz=RATE)                            # the index over rate_hz: seconds
    np.testing.assert_allclose(timed.timing_delay_s, cal.timing_delay_s, rtol=1e-6, atol=1e-12)


def test_calibrate_array_t_checked():
    t, w, _ = _array(0, delays=False, n=2000)
    with pytest.raises(InputError, match=r"t: expected shape \(2000,\)"):
        calibrate_array(w, t=t[:-1])
    bad = t.copy()
    bad[10] = bad[9]
    with pytest.raises(InputError, match="strictly increasing"):
        calibrate_array(w, t=bad)


def test_array_calibration_timing_json_round_trip(delayed):
    cal = delayed[0][3]
    d = json.loads(json.dumps(cal.to_dict()))
    assert d["format_version"] == ARRAY_FORMAT_VERSION == "1.3"
    back = ArrayCalibration.from_dict(d)
    assert back.timing_tones_hz == cal.timing_tones_hz
    for name in ("timing_delay_s", "timing_delay_std_s", "timing_explained"):
        np.testing.assert_array_equal(getattr(back, name), getattr(cal, name))
    older = {k: v for k, v in d.items() if not k.startswith("timing_")}
    older["format_version"] = "1.1"
    old = ArrayCalibration.from_dict(older)                              # written before the timing model
    assert old.timing_tones_hz == ((),) * 4 and np.all(old.timing_explained == 0)


def test_array_calibration_pair_view_carries_the_reference_pair_timing(delayed):
    cal = delayed[0][3]
    forward, backward, other = cal.pair(0, 2), cal.pair(2, 0), cal.pair(1, 2)
    assert forward.timing_tones_hz == cal.timing_tones_hz[2]
    assert forward.timing_delay_s == pytest.approx(cal.timing_delay_s[2])
    assert backward.timing_delay_s == pytest.approx(-cal.timing_delay_s[2])    # gyro 2 of the view is the reference
    assert other.timing_explained == 0.0 and any("moved to the instants" in n for n in other.notes)


def test_timing_line_names_every_delayed_gyro(delayed):
    from fusion_gyrocal.cli.array import timing_line

    cal = delayed[0][3]
    line = timing_line(cal, "auto")
    assert "gyro 2 constant +1.9" in line and "gyro 3 std 1.7" in line and "tones 1.7, " in line
    assert "none found for gyro(s) 4" in line
    assert "off" in timing_line(cal, "off")
