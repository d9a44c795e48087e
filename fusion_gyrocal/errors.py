"""Exception hierarchy: one root, one subclass per cause.

Every error the library raises on purpose derives from :class:`GyroCalError`, so
callers (and the CLI) can catch exactly the known failure modes and print them as
one line.
"""

from __future__ import annotations


class GyroCalError(Exception):
    """Root of every error raised on purpose by fusion_gyrocal."""


class InputError(GyroCalError, ValueError):
    """Input arrays or timestamps do not have the expected shape, type or content."""


class OptionError(GyroCalError, ValueError):
    """An option (keyword argument or command-line flag) has a value it does not accept, or is unknown."""


class ExcitationError(GyroCalError):
    """The motion does not excite every axis enough to determine the calibration (Lemma 1)."""


class ConfigurationError(GyroCalError):
    """A requested gauge or prior is inconsistent with what the data determine."""


class TimeAlignmentError(GyroCalError):
    """The time offset between two streams could not be determined."""


class NotRigidError(GyroCalError):
    """The two gyroscopes do not move as one rigid body (residuals grow with the rate)."""


class ConvergenceError(GyroCalError):
    """An iterative solver diverged (its normal equations became singular or non-finite)."""


class FormatError(GyroCalError):
    """A file could not be read or written in the requested format."""
