"""The YAML exports as their consumers read them: Kalibr's ImuParameters rules, OpenCV's FileStorage (OpenVINS)."""

import dataclasses
import math

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from fusion_gyrocal import FormatError, InputError, PairCalibration
from fusion_gyrocal.core.array import calibrate_array
from fusion_gyrocal.core.noise import NoiseKind
from fusion_gyrocal.evaluate.sim import DEG, HumanMotion, random_rotation
from fusion_gyrocal.io.writers import (ImuNoise, write_kalibr_imu_chain, write_kalibr_imu_configs,
                                       write_openvins_imu_chain)

NOISE_KEYS = ("accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
              "gyroscope_random_walk")


# --------------------------------------------------------------------------------- the consumers' reading rules
def kalibr_imu_parameters(path) -> dict:
    """Kalibr's ``kalibr_common.ConfigReader.ImuParameters`` restated (what ``kalibr_calibrate_imu_camera --imu``
    does with each file): ``yaml.safe_load``; the top-level keys ``rostopic`` (must be a str),
    ``update_rate`` (> 0), ``accelerometer_noise_density``, ``accelerometer_random_walk``,
    ``gyroscope_noise_density``, ``gyroscope_random_walk`` (each > 0; a missing one is "Field ... missing");
    the discrete noise is ``density / sqrt(1 / update_rate)``. Raises ``RuntimeError`` as Kalibr does."""
    with open(path) as f:
        data = yaml.safe_load(f)
    try:
        if not isinstance(data["rostopic"], str):
            raise RuntimeError("[ImuConfig Reader]: rostopic has to be a string")
        rate = data["update_rate"]
        if not rate > 0.0:
            raise RuntimeError("[ImuConfig Reader]: invalid update_rate")
        for key in NOISE_KEYS:
            if not data[key] > 0.0:
                raise RuntimeError(f"[ImuConfig Reader]: invalid {key}")
    except KeyError as e:
        raise RuntimeError(f"[ImuConfig Reader]: Field {e} missing in file: {path}") from None
    return {"rostopic": data["rostopic"], "update_rate": rate,
            "gyro_discrete": data["gyroscope_noise_density"] / math.sqrt(1.0 / rate),
            **{k: data[k] for k in NOISE_KEYS}}


def opencv_imu_chain(path, n):
    """The IMU chain as OpenVINS' ``ov_core::YamlParser`` reads it: ``cv::FileStorage`` on the ``%YAML:1.0``
    file, then per ``imu<k>`` node: matrices as nested sequences (``T_i_b`` 4x4, ``Tw`` ... 3x3), reals and
    strings (``model``, ``rostopic``)."""
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless not installed (test extra)")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.isOpened()
    out = []
    for k in range(n):
        node = fs.getNode(f"imu{k}")
        assert not node.empty(), f"imu{k} missing"

        def mat(name, size, node=node):
            m = node.getNode(name)
            assert m.size() == size, f"imu{k}.{name}: expected {size} rows, got {m.size()}"
            return np.array([[m.at(r).at(c).real() for c in range(size)] for r in range(size)])

        out.append({"T_i_b": mat("T_i_b", 4), **{m: mat(m, 3) for m in ("Tw", "R_IMUtoGYRO", "Ta", "R_IMUtoACC",
                                                                      "Tg")},
                    "model": node.getNode("model").string(), "rostopic": node.getNode("rostopic").string(),
                    "time_offset": node.getNode("time_offset").real(),
                    "update_rate": node.getNode("update_rate").real(),
                    **{k2: node.getNode(k2).real() for k2 in NOISE_KEYS}})
    fs.release()
    return out


# --------------------------------------------------------------------------------- fixtures
def _pair(rng, **over):
    cov = np.diag(rng.uniform(1e-8, 1e-6, 12))
    kw = dict(R_1_2=Rotation.from_rotvec(rng.normal(0, 0.5, 3)).as_matrix(), scale_1=[1.0, 1.003, 0.997],
              scale_2=[1.01, 0.99, 1.002], bias=rng.normal(0, 0.01, 3), configuration="general",
              scale_observable=[[True] * 3] * 2, covariance=cov, gauge="scale_1[0] == 1", snr=[500.0] * 3,
              n_samples=6000, noise_std=[0.1 * DEG, 0.2 * DEG], time_offset_s=-0.0123, time_offset_std_s=1e-4,
              rigid=True, unexplained_fraction=0.001)
    kw.update(over)
    return PairCalibration(**kw)


def _array(seed, R=None, n=4):
    rng = np.random.default_rng(seed)
    omega = HumanMotion(1.0, rng=rng)(np.arange(4000) / 100.0)
    R = [np.eye(3)] + [random_rotation(rng) for _ in range(n - 1)] if R is None else R
    scales = 1.0 + rng.normal(0, 0.01, (len(R), 3))
    omegas = [(omega @ Rk) * sk + rng.normal(0, 1e-3, omega.shape) for Rk, sk in zip(R, scales)]
    return calibrate_array(omegas), R


TOPICS = ["/imu#0", "/a:b", "/plain", "/x/y"]


# --------------------------------------------------------------------------------- Kalibr
def test_write_kalibr_imu_configs_pass_kalibr_imu_parameters(tmp_path):
    cal, _ = _array(1)
    paths = write_kalibr_imu_configs(cal, tmp_path / "kalibr", topics=TOPICS, update_rate=[200.0, 100.0, 400, 50])
    assert [p.name for p in paths] == ["imu0.yaml", "imu1.yaml", "imu2.yaml", "imu3.yaml"]
    for k, (p, topic, rate) in enumerate(zip(paths, TOPICS, (200.0, 100.0, 400.0, 50.0))):
        got = kalibr_imu_parameters(p)
        assert got["rostopic"] == topic and got["update_rate"] == rate
        text = p.read_text()
        # the joint solve's white noise per gyro (per sample: input without timestamps) at each IMU's own rate,
        # placeholders for the rest
        assert got["gyroscope_noise_density"] == pytest.approx(cal.noise_std[k] / math.sqrt(rate), rel=1e-12)
        assert f"identified: gyro {k + 1}'s white noise in the joint solve" in text
        assert text.count("PLACEHOLDER, not measured") == 3 and "Allan-variance" in text


def test_kalibr_imu_parameters_rules_reject_the_chain_layout(tmp_path):
    # the chain (Kalibr's result layout) is what a user once passed to --imu: the restated rules refuse it
    cal, _ = _array(2, n=3)
    p = write_kalibr_imu_chain(cal, tmp_path / "imu_chain.yaml")
    with pytest.raises(RuntimeError, match="Field 'rostopic' missing"):
        kalibr_imu_parameters(p)


def test_write_kalibr_imu_configs_measured_noise_written_unmarked(tmp_path):
    cal = _pair(np.random.default_rng(3))
    noise = ImuNoise(1e-4, 2e-5, 3e-3, 4e-4)
    p0, p1 = write_kalibr_imu_configs(cal, tmp_path / "k", noise=[noise, None])
    got = kalibr_imu_parameters(p0)
    assert (got["gyroscope_noise_density"], got["gyroscope_random_walk"]) == (1e-4, 2e-5)
    assert "PLACEHOLDER" not in p0.read_text() and "PLACEHOLDER" in p1.read_text()
    # a residual-derived figure is never written as a noise density: imu1 carries the placeholder
    assert kalibr_imu_parameters(p1)["gyroscope_noise_density"] == 1.6968e-4


def test_write_kalibr_imu_chain_T_i_b_and_M_reproduce_every_pair(tmp_path):
    cal, _ = _array(4)
    y = yaml.safe_load(write_kalibr_imu_chain(cal, tmp_path / "c.yaml", topics=TOPICS).read_text())
    M0C0 = np.array(y["imu0"]["gyroscopes"]["M"]) @ np.array(y["imu0"]["T_i_b"])[:3, :3]
    for k in range(1, 4):
        imu = y[f"imu{k}"]
        T = np.array(imu["T_i_b"])
        np.testing.assert_array_equal(T[:3, :3], cal.R_ref_k[k].T)
        np.testing.assert_array_equal(T[:3, 3], np.zeros(3))
        assert imu["translation_estimated"] is False and imu["model"] == "scale-misalignment"
        A = M0C0 @ np.linalg.inv(np.array(imu["gyroscopes"]["M"]) @ T[:3, :3])
        np.testing.assert_allclose(A, cal.pair(0, k).A, rtol=0, atol=1e-14)
        assert imu["rostopic"] == TOPICS[k]


def test_write_kalibr_imu_configs_pair_time_offset_in_comment_only(tmp_path):
    cal = _pair(np.random.default_rng(5))
    _, p1 = write_kalibr_imu_configs(cal, tmp_path / "k")
    assert "time offset -0.0123 s" in p1.read_text()
    assert set(yaml.safe_load(p1.read_text())) == {"rostopic", "update_rate", *NOISE_KEYS}


# --------------------------------------------------------------------------------- OpenVINS
def test_write_openvins_imu_chain_read_by_opencv_gives_each_T_i_b(tmp_path):
    cal, R = _array(6)
    p = write_openvins_imu_chain(cal, tmp_path / "kalibr_imu_chain.yaml", topics=TOPICS, update_rate=200.0)
    imus = opencv_imu_chain(p, 4)
    for k, imu in enumerate(imus):
        np.testing.assert_allclose(imu["T_i_b"][:3, :3], cal.R_ref_k[k].T, rtol=0, atol=1e-15)
        assert np.degrees(np.linalg.norm(Rotation.from_matrix(imu["T_i_b"][:3, :3] @ R[k]).as_rotvec())) < 0.05
        np.testing.assert_array_equal(imu["T_i_b"][3], [0, 0, 0, 1])
        # relative to imu0: a general mounting is one group, divided by the geometric mean of imu0's scale factors
        g = np.exp(np.mean(np.log(cal.scale[0])))
        np.testing.assert_allclose(imu["Tw"], np.diag(cal.scale[k] / g), rtol=0, atol=1e-15)
        assert imu["model"] == "kalibr" and imu["rostopic"] == TOPICS[k] and imu["update_rate"] == 200.0
        assert all(imu[key] > 0 for key in NOISE_KEYS)
        np.testing.assert_array_equal(imu["Tg"], np.zeros((3, 3)))


def test_write_openvins_imu_chain_parallel_axes_reference_exactly_one_others_relative(tmp_path):
    # axis-parallel gyros (Lemma 2): no scale factor is determined, only ratios to the parallel axis of imu0;
    # imu0's Tw is exactly the identity (OpenVINS applies Tw at every step) and the others carry the ratios
    flip = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    cal, _ = _array(7, R=[np.eye(3), flip, np.eye(3)])
    assert not cal.scale_observable.any()
    p = write_openvins_imu_chain(cal, tmp_path / "c.yaml")
    imus = opencv_imu_chain(p, 3)
    np.testing.assert_array_equal(imus[0]["Tw"], np.eye(3))
    rel, sd = cal.relative_scales()
    for k in (1, 2):
        perm = np.argmax(np.abs(cal.R_ref_k[k]), axis=0)
        np.testing.assert_allclose(np.diag(imus[k]["Tw"]), cal.scale[k] / cal.scale[0, perm], rtol=1e-15)
        np.testing.assert_allclose(np.diag(imus[k]["Tw"]), rel[k], rtol=1e-15)
        assert np.isfinite(sd[k]).all() and (sd[k] > 0).all()
        assert f"imu{k}: relative scale factors x {rel[k, 0]:.6f} +- {sd[k, 0]:.2g}" in p.read_text()


def test_write_openvins_imu_chain_pair_time_offset_and_model(tmp_path):
    cal = _pair(np.random.default_rng(8))
    imus = opencv_imu_chain(write_openvins_imu_chain(cal, tmp_path / "c.yaml", update_rate=[200.0, 100.0]), 2)
    assert imus[1]["time_offset"] == cal.time_offset_s and imus[0]["time_offset"] == 0.0
    assert [i["model"] for i in imus] == ["kalibr", "kalibr"]
    g = np.exp(np.mean(np.log(cal.scale_1)))   # a general mounting: one group, imu0's geometric mean is 1
    np.testing.assert_allclose(imus[1]["Tw"], np.diag(cal.scale_2 / g), rtol=1e-15)
    assert np.prod(np.diag(imus[0]["Tw"])) == pytest.approx(1.0, abs=1e-15)


# --------------------------------------------------------------------------------- honesty
def test_writers_warn_in_every_file_for_a_not_rigid_pair(tmp_path):
    cal = _pair(np.random.default_rng(9), rigid=False, unexplained_fraction=0.31)
    files = [*write_kalibr_imu_configs(cal, tmp_path / "k"), write_kalibr_imu_chain(cal, tmp_path / "c.yaml"),
             write_openvins_imu_chain(cal, tmp_path / "o.yaml")]
    for p in files:
        head = p.read_text().splitlines()[:3]
        assert any(line.startswith("# WARNING: NOT RIGID") and "31.0%" in line for line in head), p.name
    assert "WARNING" not in write_openvins_imu_chain(dataclasses.replace(cal, rigid=True), tmp_path / "r.yaml").read_text()


def test_writers_refuse_topics_that_cannot_be_quoted(tmp_path):
    cal = _pair(np.random.default_rng(10))
    with pytest.raises(InputError, match="topics: expected non-empty printable names"):
        write_openvins_imu_chain(cal, tmp_path / "c.yaml", topics=["/a", 'b"c'])
    with pytest.raises(InputError, match=r"topics: expected 2 topic names"):
        write_kalibr_imu_chain(cal, tmp_path / "c.yaml", topics=["/a"])
    assert list(tmp_path.iterdir()) == []


def test_writers_refuse_non_finite_array_rotation(tmp_path):
    cal, _ = _array(11, n=3)
    bad = dataclasses.replace(cal, time_offset_s=np.array([0.0, np.nan, 0.0]))
    with pytest.raises(FormatError, match=r"cal\.time_offset_s: Kalibr/OpenVINS files need finite values"):
        write_kalibr_imu_configs(bad, tmp_path / "k")


# --------------------------------------------------------------------------------- identified noise figures
@pytest.fixture(scope="module")
def walking_pair():
    """A simulated pair with 100x the paper's bias walk: the identified model is white noise + random walk."""
    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.evaluate.sim import PAPER_BIAS_WALK_STD, PAPER_NOISE_STD, simulate_pair

    sim = simulate_pair(n=30000, bias_walk_std=100 * PAPER_BIAS_WALK_STD, rng=1)
    cal = calibrate_pair(sim.omega_1, sim.omega_2, t_1=sim.t, t_2=sim.t)
    assert cal.noise_model is not None and cal.noise_model.bias_model == "random walk"
    assert cal.noise_model.rate_hz == pytest.approx(100.0)
    # truth in Kalibr's units at 100 Hz: density sigma / sqrt(rate), random walk q * sqrt(rate)
    return cal, PAPER_NOISE_STD / 10.0, 100 * PAPER_BIAS_WALK_STD * 10.0


def _comment(text, key):
    return next(line for line in text.splitlines() if line.strip().startswith(f"{key}:")).split("#", 1)[1]


def test_write_kalibr_imu_configs_identified_noise_written_with_its_source(walking_pair, tmp_path):
    cal, density, walk = walking_pair
    nm = cal.noise_model
    for i, p in enumerate(write_kalibr_imu_configs(cal, tmp_path / "k", update_rate=100.0)):
        got, text = kalibr_imu_parameters(p), p.read_text()
        assert got["gyroscope_noise_density"] == nm.noise_density[i]
        assert got["gyroscope_random_walk"] == nm.random_walk[i]
        assert abs(got["gyroscope_noise_density"] / density - 1) < 0.05
        assert abs(got["gyroscope_random_walk"] / walk - 1) < 0.25
        assert "identified" in _comment(text, "gyroscope_noise_density") and "+- " in _comment(text, "gyroscope_noise_density")
        assert "identified" in _comment(text, "gyroscope_random_walk")
        # the accelerometer figures stay placeholders (gyro-only), and say why
        assert text.count("PLACEHOLDER, not measured (gyro-only calibration)") == 2
        assert [k for k in NOISE_KEYS if "PLACEHOLDER" in _comment(text, k)] == list(NOISE_KEYS[:2])
        assert "IDENTIFIED by fusion_gyrocal from the moving pair's own residual" in text
        assert "bias model random walk" in text


def test_write_openvins_imu_chain_identified_noise_read_by_opencv(walking_pair, tmp_path):
    cal, _, _ = walking_pair
    nm = cal.noise_model
    imus = opencv_imu_chain(write_openvins_imu_chain(cal, tmp_path / "ov.yaml"), 2)
    chain = yaml.safe_load(write_kalibr_imu_chain(cal, tmp_path / "chain.yaml").read_text())
    for i in (0, 1):
        for got in (imus[i], chain[f"imu{i}"]):
            assert got["gyroscope_noise_density"] == nm.noise_density[i]
            assert got["gyroscope_random_walk"] == nm.random_walk[i]
            assert got["accelerometer_noise_density"] == 2.0e-3   # placeholder


def test_write_kalibr_imu_configs_constant_bias_walk_term_split_or_placeholder(walking_pair, tmp_path):
    cal, _, _ = walking_pair
    nm = cal.noise_model
    # a constant-bias model whose Allan fit found a walk term: that term, split equally between the gyros
    const = dataclasses.replace(cal, noise_model=dataclasses.replace(nm, bias_walk_std=None, bias_model="constant"))
    a = np.sum(cal.A * cal.A) / 3.0
    expected = nm.residual_walk_std * np.sqrt(nm.rate_hz) / np.sqrt(1.0 + a)
    for p in write_kalibr_imu_configs(const, tmp_path / "c"):
        got = kalibr_imu_parameters(p)
        assert got["gyroscope_random_walk"] == pytest.approx(expected, rel=1e-12)
        assert "split equally" in p.read_text()
    # no walk term at all: the random walk is a placeholder saying so, the white density is still written
    none = dataclasses.replace(const, noise_model=dataclasses.replace(const.noise_model, residual_walk_std=0.0))
    for i, p in enumerate(write_kalibr_imu_configs(none, tmp_path / "n")):
        text, got = p.read_text(), kalibr_imu_parameters(p)
        assert got["gyroscope_random_walk"] == 1.9393e-5
        assert "PLACEHOLDER, not measured (no random-walk term" in _comment(text, "gyroscope_random_walk")
        assert got["gyroscope_noise_density"] == nm.noise_density[i]


def test_write_kalibr_imu_configs_misfit_writes_the_sensor_noise_not_the_residual(walking_pair, tmp_path):
    cal, density, _ = walking_pair
    nm = dataclasses.replace(cal.noise_model, noise_kind=NoiseKind.RATE_MISFIT, misfit_share=0.9)
    bad = dataclasses.replace(cal, noise_model=nm, residual_rms=30 * cal.residual_rms)
    for i, p in enumerate(write_kalibr_imu_configs(bad, tmp_path / "m")):
        got, text = kalibr_imu_parameters(p), p.read_text()
        assert got["gyroscope_noise_density"] == nm.noise_density[i]
        assert got["gyroscope_noise_density"] < 2 * density   # never the residual (30x larger here)
        assert "the sensor's white noise" in _comment(text, "gyroscope_noise_density")
        assert "The residual is NOT white noise" in text and "never the residual's spread" in text


def test_write_kalibr_imu_configs_given_noise_wins_over_identified(walking_pair, tmp_path):
    cal, _, _ = walking_pair
    p0, p1 = write_kalibr_imu_configs(cal, tmp_path / "g", noise=[ImuNoise(1e-4, 2e-5, 3e-3, 4e-4), None])
    assert kalibr_imu_parameters(p0)["gyroscope_noise_density"] == 1e-4
    assert "PLACEHOLDER" not in p0.read_text() and "IDENTIFIED" not in p0.read_text()
    assert kalibr_imu_parameters(p1)["gyroscope_noise_density"] == cal.noise_model.noise_density[1]


def test_write_kalibr_imu_chain_without_noise_model_only_placeholders(walking_pair, tmp_path):
    cal, _, _ = walking_pair
    plain = dataclasses.replace(cal, noise_model=None, noise_source="user")
    text = write_kalibr_imu_chain(plain, tmp_path / "p.yaml").read_text()
    assert text.count("PLACEHOLDER, not measured  ") == 0 and text.count("PLACEHOLDER, not measured\n") == 8
    assert "IDENTIFIED" not in text and "identified:" not in text


def test_write_kalibr_imu_configs_per_sample_model_converted_with_update_rate(tmp_path):
    # sample-aligned input has no rate: the model is per sample, the file's update_rate makes the densities
    from fusion_gyrocal import calibrate_pair
    from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, simulate_pair

    sim = simulate_pair(n=20000, bias_walk_std=0.0, rng=2)
    cal = calibrate_pair(sim.omega_1, sim.omega_2)
    assert cal.noise_model.rate_hz == 1.0
    for rate in (100.0, 400.0):
        for i, p in enumerate(write_kalibr_imu_configs(cal, tmp_path / f"r{rate:g}", update_rate=rate)):
            got = kalibr_imu_parameters(p)
            assert got["gyroscope_noise_density"] == pytest.approx(cal.noise_model.noise_std[i] / np.sqrt(rate))
            # Kalibr's discrete noise at its update_rate is the per-sample white noise again
            assert abs(got["gyro_discrete"] / PAPER_NOISE_STD - 1) < 0.05
            assert "no timestamps" in p.read_text()


def test_write_kalibr_imu_configs_resampled_gyro_writes_its_own_density_and_rate(walking_pair, tmp_path):
    # gyro 2 at half gyro 1's rate, interpolated onto its grid: its figure is the sensor's own density at its own
    # rate (identify_noise with a Resampling), not the grid's per-sample noise over the grid's rate
    cal, _, _ = walking_pair
    own = (1.1e-4, 3.3e-4)
    nm = dataclasses.replace(cal.noise_model, rates_hz=(100.0, 50.0), densities=own)
    resampled = dataclasses.replace(cal, noise_model=nm)
    for i, p in enumerate(write_kalibr_imu_configs(resampled, tmp_path / "r", update_rate=[100.0, 50.0])):
        got, text = kalibr_imu_parameters(p), p.read_text()
        assert got["gyroscope_noise_density"] == own[i]
        assert got["gyroscope_random_walk"] == nm.random_walk[i]          # walk steps per grid sample
        assert f"per sample at its {(100.0, 50.0)[i]:.6g} Hz = gyroscope_noise_density {own[i]:.4g}" in text
