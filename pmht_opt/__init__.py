"""pmht-opt: multi-platform path planning with the PMHT, its M-step posed as a sparse convex QP.

The one way in is :func:`plan` (``plan(scenario, method="coverage" | "smoothed" | "pmht", ...)``) and,
for visiting orders alone, :func:`order_locales`. Public names are re-exported here; see README.md for
an overview.

The generic QP layer is the top-level package ``solvers`` (and the studies ``studies``), installed by
this distribution beside ``pmht_opt``. Those names are generic: another project's package of the same
name installed in the same environment would shadow them, so the marker each carries is checked here
and a clash is named rather than left to fail somewhere deep (docs/decisions.md, "Package names").
"""

import solvers as _solvers

if getattr(_solvers, "__distribution__", None) != "pmht-opt":
    raise ImportError(
        f"the package 'solvers' found at {getattr(_solvers, '__file__', '?')} is not pmht-opt's generic QP "
        "layer: another installed project uses the same top-level name. Install pmht-opt into a virtual "
        "environment of its own."
    )

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
from pmht_opt.em import EMCallbacks, EMRun, IterationRecord
from pmht_opt.estep import EStepSummary
from pmht_opt.exceptions import (
    ConfigError,
    InfeasibleError,
    MissingDependencyError,
    PlanWarning,
    PmhtOptError,
    ScenarioError,
    ScheduleError,
    SolverError,
    UnknownSolverError,
    WrongAnswerError,
)
from pmht_opt.model import MotionModel
from pmht_opt.mstep import available_backends, solve_mstep
from pmht_opt.ordering import TourResult, order_locales, solve_ga_tsp, solve_ortools, tour_distance
from pmht_opt.planners import PLANNERS, plan, plan_pmht, plan_smoothed
from pmht_opt.planners.coverage import plan_coverage
from pmht_opt.result import IterationHistory, PlanResult
from pmht_opt.scenario import Scenario, paper_scenario
from pmht_opt.schedule import Schedule
from pmht_opt.settings import PMHTConfig, PMHTOptions, Settings
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
    "PLANNERS",
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
    "PMHTOptions",
    "PlanResult",
    "PlanWarning",
    "PmhtOptError",
    "PolygonObstacle",
    "Progress",
    "Scenario",
    "ScenarioError",
    "Schedule",
    "ScheduleError",
    "Settings",
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
    "plan",
    "plan_coverage",
    "plan_pmht",
    "plan_smoothed",
    "solve_ga_tsp",
    "solve_mstep",
    "solve_ortools",
    "tour_distance",
]
