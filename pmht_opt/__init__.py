"""pmht-opt: multi-platform path planning with the PMHT, its M-step posed as a sparse convex QP.

Public names are re-exported here; see README.md for an overview.
"""

from pmht_opt.anneal import Anneal
from pmht_opt.constraints import (
    AccelLimit,
    AreaBounds,
    CircleObstacle,
    Constraint,
    ConstraintReport,
    CvxpyConstraint,
    PolygonObstacle,
    SpeedLimit,
    Terminal,
    VisitAll,
)
from pmht_opt.exceptions import (
    ConfigError,
    InfeasibleError,
    MissingDependencyError,
    PmhtOptError,
    ScenarioError,
    SolverError,
    UnknownSolverError,
)
from pmht_opt.model import MotionModel
from pmht_opt.mstep import available_backends
from pmht_opt.ordering import TourResult, order_locales, solve_ga_tsp, solve_ortools, tour_distance
from pmht_opt.planner import PMHTConfig, plan_pmht
from pmht_opt.result import IterationHistory, PlanResult
from pmht_opt.scenario import Scenario, paper_scenario
from pmht_opt.smoothed import plan_smoothed

__version__ = "0.1.0"

__all__ = [
    "AccelLimit",
    "Anneal",
    "AreaBounds",
    "CircleObstacle",
    "ConfigError",
    "Constraint",
    "ConstraintReport",
    "CvxpyConstraint",
    "InfeasibleError",
    "IterationHistory",
    "MissingDependencyError",
    "MotionModel",
    "PMHTConfig",
    "PlanResult",
    "PmhtOptError",
    "PolygonObstacle",
    "Scenario",
    "ScenarioError",
    "SolverError",
    "SpeedLimit",
    "Terminal",
    "TourResult",
    "UnknownSolverError",
    "VisitAll",
    "__version__",
    "available_backends",
    "order_locales",
    "paper_scenario",
    "plan_pmht",
    "plan_smoothed",
    "solve_ga_tsp",
    "solve_ortools",
    "tour_distance",
]
