"""The PMHT planner of the paper: EM decides which platform visits which locale and when.

:class:`PMHTPlanner` is ``plan(scenario, method="pmht", ...)``; :func:`plan_pmht` is the same run with
its settings in one :class:`~pmht_opt.settings.PMHTConfig`, kept for code written against it. Both
run the loop of :class:`~pmht_opt.em.EMRun` to its end (:func:`run_em`).
"""

from __future__ import annotations

import copy
import dataclasses
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.constraints.visits import VisitAll
from pmht_opt.em import EMCallbacks, EMRun
from pmht_opt.exceptions import PlanWarning, PmhtOptError, ScheduleError
from pmht_opt.planners.base import Planner
from pmht_opt.planners.coverage.method import CoverageOptions, plan_cover
from pmht_opt.planners.progress import observing, with_progress
from pmht_opt.planners.smoothed import SmoothedOptions, SmoothedPlanner
from pmht_opt.planners.windows import window_priors, witness_visits
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.settings import (
    PMHT_ITERATIONS,
    PMHT_OPTION_FIELDS,
    PMHTConfig,
    PMHTOptions,
    ProgressCallback,
    Settings,
)
from pmht_opt.stopping import MaxIterations, ProgressObserver, StoppingCriterion, iteration_limit


@dataclass(frozen=True)
class PMHTPlanOptions(PMHTOptions):
    """The options of ``plan(..., method="pmht")``: :class:`~pmht_opt.settings.PMHTOptions`, and where
    the EM starts.

    Parameters
    ----------
    time_prior, platform_prior
        Initial ``pi^tau (N, T)`` and ``pi^k (N, M)``; uniform when ``None``. Rows are normalised.
    initial_paths
        ``(M, T+1, 6)`` paths the EM starts from (``t = 0`` must be the scenario's start states);
        default: every platform standing still at its start.
    """

    time_prior: Any = field(default=None, compare=False)
    platform_prior: Any = field(default=None, compare=False)
    initial_paths: Any = field(default=None, compare=False)


class PMHTPlanner(Planner):
    """The paper's planner (docs/model.md section 4): the assignment and the visit times come out of EM.

    It stops after 100 iterations by default (the paper's); a stopping criterion with a smaller
    iteration limit (:class:`~pmht_opt.stopping.MaxIterations`) compresses the annealing schedule to fit
    (:meth:`~pmht_opt.Anneal.fit`), so the plan is fitted at the scenario's ``r``.
    """

    name = "pmht"
    summary = "the paper's EM planner: assignment and timing by EM (partial coverage unless VisitAll)"
    Options = PMHTPlanOptions

    def default_stop(self) -> StoppingCriterion:
        return MaxIterations(PMHT_ITERATIONS)

    def run(
        self,
        scenario: Scenario,
        settings: Settings,
        options: PMHTPlanOptions,
        stop: StoppingCriterion,
        callback: ProgressObserver | None,
    ) -> PlanResult:
        em_options = PMHTOptions(**{f: getattr(options, f) for f in PMHT_OPTION_FIELDS})
        limit = iteration_limit(stop) or validation.MAX_ITERATIONS
        config = PMHTConfig.of(settings, em_options, (stop,), max_iter=limit)
        return run_em(
            scenario,
            config,
            time_prior=options.time_prior,
            platform_prior=options.platform_prior,
            initial_paths=options.initial_paths,
            callbacks=observing(None, callback),
        )


def run_em(
    scenario: Scenario,
    config: PMHTConfig,
    *,
    time_prior: Any = None,
    platform_prior: Any = None,
    initial_paths: Any = None,
    callbacks: EMCallbacks | None = None,
    planner: str = "pmht",
) -> PlanResult:
    """Run the EM of ``config`` on ``scenario`` to its end and return its plan (made by ``planner``).

    A plan fitted at another ``r`` than the scenario's (a criterion other than the iteration limit
    stopped the run during annealing) is returned with a :class:`~pmht_opt.exceptions.PlanWarning`; its
    history says at which ``r`` (:attr:`~pmht_opt.IterationHistory.fitted_r`).

    When an iteration's schedule cannot be met (:class:`~pmht_opt.exceptions.ScheduleError`: the visit
    steps or obstacle sides the EM chose, not the constraints themselves), the EM starts again from
    plans that meet the constraints (:func:`restart_paths`), without annealing and with its visits kept
    where that plan makes them (:func:`_restarted`; a prior given here is replaced there). The plan
    says so in ``extras["restarted"]``. Only if every restart fails does the error reach the caller,
    saying what was tried.
    """

    def once(paths: Any, cfg: PMHTConfig, times: Any, platforms: Any) -> PlanResult:
        with EMRun(
            scenario,
            cfg,
            time_prior=times,
            platform_prior=platforms,
            initial_paths=paths,
            callbacks=callbacks,
        ) as run:
            return run.run()

    try:
        result = once(initial_paths, config, time_prior, platform_prior)
    except ScheduleError as err:
        result = _restarted(scenario, config, err, once)
    result.planner = planner
    fitted = result.history.fitted_r
    if not np.isclose(fitted, scenario.r, rtol=1e-12, atol=0.0):
        warnings.warn(
            PlanWarning(
                f"the plan was fitted at r = {fitted:.4g}, not the scenario's r = {scenario.r:g}: "
                f"{result.history.stop_reason} stopped the run during annealing."
            ),
            stacklevel=3,
        )
    return result


def restart_paths(scenario: Scenario, settings: Settings) -> Iterator[tuple[str, PlanResult | PmhtOptError]]:
    """Plans that meet ``settings``' constraints, for the EM to start again from: the coverage
    planner's, then the smoothed planner's, each as ``(name, plan)`` or ``(name, the error it raised)``.

    Both pass every locale within the radius the constraints' visits ask for
    (:class:`~pmht_opt.constraints.VisitAll`; the scenario's coverage radius without one) and meet
    every other hard constraint, checked on their positions like any plan. Made lazily: the second only
    if the first did not serve.
    """
    visits = [c for c in settings.constraints if isinstance(c, VisitAll)]
    others = tuple(c for c in settings.constraints if not isinstance(c, VisitAll))
    covered = scenario.replace(coverage_radius=_radii(scenario, visits))
    shared = dataclasses.replace(settings, constraints=others)
    witnesses: tuple[tuple[str, Callable[[], PlanResult]], ...] = (
        ("coverage", lambda: plan_cover(covered, shared, CoverageOptions())),
        ("smoothed", lambda: _smoothed(covered, shared)),
    )
    for name, make in witnesses:
        try:
            yield name, make()
        except PmhtOptError as err:  # no witness from this planner: its reason is reported
            yield name, err


def _smoothed(scenario: Scenario, settings: Settings) -> PlanResult:
    planner = SmoothedPlanner()
    return planner.run(scenario, settings, SmoothedOptions(), planner.default_stop(), None)


def _restarted(
    scenario: Scenario,
    config: PMHTConfig,
    first: ScheduleError,
    once: Callable[[Any, PMHTConfig, Any, Any], PlanResult],
) -> PlanResult:
    """The EM run again from each of :func:`restart_paths` until one meets its schedules; else a
    :class:`ScheduleError` saying what was tried.

    With hard visits (:class:`~pmht_opt.constraints.VisitAll`) the restart also keeps each locale's
    visit where the witness plan makes it (:func:`~pmht_opt.planners.windows.witness_visits`): on the
    platform that passes it and at the steps where that platform is inside its disc, imposed from the
    first iteration. Any
    schedule the EM then chooses is one the witness meets as a whole, so the M-steps have a feasible
    point; only obstacles, linearised at the iterate, can still fail.
    """
    visits = [c for c in config.constraints if isinstance(c, VisitAll) and not c.soft]
    constraints = [_at_once(c) if c in visits else c for c in config.constraints]
    plain = dataclasses.replace(config, anneal=None, constraints=constraints)
    tried = []
    for name, witness in restart_paths(scenario, config.settings):
        if isinstance(witness, PmhtOptError):
            tried.append(f"the {name} planner found no plan to start from ({witness})")
            continue
        priors: tuple[Any, Any] = (None, None)
        if visits:
            kept = witness_visits(scenario, witness.positions, _radii(scenario, visits))
            priors = window_priors(scenario, *kept)
        try:
            result = once(witness.states, plain, *priors)
        except ScheduleError as err:
            tried.append(
                f"from the {name} planner's plan, which meets them, the schedule failed again ({err})"
            )
            continue
        result.extras["restarted"] = (
            f"from the {name} planner's plan, without annealing"
            + (", visits kept where that plan makes them" if visits else "")
            + f", after the first run's schedule failed: {first}"
        )
        return result
    raise ScheduleError(
        f"{first} The EM was started again: {'; '.join(tried)}.", backend=first.backend
    ) from first


def _radii(scenario: Scenario, visits: Sequence[VisitAll]) -> np.ndarray:
    """``(N,)`` the smallest radius any of ``visits`` asks of each locale (the scenario's without one)."""
    radii = np.asarray(scenario.radii, dtype=float)
    for v in visits:
        radii = np.minimum(radii, v.radius_for(scenario))
    return radii


def _at_once(visit: VisitAll) -> VisitAll:
    """``visit`` imposed whole from the first iteration (a restart begins on paths that meet it)."""
    whole = copy.copy(visit)
    whole.warmup, whole.ramp = 0, 0
    return whole


def plan_pmht(
    scenario: Any,
    config: PMHTConfig | None = None,
    *,
    time_prior: np.ndarray | None = None,
    platform_prior: np.ndarray | None = None,
    callback: ProgressCallback | None = None,
    initial_paths: np.ndarray | None = None,
    callbacks: EMCallbacks | None = None,
) -> PlanResult:
    """Plan paths for ``scenario`` with the PMHT planner, its settings in one ``config``.

    The same plan as ``plan(scenario, "pmht", settings=config.settings, stop=..., **options)``
    (:func:`pmht_opt.plan`), kept for code written against this form.

    Parameters
    ----------
    scenario
        The locales, starts and model (a :class:`~pmht_opt.Scenario`).
    config
        Planner settings; defaults to :class:`~pmht_opt.PMHTConfig`'s.
    time_prior, platform_prior
        Initial ``pi^tau (N, T)`` and ``pi^k (N, M)``; uniform when ``None``. Rows are normalised.
    callback
        Called as ``callback(iteration, objective)`` after every iteration (e.g. a progress bar).
    callbacks
        Observers of every E-step, M-step and iteration (:class:`~pmht_opt.em.EMCallbacks`); with
        ``callback`` too, both are called.
    initial_paths
        ``(M, T+1, 6)`` paths the EM starts from (``t = 0`` must be the scenario's start states);
        default: every platform standing still at its start.

    Returns
    -------
    PlanResult
        Paths, final assignment, per-iteration history, the final E-step and metrics.
    """
    return run_em(
        scenario,
        config if config is not None else PMHTConfig(),
        time_prior=time_prior,
        platform_prior=platform_prior,
        initial_paths=initial_paths,
        callbacks=with_progress(callbacks, callback),
    )
