"""``gyrocal compare`` on recordings: the same samples as ``calibrate`` (its masks and options)."""

import json
import re

import numpy as np
import pytest

from fusion_gyrocal.cli import main
from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, HumanMotion, random_rotation, shared_data_dir

MIMU = shared_data_dir() / "mimu_8imu_array" / "npz"
needs_mimu = pytest.mark.skipif(not (MIMU / "exp_4.npz").exists(),
                                reason=f"{MIMU}/exp_4.npz not present (set FUSION_GYROCAL_DATA to the shared data)")


def _compare_samples(capsys, argv) -> int:
    """Samples ``gyrocal compare`` used (the title of its recording table)."""
    assert main(["compare", *argv, "--estimators", "rotation_only", "--no-progress"]) == 0
    out = capsys.readouterr().out
    return int(re.search(r"recording: (\d+) sample-aligned samples", out).group(1))


def _calibrate_samples(tmp_path, argv) -> int:
    """Samples ``gyrocal calibrate`` used before its flex gate (``--no-flex-rejection``)."""
    out = tmp_path / "cal.json"
    assert main(["calibrate", *argv, "--no-flex-rejection", "--allow-not-rigid", "--output", str(out)]) == 0
    return json.loads(out.read_text())["n_samples"]


def _clipped_pair(tmp_path, limit_deg=100.0):
    """A CSV pair whose gyro 2 clips flat at +-limit_deg (deg/s) during the fast stretches."""
    rng = np.random.default_rng(3)
    motion, R = HumanMotion(1.0, rng=rng), random_rotation(rng)
    t = np.arange(0, 40, 0.01)
    w1 = np.rad2deg(motion(t)) + rng.normal(0, np.rad2deg(PAPER_NOISE_STD), (t.size, 3))
    w2 = np.rad2deg(motion(t) @ R) + rng.normal(0, np.rad2deg(PAPER_NOISE_STD), (t.size, 3))
    w2 = np.clip(w2, -limit_deg, limit_deg)
    paths = []
    for name, w in (("a.csv", w1), ("b.csv", w2)):
        paths.append(tmp_path / name)
        np.savetxt(paths[-1], np.column_stack([t, w]), delimiter=",", header="t,gx,gy,gz", comments="")
    return [str(p) for p in paths], int(np.any(np.abs(w2) >= limit_deg, axis=1).sum())


def test_cli_compare_masks_clipped_samples_as_calibrate_does(tmp_path, capsys):
    paths, n_clipped = _clipped_pair(tmp_path)
    argv = [*paths, "--unit", "deg/s", "--offset", "0"]
    assert n_clipped > 100
    n_compare = _compare_samples(capsys, argv)
    assert n_compare == _calibrate_samples(tmp_path, argv)
    assert n_compare <= 4000 - n_clipped     # the clipped samples are not used


def test_cli_compare_saturation_limit_and_max_rate_reach_the_masks(tmp_path, capsys):
    paths, _ = _clipped_pair(tmp_path)
    for extra in (["--saturation-limit", "1.2"], ["--max-rate", "1.5"]):
        argv = [*paths, "--unit", "deg/s", "--offset", "0", *extra]
        n_compare = _compare_samples(capsys, argv)
        assert n_compare == _calibrate_samples(tmp_path, argv)
        assert n_compare < _compare_samples(capsys, [*paths, "--unit", "deg/s", "--offset", "0"])


@needs_mimu
def test_cli_compare_mimu_uses_the_samples_of_calibrate(tmp_path, capsys):
    # the MIMU board clips at +-1998 deg/s; exp_4's IMUs 0 and 1 also sit flat at extreme values the reader
    # does not flag, which calibrate's saturation mask removes: compare must drop the same samples
    argv = [str(MIMU / "exp_4.npz"), "--imu1", "0", "--imu2", "1"]
    n_compare = _compare_samples(capsys, argv)
    assert n_compare == _calibrate_samples(tmp_path, argv)
    limited = [*argv, "--saturation-limit", "30"]   # rad/s, below the board's 34.87 rad/s range
    n_limited = _compare_samples(capsys, limited)
    assert n_limited < n_compare and n_limited == _calibrate_samples(tmp_path, limited)
