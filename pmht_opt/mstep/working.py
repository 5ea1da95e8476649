r"""A constrained M-step solved on a working set of its rows: the sparse QP with the rows that bind.

One platform's M-step with constraint rows is the sparse QP of :mod:`pmht_opt.mstep.formulation`
with the dynamics as equalities and the rows ``b - A x in K`` below them. Keep only a set ``S`` of
the rows' units (a linear row, or a whole cone: :class:`~pmht_opt.mstep.units.Units`): the QP with
the rows of ``S`` is a relaxation of the whole one, so its optimum costs no more than the whole one's,
and if it also meets every row outside ``S`` it is the whole QP's optimum. The working set starts as
in :mod:`pmht_opt.mstep.condensed` (the equalities, the slacks' own rows, the units that bound the
platform's last answer, the units the starting point violates by at least :data:`WORST` of the
worst) and the units the answer misses join it, up to :data:`MAX_ROUNDS` solves; of the sides of a
polygon (inequalities on the same columns) only the most violated joins in a round
(:func:`~pmht_opt.mstep.units.most_violated`).

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

Misses are measured on the rows as they are meant, on the states, not as the QP holds them: rows of
position differences are rewritten on the increments with the dynamics equalities
(:func:`~pmht_opt.mstep.formulation.in_increments`), and the two agree only where the dynamics hold
exactly. A first-order backend meets those to its tolerance, which is absolute or relative to the
largest entry of ``A x`` (positions of size 10-100): on C with ``SpeedLimit(1e-3)`` OSQP met the
increments' rows and missed the positions' differences by 1.3e-6, 0.13% of the limit. A unit of the
set missed by more than :data:`REL_MET` of its size (a polygon's radius; 1 for a normalised cone or a
unit-normal row) is therefore imposed again, tighter by twice its miss, and the set solved again from
its last iterate, at most :data:`REFINE` times: the backend's error is of much the same size and sign
on the tightened rows, so the answer lands inside the true ones. When the tightened rounds do not
halve the largest relative miss, the answer before them is kept. A verdict of infeasibility on
tightened rows proves nothing: the whole QP then decides (or the answer before them stands).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.mstep.condensed import BOUND, MAX_ROUNDS, MET, ROUNDING, WORST
from pmht_opt.mstep.units import Units, groups, most_violated

#: A unit of the working set missed by more than this fraction of its size is imposed again, tighter.
REL_MET = 1e-4
#: Most times the working set is imposed again, tighter, per solve.
REFINE = 4


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
        #: The rows' groups (:func:`~pmht_opt.mstep.units.groups`) for a structure of rows, by its key.
        self._groups: tuple[tuple[object, ...], np.ndarray] | None = None

    def solve(
        self,
        problem: solvers.QPProblem,
        n_dyn: int,
        pattern: tuple[object, ...],
        session_class: type[solvers.QPSession],
        options: dict[str, Any],
        start: np.ndarray,
        budget: solvers.WorkBudget | None = None,
        sizes: np.ndarray | None = None,
        measured: tuple[sp.spmatrix, np.ndarray] | None = None,
    ) -> solvers.QPSolution | None:
        """The answer of ``problem`` (its first ``n_dyn`` rows the dynamics, its cones a
        :class:`solvers.Zero` of them and then the constraint rows'), or ``None`` if the working set
        did not settle (the caller then solves the whole QP). A verdict of infeasibility is returned.

        ``pattern`` fixes the structure of the constraint rows (a new one resets what the last answer
        bound); ``start`` is a point of the QP's variables (the unconstrained optimum) whose violated
        units seed the working set. ``sizes`` (per constraint row, default 1) is what each row's miss
        is measured against (module docstring). ``measured`` is the constraint rows ``(A, b)`` as
        they are meant, when ``problem`` holds them rewritten with the dynamics
        (:func:`~pmht_opt.mstep.formulation.in_increments`): the two agree only where the dynamics
        hold exactly, and a first-order backend meets them to its tolerance, so misses are measured
        on these.
        """
        known = self._groups[1] if self._groups is not None and self._groups[0] == pattern else None
        rows = _Rows(problem, n_dyn, self.n_vars, sizes, measured, known)
        self._groups = (pattern, rows.group)
        shape = tuple((c.kind, c.dim) for c in problem.cones[1:])
        if shape != self._shape:
            self._shape, self._bound, self._last = shape, np.zeros(0, dtype=int), None
        seed = rows.missed(start, np.zeros(0, dtype=int), MET, WORST if self._bound.size else 0.0)
        units = np.union1d(np.union1d(rows.always, self._bound), seed)
        x_start = start if self._last is None else self._last
        iterations = refined = 0
        shift = np.zeros(problem.b.size)  # what tightens each row (module docstring)
        # The answer before any tightening, and its largest relative miss: kept when the tightened
        # rounds do not halve that miss (the shift inside the backend's own tolerance, as with an
        # acceleration limit of 1e-3 on B, where rounds stopped after 25 iterations, their misses
        # unchanged and the dynamics met less well).
        first: tuple[solvers.QPSolution, np.ndarray, float] | None = None
        for _ in range(MAX_ROUNDS + REFINE):
            sol = self._round(problem, rows, units, pattern, session_class, options, x_start, budget, shift)
            iterations += sol.iterations
            if sol.status in solvers.INFEASIBLE and refined == 0:
                return sol
            if not sol.ok or sol.x is None or sol.status in solvers.INFEASIBLE:
                if first is None:
                    return None
                sol, x = first[0], first[1]
                return self._accepted(sol, x, rows, units, iterations)
            x = sol.x
            # Outside the set, a unit may be missed as far as the backend missed those in it, but no
            # further than REL_MET of its size (a unit that small joins the set and is tightened).
            met = np.maximum(MET, np.minimum(rows.worst(x, units), REL_MET * rows.scale))
            missed = rows.missed(x, units, met, 0.0)
            far = rows.far(x, units)
            if missed.size == 0 and far.size and refined < REFINE:
                if first is None:
                    first = (sol, x.copy(), rows.relative_miss(x, units))
                refined += 1
                shift[rows.n_dyn + rows.units.start[far]] -= 2.0 * rows.miss(x)[far]
                x_start = x
                continue
            if missed.size == 0:
                if first is not None and rows.relative_miss(x, units) > 0.5 * first[2]:
                    sol, x = first[0], first[1]
                return self._accepted(sol, x, rows, units, iterations)
            units = np.union1d(units, missed)
            x_start = x
        return None

    def _accepted(
        self, sol: solvers.QPSolution, x: np.ndarray, rows: _Rows, units: np.ndarray, iterations: int
    ) -> solvers.QPSolution:
        """``sol`` with answer ``x``, recorded as this solve's: the units binding it start the next."""
        self._bound = np.intersect1d(rows.binding(x), rows.on_state)
        self._last = x
        sol.x = x
        sol.iterations = iterations
        sol.info["working_set"] = {"units": int(units.size), "of": int(rows.units.start.size)}
        return sol

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
        shift: np.ndarray,
    ) -> solvers.QPSolution:
        """Solve the QP of the rows of ``units``, their right-hand sides moved by ``shift``: in the
        kept session if it holds these rows (only the numbers moved), else in a new one started from
        ``x_start``."""
        picked = np.concatenate([np.arange(rows.n_dyn), rows.n_dyn + rows.units.rows(units)])
        A = problem.A[picked]
        b = (problem.b + shift)[picked]
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

    def __init__(
        self,
        problem: solvers.QPProblem,
        n_dyn: int,
        n_vars: int,
        sizes: np.ndarray | None = None,
        measured: tuple[sp.spmatrix, np.ndarray] | None = None,
        group: np.ndarray | None = None,
    ) -> None:
        self.n_dyn = n_dyn
        if measured is None:
            self.A = problem.A.tocsr()[n_dyn:]
            self.b = problem.b[n_dyn:]
        else:
            self.A = sp.csr_matrix(measured[0])
            self.b = np.asarray(measured[1], dtype=float)
        self.units = Units.of(list(problem.cones[1:]))
        #: Per unit, what its miss is measured against (the least size of its rows).
        per_row = np.ones(self.b.size) if sizes is None or sizes.size != self.b.size else sizes
        self.scale = np.minimum.reduceat(per_row, self.units.start) if self.b.size else np.zeros(0)
        # Units with a row on the states (not only on slacks), and the rest: the slacks' own s >= 0.
        on = np.zeros(self.units.start.size, dtype=bool)
        coo = self.A.tocoo()
        on[self.units.of_row[coo.row[coo.col < n_vars]]] = True
        self.on_state = np.flatnonzero(on)
        self.always = np.flatnonzero((self.units.kind == 0) | ~on)
        #: Per unit, the largest ``|b|`` of its rows, which bounds the rounding of its slack.
        self.size = np.maximum.reduceat(np.abs(self.b), self.units.start) if self.b.size else np.zeros(0)
        #: Per unit, its group (the sides of one polygon share one): given when the structure is known.
        self.group = groups(self.A, self.units) if group is None else group

    def margin(self, x: np.ndarray) -> np.ndarray:
        """How far inside its cone each unit is at ``x`` (negative: missed)."""
        return self.units.margin(self.b - self.A @ x)

    def worst(self, x: np.ndarray, units: np.ndarray) -> float:
        """The largest miss among ``units`` at ``x`` beyond rounding (0 if none)."""
        miss = -self.margin(x)[units] - ROUNDING * self.size[units]
        return float(miss.max(initial=0.0))

    def missed(
        self, x: np.ndarray, exclude: np.ndarray, met: float | np.ndarray, fraction: float
    ) -> np.ndarray:
        """The units outside ``exclude`` missed at ``x`` by more than ``met`` plus rounding and by at
        least ``fraction`` of the worst of them."""
        miss = -self.margin(x) - (met + ROUNDING * self.size)
        miss[exclude] = 0.0
        worst = float(miss.max(initial=0.0))
        if worst <= 0.0:
            return np.zeros(0, dtype=int)
        out = np.flatnonzero(miss >= max(fraction * worst, np.finfo(float).tiny))
        return most_violated(out, -miss, self.group)

    def miss(self, x: np.ndarray) -> np.ndarray:
        """Per unit, how far it is missed at ``x`` (0 where it is met)."""
        return np.maximum(-self.margin(x), 0.0)

    def relative_miss(self, x: np.ndarray, units: np.ndarray) -> float:
        """The largest miss at ``x`` of the inequality and cone units among ``units``, relative to
        their size (0 if none is missed)."""
        keep = units[self.units.kind[units] != 0]
        return float((self.miss(x)[keep] / self.scale[keep]).max(initial=0.0))

    def far(self, x: np.ndarray, units: np.ndarray) -> np.ndarray:
        """The linear or cone units among ``units`` missed at ``x`` by more than :data:`REL_MET` of
        their size, beyond :data:`~pmht_opt.mstep.condensed.MET` and rounding."""
        miss = self.miss(x)[units] - (REL_MET * self.scale[units] + MET + ROUNDING * self.size[units])
        return units[(miss > 0.0) & (self.units.kind[units] != 0)]

    def binding(self, x: np.ndarray) -> np.ndarray:
        """The units within :data:`~pmht_opt.mstep.condensed.BOUND` of their bound at ``x``."""
        return np.flatnonzero(self.margin(x) < BOUND)
