"""Former home of the graph (before issue 11); import from :mod:`fusion_gyrocal.graph` instead.

Kept only until the import sites outside ``graph/`` move (``fusion_gyrocal/__init__.py``,
``evaluate/compare.py``); delete it then.
"""

from __future__ import annotations

from . import (GLOBAL_SCALE_GAUGE, GraphEstimate, GraphKeys, GyroPairGraph, PreintegratedRotations,
               RotationIncrements, WindowStatistics, calibrate_pair_graph, gyro_pair_factor, preintegrate_rotations,
               rotation_increment_factor)

__all__ = ["GLOBAL_SCALE_GAUGE", "GraphEstimate", "GraphKeys", "GyroPairGraph", "PreintegratedRotations",
           "RotationIncrements", "WindowStatistics", "calibrate_pair_graph", "gyro_pair_factor",
           "preintegrate_rotations", "rotation_increment_factor"]
