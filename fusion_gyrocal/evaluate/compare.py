"""Every estimator side by side on the same data: :func:`compare` and :func:`snr_sweep`.

:func:`compare` runs every estimator of the registry (:mod:`fusion_gyrocal.evaluate.registry`: the
paper's direct solution, the library default, the paper's Appendix C solver, a rotation-only
baseline, the GTSAM graph, the EKF) on one recording, one
:class:`~fusion_gyrocal.evaluate.scenarios.Scenario` or ``runs`` Monte Carlo realisations of a named
scenario (:mod:`fusion_gyrocal.evaluate.scenarios`), spread over the machine's cores with a progress
bar (:mod:`fusion_gyrocal.evaluate.montecarlo`), and returns a
:class:`~fusion_gyrocal.evaluate.tables.Comparison`: per estimator the estimate, the errors against the
truth (the paper's metrics, Eq. 37-38), their ratio to the Cramer-Rao bound and the time per solve,
as a terminal table, Markdown and CSV. :func:`snr_sweep` repeats this over the paper's SNR factors
and fits the log-log slope of RMSE versus SNR; :func:`plot_rmse_vs_snr` and
:func:`plot_residual_vs_rate` (:mod:`fusion_gyrocal.evaluate.figures`) draw the paper's figures.
``gyrocal compare`` is the same from the command line (:mod:`fusion_gyrocal.cli.compare`).

The package's modules:

* :mod:`~fusion_gyrocal.evaluate.baselines`: the paper's Appendix C solver and rotation-only Kabsch;
* :mod:`~fusion_gyrocal.evaluate.registry`: one entry per estimator, running and timing one;
* :mod:`~fusion_gyrocal.evaluate.montecarlo`: runs over seeds and processes;
* :mod:`~fusion_gyrocal.evaluate.tables`: rows, comparisons, sweeps, Markdown and CSV;
* :mod:`~fusion_gyrocal.evaluate.figures`: the figures.

The names of those modules that callers use are importable from here too.
"""

from __future__ import annotations

import numpy as np

from ..core.moments import as_rates
from ..errors import InputError
from ..options import Options
from .baselines import AppendixCResult, rotation_only, solve_appendix_c
from .figures import plot_residual_vs_rate, plot_rmse_vs_snr
from .montecarlo import RunRecord, evaluate, monte_carlo
from .registry import (DEFAULT_ESTIMATORS, ESTIMATORS, REGISTRY, Estimate, Estimator, estimator_available,
                       estimator_names, run_estimator)
from .scenarios import SNR_FACTORS, Scenario, describe_scenario
from .tables import Comparison, Row, Slope, SnrSweep

__all__ = [
    "ESTIMATORS", "DEFAULT_ESTIMATORS", "REGISTRY", "SNR_FACTORS", "Estimator", "Estimate", "AppendixCResult",
    "RunRecord", "Row", "Comparison", "Slope", "SnrSweep", "solve_appendix_c", "rotation_only", "run_estimator",
    "estimator_available", "compare", "snr_sweep", "plot_rmse_vs_snr", "plot_residual_vs_rate",
]


def check_seed(seed) -> int:
    """``seed`` as the non-negative integer numpy's generators take, else :class:`InputError`."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed: expected an integer >= 0 (numpy's random generators take no other), got {seed!r}")
    return int(seed)


def compare(source="nominal", *, estimators=None, runs: int = 1, seed: int = 0, snr_factor: float = 1.0,
            snr_via: str | None = None, workers: int | None = None, progress: bool = True,
            rate_hz: float = 100.0, options: Options | None = None, **keywords) -> Comparison:
    """Run every estimator on the same data and tabulate estimates, errors, bounds and times.

    Parameters
    ----------
    source : str, Scenario or (omega_1, omega_2)
        A scenario name (:func:`fusion_gyrocal.evaluate.scenarios.list_scenarios`; ``runs`` realisations
        are simulated), one :class:`~fusion_gyrocal.evaluate.scenarios.Scenario` realisation, or a recording
        as two sample-aligned ``(N, 3)`` rate arrays (rad/s; no truth, so no errors).
    estimators : sequence of str
        Keys of :data:`ESTIMATORS`; default :data:`DEFAULT_ESTIMATORS`.
    runs : int
        Monte Carlo realisations of a named scenario (run ``i`` uses ``rng=[seed, i]``).
    seed : int
        Base seed.
    snr_factor, snr_via
        Scale the scenario's SNR (see :func:`fusion_gyrocal.evaluate.scenarios.make_scenario`).
    workers : int, optional
        Processes for the Monte Carlo runs (default: all cores; 1 runs in this process).
    progress : bool
        Show a progress bar.
    rate_hz : float
        Sample rate of a recording (used by the EKF only).
    options : Options, optional
        Options of the solver and the pipeline, given unchanged to the estimators that take them
        (:mod:`fusion_gyrocal.evaluate.registry`: ``direct`` and ``default`` through
        :func:`~fusion_gyrocal.calibrate_pair` with their own method, the graph and the EKF what applies
        to them). Default: ``Options()``.
    **keywords
        Fields of :class:`~fusion_gyrocal.options.Options`, applied on top of ``options`` (e.g.
        ``noise_std=1.7e-3``).

    Returns
    -------
    Comparison

    Examples
    --------
    >>> from fusion_gyrocal.evaluate.compare import compare
    >>> c = compare("nominal", estimators=["direct", "default"], runs=2, workers=1, progress=False)
    >>> [r.estimator for r in c.rows]
    ['direct', 'default']
    >>> bool(c.row("default").rotation_ratio < 3)
    True
    """
    names = estimator_names(estimators)
    options = Options.of(options, **keywords)
    seed = check_seed(seed)
    if isinstance(source, str):
        description = describe_scenario(source, snr_factor=snr_factor, snr_via=snr_via)  # checks the name first
        records = monte_carlo([(source, snr_factor, snr_via)], int(runs), names, seed, workers, progress,
                              options=options)[0]
        return Comparison(source, description, names, tuple(records))
    if isinstance(source, Scenario):
        rec = evaluate(source, source.omega_1, source.omega_2, names, options=options)
        return Comparison(source.name, source.description, names, (rec,))
    try:
        omega_1, omega_2 = source
    except (TypeError, ValueError):
        raise InputError("source: expected a scenario name, a Scenario or a pair (omega_1, omega_2), got "
                         f"{type(source).__name__}") from None
    w1 = as_rates("omega_1", omega_1)
    w2 = as_rates("omega_2", omega_2, length=w1.shape[0])
    rec = evaluate(None, w1, w2, names, rate_hz=rate_hz, options=options)
    return Comparison("recording", f"{w1.shape[0]} sample-aligned samples", names, (rec,))


def snr_sweep(scenario: str = "nominal", *, factors=SNR_FACTORS, via: str = "rate", runs: int = 100,
              estimators=None, seed: int = 0, workers: int | None = None, progress: bool = True,
              paired: bool = True, options: Options | None = None, **keywords) -> SnrSweep:
    """Monte Carlo of ``scenario`` at each SNR factor (all points in one process pool).

    With ``paired`` (default) run ``i`` of every factor uses the seed ``(seed, i)``: the same truth,
    motion and noise draws at every SNR (common random numbers), so the fitted slopes are not
    blurred by realisation-to-realisation spread; through the rate norm or the noise the error of a
    linear estimator then scales exactly with 1 / SNR. ``paired=False`` draws independent
    realisations per factor (seed ``(seed, k + 1, i)`` for factor ``k``): the stricter test of the
    slope. See :func:`compare` for the other parameters.
    """
    names = estimator_names(estimators)
    options = Options.of(options, **keywords)
    seed = check_seed(seed)
    factors = tuple(float(f) for f in factors)
    descriptions = [describe_scenario(scenario, snr_factor=f, snr_via=via) for f in factors]  # checks first
    recs = monte_carlo([(scenario, f, via) for f in factors], int(runs), names, seed, workers, progress, paired,
                       options=options)
    comps = tuple(Comparison(scenario if f == 1 else f"{scenario} (SNR x{f:g} via {via})", desc, names, tuple(records))
                  for f, desc, records in zip(factors, descriptions, recs))
    return SnrSweep(scenario, via, factors, comps)
