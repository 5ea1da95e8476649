"""The PMHT planner of the paper: EM decides which platform visits which locale and when.

:class:`PMHTPlanner` is ``plan(scenario, method="pmht", ...)``; :func:`plan_pmht` is the same run with
its settings in one :class:`~pmht_opt.settings.PMHTConfig`, kept for code written against it. Both
run the loop of :class:`~pmht_opt.em.EMRun` to its end (:func:`run_em`).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.em import EMCallbacks, EMRun, IterationRecord
from pmht_opt.exceptions import ConfigError, PlanWarning
from pmht_opt.planners.base import Planner
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


def observing(callbacks: EMCallbacks | None, callback: ProgressObserver | None) -> EMCallbacks | None:
    """``callbacks`` with ``callback(progress)`` also called after every iteration, with the
    :class:`~pmht_opt.stopping.EMProgress` the stopping criteria see."""
    if callback is None:
        return callbacks

    def report(run: EMRun, record: IterationRecord) -> None:
        assert run.progress is not None  # formed before the iteration's observers are called
        callback(run.progress)

    return _also_after(callbacks, report)


def with_progress(callbacks: EMCallbacks | None, callback: ProgressCallback | None) -> EMCallbacks | None:
    """``callbacks`` with ``callback(iteration, objective)`` also called after every iteration (the
    callback of :func:`plan_pmht` and :func:`~pmht_opt.plan_smoothed`)."""
    if callback is None:
        return callbacks
    if not callable(callback):
        raise ConfigError(f"callback: expected a callable(iteration, objective), got {callback!r}.")
    return _also_after(callbacks, lambda run, record: callback(record.iteration, record.objective))


def _also_after(callbacks: EMCallbacks | None, fn: Callable[[EMRun, IterationRecord], object]) -> EMCallbacks:
    """``callbacks`` with ``fn(run, record)`` called after every iteration, after their own."""
    base = callbacks if callbacks is not None else EMCallbacks()
    inner = base.after_iteration

    def after(run: EMRun, record: IterationRecord) -> None:
        if inner is not None:
            inner(run, record)
        fn(run, record)

    return EMCallbacks(base.after_estep, base.after_mstep, after)


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
    """
    with EMRun(
        scenario,
        config,
        time_prior=time_prior,
        platform_prior=platform_prior,
        initial_paths=initial_paths,
        callbacks=callbacks,
    ) as run:
        result = run.run()
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
