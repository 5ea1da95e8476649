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
    StayNear,
    Terminal,
    VisitAll,
)
from pmht_opt.coverage import plan_coverage
from pmht_opt.em import EMCallbacks, EMRun, IterationRecord
from pmht_opt.estep import EStepSummary
from pmht_opt.exceptions import (
    ConfigError,
    InfeasibleError,
    MissingDependencyError,
    PmhtOptError,
    ScenarioError,
    SolverError,
    UnknownSolverError,
    WrongAnswerError,
)
from pmht_opt.model import MotionModel
from pmht_opt.mstep import available_backends, solve_mstep
from pmht_opt.ordering import TourResult, order_locales, solve_ga_tsp, solve_ortools, tour_distance
from pmht_opt.planner import PMHTConfig, plan_pmht
from pmht_opt.result import IterationHistory, PlanResult
from pmht_opt.scenario import Scenario, paper_scenario
from pmht_opt.schedule import Schedule
from pmht_opt.smoothed import plan_smoothed
from pmht_opt.stopping import (
    AnyOf,
    Converged,
    EMProgress,
    MaxIterations,
    NoImprovement,
    ObjectiveTolerance,
    Progress,
    StoppingCriterion,
    TimeBudget,
)

__version__ = "0.1.0"

__all__ = [
    "AccelLimit",
    "Anneal",
    "AnyOf",
    "AreaBounds",
    "CircleObstacle",
    "ConfigError",
    "Constraint",
    "ConstraintReport",
    "Converged",
    "CvxpyConstraint",
    "EMCallbacks",
    "EMProgress",
    "EMRun",
    "EStepSummary",
    "InfeasibleError",
    "IterationHistory",
    "IterationRecord",
    "MaxIterations",
    "MissingDependencyError",
    "MotionModel",
    "NoImprovement",
    "ObjectiveTolerance",
    "PMHTConfig",
    "PlanResult",
    "PmhtOptError",
    "PolygonObstacle",
    "Progress",
    "Scenario",
    "ScenarioError",
    "Schedule",
    "SolverError",
    "SpeedLimit",
    "StayNear",
    "StoppingCriterion",
    "Terminal",
    "TimeBudget",
    "TourResult",
    "UnknownSolverError",
    "VisitAll",
    "WrongAnswerError",
    "__version__",
    "available_backends",
    "order_locales",
    "paper_scenario",
    "plan_coverage",
    "plan_pmht",
    "plan_smoothed",
    "solve_ga_tsp",
    "solve_mstep",
    "solve_ortools",
    "tour_distance",
]
