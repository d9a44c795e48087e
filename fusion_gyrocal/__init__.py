"""fusion_gyrocal: infield calibration of rigidly mounted gyroscopes from their rates alone.

Implements T. Wang and S. I. Roumeliotis, "A Direct Algorithm for Multi-Gyroscope Infield
Calibration", and goes beyond it (maximum likelihood, drifting bias, priors, N gyros,
streaming, an EKF, a GTSAM graph, fleets on Dask).

The core names import eagerly; the estimators with heavy dependencies (filterpy, gtsam, dask)
load on first use.
"""

from .core.gauge import Gauge
from .core.model import PairCalibration
from .core.moments import Moments
from .core.solve import solve
from .errors import (ConfigurationError, ConvergenceError, ExcitationError, FormatError, GyroCalError, InputError,
                     NotRigidError, OptionError, TimeAlignmentError)
from .options import Options
from .pipeline.pipeline import calibrate_pair

__version__ = "0.1.0"

_LAZY = {
    "calibrate_array": "core.array", "ArrayCalibration": "core.array_result",
    "calibrate_streams": "pipeline.array",
    "StreamingCalibrator": "online.stream",
    "GyroPairTracker": "online.tracker", "TrackerConfig": "online.config",
    "calibrate_pair_graph": "graph", "GyroPairGraph": "graph",
    "run_fleet": "distributed.fleet",
}

__all__ = [
    "calibrate_pair", "solve", "Options", "Gauge", "PairCalibration", "Moments",
    "GyroCalError", "InputError", "OptionError", "ExcitationError", "ConfigurationError", "TimeAlignmentError",
    "NotRigidError", "FormatError", "ConvergenceError", "__version__", *_LAZY,
]


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module 'fusion_gyrocal' has no attribute {name!r}")
