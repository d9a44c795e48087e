"""Step alarms of the tracker: alarm -> batch solve -> re-seed, or restore and replay.

A CUSUM alarm (:class:`~.steps.Cusum`) means a step change of the mounting is suspected. The tracker then
opens its covariance by the step prior (it follows the step at once and its bands say so) and
:class:`Reseeder` decides, once the window after the estimated onset is full (``reseed_window_s``) and excites
every direction (``reseed_min_spread``; a turn about one axis does not):

* re-seed: the batch solve over that window (:func:`~.seed.batch`, with its flex rejection) differs
  significantly from the filter's state at the alarm in the rotation or the scale factors (chi-square test
  on the difference, the batch covariance raised by the seed's model error, ``robust_inflation``);
* otherwise (a step of the combined bias alone, e.g. a gravity-dependent bias after a change of pose, or a
  false alarm such as a long flex burst) restore that state, open the bias part of the step prior when the
  bias stepped, and replay the buffered samples (:class:`~.steps.SampleRing`), so the filter absorbs a
  bias step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from ..core.observability import explained_scatter
from ..errors import GyroCalError
from ..lie import log
from .ekf import misfit_coefficients
from .history import ReseedEvent
from .seed import batch, log_covariance

REPLAY_BLOCK = 100      # samples per block when a false alarm's buffered samples are re-processed


@dataclass
class Alarm:
    """An open step alarm: when it rose, the estimated onset, and the filter's state to return to."""

    t_detected: float
    onset: float
    state: tuple             # ErrorStateEKF.state() at the alarm
    n_rejected: int
    next_try_t: float = -np.inf


def spread(w1, w2) -> float:
    """Smallest over largest eigenvalue of the scatter of gyro 1 that gyro 2 explains
    (:func:`~fusion_gyrocal.core.observability.explained_scatter`): 1 for motion about every axis alike,
    near 0 for a turn about one axis."""
    from ..core.moments import Moments

    ev = np.linalg.eigvalsh(explained_scatter(Moments.from_samples(w1, w2)))
    return float(max(ev[0], 0.0) / ev[-1]) if ev[-1] > 0 else 0.0


def observable_chi2(hold, R_1_2, scale_1, scale_2, bias, state, P, extrinsic: bool = False) -> float:
    """``e^T P^-1 e`` in the observable coordinates of ``hold`` (:class:`~.hold.ScaleHold`) for ``e`` the given
    values minus ``state`` ``(R, s1, s2, b)``: ``[Log(R_1_2 R^T), log scale - log s, bias - b]``, scales expressed
    in the gauge; ``extrinsic``: the rotation and scale coordinates only (the marginal test without the bias)."""
    R, s1, s2, b = state
    t1, t2 = hold.express(scale_1, scale_2)
    e = np.concatenate([log(np.asarray(R_1_2) @ R.T), np.log(t1 / s1), np.log(t2 / s2), np.asarray(bias) - b])
    V = hold.obs_basis
    if extrinsic:                   # the held directions lie in the scale block: drop the bias rows, re-orthonormalise
        dof = hold.nees_dof - 3     # observable coordinates of the rotation and the scale factors
        V = np.linalg.svd(V[:9], full_matrices=False)[0]
        V = np.vstack([V[:, :dof], np.zeros((3, dof))])
    eo = V.T @ e
    return float(eo @ np.linalg.solve(V.T @ P @ V, eo))


class Reseeder:
    """The open step alarm of a tracker and the re-seed events so far; its methods act on the tracker's
    :class:`~.stepper.Stepper` ``track`` (filter, buffered samples, counters)."""

    __slots__ = ("alarm", "events")

    def __init__(self, alarm: Alarm | None = None, events=()):
        self.alarm: Alarm | None = alarm
        self.events: list[ReseedEvent] = list(events)

    def raise_alarm(self, track, t_detected: float, onset: float) -> None:
        """Step suspected: remember the state, open the covariance by the step prior."""
        self.alarm = Alarm(t_detected, onset, track.filter.state(), track.n_rejected)
        track.filter.open_step()

    def maybe_reseed(self, track) -> None:
        """Once the window after the onset is full and excites every direction: batch solve, then re-seed
        (the rotation or the scale factors changed) or restore, absorb a bias step and replay."""
        a, cfg, f = self.alarm, track.config, track.filter
        if f.t - a.onset < cfg.reseed_window_s or f.t < a.next_try_t:
            return
        data = track.ring.since(a.onset)
        thr = float(chi2.ppf(cfg.reseed_probability, f.hold.nees_dof - 3))
        can_wait = f.t - a.onset < cfg.reseed_max_s and track.ring.oldest() <= a.onset
        s = spread(data[:, 1:4], data[:, 4:7])
        if s < cfg.reseed_min_spread:
            if can_wait:
                a.next_try_t = f.t + 0.5 * cfg.reseed_window_s  # wait for motion about the other axes
                return
            self.restore_and_replay(track)
            self.events.append(ReseedEvent(a.t_detected, a.onset, track.filter.t, False, np.nan, thr,
                                           f"the window after the onset never excited every direction (spread "
                                           f"{s:.3g} < {cfg.reseed_min_spread:g}); no step of the rotation or "
                                           "scale can be confirmed: restored, bias step absorbed, replayed"))
            self.close(track)
            return
        try:
            if cfg.reseed_solver is not None:
                cal = cfg.reseed_solver(data[:, 1:4], data[:, 4:7])
            else:
                cal = batch(data[:, 1:4], data[:, 4:7], track.noise_std, cfg.gauge,
                            misfit=misfit_coefficients(track.noise_std, f.A, track.misfit))
        except GyroCalError as exc:
            if can_wait:
                a.next_try_t = f.t + 0.5 * cfg.reseed_window_s  # wait for more motion
                return
            self.events.append(ReseedEvent(a.t_detected, a.onset, f.t, False, np.nan, thr,
                                           f"batch solve failed ({exc}); kept the filter with the step prior"))
            self.close(track)
            return
        R0, s10, s20, b0, P0, _ = a.state       # batch minus the filter at the alarm, rotation and scales
        P_batch = track.model_error * f.project(log_covariance(cal, cfg.scale_prior_std))
        stat = observable_chi2(f.hold, cal.R_1_2, cal.scale_1, cal.scale_2, cal.bias, (R0, s10, s20, b0),
                               P_batch + P0, extrinsic=True)
        accepted = stat > thr
        if accepted:
            track.seed(cal, f.t, span_s=float(data[-1, 0] - data[0, 0]))
            reason = ("step change of the rotation or scale factors confirmed by the batch solve over the window "
                      "after the onset; re-seeded")
        else:
            db = np.asarray(cal.bias) - b0                  # the bias: did it step?
            Pb = P_batch[9:, 9:] + P0[9:, 9:]
            bias_step = float(db @ np.linalg.solve(Pb, db)) > float(chi2.ppf(cfg.reseed_probability, 3))
            self.restore_and_replay(track, bias_step)
            reason = ("batch solve agrees with the filter before the alarm in rotation and scale factors; " +
                      ("its bias stepped: restored, bias step absorbed, replayed" if bias_step else
                       "a transient (e.g. flex): restored and replayed"))
        self.events.append(ReseedEvent(a.t_detected, a.onset, track.filter.t, bool(accepted), float(stat), thr,
                                       reason))
        self.close(track)

    def close(self, track) -> None:
        self.alarm = None
        track.cusum.reset(track.filter.t)

    def restore_and_replay(self, track, bias_step: bool = True) -> None:
        """No step of the rotation or scales: return to the state at the alarm, open its bias by the step
        prior's bias part when ``bias_step`` (a step of the combined bias, which the filter then follows)
        and re-process the buffered samples after its time."""
        a, f = self.alarm, track.filter
        t_now = f.t
        f.restore(a.state)
        if bias_step:
            f.open_step(bias_only=True)
        data = track.ring.since(f.t)
        data = data[data[:, 0] > f.t]            # every buffered sample the restored state has not seen
        self.alarm = None
        track.n_rejected = a.n_rejected
        track.gate.pending = 0
        track.replaying = True
        try:
            for lo in range(0, data.shape[0], REPLAY_BLOCK):
                blk = data[lo:lo + REPLAY_BLOCK]
                track.step(blk[:, 0], blk[:, 1:4], blk[:, 4:7], "fast")
        finally:
            track.replaying = False
        f.predict_to(max(t_now, f.t))
