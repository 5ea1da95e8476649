r"""How a straight-line tour is flown: the speed along each route and the smoothing rule.

Each platform flies its route's polyline (start, turn points, and home again when closed) in the
horizon with a :class:`SpeedProfile`: from rest, speeding up over the first steps, at constant
speed, and, where the mission ends at rest, slowing down to it; then retimed so that every turn falls
on a step of its own (:func:`visit_times`), which the samples then pass through. The smooth path
follows that motion through the model's smoother (:mod:`pmht_opt.planners.coverage.fly`).

The smoothing rule
------------------
The smoother of a constant-acceleration model with white jerk noise of intensity ``q``, measured
every ``dt`` with variance ``r``, passes motions slower than its time constant
:math:`\tau = (r\,dt/q)^{1/6}` and smooths out faster ones (its frequency response is
:math:`1 / (1 + (r\,dt/q)\,\omega^6)`). A platform moving at speed :math:`v` therefore rounds the
tour's corners over a length of about :math:`\ell = v\tau`: that length, not ``q`` or the horizon,
is what a user sees. The coverage planner fixes it in the units of the problem,

.. math::

    \ell = \kappa\,\lambda, \qquad \lambda = \operatorname{median}_n \rho_n,

a fraction :math:`\kappa` (``smoothing``) of the median coverage radius, so that a plan does not
depend on the horizon ``T`` the user picked nor on the units of the coordinates: scaling every
coordinate and radius by ``s`` scales the plan by ``s``, and another ``T`` samples the same motion
more or less densely. From :math:`\ell` it sets :math:`r = \lambda^2` (the measurements' scale) and,
per platform with speed :math:`v_m`, :math:`\tau_m = \ell / v_m`; the model's ``q`` is the one of the
slowest platform and the others' measurements weigh :math:`(\tau_{\max} / \tau_m)^6` more, which gives
each platform its own :math:`\tau_m` with one motion model. :math:`\tau_{\max}` is at most ten times
the shortest :math:`\tau_m` (:data:`MAX_TAU_RATIO`), which keeps the weights within :math:`10^6`: a
platform slower than that rounds its corners over less than :math:`\ell`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pmht_opt import validation
from pmht_opt.exceptions import ConfigError

#: The shortest time constant used, in steps: smoothing finer than the sampling has nothing to do.
MIN_TAU_STEPS = 0.5
#: The longest, in steps (a slow platform's): beyond it the smoother only lags further behind.
MAX_TAU_STEPS = 50.0
#: The longest time constant used, relative to the shortest of the moving platforms. The others'
#: measurements weigh ``(tau_max / tau_m)^6`` more: a platform with a route a hundred times shorter
#: than another's (C seed 7 at radius 0.1) put a weight of 1e12 beside 1, and Clarabel then met a disc
#: touched exactly at a turn only to 1.7e-4 of its radius. At most 10 keeps the weights within 1e6; a
#: slow platform then rounds its corners over less than the rule's length, closer to its tour.
MAX_TAU_RATIO = 10.0


@dataclasses.dataclass(frozen=True)
class SpeedProfile:
    """Arc length against time along a polyline of ``length``, flown in ``steps`` steps.

    The speed ramps up linearly from rest over the first ``ramp_in`` steps (platforms start at rest: a
    measurement already moving at full speed at ``t = 1`` would cost a jolt), is constant, and ramps
    down to rest over the last ``ramp_out`` steps (0: arrive at full speed).
    """

    length: float
    steps: int
    ramp_in: int
    ramp_out: int

    @property
    def speed(self) -> float:
        """The cruising speed, in length per step."""
        return self.length / max(self.steps - 0.5 * (self.ramp_in + self.ramp_out), 1e-12)

    def arc(self, t: np.ndarray) -> np.ndarray:
        """Arc length reached at (real) times ``t``."""
        v, a, b, n = self.speed, self.ramp_in, self.ramp_out, self.steps
        t = np.clip(np.asarray(t, dtype=float), 0.0, n)
        s = v * (t - 0.5 * a)
        if a > 0:
            s = np.where(t < a, v * t * t / (2 * a), s)
        if b > 0:
            s = np.where(t > n - b, self.length - v * (n - t) ** 2 / (2 * b), s)
        return np.minimum(s, self.length)

    def time(self, s: np.ndarray) -> np.ndarray:
        """Times at which arc lengths ``s`` are reached (the inverse of :meth:`arc`)."""
        v, a, b, n = self.speed, self.ramp_in, self.ramp_out, self.steps
        s = np.clip(np.asarray(s, dtype=float), 0.0, self.length)
        t = s / v + 0.5 * a
        if a > 0:
            t = np.where(s < 0.5 * v * a, np.sqrt(2 * a * s / v), t)
        if b > 0:
            t = np.where(
                s > self.length - 0.5 * v * b, n - np.sqrt(np.maximum(2 * b * (self.length - s) / v, 0)), t
            )
        return t


@dataclasses.dataclass(frozen=True)
class SmoothingModel:
    """The model the smoother flies the tours with (module notes): ``q``, ``r`` and each platform's
    measurement weight."""

    q: float
    r: float
    weights: np.ndarray


def smoothing_model(speeds: np.ndarray, dt: float, radii: np.ndarray, smoothing: float) -> SmoothingModel:
    """The smoothing rule of the module notes for platforms flying their routes at ``speeds`` (length
    per second; 0 for an idle platform, which takes weight 1 and holds its start)."""
    if not (smoothing > 0 and np.isfinite(smoothing)):
        raise ConfigError(f"smoothing: expected a positive number, got {smoothing!r}.")
    scale = float(np.median(radii))
    turn = smoothing * scale
    speed = np.asarray(speeds, dtype=float)
    moving = speed > 0
    tau = np.full(speed.shape, np.inf)
    tau[moving] = np.maximum(turn / speed[moving], MIN_TAU_STEPS * dt)
    slowest = float(np.max(tau[moving])) if np.any(moving) else MIN_TAU_STEPS * dt
    slowest = min(slowest, MAX_TAU_STEPS * dt)
    if np.any(moving):
        slowest = min(slowest, MAX_TAU_RATIO * float(np.min(tau[moving])))
    weights = np.ones(speed.shape)
    weights[moving] = (slowest / np.minimum(tau[moving], slowest)) ** 6
    # Only q / r = dt / tau^6 shapes the paths; r = scale^2 keeps the measurements at the problem's
    # size, moved (with q, their ratio kept) where q would leave the range the numerics handle.
    r = scale * scale
    q = r * dt / slowest**6
    lo, hi = validation.Q_RANGE
    if not lo <= q <= hi:
        q = min(max(q, lo), hi)
        r = q * slowest**6 / dt
    return SmoothingModel(q=q, r=r, weights=weights)


def visit_times(t_real: np.ndarray, T: int, apart: np.ndarray) -> np.ndarray:
    r"""Times in ``[1, T]`` for a route's turn points, as near as can be to the times ``t_real``
    (ascending) at which the flight reaches them, with distinct points a step or more apart.

    Each turn (an inner vertex of the route's polyline) takes a step of its own, so that the samples
    pass through every corner of the tour; where the turns crowd (a cluster of small discs, or many
    turns for few steps) the times the constant-speed flight gives them cannot all be kept. The times
    kept are the least squares fit under the spacing,

    .. math::

        \min_{\tau'} \sum_k (\tau'_k - \tau_k)^2 \quad \text{s.t.} \quad
        \tau'_k \ge \tau'_{k-1} + g_k, \quad 1 \le \tau'_k \le T,

    with :math:`g_k = 1` where point :math:`k` differs from point :math:`k - 1` (``apart``), else 0:
    with :math:`u_k = \tau_k - G_k` (:math:`G_k` the gaps summed) it is the isotonic regression of
    :math:`u`, solved exactly by pooling adjacent violators, then clipped to the bounds. Where the
    flight's times already leave a step between distinct points it returns them unchanged. The flight is
    then retimed to pass each turn at its step (:func:`retime`). The visit points between two turns lie
    on a straight leg, which one segment of the path covers at any fraction, so they need no step of
    their own: only the turns bound how short a horizon can be. Raises ``ConfigError`` when the horizon
    has fewer steps than the route has distinct turns.
    """
    t = np.asarray(t_real, dtype=float)
    if t.size == 0:
        return t.copy()
    gap = apart.astype(float)
    gap[0] = 0.0
    G = np.cumsum(gap)
    if G[-1] + 1 > T:
        raise ConfigError(
            f"horizon: {T} steps cannot hold a route with {int(G[-1]) + 1} distinct turns; "
            "lengthen the horizon."
        )
    u = _isotonic(t - G)
    u = np.clip(u, 1.0, T - G[-1])
    return u + G


def _isotonic(y: np.ndarray) -> np.ndarray:
    """The non-decreasing sequence nearest ``y`` in least squares (pool adjacent violators)."""
    means: list[float] = []
    sizes: list[int] = []
    for v in y.tolist():
        mean, size = v, 1
        while means and means[-1] > mean:
            m, n = means.pop(), sizes.pop()
            mean, size = (m * n + mean * size) / (n + size), n + size
        means.append(mean)
        sizes.append(size)
    return np.repeat(np.array(means), np.array(sizes))


def visit_steps(times: np.ndarray, T: int) -> np.ndarray:
    """The steps ``1..T`` of visit times from :func:`visit_times`: rounded half up, which keeps times a
    step apart on distinct steps."""
    return np.clip(np.floor(np.asarray(times) + 0.5).astype(int), 1, T)


def retime(
    t: np.ndarray, before: np.ndarray, after: np.ndarray, steps: int, inverse: bool = False
) -> np.ndarray:
    """The times of the original flight at which the retimed one is at times ``t``: the retiming is
    piecewise linear, through each turn's time ``before`` (ascending) and its new time ``after``,
    and keeps the start and the end. With ``inverse``, the other way: the retimed flight's times of
    the original flight's times ``t`` (where each visit between the turns is reached)."""
    knots_new = np.concatenate([[0.0], after, [float(steps)]])
    knots_old = np.concatenate([[0.0], before, [float(steps)]])
    x, y = (knots_old, knots_new) if inverse else (knots_new, knots_old)
    keep = np.concatenate([[True], np.diff(x) > 0])
    return np.interp(t, x[keep], y[keep])
