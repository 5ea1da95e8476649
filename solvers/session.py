"""The common shape of a backend: a session built once, updated in place, solved many times."""

from __future__ import annotations

import abc
import threading
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from solvers.exceptions import SettingsError, UpdateError
from solvers.problem import QPProblem, QPSolution, Status, floats


def work_amount(what: str, value: object) -> float:
    """``value`` as an amount of work (:class:`WorkBudget`): a positive finite number, else
    :class:`SettingsError` naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < np.inf:
        raise SettingsError(f"{what} must be a positive finite number, got {value!r}.")
    return float(value)


class WorkBudget:
    """Work that several solves share; a backend that counts its work stops when it is spent.

    Work is iterations times the problem's size (stored entries of ``P`` and ``A`` plus rows and
    columns), roughly proportional to the time a first-order iteration takes, and the same on any
    machine under any load, unlike a time limit. OSQP counts it; interior-point backends, whose
    iterations are few and whose cost does not scale this way, ignore it. Shared by threads.

    Parameters
    ----------
    limit
        The work all solves together may spend (positive, finite).
    """

    def __init__(self, limit: float) -> None:
        self.limit = work_amount("a work budget", limit)
        self.spent = 0.0
        self._lock = threading.Lock()

    def room(self, size: int) -> int:
        """Iterations left for a problem of ``size``."""
        with self._lock:
            return max(int((self.limit - self.spent) // max(size, 1)), 0)

    def spend(self, work: float) -> None:
        """Record ``work`` as spent."""
        with self._lock:
            self.spent += float(work)


@dataclass(frozen=True)
class Update:
    """New numbers for a session's problem (``None``: unchanged), already validated.

    ``P_data`` and ``A_data`` are the values of the stored entries of ``P`` (upper triangle) and ``A`` in
    CSC order; ``q`` and ``b`` are whole vectors.
    """

    P_data: np.ndarray | None = None
    q: np.ndarray | None = None
    A_data: np.ndarray | None = None
    b: np.ndarray | None = None


class QPSession(abc.ABC):
    """A QP handed to one backend, whose numbers can change between solves but whose structure cannot.

    Subclasses implement :meth:`_setup`, :meth:`_apply_update` and :meth:`_solve`. The session keeps
    :attr:`problem` in step with every update, so a solution can always be checked against the exact
    problem it claims to solve.

    Parameters
    ----------
    problem
        The problem; its sparsity pattern (of ``P`` and ``A``) and cones are fixed for the session.
    settings
        Backend options, passed on verbatim after the backend's defaults. An unknown option raises.
    """

    #: Registry name of the backend.
    name: ClassVar[str] = ""
    #: Whether the backend accepts second-order cones.
    supports_soc: ClassVar[bool] = False

    def __init__(self, problem: QPProblem, **settings: Any) -> None:
        self.problem = problem
        self.settings = dict(settings)
        #: Work shared with other sessions (:class:`WorkBudget`); ``None``: this session's own limits only.
        self.budget: WorkBudget | None = None
        self._setup()

    @abc.abstractmethod
    def _setup(self) -> None:
        """Hand :attr:`problem` to the backend."""

    @abc.abstractmethod
    def _apply_update(self, update: Update) -> None:
        """Push new numbers (already validated and stored in :attr:`problem`) to the backend."""

    @abc.abstractmethod
    def _solve(self) -> QPSolution:
        """Solve the current problem."""

    def update(
        self,
        *,
        P_data: np.ndarray | None = None,
        q: np.ndarray | None = None,
        A_data: np.ndarray | None = None,
        b: np.ndarray | None = None,
    ) -> None:
        """Replace numbers of the problem, keeping its structure.

        Parameters
        ----------
        P_data
            New values of the stored entries of the upper triangle of ``P``, in CSC order
            (``problem.P.data``).
        q
            New linear cost.
        A_data
            New values of the stored entries of ``A``, in CSC order (``problem.A.data``).
        b
            New right-hand side.
        """
        prob = self.problem
        P_data = _checked("P_data", P_data, prob.P.data.shape[0])
        q = _checked("q", q, prob.n)
        A_data = _checked("A_data", A_data, prob.A.data.shape[0])
        b = _checked("b", b, prob.m)
        if P_data is not None:
            prob.P.data[:] = P_data
        if q is not None:
            prob.q = q
        if A_data is not None:
            prob.A.data[:] = A_data
        if b is not None:
            prob.b = b
        self._apply_update(Update(P_data, q, A_data, b))

    @property
    def adapts_to_updates(self) -> bool:
        """Whether the session stays tuned to numbers that have moved far from those of its setup.

        Backends equilibrate the problem at setup. Where updates keep that scaling (Clarabel applies it
        to the new data) and nothing else adapts (an interior point), a scaling far from the numbers
        can leave solves short of their tolerances, and a caller whose numbers move far should
        :meth:`rescale`. The default is ``False``.
        """
        return False

    def rescale(self) -> None:
        """Set the backend up afresh on the current numbers, so that its scaling fits them.

        For a caller whose numbers moved far from those of the setup (:attr:`adapts_to_updates`). The
        default hands :attr:`problem` to a new backend object, as at construction.
        """
        self._setup()

    def resume(self, **settings: Any) -> QPSolution | None:
        """Solve again from where the last solve stopped, with ``settings`` changed; ``None`` if the
        backend cannot (the caller then opens a new session with the merged settings).

        A first-order backend that stopped at its iteration limit keeps its iterate: continuing with a
        higher limit costs only the extra iterations, where a new session starts from nothing. The
        default is ``None``: interior-point backends have no iterate worth continuing from.
        """
        return None

    def warm_start(self, x: np.ndarray | None = None, y: np.ndarray | None = None) -> bool:
        """Start the next solve from the primal ``x`` and the dual ``y`` (either may be ``None``);
        ``False`` if the backend has no use for a starting point.

        A first-order backend starts from where it is told, so a point near the answer saves
        iterations; an interior point starts from its own central point whatever it is given. The
        default is ``False``.
        """
        return False

    def solve(self) -> QPSolution:
        """Solve the current problem and return the backend's answer with a mapped status.

        Raises
        ------
        KeyboardInterrupt
            When the backend reports that it stopped on an interrupt (OSQP and Clarabel catch SIGINT
            themselves and return a status): an interrupt is the user's, never a failed solve to retry
            with other settings.
        """
        sol = self._solve()
        if sol.status is Status.INTERRUPTED:
            raise KeyboardInterrupt(f"{sol.backend}: the solve was interrupted ({sol.raw_status}).")
        return sol


def _checked(name: str, values: np.ndarray | None, size: int) -> np.ndarray | None:
    if values is None:
        return None
    arr = floats(name, values, UpdateError).reshape(-1)
    if arr.shape[0] != size:
        raise UpdateError(f"{name} has {arr.shape[0]} values, the session's problem has {size}.")
    if not np.all(np.isfinite(arr)):
        raise UpdateError(f"{name} has non-finite values.")
    return arr.copy()
