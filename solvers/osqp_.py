"""OSQP backend (ADMM; equalities and inequalities only, no second-order cones).

Zero-cone rows become ``l = u = b``, non-negative-cone rows ``-inf <= A x <= b``. OSQP's
solution polishing is on by default: on problems whose active set ADMM has found (always the case with
equalities only) it returns the solution of the reduced KKT system, accurate far beyond ``eps_abs``.
Retrying a failed solve with other settings is a policy of the caller (:mod:`solvers.retry`); a
retry that only raises the iteration limit or changes tolerances continues from the stopped iterate
(:meth:`OSQPSession.resume`).

``polish_tolerance`` (a setting of this layer, not OSQP's) is the accuracy a "solved" answer must
have: its residuals must meet the tolerance in the form of OSQP's own termination test (absolute plus
relative, the same number for both), else it is reported as inaccurate (``"solved, not polished"``).
It is for callers that run ADMM only to a loose tolerance and rely on polishing for accuracy: set far
below ADMM's tolerance, it is met by a polished answer whose refinement has converged and by nothing
else (OSQP accepts any polish that lowers both residuals). On an equality-constrained QP polishing is
the solve of the whole KKT system (every equality row is in its active set) refined against the
unregularised matrix: exact to rounding once the refinement has converged.

``work_limit`` (a setting of this layer, not OSQP's) bounds the work of a session on one set of
numbers: iterations times the problem's size (stored entries of ``P`` and ``A`` plus rows and
columns, roughly proportional to the cost of an iteration), summed over the solves since the last
update, however often the solve is resumed. Unlike OSQP's ``time_limit`` it gives the same answer on
any machine and under any load. A :class:`~solvers.session.WorkBudget` set as a session's ``budget``
bounds the work of several sessions together in the same unit.
"""

from __future__ import annotations

import contextlib
import sys
import time
from typing import Any, ClassVar

import numpy as np
import osqp

from solvers.exceptions import ProblemError, SettingsError, UnsupportedProblemError, UpdateError
from solvers.problem import QPSolution, Status
from solvers.quiet import captured, first_line
from solvers.session import QPSession, Update, WorkBudget, work_amount

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


def _said(printed: str) -> str:
    """What OSQP's C code printed about a refusal, as a clause (``""`` if nothing): its first line
    without the ``ERROR in function:`` prefix."""
    line = first_line(printed)
    if line.startswith("ERROR in ") and ":" in line:
        line = line.split(":", 1)[1].strip()
    return f": {line}" if line else ""


def _setup_error(err: Exception, printed: str = "") -> Exception:
    """The layer's error for an ``OSQPException`` at setup: its settings or its data were refused.

    OSQP's C code prints a line naming the offending setting or bound; it is captured
    (:func:`solvers.quiet.captured`) and becomes part of the message.
    """
    name = _error_name(err)
    if err.args and err.args[0] == osqp.SolverError.OSQP_SETTINGS_VALIDATION_ERROR:
        return SettingsError(f"OSQP rejected its settings ({name}){_said(printed)}.")
    return ProblemError(f"OSQP refused the problem ({name}){_said(printed)}.")


#: Settings OSQP changes in place between solves, so that a solve can continue from its iterate.
RESUMABLE = frozenset(
    (
        "max_iter",
        "eps_abs",
        "eps_rel",
        "polishing",
        "polish_refine_iter",
        "check_termination",
        "check_dualgap",
        "polish_tolerance",
    )
)
#: Settings of this layer, not passed to OSQP.
LAYER = frozenset(("work_limit", "polish_tolerance"))


class OSQPSession(QPSession):
    """A problem held by one ``osqp.OSQP`` workspace; updates reuse its factorisation structure."""

    name: ClassVar[str] = "osqp"
    supports_soc: ClassVar[bool] = False

    @property
    def size(self) -> int:
        """The problem's size in the unit of ``work_limit``: entries of ``P`` and ``A``, rows, columns."""
        prob = self.problem
        return int(prob.P.nnz + prob.A.nnz + prob.n + prob.m)

    @property
    def adapts_to_updates(self) -> bool:
        """``True`` while ``rho`` is adaptive (OSQP's default).

        OSQP equilibrates the problem again whenever ``P`` or ``A`` is updated, and its adaptive step
        ``rho`` rebalances the primal and dual residuals for the new numbers; a new setup would only
        drop the warm start of the last iterate. A fixed ``rho`` stays tuned to the numbers it was
        chosen for.
        """
        return bool({**DEFAULTS, **self.settings}.get("adaptive_rho", True))

    def _iteration_room(self) -> int | None:
        """Iterations left under ``work_limit`` and the shared :attr:`budget` (``None``: no limit)."""
        rooms = [b.room(self.size) for b in (self._own, self.budget) if b is not None]
        return min(rooms) if rooms else None

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
        limit = opts.pop("work_limit", None)
        self._work_limit = None if limit is None else work_amount("work_limit", limit)
        self._polish_tol = _tolerance(opts.pop("polish_tolerance", None))
        self._max_iter = int(opts["max_iter"])
        #: This session's own budget on the current numbers (renewed by every update).
        self._own = None if self._work_limit is None else WorkBudget(self._work_limit)
        self._solver = osqp.OSQP()
        lower, upper = self._bounds()
        prob = self.problem
        with captured() as printed:
            try:
                self._solver.setup(prob.P, prob.q, prob.A, lower, upper, **opts)
            except (TypeError, ValueError) as err:
                raise SettingsError(f"OSQP rejected its settings: {err}") from err
            except osqp.OSQPException as err:
                raise _setup_error(err, printed.getvalue()) from err
        self._verbose = bool(opts.get("verbose"))
        if self._verbose:  # asked for: OSQP's header goes where it would have gone
            sys.stdout.write(printed.getvalue())

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
        if self._work_limit is not None:
            self._own = WorkBudget(self._work_limit)
        if kwargs:
            with captured() as printed:
                try:
                    self._solver.update(**kwargs)
                except osqp.OSQPException as err:
                    raise UpdateError(
                        f"OSQP rejected the update ({_error_name(err)}){_said(printed.getvalue())}."
                    ) from err

    def warm_start(self, x: np.ndarray | None = None, y: np.ndarray | None = None) -> bool:
        """Start the next ADMM iterations from ``x`` and ``y`` (OSQP's ``warm_start``; an omitted one
        keeps its current iterate)."""
        prob = self.problem
        kwargs: dict[str, np.ndarray] = {}
        if x is not None:
            kwargs["x"] = _checked_start("x", x, prob.n)
        if y is not None:
            kwargs["y"] = _checked_start("y", y, prob.m)
        if kwargs:
            self._solver.warm_start(**kwargs)
        return True

    def resume(self, **settings: Any) -> QPSolution | None:
        """Continue from the last iterate with ``settings`` changed (only :data:`RESUMABLE` ones;
        otherwise ``None``). ``max_iter`` counts the iterations of this solve."""
        if not set(settings) <= RESUMABLE:
            return None
        if "polish_tolerance" in settings:
            self._polish_tol = _tolerance(settings["polish_tolerance"])
        with captured() as printed:
            try:
                self._solver.update_settings(**{k: v for k, v in settings.items() if k not in LAYER})
            except (TypeError, ValueError) as err:
                raise SettingsError(f"OSQP rejected its settings: {err}") from err
            except osqp.OSQPException as err:
                raise _setup_error(err, printed.getvalue()) from err
        if printed.getvalue().strip():
            # OSQP prints a refused update of its settings and carries on with the old value.
            raise SettingsError(f"OSQP rejected its settings{_said(printed.getvalue())}.")
        self.settings.update(settings)
        self._max_iter = int(settings.get("max_iter", self._max_iter))
        return self.solve()

    def _polished(self, info: Any, x: np.ndarray | None, y: np.ndarray | None) -> bool:
        """Whether a solved answer meets ``polish_tolerance`` (always, without one): its residuals
        (OSQP's, of the polished point if polishing succeeded) within the tolerance in OSQP's form,
        ``eps (1 + the largest of the norms the residual is a difference of)``. An ADMM iterate that
        meets it counts too (a problem whose answer is its starting point: polishing then finds
        nothing to lower and reports a failure)."""
        eps = self._polish_tol
        if eps is None:
            return True
        if x is None or y is None:
            return False
        prob = self.problem
        Px = prob.P @ x + prob.P.T @ x - prob.P.diagonal() * x
        Ax = prob.A @ x
        prim_scale = max(_norm(Ax), _norm(np.clip(Ax, *self._bounds())))
        dual_scale = max(_norm(Px), _norm(prob.A.T @ y), _norm(prob.q))
        return bool(info.prim_res <= eps * (1.0 + prim_scale) and info.dual_res <= eps * (1.0 + dual_scale))

    def _solve(self) -> QPSolution:
        room = self._iteration_room()
        if room is not None:
            if room == 0:
                return QPSolution(
                    status=Status.MAX_ITER,
                    backend=self.name,
                    raw_status="work limit reached",
                    info={"work_limit": self._work_limit},
                )
            self._solver.update_settings(max_iter=min(self._max_iter, room))
        t0 = time.perf_counter()
        # Captured unless asked for: "Solver interrupted" on Ctrl-C, which the status says.
        with contextlib.nullcontext() if self._verbose else captured():
            res = self._solver.solve(raise_error=False)
        elapsed = time.perf_counter() - t0
        info = res.info
        for budget in (self._own, self.budget):
            if budget is not None:
                budget.spend(int(info.iter) * self.size)
        status = _STATUS.get(osqp.SolverStatus(info.status_val), Status.UNKNOWN)
        raw = str(info.status)
        x = None if res.x is None or not np.all(np.isfinite(res.x)) else np.array(res.x)
        if x is None and status is Status.OPTIMAL:
            status = Status.NUMERICAL_ERROR
        if status is Status.OPTIMAL and not self._polished(info, x, res.y):
            status, raw = Status.OPTIMAL_INACCURATE, f"{raw}, not polished"
        return QPSolution(
            status=status,
            backend=self.name,
            raw_status=raw,
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


def _tolerance(value: object) -> float | None:
    """``polish_tolerance`` checked: ``None`` or a positive finite number."""
    if value is None:
        return None
    return work_amount("polish_tolerance", value)


def _norm(v: np.ndarray) -> float:
    return float(np.max(np.abs(v), initial=0.0))


def _checked_start(name: str, values: np.ndarray, size: int) -> np.ndarray:
    """A starting point of ``size`` finite numbers, or :class:`ProblemError` naming it."""
    arr = np.asarray(values, dtype=float).reshape(-1)
    if arr.shape[0] != size or not np.all(np.isfinite(arr)):
        raise ProblemError(f"warm start {name}: expected {size} finite numbers, got {arr.shape[0]}.")
    return arr
