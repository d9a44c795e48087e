"""The tracker's history: :class:`TrackHistory` (frozen, one row per filter update) and its recorder.

A :class:`HistoryRecorder` takes one row per update from the filter's current estimate and builds
the frozen :class:`TrackHistory` on demand (with the truth columns and the NEES when a run was given
a :class:`PairTruth`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.model import BIAS, ROT, S1, S2
from ..errors import InputError, OptionError
from ..lie import log

__all__ = ["HistoryRecorder", "PairTruth", "ReseedEvent", "TrackHistory"]


@dataclass(frozen=True)
class PairTruth:
    """Ground truth of a pair per sample (for NEES and plots), in any gauge; ``truth[rows]`` selects samples.

    Attributes
    ----------
    R_1_2 : ndarray (N, 3, 3)
    scale_1, scale_2 : ndarray (N, 3)
    bias : ndarray (N, 3)
        Combined bias ``b_1 - A b_2`` (Eq. 5), rad/s.
    """

    R_1_2: np.ndarray
    scale_1: np.ndarray
    scale_2: np.ndarray
    bias: np.ndarray

    def __post_init__(self):
        n = np.asarray(self.scale_1).shape[0]
        for name, tail in (("R_1_2", (3, 3)), ("scale_1", (3,)), ("scale_2", (3,)), ("bias", (3,))):
            arr = np.array(getattr(self, name), dtype=np.float64)
            if arr.shape != (n,) + tail:
                raise InputError(f"PairTruth.{name}: expected shape {(n,) + tail}, got {arr.shape}")
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return self.scale_1.shape[0]

    def __getitem__(self, rows) -> "PairTruth":
        """The truth at some samples (a slice or an index array), e.g. those a tracker runs over."""
        return PairTruth(self.R_1_2[rows], self.scale_1[rows], self.scale_2[rows], self.bias[rows])


@dataclass(frozen=True)
class ReseedEvent:
    """A detected step change and what the tracker did about it.

    Attributes
    ----------
    t_detected : float
        Time of the CUSUM alarm (s).
    t_onset : float
        Estimated change time (the CUSUM's last zero), start of the re-seed window.
    t_applied : float
        End of the re-seed window (when the batch solve ran); NaN if it never ran.
    accepted : bool
        True if the filter was re-seeded (the batch solve differed significantly from the
        filter's state at the alarm).
    statistic : float
        Chi-square of the batch-minus-filter (at the alarm) difference in the observable
        coordinates (NaN if the solve failed).
    threshold : float
        Chi-square quantile the statistic was compared with.
    reason : str
        Short explanation.
    """

    t_detected: float
    t_onset: float
    t_applied: float
    accepted: bool
    statistic: float
    threshold: float
    reason: str


def _ro(a):
    arr = np.array(a, dtype=np.float64)
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class TrackHistory:
    """Estimate history of a :class:`GyroPairTracker` with 1-sigma bands.

    One row per filter update (per sample in the per-sample mode, per block in the fast mode).

    Attributes
    ----------
    t : ndarray (M,)
        Time of each row (s); in the fast mode the mean time of the block.
    R_1_2 : ndarray (M, 3, 3)
    rotation_std : ndarray (M, 3)
        1-sigma of the rotation error ``dtheta`` (rad, gyro 1's frame; ``R_true = Exp(dtheta) R``).
    scale_1, scale_2, scale_1_std, scale_2_std : ndarray (M, 3)
        Scale factors in the tracker's gauge and their 1-sigma.
    bias, bias_std : ndarray (M, 3)
        Combined bias (rad/s) and its 1-sigma.
    nis : ndarray (M,)
        Normalised innovation squared per degree of freedom of the accepted samples (about 1
        when consistent; NaN when every sample of the row was rejected).
    n_used : ndarray (M,) of int
        Samples folded into each row's update.
    nees : ndarray (M,) or None
        Normalised estimation error squared against the truth (observable coordinates,
        ``nees_dof`` degrees of freedom), when a truth was given.
    nees_dof : int
    truth_R_1_2, truth_scale_1, truth_scale_2, truth_bias : ndarray or None
        The truth at each row, scales expressed in the tracker's gauge.
    reseeds : tuple of ReseedEvent
    n_samples, n_rejected : int
        Samples seen and samples rejected by the gate.
    gauge : str
        How the unobservable scale directions are held.
    mode : str
        ``"sample"``, ``"fast"``, ``"mixed"`` (both kinds of rows) or ``"none"`` (no update yet).
    """

    t: np.ndarray
    R_1_2: np.ndarray
    rotation_std: np.ndarray
    scale_1: np.ndarray
    scale_1_std: np.ndarray
    scale_2: np.ndarray
    scale_2_std: np.ndarray
    bias: np.ndarray
    bias_std: np.ndarray
    nis: np.ndarray
    n_used: np.ndarray
    nees: np.ndarray | None
    nees_dof: int
    truth_R_1_2: np.ndarray | None
    truth_scale_1: np.ndarray | None
    truth_scale_2: np.ndarray | None
    truth_bias: np.ndarray | None
    reseeds: tuple
    n_samples: int
    n_rejected: int
    gauge: str
    mode: str

    def __post_init__(self):
        for f in ("t", "R_1_2", "rotation_std", "scale_1", "scale_1_std", "scale_2", "scale_2_std", "bias",
                  "bias_std", "nis", "nees", "truth_R_1_2", "truth_scale_1", "truth_scale_2", "truth_bias"):
            v = getattr(self, f)
            if v is not None:
                object.__setattr__(self, f, _ro(v))
        n_used = np.array(self.n_used, dtype=np.int64)
        n_used.flags.writeable = False
        object.__setattr__(self, "n_used", n_used)
        object.__setattr__(self, "reseeds", tuple(self.reseeds))

    def __len__(self) -> int:
        return self.t.shape[0]

    @property
    def rotation_change(self) -> np.ndarray:
        """(M, 3) rotation of ``R_1_2`` relative to the first row, ``Log(R_k R_0^T)`` (rad, gyro 1 frame)."""
        if len(self) == 0:
            return np.zeros((0, 3))
        return log(self.R_1_2 @ self.R_1_2[0].T)

    @property
    def rotation_error(self) -> np.ndarray | None:
        """(M, 3) ``Log(R_true R_k^T)``: the rotation error in the ``dtheta`` convention, or None."""
        if self.truth_R_1_2 is None:
            return None
        return log(self.truth_R_1_2 @ np.swapaxes(self.R_1_2, 1, 2))

    @property
    def normalised_error(self) -> np.ndarray | None:
        """(M, 12) truth minus estimate over its 1-sigma, or None: :attr:`rotation_error`, then
        ``truth_scale_1 - scale_1``, ``truth_scale_2 - scale_2`` and ``truth_bias - bias``, each
        divided by its ``*_std`` (about N(0, 1) per component when the bands are consistent)."""
        if self.truth_R_1_2 is None:
            return None
        return np.hstack([self.rotation_error / self.rotation_std,
                          (self.truth_scale_1 - self.scale_1) / self.scale_1_std,
                          (self.truth_scale_2 - self.scale_2) / self.scale_2_std,
                          (self.truth_bias - self.bias) / self.bias_std])


# one recorded row: t, R_1_2 (9), scale_1 (3), scale_2 (3), bias (3), variances of the error state (12, the
# diagonal of P as recorded: their 1-sigma is taken once in ``build``), nis, n_used
_T, _R, _S1, _S2, _B, _SD, _NIS, _USED, _WIDTH = 0, slice(1, 10), slice(10, 13), slice(13, 16), slice(16, 19), \
    slice(19, 31), 31, 32, 33


class HistoryRecorder:
    """Rows of a :class:`TrackHistory` as the tracker makes them (one per filter update).

    Rows live in one preallocated float array (33 numbers, 264 bytes a row, grown by doubling).
    With ``max_rows``, memory is bounded: when the array holds ``max_rows`` rows, every other row
    is dropped and from then on only every 2nd (then 4th, ...) update is recorded, so the rows
    stay evenly spread over the whole run. ``paused`` suppresses recording (a replay re-processes
    samples whose rows already exist).
    """

    __slots__ = ("_buf", "_n", "_modes", "paused", "max_rows", "every", "_count")

    def __init__(self, max_rows: int | None = None):
        self._buf = np.empty((64 if max_rows is None else min(64, max_rows), _WIDTH))
        self._n = 0
        self._modes: set[str] = set()
        self.paused = False
        self.max_rows = max_rows
        self.every = 1          # record one update in ``every``
        self._count = 0         # updates offered so far

    def __len__(self) -> int:
        return self._n

    def copy(self, max_rows: int | None) -> "HistoryRecorder":
        """An independent copy bounded by ``max_rows`` (None: unbounded from now on)."""
        new = HistoryRecorder(max_rows)
        new._buf = self._buf[: max(self._n, 1)].copy()
        new._n, new._modes, new.every, new._count = self._n, set(self._modes), self.every, self._count
        while new.max_rows is not None and new._n > new.max_rows:
            new._decimate()
        return new

    def require_every_update(self, updates: int, what: str) -> None:
        """Refuse (:class:`~fusion_gyrocal.errors.OptionError`) when the next ``updates`` updates would not each
        get a row: the bound would thin the history (or already has), and ``what`` needs one row per update."""
        if self.max_rows is None or (self.every == 1 and self._n + updates <= self.max_rows):
            return
        done = (f"the history is already thinned to every {self.every}th update" if self.every > 1 else
                f"{self._n} row(s) so far + {updates} update(s) of this run exceed it")
        raise OptionError(f"{what}: needs one history row per update, but the history is bounded by "
                          f"history_max_rows={self.max_rows} and {done}; pass history_max_rows=None (the full "
                          "history) in the tracker's configuration")

    def _decimate(self) -> None:
        kept = self._buf[: self._n: 2].copy()
        self._buf[: kept.shape[0]] = kept
        self._n = kept.shape[0]
        self.every *= 2

    def add(self, t: float, R, s1, s2, b, P, nis: float, n_used: int, mode: str) -> None:
        """Record the estimate ``(R, s1, s2, b)`` with the error covariance ``P`` after an update."""
        if self.paused:
            return
        self._modes.add(mode)
        k = self._count
        self._count += 1
        if k % self.every:
            return
        if self._n == self._buf.shape[0]:
            if self.max_rows is not None and self._n >= self.max_rows:
                self._decimate()
                if k % self.every:
                    return
            else:
                cap = 2 * self._buf.shape[0] if self.max_rows is None else min(2 * self._buf.shape[0], self.max_rows)
                grown = np.empty((cap, _WIDTH))
                grown[: self._n] = self._buf[: self._n]
                self._buf = grown
        row = self._buf[self._n]
        row[_T], row[_NIS], row[_USED] = t, nis, n_used
        np.concatenate((R.ravel(), s1, s2, b, P.diagonal()), out=row[_R.start:_SD.stop])    # variances: 1-sigma in build
        self._n += 1

    def build(self, *, reseeds, n_samples: int, n_rejected: int, gauge: str, nees_dof: int, nees=None,
              truth=None) -> TrackHistory:
        """The frozen history; ``nees`` (M,) and ``truth`` ``(R_1_2, scale_1, scale_2, bias)`` per row, if given."""
        M = self._n
        a = self._buf[:M].copy()
        sd = np.sqrt(np.maximum(a[:, _SD], 0.0))
        modes = self._modes
        mode = "mixed" if len(modes) > 1 else (next(iter(modes)) if modes else "none")
        tr = (None,) * 4 if truth is None else truth
        return TrackHistory(
            t=a[:, _T], R_1_2=a[:, _R].reshape(M, 3, 3), rotation_std=sd[:, ROT], scale_1=a[:, _S1],
            scale_1_std=a[:, _S1] * sd[:, S1], scale_2=a[:, _S2], scale_2_std=a[:, _S2] * sd[:, S2],
            bias=a[:, _B], bias_std=sd[:, BIAS], nis=a[:, _NIS], n_used=a[:, _USED].astype(np.int64),
            nees=None if nees is None else np.asarray(nees, float), nees_dof=nees_dof,
            truth_R_1_2=tr[0], truth_scale_1=tr[1], truth_scale_2=tr[2], truth_bias=tr[3],
            reseeds=tuple(reseeds), n_samples=int(n_samples), n_rejected=int(n_rejected), gauge=gauge, mode=mode)
