"""Clarabel backend (interior point; zero, non-negative and second-order cones).

Presolve is off by default: Clarabel refuses in-place data updates when presolve has removed rows, and
the sessions of this layer are built to be updated.
"""

from __future__ import annotations

import time
from typing import Any, ClassVar

import clarabel
import numpy as np

from solvers.exceptions import ProblemError, SettingsError
from solvers.problem import Cone, QPSolution, Status
from solvers.session import QPSession, Update

DEFAULTS: dict[str, Any] = {
    "verbose": False,
    "presolve_enable": False,
    "tol_gap_abs": 1e-9,
    "tol_gap_rel": 1e-9,
    "tol_feas": 1e-9,
    "max_iter": 200,
}

_STATUS = {
    "Solved": Status.OPTIMAL,
    "AlmostSolved": Status.OPTIMAL_INACCURATE,
    "PrimalInfeasible": Status.PRIMAL_INFEASIBLE,
    "AlmostPrimalInfeasible": Status.INFEASIBLE_INACCURATE,
    "DualInfeasible": Status.DUAL_INFEASIBLE,
    "AlmostDualInfeasible": Status.DUAL_INFEASIBLE,
    "MaxIterations": Status.MAX_ITER,
    "MaxTime": Status.TIME_LIMIT,
    "NumericalError": Status.NUMERICAL_ERROR,
    "InsufficientProgress": Status.NUMERICAL_ERROR,
    "CallbackTerminated": Status.INTERRUPTED,
    "Unsolved": Status.UNKNOWN,
}


def _cone(cone: Cone) -> Any:
    if cone.kind == "zero":
        return clarabel.ZeroConeT(cone.dim)
    if cone.kind == "nonneg":
        return clarabel.NonnegativeConeT(cone.dim)
    return clarabel.SecondOrderConeT(cone.dim)


def _settings(options: dict[str, Any]) -> Any:
    settings = clarabel.DefaultSettings()
    for key, value in options.items():
        if not hasattr(settings, key):
            raise SettingsError(f"Clarabel has no setting {key!r}.")
        try:
            setattr(settings, key, value)
        except (TypeError, ValueError, OverflowError) as err:
            raise SettingsError(f"Clarabel rejected {key}={value!r}: {err}") from err
    return settings


class ClarabelSession(QPSession):
    """A problem held by one ``clarabel.DefaultSolver``; updates keep its symbolic factorisation."""

    name: ClassVar[str] = "clarabel"
    supports_soc: ClassVar[bool] = True

    def _setup(self) -> None:
        prob = self.problem
        settings = _settings({**DEFAULTS, **self.settings})
        cones = [_cone(c) for c in prob.cones]
        try:
            self._solver = clarabel.DefaultSolver(prob.P, prob.q, prob.A, prob.b, cones, settings)
        except Exception as err:  # Clarabel raises a plain Exception for what it refuses at setup
            if "settings" in str(err).lower():
                raise SettingsError(f"Clarabel rejected its settings: {err}") from err
            raise ProblemError(f"Clarabel refused the problem: {err}") from err

    def _apply_update(self, update: Update) -> None:
        names = {"P": update.P_data, "q": update.q, "A": update.A_data, "b": update.b}
        kwargs = {key: value for key, value in names.items() if value is not None}
        if kwargs:
            self._solver.update(**kwargs)

    def _solve(self) -> QPSolution:
        t0 = time.perf_counter()
        sol = self._solver.solve()
        elapsed = time.perf_counter() - t0
        raw = str(sol.status)
        status = _STATUS.get(raw, Status.UNKNOWN)
        x: np.ndarray | None = np.array(sol.x)
        if x is None or x.size != self.problem.n or not np.all(np.isfinite(x)):
            x = None
            if status is Status.OPTIMAL:
                status = Status.NUMERICAL_ERROR
        return QPSolution(
            status=status,
            backend=self.name,
            raw_status=raw,
            x=x,
            y=np.array(sol.z),
            objective=float(sol.obj_val),
            iterations=int(sol.iterations),
            solve_time=elapsed,
            info={"r_prim": float(sol.r_prim), "r_dual": float(sol.r_dual)},
        )
