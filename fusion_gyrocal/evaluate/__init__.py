"""Evaluation: the paper's simulations (sim, scenarios) and every estimator side by side (compare).

``sim`` and ``scenarios`` simulate; ``baselines`` (Appendix C, rotation-only), ``registry`` (one entry
per estimator), ``montecarlo``, ``tables`` and ``figures`` serve :mod:`fusion_gyrocal.evaluate.compare`.
"""
