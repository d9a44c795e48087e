"""Stream checks and unit conversion at the edge: timestamps, rate units, saturated and non-finite samples.

What a check found out about timestamps the library holds (an :class:`~fusion_gyrocal.io.ImuStream`'s: read-only
arrays that own their data) is kept beside them (:func:`remember_timestamps`): their diagnosis and median step are
then not computed again by the alignment, the resampling or a second check of the same array.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, replace

import numpy as np

from ..core.moments import as_rates, column_extremes, finite_rows, median
from ..errors import InputError, OptionError
from ..units import DEG, RATE_FACTORS, RATE_UNITS, TIME_UNITS  # noqa: F401  (DEG: also this module's name)

UNITS = RATE_UNITS             # the rate units of to_rad_per_s (fusion_gyrocal.units.RATE_UNITS)
DEFAULT_GAP_PERIODS = 2.5      # default max_gap_s in nominal sample periods
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 1e5   # plausible median sample rates of a gyro (s timestamps)
CORRUPT_JUMP_STEPS = 1000.0    # a step this many median steps long ...
CORRUPT_SPAN_FACTOR = 10.0     # ... that stretches the span beyond this many times N median steps is corrupt
_TIME_UNITS = tuple((u, 10.0 ** -d) for u, d in TIME_UNITS.items() if d)   # ms, us, ns: unit in s


def _trusted(arr, dtype=np.float64, view: bool = False) -> bool:
    """An ndarray (of ``dtype`` unless None) that is read-only and owns its data (or, with ``view``, a read-only
    view): the library's own (a result, a reader's hand-over), which does not change, so it is kept as it is
    (no second copy of a long record) and what was checked about it holds."""
    return (isinstance(arr, np.ndarray) and (arr.base is None or view) and not arr.flags.writeable
            and (dtype is None or arr.dtype == dtype))


def _freeze(obj, names, dtype=None, views=()) -> None:
    """Replace the array fields ``names`` of a frozen dataclass by read-only copies.

    An array that is already read-only and owns its data (:func:`_trusted`: the library's own results, e.g. of
    :func:`~fusion_gyrocal.pipeline.alignment.align_streams`) is kept as it is: no second copy of a
    long record; so is a read-only view for the fields ``views`` (gyro 1's samples on its own timestamps).
    """
    for name in names:
        arr = getattr(obj, name)
        if not _trusted(arr, dtype, name in views):
            arr = np.array(arr, dtype=dtype)
            arr.flags.writeable = False
        object.__setattr__(obj, name, arr)


# ---------------------------------------------------------------------------------------------- timestamp quality
BURST_STEP = 0.25              # a step shorter than this many nominal periods is inside a burst (a USB packet)
BURST_FRACTION = 0.2           # timestamps with at least this fraction of burst steps are bursty
DROP_STEP = 1.5                # a step longer than this many nominal periods drops samples
_STEP_BINS = (0.0, BURST_STEP, 0.75, 1.25, DROP_STEP, 2.5, np.inf)   # the rate histogram, in nominal periods


@dataclass(frozen=True)
class TimestampQuality:
    """What a stream's timestamps look like: their nominal rate, jitter, bursts and drops.

    Attributes
    ----------
    name : str
        The stream (e.g. ``"t_2"``).
    n : int
        Timestamps.
    period_s : float
        Nominal sample period (s): the median step, or for bursty timestamps the mean step outside the
        gaps (the median step of packets is the step inside one packet).
    step_histogram : tuple of int
        Steps per bin of ``step / period_s``: ``<= 0`` (backwards or repeated), ``(0, 0.25)`` (inside a burst),
        ``[0.25, 0.75)``, ``[0.75, 1.25)`` (regular), ``[1.25, 1.5)``, ``[1.5, 2.5)`` (one sample dropped),
        ``>= 2.5`` (gaps).
    jitter : float
        Robust standard deviation of the regular steps (``[0.75, 1.25)`` periods) over ``period_s``.
    burst_fraction : float
        Fraction of steps shorter than 0.25 periods.
    drops : int
        Steps longer than 1.5 periods.
    missing : int
        Samples those steps leave out (``round(step / period_s) - 1`` each).
    longest_gap_s : float
        The longest step (s).
    backward : int
        Steps that go backwards or repeat a timestamp.
    """

    name: str
    n: int
    period_s: float
    step_histogram: tuple
    jitter: float
    burst_fraction: float
    drops: int
    missing: int
    longest_gap_s: float
    backward: int

    @property
    def rate_hz(self) -> float:
        """Nominal sample rate (Hz)."""
        return 1.0 / self.period_s

    @property
    def bursty(self) -> bool:
        """Samples delivered in packets (at least 20 % of the steps shorter than a quarter period)."""
        return self.burst_fraction >= BURST_FRACTION

    def summary(self) -> str:
        """One line naming what was found (the rate histogram in nominal periods)."""
        hist = "/".join(str(c) for c in self.step_histogram)
        found = []
        if self.bursty:
            found.append(f"BURSTY ({100 * self.burst_fraction:.0f}% of steps < {BURST_STEP:g} period: samples "
                         "delivered in packets)")
        if self.backward:
            found.append(f"{self.backward} step(s) backwards or repeated")
        if self.drops:
            found.append(f"{self.drops} drop(s), {self.missing} sample(s) missing, longest gap "
                         f"{1e3 * self.longest_gap_s:.4g} ms")
        return (f"{self.name}: {self.n} timestamps, {self.rate_hz:.6g} Hz nominal, jitter {100 * self.jitter:.3g}% of "
                f"a period, steps per bin (<=0 / <0.25 / <0.75 / <1.25 / <1.5 / <2.5 / more periods) {hist}"
                + ("; " + "; ".join(found) if found else "; regular"))


def _quality(name: str, step: np.ndarray, n: int) -> TimestampQuality:
    """:class:`TimestampQuality` from the steps of ``n`` timestamps (any order): a few passes over the steps, the
    jitter from a bounded subsample of them."""
    lo = float(step.min()) if step.size else float("nan")
    pos = step if lo > 0 else step[step > 0]
    if not pos.size:
        return TimestampQuality(name, n, float("nan"), (int(step.size),) + (0,) * 6, float("nan"), 0.0, 0, 0,
                                0.0, int(step.size))
    period = float(np.median(pos))
    longest = float(pos.max())
    mean = float(np.mean(pos))
    for _ in range(2):      # the mean step without the long pauses (a regular stream's is its median step)
        if longest > 50.0 * mean:
            mean = float(np.mean(pos[pos <= 50.0 * mean]))
    if np.count_nonzero(step < BURST_STEP * mean) >= BURST_FRACTION * step.size:
        period = mean       # packets: the median is the step inside one, the mean step outside pauses the period
    if not (np.isfinite(period) and period > 0):
        return TimestampQuality(name, n, float("nan"), (int(step.size),) + (0,) * 6, float("nan"), 0.0, 0, 0,
                                0.0, int(step.size))
    edges = np.array(_STEP_BINS[1:-1]) * period
    below = [0] + [int(np.count_nonzero(pos < e)) for e in edges] + [pos.size]   # a count per edge: no sort
    hist = [int(step.size - pos.size)] + [b - a for a, b in zip(below[:-1], below[1:])]
    sub = pos[::max(1, pos.size // (1 << 16))] / period
    regular = sub[(sub >= 0.75) & (sub < 1.25)]
    jitter = float(1.4826 * np.median(np.abs(regular - np.median(regular)))) if regular.size else float("nan")
    big = pos[pos > DROP_STEP * period] / period
    return TimestampQuality(name, n, period, tuple(hist), jitter, float(hist[1]) / max(step.size, 1),
                            int(big.size), int(np.sum(np.rint(big) - 1)), longest, hist[0])


def timestamp_quality(name: str, t) -> TimestampQuality:
    """Diagnose a stream's timestamps (s): nominal rate, rate histogram, jitter, bursts, drops, backward steps.

    Nothing is refused here: :func:`check_timestamps` names the diagnosis in its refusals, and the alignment
    (:func:`~fusion_gyrocal.pipeline.alignment.align_streams`) reports it and regularises bursty timestamps.

    Parameters
    ----------
    name : str
        The stream's name in the summary (e.g. ``"t_2"``).
    t : array_like, shape (N,)
        Timestamps (s), N >= 2.

    Returns
    -------
    TimestampQuality
    """
    arr = np.asarray(t, dtype=np.float64)
    if arr.ndim != 1 or arr.size < 2:
        raise InputError(f"{name}: expected a 1-D array of at least 2 timestamps, got shape {arr.shape}")
    return _quality(name, np.diff(arr), arr.size)


# ---------------------------------------------------------------------------------------------- checked timestamps
@dataclass(frozen=True)
class _Known:
    """What a check found out about one timestamp array: finite, strictly increasing, a plausible rate."""

    quality: TimestampQuality   # its diagnosis (named as the check named it)
    median_step: float          # ``median(diff(t))``, its nominal period (:func:`_nominal_period`)


_KNOWN: dict = {}   # id(array) -> (weak reference to the array, _Known)


def median_step(step: np.ndarray, quality: TimestampQuality) -> float:
    """``median(step)`` of checked timestamps' steps: the period of their diagnosis, unless they are bursty (that
    period is then the mean step outside the pauses, and the median is computed here)."""
    return quality.period_s if not quality.bursty else float(np.median(step))


def remember_timestamps(t: np.ndarray, median: float, quality: TimestampQuality) -> None:
    """Keep what :func:`check_timestamps` found out about ``t`` (its diagnosis, its ``median`` step) for later steps.

    Only for a read-only float64 array that owns its data (an :class:`~fusion_gyrocal.io.ImuStream`'s ``t``): such
    an array does not change, so its checks, diagnosis and median step hold as long as it lives (the entry goes
    with it). Other arrays are not remembered: every step checks them again.
    """
    if not _trusted(t) or t.ndim != 1:
        return
    key = id(t)
    forget = _KNOWN.pop        # bound now: the entry goes when the array does, also at interpreter exit
    _KNOWN[key] = (weakref.ref(t, lambda _, key=key: forget(key, None)), _Known(quality, float(median)))


def _known(t) -> _Known | None:
    """What :func:`remember_timestamps` kept about the array ``t`` (None when nothing, or it became writeable)."""
    entry = _KNOWN.get(id(t))
    if entry is None or entry[0]() is not t or t.flags.writeable:
        return None
    return entry[1]


# ---------------------------------------------------------------------------------------------- stream checks
def check_timestamps(name: str, t, *, length: int | None = None) -> np.ndarray:
    """Return timestamps as a 1-D float64 array of seconds, checking that they can be used.

    Parameters
    ----------
    name : str
        Name used in error messages (e.g. ``"t_2"``).
    t : array_like, shape (N,)
        Timestamps in seconds, strictly increasing.
    length : int, optional
        Number of rate samples they belong to.

    Returns
    -------
    ndarray, shape (N,)
        ``t`` as float64 (the caller's array is never modified; no copy when already float64).

    Raises
    ------
    InputError
        If ``t`` is not 1-D and numeric, its length differs from ``length``, it has fewer than
        two samples, a non-finite value, a duplicate timestamp or a step backwards (the message
        names the sample index and the step); if the median sample rate is outside
        1 Hz - 100 kHz (timestamps in ms, us or ns read as s: the message names the unit that
        fits); or if one step is more than 1000 median steps long and stretches the span beyond
        10 times N median steps (a corrupt timestamp: resampling such a span would allocate
        without bound; the message names the sample).
    """
    known = _known(t)
    if known is not None and (length is None or t.shape[0] == length):
        return t                  # checked when it was remembered, and read-only since
    return _checked_timestamps(name, t, length=length)[0]


def _checked_timestamps(name: str, t, *, length: int | None = None):
    """:func:`check_timestamps`, returning ``(t as float64, its steps, its TimestampQuality)``."""
    arr = np.asarray(t)
    if arr.dtype.kind not in "fiu":
        raise InputError(f"{name}: expected numeric timestamps in seconds, got dtype {arr.dtype}")
    if arr.ndim != 1:
        raise InputError(f"{name}: expected a 1-D array of timestamps, got shape {arr.shape}")
    if length is not None and arr.shape[0] != length:
        raise InputError(f"{name}: expected {length} timestamps (one per rate sample), got {arr.shape[0]}")
    if arr.shape[0] < 2:
        raise InputError(f"{name}: expected at least 2 timestamps, got {arr.shape[0]}")
    arr = arr.astype(np.float64, copy=False)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise InputError(f"{name}: expected finite timestamps, got {arr[bad[0]]} at sample {bad[0]} "
                         f"({bad.size} non-finite)")
    step = np.diff(arr)
    _check_increasing(name, arr, step, None)
    quality = _quality(name, step, arr.size)
    _check_time_scale(name, arr, step, quality)
    return arr, step, quality


def _check_increasing(name: str, arr: np.ndarray, step: np.ndarray, quality: TimestampQuality | None) -> None:
    """Refuse timestamps that do not increase strictly, naming the first offending step (and the diagnosis)."""
    nonpos = np.flatnonzero(step <= 0)
    if not nonpos.size:
        return
    q = quality if quality is not None else _quality(name, step, arr.size)
    k = int(nonpos[0])
    if step[k] == 0:
        raise InputError(f"{name}: expected strictly increasing timestamps, got a duplicate timestamp "
                         f"{arr[k]!r} s at samples {k} and {k + 1} ({nonpos.size} non-increasing step(s)). "
                         f"Timestamps: {q.summary()}")
    raise InputError(f"{name}: expected strictly increasing timestamps, got a step of {step[k]:.6g} s at "
                     f"sample {k + 1} ({nonpos.size} non-increasing step(s)). Timestamps: {q.summary()}")


def _check_time_scale(name: str, t: np.ndarray, step: np.ndarray, quality: TimestampQuality) -> None:
    """The nominal sample rate and the span of checked, increasing timestamps (see :func:`check_timestamps`)."""
    med = quality.period_s
    rate = 1.0 / med
    if not MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
        fits = [u for u, f in _TIME_UNITS if MIN_RATE_HZ <= rate / f <= MAX_RATE_HZ]
        hint = (f"they look like {fits[0]}: pass t_1/t_2 in seconds (the CLI's --time-unit1/--time-unit2 "
                f"{fits[0]})" if fits else "pass t_1/t_2 in seconds (the CLI's --time-unit1/--time-unit2)")
        hint += f". Timestamps: {quality.summary()}"
        raise InputError(f"{name}: expected timestamps in seconds with a sample rate of {MIN_RATE_HZ:g} Hz to "
                         f"{MAX_RATE_HZ:g} Hz, got a nominal step of {med:.6g} ({rate:.6g} Hz if seconds); {hint}")
    span = float(t[-1] - t[0])
    if span > CORRUPT_SPAN_FACTOR * t.shape[0] * med:
        k = int(np.argmax(step))
        if step[k] > CORRUPT_JUMP_STEPS * med:
            raise InputError(f"{name}: expected timestamps without huge jumps, got a step of {step[k]:.6g} s "
                             f"({step[k] / med:.3g} median steps) at sample {k + 1} that makes the span {span:.6g} s "
                             f"for {t.shape[0]} samples: corrupt timestamp? Drop it or split the recording there. "
                             f"Timestamps: {quality.summary()}")


def to_rad_per_s(x, unit: str, sensitivity: float | None = None) -> np.ndarray:
    """Convert angular rates to rad/s (a new float64 array).

    Parameters
    ----------
    x : array_like
        Rates in ``unit``.
    unit : {"rad/s", "deg/s", "counts"}
        Unit of ``x``. Raw ``"counts"`` need ``sensitivity``.
    sensitivity : float, optional
        Sensor sensitivity in LSB per deg/s (e.g. 16.4 for a +-2000 deg/s MEMS gyro); only
        with ``unit="counts"``.

    Raises
    ------
    InputError
        On an unknown unit, counts without a positive finite sensitivity, a sensitivity with
        another unit, or non-numeric input.
    """
    arr = np.asarray(x)
    if arr.dtype.kind not in "fiu":
        raise InputError(f"x: expected numeric angular rates, got dtype {arr.dtype}")
    if unit not in RATE_UNITS:
        raise OptionError(f"unit: expected one of {RATE_UNITS}, got {unit!r}")
    factor = RATE_FACTORS[unit]
    if unit == "counts":
        if sensitivity is None or not np.isfinite(sensitivity) or not sensitivity > 0:
            raise OptionError("sensitivity: expected a positive LSB per deg/s (e.g. 16.4) to convert counts, "
                             f"got {sensitivity!r}")
        return arr.astype(np.float64) * (factor / float(sensitivity))
    if sensitivity is not None:
        raise OptionError(f"sensitivity: only used with unit='counts', got {sensitivity!r} with unit={unit!r}")
    if factor != 1.0:
        return arr.astype(np.float64) * factor
    return np.array(arr, dtype=np.float64)


def saturation_mask(omega, limit: float | None = None, *, extremes=None) -> np.ndarray:
    """Samples at which at least one axis is saturated (clipped at the sensor range).

    Parameters
    ----------
    omega : array_like, shape (N, 3)
        Rates in any unit (``limit`` in the same unit).
    limit : float, optional
        Sensor range: a sample is saturated where ``|value| >= limit`` on any axis. Without it a
        heuristic is used: on each axis, the largest and the smallest value are taken as clip
        levels when that exact value occurs in at least two samples and its magnitude is at
        least half the largest magnitude of the whole record (clipped data sit flat at the
        range; smooth unclipped motion almost never repeats its extreme exactly). Pass
        ``limit`` when the range is known, especially for quantised (integer count) data.
    extremes : tuple, optional
        :func:`~fusion_gyrocal.core.moments.column_extremes` of ``omega`` when already known (from
        :func:`~fusion_gyrocal.core.moments.moments_with_extremes`): the heuristic then reads no more samples
        unless a clip level repeats.

    Returns
    -------
    ndarray of bool, shape (N,)
        True where saturated. Non-finite samples are ignored here (see :func:`valid_mask`).
    """
    w = as_rates("omega", omega)
    if limit is not None:
        finite = np.isfinite(w)
        if not np.isfinite(limit) or not limit > 0:
            raise OptionError(f"limit: expected a positive sensor range, got {limit!r}")
        with np.errstate(invalid="ignore"):
            return np.any(finite & (np.abs(w) >= limit), axis=1)
    out = np.zeros(w.shape[0], dtype=bool)
    if w.shape[0] < 2:
        return out
    hi, lo, hi_rep, lo_rep = column_extremes(w) if extremes is None else extremes
    if np.isfinite(hi).all() and np.isfinite(lo).all():   # the usual case (NaN/inf there: a sample is not finite)
        biggest = float(max(np.abs(hi).max(), np.abs(lo).max()))
        levels = [((hi[a], bool(hi_rep[a])), (lo[a], bool(lo_rep[a]))) for a in range(3)]
    else:
        finite = np.isfinite(w)
        if not finite.any():
            return out
        biggest = float(np.max(np.abs(w[finite])))
        cols = [w[finite[:, a], a] for a in range(3)]
        levels = [((c.max(), None), (c.min(), None)) if c.size else () for c in cols]
    for a in range(3):
        for level, repeats in levels[a]:
            if level == 0 or abs(level) < 0.5 * biggest or repeats is False:
                continue
            hit = w[:, a] == level
            if np.count_nonzero(hit) >= 2:
                out |= hit
    return out


def valid_mask(omega, *, limit: float | None = None, saturation: bool = True) -> np.ndarray:
    """Samples that may be used: finite on every axis and (by default) not saturated.

    Parameters
    ----------
    omega : array_like, shape (N, 3)
    limit : float, optional
        Sensor range for :func:`saturation_mask`.
    saturation : bool
        Also mask saturated samples (default True).

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    w = as_rates("omega", omega)
    ok = finite_rows(w)
    if saturation:
        ok &= ~saturation_mask(w, limit)
    return ok


def _and_valid(keep: np.ndarray, valid, name: str) -> np.ndarray:
    """``keep & valid`` with the caller's ``valid`` checked to be a bool mask of the same shape (None: all)."""
    if valid is None:
        return keep
    v = np.asarray(valid)
    if v.dtype != bool or v.shape != keep.shape:
        raise InputError(f"{name}: expected a bool array of shape {keep.shape}, got {v.dtype} {v.shape}")
    return keep & v


def _stream(name_t, t, name_w, omega, valid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Checked (t, omega, valid) of one stream; ``valid`` also excludes non-finite samples."""
    w = as_rates(name_w, omega)
    tt = check_timestamps(name_t, t, length=w.shape[0])
    return tt, w, _and_valid(finite_rows(w), valid, f"valid mask for {name_w}")


MAX_GLITCH_FRACTION = 0.01    # out-of-place timestamps beyond this fraction are not glitches: refused


def _out_of_place(t: np.ndarray) -> np.ndarray:
    """Samples whose timestamp is not strictly between its neighbours while the neighbours are in order
    (one corrupt timestamp, forwards or backwards, or a repeated one); the first and last against the next two."""
    bad = np.zeros(t.size, dtype=bool)
    if t.size >= 3:
        prev, this, nxt = t[:-2], t[1:-1], t[2:]
        bad[1:-1] = (prev < nxt) & ~((prev < this) & (this < nxt))
        bad[0] = t[0] >= t[1] and t[1] < t[2]
        bad[-1] = t[-1] <= t[-2] and t[-3] < t[-2]
        same = np.flatnonzero(bad[:-1] & bad[1:] & (t[:-1] == t[1:]))
        bad[same] = False       # a repeated stamp: the later sample repeats the earlier one
    return bad


def _regular_times(t: np.ndarray, period: float) -> np.ndarray:
    """Bursty timestamps replaced by the least-squares line of time against sample index, per stretch between
    gaps longer than 20 periods (packets carry samples taken at a steady rate; their arrival times do not)."""
    cut = np.flatnonzero(np.diff(t) > 20.0 * period) + 1
    out = np.empty(t.size)
    for a, b in zip(np.r_[0, cut], np.r_[cut, t.size]):
        k = np.arange(b - a, dtype=float)
        if b - a < 2:
            out[a:b] = t[a:b]
            continue
        kc, tc = k - k.mean(), t[a:b] - t[a:b].mean()
        slope = float(kc @ tc) / float(kc @ kc)
        out[a:b] = t[a:b].mean() + slope * kc
    return out


def timed_stream(name_t, t, name_w, omega, valid):
    """Checked ``(t, omega, valid, quality, notes)`` of one timestamped stream for the alignment.

    Unlike :func:`check_timestamps`, what can be repaired is repaired and said (``notes``): isolated
    out-of-place timestamps (at most 1 % of the samples: one corrupt, backward or repeated stamp) are
    moved between their neighbours and their samples masked; bursty timestamps (samples delivered in
    packets, :attr:`TimestampQuality.bursty`) are replaced by a steady clock fitted to them. The rest is
    refused as :func:`check_timestamps` does, naming the diagnosis.
    """
    w = as_rates(name_w, omega)
    known = _known(t)
    if known is not None and t.shape[0] == w.shape[0] and t.shape[0] >= 3 and not known.quality.bursty:
        # remembered (remember_timestamps): finite, strictly increasing, a plausible rate: nothing to repair
        return t, w, _and_valid(finite_rows(w), valid, f"valid mask for {name_w}"), \
            replace(known.quality, name=name_t), ()
    arr = np.asarray(t)
    if arr.dtype.kind not in "fiu" or arr.ndim != 1 or arr.shape[0] != w.shape[0] or arr.shape[0] < 3:
        tt = check_timestamps(name_t, t, length=w.shape[0])   # the specific refusal
        return tt, w, _and_valid(finite_rows(w), valid, f"valid mask for {name_w}"), None, ()
    arr = arr.astype(np.float64, copy=False)
    if not np.isfinite(arr).all():
        check_timestamps(name_t, arr)
    ok = _and_valid(finite_rows(w), valid, f"valid mask for {name_w}")
    step = np.diff(arr)
    q = _quality(name_t, step, arr.size) if known is None else replace(known.quality, name=name_t)
    notes = []
    if not q.bursty and q.backward:
        bad = _out_of_place(arr)
        n_bad = int(np.count_nonzero(bad))
        if 0 < n_bad <= MAX_GLITCH_FRACTION * arr.size:
            idx = np.flatnonzero(bad)
            fixed = arr.copy()
            inner = idx[(idx > 0) & (idx < arr.size - 1)]
            fixed[inner] = 0.5 * (arr[inner - 1] + arr[inner + 1])
            if bad[0]:
                fixed[0] = arr[1] - (arr[2] - arr[1])
            if bad[-1]:
                fixed[-1] = arr[-2] + (arr[-2] - arr[-3])
            if np.all(np.diff(fixed) > 0):
                arr, ok = fixed, ok & ~bad
                step = np.diff(arr)
                notes.append(f"{name_t}: {n_bad} out-of-place timestamp(s) (first at sample {int(idx[0])}: "
                             "corrupt, backward or repeated) moved between their neighbours and their samples masked")
    if q.bursty:
        if np.any(step < 0):
            _check_increasing(name_t, arr, step, q)
        arr = _regular_times(arr, q.period_s)
        step = np.diff(arr)
        notes.append(f"{name_t}: bursty timestamps ({100 * q.burst_fraction:.0f}% of the steps shorter than "
                     f"{BURST_STEP:g} period: samples delivered in packets) replaced by a steady "
                     f"{q.rate_hz:.6g} Hz clock fitted to them")
    _check_increasing(name_t, arr, step, q)
    _check_time_scale(name_t, arr, step, q)
    return arr, w, ok, q, tuple(notes)


def _nominal_period(t: np.ndarray) -> float:
    """``median(diff(t))`` (kept for remembered timestamps, :func:`remember_timestamps`; else the steps partitioned
    in place, :func:`~fusion_gyrocal.core.moments.median` as the resampling's query steps: one temporary)."""
    known = _known(t)
    return known.median_step if known is not None else float(median(np.diff(t), overwrite_input=True))


def grid_rate(t) -> float | None:
    """Mean sample rate (Hz) of an aligned time grid ``t`` (s): ``(N - 1) / span``; None with fewer than
    two samples or no span."""
    if len(t) < 2 or not t[-1] > t[0]:
        return None
    return float((len(t) - 1) / (t[-1] - t[0]))
