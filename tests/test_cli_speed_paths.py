"""Correctness of what keeps ``gyrocal calibrate`` and fleets fast: the numpy solvers that replace scipy on the
calibrate path (same results), the calibrate path's imports, and the fleet's batches of devices."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from fusion_gyrocal.evaluate.sim import simulate_pair
from fusion_gyrocal.numerics import minimize_bounded, nnls, solve_tridiagonal

ROOT = Path(__file__).resolve().parents[1]


def test_minimize_bounded_same_iterates_as_scipy_bounded_brent():
    optimize = pytest.importorskip("scipy.optimize")
    rng = np.random.default_rng(0)
    for _ in range(100):
        c = rng.normal(size=4)
        lo, hi = -rng.uniform(0.1, 3.0), rng.uniform(0.1, 3.0)
        tol = 10 ** rng.uniform(-12, -3)

        def f(x):
            return c[0] * np.sin(3 * c[1] * x) + abs(c[3]) * (x - c[2]) ** 2 + 0.01 * x ** 4

        ref = optimize.minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": tol})
        x, fx = minimize_bounded(f, lo, hi, xatol=tol)
        assert (x, fx) == (ref.x, ref.fun)


def test_minimize_bounded_finds_interior_and_edge_minima():
    x, fx = minimize_bounded(lambda t: (t - 0.3) ** 2, -1.0, 2.0, xatol=1e-10)
    assert abs(x - 0.3) < 1e-8 and fx < 1e-15
    x, _ = minimize_bounded(lambda t: t, 0.0, 1.0, xatol=1e-9)    # decreasing towards the left end
    assert 0.0 <= x < 1e-8


@pytest.mark.parametrize("m", [1, 2, 3, 4, 5, 8, 33, 1000])
def test_solve_tridiagonal_matches_dense_solve(m):
    rng = np.random.default_rng(m)
    sub, sup = rng.uniform(-1, 1, m), rng.uniform(-1, 1, m)
    diag = np.abs(sub) + np.abs(sup) + rng.uniform(0.1, 2.0, m)     # diagonally dominant
    A = np.diag(diag) + np.diag(sub[1:], -1) + np.diag(sup[:-1], 1)
    for rhs in (rng.normal(size=m), rng.normal(size=(m, 3))):
        x = solve_tridiagonal(sub, diag, sup, rhs)
        assert x.shape == rhs.shape
        np.testing.assert_allclose(x, np.linalg.solve(A, rhs), rtol=0, atol=1e-12)


def test_nnls_same_solution_as_scipy_and_kkt():
    optimize = pytest.importorskip("scipy.optimize")
    rng = np.random.default_rng(5)
    for _ in range(200):
        m = int(rng.integers(3, 20))
        n = int(rng.integers(1, min(m, 6) + 1))
        A = rng.normal(size=(m, n)) * 10 ** rng.uniform(-8, 8)
        b = rng.normal(size=m) * 10 ** rng.uniform(-12, 8)
        x, res = nnls(A, b)
        ref = optimize.nnls(A, b)[0]
        assert (x >= 0).all()
        np.testing.assert_allclose(x, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max(initial=0.0))
        assert res == pytest.approx(np.linalg.norm(A @ x - b), rel=1e-12)
        grad = A.T @ (b - A @ x)        # KKT: no free direction improves; zero gradient where x > 0
        scale = np.abs(A).sum(axis=0).max() * np.abs(b).max()
        assert (grad <= 1e-9 * scale).all() and (np.abs(grad[x > 0]) <= 1e-9 * scale).all()


def test_spline_slopes_match_cubic_spline_on_masked_runs():
    interpolate = pytest.importorskip("scipy.interpolate")
    from fusion_gyrocal.pipeline.resample import _RunSplines, _runs

    rng = np.random.default_rng(3)
    for _ in range(20):
        n = int(rng.integers(5, 3000))
        t = np.cumsum(rng.uniform(0.004, 0.006, n))
        y = rng.normal(size=(n, 3))
        ok = rng.uniform(size=n) > rng.choice([0.0, 0.05, 0.3])
        spl = _RunSplines(t, y, ok, 0.0125)
        for run in _runs(t, ok, 0.0125):
            q = np.linspace(t[run[0]], t[run[-1]], 50)
            got, inside = spl(q)
            assert inside.all()
            if run.size >= 4:
                ref = interpolate.CubicSpline(t[run], y[run])(q)
            else:       # 2 samples: the line, 3: the parabola through them
                ref = np.stack([np.polyval(np.polyfit(t[run], y[run, k], run.size - 1), q) for k in range(3)], -1)
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)


def test_rotation_forms_match_scipy_rotation():
    transform = pytest.importorskip("scipy.spatial.transform")
    import warnings

    from fusion_gyrocal.core.model import rotation_forms
    from fusion_gyrocal.lie import log

    Rotation = transform.Rotation
    rots = list(Rotation.random(500, random_state=2)) + [
        Rotation.from_euler("xyz", [0.3, np.pi / 2, 0.2]), Rotation.from_euler("xyz", [0.3, -np.pi / 2, 0.2]),
        Rotation.identity(), Rotation.from_rotvec([np.pi, 0, 0]), Rotation.from_rotvec([0, 0, np.pi - 1e-9])]
    for r in rots:
        R = r.as_matrix()
        f = rotation_forms(R)
        q = r.as_quat()
        q = -q if q[3] < 0 else q
        np.testing.assert_allclose(f["quaternion_xyzw"], q, atol=1e-14)
        np.testing.assert_allclose(f["matrix"], R, atol=1e-14)
        # the roll, pitch and yaw give the matrix back (R = Rz Ry Rx); away from gimbal lock, scipy's triple
        np.testing.assert_allclose(Rotation.from_euler("xyz", f["rpy"]).as_matrix(), R, atol=1e-13)
        if abs(abs(f["rpy"][1]) - np.pi / 2) > 1e-3:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                np.testing.assert_allclose(f["rpy"], r.as_euler("xyz"), atol=1e-12)
        rv = r.as_rotvec()
        got = log(R)
        assert min(np.abs(got - rv).max(), np.abs(got + rv).max() if np.linalg.norm(rv) > 3.14 else 1) < 1e-12


def test_cli_calibrate_path_imports_no_scipy(tmp_path):
    sim = simulate_pair(rng=7, n=6000)
    t = np.arange(sim.omega_1.shape[0]) / 100.0
    for name, w in (("a.csv", sim.omega_1), ("b.csv", sim.omega_2)):
        np.savetxt(tmp_path / name, np.column_stack([t, w]), delimiter=",", header="t,wx,wy,wz", comments="")
    code = textwrap.dedent(f"""
        import sys
        from fusion_gyrocal.cli import main
        code = main(["calibrate", {str(tmp_path / 'a.csv')!r}, {str(tmp_path / 'b.csv')!r}, "--output",
                     {str(tmp_path / 'cal.json')!r}])
        print(code, sorted({{m.split('.')[0] for m in sys.modules}} & {{"scipy", "pandas"}}))
    """)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (str(ROOT), os.environ.get("PYTHONPATH"))))}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path,
                         check=True).stdout.strip().splitlines()[-1]
    assert out == "0 []"
    cal = json.loads((tmp_path / "cal.json").read_text())
    assert np.isfinite(cal["time_offset_s"]) and abs(cal["time_offset_s"]) < 0.01


def test_fleet_batches_cover_every_device_once_round_robin():
    from fusion_gyrocal.distributed.fleet import TASKS_PER_THREAD, _batches

    for n, threads in ((1, 2), (5, 2), (24, 2), (24, 1), (100, 3), (3, 0)):
        batches = _batches(n, threads)
        assert sorted(i for b in batches for i in b) == list(range(n))
        assert len(batches) == min(n, TASKS_PER_THREAD * max(threads, 1))
        assert max(map(len, batches)) - min(map(len, batches)) <= 1
        assert all(b == sorted(b) and np.all(np.diff(b) == len(batches)) for b in batches if len(b) > 1)


def test_device_rows_in_order_with_errors_recorded(tmp_path):
    pytest.importorskip("pyarrow")
    from fusion_gyrocal.distributed.fleet import COLUMNS, device_row, device_rows

    import pyarrow as pa
    import pyarrow.parquet as pq

    sim = simulate_pair(rng=8, n=3000)
    data = {"t": np.arange(3000) / 100.0}
    for g, w in (("1", sim.omega_1), ("2", sim.omega_2)):
        for a, ax in enumerate("xyz"):
            data[f"w{g}{ax}"] = w[:, a]
    pq.write_table(pa.table({c: data[c] for c in COLUMNS}), tmp_path / "good.parquet")
    paths = [tmp_path / "good.parquet", tmp_path / "missing.parquet"]
    rows = device_rows(paths)
    assert [r["device"] for r in rows] == ["good", "missing"]
    assert rows[0]["ok"] and not rows[1]["ok"] and rows[1]["error_type"] == "FormatError"
    assert rows[0]["calibration_json"] == device_row(paths[0])["calibration_json"]
