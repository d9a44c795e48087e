"""Optional dependencies: which feature needs which package, and the one error when it is missing.

The core (calibration, streaming, CSV / Xsens / npz readers, the CLI's ``calibrate`` and ``demo``) needs
numpy, scipy, PyYAML and rich only. The heavy packages are extras of the install (``pyproject.toml``), loaded
where they are used through :func:`require`:

==========  ==========================  =====================================================
extra       packages                    features
==========  ==========================  =====================================================
``graph``   gtsam                       ``calibrate_pair_graph``, ``GyroPairGraph``
``track``   filterpy                    ``GyroPairTracker``, ``gyrocal track``, ``report --track``
``plots``   matplotlib                  ``gyrocal report`` figures, ``plot_history``
``ros``     rosbags, pyulog             ROS1/ROS2 bags, PX4 ULog files
``fleet``   dask, pyarrow, pandas       ``gyrocal fleet``
``all``     every package above
==========  ==========================  =====================================================
"""

from __future__ import annotations

import importlib

from .errors import GyroCalError

EXTRAS = {"graph": ("gtsam",), "track": ("filterpy",), "plots": ("matplotlib",), "ros": ("rosbags", "pyulog"),
          "fleet": ("dask", "pyarrow", "pandas")}
"""The packages of each extra of ``pip install "fusion_gyrocal[<extra>]"``."""


class MissingDependencyError(GyroCalError, ImportError):
    """A feature needs an optional package that is not installed; the message names the extra to install."""


def require(module: str, extra: str, feature: str):
    """Import ``module`` (an optional dependency) for ``feature``, or say which extra installs it.

    Parameters
    ----------
    module : str
        The module to import (``"gtsam"``, ``"filterpy.kalman"``, ...).
    extra : str
        The extra of :data:`EXTRAS` that installs it.
    feature : str
        What needs it, for the message (``"the online tracker"``).

    Returns
    -------
    module

    Raises
    ------
    MissingDependencyError
        When the import fails, naming the package, the feature and ``pip install "fusion_gyrocal[<extra>]"``.
    """
    if extra not in EXTRAS:
        raise ValueError(f"extra: expected one of {tuple(EXTRAS)}, got {extra!r}")
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        package = module.split(".")[0]
        raise MissingDependencyError(
            f"{feature} needs the optional package {package!r}, which is not installed ({exc}); install it with "
            f"pip install \"fusion_gyrocal[{extra}]\" (or \"fusion_gyrocal[all]\")") from None
