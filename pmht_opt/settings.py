"""Settings of the planners: what every planner shares, and the EM's own.

:class:`Settings` holds what every planner of :func:`pmht_opt.plan` takes (the M-step backend and its
options, threads, the user's constraints, the seed); each planner adds its own options
(:mod:`pmht_opt.planners`). :class:`PMHTConfig` is the EM run's settings in one object: the shared
settings, the PMHT planner's options and when to stop, as :func:`~pmht_opt.plan_pmht` and
:class:`~pmht_opt.em.EMRun` take them. It is the one mirror of the shared settings, kept so that code
written against ``plan_pmht(scenario, PMHTConfig(...))`` runs unchanged.

One EM iteration is an E-step (weights from the current paths and priors, eq. 9), the prior updates
(eqs 11, 12; each switchable) and an M-step (the smoothing problem, eqs 13-16). The EM objective

    L(X, Pi) = log P(X) + sum_n log sum_{t,m} pi^tau[n,t] pi^k[n,m] zeta(z_n | x_t^m)

(``log P(X)`` without its constant normaliser) never decreases from one iteration to the next without
extra constraints once the penalty ``r`` stays fixed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from pmht_opt import validation
from pmht_opt.anneal import Anneal, as_anneal
from pmht_opt.constraints.base import Constraint
from pmht_opt.estep import gate_margin
from pmht_opt.exceptions import ConfigError
from pmht_opt.mstep.registry import check_backend, check_constraints
from pmht_opt.parallel import thread_count
from pmht_opt.stopping import MaxIterations, ObjectiveTolerance, StoppingCriterion

#: ``callback(iteration, objective)``, called after every iteration (:func:`~pmht_opt.plan_pmht`'s).
ProgressCallback = Callable[[int, float], None]
#: Largest seed (PyVRP's generator takes seeds up to ``2**32 - 1``).
SEED_MAX = 2**32 - 1


@dataclass(frozen=True)
class Settings:
    """What every planner of :func:`pmht_opt.plan` shares.

    Every field is checked on construction; a bad one raises :class:`ConfigError` naming it.

    Parameters
    ----------
    solver
        M-step backend: ``"auto"`` (default: the exact ``"banded"`` smoother without constraints,
        ``"clarabel"`` with them), ``"banded"``, ``"clarabel"``, ``"osqp"``, ``"cvxpy"`` or ``"kalman"``
        (:func:`~pmht_opt.available_backends`).
    solver_settings
        Options passed verbatim to the backend (e.g. ``{"eps_abs": 1e-8}`` for OSQP,
        ``{"cvxpy_solver": "SCS"}`` for cvxpy), and two of the M-step's own:
        ``"mstep_work_limit"`` (OSQP's work budget per platform of a constrained M-step, ``None``
        lifts it) and ``"condense"`` (``False``: constrained M-steps solve the full QP instead of
        first a small one on the rows that bind, :mod:`pmht_opt.mstep.condensed`).
    accept_inaccurate
        Use solutions the backend flags as inaccurate instead of raising :class:`SolverError`.
    threads
        Threads for the per-platform QPs, the exact smoother's batch of platforms and the E-step's
        blocks of locales; ``None`` uses one per core the process may run on. The plan does not depend
        on it, to the last bit. Use 1 inside process-parallel Monte Carlo runs.
    constraints
        Constraints on the paths (:mod:`pmht_opt.constraints`): the returned plan meets every hard one
        (checked on its positions) and reports how far it misses each soft one.
    seed
        Seed of every random choice a planner makes (orderings, tour searches): the same seed and the
        same install give the same plan. An integer from 0 to ``2**32 - 1``.
    """

    solver: str = "auto"
    solver_settings: dict[str, Any] = field(default_factory=dict)
    accept_inaccurate: bool = False
    threads: int | None = None
    constraints: Sequence[Constraint] = ()
    seed: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.solver, str):
            raise ConfigError(f"solver: expected a backend name, got {validation.describe(self.solver)}.")
        object.__setattr__(self, "solver", check_backend(self.solver))
        validation.flag("accept_inaccurate", self.accept_inaccurate)
        validation.solver_settings("solver_settings", self.solver_settings)
        object.__setattr__(self, "solver_settings", dict(self.solver_settings))
        object.__setattr__(self, "threads", _threads(self.threads))
        constraints = _with_implied(self.constraints)
        check_constraints(self.solver, constraints)
        object.__setattr__(self, "constraints", constraints)
        object.__setattr__(self, "seed", validation.integer("seed", self.seed, ConfigError, 0, SEED_MAX))

    def replace(self, **changes: Any) -> Settings:
        """A copy with some settings changed (checked again)."""
        fields = {f: getattr(self, f) for f in SETTINGS_FIELDS}
        fields.update(changes)
        return Settings(**fields)


#: The fields of :class:`Settings`, which every planner takes.
SETTINGS_FIELDS = ("solver", "solver_settings", "accept_inaccurate", "threads", "constraints", "seed")


@dataclass(frozen=True)
class PMHTOptions:
    """The PMHT planner's own options (:func:`pmht_opt.plan` with ``method="pmht"``).

    Parameters
    ----------
    update_time_prior
        Re-estimate ``pi^tau`` each iteration (eq. 11). Off by default: on scenarios A-C the update
        collapses each locale's time prior onto one time within a few iterations and platforms with no
        locale left fly out of the area under constant acceleration (docs/model.md section 4.3); the
        paper's literal setting is ``True``.
    update_platform_prior
        Re-estimate ``pi^k`` each iteration (eq. 12).
    anneal
        Schedule for the fitting penalty ``r`` (:class:`pmht_opt.Anneal`): the first iterations use a
        wider penalty that shrinks to the scenario's ``r``. Accepts an :class:`Anneal`, a tuple
        ``(start, iterations)`` (geometric), a callable ``iteration -> r`` or ``None`` (plain EM).
        Default: ``Anneal(iterations=30)``, geometric from ``100 r`` to ``r`` over the first 30 of the
        100 iterations, chosen by the 100-trial study ``studies/anneal.py``: it is shorter and covers
        more locales than plain EM on A, B and C (docs/decisions.md section 5.1). A run that may take
        fewer iterations than the schedule has compresses it to the same share of its own length
        (:meth:`~pmht_opt.Anneal.fit`), and its history says so: a plan is always fitted at the
        scenario's ``r`` unless another criterion stops the run first, which its history reports
        (:attr:`~pmht_opt.IterationHistory.fitted_r`).
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
    snapshots
        Iterations after which to keep a copy of the positions (e.g. ``(5, 20)`` for the paper's
        Figure 1).
    """

    update_time_prior: bool = False
    update_platform_prior: bool = True
    anneal: Any = field(default_factory=lambda: Anneal(iterations=30))
    estep_gate: float | str | None = "auto"
    snapshots: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "anneal", as_anneal(self.anneal))
        gate = self.estep_gate
        if validation.is_real(gate):
            gate = validation.real("estep_gate", gate, ConfigError, 0.0, lo_open=True)
        gate_margin(gate, 1, 1)  # validates (ConfigError)
        object.__setattr__(self, "estep_gate", gate.lower() if isinstance(gate, str) else gate)
        for key in ("update_time_prior", "update_platform_prior"):
            validation.flag(key, getattr(self, key))
        object.__setattr__(
            self, "snapshots", validation.integers("snapshots", self.snapshots, ConfigError, 0)
        )

    @classmethod
    def paper(cls, **changes: Any) -> PMHTOptions:
        """The paper's options taken literally: both prior updates, no annealing."""
        base: dict[str, Any] = {"update_time_prior": True, "update_platform_prior": True, "anneal": None}
        base.update(changes)
        return cls(**base)


#: The fields of :class:`PMHTOptions`.
PMHT_OPTION_FIELDS = ("update_time_prior", "update_platform_prior", "anneal", "estep_gate", "snapshots")
#: Iterations of a PMHT run when nothing else limits it (the paper's 100).
PMHT_ITERATIONS = 100


@dataclass
class PMHTConfig:
    """Everything an EM run takes, in one object: the shared :class:`Settings`, the PMHT planner's
    :class:`PMHTOptions` and when to stop (``max_iter``, ``tol``, ``stop``).

    This is the settings object of :func:`~pmht_opt.plan_pmht` and :class:`~pmht_opt.em.EMRun`, kept so
    that code written against it runs unchanged; ``pmht_opt.plan(scenario, "pmht", settings=...,
    stop=..., **options)`` says the same in the form every planner shares. Every field is checked on
    construction by the class it belongs to (a bad one raises :class:`ConfigError` naming it); see
    :class:`Settings` for ``solver``, ``solver_settings``, ``accept_inaccurate``, ``threads`` and
    ``constraints``, and :class:`PMHTOptions` for ``update_time_prior``, ``update_platform_prior``,
    ``anneal``, ``estep_gate`` and ``snapshots``.

    Parameters
    ----------
    max_iter
        Maximum number of EM iterations (the paper: 100), an integer from 1 to 1e6.
    tol
        Stop when the relative change of the EM objective between iterations falls below ``tol``;
        ``0`` runs exactly ``max_iter`` iterations. Judged only once annealing is over and every
        constraint is imposed (:class:`~pmht_opt.stopping.ObjectiveTolerance`).
    stop
        Further stopping criteria (:mod:`pmht_opt.stopping`, e.g. ``TimeBudget(5.0)``): the run also
        stops when any of them says so.
    """

    solver: str = "auto"
    max_iter: int = PMHT_ITERATIONS
    tol: float = 0.0
    update_time_prior: bool = False
    update_platform_prior: bool = True
    solver_settings: dict[str, Any] = field(default_factory=dict)
    accept_inaccurate: bool = False
    snapshots: tuple[int, ...] = ()
    threads: int | None = None
    constraints: Sequence[Constraint] = ()
    anneal: Any = field(default_factory=lambda: Anneal(iterations=30))
    estep_gate: float | str | None = "auto"
    stop: Any = ()

    def __post_init__(self) -> None:
        shared = Settings(**{f: getattr(self, f) for f in SETTINGS_FIELDS if f != "seed"})
        own = PMHTOptions(**{f: getattr(self, f) for f in PMHT_OPTION_FIELDS})
        for f in SETTINGS_FIELDS:
            if f != "seed":
                setattr(self, f, getattr(shared, f))
        for f in PMHT_OPTION_FIELDS:
            setattr(self, f, getattr(own, f))
        self.max_iter = validation.integer(
            "max_iter", self.max_iter, ConfigError, 1, validation.MAX_ITERATIONS
        )
        self.tol = validation.real("tol", self.tol, ConfigError, 0.0)
        self.stop = _criteria(self.stop)

    @classmethod
    def of(
        cls,
        settings: Settings,
        options: PMHTOptions,
        stop: Sequence[StoppingCriterion] = (),
        max_iter: int = PMHT_ITERATIONS,
    ) -> PMHTConfig:
        """The EM settings of ``settings``, ``options`` and the stopping criteria ``stop``."""
        return cls(
            **{f: getattr(settings, f) for f in SETTINGS_FIELDS if f != "seed"},
            **{f: getattr(options, f) for f in PMHT_OPTION_FIELDS},
            max_iter=max_iter,
            stop=tuple(stop),
        )

    @property
    def settings(self) -> Settings:
        """The shared settings."""
        return Settings(**{f: getattr(self, f) for f in SETTINGS_FIELDS if f != "seed"})

    @property
    def options(self) -> PMHTOptions:
        """The PMHT planner's options."""
        return PMHTOptions(**{f: getattr(self, f) for f in PMHT_OPTION_FIELDS})

    def criteria(self) -> tuple[StoppingCriterion, ...]:
        """When to stop, in the order they are asked: at ``tol``, when any of :attr:`stop` says so, or
        after ``max_iter`` iterations."""
        return (ObjectiveTolerance(self.tol), *self.stop, MaxIterations(self.max_iter))

    @classmethod
    def paper(cls, **changes: Any) -> PMHTConfig:
        """The paper's settings taken literally: 100 iterations, both prior updates, no annealing."""
        base: dict[str, Any] = {
            "max_iter": PMHT_ITERATIONS,
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
