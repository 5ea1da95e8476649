"""The constraint protocol: what a constraint needs from a backend, what it adds to a platform's
M-step, and how a plan is checked against it.

A constraint is a small object with these duties:

* :attr:`Constraint.needs`: the capabilities a backend must have to impose it: ``"linear"`` rows,
  second-order cones (``"soc"``; a backend with linear rows only receives inner polygons instead,
  decided by the M-step), or native cvxpy expressions (``"cvxpy"``);
* :meth:`Constraint.check_scenario`: reject a scenario that violates it before anything is solved
  (a start inside an obstacle, outside the area);
* :meth:`Constraint.blocks`: the rows it adds to one EM iteration's M-step, as
  :class:`~pmht_opt.constraints.blocks.Block` s of conic rows on one platform's stacked states;
* :meth:`Constraint.violation`: how far a returned plan is from meeting it, measured on the exact
  geometry (true circles, not polygons), per platform and time step;
* :attr:`Constraint.warmup`: ``None`` to be imposed from the first EM iteration, or a number of
  iterations to wait after annealing ends (the planner's schedule applies it).

Soft mode (``soft=True``) is applied by the M-step, not the kinds: each unit of a block (a row of a
linear block, a whole cone of a conic block) gets a non-negative slack ``s`` that relaxes it, and
``weight * s`` joins the cost. That is an exact L1 penalty: when the hard problem is feasible and
``weight`` exceeds the constraint's multipliers, the soft problem has the hard problem's solution.
"""

from __future__ import annotations

import abc
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, cast

import numpy as np

from pmht_opt.constraints.blocks import Block
from pmht_opt.constraints.params import WEIGHT_MAX, check_platforms, positive_number
from pmht_opt.exceptions import ConfigError

if TYPE_CHECKING:
    from pmht_opt.estep import EStepResult
    from pmht_opt.scenario import Scenario

#: What a backend may be asked for: linear rows, second-order cones, native cvxpy constraints.
CAPABILITIES = frozenset({"linear", "soc", "cvxpy"})

#: Violations at or below this fraction of a constraint's own size (:meth:`Constraint.scale`) are
#: reported as met.
VIOLATION_TOL = 1e-6


@dataclass
class ConstraintContext:
    """What a constraint may look at when it writes one iteration's rows.

    Attributes
    ----------
    scenario
        The scenario being planned.
    states
        ``(M, T+1, 6)`` current iterate (the previous M-step's answer): the linearisation point of the
        non-convex kinds.
    estep
        The E-step that produced this iteration's weights (MAP assignments for visit constraints).
    iteration
        EM iteration about to be solved (``1..``).
    strength
        How much of the constraint this iteration imposes, in ``(0, 1]`` (the planner's schedule
        brings constraints with a ``ramp`` in gradually); 1 is the constraint itself.
    ends
        ``(M, 3)``: where the hard constraints pin each platform's path at ``t = T``, as ``x, y`` and
        the radius it must end within (NaN rows for platforms whose end is free); ``None``: no end is
        pinned. Visit schedules keep visits away from the last steps of a path that must end far from
        the locale (:func:`pinned_ends`).
    """

    scenario: Scenario
    states: np.ndarray
    estep: EStepResult | None = None
    iteration: int = 1
    strength: float = 1.0
    ends: np.ndarray | None = None


def pinned_ends(scenario: Scenario, constraints: Sequence[Constraint]) -> np.ndarray | None:
    """``(M, 3)`` final positions (``x, y, radius``) that hard constraints impose; NaN where free.

    Only a constraint's :meth:`Constraint.end_position` pins an end (a hard
    :class:`~pmht_opt.constraints.terminal.Terminal` position); the smallest radius wins where two pin
    the same platform. ``None`` when nothing is pinned.
    """
    out = np.full((scenario.n_platforms, 3), np.nan)
    for con in constraints:
        if con.soft:
            continue
        for m, xy, radius in con.end_position(scenario):
            if np.isnan(out[m, 2]) or radius < out[m, 2]:
                out[m] = (xy[0], xy[1], radius)
    return None if np.isnan(out[:, 2]).all() else out


@dataclass
class ConstraintReport:
    """How well one constraint holds on a plan (exact geometry).

    Attributes
    ----------
    name
        The constraint's description.
    soft
        Whether it was imposed softly.
    max_violation
        Largest violation over all platforms and times (0 when met).
    n_violations
        Number of (platform, time) units violated by more than :data:`VIOLATION_TOL` of the
        constraint's own size (:meth:`Constraint.scale`).
    worst
        ``(platform, time)`` of the largest violation, or ``None``.
    details
        Kind-specific extras (e.g. segments that cut an obstacle).
    """

    name: str
    soft: bool
    max_violation: float
    n_violations: int
    worst: tuple[int, int] | None
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def satisfied(self) -> bool:
        """Whether every unit holds within :data:`VIOLATION_TOL` of the constraint's size."""
        return self.n_violations == 0


class Constraint(abc.ABC):
    """Base class of every constraint kind.

    Parameters
    ----------
    soft
        Impose the constraint through an exact L1 penalty on slacks instead of as a hard constraint;
        the plan then exists even when the constraint cannot be met, and its report gives the
        violations.
    weight
        Penalty per unit of violation in soft mode (in units of the M-step cost, whose fit term is
        ``W / (2 r)`` times a squared distance, so ``r = 0.01`` makes 1e3 a moderate weight).
    platforms
        Platforms the constraint applies to; ``None`` means all.
    """

    #: Capabilities a backend needs to impose this kind (see :data:`CAPABILITIES`).
    needs: frozenset[str] = frozenset({"linear"})
    #: Whether :meth:`blocks` depends on the iterate (linearisations, MAP visits).
    dynamic: ClassVar[bool] = False
    #: Whether its rows *are* the constraint on every path: convex, written whole, neither linearised at
    #: an iterate nor placed at steps a planner chose (a speed limit, an area, a terminal condition).
    #: Only such rows can prove that no plan meets the constraints (:mod:`pmht_opt.mstep.diagnosis`).
    exact: ClassVar[bool] = False
    #: ``None``: imposed from the first iteration; ``k``: from ``k`` iterations after annealing ends.
    warmup: int | None = None
    #: Iterations over which the schedule brings the constraint in (``ConstraintContext.strength``).
    ramp: int = 0

    def __init__(self, soft: bool = False, weight: float = 1e4, platforms: Any = None) -> None:
        if not isinstance(soft, (bool, np.bool_)):
            raise ConfigError(f"{type(self).__name__}.soft: expected True or False, got {soft!r}.")
        self.soft = bool(soft)
        self.weight = positive_number(f"{type(self).__name__}.weight", weight, maximum=WEIGHT_MAX)
        self.platforms = check_platforms(type(self).__name__, platforms)

    @property
    def name(self) -> str:
        """Short description used in reports and error messages."""
        return type(self).__name__

    def implied(self) -> list[Constraint]:
        """Constraints that come with this one (the planner adds them unless already given)."""
        return []

    def applies_to(self, scenario: Scenario) -> list[int]:
        """Platforms of ``scenario`` this constraint binds."""
        if self.platforms is None:
            return list(range(scenario.n_platforms))
        return list(self.platforms)

    def check_scenario(self, scenario: Scenario) -> None:
        """Raise :class:`~pmht_opt.exceptions.ScenarioError` or :class:`ConfigError` before any solve
        if ``scenario`` makes this constraint meaningless (a start inside an obstacle, parameters per
        platform of the wrong length, platform indices out of range)."""
        bad = [p for p in self.applies_to(scenario) if p >= scenario.n_platforms]
        if bad:
            raise ConfigError(
                f"{self.name}: platforms {bad} do not exist (the scenario has {scenario.n_platforms})."
            )

    def scale(self, scenario: Scenario) -> float:
        """The constraint's own size (a limit, a radius, an area's side), in its own units:
        verification tolerances are relative to it. The default is the scenario's extent."""
        xmin, xmax, ymin, ymax = scenario.bounds or (0.0, 1.0, 0.0, 1.0)
        return max(xmax - xmin, ymax - ymin, 1e-12)

    def end_position(self, scenario: Scenario) -> list[tuple[int, np.ndarray, float]]:
        """``(platform, (2,) position, radius)`` for each platform whose final position this constraint
        fixes (within ``radius``); none by default (:func:`pinned_ends`)."""
        return []

    @abc.abstractmethod
    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        """Rows for this iteration's M-step, one or more blocks per bound platform."""

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        """Violations on the plan ``states (M, T+1, 6)``, measured exactly.

        ``ctx`` is the context of the M-step that produced ``states`` (its linearisation point and
        E-step), so kinds whose rows depend on the iterate are judged on the rows they imposed. The
        default measures this constraint's own blocks (with their cones, not polygons) at ``states``;
        kinds that linearise a non-convex set override it with the exact geometry.
        """
        return self._report(ctx.scenario, self._block_residuals(self.blocks(ctx), states))

    def _block_residuals(
        self, blocks: list[Block], states: np.ndarray
    ) -> list[tuple[int, np.ndarray, np.ndarray]]:
        out = []
        for blk in blocks:
            z = states[blk.platform, 1:, :].reshape(-1)
            out.append((blk.platform, blk.times, blk.residual(z)))
        return out

    def _report(
        self,
        scenario: Scenario,
        residuals: list[tuple[int, np.ndarray, np.ndarray]],
        details: dict[str, Any] | None = None,
    ) -> ConstraintReport:
        tol = VIOLATION_TOL * self.scale(scenario)
        worst_val, worst_at, count = 0.0, None, 0
        for platform, times, res in residuals:
            if res.size == 0:
                continue
            count += int(np.sum(res > tol))
            i = int(np.argmax(res))
            if res[i] > worst_val:
                worst_val, worst_at = float(res[i]), (int(platform), int(times[i]))
        return ConstraintReport(
            name=self.name,
            soft=self.soft,
            max_violation=worst_val,
            n_violations=count,
            worst=worst_at if worst_val > tol else None,
            details=details or {},
        )


def fitting_constraints(
    scenario: Scenario, constraints: Any, containers: tuple[type, ...] = (tuple, list)
) -> tuple[Constraint, ...]:
    """``constraints`` (one of ``containers``, never a lone constraint) as a tuple of constraints that
    fit ``scenario``; :class:`ConfigError` naming ``constraints`` otherwise, or the constraint's own
    error when it does not fit the scenario."""
    if isinstance(constraints, Constraint) or not isinstance(constraints, containers):
        raise ConfigError(f"constraints: expected a sequence of constraints, got {constraints!r}.")
    cons: tuple[Any, ...] = tuple(cast("Iterable[Any]", constraints))  # a container, checked above
    for con in cons:
        if not isinstance(con, Constraint):
            raise ConfigError(
                f"constraints: expected pmht_opt.constraints objects, got {type(con).__name__}."
            )
        con.check_scenario(scenario)
    return cons
