"""Monte Carlo runs of the comparison: every estimator on each realisation, over processes, with progress.

:func:`evaluate` runs every estimator on one data set and measures the paper's errors against the
truth (Eq. 37-38); :func:`monte_carlo` does this for ``runs`` seeded realisations of one or more
scenarios (:mod:`fusion_gyrocal.evaluate.scenarios`), in this process or over a process pool, with
a progress bar. The results are :class:`RunRecord` objects, which
:class:`~fusion_gyrocal.evaluate.tables.Comparison` tabulates.
"""

from __future__ import annotations

import os
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..options import Options
from ..progress import progress_bar
from .registry import run_estimator
from .scenarios import Scenario, ScenarioBound, make_scenario, scenario_bound
from .sim import rotation_error, scale_error

__all__ = ["RunRecord", "evaluate", "monte_carlo"]


@dataclass(frozen=True)
class RunRecord:
    """Every estimator on one data set (one Monte Carlo run).

    Attributes
    ----------
    seed : tuple of int
        Seed of the realisation (``make_scenario(name, rng=list(seed))`` reproduces it); ``()``
        for a recording.
    snr : float
        SNR of the realisation (Eq. 36), NaN without truth.
    bound : ScenarioBound or None
        Cramer-Rao bound of the realisation (None without truth).
    estimates : tuple of Estimate
        One per estimator, in the comparison's order.
    rotation_error, scale_error : ndarray (n_estimators,)
        The paper's errors (Eq. 37-38) against the truth (rad, fraction); NaN without truth, for a
        failed estimator, or (scales) for an estimator without scale factors.
    """

    seed: tuple
    snr: float
    bound: ScenarioBound | None
    estimates: tuple
    rotation_error: np.ndarray
    scale_error: np.ndarray


def evaluate(scenario: Scenario | None, omega_1, omega_2, estimators, seed=(), rate_hz: float = 100.0,
             options: Options | None = None) -> RunRecord:
    """Every estimator on one data set; errors against the truth of ``scenario`` (NaN without one)."""
    estimates = tuple(run_estimator(name, omega_1, omega_2, rate_hz=rate_hz, options=options) for name in estimators)
    rot, sca = np.full(len(estimates), np.nan), np.full(len(estimates), np.nan)
    if scenario is None:
        return RunRecord(tuple(seed), float("nan"), None, estimates, rot, sca)
    d = scenario.data
    for i, e in enumerate(estimates):
        if e.ok:
            rot[i] = rotation_error(e.R_1_2, d.R_1_2)
            if e.has_scales:
                sca[i] = scale_error(e.scale_1, e.scale_2, d.scale_1, d.scale_2)
    return RunRecord(tuple(seed), scenario.snr, scenario_bound(scenario), estimates, rot, sca)


def _task(spec, seed, estimators, options) -> RunRecord:
    """One Monte Carlo run: simulate ``spec = (name, snr_factor, snr_via)`` with ``seed``, run all."""
    name, factor, via = spec
    sc = make_scenario(name, rng=list(seed), snr_factor=factor, snr_via=via)
    return evaluate(sc, sc.omega_1, sc.omega_2, estimators, seed, options=options)


def _pool_task(spec, seed, estimators, options):
    """:func:`_task` in a worker process, with the warnings it emitted (relayed to the parent by
    :func:`monte_carlo`, so that the caller's warning filters decide, as for runs in its own process)."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        record = _task(spec, seed, estimators, options)
    return record, [(str(w.message), w.category, w.filename, w.lineno) for w in caught]


_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def monte_carlo(specs, runs: int, estimators, seed: int, workers: int | None, progress: bool,
                paired: bool = True, options: Options | None = None) -> list[list[RunRecord]]:
    """``runs`` realisations of every spec ``(scenario name, snr_factor, snr_via)``, every estimator on each.

    Parameters
    ----------
    specs : sequence of (str, float, str or None)
        Scenarios to simulate (see :func:`~fusion_gyrocal.evaluate.scenarios.make_scenario`).
    runs : int
        Realisations per spec (>= 1).
    estimators : tuple of str
        Registry names, in row order.
    seed : int
        Base seed. ``paired``: run ``i`` of every spec uses the seed ``(seed, i)`` (common random
        numbers: the same truth and motion at every SNR point); else spec ``s`` uses
        ``(seed, s + 1, i)`` (independent realisations).
    workers : int, optional
        Processes (default: all cores; 1 runs in this process). Each worker uses one BLAS thread; the warnings
        of the workers are re-emitted in this process.
    progress : bool
        Show a progress bar.
    options : Options, optional
        Given to every estimator (:func:`~fusion_gyrocal.evaluate.registry.run_estimator`).

    Returns
    -------
    list of list of RunRecord
        ``out[s][i]``: run ``i`` of spec ``s``.
    """
    if runs < 1:
        raise InputError(f"runs: expected >= 1, got {runs}")
    tasks = [(s, i, (int(seed), i) if paired else (int(seed), s + 1, i)) for s in range(len(specs))
             for i in range(runs)]
    out = [[None] * runs for _ in specs]
    workers = (os.cpu_count() or 1) if workers is None else int(workers)
    with progress_bar(progress) as bar:
        job = bar.add_task(f"{len(specs)} x {runs} runs, {len(estimators)} estimators", total=len(tasks))
        if workers <= 1 or len(tasks) == 1:
            for s, j, sd in tasks:
                out[s][j] = _task(specs[s], sd, estimators, options)
                bar.advance(job)
        else:
            import multiprocessing as mp
            saved = {k: os.environ.get(k) for k in _THREAD_VARS}
            os.environ.update({k: "1" for k in _THREAD_VARS})  # one BLAS thread per worker process
            try:
                with ProcessPoolExecutor(min(workers, len(tasks)), mp_context=mp.get_context("spawn")) as pool:
                    futures = {pool.submit(_pool_task, specs[s], sd, estimators, options): (s, j)
                               for s, j, sd in tasks}
                    for fut in as_completed(futures):
                        s, j = futures[fut]
                        out[s][j], caught = fut.result()
                        for message, category, filename, lineno in caught:
                            warnings.warn_explicit(message, category, filename, lineno)
                        bar.advance(job)
            finally:
                for k, v in saved.items():
                    if v is None:
                        os.environ.pop(k, None)
                    else:
                        os.environ[k] = v
    return out
