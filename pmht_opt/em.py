"""The EM loop of the PMHT planner as an object that can be stepped and watched.

:class:`EMRun` holds one run: the current paths, priors and E-step, the M-step backend, the schedule
(:class:`~pmht_opt.schedule.Schedule`: the penalty ``r``, the end of annealing and the constraints
imposed at each iteration) and the stopping criterion. :meth:`EMRun.step` runs one iteration (prior
updates, M-step, E-step, objective); :meth:`EMRun.run` steps until the criterion says stop and returns
the :class:`~pmht_opt.result.PlanResult`. Observers get :class:`EMCallbacks` after every E-step, M-step
and iteration, so studies watch a run without re-implementing it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import numpy as np

import solvers
from pmht_opt import validation
from pmht_opt.constraints.base import ConstraintContext, pinned_ends
from pmht_opt.constraints.feasibility import check_feasible
from pmht_opt.estep import EStepResult, estep, estep_scored, gate_margin, log_likelihood, safe_log
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.model import POS
from pmht_opt.mstep.base import MStepData, MStepOutput
from pmht_opt.mstep.registry import make_mstep, resolve
from pmht_opt.parallel import block_threads, concurrent, usable_cores
from pmht_opt.result import IterationHistory, PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.schedule import Schedule
from pmht_opt.settings import PMHTConfig
from pmht_opt.stopping import AnyOf, Converged, EMProgress, ObjectiveTolerance, fired, iteration_limit
from pmht_opt.verify import verify_plan


@dataclass(frozen=True)
class IterationRecord:
    """What one EM iteration did.

    ``objective`` is the EM objective after the iteration, computed with its ``r``; ``estep_gated``
    says whether the E-step whose weights feed the next M-step was gated.
    """

    iteration: int
    r: float
    objective: float
    estep_time: float
    mstep_time: float
    solver_iterations: int
    fallbacks: int
    mstep_status: solvers.Status
    estep_gated: bool
    path_change: float = float("inf")
    assignment_changed: bool = True


@dataclass(frozen=True)
class EMCallbacks:
    """Observers of an :class:`EMRun`, each called with the run and what just happened.

    ``after_estep(run, estep)`` follows every E-step (the initial one included), ``after_mstep(run,
    output)`` every M-step, ``after_iteration(run, record)`` every iteration.
    """

    after_estep: Callable[[EMRun, EStepResult], None] | None = None
    after_mstep: Callable[[EMRun, MStepOutput], None] | None = None
    after_iteration: Callable[[EMRun, IterationRecord], None] | None = None

    def __post_init__(self) -> None:
        for name in ("after_estep", "after_mstep", "after_iteration"):
            fn = getattr(self, name)
            if fn is not None and not callable(fn):
                raise ConfigError(f"EMCallbacks.{name}: expected a callable or None, got {fn!r}.")


class EMRun:
    """One run of the PMHT planner's EM, from the standing (or given) paths to a plan.

    Parameters
    ----------
    scenario
        The locales, starts and model.
    config
        Planner settings (:class:`~pmht_opt.PMHTConfig`).
    time_prior, platform_prior
        Initial ``pi^tau (N, T)`` and ``pi^k (N, M)``; uniform when ``None``.
    initial_paths
        ``(M, T+1, 6)`` paths to start from; default: every platform standing at its start.
    callbacks
        Observers (:class:`EMCallbacks`).

    Attributes
    ----------
    states
        ``(M, T+1, 6)`` current paths.
    estep
        The E-step of the current paths (at the next iteration's ``r``).
    iteration
        Iterations run so far.
    last_context
        The :class:`~pmht_opt.constraints.ConstraintContext` of the last M-step (``None`` before the
        first): what its constraint rows were written from; its ``estep`` is ``None`` without
        constraints (released, see the notes).
    stop_reason
        ``None`` while the run goes on; then the name of the criterion that stopped it.

    Notes
    -----
    An iteration changes the run's state (paths, priors, E-step, iteration count) only once it has
    finished: after Ctrl-C or an error the run is the last finished iteration's, :meth:`result` gives
    that plan and :meth:`step` runs the iteration again. Without constraints the E-step an M-step used
    is released before the next is formed (a large dense E-step's weights are never held twice) and,
    if the next does not finish, :attr:`estep` is formed again from the same inputs. With
    constraints the interrupted iteration's context has already replaced the finished one's (keeping
    both would hold a third set of weights), so :meth:`result` refuses until an iteration finishes.
    """

    @validation.plan_boundary("setting up the plan")
    def __init__(
        self,
        scenario: Scenario,
        config: PMHTConfig | None = None,
        *,
        time_prior: Any = None,
        platform_prior: Any = None,
        initial_paths: Any = None,
        callbacks: EMCallbacks | None = None,
    ) -> None:
        if not isinstance(scenario, Scenario):
            raise ScenarioError(f"Expected a Scenario, got {type(scenario).__name__}.")
        cfg = config if config is not None else PMHTConfig()
        if not isinstance(cfg, PMHTConfig):
            raise ConfigError(f"config must be a PMHTConfig, got {type(cfg).__name__}.")
        if callbacks is not None and not isinstance(callbacks, EMCallbacks):
            raise ConfigError(f"callbacks: expected EMCallbacks, got {type(callbacks).__name__}.")
        N, M, T = scenario.n_locales, scenario.n_platforms, scenario.horizon
        self.scenario = scenario
        self.config = cfg
        self.callbacks = callbacks if callbacks is not None else EMCallbacks()
        self.log_tau = validation.log_prior_rows("time_prior", time_prior, (N, T), ScenarioError)
        self.log_k = validation.log_prior_rows("platform_prior", platform_prior, (N, M), ScenarioError)
        self.states = validation.initial_paths(scenario.initial_states, T, initial_paths, ScenarioError)
        for con in cfg.constraints:
            con.check_scenario(scenario)
        check_feasible(scenario, cfg.constraints)
        #: Where the hard constraints pin each path's end, for the visit schedules (``None``: nowhere).
        self.ends = pinned_ends(scenario, cfg.constraints)
        # The schedule fits the iterations the run may take: its plan is fitted at the scenario's r.
        limit = min(cfg.max_iter, iteration_limit(AnyOf(cfg.stop)) or cfg.max_iter)
        anneal, note = cfg.anneal.fit(limit)
        self.schedule = Schedule.of(anneal, scenario.r, cfg.max_iter)
        #: The annealing schedule the run uses, described (and whether it was compressed to fit).
        self.anneal = anneal.describe(scenario.r) + (f" ({note})" if note else "")
        self.criteria = cfg.criteria()
        # "auto" gates only where the gated EM is the dense one to rounding: not with the time-prior update.
        auto_off = cfg.estep_gate == "auto" and cfg.update_time_prior
        self.gate = None if auto_off else gate_margin(cfg.estep_gate, T, M)
        self._started = time.perf_counter()
        threads = cfg.threads if cfg.threads is not None else min(M, usable_cores())
        #: Threads of the E-step's blocks of locales (any number gives the same weights, bit for bit).
        self.estep_threads = block_threads(cfg.threads or usable_cores(), N * T * M)
        #: The backend that runs the M-steps (``"auto"`` resolved).
        self.solver = resolve(cfg.solver, cfg.constraints)
        self.mstep = make_mstep(
            scenario, cfg.solver, cfg.solver_settings, cfg.accept_inaccurate, threads, tuple(cfg.constraints)
        )
        self.iteration = 0
        self.last_context: ConstraintContext | None = None
        self.stop_reason: str | None = None
        #: What the stopping criteria saw after the last iteration (``None`` before the first).
        self.progress: EMProgress | None = None
        self.records: list[IterationRecord] = []
        self.snapshots: dict[int, np.ndarray] = {}
        if 0 in cfg.snapshots:
            self.snapshots[0] = self.states[:, :, POS].copy()
        t0 = time.perf_counter()
        r0 = self.schedule.r_at(1)
        es, objective = self._estep(self.states, r0, None, self.log_tau, self.log_k)
        self._es: EStepResult | None = es
        #: An iteration whose M-step replaced ``last_context`` but whose E-step did not finish.
        self._unfinished: int | None = None
        self._initial = (objective, time.perf_counter() - t0, r0, es.gated)
        self._objectives = [objective]
        self._assignment = es.map_assignment()[0]
        self._assignment_age = 0
        self._notify(self.callbacks.after_estep, es)

    # ------------------------------------------------------------------ the loop

    def _estep(
        self,
        states: np.ndarray,
        r: float,
        noise: np.ndarray | None,
        log_tau: np.ndarray | None,
        log_k: np.ndarray | None,
    ) -> tuple[EStepResult, float]:
        """The E-step of ``states`` at ``r`` under the priors ``log_tau``, ``log_k``, and the EM
        objective there.

        The prior term ``log P(X) = -1/2 sum ||u||^2`` comes from the M-step's process noise ``noise``
        when the backend has it: recomputed from the states it would be a difference of nearly equal
        numbers, which loses every digit when ``q dt^5`` is tiny against the positions.
        """
        es = estep(
            self.scenario.locales,
            states[:, 1:, POS],
            log_tau,
            log_k,
            r,
            gate=self.gate,
            threads=self.estep_threads,
            time_totals=self.config.update_time_prior,
        )
        return es, self._log_prior(states, noise) + es.log_likelihood

    def _next_estep(
        self,
        it: int,
        r: float,
        states: np.ndarray,
        noise: np.ndarray | None,
        priors: tuple[np.ndarray | None, np.ndarray | None],
    ) -> tuple[EStepResult, float]:
        """The E-step of iteration ``it``'s paths ``states`` that feeds iteration ``it + 1``, and
        iteration ``it``'s objective at its own ``r``.

        During annealing the two penalties differ: the next iteration weighs with its ``r``, so at
        this one only the objective is formed (:func:`~pmht_opt.estep.log_likelihood`: the same
        number, without the weights). On one thread the two share their squared distances
        (:func:`~pmht_opt.estep.estep_scored`); on several the objective runs beside the E-step.
        """
        schedule = self.schedule
        if it < schedule.max_iter and schedule.r_at(it + 1) != r:
            r_next, threads = schedule.r_at(it + 1), self.estep_threads
            if threads <= 1:
                es, score = estep_scored(
                    self.scenario.locales,
                    states[:, 1:, POS],
                    *priors,
                    r_next,
                    r,
                    gate=self.gate,
                    time_totals=self.config.update_time_prior,
                )
                return es, self._log_prior(states, noise) + score
            args = (self.scenario.locales, states[:, 1:, POS], *priors, r)
            with concurrent(threads, log_likelihood, *args, gate=self.gate, threads=threads) as data_term:
                es, _ = self._estep(states, r_next, None, *priors)
                return es, self._log_prior(states, noise) + data_term()
        return self._estep(states, r, noise, *priors)

    def _log_prior(self, states: np.ndarray, noise: np.ndarray | None) -> float:
        """``log P(X)`` up to its constant: from the M-step's process noise ``noise`` where the backend
        has it (see :meth:`_estep`), else from the states."""
        if noise is None:
            return self.scenario.model.log_prior(states)
        return float(-0.5 * np.sum(noise * noise))

    def _notify(self, fn: Callable[[EMRun, Any], None] | None, value: Any) -> None:
        if fn is not None:
            validation.call_user(fn, self, value)

    @property
    def estep(self) -> EStepResult:
        """The E-step of the current paths, at the next iteration's ``r`` (formed again, with the same
        numbers, if an interrupted iteration had released it)."""
        if self._es is None:
            r = self.schedule.r_at(min(self.iteration + 1, self.schedule.max_iter))
            self._es = self._estep(self.states, r, None, self.log_tau, self.log_k)[0]
        return self._es

    @property
    def done(self) -> bool:
        """Whether the stopping criterion has stopped the run."""
        return self.stop_reason is not None

    @validation.plan_boundary("an EM iteration")
    def step(self) -> IterationRecord:
        """Run one EM iteration: prior updates, M-step, E-step and objective; then the stop test."""
        if self.done:
            raise ConfigError(f"the run has stopped ({self.stop_reason}); start a new EMRun.")
        cfg, schedule = self.config, self.schedule
        it = self.iteration + 1
        r = schedule.r_at(it)
        es = self.estep
        log_tau = safe_log(es.time_prior()) if cfg.update_time_prior else self.log_tau
        log_k = safe_log(es.platform_prior()) if cfg.update_platform_prior else self.log_k
        ctx = ConstraintContext(
            scenario=self.scenario, states=self.states, estep=es, iteration=it, ends=self.ends
        )
        active = schedule.active(cfg.constraints, it)
        strengths = schedule.strengths(cfg.constraints, it)
        t0 = time.perf_counter()
        out = self.mstep.solve(MStepData(W=es.W, WZ=es.WZ, r=r, ctx=ctx, active=active, strengths=strengths))
        mstep_time = time.perf_counter() - t0
        self._notify(self.callbacks.after_mstep, out)
        path_change = float(np.max(np.abs(out.states[:, :, POS] - self.states[:, :, POS])))
        # Without constraints the used E-step goes before the next is formed (class notes). With them
        # the new context keeps it for their reports (the run may as well) and replaces the previous
        # context now, which holds the E-step before it.
        if cfg.constraints:
            self.last_context, self._unfinished = ctx, it
        else:
            ctx.estep = self._es = None
        del es
        t0 = time.perf_counter()
        es, objective = self._next_estep(it, r, out.states, out.noise, (log_tau, log_k))
        estep_time = time.perf_counter() - t0
        self.states, self.log_tau, self.log_k, self._es = out.states, log_tau, log_k, es
        self.last_context, self._unfinished = ctx, None
        self.iteration = it
        self._objectives.append(objective)
        assignment = es.map_assignment()[0]
        changed = bool(np.any(assignment != self._assignment))
        self._assignment = assignment
        self._assignment_age = 0 if changed else self._assignment_age + 1
        self._notify(self.callbacks.after_estep, es)
        record = IterationRecord(
            iteration=it,
            r=r,
            objective=objective,
            estep_time=estep_time,
            mstep_time=mstep_time,
            solver_iterations=out.iterations,
            fallbacks=out.fallbacks,
            mstep_status=out.status,
            estep_gated=es.gated,
            path_change=path_change,
            assignment_changed=changed,
        )
        self.records.append(record)
        if it in cfg.snapshots:
            self.snapshots[it] = self.states[:, :, POS].copy()
        self.progress = self._progress(it)
        self._notify(self.callbacks.after_iteration, record)
        for crit in self.criteria:
            reason = validation.call_user(fired, crit, self.progress)
            if reason is not None:
                self.stop_reason = reason
                break
        return record

    def _progress(self, it: int) -> EMProgress:
        """What the stopping criteria and observers see after iteration ``it``."""
        bounds = self.scenario.bounds or (0.0, 1.0, 0.0, 1.0)
        return EMProgress(
            iteration=it,
            scores=[-o for o in self._objectives],
            elapsed=time.perf_counter() - self._started,
            settled=self.schedule.settled_at(self.config.constraints, it),
            stage="em",
            path_change=self.records[-1].path_change,
            assignment_age=self._assignment_age,
            scale=max(bounds[1] - bounds[0], bounds[3] - bounds[2], 1e-12),
        )

    def run(self) -> PlanResult:
        """Step until the stopping criterion says stop; return the plan."""
        while not self.done:
            self.step()
        return self.result()

    # ------------------------------------------------------------------ the outcome

    @property
    def converged(self) -> bool:
        """Whether the run stopped on a convergence test (not on an iteration or time limit)."""
        return self.stop_reason in (ObjectiveTolerance.__name__, Converged.__name__)

    def history(self) -> IterationHistory:
        """The per-iteration record so far."""
        obj0, time0, r0, gated0 = self._initial
        recs = self.records
        return IterationHistory(
            objective=np.array([obj0, *(r.objective for r in recs)]),
            estep_time=np.array([time0, *(r.estep_time for r in recs)]),
            mstep_time=np.array([r.mstep_time for r in recs]),
            solver_iterations=np.array([r.solver_iterations for r in recs], dtype=int),
            r=np.array([r0, *(r.r for r in recs)]),
            fallbacks=np.array([r.fallbacks for r in recs], dtype=int),
            mstep_status=tuple(r.mstep_status for r in recs),
            estep_gated=np.array([gated0, *(r.estep_gated for r in recs)], dtype=bool),
            stop_reason=self.stop_reason or "",
            anneal=self.anneal,
        )

    @validation.plan_boundary("the plan's result")
    def result(self) -> PlanResult:
        """The plan of the current paths: assignment, history, final E-step, constraint reports.

        A plan with a non-finite state is never returned (:class:`~pmht_opt.exceptions.SolverError`).
        """
        scenario, cfg = self.scenario, self.config
        validation.check_finite_plan(self.states, self.solver)
        N, M = scenario.n_locales, scenario.n_platforms
        if self._unfinished is not None:
            raise ConfigError(
                f"iteration {self._unfinished} stopped after its M-step, and the constraints' context of "
                f"iteration {self.iteration} it replaced is gone, so the plan's constraint reports cannot "
                "be formed: step() again to finish an iteration first."
            )
        es = self.estep
        assignment, visit_time = es.map_assignment()
        reports: tuple[Any, ...] = ()
        if cfg.constraints and self.last_context is not None:
            reports = tuple(c.violation(self.states, self.last_context) for c in cfg.constraints)
            verify_plan(self.solver, scenario, cfg.constraints, reports)
        return PlanResult(
            scenario=scenario,
            states=self.states,
            assignment=assignment,
            visit_time=visit_time,
            platform_prior=np.exp(self.log_k) if self.log_k is not None else np.full((N, M), 1.0 / M),
            history=self.history(),
            converged=self.converged,
            wall_time=time.perf_counter() - self._started,
            solver=self.solver,
            snapshots=dict(self.snapshots),
            constraints=tuple(cfg.constraints),
            reports=reports,
            estep=es.summary(),
            anneal=self.anneal,
        )

    def close(self) -> None:
        """Release the M-step backend's threads and workspaces."""
        self.mstep.close()

    def __enter__(self) -> EMRun:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
