"""The hostile-input matrix of issue 22: every class of bad input through the API, the readers and the CLI.

Each case says what a good answer is (a refusal naming what was expected, or a correct result) and is
classified as one of: ``clean`` (a GyroCalError / exit 1-3 with a message saying what was expected, or for a failed write "could not
write" and the cause),
``unclear`` (a GyroCalError without that, or a refusal where a correct answer was possible), ``correct``,
``silent wrong`` (a result, exit 0, that is wrong or destroys something), ``foreign`` (another exception, or
exit 70) and ``crash`` (out of memory under the run's 3 GiB address-space limit, a recursion overflow).

Run from the checkout to measure (``python benchmarks/hostile_matrix.py``); ``PYTHONPATH=<other checkout>``
measures another one (e.g. main before the fixes). Prints one line per case and the counts.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import resource
import stat
import sys
import tempfile
import threading
import warnings
import zipfile
from collections import Counter
from pathlib import Path

import numpy as np

LIMIT = 3 << 30
resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))
sys.setrecursionlimit(3000)
warnings.simplefilter("ignore")

import fusion_gyrocal  # noqa: E402
from fusion_gyrocal import calibrate_pair  # noqa: E402
from fusion_gyrocal.errors import GyroCalError  # noqa: E402
from fusion_gyrocal.evaluate.sim import simulate_pair, simulate_streams  # noqa: E402

DEG = np.pi / 180
TMP = Path(tempfile.mkdtemp(prefix="hostile_"))
CASES = []


def case(cls: str, name: str, works: bool = False):
    """Register a case; ``works``: a correct result is possible, so a refusal is ``unclear``."""
    def deco(f):
        CASES.append((cls, name, f, works))
        return f
    return deco


class Wrong(Exception):
    """A result came back (exit 0) but it is wrong."""


def cli(*argv) -> tuple[int, str, str]:
    from fusion_gyrocal.cli.app import main
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 2
    return code, out.getvalue(), err.getvalue()


def cli_expect_refusal(*argv):
    code, out, err = cli(*argv)
    if code == 70:
        raise RuntimeError(f"exit 70: {err.strip()[:100]}")
    if code == 0:
        raise Wrong("exit 0")
    if "expected" not in err:
        raise GyroCalError(f"(unclear) exit {code}: {err.strip()[:100]}")
    return "clean"


def pair_csv(folder: Path, unit_scale=1.0, rms=1.0, label="", n=3000, seed=1, encoding="utf-8"):
    """Two CSV files of a simulated pair (rates multiplied by ``unit_scale``, header label ``label``)."""
    sim = simulate_pair(n=n, rms=rms, rng=seed)
    paths = []
    for k, w in ((1, sim.omega_1), (2, sim.omega_2)):
        p = folder / f"g{k}.csv"
        head = ",".join(["t"] + [f"gyro_{a}{label}" for a in "xyz"])
        rows = "\n".join(f"{t:.6f},{x:.9g},{y:.9g},{z:.9g}" for t, (x, y, z) in zip(sim.t, w * unit_scale))
        p.write_bytes((head + "\n" + rows + "\n").encode(encoding))
        paths.append(p)
    return sim, paths


def check_bias(cal, sim, tol=0.1):
    """The combined bias (rad/s) within ``tol`` relative of the truth (a unit error is 57x or 1000x)."""
    if not np.allclose(cal.bias, sim.bias, atol=tol * np.abs(sim.bias).max() + 5e-3):
        raise Wrong(f"bias {np.round(cal.bias, 4)} against {np.round(sim.bias, 4)}")
    return "correct"


def new_dir(name):
    d = TMP / name
    d.mkdir()
    return d


# ----------------------------------------------------------------------------- 1: output paths
def _calibrated_pair(d):
    sim, (a, b) = pair_csv(d, label=" [rad/s]")
    return a, b


@case("1 output path", "-o a character device (a /dev/null node made with mknod)", works=True)
def _():
    d = new_dir("dev")
    a, b = _calibrated_pair(d)
    node = d / "null"
    try:
        os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except OSError:
        return "skip"
    code, out, err = cli("calibrate", a, b, "-o", node)
    if not stat.S_ISCHR(os.stat(node).st_mode):
        raise Wrong(f"exit {code}: the device node was replaced by a regular file")
    if code:
        raise GyroCalError(err)
    return "correct"


@case("1 output path", "-o a FIFO with a reader", works=True)
def _():
    d = new_dir("fifo")
    a, b = _calibrated_pair(d)
    fifo = d / "pipe"
    os.mkfifo(fifo)
    got = []
    t = threading.Thread(target=lambda: got.append(open(fifo, "rb").read()), daemon=True)
    t.start()
    code, out, err = cli("calibrate", a, b, "-o", fifo)
    if not stat.S_ISFIFO(os.stat(fifo).st_mode):
        with contextlib.suppress(OSError):
            open(fifo, "wb").close()   # release the reader if the fifo survives elsewhere
        raise Wrong(f"exit {code}: the FIFO was replaced by a regular file")
    t.join(10)
    if code or not got or b"R_1_2" not in got[0]:
        raise Wrong(f"exit {code}: nothing came through the FIFO")
    return "correct"


@case("1 output path", "-o - (standard output)", works=True)
def _():
    d = new_dir("stdout")
    a, b = _calibrated_pair(d)
    cwd = os.getcwd()
    os.chdir(d)
    try:
        code, out, err = cli("calibrate", a, b, "-o", "-")
    finally:
        os.chdir(cwd)
    if (d / "-").exists():
        raise Wrong("a file named '-' was written")
    if code:
        raise GyroCalError(err)
    try:
        json.loads(out[out.index("{"):out.rindex("}") + 1])
    except ValueError:
        raise Wrong("no JSON on standard output") from None
    if not out.lstrip().startswith("{"):
        raise Wrong("standard output holds the table too, not the JSON alone")
    return "correct"


@case("1 output path", "-o a symbolic link to a file", works=True)
def _():
    d = new_dir("link")
    a, b = _calibrated_pair(d)
    target = d / "real.json"
    target.write_text("{}")
    link = d / "cal.json"
    link.symlink_to(target)
    code, out, err = cli("calibrate", a, b, "-o", link)
    if code:
        raise GyroCalError(err)
    if not link.is_symlink() or "R_1_2" not in target.read_text():
        raise Wrong("the link was replaced by a file (the file it pointed at is unchanged)")
    return "correct"


@case("1 output path", "-o a folder")
def _():
    d = new_dir("outdir")
    a, b = _calibrated_pair(d)
    return cli_expect_refusal("calibrate", a, b, "-o", d)


# ----------------------------------------------------------------------------- 2: unit labels, encodings
@case("2 unit labels", "[mdps] header", works=True)
def _():
    sim, (a, b) = pair_csv(new_dir("mdps"), 1000 / DEG, label=" [mdps]")
    return check_bias(calibrate_pair(*_read2(a, b)), sim)


@case("2 unit labels", "[mrad/s] header", works=True)
def _():
    sim, (a, b) = pair_csv(new_dir("mrad"), 1000.0, label=" [mrad/s]", rms=0.05)
    return check_bias(calibrate_pair(*_read2(a, b)), sim)


@case("2 unit labels", "cp1252 header [°/s]", works=True)
def _():
    sim, (a, b) = pair_csv(new_dir("cp1252"), 1 / DEG, label=" [°/s]", encoding="cp1252", rms=0.05)
    return check_bias(calibrate_pair(*_read2(a, b)), sim)


@case("2 unit labels", "latin-1 header (°/s)", works=True)
def _():
    sim, (a, b) = pair_csv(new_dir("latin1"), 1 / DEG, label=" (°/s)", encoding="latin-1", rms=0.05)
    return check_bias(calibrate_pair(*_read2(a, b)), sim)


@case("2 unit labels", "UTF-8 header [º/s] (masculine ordinal)", works=True)
def _():
    sim, (a, b) = pair_csv(new_dir("ordinal"), 1 / DEG, label=" [º/s]", rms=0.05)
    return check_bias(calibrate_pair(*_read2(a, b)), sim)


@case("2 unit labels", "[rpm] header (a unit the reader does not take)")
def _():
    sim, (a, b) = pair_csv(new_dir("rpm"), 60 / (2 * np.pi), label=" [rpm]")
    cal = calibrate_pair(*_read2(a, b))
    return check_bias(cal, sim)


@case("2 unit labels", "gyrocal calibrate on [mdps] files", works=True)
def _():
    sim, (a, b) = pair_csv(new_dir("mdps_cli"), 1000 / DEG, label=" [mdps]")
    out = a.parent / "cal.json"
    code, _, err = cli("calibrate", a, b, "-o", out)
    if code:
        raise GyroCalError(err)
    return check_bias(fusion_gyrocal.io.writers.read_json(out), sim)


def _read2(a, b, **kw):
    from fusion_gyrocal.io import read_imu
    s1, s2 = read_imu(a, **kw), read_imu(b, **kw)
    return s1.masked_omega, s2.masked_omega


# ----------------------------------------------------------------------------- 3: deg/s under 100 deg/s
for _rms in (0.03, 0.2, 0.5):
    @case("3 deg/s read as rad/s", f"both gyros in deg/s, motion rms {_rms} rad/s (array API)")
    def _(rms=_rms):
        sim = simulate_pair(n=6000, rms=rms, rng=2)
        cal = calibrate_pair(sim.omega_1 / DEG, sim.omega_2 / DEG)
        check_bias(cal, sim)
        return "correct"


@case("3 deg/s read as rad/s", "both CSVs in deg/s without a unit in the header (CLI)")
def _():
    sim, (a, b) = pair_csv(new_dir("degcli"), 1 / DEG, rms=0.2)
    out = a.parent / "cal.json"
    code, _, err = cli("calibrate", a, b, "-o", out)
    if code == 70:
        raise RuntimeError(err)
    if code:
        if "deg/s" in err and "expected" in err:
            return "clean"
        raise GyroCalError(err)
    return check_bias(fusion_gyrocal.io.writers.read_json(out), sim)


@case("3 deg/s read as rad/s", "slow motion in rad/s (must still calibrate)", works=True)
def _():
    sim = simulate_pair(n=6000, rms=0.05, rng=3)
    return check_bias(calibrate_pair(sim.omega_1, sim.omega_2), sim)


# ----------------------------------------------------------------------------- 6: tiny inputs
def _rotation_z(cal, sim):
    from scipy.spatial.transform import Rotation
    err = Rotation.from_matrix(cal.R_1_2 @ sim.R_1_2.T).as_rotvec()
    P = cal.covariance[:3, :3]
    return float(err @ np.linalg.pinv(P) @ err)


for _n in (0, 3, 4, 5, 8):
    @case("6 too few samples", f"{_n} noise-free samples")
    def _(n=_n):
        sim = simulate_pair(n=max(n, 1), noise_std=0.0, rng=4)
        cal = calibrate_pair(sim.omega_1[:n], sim.omega_2[:n])
        if _rotation_z(cal, sim) > 14.16:     # chi2(3) at 0.9973 (3 sigma)
            raise Wrong("rotation outside its 3-sigma region")
        return "correct"


# ----------------------------------------------------------------------------- 4, 5: honest covariance
def _mean_z2(pairs) -> float:
    from fusion_gyrocal.lie import log
    z2 = []
    for cal, R in pairs:
        d = log(R @ cal.R_1_2.T)
        z2.append(float(d @ np.linalg.solve(cal.covariance[:3, :3], d)))
    return float(np.mean(z2))


@case("4 near-parallel axes", "linear_map='rigid', 4 deg tilt, scales 8 % apart (6 runs)", works=True)
def _():
    from fusion_gyrocal.lie import exp

    def run(seed):
        rng = np.random.default_rng(100 + seed)
        axis = rng.standard_normal(3)
        R = exp(np.deg2rad(4.0) * axis / np.linalg.norm(axis))
        sim = simulate_pair(n=40_000, R_1_2=R, scale_1=1 + 0.08 * rng.standard_normal(3),
                            scale_2=1 + 0.08 * rng.standard_normal(3), bias_walk_std=0.0, rng=seed)
        return calibrate_pair(sim.omega_1, sim.omega_2, linear_map="rigid"), R
    z2 = _mean_z2(run(seed) for seed in range(6))
    if z2 > 6.0:
        raise Wrong(f"mean z^2 {z2:.3g} (3 for an honest covariance)")
    return "correct"


for _rates in ((5000.0, 50.0), (50.0, 5000.0)):
    @case("5 two rates", f"gyro 1 at {_rates[0]:g} Hz, gyro 2 at {_rates[1]:g} Hz (10 runs)", works=True)
    def _(rates=_rates):
        z2 = _mean_z2((calibrate_pair(s.omega_1, s.omega_2, t_1=s.t_1, t_2=s.t_2), s.R_1_2)
                      for s in (simulate_streams(seed, rate_1=rates[0], rate_2=rates[1], duration=8.0)
                                for seed in range(10)))
        if z2 > 6.0:
            raise Wrong(f"mean z^2 {z2:.3g} (3 for an honest covariance)")
        return "correct"


# ----------------------------------------------------------------------------- 8: memory by option or file
def _streams():
    s = simulate_streams(5, duration=20)
    return s


@case("8 memory", "max_offset_s=1e7", works=True)
def _():
    s = _streams()
    cal = calibrate_pair(s.omega_1, s.omega_2, t_1=s.t_1, t_2=s.t_2, max_offset_s=1e7)
    if abs(cal.time_offset_s - 0.1) > 0.01:
        raise Wrong(f"offset {cal.time_offset_s}")
    return "correct"


@case("8 memory", "rate_hz=1e6 on a 100/200 Hz pair")
def _():
    s = _streams()
    calibrate_pair(s.omega_1, s.omega_2, t_1=s.t_1, t_2=s.t_2, rate_hz=1e6)
    raise Wrong("accepted")


@case("8 memory", "bias_window=1e12 samples", works=True)
def _():
    sim = simulate_pair(n=3000, rng=6)
    return check_bias(calibrate_pair(sim.omega_1, sim.omega_2, bias_window=10 ** 12), sim)


@case("8 memory", "npz whose array header claims 8 GiB (a few hundred bytes)")
def _():
    p = TMP / "claim.npz"
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": (1 << 30,)})
    raw = buf.getvalue() + bytes(32)
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("t.npy", raw)
        z.writestr("omega.npy", raw)
    fusion_gyrocal.io.read_npz(p)
    raise Wrong("read")


@case("8 memory", "npz of zeros compressed about 1000x (3 GiB of arrays in about 3 MB)")
def _():
    p = TMP / "bomb.npz"
    with zipfile.ZipFile(p, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for key, shape in (("t", (1 << 27,)), ("omega", ((3 << 27) // 3 * 2, 3))):   # 1 GiB and 2 GiB of float64
            with z.open(f"{key}.npy", "w", force_zip64=True) as f:
                np.lib.format.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": shape})
                left, zero = int(np.prod(shape)) * 8, bytes(1 << 22)
                while left:
                    f.write(zero[:min(left, len(zero))])
                    left -= min(left, len(zero))
    fusion_gyrocal.io.read_npz(p)
    raise Wrong("read")


@case("8 memory", "CSV whose one line is 50 MB")
def _():
    p = TMP / "longline.csv"
    with open(p, "w") as f:
        f.write("t,gyro_x,gyro_y,gyro_z\n")
        f.write(",".join(["1.0"] * 12_500_000) + "\n")
    fusion_gyrocal.io.read_imu(p)
    raise Wrong("read")


# ----------------------------------------------------------------------------- 9: rostopic echo -p
def _rostopic(folder: Path, seed=7):
    sim = simulate_pair(n=3000, rng=seed)
    stamp0 = 1_700_000_000_000_000_000
    paths = []
    for k, w in ((1, sim.omega_1), (2, sim.omega_2)):
        p = folder / f"imu{k}.csv"
        head = ("%time,field.header.seq,field.header.stamp,field.header.frame_id,field.angular_velocity.x,"
                "field.angular_velocity.y,field.angular_velocity.z")
        rows = [f"{stamp0 + int(t * 1e9) + 150000},{i},{stamp0 + int(t * 1e9)},imu_link,{float(x)!r},{float(y)!r},"
                f"{float(z)!r}"
                for i, (t, (x, y, z)) in enumerate(zip(sim.t, w))]
        p.write_text(head + "\n" + "\n".join(rows) + "\n")
        paths.append(p)
    return sim, paths


@case("9 rostopic", "rostopic echo -p CSV, defaults", works=True)
def _():
    sim, (a, b) = _rostopic(new_dir("ros1"))
    return check_bias(calibrate_pair(*_read2(a, b)), sim)


@case("9 rostopic", "rostopic echo -p CSV, time_unit='ns'", works=True)
def _():
    sim, (a, b) = _rostopic(new_dir("ros2"))
    return check_bias(calibrate_pair(*_read2(a, b, time_unit="ns")), sim)


# ----------------------------------------------------------------------------- 10: foreign exceptions
@case("10 foreign", "unreadable file (open raises PermissionError)")
def _():
    import builtins
    sim, (a, b) = pair_csv(new_dir("perm"))
    real = builtins.open

    def deny(f, *args, **kw):
        if str(f) == str(a):
            raise PermissionError(13, "Permission denied", str(f))
        return real(f, *args, **kw)
    builtins.open = deny
    real_access = os.access
    os.access = lambda p, m: False if str(p) == str(a) else real_access(p, m)
    try:
        fusion_gyrocal.io.read_imu(a)
    finally:
        builtins.open = real
        os.access = real_access
    raise Wrong("read")


@case("10 foreign", "Moments.from_samples(chunk_size=0)")
def _():
    from fusion_gyrocal.core.moments import Moments
    sim = simulate_pair(n=100, rng=8)
    Moments.from_samples(sim.omega_1, sim.omega_2, chunk_size=0)
    raise Wrong("accepted")


@case("10 foreign", "calibrate_array(reference=1.5)")
def _():
    sim, other = simulate_pair(n=2000, rng=9), simulate_pair(n=2000, rng=10)
    fusion_gyrocal.calibrate_array([sim.omega_1, sim.omega_2, other.omega_2], reference=1.5)
    raise Wrong("accepted")


@case("10 foreign", "calibrate_array given the same stream for two gyros")
def _():
    sim = simulate_pair(n=2000, rng=9)
    fusion_gyrocal.calibrate_array([sim.omega_1, sim.omega_2, sim.omega_1])
    raise Wrong("accepted")


@case("10 foreign", "calibrate_pair given one stream twice")
def _():
    sim = simulate_pair(n=2000, rng=9)
    calibrate_pair(sim.omega_2, sim.omega_2.copy())
    raise Wrong("accepted")


@case("10 foreign", "read_json of deeply nested JSON")
def _():
    p = TMP / "deep.json"
    p.write_text("[" * 100000 + "]" * 100000)
    fusion_gyrocal.io.writers.read_json(p)
    raise Wrong("read")


@case("10 foreign", "read_json of {'R_1_2': [[[[...]]]]} nested in an object")
def _():
    p = TMP / "deep2.json"
    p.write_text('{"format_version": 1, "R_1_2": ' + "[" * 50000 + "]" * 50000 + "}")
    fusion_gyrocal.io.writers.read_json(p)
    raise Wrong("read")


@case("10 foreign", "npz holding strings")
def _():
    p = TMP / "strings.npz"
    np.savez(p, t=np.array(["a", "b", "c"]), omega=np.array([["x"] * 3] * 3))
    fusion_gyrocal.io.read_npz(p)
    raise Wrong("read")


@case("10 foreign", "npz with an MIMU sensitivity of two values")
def _():
    p = TMP / "lsb.npz"
    np.savez(p, t_s=np.arange(10) / 100.0, gyro_counts=np.zeros((10, 2, 3), np.int16),
             gyro_lsb_per_dps=np.array([16.4, 16.4]))
    fusion_gyrocal.io.read_npz(p)
    raise Wrong("read")


@case("10 foreign", "gyrocal calibrate --rate 1e300")
def _():
    d = new_dir("rate")
    s = _streams()
    paths = []
    for k, (t, w) in enumerate(((s.t_1, s.omega_1), (s.t_2, s.omega_2))):
        p = d / f"g{k}.csv"
        np.savetxt(p, np.c_[t, w], delimiter=",", header="t,gyro_x,gyro_y,gyro_z", comments="")
        paths.append(p)
    return cli_expect_refusal("calibrate", *paths, "--rate", "1e300")


@case("10 foreign", "gyrocal compare --seed -1")
def _():
    return cli_expect_refusal("compare", "--seed", "-1", "--runs", "1", "--estimators", "direct", "--workers", "1",
                              "--no-progress")


@case("10 foreign", "fleet Parquet device with string columns")
def _():
    import pandas as pd
    from fusion_gyrocal.distributed.fleet import calibrate_device
    p = TMP / "strdev.parquet"
    n = 200
    pd.DataFrame({"t": np.arange(n) / 100.0, **{c: ["x"] * n for c in ("w1x", "w1y", "w1z", "w2x", "w2y", "w2z")}}
                 ).to_parquet(p)
    calibrate_device(p)
    raise Wrong("accepted")


@case("10 foreign", "a ROS2 bag written to a full disk (sqlite3 raises OperationalError)")
def _():
    import sqlite3

    from rosbags.rosbag2 import storage_sqlite3

    from fusion_gyrocal.io.bags import write_imu_bag
    sim = simulate_pair(n=200, rng=10)
    s1 = fusion_gyrocal.io.ImuStream(sim.t, sim.omega_1, name="a")
    real = storage_sqlite3.Sqlite3Writer.write

    def full(self, *args, **kw):
        raise sqlite3.OperationalError("database or disk is full")
    storage_sqlite3.Sqlite3Writer.write = full
    try:
        write_imu_bag(TMP / "full_bag", {"/imu0": s1}, version=2)
    finally:
        storage_sqlite3.Sqlite3Writer.write = real
    raise Wrong("written")


# ----------------------------------------------------------------------------- 11: smaller silent ones
@case("11 silent", "read_json with R_1_2 = 2 I")
def _():
    sim = simulate_pair(n=3000, rng=11)
    cal = calibrate_pair(sim.omega_1, sim.omega_2)
    p = TMP / "twoI.json"
    fusion_gyrocal.io.writers.write_json(cal, p)
    d = json.loads(p.read_text())
    d["R_1_2"] = (2 * np.eye(3)).tolist()
    p.write_text(json.dumps(d))
    fusion_gyrocal.io.writers.read_json(p)
    raise Wrong("read")


@case("11 silent", "compare rotation_only with one-axis motion")
def _():
    from fusion_gyrocal.evaluate.compare import compare
    rng = np.random.default_rng(12)
    n = 6000
    w = np.zeros((n, 3))
    w[:, 2] = np.sin(np.arange(n) / 20.0)
    R = simulate_pair(n=10, rng=12).R_1_2
    w1 = w + rng.normal(0, 1e-3, w.shape)
    w2 = w @ R + rng.normal(0, 1e-3, w.shape)
    c = compare((w1, w2), estimators=["rotation_only"], progress=False)
    row = c.rows[0]
    if row.failures == 0 and not row.note:
        raise Wrong("rotation_only printed without a flag")
    return "clean"


@case("11 silent", "noise_std=True")
def _():
    sim = simulate_pair(n=3000, rng=13)
    calibrate_pair(sim.omega_1, sim.omega_2, noise_std=True)
    raise Wrong("accepted")


# ----------------------------------------------------------------------------- 13: kill safety
@case("13 kill safety", "killed between the renames of one run's outputs; then the next run", works=True)
def _():
    d = new_dir("kill")
    a, b = _calibrated_pair(d)
    out, kal = d / "cal.json", d / "kalibr"
    code, _, err = cli("calibrate", a, b, "-o", out, "--kalibr", kal)
    if code:
        raise GyroCalError(err)
    old = {p: p.read_bytes() for p in [out, *kal.iterdir()]}
    sim, (a2, b2) = pair_csv(d, label=" [rad/s]", seed=99)
    pid = os.fork()
    if pid == 0:   # the child: dies on its second rename
        calls = []
        real = os.replace

        def dying(src, dst, *args, **kw):
            calls.append(dst)
            if len(calls) == 2:
                os._exit(9)
            return real(src, dst, *args, **kw)
        os.replace = dying
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            cli("calibrate", a2, b2, "-o", out, "--kalibr", kal)
        os._exit(0)
    os.waitpid(pid, 0)
    # the next run (any write into the folders) finishes or undoes the killed one
    from fusion_gyrocal.io.writers import atomic_write
    atomic_write(d / "other.txt", "x")
    atomic_write(kal / "other.txt", "x")
    now = {p: p.read_bytes() for p in old}
    changed = [p.name for p in old if now[p] != old[p]]
    temps = [p.name for p in [*d.iterdir(), *kal.iterdir()] if p.name.startswith(".")]
    if temps:
        raise Wrong(f"temp files left: {temps}")
    if changed and len(changed) != len(old):
        raise Wrong(f"a mix of new ({changed}) and old files")
    return "correct"


# ----------------------------------------------------------------------------- run
def classify(f, works: bool) -> tuple[str, str]:
    try:
        verdict = f()
        return verdict, ""
    except Wrong as exc:
        return "silent wrong", str(exc)
    except GyroCalError as exc:
        msg = " ".join(str(exc).split())
        clear = ("expected" in msg or "could not write" in msg) and not msg.startswith("(unclear)") and not works
        return ("clean" if clear else "unclear"), msg
    except (MemoryError, RecursionError) as exc:
        return "crash", f"{type(exc).__name__}: {exc}"[:100]
    except Exception as exc:   # noqa: BLE001 - what the matrix measures
        return "foreign", f"{type(exc).__name__}: {exc}"[:100]


def main() -> None:
    print(f"checkout: {Path(fusion_gyrocal.__file__).parents[1]}")
    counts = Counter()
    for cls, name, f, works in CASES:
        verdict, why = classify(f, works)
        if verdict == "skip":
            continue
        counts[verdict] += 1
        print(f"{verdict:>12} | {cls:<24} | {name} {('| ' + why[:110]) if why else ''}")
    order = ("clean", "unclear", "correct", "silent wrong", "foreign", "crash")
    print(f"{sum(counts.values())} cases: " + ", ".join(f"{k} {counts[k]}" for k in order))


if __name__ == "__main__":
    main()
