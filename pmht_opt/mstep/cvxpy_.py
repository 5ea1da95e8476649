"""The M-step with native cvxpy constraints: all platforms in one cvxpy problem.

Without native cvxpy constraints the ``cvxpy`` backend is the platform QPs of
:class:`~pmht_opt.mstep.qp.QPMStep` handed to :class:`solvers.cvxpy_.CvxpySession`: the same
formulation and the same translation into cvxpy as every other use of cvxpy in this library.
A :class:`~pmht_opt.constraints.CvxpyConstraint` may couple platforms, so with one the M-step is the
QP of all platforms stacked (block-diagonal), the constraint blocks assembled exactly as for the QP
backends, and the user's constraints added on views of the stacked variable as the states they
describe.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.constraints.user import CvxpyConstraint, CvxpyVariables
from pmht_opt.exceptions import ConfigError, InfeasibleError, ScheduleError, SolverError
from pmht_opt.model import PX, PY, STATE_DIM
from pmht_opt.mstep.base import MStep, MStepData, MStepOutput, check_cvxpy_solver
from pmht_opt.mstep.formulation import QPLayout, dynamics_rows
from pmht_opt.mstep.qp import check_solution
from pmht_opt.mstep.rows import RowBuilder, assemble, soften_cvxpy

#: Statuses of a solve stopped by a limit of the caller's, not by the problem.
_LIMITS = frozenset({solvers.Status.MAX_ITER, solvers.Status.TIME_LIMIT, solvers.Status.INTERRUPTED})


class JointCvxpyMStep(MStep):
    """Every platform's M-step QP in one cvxpy problem, with the native cvxpy constraints on top.

    ``settings`` may hold ``cvxpy_solver`` (default ``"CLARABEL"``); the rest goes to
    ``cvxpy.Problem.solve``. The problem is compiled again at every solve (the iteration's constraint
    rows enter as constants); each :class:`~pmht_opt.constraints.CvxpyConstraint` function is called
    at every compilation on the same kind of variables and must not depend on the iterate.
    """

    name: ClassVar[str] = "cvxpy"

    def _setup(self) -> None:
        from solvers.cvxpy_ import CvxpySession

        self.options = dict(self.settings)
        check_cvxpy_solver(self.options, "solver_settings")
        self.session_class = CvxpySession
        self.rows = RowBuilder(self.constraints, conic=True)
        self.layout = QPLayout(self.M, self.T)
        self.A_dyn, self.b_dyn = dynamics_rows(self.model, self.layout, self.x0)
        self.native = [c for c in self.constraints if isinstance(c, CvxpyConstraint)]

    def _native(self, x: Any) -> tuple[list[Any], Any]:
        """The user's constraints on views of ``x`` as per-platform ``(T, 6)`` states."""
        import cvxpy as cp

        t_idx = np.arange(1, self.T + 1)[:, None]
        units = np.tile(self.layout.units, self.T)  # the QP's variables are states in its own units
        states = [
            cp.reshape(
                cp.multiply(units, x[self.layout.x(m, t_idx, np.arange(STATE_DIM)).ravel()]),
                (self.T, STATE_DIM),
                order="C",
            )
            for m in range(self.M)
        ]
        variables = CvxpyVariables.of(states, self.scenario.dt)
        out: list[Any] = []
        cost: Any = 0
        for con in self.native:
            items = con.build(variables)
            if con.soft:
                items, penalty = soften_cvxpy(items, con.weight)
                cost = cost + penalty
            out += items
        return out, cost

    def _problem(self, data: MStepData) -> solvers.QPProblem:
        lay, T = self.layout, self.T
        t_idx = np.arange(1, T + 1)
        n = lay.n
        diag = np.zeros(n)
        diag[lay.u(np.arange(self.M)[:, None, None], t_idx[None, :, None], np.arange(STATE_DIM))] = 1.0
        q = np.zeros(n)
        for m in range(self.M):
            for c, comp in enumerate((PX, PY)):
                idx = lay.x(m, t_idx, comp)
                diag[idx] = data.W[:, m] / data.r
                q[idx] = -data.WZ[:, m, c] / data.r
        blocks = [self.A_dyn]
        b = [self.b_dyn]
        cones: list[solvers.Cone] = [solvers.Zero(self.A_dyn.shape[0])]
        slack_cost = [np.zeros(0)]
        n_slack = 0
        for m, platform_rows in sorted(self.rows.rows(data.ctx, data.active, data.strengths).items()):
            col_map = lay.x(m, t_idx[:, None], np.arange(STATE_DIM)).ravel()
            extra = assemble(platform_rows.items, n + n_slack, col_map, units=lay.units)
            blocks.append(extra.A)
            b.append(extra.b)
            cones += extra.cones
            slack_cost.append(extra.slack_cost)
            n_slack += extra.n_slack
        width = n + n_slack
        A = sp.vstack(
            [sp.csc_matrix(blk, shape=(blk.shape[0], width)) for blk in _widen(blocks, width)]
        ).tocsc()
        P = sp.diags(np.concatenate([diag, np.zeros(n_slack)])).tocsc()
        return solvers.QPProblem(
            P=P, q=np.concatenate([q, *slack_cost]), A=A, b=np.concatenate(b), cones=tuple(cones)
        )

    def _solve(self, data: MStepData) -> MStepOutput:
        problem = self._problem(data)
        try:
            session = self.session_class(problem, extra=self._native, **self.options)
        except solvers.SettingsError as err:
            raise ConfigError(f"solver_settings: {err}") from err
        except solvers.QPError as err:
            raise SolverError(f"cannot set up the M-step problem: {err}") from err
        sol = session.solve()
        # A solver that fails without a limit (a numerical error, an inaccurate answer the caller does not
        # accept) may be facing contradictory constraints: the probe tells. Iteration or time limits are
        # the caller's and are reported as they are.
        failed = not sol.usable(self.accept_inaccurate) and sol.status not in _LIMITS
        verdict = self._probe(problem) if failed and sol.status not in solvers.INFEASIBLE else sol
        if verdict is not None and verdict.status in solvers.INFEASIBLE and self.constraints:
            hard = [c for c in self.constraints if not c.soft]
            names = ", ".join(sorted({c.name for c in hard}))
            if all(c.exact for c in hard):  # every row is a constraint itself: a proof
                raise InfeasibleError(
                    f"{sol.backend}: the constraints {names} cannot all be met by any path (status "
                    f"{verdict.raw_status}); the clarabel backend names the platform and time steps. Relax "
                    "them or pass soft=True.",
                    backend=sol.backend,
                    status=verdict.raw_status,
                )
            raise ScheduleError(
                f"{sol.backend}: the constraints {names} cannot all be met where this iteration imposes "
                f"them (status {verdict.raw_status}); the constraints themselves were not shown to be "
                "infeasible: other steps may meet them.",
                backend=sol.backend,
                status="schedule infeasible",
            )
        check_solution(sol, self.accept_inaccurate)
        assert sol.x is not None
        x = sol.x[: self.layout.n]
        return MStepOutput(
            states=self._with_start(self.layout.states(x)),
            status=sol.status,
            raw_status=sol.raw_status,
            iterations=sol.iterations,
            noise=self.layout.noise(x),
            constrained=tuple(range(self.M)),  # native constraints may bind any platform
        )

    def _probe(self, problem: solvers.QPProblem) -> solvers.QPSolution | None:
        """After a failed solve: the same constraints with no cost, to tell an infeasible problem
        (which solvers sometimes report as a numerical failure) from a hard one; ``None`` without
        constraints or when the probe cannot be set up."""
        if not self.constraints:
            return None
        probe = solvers.QPProblem(
            P=sp.csc_matrix(problem.P.shape),
            q=np.zeros_like(problem.q),
            A=problem.A,
            b=problem.b,
            cones=problem.cones,
        )
        try:
            return self.session_class(probe, extra=self._native, **self.options).solve()
        except solvers.QPError:
            return None


def _widen(blocks: list[sp.spmatrix], width: int) -> list[sp.csc_matrix]:
    """Each block padded with empty columns up to ``width`` (the slacks of later platforms)."""
    out = []
    for blk in blocks:
        blk = sp.csc_matrix(blk)
        if blk.shape[1] < width:
            indptr = np.concatenate([blk.indptr, np.full(width - blk.shape[1], blk.indptr[-1])])
            blk = sp.csc_matrix((blk.data, blk.indices, indptr), shape=(blk.shape[0], width))
        out.append(blk)
    return out
