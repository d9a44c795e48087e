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
    # one tone per chip: gyro 3's sawtooth at 1.7 Hz (its 4th harmonic, 6.8 Hz, is not taken for another chip's)
    assert "gyro 2 constant +2 ms" in line and "gyro 3 std 2." in line and "tones 1.7 Hz" in line  # 2 ms; 2.31
    assert "none found for gyro(s) 4" in line
    assert "off" in timing_line(cal, "off")


# ---------------------------------------------------------------------------------------- one delay per chip
from test_timing_model import CHIP_PERIOD_S, NOISE, RATE_HZ, chip_delay  # noqa: E402

from fusion_gyrocal.pipeline.timing import estimate_array_timing, estimate_timing  # noqa: E402

CHIP_TONES_HZ = (0.35, 2.5, 1.3, 0.8)           # every chip's clock against the read-out; chip 0 the reference


def _chip_array(seed, n=20000):
    """Four chips, each on its own clock: per-chip sawtooth delays over one internal sample period (as in
    tests/test_timing_model.py), read out together at ``RATE_HZ``."""
    rng = np.random.default_rng([20, 7, seed])
    t = np.arange(n) / RATE_HZ
    motion = HumanMotion(3.0, max_freq_hz=4.0, rng=rng)
    R = [np.eye(3)] + [general_rotation(rng) for _ in range(3)]
    late = [chip_delay(t, f, rng.uniform()) for f in CHIP_TONES_HZ]
    rates = [motion(t - late[g]) @ R[g] + rng.normal(0, NOISE, (n, 3)) + rng.normal(0, 0.01, 3) for g in range(4)]
    return t, rates, R, late


@pytest.fixture(scope="module")
def chips():
    """Two seeds: ``[(t, rates, R, late, calibrate_array, calibrate_array with timing_model='off')]``."""
    out = []
    for seed in range(2):
        t, w, R, late = _chip_array(seed)
        out.append((t, w, R, late, calibrate_array(w, t=t), calibrate_array(w, t=t, timing_model="off")))
    return out


def test_estimate_array_timing_recovers_every_chip(chips):
    for t, w, R, late, _, _ in chips:
        model = estimate_array_timing(t, w, R, np.zeros((4, 3)))          # omega_ref ~ R_g omega_g
        for g, f in enumerate(CHIP_TONES_HZ):
            assert len(model.tones_hz[g]) == 1 and model.tones_hz[g][0] == pytest.approx(f, abs=0.005)
            own = model.delay(g, t)                        # the reference's mean is the zero of the others'
            assert own.std() == pytest.approx(late[g].std(), rel=0.25)
        for j in (1, 2, 3):
            truth = late[j] - late[0]
            rel = model.relative[j]
            assert rel.tones_hz == model.tones_hz[j] + model.tones_hz[0]     # its own tone, then the reference's
            fit = rel.delay(t)
            assert np.sqrt(np.mean((fit - fit.mean() - (truth - truth.mean())) ** 2)) < 0.5 * truth.std()
            assert abs(fit.mean() - truth.mean()) < 0.1 * CHIP_PERIOD_S
            assert rel.explained > 0.3


def test_calibrate_array_timing_shares_the_reference_chip_tone(chips):
    for _, _, _, _, cal, _ in chips:
        ref = {tones[-1] for tones in cal.timing_tones_hz[1:]}
        assert len(ref) == 1 and ref.pop() == pytest.approx(CHIP_TONES_HZ[0], abs=0.005)   # one estimate, every pair
        for g in (1, 2, 3):
            assert cal.timing_tones_hz[g][0] == pytest.approx(CHIP_TONES_HZ[g], abs=0.005)
        note = [n for n in cal.notes if n.startswith("inter-sensor timing")][0]
        assert "the reference chip's own beat, at 0.35" in note


def test_calibrate_array_timing_chip_rotations_honest(chips):
    z2 = []
    for _, _, R, _, cal, off in chips:
        # the delays modelled: closer to the truth than without them (over the three gyros: each is noise-limited)
        assert sum(_error(cal, R, g) ** 2 for g in (1, 2, 3)) < sum(_error(off, R, g) ** 2 for g in (1, 2, 3))
        z2 += [_z2(cal, R, g) for g in (1, 2, 3)]
        for i, j in ((1, 2), (1, 3), (2, 3)):           # the pairs without the reference: its delay cancels there
            view = cal.pair(i, j)
            d = log(view.R_1_2 @ (R[i].T @ R[j]).T)
            z2.append(float(d @ np.linalg.solve(view.covariance[:3, :3], d)))
    assert max(z2) < 16.3, z2                           # chi2_3's 99.9 % point
    assert np.mean(z2) < 6.0, z2


def test_estimate_array_timing_one_pair_gives_both_tones_to_gyro_2():
    from test_timing_model import simulated_pair

    t, w1, w2, R, relative = simulated_pair(0)
    A, b = R, np.zeros(3)                                # omega_1 ~ R omega_2
    pair = estimate_timing(t, w1, w2, A, b)
    model = estimate_array_timing(t, [w1, w2], [np.eye(3), A], [b, b])
    assert model.tones_hz[0] == () and model.relative[0].explained == 0.0
    assert np.allclose(sorted(model.tones_hz[1]), sorted(pair.tones_hz), atol=0.002)
    assert model.relative[1].explained == pytest.approx(pair.explained, rel=0.02)
    assert model.relative[1].delay_std == pytest.approx(pair.delay_std, rel=0.05)
