r"""Smooth paths that follow the visit polylines and pass every locale's disc (the last stage of
:func:`~pmht_opt.coverage.plan_coverage`).

Each platform flies its polyline (start, then its visit points in order) at constant speed over the
horizon: at step :math:`t` it should be at arc length :math:`t L_m / T`, and it reaches visit point
:math:`k` at step :math:`\tau_k = \mathrm{round}(s_k T / L_m)`. The path is the model's smoother run on
those positions as synthetic measurements, one per step, each with the scenario's penalty ``r``: the
M-step of section 4.4 of docs/model.md with unit weights, the same motion prior (``q``) every other
planner of the package uses, so the paths are exactly as smooth as the model makes any path that
follows these points. On top, every locale gets a hard constraint: within the coverage radius of its
platform's position at step :math:`\tau_n` (:class:`VisitDiscs`), which is what guarantees coverage.

A tour's paths are sparse pulls towards the locales in :func:`~pmht_opt.plan_smoothed`; here the
pull is dense and along straight legs, so the smoother rounds the polyline's corners (inwards, into
the discs the corners wrap) instead of swinging between sparse points, and the path length stays near
the polyline's.

The run is an :class:`~pmht_opt.em.EMRun` on a derived scenario whose "locales" are the synthetic
measurements, each with its time and platform fixed by its priors (so every E-step gives the same
weights and every iteration is the same M-step): user constraints that are linearised at the current
iterate (obstacles) are re-linearised at each iteration, and the run's constraint reports measure
everything on the returned paths.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from pmht_opt.constraints.base import Constraint, ConstraintContext, ConstraintReport
from pmht_opt.constraints.blocks import Block, disc_block
from pmht_opt.constraints.terminal import Terminal
from pmht_opt.em import EMRun
from pmht_opt.exceptions import ConfigError
from pmht_opt.model import POS, PX, PY, VEL
from pmht_opt.planner import PMHTConfig
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario


class VisitDiscs(Constraint):
    """Locale ``n`` within ``radius`` of platform ``platform[n]`` at step ``times[n]`` (fixed).

    Unlike :class:`~pmht_opt.constraints.VisitAll`, the platform and the step are given, and the
    centres need not be the run's locales: the coverage planner's run pulls towards synthetic
    measurements while the discs stay on the real locales.
    """

    needs = frozenset({"soc"})

    def __init__(self, platform: np.ndarray, times: np.ndarray, centres: np.ndarray, radius: float) -> None:
        super().__init__()
        self.platform = np.asarray(platform, dtype=int)
        self.times = np.asarray(times, dtype=int)
        self.centres = np.asarray(centres, dtype=float)
        self.radius = float(radius)

    @property
    def name(self) -> str:
        return f"VisitDiscs({self.radius:g})"

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        out = []
        for m in range(ctx.scenario.n_platforms):
            mine = np.flatnonzero(self.platform == m)
            if mine.size:
                out.append(
                    disc_block(
                        m,
                        ctx.scenario.horizon,
                        self.times[mine],
                        (PX, PY),
                        self.centres[mine],
                        np.full(mine.size, self.radius),
                        labels=[f"locale {n}" for n in mine.tolist()],
                    )
                )
        return out

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        report = super().violation(states, ctx)
        dist = np.hypot(*(states[self.platform, self.times][:, POS] - self.centres).T)
        report.details["visits_met"] = int(np.sum(dist <= self.radius * (1.0 + 1e-6)))
        return report


@dataclasses.dataclass
class Track:
    """The synthetic measurements and visit steps of one set of routes (see the module notes)."""

    points: np.ndarray  # (K, 2) measurement positions
    times: np.ndarray  # (K,) their steps, 1..T
    owner: np.ndarray  # (K,) their platforms
    visit_time: np.ndarray  # (N,) step at which each locale's disc is met
    platform: np.ndarray  # (N,) platform of each locale
    initial: np.ndarray  # (M, T+1, 6) the polylines at constant speed, as states


def _visit_steps(s: np.ndarray, length: float, T: int, apart: np.ndarray) -> np.ndarray:
    """Steps ``1..T`` at which arc lengths ``s`` (ascending) are reached at constant speed.

    Kept in order, and one step apart where ``apart[k]`` (visit point ``k`` differs from ``k - 1``):
    two discs that no one point meets cannot share a step. Raises ``ConfigError`` when the horizon has
    fewer steps than the route has distinct visit points.
    """
    t = np.clip(np.rint(s / length * T).astype(int), 1, T) if length > 0 else np.ones(s.shape, dtype=int)
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
    """Constant-speed polylines through each route's visit points ``points (N, 2)``.

    ``ends (M, 2)``, where not NaN, is a last vertex after the visits (a terminal position); the
    polylines are then flown in the first ``T - reserve`` steps and the last ``reserve`` steps hold
    the final point, so that a platform can come to rest.
    """
    T, N = scenario.horizon, scenario.n_locales
    T_fly = max(T - reserve, 1)
    initial = np.repeat(scenario.initial_states[:, None, :], T + 1, axis=1)
    visit_time = np.ones(N, dtype=int)
    platform = np.zeros(N, dtype=int)
    steps = np.arange(1, T + 1)
    pts, times, owner = [], [], []
    for m, route in enumerate(routes):
        end = None if ends is None or np.any(np.isnan(ends[m])) else ends[m]
        if len(route) == 0 and end is None:
            continue  # an idle platform: no pull, it stays at its start
        poly = np.vstack([scenario.start_positions[m], points[route], *([end] if end is not None else [])])
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(poly, axis=0).T))])
        length = float(s[-1])
        if len(route):
            apart = np.ones(len(route), dtype=bool)
            apart[1:] = np.hypot(*np.diff(points[route], axis=0).T) > 1e-9
            visit_time[route] = _visit_steps(s[1 : len(route) + 1], length, T_fly, apart)
            platform[route] = m
        arc = np.minimum(steps / T_fly, 1.0) * length
        xy = np.column_stack([np.interp(arc, s, poly[:, 0]), np.interp(arc, s, poly[:, 1])])
        pts.append(xy)
        times.append(steps)
        owner.append(np.full(T, m))
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
    discs = VisitDiscs(track.platform, track.visit_time, scenario.locales, radius)
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
    platform_prior_out = np.zeros((scenario.n_locales, M))
    platform_prior_out[np.arange(scenario.n_locales), track.platform] = 1.0
    extras: dict[str, Any] = {"visit_points": points, "routes": [np.asarray(r) for r in routes]}
    return dataclasses.replace(
        result,
        scenario=scenario,
        assignment=track.platform,
        visit_time=track.visit_time,
        platform_prior=platform_prior_out,
        estep=None,
        extras=extras,
    )
