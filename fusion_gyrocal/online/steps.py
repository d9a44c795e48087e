"""Screening the tracker's innovations: the gate (flex spikes), the CUSUM (step changes), recent samples,
and the blocks a run is cut into.

Each works on a block of per-sample normalised innovations ``d^2 = r^T S^-1 r`` (chi-square(3) when
the filter is consistent); a block of one sample is the per-sample mode, so both modes share them.
"""

from __future__ import annotations

import numpy as np


class InnovationGate:
    """Chi-square gate on ``d^2`` that also drops the neighbours of a gated sample.

    Inside a block the ``neighbours`` samples on each side of a gated one are dropped; the
    ``neighbours`` samples after a gated one are dropped even when they fall in the next block
    (``pending``): samples already folded into the filter are never revisited.
    """

    __slots__ = ("limit", "neighbours", "pending")

    def __init__(self, limit: float, neighbours: int, pending: int = 0):
        self.limit, self.neighbours, self.pending = float(limit), int(neighbours), int(pending)

    def keep(self, d2, *, fresh: bool = False) -> list[bool]:
        """Which samples of a block to use (a list of B bools) from their ``d2`` (a sequence of B floats);
        ``fresh`` forgets the drops owed by earlier blocks. A plain loop: a block of one sample (the per-sample
        mode) costs a few Python operations, a block of a hundred about what a vectorised mask does."""
        if fresh:
            self.pending = 0
        limit, pending = self.limit, self.pending
        keep = [x <= limit for x in d2]    # NaN is gated too
        if not pending and all(keep):
            return keep
        B, n = len(keep), self.neighbours
        last = -1                          # the last gated sample
        for k, ok in enumerate(keep.copy()):
            if not ok:
                last = k
                lo = k - n if k > n else 0
                keep[lo:k + n + 1] = [False] * (min(k + n + 1, B) - lo)
        carry = pending - B if pending > B else 0
        if last >= 0 and n - (B - 1 - last) > carry:
            carry = n - (B - 1 - last)
        if pending:
            keep[:pending] = [False] * min(pending, B)
        self.pending = carry
        return keep


class Cusum:
    """One-sided CUSUM of ``min(d^2, clip) / 3 - 1 - allowance`` (a step raises the innovations).

    The level restarts from zero whenever it would go negative; its last zero estimates the
    onset of a change. :meth:`scan` runs the recursion sample by sample over a block (a plain loop:
    as fast as a vectorised scan for blocks of a hundred, and ten times faster for one sample).
    """

    __slots__ = ("allowance", "threshold", "clip", "level", "zero_t")

    def __init__(self, allowance: float, threshold: float, clip: float, t0: float):
        self.allowance, self.threshold, self.clip = float(allowance), float(threshold), float(clip)
        self.level, self.zero_t = 0.0, float(t0)

    def reset(self, t: float) -> None:
        """Start again from zero at time ``t``."""
        self.level, self.zero_t = 0.0, float(t)

    def scan(self, t, d2):
        """Run over a block (times ``t``, ``d2`` a sequence of floats); ``(t_detected, onset)`` of the first alarm
        (the level then restarts), else None."""
        level, clip, shift, threshold = self.level, self.clip, 1.0 + self.allowance, self.threshold
        zero = -1
        for k, x in enumerate(d2):
            level += (x if x <= clip else clip) / 3.0 - shift      # NaN counts as the clip
            if level <= 0.0:
                level, zero = 0.0, k
            elif level > threshold:
                onset = float(t[zero]) if zero >= 0 else self.zero_t
                self.level = 0.0
                return float(t[k]), onset
        if zero >= 0:
            self.zero_t = float(t[zero])
        self.level = level
        return None


class SampleRing:
    """Fixed-capacity ring buffer of ``[t, omega_1, omega_2]`` rows (the re-seed window, replays); the times and
    the two gyros' rates are kept in three arrays (a row is written as three contiguous slices)."""

    __slots__ = ("t", "w1", "w2", "cap", "n", "head")

    def __init__(self, capacity: int):
        self.t, self.w1, self.w2 = np.empty(capacity), np.empty((capacity, 3)), np.empty((capacity, 3))
        self.cap = capacity
        self.n = 0       # rows stored
        self.head = 0    # next write position

    def push(self, t, w1, w2) -> None:
        """Append sample rows (``t`` (m,), ``w1``/``w2`` (m, 3)); the oldest are overwritten."""
        m, cap, head = len(t), self.cap, self.head
        if m >= cap:
            t, w1, w2, m, head = t[-cap:], w1[-cap:], w2[-cap:], cap, 0
        end = head + m
        if end <= cap:
            self.t[head:end] = t
            self.w1[head:end] = w1
            self.w2[head:end] = w2
        else:
            k = cap - head
            self.t[head:], self.w1[head:], self.w2[head:] = t[:k], w1[:k], w2[:k]
            self.t[:m - k], self.w1[:m - k], self.w2[:m - k] = t[k:], w1[k:], w2[k:]
        self.head = end if end < cap else end - cap
        n = self.n + m
        self.n = n if n < cap else cap

    def rows(self) -> np.ndarray:
        """Every stored row ``[t, omega_1, omega_2]`` (n, 7), oldest first (a copy)."""
        parts = (slice(0, self.n),) if self.n < self.cap else (slice(self.head, None), slice(0, self.head))
        return np.concatenate([np.column_stack((self.t[s], self.w1[s], self.w2[s])) for s in parts])

    def since(self, t0: float) -> np.ndarray:
        """Stored rows at or after ``t0``, oldest first."""
        data = self.rows()
        return data[data[:, 0] >= t0]

    def oldest(self) -> float:
        """Time of the oldest stored row (inf when empty)."""
        if self.n == 0:
            return np.inf
        return float(self.t[0 if self.n < self.cap else self.head])

    def resized(self, capacity: int) -> "SampleRing":
        """A new ring of ``capacity`` holding the most recent rows of this one."""
        new = SampleRing(capacity)
        data = self.rows()
        if data.shape[0]:
            new.push(data[:, 0], data[:, 1:4], data[:, 4:7])
        return new


def block_spans(t, size: int, max_gap_s: float | None) -> list[tuple[int, int]]:
    """``(start, end)`` of blocks of about ``size`` samples that never straddle a gap (a short tail joins
    the block before it); a step larger than ``max_gap_s`` (default 5 median intervals) is a gap."""
    if max_gap_s is None:
        max_gap_s = 5.0 * float(np.median(np.diff(t))) if t.shape[0] > 1 else np.inf
    bounds = np.concatenate([[0], np.flatnonzero(np.diff(t) > max_gap_s) + 1, [t.shape[0]]])
    spans = []
    for lo, hi in zip(bounds[:-1].tolist(), bounds[1:].tolist()):
        for s in range(lo, hi, size):
            e = min(s + size, hi)
            if hi - e < size // 2 and e < hi:   # fold a short tail into this block
                e = hi
            spans.append((s, e))
            if e == hi:
                break
    return spans
