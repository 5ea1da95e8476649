r"""The first visiting order: routes through the disc centres from PyVRP's iterated local search.

The discs are first treated as their centres, and the multiple TSP through them is solved by PyVRP:
one vehicle type per vehicle, starting at its own start; a closed route ends there too, an open one at
a shared end depot that every point reaches at no cost (so it ends at its last point). No arc depends
on the vehicle, so one distance matrix serves all. The leg home of a closed route is an ordinary arc,
so it is in the cost that orders the visits. An empty route is allowed.

Costs are integers: unit-box distances times :data:`COST_PER_UNIT` (a relative rounding of about
``1e-8`` of the box per arc, and no dependence on the user's units). ``max_length``, when given, caps
every route's length (PyVRP's maximum route distance): the makespan
objective bisects on it. ``caps`` cap each vehicle's route (the problem's route length caps): one
vehicle type per vehicle carries its own maximum distance, the smaller of the two when both are
given. A route through the centres is never shorter than the best one through the discs in the same
order, so a route within its cap here stays within it after the cone program (up to the rounding of
the costs; the search checks every change anyway). The search stops after a number of
iterations, never on wall time, so a seed fixes the answer.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

#: Integer cost of a unit-box distance.
COST_PER_UNIT = 10_000_000


def order_points(
    starts: np.ndarray,
    closed: np.ndarray,
    points: np.ndarray,
    iterations: int,
    seed: int,
    max_length: float | None = None,
    caps: np.ndarray | None = None,
    keep: bool = False,
) -> list[list[int]] | None:
    """Indices of ``points`` visited by each route, in order (None when a length limit is not met).

    Parameters
    ----------
    starts
        ``(M, 2)`` starts (unit box).
    closed
        ``(M,)`` whether each route returns to its start.
    points
        ``(N, 2)`` points to visit, each once (unit box).
    iterations
        PyVRP iterations (also the limit without improvement).
    seed
        PyVRP's seed.
    max_length
        Longest route allowed (unit box), or None.
    caps
        ``(M,)`` longest route allowed per vehicle (unit box, ``inf`` for none), or None.
    keep
        Return PyVRP's best routes even when they break a limit (its search prices the excess with
        a penalty, so they are near the limits), instead of None.
    """
    import pyvrp
    from pyvrp.stop import MaxIterations

    M, N = starts.shape[0], points.shape[0]
    if N == 0:
        return [[] for _ in range(M)]
    any_open = bool((~closed).any())
    n_depots = M + 1 if any_open else M
    xy = np.vstack([starts, starts[:1]]) if any_open else starts
    pts = np.vstack([xy, points])
    diff = pts[:, None, :] - pts[None, :, :]
    dist = np.rint(np.hypot(diff[..., 0], diff[..., 1]) * COST_PER_UNIT).astype(np.int64)
    if any_open:
        dist[:, M] = 0
    np.fill_diagonal(dist, 0)
    limit = np.full(M, np.inf if max_length is None else float(max_length))
    if caps is not None:
        limit = np.minimum(limit, caps)
    limits: list[dict[str, Any]] = [
        {"max_distance": int(np.floor(v * COST_PER_UNIT))} if np.isfinite(v) else {} for v in limit
    ]
    locations = [pyvrp.Location(float(x), float(y)) for x, y in pts]
    depots = [pyvrp.Depot(i) for i in range(n_depots)]
    clients = [pyvrp.Client(n_depots + p) for p in range(N)]
    types = [
        pyvrp.VehicleType(1, start_depot=m, end_depot=m if closed[m] else M, **limits[m]) for m in range(M)
    ]
    data = pyvrp.ProblemData(locations, clients, depots, types, [dist], [np.zeros_like(dist)])
    with warnings.catch_warnings():  # a tight length limit makes PyVRP warn of its penalties
        warnings.simplefilter("ignore")
        result = pyvrp.solve(data, stop=MaxIterations(iterations), seed=seed, collect_stats=False)
    if not result.best.is_feasible() and not keep:
        return None
    routes: list[list[int]] = [[] for _ in range(M)]
    for route in result.best.routes():
        routes[route.vehicle_type()] = [a.idx for a in route if a.is_client()]
    return routes


def route_lengths(
    starts: np.ndarray, closed: np.ndarray, points: np.ndarray, routes: list[list[int]]
) -> np.ndarray:
    """``(M,)`` lengths of the routes through ``points`` (unit box)."""
    out = np.zeros(len(routes))
    for m, r in enumerate(routes):
        parts = [starts[m][None], points[r]] + ([starts[m][None]] if closed[m] else [])
        v = np.vstack(parts)
        out[m] = float(np.hypot(*np.diff(v, axis=0).T).sum())
    return out


def order_points_minmax(
    starts: np.ndarray,
    closed: np.ndarray,
    points: np.ndarray,
    iterations: int,
    seed: int,
    steps: int = 6,
    caps: np.ndarray | None = None,
) -> list[list[int]]:
    """Routes through ``points`` whose longest is short: a bisection on PyVRP's route length limit.

    Starts from the shortest-total routes; each step asks PyVRP for routes no longer than the middle
    of the bracket ``[lower, upper]`` (``lower``: the farthest point's round trip or reach from its
    nearest start, and the total over ``M``), keeping the best feasible answer. ``steps`` solves.
    With ``caps``, every solve keeps each route within its cap too (the first one's routes are
    PyVRP's best even if they are not).
    """
    routes = order_points(starts, closed, points, iterations, seed, caps=caps, keep=True)
    assert routes is not None
    best = routes
    upper = float(route_lengths(starts, closed, points, routes).max())
    off = points[:, None, :] - starts[None, :, :]
    reach = np.hypot(off[..., 0], off[..., 1]).min(axis=1).max() if len(points) else 0.0
    lower = max(float(reach) * (2 if bool(closed.all()) else 1), upper / len(starts) * 0.5)
    for _ in range(steps):
        if upper - lower <= 1e-6 * upper:
            break
        mid = (lower + upper) / 2
        trial = order_points(starts, closed, points, iterations, seed, max_length=mid, caps=caps)
        if trial is None:
            lower = mid
            continue
        best = trial
        upper = float(route_lengths(starts, closed, points, trial).max())
    return best
