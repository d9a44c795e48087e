"""The noise of a moving rigid pair, identified from its own residual: :func:`identify_noise`.

The residual of a rigid pair, ``r_k = omega_1(k) - A omega_2(k) - b`` (Eq. 4-5 with ``A`` and ``b``
from the direct solve, Eq. 12-17), removes the motion and keeps what the calibration has to weigh:
the white noise of both gyros, ``n_1 - A n_2``, the drift of the combined bias ``b_1(k) - A b_2(k)``
about its mean, and any model error. Four questions are answered from it, each in O(N):

* **Is it noise at all?** In windows of about a second the residual variance is regressed on the
  window's mean squared rate, ``var = sigma_0^2 + c_1 |omega|^2 + c_2 |omega|^4`` (non-negative
  least squares). A significant rate term that explains more than a tenth of the variance is model
  error (a rate-dependent scale or cross-axis error, timing, flex), not sensor noise: the result says
  so (:attr:`NoiseKind.RATE_MISFIT`, ``kind = "not white noise: rate-dependent misfit"``) and the noise
  is then taken from the windows where the fitted misfit is negligible.
* **How much white noise, how much bias drift?** The overlapping Allan deviation of the residual
  (the residual as a rate signal; checked against allantools in the tests) is fitted with a gyro's noise
  terms (IEEE Std 952, :func:`~fusion_gyrocal.core.allan.fit_allan`): ``AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau
  + (2 ln 2 / pi) B^2 + K^2 tau / 3 + F^2 g(tau / T_c) / tau`` with quantisation or white angle noise ``Q``
  (slope -1: a quantised angle, or a rate differentiated from a noisy orientation such as motion capture's),
  white rate noise ``N`` (slope -1/2, rad/s/sqrt(Hz)), bias instability ``B`` (flat), bias random walk ``K``
  (slope +1/2, rad/s^1.5) and first-order low-pass filtered white noise ``F`` (flat below its time constant
  ``T_c``), each term kept only where it lowers the chi-square significantly (and, for ``Q`` and ``F``, makes a
  material share of the curve). The weights are the equivalent degrees of freedom of each point. The white
  level a calibration over windows of ``window_s`` sees (:func:`white_level`) is ``tau AVAR(tau)`` of the
  short-term terms at ``tau = window_s``: ``N^2``, nearly all of ``F^2``, ``3 Q^2 / window_s``. A per-sample
  white std ``sigma`` is that level times ``rate_hz``, square-rooted; a random walk of step std ``q`` per sample
  is ``K / sqrt(rate_hz)``. Where no term fits the short taus, those taus are dropped and the residual is
  reported as coloured; ``adev_worst`` says how far the model is from the points it fitted.
* **Which gyro?** The residual only sees ``sigma_1^2 + sigma_2^2``. Where the log has still stretches (the
  pair's motion below the residual's noise and each gyro at its quietest, e.g. the static poses many logs start
  with, or the breaks of a hand-held log), each gyro's own stream there is its noise: its own Allan deviation is
  fitted with the same terms, a static test from the log itself (:func:`_steady_allan`), and its white level is
  used for that gyro (``still_noise_std``; the residual's level is then the check). Else the steady windows'
  variances give the ratio (``var(omega_1) - cov(omega_1, A omega_2)`` is gyro 1's, ``var(A omega_2) - cov``
  gyro 2's), else each stream's third differences, else the split is equal. The bias walk is split equally
  (only the sum is observable).
* **Never above the residual.** The per-sample variance the white noise implies may not exceed the residual's
  own spread by more than :data:`CONTRADICT` unless the fit found filtered noise (correlated samples spread less
  than the white level the motion sees); beyond it both levels are scaled down to the residual's, and say so.

The bias model is chosen from the fit: a random walk when ``K`` is significant (z >= 3) and its
steady-state Kalman filter settles within a twentieth of the log (otherwise the constant-bias model
loses nothing and keeps every sample). :attr:`NoiseModel.calibrate_keywords` gives ``noise_std`` and
``bias_walk_std`` as :func:`~fusion_gyrocal.calibrate_pair` takes them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from enum import Enum
from typing import NamedTuple

import numpy as np

from ..errors import InputError, OptionError
from .allan import (FILTERED, FIT_FACTOR, FLICKER_TERM, QUANTISATION, TERMS, WALK, AllanFit, allan_points,
                    edf_table, fit_allan, second_differences)
from .moments import NOMINAL_WINDOW, as_rates, column_means, finite_rows, median, minus_row, rows_times

MISFIT_SHARE = 0.1                    # rate-explained share of the residual variance that is flagged
WALK_Z = 3.0                          # significance of K for a random-walk bias
SETTLE_FRACTION = 1.0 / 20.0          # Kalman time constant of the walk, at most this fraction of the log
MIN_STEADY_WINDOWS = 5
MAX_IDENTIFY_SAMPLES = 2 ** 16   # longer logs: identified on stretches spread over them (bounded time and memory)
STRETCH_WINDOWS = 64             # windows per stretch
NOISE_SPLIT_SAMPLES = 16384   # samples behind the noise split: 16 blocks of 1024 spread over the log
_NOISE_BLOCK = 1024
#: Fewest degrees of freedom of a residual a noise level is estimated from (the estimate's relative std is then
#: at most sqrt(2 / 30) = 26 % in variance): fewer, and a noise-free exact fit reports a spurious zero noise.
MIN_RESIDUAL_DOF = 30


def check_residual_dof(dof: float, what: str = "the least-squares residual") -> None:
    """Refuse to estimate a noise level from ``what`` with fewer than :data:`MIN_RESIDUAL_DOF` degrees of freedom.

    ``dof`` counts the residual's scalar degrees of freedom: three per sample, less every fitted parameter
    (``A`` and the bias of the direct solve, Eq. 12-17: 12, and 3 per bias window beyond the first).
    """
    if not dof >= MIN_RESIDUAL_DOF:
        raise InputError(f"noise_std: expected at least {MIN_RESIDUAL_DOF} degrees of freedom in {what} to estimate "
                         f"the noise from it, got {max(dof, 0):g} (three per sample less the fitted A and biases): "
                         "record more samples or pass noise_std")


def difference_noise_std(omega, mask=None, *, max_samples: int = NOISE_SPLIT_SAMPLES) -> float:
    """White-noise std per sample of one stream from its third differences (robust, MAD).

    ``Var(Delta^3 n) = 20 sigma^2`` for white noise, while smooth motion contributes little to the
    third difference; fast motion at a low sample rate biases the value upwards, so the library
    uses it only to split the residual variance between the gyros, never for its level.

    A log longer than ``max_samples`` is subsampled: blocks of 1024 consecutive samples spread evenly
    over it (differences never cross a block), so the cost is bounded whatever the length.
    Masked (``mask`` False) and non-finite samples are dropped before differencing.
    """
    w = np.asarray(omega)
    n = w.shape[0]
    if n > max_samples:
        nb = max(1, max_samples // _NOISE_BLOCK)
        starts = np.linspace(0, n - _NOISE_BLOCK, nb).astype(np.int64)
        spans = [(int(a), int(a) + _NOISE_BLOCK) for a in starts]
    else:
        spans = [(0, n)]
    x = np.concatenate([np.asarray(w[a:b], dtype=np.float64) for a, b in spans])
    if mask is None and x.shape[0] > 3 and np.isfinite(x.sum()):   # all whole: differenced at once, (3, blocks, len)
        x = np.ascontiguousarray(x.T).reshape(3, len(spans), -1)
        d = x[..., 3:] - x[..., :-3]
        inner = x[..., 2:-1] - x[..., 1:-2]
        inner *= 3.0
        d -= inner                         # (x3 - x0) - 3 (x2 - x1): the loop's operations, two temporaries
        parts = [d.reshape(3, -1)]
    else:
        parts = []
        for a, b in spans:
            x = np.asarray(w[a:b], dtype=np.float64)
            ok = finite_rows(x)
            if mask is not None:
                ok &= np.asarray(mask[a:b], dtype=bool)
            x = (x if ok.all() else x[ok]).T              # (3, m): rows contiguous for the partitions below
            if x.shape[1] > 3:
                parts.append((x[:, 3:] - x[:, :-3]) - 3.0 * (x[:, 2:-1] - x[:, 1:-2]))
    d = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1) if parts else np.zeros((3, 0))
    if d.shape[1] < 10:
        return float("nan")
    d -= median(d, axis=1)[:, None]
    np.abs(d, out=d)
    return float(median(1.4826 * median(d, axis=1)) / np.sqrt(20.0))



class NoiseKind(str, Enum):
    """What the residual of a pair is (:attr:`NoiseModel.noise_kind`); :attr:`text` is the sentence reports show.

    The members' values are what :meth:`NoiseModel.to_dict` writes as ``noise_kind``; decisions test the member,
    never the sentence.
    """

    WHITE = "white"
    WHITE_WALK = "white_walk"
    COLOURED = "coloured"
    RATE_MISFIT = "rate_misfit"

    @property
    def text(self) -> str:
        """The sentence for reports and the ``kind`` of the JSON (``"white noise"``, ...)."""
        return _KIND_TEXT[self]

    @property
    def is_white(self) -> bool:
        """White noise, with or without a bias random walk."""
        return self in (NoiseKind.WHITE, NoiseKind.WHITE_WALK)

    @classmethod
    def from_text(cls, text: str) -> "NoiseKind":
        """The kind a file of format 1.0-1.2 names by its sentence only (:data:`LEGACY_KIND_TEXTS`)."""
        try:
            return LEGACY_KIND_TEXTS[text]
        except KeyError:
            raise ValueError(f"kind: expected one of {sorted(LEGACY_KIND_TEXTS)}, got {text!r}") from None


_KIND_TEXT = {NoiseKind.WHITE: "white noise", NoiseKind.WHITE_WALK: "white noise + bias random walk",
              NoiseKind.COLOURED: "coloured noise", NoiseKind.RATE_MISFIT: "not white noise: rate-dependent misfit"}
#: The sentences calibrations of format 1.0-1.2 stored as the noise model's ``kind`` (and nothing else): read
#: back by :meth:`NoiseKind.from_text` whatever :attr:`NoiseKind.text` says today.
LEGACY_KIND_TEXTS = {"white noise": NoiseKind.WHITE, "white noise + bias random walk": NoiseKind.WHITE_WALK,
                     "coloured noise": NoiseKind.COLOURED,
                     "not white noise: rate-dependent misfit": NoiseKind.RATE_MISFIT}


@dataclass(frozen=True)
class Resampling:
    """How each stream of an aligned pair reached the grid (:func:`~fusion_gyrocal.pipeline.resample.noise_factors`).

    Attributes
    ----------
    rates_hz : tuple of float
        Each gyro's own sample rate (Hz).
    variance : tuple of float
        Variance of each stream's white noise on the grid over that at its own samples (1: not resampled).
    diff3 : tuple of float
        The same for its third differences (against the 20 sigma^2 of white noise).
    density : tuple of float
        Each stream's low-frequency noise density on the grid over its own (1 when upsampled; about
        ``variance f_own / f_grid`` when downsampled: aliasing).
    white_from : int
        Grid samples from which the interpolated noise's Allan variance is within 5 % of its white line (the
        residual's Allan fit starts there).
    """

    rates_hz: tuple
    variance: tuple = (1.0, 1.0)
    diff3: tuple = (1.0, 1.0)
    density: tuple = (1.0, 1.0)
    white_from: int = 1


@dataclass(frozen=True)
class NoiseModel:
    """Noise of a gyro pair identified from its residual (:func:`identify_noise`).

    Attributes
    ----------
    rate_hz : float
        Sample rate the per-sample numbers refer to.
    noise_std : tuple of float
        White-noise std per sample of gyro 1 and gyro 2 (rad/s), as ``calibrate_pair(noise_std=...)``
        takes it.
    noise_std_uncertainty : tuple of float
        Their standard uncertainties (statistical; an equal split carries none, see ``sources``).
    bias_walk_std : tuple of float or None
        Bias random-walk step std per sample of gyro 1 and gyro 2 (rad/s), as
        ``calibrate_pair(bias_walk_std=...)`` takes it; None when ``bias_model == "constant"``.
    bias_model : {"constant", "random walk"}
        The bias model chosen from the data.
    residual_noise_std, residual_noise_std_uncertainty : float
        White std per sample of the residual per axis, ``sqrt(sigma_1^2 + sigma_2^2 |A|_F^2 / 3)``.
    residual_walk_std, residual_walk_std_uncertainty : float
        Random-walk step std per sample of the combined bias ``b_1 - A b_2`` per axis (0 when the fit
        has no walk term); reported even when the constant model is chosen.
    bias_instability, bias_instability_uncertainty : float
        ``B`` (rad/s) of the residual, 0 when the fit has no flicker term.
    white_std_at_rest : float
        Intercept ``sigma_0`` of the heteroscedastic regression (the residual's std at zero rate).
    misfit_gain : tuple of float
        ``(a, b)`` of the misfit ``(a + b |omega|) omega`` fitted to the windows' mean square residual:
        ``a`` dimensionless (a leftover scale or cross-axis error), ``b`` per rad/s (a rate-dependent
        scale error).
    misfit_share : float
        Share of the residual variance that the rate terms explain.
    noise_kind : NoiseKind
        White noise, white noise and a bias random walk, coloured noise or a rate-dependent misfit;
        :attr:`kind` is its sentence.
    taus : ndarray (T,)
        Averaging times of the Allan curve (s).
    adev : ndarray (T, 3)
        Overlapping Allan deviation of the residual per axis (rad/s), on the samples of the fit.
    adev_fit : ndarray (T,)
        The fitted model's Allan deviation (rad/s).
    fit_taus : tuple of float
        The range of taus the fit used.
    sources : dict
        Where each number came from (keys ``noise``, ``split``, ``bias``, ``misfit``).
    notes : tuple of str
    rate_known : bool
        False when the input had no sample rate (sample-aligned arrays): ``rate_hz`` is then 1 and
        the times are in samples; the per-sample figures hold at any rate, the densities need one.
    rates_hz : tuple of float or None
        Each gyro's own sample rate when a stream was resampled onto the grid (:class:`Resampling`); None:
        both at ``rate_hz``.
    densities : tuple of float or None
        Each gyro's own white rate-noise density (rad/s/sqrt(Hz)) when a stream was resampled (interpolation
        changes its noise per grid sample, and aliasing its density on a coarser grid); None: ``noise_std /
        sqrt(rate_hz)``.
    adev_worst : float
        How far the fitted model (``adev_fit``) is from the residual's Allan deviation over the fitted taus: the
        largest ratio (either way) beyond each point's 2-sigma scatter; NaN in files written before it.
    quantisation : float
        ``Q`` (rad) of the residual's slope -1 term (quantisation, or a rate differentiated from a noisy angle),
        0 without it.
    filter_time_s : float
        Time constant (s) of the residual's low-pass filtered noise term, 0 without it.
    still_noise_std : tuple of float or None
        Each gyro's white noise per sample (rad/s) from its own still stretches (a static test from the log:
        :func:`identify_noise`), None where the log has none; ``noise_std`` is this pair when it was used.
    """

    rate_hz: float
    noise_std: tuple
    noise_std_uncertainty: tuple
    bias_walk_std: tuple | None
    bias_model: str
    residual_noise_std: float
    residual_noise_std_uncertainty: float
    residual_walk_std: float
    residual_walk_std_uncertainty: float
    bias_instability: float
    bias_instability_uncertainty: float
    white_std_at_rest: float
    misfit_gain: tuple
    misfit_share: float
    noise_kind: NoiseKind
    taus: np.ndarray
    adev: np.ndarray
    adev_fit: np.ndarray
    fit_taus: tuple
    sources: dict = field(default_factory=dict)
    notes: tuple = ()
    rate_known: bool = True
    rates_hz: tuple | None = None
    densities: tuple | None = None
    adev_worst: float = float("nan")
    quantisation: float = 0.0
    filter_time_s: float = 0.0
    still_noise_std: tuple | None = None

    def __post_init__(self):
        object.__setattr__(self, "noise_kind", NoiseKind(self.noise_kind))   # a member, also when given its value

    @property
    def kind(self) -> str:
        """The sentence of :attr:`noise_kind`: ``"white noise"``, ``"white noise + bias random walk"``,
        ``"coloured noise"`` or ``"not white noise: rate-dependent misfit"``."""
        return self.noise_kind.text

    @property
    def is_white(self) -> bool:
        """True when the residual is white noise (with or without a bias random walk)."""
        return self.noise_kind.is_white

    @property
    def fits(self) -> bool:
        """The fitted Allan model passes through the residual's points (``adev_worst`` at most
        :data:`~fusion_gyrocal.core.allan.FIT_FACTOR`; True for a file that does not say)."""
        return not self.adev_worst > FIT_FACTOR

    @property
    def is_misfit(self) -> bool:
        """True when the residual is a rate-dependent misfit (model error, not sensor noise)."""
        return self.noise_kind is NoiseKind.RATE_MISFIT

    @property
    def noise_density(self) -> tuple:
        """White rate noise density of each gyro (rad/s/sqrt(Hz)): ``noise_std / sqrt(rate_hz)``, or the sensor's
        own (``densities``) when a stream was resampled onto the grid."""
        if self.densities is not None:
            return tuple(float(d) for d in self.densities)
        return tuple(float(s / np.sqrt(self.rate_hz)) for s in self.noise_std)

    @property
    def sensor_rates(self) -> tuple:
        """Each gyro's own sample rate (Hz): ``rates_hz``, or ``rate_hz`` for both."""
        return tuple(float(r) for r in (self.rates_hz or (self.rate_hz, self.rate_hz)))

    @property
    def random_walk(self) -> tuple | None:
        """Bias random walk of each gyro, ``bias_walk_std * sqrt(rate_hz)`` (rad/s^1.5, the Allan ``K``)."""
        if self.bias_walk_std is None:
            return None
        return tuple(float(q * np.sqrt(self.rate_hz)) for q in self.bias_walk_std)

    @property
    def calibrate_keywords(self) -> dict:
        """``noise_std`` (and ``bias_walk_std`` for a random-walk bias) for :func:`~fusion_gyrocal.calibrate_pair`."""
        out = {"noise_std": self.noise_std}
        if self.bias_walk_std is not None:
            out["bias_walk_std"] = self.bias_walk_std
        return out

    def to_dict(self) -> dict:
        """JSON-ready dictionary (non-finite numbers as ``"NaN"``/``"Infinity"`` strings, as the calibration's);
        the kind as its sentence (``kind``) and its member's value (``noise_kind``)."""
        from .model import to_json_list, to_json_number

        def enc(v):
            if isinstance(v, np.ndarray):
                return to_json_list(v)
            if isinstance(v, (tuple, list)):
                return [enc(x) for x in v]
            if isinstance(v, float):
                return to_json_number(v)
            return v
        out = {}
        for f in fields(self):
            if f.name == "noise_kind":
                out["kind"] = self.kind
                out["noise_kind"] = self.noise_kind.value
            else:
                out[f.name] = enc(getattr(self, f.name))
        return out

    @classmethod
    def from_dict(cls, d: dict) -> "NoiseModel":
        """Inverse of :meth:`to_dict`; a model of format 1.0-1.2 (its ``kind`` sentence only) gets the kind that
        sentence names (:meth:`NoiseKind.from_text`)."""
        from ..errors import FormatError
        from .model import NON_FINITE, from_json_list

        def num(v):
            return NON_FINITE[v] if isinstance(v, str) else float(v)
        try:
            kw = dict(d)
            for name in ("taus", "adev_fit", "adev"):
                kw[name] = from_json_list(kw[name], np.float64)
            for name in ("noise_std", "noise_std_uncertainty", "misfit_gain", "fit_taus", "bias_walk_std", "rates_hz",
                         "densities", "still_noise_std"):
                if kw.get(name) is not None:
                    kw[name] = tuple(num(x) for x in kw[name])
            for name in ("rate_hz", "residual_noise_std", "residual_noise_std_uncertainty", "residual_walk_std",
                         "residual_walk_std_uncertainty", "bias_instability", "bias_instability_uncertainty",
                         "white_std_at_rest", "misfit_share"):
                kw[name] = num(kw[name])
            for name in ("adev_worst", "quantisation", "filter_time_s"):
                if name in kw:
                    kw[name] = num(kw[name])
            kw["notes"] = tuple(kw.get("notes", ()))
            text = kw.pop("kind")
            kw["noise_kind"] = NoiseKind(kw["noise_kind"]) if "noise_kind" in kw else NoiseKind.from_text(text)
            return cls(**kw)
        except (KeyError, TypeError, ValueError) as exc:
            raise FormatError(f"calibration: expected a noise_model with the fields of NoiseModel, got {exc}") from None

    def describe(self) -> str:
        """One line per number with its source (for reports and the CLI)."""
        deg = 180.0 / np.pi
        lines = [f"residual: {self.kind}"]
        for i in (0, 1):
            density = (f" ({self.noise_density[i] * deg * 3600 / 60:.4g} deg/sqrt(h))" if self.rate_known else
                       " (sample rate unknown: times are in samples)")
            lines.append(f"gyro {i + 1}: white {self.noise_std[i] * deg:.4g} +- {self.noise_std_uncertainty[i] * deg:.2g} "
                         f"deg/s per sample{density}")
        if self.bias_walk_std is not None:
            lines.append(f"bias random walk {self.bias_walk_std[0] * deg:.3g} deg/s per sample per gyro")
        else:
            lines.append("bias: constant")
        if self.still_noise_std is not None:
            lines.append("white noise from: " + ("each gyro's own still stretches (a static test from the log)"
                                                 if np.allclose(self.noise_std, self.still_noise_std, rtol=1e-9) else "the residual's Allan fit"
                                                 ) + "; still stretches give "
                         + " / ".join(f"{v * deg:.4g}" for v in self.still_noise_std) + " deg/s per sample")
        else:
            lines.append("white noise from: the residual's Allan fit (no still stretch in the log)")
        if np.isfinite(self.adev_worst):
            lines.append(f"Allan model vs the residual's points: within {self.adev_worst:.2f}x beyond their scatter"
                         + ("" if self.fits else f" (does NOT pass through them; more than {FIT_FACTOR:g}x off)"))
        lines += [f"{k}: {v}" for k, v in self.sources.items()]
        return "\n".join(lines + list(self.notes))


# ---------------------------------------------------------------------------------------------- windows
@dataclass(frozen=True)
class _Windows:
    start: np.ndarray     # first sample of each full, valid window
    v_r: np.ndarray       # residual mean square per axis (about the log's bias, so slow misfit counts)
    rate_powers: np.ndarray  # (W, 3) window means of |omega_1|^2, |omega_1|^3, |omega_1|^4
    e_1: np.ndarray       # var(omega_1) - cov(omega_1, A omega_2), per axis
    e_2: np.ndarray       # var(A omega_2) - cov, per axis
    cov: np.ndarray       # cov(omega_1, A omega_2) per axis (motion variance)
    length: int


_WINDOW_GROUP = 4096   # samples of the windows _windows reduces at a time: each stream's (3, samples) copy (96 KiB)
#                        reuses memory just freed; copies of a whole long log's stretches (1.5 MiB each) were
#                        fresh pages from the OS on every call, page faults costing more than the reductions


def _windows(r, w1, aw2, valid, w) -> _Windows:
    """Statistics of consecutive windows of ``w`` samples with at least half of them valid (the invalid
    samples are zero in ``r``, ``w1`` and ``aw2`` and left out of every sum)."""
    n_win = r.shape[0] // w
    m = n_win * w
    cnt = valid[:m].reshape(n_win, w).sum(axis=1)
    idx = np.flatnonzero(cnt >= max(w // 2, 4))
    cnt = cnt[idx].astype(float)
    v_r, m1, m2 = np.empty(idx.size), np.empty((3, idx.size)), np.empty((3, idx.size))
    powers, ss2, s12 = np.empty((idx.size, 3)), np.empty(idx.size), np.empty(idx.size)
    per = max(1, _WINDOW_GROUP // w)
    for lo in range(0, idx.size, per):      # the kept windows, a group of consecutive ones at a time
        sel = idx[lo:lo + per]
        a, b = int(sel[0]) * w, (int(sel[-1]) + 1) * w
        pick = slice(None) if sel.size == (b - a) // w else sel - sel[0]   # no copy when every window is kept
        # (3, windows, w): sums along contiguous rows (numpy sums (N, 3) along axis 0 slowly)
        R, X1, X2 = (np.ascontiguousarray(x[a:b].T).reshape(3, -1, w)[:, pick] for x in (r, w1, aw2))
        part = slice(lo, lo + sel.size)
        v_r[part] = np.einsum("ijk,ijk->j", R, R)
        sq = np.einsum("ijk,ijk->jk", X1, X1)        # |omega_1|^2 of each sample
        np.sum(sq, axis=1, out=powers[part, 0])
        np.sum(sq * np.sqrt(sq), axis=1, out=powers[part, 1])
        np.sum(sq * sq, axis=1, out=powers[part, 2])
        np.sum(X1, axis=2, out=m1[:, part])
        np.sum(X2, axis=2, out=m2[:, part])
        ss2[part] = np.einsum("ijk,ijk->j", X2, X2)
        s12[part] = np.einsum("ijk,ijk->j", X1, X2)
    v_r /= 3.0 * cnt
    rate_powers = powers / (3.0 * cnt[:, None])  # per axis
    # centred (co)variances per axis from window sums (rates and biases are far below 1e8 x the noise)
    k = 3.0 * (cnt - 1.0)
    v1 = (powers[:, 0] - np.einsum("ij,ij->j", m1, m1) / cnt) / k
    v2 = (ss2 - np.einsum("ij,ij->j", m2, m2) / cnt) / k
    c = (s12 - np.einsum("ij,ij->j", m1, m2) / cnt) / k
    return _Windows(idx * w, v_r, rate_powers, v1 - c, v2 - c, c, w)


def _misfit_fit(win: _Windows):
    """Heteroscedastic regression of the windows' mean square residual on their rate.

    The model is white noise plus a gain error that grows linearly with the rate,
    ``r = n + (a + b |omega|) omega``: ``E r^2 = sigma_0^2 + a^2 |omega|^2 + 2 a b |omega|^3 + b^2 |omega|^4``
    averaged over each window (``a`` is a scale or cross-axis error left over, ``b`` a rate-dependent
    scale error per rad/s; the direct solve absorbs the mean gain, so ``a`` and ``b`` usually have
    opposite signs). Weighted by the chi-square spread of a mean square, reweighted with the model.

    Returns
    -------
    params : (sigma_0^2, a, b)
    pred : ndarray, the fitted mean square of each window
    drop : float
        Chi-square drop against a constant, divided by the reduced chi-square of the fit when above 1.
    """
    v, P = win.v_r, win.rate_powers
    dof = 3.0 * win.length
    phi = np.linspace(0.0, np.pi, 61)[:-1]  # direction of (a, b); the fit is linear in (sigma_0^2, g^2)
    cos, sin = np.cos(phi), np.sin(phi)
    U = cos[:, None] ** 2 * P[:, 0] + 2.0 * (cos * sin)[:, None] * P[:, 1] + sin[:, None] ** 2 * P[:, 2]
    UU, vv = U * U, v * v      # (directions, windows) and (windows,): the same in every pass
    pred = np.full_like(v, max(float(median(v)), 1e-300))
    for _ in range(3):
        wt2 = (dof / 2.0) / np.maximum(pred, 1e-300) ** 2
        # weighted two-parameter least squares for every direction at once, clipped to g^2 >= 0
        S0, Sv, Svv = wt2.sum(), wt2 @ v, wt2 @ vv
        Su, Suu, Suv = U @ wt2, UU @ wt2, U @ (wt2 * v)
        det = S0 * Suu - Su * Su
        g2 = np.where(det > 0, (S0 * Suv - Su * Sv) / np.where(det > 0, det, 1.0), 0.0)
        g2 = np.maximum(g2, 0.0)
        c0 = np.maximum((Sv - g2 * Su) / S0, 0.0)
        chi = Svv - 2 * c0 * Sv - 2 * g2 * Suv + c0 * c0 * S0 + 2 * c0 * g2 * Su + g2 * g2 * Suu
        k = int(np.argmin(chi))
        pred = c0[k] + g2[k] * U[k]
    g = np.sqrt(g2[k])
    x = (np.sqrt(c0[k]), g * np.cos(phi[k]), g * np.sin(phi[k]))
    wt = np.sqrt(dof / 2.0) / np.maximum(pred, 1e-300)
    chi2 = float(np.sum(((v - pred) * wt) ** 2))
    mean0 = float(np.mean(v))
    chi2_0 = float(np.sum(((v - mean0) * np.sqrt(dof / 2.0) / mean0) ** 2))
    red = max(1.0, chi2 / max(v.size - 3, 1))
    return (float(x[0] ** 2), float(x[1]), float(x[2])), pred, (chi2_0 - chi2) / red


def _steady_split(win: _Windows, rate_hz: float):
    """Each gyro's own variance from the windows where the motion is below the noise; None if too few."""
    steady = win.cov <= win.v_r
    n = int(steady.sum())
    if n < MIN_STEADY_WINDOWS:
        return None
    e1, e2 = win.e_1[steady], win.e_2[steady]
    m1, m2 = float(e1.mean()), float(e2.mean())
    if m1 <= 0 or m2 <= 0:
        return None
    sd1, sd2 = float(e1.std(ddof=1)) / np.sqrt(n), float(e2.std(ddof=1)) / np.sqrt(n)
    starts = win.start[steady]
    runs = np.split(starts, np.flatnonzero(np.diff(starts) != win.length) + 1)
    longest = max(runs, key=len)
    t0, t1 = longest[0] / rate_hz, (longest[-1] + win.length) / rate_hz
    text = (f"steady stretches (both gyros' motion below their noise): {n * win.length / rate_hz:.1f} s in "
            f"{len(runs)} stretch(es), longest {t0:.1f}-{t1:.1f} s")
    # ratio^2 = m1 / m2 and its relative variance (delta method)
    return m1 / m2, (sd1 / m1) ** 2 + (sd2 / m2) ** 2, text, (np.sqrt(m1), np.sqrt(m2))


class _SteadyNoise(NamedTuple):
    """Each gyro's own noise on the steady stretches (:func:`_steady_allan`)."""

    taus: np.ndarray
    avar: tuple           # each gyro's Allan variance (gyro 2's in its own frame: divided by |A|_F^2 / 3)
    fits: tuple           # each gyro's AllanFit
    level: tuple          # each gyro's white level N^2 on the grid (white_level) and
    level_sd: tuple       # its standard uncertainty
    seconds: float
    text: str


CONTRADICT = 1.5 ** 2    # the white level's per-sample variance over the residual's mean square, at most
MAX_FILTER_S = 1.0 / 8.0   # the filtered term's time constant, at most this fraction of the window
STILL_TAU = 4.0     # a gyro's still stretches are fitted up to tau = this many windows (the white level's range)
STILL_SMOOTHNESS = 10.0   # a still stream's variance over its Allan variance at one sample, at most (motion: far more)
STILL_FACTOR = 2.0   # a gyro's still windows: its variance within this factor of its quietest tenth


def _steady_allan(win: _Windows, w1, aw2, a: float, rate_hz: float, first: int, window_s: float,
                  boundary: int | None) -> _SteadyNoise | None:
    """Each gyro's own Allan variance on its still stretches, fitted with the terms of
    :func:`~fusion_gyrocal.core.allan.fit_allan`: the noise a static test of each sensor would give, from the log
    itself (the static poses many logs start with, the breaks of a hand-held one).

    A gyro's still windows are the steady ones (the pair's common motion below the residual's noise,
    ``cov(omega_1, A omega_2) <= E r^2``) where its own variance is within :data:`STILL_FACTOR` of the quietest
    tenth of them: there its stream is its noise. Runs of consecutive still windows are the stretches (never
    across ``boundary``, the length of a joined stretch of a long log); their second differences are pooled per
    tau. Gyro 2's stream is ``A omega_2``, divided by ``|A|_F^2 / 3``. None with fewer than
    :data:`MIN_STEADY_WINDOWS` still windows or four taus for either gyro, or where a gyro's still stretches are
    smooth (their variance over :data:`STILL_SMOOTHNESS` times their Allan variance at one sample: the quietest
    windows of a log with no rest are slow motion, not noise)."""
    steady = win.cov <= win.v_r
    if int(steady.sum()) < MIN_STEADY_WINDOWS:
        return None
    fits, levels, sds, avars, seconds, taus_all = [], [], [], [], [], None
    texts = []
    for i, (x, var) in enumerate(((w1, win.e_1 + win.cov), (aw2, win.e_2 + win.cov))):
        floor = np.quantile(var[steady], 0.1)
        still = steady & (var <= STILL_FACTOR * floor)
        if int(still.sum()) < MIN_STEADY_WINDOWS:
            return None
        starts = win.start[still]
        cut = np.diff(starts) != win.length
        if boundary:
            cut |= (starts[1:] // boundary) != (starts[:-1] // boundary)
        runs = np.split(starts, np.flatnonzero(cut) + 1)
        T = int(np.floor(np.log2(max(max(len(r) for r in runs) * win.length / 4.0, 1.0)))) + 1
        S, C, dof = np.zeros(T), np.zeros(T), np.zeros((T, 4))
        ss, count = 0.0, 0
        tables: dict = {}     # runs of one length share their phase points: each table computed once
        for run in runs:
            lo, hi = int(run[0]), int(run[-1]) + win.length
            xr = x[lo:hi]
            ss += float(np.sum(minus_row(xr, column_means(xr)) ** 2))
            count += 3 * (hi - lo - 1)
            taus, sums, sub_n, sub_m = second_differences([xr], rate_hz)
            k = taus.size
            S[:k] += sums[0].sum(axis=1)
            C[:k] += 3.0 * sums[-1]
            if hi - lo not in tables:
                tables[hi - lo] = edf_table(sub_n, sub_m)
            dof[:k] += tables[hi - lo]
        n = min(int(np.count_nonzero(C > 0)), int(np.log2(STILL_TAU * window_s * rate_hz)) + 1)
        if n < 4:
            return None
        taus = 2.0 ** np.arange(n) / rate_hz
        v = S[:n] / C[:n] / (1.0 if i == 0 else a)
        if ss / count / (1.0 if i == 0 else a) > STILL_SMOOTHNESS * v[0]:   # smooth: motion, not noise
            return None
        fit = fit_allan(taus, v, dof[:n], min(first if i == 1 else 0, n - 4), MAX_FILTER_S * window_s)
        level, sd = white_level(fit, window_s)
        fits.append(fit)
        levels.append(level)
        sds.append(sd)
        avars.append(v)
        seconds.append(int(still.sum()) * win.length / rate_hz)
        longest = max(runs, key=len)
        texts.append(f"gyro {i + 1} {seconds[-1]:.1f} s in {len(runs)} stretch(es), longest "
                     f"{longest[0] / rate_hz:.1f}-{(longest[-1] + win.length) / rate_hz:.1f} s")
        taus_all = taus if taus_all is None or taus.size > taus_all.size else taus_all
    text = "steady stretches, each gyro at its quietest (still): " + "; ".join(texts)
    return _SteadyNoise(taus_all, tuple(avars), tuple(fits), tuple(levels), tuple(sds), min(seconds), text)


# ---------------------------------------------------------------------------------------------- entry point
def identify_noise(omega_1, omega_2, A, bias, *, rate_hz: float | None, mask=None, window_s: float = 1.0,
                   resampling: Resampling | None = None) -> NoiseModel:
    """Identify white noise, bias drift and model error of a rigid pair from its residual.

    Parameters
    ----------
    omega_1, omega_2 : array_like, shape (N, 3)
        Sample-aligned rates (rad/s) of gyro 1 and gyro 2 at ``rate_hz``.
    A : array_like (3, 3)
        ``S_1 R_1_2 S_2^-1`` (Eq. 4), e.g. from :func:`~fusion_gyrocal.core.direct.solve_A`. A log longer than
        :data:`MAX_IDENTIFY_SAMPLES` is identified on stretches spread over it, with ``A`` fitted again on them,
        each with a bias of its own (a drifting bias leaks into a constant-bias fit's ``A``), and no Allan
        difference across two stretches.
    bias : array_like (3,)
        The combined bias ``b_1 - A b_2`` (Eq. 5) that goes with ``A``.
    rate_hz : float or None
        Sample rate (Hz): converts per-sample numbers to densities and sets the windows. None for input
        without one (sample-aligned arrays): the model is identified per sample, ``window_s`` counting
        :data:`~fusion_gyrocal.core.moments.NOMINAL_WINDOW` samples a second, and says so (``rate_known``).
    mask : array_like of bool (N,), optional
        Samples to use (non-finite samples are always left out). Masked samples are skipped in the
        Allan computation (the kept samples are joined; the walk is corrected for the time left out).
    window_s : float
        Length of the windows of the heteroscedastic regression and the steady-stretch search (s).
    resampling : Resampling, optional
        How the streams reached the grid (a two-rate pair, a fractional offset): the split between the gyros
        and their densities are then the sensors' own (``densities``, ``rates_hz``), while ``noise_std`` stays
        the noise per grid sample the solver weighs.

    Returns
    -------
    NoiseModel

    Raises
    ------
    InputError
        Wrong shapes, or fewer than 16 full windows of valid samples.
    OptionError
        A non-positive ``rate_hz`` or ``window_s``.

    Examples
    --------
    >>> from fusion_gyrocal.core.direct import solve_A
    >>> from fusion_gyrocal.core.moments import Moments
    >>> from fusion_gyrocal.evaluate.sim import simulate_pair
    >>> sim = simulate_pair(n=6000, rng=0, bias_walk_std=0.0)
    >>> A, b = solve_A(Moments.from_samples(sim.omega_1, sim.omega_2))
    >>> nm = identify_noise(sim.omega_1, sim.omega_2, A, b, rate_hz=100.0)
    >>> nm.kind, nm.bias_model
    ('white noise', 'constant')
    """
    if rate_hz is None:   # per sample: times in samples, the figures hold at any rate
        import dataclasses
        nm = identify_noise(omega_1, omega_2, A, bias, rate_hz=1.0, mask=mask, window_s=window_s * NOMINAL_WINDOW)
        return dataclasses.replace(nm, rate_known=False)
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise OptionError(f"rate_hz: expected a positive sample rate in Hz, got {rate_hz!r}")
    if not (np.isfinite(window_s) and window_s > 0):
        raise OptionError(f"window_s: expected a positive window length in s, got {window_s!r}")
    w1 = as_rates("omega_1", omega_1)
    w2 = as_rates("omega_2", omega_2, length=w1.shape[0])
    n = w1.shape[0]
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (n,):
            raise InputError(f"mask: expected shape ({n},), got {mask.shape}")
    if n > MAX_IDENTIFY_SAMPLES:   # a long log: contiguous stretches spread over it, each on its own
        w = max(8, int(round(window_s * rate_hz)))
        spans = _stretches(n, w)
        size = sum(b - a for a, b in spans)
        j1, j2 = _join(w1, spans, np.float64), _join(w2, spans, np.float64)
        jmask = None if mask is None else _join(mask, spans, bool)
        stretch = spans[0][1] - spans[0][0]
        nm = _identify(j1, j2, _stretch_map(j1, j2, jmask, stretch, A), bias, rate_hz, jmask, window_s,
                       stride=n / size, resampling=resampling, stretch=stretch)
        sources = dict(nm.sources)
        sources["noise"] += (f"; on {size} samples in {len(spans)} stretches spread over the "
                             f"{n}-sample log (their Allan sums pooled, none across two stretches)")
        import dataclasses
        return dataclasses.replace(nm, sources=sources)
    return _identify(np.asarray(w1, dtype=np.float64), np.asarray(w2, dtype=np.float64), A, bias, rate_hz, mask,
                     window_s, resampling=resampling)


def _stretch_map(w1, w2, mask, length: int, A) -> np.ndarray:
    """``A`` of the least-squares fit (Eq. 17) on the joined stretches of ``length`` samples ``w1``, ``w2`` (the
    samples ``mask``, and finite), each with a bias of its own: a bias that drifts over a long log leaks into a
    constant-bias fit's ``A`` (its residual then carries the motion, far above the noise), not into this one;
    ``A`` as given where the stretches cannot determine it."""
    from ..errors import GyroCalError
    from .direct import solve_A
    from .moments import Moments, window_moments

    use = finite_rows(w1) & finite_rows(w2)
    if mask is not None:
        use &= mask
    try:
        return solve_A(Moments.pool_all(window_moments(w1, w2, length, mask=None if use.all() else use)))[0]
    except GyroCalError:
        return np.asarray(A, dtype=float)


def _stretches(n: int, window: int) -> list[tuple[int, int]]:
    """``(start, stop)`` of contiguous stretches of :data:`STRETCH_WINDOWS` windows, evenly spread over ``n``
    samples, :data:`MAX_IDENTIFY_SAMPLES` in all (windows never straddle two stretches)."""
    length = STRETCH_WINDOWS * window
    count = max(1, MAX_IDENTIFY_SAMPLES // length)
    starts = np.linspace(0, n - length, count).astype(np.int64) // window * window
    return [(int(a), int(a) + length) for a in starts]


def _join(a, spans, dtype) -> np.ndarray:
    """The rows of ``spans`` of ``a`` as one contiguous array (slices: far cheaper than a fancy index)."""
    return np.concatenate([np.asarray(a[lo:hi], dtype=dtype) for lo, hi in spans])


def _identify(w1, w2, A, bias, rate_hz, mask, window_s, stride: float = 1.0,
              resampling: Resampling | None = None, stretch: int | None = None) -> NoiseModel:
    """:func:`identify_noise` on float64 rates; ``stride`` log samples per sample given, ``stretch`` the samples
    of each of the joined stretches they are (None: one contiguous log).

    The steps, in order: the residual and its windows; 1. the rate-dependent misfit (:func:`_misfit_test`);
    2. the Allan fit of the residual (:func:`_allan_fit`); 3. the bias model (:func:`_bias_choice`); 4. the
    split between the gyros (:func:`_split`, or :func:`_own_noise` when every window carries the misfit).
    """
    A = np.asarray(A, dtype=float).reshape(3, 3)
    bias = np.asarray(bias, dtype=float).reshape(3)
    valid = finite_rows(w1) & finite_rows(w2)
    if mask is not None:
        valid &= mask
    everything = bool(valid.all())
    if not everything:
        w1, w2 = np.where(valid[:, None], w1, 0.0), np.where(valid[:, None], w2, 0.0)
    aw2 = rows_times(w2, A.T)
    r = w1 - aw2
    minus_row(r, bias, out=r)
    if not everything:
        r[~valid] = 0.0
    w = max(8, int(round(window_s * rate_hz)))
    win = _windows(r, w1, aw2, valid, w)
    if win.start.size < 16:
        raise InputError(f"omega_1/omega_2: expected at least 16 windows of {w} samples, half of them valid "
                         f"({window_s:g} s) to identify the noise, got {win.start.size}")
    notes, sources = [], {}
    mis = _misfit_test(win, valid, rate_hz, sources, notes)
    fit = _allan_fit(r, None if everything and not mis.flagged else mis.use, rate_hz, stride, resampling,
                     mis.flagged, window_s, sources, notes, stretch)
    walk = _bias_choice(fit, stride, rate_hz, sources, notes)
    if walk and mis.few_quiet:   # misfit in every window: the residual's Allan deviation is no drift figure either
        walk = False
        sources["bias"] = ("constant: the residual carries the rate-dependent misfit in every window, so its Allan "
                           "deviation's walk term is no drift figure")
    rs = resampling or Resampling((rate_hz, rate_hz))
    first = 0 if resampling is None else int(np.searchsorted(fit.taus, (resampling.white_from - 0.5) / rate_hz))
    steady = _steady_allan(win, w1, aw2, float(np.sum(A * A) / 3.0), rate_hz, first, window_s,
                           STRETCH_WINDOWS * w if stride > 1.0 else None)
    noise_std, noise_sd, dens_sq = _split(win, w1, w2, A, rate_hz, rs, fit, sources,
                                          resampling is not None, steady)
    if mis.few_quiet and steady is None:  # misfit in every window: even the quietest carry it; each stream's own high frequencies do not
        noise_std, noise_sd, dens_sq = _own_noise(w1, w2, valid, rs, sources, (noise_std, noise_sd, dens_sq))
    a = float(np.sum(A * A) / 3.0)
    noise_std, noise_sd, dens_sq = _within_residual(r, mis.use, a, fit,
                                                    (noise_std, noise_sd, dens_sq), sources, notes)
    q_each = fit.q_r / np.sqrt(1.0 + a)
    bias_walk = (float(q_each), float(q_each)) if walk else None

    kind = (NoiseKind.RATE_MISFIT if mis.flagged else NoiseKind.COLOURED if fit.coloured
            else NoiseKind.WHITE_WALK if walk else NoiseKind.WHITE)
    return NoiseModel(
        rate_hz=float(rate_hz), noise_std=noise_std, noise_std_uncertainty=(float(noise_sd[0]), float(noise_sd[1])),
        bias_walk_std=bias_walk, bias_model="random walk" if walk else "constant",
        residual_noise_std=fit.sigma_r, residual_noise_std_uncertainty=fit.sigma_r_sd,
        residual_walk_std=fit.q_r, residual_walk_std_uncertainty=fit.q_r_sd,
        bias_instability=fit.B, bias_instability_uncertainty=fit.B_sd,
        white_std_at_rest=float(np.sqrt(mis.v0)), misfit_gain=mis.gain, misfit_share=mis.share, noise_kind=kind,
        taus=fit.taus, adev=fit.adev, adev_fit=np.sqrt(np.maximum(fit.model.pred, 0.0)),
        fit_taus=fit.tau_fit, sources=sources, notes=tuple(notes),
        rates_hz=None if resampling is None else tuple(float(f) for f in rs.rates_hz),
        densities=None if resampling is None else tuple(float(np.sqrt(d)) for d in dens_sq),
        adev_worst=float(fit.model.worst), quantisation=float(np.sqrt(fit.coef[QUANTISATION])),
        filter_time_s=float(fit.model.tc if fit.coef[FILTERED] > 0 else 0.0),
        still_noise_std=None if steady is None or min(steady.level) <= 0 else tuple(
            float(np.sqrt(rs.variance[i] * rs.rates_hz[i] * steady.level[i] / rs.density[i])) for i in (0, 1)))


class _Misfit(NamedTuple):
    """The rate-dependent misfit test (:func:`_misfit_test`)."""

    v0: float             # white variance at zero rate (the regression's intercept)
    gain: tuple           # (a, b) of the misfit
    share: float          # share of the residual variance the rate explains
    flagged: bool         # a significant misfit: the noise comes from the quiet windows
    few_quiet: bool       # fewer than 16 quiet windows (the lowest-misfit sixteen taken)
    use: np.ndarray       # the samples the Allan fit uses (the valid ones, or those of the quiet windows)


def _misfit_test(win: _Windows, valid, rate_hz, sources: dict, notes: list) -> _Misfit:
    """Step 1 of :func:`_identify`: is the residual's variance growing with the rate (heteroscedastic
    regression, :func:`_misfit_fit`)? Adds ``sources["misfit"]`` and, when it is, a note."""
    n, w = valid.shape[0], win.length
    (v0, gain_a, gain_b), pred, drop = _misfit_fit(win)
    excess = pred - v0
    share = float(excess.mean() / pred.mean()) if pred.mean() > 0 else 0.0
    # significant: the chi-square drop (scaled by the fit's reduced chi-square), or, robust to heavy-tailed
    # windows, the fastest quarter of the windows with twice the median mean square of the slowest quarter
    order = np.argsort(win.rate_powers[:, 0])
    q = max(order.size // 4, 1)
    contrast = float(median(win.v_r[order[-q:]]) / max(median(win.v_r[order[:q]]), 1e-300))
    misfit = share > MISFIT_SHARE and (drop > 25.0 or contrast > 2.0)
    use = valid.copy()
    few_quiet = False
    if misfit:
        quiet = excess <= MISFIT_SHARE * v0
        few_quiet = quiet.sum() < 16
        if few_quiet:  # too few quiet windows: keep the lowest-misfit sixteen
            quiet = np.zeros_like(quiet)
            quiet[np.argsort(excess)[:16]] = True
        use = np.zeros(n, bool)
        use[:w * (n // w)].reshape(-1, w)[win.start[quiet] // w] = True
        use &= valid
        sources["misfit"] = (f"residual variance grows with the rate: {100 * share:.0f}% of it is explained by "
                             f"|omega| (a gain error {gain_a:+.3g} {gain_b:+.3g}/(rad/s) |omega|); the noise "
                             f"is from the {int(quiet.sum())} windows of {w / rate_hz:g} s where the misfit is below "
                             f"{100 * MISFIT_SHARE:g}% of the white variance")
        notes.append("the residual is NOT white noise: it is mostly rate-dependent model error (scale or cross-axis "
                     "error, timing, flex); its standard deviation is no sensor noise figure")
    else:
        sources["misfit"] = (f"no significant rate-dependent misfit ({100 * share:.1f}% of the residual variance "
                             "explained by the rate)")
    return _Misfit(v0, (gain_a, gain_b), share, misfit, few_quiet, use)


class _AllanFit(NamedTuple):
    """The residual's Allan deviation and its fit (:func:`_allan_fit`), with the residual's levels."""

    taus: np.ndarray
    adev: np.ndarray
    model: AllanFit       # the fit (coefficients N^2, B^2, K^2, Q^2, F^2, time constant, how well it fits)
    coef: np.ndarray      # model.coef
    sd: np.ndarray        # their standard uncertainties
    tau_fit: tuple
    coloured: bool
    idx: np.ndarray | None   # the samples fitted (None: all of them)
    span: int                # samples from the first to the last fitted one
    kept: int                # samples fitted
    Nsq: float               # white level the calibration sees (white_level), and its standard uncertainty
    Nsq_sd: float
    R_r: float               # white variance per sample of the residual, and its standard uncertainty
    R_sd: float
    sigma_r: float
    sigma_r_sd: float
    q2: float                # walk step variance per sample of the residual
    q_r: float
    q_r_sd: float
    B: float
    B_sd: float


def white_level(fit: AllanFit, window_s: float) -> tuple[float, float]:
    """The white level ``N^2`` (rad^2/s) a calibration over windows of ``window_s`` sees in a fitted Allan
    variance, and its standard uncertainty: ``tau AVAR(tau)`` at ``tau = window_s`` of the short-term terms, i.e.
    the white term, the filtered term's share ``F^2 g(window_s / T_c)`` (nearly all of it: the motion is slower
    than the filter) and the quantisation's white equivalent ``3 Q^2 / window_s`` (it averages out over the
    motion's time scale); the bias terms are left to the bias model."""
    g = fit.white_row(window_s)     # each short-term term's white equivalent at the window
    level = float(g @ fit.coef)
    var = float(g @ np.nan_to_num(fit.cov) @ g) if fit.coef.any() else 0.0
    return level, float(np.sqrt(max(var, 0.0)))


def _allan_fit(r, use, rate_hz, stride, resampling, misfit: bool, window_s: float, sources: dict,
               notes: list, stretch: int | None = None) -> _AllanFit:
    """Step 2 of :func:`_identify`: the Allan deviation of the residual ``r`` on the samples ``use`` (None: all)
    fitted with the terms of :func:`~fusion_gyrocal.core.allan.fit_allan` (white, bias instability, random walk,
    quantisation, filtered). Adds ``sources["noise"]`` and, for coloured noise, a note."""
    n = r.shape[0]
    starts = np.arange(0, n, stretch if stretch is not None else n)
    if use is None:
        idx, y, span = None, r, n
        kept = n
        lengths, covered = np.diff(np.append(starts, n)), n
    else:
        idx = np.flatnonzero(use)
        y = r[idx]
        span, kept = int(idx[-1] - idx[0] + 1), idx.size
        cut = np.searchsorted(idx, np.append(starts, n))                 # the kept samples of each stretch
        lengths = np.diff(cut)
        covered = sum(int(idx[b - 1] - idx[a] + 1) for a, b in zip(cut[:-1], cut[1:]) if b > a)
    taus, adev, sub_n, sub_m, scatter = allan_points(y, rate_hz, None if stretch is None else lengths)
    avar = (adev ** 2).mean(axis=1)
    edf = edf_table(sub_n, sub_m)
    # an interpolated stream is smoother than white noise over its first grid samples (Resampling.white_from)
    first = 0 if resampling is None else int(np.searchsorted(taus, (resampling.white_from - 0.5) / rate_hz))
    # a misfit's motion-band residue mimics filtered noise (a bump at the motion's time scale): no filtered term then
    model = fit_allan(taus, avar, edf, first, 0.0 if misfit else MAX_FILTER_S * window_s, scatter[:, 3], extra=True)
    c, cov, lo = model.coef, model.cov, model.first
    # joined samples: the walk per joined step covers the samples left out too (within a stretch: the stretches'
    # Allan sums are pooled, none across two of them, so the walk between stretches is not in the points)
    compress = kept / (span * stride) if stretch is None else kept / covered
    Bsq, Ksq = c[FLICKER_TERM], c[WALK]
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0)) if np.isfinite(cov).all() else np.full(c.size, np.nan)
    Nsq, Nsq_sd = white_level(model, window_s)
    R_r = Nsq * rate_hz
    R_sd = Nsq_sd * rate_hz
    sigma_r = float(np.sqrt(R_r))
    sigma_r_sd = float(R_sd / (2.0 * sigma_r)) if sigma_r > 0 else float("inf")
    q2 = Ksq / rate_hz * compress
    q2_sd = sd[WALK] / rate_hz * compress
    q_r = float(np.sqrt(q2))
    q_r_sd = float(q2_sd / (2.0 * q_r)) if q_r > 0 else 0.0
    B = float(np.sqrt(Bsq))
    B_sd = float(sd[FLICKER_TERM] / (2.0 * B)) if B > 0 else 0.0
    tau_fit = (float(taus[lo]), float(taus[-1]))
    coloured = lo > first or c[FILTERED] > 0    # beyond what interpolation onto the grid explains
    where = "samples kept" if misfit else "valid samples"
    kept_terms = [name for name, v in zip(TERMS, c) if v > 0]
    sources["noise"] = (f"white level of the residual's Allan fit ({' + '.join(kept_terms) or 'no term'}) at tau "
                        f"{tau_fit[0]:.3g}-{tau_fit[1]:.3g} s on {kept / rate_hz:.0f} s of {where}; the model is within "
                        f"{model.worst:.2f}x of the points"
                        + ("" if model.fits else f" (does NOT pass through them: more than {FIT_FACTOR:g}x off)"))
    if first > 0:
        sources["noise"] += (f" (from tau {taus[first]:.3g} s on: the interpolation onto the grid smooths the noise "
                             "over the first samples)")
    if c[QUANTISATION] > 0:
        notes.append(f"the residual has a slope -1 term (quantisation, or a rate differentiated from a noisy angle "
                     f"such as motion capture's): Q = {np.sqrt(c[QUANTISATION]):.3g} rad, per-sample std "
                     f"{np.sqrt(2.0 * c[QUANTISATION]) * rate_hz:.3g} rad/s that averages out over the motion; the "
                     f"white level counts only its share at tau = {window_s:g} s")
    if c[FILTERED] > 0:
        notes.append(f"the residual's noise is low-pass filtered (time constant {model.tc:.3g} s; its Allan deviation "
                     "flattens below it): consecutive samples are correlated, so the per-sample spread is below the "
                     "white level the motion sees (noise_std), and a residual chi2/dof below 1 is expected")
    if lo > first:
        notes.append(f"the residual is coloured below tau = {tau_fit[0]:.3g} s (its Allan deviation there fits none "
                     "of the terms): noise_std is the white level of the longer taus, where the motion is")
    return _AllanFit(taus, adev, model, c, sd, tau_fit, coloured, idx, span, kept, Nsq, Nsq_sd, R_r, R_sd, sigma_r,
                     sigma_r_sd, q2, q_r, q_r_sd, B, B_sd)


def _bias_choice(fit: _AllanFit, stride, rate_hz, sources: dict, notes: list) -> bool:
    """Step 3 of :func:`_identify`: a random-walk bias (True) when the fit's walk term is significant
    (:data:`WALK_Z`) and its Kalman filter settles within :data:`SETTLE_FRACTION` of the log, else constant.
    Adds ``sources["bias"]`` and, for a flicker floor, a note."""
    span = fit.span
    Ksq, Bsq = fit.coef[WALK], fit.coef[FLICKER_TERM]
    z = Ksq / fit.sd[WALK] if Ksq > 0 and fit.sd[WALK] > 0 else 0.0
    settle = np.sqrt(fit.R_r / fit.q2) if fit.q2 > 0 else np.inf  # samples: Kalman time constant of the walk
    walk = bool(z >= WALK_Z and settle <= SETTLE_FRACTION * span * stride)
    if walk:
        sources["bias"] = (f"random walk: the Allan fit's K term (slope +1/2) is {z:.1f} sigma, and the Kalman "
                           f"filter of the walk settles in {settle / rate_hz:.3g} s; split equally between the gyros "
                           "(only the sum is observable)")
    elif Ksq > 0 and z < WALK_Z:
        sources["bias"] = (f"constant: the Allan fit's walk term is only {z:.1f} sigma (a random walk needs "
                           f"{WALK_Z:g})")
    elif Ksq > 0:
        sources["bias"] = (f"constant: the walk ({z:.1f} sigma) is too slow to matter: its Kalman filter would take "
                           f"{settle / rate_hz:.3g} s to settle, against {span * stride / rate_hz:.0f} s of log")
    else:
        sources["bias"] = "constant: no random-walk term in the residual's Allan deviation"
    if Bsq > 0:
        notes.append(f"the residual has a bias-instability (flicker) floor B = {fit.B:.3g} rad/s, which neither bias "
                     "model describes exactly")
    return walk


def _split(win: _Windows, w1, w2, A, rate_hz, rs: Resampling, fit: _AllanFit, sources: dict, resampled: bool,
           steady: _SteadyNoise | None = None):
    """Step 4 of :func:`_identify`: the residual's white level split between the gyros by their own densities
    ``N_i``: on the grid (:class:`Resampling`) a stream's noise per sample is ``kv_i f_i N_i^2`` and its
    low-frequency density ``g_i N_i^2``, so the Allan fit's white level is ``Nsq = g_1 N_1^2 + a g_2 N_2^2``.
    The ratio comes from each gyro's own Allan fit on the steady stretches (:func:`_steady_allan`), else their
    variances there (:func:`_steady_split`), else each stream's third differences, else equal densities. Where the
    steady stretches give both levels and the residual's fit does not pass through its points, disagrees with
    their sum by more than 1.5x, or is a misfit, the steady levels themselves are used (a static test of each
    sensor, from the log). Adds ``sources["split"]`` (and says in ``sources["noise"]`` which was used); returns
    ``(noise_std, (sd_1, sd_2), densities^2)``."""
    Nsq, R_r, R_sd, idx, kept = fit.Nsq, fit.R_r, fit.R_sd, fit.idx, fit.kept
    a = float(np.sum(A * A) / 3.0)  # Var(A n_2) per axis = sigma_2^2 |A|_F^2 / 3
    kv, kd, fr, g = rs.variance, rs.diff3, rs.rates_hz, rs.density
    split = None if steady is not None and min(steady.level) > 0 else _steady_split(win, rate_hz)
    if steady is not None and min(steady.level) > 0:
        lv, lv_sd = steady.level, steady.level_sd
        rho2 = (lv[0] / g[0]) / (lv[1] / g[1])                  # N_1^2 / N_2^2, each sensor's own
        rho2_relvar = (lv_sd[0] / lv[0]) ** 2 + (lv_sd[1] / lv[1]) ** 2
        agree = Nsq / (lv[0] + a * lv[1])
        sources["split"] = (steady.text + f"; each gyro's own Allan deviation there: white {np.sqrt(lv[0] * rate_hz):.3g} / {np.sqrt(lv[1] * rate_hz):.3g} rad/s "
                            "per sample")
        still_fits = all(f.fits for f in steady.fits)
        direct = True   # a static test of each sensor: the residual's level (during motion) is the check
        if direct:
            Nsq = lv[0] * 1.0 + a * lv[1]
            R_r, R_sd = Nsq * rate_hz, float(np.hypot(lv_sd[0], a * lv_sd[1])) * rate_hz
            why = ("their fits pass through their points" if still_fits else "their fits are up to "
                   f"{max(f.worst for f in steady.fits):.2f}x off their points")
            sources["noise"] = (f"USED: each gyro's own white level on its still stretches ({why}; the residual's level "
                                f"is {np.sqrt(agree):.2f}x their sum in std); residual: " + sources["noise"])
        else:
            sources["noise"] += (f"; the steady stretches' levels agree with it ({np.sqrt(agree):.2f}x their sum in "
                                 "std) and split it")
    elif split is not None:
        ratio, rho2_relvar, text, _ = split
        grid2 = a * ratio                  # sigma_1^2 / sigma_2^2 per grid sample (e_2 carries |A|_F^2 / 3)
        sources["split"] = text
        rho2 = grid2 * (kv[1] * fr[1]) / (kv[0] * fr[0])
    else:
        head = slice(0, 200_000) if idx is None else idx[:200_000]  # plenty for a noise level
        d1, d2 = difference_noise_std(w1[head]), difference_noise_std(w2[head])
        if d1 > 0 and d2 > 0:
            grid2 = (kv[0] * d1 ** 2 / kd[0]) / (kv[1] * d2 ** 2 / kd[1])
            rho2_relvar = 2.0 * (2.0 * 1.3 ** 2 / min(kept, 200_000))  # MAD of third differences, both streams
            sources["split"] = (f"third differences of each stream (ratio {np.sqrt(grid2):.3g}; fast motion at a low "
                                "sample rate biases it)")
        else:
            grid2, rho2_relvar = kv[0] * fr[0] / (kv[1] * fr[1]), 0.0
            sources["split"] = "equal densities (no steady stretch, third differences unusable)"
        rho2 = grid2 * (kv[1] * fr[1]) / (kv[0] * fr[0])         # N_1^2 / N_2^2
    if resampled:
        sources["split"] += (f"; each stream's grid noise referred to its own rate ({fr[0]:.6g} / {fr[1]:.6g} Hz; "
                             f"interpolation keeps {kv[0]:.3g} / {kv[1]:.3g} of the variance)")
    n2_sq = Nsq / (g[0] * rho2 + a * g[1])
    dens_sq = (rho2 * n2_sq, n2_sq)
    s1_sq, s2_sq = (kv[i] * fr[i] * dens_sq[i] for i in (0, 1))   # per grid sample, what the solver weighs
    rel_R = (R_sd / R_r) ** 2 if R_r > 0 else np.inf
    f1, f2 = a * g[1] / (g[0] * rho2 + a * g[1]), g[0] * rho2 / (g[0] * rho2 + a * g[1])
    sd1 = np.sqrt(s1_sq) * 0.5 * np.sqrt(rel_R + f1 ** 2 * rho2_relvar)
    sd2 = np.sqrt(s2_sq) * 0.5 * np.sqrt(rel_R + f2 ** 2 * rho2_relvar)
    return (float(np.sqrt(s1_sq)), float(np.sqrt(s2_sq))), (sd1, sd2), dens_sq


def _within_residual(r, use, a: float, fit: _AllanFit, levels, sources: dict, notes: list):
    """The white noise never contradicts the residual: the per-sample variance it implies,
    ``sigma_1^2 + |A|_F^2 / 3 sigma_2^2``, may not exceed the residual's own mean square on the samples ``use``
    by more than :data:`CONTRADICT` (the residual holds the noise and more), unless the residual's fit has the
    filtered term (low-pass noise: correlated samples spread less than the white level the motion sees, said in
    a note). Beyond it both gyros' levels are scaled down to the residual's and ``sources["noise"]`` says so.
    Returns ``(noise_std, noise_sd, densities^2)``; ``r``, its caller's last use, is centred in place (no fresh
    pages for a copy)."""
    (s1, s2), sd, dens_sq = levels
    x = r if use is None or use.all() else r[use]
    if x.size:   # the mean square about the mean per axis (numpy reduces an (N, 3) array down its rows slowly)
        d = minus_row(x, (np.ones(x.shape[0]) @ x) / x.shape[0], out=x)
        ms = float(np.einsum("ij,ij->", d, d) / d.size)
    else:
        ms = 0.0
    implied = s1 * s1 + a * s2 * s2
    if not (ms > 0 and implied > CONTRADICT * ms) or fit.coef[FILTERED] > 0:
        return levels
    k = np.sqrt(ms / implied)
    sources["noise"] += (f"; CAPPED: that level implied {np.sqrt(implied / ms):.2f}x the residual's own per-sample "
                         f"spread (no filter to explain it): both gyros scaled by {k:.3g} to the residual's")
    notes.append(f"the noise level first identified ({np.sqrt(implied):.3g} rad/s per sample in the residual) exceeded "
                 f"the residual itself ({np.sqrt(ms):.3g}): it was scaled down to it")
    return (float(s1 * k), float(s2 * k)), (float(sd[0] * k), float(sd[1] * k)), (dens_sq[0] * k * k,
                                                                                dens_sq[1] * k * k)


def _own_noise(w1, w2, valid, rs: Resampling, sources: dict, split):
    """Each stream's white noise from its own third differences, for a residual that carries the misfit in every
    window (its Allan deviation is then no noise figure); ``split`` (:func:`_split`'s) when they are unusable.
    Replaces ``sources["noise"]`` when they are used."""
    kv, kd, fr = rs.variance, rs.diff3, rs.rates_hz
    head = np.flatnonzero(valid)[:200_000]
    d1, d2 = difference_noise_std(w1[head]), difference_noise_std(w2[head])
    if not (d1 > 0 and d2 > 0):
        return split
    rel = 1.3 / np.sqrt(head.size)   # MAD of third differences
    own = (d1 / np.sqrt(kd[0]), d2 / np.sqrt(kd[1]))      # each sensor's noise per own sample
    noise_std = (float(own[0] * np.sqrt(kv[0])), float(own[1] * np.sqrt(kv[1])))
    dens_sq = (own[0] ** 2 / fr[0], own[1] ** 2 / fr[1])
    sources["noise"] = ("third differences of each stream: the residual carries the rate-dependent misfit "
                        "in every window, so its Allan deviation is no noise figure")
    return noise_std, (noise_std[0] * rel, noise_std[1] * rel), dens_sq
