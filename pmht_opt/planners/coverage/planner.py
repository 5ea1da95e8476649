"""``plan_coverage``: the coverage planner with its settings in one :class:`~pmht_opt.PMHTConfig`."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from pmht_opt.constraints.params import positive_number
from pmht_opt.exceptions import ConfigError
from pmht_opt.geometry import missed_locales as missed_by
from pmht_opt.ordering.tour import check_min_tour
from pmht_opt.planners.base import refuse_ignored
from pmht_opt.planners.coverage.method import DEFAULT_SMOOTHING, CoverageOptions, plan_cover
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.settings import PMHTConfig
from pmht_opt.stopping import Progress, StoppingCriterion

#: The EM settings of a PMHTConfig that the coverage planner does not use: its paths come from the
#: tours' motion, smoothed ``iterations`` times.
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
#: Options of an earlier tour search that no longer exists: refused rather than ignored.
RETIRED = ("orderer", "starts", "rounds", "beam", "keep", "shrink", "time_budget")


def missed_locales(scenario: Scenario, positions: np.ndarray, radius: float | np.ndarray) -> np.ndarray:
    """Locales further than ``radius`` (one, or one per locale; up to the metric's relative slack)
    from every path ``positions (M, T+1, 2)``, measured on the segments between consecutive
    positions."""
    return missed_by(scenario.locales, positions, radius)


def plan_coverage(
    scenario: Scenario,
    radius: float | np.ndarray | None = None,
    config: PMHTConfig | None = None,
    *,
    seed: int = 0,
    objective: str = "distance",
    smoothing: float = DEFAULT_SMOOTHING,
    iterations: int | None = None,
    callback: Callable[[Progress], Any] | None = None,
    stop: StoppingCriterion | None = None,
    **retired: Any,
) -> PlanResult:
    """The shortest smooth plan found in which every locale is within its radius of some path.

    The same plan as ``plan(scenario, "coverage", settings=config.settings + seed, radius=...,
    ...)`` (:func:`pmht_opt.plan`; the method is described in
    :mod:`pmht_opt.planners.coverage.method`), kept for code written against this form. ``config``
    gives the backend, its settings, threads and the user's constraints; its EM settings do not apply
    and are refused if set. The options of the earlier tour search (``orderer``, ``starts``,
    ``rounds``, ``beam``, ``keep``, ``shrink``, ``time_budget``) are refused, naming them.

    Raises
    ------
    ConfigError
        A bad argument, naming it.
    InfeasibleError
        The discs cannot be met together with the user's constraints.
    SolverError
        The plan failed its checks, or a backend failed.
    """
    for name in retired:
        if name in RETIRED:
            raise ConfigError(
                f"{name}: an option of the earlier tour search, which the tour engine replaced; leave it "
                "out (effort: search={...}, TourSettings' options)."
            )
        raise ConfigError(f"{name}: not an option of plan_coverage.")
    if not isinstance(scenario, Scenario):
        raise ConfigError(f"scenario: expected a Scenario, got {type(scenario).__name__}.")
    check_min_tour(scenario, 1)
    cfg = PMHTConfig() if config is None else config
    if not isinstance(cfg, PMHTConfig):
        raise ConfigError(f"config: expected a PMHTConfig, got {type(cfg).__name__}.")
    refuse_ignored(cfg, IGNORED, "plan_coverage")
    if radius is not None and np.ndim(radius) == 0:
        radius = positive_number("radius", radius)
    options = CoverageOptions(radius=radius, objective=objective, smoothing=smoothing, iterations=iterations)
    return plan_cover(scenario, cfg.settings.replace(seed=seed), options, stop, callback)
