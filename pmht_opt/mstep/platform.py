"""One platform's M-step QP: built once per horizon, its weights updated in place each iteration.

A trailing stretch of steps without weight (nothing pulls on the path after its last weighted step)
has the exact answer "no process noise": the path coasts from the state at the last weighted step.
Left in the QP, that stretch is a flat valley of the objective in which every backend stops early,
and the error grows along the coasting path (units at the horizon's end where the weights stop
halfway). Without constraint rows the QP is therefore solved up to the last weighted step only and the
tail is propagated exactly. A weight counts when it is above :data:`NEGLIGIBLE_WEIGHT` times the
platform's largest: below that its pull on the path is lost in rounding.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

import solvers
from pmht_opt.model import MotionModel
from pmht_opt.mstep.horizon import HorizonQP, Settings
from pmht_opt.mstep.rows import PlatformRows

#: Weights at or below this fraction of a platform's largest do not extend the horizon of its QP.
NEGLIGIBLE_WEIGHT = 1e-12


def weighted_horizon(W: np.ndarray) -> int:
    """The last step (``1..T``) whose weight is not negligible (:data:`NEGLIGIBLE_WEIGHT`); 0 if none."""
    peak = float(np.max(W)) if W.size else 0.0
    if peak <= 0.0:
        return 0
    steps = np.flatnonzero(W > NEGLIGIBLE_WEIGHT * peak)
    return int(steps[-1]) + 1


class PlatformQP:
    """The M-step of one platform: a :class:`~pmht_opt.mstep.horizon.HorizonQP` per horizon, the
    coasting tail propagated.

    Parameters are those of :class:`~pmht_opt.mstep.horizon.HorizonQP`. :meth:`solve` returns the
    backend's answer, the platform's states ``(T, 6)`` for ``t = 1..T`` and their whitened process
    noise ``(T, 6)`` (both ``None`` when the answer has no primal vector).
    """

    #: Horizons whose QP (and backend session) is kept for later iterations.
    CACHE = 4

    def __init__(
        self,
        model: MotionModel,
        x0: np.ndarray,
        horizon: int,
        session_class: type[solvers.QPSession],
        settings: dict[str, Any],
        constrained_settings: dict[str, Any] | None = None,
        retries: solvers.RetryChain = solvers.NO_RETRY,
        constrained_retries: solvers.RetryChain | None = None,
        margin: float = 0.0,
        condensed_settings: dict[str, Any] | None = None,
        working_settings: dict[str, Any] | None = None,
        condensed_retries: solvers.RetryChain = solvers.NO_RETRY,
    ) -> None:
        self.model = model
        #: The least absolute back-off of hard cones (:func:`~pmht_opt.mstep.rows.assemble`).
        self.margin = margin
        self.x0 = x0
        self.horizon = horizon
        self.session_class = session_class
        self.state = Settings(
            settings,
            settings if constrained_settings is None else constrained_settings,
            retries,
            constrained_retries,
            condensed=condensed_settings,
            condensed_retries=condensed_retries,
            working=working_settings,
        )
        self._qps: dict[int, HorizonQP] = {}

    @property
    def settings(self) -> dict[str, Any]:
        """The settings of unconstrained solves (a retry set that solved included)."""
        return self.state.plain

    @property
    def retries(self) -> solvers.RetryChain:
        """The settings tried after a failed solve."""
        return self.state.retries

    @retries.setter
    def retries(self, chain: solvers.RetryChain) -> None:
        self.state.retries = chain

    def qp(self, horizon: int) -> HorizonQP:
        """The QP of the first ``horizon`` steps (created on first use, the oldest dropped)."""
        if horizon not in self._qps:
            if len(self._qps) >= self.CACHE:
                self._qps.pop(next(iter(self._qps)))
            self._qps[horizon] = HorizonQP(
                self.model, self.x0, horizon, self.session_class, self.state, self.margin
            )
        return self._qps[horizon]

    def solve(
        self,
        W: np.ndarray,
        WZ: np.ndarray,
        r: float,
        rows: PlatformRows | None = None,
        probe: Callable[[solvers.QPSolution], None] | None = None,
        budget: solvers.WorkBudget | None = None,
        exact: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[solvers.QPSolution, np.ndarray | None, np.ndarray | None]:
        """Solve for weights ``W (T,)``, weighted locale sums ``WZ (T, 2)`` and constraint rows
        (``probe``, ``budget``, ``exact``: see :meth:`~pmht_opt.mstep.horizon.HorizonQP.solve`)."""
        T = self.horizon
        constrained = rows is not None and bool(rows.items)
        n = T if constrained else max(weighted_horizon(W), 1)
        qp = self.qp(n)
        sol = qp.solve(W[:n], WZ[:n], r, rows, probe, budget, exact if n == T else None)
        if sol.x is None:
            return sol, None, None
        head = qp.states(sol.x)
        noise = np.zeros((T, head.shape[1]))
        noise[:n] = qp.layout.noise(sol.x[: qp.layout.n])[0]
        if n == T:
            return sol, head, noise
        tail = self.model.propagate(head[-1], T - n)[1:]
        return sol, np.concatenate([head, tail]), noise
