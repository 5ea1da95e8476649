"""``plan_coverage``: the shortest smooth plan found that passes every locale within a sensor radius."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.constraints.params import positive_number
from pmht_opt.constraints.visits import VisitAll
from pmht_opt.exceptions import ConfigError, SolverError
from pmht_opt.geometry import missed_locales as missed_by
from pmht_opt.ordering.pyvrp_ import SEED_MAX
from pmht_opt.ordering.tour import check_min_tour
from pmht_opt.planners.base import refuse_ignored
from pmht_opt.planners.coverage.search import Candidate, resolve_orderer, search, variants
from pmht_opt.planners.coverage.tracking import track_routes
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.settings import PMHTConfig
from pmht_opt.stopping import Progress, StoppingCriterion
from pmht_opt.validation import MAX_ITERATIONS

#: Fraction of the coverage radius at which the visit polylines touch the discs: the rest is room for
#: the smoother to round the polylines' corners without leaving a disc.
DEFAULT_SHRINK = 0.8
#: The EM settings of a PMHTConfig that plan_coverage does not use: its paths come from fixed
#: synthetic measurements, smoothed ``iterations`` times.
IGNORED = (
    "max_iter",
    "tol",
    "update_time_prior",
    "update_platform_prior",
    "anneal",
    "estep_gate",
    "snapshots",
    "stop",
)
#: Iterations of the final smoothing: each re-chooses the visit steps on the last iterate.
ITERATIONS = 3
#: The same when a user constraint is re-linearised at each iterate (obstacles).
DYNAMIC_ITERATIONS = 10


@dataclass(frozen=True)
class CoverageProgress:
    """What :func:`plan_coverage` has just done, for a progress callback.

    ``stage`` is ``"search"`` (before each ordering of the tour search; ``length`` is the shortest
    visit polyline so far, ``candidate`` is -1) or ``"smooth"`` (candidate ``candidate`` has been
    flown; ``length`` is its path length); ``best`` is the shortest smoothed plan so far (``inf``
    before any).
    """

    stage: str
    candidate: int
    length: float
    best: float
    elapsed: float


#: Most tours (``starts``), rounds, beam and kept candidates a run may ask for: each is a full
#: ordering or smoothing, seconds apiece.
SEARCH_MAX = 10_000


def _count(name: str, value: Any, minimum: int, maximum: int | None = SEARCH_MAX) -> int:
    return validation.integer(name, value, ConfigError, minimum, maximum)


@dataclass(frozen=True)
class _Settings:
    radius: float
    config: PMHTConfig
    seed: int
    orderer: str
    starts: int
    rounds: int
    beam: int
    keep: int
    shrink: float
    iterations: int
    time_budget: float | None


def _settings(scenario: Any, radius: Any, config: Any, opts: dict[str, Any]) -> _Settings:
    check_min_tour(scenario, 1)  # a Scenario with a locale for every platform's tour
    if radius is None:
        rho = positive_number("scenario.coverage_radius", scenario.coverage_radius)
    else:
        rho = positive_number("radius", radius)
    cfg = PMHTConfig() if config is None else config
    if not isinstance(cfg, PMHTConfig):
        raise ConfigError(f"config: expected a PMHTConfig, got {type(cfg).__name__}.")
    refuse_ignored(cfg, IGNORED, "plan_coverage")
    visits = [c.name for c in cfg.constraints if isinstance(c, VisitAll)]
    if visits:
        raise ConfigError(
            f"config.constraints: {', '.join(visits)} places visits on the locales, which plan_coverage "
            "already guarantees at its radius; leave it out and pass radius= instead."
        )
    shrink = positive_number("shrink", opts["shrink"])
    if shrink > 1.0:
        raise ConfigError(f"shrink: expected a number in (0, 1], got {opts['shrink']!r}.")
    iterations = opts["iterations"]
    if iterations is None:
        dynamic = any(c.dynamic for c in cfg.constraints)
        iterations = DYNAMIC_ITERATIONS if dynamic else ITERATIONS
    budget = opts["time_budget"]
    if opts["callback"] is not None and not callable(opts["callback"]):
        raise ConfigError(f"callback: expected a callable, got {type(opts['callback']).__name__}.")
    starts = _count("starts", opts["starts"], 1)
    orderer = resolve_orderer(opts["orderer"])
    # The tours use seeds seed .. seed + starts - 1; PyVRP takes seeds up to SEED_MAX.
    top = SEED_MAX - (starts - 1) if orderer == "pyvrp" else None
    return _Settings(
        radius=rho,
        config=cfg,
        seed=_count("seed", opts["seed"], 0, top),
        orderer=orderer,
        starts=starts,
        rounds=_count("rounds", opts["rounds"], 0),
        beam=_count("beam", opts["beam"], 1),
        keep=_count("keep", opts["keep"], 1),
        shrink=shrink,
        iterations=_count("iterations", iterations, 1, MAX_ITERATIONS),
        time_budget=None if budget is None else positive_number("time_budget", budget),
    )


def missed_locales(scenario: Scenario, positions: np.ndarray, radius: float) -> np.ndarray:
    """Locales further than ``radius`` (up to the metric's relative slack) from every path
    ``positions (M, T+1, 2)``, measured on the segments between consecutive positions."""
    return missed_by(scenario.locales, positions, radius)


def _check(result: PlanResult, radius: float) -> None:
    """Raise :class:`SolverError` unless every locale is covered on the segments between positions.

    The hard constraints (the user's and the visit discs) were verified on the positions when the run
    returned its plan (:func:`pmht_opt.verify.verify_plan`, the tolerance every planner uses); coverage
    is measured here, independently of the visit steps the discs were imposed at.
    """
    missed = missed_locales(result.scenario, result.positions, radius)
    if missed.size:
        raise SolverError(
            f"plan_coverage: locales {missed.tolist()} are further than {radius:g} from every path.",
            backend=result.solver,
        )


def plan_coverage(
    scenario: Scenario,
    radius: float | None = None,
    config: PMHTConfig | None = None,
    *,
    seed: int = 0,
    orderer: str = "auto",
    starts: int = 3,
    rounds: int = 4,
    beam: int = 1,
    keep: int = 2,
    shrink: float = DEFAULT_SHRINK,
    iterations: int | None = None,
    time_budget: float | None = None,
    callback: Callable[[CoverageProgress], None] | None = None,
    stop: StoppingCriterion | None = None,
) -> PlanResult:
    """The shortest smooth plan found in which every locale is within ``radius`` of some path.

    The method, in three stages (docs in :mod:`pmht_opt.planners.coverage`):

    1. *Tours.* ``starts`` orderings of the locales (the open multiple TSP of docs/model.md section 9)
       by ``orderer``; for each, the shortest polyline from the platforms' starts through the locales'
       discs in that order, at ``shrink * radius`` (:mod:`~pmht_opt.planners.coverage.discs`), gives a visit
       point per locale.
    2. *Rounds.* The visit points of the ``beam`` best tours are ordered again as if they were the
       locales, with every variant of the orderer, up to ``rounds`` times, while the polyline through
       the discs gets shorter (:mod:`~pmht_opt.planners.coverage.search`): the order adapts to discs
       instead of centres, and one pass serves locales whose discs overlap.
    3. *Paths.* The ``keep`` tours with the shortest polylines are flown: the model's smoother follows
       each polyline at constant speed, with every locale's disc (``radius``) a hard constraint at the
       step its visit point is reached, and with the user's constraints from ``config``
       (:mod:`~pmht_opt.planners.coverage.tracking`). The shortest plan is returned.

    Every flown plan is checked on its positions: every locale within ``radius`` of a path (measured
    on the segments between positions, independently of the visit steps the plan was built with) and
    every hard constraint holding; a plan that fails the check is never returned.

    Parameters
    ----------
    scenario
        The locales, starts and model.
    radius
        Sensor footprint; default the scenario's :attr:`~pmht_opt.Scenario.coverage_radius`.
    config
        Backend, its settings and threads, and the user's constraints (speed limits, obstacles, area
        bounds, terminal conditions, ...). Its EM settings (iterations, priors, annealing) do not apply:
        the paths come from a fixed set of synthetic measurements.
    seed
        Seed of the orderings (PyVRP and the GA; OR-Tools' greedy descent needs none). The same seed
        gives the same plan.
    orderer
        ``"auto"`` (the first installed of PyVRP, OR-Tools, the GA), or a method of
        :func:`~pmht_opt.order_locales`.
    starts
        Variants of the orderer (seeds; for OR-Tools, construction heuristics, at most 6), each used
        on the locales and in every round.
    rounds
        Rounds of re-ordering at most.
    beam
        Tours whose visit points are ordered again in each round.
    keep
        Candidates, shortest polylines first, that are smoothed.
    shrink
        Fraction of ``radius`` at which the polylines touch the discs, in ``(0, 1]``.
    iterations
        Iterations of the final smoothing, each of which moves every locale's visit step to where the
        last iterate passes closest; default 3, or 10 with a constraint that is re-linearised at each
        iterate (obstacles).
    time_budget
        Seconds after which no new candidate or round is started (at least one candidate is always
        smoothed). A wall-clock limit makes the result depend on the machine: for interactive use only.
    callback
        Called with a :class:`CoverageProgress` after each stage.
    stop
        A stopping criterion asked before each ordering of the tour search but the first, with a
        :class:`~pmht_opt.stopping.Progress` whose scores are the shortest polyline so far.

    Returns
    -------
    PlanResult
        The paths; ``assignment`` is each locale's platform, ``visit_time`` the step at which its disc
        is met; ``extras`` holds ``routes``, ``visit_points``, ``polyline_length``, ``orderer``,
        ``candidates`` (each tour's label and polyline length) and ``radius``.

    Raises
    ------
    ConfigError
        A bad argument, naming it.
    InfeasibleError
        The discs cannot be met together with the user's constraints by any candidate flown.
    SolverError
        No candidate flown gave a plan that passes the check (or a backend failed on every one).
    """
    s = _settings(
        scenario,
        radius,
        config,
        {
            "seed": seed,
            "orderer": orderer,
            "starts": starts,
            "rounds": rounds,
            "beam": beam,
            "keep": keep,
            "shrink": shrink,
            "iterations": iterations,
            "time_budget": time_budget,
            "callback": callback,
        },
    )
    t0 = time.perf_counter()
    best = float("inf")

    def report(stage: str, index: int, length: float) -> None:
        if callback is not None:
            callback(CoverageProgress(stage, index, length, best, time.perf_counter() - t0))

    lengths: list[float] = []

    def in_time() -> bool:
        if stop is not None and lengths:
            progress = Progress(len(lengths), list(lengths), time.perf_counter() - t0, True, "search")
            if stop(progress):
                return False
        return s.time_budget is None or time.perf_counter() - t0 < s.time_budget

    def searched(stage: str, index: int, length: float) -> None:
        if stage == "search":
            lengths.append(length)
        report(stage, index, length)

    candidates = _candidates(scenario, s, searched, in_time)
    result: PlanResult | None = None
    error: SolverError | None = None
    for index, cand in sorted(enumerate(candidates), key=lambda ic: ic[1].length)[: s.keep]:
        if result is not None and not in_time():
            break
        try:
            plan = track_routes(scenario, cand.routes, cand.points, s.radius, s.config, s.iterations)
            _check(plan, s.radius)
        except SolverError as err:  # infeasible with the user's constraints, or not standing the check
            error = err
            continue
        length = plan.total_distance
        report("smooth", index, length)
        if length < best:
            best, result = length, plan
            result.extras["polyline_length"] = cand.length
    if result is None:
        assert error is not None
        raise error
    result.extras.update(
        {
            "orderer": s.orderer,
            "radius": s.radius,
            "candidates": [(c.label, c.length) for c in candidates],
        }
    )
    result.wall_time = time.perf_counter() - t0
    result.planner = "coverage"
    return result


def _candidates(
    scenario: Scenario,
    s: _Settings,
    report: Callable[[str, int, float], None],
    in_time: Callable[[], bool],
) -> list[Candidate]:
    """Stages 1 and 2: the candidate tours and their re-ordering rounds."""

    def keep_going(best: Candidate) -> bool:
        report("search", -1, best.length)
        return in_time()

    out = search(
        scenario,
        s.orderer,
        variants(s.orderer, s.starts),
        s.seed,
        s.shrink * s.radius,
        s.rounds,
        s.beam,
        keep_going,
    )
    if not out:
        raise SolverError(f"plan_coverage: the orderer {s.orderer!r} found no tour.", backend=s.orderer)
    return out
