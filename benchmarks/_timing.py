"""The one timing helper of the benchmarks: the best wall time of repeated runs (imported as a sibling module)."""

from __future__ import annotations

import time


def best_of(f, k: int = 3):
    """``(best wall time in s of k calls of f, the last result)``."""
    best, out = float("inf"), None
    for _ in range(k):
        t0 = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t0)
    return best, out
