"""The ROS exports read as ROS reads them, the rotation in every form, relative scales, --nominal, --noise, JSON 1.4."""

import dataclasses
import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from fusion_gyrocal import InputError, PairCalibration, calibrate_pair
from fusion_gyrocal.cli import main
from fusion_gyrocal.core.array import calibrate_array
from fusion_gyrocal.evaluate.sim import HumanMotion, random_rotation, simulate_pair
from fusion_gyrocal.io.ros import check_frames, parse_nominals, parse_rotation, write_ros_frames
from fusion_gyrocal.io.writers import (FormatError, ImuNoise, read_imu_noise, write_kalibr_imu_configs,
                                       write_openvins_imu_chain)

FLIP = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])   # 180 deg about (1, -1, 0)


# --------------------------------------------------------------------------------- the consumers' reading rules
def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _quat_matrix(x, y, z, w):
    """tf2::Quaternion -> Matrix3x3 (Hamilton, scalar last), written out."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def tf2_static_args(args: str):
    """``static_transform_publisher``'s positional arguments (ROS 1): 9 = ``x y z qx qy qz qw frame child``,
    8 = ``x y z yaw pitch roll frame child`` (``setRPY(roll, pitch, yaw)``: Rz(yaw) Ry(pitch) Rx(roll)); an extra
    trailing period is tf1's. Returns (parent, child, R_parent_child, t)."""
    a = args.split()
    if len(a) in (10, 11):
        a = a[:-1]
    if len(a) == 9:
        return a[7], a[8], _quat_matrix(*map(float, a[3:7])), np.array(a[:3], float)
    if len(a) == 8:
        yaw, pitch, roll = map(float, a[3:6])
        return a[6], a[7], _rz(yaw) @ _ry(pitch) @ _rx(roll), np.array(a[:3], float)
    raise ValueError(f"static_transform_publisher: bad argument count {len(a)}")


def tf2_static_named_args(args: str):
    """ROS 2's named arguments (``--x ... --qw``, ``--roll --pitch --yaw``, ``--frame-id``, ``--child-frame-id``)."""
    a = args.split()
    kv = dict(zip(a[0::2], a[1::2]))
    t = np.array([float(kv.get(f"--{k}", 0.0)) for k in "xyz"])
    if "--qw" in kv:
        R = _quat_matrix(*(float(kv[f"--q{k}"]) for k in "xyzw"))
    else:
        R = _rz(float(kv.get("--yaw", 0))) @ _ry(float(kv.get("--pitch", 0))) @ _rx(float(kv.get("--roll", 0)))
    return kv["--frame-id"], kv["--child-frame-id"], R, t


def launch_nodes(path, ros: int):
    """Every static_transform_publisher node of a launch file (xml.etree), read by its arguments."""
    root = ET.parse(path).getroot()
    assert root.tag == "launch"
    out = []
    for node in root.iter("node"):
        assert node.get("pkg") == "tf2_ros" and node.get("type" if ros == 1 else "exec") == "static_transform_publisher"
        out.append((tf2_static_args if ros == 1 else tf2_static_named_args)(node.get("args")))
    return out


def tf_message(path):
    """A tf2_msgs/TFMessage YAML: ``transforms`` of TransformStamped."""
    out = []
    for tr in yaml.safe_load(open(path))["transforms"]:
        q = tr["transform"]["rotation"]
        p = tr["transform"]["translation"]
        out.append((tr["header"]["frame_id"], tr["child_frame_id"], _quat_matrix(q["x"], q["y"], q["z"], q["w"]),
                    np.array([p["x"], p["y"], p["z"]])))
    return out


def urdf_joints(path):
    """URDF fixed joints (xml.etree): parent link, child link, origin rpy about fixed x, y, z."""
    root = ET.parse(path).getroot()
    assert root.tag == "robot"
    links = {link.get("name") for link in root.iter("link")}
    out = []
    for j in root.iter("joint"):
        assert j.get("type") == "fixed"
        parent, child = j.find("parent").get("link"), j.find("child").get("link")
        assert parent in links and child in links
        o = j.find("origin")
        r, p, y = map(float, o.get("rpy").split())
        out.append((parent, child, _rz(y) @ _ry(p) @ _rx(r), np.array(o.get("xyz").split(), float)))
    return out


def _angle_deg(A, B):
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(A @ B.T).as_rotvec())))


# --------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def sim_pair():
    sim = simulate_pair(rng=3, n=8000, R_1_2=Rotation.from_euler("xyz", [30, -50, 110], degrees=True).as_matrix(),
                        scale_1=[1.0, 1.002, 0.998], scale_2=[1.01, 0.99, 1.003])
    return sim, calibrate_pair(sim.omega_1, sim.omega_2)


@pytest.fixture(scope="module")
def sim_array():
    rng = np.random.default_rng(12)
    omega = HumanMotion(1.0, rng=rng)(np.arange(6000) / 100.0)
    R = [np.eye(3)] + [random_rotation(rng) for _ in range(3)]
    omegas = [(omega @ Rk) + rng.normal(0, 1e-3, omega.shape) for Rk in R]
    return calibrate_array(omegas), R


# --------------------------------------------------------------------------------- tf2 / URDF
def test_write_ros_frames_pair_every_file_gives_the_simulated_rotation_in_both_directions(sim_pair, tmp_path):
    sim, cal = sim_pair
    assert _angle_deg(cal.R_1_2, sim.R_1_2) < 0.05
    paths = {p.name: p for p in write_ros_frames(cal, tmp_path / "ros", frames=["imu_ref", "imu_b"])}
    read = {"static_transforms.launch": launch_nodes(paths["static_transforms.launch"], 1),
            "static_transforms.launch.xml": launch_nodes(paths["static_transforms.launch.xml"], 2),
            "static_transforms.yaml": tf_message(paths["static_transforms.yaml"]),
            "imu_joints.urdf": urdf_joints(paths["imu_joints.urdf"])}
    w2 = sim.omega_true_1 @ sim.R_1_2           # gyro 2's true rates (its own frame)
    for name, transforms in read.items():
        (parent, child, R, t), = transforms
        assert (parent, child) == ("imu_ref", "imu_b"), name
        np.testing.assert_array_equal(t, np.zeros(3))
        assert _angle_deg(R, sim.R_1_2) < 0.05, name              # the simulated rotation ...
        assert _angle_deg(R, sim.R_1_2.T) > 10.0, name            # ... not its inverse
        # child -> parent maps gyro 2's rates onto gyro 1's, parent -> child (R^T) the other way
        assert np.abs(w2 @ R.T - sim.omega_true_1).max() < 2e-3 * np.abs(sim.omega_true_1).max(), name
        assert np.abs(sim.omega_true_1 @ R - w2).max() < 2e-3 * np.abs(w2).max(), name
        assert "lookupTransform('imu_ref', 'imu_b')" in paths[name].read_text()   # the direction, stated
        assert "TRANSLATION IS NOT ESTIMATED" in paths[name].read_text()


def test_write_ros_frames_array_one_transform_per_gyro_from_the_reference(sim_array, tmp_path):
    cal, R = sim_array
    paths = {p.name: p for p in write_ros_frames(cal, tmp_path / "ros")}
    for transforms in (launch_nodes(paths["static_transforms.launch"], 1), urdf_joints(paths["imu_joints.urdf"]),
                       tf_message(paths["static_transforms.yaml"])):
        assert [(p, c) for p, c, _, _ in transforms] == [("gyro1", f"gyro{k}") for k in (2, 3, 4)]
        for k, (_, _, Rk, _) in zip((1, 2, 3), transforms):
            assert _angle_deg(Rk, R[k]) < 0.05 and _angle_deg(Rk, cal.R_ref_k[k]) < 1e-6


def test_write_ros_frames_not_rigid_warns_and_bad_frames_refused(sim_pair, tmp_path):
    _, cal = sim_pair
    for p in write_ros_frames(dataclasses.replace(cal, rigid=False), tmp_path / "r"):
        assert "WARNING: NOT RIGID" in p.read_text()[:300], p.name   # at the top, and the file still parses
        assert (yaml.safe_load(p.read_text()) if p.suffix == ".yaml" else ET.parse(p).getroot()) is not None
    with pytest.raises(InputError, match="frames: expected 2 frame names"):
        write_ros_frames(cal, tmp_path / "x", frames=["a"])
    with pytest.raises(InputError, match="frames: expected ROS frame names"):
        check_frames(["a b", "c"], 2)
    with pytest.raises(InputError, match="expected 2 different names"):
        check_frames(["a", "a"], 2)


def test_rotation_forms_quaternion_rpy_and_scipy_rotation_agree(sim_pair):
    _, cal = sim_pair
    x, y, z, w = cal.quaternion_xyzw
    assert w >= 0 and np.allclose(cal.quaternion_wxyz, [w, x, y, z])
    np.testing.assert_allclose(_quat_matrix(x, y, z, w), cal.R_1_2, atol=1e-12)
    r, p, yw = cal.rpy
    np.testing.assert_allclose(_rz(yw) @ _ry(p) @ _rx(r), cal.R_1_2, atol=1e-12)
    np.testing.assert_allclose(cal.rotation.as_matrix(), cal.R_1_2, atol=1e-12)
    np.testing.assert_allclose(cal.rotation.apply([1.0, 2.0, 3.0]), cal.R_1_2 @ [1.0, 2.0, 3.0], atol=1e-12)


def test_pair_calibration_repr_is_one_short_line(sim_pair):
    _, cal = sim_pair
    text = repr(cal)
    assert "\n" not in text and len(text) < 400 and "deg about" in text and "scale_2/scale_1" in text


# --------------------------------------------------------------------------------- --nominal
def test_parse_rotation_every_form_gives_the_same_flip():
    for text in ("180 deg about (1,-1,0)", "3.141592653589793 rad about 1, -1, 0", "[[0,-1,0],[-1,0,0],[0,0,-1]]",
                 "0 -1 0 -1 0 0 0 0 -1", "xyzw 0.70710678, -0.70710678, 0, 0", "wxyz 0, 0.7071068, -0.7071068, 0",
                 "rpy 180, 0, -90 deg"):
        assert _angle_deg(parse_rotation(text), FLIP) < 1e-5, text
    np.testing.assert_array_equal(parse_rotation("identity"), np.eye(3))


def test_parse_rotation_refuses_reflections_and_nonsense():
    with pytest.raises(InputError, match="reflection"):
        parse_rotation("1 0 0 0 1 0 0 0 -1")
    with pytest.raises(InputError, match="orthonormal"):
        parse_rotation("1 0 0 0 2 0 0 0 1")
    with pytest.raises(InputError, match="non-zero axis"):
        parse_rotation("90 deg about (0, 0, 0)")
    with pytest.raises(InputError, match="expected 'identity'"):
        parse_rotation("sideways")
    with pytest.raises(InputError, match=r"one per gyro 2\.\.4 \(3\)"):
        parse_nominals("identity;identity", 4)


def test_deviation_from_nominal_is_the_known_small_rotation_with_its_uncertainty():
    nominal = FLIP
    small = Rotation.from_rotvec(np.deg2rad([0.3, -0.2, 0.5])).as_matrix()
    sim = simulate_pair(rng=5, n=8000, R_1_2=small @ nominal, scale_2=[1.004, 0.997, 1.001])
    cal = dataclasses.replace(calibrate_pair(sim.omega_1, sim.omega_2), nominal_R_1_2=nominal)
    d, C = cal.deviation
    sd = np.sqrt(np.diag(C))
    assert np.all(np.abs(d - np.deg2rad([0.3, -0.2, 0.5])) < 5 * sd + 1e-9)
    np.testing.assert_allclose(sd, cal.rotation_std_rad, rtol=1e-3)   # small deviation: J_l ~ I


# --------------------------------------------------------------------------------- relative scales
def test_parallel_pair_scale_ratios_finite_with_uncertainty_and_in_the_exports(tmp_path):
    # an axis-parallel pair (Lemma 2): no scale factor determined, its three ratios are
    s1, s2 = np.array([1.0, 1.003, 0.996]), np.array([1.012, 0.991, 1.004])
    sim = simulate_pair(rng=8, n=10000, R_1_2=FLIP, scale_1=s1, scale_2=s2)
    cal = calibrate_pair(sim.omega_1, sim.omega_2)
    assert cal.configuration == "all_axes_parallel" and not cal.scale_observable.any()
    truth = s2 / s1[[1, 0, 2]]                      # gyro 2's x is parallel to gyro 1's y, y to x, z to z
    assert np.isfinite(cal.scale_ratio_std).all() and (cal.scale_ratio_std > 0).all()
    assert np.all(np.abs(cal.scale_ratio - truth) < 5 * cal.scale_ratio_std)
    d = json.loads(cal.to_json())
    assert d["scale_ratio"]["value"] == cal.scale_ratio.tolist() and d["scale_ratio"]["axis_of_gyro_1"] == [1, 0, 2]
    assert all(isinstance(v, float) for v in d["scale_ratio"]["std"])   # numbers, never strings
    imus = yaml.safe_load(write_openvins_imu_chain(cal, tmp_path / "ov.yaml").read_text().split("\n", 1)[1])
    np.testing.assert_array_equal(imus["imu0"]["Tw"], np.eye(3))       # the reference is not rescaled
    np.testing.assert_allclose(np.diag(imus["imu1"]["Tw"]), cal.scale_ratio, rtol=1e-15)


# --------------------------------------------------------------------------------- --noise FILE
def test_read_imu_noise_kalibr_allan_variance_ros_and_chain(tmp_path):
    flat = tmp_path / "imu.yaml"   # allan_variance_ros / Kalibr layout: the four figures at the top level
    flat.write_text("#Accelerometer\naccelerometer_noise_density: 0.0011 \naccelerometer_random_walk: 3.1e-05 \n\n"
                    "#Gyroscope\ngyroscope_noise_density: 0.00012 \ngyroscope_random_walk: 1.5e-06 \n\n"
                    "rostopic: '/imu0'\nupdate_rate: 400.0\n")
    got, = read_imu_noise(flat)
    assert got == ImuNoise(1.2e-4, 1.5e-6, 1.1e-3, 3.1e-5)
    sim = simulate_pair(rng=2, n=3000)
    cal = calibrate_pair(sim.omega_1, sim.omega_2)
    chain = write_openvins_imu_chain(cal, tmp_path / "ov.yaml", noise=[got, ImuNoise(2e-4, 2e-6, 2e-3, 2e-5)])
    back = read_imu_noise(chain)
    assert back == (got, ImuNoise(2e-4, 2e-6, 2e-3, 2e-5))
    bad = tmp_path / "bad.yaml"
    bad.write_text("gyroscope_noise_density: 0.001\n")
    with pytest.raises(FormatError, match=r"bad\.yaml: expected the Kalibr noise keys .* missing"):
        read_imu_noise(bad)
    bad.write_text("gyroscope_noise_density: 0\ngyroscope_random_walk: 1\naccelerometer_noise_density: 1\n"
                   "accelerometer_random_walk: 1\n")
    with pytest.raises(FormatError, match="positive finite"):
        read_imu_noise(bad)


def test_cli_calibrate_noise_file_goes_into_every_export_and_ros_folder_written(tmp_path, capsys):
    from test_cli import _write_pair

    p1, p2, R, _ = _write_pair(tmp_path, seed=3)
    noise = tmp_path / "imu.yaml"
    noise.write_text("accelerometer_noise_density: 0.0011\naccelerometer_random_walk: 3.1e-05\n"
                     "gyroscope_noise_density: 0.00012\ngyroscope_random_walk: 1.5e-06\n")
    code = main(["calibrate", str(p1), str(p2), "--unit2", "deg/s", "--noise", str(noise), "--kalibr",
                 str(tmp_path / "k"), "--openvins", str(tmp_path / "ov.yaml"), "--ros", str(tmp_path / "ros"),
                 "--frames", "base_imu,aux_imu", "--nominal", "identity"])
    out = capsys.readouterr().out
    assert code == 0
    for p in (tmp_path / "k" / "imu0.yaml", tmp_path / "k" / "imu1.yaml"):
        assert yaml.safe_load(p.read_text())["gyroscope_noise_density"] == 1.2e-4
    assert read_imu_noise(tmp_path / "ov.yaml") == (ImuNoise(1.2e-4, 1.5e-6, 1.1e-3, 3.1e-5),) * 2
    (parent, child, Rr, _), = urdf_joints(tmp_path / "ros" / "imu_joints.urdf")
    assert (parent, child) == ("base_imu", "aux_imu") and _angle_deg(Rr, R) < 0.1
    assert "quaternion xyzw" in out and "deviation from nominal" in out and "input: gyro 2:" in out


def test_cli_calibrate_bad_nominal_or_frames_is_one_line_error(tmp_path, capsys):
    from test_cli import _write_pair

    p1, p2, _, _ = _write_pair(tmp_path, seed=4)
    assert main(["calibrate", str(p1), str(p2), "--nominal", "sideways"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--nominal: expected 'identity'" in err
    assert main(["calibrate", str(p1), str(p2), "--ros", str(tmp_path / "r"), "--frames", "a"]) == 1
    assert "frames: expected 2 frame names" in capsys.readouterr().err


def test_cli_version_prints_the_library_version(capsys):
    import fusion_gyrocal

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.strip() == f"gyrocal (fusion_gyrocal) {fusion_gyrocal.__version__}"


# --------------------------------------------------------------------------------- JSON
def _assert_same(a, b):
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        elif f.name == "moments":
            assert [m.to_dict() for m in x.pairs] == [m.to_dict() for m in y.pairs]
        elif f.name == "noise_model" and x is not None:
            assert json.dumps(x.to_dict()) == json.dumps(y.to_dict())
        elif isinstance(x, float) and math.isnan(x):
            assert math.isnan(y), f.name
        else:
            assert x == y, f.name


def test_pair_calibration_json_round_trips_every_field_with_provenance_and_nominal(sim_pair):
    from fusion_gyrocal.provenance import InputRecord, Provenance

    _, cal = sim_pair
    prov = Provenance("0.1.0", "gyrocal calibrate a.csv b.csv", (InputRecord(1, "a.csv", "csv", (("unit", "deg/s"),),
                                                                              "deg/s", 200.0, 6000, 12),
                                                                 InputRecord(2, "b.csv", "csv", (), "rad/s", 100.0,
                                                                             3000, 0)),
                      (("method", "ml"),), 5980, 7, "2026-01-01T00:00:00+00:00")
    cal = dataclasses.replace(cal, provenance=prov, nominal_R_1_2=np.eye(3))
    d = json.loads(json.dumps(cal.to_dict(), allow_nan=False))
    back = PairCalibration.from_dict(d)
    _assert_same(cal, back)
    assert back.provenance.n_masked == (12, 0)
    assert d["format_version"] == "1.5" and d["deviation"]["angle_deg"] == pytest.approx(
        np.degrees(np.linalg.norm(cal.rotvec)))
    for key in ("rotation", "scale_ratio", "deviation"):     # derived entries: numbers only, never strings
        assert "Infinity" not in json.dumps(d[key]) and "NaN" not in json.dumps(d[key])


def test_pair_calibration_reads_format_1_3(sim_pair):
    _, cal = sim_pair
    d = cal.to_dict()
    for key in ("rotation", "scale_ratio", "deviation", "scale_ratio_std", "nominal_R_1_2", "provenance"):
        d.pop(key)
    d["format_version"] = "1.3"
    back = PairCalibration.from_dict(d)
    np.testing.assert_array_equal(back.R_1_2, cal.R_1_2)
    np.testing.assert_allclose(back.scale_ratio_std, cal.scale_ratio_std, rtol=1e-6)   # general: from the covariance


def test_array_calibration_json_round_trips_every_field(sim_array):
    from fusion_gyrocal.core.array_result import ArrayCalibration

    cal, _ = sim_array
    cal = dataclasses.replace(cal, nominal_R_ref_k=np.stack([np.eye(3)] * 4))
    d = json.loads(json.dumps(cal.to_dict()))
    back = ArrayCalibration.from_dict(d)
    _assert_same(cal, back)
    assert len(d["rotations"]) == 4 and d["rotations"][1]["gyro"] == 2
    assert d["relative_scale"]["value"][0] == [1.0, 1.0, 1.0] and len(d["deviation"]) == 4
    assert "view of the joint calibration of 4 gyros (gyro 2 as gyro 1, gyro 3 as gyro 2)" in cal.pair(1, 2).notes
    assert "\n" not in repr(cal) and "gyro 4:" in repr(cal)


def test_kalibr_configs_scale_comment_relative_to_imu0(sim_pair, tmp_path):
    _, cal = sim_pair
    _, p1 = write_kalibr_imu_configs(cal, tmp_path / "k")
    text = p1.read_text()
    assert cal.configuration == "general"
    g = np.exp(np.mean(np.log(cal.scale_1)))   # a general mounting: one group, divided by imu0's geometric mean
    assert f"x {cal.scale_2[0] / g:.6f}" in text
