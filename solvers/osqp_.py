"""OSQP backend (ADMM; equalities and inequalities only, no second-order cones).

Zero-cone rows become ``l = u = b``, non-negative-cone rows ``-inf <= A x <= b``. OSQP's
solution polishing is on by default: on problems whose active set ADMM has found (always the case with
equalities only) it returns the solution of the reduced KKT system, accurate far beyond ``eps_abs``.
Retrying a failed solve with other settings is a policy of the caller (:mod:`solvers.retry`).
"""

from __future__ import annotations

import time
from typing import Any, ClassVar

import numpy as np
import osqp

from solvers.exceptions import ProblemError, SettingsError, UnsupportedProblemError, UpdateError
from solvers.problem import QPSolution, Status
from solvers.session import QPSession, Update

DEFAULTS: dict[str, Any] = {
    "verbose": False,
    "eps_abs": 1e-7,
    "eps_rel": 1e-7,
    "eps_prim_inf": 1e-9,
    "eps_dual_inf": 1e-9,
    "max_iter": 50_000,
    "polishing": True,
    "polish_refine_iter": 10,
    "warm_starting": True,
}

_STATUS = {
    osqp.SolverStatus.OSQP_SOLVED: Status.OPTIMAL,
    osqp.SolverStatus.OSQP_SOLVED_INACCURATE: Status.OPTIMAL_INACCURATE,
    osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE: Status.PRIMAL_INFEASIBLE,
    osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE_INACCURATE: Status.INFEASIBLE_INACCURATE,
    osqp.SolverStatus.OSQP_DUAL_INFEASIBLE: Status.DUAL_INFEASIBLE,
    osqp.SolverStatus.OSQP_DUAL_INFEASIBLE_INACCURATE: Status.DUAL_INFEASIBLE,
    osqp.SolverStatus.OSQP_MAX_ITER_REACHED: Status.MAX_ITER,
    osqp.SolverStatus.OSQP_TIME_LIMIT_REACHED: Status.TIME_LIMIT,
    osqp.SolverStatus.OSQP_NON_CVX: Status.NUMERICAL_ERROR,
    osqp.SolverStatus.OSQP_SIGINT: Status.INTERRUPTED,
    osqp.SolverStatus.OSQP_UNSOLVED: Status.UNKNOWN,
}


def _error_name(err: Exception) -> str:
    """OSQP's name of the error code an ``OSQPException`` carries."""
    code = err.args[0] if err.args else None
    try:
        return osqp.SolverError(code).name
    except ValueError:
        return f"error {code!r}"


def _setup_error(err: Exception) -> Exception:
    """The layer's error for an ``OSQPException`` at setup: its settings or its data were refused.

    OSQP's C code also prints its own line on stderr naming the offending setting or bound.
    """
    name = _error_name(err)
    if err.args and err.args[0] == osqp.SolverError.OSQP_SETTINGS_VALIDATION_ERROR:
        return SettingsError(f"OSQP rejected its settings ({name}).")
    return ProblemError(f"OSQP refused the problem ({name}).")


class OSQPSession(QPSession):
    """A problem held by one ``osqp.OSQP`` workspace; updates reuse its factorisation structure."""

    name: ClassVar[str] = "osqp"
    supports_soc: ClassVar[bool] = False

    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        prob = self.problem
        lower = np.full(prob.m, -np.inf)
        upper = prob.b.copy()
        for cone, rows in prob.cone_slices():
            if cone.kind == "zero":
                lower[rows] = prob.b[rows]
        return lower, upper

    def _setup(self) -> None:
        if self.problem.has_soc:
            raise UnsupportedProblemError(
                "OSQP cannot handle second-order cones; use clarabel or cvxpy, or a polygonal "
                "approximation of the cone."
            )
        opts = {**DEFAULTS, **self.settings}
        self._solver = osqp.OSQP()
        lower, upper = self._bounds()
        prob = self.problem
        try:
            self._solver.setup(prob.P, prob.q, prob.A, lower, upper, **opts)
        except (TypeError, ValueError) as err:
            raise SettingsError(f"OSQP rejected its settings: {err}") from err
        except osqp.OSQPException as err:
            raise _setup_error(err) from err

    def _apply_update(self, update: Update) -> None:
        kwargs: dict[str, Any] = {}
        if update.q is not None:
            kwargs["q"] = update.q
        if update.b is not None:
            kwargs["l"], kwargs["u"] = self._bounds()
        if update.P_data is not None:
            kwargs["Px"] = update.P_data
        if update.A_data is not None:
            kwargs["Ax"] = update.A_data
        if kwargs:
            try:
                self._solver.update(**kwargs)
            except osqp.OSQPException as err:
                raise UpdateError(f"OSQP rejected the update: {_error_name(err)}.") from err

    def _solve(self) -> QPSolution:
        t0 = time.perf_counter()
        res = self._solver.solve(raise_error=False)
        elapsed = time.perf_counter() - t0
        info = res.info
        status = _STATUS.get(osqp.SolverStatus(info.status_val), Status.UNKNOWN)
        x = None if res.x is None or not np.all(np.isfinite(res.x)) else np.array(res.x)
        if x is None and status is Status.OPTIMAL:
            status = Status.NUMERICAL_ERROR
        return QPSolution(
            status=status,
            backend=self.name,
            raw_status=str(info.status),
            x=x,
            y=None if res.y is None else np.array(res.y),
            objective=float(info.obj_val),
            iterations=int(info.iter),
            solve_time=elapsed,
            info={
                "polish_status": int(info.status_polish),
                "prim_res": float(info.prim_res),
                "dual_res": float(info.dual_res),
                "rho_updates": int(info.rho_updates),
            },
        )
