r"""A constrained M-step condensed onto the rows that bind: a small QP on the exact smoother's responses.

One platform's M-step with constraint rows is, on its stacked states ``X`` (``6 T``, the model's
units) and the soft rows' slacks ``s``,

.. math::

    \min_{X, s}\ \tfrac12 X^\top H X - g^\top X + c^\top s
    \quad\text{s.t.}\quad b - C X - E s \in \mathcal K,

where ``1/2 X'HX - g'X`` is the M-step objective (docs/model.md section 5: the process noise and
the weighted fit), ``H`` positive definite and banded in time, and ``(C, E, b, K)`` the rows of
:func:`~pmht_opt.mstep.rows.assemble`. Its unconstrained optimum ``X* = H^-1 g`` is the exact
smoother's (:class:`solvers.banded.BandedSmoother`).

**Condensing.** Keep only a set ``S`` of the rows. The optimum of that problem is stationary,
``H X - g + C_S' mu = 0``, so it lies in ``X* + H^-1 C_S' w`` for some ``w`` (``w = -mu``), and on
that affine set ``J(X* + B w) = J(X*) + 1/2 w' Sigma w`` with ``B = H^-1 C_S'`` and
``Sigma = C_S B``. The problem with the rows ``S`` is therefore exactly

.. math::

    \min_{w, s_S}\ \tfrac12 w^\top \Sigma w + c_S^\top s_S
    \quad\text{s.t.}\quad (b_S - C_S X^*) - \Sigma w - E_S s_S \in \mathcal K_S,

a QP with one variable per row of ``S`` (and its slacks), whatever the horizon. ``B`` takes one
solve of the exact smoother's factorised KKT system per row pattern and axis
(:class:`solvers.banded.BandedFactor`): ``H`` is never formed, so its conditioning (entries near
1e10 beside 1e2) never enters. The backend is given the cost as ``1/2 |v|^2`` with ``v = R D^-1 w``,
``R'R = D Sigma D`` (``D`` the Jacobi scaling): an identity Hessian and triangular rows, which keep
its KKT system sparse; rows that depend on each other (``Sigma`` singular) are left to the full QP.

**Working set.** The problem with the rows ``S`` is a relaxation of the whole one; if its optimum
meets every other row, it is the whole problem's optimum. ``S`` starts with the equalities and the
units that bound the platform's last answer to rows of the same shape, with those the unconstrained
optimum violates by at least :data:`WORST` of the worst (all it violates when there is no last
answer); units the answer still violates join it, and the small QP is solved again (at most
:data:`MAX_ROUNDS` times). Of the inequalities on the same columns (the sides of a polygon that
stands for a cone on OSQP) only the most violated joins in a round
(:func:`~pmht_opt.mstep.units.groups`): one side usually pulls the answer inside, and nearly
parallel sides slow ADMM down. Speed limits and area bounds on the paper's scenarios bind at a
handful of the 500 steps, and guaranteed visits at one step per locale, so the QP the backend solves
has tens of variables instead of the 6000 of the full one.

The answer is the same optimum as the full QP's, to the backend's tolerance; the two differ by that
much, not bit for bit. A condensed solve that does not succeed (a status other than solved, too many
rounds, more than :data:`MAX_ROWS` rows) is given up and the full QP is solved instead, with its
retries and infeasibility diagnosis: a failure is never reported from here. The full QP's answer then
seeds the next working set (:meth:`CondensedQP.observe`), and failures in a row leave the next few
M-steps to the full QP without an attempt.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.model import STATE_DIM, MotionModel
from pmht_opt.mstep.basis import PIVOT, factor_sigma, row_basis
from pmht_opt.mstep.formulation import BLOCK, QPLayout
from pmht_opt.mstep.responses import Responses
from pmht_opt.mstep.rows import ExtraRows
from pmht_opt.mstep.units import CondensedRows, most_violated
from solvers.banded import BandedSmoother

#: A unit outside the working set counts as met when its violation (``-s`` of a linear row,
#: ``||s_1..|| - s_0`` of a cone, in the rows' own scale: cones have radius 1, linear rows unit
#: normals) is at most this, plus :data:`ROUNDING` times the size of the numbers its slack is the
#: difference of (a bound of 1e4 in a geographic frame leaves a slack's last digits at 1e-12).
MET = 1e-9
#: Relative rounding allowed in a slack ``b - C x`` (64 units of the last place).
ROUNDING = 64 * float(np.finfo(float).eps)
#: Of the units the unconstrained optimum violates, those violated by at least this fraction of the
#: worst start the working set, beside the units that bound the platform's last answer to the same rows.
WORST = 0.5
#: A unit of the working set whose slack at the answer is below this binds it: it starts the next
#: M-step's working set.
BOUND = 1e-3
#: Most small QPs per M-step before the full QP is solved instead.
MAX_ROUNDS = 16
#: Most rows on the states in the working set. The small QP is dense: its cost grows with the cube of
#: its rows, and past about this many (a limit binding over long stretches) the sparse full QP is
#: cheaper, so it is solved instead.
MAX_ROWS = 160
#: Most rows on the states in the working set before they are reduced to independent ones
#: (:func:`~pmht_opt.mstep.basis.row_basis`): the rows of a polygon standing for one cone add one
#: variable per direction of the plane, not one per row.
MAX_DEPENDENT_ROWS = 16 * MAX_ROWS
#: Most independent rows of a working set reduced from dependent ones. Dependent rows are the
#: polygons of a backend without cones (OSQP), whose whole QP with polygons costs far more than an
#: interior point's with cones, so the small QP stays the cheaper one up to more rows (B with
#: ``VisitAll(0.05)``: 190 of 190 M-steps condensed at 400, one given up at 160, after which the
#: whole QP failed).
MAX_BASIS = 400
#: Most solves of a working set again, with the small QP's right-hand side corrected by what its
#: rows' slacks on the path differ from its own.
REFINE = 2
#: The work (iterations times size, :class:`solvers.WorkBudget`) the small QPs of one condensed
#: attempt may spend together, on backends that count it (OSQP), apart from the M-step's own budget
#: (:data:`pmht_opt.mstep.tuning.MSTEP_WORK`, 2e9). The size counts the small QP's entries, but its
#: rows are dense, so an ADMM iteration costs more per unit than the sparse whole QP's: a small QP of
#: a limit binding over long stretches that does not settle is cheaper to give up early. B at
#: T = 150 with ``SpeedLimit(0.06)``: three platforms' attempts each spent 4e9 (5.8 s) and failed,
#: after which the whole QP solved in 0.24 s; at 1.5e9 the stress sweep's slowest feasible M-step
#: (B, ``SpeedLimit(0.05)``) took 7.4 s instead of 18.1 s, B with a square keep-out 6.0 s instead of
#: 17.5 s. The largest attempt that succeeds on the guaranteed visits of plan_smoothed on C seed 1000
#: (radius 0.1), the heaviest measured, spends 1.17e9.
ATTEMPT_WORK = 1.5e9
#: An attempt that spends more work than this (OSQP: about 0.5 s of ADMM on small dense QPs) marks its
#: rows as costly to condense: a limit binding over long stretches (A with SpeedLimit(0.05): 145 small
#: QPs in 25 M-steps, 55 s, against 1.1 s for the working sets of the whole QP), so the next M-step
#: tries a working set first and condenses only if that does not settle (guaranteed visits, where
#: the working set's ADMM does not). A cold attempt (no binding rows carried over from a last answer)
#: that succeeds does not count: it pays for finding the rows the next M-steps start from (the
#: guaranteed visits of plan_smoothed on C seed 1000 at radius 0.1: 33000 ADMM iterations over five
#: rounds in the first M-step, then a working set tried in vain for 0.4 s, where the later condensed
#: M-steps take 0.01-0.05 s each).
COSTLY_WORK = 2e8
#: Most M-steps left to the full QP after condensed solves that did not succeed.
SKIP_MAX = 15


class CondensedQP:
    """The condensed constrained M-step of one platform over one horizon (module docstring).

    Parameters
    ----------
    model, layout
        The motion model and the layout of the platform's constrained QP.
    retries
        Settings tried in turn after a small QP's solve failed.
    """

    def __init__(
        self, model: MotionModel, layout: QPLayout, retries: solvers.RetryChain = solvers.NO_RETRY
    ) -> None:
        self.layout = layout
        #: Settings tried in turn after a small QP's solve failed (continued from its iterate).
        self.retries = retries
        self.T = layout.T
        self.smoother = BandedSmoother(model.F3, model.Q3, np.array([1.0, 0.0, 0.0]), self.T, 1)
        self._rows: CondensedRows | None = None
        self._extra: ExtraRows | None = None
        #: The units that bound the last answer to the current rows.
        self._bound = np.zeros(0, dtype=int)
        #: The work budget of the current attempt (shared by its small QPs' solves).
        self._budget: solvers.WorkBudget | None = None
        #: Whether the last attempt spent more than :data:`COSTLY_WORK`: the caller then tries a
        #: working set of the whole QP's rows first (:mod:`pmht_opt.mstep.working`).
        self.costly = False
        #: Condensed solves given up in a row, and solves still to leave to the full QP.
        self._failures = 0
        self._skip = 0
        #: The last small QP solved: its rows and shape and its primal answer, from which a small QP
        #: of the same rows starts (backends that take a warm start) ...
        self._warm: tuple[bytes, tuple[int, int], np.ndarray] | None = None
        #: ... and the latest dual value of every row, from which every small QP's duals start.
        self._duals = np.zeros(0)

    def solve(
        self,
        extra: ExtraRows,
        W: np.ndarray,
        r: float,
        session_class: type[solvers.QPSession],
        options: dict[str, Any],
        exact: tuple[np.ndarray, np.ndarray],
    ) -> solvers.QPSolution | None:
        """The M-step's solution vector in the full QP's layout, or ``None`` if the condensed solve did
        not succeed (the caller then solves the full QP). The small QPs of one call share a work budget
        of :data:`ATTEMPT_WORK` (:class:`solvers.WorkBudget`, counted by first-order backends), apart
        from the M-step's: an attempt that does not settle leaves the whole QP the work it had.

        ``exact`` is the unconstrained optimum's states and whitened noise, both ``(T, 6)`` (the exact
        smoother's, which the M-step has computed for its check and screening anyway).
        """
        rows = self._use(extra)
        if self._skip:
            self._skip -= 1
            return None
        if rows.has_state[rows.units.rows(self._bound)].sum() > MAX_DEPENDENT_ROWS:
            return None  # the last answer was bound by more rows than a condensed QP should take
        self._budget = solvers.WorkBudget(ATTEMPT_WORK)
        cold = self._bound.size == 0  # no binding rows carried over from a last answer
        answer = self._solve(rows, W, r, session_class, options, exact)
        # A cold attempt that succeeds pays for finding the binding rows, which the next M-steps
        # carry over: its cost says nothing about condensing these rows (COSTLY_WORK).
        self.costly = self._budget.spent > COSTLY_WORK and not (cold and answer is not None)
        # After failures in a row, wait 1, 3, 7, ... M-steps (at most SKIP_MAX) before trying again:
        # rows that defeat condensing (long stretches of rows at neighbouring steps, whose Sigma is
        # singular to working precision) tend to stay, and each attempt costs more than its full QP.
        self._failures = 0 if answer is not None else self._failures + 1
        self._skip = min(2**self._failures - 1, SKIP_MAX)
        return answer

    def _solve(
        self,
        rows: CondensedRows,
        W: np.ndarray,
        r: float,
        session_class: type[solvers.QPSession],
        options: dict[str, Any],
        exact: tuple[np.ndarray, np.ndarray],
    ) -> solvers.QPSolution | None:
        """:meth:`solve` once it is tried."""
        try:
            factor = self.smoother.factor(r, W[None])
        except solvers.ProblemError:
            return None
        X0, U0 = exact[0].ravel(), exact[1].ravel()
        margin = rows.units.margin(rows.b - rows.C @ X0)
        # Carried over: the units that bound the last answer and the worst violations now; afresh:
        # every unit the unconstrained optimum violates.
        first = _worst(margin, self._bound, WORST if self._bound.size else 0.0, rows)
        units = np.union1d(np.union1d(rows.always, first), self._bound)
        responses = Responses(rows.C, factor, self.T)
        iterations = refined = 0
        # What the rows' slacks on the path differ from the small QP's by, added to its right-hand side.
        shift = np.zeros(rows.b.size)
        for _ in range(MAX_ROUNDS):
            try:
                answer = self._round(rows, units, responses, session_class, options, X0, shift)
                if answer is None:
                    return None
                sol, w, state_rows, slack, picked, predicted = answer
                dX, dU = responses.apply(state_rows, w)
            except solvers.QPError:
                return None
            X, U = X0 + dX, U0 + dU
            iterations += sol.iterations
            s_path = rows.b - rows.C @ X - rows.E @ slack
            margin = rows.units.margin(s_path)
            if _missed_in(margin[units], rows.units.kind[units], rows.size[units]):
                # A row of the working set is missed on the path itself: the small QP's Sigma is
                # formed without refinement. Solved again with the difference moved into its
                # right-hand side (iterative refinement, the path's slacks as the residual), at most
                # REFINE times; then the full QP decides.
                if refined == REFINE:
                    return None
                refined += 1
                shift[picked] += s_path[picked] - predicted
                continue
            missed = _worst(margin, units, 0.0, rows)
            if missed.size == 0:
                self._bound = units[(margin[units] < BOUND) & rows.on_state[units]]
                return solvers.QPSolution(
                    status=sol.status,
                    backend=sol.backend,
                    raw_status=sol.raw_status,
                    x=self._vector(X, U, slack),
                    iterations=iterations,
                    info={"condensed": {"rows": int(state_rows.size), "units": int(units.size)}},
                )
            units = np.union1d(units, missed)
        return None

    def observe(self, extra: ExtraRows, states: np.ndarray) -> None:
        """Learn the units on the states that bind ``states`` (``(T, 6)``, the full QP's answer to
        ``extra``): the next condensed solve starts from them, or is not tried if they are too many.
        (A slack's own ``s >= 0`` joins with the rows it relaxes.)"""
        rows = self._use(extra)
        margin = rows.units.margin(rows.b - rows.C @ states.ravel())
        self._bound = np.flatnonzero((margin < BOUND) & rows.on_state)

    def _use(self, extra: ExtraRows) -> CondensedRows:
        """The split rows of ``extra``, made when the rows change."""
        if extra is not self._extra:
            shape = None if self._extra is None else [(c.kind, c.dim) for c in self._extra.cones]
            if shape != [(c.kind, c.dim) for c in extra.cones]:
                # Rows of another shape: the last answer's binding units say nothing about them. (Rows
                # of the same shape, such as visits moved to other steps, keep them as a first guess.)
                self._bound = np.zeros(0, dtype=int)
            self._extra, self._rows = extra, CondensedRows(extra, self.layout)
        assert self._rows is not None
        return self._rows

    def _round(
        self,
        rows: CondensedRows,
        units: np.ndarray,
        responses: Responses,
        session_class: type[solvers.QPSession],
        options: dict[str, Any],
        X0: np.ndarray,
        shift: np.ndarray,
    ) -> tuple[solvers.QPSolution, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """Solve the small QP of the rows of ``units`` (their right-hand sides moved by ``shift``): the
        backend's solution, ``w`` and the rows it belongs to, the full slack vector, the rows of the
        small QP and their slacks in it; ``None`` if the backend did not solve it."""
        E = rows.E
        picked = rows.units.rows(units)
        E_picked = E[picked]
        slacks = np.unique(E_picked.indices)
        own = rows.slack_unit[slacks]
        own = own[(own >= 0) & ~np.isin(own, units)]
        if own.size:  # the slacks' own rows s >= 0
            units = np.union1d(units, own)
            picked = rows.units.rows(units)
            E_picked = E[picked]
        on_state = rows.has_state[picked]
        state_rows = picked[on_state]
        k, p = state_rows.size, slacks.size
        if k > MAX_DEPENDENT_ROWS:
            return None
        if k + p == 0:  # no row in the working set: the unconstrained optimum, exact
            none = solvers.QPSolution(solvers.Status.OPTIMAL, "banded", "exact", x=np.zeros(0))
            return none, np.zeros(0), state_rows, np.zeros(E.shape[1]), picked, np.zeros(picked.size)
        C_picked = rows.C[picked]
        # The cost 1/2 w' Sigma w written as 1/2 |v|^2 with v = R D^-1 w, R'R = D Sigma D (D the
        # Jacobi scaling): an identity Hessian and triangular rows keep the small QP's KKT system sparse.
        # Rows that depend on each other (the rows of a polygon standing for one cone are combinations
        # of its two rows on the path) make Sigma singular: they are written on a basis of independent
        # ones, C_S = T C_J, and Sigma_J takes Sigma's place.
        basis, T = np.arange(k), None
        if k > MAX_ROWS:  # more rows than a small QP takes, unless they depend on each other
            basis, T = row_basis(rows.C[state_rows])
            if basis.size > (MAX_ROWS if T is None else MAX_BASIS):
                return None
        sigma = responses.sigma(state_rows[basis])
        root, d = factor_sigma(sigma)
        if T is None and (root is None or np.min(np.diag(root[0])) ** 2 <= PIVOT):
            basis, T = row_basis(rows.C[state_rows])
            if T is not None:
                sigma = sigma[np.ix_(basis, basis)]
            root, d = factor_sigma(sigma, exact=False) if T is not None or root is None else (root, d)
        if root is None:  # Sigma singular to working precision: the full QP takes the rows
            return None
        F, back = root
        r = F.shape[1]
        P = sp.diags(np.concatenate([np.ones(r), np.zeros(p)]), format="csc")
        q = np.zeros(r + p)
        assert self._extra is not None
        q[r:] = self._extra.slack_cost[slacks]
        A = np.zeros((picked.size, r + p))
        A[on_state, :r] = F / d[:, None] if T is None else T @ (F / d[:, None])
        A[:, r:] = E_picked[:, slacks].toarray()
        problem = solvers.QPProblem(
            P=P,
            q=q,
            A=sp.csc_matrix(A),
            b=rows.b[picked] - C_picked @ X0 + shift[picked],
            cones=tuple(rows.units.cones(units)),
        )
        key = (picked.tobytes(), A.shape)
        try:
            session = session_class(problem, **options)
            session.budget = self._budget
            if self._duals.size != rows.b.size:
                self._duals = np.zeros(rows.b.size)
            # A first-order backend's iterations start from the rows' last duals (a round of the
            # same M-step with fewer rows, or the last M-step) and, for the same rows as the last
            # small QP (most M-steps after the first), from its primal answer too.
            last = self._warm[2] if self._warm is not None and self._warm[:2] == key else None
            session.warm_start(last, self._duals[picked])
            sol, _ = solvers.retry_failed(session.solve(), options, self.retries, _continued(session))
        except solvers.SettingsError:
            return None
        if not sol.ok or sol.x is None:
            return None
        self._warm = (key[0], key[1], sol.x)
        if sol.y is not None and sol.y.size == picked.size:
            self._duals[picked] = sol.y
        slack = np.zeros(E.shape[1])
        slack[slacks] = sol.x[r:]
        predicted = problem.b - problem.A @ sol.x
        return sol, d * back(sol.x[:r]), state_rows[basis], slack, picked, predicted

    def _vector(self, X: np.ndarray, U: np.ndarray, slack: np.ndarray) -> np.ndarray:
        """The full QP's variable vector: per step ``[x_t / units, u_t]``, then the slacks."""
        body = np.empty((self.T, BLOCK))
        body[:, :STATE_DIM] = X.reshape(self.T, STATE_DIM) / self.layout.units
        body[:, STATE_DIM:] = U.reshape(self.T, STATE_DIM)
        return np.concatenate([body.ravel(), slack])


def _continued(session: solvers.QPSession) -> Callable[[dict[str, Any]], solvers.QPSolution]:
    """A retry of ``session``'s solve with other settings: continued from its iterate where the
    backend can (:meth:`solvers.QPSession.resume`), else a new session."""

    def attempt(settings: dict[str, Any]) -> solvers.QPSolution:
        changed = {k: v for k, v in settings.items() if session.settings.get(k) != v}
        resumed = session.resume(**changed)
        if resumed is not None:
            return resumed
        fresh = type(session)(session.problem, **settings)
        fresh.budget = session.budget
        return fresh.solve()

    return attempt


def _worst(margin: np.ndarray, exclude: np.ndarray, fraction: float, rows: CondensedRows) -> np.ndarray:
    """The units outside ``exclude`` violated by more than their tolerance (:data:`MET`, and the
    rounding of slacks formed from numbers of ``rows.size``) and by at least ``fraction`` times the
    worst of them (none if none is violated), the most violated of each group of ``rows`` only."""
    violation = -margin - (MET + ROUNDING * rows.size)
    violation[exclude] = 0.0
    worst = float(violation.max(initial=0.0))
    if worst <= 0.0:
        return np.zeros(0, dtype=int)
    out = np.flatnonzero(violation >= max(fraction * worst, np.finfo(float).tiny))
    return most_violated(out, margin, rows.group)


def _missed_in(margin: np.ndarray, kind: np.ndarray, size: np.ndarray) -> bool:
    """Whether a unit of the working set is missed on the returned path: by more than :data:`MET`
    (plus rounding) for inequalities and cones, which are imposed backed off inside their bounds, and
    by more than rounding for an equality, which has no back-off to absorb a miss (a terminal
    acceleration of zero is verified to 1e-11)."""
    least = np.where(kind == 0, 0.0, MET) + ROUNDING * np.maximum(size, 1.0)
    return bool(np.any(-margin > least))
