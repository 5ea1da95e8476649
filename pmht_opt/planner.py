"""Settings of the PMHT planner and its entry point (docs/model.md section 4).

One iteration of the EM is an E-step (weights from the current paths and priors, eq. 9), the prior
updates (eqs 11, 12; each switchable) and an M-step (the smoothing problem, eqs 13-16). The EM objective

    L(X, Pi) = log P(X) + sum_n log sum_{t,m} pi^tau[n,t] pi^k[n,m] zeta(z_n | x_t^m)

(``log P(X)`` without its constant normaliser) never decreases from one iteration to the next without
extra constraints once the penalty ``r`` stays fixed. :func:`plan_pmht` runs the loop of
:class:`~pmht_opt.em.EMRun` to its end.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.anneal import Anneal, as_anneal
from pmht_opt.constraints.base import Constraint
from pmht_opt.estep import gate_margin
from pmht_opt.exceptions import ConfigError
from pmht_opt.mstep.registry import check_backend, check_constraints
from pmht_opt.parallel import thread_count
from pmht_opt.stopping import MaxIterations, ObjectiveTolerance, StoppingCriterion

#: ``callback(iteration, objective)``, called after every iteration.
ProgressCallback = Callable[[int, float], None]


@dataclass
class PMHTConfig:
    """Settings of :func:`plan_pmht`.

    Every field is checked on construction (:mod:`pmht_opt.validation`): a string or a boolean where a
    number belongs, a non-finite or out-of-range value raises :class:`ConfigError` naming the field.

    Parameters
    ----------
    solver
        M-step backend: ``"auto"`` (default: the exact ``"banded"`` smoother without constraints,
        ``"clarabel"`` with them), ``"banded"``, ``"clarabel"``, ``"osqp"``, ``"cvxpy"`` or
        ``"kalman"`` (:func:`~pmht_opt.available_backends`).
    max_iter
        Maximum number of EM iterations (the paper: 100), an integer from 1 to 1e6.
    tol
        Stop when the relative change of the EM objective between iterations falls below ``tol``;
        ``0`` runs exactly ``max_iter`` iterations.
    update_time_prior
        Re-estimate ``pi^tau`` each iteration (eq. 11). Off by default: on scenarios A-C the
        update collapses each locale's time prior onto one time within a few iterations and platforms
        with no locale left fly out of the area under constant acceleration (docs/model.md section 4.3); the
        paper's literal setting is ``True``.
    update_platform_prior
        Re-estimate ``pi^k`` each iteration (eq. 12).
    solver_settings
        Options passed verbatim to the backend (e.g. ``{"eps_abs": 1e-8}`` for OSQP,
        ``{"cvxpy_solver": "SCS"}`` for cvxpy), and two of the M-step's own:
        ``"mstep_work_limit"`` (OSQP's work budget per constrained M-step, ``None`` lifts it) and
        ``"condense"`` (``False``: constrained Clarabel M-steps solve the full QP instead of first
        a small one on the rows that bind, :mod:`pmht_opt.mstep.condensed`).
    accept_inaccurate
        Use solutions the backend flags as inaccurate instead of raising :class:`SolverError`.
    snapshots
        Iterations after which to keep a copy of the positions (e.g. ``(5, 20)`` for the paper's
        Figure 1).
    threads
        Threads for the per-platform QPs of ``osqp`` and ``clarabel``, for the exact smoother's
        batch of platforms (``banded``, and the check of every other backend's answer) and for the
        E-step's blocks of locales; ``None`` uses one per core the process may run on (up to the
        number of platforms for the QPs; E-steps of fewer than
        :data:`~pmht_opt.parallel.MIN_THREADED_TRIPLES` triples stay on one). The plan does not
        depend on it, to the last bit. Use 1 inside process-parallel Monte Carlo runs.
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
        it is shorter and covers more locales than plain EM on A, B and C (docs/decisions.md section 5.1). The
        objective history is computed with each iteration's ``r``; it never decreases once ``r`` stays
        fixed.
    estep_gate
        Gate of the E-step (:mod:`pmht_opt.estep`): a margin ``G`` in nats, ``"auto"`` (default) or
        ``None`` (always dense). A triple (locale, time, platform) whose log weight is more than ``G``
        below the best of its (locale, platform) pair gets weight zero; the others are found within
        a radius of each locale (:mod:`pmht_opt.estep.candidates`) without forming the ``N x T x M``
        array, and the weights are stored sparse. ``"auto"`` is ``G = log(T M) + 37``: the mass
        dropped from any pair is below ``1e-16`` of it, so the E-step, including the re-estimated
        platform prior, equals the dense one to rounding and whole plans agree with dense ones to
        about 1e-12 (tests). The dense computation runs whenever the gate would keep more than a
        tenth of the triples (a wide ``r``, early in annealing). ``"auto"`` stays dense with
        ``update_time_prior=True``: the gated ``pi^tau[n, t]`` is zero, not tiny, where no triple of
        ``(n, t)`` is kept, and the EM can revive tiny time priors; a numeric ``G`` gates anyway. On
        by default: large plans are much faster, and where the gate does not pay it costs nothing
        (dense; docs/decisions.md section 6.1).
    stop
        Further stopping criteria (:mod:`pmht_opt.stopping`, e.g. ``TimeBudget(5.0)``): the run also
        stops when any of them says so. ``tol`` is :class:`~pmht_opt.stopping.ObjectiveTolerance`,
        judged only once annealing is over and every constraint is imposed.
    """

    solver: str = "auto"
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
    stop: Any = ()

    def __post_init__(self) -> None:
        self.anneal = as_anneal(self.anneal)
        if validation.is_real(self.estep_gate):
            self.estep_gate = validation.real("estep_gate", self.estep_gate, ConfigError, 0.0, lo_open=True)
        gate_margin(self.estep_gate, 1, 1)  # validates (ConfigError)
        if isinstance(self.estep_gate, str):
            self.estep_gate = self.estep_gate.lower()
        if not isinstance(self.solver, str):
            raise ConfigError(f"solver: expected a backend name, got {validation.describe(self.solver)}.")
        self.solver = check_backend(self.solver)
        self.max_iter = validation.integer(
            "max_iter", self.max_iter, ConfigError, 1, validation.MAX_ITERATIONS
        )
        self.tol = validation.real("tol", self.tol, ConfigError, 0.0)
        for key in ("update_time_prior", "update_platform_prior", "accept_inaccurate"):
            validation.flag(key, getattr(self, key))
        validation.solver_settings("solver_settings", self.solver_settings)
        self.threads = _threads(self.threads)
        self.constraints = _with_implied(self.constraints)
        check_constraints(self.solver, self.constraints)
        self.snapshots = validation.integers("snapshots", self.snapshots, ConfigError, 0)
        self.stop = _criteria(self.stop)

    def criteria(self) -> tuple[StoppingCriterion, ...]:
        """When to stop, in the order they are asked: at ``tol``, when any of :attr:`stop` says so, or
        after ``max_iter`` iterations."""
        return (ObjectiveTolerance(self.tol), *self.stop, MaxIterations(self.max_iter))

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


def _threads(threads: Any) -> int | None:
    """``threads`` as an ``int``, or ``None`` (one per core); :class:`ConfigError` unless positive."""
    return None if threads is None else thread_count(threads, or_none=True)


def _with_implied(constraints: Any) -> tuple[Constraint, ...]:
    """The constraints as a tuple, each checked to be one, followed by the companions they imply and
    the caller did not give (one of each kind)."""
    if isinstance(constraints, Constraint):
        constraints = (constraints,)
    try:
        given = tuple(constraints)
    except TypeError:
        raise ConfigError(
            f"constraints: expected a list of constraints, got {type(constraints).__name__}."
        ) from None
    for con in given:
        if not isinstance(con, Constraint):
            raise ConfigError(
                f"constraints: expected pmht_opt.constraints objects, got {type(con).__name__}."
            )
    names = {con.name for con in given}
    implied = [i for con in given for i in con.implied() if i.name not in names]
    return (*given, *{i.name: i for i in implied}.values())


def _criteria(stop: Any) -> tuple[StoppingCriterion, ...]:
    """``stop`` (one criterion or several) as a tuple of callables; :class:`ConfigError` otherwise."""
    criteria = (stop,) if callable(stop) else stop
    try:
        out = tuple(criteria)
    except TypeError:
        raise ConfigError(f"stop: expected stopping criteria, got {type(stop).__name__}.") from None
    for crit in out:
        if not callable(crit):
            raise ConfigError(f"stop: expected callables progress -> bool, got {type(crit).__name__}.")
    return out


def plan_pmht(
    scenario: Any,
    config: PMHTConfig | None = None,
    *,
    time_prior: np.ndarray | None = None,
    platform_prior: np.ndarray | None = None,
    callback: ProgressCallback | None = None,
    initial_paths: np.ndarray | None = None,
    callbacks: Any = None,
) -> Any:
    """Plan paths for ``scenario`` with the PMHT planner.

    Parameters
    ----------
    scenario
        The locales, starts and model (a :class:`~pmht_opt.Scenario`).
    config
        Planner settings; defaults to :class:`PMHTConfig`'s.
    time_prior, platform_prior
        Initial ``pi^tau (N, T)`` and ``pi^k (N, M)``; uniform when ``None``. Rows are normalised.
    callback
        Called as ``callback(iteration, objective)`` after every iteration (e.g. a progress bar).
    callbacks
        Observers of every E-step, M-step and iteration (:class:`~pmht_opt.em.EMCallbacks`); with
        ``callback`` too, both are called.
    initial_paths
        ``(M, T+1, 6)`` paths the EM starts from (``t = 0`` must be the scenario's start states);
        default: every platform standing still at its start.

    Returns
    -------
    PlanResult
        Paths, final assignment, per-iteration history, the final E-step and metrics.
    """
    from pmht_opt.em import EMRun, with_progress

    callbacks = with_progress(callbacks, callback)
    with EMRun(
        scenario,
        config,
        time_prior=time_prior,
        platform_prior=platform_prior,
        initial_paths=initial_paths,
        callbacks=callbacks,
    ) as run:
        return run.run()
