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
import warnings
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import cvxpy as cp
import numpy as np
import scipy.sparse as sp

from solvers.exceptions import SettingsError, UnknownSolverError
from solvers.problem import Cone, QPProblem, QPSolution, Status
from solvers.session import QPSession, Update

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


def cone_constraints(slack: Any, cones: Sequence[Cone]) -> list[Any]:
    """``slack`` (a cvxpy vector expression ``b - A x``) in ``cones``, as cvxpy constraints.

    The one translation of this library's cones into cvxpy. Consecutive second-order cones of one
    dimension become a single vectorised ``cvxpy.SOC`` (one column per cone), which cvxpy compiles far
    faster than one constraint object per cone.
    """
    out: list[Any] = []
    start = 0
    i = 0
    while i < len(cones):
        cone = cones[i]
        if cone.kind != "soc":
            part = slack[start : start + cone.dim]
            out.append(part == 0 if cone.kind == "zero" else part >= 0)
            start += cone.dim
            i += 1
            continue
        run = 1
        while i + run < len(cones) and cones[i + run].kind == "soc" and cones[i + run].dim == cone.dim:
            run += 1
        d = cone.dim
        part = slack[start : start + run * d]
        head = part[0::d]
        tail = cp.vstack([part[c::d] for c in range(1, d)])
        out.append(cp.SOC(head, tail, axis=0))
        start += run * d
        i += run
    return out


def _interrupted(problem: cp.Problem, solver: str) -> bool:
    """Whether ``solver`` stopped on an interrupt it caught itself (SIGINT during OSQP's iterations).

    cvxpy reports that only as a solver error; the raw OSQP result, which cvxpy keeps in the
    problem's solver cache, says whether it was an interrupt.
    """
    if solver.upper() != "OSQP":
        return False
    import osqp

    cache = getattr(problem, "_solver_cache", None)
    entry = cache.get("OSQP") if isinstance(cache, dict) else None
    info = getattr(entry[-1], "info", None) if isinstance(entry, tuple) and entry else None
    return getattr(info, "status_val", None) == osqp.SolverStatus.OSQP_SIGINT


def solve_to_solution(
    problem: cp.Problem,
    read_x: Callable[[], np.ndarray | None],
    backend: str,
    solver: str,
    options: dict[str, Any],
) -> QPSolution:
    """Solve ``problem`` and build the library's solution from it; failures become statuses.

    ``read_x`` returns the primal vector from the problem's variables after the solve (``None`` if
    cvxpy left them unset). A vector with a non-finite entry is no solution; an "optimal" status
    without a usable vector becomes a numerical error.
    """
    t0 = time.perf_counter()
    iterations = 0
    x: np.ndarray | None = None
    try:
        with warnings.catch_warnings():
            # cvxpy warns of inaccurate answers; the status says so, and is judged by the caller.
            warnings.simplefilter("ignore", UserWarning)
            problem.solve(solver=solver, **options)
    except cp.error.SolverError as err:
        if _interrupted(problem, solver):
            raw, status = "interrupted", Status.INTERRUPTED
        else:
            raw, status = f"solver_error: {err}", Status.NUMERICAL_ERROR
    except TypeError as err:
        raise SettingsError(f"{backend}: cvxpy rejected the solver options {options}: {err}") from err
    else:
        raw, status = str(problem.status), map_status(problem.status)
        stats = problem.solver_stats
        if stats is not None and stats.num_iters is not None:
            iterations = int(stats.num_iters)
        x = read_x()
    elapsed = time.perf_counter() - t0
    if x is not None:
        x = np.asarray(x, dtype=float)
        if not np.all(np.isfinite(x)):
            x = None
    if x is None and status is Status.OPTIMAL:
        status = Status.NUMERICAL_ERROR
    value = problem.value if x is not None else None
    return QPSolution(
        status=status,
        backend=backend,
        raw_status=raw,
        x=x,
        objective=float(value) if value is not None else float("nan"),
        iterations=iterations,
        solve_time=elapsed,
    )


#: ``extra(x) -> (constraints, cost)``: native cvxpy constraints and cost terms on the variable ``x``.
ExtraTerms = Callable[[Any], tuple[list[Any], Any]]


class CvxpySession(QPSession):
    """The problem in cvxpy form, compiled once where cvxpy's parametrised (DPP) form allows.

    ``q`` and ``b`` are parameters. A diagonal ``P`` enters as ``1/2 sum(p_i x_i^2)`` through the
    parameter ``sqrt(p)``, so its updates need no recompilation either; any other ``P``, and every
    change of ``A``, rebuilds the problem. Problems with second-order cones are solved with
    ``ignore_dpp``: cvxpy's parametrised compilation of many cones costs minutes and gigabytes, a plain
    one a fraction of a second.

    ``settings`` may hold ``cvxpy_solver`` (default ``"CLARABEL"``) and ``extra``, a callable
    ``extra(x) -> (constraints, cost)`` adding native cvxpy constraints and cost terms on the
    variable vector ``x`` (re-applied at every rebuild); the rest goes to ``cvxpy.Problem.solve``.
    """

    name: ClassVar[str] = "cvxpy"
    supports_soc: ClassVar[bool] = True

    def _setup(self) -> None:
        opts = dict(self.settings)
        self._solver_name = check_solver_name(opts.pop("cvxpy_solver", DEFAULT_SOLVER))
        extra = opts.pop("extra", None)
        if extra is not None and not callable(extra):
            raise SettingsError(f"cvxpy: extra must be a callable x -> (constraints, cost), got {extra!r}.")
        self._extra: ExtraTerms | None = extra
        if self.problem.has_soc or extra is not None:
            # Cones (ours, or any the extra terms bring) compile far faster without parameters.
            opts.setdefault("ignore_dpp", True)
        self._options = opts
        #: Whether the next solve hands its data to a new inner solver (:meth:`rescale`).
        self._fresh_inner = False
        self._build()

    def rescale(self) -> None:
        """Hand the next solve's data to a new inner solver, which scales it afresh.

        cvxpy keeps the inner solver of the last solve and updates it with the new data (its warm
        start), so that solver keeps the scaling of its setup. The compiled problem does not depend on
        the numbers, and compiling it again would only cost time.
        """
        self._fresh_inner = True

    def _build(self) -> None:
        prob: QPProblem = self.problem
        x = cp.Variable(prob.n)
        self._q = cp.Parameter(prob.n, value=prob.q)
        self._b = cp.Parameter(prob.m, value=prob.b) if prob.m else None
        coo = prob.P.tocoo()
        self._diag: np.ndarray | None = None
        if np.all(coo.row == coo.col):
            # Diagonal P: its stored entries (a subset of the diagonal) become one parameter.
            self._diag = coo.row
            self._sqrt_p = cp.Parameter(coo.row.size, nonneg=True, value=np.sqrt(np.maximum(coo.data, 0.0)))
            quad = 0.5 * cp.sum_squares(cp.multiply(self._sqrt_p, x[coo.row])) if coo.row.size else 0.0
        else:
            full = prob.P + sp.triu(prob.P, k=1).T
            quad = 0.5 * cp.quad_form(x, cp.psd_wrap(full))
        constraints = cone_constraints(self._b - prob.A @ x, prob.cones) if self._b is not None else []
        cost: Any = quad + self._q @ x
        if self._extra is not None:
            more, extra_cost = self._extra(x)
            constraints += list(more)
            cost = cost + extra_cost
        self._x = x
        self._problem = cp.Problem(cp.Minimize(cost), constraints)

    def _apply_update(self, update: Update) -> None:
        if update.A_data is not None or (update.P_data is not None and self._diag is None):
            self._build()
            return
        if update.P_data is not None:
            self._sqrt_p.value = np.sqrt(np.maximum(self.problem.P.tocoo().data, 0.0))
        if update.q is not None:
            self._q.value = update.q
        if update.b is not None and self._b is not None:
            self._b.value = update.b

    def _solve(self) -> QPSolution:
        options = {**self._options, "warm_start": False} if self._fresh_inner else self._options
        self._fresh_inner = False
        return solve_to_solution(
            self._problem,
            lambda: self._x.value,
            f"{self.name}/{self._solver_name}",
            self._solver_name,
            options,
        )
