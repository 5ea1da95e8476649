"""Conditions on the final state: a velocity (e.g. at rest) and/or a region to end in."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from pmht_opt.constraints.base import Constraint, ConstraintContext
from pmht_opt.constraints.blocks import DEFAULT_SIDES, Block, disc_block, state_rows
from pmht_opt.constraints.params import check_sides, point_array, positive_number, real_array
from pmht_opt.exceptions import ConfigError
from pmht_opt.model import AX, AY, PX, PY, VX, VY

if TYPE_CHECKING:
    from pmht_opt.scenario import Scenario


class Terminal(Constraint):
    """The state at ``t = T``: velocity, acceleration and/or position.

    Parameters
    ----------
    velocity
        Final velocity, ``(2,)`` for all platforms or ``(M, 2)``; ``(0, 0)`` ends at rest. ``None``
        leaves it free.
    position
        Final position (``(2,)`` or ``(M, 2)``), met within ``radius``; ``"start"`` is each platform's
        own start (return to base); ``None`` leaves it free.
    radius
        ``0`` makes the final position exact; otherwise a disc (a cone, or an inner polygon on OSQP).
    acceleration
        Final acceleration, like ``velocity``.
    sides, soft, weight, platforms
        See :class:`~pmht_opt.constraints.motion.SpeedLimit` and
        :class:`~pmht_opt.constraints.base.Constraint`.
    """

    exact = True

    def __init__(
        self,
        velocity: Any = None,
        position: Any = None,
        radius: float = 0.0,
        acceleration: Any = None,
        sides: int = DEFAULT_SIDES,
        **kwargs: Any,
    ) -> None:
        super().__init__(**kwargs)
        if velocity is None and position is None and acceleration is None:
            raise ConfigError("Terminal: give at least one of velocity, position, acceleration.")
        self.velocity = None if velocity is None else self._points("velocity", velocity)
        self.acceleration = None if acceleration is None else self._points("acceleration", acceleration)
        #: Whether the final position is each platform's start.
        self.at_start = isinstance(position, str)
        if self.at_start and position != "start":
            raise ConfigError(f"Terminal.position: expected coordinates or 'start', got {position!r}.")
        self.position = None if position is None or self.at_start else self._points("position", position)
        self.radius = positive_number("Terminal.radius", radius, allow_zero=True)
        self.sides = check_sides("Terminal", sides)
        # A final position within a radius is a cone; everything else is linear rows.
        if (self.position is not None or self.at_start) and self.radius > 0:
            self.needs = frozenset({"linear", "soc"})

    @classmethod
    def return_to_base(cls, **kwargs: Any) -> Terminal:
        """Every platform ends at its own start, at rest (velocity and acceleration zero)."""
        return cls(velocity=(0.0, 0.0), acceleration=(0.0, 0.0), position="start", **kwargs)

    def scale(self, scenario: Scenario) -> float:
        """A final position's radius, or else the speed (acceleration) of crossing the scenario's area
        once in the horizon (twice divided by the horizon for an acceleration)."""
        extent = super().scale(scenario)
        span = scenario.horizon * scenario.dt
        sizes = []
        if self.position is not None or self.at_start:
            sizes.append(self.radius if self.radius > 0 else 1e-3 * extent)
        if self.velocity is not None:
            sizes.append(extent / span)
        if self.acceleration is not None:
            sizes.append(extent / span**2)
        return min(sizes)

    def targets(self, scenario: Scenario) -> np.ndarray | None:
        """``(1, 2)`` or ``(M, 2)`` final positions on ``scenario`` (``None`` when free)."""
        return scenario.start_positions if self.at_start else self.position

    def end_position(self, scenario: Scenario) -> list[tuple[int, np.ndarray, float]]:
        positions = self.targets(scenario)
        if positions is None:
            return []
        row = (lambda m: 0) if positions.shape[0] == 1 else (lambda m: m)
        return [(m, positions[row(m)], self.radius) for m in self.applies_to(scenario)]

    @staticmethod
    def _points(name: str, value: Any) -> np.ndarray:
        arr = real_array(f"Terminal.{name}", value)
        return point_array(f"Terminal.{name}", arr.reshape(1, -1) if arr.ndim == 1 else arr, (-1, 2))

    @property
    def name(self) -> str:
        parts = []
        if self.velocity is not None:
            parts.append("velocity")
        if self.acceleration is not None:
            parts.append("acceleration")
        if self.position is not None or self.at_start:
            where = "start" if self.at_start else "position"
            parts.append(where + (f" within {self.radius:g}" if self.radius > 0 else ""))
        return f"Terminal({', '.join(parts)})"

    def check_scenario(self, scenario: Scenario) -> None:
        super().check_scenario(scenario)
        for key in ("velocity", "acceleration", "position"):
            arr = getattr(self, key)
            if arr is not None and arr.shape[0] not in (1, scenario.n_platforms):
                raise ConfigError(
                    f"Terminal.{key}: {arr.shape[0]} rows given for {scenario.n_platforms} platforms."
                )

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        T = ctx.scenario.horizon
        end = np.array([T])
        out = []
        positions = self.targets(ctx.scenario)
        for m in self.applies_to(ctx.scenario):
            for arr, comps in ((self.velocity, (VX, VY)), (self.acceleration, (AX, AY))):
                if arr is not None:
                    target = arr[0 if arr.shape[0] == 1 else m]
                    G = state_rows(T, np.array([T, T]), np.array(comps), np.eye(2))
                    out.append(Block(m, "zero", G, target, times=np.array([T, T])))
            if positions is not None:
                target = positions[0 if positions.shape[0] == 1 else m]
                if self.radius == 0:
                    G = state_rows(T, np.array([T, T]), np.array([PX, PY]), np.eye(2))
                    out.append(Block(m, "zero", G, target, times=np.array([T, T])))
                else:
                    disc = disc_block(
                        m, T, end, (PX, PY), target[None, :], np.array([self.radius]), self.sides
                    )
                    out.append(disc)
        return out
