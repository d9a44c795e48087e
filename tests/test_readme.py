"""The README's Python snippets run against the real API (on simulated data)."""

import re
from pathlib import Path

import numpy as np
import pytest

from fusion_gyrocal.evaluate.sim import PAPER_NOISE_STD, general_rotation, simulate_pair

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_blocks():
    return re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


@pytest.fixture(scope="module")
def namespace():
    sim = simulate_pair(rng=0, n=6000)
    t = np.arange(6000) / 100.0
    third = sim.omega_true_1 @ general_rotation(1) + np.random.default_rng(1).normal(0, PAPER_NOISE_STD, (6000, 3))
    return {"omega_1": sim.omega_1, "omega_2": sim.omega_2, "t1": t, "t2": t - 0.02,
            "omega_a": sim.omega_1, "omega_b": sim.omega_2, "omega_c": third}


def test_readme_python_snippets_run(namespace):
    blocks = _python_blocks()
    assert len(blocks) >= 2
    ns = dict(namespace)
    for code in blocks:
        exec(compile(code, str(README), "exec"), ns)  # noqa: S102 - the README is part of the project
    assert ns["cal"].configuration == "general" and abs(ns["cal"].time_offset_s - 0.02) < 1e-3
    assert ns["arr"].R_ref_k.shape == (3, 3, 3)
    assert ns["cal_g"].method.startswith("graph") and ns["cal_d"].bias_segments == 1
