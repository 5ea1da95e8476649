"""Tours for the coverage planner: orderings of the locales, then of their visit points, kept while the
polyline through the discs gets shorter.

An ordering of the locale centres (the open multiple TSP of docs/model.md section 9) is a poor guide
once a path only has to touch each disc: two locales 0.5 apart are one pass, not a leg, and the best
order through the discs differs from the best order through the centres. So the tours are improved
in rounds: the visit points (:func:`~pmht_opt.planners.coverage.discs.visit_points`) of the best tour so far
are ordered again as if they were the locales, each new order gets its own visit points, and the
rounds go on while the polyline through the discs gets shorter. Overlapping discs end up with one
shared visit point, which the next ordering treats as one stop.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError, SolverError
from pmht_opt.ordering import METHODS, order_locales
from pmht_opt.planners.coverage.discs import visit_points
from pmht_opt.scenario import Scenario

#: Preference of ``orderer="auto"``: the first one installed.
AUTO_ORDER = ("pyvrp", "ortools", "ga")
#: Construction heuristics that give OR-Tools' deterministic descent its different starts.
ORTOOLS_STARTS = (
    "PATH_CHEAPEST_ARC",
    "PARALLEL_CHEAPEST_INSERTION",
    "LOCAL_CHEAPEST_INSERTION",
    "SAVINGS",
    "BEST_INSERTION",
    "GLOBAL_CHEAPEST_ARC",
)
#: PyVRP's search per ordering: stopped on iterations, never on time.
PYVRP_OPTIONS: dict[str, Any] = {"iterations": 1000, "no_improvement": 300}
#: OR-Tools' wall-clock limit, far above what its greedy descent takes: a guard, never the stop.
ORTOOLS_GUARD_SECONDS = 600.0
_PACKAGES = {"pyvrp": "pyvrp", "ortools": "ortools"}


def resolve_orderer(name: Any) -> str:
    """The ordering method to use: ``name`` checked, or for ``"auto"`` the first installed of
    :data:`AUTO_ORDER`."""
    if not isinstance(name, str) or (name != "auto" and name not in METHODS):
        raise ConfigError(f"orderer: expected 'auto' or one of {', '.join(sorted(METHODS))}, got {name!r}.")
    if name != "auto":
        return name
    for method in AUTO_ORDER:
        package = _PACKAGES.get(method)
        if method in METHODS and (package is None or importlib.util.find_spec(package) is not None):
            return method
    return "ga"


def variants(orderer: str, starts: int) -> int:
    """How many different tours ``orderer`` can give (OR-Tools: one per construction heuristic)."""
    return min(starts, len(ORTOOLS_STARTS)) if orderer == "ortools" else starts


def order(scenario: Scenario, orderer: str, variant: int, seed: int) -> list[np.ndarray]:
    """Routes of variant ``variant`` of ``orderer`` on ``scenario``'s locales; deterministic.

    OR-Tools runs its greedy descent (no time-dependent search) from construction heuristic
    ``variant``; PyVRP and the GA run with seed ``seed + variant``.
    """
    if orderer == "ortools":
        tour = order_locales(
            scenario,
            "ortools",
            first_solution=ORTOOLS_STARTS[variant],
            metaheuristic="GREEDY_DESCENT",
            time_limit=ORTOOLS_GUARD_SECONDS,
        )
    elif orderer == "pyvrp":
        tour = order_locales(scenario, "pyvrp", seed=seed + variant, **PYVRP_OPTIONS)
    else:
        tour = order_locales(scenario, orderer, seed=seed + variant)
    return [np.asarray(r, dtype=np.intp) for r in tour.routes]


@dataclass
class Candidate:
    """One tour and its visit polyline (``length``); ``parent`` is the candidate whose visit points
    were ordered to make it (``-1``: an ordering of the locales themselves)."""

    label: str
    routes: list[np.ndarray]
    points: np.ndarray
    length: float
    parent: int = -1
    expanded: bool = field(default=False, compare=False)


def _key(routes: list[np.ndarray]) -> tuple[tuple[int, ...], ...]:
    return tuple(tuple(int(n) for n in r) for r in routes)


def search(
    scenario: Scenario,
    orderer: str,
    n_variants: int,
    seed: int,
    radius: float,
    rounds: int,
    beam: int,
    keep_going: Callable[[Candidate], bool],
) -> list[Candidate]:
    """Candidate tours: orderings of the locales, then rounds of orderings of the best visit points.

    Round 0 orders the locales with each of ``n_variants`` variants of ``orderer``. Each later round
    takes the ``beam`` shortest candidates not yet expanded and orders their visit points with every
    variant; it stops after ``rounds`` rounds, when a round finds nothing shorter, or when
    ``keep_going(best)`` says so (asked before each ordering but the first). Tours found twice are
    kept once. Returns every candidate, in the order found.
    """
    pool: list[Candidate] = []
    seen: set[tuple[tuple[int, ...], ...]] = set()

    def add(routes: list[np.ndarray], label: str, parent: int) -> None:
        key = _key(routes)
        if key in seen:
            return
        seen.add(key)
        points, length = visit_points(scenario, routes, radius)
        pool.append(Candidate(label, routes, points, length, parent))

    def expand(locales: np.ndarray, label: str, parent: int) -> bool:
        for v in range(n_variants):
            if pool and not keep_going(min(pool, key=lambda c: c.length)):
                return False
            try:
                routes = order(scenario.replace(locales=locales), orderer, v, seed)
            except SolverError:
                continue  # a construction heuristic that finds nothing here; the others remain
            add(routes, f"{label}{orderer}[{v}]", parent)
        return True

    expand(scenario.locales, "", -1)
    for _ in range(rounds):
        if not pool:
            break
        best = min(c.length for c in pool)
        parents = sorted((i for i, c in enumerate(pool) if not c.expanded), key=lambda i: pool[i].length)
        go = True
        for i in parents[:beam]:
            pool[i].expanded = True
            go = expand(pool[i].points, f"{pool[i].label} > ", i)
            if not go:
                break
        if not go or min(c.length for c in pool) >= best * (1.0 - 1e-9):
            break
    return pool
