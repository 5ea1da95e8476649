"""The PMHT planner: EM over locale-to-(platform, time) assignments (SPEC section 2).

One iteration is an E-step (weights from the current paths and priors, eq. 9), the prior updates (eqs
11, 12; each switchable) and an M-step (the smoothing problem, eqs 13-16). The EM objective

    L(X, Pi) = log P(X) + sum_n log sum_{t,m} pi^tau[n,t] pi^k[n,m] zeta(z_n | x_t^m)

(``log P(X)`` without its constant normaliser) never decreases from one iteration to the next without
extra constraints; the history records it after every iteration.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmht_opt.anneal import Anneal, as_anneal
from pmht_opt.constraints.base import Constraint, ConstraintContext
from pmht_opt.estep import EStepResult, estep, gate_margin, safe_log
from pmht_opt.exceptions import ConfigError, ScenarioError, UnknownSolverError
from pmht_opt.model import POS, STATE_DIM
from pmht_opt.mstep import MSTEP_BACKENDS, MStep, MStepData, available_backends, make_mstep
from pmht_opt.result import IterationHistory, PlanResult
from pmht_opt.scenario import Scenario


@dataclass
class PMHTConfig:
    """Settings of :func:`plan_pmht`.

    Parameters
    ----------
    solver
        M-step backend: ``"clarabel"`` (default), ``"osqp"``, ``"cvxpy"`` or ``"kalman"``.
    max_iter
        Maximum number of EM iterations (the paper: 100).
    tol
        Stop when the relative change of the EM objective between iterations falls below ``tol``;
        ``0`` runs exactly ``max_iter`` iterations.
    update_time_prior
        Re-estimate ``pi^tau`` each iteration (eq. 11). Off by default: measured on scenarios A-C, the
        update collapses each locale's time prior onto one time within a few iterations and platforms
        with no locale left fly out of the area under constant acceleration (SPEC section 6); the
        paper's literal setting is ``True``.
    update_platform_prior
        Re-estimate ``pi^k`` each iteration (eq. 12).
    solver_settings
        Options passed verbatim to the backend (e.g. ``{"eps_abs": 1e-8}`` for OSQP,
        ``{"cvxpy_solver": "SCS"}`` for cvxpy).
    accept_inaccurate
        Use solutions the backend flags as inaccurate instead of raising :class:`SolverError`.
    snapshots
        Iterations after which to keep a copy of the positions (e.g. ``(5, 20)`` for the paper's
        Figure 1).
    threads
        Threads for the per-platform QPs of ``osqp`` and ``clarabel``; ``None`` uses one per core up to
        the number of platforms. Use 1 inside process-parallel Monte Carlo runs.
    constraints
        Constraints on the paths (:mod:`pmht_opt.constraints`), imposed in every M-step; the returned
        plan meets them (hard) or reports how far it misses them (soft), see
        :meth:`PlanResult.constraint_reports`. Not available with ``solver="kalman"``. With constraints
        the EM objective is no longer guaranteed to increase.
    anneal
        Schedule for the fitting penalty ``r`` (:class:`pmht_opt.Anneal`): the first iterations use a
        wider penalty that shrinks to the scenario's ``r``. Accepts an :class:`Anneal`, a tuple
        ``(start, iterations)`` (geometric), a callable ``iteration -> r`` or ``None`` (plain EM).
        Default: ``Anneal(start=1.0, iterations=30)``, geometric from 1.0 to ``r`` over the first 30 of
        the 100 iterations, chosen by the 100-trial study ``studies/anneal.py`` (README, "Annealed EM"):
        it is shorter and covers more locales than plain EM on A, B and C. The objective history is
        computed with each iteration's ``r``; it never decreases once ``r`` stays fixed.
    estep_gate
        Gate of the E-step (:mod:`pmht_opt.estep`): a margin ``G`` in nats, ``"auto"`` (default) or
        ``None`` (always dense). A triple (locale, time, platform) whose log weight is more than ``G``
        below the best of its (locale, platform) pair gets weight zero; the others are found by
        KD-tree radius queries without forming the ``N x T x M`` array, and the weights are stored
        sparse. ``"auto"`` is ``G = log(T M) + 37``: the mass dropped from any pair is below
        ``1e-16`` of it, so the E-step, including the re-estimated platform prior, equals the dense
        one to rounding and whole plans agree with dense ones to about 1e-12 (tests). The dense
        computation runs whenever the gate would keep more than a tenth of the triples (a wide ``r``,
        early in annealing). ``"auto"`` stays dense with ``update_time_prior=True``: the gated
        ``pi^tau[n, t]`` is zero, not tiny, where no triple of ``(n, t)`` is kept, and the EM can
        revive tiny time priors; a numeric ``G`` gates anyway. On by default, by measurement
        (``pmht-opt study scaling``, ``studies/results/scaling``): N = 1000, T = 2000, M = 10 plans
        take 33 s instead of 51 s (kalman; E-steps after annealing 3.4 times faster), every sweep
        point is faster, and where the gate does not pay it costs nothing (dense).
    """

    solver: str = "clarabel"
    max_iter: int = 100
    tol: float = 0.0
    update_time_prior: bool = False
    update_platform_prior: bool = True
    solver_settings: dict[str, Any] = field(default_factory=dict)
    accept_inaccurate: bool = False
    snapshots: tuple[int, ...] = ()
    threads: int | None = None
    constraints: Sequence[Constraint] = ()
    anneal: Any = field(default_factory=lambda: Anneal(start=1.0, iterations=30))
    estep_gate: float | str | None = "auto"

    def __post_init__(self) -> None:
        self.anneal = as_anneal(self.anneal)
        gate_margin(self.estep_gate, 1, 1)  # validates (ConfigError)
        if isinstance(self.estep_gate, str):
            self.estep_gate = self.estep_gate.lower()
        elif self.estep_gate is not None:
            self.estep_gate = float(self.estep_gate)
        self.solver = str(self.solver).lower()
        if self.solver not in MSTEP_BACKENDS:
            raise UnknownSolverError(
                f"solver: unknown solver {self.solver!r}; available: {', '.join(available_backends())}."
            )
        if isinstance(self.max_iter, bool) or not isinstance(self.max_iter, (int, np.integer)):
            raise ConfigError(f"max_iter: expected a positive integer, got {self.max_iter!r}.")
        if self.max_iter < 1:
            raise ConfigError(f"max_iter: expected a positive integer, got {self.max_iter}.")
        self.max_iter = int(self.max_iter)
        try:
            tol = float(self.tol)
        except (TypeError, ValueError):
            raise ConfigError(f"tol: expected a non-negative number, got {self.tol!r}.") from None
        if not np.isfinite(tol) or tol < 0:
            raise ConfigError(f"tol: expected a finite non-negative number, got {self.tol!r}.")
        self.tol = tol
        for key in ("update_time_prior", "update_platform_prior", "accept_inaccurate"):
            if not isinstance(getattr(self, key), (bool, np.bool_)):
                raise ConfigError(f"{key}: expected True or False, got {getattr(self, key)!r}.")
        if not isinstance(self.solver_settings, dict):
            kind = type(self.solver_settings).__name__
            raise ConfigError(f"solver_settings: expected a dict, got {kind}.")
        if self.threads is not None:
            if (
                isinstance(self.threads, bool)
                or not isinstance(self.threads, (int, np.integer))
                or self.threads < 1
            ):
                raise ConfigError(f"threads: expected a positive integer or None, got {self.threads!r}.")
            self.threads = int(self.threads)
        if isinstance(self.constraints, Constraint):
            self.constraints = (self.constraints,)
        try:
            self.constraints = tuple(self.constraints)
        except TypeError:
            raise ConfigError(
                f"constraints: expected a list of constraints, got {type(self.constraints).__name__}."
            ) from None
        for con in self.constraints:
            if not isinstance(con, Constraint):
                raise ConfigError(
                    f"constraints: expected pmht_opt.constraints objects, got {type(con).__name__}."
                )
            if self.solver not in con.backends:
                raise ConfigError(
                    f"constraints: {con.name} cannot be imposed by the {self.solver} backend; "
                    f"use one of {', '.join(sorted(con.backends))}."
                )
        self.snapshots = tuple(int(s) for s in self.snapshots)
        if any(s < 0 for s in self.snapshots):
            raise ConfigError(f"snapshots: iterations must be >= 0, got {self.snapshots}.")

    @classmethod
    def paper(cls, **changes: Any) -> PMHTConfig:
        """The paper's settings taken literally: 100 iterations, both prior updates, no annealing."""
        base: dict[str, Any] = {
            "max_iter": 100,
            "tol": 0.0,
            "update_time_prior": True,
            "update_platform_prior": True,
            "anneal": None,
        }
        base.update(changes)
        return cls(**base)


ProgressCallback = Callable[[int, float], None]


def _initial_log_prior(name: str, prior: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    if prior is None:
        return None
    arr = np.asarray(prior, dtype=float)
    if arr.shape != shape:
        raise ScenarioError(f"{name} must have shape {shape}, got {arr.shape}.")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ScenarioError(f"{name} must be finite and non-negative.")
    sums = arr.sum(axis=1)
    if np.any(sums <= 0):
        raise ScenarioError(f"{name} has a locale (row {int(np.argmin(sums))}) with no mass.")
    return safe_log(arr / sums[:, None])


def _initial_paths(scenario: Scenario, paths: np.ndarray | None) -> np.ndarray:
    x0 = scenario.initial_states
    M, T = scenario.n_platforms, scenario.horizon
    if paths is None:
        # Every platform standing still at its start (SPEC section 2).
        return np.repeat(x0[:, None, :], T + 1, axis=1)
    arr = np.asarray(paths, dtype=float)
    if arr.shape != (M, T + 1, STATE_DIM):
        raise ScenarioError(f"initial_paths must have shape {(M, T + 1, STATE_DIM)}, got {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise ScenarioError("initial_paths contains NaN or infinite values.")
    if not np.allclose(arr[:, 0], x0):
        raise ScenarioError("initial_paths must start (t = 0) at the scenario's start states.")
    return arr.copy()


def plan_pmht(
    scenario: Scenario,
    config: PMHTConfig | None = None,
    *,
    time_prior: np.ndarray | None = None,
    platform_prior: np.ndarray | None = None,
    callback: ProgressCallback | None = None,
    initial_paths: np.ndarray | None = None,
) -> PlanResult:
    """Plan paths for ``scenario`` with the PMHT planner.

    Parameters
    ----------
    scenario
        The locales, starts and model.
    config
        Planner settings; defaults to :class:`PMHTConfig`'s.
    time_prior, platform_prior
        Initial ``pi^tau (N, T)`` and ``pi^k (N, M)``; uniform when ``None``. Rows are normalised.
    callback
        Called as ``callback(iteration, objective)`` after every iteration (e.g. a progress bar).
    initial_paths
        ``(M, T+1, 6)`` paths the EM starts from (``t = 0`` must be the scenario's start states);
        default: every platform standing still at its start.

    Returns
    -------
    PlanResult
        Paths, final assignment, per-iteration history and metrics.
    """
    if not isinstance(scenario, Scenario):
        raise ScenarioError(f"Expected a Scenario, got {type(scenario).__name__}.")
    cfg = config if config is not None else PMHTConfig()
    if not isinstance(cfg, PMHTConfig):
        raise ConfigError(f"config must be a PMHTConfig, got {type(cfg).__name__}.")
    N, M, T = scenario.n_locales, scenario.n_platforms, scenario.horizon
    log_tau = _initial_log_prior("time_prior", time_prior, (N, T))
    log_k = _initial_log_prior("platform_prior", platform_prior, (N, M))
    start_paths = _initial_paths(scenario, initial_paths)
    for con in cfg.constraints:
        con.check_scenario(scenario)
    started = time.perf_counter()
    threads = cfg.threads if cfg.threads is not None else min(M, os.cpu_count() or 1)
    mstep = make_mstep(
        scenario, cfg.solver, cfg.solver_settings, cfg.accept_inaccurate, threads, tuple(cfg.constraints)
    )
    try:
        return _run_em(scenario, cfg, mstep, log_tau, log_k, callback, started, start_paths)
    finally:
        mstep.close()


def _run_em(
    scenario: Scenario,
    cfg: PMHTConfig,
    mstep: MStep,
    log_tau: np.ndarray | None,
    log_k: np.ndarray | None,
    callback: ProgressCallback | None,
    started: float,
    start_paths: np.ndarray,
) -> PlanResult:
    N, M = scenario.n_locales, scenario.n_platforms
    model = scenario.model
    # "auto" gates only where the gated EM is the dense one to rounding: not with the time-prior update.
    auto_off = cfg.estep_gate == "auto" and cfg.update_time_prior
    gate = None if auto_off else gate_margin(cfg.estep_gate, scenario.horizon, M)
    r_sched = cfg.anneal.values(scenario.r, cfg.max_iter)
    anneal_end = cfg.anneal.end(scenario.r, cfg.max_iter)

    states = start_paths
    objective: list[float] = []
    e_times: list[float] = []
    m_times: list[float] = []
    solver_iters: list[int] = []
    fallbacks: list[int] = []
    snapshots: dict[int, np.ndarray] = {}
    if 0 in cfg.snapshots:
        snapshots[0] = states[:, :, POS].copy()

    def run_estep(states: np.ndarray, r: float) -> tuple[EStepResult, float]:
        es = estep(scenario.locales, states[:, 1:, POS], log_tau, log_k, r, gate=gate)
        return es, model.log_prior(states) + es.log_likelihood

    converged = False
    t0 = time.perf_counter()
    es, obj = run_estep(states, float(r_sched[0]))
    e_times.append(time.perf_counter() - t0)
    objective.append(obj)
    r_used = [float(r_sched[0])]
    for it in range(1, cfg.max_iter + 1):
        r = float(r_sched[it - 1])
        if cfg.update_time_prior:
            log_tau = safe_log(es.time_prior())
        if cfg.update_platform_prior:
            log_k = safe_log(es.platform_prior())
        ctx = ConstraintContext(
            scenario=scenario,
            states=states,
            estep=es,
            iteration=it,
            max_iter=cfg.max_iter,
            conic=mstep.conic,
            settled=anneal_end,
        )
        t0 = time.perf_counter()
        out = mstep.solve(MStepData(W=es.W, WZ=es.WZ, r=r, ctx=ctx))
        m_times.append(time.perf_counter() - t0)
        solver_iters.append(out.iterations)
        fallbacks.append(int(out.info.get("fallbacks", 0)))
        states = out.states
        t0 = time.perf_counter()
        es, obj = run_estep(states, r)
        if it < cfg.max_iter and r_sched[it] != r:
            # The objective is recorded at this iteration's r; the next iteration weighs with its own.
            es, _ = run_estep(states, float(r_sched[it]))
        e_times.append(time.perf_counter() - t0)
        objective.append(obj)
        r_used.append(r)
        if it in cfg.snapshots:
            snapshots[it] = states[:, :, POS].copy()
        if callback is not None:
            callback(it, obj)
        warming_up = any(not c.active(it + 1, cfg.max_iter, anneal_end) for c in cfg.constraints)
        if cfg.tol > 0 and not warming_up and it > anneal_end:
            prev = objective[-2]
            if abs(obj - prev) <= cfg.tol * max(abs(prev), 1e-300):
                converged = True
                break
    assignment, visit_time = es.map_assignment()
    history = IterationHistory(
        objective=np.array(objective),
        estep_time=np.array(e_times),
        mstep_time=np.array(m_times),
        solver_iterations=np.array(solver_iters, dtype=int),
        r=np.array(r_used),
        fallbacks=np.array(fallbacks, dtype=int),
    )
    return PlanResult(
        scenario=scenario,
        states=states,
        assignment=assignment,
        visit_time=visit_time,
        platform_prior=np.exp(log_k) if log_k is not None else np.full((N, M), 1.0 / M),
        history=history,
        converged=converged,
        wall_time=time.perf_counter() - started,
        solver=cfg.solver,
        snapshots=snapshots,
        constraints=tuple(cfg.constraints),
        constraint_context=ctx if cfg.constraints else None,
        anneal=cfg.anneal.describe(),
    )
