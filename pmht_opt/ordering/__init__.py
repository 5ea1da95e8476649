"""Locale orderings (tours) of the multiple TSP from per-platform starts: GA-TSP, OR-Tools and PyVRP.

:func:`order_locales` is the entry point; every method is one function ``solve(scenario, **options) ->
TourResult`` registered in :data:`METHODS`. OR-Tools and PyVRP are imported only when their method runs.
"""

from __future__ import annotations

import inspect
import math
import time
from collections.abc import Callable, Mapping
from typing import Any

from pmht_opt.exceptions import ConfigError
from pmht_opt.ordering.ga import GAParams, NoRestart, OperatorSet, StallRestart, solve_ga_tsp
from pmht_opt.ordering.ortools_ import solve_ortools
from pmht_opt.ordering.pyvrp_ import solve_pyvrp
from pmht_opt.ordering.tour import TourResult, check_routes, route_costs, route_legs, tour_distance
from pmht_opt.scenario import Scenario
from pmht_opt.stopping import (
    AnyOf,
    Progress,
    ProgressObserver,
    StoppingCriterion,
    as_criterion,
    check_callback,
)

#: Ordering methods by name.
METHODS: dict[str, Callable[..., TourResult]] = {
    "ga": solve_ga_tsp,
    "ortools": solve_ortools,
    "pyvrp": solve_pyvrp,
}


def order_locales(
    scenario: Scenario, method: str = "ga", *, stop: Any = None, callback: Any = None, **options: Any
) -> TourResult:
    """Order the locales into one route per platform: open (the paper's problem) or, with
    ``closed=True``, back to each platform's start (return to base; every method takes ``closed``).

    Parameters
    ----------
    scenario
        The scenario to solve.
    method
        ``"ga"`` (:func:`solve_ga_tsp`, the paper's baseline), ``"ortools"`` (:func:`solve_ortools`,
        near-optimal; needs the ``ortools`` extra) or ``"pyvrp"`` (:func:`solve_pyvrp`, near-optimal
        and deterministic for a seed).
    stop
        When the method's search ends, beside its own limits: a stopping criterion of
        :mod:`pmht_opt.stopping` (or a list of them), asked after every iteration (the GA's
        generations, PyVRP's iterations, OR-Tools' solutions), as :func:`pmht_opt.plan` asks it.
    callback
        ``callback(progress)`` after every iteration, with a :class:`~pmht_opt.stopping.Progress`
        (stage ``"ordering"``; scores are the best tour's cost so far).
    options
        Keyword options of the chosen method, e.g. ``seed``, ``iterations``, ``min_tour``, ``operators``
        (``"improved"`` or the paper's ``"kirk"``), ``restart`` for the GA or ``time_limit``,
        ``min_tour`` for OR-Tools, ``seed``, ``iterations``, ``no_improvement``, ``min_tour`` for PyVRP.

    Raises
    ------
    ConfigError
        An unknown method (the message lists the methods) or an option the method does not take.
    """
    if not isinstance(scenario, Scenario):
        raise ConfigError(f"scenario: expected a Scenario, got {type(scenario).__name__}.")
    solve = ordering_method(method, options)
    criterion = None if stop is None else as_criterion(stop)
    observer = check_callback(callback)
    if method == "ga" and (criterion is not None or observer is not None):
        options = _ga_observed(options, criterion, observer)
    elif criterion is not None or observer is not None:
        options = {**options, "stop": criterion, "callback": observer}
    return solve(scenario, **options)


def _ga_observed(
    options: dict[str, Any], stop: StoppingCriterion | None, callback: ProgressObserver | None
) -> dict[str, Any]:
    """The GA's options with ``stop`` joined to its own and ``callback`` fed :class:`Progress`
    records (the GA's own ``callback`` option takes ``(iteration, best_cost)``)."""
    out = dict(options)
    if stop is not None:
        own = out.get("stop")
        out["stop"] = stop if own is None else AnyOf((own, stop))
    if callback is not None:
        if out.get("callback") is not None:
            raise ConfigError("callback: give the GA's own callback option or callback=, not both.")
        t0 = time.perf_counter()
        scores: list[float] = [math.inf]

        def report(iteration: int, best: float) -> None:
            scores.append(best)
            callback(Progress(iteration + 1, list(scores), time.perf_counter() - t0, True, "ordering"))

        out["callback"] = report
    return out


def ordering_method(method: Any, options: Mapping[str, Any] | None = None) -> Callable[..., TourResult]:
    """The solve function of ``method``, after checking that it takes every one of ``options``' names
    (their values are checked when it runs); ConfigError naming the method or the first unknown option."""
    solve = METHODS.get(method) if isinstance(method, str) else None
    if solve is None:
        raise ConfigError(f"method: expected one of {', '.join(sorted(METHODS))}, got {method!r}.")
    accepted = [p for p in inspect.signature(solve).parameters if p != "scenario"]
    unknown = sorted(set(options or {}) - set(accepted))
    if unknown:
        raise ConfigError(
            f"{unknown[0]}: not an option of method {method!r}; it takes {', '.join(accepted)}."
        )
    return solve


__all__ = [
    "METHODS",
    "GAParams",
    "NoRestart",
    "OperatorSet",
    "StallRestart",
    "TourResult",
    "check_routes",
    "order_locales",
    "ordering_method",
    "route_costs",
    "route_legs",
    "solve_ga_tsp",
    "solve_ortools",
    "solve_pyvrp",
    "tour_distance",
]
