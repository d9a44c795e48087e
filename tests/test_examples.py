"""The examples are run by the tests (each asserts what it demonstrates)."""


import numpy as np
from _examples import load_example
import pytest

from fusion_gyrocal.evaluate.sim import shared_data_dir



def _load(name):
    return load_example(name)


def test_example_simulated_pair_runs_and_is_accurate(capsys):
    out = _load("simulated_pair").main()
    for rot, sc, cal in out.values():
        assert rot < 5 * np.linalg.norm(cal.rotation_std_rad)
        assert sc < 1e-3
    assert "rotation error" in capsys.readouterr().out


@pytest.mark.skipif(not shared_data_dir().exists(), reason="../shared/data not present (real recordings are only in "
                                                           "the project checkout)")
def test_example_real_motion_pair_runs_and_is_accurate():
    out = _load("real_motion_pair").main()
    cal = out["calibration"]
    assert out["rotation_error"] < 5 * np.linalg.norm(cal.rotation_std_rad)
    assert abs(cal.time_offset_s - out["offset"]) < 1e-4
