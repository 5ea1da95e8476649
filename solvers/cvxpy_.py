"""cvxpy backend: the same conic QP written as a cvxpy problem, solved by any installed cvxpy solver.

Settings: ``cvxpy_solver`` (a cvxpy solver name, default ``"CLARABEL"``); every other option is passed
to ``cvxpy.Problem.solve``. The problem is rebuilt when ``P`` or ``A`` change; ``q`` and ``b`` are
cvxpy parameters, so a problem of zero and nonnegative cones is compiled once (DPP). A problem with
second-order cones is compiled at every solve with ``q`` and ``b`` as constants (``ignore_dpp``):
cvxpy's parametrised compilation reorders each cone through a tensor with a column per (variable,
parameter) pair, which on problems of tens of thousands of variables costs minutes and gigabytes.
This backend is for generality and cross-checks, not speed.
"""

from __future__ import annotations

import time
from typing import Any, ClassVar

import cvxpy as cp
import numpy as np
import scipy.sparse as sp

from solvers.exceptions import SettingsError, UnknownSolverError
from solvers.problem import QPProblem, QPSolution, Status
from solvers.session import QPSession

_STATUS = {
    cp.OPTIMAL: Status.OPTIMAL,
    cp.OPTIMAL_INACCURATE: Status.OPTIMAL_INACCURATE,
    cp.INFEASIBLE: Status.PRIMAL_INFEASIBLE,
    cp.INFEASIBLE_INACCURATE: Status.INFEASIBLE_INACCURATE,
    cp.UNBOUNDED: Status.DUAL_INFEASIBLE,
    cp.UNBOUNDED_INACCURATE: Status.DUAL_INFEASIBLE,
    cp.USER_LIMIT: Status.MAX_ITER,
    cp.SOLVER_ERROR: Status.NUMERICAL_ERROR,
}

DEFAULT_SOLVER = "CLARABEL"


def map_status(status: str | None) -> Status:
    """Map a cvxpy status string onto the library's statuses; unknown strings map to ``UNKNOWN``."""
    if status is None:
        return Status.UNKNOWN
    return _STATUS.get(status, Status.UNKNOWN)


def check_solver_name(name: str) -> str:
    """Return ``name`` upper-cased if cvxpy has that solver installed, else raise listing those it has."""
    installed = cp.installed_solvers()
    upper = str(name).upper()
    if upper not in installed:
        raise UnknownSolverError(
            f"cvxpy solver {name!r} is not installed; cvxpy has: {', '.join(sorted(installed))}."
        )
    return upper


def solve_cvxpy_problem(
    problem: cp.Problem, backend: str, solver: str, options: dict[str, Any]
) -> tuple[Status, str, float, int]:
    """Solve a cvxpy problem, mapping failures to statuses instead of exceptions.

    Returns the mapped status, cvxpy's own status string, the wall time and the solver's iteration
    count (0 where the solver does not report one).
    """
    t0 = time.perf_counter()
    try:
        problem.solve(solver=solver, **options)
        raw = str(problem.status)
    except cp.error.SolverError as err:
        raw = f"solver_error: {err}"
        return Status.NUMERICAL_ERROR, raw, time.perf_counter() - t0, 0
    except TypeError as err:
        raise SettingsError(f"{backend}: cvxpy rejected the solver options {options}: {err}") from err
    elapsed = time.perf_counter() - t0
    stats = problem.solver_stats
    iters = int(stats.num_iters) if stats is not None and stats.num_iters is not None else 0
    return map_status(problem.status), raw, elapsed, iters


class CvxpySession(QPSession):
    """The problem in cvxpy form; ``q`` and ``b`` are parameters, ``P`` and ``A`` rebuild it."""

    name: ClassVar[str] = "cvxpy"
    supports_soc: ClassVar[bool] = True

    def _setup(self) -> None:
        opts = dict(self.settings)
        self._solver_name = check_solver_name(opts.pop("cvxpy_solver", DEFAULT_SOLVER))
        if self.problem.has_soc:
            opts.setdefault("ignore_dpp", True)
        self._options = opts
        self._build()

    def _build(self) -> None:
        prob: QPProblem = self.problem
        x = cp.Variable(prob.n)
        self._q = cp.Parameter(prob.n, value=prob.q)
        self._b = cp.Parameter(prob.m, value=prob.b) if prob.m else None
        full = prob.P + sp.triu(prob.P, k=1).T
        objective = 0.5 * cp.quad_form(x, cp.psd_wrap(full)) + self._q @ x
        constraints = []
        for cone, rows in prob.cone_slices():
            assert self._b is not None
            slack = self._b[rows] - prob.A[rows] @ x
            if cone.kind == "zero":
                constraints.append(slack == 0)
            elif cone.kind == "nonneg":
                constraints.append(slack >= 0)
            else:
                constraints.append(cp.SOC(slack[0], slack[1:]))
        self._x = x
        self._problem = cp.Problem(cp.Minimize(objective), constraints)

    def _apply_update(
        self,
        P_data: np.ndarray | None,
        q: np.ndarray | None,
        A_data: np.ndarray | None,
        b: np.ndarray | None,
    ) -> None:
        if P_data is not None or A_data is not None:
            self._build()
            return
        if q is not None:
            self._q.value = q
        if b is not None and self._b is not None:
            self._b.value = b

    def _solve(self) -> QPSolution:
        status, raw, elapsed, iters = solve_cvxpy_problem(
            self._problem, self.name, self._solver_name, self._options
        )
        value = self._x.value
        x = None if value is None or not np.all(np.isfinite(value)) else np.array(value)
        if x is None and status is Status.OPTIMAL:
            status = Status.NUMERICAL_ERROR
        return QPSolution(
            status=status,
            backend=f"{self.name}/{self._solver_name}",
            raw_status=raw,
            x=x,
            objective=float(self._problem.value) if x is not None else float("nan"),
            iterations=iters,
            solve_time=elapsed,
        )
