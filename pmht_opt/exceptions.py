"""The errors pmht-opt raises. Everything derives from :class:`PmhtOptError`."""

from __future__ import annotations

import solvers.exceptions as _qp


class PmhtOptError(Exception):
    """Base class of every error raised by pmht-opt."""


class ScenarioError(PmhtOptError, ValueError):
    """A scenario (or scenario file) that is malformed; the message names the field."""


class ConfigError(PmhtOptError, ValueError):
    """A planner configuration or parameter that is out of range; the message names the field."""


class UnknownSolverError(ConfigError, _qp.UnknownSolverError):
    """A solver name that is unknown or whose package is not installed; the message lists the others.

    The same error as :class:`solvers.UnknownSolverError` (a subclass of it), raised where the name was
    given to pmht-opt: one ``except`` catches it from either layer."""


class SolverError(PmhtOptError, RuntimeError):
    """A solve that failed, or that the backend did not stand behind (inaccurate, iteration limit).

    Attributes
    ----------
    backend
        The backend's name.
    status
        The backend's own status string.
    """

    def __init__(self, message: str, backend: str = "", status: str = "") -> None:
        super().__init__(message)
        self.backend = backend
        self.status = status


class WrongAnswerError(SolverError):
    """An answer the backend reported as solved that the library's own check refused: not finite, away
    from the exact smoother's, or cheaper than the unconstrained optimum (``status`` is what the
    backend reported)."""


class InfeasibleError(SolverError):
    """Hard constraints that no plan can meet, proven: the message names the constraints and what the
    least relaxation that reconciles them needs. Raised only on a proof (a geometric necessary
    condition, or a feasibility problem over the constraints themselves that needs slack), never
    because a planner's own choice (a visit schedule, a tour, a linearisation) could not be met."""


class ScheduleError(SolverError):
    """A planner's own choice (the steps at which visits are imposed, a tour, the linearisation of an
    obstacle at an iterate) that cannot be met together with the constraints, while the constraints
    themselves were not shown to be infeasible: another choice may meet them. Planners catch it and
    try other schedules; it reaches the caller only when every one failed, saying so."""


class MissingDependencyError(PmhtOptError, ImportError):
    """An optional feature whose package is not installed; the message names the extra to install."""


class PlanWarning(UserWarning):
    """A plan that is returned, but not quite as asked: for example fitted at another penalty than the
    scenario's ``r``, because a criterion other than the iteration limit stopped its run during
    annealing. The result's history holds the details."""
