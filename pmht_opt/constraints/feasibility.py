"""Cheap necessary conditions checked before any solve: constraints that cannot hold together.

An infeasible combination should be named in milliseconds, not discovered by an interior-point or
ADMM solver after many iterations. Each test below is a necessary condition for feasibility, computed
from geometry alone; failing one raises :class:`~pmht_opt.exceptions.InfeasibleError` naming the
constraints that conflict and by how much.

* **Travel budget.** With a speed limit ``v_m`` platform ``m``'s displacement per step is at most
  ``v_m dt``; with an acceleration limit ``a_m`` it is at most ``|v_0| dt + t a_m dt^2`` at step ``t``
  (the limit bounds the change of the displacement from one step to the next, and of the first one
  from the start's velocity), so over the horizon the platform travels at most
  ``sum_t min(v_m dt, |v_0| dt + t a_m dt^2)``. To
  visit every locale's disc (radius ``rho``, :class:`~pmht_opt.constraints.VisitAll`) the paths, taken
  together, form a forest that touches every disc and has one tree per start, so their total length
  is at least the weight of a minimum spanning forest on the locales and starts with edge lengths
  ``max(0, |z_i - z_j| - 2 rho)`` between locales and ``max(0, |z_i - s_m| - rho)`` to a start (the
  starts joined at no cost). If that exceeds the total budget, or a single locale lies beyond every
  platform's reach, the visits and the limit conflict.
* **Unreachable visits and ends.** A visit disc wholly inside a keep-out zone or wholly outside the
  area bounds; a terminal position (within its radius) inside a keep-out zone, outside the bounds,
  or further from its platform's start than the platform can travel; a terminal velocity above the
  speed limit or acceleration above the acceleration limit.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from pmht_opt.constraints.area import AreaBounds
from pmht_opt.constraints.base import Constraint
from pmht_opt.constraints.motion import AccelLimit, SpeedLimit
from pmht_opt.constraints.obstacles import _Obstacle
from pmht_opt.constraints.terminal import Terminal
from pmht_opt.constraints.visits import VisitAll
from pmht_opt.exceptions import InfeasibleError

if TYPE_CHECKING:
    from pmht_opt.scenario import Scenario

#: Relative margin before a necessary condition counts as failed (rounding of the geometry).
MARGIN = 1e-9


def _hard(constraints: Sequence[Constraint], kind: type[Constraint]) -> list[Any]:
    return [c for c in constraints if isinstance(c, kind) and not c.soft]


def _travel(scenario: Scenario, speed: list[SpeedLimit], accel: list[AccelLimit]) -> np.ndarray:
    """``(M,)`` the most each platform can travel over the horizon (module docstring; inf without a
    speed or acceleration limit)."""
    M, T, dt = scenario.n_platforms, scenario.horizon, scenario.dt
    step = np.full((M, T), np.inf)  # bound on |p_t - p_{t-1}|, t = 1..T
    for lim in speed:
        for m in lim.applies_to(scenario):
            np.minimum(step[m], lim.limit_for(m) * dt, out=step[m])
    v0 = np.hypot(scenario.initial_states[:, 1], scenario.initial_states[:, 4])
    t = np.arange(1, T + 1)
    for acc in accel:
        for m in acc.applies_to(scenario):
            np.minimum(step[m], v0[m] * dt + t * acc.limit_for(m) * dt**2, out=step[m])
    return step.sum(axis=1)


def covering_length(locales: np.ndarray, starts: np.ndarray, radius: float | np.ndarray) -> float:
    """A lower bound on the total length of paths from ``starts`` that pass within ``radius`` (one
    number, or one per locale) of every locale: the minimum spanning forest of the module docstring."""
    N = locales.shape[0]
    r = np.broadcast_to(np.asarray(radius, dtype=float), (N,))
    between = np.hypot(*(locales[:, None, :] - locales[None, :, :]).transpose(2, 0, 1))
    to_start = np.hypot(*(locales[:, None, :] - starts[None, :, :]).transpose(2, 0, 1)).min(axis=1)
    # Nodes 0..N-1 the locales, node N every start merged into one root.
    graph = np.zeros((N + 1, N + 1))
    graph[:N, :N] = np.maximum(between - (r[:, None] + r[None, :]), 0.0)
    graph[:N, N] = np.maximum(to_start - r, 0.0)
    graph[N, :N] = graph[:N, N]
    # Zero-length edges are absent in a sparse graph: give them a length far below any other.
    tiny = 1e-300
    graph = np.where(graph > 0, graph, tiny)
    np.fill_diagonal(graph, 0.0)
    from scipy.sparse.csgraph import minimum_spanning_tree  # only here: 50 ms of every import

    return float(minimum_spanning_tree(graph).sum())


def check_feasible(scenario: Scenario, constraints: Sequence[Constraint]) -> None:
    """Raise :class:`InfeasibleError` if the hard constraints fail a necessary condition (module
    docstring); return quietly otherwise (the problem may still be infeasible)."""
    limits = _hard(constraints, SpeedLimit) + _hard(constraints, AccelLimit)
    travel = _travel(scenario, _hard(constraints, SpeedLimit), _hard(constraints, AccelLimit))
    for visits in _hard(constraints, VisitAll):
        _check_visits(scenario, visits, constraints, limits, travel)
    for end in _hard(constraints, Terminal):
        _check_terminal(scenario, end, constraints, limits, travel)


def _check_visits(
    scenario: Scenario,
    visits: VisitAll,
    constraints: Sequence[Constraint],
    limits: list[Constraint],
    travel: np.ndarray,
) -> None:
    rho = np.broadcast_to(np.asarray(visits.radius_for(scenario), dtype=float), (scenario.n_locales,))
    z, s = scenario.locales, scenario.start_positions
    for ob in _hard(constraints, _Obstacle):
        depth = ob.penetration(z)
        inside = np.flatnonzero(depth >= rho * (1 + MARGIN))
        if inside.size:
            raise InfeasibleError(
                f"{visits.name} and {ob.name} conflict: the visit disc of locale {int(inside[0])} lies "
                f"inside the keep-out zone ({inside.size} locale(s) in all)."
            )
    for box in _hard(constraints, AreaBounds):
        xmin, xmax, ymin, ymax = box.box
        gap = np.hypot(
            np.maximum(np.maximum(xmin - z[:, 0], z[:, 0] - xmax), 0.0),
            np.maximum(np.maximum(ymin - z[:, 1], z[:, 1] - ymax), 0.0),
        )
        outside = np.flatnonzero(gap > rho * (1 + MARGIN))
        if outside.size:
            raise InfeasibleError(
                f"{visits.name} and {box.name} conflict: the visit disc of locale {int(outside[0])} lies "
                f"outside the area ({outside.size} locale(s) in all)."
            )
    if not limits:
        return
    limit_names = names = " and ".join(c.name for c in limits)
    reach = np.maximum(np.hypot(*(z[:, None, :] - s[None, :, :]).transpose(2, 0, 1)) - rho[:, None], 0.0)
    # A platform that must end at a terminal position also has to get there from the locale.
    for end in _hard(constraints, Terminal):
        targets = end.targets(scenario)
        if targets is None:
            continue
        for m in end.applies_to(scenario):
            e = targets[0 if targets.shape[0] == 1 else m]
            back = np.maximum(np.hypot(z[:, 0] - e[0], z[:, 1] - e[1]) - rho - end.radius, 0.0)
            reach[:, m] += back
        names += f" and {end.name}"
    beyond = np.all(reach > travel[None, :] * (1 + MARGIN), axis=1)
    if np.any(beyond):
        n = int(np.flatnonzero(beyond)[0])
        m = int(np.argmin(reach[n]))
        raise InfeasibleError(
            f"{visits.name} and {names} conflict: platform {m}, the nearest, cannot reach locale {n}: it "
            f"needs {float(reach[n, m]):.4g} of travel to reach its visit disc (and its end, if it has one), "
            "and the platform travels "
            f"at most {float(travel[m]):.4g} in the horizon ({int(np.sum(beyond))} locale(s) out of reach)."
        )
    need = covering_length(z, s, rho)
    budget = float(np.sum(travel))
    if need > budget * (1 + MARGIN):
        raise InfeasibleError(
            f"{visits.name} and {limit_names} conflict: visiting every locale needs at least {need:.4g} "
            f"units of travel, and {limit_names} allow {budget:.4g} over the horizon."
        )


def _check_terminal(
    scenario: Scenario,
    end: Terminal,
    constraints: Sequence[Constraint],
    limits: list[Constraint],
    travel: np.ndarray,
) -> None:
    targets = end.targets(scenario)
    if targets is not None:
        for m in end.applies_to(scenario):
            target = targets[0 if targets.shape[0] == 1 else m]
            _check_end_position(scenario, end, constraints, limits, travel, m, target)
    for values, kind in ((end.velocity, SpeedLimit), (end.acceleration, AccelLimit)):
        if values is None:
            continue
        for lim in _hard(constraints, kind):
            for m in set(end.applies_to(scenario)) & set(lim.applies_to(scenario)):
                wanted = float(np.hypot(*values[0 if values.shape[0] == 1 else m]))
                if wanted > lim.limit_for(m) * (1 + MARGIN):
                    raise InfeasibleError(
                        f"{end.name} and {lim.name} conflict: platform {m} must end at {wanted:.4g}, above "
                        "the limit."
                    )


def _check_end_position(
    scenario: Scenario,
    end: Terminal,
    constraints: Sequence[Constraint],
    limits: list[Constraint],
    travel: np.ndarray,
    m: int,
    target: np.ndarray,
) -> None:
    radius = end.radius
    distance = float(np.hypot(*(target - scenario.start_positions[m]))) - radius
    if limits and distance > travel[m] * (1 + MARGIN):
        names = " and ".join(c.name for c in limits)
        raise InfeasibleError(
            f"{end.name} and {names} conflict: platform {m} must end {distance:.4g} from its start, and "
            f"can travel at most {travel[m]:.4g}."
        )
    for ob in _hard(constraints, _Obstacle):
        if m in ob.applies_to(scenario) and ob.penetration(target[None, :])[0] > radius * (1 + MARGIN):
            raise InfeasibleError(f"{end.name} and {ob.name} conflict: platform {m} must end inside it.")
    for box in _hard(constraints, AreaBounds):
        xmin, xmax, ymin, ymax = box.box
        gap = float(
            np.hypot(
                max(xmin - target[0], target[0] - xmax, 0.0), max(ymin - target[1], target[1] - ymax, 0.0)
            )
        )
        if m in box.applies_to(scenario) and gap > radius * (1 + MARGIN):
            raise InfeasibleError(
                f"{end.name} and {box.name} conflict: platform {m} must end outside the area."
            )
