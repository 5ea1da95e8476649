"""The one way in: :func:`plan` and the registry of planners it runs.

In the spirit of ``scipy.optimize.minimize(method=...)`` and PyVRP's ``solve(data, stop)``: one verb,
the method by name, one settings object every method shares, one stopping and one callback contract,
and each method's own options as keywords, checked by the method (an option it would ignore is
refused).
"""

from __future__ import annotations

from typing import Any

from pmht_opt import validation
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.planners.base import Planner
from pmht_opt.planners.coverage.method import CoveragePlanner
from pmht_opt.planners.pmht import PMHTPlanner
from pmht_opt.planners.smoothed import SmoothedPlanner
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.settings import Settings
from pmht_opt.stopping import as_criterion, check_callback

#: The planners by name, in the order the documentation presents them.
PLANNERS: dict[str, Planner] = {p.name: p for p in (CoveragePlanner(), SmoothedPlanner(), PMHTPlanner())}


def planner(method: Any) -> Planner:
    """The planner named ``method``; :class:`ConfigError` listing the planners otherwise."""
    found = PLANNERS.get(method) if isinstance(method, str) else None
    if found is None:
        raise ConfigError(f"method: expected one of {', '.join(PLANNERS)}, got {method!r}.")
    return found


def plan(
    scenario: Scenario,
    method: str = "coverage",
    *,
    settings: Settings | None = None,
    stop: Any = None,
    callback: Any = None,
    **options: Any,
) -> PlanResult:
    """Plan paths for ``scenario`` with the planner ``method``.

    Parameters
    ----------
    scenario
        The locales, starts and model (:class:`~pmht_opt.Scenario`).
    method
        ``"coverage"`` (every locale within its sensor radius, shortest smooth paths: what most users
        want), ``"smoothed"`` (a given or computed visiting order flown through every locale's disc)
        or ``"pmht"`` (the paper's EM planner). :data:`PLANNERS` holds them.
    settings
        What every planner shares (:class:`~pmht_opt.Settings`: backend, its settings, threads,
        constraints, seed); default ``Settings()``.
    stop
        When the method's iterations end: a stopping criterion (:mod:`pmht_opt.stopping`, e.g.
        ``MaxIterations(50)``) or a list of them, any of which stops; default: the method's own.
    callback
        ``callback(progress)`` after every iteration of the method, with a
        :class:`~pmht_opt.stopping.Progress` record (the same kind for every method).
    options
        The method's own options (``Planner.Options`` of :data:`PLANNERS`); one it does not take
        raises :class:`ConfigError` naming it.

    Returns
    -------
    PlanResult
        Paths that meet every hard constraint (checked on their positions), with the metrics.
    """
    if not isinstance(scenario, Scenario):
        raise ScenarioError(f"scenario: expected a Scenario, got {type(scenario).__name__}.")
    chosen = planner(method)
    shared = Settings() if settings is None else settings
    if not isinstance(shared, Settings):
        raise ConfigError(f"settings: expected a pmht_opt.Settings, got {type(shared).__name__}.")
    own = chosen.options(options)
    criterion = chosen.default_stop() if stop is None else as_criterion(stop)
    observer = check_callback(callback)
    if observer is not None:
        observer = _guarded(observer)
    return chosen.run(scenario, shared, own, criterion, observer)


def _guarded(callback: Any) -> Any:
    """``callback`` with an exception it raises reported as the user's (not the planner's) error."""

    def call(progress: Any) -> None:
        validation.call_user(callback, progress)

    return call
