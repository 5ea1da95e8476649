"""Near-optimal orderings from OR-Tools routing (the optional ``ortools`` extra).

The open multiple TSP with a start per platform is posed as a vehicle routing problem on ``N + M + 1``
nodes: the locales ``0 .. N-1``, one start node ``N + m`` per platform (vehicle ``m`` starts there) and a
single shared end node ``N + M`` reached at zero cost from anywhere, which makes the routes open. Closed
routes (return to base) drop the end node: vehicle ``m`` ends at its own start node, and the arc from a
locale to it costs the distance home. Arcs into
a start node never occur in a solution (OR-Tools uses start nodes only as starts) and get the largest
cost. Arc costs are integers: distances times a scale chosen so the largest arc is :data:`COST_SCALE_MAX`,
i.e. a relative rounding error of about 1e-9 per arc. The reported distance is recomputed in floating
point from the routes, never taken from the integer objective.

``min_tour`` is a counting dimension: every arc adds 1, so the cumul at a vehicle's end is its number of
locales plus one, and should be ``>= min_tour + 1``. The bound is soft, with a price per missing locale
above the cost of any tour, so that the first-solution heuristics always succeed and the local search
drives the shortfall to zero; a final answer still short raises SolverError.

Routing searches on one thread and has no seed, so the only source of run-to-run variation is a
wall-clock limit. The default mode has none: it stops after a number of solutions and is reproducible.
"""

from __future__ import annotations

import math
import multiprocessing
import numbers
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError, MissingDependencyError, SolverError
from pmht_opt.ordering.tour import TourResult, _check_closed, check_count, check_min_tour, tour_distance
from pmht_opt.scenario import Scenario
from pmht_opt.stopping import ProgressObserver, StoppingCriterion, Watched

#: Integer cost of the longest arc; leaves int64 headroom for OR-Tools' sums and GLS penalties.
COST_SCALE_MAX = 1_000_000_000
#: Solutions after which the deterministic mode (no ``time_limit``) stops.
DEFAULT_SOLUTION_LIMIT = 300

FIRST_SOLUTIONS = (
    "AUTOMATIC",
    "PATH_CHEAPEST_ARC",
    "PATH_MOST_CONSTRAINED_ARC",
    "SAVINGS",
    "PARALLEL_SAVINGS",
    "SWEEP",
    "CHRISTOFIDES",
    "BEST_INSERTION",
    "PARALLEL_CHEAPEST_INSERTION",
    "SEQUENTIAL_CHEAPEST_INSERTION",
    "LOCAL_CHEAPEST_INSERTION",
    "LOCAL_CHEAPEST_COST_INSERTION",
    "GLOBAL_CHEAPEST_ARC",
    "LOCAL_CHEAPEST_ARC",
    "FIRST_UNBOUND_MIN_VALUE",
)
METAHEURISTICS = (
    "AUTOMATIC",
    "GREEDY_DESCENT",
    "GUIDED_LOCAL_SEARCH",
    "SIMULATED_ANNEALING",
    "TABU_SEARCH",
    "GENERIC_TABU_SEARCH",
)


class _LoadError(Exception):
    """ortools is installed but its native library cannot be loaded into this process."""


def _import_ortools() -> tuple[Any, Any]:
    try:
        from ortools.constraint_solver import pywrapcp, routing_enums_pb2
    except ModuleNotFoundError as err:
        raise MissingDependencyError(
            'The OR-Tools ordering needs the ortools package: pip install "pmht-opt[ortools]".'
        ) from err
    except ImportError as err:
        # libortools bundles HiGHS and can clash with highspy (a cvxpy dependency) once the latter
        # is loaded, e.g. after a plan with the cvxpy backend.
        raise _LoadError(str(err)) from err
    return pywrapcp, routing_enums_pb2


def _choice(name: str, value: Any, allowed: tuple[str, ...]) -> str:
    key = str(value).upper()
    if not isinstance(value, str) or key not in allowed:
        raise ConfigError(f"{name}: expected one of {', '.join(allowed)}, got {value!r}.")
    return key


def _shortfall_penalty(n_locales: int, n_platforms: int, closed: bool) -> int:
    """Price of one locale missing from a route's ``min_tour``: more than any tour costs (``N`` arcs,
    ``N + M`` if closed, each at most :data:`COST_SCALE_MAX`)."""
    return (n_locales + 1 + (n_platforms if closed else 0)) * COST_SCALE_MAX


def arc_costs(scenario: Scenario, closed: bool = False) -> tuple[np.ndarray, float]:
    """Integer arc-cost matrix of the routing model and its scale (cost per unit).

    Rows are tails and columns heads: locales, then start nodes, then (open routes only) the end node,
    so the matrix is ``(N+M+1, N+M+1)`` for open routes and ``(N+M, N+M)`` for closed ones, where each
    vehicle ends at its own start node and a locale-to-start arc is the leg home.
    """
    z, s = scenario.locales, scenario.start_positions
    N, M = z.shape[0], s.shape[0]
    pts = np.vstack([z, s])
    dist = np.sqrt(((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1))
    longest = float(dist[:, :N].max()) if N else 0.0
    scale = COST_SCALE_MAX / longest if longest > 0 else 1.0
    size = N + M + (0 if closed else 1)
    cost = np.zeros((size, size), dtype=np.int64)
    cost[: N + M, :N] = np.rint(dist[:, :N] * scale).astype(np.int64)
    # Into a start: never used by an open solution (nor, closed, from another start), priced out in
    # case a heuristic considers it.
    cost[:, N : N + M] = COST_SCALE_MAX * 4
    if closed:
        cost[:N, N : N + M] = np.rint(dist[:N, N:] * scale).astype(np.int64)
    else:
        cost[:, N + M] = 0
    np.fill_diagonal(cost, 0)
    return cost, scale


#: The longest time limit OR-Tools is given (seconds, about 30 years): its duration field overflows
#: not far above.
TIME_LIMIT_MAX = 1e9


def _check_time_limit(time_limit: Any) -> float | None:
    if time_limit is None:
        return None
    try:
        value = float(time_limit) if isinstance(time_limit, numbers.Real) else math.nan
    except OverflowError:  # an integer beyond the float range
        value = math.nan
    if isinstance(time_limit, bool) or not (math.isfinite(value) and 0 < value <= TIME_LIMIT_MAX):
        raise ConfigError(
            f"time_limit: expected a positive number of seconds up to {TIME_LIMIT_MAX:g} or None, "
            f"got {time_limit!r}."
        )
    return value


def solve_ortools(
    scenario: Scenario,
    time_limit: float | None = None,
    min_tour: int = 1,
    first_solution: str = "PATH_CHEAPEST_ARC",
    metaheuristic: str = "GUIDED_LOCAL_SEARCH",
    solution_limit: int | None = None,
    log_search: bool = False,
    closed: bool = False,
    stop: StoppingCriterion | None = None,
    callback: ProgressObserver | None = None,
) -> TourResult:
    """Order the locales with OR-Tools routing: routes from per-platform starts, minimum distance.

    OR-Tools routing has no seed and searches on one thread, so without a wall-clock limit the same
    input gives the same tour. The default is that deterministic mode: the search stops after
    ``solution_limit`` solutions (:data:`DEFAULT_SOLUTION_LIMIT` unless given), which is what studies
    should use. ``time_limit`` stops on wall-clock time instead, for interactive use: how far the search
    gets then depends on the machine and its load, so the tour can differ from run to run.

    Parameters
    ----------
    scenario
        Locales ``(N, 2)`` and platforms' starts ``(M, 2)``.
    time_limit
        Seconds of search at most (None: no wall-clock limit, the deterministic mode).
    min_tour
        Minimum locales per route, ``>= 1`` with ``min_tour * M <= N``.
    first_solution
        Name of an OR-Tools ``FirstSolutionStrategy`` (see :data:`FIRST_SOLUTIONS`).
    metaheuristic
        Name of an OR-Tools ``LocalSearchMetaheuristic`` (see :data:`METAHEURISTICS`).
        ``"GREEDY_DESCENT"`` stops at its first local optimum: deterministic and fast, and weaker.
    solution_limit
        Stop after this many solutions; None: :data:`DEFAULT_SOLUTION_LIMIT` without ``time_limit``,
        no limit with it.
    log_search
        Let OR-Tools log its search to stderr.
    closed
        Return to base: each vehicle ends at its own start and the cost includes that leg.
    stop, callback
        A stopping criterion asked, and ``callback(progress)`` called, at every solution the search
        finds (:mod:`pmht_opt.stopping`; scores are the best cost so far in the scenario's units).

    Returns
    -------
    TourResult
        ``history`` holds the costs of the improving solutions found, in order (the last one is the
        answer, up to the integer scaling); ``extras["deterministic"]`` says whether the run stopped
        on solutions only.

    Raises
    ------
    MissingDependencyError
        ortools is not installed.
    SolverError
        OR-Tools found no solution within the limits.
    """
    limit = _check_time_limit(time_limit)
    min_tour = check_min_tour(scenario, min_tour)
    first = _choice("first_solution", first_solution, FIRST_SOLUTIONS)
    meta = _choice("metaheuristic", metaheuristic, METAHEURISTICS)
    if solution_limit is not None:
        solution_limit = check_count("solution_limit", solution_limit)
    elif limit is None:
        solution_limit = DEFAULT_SOLUTION_LIMIT
    if not isinstance(log_search, bool):
        raise ConfigError(f"log_search: expected True or False, got {log_search!r}.")
    closed = _check_closed(closed)
    try:
        pywrapcp, enums = _import_ortools()
    except _LoadError:
        if stop is not None or callback is not None:
            raise ConfigError(
                "stop: OR-Tools runs in a process of its own here (another library holds its solver "
                "symbols), where a stopping criterion or callback cannot follow it; use solution_limit."
            ) from None
        # Solve in a fresh process, where nothing else has claimed the HiGHS symbols.
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(1, mp_context=ctx) as pool:
            job = pool.submit(
                solve_ortools, scenario, limit, min_tour, first, meta, solution_limit, log_search, closed
            )
            return job.result()
    settings = _Settings(limit, solution_limit, min_tour, first, meta, log_search, closed)
    return _solve(scenario, settings, pywrapcp, enums, stop, callback)


@dataclass(frozen=True)
class _Settings:
    """Validated options of one solve."""

    time_limit: float | None
    solution_limit: int | None
    min_tour: int
    first_solution: str
    metaheuristic: str
    log_search: bool
    closed: bool

    def limits(self) -> str:
        """The limits in words, for error messages."""
        parts = [f"{self.solution_limit} solutions"] if self.solution_limit is not None else []
        parts += [f"{self.time_limit} s"] if self.time_limit is not None else []
        return " and ".join(parts)


def _model(scenario: Scenario, settings: _Settings, pywrapcp: Any) -> tuple[Any, Any, float]:
    """The routing model (manager, model) and the cost scale."""
    N, M = scenario.n_locales, scenario.n_platforms
    cost, scale = arc_costs(scenario, settings.closed)
    starts = [N + m for m in range(M)]
    ends = starts if settings.closed else [N + M] * M
    manager = pywrapcp.RoutingIndexManager(cost.shape[0], M, starts, ends)
    routing = pywrapcp.RoutingModel(manager)
    transit = routing.RegisterTransitMatrix(cost.tolist())
    routing.SetArcCostEvaluatorOfAllVehicles(transit)
    # Every arc counts 1: the cumul at a vehicle's end is its number of locales + 1. A hard lower bound
    # there defeats the first-solution heuristics (they fill one route first and then time out
    # backtracking), so it is soft, at a price per missing locale above the cost of any whole tour;
    # the answer is checked afterwards.
    routing.AddConstantDimension(1, N + 1, True, "count")
    count = routing.GetDimensionOrDie("count")
    penalty = _shortfall_penalty(N, M, settings.closed)
    for v in range(M):
        count.SetCumulVarSoftLowerBound(routing.End(v), settings.min_tour + 1, penalty)
        # Otherwise OR-Tools skips the costs of an empty route, and with them its shortfall.
        routing.SetVehicleUsedWhenEmpty(True, v)
    return manager, routing, scale


def _search_parameters(settings: _Settings, pywrapcp: Any, enums: Any) -> Any:
    search = pywrapcp.DefaultRoutingSearchParameters()
    search.first_solution_strategy = getattr(enums.FirstSolutionStrategy, settings.first_solution)
    search.local_search_metaheuristic = getattr(enums.LocalSearchMetaheuristic, settings.metaheuristic)
    if settings.time_limit is not None:
        search.time_limit.FromMilliseconds(max(1, round(settings.time_limit * 1000)))
    if settings.solution_limit is not None:
        search.solution_limit = settings.solution_limit
    search.log_search = settings.log_search
    return search


def _routes(solution: Any, manager: Any, routing: Any, M: int) -> list[np.ndarray]:
    routes: list[np.ndarray] = []
    for v in range(M):
        node_index = solution.Value(routing.NextVar(routing.Start(v)))
        route = []
        while not routing.IsEnd(node_index):
            route.append(manager.IndexToNode(node_index))
            node_index = solution.Value(routing.NextVar(node_index))
        routes.append(np.array(route, dtype=np.intp))
    return routes


def _solve(
    scenario: Scenario,
    settings: _Settings,
    pywrapcp: Any,
    enums: Any,
    stop: StoppingCriterion | None = None,
    callback: ProgressObserver | None = None,
) -> TourResult:
    N, M = scenario.n_locales, scenario.n_platforms
    t0 = time.perf_counter()
    manager, routing, scale = _model(scenario, settings, pywrapcp)
    penalty = _shortfall_penalty(N, M, settings.closed)
    improvements: list[float] = []
    watched = Watched(stop, callback, lambda cost: cost / scale, t0)

    def record() -> None:
        value = routing.CostVar().Value()
        # Solutions short of min_tour carry a penalty larger than any tour: not part of the history.
        if value < penalty and (not improvements or value / scale < improvements[-1]):
            improvements.append(value / scale)
        # Only solutions that meet min_tour count as the search's iterations: stopping before one
        # would leave no ordering to return.
        if value < penalty and (stop is not None or callback is not None) and watched(value):
            routing.solver().FinishCurrentSearch()

    routing.AddAtSolutionCallback(record)
    solution = routing.SolveWithParameters(_search_parameters(settings, pywrapcp, enums))
    wall = time.perf_counter() - t0
    status = str(routing.status())
    if solution is None:
        raise SolverError(
            f"OR-Tools found no ordering within {settings.limits()} (status {status}); "
            "raise the limits or lower min_tour.",
            backend="ortools",
            status=status,
        )
    routes = _routes(solution, manager, routing, M)
    short = [m for m, r in enumerate(routes) if r.size < settings.min_tour]
    if short:
        raise SolverError(
            f"OR-Tools found no ordering with min_tour={settings.min_tour} within {settings.limits()} "
            f"(route(s) {short} are short); raise the limits or lower min_tour.",
            backend="ortools",
            status=status,
        )
    return TourResult(
        routes=routes,
        total_distance=tour_distance(scenario, routes, settings.closed),
        history=np.array(improvements if improvements else [solution.ObjectiveValue() / scale]),
        wall_time=wall,
        method="ortools",
        scenario=scenario,
        extras={
            "time_limit": settings.time_limit,
            "solution_limit": settings.solution_limit,
            "deterministic": settings.time_limit is None,
            "min_tour": settings.min_tour,
            "first_solution": settings.first_solution,
            "metaheuristic": settings.metaheuristic,
            "status": int(routing.status()),
            "objective_scaled": int(solution.ObjectiveValue()),
            "cost_scale": scale,
        },
        closed=settings.closed,
    )
