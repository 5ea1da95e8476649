"""The one owner of "what happens at iteration i" of an EM run: the penalty ``r``, whether annealing
is over, and which constraints are imposed."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pmht_opt import validation
from pmht_opt.anneal import Anneal
from pmht_opt.constraints.base import Constraint
from pmht_opt.exceptions import ConfigError


@dataclass(frozen=True)
class Schedule:
    """Per-iteration answers for a run of ``max_iter`` iterations.

    Attributes
    ----------
    r
        ``(max_iter,)``: ``r[i - 1]`` is iteration ``i``'s penalty, used by its E-step and M-step.
    settled
        The first iteration from which every iteration uses the scenario's ``r`` (1 without annealing;
        ``max_iter + 1`` if the schedule never settles): annealing is over from there, and without
        constraints the EM objective never decreases from that iteration on.
    """

    r: np.ndarray
    settled: int

    def __post_init__(self) -> None:
        r = validation.real_array("Schedule.r", self.r, ConfigError)
        if r.ndim != 1 or r.size == 0 or not np.all(np.isfinite(r)) or np.any(r <= 0):
            raise ConfigError(
                f"Schedule.r: expected a non-empty 1-D array of positive penalties, got {self.r!r}."
            )
        settled = validation.integer("Schedule.settled", self.settled, ConfigError, 1, r.size + 1)
        object.__setattr__(self, "r", r)
        object.__setattr__(self, "settled", settled)

    @classmethod
    def of(cls, anneal: Anneal, r: float, max_iter: int) -> Schedule:
        """The schedule of annealing ``anneal`` towards the scenario's ``r`` over ``max_iter`` iterations."""
        values = anneal.values(r, max_iter)
        off = np.nonzero(values != r)[0]
        return cls(values, int(off[-1]) + 2 if off.size else 1)

    @property
    def max_iter(self) -> int:
        """The run's iteration budget."""
        return int(self.r.shape[0])

    def r_at(self, iteration: int) -> float:
        """The penalty of iteration ``iteration`` (``1..max_iter``)."""
        return float(self.r[iteration - 1])

    def start(self, constraint: Constraint) -> int:
        """The first iteration that imposes ``constraint``.

        A constraint without a warm-up is imposed throughout. One with ``warmup = k`` waits ``k``
        iterations after annealing ends, but starts early enough to reach full strength (after its
        ``ramp``) by the last iteration, so the returned plan has it.
        """
        if constraint.warmup is None:
            return 1
        latest = max(1, self.max_iter - max(constraint.ramp, 1) + 1)
        return min(self.settled + constraint.warmup, latest)

    def imposes(self, constraint: Constraint, iteration: int) -> bool:
        """Whether ``constraint`` is imposed in iteration ``iteration``."""
        return iteration >= self.start(constraint)

    def strength(self, constraint: Constraint, iteration: int) -> float:
        """How much of ``constraint`` iteration ``iteration`` imposes, in ``(0, 1]``.

        A constraint with a ``ramp`` of ``n`` iterations is brought in over its first ``n`` (fewer if
        the run ends sooner): ``k / n`` in its ``k``-th, then 1. Others are imposed whole.
        """
        ramp = constraint.ramp
        if ramp <= 0:
            return 1.0
        first = self.start(constraint)
        span = max(1, min(ramp, self.max_iter - first + 1))
        return min(1.0, (iteration - first + 1) / span)

    def active(self, constraints: Sequence[Constraint], iteration: int) -> tuple[int, ...]:
        """Indices of the ``constraints`` imposed in ``iteration``."""
        return tuple(i for i, c in enumerate(constraints) if self.imposes(c, iteration))

    def strengths(self, constraints: Sequence[Constraint], iteration: int) -> tuple[float, ...]:
        """The :meth:`strength` of each active constraint, in the order of :meth:`active`."""
        return tuple(self.strength(constraints[i], iteration) for i in self.active(constraints, iteration))

    def settled_at(self, constraints: Sequence[Constraint], iteration: int) -> bool:
        """Whether ``iteration`` and the one before ran in the final regime: at the scenario's ``r``
        and with every constraint imposed at full strength. Convergence is only judged from there, so
        the last two objectives compared were computed alike and the returned plan has every
        constraint (the first iteration at the final ``r`` still compares against another ``r``)."""
        if iteration <= self.settled:
            return False
        return all(
            self.imposes(c, iteration - 1) and self.strength(c, iteration - 1) == 1.0 for c in constraints
        )
