"""What the user's constraints say about the routes a planner orders: which return to their start,
where they end, how fast each platform may fly them, and so how long each route may be."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from pmht_opt.constraints.base import Constraint
from pmht_opt.constraints.motion import SpeedLimit
from pmht_opt.constraints.terminal import Terminal
from pmht_opt.exceptions import SolverError
from pmht_opt.scenario import Scenario
from pmht_opt.tours import DiscProblem, DiscTours, TourSettings, plan_tours


def terminal_ends(scenario: Scenario, constraints: Sequence[Constraint]) -> tuple[np.ndarray, bool]:
    """Final positions ``(M, 2)`` the user's :class:`~pmht_opt.Terminal` constraints ask for (NaN:
    free), and whether any terminal condition asks the platforms to end at rest or in place."""
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
    return ends, found


def speed_limits(scenario: Scenario, constraints: Sequence[Constraint]) -> np.ndarray:
    """``(M,)`` each platform's hard speed limit (the smallest that binds it; ``inf`` without one)."""
    vmax = np.full(scenario.n_platforms, np.inf)
    for con in constraints:
        if isinstance(con, SpeedLimit) and not con.soft:
            for m in con.applies_to(scenario):
                vmax[m] = min(vmax[m], float(con.limit_for(m)))
    return vmax


def closed_routes(scenario: Scenario, constraints: Sequence[Constraint]) -> np.ndarray:
    """``(M,)`` whether each platform's route returns to its start (a terminal position there)."""
    ends, _ = terminal_ends(scenario, constraints)
    return np.all(np.isclose(ends, scenario.start_positions, rtol=0.0, atol=1e-9), axis=1)


#: The speed ramps up from rest over ``T // RAMP_FRACTION`` steps (and down before a terminal point).
RAMP_FRACTION = 20
#: Share of the speed limit a route is planned to be flown at: room for the smoother to round corners.
CRUISE_SHARE = 0.95


def ramp_steps(horizon: int, steps: int) -> int:
    """Steps over which a platform speeds up from rest (and slows down to it)."""
    return min(max(horizon // RAMP_FRACTION, 1), max(steps // 3, 0))


def route_budgets(scenario: Scenario, constraints: Sequence[Constraint]) -> np.ndarray:
    """``(M,)`` the longest route each platform can fly in the horizon: from rest, at
    :data:`CRUISE_SHARE` of its speed limit, to rest when it must end at rest (a tenth of the horizon
    kept for it); ``inf`` without a limit."""
    _, at_rest = terminal_ends(scenario, constraints)
    T = scenario.horizon
    reserve = max(1, T // 10) if at_rest else 0
    steps = max(T - reserve, 1)
    ramp = ramp_steps(T, steps)
    flying = steps - 0.5 * (ramp + (ramp if reserve else 0))
    return CRUISE_SHARE * speed_limits(scenario, constraints) * scenario.dt * flying


def tours_within_budgets(
    scenario: Scenario,
    constraints: Sequence[Constraint],
    problem: DiscProblem,
    search: TourSettings,
    **kwargs: Any,
) -> DiscTours:
    """The tour engine's routes with each platform's :func:`route_budgets` as its route's length cap.

    The caps hold whatever the objective: with ``"distance"`` the shortest routes in total that each
    platform can fly in the horizon, with ``"time"`` the earliest finish within them. ``kwargs`` go to
    :func:`~pmht_opt.tours.plan_tours` (callback, stop).

    Raises
    ------
    InfeasibleError
        If a locale is out of every platform's reach within its budget (a proof), with what to change.
    SolverError
        If the search found no routes within the budgets (``status="caps"``), with what to change.
    """
    budgets = route_budgets(scenario, constraints)
    capped = dataclasses.replace(problem, max_lengths=budgets)
    try:
        return plan_tours(capped, search, **kwargs)
    except SolverError as err:
        if err.status not in ("caps", "infeasible"):
            raise
        each = ", ".join(f"{b:.4g}" for b in budgets)
        advice = (
            f" The horizon of {scenario.horizon} steps of {scenario.dt:g} at each platform's speed limit "
            f"lets the platforms fly {each} (from rest, at {CRUISE_SHARE:g} of the limit): lengthen the "
            "horizon, raise the speed limit or add platforms."
        )
        raise type(err)(f"{err}{advice}", backend=err.backend, status=err.status) from err
