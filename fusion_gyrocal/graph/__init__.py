"""GTSAM factor-graph variant: gyro-pair window factors, bias random walk, optional global scale.

Visual-inertial pipelines built on GTSAM can put the pair calibration inside their own graph:

* :mod:`~fusion_gyrocal.graph.factors`: the gyro-pair window factor (Eq. 8 from a window's moments),
  the gauge factor (Theorem 2) and the rotation-increment (camera) factor;
* :mod:`~fusion_gyrocal.graph.preintegration`: external rotation increments and gyro 1's rate
  preintegrated over their keyframe intervals;
* :mod:`~fusion_gyrocal.graph.solver`: :class:`GyroPairGraph` (Levenberg-Marquardt or iSAM2,
  covariances from ``gtsam.Marginals``) and :func:`calibrate_pair_graph`.
"""

from __future__ import annotations

from .factors import WindowStatistics, gauge_factor, gyro_pair_factor, rotation_increment_factor
from .preintegration import PreintegratedRotations, RotationIncrements, preintegrate_rotations
from .solver import GLOBAL_SCALE_GAUGE, GraphEstimate, GraphKeys, GyroPairGraph, calibrate_pair_graph

__all__ = [
    "calibrate_pair_graph", "GyroPairGraph", "GraphEstimate", "GraphKeys", "GLOBAL_SCALE_GAUGE",
    "RotationIncrements", "PreintegratedRotations", "preintegrate_rotations",
    "WindowStatistics", "gyro_pair_factor", "gauge_factor", "rotation_increment_factor",
]
