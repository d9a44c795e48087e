"""compare_sessions and ``gyrocal sessions``: did the device change between calibrations?"""

import json

import numpy as np
import pytest

from fusion_gyrocal import InputError, calibrate_pair, compare_sessions
from fusion_gyrocal.core.array import calibrate_array
from fusion_gyrocal.evaluate.sim import HumanMotion, general_rotation, simulate_pair
from fusion_gyrocal.lie import exp, log

from _shared import data_folder

DEG = np.pi / 180.0
R0 = general_rotation(np.random.default_rng(7))


def _pair_sessions(n, turned=None, turn=np.array([0.0, 0.0, 0.0]), seed=0):
    """``n`` calibrations of one simulated pair; session ``turned`` with its rotation turned by ``turn`` (rad)."""
    cals = []
    for e in range(n):
        R = exp(turn) @ R0 if e == turned else R0
        sim = simulate_pair(n=4000, R_1_2=R, bias_walk_std=0.0, rng=seed + e)
        cals.append(calibrate_pair(sim.omega_1, sim.omega_2))
    return cals


@pytest.fixture(scope="module")
def steady():
    return _pair_sessions(5)


def test_compare_sessions_consistent_pairs(steady):
    r = compare_sessions(steady)
    assert not r.changed.any()
    assert r.dof == 3 and r.rotations == ("R_1_2",)
    assert r.deviation.shape == (5, 1, 3) and r.z2.shape == (5,)
    assert np.all(r.z2 < r.limit) and 0.1 < r.spread < 4.0
    assert r.spread_dof == 12
    assert np.degrees(np.linalg.norm(log(r.mean_rotation[0] @ R0.T))) < 0.05   # the mean is the truth, to noise


def test_compare_sessions_flags_the_session_that_moved(steady):
    sigma = np.sqrt(np.trace(steady[0].covariance[:3, :3]) / 3.0)
    moved = _pair_sessions(1, turned=0, turn=np.array([12.0 * sigma, 0.0, 0.0]), seed=100)[0]
    cals = steady[:2] + [moved] + steady[2:]
    r = compare_sessions(cals, [f"s{e}" for e in range(6)])
    assert r.changed.tolist() == [False, False, True, False, False, False]
    assert r.p_value[2] < 1e-6
    d = r.deviation[2, 0]
    assert abs(d[0] - 12.0 * sigma) < 4.0 * r.deviation_std[2, 0, 0]          # the turn, about x, measured
    assert "s2 left it" in " ".join(r.notes)
    assert "CHANGED" in r.summary().splitlines()[3] and r.summary().count("CHANGED") == 1


def test_compare_sessions_two_sessions_cannot_say_which(steady):
    sigma = np.sqrt(np.trace(steady[0].covariance[:3, :3]) / 3.0)
    moved = _pair_sessions(1, turned=0, turn=np.array([0.0, 15.0 * sigma, 0.0]), seed=200)[0]
    r = compare_sessions([steady[0], moved])
    assert r.changed.tolist() == [True, True]
    assert np.isclose(r.z2[0], r.z2[1])
    assert any("which one moved" in note for note in r.notes)
    assert not compare_sessions(steady[:2]).changed.any()


def test_compare_sessions_arrays_jointly():
    rng = np.random.default_rng(3)
    Rs = [np.eye(3), general_rotation(rng), general_rotation(rng)]
    t = np.arange(5000) / 100.0

    def session(seed, bend=np.zeros(3)):
        g = np.random.default_rng(seed)
        w = HumanMotion(1.0, rng=g)(t)
        rot = [Rs[0], Rs[1], exp(bend) @ Rs[2]]
        return calibrate_array([w @ R + g.normal(0, 0.1 * DEG, w.shape) for R in rot])

    cals = [session(s) for s in range(4)]
    r = compare_sessions(cals)
    assert r.rotations == ("R_1_2", "R_1_3") and r.dof == 6
    assert not r.changed.any()
    sigma = np.sqrt(cals[0].covariance[6, 6])
    r = compare_sessions(cals + [session(9, np.array([0.0, 0.0, 15.0 * sigma]))])
    assert r.changed.tolist() == [False] * 4 + [True]
    assert abs(r.deviation[4, 1, 2] - 15.0 * sigma) < 4.0 * r.deviation_std[4, 1, 2]


def _array_sessions(rotations, turns):
    """Array calibrations of one simulated device, one per entry of ``turns``: a dict gyro index -> the turn (rad,
    the reference's frame) of that gyro in that session."""
    t = np.arange(5000) / 100.0
    cals = []
    for seed, turn in enumerate(turns):
        g = np.random.default_rng(seed)
        w = HumanMotion(1.0, rng=g)(t)
        rot = [exp(turn.get(k, np.zeros(3))) @ R for k, R in enumerate(rotations)]
        cals.append(calibrate_array([w @ R + g.normal(0, 0.1 * DEG, w.shape) for R in rot]))
    return cals


def test_compare_sessions_says_which_gyros_turned_together():
    rng = np.random.default_rng(4)
    Rs = [np.eye(3)] + [general_rotation(rng) for _ in range(4)]
    steady = _array_sessions(Rs, [{}] * 4)
    sigma = np.sqrt(steady[0].covariance[6, 6])
    bend = np.array([12.0, -6.0, 3.0]) * sigma
    cals = steady + _array_sessions(Rs, [{2: bend, 3: bend}])            # gyros 3 and 4 turned as one
    r = compare_sessions(cals)
    assert r.changed.tolist() == [False] * 4 + [True]
    assert r.moved[:4] == ((),) * 4 and r.stayed[4] == (1, 2, 5)
    (group,) = r.moved[4]
    assert group.gyros == (3, 4)
    assert np.all(np.abs(group.rotation - bend) < 4.0 * group.rotation_std)
    assert np.all(group.rotation_std < 0.8 * r.deviation_std[4, 1])       # the group's turn: both gyros' evidence
    assert "gyros 3 and 4:" in r.summary() and "against gyros 1, 2 and 5 (which stayed)" in r.summary()
    saved = json.loads(json.dumps(r.to_dict()))
    assert saved["moved"][4][0]["gyros"] == [3, 4] and saved["stayed"][4] == [1, 2, 5]
    # the reference alone turned: every other gyro's rotation moved alike, the opposite way
    r = compare_sessions(steady + _array_sessions(Rs, [{0: bend}]))
    assert r.changed[4] and r.stayed[4] == (2, 3, 4, 5)
    (group,) = r.moved[4]
    assert group.gyros == (1,) and np.all(np.abs(group.rotation - bend) < 4.0 * group.rotation_std)


def test_compare_sessions_pairs_do_not_say_which_gyro_moved(steady):
    sigma = np.sqrt(np.trace(steady[0].covariance[:3, :3]) / 3.0)
    moved = _pair_sessions(1, turned=0, turn=np.array([0.0, 20.0 * sigma, 0.0]), seed=400)[0]
    r = compare_sessions(steady + [moved])
    assert r.changed[-1] and r.moved == () and r.stayed == ()


def test_compare_sessions_refuses_what_is_not_one_device(steady):
    with pytest.raises(InputError, match="at least two calibrations"):
        compare_sessions(steady[:1])
    with pytest.raises(InputError, match="one name per calibration"):
        compare_sessions(steady, ["a", "b"])
    with pytest.raises(InputError, match="false-alarm rate"):
        compare_sessions(steady, alpha=1.5)
    with pytest.raises(InputError, match="PairCalibration or ArrayCalibration"):
        compare_sessions([steady[0], "cal.json"])
    other = calibrate_pair(*(lambda s: (s.omega_1, s.omega_2))(simulate_pair(n=4000, rng=5)))   # another mounting
    with pytest.raises(InputError, match="one device"):
        compare_sessions([steady[0], other])


def test_sessions_cli_exit_codes(tmp_path, steady, capsys):
    from fusion_gyrocal.cli.app import EXIT_CHANGED, main
    from fusion_gyrocal.io.writers import write_json

    files = [str(write_json(c, tmp_path / f"day{e}.json")) for e, c in enumerate(steady[:3])]
    assert main(["sessions", *files, "--output", str(tmp_path / "cmp.json")]) == 0
    out = capsys.readouterr().out
    assert "day2" in out and "CHANGED" not in out
    saved = json.loads((tmp_path / "cmp.json").read_text())
    assert saved["kind"] == "session_comparison" and saved["changed"] == [False, False, False]
    sigma = np.sqrt(np.trace(steady[0].covariance[:3, :3]) / 3.0)
    moved = _pair_sessions(1, turned=0, turn=np.array([0.0, 0.0, 20.0 * sigma]), seed=300)[0]
    files.append(str(write_json(moved, tmp_path / "after_drop.json")))
    assert main(["sessions", *files]) == EXIT_CHANGED
    assert "after_drop" in capsys.readouterr().out
    assert main(["sessions", files[0]]) == 1
    err = capsys.readouterr().err
    assert "at least two calibrations" in err and "Traceback" not in err


def test_compare_sessions_mimu_flags_the_bent_session():
    """The MIMU board's nine sessions, IMU 1 against IMU 4 (its -y half): exp_6, where that half of the board turned
    ~45 mdeg about x (``benchmarks/sensor_model.py``, site check), is the one session flagged."""
    from fusion_gyrocal.io import read_npz

    d = data_folder("mimu_8imu_array") / "npz"
    cals = []
    for e in range(1, 10):
        s = read_npz(d / f"exp_{e}.npz")
        cals.append(calibrate_pair(s[0].omega, s[3].omega, t_1=s[0].t, t_2=s[3].t))
    r = compare_sessions(cals, [f"exp_{e}" for e in range(1, 10)])
    assert r.changed.tolist() == [e == 6 for e in range(1, 10)]
    assert abs(np.degrees(r.deviation[5, 0, 0]) * 1e3) > 25.0    # about x, tens of mdeg


def test_compare_sessions_mimu_says_the_bent_site_turned():
    """The MIMU board's IMUs 1-4 as one array, nine sessions: in exp_6 IMUs 3 and 4 (top and bottom of the board at
    one site, different axes) turned together, ~48 mdeg about x, against IMUs 1 and 2 (the other site): a bend of
    the board, not an error of either chip's estimate."""
    from fusion_gyrocal.io import read_npz

    d = data_folder("mimu_8imu_array") / "npz"
    cals = []
    for e in range(1, 10):
        s = read_npz(d / f"exp_{e}.npz")
        mask = np.all([g.valid for g in s[:4]], axis=0)
        cals.append(calibrate_array([g.omega for g in s[:4]], mask=mask, rate_hz=62.5))
    r = compare_sessions(cals, [f"exp_{e}" for e in range(1, 10)])
    assert r.changed.tolist() == [e == 6 for e in range(1, 10)]
    assert r.stayed[5] == (1, 2)
    (group,) = r.moved[5]
    assert group.gyros == (3, 4)
    assert np.degrees(group.rotation[0]) * 1e3 < -25.0 and abs(group.rotation[0]) > 5.0 * group.rotation_std[0]


def test_compare_sessions_refuses_a_rotation_without_covariance(steady):
    import dataclasses

    cov = np.array(steady[1].covariance)
    cov[:3, :3] = np.nan
    blind = dataclasses.replace(steady[1], covariance=cov)
    with pytest.raises(InputError, match="positive definite rotation covariance"):
        compare_sessions([steady[0], blind])
