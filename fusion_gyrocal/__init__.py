"""fusion_gyrocal: infield calibration of rigidly mounted gyroscopes from their rates alone.

Implements T. Wang and S. I. Roumeliotis, "A Direct Algorithm for Multi-Gyroscope Infield
Calibration", and goes beyond it (maximum likelihood, drifting bias, priors, N gyros,
streaming, an EKF, a GTSAM graph, fleets on Dask).

Every name loads on first use (``from fusion_gyrocal import calibrate_pair`` imports the pair pipeline then),
so that ``import fusion_gyrocal`` and the ``gyrocal`` command line start light.
"""

__version__ = "0.2.0"

_LAZY = {
    "calibrate_pair": "pipeline.pipeline", "solve": "core.solve", "Options": "options", "Gauge": "core.gauge",
    "PairCalibration": "core.model", "Moments": "core.moments",
    **{name: "errors" for name in ("GyroCalError", "InputError", "OptionError", "ExcitationError",
                                    "ConfigurationError", "TimeAlignmentError", "NotRigidError", "FormatError",
                                    "ConvergenceError")},
    "calibrate_array": "core.array", "ArrayCalibration": "core.array_result",
    "calibrate_streams": "pipeline.array",
    "StreamingCalibrator": "online.stream",
    "GyroPairTracker": "online.tracker", "TrackerConfig": "online.config",
    "calibrate_pair_graph": "graph", "GyroPairGraph": "graph",
    "run_fleet": "distributed.fleet",
    "compare_sessions": "core.sessions", "SessionComparison": "core.sessions",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value      # once loaded, an ordinary attribute
        return value
    raise AttributeError(f"module 'fusion_gyrocal' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
