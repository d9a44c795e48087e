"""The units the library reads: rate units with their factors to rad/s, time units with their powers of ten.

The one table of units (numpy only, so every layer can import it): the readers
(:mod:`fusion_gyrocal.io`), the conversion :func:`fusion_gyrocal.pipeline.streams.to_rad_per_s`, the
timestamp checks of :mod:`fusion_gyrocal.pipeline.streams` and the command line's ``--unit`` /
``--time-unit`` flags all take their units from here. Inside the library rates are rad/s and times s.
"""

from __future__ import annotations

import numpy as np

#: One degree in radians.
DEG = np.pi / 180.0

#: Rate units: name -> factor to rad/s. Raw ``"counts"`` are further divided by the sensor's
#: sensitivity in LSB per deg/s (rad/s = counts / sensitivity * pi / 180).
RATE_FACTORS = {"rad/s": 1.0, "deg/s": DEG, "counts": DEG}
#: The rate unit names, in the order of :data:`RATE_FACTORS`.
RATE_UNITS = tuple(RATE_FACTORS)
#: Spellings of the rate units in a column header's brackets (spaces removed): ``[rad s^-1]``, ``[dps]``, ...
RATE_UNIT_LABELS = {
    "rad/s": "rad/s", "rads^-1": "rad/s", "rad/sec": "rad/s", "rad*s^-1": "rad/s",
    "deg/s": "deg/s", "dps": "deg/s", "°/s": "deg/s", "degs^-1": "deg/s", "deg/sec": "deg/s",
    "counts": "counts", "lsb": "counts", "raw": "counts",
}

#: Time units: name -> power of ten of one second (``"ms"``: 3, one unit is 1e-3 s).
TIME_UNITS = {"s": 0, "ms": 3, "us": 6, "ns": 9}
#: Spellings of the time units in a column header's brackets: ``[ns]``, ``[sec]``, ``[µs]``, ...
TIME_UNIT_LABELS = {**{u: u for u in TIME_UNITS}, "sec": "s", "seconds": "s", "µs": "us", "usec": "us"}
