"""The core works without the optional packages; a feature that needs one names the extra to install."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from fusion_gyrocal.extras import EXTRAS, MissingDependencyError, require

ROOT = Path(__file__).resolve().parents[1]

# A Python run in which the optional packages cannot be imported (as after `pip install .` alone).
_BLOCK = textwrap.dedent("""
    import importlib.abc, sys
    BLOCKED = {"gtsam", "filterpy", "matplotlib", "rosbags", "pyulog", "dask", "pyarrow", "pandas"}
    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ModuleNotFoundError(f"No module named {name!r}")
    sys.meta_path.insert(0, Block())
""")


def _run_without_extras(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", _BLOCK + textwrap.dedent(code)], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)


def test_require_missing_names_the_extra():
    with pytest.raises(MissingDependencyError, match=r'pip install "fusion_gyrocal\[graph\]"') as e:
        require("no_such_module_xyz", "graph", "the factor graph")
    assert isinstance(e.value, ImportError) and "the factor graph" in str(e.value)
    assert require("numpy", "track", "x").__name__ == "numpy"
    assert set(EXTRAS) >= {"graph", "track", "plots", "ros"}


def test_core_without_extras_calibrates_and_features_name_their_extra():
    r = _run_without_extras("""
        import numpy as np
        from fusion_gyrocal import calibrate_pair
        from fusion_gyrocal.evaluate.sim import simulate_pair
        from fusion_gyrocal.cli import main
        sim = simulate_pair(rng=0, n=4000)
        cal = calibrate_pair(sim.omega_1, sim.omega_2)
        print("calibrated", cal.configuration)
        for what in ("GyroPairTracker", "calibrate_pair_graph"):
            try:
                getattr(__import__("fusion_gyrocal"), what)
            except ImportError as exc:
                print("refused", what, type(exc).__name__, exc)
        print("exit", main(["track", "-"]))
        print("exit", main(["demo"]))
    """)
    out = r.stdout
    assert r.returncode == 0, r.stderr
    assert "calibrated general" in out
    assert 'refused GyroPairTracker MissingDependencyError' in out and '"fusion_gyrocal[track]"' in out
    assert 'refused calibrate_pair_graph MissingDependencyError' in out and '"fusion_gyrocal[graph]"' in out
    assert "exit 1" in out and "exit 0" in out
    assert 'gyrocal: error: the online tracker' in r.stderr and "[track]" in r.stderr
    assert "Traceback" not in r.stderr


def test_bag_and_ulog_without_ros_extra_name_it(tmp_path):
    (tmp_path / "a.bag").write_bytes(b"#ROSBAG V2.0\n")
    (tmp_path / "f.ulg").write_bytes(b"ULog\x01\x12\x35\x01" + bytes(8))
    r = _run_without_extras(f"""
        from fusion_gyrocal.io import read_imu
        for name in ("a.bag", "f.ulg"):
            try:
                read_imu({str(tmp_path)!r} + "/" + name)
            except ImportError as exc:
                print(name, exc)
    """)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].startswith("a.bag reading ROS bags needs the optional package 'rosbags'") and "[ros]" in lines[0]
    assert lines[1].startswith("f.ulg reading PX4 ULog files needs the optional package 'pyulog'")
