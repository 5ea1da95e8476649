"""The M-step: the smoothing problem posed as a sparse convex QP, and its Kalman cross-check.

Given the E-step's weights, the M-step (SPEC section 2, paper eqs 13-16) minimises over the paths

    J(X) = 1/2 sum_{t,m} ||u_t^m||^2 + sum_{t,m} W[t,m] / (2 r) ||H x_t^m - ztilde[t,m]||^2

with ``x_t = F x_{t-1} + L u_t`` (``L L' = Q``), ``x_0`` known. Writing the process noise as an explicit
variable ``u`` scaled by the Cholesky factor of ``Q`` gives an identity Hessian on ``u`` and the
penalty weights ``W / r`` on the positions; the alternative with ``Q^-1`` in the Hessian (entries near
1e10 against 1e2) is so badly conditioned that solvers report success several units from the answer
(SPEC section 6).

Without coupling constraints the QP separates by platform, so each platform is its own QP. Its
variables, per step ``t = 1..T``, are a block of 12, ``[x_t (6), u_t (6)]``, at offset ``12 (t - 1)``;
its constraints ``x_t - F x_{t-1} - L u_t = 0`` (``x_1 - L u_1 = F x_0``). Each QP is built once per
plan; an iteration changes only the diagonal of ``P`` and ``q``.

Backends:

* ``clarabel``, ``osqp``: that QP through :mod:`solvers`, updated in place.
* ``cvxpy``: the same problem written in cvxpy, any installed cvxpy solver; compiled once with the
  weights as parameters (DPP) when unconstrained, compiled per iteration when constrained.
* ``kalman``: a Rauch-Tung-Striebel smoother on the synthetic measurements ``ztilde = WZ / W`` with
  covariance ``R / W`` (eqs 15-16), run per axis; the reference for the others.
"""

from __future__ import annotations

import abc
import importlib.util
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.constraints.assemble import ExtraRows, Imposed, assemble
from pmht_opt.constraints.base import Constraint, ConstraintContext
from pmht_opt.exceptions import ConfigError, InfeasibleError, SolverError, UnknownSolverError
from pmht_opt.model import PX, PY, STATE_DIM, MotionModel
from pmht_opt.scenario import Scenario
from solvers.kalman import rts_smoother

BLOCK = 2 * STATE_DIM  # [x_t, u_t]

#: Backend options this module uses unless the caller overrides them. OSQP: residuals of the dynamics
#: integrate into positions over hundreds of steps (roughly like T^2.5), so ADMM must run to 1e-9;
#: with rho = 1 it gets there in fewer iterations than with its default, and polishing needed about
#: 60 refinement steps for the same accuracy, which cost more. Measured on scenarios A-C (seed 1):
#: <= 1.3e-12 from RTS after one iteration; 1.6-2.9 s per 100-iteration plan.
BACKEND_DEFAULTS: dict[str, dict[str, Any]] = {
    "osqp": {
        "eps_abs": 1e-9,
        "eps_rel": 1e-9,
        "rho": 1.0,
        "polishing": False,
        "check_termination": 10,
    },
    # Iterative refinement of the KKT solves roughly doubles the time of a constrained M-step (12-13
    # interior-point iterations; measured 3.4 s against 1.9 s for 20 iterations of scenario A with a
    # speed limit and area bounds) and is not needed: without it the unconstrained answer is still
    # within 4e-10 of RTS, and constraint violations stay below 1e-9.
    "clarabel": {"iterative_refinement_enable": False},
}


#: Settings for retries, tried in turn, when a solve fails without an infeasibility verdict (each a
#: fresh setup; a set that touches a setting the caller chose is skipped).
#:
#: * Clarabel without iterative refinement (the fast default above) can stop with
#:   'InsufficientProgress' on ill-scaled constrained M-steps (seen with VisitAll while annealing,
#:   r = 0.3); with refinement it solves them.
#: * OSQP with adaptive rho can stall on the M-step where VisitAll is first imposed: the visits force
#:   a manoeuvre (process noise up to 110 against 1.3 unconstrained, positions moved 1.7 units) and
#:   ADMM was still 1.8 units from the answer after 50 000 iterations (B seeds 0 and 2, 2 of 12 full
#:   runs on A, B, C seeds 0-3). A fixed rho = 100 solved both in about 20 000 iterations with
#:   polishing, to 2e-4 of Clarabel (B seed 0, a degenerate optimum: equal objective) and 3e-6;
#:   rho = 30 solved both too, more slowly.
FALLBACK_SETTINGS: dict[str, tuple[dict[str, Any], ...]] = {
    "clarabel": ({"iterative_refinement_enable": True},),
    "osqp": ({"rho": 100.0, "adaptive_rho": False}, {"rho": 30.0, "adaptive_rho": False}),
}

#: Option sets for Clarabel through cvxpy on the unconstrained M-step, tried in turn while the answer
#: is 'optimal_inaccurate' (user settings override each): Clarabel's defaults, then a smaller static
#: regularisation, then no equilibration. cvxpy's form keeps the raw penalty weights and its answers
#: are less precise than the clarabel backend's: about 1e-9 from RTS at r = 0.01 but 2e-4 at r = 1
#: (the start of annealing), and some iterations (A seeds 0/1 while annealing, B seed 2 plain) end
#: 'almost solved' with the defaults; the later sets solve those. Putting the smaller regularisation
#: first is more precise per solve but on A seed 1 returned an answer that lowered the EM objective
#: (0.41 at iteration 45) while reporting optimal, so it is only a fallback.
CVXPY_CLARABEL_CHAIN: tuple[dict[str, Any], ...] = (
    {},
    {"static_regularization_constant": 1e-10},
    {"equilibrate_enable": False},
)


#: Backend options for platforms whose M-step has constraint rows (inequalities). OSQP: at 1e-9 ADMM
#: needs tens of thousands of iterations with inequality rows; at 1e-5 with polishing it returns
#: 'solved' on limits, bounds, obstacles and terminal conditions, but not reliably on VisitAll
#: (``check_dualgap`` off: OSQP 1.1's duality-gap test is what kept it at 'solved inaccurate').
#: Polishing recovers the exact answer when ADMM found the active set (visits, terminal conditions,
#: most obstacle steps), but rarely on speed limits, where
#: positions stay about 1e-3 from the optimum and violations at the ADMM tolerance; use clarabel for
#: exact constrained plans.
CONSTRAINED_DEFAULTS: dict[str, dict[str, Any]] = {
    "osqp": {
        "eps_abs": 1e-5,
        "eps_rel": 1e-5,
        "rho": 1.0,
        "polishing": True,
        "polish_refine_iter": 10,
        "check_dualgap": False,
        "check_termination": 25,
    },
    "clarabel": BACKEND_DEFAULTS["clarabel"],
}


@dataclass
class MStepData:
    """What the M-step needs from the E-step: ``W (T, M)``, ``WZ (T, M, 2)`` and the penalty ``r``."""

    W: np.ndarray
    WZ: np.ndarray
    r: float
    ctx: ConstraintContext | None = None

    def synthetic(self) -> tuple[np.ndarray, np.ndarray]:
        """Synthetic measurements ``WZ / W`` (zero where ``W == 0``) and their weights ``W``."""
        W = self.W
        with np.errstate(invalid="ignore", divide="ignore"):
            zt = np.where(W[..., None] > 0, self.WZ / W[..., None], 0.0)
        return zt, W


@dataclass
class MStepOutput:
    """Paths ``(M, T+1, 6)`` including ``t = 0``, and how the solve went."""

    states: np.ndarray
    iterations: int = 0
    status: str = "optimal"
    info: dict[str, Any] = field(default_factory=dict)


def mstep_objective(model: MotionModel, states: np.ndarray, data: MStepData) -> float:
    """``J(X)`` of the module docstring, without terms constant in ``X``; smaller is better."""
    u = model.process_noise(states)
    pos = states[:, 1:, [PX, PY]].transpose(1, 0, 2)  # (T, M, 2)
    fit = 0.5 * np.sum(data.W[..., None] * pos * pos) - np.sum(data.WZ * pos)
    return float(0.5 * np.sum(u * u) + fit / data.r)


class MStep(abc.ABC):
    """One backend of the M-step, built for one scenario and reused across EM iterations."""

    name: ClassVar[str] = ""

    def __init__(
        self,
        scenario: Scenario,
        settings: dict[str, Any] | None = None,
        accept_inaccurate: bool = False,
        constraints: tuple[Constraint, ...] = (),
    ) -> None:
        self.scenario = scenario
        self.constraints = tuple(constraints)
        self.model = scenario.model
        self.settings = dict(settings or {})
        self.accept_inaccurate = accept_inaccurate
        self.T = scenario.horizon
        self.M = scenario.n_platforms
        self.x0 = scenario.initial_states
        #: Whether the backend takes second-order cones (else constraints give inner polygons).
        self.conic = True
        self._static: dict[tuple[int, bool], list[Imposed]] = {}

    @abc.abstractmethod
    def solve(self, data: MStepData) -> MStepOutput:
        """Minimise ``J`` for these weights, subject to the constraints active in ``data.ctx``."""

    def imposed(self, ctx: ConstraintContext | None) -> dict[int, list[Imposed]]:
        """Blocks of the constraints active at ``ctx.iteration``, per platform."""
        out: dict[int, list[Imposed]] = {}
        if ctx is None:
            return out
        for con in self.constraints:
            if not con.active(ctx.iteration, ctx.max_iter, ctx.settled):
                continue
            if con.dynamic:
                items = [Imposed.of(blk, con) for blk in con.blocks(ctx)]
            else:
                # The same rows every iteration: written once, and the very same objects handed out
                # again, so a platform QP can tell that nothing changed and skip re-assembling them.
                key = (id(con), ctx.conic)
                if key not in self._static:
                    self._static[key] = [Imposed.of(blk, con) for blk in con.blocks(ctx)]
                items = self._static[key]
            for item in items:
                out.setdefault(item.block.platform, []).append(item)
        return out

    def close(self) -> None:  # noqa: B027 - most backends hold nothing to release
        """Release threads or solver workspaces held by this backend."""

    def _with_start(self, body: np.ndarray) -> np.ndarray:
        """Prepend the known initial states to ``(M, T, 6)`` paths."""
        return np.concatenate([self.x0[:, None, :], body], axis=1)


class KalmanMStep(MStep):
    """RTS smoother per platform and axis on the synthetic measurements (the cross-check)."""

    name: ClassVar[str] = "kalman"

    def solve(self, data: MStepData) -> MStepOutput:
        zt, W = data.synthetic()
        model = self.model
        # The x and y axes share F3, Q3 and R / W: one covariance recursion per platform, two means.
        x0 = np.stack([self.x0[:, 0:3], self.x0[:, 3:6]], axis=-1)  # (M, 3, 2)
        res = rts_smoother(
            F=model.F3,
            Q=model.Q3,
            H=np.array([[1.0, 0.0, 0.0]]),
            R=np.array([[data.r]]),
            x0=x0,
            P0=np.zeros((self.M, 3, 3)),
            y=zt.transpose(1, 0, 2)[:, :, None, :],
            weight=W.T,
        )
        means = res.means  # (M, T+1, 3, 2)
        states = np.concatenate([means[..., 0], means[..., 1]], axis=2)
        return MStepOutput(states=states, iterations=0, status="optimal")


class QPLayout:
    """Index arithmetic of the M-step QP's variable vector."""

    def __init__(self, n_platforms: int, horizon: int) -> None:
        self.M = n_platforms
        self.T = horizon
        self.n = BLOCK * n_platforms * horizon

    def x(self, m: Any, t: Any, comp: Any) -> Any:
        """Index of state component ``comp`` of platform ``m`` at time ``t`` (``1..T``)."""
        return BLOCK * (np.asarray(m) * self.T + np.asarray(t) - 1) + np.asarray(comp)

    def u(self, m: Any, t: Any, comp: Any) -> Any:
        """Index of noise component ``comp`` of platform ``m`` at time ``t`` (``1..T``)."""
        return self.x(m, t, comp) + STATE_DIM

    def states(self, xvec: np.ndarray) -> np.ndarray:
        """``(M, T, 6)`` states from a solution vector."""
        return xvec.reshape(self.M, self.T, BLOCK)[:, :, :STATE_DIM]


def dynamics_rows(model: MotionModel, layout: QPLayout, x0: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
    """Equality rows ``x_t - F x_{t-1} - L u_t = 0`` (``= F x_0`` at ``t = 1``) for every platform.

    The velocity rows are multiplied by ``T / 5`` and the acceleration rows by ``(T / 5)^2``. This is the
    same constraint, but it changes what a solver's residual tolerance means: a residual ``e`` left in a
    velocity row at step ``s`` moves every later position by ``(t - s) e``, and one in an acceleration
    row by ``(t - s)^2 e / 2``, so unscaled rows let an ``eps``-accurate solve drift in position by
    orders of magnitude more than ``eps`` (measured with OSQP at 1e-9: 1e-7 position errors, 1e-9
    with the scaling).
    """
    M, T = layout.M, layout.T
    F, L = model.F, model.L
    m_grid, t_grid = np.meshgrid(np.arange(M), np.arange(1, T + 1), indexing="ij")
    m_idx, t_idx = m_grid.ravel(), t_grid.ravel()
    row0 = STATE_DIM * (m_idx * T + t_idx - 1)
    rows, cols, vals = [], [], []
    for i in range(STATE_DIM):
        rows.append(row0 + i)
        cols.append(layout.x(m_idx, t_idx, i))
        vals.append(np.ones(row0.size))
        for j in range(STATE_DIM):
            if L[i, j] != 0.0:
                rows.append(row0 + i)
                cols.append(layout.u(m_idx, t_idx, j))
                vals.append(np.full(row0.size, -L[i, j]))
            if F[i, j] != 0.0:
                later = t_idx > 1
                rows.append(row0[later] + i)
                cols.append(layout.x(m_idx[later], t_idx[later] - 1, j))
                vals.append(np.full(int(later.sum()), -F[i, j]))
    n_rows = STATE_DIM * M * T
    A = sp.csc_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n_rows, layout.n)
    )
    b = np.zeros(n_rows)
    first = (STATE_DIM * (np.arange(M) * T))[:, None] + np.arange(STATE_DIM)[None, :]
    b[first] = x0 @ F.T
    horizon = max(T / 5.0, 1.0)
    row_scale = np.tile(np.array([1.0, horizon, horizon**2, 1.0, horizon, horizon**2]), M * T)
    return (sp.diags(row_scale) @ A).tocsc(), row_scale * b


class PlatformQP:
    """The M-step QP of one platform: built once, its weights updated in place each iteration.

    Constraint rows (:mod:`pmht_opt.constraints`) go below the dynamics, soft constraints' slacks after
    the platform's own variables. While their structure stays the same from one iteration to the next
    (speed limits, area bounds, obstacle half-planes) only the numbers are pushed to the backend; when
    it changes (a visit moves to another time step) the backend session is set up afresh.

    The backend session is created at the first solve, with real weights: both backends compute
    their scaling (equilibration) at setup, and a setup with every position weight at zero leaves
    Clarabel badly scaled for every later update (measured: 5 IPM iterations and 7e-6 errors instead
    of a direct solve to 1e-11).
    """

    def __init__(
        self,
        model: MotionModel,
        x0: np.ndarray,
        horizon: int,
        session_class: type[solvers.QPSession],
        settings: dict[str, Any],
        constrained_settings: dict[str, Any] | None = None,
        fallback_settings: tuple[dict[str, Any], ...] = (),
    ) -> None:
        self.layout = lay = QPLayout(1, horizon)
        self.session_class = session_class
        self.settings = settings
        self.constrained_settings = settings if constrained_settings is None else constrained_settings
        self.fallback_settings = fallback_settings
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
        self.A_dyn, self.b_dyn = dynamics_rows(model, lay, x0[None, :])
        self.problem: solvers.QPProblem | None = None
        self.session: solvers.QPSession | None = None
        self.extra: ExtraRows | None = None
        self._key: tuple[object, ...] | None = None
        self._imposed: list[Imposed] = []

    def _P(self, n_slack: int) -> sp.csc_matrix:
        # CSC arrays by hand so the position entries stay stored while their weight is zero; slack
        # columns (if any) are empty.
        n = self.layout.n
        stored = np.zeros(n, dtype=bool)
        stored[self.stored] = True
        indptr = np.concatenate([[0], np.cumsum(stored), np.full(n_slack, stored.sum())])
        return sp.csc_matrix((self.diag[self.stored], self.stored, indptr), shape=(n + n_slack, n + n_slack))

    def _cost(self, W: np.ndarray, WZ: np.ndarray, r: float, extra: ExtraRows | None) -> np.ndarray:
        scale = 1.0 / r
        self.diag[self.px] = W * scale
        self.diag[self.py] = W * scale
        q = np.zeros(self.layout.n)
        q[self.px] = -WZ[:, 0] * scale
        q[self.py] = -WZ[:, 1] * scale
        return q if extra is None or extra.n_slack == 0 else np.concatenate([q, extra.slack_cost])

    def _constraints(
        self, extra: ExtraRows | None
    ) -> tuple[sp.csc_matrix, np.ndarray, tuple[solvers.Cone, ...]]:
        zero = solvers.Zero(self.A_dyn.shape[0])
        if extra is None:
            return self.A_dyn, self.b_dyn, (zero,)
        A_dyn = self.A_dyn
        if extra.n_slack:
            indptr = np.concatenate([A_dyn.indptr, np.full(extra.n_slack, A_dyn.indptr[-1])])
            A_dyn = sp.csc_matrix(
                (A_dyn.data, A_dyn.indices, indptr), shape=(A_dyn.shape[0], extra.A.shape[1])
            )
        A = sp.vstack([A_dyn, extra.A], format="csc")
        A.sort_indices()
        return A, np.concatenate([self.b_dyn, extra.b]), (zero, *extra.cones)

    def solve(
        self, W: np.ndarray, WZ: np.ndarray, r: float, imposed: list[Imposed] | None = None
    ) -> solvers.QPSolution:
        """Solve for weights ``W (T,)``, weighted locale sums ``WZ (T, 2)`` and constraint blocks."""
        imposed = imposed or []
        unchanged = (
            self.session is not None
            and len(imposed) == len(self._imposed)
            and all(a is b for a, b in zip(imposed, self._imposed, strict=True))
        )
        self._imposed = list(imposed)
        if unchanged:  # the same constraint rows as last time: only the weights moved
            q = self._cost(W, WZ, r, self.extra)
            assert self.session is not None
            self.session.update(P_data=self.diag[self.stored], q=q)
            return self._fallback(self.session.solve(), q)
        extra = assemble(imposed, self.layout.n, self.col_map) if imposed else None
        self.extra = extra
        key = None if extra is None else (extra.n_slack, *extra.pattern_key())
        q = self._cost(W, WZ, r, extra)
        A, b, cones = self._constraints(extra)
        if self.session is None or key != self._key:
            self._key = key
            self.problem = solvers.QPProblem(
                P=self._P(0 if extra is None else extra.n_slack), q=q, A=A, b=b, cones=cones
            )
            try:
                options = self.settings if extra is None else self.constrained_settings
                self.session = self.session_class(self.problem, **options)
            except solvers.SettingsError as err:
                raise ConfigError(f"solver_settings: {err}") from err
            except solvers.QPError as err:
                raise SolverError(f"cannot set up the M-step QP: {err}") from err
        elif extra is None:
            self.session.update(P_data=self.diag[self.stored], q=q)
        else:
            self.session.update(P_data=self.diag[self.stored], q=q, A_data=A.data, b=b)
        return self._fallback(self.session.solve(), q)

    def _fallback(self, sol: solvers.QPSolution, q: np.ndarray) -> solvers.QPSolution:
        """Re-solve with the backend's slower, more robust settings, in turn, if the fast ones failed.

        Only for failures that are not a verdict on the problem (not infeasible): e.g. Clarabel's
        ``InsufficientProgress`` without iterative refinement (see :data:`FALLBACK_SETTINGS`). The
        set that solves is kept for this platform's later solves (its session, warm, replaces the
        failed one), so a run does not pay for the failing settings every iteration. (Measured on
        OSQP with VisitAll, B seed 2: going back to the fast settings, warm-started from the
        fallback's answer, failed 8 more times and took 229 s; keeping the set took 156 s.) The answer
        records the set in ``info["fallback"]``; if none solves, the first failure is returned.
        """
        if not self.fallback_settings or sol.usable(False) or sol.status in solvers.INFEASIBLE:
            return sol
        A, b, cones = self._constraints(self.extra)
        n_slack = 0 if self.extra is None else self.extra.n_slack
        problem = solvers.QPProblem(P=self._P(n_slack), q=q, A=A, b=b, cones=cones)
        options = self.settings if self.extra is None else self.constrained_settings
        for extra in self.fallback_settings:
            if extra.items() <= options.items():
                continue  # already in use: it is what just failed
            merged = {**options, **extra}
            session = self.session_class(problem, **merged)
            retry = session.solve()
            if retry.usable(False):
                retry.info["fallback"] = extra
                retry.info["first_status"] = sol.raw_status
                self.problem, self.session = problem, session
                if self.extra is None:
                    self.settings = merged
                else:
                    self.constrained_settings = merged
                return retry
        return sol

    def slacks(self, x: np.ndarray) -> np.ndarray:
        """The soft constraints' slack values in a solution vector."""
        return x[self.layout.n :]


class QPMStep(MStep):
    """The M-step QP through a :mod:`solvers` backend (``osqp`` or ``clarabel``).

    Without coupling constraints the QP separates by platform, so each platform is its own QP
    (:class:`PlatformQP`), and the platforms are solved concurrently on ``threads`` threads (both
    backends release the GIL while they solve). Every constraint kind binds one platform at a time,
    so constraints keep this separation.
    """

    name: ClassVar[str] = "qp"

    def __init__(
        self,
        scenario: Scenario,
        settings: dict[str, Any] | None = None,
        accept_inaccurate: bool = False,
        solver: str = "clarabel",
        threads: int = 1,
        constraints: tuple[Constraint, ...] = (),
    ) -> None:
        super().__init__(scenario, settings, accept_inaccurate, constraints)
        self.solver = solver
        try:
            session_class = solvers.get_session_class(solver)
        except solvers.UnknownSolverError as err:
            raise UnknownSolverError(str(err)) from err
        self.session_class = session_class
        self.conic = session_class.supports_soc
        self.options = {**BACKEND_DEFAULTS.get(solver, {}), **self.settings}
        self.constrained_options = {**CONSTRAINED_DEFAULTS.get(solver, {}), **self.settings}
        # Sets touching a setting the caller chose are skipped: do not second-guess the caller.
        fallback = tuple(f for f in FALLBACK_SETTINGS.get(solver, ()) if not set(f) & set(self.settings))
        self.blocks = [
            PlatformQP(
                self.model,
                self.x0[m],
                self.T,
                session_class,
                self.options,
                self.constrained_options,
                fallback,
            )
            for m in range(self.M)
        ]
        self.threads = max(1, min(int(threads), self.M))
        self._pool: ThreadPoolExecutor | None = None

    def solve(self, data: MStepData) -> MStepOutput:
        imposed = self.imposed(data.ctx)
        # A platform with no weight and no constraint has the unique answer u = 0 (it coasts from its
        # start); first-order solvers struggle on this degenerate QP (its dual residual has no scale),
        # so the answer is written down instead of solved for.
        idle = ~np.any(data.W > 0, axis=0)
        for m in imposed:
            idle[m] = False
        active = [int(m) for m in np.flatnonzero(~idle)]

        def one(m: int) -> solvers.QPSolution:
            return self.blocks[m].solve(data.W[:, m], data.WZ[:, m], data.r, imposed.get(m))

        if self.threads > 1 and len(active) > 1:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="pmht-mstep")
            sols = list(self._pool.map(one, active))
        else:
            sols = [one(m) for m in active]
        body = np.empty((self.M, self.T, STATE_DIM))
        for m in np.flatnonzero(idle).tolist():
            body[m] = self.model.propagate(self.x0[m], self.T)[1:]
        for m, sol in zip(active, sols, strict=True):
            if sol.status in solvers.INFEASIBLE and imposed.get(m):
                raise self._diagnose(m, data, imposed[m], sol)
            check_solution(sol, self.accept_inaccurate, platform=m)
            assert sol.x is not None
            body[m] = self.blocks[m].layout.states(sol.x[: self.blocks[m].layout.n])[0]
        status = "optimal"
        if sols:
            status = max(
                sols, key=lambda s: (s.status is not solvers.Status.OPTIMAL, s.iterations)
            ).raw_status
        return MStepOutput(
            states=self._with_start(body),
            iterations=int(sum(s.iterations for s in sols)),
            status=status,
            info={"fallbacks": sum("fallback" in s.info for s in sols)},
        )

    def _diagnose(
        self, m: int, data: MStepData, imposed: list[Imposed], sol: solvers.QPSolution
    ) -> InfeasibleError:
        """Name the constraints that cannot be met on platform ``m``: re-solve with every block soft and
        see which slacks stay positive."""
        probe = PlatformQP(
            self.model, self.x0[m], self.T, self.session_class, self.options, self.constrained_options
        )
        names = sorted({i.name for i in imposed if not i.soft})
        where = f"platform {m}: the constraints {', '.join(names)} cannot all be met"
        try:
            relaxed = probe.solve(
                data.W[:, m], data.WZ[:, m], data.r, [i.relaxed(DIAGNOSIS_WEIGHT) for i in imposed]
            )
        except (SolverError, ConfigError):
            relaxed = None
        if relaxed is None or relaxed.x is None or probe.extra is None:
            return InfeasibleError(
                f"{sol.backend}: {where} (status {sol.raw_status}).", sol.backend, sol.raw_status
            )
        slack = probe.slacks(relaxed.x)
        culprits: dict[str, list[tuple[int, str | None, float]]] = {}
        for value, owner in zip(slack, probe.extra.slack_owner, strict=True):
            if value > 1e-6:
                culprits.setdefault(owner.constraint, []).append((owner.time, owner.label, float(value)))
        if not culprits:
            return InfeasibleError(
                f"{sol.backend}: {where} (status {sol.raw_status}).", sol.backend, sol.raw_status
            )
        parts = []
        for name, hits in sorted(culprits.items(), key=lambda kv: -max(h[2] for h in kv[1])):
            times = sorted({h[0] for h in hits})
            labels = sorted({h[1] for h in hits if h[1]}, key=lambda s: (len(s), s))
            what = f"{name} on platform {m}"
            span = (
                f"t = {times[0]}" if len(times) == 1 else f"{len(times)} steps in t = {times[0]}..{times[-1]}"
            )
            if labels:
                span += " (" + ", ".join(labels[:5]) + (", ..." if len(labels) > 5 else "") + ")"
            parts.append(f"{what} at {span}, short by up to {max(h[2] for h in hits):.3g}")
        return InfeasibleError(
            f"{sol.backend}: infeasible constraints: " + "; ".join(parts) + ". Relax them or pass soft=True.",
            sol.backend,
            sol.raw_status,
        )

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


#: Penalty weight of the soft re-solve that locates infeasible constraints.
DIAGNOSIS_WEIGHT = 1e6


def check_solution(sol: solvers.QPSolution, accept_inaccurate: bool, platform: int | None = None) -> None:
    """Raise the project's error unless the backend stands behind ``sol``."""
    if sol.usable(accept_inaccurate):
        return
    where = "" if platform is None else f" (platform {platform})"
    if sol.status in solvers.INFEASIBLE:
        raise InfeasibleError(
            f"{sol.backend}: the M-step constraints are infeasible{where} (status {sol.raw_status}).",
            backend=sol.backend,
            status=sol.raw_status,
        )
    hint = "" if accept_inaccurate else " (pass accept_inaccurate=True to use inaccurate solutions)"
    raise SolverError(
        f"{sol.backend}: the M-step solve failed{where} with status {sol.raw_status!r}{hint}.",
        backend=sol.backend,
        status=sol.raw_status,
    )


class CvxpyMStep(MStep):
    """The M-step written in cvxpy; any installed cvxpy solver can be chosen.

    ``settings`` may hold ``cvxpy_solver`` (default ``"CLARABEL"``); the rest goes to
    ``cvxpy.Problem.solve``. The variables are exposed as :attr:`states` (one ``(T, 6)`` cvxpy variable
    per platform, rows ``t = 1..T``) and :attr:`noise`.

    Without constraints the weights are parameters and the problem is compiled once (DPP). With
    constraints it is compiled again at every solve, the weights and the iteration's constraint rows
    entering as constants (``ignore_dpp``): cvxpy's parametrised compilation reorders every
    second-order cone through a tensor with one column per (variable, parameter) pair, which for
    scenario A (T = 500, M = 4) and one speed limit took 44 s and 12 GB, and for plan_smoothed's
    visit cones 70 s, whereas a plain compilation takes a fraction of a second per iteration
    (measured: 4 iterations of A with six constraint kinds in 1.4 s).
    :class:`~pmht_opt.constraints.CvxpyConstraint` s are built once with the variables.
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

        from pmht_opt.constraints.user import CvxpyConstraint, CvxpyVariables
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
        #: Option sets tried in turn until one gives an optimal (not inaccurate) answer.
        self.option_chain: list[dict[str, Any]] = [opts]
        if self.cvxpy_solver == "CLARABEL" and self.dpp:
            chain = [{**extra, **opts} for extra in CVXPY_CLARABEL_CHAIN]
            self.option_chain = [o for i, o in enumerate(chain) if o not in chain[:i]]
        self.options = self.option_chain[0]
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
                hard, penalty = con.build(variables)
                rows.extend(hard)
                cost += penalty
        self._base_cost = cost
        self._base_constraints = rows
        self.problem = cp.Problem(cp.Minimize(cost), rows)

    def _build(self, imposed: list[Imposed]) -> None:
        """The problem with this iteration's constraint rows written in as constants."""
        import cvxpy as cp

        cost = self._base_cost
        constraints: list[Any] = list(self._base_constraints)
        for item in imposed:
            blk = item.block
            e = blk.h - sp.csr_matrix(blk.G) @ self._stacked[blk.platform]
            slack = cp.Variable(blk.units, nonneg=True) if item.soft else None
            if slack is not None:
                cost += item.weight * cp.sum(slack)
            if blk.kind == "zero":
                constraints += [e == 0] if slack is None else [e <= slack, -e <= slack]
            elif blk.kind == "nonneg":
                constraints += [e >= 0] if slack is None else [e + slack >= 0]
            else:
                head = e[0 :: blk.dim] if slack is None else e[0 :: blk.dim] + slack
                tail = cp.vstack([e[c :: blk.dim] for c in range(1, blk.dim)])
                constraints.append(cp.SOC(head, tail, axis=0))
        self.problem = cp.Problem(cp.Minimize(cost), constraints)

    def solve(self, data: MStepData) -> MStepOutput:
        from solvers.cvxpy_ import solve_cvxpy_problem

        if not self.dpp:
            self._build([i for items in self.imposed(data.ctx).values() for i in items])
        self._sqrt_w.value = np.sqrt(np.maximum(data.W, 0.0) / data.r)
        self._lin.value = (data.WZ / data.r).reshape(self.T, 2 * self.M)
        iters = 0
        for options in self.option_chain:
            status, raw, _elapsed, more = solve_cvxpy_problem(
                self.problem, "cvxpy", self.cvxpy_solver, options
            )
            iters += more
            if status is not solvers.Status.OPTIMAL_INACCURATE:
                break
        values = [X.value for X in self.states]
        x: np.ndarray | None = None
        if all(v is not None for v in values):
            x = np.stack([np.asarray(v) for v in values])
            if not np.all(np.isfinite(x)):
                x = None
        if x is None and status is solvers.Status.OPTIMAL:
            status = solvers.Status.NUMERICAL_ERROR
        sol = solvers.QPSolution(
            status=status,
            backend=f"cvxpy/{self.cvxpy_solver}",
            raw_status=raw,
            x=None if x is None else x.ravel(),
            iterations=iters,
        )
        if sol.status in solvers.INFEASIBLE and self.constraints:
            names = sorted({c.name for c in self.constraints if not c.soft})
            raise InfeasibleError(
                f"{sol.backend}: the constraints {', '.join(names)} cannot all be met (status {raw}); "
                "the clarabel backend names the platform and time steps. Relax them or pass soft=True.",
                backend=sol.backend,
                status=raw,
            )
        check_solution(sol, self.accept_inaccurate)
        assert x is not None
        return MStepOutput(states=self._with_start(x), iterations=iters, status=raw)


#: M-step backends by name, and the package each needs.
MSTEP_BACKENDS: dict[str, str | None] = {
    "clarabel": "clarabel",
    "osqp": "osqp",
    "kalman": None,
    "cvxpy": "cvxpy",
}


def available_backends() -> list[str]:
    """Names of the M-step backends usable on this machine."""
    return [k for k, pkg in MSTEP_BACKENDS.items() if pkg is None or importlib.util.find_spec(pkg)]


def make_mstep(
    scenario: Scenario,
    solver: str,
    settings: dict[str, Any] | None = None,
    accept_inaccurate: bool = False,
    threads: int = 1,
    constraints: tuple[Constraint, ...] = (),
) -> MStep:
    """Build the M-step backend ``solver`` for ``scenario``.

    Raises
    ------
    UnknownSolverError
        If ``solver`` is not a backend name or its package is not installed; lists those available.
    """
    key = str(solver).lower()
    if key not in MSTEP_BACKENDS:
        raise UnknownSolverError(f"Unknown solver {solver!r}; available: {', '.join(available_backends())}.")
    if key not in available_backends():
        raise UnknownSolverError(
            f"Solver {solver!r} needs the package {MSTEP_BACKENDS[key]!r}, which is not installed; "
            f"available: {', '.join(available_backends())}."
        )
    for con in constraints:
        if key not in con.backends:
            raise ConfigError(
                f"constraints: {con.name} cannot be imposed by the {key} backend; "
                f"use one of {', '.join(sorted(con.backends))}."
            )
    if key == "kalman":
        if settings:
            raise ConfigError(f"solver_settings: the kalman backend takes none, got {sorted(settings)}.")
        return KalmanMStep(scenario, accept_inaccurate=accept_inaccurate)
    if key == "cvxpy":
        return CvxpyMStep(scenario, settings, accept_inaccurate, tuple(constraints))
    return QPMStep(
        scenario, settings, accept_inaccurate, solver=key, threads=threads, constraints=tuple(constraints)
    )
