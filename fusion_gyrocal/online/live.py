"""Live input for the tracker and the streaming calibrator: timestamped samples of two gyros as they arrive.

Three parts, each usable alone:

* :class:`LiveAligner` pairs the samples of gyro 1 and gyro 2, which may arrive in any order between the two
  streams (each stream in its own time order): every gyro-1 sample is paired with gyro 2 at the same instant
  (``time_offset_s`` added to gyro 2's clock, ARCHITECTURE convention): gyro 2's sample when one has that exact
  timestamp (a shared clock), else the linear interpolation between the two gyro-2 samples around it (none
  across a gap larger than ``max_gap_s``). Its buffers are bounded (``max_buffer`` samples per stream); what it
  drops (late, unmatched, overflow) is counted in :attr:`LiveAligner.dropped`.
* :class:`LiveBlocks` cuts the aligned samples into the tracker's blocks exactly as the batch tracker does
  (:func:`~fusion_gyrocal.online.steps.block_spans`: blocks of ``block_size`` that never straddle a gap, a short
  tail folded into the block before it), holding at most ``1.5 * block_size`` samples back.
* :class:`LivePair` feeds the blocks to a :class:`~fusion_gyrocal.online.tracker.GyroPairTracker` (seeded by a
  calibration, or by the first ``seed_s`` seconds of the stream) and to a
  :class:`~fusion_gyrocal.online.stream.StreamingCalibrator`, and reports the tracked state and the step alarms
  as JSON-ready dicts (:meth:`LivePair.state`, :meth:`LivePair.push` returns the events).

Fed the samples of a recording in any interleaving, :class:`LivePair` ends in the state the batch tracker
(:meth:`GyroPairTracker.run` on the same aligned samples, the same ``max_gap_s``) ends in: the same blocks reach
the same filter in the same order.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from ..errors import GyroCalError, InputError, OptionError
from ..lie import log

GYROS = (1, 2)


class LiveAligner:
    """Pair two gyros' samples by time as they arrive, with bounded buffers.

    Parameters
    ----------
    time_offset_s : float
        Added to gyro 2's timestamps to put them on gyro 1's clock.
    max_gap_s : float, optional
        No interpolation across a step of gyro 2 larger than this (s); default: 5 times the median of gyro 2's
        last 64 intervals (updated every 64 samples).
    max_buffer : int
        Samples held per stream at most; when one stream stalls, the other's oldest samples are dropped
        (counted in ``dropped["overflow"]``).

    Examples
    --------
    >>> a = LiveAligner()
    >>> _ = a.push(2, 0.0, [0, 0, 1.0]), a.push(2, 0.1, [0, 0, 2.0])
    >>> t, w1, w2 = a.push(1, 0.05, [1.0, 0, 0])
    >>> float(t[0]), w2[0].tolist()
    (0.05, [0.0, 0.0, 1.5])
    """

    def __init__(self, *, time_offset_s: float = 0.0, max_gap_s: float | None = None, max_buffer: int = 4096):
        if not math.isfinite(time_offset_s):
            raise OptionError(f"time_offset_s: expected a finite offset in seconds, got {time_offset_s!r}")
        if max_gap_s is not None and not (math.isfinite(max_gap_s) and max_gap_s > 0):
            raise OptionError(f"max_gap_s: expected a positive duration in seconds, got {max_gap_s!r}")
        if isinstance(max_buffer, bool) or int(max_buffer) != max_buffer or max_buffer < 2:
            raise OptionError(f"max_buffer: expected an integer >= 2, got {max_buffer!r}")
        self.time_offset_s = float(time_offset_s)
        self.max_gap_s = None if max_gap_s is None else float(max_gap_s)
        self.max_buffer = int(max_buffer)
        self._buf1: deque = deque()        # (t, omega) of gyro 1 waiting for gyro 2
        self._buf2: deque = deque()        # (t + offset, omega) of gyro 2: the one at or before buf1[0] on
        self._last = {1: -math.inf, 2: -math.inf}
        self._steps2: deque = deque(maxlen=64)
        self._gap2 = math.inf
        self._n2 = 0                       # gyro-2 intervals seen
        self.dropped = {"late": 0, "unmatched": 0, "overflow": 0}

    @property
    def buffered(self) -> tuple[int, int]:
        """Samples of gyro 1 and gyro 2 held now."""
        return len(self._buf1), len(self._buf2)

    def push(self, gyro: int, t: float, omega):
        """Take one sample of gyro ``gyro`` (1 or 2) at time ``t`` (s, its own clock), rates ``omega`` (3, rad/s).

        Returns
        -------
        t, omega_1, omega_2 : ndarray (m,), (m, 3), (m, 3)
            The gyro-1 samples this one completed, with gyro 2 at their instants (``m`` may be 0).

        Raises
        ------
        InputError
            ``gyro`` not 1 or 2, ``omega`` not 3 finite numbers, or ``t`` not finite. A sample older than the
            last of its stream is not an error: it is dropped and counted (``dropped["late"]``).
        """
        if gyro not in GYROS:
            raise InputError(f"gyro: expected 1 or 2, got {gyro!r}")
        w = np.asarray(omega, dtype=np.float64).reshape(-1)
        t = float(t)
        if w.shape != (3,) or not np.isfinite(w).all() or not math.isfinite(t):
            raise InputError(f"gyro {gyro}: expected a finite time and 3 finite rates, got t = {t!r}, "
                             f"omega = {np.asarray(omega).tolist()!r}")
        if gyro == 2:
            t += self.time_offset_s
        if not t > self._last[gyro]:
            self.dropped["late"] += 1
            return self._empty()
        if gyro == 1:
            self._buf1.append((t, w))
            if len(self._buf1) > self.max_buffer:
                self._buf1.popleft()
                self.dropped["overflow"] += 1
        else:
            if self._last[2] > -math.inf:
                self._steps2.append(t - self._last[2])
                self._n2 += 1
                if self._n2 in (1, 2, 4, 8, 16, 32) or self._n2 % self._steps2.maxlen == 0:   # kept cheap
                    self._gap2 = 5.0 * float(np.median(self._steps2))
            self._buf2.append((t, w))
            if len(self._buf2) > self.max_buffer:
                self._buf2.popleft()
                self.dropped["overflow"] += 1
        self._last[gyro] = t
        return self._drain()

    @staticmethod
    def _empty():
        return np.empty(0), np.empty((0, 3)), np.empty((0, 3))

    def _drain(self):
        """Pair every gyro-1 sample that gyro 2 has passed; keep gyro 2 from the sample at or before the next."""
        b1, b2 = self._buf1, self._buf2
        out_t, out_1, out_2 = [], [], []
        gap = self.max_gap_s if self.max_gap_s is not None else self._gap2
        while b1 and b2 and b2[-1][0] >= b1[0][0]:
            t1, w1 = b1.popleft()
            while len(b2) >= 2 and b2[1][0] <= t1:
                b2.popleft()
            ta, wa = b2[0]
            if ta == t1:
                w2 = wa
            elif ta > t1:                          # before gyro 2's first sample
                self.dropped["unmatched"] += 1
                continue
            else:
                tb, wb = b2[1]
                if tb - ta > gap:                  # inside a gap of gyro 2
                    self.dropped["unmatched"] += 1
                    continue
                f = (t1 - ta) / (tb - ta)
                w2 = wa + f * (wb - wa)
            out_t.append(t1)
            out_1.append(w1)
            out_2.append(w2)
        if not out_t:
            return self._empty()
        return np.array(out_t), np.array(out_1), np.array(out_2)


class LiveBlocks:
    """Cut aligned samples into the batch tracker's blocks as they arrive.

    A block of ``block_size`` samples is released once ``block_size + block_size // 2`` samples are held (so no
    later sample can make it the short tail the batch cut folds in); a step larger than ``max_gap_s`` or
    :meth:`close` ends a segment and releases the rest with the batch rule
    (:func:`~fusion_gyrocal.online.steps.block_spans`).
    """

    def __init__(self, block_size: int, max_gap_s: float):
        if isinstance(block_size, bool) or int(block_size) != block_size or block_size < 1:
            raise OptionError(f"block_size: expected an integer >= 1, got {block_size!r}")
        if not (math.isfinite(max_gap_s) and max_gap_s > 0):
            raise OptionError(f"max_gap_s: expected a positive duration in seconds, got {max_gap_s!r}")
        self.size, self.max_gap_s = int(block_size), float(max_gap_s)
        self._t: list = []
        self._w1: list = []
        self._w2: list = []

    def push(self, t, omega_1, omega_2) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Add aligned samples (``(m,)``, ``(m, 3)``, ``(m, 3)``); return the blocks now complete."""
        out = []
        for k in range(len(t)):
            if self._t and t[k] - self._t[-1] > self.max_gap_s:
                out += self._release(final=True)
            self._t.append(t[k])
            self._w1.append(omega_1[k])
            self._w2.append(omega_2[k])
            if len(self._t) >= self.size + self.size // 2:
                out += self._release(final=False)
        return out

    def close(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """The blocks of the samples still held (the end of the stream)."""
        return self._release(final=True)

    def _release(self, final: bool):
        n, size, out = len(self._t), self.size, []
        s = 0
        while s < n:
            e = min(s + size, n)
            if final and n - e < size // 2 and e < n:
                e = n
            if not final and n - e < size // 2:
                break
            out.append((np.array(self._t[s:e]), np.array(self._w1[s:e]), np.array(self._w2[s:e])))
            s = e
        del self._t[:s], self._w1[:s], self._w2[:s]
        return out


def _num(v) -> float | None:
    """A float for JSON: None where it is not finite (strict JSON has no NaN or Infinity)."""
    v = float(v)
    return v if math.isfinite(v) else None


def _vec(x) -> list:
    return [_num(v) for v in np.asarray(x).reshape(-1)]


class LivePair:
    """The tracker and the streaming calibrator of a gyro pair, fed sample by sample from two live streams.

    Parameters
    ----------
    tracker : GyroPairTracker, optional
        A seeded tracker to continue. Without it the tracker is seeded by
        :meth:`GyroPairTracker.from_samples` on the first ``seed_s`` seconds of aligned samples.
    seed_s : float
        Seconds of aligned samples that seed the tracker when ``tracker`` is None. When that solve fails (too little
        motion yet: a ``"seed_failed"`` event says why), the window slides: the last ``seed_s / 2`` seconds are
        kept and the seed is tried again ``seed_s / 2`` seconds later, until it succeeds.
    calibrator : StreamingCalibrator, optional
        Fed every block too (default: a sliding window of ``window_s``); its estimate is in :meth:`state`.
    window_s : float
        Window of the default streaming calibrator (s).
    mode : {"fast", "sample"}
        Blocks of ``block_size`` folded into one update each, or one update per sample (as
        :meth:`GyroPairTracker.run`).
    block_size : int, optional
        Default: the tracker's ``config.block_size``.
    max_gap_s : float, optional
        A larger step between aligned samples is a gap (no block straddles it). Default: 5 times the median
        interval of the seed window (with a given tracker: of the first block, held back until complete).
    time_offset_s : float, optional
        Added to gyro 2's clock (default: the tracker's seed offset, else 0).
    max_buffer : int
        Bound of each stream's buffer in the aligner.
    tracker_options
        Fields of :class:`~fusion_gyrocal.online.config.TrackerConfig` for the seeded tracker (default
        ``history_max_rows=2000``, so a long run keeps bounded memory).
    """

    def __init__(self, *, tracker=None, seed_s: float = 30.0, calibrator=None, window_s: float = 60.0,
                 mode: str = "fast", block_size: int | None = None, max_gap_s: float | None = None,
                 time_offset_s: float | None = None, max_buffer: int = 4096, **tracker_options):
        from .tracker import GyroPairTracker   # filterpy (extra [track]): refused here, before any sample

        if mode not in ("fast", "sample"):
            raise OptionError(f"mode: expected 'fast' or 'sample', got {mode!r}")
        if tracker is not None and not isinstance(tracker, GyroPairTracker):
            raise InputError(f"tracker: expected a GyroPairTracker, got {type(tracker).__name__}")
        if tracker is not None and tracker_options:
            raise OptionError(f"{', '.join(sorted(tracker_options))}: tracker options configure the tracker LivePair "
                              "seeds; expected them without tracker=, got a tracker too (use tracker.reconfigured)")
        if tracker is None and not (math.isfinite(seed_s) and seed_s > 0):
            raise OptionError(f"seed_s: expected a positive duration in seconds, got {seed_s!r}")
        if calibrator is None:
            from .stream import StreamingCalibrator
            calibrator = StreamingCalibrator(window_s=window_s)
        offset = time_offset_s if time_offset_s is not None else (tracker.time_offset_s if tracker else 0.0)
        self.aligner = LiveAligner(time_offset_s=offset, max_buffer=max_buffer)
        self.tracker, self.calibrator, self.mode, self.seed_s = tracker, calibrator, mode, float(seed_s)
        self._tracker_cls = GyroPairTracker
        self._block_size, self._max_gap_s = block_size, max_gap_s
        tracker_options.setdefault("history_max_rows", 2000)
        self._tracker_options = tracker_options
        self._seed = ([], [], [])           # aligned samples before the tracker is seeded
        self._next_try_t = -math.inf         # after a failed seed attempt: when to try again
        self._blocks: LiveBlocks | None = None
        self._events: list[dict] = []
        self._alarm_seen = None
        self._reseeds_seen = 0
        self.n_aligned = 0

    # ------------------------------------------------------------------ input
    def push(self, gyro: int, t: float, omega) -> list[dict]:
        """Take one sample of gyro 1 or 2; return the events it caused (``{"type": "seeded" | "seed_failed" |
        "alarm" | "reseed", ...}``, JSON-ready)."""
        self._feed(*self.aligner.push(gyro, t, omega))
        return self._take_events()

    def close(self) -> list[dict]:
        """End of the streams: the samples held back for the last block reach the tracker."""
        if self._blocks is None and self.tracker is not None and len(self._seed[0]) > 1:
            t, w1, w2 = (np.array(x) for x in self._seed)
            self._seed = ([], [], [])
            self._start_blocks(t)
            for block in self._blocks.push(t, w1, w2):
                self._update(*block)
        if self._blocks is not None:
            for block in self._blocks.close():
                self._update(*block)
        return self._take_events()

    def _take_events(self):
        events, self._events = self._events, []
        return events

    def _feed(self, t, w1, w2):
        if not len(t):
            return
        self.n_aligned += len(t)
        if self.tracker is None:
            st, s1, s2 = self._seed
            k = 0
            while k < len(t) and not (st and st[-1] - st[0] >= self.seed_s and st[-1] >= self._next_try_t):
                st.append(float(t[k]))
                s1.append(w1[k])
                s2.append(w2[k])
                k += 1
            if not (st[-1] - st[0] >= self.seed_s and st[-1] >= self._next_try_t):
                return
            try:
                self._seed_tracker(np.array(st), np.array(s1), np.array(s2))
            except GyroCalError as exc:      # e.g. no motion yet: slide the window and try again
                self._seed_failed(exc)
                return self._feed_rest(t[k:], w1[k:], w2[k:])
            t, w1, w2 = t[k:], w1[k:], w2[k:]
            if not len(t):
                return
        if self._blocks is None:        # a given tracker: the first samples set the default gap
            st, s1, s2 = self._seed
            st.extend(t.tolist())
            s1.extend(w1)
            s2.extend(w2)
            if self._max_gap_s is None and len(st) < self._size() + 1:
                return
            self._seed = ([], [], [])
            t, w1, w2 = np.array(st), np.array(s1), np.array(s2)
            self._start_blocks(t)
        if self.mode == "sample":
            for k in range(len(t)):
                self._update(t[k:k + 1], w1[k:k + 1], w2[k:k + 1])
            return
        for block in self._blocks.push(t, w1, w2):
            self._update(*block)

    def _feed_rest(self, t, w1, w2):
        """Samples of a batch that follow a failed seed attempt (not counted again)."""
        if len(t):
            self.n_aligned -= len(t)
            self._feed(t, w1, w2)

    def _seed_failed(self, exc) -> None:
        """A seed attempt failed: say why, keep the last ``seed_s / 2`` seconds, try again ``seed_s / 2`` later."""
        st, s1, s2 = self._seed
        t_end = st[-1]
        self._events.append({"type": "seed_failed", "t": t_end, "samples": len(st),
                             "reason": " ".join(str(exc).split())[:300]})
        keep = int(np.searchsorted(np.asarray(st), t_end - 0.5 * self.seed_s))
        del st[:keep], s1[:keep], s2[:keep]
        self._next_try_t = t_end + 0.5 * self.seed_s

    def _seed_tracker(self, t, w1, w2):
        self.tracker = self._tracker_cls.from_samples(t, w1, w2, **self._tracker_options)
        self._seed = ([], [], [])
        self.calibrator.update(w1, w2, t=t)
        self._start_blocks(t)
        self._events.append({"type": "seeded", "t": float(t[-1]), "samples": int(len(t)),
                             "configuration": self.tracker.configuration.name})

    def _size(self) -> int:
        return self.tracker.config.block_size if self._block_size is None else self._block_size

    def _start_blocks(self, t):
        gap = self._max_gap_s if self._max_gap_s is not None else 5.0 * float(np.median(np.diff(t)))
        self._blocks = LiveBlocks(1 if self.mode == "sample" else self._size(), gap)

    def _update(self, t, w1, w2):
        if self.mode == "sample":
            self.tracker.update(t[0], w1[0], w2[0])
        else:
            self.tracker.update_block(t, w1, w2)
        self.calibrator.update(w1, w2, t=t)
        alarm = self.tracker.open_alarm
        if alarm is not None and alarm != self._alarm_seen:
            self._events.append({"type": "alarm", "t_detected": _num(alarm[0]), "onset": _num(alarm[1])})
        self._alarm_seen = alarm
        events = self.tracker.reseeds
        for ev in events[self._reseeds_seen:]:
            self._events.append({"type": "reseed", "t_detected": _num(ev.t_detected), "t_onset": _num(ev.t_onset),
                                 "t_applied": _num(ev.t_applied), "accepted": bool(ev.accepted),
                                 "statistic": _num(ev.statistic), "threshold": _num(ev.threshold),
                                 "reason": ev.reason})
        self._reseeds_seen = len(events)

    # ------------------------------------------------------------------ output
    def state(self) -> dict:
        """The tracked state now, JSON-ready (strict JSON: a value that is not finite, e.g. the std of a scale factor
        no data determine, is None): time, samples, ``R_1_2`` (matrix and rotation vector in deg), scale
        factors, combined bias, their 1-sigma, the open alarm, the streaming calibrator's rotation, the aligner's
        drop counts. ``{"type": "state", "seeded": False, ...}`` before the tracker is seeded."""
        a = self.aligner
        base = {"type": "state", "aligned": self.n_aligned, "dropped": dict(a.dropped)}
        tr = self.tracker
        if tr is None:
            return {**base, "seeded": False, "seed_s_collected": (self._seed[0][-1] - self._seed[0][0])
                    if self._seed[0] else 0.0}
        std = np.sqrt(np.maximum(np.diag(tr.covariance), 0.0))
        out = {**base, "seeded": True, "t": float(tr.t), "n_samples": int(tr.n_samples),
               "n_rejected": int(tr.n_rejected), "R_1_2": [_vec(r) for r in tr.R_1_2],
               "rotvec_deg": _vec(np.degrees(log(tr.R_1_2))), "scale_1": _vec(tr.scale_1),
               "scale_2": _vec(tr.scale_2), "bias": _vec(tr.bias), "rotation_std_deg": _vec(np.degrees(std[:3])),
               "scale_1_std": _vec(std[3:6]), "scale_2_std": _vec(std[6:9]), "bias_std": _vec(std[9:12]),
               "alarm_open": tr.open_alarm is not None}
        try:
            cal = self.calibrator.estimate()
            out["window_rotvec_deg"] = _vec(np.degrees(log(cal.R_1_2)))
        except GyroCalError as exc:   # too little motion in the window yet: said, not raised
            out["window_note"] = " ".join(str(exc).split())[:200]
        return out


# ---------------------------------------------------------------------------------------------- text lines
LINE_FORMATS = ("auto", "pair", "tagged", "ros2")
"""Layouts of the text lines :class:`LineReader` reads:

* ``pair``: ``t, w1x, w1y, w1z, w2x, w2y, w2z`` (both gyros sampled together);
* ``tagged``: ``gyro, t, wx, wy, wz`` with ``gyro`` 1 / 2 or a name given as ``names``;
* ``ros2``: the rows of ``ros2 topic echo --csv <topic>`` for ``sensor_msgs/msg/Imu`` (``stamp.sec``,
  ``stamp.nanosec``, ``frame_id``, orientation (4), its covariance (9), angular velocity (3), ...), the gyro told
  by ``frame_id`` (``names``).
"""

_ROS2_OMEGA = slice(16, 19)   # angular_velocity.x..z in a flattened sensor_msgs/msg/Imu row


class LineReader:
    """Text lines of a live source -> ``(gyro, t, omega)`` samples.

    Parameters
    ----------
    format : {"auto", "pair", "tagged", "ros2"}
        See :data:`LINE_FORMATS`; ``auto`` decides on the first data line (7 numbers: pair; 5 fields: tagged;
        19 or more with a text third field: ros2).
    names : (str, str), optional
        The tags (``tagged``) or frame ids (``ros2``) of gyro 1 and gyro 2; default ``("1", "2")`` for tagged,
        and for ros2 the first two frame ids seen, in order.
    time_scale : float
        Factor of the timestamps to seconds (``pair`` and ``tagged``; 1e-9 for nanoseconds).

    Lines that are empty or comments (``#``) are skipped, and one header line before the data; a line that
    does not parse after that raises an :class:`InputError` naming the line number and what was expected.
    """

    def __init__(self, format: str = "auto", *, names=None, time_scale: float = 1.0):
        if format not in LINE_FORMATS:
            raise OptionError(f"format: expected one of {LINE_FORMATS}, got {format!r}")
        if names is not None and (len(names) != 2 or names[0] == names[1]):
            raise OptionError(f"names: expected two different names of gyro 1 and gyro 2, got {names!r}")
        if not (math.isfinite(time_scale) and time_scale > 0):
            raise OptionError(f"time_scale: expected a positive factor to seconds, got {time_scale!r}")
        self.format, self.time_scale = format, float(time_scale)
        self.names = None if names is None else tuple(str(n) for n in names)
        self.line_no = 0
        self.skipped = 0
        self._seen: list[str] = []         # frame ids in order of appearance (ros2 without names)
        self._header_seen = self._data_seen = False

    def _gyro(self, tag: str) -> int | None:
        if self.names is None:
            if self.format == "tagged":
                self.names = ("1", "2")
            else:
                if tag not in self._seen and len(self._seen) < 2:
                    self._seen.append(tag)
                return self._seen.index(tag) + 1 if tag in self._seen else None
        return self.names.index(tag) + 1 if tag in self.names else None

    def samples(self, line: str) -> list[tuple[int, float, np.ndarray]]:
        """The samples of one line (two for ``pair``, one otherwise, none for a skipped line)."""
        self.line_no += 1
        text = line.strip()
        if not text or text.startswith("#"):
            return []
        fields = [f.strip() for f in text.split(",")] if "," in text else text.split()
        fmt = self.format
        if fmt == "auto":
            fmt = ("pair" if len(fields) == 7 else "tagged" if len(fields) == 5 else
                   "ros2" if len(fields) >= 19 else None)
            if fmt is None:
                raise InputError(f"line {self.line_no}: expected 7 fields (t and both gyros' rates), 5 (gyro, t, "
                                 f"wx, wy, wz) or a 'ros2 topic echo --csv' Imu row, got {len(fields)} fields")
        try:
            if fmt == "pair":
                v = [float(f) for f in fields[:7]]
                if len(fields) != 7:
                    raise ValueError
                t = v[0] * self.time_scale
                self.format, self._data_seen = fmt, True
                return [(1, t, np.array(v[1:4])), (2, t, np.array(v[4:7]))]
            if fmt == "tagged":
                if len(fields) != 5:
                    raise ValueError
                t = float(fields[1]) * self.time_scale
                w = np.array([float(f) for f in fields[2:5]])
                self.format = fmt
                gyro = self._gyro(fields[0])
            else:
                if len(fields) < 19:
                    raise ValueError
                t = int(fields[0]) + int(fields[1]) * 1e-9
                w = np.array([float(f) for f in fields[_ROS2_OMEGA]])
                self.format = fmt
                gyro = self._gyro(fields[2])
        except ValueError:
            if not self._header_seen and not self._data_seen:   # one header line before the data
                self._header_seen = True
                self.skipped += 1
                return []
            raise InputError(f"line {self.line_no}: expected a {fmt} row of numbers ({LINE_FORMATS} layouts), got "
                             f"{text[:80]!r}") from None
        self._data_seen = True
        if gyro is None:
            self.skipped += 1
            return []
        return [(gyro, t, w)]
