"""How the tracker holds the scale directions that the data never inform (Theorem 2).

The scale factors are linked in groups (:attr:`~fusion_gyrocal.core.observability.Configuration.groups`):
scaling every member of a group by one factor leaves ``A`` unchanged. The tracker holds each group's
common factor:

* a group of at least four linked scale factors that contains members of the
  :class:`~fusion_gyrocal.core.gauge.Gauge` follows the gauge (Eq. 32-34), as in
  :func:`fusion_gyrocal.calibrate_pair`; its common factor has no variance in the gauge;
* every other group (a parallel axis pair, Lemmas 2-3) keeps the log-mean of its scale factors at the
  seed's value with a prior standard deviation (the tracker's ``scale_prior_std``).

The gauge's conditions come from :mod:`fusion_gyrocal.core.gauge` (``Gauge.apply``,
``Gauge.constraints``, ``null_directions``, ``oblique_projector``); the prior groups add one
linear condition each, on their log-mean.
"""

from __future__ import annotations

import numpy as np

from ..core.gauge import Gauge, null_directions, oblique_projector

DIM = 12                 # error state [dtheta, log s_1, log s_2, db]
LOG = slice(3, 9)        # its log-scales


def _key(group) -> tuple:
    return tuple(sorted(group))


class ScaleHold:
    """The held scale directions of one seed: gauge groups, prior groups and the values held.

    Parameters
    ----------
    configuration : Configuration
        The seed's configuration (its groups of linked scale factors).
    gauge : Gauge
    prior_std : float
        Prior 1-sigma of the log-mean of each prior group.
    scale_1, scale_2 : ndarray (3,)
        The seed's scale factors: the prior groups hold their log-means (after the gauge is applied).
    previous : ScaleHold, optional
        On a re-seed: groups held before keep their held value.

    Attributes
    ----------
    N : ndarray (6, n_groups)
        Null direction of each group in the log-scales, gauge groups first.
    held_cov : ndarray (12, 12)
        Covariance of the held directions in the error state (zero for the gauge groups, the prior for
        the others).
    obs_basis : ndarray (12, 12 - n_groups)
        Orthonormal basis of the observable coordinates (the complement of the held directions).
    """

    __slots__ = ("gauge", "prior_std", "gauge_groups", "prior_groups", "values", "N", "held_cov", "obs_basis",
                 "_prior_rows")

    def __init__(self, configuration, gauge: Gauge, prior_std: float, scale_1, scale_2, previous=None):
        self.gauge, self.prior_std = gauge, float(prior_std)
        self.gauge_groups = tuple(g for g in configuration.groups if len(g) >= 4 and gauge.members_in(g))
        self.prior_groups = tuple(g for g in configuration.groups if g not in self.gauge_groups)
        s = self._apply_gauge(scale_1, scale_2).ravel()
        old = previous.values if previous is not None else {}
        self.values = {_key(g): old[_key(g)] if _key(g) in old else self._log_mean(s, g) for g in self.prior_groups}
        ng = len(self.gauge_groups)
        self.N = null_directions(self.gauge_groups + self.prior_groups, 2)
        self._prior_rows = (self.N[:, ng:] / self.N[:, ng:].sum(axis=0)).T     # log-mean of each prior group
        Nf = np.zeros((DIM, self.N.shape[1]))
        Nf[LOG] = self.N
        var = np.array([0.0] * ng + [self.prior_std**2] * len(self.prior_groups))
        self.held_cov = (Nf * var) @ Nf.T
        Q, _ = np.linalg.qr(Nf, mode="complete")
        self.obs_basis = Q[:, Nf.shape[1]:]

    @staticmethod
    def _log_mean(s, group) -> float:
        return float(np.mean(np.log(s[[3 * g + a for g, a in group]])))

    def _apply_gauge(self, scale_1, scale_2) -> np.ndarray:
        return self.gauge.apply(self.gauge_groups, np.array([scale_1, scale_2], dtype=float))

    @property
    def nees_dof(self) -> int:
        """Observable coordinates of the error state."""
        return int(self.obs_basis.shape[1])

    def express(self, scale_1, scale_2) -> tuple[np.ndarray, np.ndarray]:
        """Scale factors in the hold: the gauge applied, each prior group's log-mean set to its held value."""
        s = self._apply_gauge(scale_1, scale_2).ravel()
        for g in self.prior_groups:
            idx = [3 * gy + a for gy, a in g]
            s[idx] *= np.exp(self.values[_key(g)] - np.mean(np.log(s[idx])))
        return s[:3], s[3:]

    def projector(self, scale_1, scale_2) -> np.ndarray:
        """(6, 6) oblique projector of the log-scales onto the held conditions, linearised at the scales."""
        rows = [self._prior_rows]
        if self.gauge_groups:
            rows.insert(0, self.gauge.constraints(self.gauge_groups, np.array([scale_1, scale_2])))
        return oblique_projector(self.N, np.vstack(rows))

    def describe(self) -> str:
        """How each held direction is held, in words."""
        parts = [self.gauge.describe()] if self.gauge_groups else []
        for g in self.prior_groups:
            names = " * ".join(f"scale_{gy + 1}[{a}]" for gy, a in g)
            parts.append(f"common factor of {names} held at the seed (prior std {self.prior_std:g})")
        return "; ".join(parts)
