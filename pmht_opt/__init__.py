"""pmht-opt: multi-platform path planning with the PMHT, its M-step posed as a sparse convex QP.

Public names are re-exported here; see README.md for an overview.
"""

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
from pmht_opt.planner import PMHTConfig, plan_pmht
from pmht_opt.result import IterationHistory, PlanResult
from pmht_opt.scenario import Scenario, paper_scenario

__version__ = "0.1.0"

__all__ = [
    "ConfigError",
    "InfeasibleError",
    "IterationHistory",
    "MissingDependencyError",
    "MotionModel",
    "PMHTConfig",
    "PlanResult",
    "PmhtOptError",
    "Scenario",
    "ScenarioError",
    "SolverError",
    "UnknownSolverError",
    "__version__",
    "available_backends",
    "paper_scenario",
    "plan_pmht",
]
