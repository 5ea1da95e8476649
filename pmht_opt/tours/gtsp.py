r"""Routes through candidate points, one point per group: a generalised TSP solved by PyVRP.

Every disc that needs a vertex is a *group* of candidate points (points of the disc); a route must take
exactly one point of each group. PyVRP models this directly: each candidate is an optional client with
no prize, each group a required, mutually exclusive client group. A point that lies in several discs
is entered once per group (copies at distance zero), so one stop can serve several discs at no extra
cost, which is how the intersections of discs ("Steiner zones") enter the search.

Locations: the vehicles' starts ``0 .. M-1`` (a depot each, where vehicle ``m`` starts), one shared end
depot ``M`` when some route is open, then the candidates. Arc costs are the straight distances except
into the end depot, which costs nothing: an open route ends at its last point. A closed route ends at
its own start, so the leg home is an ordinary arc and is in the cost that orders the visits. No arc is
vehicle specific, so one distance matrix serves every vehicle.

Costs are integers: unit-box distances times :data:`COST_PER_UNIT`, so the relative rounding is about
``1e-8`` of the box per arc and the answer does not depend on the user's units. The search stops after
a number of iterations (or of iterations without improvement), never on wall time, so a seed fixes it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Integer cost of a unit-box distance.
COST_PER_UNIT = 10_000_000


@dataclass(frozen=True)
class Candidates:
    """Candidate points and the group (disc) each belongs to.

    Attributes
    ----------
    points
        ``(P, 2)`` candidate points (unit box).
    group
        ``(P,)`` index of the disc each candidate serves (several candidates may share a location).
    """

    points: np.ndarray
    group: np.ndarray


def _distance_matrix(pts: np.ndarray) -> np.ndarray:
    diff = pts[:, None, :] - pts[None, :, :]
    return np.rint(np.hypot(diff[..., 0], diff[..., 1]) * COST_PER_UNIT).astype(np.int64)


def solve_gtsp(
    starts: np.ndarray,
    closed: np.ndarray,
    cands: Candidates,
    groups: np.ndarray,
    warm: Sequence[Sequence[int]] | None,
    iterations: int,
    no_improvement: int,
    seed: int,
    max_distance: int | None = None,
) -> list[list[int]]:
    """Candidate indices visited by each route, in order.

    Parameters
    ----------
    starts
        ``(M, 2)`` starts (unit box).
    closed
        ``(M,)`` whether each route returns to its start.
    cands
        The candidates.
    groups
        The group (disc) indices that must each get one visit; every candidate's group is among them.
    warm
        Candidate indices of a feasible solution per route to start from, or None.
    iterations, no_improvement
        Stop after this many iterations, or this many without improvement.
    seed
        PyVRP's seed.
    max_distance
        Longest route in integer cost units (a hard limit, used for the makespan), or None.
    """
    import pyvrp
    from pyvrp.stop import MaxIterations, MultipleCriteria, NoImprovement

    M = starts.shape[0]
    P = cands.points.shape[0]
    any_open = bool((~closed).any())
    n_depots = M + 1 if any_open else M
    xy = np.vstack([starts, starts[:1]]) if any_open else starts
    pts = np.vstack([xy, cands.points])
    dist = _distance_matrix(pts)
    if any_open:
        dist[:, M] = 0
    np.fill_diagonal(dist, 0)
    duration = dist if max_distance is not None else np.zeros_like(dist)
    scale = 1.0 / max(float(np.abs(pts).max()), 1.0)
    locations = [pyvrp.Location(float(x * scale * 1e6), float(y * scale * 1e6)) for x, y in pts]
    depots = [pyvrp.Depot(i) for i in range(n_depots)]
    slot = {int(g): i for i, g in enumerate(groups)}
    clients = [
        pyvrp.Client(n_depots + p, required=False, group=slot[int(cands.group[p])]) for p in range(P)
    ]
    members: list[list[int]] = [[] for _ in groups]
    for p in range(P):
        members[slot[int(cands.group[p])]].append(p)
    client_groups = [pyvrp.ClientGroup(mem, required=True) for mem in members]
    limit: dict[str, Any] = {} if max_distance is None else {"max_duration": int(max_distance)}
    types = [
        pyvrp.VehicleType(1, start_depot=m, end_depot=m if closed[m] else M, **limit) for m in range(M)
    ]
    data = pyvrp.ProblemData(locations, clients, depots, types, [dist], [duration], groups=client_groups)
    init = None
    if warm is not None:
        init = pyvrp.Solution(
            data,
            [pyvrp.Route(data, [int(p) for p in r], m) for m, r in enumerate(warm) if len(r)],
        )
    stop = MultipleCriteria([MaxIterations(iterations), NoImprovement(no_improvement)])
    result = pyvrp.solve(data, stop=stop, seed=seed, collect_stats=False, initial_solution=init)
    best = result.best
    if init is not None and (not best.is_feasible() or best.distance() > init.distance()):
        best = init
    routes: list[list[int]] = [[] for _ in range(M)]
    for route in best.routes():
        routes[route.vehicle_type()] = [a.idx for a in route if a.is_client()]
    return routes
