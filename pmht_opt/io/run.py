"""Running a mission: its planner, with its settings and constraints, exactly as the library would.

:data:`PLANNERS` maps each planner's name to one function ``(mission, config, callback) ->
PlanResult``; the command line runs missions through :func:`plan_mission`, so a mission planned from
a file is the plan :func:`~pmht_opt.plan_pmht` (or :func:`~pmht_opt.plan_smoothed`, or
``plan_coverage``) gives for the same scenario, constraints and settings.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

from pmht_opt.exceptions import ConfigError
from pmht_opt.io.mission import Mission, check_mission
from pmht_opt.ordering import TourResult
from pmht_opt.planner import PMHTConfig, ProgressCallback, plan_pmht
from pmht_opt.result import PlanResult
from pmht_opt.smoothed import plan_smoothed


def _orderer(method: str) -> Callable[..., TourResult]:
    from pmht_opt.ordering import METHODS

    solve = METHODS.get(method)
    if solve is None:
        raise ConfigError(
            f"ordering method {method!r} is not in this installation of pmht-opt; it has "
            f"{', '.join(sorted(METHODS))}."
        )
    return solve


def order_mission(mission: Mission) -> TourResult:
    """Order the mission's locales with its ordering method and options
    (:func:`~pmht_opt.order_locales`); closed routes when the mission returns to base.

    Raises
    ------
    ConfigError
        A method this installation lacks, an option it does not take, or a return to base with a
        method that cannot close its routes; an option's value it refuses (named by the option).
    """
    from pmht_opt.ordering import order_locales

    s = check_mission(mission).planner
    options = s.ordering_options
    if s.return_to_base:
        if "closed" not in inspect.signature(_orderer(s.method)).parameters:
            raise ConfigError(
                f"return_to_base: the {s.method!r} ordering of this installation cannot close its routes "
                "(it has no 'closed' option)."
            )
        options = {**options, "closed": True}
    else:
        _orderer(s.method)
    return order_locales(mission.scenario, method=s.method, **options)


def _pmht(mission: Mission, config: PMHTConfig, callback: ProgressCallback | None) -> PlanResult:
    result: PlanResult = plan_pmht(mission.scenario, config, callback=callback)
    return result


def _smoothed(mission: Mission, config: PMHTConfig, callback: ProgressCallback | None) -> PlanResult:
    s = mission.planner
    tour = order_mission(mission)
    return plan_smoothed(mission.scenario, tour, config, s.visit_radius, split=s.split, callback=callback)


def _coverage(mission: Mission, config: PMHTConfig, callback: ProgressCallback | None) -> PlanResult:
    """``plan_coverage`` on the mission; ``callback(step, best)`` after each of its stages (``best``:
    the shortest verified plan so far, ``inf`` before any)."""
    from pmht_opt.coverage import CoverageProgress, plan_coverage

    radius = (
        mission.planner.radius if mission.planner.radius is not None else mission.scenario.coverage_radius
    )
    steps = [0]

    def stage(progress: CoverageProgress) -> None:
        steps[0] += 1
        assert callback is not None
        callback(steps[0], progress.best)

    return plan_coverage(mission.scenario, radius, config, callback=None if callback is None else stage)


#: Planner functions by name: ``(mission, config, callback) -> PlanResult``.
PLANNERS: dict[str, Callable[[Mission, PMHTConfig, ProgressCallback | None], PlanResult]] = {
    "pmht": _pmht,
    "smoothed": _smoothed,
    "coverage": _coverage,
}


def plan_mission(
    mission: Mission, callback: ProgressCallback | None = None, snapshots: tuple[int, ...] = ()
) -> PlanResult:
    """Plan ``mission`` with its planner, settings and constraints (plus a return to base when its
    settings ask for one).

    Parameters
    ----------
    mission
        The mission (:func:`~pmht_opt.io.load_mission`).
    callback
        ``callback(iteration, objective)`` after every EM iteration.
    snapshots
        EM iterations after which to keep the positions (``PMHTConfig.snapshots``).
    """
    config = check_mission(mission).planner.config(mission.constraints_for_plan(), snapshots)
    return PLANNERS[mission.planner.kind](mission, config, callback)
