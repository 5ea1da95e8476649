r"""Smooth paths that follow the visit polylines and pass every locale's disc (the last stage of
:func:`~pmht_opt.planners.coverage.plan_coverage`).

Each platform flies its polyline (start, then its visit points in order) over the horizon with a
:class:`SpeedProfile`: from rest, speeding up over the first steps, then at constant speed, so that
it is at arc length :math:`s(t)` at step :math:`t` and reaches visit point :math:`k` near step
:math:`\tau_k = s^{-1}(s_k)`. The path is the model's smoother run on the positions :math:`s(t)` as
synthetic measurements, one per step, each with the scenario's penalty ``r``: the M-step of
docs/model.md section 4.4 with unit weights and the same motion prior (``q``) as every other planner
of the package, so the paths are exactly as smooth as the model makes any path that tracks these
points. On top, every locale's disc is a hard constraint at one step near :math:`\tau_n`
(:class:`VisitDiscs`), which is what guarantees coverage.

:func:`~pmht_opt.plan_smoothed` pulls a tour's paths towards the locales only, sparsely, and the
smoother swings between them; here the pull is dense and along the straight legs, so the path stays
near the polyline and its length near the polyline's: the smoother rounds the corners (shorter), and
the discs hold it where rounding would leave them. The polylines touch the discs at a fraction of the
radius (``shrink`` in :func:`~pmht_opt.planners.coverage.plan_coverage`), which leaves the rounding room.

The run is an :class:`~pmht_opt.em.EMRun` on a derived scenario whose "locales" are the synthetic
measurements, each with its time and platform fixed by its priors, so every E-step gives the same
weights; the iterations differ only in the constraints: each moves every locale's visit step to where
the last iterate passes closest, and re-linearises the user's constraints that depend on the iterate
(obstacles). The run's constraint reports measure everything on the returned paths.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from pmht_opt.constraints.base import Constraint, ConstraintContext, ConstraintReport
from pmht_opt.constraints.blocks import Block, disc_block
from pmht_opt.constraints.terminal import Terminal
from pmht_opt.constraints.visits import can_share_step
from pmht_opt.em import EMRun
from pmht_opt.exceptions import ConfigError
from pmht_opt.model import POS, PX, PY, VEL
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.settings import PMHTConfig


class VisitDiscs(Constraint):
    """Locale ``n`` within ``radius`` of platform ``platform[n]`` at one step near ``times[n]``.

    Unlike :class:`~pmht_opt.constraints.VisitAll`, the platform is given and the centres need not be
    the run's locales: the coverage planner's run pulls towards synthetic measurements while the discs
    stay on the real locales. The step is re-chosen at every iteration: the step within ``window`` of
    ``times[n]`` at which the current iterate is closest to the locale. A path that met the discs at
    the last iteration's steps meets them at these too, so once one iteration is feasible every later
    one is. An iterate that does not meet them yet (the first) can be closest to two discs that no
    point meets at one step; that platform then keeps the given ``times`` for the iteration.
    """

    needs = frozenset({"soc"})
    dynamic = True

    def __init__(
        self, platform: np.ndarray, times: np.ndarray, centres: np.ndarray, radius: float, window: int = 0
    ) -> None:
        super().__init__()
        self.platform = np.asarray(platform, dtype=int)
        self.times = np.asarray(times, dtype=int)
        self.centres = np.asarray(centres, dtype=float)
        self.radius = float(radius)
        self.window = int(window)

    @property
    def name(self) -> str:
        return f"VisitDiscs({self.radius:g})"

    def visit_steps(self, ctx: ConstraintContext) -> np.ndarray:
        """``(N,)`` the step of each locale's disc in the M-step of ``ctx``."""
        T = ctx.scenario.horizon
        if self.window == 0:
            return self.times
        pos = ctx.states[:, :, POS]
        out = self.times.copy()
        for n, (m, t) in enumerate(zip(self.platform, self.times, strict=True)):
            lo, hi = max(1, t - self.window), min(T, t + self.window)
            out[n] = lo + int(np.argmin(np.hypot(*(pos[m, lo : hi + 1] - self.centres[n]).T)))
        for m in np.unique(self.platform):
            mine = np.flatnonzero(self.platform == m)
            if _clash(out[mine], self.centres[mine], self.radius):
                out[mine] = self.times[mine]
        return out

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        times, T = self.visit_steps(ctx), ctx.scenario.horizon
        out = []
        for m in range(ctx.scenario.n_platforms):
            mine = np.flatnonzero(self.platform == m)
            if mine.size:
                blk = disc_block(
                    m,
                    T,
                    times[mine],
                    (PX, PY),
                    self.centres[mine],
                    np.full(mine.size, self.radius),
                    labels=[f"locale {n}" for n in mine.tolist()],
                )
                nominal = self.times[mine]
                blk.span = np.column_stack(
                    [np.maximum(nominal - self.window, 1), np.minimum(nominal + self.window, T)]
                )
                out.append(blk)
        return out

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        report = super().violation(states, ctx)
        times = self.visit_steps(ctx)
        dist = np.hypot(*(states[self.platform, times][:, POS] - self.centres).T)
        report.details["visits_met"] = int(np.sum(dist <= self.radius * (1.0 + 1e-6)))
        return report


#: Synthetic measurements at most: beyond, one every few steps (their priors are a dense array).
MAX_MEASUREMENTS = 5000
#: A locale's disc may be met up to ``T // WINDOW_FRACTION`` steps from where its visit point is.
WINDOW_FRACTION = 25
#: The speed ramps up from rest over ``T // RAMP_FRACTION`` steps (and down before a terminal point).
RAMP_FRACTION = 20


@dataclasses.dataclass
class Track:
    """The synthetic measurements and visit steps of one set of routes (see the module notes)."""

    points: np.ndarray  # (K, 2) measurement positions
    times: np.ndarray  # (K,) their steps, 1..T
    owner: np.ndarray  # (K,) their platforms
    visit_time: np.ndarray  # (N,) step at which each locale's disc is met
    platform: np.ndarray  # (N,) platform of each locale
    initial: np.ndarray  # (M, T+1, 6) the polylines at constant speed, as states


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
        """The cruising speed."""
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


def _clash(steps: np.ndarray, centres: np.ndarray, radius: float) -> bool:
    """Whether two of one platform's discs share a step although no point meets both
    (:func:`~pmht_opt.constraints.visits.can_share_step`)."""
    same = steps[:, None] == steps[None, :]
    apart = np.hypot(*(centres[:, None, :] - centres[None, :, :]).transpose(2, 0, 1))
    return bool(np.any(same & ~can_share_step(apart, 2.0 * radius)))


def _visit_steps(t_real: np.ndarray, T: int, apart: np.ndarray) -> np.ndarray:
    """Steps ``1..T`` nearest to the times ``t_real`` (ascending) at which the visit points are reached.

    Kept in order, and one step apart where ``apart[k]`` (visit point ``k`` differs from ``k - 1``):
    two discs that no one point meets cannot share a step. Raises ``ConfigError`` when the horizon has
    fewer steps than the route has distinct visit points.
    """
    t = np.clip(np.rint(t_real).astype(int), 1, T)
    gap = apart.astype(int)
    gap[0] = 0
    for k in range(1, t.size):
        t[k] = max(t[k], t[k - 1] + gap[k])
    if t.size:
        t[-1] = min(t[-1], T)
    for k in range(t.size - 2, -1, -1):
        t[k] = min(t[k], t[k + 1] - gap[k + 1])
    if t.size and t[0] < 1:
        raise ConfigError(
            f"horizon: {T} steps cannot hold a route with {int(gap.sum()) + 1} distinct visits; "
            "lengthen the horizon."
        )
    return t


def make_track(
    scenario: Scenario,
    routes: Sequence[np.ndarray],
    points: np.ndarray,
    ends: np.ndarray | None = None,
    reserve: int = 0,
) -> Track:
    """Polylines through each route's visit points ``points (N, 2)``, flown with a
    :class:`SpeedProfile` (from rest, then at constant speed).

    ``ends (M, 2)``, where not NaN, is a last vertex after the visits (a terminal position); the
    polylines are then flown in the first ``T - reserve`` steps and the last ``reserve`` steps hold
    the final point, so that a platform can come to rest.
    """
    T, N = scenario.horizon, scenario.n_locales
    T_fly = max(T - reserve, 1)
    ramp = min(max(T // RAMP_FRACTION, 1), T_fly // 3)
    initial = np.repeat(scenario.initial_states[:, None, :], T + 1, axis=1)
    visit_time = np.ones(N, dtype=int)
    platform = np.zeros(N, dtype=int)
    steps = np.arange(1, T + 1)
    # The run's priors are dense (measurements x T): thin the measurements on very large problems.
    stride = -(-scenario.n_platforms * T // MAX_MEASUREMENTS)
    pts, times, owner = [], [], []
    for m, route in enumerate(routes):
        end = None if ends is None or np.any(np.isnan(ends[m])) else ends[m]
        if len(route) == 0 and end is None:
            continue  # an idle platform: no pull, it stays at its start
        poly = np.vstack([scenario.start_positions[m], points[route], *([end] if end is not None else [])])
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(poly, axis=0).T))])
        profile = SpeedProfile(float(s[-1]), T_fly, ramp, ramp if end is not None or reserve else 0)
        if len(route):
            apart = np.ones(len(route), dtype=bool)
            apart[1:] = np.hypot(*np.diff(points[route], axis=0).T) > 1e-9
            visit_time[route] = _visit_steps(profile.time(s[1 : len(route) + 1]), T_fly, apart)
            platform[route] = m
        arc = profile.arc(steps)
        xy = np.column_stack([np.interp(arc, s, poly[:, 0]), np.interp(arc, s, poly[:, 1])])
        pts.append(xy[stride - 1 :: stride])
        times.append(steps[stride - 1 :: stride])
        owner.append(np.full(times[-1].size, m))
        body = initial[m, 1:]
        body[:] = 0.0
        body[:, POS] = xy
        body[:, VEL] = np.gradient(np.vstack([poly[:1], xy]), scenario.dt, axis=0)[1:]
    if not pts:  # every platform idle: one harmless measurement at a start keeps the run well posed
        pts, times, owner = [scenario.start_positions[:1]], [np.array([1])], [np.array([0])]
    return Track(
        points=np.vstack(pts),
        times=np.concatenate(times),
        owner=np.concatenate(owner),
        visit_time=visit_time,
        platform=platform,
        initial=initial,
    )


def terminal_ends(scenario: Scenario, constraints: Sequence[Constraint]) -> tuple[np.ndarray | None, int]:
    """Final positions ``(M, 2)`` (NaN: free) the user's :class:`~pmht_opt.Terminal` constraints ask
    for, and the steps to hold at the end (a tenth of the horizon when there is a terminal
    condition, so a platform can slow down; 0 otherwise)."""
    ends = np.full((scenario.n_platforms, 2), np.nan)
    found = False
    for con in constraints:
        if not isinstance(con, Terminal):
            continue
        found = True
        targets = con.targets(scenario)
        if targets is not None:
            for m in con.applies_to(scenario):
                ends[m] = targets[0 if targets.shape[0] == 1 else m]
    if not found:
        return None, 0
    return ends, max(1, scenario.horizon // 10)


def track_routes(
    scenario: Scenario,
    routes: Sequence[np.ndarray],
    points: np.ndarray,
    radius: float,
    config: PMHTConfig,
    iterations: int,
) -> PlanResult:
    """Smooth paths along the routes' visit polylines, every locale within ``radius`` at its step.

    ``config`` supplies the backend, its settings, threads and the user's constraints; the priors are
    fixed by the track and annealing is off. Returns the run's plan on the *original* scenario, with
    ``assignment`` and ``visit_time`` the track's and no E-step summary (the run's E-step is about
    the synthetic measurements). Raises :class:`~pmht_opt.exceptions.InfeasibleError` when the discs
    cannot be met together with the user's constraints.
    """
    ends, reserve = terminal_ends(scenario, config.constraints)
    track = make_track(scenario, routes, points, ends, reserve)
    K, M, T = track.points.shape[0], scenario.n_platforms, scenario.horizon
    derived = scenario.replace(locales=track.points)
    time_prior = np.zeros((K, T))
    time_prior[np.arange(K), track.times - 1] = 1.0
    platform_prior = np.zeros((K, M))
    platform_prior[np.arange(K), track.owner] = 1.0
    discs = VisitDiscs(
        track.platform, track.visit_time, scenario.locales, radius, max(1, T // WINDOW_FRACTION)
    )
    run_cfg = dataclasses.replace(
        config,
        max_iter=iterations,
        tol=0.0,
        update_time_prior=False,
        update_platform_prior=False,
        anneal=None,
        snapshots=(),
        stop=(),
        constraints=(*config.constraints, discs),
    )
    with EMRun(
        derived, run_cfg, time_prior=time_prior, platform_prior=platform_prior, initial_paths=track.initial
    ) as run:
        result = run.run()
        ctx = run.last_context
    assert ctx is not None
    platform_prior_out = np.zeros((scenario.n_locales, M))
    platform_prior_out[np.arange(scenario.n_locales), track.platform] = 1.0
    extras: dict[str, Any] = {"visit_points": points, "routes": [np.asarray(r) for r in routes]}
    return dataclasses.replace(
        result,
        scenario=scenario,
        assignment=track.platform,
        visit_time=discs.visit_steps(ctx),
        platform_prior=platform_prior_out,
        estep=None,
        extras=extras,
    )
