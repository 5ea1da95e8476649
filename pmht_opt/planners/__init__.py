"""The planners behind :func:`pmht_opt.plan`, one small object each (:mod:`.base`), by name in
:data:`PLANNERS` (:mod:`.registry`): ``"coverage"``, ``"smoothed"`` and ``"pmht"``."""

from pmht_opt.planners.base import Planner
from pmht_opt.planners.coverage.method import CoverageOptions, CoveragePlanner
from pmht_opt.planners.pmht import PMHTPlanner, PMHTPlanOptions, plan_pmht
from pmht_opt.planners.registry import PLANNERS, plan, planner
from pmht_opt.planners.smoothed import SmoothedOptions, SmoothedPlanner, plan_smoothed

__all__ = [
    "PLANNERS",
    "CoverageOptions",
    "CoveragePlanner",
    "PMHTPlanOptions",
    "PMHTPlanner",
    "Planner",
    "SmoothedOptions",
    "SmoothedPlanner",
    "plan",
    "plan_pmht",
    "plan_smoothed",
    "planner",
]
