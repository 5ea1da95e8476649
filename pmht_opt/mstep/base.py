"""The contract every M-step backend meets: what goes in, what comes out, what it can impose."""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar, Protocol

import numpy as np

import solvers
from pmht_opt.constraints.base import Constraint, ConstraintContext
from pmht_opt.exceptions import ConfigError
from pmht_opt.parallel import thread_count
from pmht_opt.scenario import Scenario
from solvers.banded import BandedSmootherResult


class ExactReference(Protocol):
    """The exact unconstrained smoother an M-step's answers are checked against: for given weights,
    its answer for every platform and both axes."""

    def smooth(self, data: MStepData) -> BandedSmootherResult:
        """The exact smoother's answer for ``data``'s weights."""
        ...


#: ``check(mstep, data, output)``: raises if ``output`` is not a plausible answer of ``data``.
AnswerCheck = Callable[["MStep", "MStepData", "MStepOutput"], None]


@dataclass
class MStepData:
    """One M-step's input.

    Attributes
    ----------
    W
        ``(T, M)`` summed weights ``sum_n w[n, t, m]`` (t = 1..T).
    WZ
        ``(T, M, 2)`` weighted locale sums ``sum_n w[n, t, m] z_n``.
    r
        The fitting penalty's variance for this iteration.
    ctx
        What constraint rows are written from (linearisation point, E-step); ``None`` without
        constraints.
    active
        Indices, into the backend's constraints, of those imposed in this M-step (the planner's
        schedule decides).
    strengths
        How much of each active constraint is imposed (:attr:`ConstraintContext.strength`), in the
        order of ``active``; empty means every one whole.
    """

    W: np.ndarray
    WZ: np.ndarray
    r: float
    ctx: ConstraintContext | None = None
    active: tuple[int, ...] = ()
    strengths: tuple[float, ...] = ()

    def synthetic(self) -> tuple[np.ndarray, np.ndarray]:
        """Synthetic measurements ``WZ / W`` (zero where ``W == 0``) and their weights ``W``."""
        W = self.W
        with np.errstate(invalid="ignore", divide="ignore"):
            zt = np.where(W[..., None] > 0, self.WZ / W[..., None], 0.0)
        return zt, W


@dataclass
class MStepOutput:
    """Paths ``(M, T+1, 6)`` including ``t = 0``, and how the solve went.

    ``status`` is the library's status of the least successful platform solve (the backend's own
    words in ``raw_status``); ``fallbacks`` counts the platforms whose solve needed a retry with other
    settings; ``constrained`` lists the platforms that had constraint rows. ``noise`` is the whitened
    process noise ``(M, T, 6)`` of the answer where the backend
    has it (its own variables, or multipliers): the prior term ``1/2 sum ||u||^2`` of the EM objective
    is then taken from it rather than from differences of nearly equal states.
    """

    states: np.ndarray
    status: solvers.Status = solvers.Status.OPTIMAL
    raw_status: str = "optimal"
    iterations: int = 0
    fallbacks: int = 0
    noise: np.ndarray | None = None
    constrained: tuple[int, ...] = ()
    info: dict[str, object] = field(default_factory=dict)


class MStep(abc.ABC):
    """One backend of the M-step, built for one scenario and reused across EM iterations.

    Parameters
    ----------
    scenario
        The scenario (starts, horizon, model).
    settings
        Options for the backend, passed on verbatim over this package's tuned defaults.
    accept_inaccurate
        Use answers the backend flags as inaccurate instead of raising ``SolverError``.
    constraints
        Every constraint of the run; :attr:`MStepData.active` says which are imposed in a solve.
    threads
        Threads a solve may use (the exact smoother splits its batch of platforms over them).
    reference
        The exact unconstrained smoother of this scenario, which answers are checked against
        (:class:`ExactReference`; the registry gives every backend but the exact one its own).
    check
        The check every answer passes before :meth:`solve` returns it (the registry gives
        :func:`pmht_opt.mstep.check.check_answer`); ``None`` checks nothing.
    """

    #: Registry name.
    name: ClassVar[str] = ""

    def __init__(
        self,
        scenario: Scenario,
        settings: dict[str, object] | None = None,
        accept_inaccurate: bool = False,
        constraints: tuple[Constraint, ...] = (),
        threads: int = 1,
        *,
        reference: ExactReference | None = None,
        check: AnswerCheck | None = None,
    ) -> None:
        self.scenario = scenario
        self.constraints = tuple(constraints)
        self.model = scenario.model
        self.settings = dict(settings or {})
        self.accept_inaccurate = accept_inaccurate
        self.T = scenario.horizon
        self.M = scenario.n_platforms
        self.x0 = scenario.initial_states
        self.threads = thread_count(threads)
        self._reference = reference
        self._check = check
        self._setup()

    def _setup(self) -> None:
        """What a backend prepares once from the attributes above (nothing by default)."""
        return None

    def solve(self, data: MStepData) -> MStepOutput:
        """Minimise ``J`` for these weights, subject to the constraints active in ``data``.

        The answer is checked before it is returned (the ``check`` given at construction,
        :func:`~pmht_opt.mstep.check.check_answer` from the registry): a backend that reports
        success on a wrong answer raises :class:`~pmht_opt.exceptions.WrongAnswerError`.
        """
        out = self._solve(data)
        if self._check is not None:
            self._check(self, data, out)
        return out

    @abc.abstractmethod
    def _solve(self, data: MStepData) -> MStepOutput:
        """The backend's own solve."""

    def reference(self) -> ExactReference:
        """The exact unconstrained smoother of this scenario, which answers are checked against."""
        if self._reference is None:
            raise ConfigError(f"the {self.name} M-step was built without an exact reference.")
        return self._reference

    def close(self) -> None:  # noqa: B027 - most backends hold nothing to release
        """Release threads or solver workspaces held by this backend."""

    def _with_start(self, body: np.ndarray) -> np.ndarray:
        """Prepend the known initial states to ``(M, T, 6)`` paths."""
        return np.concatenate([self.x0[:, None, :], body], axis=1)


def check_cvxpy_solver(settings: dict[str, object], field: str) -> None:
    """Raise :class:`~pmht_opt.exceptions.UnknownSolverError` naming ``field`` if the settings'
    ``cvxpy_solver`` (default ``"CLARABEL"``) is not a solver cvxpy has installed."""
    from pmht_opt.exceptions import UnknownSolverError
    from solvers.cvxpy_ import check_solver_name  # cvxpy's solver names, where cvxpy is asked for

    try:
        check_solver_name(str(settings.get("cvxpy_solver", "CLARABEL")))
    except solvers.UnknownSolverError as err:
        raise UnknownSolverError(f"{field}: {err}") from err
