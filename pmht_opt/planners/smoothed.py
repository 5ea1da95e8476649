"""GA-TSP PMHT smoothed: a tour turned into hard ordering constraints (docs/model.md section 10).

The paper feeds a GA tour to the PMHT planner through its priors: ``pi^k[n, m] = 1`` for the tour's
platform, and ``pi^tau[n, .]`` uniform on the locale's *sub-batch* (the platform's horizon cut into one
window per locale, in tour order) and zero elsewhere. That makes the order likely, not certain: a
locale can still be passed at a distance. Here the tour is also a constraint: in every M-step, each
locale must be within ``visit_radius`` of its platform at one time step inside its own sub-batch,
the step the E-step finds most probable (re-chosen every iteration). Sub-batches are disjoint and
ordered, so the returned paths pass the locales in tour order, guaranteed.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.constraints.blocks import DEFAULT_SIDES
from pmht_opt.constraints.params import positive_number
from pmht_opt.constraints.visits import VisitAll
from pmht_opt.em import EMCallbacks, EMRun
from pmht_opt.exceptions import ConfigError, PmhtOptError, ScheduleError
from pmht_opt.ordering import TourResult, check_routes, order_locales
from pmht_opt.planners.base import Planner, refuse_ignored
from pmht_opt.planners.coverage.method import CoverageOptions, plan_cover
from pmht_opt.planners.progress import observing, with_progress
from pmht_opt.planners.routes import closed_routes, tours_within_budgets
from pmht_opt.planners.windows import (
    SPLITS,
    TourVisits,
    polyline_start,
    sub_batches,
    window_priors,
    witness_visits,
)
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.settings import PMHT_ITERATIONS, PMHTConfig, PMHTOptions, ProgressCallback, Settings
from pmht_opt.stopping import (
    AnyOf,
    Converged,
    MaxIterations,
    ProgressObserver,
    StoppingCriterion,
    iteration_limit,
)
from pmht_opt.tours import DiscProblem, TourSettings

#: When :func:`plan_smoothed` stops by default: the tour fixes the assignment, so once the visits are
#: at full strength the paths only polish; a position change below 3e-4 of the area for three
#: iterations marks the end of that.
SMOOTHED_CONVERGED = Converged(path_rtol=3e-4, stable=3)


def _same_places(a: Scenario | None, b: Scenario) -> bool:
    """Whether a tour ordered on ``a`` (``None``: unknown) is one of ``b``'s locales and starts."""
    if a is None or a is b:
        return True
    return bool(np.array_equal(a.locales, b.locales) and np.array_equal(a.start_positions, b.start_positions))


def plan_smoothed(
    scenario: Scenario,
    tour: TourResult | Sequence[Any],
    config: PMHTConfig | None = None,
    visit_radius: float | None = None,
    *,
    split: str = "equal",
    sides: int = DEFAULT_SIDES,
    callback: ProgressCallback | None = None,
    callbacks: EMCallbacks | None = None,
    converge: Converged | None = SMOOTHED_CONVERGED,
) -> PlanResult:
    """Smooth paths that pass every locale in the order of ``tour`` (GA-TSP PMHT smoothed).

    Parameters
    ----------
    scenario
        The locales, starts and model.
    tour
        A :class:`~pmht_opt.ordering.TourResult` (e.g. from :func:`~pmht_opt.order_locales`) or one
        sequence of locale indices per platform, in visiting order.
    config
        Planner settings (solver, iterations, extra constraints such as a
        :class:`~pmht_opt.constraints.SpeedLimit`). Both prior updates and annealing are switched
        off: the tour fixes the assignment and the order, which is what they exist to find.
    visit_radius
        Each locale is passed within this distance, at a step inside its sub-batch; default: the
        scenario's :attr:`~pmht_opt.Scenario.coverage_radius`.
    split
        How each platform's horizon is cut into sub-batches: ``"equal"`` (the paper) or
        ``"distance"`` (proportional to the legs of the tour).
    sides
        Sides of the inner polygon standing in for the visit disc on a backend without cones.
    callback
        Called as ``callback(iteration, objective)`` after every iteration.
    callbacks
        Observers of the EM run (:class:`~pmht_opt.em.EMCallbacks`).
    converge
        Stop once the paths have settled (:class:`~pmht_opt.stopping.Converged`), within the
        configuration's iteration limit; ``None`` runs every iteration. The default
        (:data:`SMOOTHED_CONVERGED`) was chosen on recorded runs of A, B and C: it stops after about
        30 iterations instead of 100, with total distances within 0.15% of the 100-iteration plans and
        the same coverage (docs/decisions.md).

    Returns
    -------
    PlanResult
        The paths; ``assignment`` is the tour's platform and ``visit_time`` the enforced visit step of
        each locale; ``extras`` holds ``routes`` and ``sub_batches``.

    Raises
    ------
    InfeasibleError
        If the visits cannot be met together with the configuration's other constraints; the
        message names the platform and the locales.
    """
    cfg = config if config is not None else PMHTConfig()
    if not isinstance(cfg, PMHTConfig):
        raise ConfigError(f"config must be a PMHTConfig, got {type(cfg).__name__}.")
    refuse_ignored(cfg, IGNORED, "plan_smoothed")
    if converge is not None and not callable(converge):
        raise ConfigError(
            f"converge: expected a stopping criterion such as Converged(...) or None, got {converge!r}."
        )
    stop = (*cfg.criteria(), *(() if converge is None else (converge,)))
    return smooth_tour(
        scenario,
        tour,
        cfg.settings,
        AnyOf(stop),
        visit_radius=visit_radius,
        split=split,
        sides=sides,
        snapshots=cfg.snapshots,
        callbacks=with_progress(callbacks, callback),
    )


#: The EM options the smoothed planner fixes itself: the tour decides assignment and timing.
IGNORED = ("update_time_prior", "update_platform_prior", "anneal")


def smooth_tour(
    scenario: Scenario,
    tour: TourResult | Sequence[Any],
    settings: Settings,
    stop: StoppingCriterion,
    *,
    visit_radius: float | None = None,
    split: str = "equal",
    sides: int = DEFAULT_SIDES,
    snapshots: tuple[int, ...] = (),
    callbacks: EMCallbacks | None = None,
    rescue: bool = False,
) -> PlanResult:
    """The smoothed plan of ``tour`` (:func:`plan_smoothed`, whose parameters these are), its EM run
    stopped by ``stop``.

    When the sub-batches cannot be met (:class:`~pmht_opt.exceptions.ScheduleError`: the windows the
    split gives, not the constraints themselves), the other split's are tried; with ``rescue`` (the
    tour was the planner's own choice, not the caller's) then the coverage planner's plan, which
    fixes its own order and the windows where its paths pass each locale
    (:func:`~pmht_opt.planners.windows.witness_visits`). The plan says so in ``extras["restarted"]``.
    """
    routes = check_routes(scenario, tour.routes if isinstance(tour, TourResult) else tour)
    if isinstance(tour, TourResult) and not _same_places(tour.scenario, scenario):
        raise ConfigError(
            "tour: it was ordered for a scenario with other locales or starts than this one; order this "
            "scenario's locales (or pass the routes themselves)."
        )
    radius: float | np.ndarray = (
        scenario.coverage_radius if visit_radius is None else positive_number("visit_radius", visit_radius)
    )
    closed = closed_routes(scenario, settings.constraints)
    platform = np.empty(scenario.n_locales, dtype=int)
    for m, route in enumerate(routes):
        platform[route] = m
    run = functools.partial(
        _smooth,
        scenario,
        settings,
        stop,
        radius=radius,
        sides=sides,
        snapshots=snapshots,
        callbacks=callbacks,
    )
    tried = []
    for how in (split, *(s for s in SPLITS if s != split)):
        windows = sub_batches(scenario, routes, how, closed=closed)
        try:
            result = run(routes, platform, windows, polyline_start(scenario, routes, windows, how, closed))
        except ScheduleError as err:
            tried.append((how, err))
            continue
        if tried:
            result.extras["restarted"] = (
                f"with the {how!r} split, after the {split!r} split's failed: {tried[0][1]}"
            )
        return result
    first = tried[0][1]
    failures = [f"the {how!r} split's sub-batches failed too ({err})" for how, err in tried[1:]]
    if rescue:
        others = settings.replace(
            constraints=[c for c in settings.constraints if not isinstance(c, VisitAll)]
        )
        try:
            witness = plan_cover(scenario.replace(coverage_radius=radius), others, CoverageOptions())
        except PmhtOptError as err:
            failures.append(f"the coverage planner found no plan to start from ({err})")
        else:
            platform, windows = witness_visits(scenario, witness.positions, radius)
            order = [np.flatnonzero(platform == m) for m in range(scenario.n_platforms)]
            routes = [r[np.argsort(windows[r, 0], kind="stable")] for r in order]
            try:
                result = run(routes, platform, windows, witness.states)
            except ScheduleError as err:
                failures.append(f"the coverage planner's order and visit steps failed too ({err})")
            else:
                result.extras["restarted"] = (
                    f"in the coverage planner's order and visit steps, after the tour's sub-batches failed: "
                    f"{first}"
                )
                return result
    raise ScheduleError(f"{first} {' '.join(failures)}".strip(), backend=first.backend) from first


def _smooth(
    scenario: Scenario,
    settings: Settings,
    stop: StoppingCriterion,
    routes: list[np.ndarray],
    platform: np.ndarray,
    windows: np.ndarray,
    initial: np.ndarray,
    *,
    radius: float | np.ndarray,
    sides: int,
    snapshots: tuple[int, ...],
    callbacks: EMCallbacks | None,
) -> PlanResult:
    """The EM run of one schedule: each locale on its ``platform``, inside its window, from ``initial``."""
    visits = TourVisits(platform, windows, radius, sides=sides)
    limit = iteration_limit(stop) or validation.MAX_ITERATIONS
    run_cfg = PMHTConfig.of(
        settings.replace(constraints=(*settings.constraints, visits)),
        PMHTOptions(update_platform_prior=False, anneal=None, snapshots=snapshots),
        (stop,),
        max_iter=limit,
    )
    time_prior, platform_prior = window_priors(scenario, platform, windows)
    with EMRun(
        scenario,
        run_cfg,
        time_prior=time_prior,
        platform_prior=platform_prior,
        initial_paths=initial,
        callbacks=callbacks,
    ) as run:
        result = run.run()
        ctx = run.last_context
    assert ctx is not None
    result.assignment = platform
    result.planner = "smoothed"
    result.visit_time = visits.visits(ctx)[1]
    result.extras.update({"routes": routes, "sub_batches": windows, "visit_radius": visits.radius})
    return result


@dataclass(frozen=True)
class SmoothedOptions:
    """The options of ``plan(..., method="smoothed")``.

    Parameters
    ----------
    tour
        The visiting order: a :class:`~pmht_opt.ordering.TourResult` or one sequence of locale indices
        per platform; ``None`` (default) orders the locales with ``orderer``.
    orderer
        The ordering when no tour is given: ``"tours"`` (default: the coverage planner's tour engine,
        :mod:`pmht_opt.tours`, through the locales' visit discs) or a method of
        :func:`~pmht_opt.order_locales` (``"pyvrp"``, ``"ortools"``, ``"ga"``), run with the settings'
        seed. Routes are closed where the mission returns to base.
    order_options
        That method's own options (for ``"tours"``: :class:`~pmht_opt.tours.TourSettings`' effort).
    objective
        ``"distance"`` (default: the shortest routes in total) or ``"time"`` (the longest route as
        short as can be: the earliest finish; ``"tours"`` only). With ``"tours"`` each route is
        capped at what its platform can fly in the horizon at its speed limit, whatever the objective
        (:func:`~pmht_opt.planners.routes.tours_within_budgets`).
    visit_radius
        Each locale is passed within this distance, at a step inside its sub-batch; default: the
        scenario's coverage radius.
    split
        How each platform's horizon is cut into sub-batches: ``"equal"`` (the paper) or ``"distance"``
        (proportional to the legs of the tour).
    sides
        Sides of the inner polygon standing in for a visit disc on a backend without cones.
    snapshots
        EM iterations after which to keep a copy of the positions.
    """

    tour: Any = field(default=None, compare=False)
    orderer: str = "tours"
    order_options: dict[str, Any] = field(default_factory=dict)
    objective: str = "distance"
    visit_radius: float | None = None
    split: str = "distance"
    sides: int = DEFAULT_SIDES
    snapshots: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if self.split not in SPLITS:
            raise ConfigError(f"split: expected one of {', '.join(SPLITS)}, got {self.split!r}.")
        if self.visit_radius is not None:
            positive_number("visit_radius", self.visit_radius)
        if not isinstance(self.order_options, dict):
            raise ConfigError(f"order_options: expected a dict of options, got {self.order_options!r}.")
        if self.objective not in ("distance", "time"):
            raise ConfigError(f"objective: expected 'distance' or 'time', got {self.objective!r}.")
        if self.orderer != "tours" and self.objective != "distance":
            raise ConfigError("objective: 'time' needs orderer='tours' (the others minimise the total).")
        validation.integers("snapshots", self.snapshots, ConfigError, 0)


class SmoothedPlanner(Planner):
    """A visiting order flown through every locale's disc (the paper's GA-TSP PMHT smoothed, with the
    order made certain by hard constraints)."""

    name = "smoothed"
    summary = "a visiting order (given, or from an orderer) flown through every locale's disc"
    Options = SmoothedOptions

    def default_stop(self) -> StoppingCriterion:
        return AnyOf((SMOOTHED_CONVERGED, MaxIterations(PMHT_ITERATIONS)))

    def run(
        self,
        scenario: Scenario,
        settings: Settings,
        options: SmoothedOptions,
        stop: StoppingCriterion,
        callback: ProgressObserver | None,
    ) -> PlanResult:
        objective = None
        if options.tour is not None:
            tour = options.tour
        else:
            tour, objective = order_for(scenario, settings, options)
        result = smooth_tour(
            scenario,
            tour,
            settings,
            stop,
            visit_radius=options.visit_radius,
            split=options.split,
            sides=options.sides,
            snapshots=tuple(options.snapshots),
            callbacks=observing(None, callback),
            rescue=options.tour is None,
        )
        if objective is not None:
            result.extras["objective"] = objective
        return result


def order_for(scenario: Scenario, settings: Settings, options: SmoothedOptions) -> tuple[Any, str]:
    """The smoothed planner's visiting order when none is given (:class:`SmoothedOptions`), and the
    objective its routes were chosen by."""
    closed = closed_routes(scenario, settings.constraints)
    if options.orderer != "tours":
        seeded = {"seed": settings.seed} if options.orderer in ("ga", "pyvrp") else {}
        closing = {"closed": True} if closed.all() else {}
        tour = order_locales(scenario, options.orderer, **{**seeded, **closing, **options.order_options})
        return tour, "distance"
    given = options.visit_radius
    radius = scenario.radii if given is None else np.full(scenario.n_locales, float(given))
    problem = DiscProblem(scenario.start_positions, scenario.locales, radius, closed=closed)
    search = TourSettings(seed=settings.seed, objective=options.objective, **options.order_options)
    tours = tours_within_budgets(scenario, settings.constraints, problem, search)
    return [np.asarray(r, dtype=np.intp) for r in tours.routes], options.objective
