"""A generic conic-QP layer: problem and solution types, one module per backend, a registry.

Nothing here knows about path planning. Backends are imported on first use, never at import time::

    from solvers import QPProblem, Zero, open_session
    session = open_session(problem, "clarabel")
    solution = session.solve()
    if not solution.ok: ...

| name       | package  | cones                       |
|------------|----------|-----------------------------|
| ``osqp``     | osqp     | zero, non-negative          |
| ``clarabel`` | clarabel | zero, non-negative, SOC     |
| ``cvxpy``    | cvxpy    | zero, non-negative, SOC     |
"""

from __future__ import annotations

import importlib
import importlib.util
from dataclasses import dataclass
from typing import Any

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
)
from solvers.session import QPSession


@dataclass(frozen=True)
class BackendSpec:
    """Where a backend lives and what it needs installed."""

    name: str
    module: str
    cls: str
    package: str
    install_hint: str


BACKENDS: dict[str, BackendSpec] = {
    "osqp": BackendSpec("osqp", "solvers.osqp_", "OSQPSession", "osqp", "pip install 'osqp>=1.1'"),
    "clarabel": BackendSpec(
        "clarabel", "solvers.clarabel_", "ClarabelSession", "clarabel", "pip install clarabel"
    ),
    "cvxpy": BackendSpec("cvxpy", "solvers.cvxpy_", "CvxpySession", "cvxpy", "pip install cvxpy"),
}


def available_solvers() -> list[str]:
    """Names of the backends whose package is installed (checked now, not at import)."""
    return [name for name, spec in BACKENDS.items() if importlib.util.find_spec(spec.package)]


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
        raise UnknownSolverError(
            f"Unknown QP solver {name!r}; available: {', '.join(available_solvers()) or 'none'}."
        )
    if importlib.util.find_spec(spec.package) is None:
        raise UnknownSolverError(
            f"QP solver {spec.name!r} needs the package {spec.package!r}, which is not installed "
            f"({spec.install_hint}); available: {', '.join(available_solvers()) or 'none'}."
        )
    module = importlib.import_module(spec.module)
    cls: type[QPSession] = getattr(module, spec.cls)
    return cls


def open_session(problem: QPProblem, solver: str, **settings: Any) -> QPSession:
    """Hand ``problem`` to backend ``solver``, ready to be updated in place and solved repeatedly."""
    return get_session_class(solver)(problem, **settings)


def solve_qp(problem: QPProblem, solver: str, **settings: Any) -> QPSolution:
    """Solve ``problem`` once with backend ``solver``; check ``.ok`` on the result."""
    return open_session(problem, solver, **settings).solve()


__all__ = [
    "BACKENDS",
    "INFEASIBLE",
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
    "SettingsError",
    "Status",
    "UnknownSolverError",
    "UnsupportedProblemError",
    "UpdateError",
    "Zero",
    "available_solvers",
    "get_session_class",
    "open_session",
    "solve_qp",
]
