"""A generic conic-QP layer: problem and solution types, one module per backend, a registry.

Nothing here knows about path planning. Backends are imported on first use, never at import time::

    from solvers import QPProblem, Zero, open_session
    session = open_session(problem, "clarabel")
    solution = session.solve()
    if not solution.ok: ...

============  ========  =======================
name          package   cones
============  ========  =======================
``osqp``      osqp      zero, non-negative
``clarabel``  clarabel  zero, non-negative, SOC
``cvxpy``     cvxpy     zero, non-negative, SOC
============  ========  =======================
"""

from __future__ import annotations

import importlib
import importlib.util
from dataclasses import dataclass
from typing import Any

#: The distribution this package is installed by. The top-level name ``solvers`` is generic, so
#: ``pmht_opt`` checks this marker on import and says so if another project's ``solvers`` shadows it.
__distribution__ = "pmht-opt"

from solvers.exceptions import (
    ProblemError,
    QPError,
    SettingsError,
    UnknownSolverError,
    UnsupportedProblemError,
    UpdateError,
)
from solvers.problem import (
    INFEASIBLE,
    SOC,
    SOLUTION_INACCURATE,
    SOLUTION_PRESENT,
    Cone,
    Nonneg,
    QPProblem,
    QPSolution,
    Status,
    Zero,
    cone_violation,
)
from solvers.retry import NO_RETRY, RetryChain, retry_failed
from solvers.session import QPSession, Update, WorkBudget, work_amount


@dataclass(frozen=True)
class BackendSpec:
    """Where a backend lives, what it needs installed and which cones it accepts."""

    name: str
    module: str
    cls: str
    package: str
    install_hint: str
    cones: frozenset[str] = frozenset({"zero", "nonneg", "soc"})

    @property
    def installed(self) -> bool:
        """Whether the backend's package can be imported (checked now, not at import)."""
        return importlib.util.find_spec(self.package) is not None


BACKENDS: dict[str, BackendSpec] = {
    "osqp": BackendSpec(
        "osqp",
        "solvers.osqp_",
        "OSQPSession",
        "osqp",
        "pip install 'osqp>=1.1'",
        frozenset({"zero", "nonneg"}),
    ),
    "clarabel": BackendSpec(
        "clarabel", "solvers.clarabel_", "ClarabelSession", "clarabel", "pip install clarabel"
    ),
    "cvxpy": BackendSpec("cvxpy", "solvers.cvxpy_", "CvxpySession", "cvxpy", "pip install cvxpy"),
}


def available_solvers() -> list[str]:
    """Names of the backends whose package is installed (checked now, not at import)."""
    return [name for name, spec in BACKENDS.items() if spec.installed]


def unknown_solver_message(name: object, available: list[str], what: str = "solver") -> str:
    """The one wording of "no such solver": what was asked for and what is available."""
    return f"unknown {what} {name!r}; available: {', '.join(available) or 'none'}."


def missing_package_message(spec: BackendSpec, available: list[str], what: str = "solver") -> str:
    """The one wording of "known, but its package is not installed"."""
    return (
        f"{what} {spec.name!r} needs the package {spec.package!r}, which is not installed "
        f"({spec.install_hint}); available: {', '.join(available) or 'none'}."
    )


def get_session_class(name: str) -> type[QPSession]:
    """The session class of backend ``name``.

    Raises
    ------
    UnknownSolverError
        If ``name`` is not a known backend or its package is not installed; the message lists the
        backends that are available and how to install the missing one.
    """
    spec = BACKENDS.get(str(name).lower())
    if spec is None:
        raise UnknownSolverError(unknown_solver_message(name, available_solvers(), "QP solver"))
    if not spec.installed:
        raise UnknownSolverError(missing_package_message(spec, available_solvers(), "QP solver"))
    module = importlib.import_module(spec.module)
    cls: type[QPSession] = getattr(module, spec.cls)
    return cls


def open_session(problem: QPProblem, solver: str, **settings: Any) -> QPSession:
    """Hand ``problem`` to backend ``solver``, ready to be updated in place and solved repeatedly."""
    if not isinstance(problem, QPProblem):
        raise ProblemError(f"problem: expected a QPProblem, got {type(problem).__name__}.")
    return get_session_class(solver)(problem, **settings)


def solve_qp(problem: QPProblem, solver: str, **settings: Any) -> QPSolution:
    """Solve ``problem`` once with backend ``solver``; check ``.ok`` on the result."""
    return open_session(problem, solver, **settings).solve()


__all__ = [
    "BACKENDS",
    "INFEASIBLE",
    "NO_RETRY",
    "SOC",
    "SOLUTION_INACCURATE",
    "SOLUTION_PRESENT",
    "BackendSpec",
    "Cone",
    "Nonneg",
    "ProblemError",
    "QPError",
    "QPProblem",
    "QPSession",
    "QPSolution",
    "RetryChain",
    "SettingsError",
    "Status",
    "UnknownSolverError",
    "UnsupportedProblemError",
    "Update",
    "UpdateError",
    "WorkBudget",
    "Zero",
    "available_solvers",
    "cone_violation",
    "get_session_class",
    "missing_package_message",
    "open_session",
    "retry_failed",
    "solve_qp",
    "unknown_solver_message",
    "work_amount",
]
