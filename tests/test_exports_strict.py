"""Result files as their consumers need them: strict JSON with no numbers as strings (undetermined directions null
and named), and N-gyro noise densities at each IMU's own rate."""

import json
import math

import numpy as np
import pytest
import yaml

from fusion_gyrocal import calibrate_pair, calibrate_streams
from fusion_gyrocal.core.model import PARAMETER_NAMES
from fusion_gyrocal.evaluate.sim import HumanMotion, random_rotation, simulate_pair
from fusion_gyrocal.io import read_json, write_json
from fusion_gyrocal.io.writers import FormatError, write_kalibr_imu_configs
from fusion_gyrocal.pipeline.resample import noise_factors

FLIP = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])   # 180 deg about (1, -1, 0)


def _refuse(name):
    raise ValueError(f"non-standard JSON constant {name}")


def _strings(v):
    if isinstance(v, dict):
        return [s for x in v.values() for s in _strings(x)]
    if isinstance(v, list):
        return [s for x in v for s in _strings(x)]
    return [v] if isinstance(v, str) else []


def _at(doc, pointer):
    for token in pointer.split("/")[1:]:
        doc = doc[int(token)] if isinstance(doc, list) else doc[token]
    return doc


@pytest.fixture(scope="module")
def parallel_pair():
    # an axis-parallel pair (Lemma 2): no scale factor determined (infinite variance), their ratios are
    sim = simulate_pair(rng=8, n=10000, R_1_2=FLIP, scale_1=[1.0, 1.003, 0.996], scale_2=[1.012, 0.991, 1.004])
    return calibrate_pair(sim.omega_1, sim.omega_2)


def test_write_json_undetermined_scales_null_named_and_read_back(parallel_pair, tmp_path):
    cal = parallel_pair
    assert np.isposinf(np.diag(cal.covariance)[3:9]).all()
    text = write_json(cal, tmp_path / "cal.json").read_text()
    d = json.loads(text, parse_constant=_refuse)               # strict: no NaN / Infinity literals
    assert not {"NaN", "Infinity", "-Infinity"} & set(_strings(d))   # and no numbers as strings
    # every infinite variance is null, named by its JSON Pointer; the parameters by name
    expected = {f"/covariance/{i}/{i}" for i in range(3, 9)}
    assert expected <= set(d["non_finite"]["inf"])
    assert all(_at(d, p) is None for kind in d["non_finite"].values() for p in kind)
    assert d["undetermined"] == list(PARAMETER_NAMES[3:9])
    # what the data determine stays a finite number: the ratios and their 1-sigma, the rotation block
    assert all(isinstance(v, float) and math.isfinite(v) for v in d["scale_ratio"]["value"] + d["scale_ratio"]["std"])
    assert all(isinstance(v, float) for row in d["covariance"][:3] for v in row[:3])
    back = read_json(tmp_path / "cal.json")
    np.testing.assert_array_equal(back.covariance, cal.covariance)   # inf where it was, numbers elsewhere
    np.testing.assert_array_equal(back.scale_ratio_std, cal.scale_ratio_std)


def test_read_json_non_finite_pointer_to_a_number_is_a_format_error(parallel_pair, tmp_path):
    p = tmp_path / "cal.json"
    d = json.loads(write_json(parallel_pair, p).read_text())
    d["non_finite"]["inf"].append("/n_samples")
    p.write_text(json.dumps(d))
    with pytest.raises(FormatError, match=r"cal\.json: non_finite: expected '/n_samples' to name a null entry of "
                                         r"the file, got 10000"):
        read_json(p)
    d["non_finite"] = {"Infinity": []}
    p.write_text(json.dumps(d))
    with pytest.raises(FormatError, match=r"non_finite: expected a mapping of \['-inf', 'inf', 'nan'\]"):
        read_json(p)


@pytest.fixture(scope="module")
def mixed_rates():
    """Three gyros at 200 (the reference), 100 and 400 Hz on one clock, the others 1.3 ms late: resampled."""
    rng = np.random.default_rng(5)
    motion = HumanMotion(1.0, rng=rng)
    rates, density = (200.0, 100.0, 400.0), (2e-4, 4e-4, 3e-4)
    ts, ws = [], []
    for k, (f, n) in enumerate(zip(rates, density)):
        t = np.arange(int(90 * f)) / f + (0.0013 if k else 0.0)
        Rk = np.eye(3) if k == 0 else random_rotation(rng)
        ts.append(t)
        ws.append(motion(t) @ Rk + rng.normal(0, n * math.sqrt(f), (t.size, 3)))
    return ts, calibrate_streams(ts, ws, time_offset_s=0.0)


def test_calibrate_streams_noise_density_each_gyro_at_its_own_rate(mixed_rates):
    ts, cal = mixed_rates
    np.testing.assert_allclose(cal.rates_hz, [200.0, 100.0, 400.0], rtol=1e-9)
    grid = ts[0][(ts[0] >= ts[1][0]) & (ts[0] <= ts[1][-1])]
    for k in range(3):
        # noise_std per grid sample = v_k f_k N_k^2: v_k what the spline kept of gyro k's white variance there
        v = 1.0 if k == 0 else noise_factors(ts[k], grid)[0]
        assert cal.noise_density[k] == pytest.approx(cal.noise_std[k] / math.sqrt(v * cal.rates_hz[k]), rel=0.02)
    # gyro 2 was upsampled (interpolated samples keep less variance) and runs at half the grid's rate
    assert cal.noise_density[1] > 1.3 * cal.noise_std[1] / math.sqrt(200.0)


def test_calibrate_streams_noise_density_recovers_each_gyros_truth(mixed_rates):
    """Each pair's noise is split between its gyros as their own rates and resampling make it (the resampling
    passed to the identification): the densities are the simulated ones (2e-4, 4e-4, 3e-4), not a split that
    treats every stream as if it were sampled on the grid (1.70x, 0.53x, 0.90x of the truth)."""
    _, cal = mixed_rates
    np.testing.assert_allclose(cal.noise_density, [2e-4, 4e-4, 3e-4], rtol=0.10)


def test_write_kalibr_imu_configs_array_writes_each_gyros_own_density(mixed_rates, tmp_path):
    _, cal = mixed_rates
    paths = write_kalibr_imu_configs(cal, tmp_path / "k", update_rate=list(cal.rates_hz))
    for k, p in enumerate(paths):
        got = yaml.safe_load(p.read_text())
        assert got["gyroscope_noise_density"] == pytest.approx(cal.noise_density[k], rel=1e-12)
        assert got["update_rate"] == pytest.approx(cal.rates_hz[k], rel=1e-12)
        assert f"own rate {cal.rates_hz[k]:.6g} Hz" in p.read_text()


def test_array_json_round_trips_rates_and_densities_strictly(mixed_rates, tmp_path):
    _, cal = mixed_rates
    text = write_json(cal, tmp_path / "a.json").read_text()
    d = json.loads(text, parse_constant=_refuse)
    assert not {"NaN", "Infinity", "-Infinity"} & set(_strings(d))
    assert d["cross_axis_chi2"][0] is None and f"/cross_axis_chi2/{cal.reference}" in d["non_finite"]["nan"]
    back = read_json(tmp_path / "a.json")
    np.testing.assert_array_equal(back.rates_hz, cal.rates_hz)
    np.testing.assert_array_equal(back.noise_density, cal.noise_density)
    np.testing.assert_array_equal(back.cross_axis_chi2, cal.cross_axis_chi2)
