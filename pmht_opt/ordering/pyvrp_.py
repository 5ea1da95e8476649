r"""Near-optimal orderings from PyVRP's iterated local search (the optional ``pyvrp`` extra).

The open multiple TSP with a start per platform is posed as a vehicle routing problem with one vehicle
type per platform (one vehicle each), on these locations:

- the starts ``s_0 .. s_{M-1}``, a depot each, where vehicle ``m`` starts;
- one shared end depot, where every vehicle ends;
- the ``N`` locales, required clients;
- ``M`` *route ends*, required dummy clients that stand between a route's last locale and the end
  depot.

Arc costs: locale to locale and start to locale are the distances; a locale to a route end and a route
end to the end depot cost 0, which makes the routes open; every other arc (a start straight to a route
end, a route end to a locale or to another route end, anything into a start) is *forbidden*: priced at
:data:`FORBIDDEN`, more than any tour. So each route holds exactly one route end, last, after at least
one locale: every platform gets a locale (``min_tour >= 1``) although PyVRP, left alone, would leave a
far-away vehicle unused. The route ends are interchangeable, so PyVRP's inter-route moves (exchanging
the tails of two routes, say) carry them along at no cost.

``min_tour > 1`` uses time: entering a locale takes one unit, everything else none, vehicles leave at
time 0, and a route end opens at time ``min_tour``. A route with ``k < min_tour`` locales waits
``min_tour - k`` units there, and each unit of route duration costs :math:`W`, more than any tour
costs. Summed over the routes the duration is :math:`\sum_m \max(k_m, \text{min\_tour}) \ge N`, with
equality exactly when every route is long enough, so the constant :math:`W N` is the only duration
cost of a valid tour and every missing locale costs :math:`W`: a soft lower bound, like the OR-Tools
adapter's, that the search drives to zero; a final answer still short raises SolverError.

Arc costs are integers: distances times a scale chosen so the longest arc is at most
:data:`COST_SCALE_MAX` (less on large instances, so the costs keep headroom below the forbidden price
in int64). The reported distance is recomputed in floating point from the routes.

Closed routes (return to base) have no end depot: vehicle ``m`` ends at its own start, a route end
leads there at no cost, and the leg home is the arc from the last locale into the route end. That arc
depends on the vehicle, so each platform gets its own routing profile (its own distance matrix) in
which every locale-to-route-end arc costs its distance home; the route ends stay interchangeable.

The search stops after ``iterations`` iterations or ``no_improvement`` iterations without a better
solution, never on wall time, so a seed fixes the answer.
"""

from __future__ import annotations

import numbers
import time
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError, MissingDependencyError, SolverError
from pmht_opt.ordering.tour import TourResult, _check_closed, check_count, check_min_tour, tour_distance
from pmht_opt.scenario import Scenario
from pmht_opt.stopping import ProgressObserver, StoppingCriterion, Watched

#: Integer cost of the longest arc at most (relative rounding of about 5e-9 per arc).
COST_SCALE_MAX = 100_000_000
#: Price of a forbidden arc: above any tour and any waiting cost (PyVRP's own price of a missing edge).
FORBIDDEN = 1 << 44
#: Largest seed PyVRP's generator takes.
SEED_MAX = 2**32 - 1


def _import_pyvrp() -> Any:
    try:
        import pyvrp
    except ModuleNotFoundError as err:
        raise MissingDependencyError(
            'The PyVRP ordering needs the pyvrp package: pip install "pmht-opt[pyvrp]".'
        ) from err
    return pyvrp


def cost_scale(scenario: Scenario) -> float:
    """Integer cost per unit of distance: the longest arc maps to at most :data:`COST_SCALE_MAX`.

    A valid tour's cost (arcs plus the constant duration cost ``W N``, ``W = (N + M + 1)`` longest
    arcs) stays below ``FORBIDDEN / 8``.
    """
    N, M = scenario.n_locales, scenario.n_platforms
    pts = np.vstack([scenario.locales, scenario.start_positions])
    longest = float(np.sqrt(((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1)).max())
    top = min(COST_SCALE_MAX, FORBIDDEN // (8 * (N + M + 1) * (2 * N + M + 1)))
    return top / longest if longest > 0 else 1.0


def problem_data(scenario: Scenario, min_tour: int = 1, closed: bool = False) -> tuple[Any, float, int]:
    """PyVRP ``ProblemData`` of the multiple TSP, its cost scale and the cost of one missing locale.

    Locations: the starts ``0 .. M-1``, the end depot ``M`` (open routes only), the locales, then the
    route ends. Depots are the starts (and the end depot); clients are the locales, then the route ends.
    """
    pyvrp = _import_pyvrp()
    z, s = scenario.locales, scenario.start_positions
    N, M = z.shape[0], s.shape[0]
    scale = cost_scale(scenario)
    pts = np.vstack([z, s])
    dist = np.rint(np.sqrt(((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1)) * scale).astype(np.int64)
    n_depots = M if closed else M + 1
    loc = np.arange(n_depots, n_depots + N)
    ends = np.arange(n_depots + N, n_depots + N + M)
    size = n_depots + N + M
    d = np.full((size, size), FORBIDDEN, dtype=np.int64)
    d[np.ix_(loc, loc)] = dist[:N, :N]
    d[:M, loc] = dist[N:, :N]
    d[np.ix_(loc, ends)] = 0
    d[np.ix_(ends, np.arange(M) if closed else [M])] = 0
    np.fill_diagonal(d, 0)
    if closed:  # one profile per platform: its own leg home from every locale into a route end
        distances = []
        for m in range(M):
            dm = d.copy()
            dm[np.ix_(loc, ends)] = dist[:N, N + m, None]
            distances.append(dm)
    else:
        distances = [d]
    timed = min_tour > 1
    t = np.zeros_like(d)
    if timed:  # one unit to enter a locale (see the module notes)
        t[np.ix_(loc, loc)] = 1
        t[:M, loc] = 1
        np.fill_diagonal(t, 0)
    penalty = int((N + M + 1) * np.ceil(dist.max())) + 1
    xy = np.vstack([s, s[: n_depots - M], z, s])
    locations = [pyvrp.Location(float(x), float(y)) for x, y in xy]
    depots = [pyvrp.Depot(i) for i in range(n_depots)]
    clients = [pyvrp.Client(int(i)) for i in loc]
    clients += [pyvrp.Client(int(i), tw_early=min_tour if timed else 0) for i in ends]
    vehicle = {"unit_duration_cost": penalty, "start_late": 0} if timed else {}
    types = [
        pyvrp.VehicleType(
            1,
            start_depot=m,
            end_depot=m if closed else M,
            profile=m if closed else 0,
            name=f"platform {m}",
            **vehicle,
        )
        for m in range(M)
    ]
    data = pyvrp.ProblemData(locations, clients, depots, types, distances, [t] * len(distances))
    return data, scale, penalty


def _history(stats: Any, scale: float, offset: int, penalty: int) -> list[float]:
    """Distances of the successive improving best solutions that meet ``min_tour``."""
    out: list[float] = []
    for datum in stats.data:
        cost = int(datum.best_cost) - offset
        if 0 <= cost < penalty and (not out or cost / scale < out[-1]):
            out.append(cost / scale)
    return out


def _check_seed(seed: Any) -> int:
    if isinstance(seed, np.random.Generator):
        return int(seed.integers(0, SEED_MAX, endpoint=True))
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or not 0 <= int(seed) <= SEED_MAX:
        raise ConfigError(
            f"seed: expected an integer in 0..{SEED_MAX} or a numpy.random.Generator, got {seed!r}."
        )
    return int(seed)


def solve_pyvrp(
    scenario: Scenario,
    seed: int | np.random.Generator = 0,
    iterations: int = 5000,
    no_improvement: int | None = None,
    min_tour: int = 1,
    closed: bool = False,
    stop: StoppingCriterion | None = None,
    callback: ProgressObserver | None = None,
) -> TourResult:
    """Order the locales with PyVRP: routes from per-platform starts, minimum total distance.

    Parameters
    ----------
    scenario
        Locales ``(N, 2)`` and platforms' starts ``(M, 2)``.
    seed
        Seed of PyVRP's generator (``0 .. 2**32 - 1``), or a ``numpy.random.Generator`` that draws
        it: the same seed gives the same tour.
    iterations
        Iterations of the iterated local search at most.
    no_improvement
        Stop earlier after this many iterations without a better solution (None: never).
    min_tour
        Minimum locales per route, ``>= 1`` with ``min_tour * M <= N``.
    closed
        Return to base: each vehicle ends at its own start and the cost includes that leg.
    stop, callback
        A stopping criterion asked, and ``callback(progress)`` called, after every iteration of the
        search (:mod:`pmht_opt.stopping`; scores are the best cost so far in the scenario's units).

    Returns
    -------
    TourResult
        ``history`` holds the distances of the improving solutions found, in order (the last is the
        answer up to the integer scaling); ``extras`` the iterations run, the seed and the scale.

    Raises
    ------
    MissingDependencyError
        pyvrp is not installed.
    SolverError
        The answer leaves a platform with fewer than ``min_tour`` locales.
    """
    seed = _check_seed(seed)
    iterations = check_count("iterations", iterations)
    if no_improvement is not None:
        no_improvement = check_count("no_improvement", no_improvement)
    min_tour = check_min_tour(scenario, min_tour)
    closed = _check_closed(closed)
    _import_pyvrp()
    from pyvrp import solve
    from pyvrp.stop import MaxIterations, MultipleCriteria, NoImprovement

    N, M = scenario.n_locales, scenario.n_platforms
    t0 = time.perf_counter()
    data, scale, penalty = problem_data(scenario, min_tour, closed)
    criteria: list[Any] = [MaxIterations(iterations)]
    if no_improvement is not None:
        criteria.append(NoImprovement(no_improvement))
    if stop is not None or callback is not None:
        offset0 = penalty * N if min_tour > 1 else 0
        criteria.append(Watched(stop, callback, lambda cost: (cost - offset0) / scale, t0))
    result = solve(data, stop=MultipleCriteria(criteria), seed=seed, collect_stats=True, display=False)
    wall = time.perf_counter() - t0
    routes = [np.zeros(0, dtype=np.intp) for _ in range(M)]
    for route in result.best.routes():
        visits = [a.idx for a in route if a.is_client() and a.idx < N]
        routes[route.vehicle_type()] = np.array(visits, dtype=np.intp)
    short = [m for m, r in enumerate(routes) if r.size < min_tour]
    if short:
        raise SolverError(
            f"PyVRP found no ordering with min_tour={min_tour} within {iterations} iterations "
            f"(route(s) {short} are short); raise iterations or lower min_tour.",
            backend="pyvrp",
        )
    offset = penalty * N if min_tour > 1 else 0
    history = _history(result.stats, scale, offset, penalty)
    total = tour_distance(scenario, routes, closed)
    return TourResult(
        routes=routes,
        total_distance=total,
        history=np.array(history if history else [total]),
        wall_time=wall,
        method="pyvrp",
        scenario=scenario,
        extras={
            "seed": seed,
            "iterations": int(result.num_iterations),
            "max_iterations": iterations,
            "no_improvement": no_improvement,
            "min_tour": min_tour,
            "objective_scaled": int(result.best.distance()),
            "cost_scale": scale,
        },
        closed=closed,
    )
