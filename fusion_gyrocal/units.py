"""The units the library reads: rate units with their factors to rad/s, time units with their powers of ten.

The one table of units (numpy only, so every layer can import it): the readers
(:mod:`fusion_gyrocal.io`), the conversion :func:`fusion_gyrocal.pipeline.streams.to_rad_per_s`, the
timestamp checks of :mod:`fusion_gyrocal.pipeline.streams` and the command line's ``--unit`` /
``--time-unit`` flags all take their units from here. Inside the library rates are rad/s and times s.
"""

from __future__ import annotations

import numpy as np

#: One degree in radians.
DEG = np.pi / 180.0

#: Rate units: name -> factor to rad/s. Raw ``"counts"`` are further divided by the sensor's
#: sensitivity in LSB per deg/s (rad/s = counts / sensitivity * pi / 180).
RATE_FACTORS = {"rad/s": 1.0, "deg/s": DEG, "counts": DEG, "mrad/s": 1e-3, "mdeg/s": 1e-3 * DEG}
#: The rate unit names, in the order of :data:`RATE_FACTORS`.
RATE_UNITS = tuple(RATE_FACTORS)
#: Spellings of the rate units in a column header's brackets (spaces removed, lower case): ``[rad s^-1]``,
#: ``[dps]``, ``[°/s]`` (also the masculine ordinal ``º`` many Spanish and Italian files use), ``[mdps]``, ...
RATE_UNIT_LABELS = {
    "rad/s": "rad/s", "rads^-1": "rad/s", "rad/sec": "rad/s", "rad*s^-1": "rad/s", "rad.s^-1": "rad/s",
    "deg/s": "deg/s", "dps": "deg/s", "°/s": "deg/s", "º/s": "deg/s", "degs^-1": "deg/s", "deg/sec": "deg/s",
    "°/sec": "deg/s", "deg*s^-1": "deg/s", "°s^-1": "deg/s",
    "counts": "counts", "lsb": "counts", "raw": "counts",
    "mrad/s": "mrad/s", "mrads^-1": "mrad/s", "mrad/sec": "mrad/s",
    "mdeg/s": "mdeg/s", "mdps": "mdeg/s", "m°/s": "mdeg/s", "mº/s": "mdeg/s", "mdeg/sec": "mdeg/s",
}
#: Pieces of a bracketed header label that make it a rate unit: a label with one of them that
#: :data:`RATE_UNIT_LABELS` does not know is refused by the readers (naming it), never read as rad/s.
RATE_UNIT_HINTS = ("/", "^-1", "rad", "deg", "dps", "°", "º", "rpm", "rps", "lsb", "count", "digit", "raw", "hz")

#: Time units: name -> power of ten of one second (``"ms"``: 3, one unit is 1e-3 s).
TIME_UNITS = {"s": 0, "ms": 3, "us": 6, "ns": 9}
#: Spellings of the time units in a column header's brackets: ``[ns]``, ``[sec]``, ``[µs]``, ...
TIME_UNIT_LABELS = {**{u: u for u in TIME_UNITS}, "sec": "s", "seconds": "s", "µs": "us", "μs": "us",
                    "usec": "us", "msec": "ms", "nsec": "ns", "nanosec": "ns", "microsec": "us", "millisec": "ms",
                    "second": "s"}


# ----------------------------------------------------------------------------- is it rad/s?
#: What MEMS gyros measure in rad/s, at the default plausibility limit of 100 rad/s (``max_plausible_rate``;
#: each scales with it): white noise per sample below 0.05 rad/s (2.9 deg/s: noise densities up to
#: 0.1 deg/s/sqrt(Hz) at 800 Hz), a zero-rate offset below 0.35 rad/s (20 deg/s, beyond the datasheet
#: limits), a rate norm within 60 rad/s (2000 deg/s on each axis, the widest usual full scale). Rates in
#: deg/s read as rad/s are 57.3 times larger in each.
MEMS_LIMITS = {"noise": 0.05, "bias": 0.35, "offset": 0.35, "range": 60.0}
_DEFAULT_LIMIT = 100.0
#: A figure this many times its MEMS limit is refused on its own.
STRONG_SIGN = 2.0
_QUIET_WINDOW = 32          # samples per window when looking for static stretches
_MIN_QUIET_WINDOWS = 3
_QUIET_SPREAD = 1.5         # a window at rest spreads like the white noise (+-13 % over 32 samples)
_EVIDENCE_SAMPLES = 1 << 14


def rate_unit_evidence(streams, mask=None, limit: float = _DEFAULT_LIMIT, *, per_stream: list | None = None
                       ) -> tuple[dict, list[str]]:
    """What the data say about their unit: ``(figures, signs)``, the figures in the unit they are read in.

    ``figures`` holds ``noise`` (white noise per sample, from the third differences, the larger of the
    streams'), ``bias`` (the rate norm at rest: over windows whose spread is within 1.5 times the noise,
    the 10th percentile of their mean rate norms, which slow turns do not raise; the larger of the streams';
    NaN without :data:`_MIN_QUIET_WINDOWS` such windows), ``offset`` (the norm of the combined bias
    ``b_1 - A b_2`` of the least-squares fit of gyro 1's rates on gyro 2's, Eq. 5 and 12: two gyros' offsets, seen
    without any static stretch) and ``range``
    (the 99th percentile of the rate norm, the larger). ``signs`` names each figure above
    its MEMS limit (:data:`MEMS_LIMITS`, times ``limit / 100``): signs that the rates are in deg/s, not rad/s.
    A bounded subsample (:data:`_EVIDENCE_SAMPLES` samples in contiguous blocks spread over the log) is used.
    """
    from .core.moments import finite_rows, median, minus_row

    scale = float(limit) / _DEFAULT_LIMIT
    figures = {"noise": 0.0, "bias": float("nan"), "offset": float("nan"), "range": 0.0}
    sub = []
    for w in streams:
        w = np.asarray(w)
        n = len(w)
        block = 4096
        m = None if mask is None else np.asarray(mask, bool)
        if n > _EVIDENCE_SAMPLES:    # the subsample first: nothing below reads the whole log
            starts = np.linspace(0, n - block, _EVIDENCE_SAMPLES // block).astype(int)
            w = np.concatenate([w[s:s + block] for s in starts])
            m = None if m is None else np.concatenate([m[s:s + block] for s in starts])
        w = np.asarray(w, dtype=np.float64)
        ok = finite_rows(w) if m is None else (m & finite_rows(w))
        sub.append((w, ok))
        if ok.sum() < 8:
            continue
        everything = bool(ok.all())      # the usual case: no copies, no NaN placeholders
        good = w if everything else np.where(ok[:, None], w, np.nan)
        d3 = np.diff(good, n=3, axis=0)
        finite = finite_rows(d3)
        d3 = d3 if finite.all() else d3[finite]
        noise = float(np.sqrt(median(d3 ** 2) / 20.0 / 0.4549)) if len(d3) else 0.0   # median of chi2_1 = 0.4549
        norms = _row_norms(good if everything else good[ok])
        own = {"noise": noise, "bias": float("nan"), "offset": float("nan"),
               "range": float(np.quantile(norms, 0.99))}
        figures["noise"] = max(figures["noise"], noise)
        figures["range"] = max(figures["range"], own["range"])
        whole = (len(good) // _QUIET_WINDOW) * _QUIET_WINDOW
        win = good[:whole].reshape(-1, _QUIET_WINDOW, 3)
        full = np.ones(len(win), bool) if everything else np.isfinite(win).all(axis=(1, 2))
        if full.sum() >= _MIN_QUIET_WINDOWS and noise > 0:
            win = win if everything else win[full]
            # each window's variance per axis, reduced along contiguous rows (down a window's (32, 3) rows numpy
            # reduces slowly)
            spread = np.sqrt(np.ascontiguousarray(win.transpose(2, 0, 1)).var(axis=2).sum(axis=0) / 3.0)
            quiet = spread <= _QUIET_SPREAD * noise
            if quiet.sum() >= _MIN_QUIET_WINDOWS:   # the floor of the rate at rest (slow turns are not rest)
                bias = float(np.quantile(np.linalg.norm(win[quiet].mean(axis=1), axis=1), 0.1))
                figures["bias"] = bias if np.isnan(figures["bias"]) else max(figures["bias"], bias)
                own["bias"] = bias
        if per_stream is not None:   # each stream's own figures and signs (``per_stream``: a list to fill)
            per_stream.append((own, [k for k, lim in MEMS_LIMITS.items() if own[k] > lim * scale]))
    if len(sub) == 2 and len(sub[0][0]) == len(sub[1][0]):
        (w1, ok1), (w2, ok2) = sub
        both = ok1 & ok2
        if not both.all():
            w1, w2 = w1[both], w2[both]
        if len(w2) >= 16:   # the least-squares fit of w1 on w2 and a constant, centred: from the SVD of gyro 2's
            ones = np.ones(len(w2))          # centred rates (also its test of gyro 2's motion about every axis)
            m1, m2 = ones @ w1 / len(w1), ones @ w2 / len(w2)
            U, sv, Vt = np.linalg.svd(minus_row(w2, m2), full_matrices=False)
            if sv[-1] > 1e-6 * sv[0]:   # gyro 2 moves about every axis: the fit's offset is determined
                offset = m1 - m2 @ (Vt.T @ ((U.T @ minus_row(w1, m1)) / sv[:, None]))
                if np.isfinite(offset).all():
                    figures["offset"] = float(np.linalg.norm(offset))
    signs = [k for k, lim in MEMS_LIMITS.items() if figures[k] > lim * scale]
    return figures, signs


def _row_norms(x) -> np.ndarray:
    """``np.linalg.norm(x, axis=1)`` of an (N, 3) array, the same values (the squares added column by column in
    the same order), without numpy's slow reduction along short rows."""
    sq = x * x
    return np.sqrt(sq[:, 0] + sq[:, 1] + sq[:, 2])


def describe_unit_evidence(figures: dict, signs, limit: float = _DEFAULT_LIMIT) -> str:
    """The figures of :func:`rate_unit_evidence` against their MEMS limits, in words."""
    scale = float(limit) / _DEFAULT_LIMIT
    what = {"noise": "white noise per sample", "bias": "rate at rest (static stretches)",
            "offset": "combined bias b_1 - A b_2", "range": "99th percentile of the rate"}
    parts = [f"{what[k]} {figures[k]:.3g} ({'above' if k in signs else 'within'} a MEMS gyro's "
             f"{MEMS_LIMITS[k] * scale:g})" for k in MEMS_LIMITS if np.isfinite(figures[k])]
    return "; ".join(parts)


def check_unit_evidence(omega_1, omega_2, mask=None, limit: float = _DEFAULT_LIMIT) -> None:
    """Refuse a pair whose rates both look like deg/s by two or more signs of :func:`rate_unit_evidence` each
    (or one at :data:`STRONG_SIGN` times its limit or more, the noise excepted: vibration aliased at the sample
    rate, or a rate with no smooth motion, raises the third differences without any unit in it); warn on any sign
    otherwise.

    The rate level alone (the 99th percentile above ``limit``) misses deg/s logs with slow motion; the noise,
    the rate at rest and the level together do not: in deg/s each is 57.3 times what a MEMS gyro gives in
    rad/s. One sign alone is said (a :class:`UserWarning` naming what was assumed), not refused: a noisy gyro
    or a large offset exists; a gyro beyond the MEMS figures is accepted with a larger ``limit``
    (``max_plausible_rate``).

    Raises
    ------
    InputError
        Naming the figures, their limits and the unit to pass.
    """
    import warnings

    from .errors import InputError

    scale = float(limit) / _DEFAULT_LIMIT
    per = []
    figures, signs = rate_unit_evidence((omega_1, omega_2), mask, limit, per_stream=per)
    joint = ["offset"] if "offset" in signs else []

    def deg_like(own_figures, own) -> bool:   # one stream's own signs, with the pair's combined bias
        own = own + joint
        return len(own) >= 2 or any((figures[k] if k == "offset" else own_figures[k]) >= STRONG_SIGN *
                                    MEMS_LIMITS[k] * scale for k in own if k != "noise")
    # both streams: one alone in deg/s is a unit mismatch, which the solver names with both units
    if signs and len(per) == 2 and all(deg_like(*p) for p in per):
        raise InputError(f"omega_1 and omega_2: expected rates in rad/s, got rates that look like deg/s: "
                         f"{describe_unit_evidence(figures, signs, limit)}; pass unit deg/s (--unit1/--unit2), or a "
                         f"larger max_plausible_rate for a gyro beyond these MEMS figures")
    if signs:
        warnings.warn("rates taken as rad/s although some signs say deg/s: "
                      f"{describe_unit_evidence(figures, signs, limit)}",
                      UserWarning, stacklevel=3)
