"""``plan(scenario, method="coverage")``: every locale within its sensor radius, shortest smooth paths.

Two stages. The *tour*: the shortest straight-line routes from the platforms' starts (home again when
the mission returns to base) that meet every locale's disc, by the tour engine of
:mod:`pmht_opt.tours` (the Close-Enough TSP's state of the art, for one platform or several, total
length or mission time). The *flight*: smooth paths that follow those routes closely and meet every
disc at its full radius, together with the user's constraints (:mod:`.fly`, with the smoothing rule
of :mod:`.flight`). The straight-line tour is kept in the result beside the smooth plan: it is a
valid waypoint mission on its own.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.constraints.feasibility import check_feasible
from pmht_opt.constraints.visits import VisitAll
from pmht_opt.exceptions import ConfigError
from pmht_opt.planners.base import Planner
from pmht_opt.planners.coverage.fly import fly
from pmht_opt.planners.routes import closed_routes, tours_within_budgets
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.settings import Settings
from pmht_opt.stopping import AnyOf, Progress, ProgressObserver, StoppingCriterion
from pmht_opt.tours import DiscProblem, TourSettings
from pmht_opt.tours import Progress as TourProgress

#: The tour search's effort options (:class:`~pmht_opt.tours.TourSettings`) a caller may set.
SEARCH_OPTIONS = tuple(
    f.name for f in dataclasses.fields(TourSettings) if f.name not in ("seed", "objective")
)
#: The smoothing rule's default: corners rounded over 0.3 of the median coverage radius (measured on
#: the development cases of the CETSP benchmark: 1.2% longer than the straight tour on average, 2.2% at most;
#: 0.1 gave 0.4% and 0.9%, 1.0 gave 3.6% and 7.6%).
DEFAULT_SMOOTHING = 0.3
#: Iterations of the flight: each moves every disc's step to where the last path passes closest.
ITERATIONS = 3
#: The same when a user constraint is re-linearised at each iterate (obstacles).
DYNAMIC_ITERATIONS = 10


@dataclass(frozen=True)
class CoverageOptions:
    """The options of ``plan(..., method="coverage")``.

    Parameters
    ----------
    radius
        The sensor radius every locale must be within: one number, one per locale, or ``None``
        (default) for the scenario's :attr:`~pmht_opt.Scenario.coverage_radius`.
    objective
        ``"distance"`` (default: the shortest routes in total, the paper's metric) or ``"time"``
        (the earliest finish: the longest route as short as it can be, then the total). Either way
        each route is capped at what its platform can fly in the horizon at its speed limit
        (:func:`~pmht_opt.planners.routes.tours_within_budgets`): with ``"distance"``, the shortest
        routes in total that fit the horizon.
    smoothing
        How much the smooth paths round the tour's corners: over ``smoothing`` times the median
        coverage radius (the rule of :mod:`pmht_opt.planners.coverage.flight`). Smaller follows the
        tour more tightly (shorter, sharper turns).
    iterations
        Iterations of the flight (default 3, or 10 with a constraint re-linearised at each path, such
        as an obstacle).
    search
        Effort of the tour search, :class:`~pmht_opt.tours.TourSettings`' fields by name (``seed``
        comes from the shared settings, ``objective`` from above); the defaults are the benchmark's.
    """

    radius: Any = field(default=None, compare=False)
    objective: str = "distance"
    smoothing: float = DEFAULT_SMOOTHING
    iterations: int | None = None
    search: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.radius is not None:
            object.__setattr__(self, "radius", _radius(self.radius))
        if self.objective not in ("distance", "time"):
            raise ConfigError(f"objective: expected 'distance' or 'time', got {self.objective!r}.")
        validation.real("smoothing", self.smoothing, ConfigError, 0.0, 1e6, lo_open=True)
        if self.iterations is not None:
            validation.integer("iterations", self.iterations, ConfigError, 1, validation.MAX_ITERATIONS)
        if not isinstance(self.search, Mapping):
            raise ConfigError(f"search: expected a mapping of TourSettings' options, got {self.search!r}.")
        unknown = sorted(set(self.search) - set(SEARCH_OPTIONS))
        if unknown:
            takes = ", ".join(SEARCH_OPTIONS)
            raise ConfigError(f"search.{unknown[0]}: not an option of the tour search; it takes {takes}.")
        TourSettings(**self.search)  # checks the values, naming them


class CoveragePlanner(Planner):
    """Every locale within its sensor radius, with the shortest smooth paths found (module notes)."""

    name = "coverage"
    summary = "every locale within its sensor radius of a path, shortest smooth paths (recommended)"
    Options = CoverageOptions

    def default_stop(self) -> StoppingCriterion:
        return AnyOf(())  # the tour search's own iteration limits end it

    def run(
        self,
        scenario: Scenario,
        settings: Settings,
        options: CoverageOptions,
        stop: StoppingCriterion,
        callback: ProgressObserver | None,
    ) -> PlanResult:
        return plan_cover(scenario, settings, options, stop, callback)


def plan_cover(
    scenario: Scenario,
    settings: Settings,
    options: CoverageOptions,
    stop: StoppingCriterion | None = None,
    callback: ProgressObserver | None = None,
) -> PlanResult:
    """The coverage plan of ``scenario`` (module notes); ``stop`` and ``callback`` follow the tour
    search's iterations (stage ``"search"``)."""
    t0 = time.perf_counter()
    scenario = scenario.replace()  # checked again: a scenario changed after it was made is refused
    visits = [c.name for c in settings.constraints if isinstance(c, VisitAll)]
    if visits:
        raise ConfigError(
            f"constraints: {', '.join(visits)} places visits on the locales, which the coverage planner "
            "already guarantees at its radius; leave it out and give the radius instead."
        )
    sc = scenario if options.radius is None else scenario.replace(coverage_radius=_radius(options.radius))
    # What can be proven before any search: a disc inside a keep-out zone or outside the area, out of
    # every platform's reach at its speed limit (InfeasibleError).
    check_feasible(sc, (*settings.constraints, VisitAll()))
    problem = DiscProblem(
        starts=sc.start_positions,
        centres=sc.locales,
        radii=sc.radii,
        closed=closed_routes(sc, settings.constraints),
    )
    search = TourSettings(seed=settings.seed, objective=options.objective, **options.search)

    def observed(p: TourProgress) -> Progress:
        return Progress(p.iteration, list(p.scores), p.elapsed, True, "search")

    def report(p: TourProgress) -> None:
        if callback is not None:
            callback(observed(p))

    # Each route no longer than its platform can fly in the horizon at its speed limit: a hard cap of
    # the search whatever the objective (SolverError saying what to change when none is found).
    tours = tours_within_budgets(
        sc,
        settings.constraints,
        problem,
        search,
        callback=None if callback is None else report,
        stop=None if stop is None else (lambda p: bool(stop(observed(p)))),
    )
    dynamic = any(c.dynamic for c in settings.constraints)
    iterations = options.iterations or (DYNAMIC_ITERATIONS if dynamic else ITERATIONS)
    result = fly(sc, tours, settings, options.smoothing, iterations)
    result.extras.update({"objective": options.objective, "search": tours.info})
    result.wall_time = time.perf_counter() - t0
    return dataclasses.replace(result, scenario=scenario) if options.radius is None else result


def _radius(radius: Any) -> float | np.ndarray:
    """A radius option: one positive number, or one per locale (their number checked by the
    scenario)."""
    if isinstance(radius, str) or np.ndim(radius) == 0:
        return validation.real("radius", radius, ConfigError, 0.0, validation.RADIUS_MAX, lo_open=True)
    arr = validation.real_array("radius", radius, ConfigError)
    good = arr.ndim == 1 and np.all(np.isfinite(arr)) and np.all((arr > 0) & (arr <= validation.RADIUS_MAX))
    if not good:
        raise ConfigError(f"radius: expected one positive number or one per locale, got {radius!r}.")
    return arr
