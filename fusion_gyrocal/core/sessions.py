"""Did the device change between calibrations? Sessions of one device tested against one another.

A device calibrated again (each morning, after a shock, at another temperature) gives a rotation per session, each
with its covariance. If the device did not change, the sessions differ only by what those covariances allow; a
session beyond that is a device that moved (a board that bent, a sensor that shifted), not noise.

What is compared: a pair's ``R_1_2``; an array's ``R_ref_k`` of every gyro but the reference (all together: a bend
that turns several gyros a little shows in the joint test before it shows in any one of them). Their covariance
without ``skew_rotation_covariance`` (the rotation the sensors' constant cross-axis terms leave undetermined,
Appendix D, Eq. 40-41: the same in every session of one device, so the difference of two sessions cancels it): the
results' ``repeatable_rotation_covariance`` ``P_e``.

Per session ``e``: its deviation ``d_e`` from the information-weighted mean of the other consistent sessions
(``R_e = Exp(d_e) R_mean``, the reference frame, as everywhere: :mod:`~fusion_gyrocal.lie`) and
``z2_e = d_e^T (P_e + P_mean)^-1 d_e``, chi-square with 3 degrees of freedom per rotation when nothing changed. A
session beyond the chi-square point of a family-wise false-alarm rate ``alpha`` (``alpha / n`` per session,
Bonferroni) changed. The changed sessions leave the mean one at a time, the most extreme first, so that one changed
session does not pull the mean the others are tested against. With two sessions the test says whether they differ,
not which one moved.

Also the spread of the consistent sessions about their mean in units of their covariances (``z2`` per degree of
freedom): near 1 when the covariances explain the sessions' spread, above when they understate it.

Which gyros moved (arrays): a gyro ``j`` turned by ``phi_j`` against the device turns ``R_ref_k`` by ``phi_k -
phi_ref`` (first order, the reference's frame), so a changed session's deviations say which gyros turned together.
Gyros that share one turn are grouped greedily (:func:`_groups`: the two groups whose joining raises the
least-squares chi-square the least join, while the rise stays below the chi-square point of ``alpha`` for 3 degrees
of freedom); the largest group (with the reference on a tie) is the device, which stayed, and every other group's
turn is given against it with its covariance. Chips on one site of a board that bends move as one group; a reference
that moved alone shows as every other gyro in one group turned the opposite way, and is reported so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..lie import exp, log

#: largest rotation between two sessions of one device (deg): beyond it the files are of different devices or
#: mountings, not one device to compare (the test is linear in the sessions' small differences)
MAX_SESSION_ANGLE_DEG = 15.0
#: default family-wise false-alarm rate of the change test (over all sessions compared)
ALPHA = 0.01


@dataclass(frozen=True)
class MovedGroup:
    """Gyros of an array that turned together in a changed session, against the gyros that stayed
    (:func:`compare_sessions`).

    Attributes
    ----------
    gyros : tuple of int
        The gyros (1-based, as in ``R_1_k``).
    rotation : ndarray (3,)
        Their common turn against the gyros that stayed (rad, rotation vector in the reference's frame: a gyro of the
        group has ``R_ref_k = Exp(rotation) R_ref_k,mean`` when the reference stayed).
    rotation_std : ndarray (3,)
        Its 1-sigma per axis.
    """

    gyros: tuple
    rotation: np.ndarray
    rotation_std: np.ndarray

    def __post_init__(self):
        for name in ("rotation", "rotation_std"):
            a = np.array(getattr(self, name), dtype=float)
            a.flags.writeable = False
            object.__setattr__(self, name, a)

    def to_dict(self) -> dict:
        return {"gyros": list(self.gyros), "rotation": self.rotation.tolist(),
                "rotation_std": self.rotation_std.tolist()}


@dataclass(frozen=True)
class SessionComparison:
    """The sessions of one device tested against one another (:func:`compare_sessions`).

    Attributes
    ----------
    names : tuple of str (n,)
        The sessions.
    rotations : tuple of str (m,)
        What was compared per session: ``"R_1_2"`` for a pair, ``"R_1_k"`` (1-based, the reference first) for an
        array.
    deviation : ndarray (n, m, 3)
        Each session's rotation(s) against the mean of the consistent sessions (the others, for a consistent one):
        ``R_session = Exp(d) R_mean`` (rad, the reference frame).
    deviation_std : ndarray (n, m, 3)
        The 1-sigma of ``deviation`` per axis (the session's repeatable covariance plus the mean's).
    z2 : ndarray (n,)
        ``d^T (P_session + P_mean)^-1 d``: chi-square with ``dof`` degrees of freedom where the device did not change.
    dof : int
        ``3 m``.
    p_value : ndarray (n,)
        Chance of a ``z2`` at least as large from noise alone.
    limit : float
        The ``z2`` beyond which a session changed (the chi-square point of ``alpha / n``).
    alpha : float
        Family-wise false-alarm rate of the test.
    changed : ndarray of bool (n,)
        The sessions beyond ``limit``.
    spread : float
        ``z2`` per degree of freedom of the consistent sessions (at least two) about their mean: 1 when their
        covariances explain their spread.
    spread_dof : int
        Its degrees of freedom, ``3 m (n_consistent - 1)``.
    mean_rotation : ndarray (m, 3, 3)
        The information-weighted mean of the consistent sessions' rotations.
    moved : tuple (n,) of tuple of MovedGroup
        Per session, the groups of gyros that turned against those that stayed (arrays, changed sessions only; empty
        otherwise: a pair's two gyros cannot say which of them moved).
    stayed : tuple (n,) of tuple of int
        Per session, the gyros that stayed (the largest group; empty where ``moved`` was not asked).
    notes : tuple of str
    """

    names: tuple
    rotations: tuple
    deviation: np.ndarray
    deviation_std: np.ndarray
    z2: np.ndarray
    dof: int
    p_value: np.ndarray
    limit: float
    alpha: float
    changed: np.ndarray
    spread: float
    spread_dof: int
    mean_rotation: np.ndarray
    moved: tuple = ()
    stayed: tuple = ()
    notes: tuple = ()

    def __post_init__(self):
        for name in ("deviation", "deviation_std", "z2", "p_value", "changed", "mean_rotation"):
            a = np.array(getattr(self, name))
            a.flags.writeable = False
            object.__setattr__(self, name, a)

    def to_dict(self) -> dict:
        """Plain JSON-ready values (arrays as lists)."""
        out = {"kind": "session_comparison"}
        for name in self.__dataclass_fields__:
            v = getattr(self, name)
            out[name] = v.tolist() if isinstance(v, np.ndarray) else list(v) if isinstance(v, tuple) else v
        out["moved"] = [[g.to_dict() for g in groups] for groups in self.moved]
        out["stayed"] = [list(g) for g in self.stayed]
        return out

    def summary(self) -> str:
        """A table for a person: per session the deviation (mdeg) with its 1-sigma, ``z2`` and the verdict."""
        mdeg = 180e3 / np.pi
        width = max(len(n) for n in self.names)
        lines = [f"{len(self.names)} sessions, {', '.join(self.rotations)} compared; changed where z2 > "
                 f"{self.limit:.1f} ({self.dof} dof, false alarms {self.alpha:g} over all sessions)"]
        for e, name in enumerate(self.names):
            rows = [f"{r}: [{', '.join(f'{v:7.1f}' for v in self.deviation[e, k] * mdeg)}] +- "
                    f"[{', '.join(f'{v:5.1f}' for v in self.deviation_std[e, k] * mdeg)}] mdeg"
                    for k, r in enumerate(self.rotations)]
            verdict = f"z2 {self.z2[e]:7.1f}  p {self.p_value[e]:.2g}  {'CHANGED' if self.changed[e] else 'consistent'}"
            if len(rows) == 1:
                lines.append(f"{name:>{width}}  {rows[0]}  {verdict}")
            else:   # an array: the verdict, then each rotation's deviation
                lines += [f"{name:>{width}}  {verdict}"] + [f"{'':>{width}}    {row}" for row in rows]
            if self.moved and self.moved[e]:
                lines.append(f"{'':>{width}}    against gyros {_numbers(self.stayed[e])} (which stayed), turned together:")
                lines += [f"{'':>{width}}      gyro{'s' if len(g.gyros) > 1 else ''} {_numbers(g.gyros)}: "
                          f"[{', '.join(f'{v:7.1f}' for v in g.rotation * mdeg)}] +- "
                          f"[{', '.join(f'{v:5.1f}' for v in g.rotation_std * mdeg)}] mdeg" for g in self.moved[e]]
        lines.append(f"consistent sessions' spread: z2 per dof {self.spread:.2f} ({self.spread_dof} dof; 1 when their "
                     "covariances explain it)")
        lines += list(self.notes)
        return "\n".join(lines)


def _numbers(gyros) -> str:
    """Gyro numbers as text: ``1, 2 and 5``."""
    g = [str(k) for k in gyros]
    return g[0] if len(g) == 1 else f"{', '.join(g[:-1])} and {g[-1]}"


def _labels(gyros) -> tuple:
    """The rotations' names ``R_i_k`` of the ``(i, k)`` of :func:`_rotations_of`."""
    return tuple(f"R_{i}_{k}" for i, k in gyros)


def _rotations_of(cal) -> tuple[list, np.ndarray, tuple]:
    """``(rotations, repeatable covariance (3m, 3m), gyros)`` of a pair or an array calibration; ``gyros``: the
    1-based ``(reference, k)`` of each rotation ``R_ref_k``."""
    from .array_result import ArrayCalibration
    from .model import PairCalibration

    if isinstance(cal, PairCalibration):
        return [cal.R_1_2], cal.repeatable_rotation_covariance, ((1, 2),)
    if isinstance(cal, ArrayCalibration):
        ks = [k for k in range(cal.n_gyros) if k != cal.reference]
        idx = np.concatenate([np.arange(3 * k, 3 * k + 3) for k in ks])
        P = cal.repeatable_rotation_covariance[np.ix_(idx, idx)]
        return [cal.R_ref_k[k] for k in ks], P, tuple((cal.reference + 1, k + 1) for k in ks)
    raise InputError(f"sessions: expected PairCalibration or ArrayCalibration results, got {type(cal).__name__}")


def _chi2_sf(x, dof: int):
    from scipy.special import gammaincc

    return gammaincc(0.5 * dof, 0.5 * np.asarray(x, float))


def _chi2_isf(p: float, dof: int) -> float:
    from scipy.special import gammainccinv

    return float(2.0 * gammainccinv(0.5 * dof, p))


def _inverse(P, name: str) -> np.ndarray:
    """The inverse of a session's rotation covariance; refused where it is not positive definite (or not finite)."""
    P = 0.5 * (P + P.T)
    lam = np.linalg.eigvalsh(P) if np.all(np.isfinite(P)) else np.full(len(P), np.nan)
    if not (lam.min() > 1e-12 * max(lam.max(), 0.0) and lam.max() > 0):
        raise InputError(f"{name}: expected a positive definite rotation covariance (a calibration that estimated the "
                         f"rotation), got eigenvalues {np.array2string(lam, precision=3)}")
    return np.linalg.inv(P)


def _deviations(rotations, base) -> np.ndarray:
    """(n, 3m): each session's ``Log(R R_base^T)`` per rotation, stacked."""
    return np.stack([np.concatenate([log(R @ B.T) for R, B in zip(rs, base)]) for rs in rotations])


def _mean(d, infos, members):
    """Information-weighted mean of the deviations of ``members`` and its covariance."""
    info = sum(infos[k] for k in members)
    cov = np.linalg.inv(info)
    return cov @ sum(infos[k] @ d[k] for k in members), cov


def _tested(d, Ps, infos, members, e):
    """Session ``e`` against the mean of ``members`` other than itself (all of them for a session outside):
    ``(deviation, its covariance, z2)``."""
    others = [k for k in members if k != e]
    m, M = _mean(d, infos, others)
    diff, C = d[e] - m, Ps[e] + M
    return diff, C, float(diff @ np.linalg.solve(C, diff))


def _group_fit(d, info, others, groups, ref):
    """Least squares of the deviations ``d`` (3m,) (information ``info``) of the gyros ``others`` (one per 3 rows)
    with one turn per group of ``groups`` (sets of gyro numbers), the reference's group held still:
    ``(chi2, turns (g, 3) of the groups in order (zero for the reference's), their covariance (3g, 3g))``."""
    free = [j for j, g in enumerate(groups) if ref not in g]
    H = np.zeros((d.size, 3 * len(free)))
    for i, k in enumerate(others):
        for c, j in enumerate(free):
            if k in groups[j]:
                H[3 * i:3 * i + 3, 3 * c:3 * c + 3] = np.eye(3)
    F = H.T @ info @ H
    cov_free = np.linalg.inv(F) if free else np.zeros((0, 0))
    x = cov_free @ (H.T @ info @ d) if free else np.zeros(0)
    r = d - H @ x
    turns, cov = np.zeros((len(groups), 3)), np.zeros((3 * len(groups), 3 * len(groups)))
    idx = np.concatenate([np.arange(3 * j, 3 * j + 3) for j in free]) if free else np.zeros(0, int)
    turns[free] = x.reshape(-1, 3)
    cov[np.ix_(idx, idx)] = cov_free
    return float(r @ info @ r), turns, cov


def _groups(d, C, gyros, limit3: float) -> tuple[tuple, tuple]:
    """``(moved, stayed)`` of an array session's deviations ``d`` (3m,) with covariance ``C`` (``gyros``: the
    ``(reference, k)`` of each rotation, :func:`_rotations_of`): the gyros grouped by
    a common turn (the module docstring), each group but the largest as a :class:`MovedGroup` against it."""
    ref, others = gyros[0][0], [k for _, k in gyros]
    info = np.linalg.inv(0.5 * (C + C.T))
    groups = [{ref}] + [{k} for k in others]
    chi2 = 0.0
    while len(groups) > 1:
        trials = []
        for a in range(len(groups)):
            for b in range(a + 1, len(groups)):
                joined = [g for j, g in enumerate(groups) if j not in (a, b)] + [groups[a] | groups[b]]
                trials.append((_group_fit(d, info, others, joined, ref)[0], joined))
        best, joined = min(trials, key=lambda t: t[0])
        if best - chi2 > limit3:
            break
        groups, chi2 = joined, best
    groups.sort(key=lambda g: (-len(g), ref not in g, min(g)))     # the device first: the largest, the reference's
    _, turns, cov = _group_fit(d, info, others, groups, ref)
    g = len(groups)
    T = np.kron(np.eye(g) - np.outer(np.ones(g), np.eye(g)[0]), np.eye(3))     # each turn less the device's
    turns, cov = (T @ turns.ravel()).reshape(-1, 3), T @ cov @ T.T
    moved = tuple(MovedGroup(tuple(sorted(g)), turns[j], np.sqrt(np.clip(np.diag(cov)[3 * j:3 * j + 3], 0.0, None)))
                  for j, g in enumerate(groups) if j > 0)
    return moved, tuple(sorted(groups[0]))


def compare_sessions(calibrations, names=None, *, alpha: float = ALPHA) -> SessionComparison:
    """Test whether a device changed between sessions: each session's rotation(s) against the others' mean in units
    of their repeatable covariances (see the module docstring).

    Parameters
    ----------
    calibrations : sequence of PairCalibration or ArrayCalibration
        Two or more calibrations of one device, all pairs or all arrays of the same gyros and reference.
    names : sequence of str, optional
        The sessions' names (default ``session 1`` ...).
    alpha : float
        Family-wise false-alarm rate over all sessions (default :data:`ALPHA`).

    Returns
    -------
    SessionComparison

    Raises
    ------
    InputError
        Fewer than two calibrations, mixed kinds or gyros, a rotation without a covariance, or sessions more than
        :data:`MAX_SESSION_ANGLE_DEG` apart (not one device).
    """
    cals = list(calibrations)
    n = len(cals)
    if n < 2:
        raise InputError(f"sessions: expected at least two calibrations of one device, got {n}")
    names = tuple(f"session {e + 1}" for e in range(n)) if names is None else tuple(str(v) for v in names)
    if len(names) != n:
        raise InputError(f"sessions: expected one name per calibration ({n}), got {len(names)}")
    if not (0.0 < float(alpha) < 1.0):
        raise InputError(f"alpha: expected a false-alarm rate in (0, 1), got {alpha!r}")
    parts = [_rotations_of(c) for c in cals]
    gyros = parts[0][2]
    labels = _labels(gyros)
    for name, (_, _, other) in zip(names, parts):
        if other != gyros:
            raise InputError(f"sessions: expected calibrations of the same gyros ({', '.join(labels)}), got "
                             f"{', '.join(_labels(other))} in {name}")
    rotations = [p[0] for p in parts]
    base = rotations[0]
    Ps = [p[1] for p in parts]
    infos = [_inverse(P, f"{name}'s rotation covariance") for name, P in zip(names, Ps)]
    d = _deviations(rotations, base)
    m = len(labels)
    angles = np.degrees(np.linalg.norm(d.reshape(n, m, 3), axis=2))
    if angles.max() > MAX_SESSION_ANGLE_DEG:
        e, k = np.unravel_index(np.argmax(angles), angles.shape)
        raise InputError(f"sessions: expected calibrations of one device (rotations within {MAX_SESSION_ANGLE_DEG:g} "
                         f"deg of one another), got {angles[e, k]:.3g} deg between {names[0]} and {names[e]} "
                         f"(rotation {labels[k]})")
    dof = 3 * m
    limit = _chi2_isf(alpha / n, dof)
    members = list(range(n))
    while len(members) > 2:     # the most extreme changed session leaves the mean, one at a time
        z2 = {e: _tested(d, Ps, infos, members, e)[2] for e in members}
        worst = max(z2, key=z2.get)
        if z2[worst] <= limit:
            break
        members.remove(worst)
    # re-linearise about the consistent sessions' mean (the differences are small: one step settles it)
    mean, _ = _mean(d, infos, members)
    base = [exp(mean[3 * k:3 * k + 3]) @ B for k, B in enumerate(base)]
    d = _deviations(rotations, base)
    tested = [_tested(d, Ps, infos, members, e) for e in range(n)]
    dev = np.stack([t[0] for t in tested])
    z2 = np.array([t[2] for t in tested])
    std = np.stack([np.sqrt(np.clip(np.diag(t[1]), 0.0, None)) for t in tested])
    changed = z2 > limit
    mean, _ = _mean(d, infos, members)
    spread_dof = dof * (len(members) - 1)
    spread = float(sum((d[e] - mean) @ infos[e] @ (d[e] - mean) for e in members)) / spread_dof
    moved, stayed = [()] * n, [()] * n
    if m > 1:                   # an array: which gyros moved, in each changed session
        for e in np.flatnonzero(changed):
            moved[e], stayed[e] = _groups(dev[e], tested[e][1], gyros, _chi2_isf(alpha, 3))
    notes = []
    if n == 2 and changed.any():
        notes.append("two sessions: they differ beyond their covariances, but which one moved takes a third session")
    if len(members) < n and n > 2:
        notes.append(f"the mean is of the {len(members)} consistent sessions; "
                     f"{', '.join(names[e] for e in range(n) if e not in members)} left it (changed)")
    return SessionComparison(
        names=names, rotations=labels, deviation=dev.reshape(n, m, 3), deviation_std=std.reshape(n, m, 3), z2=z2,
        dof=dof, p_value=_chi2_sf(z2, dof), limit=limit, alpha=float(alpha), changed=changed, spread=spread,
        spread_dof=spread_dof, mean_rotation=np.stack([exp(mean[3 * k:3 * k + 3]) @ B for k, B in enumerate(base)]),
        moved=tuple(moved) if m > 1 else (), stayed=tuple(stayed) if m > 1 else (), notes=tuple(notes))
