"""The bias model of a pair run: :class:`BiasModel` (constant, random walk or piecewise constant).

The model is chosen once per run (:meth:`BiasModel.of`) from what the user said (``bias_window``,
``bias_walk_std``) and from the identified noise model (a random-walk bias it found), and passed to whoever
builds moments on a set of samples: the solve of :func:`~fusion_gyrocal.pipeline.pipeline.run_pipeline` and
the flex gate (:func:`~fusion_gyrocal.pipeline.flex.gate`).

* constant: the moments of the samples (Eq. 12-17);
* random walk: the moments of the Kalman innovations (:func:`~fusion_gyrocal.core.moments.random_walk_bias_moments`),
  whose white noise is ``sqrt((P + R) / R)`` times the samples' (:meth:`BiasModel.solve_noise`);
* piecewise: the moments pooled over windows of ``window`` samples, each with its own bias.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from ..core.moments import Moments, random_walk_bias_moments, random_walk_gain, window_moments, window_stats


class BiasKind(str, Enum):
    """How the combined bias ``b_1 - A b_2`` is modelled."""

    CONSTANT = "constant"
    RANDOM_WALK = "random walk"
    PIECEWISE = "piecewise"


@dataclass(frozen=True)
class BiasModel:
    """The bias model of a run and its parameters.

    Attributes
    ----------
    kind : BiasKind
    walk_std : tuple of float or None
        Random-walk step std per sample of each gyro (rad/s), for ``RANDOM_WALK``.
    noise_std : tuple of float or None
        White-noise std per sample of each gyro (rad/s) the walk's Kalman filter weighs, for ``RANDOM_WALK``.
    window : int or None
        Samples per bias segment, for ``PIECEWISE``.
    """

    kind: BiasKind = BiasKind.CONSTANT
    walk_std: tuple | None = None
    noise_std: tuple | None = None
    window: int | None = None

    @classmethod
    def of(cls, options, noise_std=None, noise_model=None) -> "BiasModel":
        """The model of a run: the user's ``bias_walk_std`` (with ``noise_std``, the white noise the run uses) or
        ``bias_window``; else the random walk of the identified ``noise_model``
        (:class:`~fusion_gyrocal.core.noise.NoiseModel`) when it chose one; else constant."""
        walk = options.bias_walk_std
        if walk is None and noise_model is not None and options.bias_window is None:
            walk = noise_model.bias_walk_std
        if walk is not None:
            return cls(BiasKind.RANDOM_WALK, tuple(walk), tuple(noise_std))
        if options.bias_window is not None:
            return cls(BiasKind.PIECEWISE, window=int(options.bias_window))
        return cls()

    @property
    def gate_window(self) -> int | None:
        """Residual windows the flex gate removes the bias over: the walk filter's time constant (at least 20
        samples), the segments, or None (one bias for the log)."""
        if self.kind is BiasKind.RANDOM_WALK:
            gain, _ = random_walk_gain(self.walk_std, self.noise_std)
            return max(20, int(round(1.0 / gain)))
        return self.window

    def solve_noise(self, noise_std):
        """The white noise per sample the solve weighs the moments with: ``noise_std`` itself, or for the random
        walk that of the innovations, ``sqrt((P + R) / R)`` times it."""
        if self.kind is not BiasKind.RANDOM_WALK or noise_std is None:
            return noise_std
        _, noise_scale = random_walk_gain(self.walk_std, self.noise_std)
        return tuple(np.asarray(noise_std, float) * noise_scale)

    def moments(self, w1, w2, use, window: int | None = None, base: Moments | None = None, weights=None):
        """``(moments, windows)`` of the samples ``use`` (bool mask or None) under this model; ``windows`` their
        per-window statistics in windows of ``window`` samples (for the block-robust covariance; segments for the
        piecewise model), None without ``window``. ``base``: the constant model's moments of ``use`` when known.
        ``weights``: a weight per sample (constant bias only, :meth:`~fusion_gyrocal.core.moments.Moments.from_samples`)."""
        if weights is not None:
            if self.kind is not BiasKind.CONSTANT:
                from ..errors import OptionError
                raise OptionError(f"weights: expected a constant bias model for weighted moments, got {self.kind.value}")
            m = Moments.from_samples(w1, w2, mask=use, weights=weights)
            return m, (window_stats(w1, w2, window, mask=use, weights=weights) if window is not None else None)
        if self.kind is BiasKind.RANDOM_WALK:
            out = random_walk_bias_moments(w1, w2, self.walk_std, self.noise_std, mask=use, window=window)
            return out[0], (out[2] if window is not None else None)
        if self.kind is BiasKind.CONSTANT:
            m = base if base is not None else Moments.from_samples(w1, w2, mask=use)
            return m, (window_stats(w1, w2, window, mask=use) if window is not None else None)
        m = Moments.pool_all(window_moments(w1, w2, self.window, mask=use))
        return m, (window_stats(w1, w2, self.window, mask=use, pooled=True) if window is not None else None)
