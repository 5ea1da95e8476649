"""Guaranteed visits: every locale passed within a radius by its MAP platform at its MAP time."""

from __future__ import annotations

from typing import Any

import numpy as np

from pmht_opt.constraints.area import StayNear
from pmht_opt.constraints.base import Constraint, ConstraintContext, ConstraintReport
from pmht_opt.constraints.blocks import DEFAULT_SIDES, Block, disc_block
from pmht_opt.constraints.params import check_sides, positive_number
from pmht_opt.exceptions import ConfigError
from pmht_opt.model import POS, PX, PY
from pmht_opt.scenario import Scenario, describe_radius

#: Share of the visit radius two visits at one step may use between them (:func:`choose_visits`): 1e-3
#: inside it, a hundred times the inward back-off of the M-step's hard rows.
SHARED_RADIUS = 0.999


def can_share_step(apart: np.ndarray, reach: np.ndarray | float) -> np.ndarray:
    """Whether two discs whose centres are ``apart`` and whose radii add up to ``reach`` may be visited
    at one step: a point must meet both with room to spare (:data:`SHARED_RADIUS`)."""
    return np.asarray(apart) < SHARED_RADIUS * np.asarray(reach)


def choose_visits(ctx: ConstraintContext, radius: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(platform (N,), time (N,))`` each locale must be visited at, from ``ctx.estep``.

    Each locale takes its MAP ``(platform, time)``, in order of decreasing MAP weight, unless that time
    clashes with a locale already placed on the same platform, with its start (at ``t = 0``) or with
    the end its path is pinned to (at ``t = T``, ``ctx.ends``: a platform that must be home at the end
    cannot be far away just before): two visits clash when the platform
    would have to cover the distance between the two discs faster than twice the current path's mean
    speed (two locales further apart than their radii add up to, at the same step, always clash).
    ``radius`` is one number or one per locale. Two locales share a step only if they lie within
    ``SHARED_RADIUS`` of their radii's sum (:data:`SHARED_RADIUS`): discs that barely
    touch leave a single point at which both visits hold (two locales of a unit grid at a visit radius
    of 0.5), which the 1e-5 inward back-off of hard rows (:data:`pmht_opt.mstep.rows.BACKOFF`) makes
    infeasible. A clashing locale
    takes its most probable time that clashes with nothing (the nearest such time among equally probable
    ones), so times with zero weight (outside a sub-batch in
    :func:`~pmht_opt.planners.smoothed.plan_smoothed`) are chosen only if nothing else is left.
    """
    es = ctx.estep
    if es is None:
        raise ConfigError("VisitAll needs the E-step result; it can only be used inside the planner.")
    locales = ctx.scenario.locales
    starts = ctx.scenario.start_positions
    platform, time = es.map_assignment()
    best = es.max_weight()  # the weight at each locale's MAP (platform, time)
    steps = np.diff(ctx.states[:, :, POS], axis=1)
    speed = np.median(np.hypot(steps[..., 0], steps[..., 1]), axis=1)  # (M,) typical step length
    # Where the hard constraints pin each path's end (NaN: free, no end gap).
    ends = np.full((starts.shape[0], 3), np.nan) if ctx.ends is None else ctx.ends
    T = ctx.states.shape[1] - 1
    N, M = locales.shape[0], starts.shape[0]
    radii = np.broadcast_to(np.asarray(radius, dtype=float), (N,))
    # The visits placed so far on each platform: their locales' coordinates, radii and times, in order.
    placed_xy = np.empty((M, N, 2))
    placed_r = np.empty((M, N))
    placed_t = np.empty((M, N))
    count = np.zeros(M, dtype=int)
    for n in np.argsort(-best, kind="stable").tolist():
        m, t = int(platform[n]), int(time[n])
        k = int(count[m])
        # The start (t = 0) counts as a placed visit, for speed only: a locale 1 unit from the start
        # cannot be met at t = 1.
        start_gap = max(float(np.hypot(*(starts[m] - locales[n]))) - radii[n], 0.0)
        end_gap = max(float(np.hypot(*(ends[m, :2] - locales[n]))) - radii[n] - ends[m, 2], 0.0)
        end_gap = 0.0 if np.isnan(end_gap) else end_gap
        vref = 2.0 * max(float(speed[m]), 1e-9)
        apart = np.hypot(placed_xy[m, :k, 0] - locales[n, 0], placed_xy[m, :k, 1] - locales[n, 1])
        reach = placed_r[m, :k] + radii[n]
        gap = np.maximum(apart - reach, 0.0)
        # At one step, discs that barely touch clash too (docstring).
        at_once = ~can_share_step(apart, reach)
        pinned = t * vref < start_gap or (T - t) * vref < end_gap
        if pinned or _clash_at(t, placed_t[m, :k], gap, at_once, vref):
            # Most probable first; among equally probable (e.g. underflowed) times, the nearest.
            wn = es.locale_weights(n)[:, m]  # (T,)
            cand = np.arange(1, wn.shape[0] + 1)
            order = cand[np.lexsort((np.abs(cand - t), -wn))]
            tried = order.astype(float)
            placed = placed_t[m, :k]
            pick = np.flatnonzero(~_clashes(tried, placed, gap, at_once, start_gap, vref, (T, end_gap)))
            if pick.size == 0:  # no time the platform can reach comfortably: at least never two at once,
                # and not at the end when the path ends away from the locale (a terminal position)
                free = ~_clashes(tried, placed, gap, at_once, start_gap, None)
                pick = np.flatnonzero(free & ~((tried >= T) & (end_gap > 0)))
                if pick.size == 0:
                    pick = np.flatnonzero(free)
            if pick.size:
                t = int(order[pick[0]])
        time[n] = t
        placed_xy[m, k], placed_r[m, k], placed_t[m, k] = locales[n], radii[n], t
        count[m] = k + 1
    return platform, time


def _clash_at(t: int, others: np.ndarray, gap: np.ndarray, at_once: np.ndarray, vref: float) -> bool:
    """:func:`_clashes` of the one time ``t`` with the placed visits (the start apart), on
    one-dimensional arrays: the check every locale's most probable time gets."""
    if others.size == 0:
        return False
    dt = np.abs(t - others)
    return bool((((dt == 0) & ((gap > 0) | at_once)) | (dt * vref < gap)).any())


def _clashes(
    t: np.ndarray,
    others: np.ndarray,
    gap: np.ndarray,
    at_once: np.ndarray,
    start_gap: float,
    vref: float | None,
    end: tuple[int, float] = (0, 0.0),
) -> np.ndarray:
    """Whether a visit at each of the times ``t`` clashes with the platform's visits placed at times
    ``others`` (their discs ``gap`` apart, beyond reach at one step where ``at_once``), with its start
    (``start_gap`` away, at ``t = 0``) or with its end (``end = (T, end_gap)``): at one step with a
    disc it cannot meet at once, or, with a reference speed ``vref``, farther than ``vref`` covers in
    the steps between (``None``: the speed is not checked, nor the start and end)."""
    dt = np.abs(t[:, None] - others[None, :])
    same = (dt == 0) & ((gap > 0) | at_once)
    if vref is None:
        return np.any(same, axis=1)
    same |= dt * vref < gap
    horizon, end_gap = end
    return np.any(same, axis=1) | (np.abs(t) * vref < start_gap) | ((horizon - t) * vref < end_gap)


def _visit_radius(name: str, radius: Any) -> float | np.ndarray | None:
    """A visit radius: ``None``, a positive number, or an array of them (one per locale)."""
    if radius is None:
        return None
    if np.ndim(radius) == 0:
        return positive_number(name, radius)
    arr = np.asarray(radius, dtype=float) if not isinstance(radius, np.ndarray) else radius.astype(float)
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ConfigError(f"{name}: expected a positive number or one per locale, got {radius!r}.")
    return arr


class VisitAll(Constraint):
    """Every locale within ``radius`` of its MAP platform's position at its MAP time (hard by default).

    PMHT's coverage is soft: a locale pulls on the path with weight ``1 / r`` but may be left out.
    This constraint makes it a guarantee: each iteration's M-step requires ``||p_t^m - z_n|| <= radius``
    for the E-step's most probable ``(m, t)`` of every locale (re-chosen every iteration; conflicts
    resolved by :func:`choose_visits`). A cone per locale (an inner polygon on a backend without
    cones).

    The visits are brought in over ``ramp`` iterations: while the schedule's strength ``s`` is below
    1, locale ``n``'s disc is ``radius + (1 - s) (d_n - radius)`` with ``d_n`` its distance from the
    current path at the visit time, so each iteration closes a share of every gap instead of demanding
    the whole manoeuvre at once (which, from paths far from some locales, can ask for process noise
    orders of magnitude above the rest of the plan, leave the area, and defeat first-order solvers).

    Parameters
    ----------
    radius
        Visit radius: one number, one per locale (an ``(N,)`` array), or ``None`` (default) for the
        scenario's :attr:`~pmht_opt.Scenario.coverage_radius`, its sensor footprint.
    warmup
        EM iterations run without the constraint first, so the MAP times come from paths that already
        pass near the locales (from the standing start every time is equally likely). They are counted
        from the end of an annealing schedule (the wide early penalties blur the MAP times); the
        planner's schedule (:class:`~pmht_opt.schedule.Schedule`) starts it early enough to be at full
        strength on the last iteration, so the returned plan has it.
    ramp
        Iterations over which the visit discs shrink to ``radius`` (above); 0 imposes them whole.
    keep_within
        The planner adds ``StayNear(keep_within)`` (:class:`~pmht_opt.constraints.StayNear`): the
        paths stay within this distance of the scenario's area, beyond what their starts need. Visits
        imposed at fixed times on a smooth path can otherwise be met by a loop far outside the area,
        which no user wants flown (Table 1 scenarios: up to 4 units out). ``None`` lets them roam.
    sides
        Sides of the inner polygon on a backend without cones.
    soft, weight, platforms
        See :class:`~pmht_opt.constraints.base.Constraint`; ``platforms`` is not used (the locale's MAP
        platform is constrained).
    """

    dynamic = True
    needs = frozenset({"soc"})

    def __init__(
        self,
        radius: float | np.ndarray | None = None,
        warmup: int = 10,
        sides: int = DEFAULT_SIDES,
        ramp: int = 4,
        keep_within: float | None = 0.5,
        **kwargs: Any,
    ) -> None:
        super().__init__(**kwargs)
        self.radius = _visit_radius(f"{type(self).__name__}.radius", radius)
        if isinstance(warmup, bool) or not isinstance(warmup, (int, np.integer)) or warmup < 0:
            raise ConfigError(f"VisitAll.warmup: expected an integer >= 0, got {warmup!r}.")
        self.warmup: int | None = int(warmup)
        if isinstance(ramp, bool) or not isinstance(ramp, (int, np.integer)) or ramp < 0:
            raise ConfigError(f"VisitAll.ramp: expected an integer >= 0, got {ramp!r}.")
        self.ramp = int(ramp)
        self.sides = check_sides("VisitAll", sides)
        self.keep_within = (
            None if keep_within is None else positive_number("VisitAll.keep_within", keep_within)
        )

    @property
    def name(self) -> str:
        label = "" if self.radius is None else describe_radius(self.radius)
        return f"{type(self).__name__}({label})"

    def scale(self, scenario: Scenario) -> float:
        """The smallest visit radius: violations are judged relative to it."""
        return float(np.min(self.radius_for(scenario)))

    def radius_for(self, scenario: Scenario) -> float | np.ndarray:
        """The visit radius on ``scenario``: the given one, or the scenario's coverage radius (one
        number, or one per locale)."""
        return scenario.coverage_radius if self.radius is None else self.radius

    def check_scenario(self, scenario: Scenario) -> None:
        super().check_scenario(scenario)
        if isinstance(self.radius, np.ndarray) and self.radius.shape != (scenario.n_locales,):
            raise ConfigError(
                f"{type(self).__name__}.radius: expected one radius per locale ({scenario.n_locales},), "
                f"got shape {self.radius.shape}."
            )

    def visits(self, ctx: ConstraintContext) -> tuple[np.ndarray, np.ndarray]:
        """``(platform (N,), time (N,))`` of the visit each locale must make in this iteration."""
        return choose_visits(ctx, self.radius_for(ctx.scenario))

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        return self.visit_blocks(ctx)

    def implied(self) -> list[Constraint]:
        """:class:`~pmht_opt.constraints.area.StayNear` of ``keep_within`` (parameters)."""
        return [] if self.keep_within is None else [StayNear(self.keep_within)]

    def visit_blocks(self, ctx: ConstraintContext) -> list[Block]:
        """The visit discs of this iteration, one block per platform."""
        platform, time = self.visits(ctx)
        rho = self.radius_for(ctx.scenario)
        gap = np.hypot(*(ctx.states[platform, time][:, POS] - ctx.scenario.locales).T) - rho
        radii = rho + (1.0 - ctx.strength) * np.maximum(gap, 0.0)
        out = []
        for m in range(ctx.scenario.n_platforms):
            mine = np.flatnonzero(platform == m)
            if mine.size:
                out.append(
                    disc_block(
                        m,
                        ctx.scenario.horizon,
                        time[mine],
                        (PX, PY),
                        ctx.scenario.locales[mine],
                        radii[mine],
                        self.sides,
                        labels=[f"locale {n}" for n in mine.tolist()],
                    )
                )
        return out

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        report = super().violation(states, ctx)
        platform, time = self.visits(ctx)
        dist = np.hypot(*(states[platform, time][:, POS] - ctx.scenario.locales).T)
        report.details.update(
            {
                "visits_met": int(np.sum(dist <= self.radius_for(ctx.scenario) + 1e-6)),
                "max_visit_distance": float(np.max(dist)) if dist.size else 0.0,
            }
        )
        return report
