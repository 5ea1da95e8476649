"""User constraints written in cvxpy, for the ``cvxpy`` backend."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt.constraints.base import Constraint, ConstraintContext, ConstraintReport
from pmht_opt.constraints.blocks import Block
from pmht_opt.exceptions import ConfigError
from pmht_opt.model import AX, AY, PX, PY, VX, VY


@dataclass
class CvxpyVariables:
    """What a :class:`CvxpyConstraint` function receives: the M-step's cvxpy variables.

    Attributes
    ----------
    states
        One ``(T, 6)`` cvxpy variable per platform, rows ``t = 1..T``, columns
        ``[px, vx, ax, py, vy, ay]``.
    positions, velocities, accelerations
        One ``(T, 2)`` cvxpy expression per platform (columns ``x, y``), views of :attr:`states`.
    dt
        Time step.
    """

    states: list[Any]
    positions: list[Any]
    velocities: list[Any]
    accelerations: list[Any]
    dt: float

    @classmethod
    def of(cls, states: list[Any], dt: float) -> CvxpyVariables:
        """Wrap per-platform ``(T, 6)`` variables."""
        import cvxpy as cp

        def pair(X: Any, a: int, b: int) -> Any:
            return cp.hstack([X[:, a : a + 1], X[:, b : b + 1]])

        return cls(
            states=states,
            positions=[pair(X, PX, PY) for X in states],
            velocities=[pair(X, VX, VY) for X in states],
            accelerations=[pair(X, AX, AY) for X in states],
            dt=dt,
        )

    @property
    def n_platforms(self) -> int:
        """Number of platforms."""
        return len(self.states)


class CvxpyConstraint(Constraint):
    """Any convex constraint a user can write in cvxpy on the paths (``solver="cvxpy"`` only).

    Parameters
    ----------
    fn
        ``fn(vars: CvxpyVariables) -> list of cvxpy constraints``; called once when the M-step is
        compiled (it must not depend on the iterate).
    name
        Label used in reports and error messages.
    soft, weight
        In soft mode every entry of a returned inequality or equality gets a slack with the
        penalty ``weight`` per unit of violation.

    Examples
    --------
    Keep platform 0 to the left of x = 5 for the first half of the horizon::

        CvxpyConstraint(lambda v: [v.positions[0][:250, 0] <= 5.0], name="west first")
    """

    exact = True  # the user's own convex constraint, written whole

    needs = frozenset({"cvxpy"})

    def __init__(
        self, fn: Callable[[CvxpyVariables], Any], name: str = "CvxpyConstraint", **kwargs: Any
    ) -> None:
        super().__init__(**kwargs)
        if not callable(fn):
            raise ConfigError(f"CvxpyConstraint: fn must be callable, got {type(fn).__name__}.")
        self.fn = fn
        if not isinstance(name, str) or not name:
            raise ConfigError(f"CvxpyConstraint.name: expected a non-empty string, got {name!r}.")
        self._name = name

    @property
    def name(self) -> str:
        return self._name

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        return []

    def build(self, variables: CvxpyVariables) -> list[Any]:
        """The cvxpy constraints ``fn`` writes on ``variables``, checked to be cvxpy constraints.

        In soft mode the M-step relaxes them by the exact L1 rule of every soft constraint
        (:func:`pmht_opt.mstep.rows.soften_cvxpy`): inequalities and equalities only.
        """
        import cvxpy as cp

        out = self.fn(variables)
        items = list(out) if isinstance(out, (list, tuple)) else [out]
        for c in items:
            if not isinstance(c, cp.constraints.constraint.Constraint):
                raise ConfigError(f"{self.name}: fn must return cvxpy constraints, got {type(c).__name__}.")
            if self.soft and not isinstance(c, (cp.constraints.Inequality, cp.constraints.Equality)):
                raise ConfigError(
                    f"{self.name}: soft mode takes inequalities and equalities only, got {type(c).__name__}."
                )
        return items

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        import cvxpy as cp

        T = states.shape[1] - 1
        variables = [cp.Variable((T, states.shape[2])) for _ in range(states.shape[0])]
        for X, value in zip(variables, states[:, 1:, :], strict=True):
            X.value = value
        out = self.fn(CvxpyVariables.of(variables, ctx.scenario.dt))
        items = list(out) if isinstance(out, (list, tuple)) else [out]
        worst = max((float(np.max(np.atleast_1d(c.violation()))) for c in items), default=0.0)
        count = sum(int(np.sum(np.atleast_1d(c.violation()) > 1e-6)) for c in items)
        return ConstraintReport(self.name, self.soft, max(worst, 0.0), count, None)
