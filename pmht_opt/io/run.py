"""Running a mission: its planner, with its settings and constraints, exactly as the library would.

:func:`plan_mission` is :func:`pmht_opt.plan` with the mission's scenario, its ``[planner]`` settings
and options and its constraints (plus a return to base when it asks for one), so a mission planned
from a file is the plan the library gives for the same inputs.
"""

from __future__ import annotations

from typing import Any

from pmht_opt.io.mission import Mission, check_mission
from pmht_opt.ordering import TourResult, order_locales
from pmht_opt.planners import plan
from pmht_opt.result import PlanResult
from pmht_opt.stopping import ProgressObserver


def order_mission(mission: Mission) -> TourResult:
    """Order the mission's locales with its ordering method and options (the smoothed planner's
    ``orderer`` and ``order_options``, :func:`~pmht_opt.order_locales`), its shared seed, and closed
    routes when the mission returns to base.

    Raises
    ------
    ConfigError
        A method this installation lacks, or an option it does not take (named).
    """
    s = check_mission(mission).planner
    method = s.options.get("orderer", "pyvrp")
    if method == "tours":  # the smoothed planner's own: the `order` command uses PyVRP's instead
        method = "pyvrp"
    options: dict[str, Any] = dict(s.options.get("order_options", {}))
    if method in ("ga", "pyvrp") and "seed" in s.shared:
        options.setdefault("seed", s.shared["seed"])
    if s.return_to_base:
        options = {**options, "closed": True}
    return order_locales(mission.scenario, method, **options)


def plan_mission(
    mission: Mission, callback: ProgressObserver | None = None, snapshots: tuple[int, ...] = ()
) -> PlanResult:
    """Plan ``mission`` with its planner, settings, options and constraints.

    Parameters
    ----------
    mission
        The mission (:func:`~pmht_opt.io.load_mission`).
    callback
        ``callback(progress)`` after every iteration (:class:`~pmht_opt.stopping.Progress`).
    snapshots
        Iterations after which to keep the positions (planners with EM iterations only).
    """
    s = check_mission(mission).planner
    options = s.planner_options()
    if snapshots:
        options["snapshots"] = tuple(snapshots)
    return plan(
        mission.scenario,
        s.method,
        settings=s.settings(mission.constraints_for_plan()),
        stop=s.stop(),
        callback=callback,
        **options,
    )
