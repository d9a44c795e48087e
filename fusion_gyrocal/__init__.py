"""fusion_gyrocal: infield calibration of rigidly mounted gyroscopes from their rates alone.

Implements T. Wang and S. I. Roumeliotis, "A Direct Algorithm for Multi-Gyroscope Infield
Calibration", and goes beyond it (maximum likelihood, drifting bias, priors, streaming).
"""

from .calibrate import calibrate_pair, solve
from .direct import Gauge
from .errors import (ConfigurationError, ExcitationError, FormatError, GyroCalError, InputError, NotRigidError,
                     TimeAlignmentError)
from .model import PairCalibration
from .moments import Moments

__version__ = "0.1.0"

__all__ = [
    "calibrate_pair", "solve", "Gauge", "PairCalibration", "Moments",
    "GyroCalError", "InputError", "ExcitationError", "ConfigurationError", "TimeAlignmentError",
    "NotRigidError", "FormatError", "__version__",
]
