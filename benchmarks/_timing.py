"""The timing helpers of the benchmarks (imported as a sibling module): the best wall time of repeated runs, and the
environment of child interpreters that run this checkout as an installed package would run."""

from __future__ import annotations

import os
import tempfile
import time


def best_of(f, k: int = 3):
    """``(best wall time in s of k calls of f, the last result)``."""
    best, out = float("inf"), None
    for _ in range(k):
        t0 = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t0)
    return best, out


def installed_like_env(root) -> dict:
    """The environment of a child interpreter that imports this checkout's package (``root`` on ``PYTHONPATH``) with
    its bytecode cached, as an installed package's is (pip compiles it; Python caches it on first import): the cache
    goes to a fresh temporary folder (``PYTHONPYCACHEPREFIX``), also where the environment sets
    ``PYTHONDONTWRITEBYTECODE`` (which would make every start compile the package again). The first run fills it: a
    warm-up run before timing."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(PYTHONPATH=os.pathsep.join(filter(None, (str(root), os.environ.get("PYTHONPATH")))),
               PYTHONPYCACHEPREFIX=tempfile.mkdtemp(prefix="gyrocal_pycache_"))
    return env
