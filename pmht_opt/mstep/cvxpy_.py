"""The M-step written in cvxpy, for any installed cvxpy solver and for native cvxpy constraints."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.constraints.base import Constraint
from pmht_opt.constraints.user import CvxpyConstraint, CvxpyVariables
from pmht_opt.exceptions import InfeasibleError, UnknownSolverError
from pmht_opt.model import PX, PY, STATE_DIM
from pmht_opt.mstep.base import MStep, MStepData, MStepOutput
from pmht_opt.mstep.qp import check_solution
from pmht_opt.mstep.rows import PlatformRows, RowBuilder, assemble, soften_cvxpy
from pmht_opt.mstep.tuning import CVXPY_CLARABEL_RETRIES
from pmht_opt.scenario import Scenario


class CvxpyMStep(MStep):
    """The M-step written in cvxpy; any installed cvxpy solver can be chosen.

    ``settings`` may hold ``cvxpy_solver`` (default ``"CLARABEL"``); the rest goes to
    ``cvxpy.Problem.solve``. The variables are exposed as :attr:`states` (one ``(T, 6)`` cvxpy variable
    per platform, rows ``t = 1..T``) and :attr:`noise`.

    Without constraints the weights are parameters and the problem is compiled once (DPP). With
    constraints it is compiled again at every solve, the weights and the iteration's constraint rows
    entering as constants (``ignore_dpp``): cvxpy's parametrised compilation reorders every
    second-order cone through a tensor with one column per (variable, parameter) pair, which costs
    minutes and gigabytes at the paper's sizes, where a plain compilation takes a fraction of a
    second. Constraint blocks are assembled into rows exactly as for the QP backends
    (:func:`~pmht_opt.mstep.rows.assemble`, one soft rule) and translated into cvxpy by
    :func:`solvers.cvxpy_.cone_constraints`. :class:`~pmht_opt.constraints.CvxpyConstraint` s are built
    once with the variables.
    """

    name: ClassVar[str] = "cvxpy"

    def __init__(
        self,
        scenario: Scenario,
        settings: dict[str, Any] | None = None,
        accept_inaccurate: bool = False,
        constraints: tuple[Constraint, ...] = (),
    ) -> None:
        super().__init__(scenario, settings, accept_inaccurate, constraints)
        import cvxpy as cp

        from solvers.cvxpy_ import DEFAULT_SOLVER, check_solver_name

        opts = dict(self.settings)
        try:
            self.cvxpy_solver = check_solver_name(str(opts.pop("cvxpy_solver", DEFAULT_SOLVER)))
        except solvers.UnknownSolverError as err:
            raise UnknownSolverError(str(err)) from err
        #: Whether the problem is compiled once with the weights as parameters (no constraints).
        self.dpp = not self.constraints
        if not self.dpp:
            opts.setdefault("ignore_dpp", True)
        self.options = opts
        self.retries = solvers.RetryChain()
        if self.cvxpy_solver == "CLARABEL" and self.dpp:
            self.retries = CVXPY_CLARABEL_RETRIES.without(opts)
        self.rows = RowBuilder(self.constraints, conic=True)
        M, T = self.M, self.T
        F, L = self.model.F, self.model.L
        self.states = [cp.Variable((T, STATE_DIM), name=f"x{m}") for m in range(M)]
        self.noise = [cp.Variable((T, STATE_DIM), name=f"u{m}") for m in range(M)]
        self._stacked = [cp.reshape(X, (T * STATE_DIM,), order="C") for X in self.states]
        self._sqrt_w = cp.Parameter((T, M), nonneg=True, name="sqrt_w_over_r")
        self._lin = cp.Parameter((T, 2 * M), name="wz_over_r")
        cost = 0
        rows: list[Any] = []
        for m in range(M):
            X, U = self.states[m], self.noise[m]
            rows.append(X[0] == F @ self.x0[m] + L @ U[0])
            rows.append(X[1:] == X[:-1] @ F.T + U[1:] @ L.T)
            cost += 0.5 * cp.sum_squares(U)
            cost += 0.5 * cp.sum_squares(cp.multiply(self._sqrt_w[:, m], X[:, PX]))
            cost += 0.5 * cp.sum_squares(cp.multiply(self._sqrt_w[:, m], X[:, PY]))
            cost -= self._lin[:, 2 * m] @ X[:, PX] + self._lin[:, 2 * m + 1] @ X[:, PY]
        variables = CvxpyVariables.of(self.states, scenario.dt)
        for con in self.constraints:
            if isinstance(con, CvxpyConstraint):
                items = con.build(variables)
                if con.soft:
                    items, penalty = soften_cvxpy(items, con.weight)
                    cost += penalty
                rows.extend(items)
        self._base_cost = cost
        self._base_constraints = rows
        self.problem = cp.Problem(cp.Minimize(cost), rows)

    def _build(self, rows: dict[int, PlatformRows]) -> None:
        """The problem with this iteration's constraint rows written in as constants."""
        import cvxpy as cp

        from solvers.cvxpy_ import cone_constraints

        cost = self._base_cost
        constraints: list[Any] = list(self._base_constraints)
        n = self.T * STATE_DIM
        for m, platform_rows in sorted(rows.items()):
            extra = assemble(platform_rows.items, n, np.arange(n))
            z: Any = self._stacked[m]
            if extra.n_slack:
                slack = cp.Variable(extra.n_slack)
                z = cp.hstack([z, slack])
                cost += extra.slack_cost @ slack
            constraints += cone_constraints(extra.b - sp.csr_matrix(extra.A) @ z, extra.cones)
        self.problem = cp.Problem(cp.Minimize(cost), constraints)

    def solve(self, data: MStepData) -> MStepOutput:
        from solvers.cvxpy_ import solve_to_solution

        if not self.dpp:
            self._build(self.rows.rows(data.ctx, data.active))
        self._sqrt_w.value = np.sqrt(np.maximum(data.W, 0.0) / data.r)
        self._lin.value = (data.WZ / data.r).reshape(self.T, 2 * self.M)
        backend = f"cvxpy/{self.cvxpy_solver}"
        iterations = [0]

        def read() -> np.ndarray | None:
            values = [X.value for X in self.states]
            return None if any(v is None for v in values) else np.stack([np.asarray(v) for v in values])

        def attempt(options: dict[str, Any]) -> solvers.QPSolution:
            sol = solve_to_solution(self.problem, read, backend, self.cvxpy_solver, options)
            iterations[0] += sol.iterations
            return sol

        sol, _ = solvers.retry_failed(attempt(self.options), self.options, self.retries, attempt)
        if sol.status in solvers.INFEASIBLE and self.constraints:
            names = sorted({c.name for c in self.constraints if not c.soft})
            raise InfeasibleError(
                f"{sol.backend}: the constraints {', '.join(names)} cannot all be met (status "
                f"{sol.raw_status}); the clarabel backend names the platform and time steps. Relax them "
                "or pass soft=True.",
                backend=sol.backend,
                status=sol.raw_status,
            )
        check_solution(sol, self.accept_inaccurate)
        assert sol.x is not None
        states = self._with_start(sol.x.reshape(self.M, self.T, STATE_DIM))
        return MStepOutput(
            states=states,
            status=sol.status,
            raw_status=sol.raw_status,
            iterations=iterations[0],
            fallbacks=int("fallback" in sol.info),
        )
