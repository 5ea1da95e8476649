r"""A constrained M-step solved on a working set of its rows: the sparse QP with the rows that bind.

One platform's M-step with constraint rows is the sparse QP of :mod:`pmht_opt.mstep.formulation`
with the dynamics as equalities and the rows ``b - A x in K`` below them. Keep only a set ``S`` of
the rows' units (a linear row, or a whole cone: :class:`~pmht_opt.mstep.units.Units`): the QP with
the rows of ``S`` is a relaxation of the whole one, so its optimum costs no more than the whole one's,
and if it also meets every row outside ``S`` it is the whole QP's optimum. The working set starts as
in :mod:`pmht_opt.mstep.condensed` (the equalities, the slacks' own rows, the units that bound the
platform's last answer, the units the starting point violates by at least :data:`WORST` of the
worst) and the units the answer misses join it, up to :data:`MAX_ROUNDS` solves.

Why: a first-order solver's iterations cost in proportion to the rows it is given, and their number
grows with the rows it must sort into active and inactive. An acceleration limit on every step of
scenario A is 16000 polygon rows, of which about 200 bind at the answer: OSQP needed about 9000 ADMM
iterations on all of them and 325 on those 200. Unlike the condensed QP, which is dense in the rows
it keeps and gives up on more than :data:`~pmht_opt.mstep.condensed.MAX_ROWS` of them or on rows that
depend on each other, this QP stays sparse whatever the working set.

A unit outside the set counts as met when it is missed by no more than the backend missed the units
it was given (its own feasibility tolerance), or :data:`~pmht_opt.mstep.condensed.MET`, and the
rounding of its slack: the answer is then the whole QP's to the backend's tolerance, as a solve of the
whole QP would be. The session of a working set is kept while the set and the rows' structure stay
the same (the weights move every EM iteration), so that the backend continues from its last iterate;
a new set starts from the last answer. A working-set solve that does not succeed is given up for the
whole QP (:meth:`~pmht_opt.mstep.horizon.HorizonQP.solve`), except a verdict of infeasibility, which a
relaxation's rows already imply for the whole.
"""

from __future__ import annotations

from typing import Any

import numpy as np

import solvers
from pmht_opt.mstep.condensed import BOUND, MAX_ROUNDS, MET, ROUNDING, WORST
from pmht_opt.mstep.units import Units


class WorkingSetQP:
    """The working-set solve of one platform's constrained QP over one horizon (module docstring).

    Parameters
    ----------
    n_vars
        The number of the QP's own variables (states and noise); slack columns follow them.
    """

    def __init__(self, n_vars: int) -> None:
        self.n_vars = n_vars
        self._shape: tuple[tuple[str, int], ...] | None = None
        #: The units on the states that bound the last answer to rows of the current shape.
        self._bound = np.zeros(0, dtype=int)
        self._session: solvers.QPSession | None = None
        self._session_key: tuple[object, ...] | None = None
        self._last: np.ndarray | None = None

    def solve(
        self,
        problem: solvers.QPProblem,
        n_dyn: int,
        pattern: tuple[object, ...],
        session_class: type[solvers.QPSession],
        options: dict[str, Any],
        start: np.ndarray,
        budget: solvers.WorkBudget | None = None,
    ) -> solvers.QPSolution | None:
        """The answer of ``problem`` (its first ``n_dyn`` rows the dynamics, its cones a
        :class:`solvers.Zero` of them and then the constraint rows'), or ``None`` if the working set
        did not settle (the caller then solves the whole QP). A verdict of infeasibility is returned.

        ``pattern`` fixes the structure of the constraint rows (a new one resets what the last answer
        bound); ``start`` is a point of the QP's variables (the unconstrained optimum) whose violated
        units seed the working set.
        """
        rows = _Rows(problem, n_dyn, self.n_vars)
        shape = tuple((c.kind, c.dim) for c in problem.cones[1:])
        if shape != self._shape:
            self._shape, self._bound, self._last = shape, np.zeros(0, dtype=int), None
        seed = rows.missed(start, np.zeros(0, dtype=int), MET, WORST if self._bound.size else 0.0)
        units = np.union1d(np.union1d(rows.always, self._bound), seed)
        x_start = start if self._last is None else self._last
        iterations = 0
        for _ in range(MAX_ROUNDS):
            sol = self._round(problem, rows, units, pattern, session_class, options, x_start, budget)
            iterations += sol.iterations
            if sol.status in solvers.INFEASIBLE:
                return sol
            if not sol.ok or sol.x is None:
                return None
            x = sol.x
            met = max(MET, rows.worst(x, units))
            missed = rows.missed(x, units, met, 0.0)
            if missed.size == 0:
                self._bound = np.intersect1d(rows.binding(x), rows.on_state)
                self._last = x
                sol.iterations = iterations
                sol.info["working_set"] = {"units": int(units.size), "of": int(rows.units.start.size)}
                return sol
            units = np.union1d(units, missed)
            x_start = x
        return None

    def _round(
        self,
        problem: solvers.QPProblem,
        rows: _Rows,
        units: np.ndarray,
        pattern: tuple[object, ...],
        session_class: type[solvers.QPSession],
        options: dict[str, Any],
        x_start: np.ndarray,
        budget: solvers.WorkBudget | None,
    ) -> solvers.QPSolution:
        """Solve the QP of the rows of ``units``: in the kept session if it holds these rows (only the
        numbers moved), else in a new one started from ``x_start``."""
        picked = np.concatenate([np.arange(rows.n_dyn), rows.n_dyn + rows.units.rows(units)])
        A = problem.A[picked]
        b = problem.b[picked]
        key = (pattern, units.tobytes())
        session = self._session
        if session is not None and key == self._session_key:
            session.update(P_data=problem.P.data, q=problem.q, A_data=A.data, b=b)
        else:
            sub = solvers.QPProblem(
                P=problem.P.copy(),
                q=problem.q,
                A=A,
                b=b,
                cones=(solvers.Zero(rows.n_dyn), *rows.units.cones(units)),
            )
            try:
                session = session_class(sub, **options)
            except solvers.QPError:
                self._session = None
                raise
            session.warm_start(x=x_start)
            self._session, self._session_key = session, key
        session.budget = budget
        return session.solve()


class _Rows:
    """The constraint rows of a QP split into units, with the measures of a working set."""

    def __init__(self, problem: solvers.QPProblem, n_dyn: int, n_vars: int) -> None:
        self.n_dyn = n_dyn
        A = problem.A.tocsr()
        self.A = A[n_dyn:]
        self.b = problem.b[n_dyn:]
        self.units = Units.of(list(problem.cones[1:]))
        # Units with a row on the states (not only on slacks), and the rest: the slacks' own s >= 0.
        on = np.zeros(self.units.start.size, dtype=bool)
        coo = self.A.tocoo()
        on[self.units.of_row[coo.row[coo.col < n_vars]]] = True
        self.on_state = np.flatnonzero(on)
        self.always = np.flatnonzero((self.units.kind == 0) | ~on)
        #: Per unit, the largest ``|b|`` of its rows, which bounds the rounding of its slack.
        self.size = np.maximum.reduceat(np.abs(self.b), self.units.start) if self.b.size else np.zeros(0)

    def margin(self, x: np.ndarray) -> np.ndarray:
        """How far inside its cone each unit is at ``x`` (negative: missed)."""
        return self.units.margin(self.b - self.A @ x)

    def worst(self, x: np.ndarray, units: np.ndarray) -> float:
        """The largest miss among ``units`` at ``x`` beyond rounding (0 if none)."""
        miss = -self.margin(x)[units] - ROUNDING * self.size[units]
        return float(miss.max(initial=0.0))

    def missed(self, x: np.ndarray, exclude: np.ndarray, met: float, fraction: float) -> np.ndarray:
        """The units outside ``exclude`` missed at ``x`` by more than ``met`` plus rounding and by at
        least ``fraction`` of the worst of them."""
        miss = -self.margin(x) - (met + ROUNDING * self.size)
        miss[exclude] = 0.0
        worst = float(miss.max(initial=0.0))
        if worst <= 0.0:
            return np.zeros(0, dtype=int)
        return np.flatnonzero(miss >= max(fraction * worst, np.finfo(float).tiny))

    def binding(self, x: np.ndarray) -> np.ndarray:
        """The units within :data:`~pmht_opt.mstep.condensed.BOUND` of their bound at ``x``."""
        return np.flatnonzero(self.margin(x) < BOUND)
