"""The gauge: how the unobservable global scale is fixed (Theorem 2), for pairs and arrays alike.

Scale factors are linked in *groups* (:attr:`~fusion_gyrocal.core.observability.Configuration.groups`
for a pair, the union of every pair's groups for an array): shifting every log-scale of one group by
a common amount leaves every ``A = S_i R S_j^-1`` unchanged, so each group needs one condition. The
:class:`Gauge` supplies it, and this module is the one place that turns it into numbers:

* :meth:`Gauge.apply` rescales estimates so that the gauge holds (Eq. 32-34);
* :meth:`Gauge.condition` gives the conditions' values, :meth:`Gauge.constraints` their linearisation on the
  log-scales (the graph's gauge factor uses both);
* :meth:`Gauge.null_directions` and :func:`oblique_projector` move a covariance onto the constraint
  surface (``T = I - N (G N)^-1 G``), as the EKF and the graph need;
* :func:`constrained_inverse` inverts a Fisher information inside the gauge's tangent space
  (``Z pinv(Z^T F Z) Z^T``), as the pair and array solvers need.

Scale factors are indexed ``(gyro, axis)`` with gyros counted from 0 (gyro 0 is the reference,
``scale_1`` of a pair); log-scales are stacked gyro after gyro, ``3 * gyro + axis``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigurationError, OptionError

PAIR_NAMES = ("scale_1", "scale_2")


@dataclass(frozen=True)
class Gauge:
    """How the unobservable global scale is fixed (Theorem 2).

    Parameters
    ----------
    members : tuple of (gyro, axis)
        Scale factors the gauge acts on; gyros counted from 0 (gyro 0 is a pair's gyro 1).
    value : float or None
        ``None``: the paper's unit-scale prior, the members' scale factors are as close to 1 as their
        determined ratios allow (Eq. 32-34). A float: the single member's scale factor is known and
        equal to ``value``.

    Examples
    --------
    >>> import numpy as np
    >>> g = Gauge.unit_prior()
    >>> g.describe()
    'unit prior on scale_1[0], scale_2[0] (Eq. 32-34)'
    >>> s = g.apply([((0, 0), (1, 0))], np.array([[2.0, 1, 1], [2.0, 1, 1]]))
    >>> s[:, 0]
    array([1., 1.])
    """

    members: tuple = ((0, 0), (1, 0))
    value: float | None = None

    @classmethod
    def unit_prior(cls, axis: int = 0, n_gyros: int = 2) -> "Gauge":
        """The paper's prior that the ``axis`` scale factors of every gyro are close to 1 (Eq. 32)."""
        return cls(tuple((k, axis) for k in range(n_gyros)), None)

    @classmethod
    def known_scale(cls, gyro: int, axis: int, value: float) -> "Gauge":
        """A known scale factor: ``scale_<gyro>[axis] == value`` (gyro counted from 1, as in ``scale_1``)."""
        if isinstance(gyro, bool) or not isinstance(gyro, (int, np.integer)) or gyro < 1 \
                or axis not in (0, 1, 2) or not value > 0:
            raise OptionError(f"known scale: expected gyro >= 1, axis in (0, 1, 2), value > 0; "
                              f"got gyro={gyro}, axis={axis}, value={value}")
        return cls(((int(gyro) - 1, int(axis)),), float(value))

    @classmethod
    def fixed(cls, gyro: int = 1) -> "Gauge":
        """``scale_<gyro>[0] == 1`` (gyro counted from 1)."""
        return cls.known_scale(gyro, 0, 1.0)

    @classmethod
    def parse(cls, gauge, n_gyros: int = 2, reference: int = 0) -> "Gauge":
        """Accept a :class:`Gauge`, ``"unit_prior"`` (every gyro's x axis) or ``"fixed"`` (the reference's x)."""
        if isinstance(gauge, Gauge):
            bad = [m for m in gauge.members if not (0 <= m[0] < n_gyros and m[1] in (0, 1, 2))]
            if bad or not gauge.members:
                raise OptionError(f"gauge: members {list(gauge.members)} do not name scale factors of "
                                  f"{n_gyros} gyros (gyro in 0..{n_gyros - 1}, axis in 0..2)")
            return gauge
        if isinstance(gauge, str) and gauge == "unit_prior":
            return cls.unit_prior(0, n_gyros)
        if isinstance(gauge, str) and gauge == "fixed":
            return cls.fixed(reference + 1)
        raise OptionError(f"gauge: expected 'unit_prior', 'fixed' or a Gauge, got {gauge!r}")

    def describe(self, names=None) -> str:
        """The gauge in words; ``names[g]`` names gyro ``g``'s scale factors (default ``scale_1``, ``scale_2``)."""
        if names is None:
            n = 1 + max(g for g, _ in self.members)
            names = PAIR_NAMES if n <= 2 else tuple(f"scale[{k}]" for k in range(n))
        text = ", ".join(f"{names[g]}[{a}]" for g, a in self.members)
        return f"unit prior on {text} (Eq. 32-34)" if self.value is None else f"{text} == {self.value:g}"

    def members_in(self, group) -> list:
        """The gauge's members that belong to ``group`` (a tuple of ``(gyro, axis)``)."""
        return [m for m in self.members if m in group]

    def _condition(self, group):
        """``(members, value)`` that fix ``group``: the gauge's own members in it, else every member under
        the unit convention (the common factor of a parallel axis pair the data cannot fix)."""
        own = self.members_in(group)
        return (own, self.value) if own and self.value is not None else (own or list(group), None)

    def apply(self, groups, scales) -> np.ndarray:
        """``scales`` (n_gyros, 3) rescaled group by group so that the gauge holds.

        The group holding the gauge's members follows the gauge; any other group follows the unit
        convention over all its members (``argmin_c sum (c s - 1)^2``, Eq. 32-34).
        """
        s = np.array(scales, dtype=float)
        for group in groups:
            members, value = self._condition(group)
            r = np.array([s[g, a] for g, a in members])
            c = value / r[0] if value is not None else r.sum() / (r**2).sum()
            for g, a in group:
                s[g, a] *= c
        return s

    def condition(self, groups, scales) -> np.ndarray:
        """Values of the gauge conditions, one per group, at ``scales`` (n_gyros, 3); zero where the gauge holds.

        A known scale: ``log s_m - log value``; the unit convention: ``sum_m s_m (s_m - 1)`` (Eq. 32-34).
        :meth:`constraints` is their derivative with respect to ``log s``.
        """
        s = np.asarray(scales, dtype=float)
        out = np.zeros(len(groups))
        for j, group in enumerate(groups):
            members, value = self._condition(group)
            r = np.array([s[g, a] for g, a in members])
            out[j] = np.sum(np.log(r) - np.log(value)) if value is not None else np.sum(r * (r - 1.0))
        return out

    def constraints(self, groups, scales, leading: int = 0) -> np.ndarray:
        """Linearised gauge conditions, one row per group, on ``[leading zeros, log s (3 n_gyros)]``.

        A known scale: ``d log s_m = 0``; the unit convention: ``d/dlog s of sum (s - 1) s = (2 s - 1) s``.
        """
        s = np.asarray(scales, dtype=float)
        rows = np.zeros((len(groups), leading + s.size))
        for j, group in enumerate(groups):
            members, value = self._condition(group)
            for g, a in members:
                rows[j, leading + 3 * g + a] = 1.0 if value is not None else s[g, a] * (2 * s[g, a] - 1)
        return rows


def null_directions(groups, n_gyros: int) -> np.ndarray:
    """(3 n_gyros, n_groups): the log-scale direction of each group (a common shift leaves every A unchanged)."""
    N = np.zeros((3 * n_gyros, len(groups)))
    for j, group in enumerate(groups):
        for g, a in group:
            N[3 * g + a, j] = 1.0
    return N


def oblique_projector(N, G) -> np.ndarray:
    """``T = I - N (G N)^-1 G``: the projection along the null directions ``N`` onto ``G dx = 0``.

    Applied to a covariance (``T C T^T``) it re-expresses it in the gauge without changing anything
    the data determine (``A`` does not move along ``N``).
    """
    GN = G @ N
    if np.linalg.cond(GN) > 1e12:
        raise ConfigurationError("gauge: the conditions do not fix the unobservable scale directions "
                                 "(a gauge member outside every linked group?)")
    return np.eye(N.shape[0]) - N @ np.linalg.solve(GN, G)


def null_space(M) -> np.ndarray:
    """Orthonormal basis (columns) of the null space of ``M`` (k, n): the right singular vectors beyond its
    numerical rank (singular values above ``max(k, n) eps`` times the largest)."""
    M = np.atleast_2d(np.asarray(M, dtype=float))
    _, s, vt = np.linalg.svd(M, full_matrices=True)
    rank = int(np.count_nonzero(s > max(M.shape) * np.finfo(float).eps * (s[0] if s.size else 0.0)))
    return vt[rank:].T


def constrained_inverse(F, constraints, rcond: float = 1e-12) -> np.ndarray:
    """Inverse of the information ``F`` in the tangent space ``constraints @ dx = 0``: ``Z pinv(Z^T F Z) Z^T``."""
    Z = null_space(constraints) if len(constraints) else np.eye(F.shape[0])
    return Z @ np.linalg.pinv(Z.T @ F @ Z, rcond=rcond, hermitian=True) @ Z.T
