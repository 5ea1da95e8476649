"""Guaranteed visits: every locale passed within a radius by its MAP platform at its MAP time."""

from __future__ import annotations

from typing import Any

import numpy as np

from pmht_opt.constraints.base import (
    DEFAULT_SIDES,
    Block,
    Constraint,
    ConstraintContext,
    ConstraintReport,
    check_sides,
    disc_block,
    positive_number,
)
from pmht_opt.exceptions import ConfigError
from pmht_opt.model import POS, PX, PY


def choose_visits(ctx: ConstraintContext, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """``(platform (N,), time (N,))`` each locale must be visited at, from ``ctx.estep``.

    Each locale takes its MAP ``(platform, time)``. Two locales that share a platform and time but lie
    more than ``2 radius`` apart cannot both be met; the later of them (in order of decreasing MAP
    weight) moves to its most probable time on the same platform that is free of such a conflict.
    Times with zero weight (outside a sub-batch in :func:`~pmht_opt.smoothed.plan_smoothed`) are never
    chosen unless nothing else is left.
    """
    es = ctx.estep
    if es is None:
        raise ConfigError("VisitAll needs the E-step result; it can only be used inside the planner.")
    locales = ctx.scenario.locales
    w = es.weights_ntm()  # (N, T, M)
    platform, time = es.map_assignment()
    best = w[np.arange(w.shape[0]), time - 1, platform]
    taken: dict[tuple[int, int], list[int]] = {}
    reach = 2.0 * radius
    for n in np.argsort(-best, kind="stable").tolist():
        m = int(platform[n])

        def clash(t: int, n: int = n, m: int = m) -> bool:
            others = taken.get((m, t), [])
            return any(np.hypot(*(locales[n] - locales[k])) > reach for k in others)

        t = int(time[n])
        if clash(t):
            order = np.argsort(-w[n, :, m], kind="stable") + 1
            free = [int(s) for s in order if w[n, s - 1, m] > 0 and not clash(int(s))]
            if not free:
                free = [int(s) for s in order if not clash(int(s))]
            if free:
                t = free[0]
        time[n] = t
        taken.setdefault((m, t), []).append(n)
    return platform, time


class VisitAll(Constraint):
    """Every locale within ``radius`` of its MAP platform's position at its MAP time (hard by default).

    PMHT's coverage is soft: a locale pulls on the path with weight ``1 / r`` but may be left out.
    This constraint makes it a guarantee: each iteration's M-step requires ``||p_t^m - z_n|| <= radius``
    for the E-step's most probable ``(m, t)`` of every locale (re-chosen every iteration; conflicts
    resolved by :func:`choose_visits`). A cone per locale, or an inner polygon on OSQP.

    Parameters
    ----------
    radius
        Visit radius.
    warmup
        EM iterations run without the constraint first, so the MAP times come from paths that already
        pass near the locales (from the standing start every time is equally likely). The constraint is
        imposed from iteration ``min(warmup, max_iter - 1) + 1`` on, so the returned plan always has it.
    sides
        Sides of the inner polygon on OSQP.
    soft, weight, platforms
        See :class:`~pmht_opt.constraints.base.Constraint`; ``platforms`` is not used (the locale's MAP
        platform is constrained).
    """

    dynamic = True

    def __init__(
        self, radius: float = 0.1, warmup: int = 10, sides: int = DEFAULT_SIDES, **kwargs: Any
    ) -> None:
        super().__init__(**kwargs)
        self.radius = positive_number("VisitAll.radius", radius)
        if isinstance(warmup, bool) or not isinstance(warmup, (int, np.integer)) or warmup < 0:
            raise ConfigError(f"VisitAll.warmup: expected an integer >= 0, got {warmup!r}.")
        self.warmup = int(warmup)
        self.sides = check_sides("VisitAll", sides)

    @property
    def name(self) -> str:
        return f"VisitAll({self.radius:g})"

    def active(self, iteration: int, max_iter: int) -> bool:
        return iteration > min(self.warmup, max_iter - 1)

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        platform, time = choose_visits(ctx, self.radius)
        T = ctx.scenario.horizon
        out = []
        for m in range(ctx.scenario.n_platforms):
            mine = np.flatnonzero(platform == m)
            if mine.size == 0:
                continue
            out.append(
                disc_block(
                    m,
                    T,
                    time[mine],
                    (PX, PY),
                    ctx.scenario.locales[mine],
                    np.full(mine.size, self.radius),
                    ctx.conic,
                    self.sides,
                    labels=[f"locale {n}" for n in mine.tolist()],
                )
            )
        return out

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        report = super().violation(states, ctx)
        platform, time = choose_visits(ctx, self.radius)
        dist = np.hypot(*(states[platform, time][:, POS] - ctx.scenario.locales).T)
        report.details.update(
            {
                "visits_met": int(np.sum(dist <= self.radius + 1e-6)),
                "max_visit_distance": float(np.max(dist)) if dist.size else 0.0,
            }
        )
        return report
