"""One platform's M-step QP over a fixed horizon and its backend session's lifecycle.

The QP is built once and its numbers pushed to the backend at every EM iteration; the session is set
up afresh when the rows' structure changes, rescaled when annealing has moved ``r`` far from the
setup's (for backends that do not adapt to new numbers themselves), and retried with the backend's
slower settings when a solve fails (:mod:`pmht_opt.mstep.tuning`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.exceptions import ConfigError, SolverError
from pmht_opt.model import PX, PY, STATE_DIM, MotionModel
from pmht_opt.mstep.condensed import COSTLY_WORK, CondensedQP
from pmht_opt.mstep.formulation import QPLayout, dynamics_rows, in_increments
from pmht_opt.mstep.rows import ExtraRows, PlatformRows, assemble
from pmht_opt.mstep.working import WorkingSetQP

#: A backend session keeps its setup-time scaling while ``r`` stays within this factor of its setup ``r``
#: (unless it adapts to new numbers itself, :attr:`solvers.QPSession.adapts_to_updates`).
RESCALE = 2.0
_UNSET = object()


@dataclass
class Settings:
    """The settings one platform's QPs use: shared by its horizons, so a retry set that solved is kept."""

    plain: dict[str, Any]
    constrained: dict[str, Any]
    retries: solvers.RetryChain
    #: The retries of solves with constraint rows (``None``: :attr:`retries`).
    constrained_retries: solvers.RetryChain | None = None
    #: The settings of condensed constrained solves (``None``: no condensing,
    #: :mod:`pmht_opt.mstep.condensed`).
    condensed: dict[str, Any] | None = None
    #: The retries of a condensed QP's solve.
    condensed_retries: solvers.RetryChain = solvers.NO_RETRY
    #: The settings of constrained solves on a working set of the rows (``None``: the whole QP only,
    #: :mod:`pmht_opt.mstep.working`).
    working: dict[str, Any] | None = None

    def chain(self, constrained: bool) -> solvers.RetryChain:
        """The retries of a solve with (``True``) or without constraint rows."""
        if constrained and self.constrained_retries is not None:
            return self.constrained_retries
        return self.retries


@contextlib.contextmanager
def _setting_up() -> Iterator[None]:
    """The library's errors for a backend that refuses its settings or the problem at setup."""
    try:
        yield
    except solvers.SettingsError as err:
        raise ConfigError(f"solver_settings: {err}") from err
    except solvers.QPError as err:
        raise SolverError(f"cannot set up the M-step QP: {err}") from err


class HorizonQP:
    """The M-step QP of one platform over ``horizon`` steps (:mod:`pmht_opt.mstep.formulation`).

    Constraint rows go below the dynamics, soft constraints' slacks after the platform's own variables.
    While the rows stay the same (their key is unchanged) only the weights are pushed to the backend;
    while their structure stays the same only the numbers are; when it changes (a visit moves to
    another time step) the backend session is set up afresh.

    The backend session is created at the first solve, with real weights: both backends compute their
    scaling (equilibration) at setup, and a setup with every position weight at zero leaves Clarabel
    badly scaled for every later update.

    ``margin`` is the least absolute back-off of its hard cones (:func:`~pmht_opt.mstep.rows.assemble`).
    """

    def __init__(
        self,
        model: MotionModel,
        x0: np.ndarray,
        horizon: int,
        session_class: type[solvers.QPSession],
        state: Settings,
        margin: float = 0.0,
    ) -> None:
        self.margin = margin
        self.layout = lay = QPLayout(1, horizon)
        #: The layout of a QP without constraint rows, in the states' own units (:meth:`layout_for`).
        self.plain_layout = QPLayout(1, horizon, scaled=False)
        self.session_class = session_class
        self.state = state
        t_idx = np.arange(1, horizon + 1)
        self.px = lay.x(0, t_idx, PX)
        self.py = lay.x(0, t_idx, PY)
        #: QP column of each entry of the stacked states ``(x_1, ..., x_T)``.
        self.col_map = lay.x(0, t_idx[:, None], np.arange(STATE_DIM)).ravel()
        diag = np.zeros(lay.n)
        stored = np.zeros(lay.n, dtype=bool)
        stored[self.px] = True
        stored[self.py] = True
        u_idx = lay.u(0, t_idx[:, None], np.arange(STATE_DIM)).ravel()
        stored[u_idx] = True
        diag[u_idx] = 1.0
        self.diag = diag
        self.stored = np.flatnonzero(stored)
        self._model, self._x0 = model, x0
        #: Dynamics rows and right-hand side without (``False``) and with constraint rows, made on first use.
        self._dynamics: dict[bool, tuple[sp.csc_matrix, np.ndarray]] = {}
        self.problem: solvers.QPProblem | None = None
        self.session: solvers.QPSession | None = None
        self.extra: ExtraRows | None = None
        self._pattern: tuple[object, ...] | None = None
        self._setup_r: float | None = None
        #: The key of the rows in :attr:`extra`, and of those the backend session holds.
        self._rows_key: tuple[tuple[int, ...], ...] | None = None
        self._session_key: tuple[tuple[int, ...], ...] | None = None
        #: The condensed solve of constrained M-steps (:mod:`pmht_opt.mstep.condensed`), if used.
        self.condensed = (
            None if state.condensed is None else CondensedQP(model, self.layout, state.condensed_retries)
        )
        #: The working-set solve of constrained M-steps (:mod:`pmht_opt.mstep.working`), if used.
        self.working = None if state.working is None else WorkingSetQP(lay.n)
        #: Whether a working set goes before condensing where condensing proved costly.
        self._working_first = True
        #: The rows key and the whole constrained QP's rows ``(A, b, cones)`` of the working-set solve.
        self._rows_qp: tuple[object, tuple[sp.csc_matrix, np.ndarray, tuple[solvers.Cone, ...]]] | None = None

    def layout_for(self, constrained: bool) -> QPLayout:
        """The layout of a QP with or without constraint rows.

        A QP with constraint rows is posed in scaled units
        (:func:`~pmht_opt.mstep.formulation.state_units`), which let an interior point meet binding
        limits. One without keeps the states' own units, which its settings
        (:mod:`pmht_opt.mstep.tuning`) were tuned for: OSQP with loose tolerances stopped 2e-4 from the
        exact smoother in scaled units.
        """
        return self.layout if constrained else self.plain_layout

    def states(self, x: np.ndarray) -> np.ndarray:
        """The platform's states ``(T, 6)`` in their own units from a solution vector of the last QP."""
        lay = self.layout_for(self.extra is not None)
        return lay.states(x[: lay.n])[0]

    def _P(self, n_slack: int) -> sp.csc_matrix:
        # CSC arrays by hand so the position entries stay stored while their weight is zero; slack
        # columns (if any) are empty.
        n = self.layout.n
        stored = np.zeros(n, dtype=bool)
        stored[self.stored] = True
        indptr = np.concatenate([[0], np.cumsum(stored), np.full(n_slack, stored.sum())])
        return sp.csc_matrix((self.diag[self.stored], self.stored, indptr), shape=(n + n_slack, n + n_slack))

    def _cost(self, W: np.ndarray, WZ: np.ndarray, r: float) -> np.ndarray:
        scale = 1.0 / r
        self.diag[self.px] = W * scale
        self.diag[self.py] = W * scale
        q = np.zeros(self.layout.n)
        q[self.px] = -WZ[:, 0] * scale
        q[self.py] = -WZ[:, 1] * scale
        extra = self.extra
        return q if extra is None or extra.n_slack == 0 else np.concatenate([q, extra.slack_cost])

    def _constraints(self) -> tuple[sp.csc_matrix, np.ndarray, tuple[solvers.Cone, ...]]:
        extra = self.extra
        constrained = extra is not None
        if constrained not in self._dynamics:
            self._dynamics[constrained] = dynamics_rows(
                self._model, self.layout_for(constrained), self._x0[None, :]
            )
        A_dyn, b_dyn = self._dynamics[constrained]
        zero = solvers.Zero(A_dyn.shape[0])
        if extra is None:
            return A_dyn, b_dyn, (zero,)
        if extra.n_slack:
            indptr = np.concatenate([A_dyn.indptr, np.full(extra.n_slack, A_dyn.indptr[-1])])
            A_dyn = sp.csc_matrix(
                (A_dyn.data, A_dyn.indices, indptr), shape=(A_dyn.shape[0], extra.A.shape[1])
            )
        rows_A, rows_b = in_increments(extra.A, extra.b, A_dyn, b_dyn, self.layout.n)
        A = sp.vstack([A_dyn, rows_A], format="csc")
        A.sort_indices()
        return A, np.concatenate([b_dyn, rows_b]), (zero, *extra.cones)

    @property
    def options(self) -> dict[str, Any]:
        """The settings in use: the constrained ones when there are constraint rows."""
        return self.state.plain if self.extra is None else self.state.constrained

    def solve(
        self,
        W: np.ndarray,
        WZ: np.ndarray,
        r: float,
        rows: PlatformRows | None = None,
        probe: Callable[[solvers.QPSolution], None] | None = None,
        budget: solvers.WorkBudget | None = None,
        exact: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> solvers.QPSolution:
        """Solve for weights ``W (T,)``, weighted locale sums ``WZ (T, 2)`` and constraint rows.

        ``probe`` is called with a failed constrained solve before any retry; it may raise (the
        M-step asks whether the rows are infeasible, which a cheap feasibility problem settles far
        sooner than a chain of retries of a solver that cannot succeed). ``budget`` is the work this
        solve and its retries may spend together (:class:`solvers.WorkBudget`).
        ``exact`` is the unconstrained optimum's states and whitened noise ``(T, 6)``, if the caller
        has them: a condensed solve starts from them (:mod:`pmht_opt.mstep.condensed`).

        With constraint rows, condensing on and ``exact`` given, the condensed solve is tried first;
        if it does not succeed, the whole QP below is solved.

        A session's scaling (both backends equilibrate at setup) is kept while ``r`` stays within a
        factor :data:`RESCALE` of the ``r`` it was set up with, or for good if the session adapts to
        new numbers itself (:attr:`solvers.QPSession.adapts_to_updates`: OSQP with its adaptive ``rho``);
        past that, and whenever the rows' structure changes, the session is set up afresh. Under
        annealing ``r`` shrinks a hundredfold, and a stale scaling leaves interior-point solves
        "almost solved".
        """
        key = rows.key if rows is not None else ()
        if key != self._rows_key:
            self._rows_key = key
            self.extra = None
            if rows and rows.items:
                self.extra = assemble(
                    rows.items, self.layout.n, self.col_map, units=self.layout.units, margin=self.margin
                )
        if self.extra is not None and self.condensed is not None and exact is not None:
            assert self.state.condensed is not None
            first = self.condensed.costly and self._working_first
            if first:  # condensing these rows cost more than a working set may: that first
                # ... with no more work than made condensing costly, charged to the M-step's budget.
                trial = solvers.WorkBudget(COSTLY_WORK)
                sol = self._solve_working(W, WZ, r, probe, trial, exact)
                if budget is not None:
                    budget.spend(trial.spent)
                if sol is not None:
                    return sol
                self._working_first = False  # it did not settle here (guaranteed visits): not again
            sol = self.condensed.solve(self.extra, W, r, self.session_class, self.state.condensed, exact)
            if sol is not None:
                return sol
            full = self._solve_rows(W, WZ, r, probe, budget, exact, working=not first)
            if full.ok and full.x is not None:
                self.condensed.observe(self.extra, self.states(full.x))
            return full
        return self._solve_rows(W, WZ, r, probe, budget, exact)

    def _solve_rows(
        self,
        W: np.ndarray,
        WZ: np.ndarray,
        r: float,
        probe: Callable[[solvers.QPSolution], None] | None,
        budget: solvers.WorkBudget | None,
        exact: tuple[np.ndarray, np.ndarray] | None,
        working: bool = True,
    ) -> solvers.QPSolution:
        """The sparse QP of the current rows: on a working set of them first (if ``working``), where
        that is used and ``exact`` is given (:mod:`pmht_opt.mstep.working`), else (or if it does not
        settle) whole."""
        sol = self._solve_working(W, WZ, r, probe, budget, exact) if working else None
        return sol if sol is not None else self._solve_full(W, WZ, r, probe, budget)

    def _solve_working(
        self,
        W: np.ndarray,
        WZ: np.ndarray,
        r: float,
        probe: Callable[[solvers.QPSolution], None] | None,
        budget: solvers.WorkBudget | None,
        exact: tuple[np.ndarray, np.ndarray] | None,
    ) -> solvers.QPSolution | None:
        """The QP of the current rows solved on a working set of them, or ``None`` if that is not
        used here or does not settle (an infeasibility verdict is first put to ``probe``)."""
        if self.extra is None or self.working is None or exact is None:
            return None
        assert self.state.working is not None
        q = self._cost(W, WZ, r)
        if self._rows_qp is None or self._rows_qp[0] != self._rows_key:
            self._rows_qp = (self._rows_key, self._constraints())
        A, b, cones = self._rows_qp[1]
        problem = solvers.QPProblem(P=self._P(self.extra.n_slack), q=q, A=A, b=b, cones=cones)
        sol = self.working.solve(
            problem,
            cones[0].dim,
            self.extra.pattern_key(),
            self.session_class,
            self.state.working,
            self._vector(*exact),
            budget,
            self.extra.row_size,
            (self.extra.A, self.extra.b),
        )
        if sol is not None and sol.status in solvers.INFEASIBLE and probe is not None:
            probe(sol)  # the relaxation's verdict holds for the whole QP: it names the culprits
            return None
        return sol

    def _vector(self, states: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """The constrained QP's variable vector of states and whitened noise ``(T, 6)``, no slack."""
        lay = self.layout
        body = np.concatenate([states / lay.units, noise], axis=1).ravel()
        n_slack = 0 if self.extra is None else self.extra.n_slack
        return np.concatenate([body, np.zeros(n_slack)])

    def _solve_full(
        self,
        W: np.ndarray,
        WZ: np.ndarray,
        r: float,
        probe: Callable[[solvers.QPSolution], None] | None,
        budget: solvers.WorkBudget | None,
    ) -> solvers.QPSolution:
        """Solve the whole QP of the current rows through the backend session (:meth:`solve`)."""
        key = self._rows_key
        stale = (
            self.session is not None
            and self._setup_r is not None
            and not self.session.adapts_to_updates
            and not (1.0 / RESCALE <= r / self._setup_r <= RESCALE)
        )
        if self.session is not None and key == self._session_key and not stale:  # only the weights moved
            q = self._cost(W, WZ, r)
            self.session.update(P_data=self.diag[self.stored], q=q)
            self.session.budget = budget
            return self._retry(self.session.solve(), q, fresh=False, probe=probe)
        self._session_key = key
        pattern = None if self.extra is None else self.extra.pattern_key()
        q = self._cost(W, WZ, r)
        A, b, cones = self._constraints()
        fresh = self.session is None or pattern != self._pattern
        if self.session is None or fresh:
            self._pattern = pattern
            self._setup_r = r
            n_slack = 0 if self.extra is None else self.extra.n_slack
            self.problem = solvers.QPProblem(P=self._P(n_slack), q=q, A=A, b=b, cones=cones)
            self.session = self._open(self.problem, self.options)
        else:
            if self.extra is None:
                self.session.update(P_data=self.diag[self.stored], q=q)
            else:
                self.session.update(P_data=self.diag[self.stored], q=q, A_data=A.data, b=b)
            if stale:
                with _setting_up():
                    self.session.rescale()
                self._setup_r = r
                fresh = True
        self.session.budget = budget
        return self._retry(self.session.solve(), q, fresh=fresh, probe=probe)

    def _open(self, problem: solvers.QPProblem, options: dict[str, Any]) -> solvers.QPSession:
        with _setting_up():
            return self.session_class(problem, **options)

    def _retry(
        self,
        sol: solvers.QPSolution,
        q: np.ndarray,
        fresh: bool,
        probe: Callable[[solvers.QPSolution], None] | None = None,
    ) -> solvers.QPSolution:
        """After a failed solve: first the same settings on a fresh session (a new scaling), if the
        failed one was an updated session; then the backend's slower, more robust settings in turn.

        The session that solves is kept for this platform's later solves, and with it a retry set that
        solved, so a run does not pay for the failing settings every iteration.
        """
        if sol.ok or sol.status in solvers.INFEASIBLE:
            return sol
        if probe is not None and self.extra is not None:
            probe(sol)
        A, b, cones = self._constraints()
        n_slack = 0 if self.extra is None else self.extra.n_slack
        problem = solvers.QPProblem(P=self._P(n_slack), q=q, A=A, b=b, cones=cones)
        assert self.session is not None
        budget = self.session.budget
        last: list[solvers.QPSession] = [self.session]
        if not fresh:
            last[:] = [self._open(problem, self.options)]
            last[0].budget = budget
            again = last[0].solve()
            if again.ok:
                self.problem, self.session = problem, last[0]
                return again
        chain = self.state.chain(self.extra is not None)
        if not chain.sets:
            return sol

        def attempt(settings: dict[str, Any]) -> solvers.QPSolution:
            # Continue the last session where its backend can (a first-order solver keeps its
            # iterate); otherwise start a new one.
            changed = {k: v for k, v in settings.items() if last[0].settings.get(k, _UNSET) != v}
            dropped = set(last[0].settings) - set(settings)
            resumed = None if dropped else last[0].resume(**changed)
            if resumed is not None:
                return resumed
            last[:] = [self.session_class(problem, **settings)]
            last[0].budget = budget
            return last[0].solve()

        out, used = solvers.retry_failed(sol, self.options, chain, attempt)
        if used is not None:  # the last session is the one that solved
            self.problem, self.session = last[0].problem, last[0]
            if self.extra is None:
                self.state.plain = used
            else:
                self.state.constrained = used
        return out

    def slacks(self, x: np.ndarray) -> np.ndarray:
        """The soft constraints' slack values in a solution vector."""
        return x[self.layout.n :]
