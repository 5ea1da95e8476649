"""Limits on speed and acceleration: on the states and on the motion measured from the positions.

The motion model moves positions by process noise directly (``Q`` has a position component), so a
bound on the velocity *state* does not bound the displacement ``p_t - p_{t-1}`` a user measures: a
plan can meet a speed limit on its states and still jump. Each limit therefore holds on both:

* :class:`SpeedLimit`: ``||v_t|| <= vmax`` and ``||p_t - p_{t-1}|| <= vmax dt`` for ``t = 1..T``;
* :class:`AccelLimit`: ``||a_t|| <= amax`` and ``||p_{t+1} - 2 p_t + p_{t-1}|| <= amax dt^2`` for
  ``t = 0..T-1``, with ``p_{-1} = p_0 - v_0 dt`` (the start's own velocity): the first step may not
  change the velocity more than the limit allows either.

Every bound is a second-order cone per step (inner polygons on a backend without cones). A start
whose state already breaks a limit is rejected before planning (:class:`~pmht_opt.ScenarioError`):
the limit could only hold from some later step, after a manoeuvre the limit itself forbids.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from pmht_opt.constraints.base import Constraint, ConstraintContext, ConstraintReport
from pmht_opt.constraints.blocks import DEFAULT_SIDES, Block, difference_block, disc_block
from pmht_opt.constraints.params import check_sides, limits
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.model import AX, AY, POS, PX, PY, VX, VY

if TYPE_CHECKING:
    from pmht_opt.scenario import Scenario


#: The smallest travel over the horizon a motion limit may allow, relative to the scenario's extent.
RESOLVED = 1e-9


class _NormLimit(Constraint):
    """A bound on the norm of a state pair and of a finite difference of positions (module docstring)."""

    needs = frozenset({"soc"})
    exact = True
    comps: ClassVar[tuple[int, int]] = (VX, VY)
    #: Finite-difference stencil on the positions, ``(offset, coefficient)`` pairs.
    stencil: ClassVar[tuple[tuple[int, float], ...]] = ((0, 1.0), (-1, -1.0))
    #: Power of ``dt`` that turns the limit into a bound on the difference.
    order: ClassVar[int] = 1
    quantity: ClassVar[str] = "speed"

    def __init__(self, limit: Any, sides: int = DEFAULT_SIDES, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.limit = limits(type(self).__name__, limit)
        self.sides = check_sides(type(self).__name__, sides)

    @property
    def name(self) -> str:
        lim = f"{self.limit[0]:g}" if self.limit.size == 1 else str(self.limit.tolist())
        return f"{type(self).__name__}({lim})"

    def limit_for(self, platform: int) -> float:
        """The limit of ``platform``."""
        return float(self.limit[0] if self.limit.size == 1 else self.limit[platform])

    def scale(self, scenario: Scenario) -> float:
        """The size verification tolerances are relative to: the smallest limit."""
        return float(np.min(self.limit))

    def check_scenario(self, scenario: Scenario) -> None:
        super().check_scenario(scenario)
        if self.limit.size not in (1, scenario.n_platforms):
            raise ConfigError(
                f"{self.name}: {self.limit.size} limits given for {scenario.n_platforms} platforms."
            )
        # Below this the limit is rounding on the scenario's scale: rows scaled to it overflow.
        span = scenario.horizon * scenario.dt
        reach = float(np.min(self.limit)) * span**self.order
        extent = Constraint.scale(self, scenario)
        if reach < RESOLVED * extent:
            raise ConfigError(
                f"{self.name}: at this limit a platform moves {reach:.3g} in the whole horizon, below "
                f"{RESOLVED:g} of the scenario's extent ({extent:g}), which the solvers cannot resolve. "
                "To keep a platform where it is, end it there with Terminal(position=...)."
            )
        for m in self.applies_to(scenario):
            value = float(np.hypot(*scenario.initial_states[m, list(self.comps)]))
            if value > self.limit_for(m):
                raise ScenarioError(
                    f"platform {m} starts with {self.quantity} {value:g}, above {self.name}; the limit "
                    "cannot hold from the first step. Start it within the limit or raise the limit."
                )

    def _difference_times(self, T: int) -> np.ndarray:
        reach = max(k for k, _ in self.stencil)
        return np.arange(1, T + 1 - reach)

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        sc = ctx.scenario
        T = sc.horizon
        times = np.arange(1, T + 1)
        steps = self._difference_times(T)
        out = []
        for m in self.applies_to(sc):
            lim = self.limit_for(m)
            out.append(disc_block(m, T, times, self.comps, np.zeros(2), np.full(T, lim), self.sides))
            bound = lim * sc.dt**self.order
            start = sc.start_positions[m]
            if steps.size:
                stencil = dict(self.stencil)
                out.append(
                    difference_block(
                        m, T, steps, stencil, start, np.full(steps.size, bound), (PX, PY), self.sides
                    )
                )
            if self.order == 2:  # t = 0: p_1 - p_0 - v_0 dt, the change from the start's own velocity
                first = difference_block(
                    m, T, np.array([0]), {1: 1.0, 0: -1.0}, start, np.array([bound]), (PX, PY), self.sides
                )
                first.h[1:] += sc.initial_states[m, [VX, VY]] * sc.dt
                out.append(first)
        return out

    def measured(self, states: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(M, T)`` norms of the state pair at ``t = 1..T`` and ``(M, T')`` norms of the position
        difference per unit time (``dt**order``), both in the limit's units."""
        state = np.hypot(states[:, 1:, self.comps[0]], states[:, 1:, self.comps[1]])
        pos = states[:, :, POS]
        diff = np.zeros_like(pos[:, : pos.shape[1] - max(k for k, _ in self.stencil) - 1])
        for offset, coef in self.stencil:
            lo = 1 + offset
            diff = diff + coef * pos[:, lo : lo + diff.shape[1]]
        if self.order == 2:  # t = 0 (module docstring)
            first = pos[:, 1] - pos[:, 0] - states[:, 0][:, [VX, VY]] * dt
            diff = np.concatenate([first[:, None, :], diff], axis=1)
        return state, np.hypot(diff[..., 0], diff[..., 1]) / dt**self.order

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        sc = ctx.scenario
        state, moved = self.measured(states, sc.dt)
        residuals = []
        for m in self.applies_to(sc):
            lim = self.limit_for(m)
            worse = np.maximum(state[m], np.pad(moved[m], (0, state.shape[1] - moved.shape[1])))
            residuals.append((m, np.arange(1, state.shape[1] + 1), np.maximum(worse - lim, 0.0)))
        mine = self.applies_to(sc)
        details = {
            f"max_{self.quantity}_state": float(state[mine].max()) if state.size else 0.0,
            f"max_{self.quantity}_measured": float(moved[mine].max()) if moved.size else 0.0,
        }
        return self._report(sc, residuals, details)


class SpeedLimit(_NormLimit):
    """Speed at most ``vmax``: ``||v_t|| <= vmax`` and ``||p_t - p_{t-1}|| <= vmax dt``, ``t = 1..T``.

    Parameters
    ----------
    vmax
        Limit (distance per unit time), one for all platforms or one per platform.
    sides
        Sides of the inner regular polygons used on backends without cones: they meet the limit with a
        margin of at most ``vmax (1 - cos(pi / sides))`` (2% at 16 sides).
    soft, weight, platforms
        See :class:`~pmht_opt.constraints.base.Constraint`.
    """

    comps = (VX, VY)
    stencil = ((0, 1.0), (-1, -1.0))
    order = 1
    quantity = "speed"

    def __init__(self, vmax: Any, sides: int = DEFAULT_SIDES, **kwargs: Any) -> None:
        super().__init__(vmax, sides, **kwargs)


class AccelLimit(_NormLimit):
    """Acceleration at most ``amax``: ``||a_t|| <= amax`` and
    ``||p_{t+1} - 2 p_t + p_{t-1}|| <= amax dt^2`` wherever the second difference exists.

    Parameters
    ----------
    amax
        Limit, one for all platforms or one per platform.
    sides
        Sides of the inner polygons on backends without cones (see :class:`SpeedLimit`).
    soft, weight, platforms
        See :class:`~pmht_opt.constraints.base.Constraint`.
    """

    comps = (AX, AY)
    stencil = ((1, 1.0), (0, -2.0), (-1, 1.0))
    order = 2
    quantity = "acceleration"

    def __init__(self, amax: Any, sides: int = DEFAULT_SIDES, **kwargs: Any) -> None:
        super().__init__(amax, sides, **kwargs)
